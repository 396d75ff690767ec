#!/usr/bin/env bash
# Sets up, builds and runs every test: unit and property tests, the kernel tests (real SocketCAN
# in a QEMU guest, with can-utils as the peer; the deploying guide under systemd on an emulated
# CAN FD controller) and a bounded fuzzing run of every decoder.
#   scripts/test.sh
# Environment: SKINBUS_FUZZ_SECONDS (default 20 per target), SKINBUS_SKIP_VM=1 to skip the VM.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
# The kernel, and the CTU CAN FD driver the deploying guide's VM test needs (built once per kernel).
[[ ${SKINBUS_SKIP_VM:-0} == 1 ]] || scripts/can_vm.sh --prepare --ctucanfd
scripts/format.sh
scripts/build.sh
ctest --test-dir build -j2 --output-on-failure
SKINBUS_FUZZ_SECONDS=${SKINBUS_FUZZ_SECONDS:-20} scripts/fuzz.sh
echo "test.sh: all tests passed"
