#!/usr/bin/env bash
# Sets up, builds and runs every test: unit and property tests, the kernel tests (real SocketCAN
# in a QEMU guest, with can-utils as the peer) and a bounded fuzzing run of every decoder.
#   scripts/test.sh
# Environment: SKINBUS_FUZZ_SECONDS (default 20 per target), SKINBUS_SKIP_VM=1 to skip the VM.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
[[ ${SKINBUS_SKIP_VM:-0} == 1 ]] || scripts/can_vm.sh --prepare
scripts/format.sh
scripts/build.sh
ctest --test-dir build -j2 --output-on-failure
SKINBUS_FUZZ_SECONDS=${SKINBUS_FUZZ_SECONDS:-20} scripts/fuzz.sh
echo "test.sh: all tests passed"
