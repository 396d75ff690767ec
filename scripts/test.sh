#!/usr/bin/env bash
# Sets up, builds and runs every test: unit and property tests, the kernel tests (real SocketCAN
# in a QEMU guest, with can-utils as the peer; the deploying guide under systemd on an emulated
# CAN FD controller), the network runtime built for aarch64 and tested under qemu-aarch64 (and
# the x86 kernels on an emulated AVX2-only CPU) and a bounded fuzzing run of every decoder.
#   scripts/test.sh
# Environment: SKINBUS_FUZZ_SECONDS (default 20 per target), SKINBUS_SKIP_VM=1 to skip the VM,
# SKINBUS_SKIP_ARM=1 to skip the Arm build and the emulated-CPU tests (scripts/arm_test.sh).
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
# The kernel, and the CTU CAN FD driver the deploying guide's VM test needs (built once per kernel).
[[ ${SKINBUS_SKIP_VM:-0} == 1 ]] || scripts/can_vm.sh --prepare --ctucanfd
scripts/format.sh
scripts/build.sh
ctest --test-dir build -j2 --output-on-failure
[[ ${SKINBUS_SKIP_ARM:-0} == 1 ]] || scripts/arm_test.sh
SKINBUS_FUZZ_SECONDS=${SKINBUS_FUZZ_SECONDS:-20} scripts/fuzz.sh
echo "test.sh: all tests passed"
