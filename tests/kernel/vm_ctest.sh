#!/usr/bin/env bash
# CTest entry point for the kernel tests: boots the CAN test VM and runs run_in_guest.sh.
# Exit 77 (CTest: skipped) only when SKINBUS_SKIP_VM=1 is set explicitly.
set -euo pipefail
build=${1:?usage: vm_ctest.sh BUILD_DIR}
cd "$(dirname "$0")/../.."
if [[ ${SKINBUS_SKIP_VM:-0} == 1 ]]; then
  echo "kernel tests skipped: SKINBUS_SKIP_VM=1"
  exit 77
fi
exec scripts/can_vm.sh --timeout 600 --fd-ifaces 1 --classic-ifaces 1 -- tests/kernel/run_in_guest.sh "$build"
