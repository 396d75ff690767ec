#!/usr/bin/env bash
# Everything that needs a kernel with SocketCAN, run inside the CAN test VM:
#   scripts/can_vm.sh -- tests/kernel/run_in_guest.sh BUILD_DIR
set -uo pipefail
build=${1:?usage: run_in_guest.sh BUILD_DIR}
here=$(cd "$(dirname "$0")" && pwd)
status=0
"$build/tests/kernel_socketcan_test" --gtest_brief=1 || status=1
"$here/bus_e2e.sh" "$build" || status=1
"$here/patchd_e2e.sh" "$build" || status=1
if [[ -x "$build/tools/skinbus-listen" ]]; then
  "$here/host_e2e.sh" "$build" || status=1
  "$here/demo_vm.sh" "$build" || status=1
fi
"$here/guides_vm.sh" "$build" || status=1
exit $status
