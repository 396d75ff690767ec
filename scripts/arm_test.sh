#!/usr/bin/env bash
# The Arm path of the network runtime, checked without Arm hardware: builds the runtime library
# (common and the estimators library; no oneDNN, no LibTorch) and its LibTorch-free tests with
# Debian's aarch64 cross compiler into build-aarch64/ and runs them under qemu-aarch64 twice: on a
# CPU with the dot-product instructions (-cpu max: NEON float32 and bfloat16, SDOT int8) and on
# one without (-cpu cortex-a53: the widening int8 path). Then the x86 kernel and runtime tests of
# build/ run under qemu-x86_64 on a Haswell CPU (AVX2 + FMA, no AVX-512): the run-time choice of
# the AVX2 kernels, on a machine whose own CPU has AVX-512. Emulated speed means nothing here:
# only equality with the portable kernels is checked.
#   scripts/arm_test.sh
# Environment: SKINBUS_SKIP_X86_QEMU=1 skips the x86 part (which needs build/, scripts/build.sh).
set -euo pipefail
cd "$(dirname "$0")/.."
root=$PWD
build="build-aarch64"
deps=$root/$build/deps
toolchain=$root/cmake/aarch64-linux-gnu.toolchain.cmake
sysroot=/usr/aarch64-linux-gnu

for tool in aarch64-linux-gnu-g++ qemu-aarch64 qemu-x86_64; do
  command -v "$tool" >/dev/null || { echo "arm_test.sh: $tool missing: run scripts/setup.sh" >&2; exit 1; }
done

# Runs "$@", shows the lines matching $show, and fails unless one of them contains $want.
expect_line() {
  local show=$1 want=$2 out
  shift 2
  out=$("$@")
  grep -E "$show" <<<"$out" | sed 's/^/  /'
  grep -qF -- "$want" <<<"$out" || { echo "arm_test.sh: expected '$want' from $*" >&2; exit 1; }
}

# GoogleTest for aarch64, from the sources Debian's libgtest-dev ships (built once per build dir).
if [[ ! -f $deps/lib/cmake/GTest/GTestConfig.cmake ]]; then
  echo "arm_test: GoogleTest for aarch64 from /usr/src/googletest"
  cmake -S /usr/src/googletest -B "$build/googletest" -G Ninja -DCMAKE_TOOLCHAIN_FILE="$toolchain" \
    -DCMAKE_BUILD_TYPE=Release -DCMAKE_CXX_COMPILER_LAUNCHER=ccache \
    -DCMAKE_C_COMPILER_LAUNCHER=ccache -DCMAKE_INSTALL_PREFIX="$deps" >/dev/null
  cmake --build "$build/googletest" -j2
  cmake --install "$build/googletest" >/dev/null
fi

echo "arm_test: building the runtime for aarch64 into $build/"
cmake -S . -B "$build" -G Ninja -DCMAKE_TOOLCHAIN_FILE="$toolchain" -DSKINBUS_RUNTIME_ONLY=ON \
  -DSKINBUS_ONEDNN=OFF -DSKINBUS_WERROR=ON -DGTest_DIR="$deps/lib/cmake/GTest" >/dev/null
cmake --build "$build" -j2

export SKINBUS_SOURCE_DIR=$root
kernels_test=$build/estimators/estimators_network_kernels_test
for cpu in max cortex-a53; do
  want=$([[ $cpu == max ]] && echo "neon (int8 neon-dotprod)" || echo "neon (int8 neon)")
  echo "arm_test: qemu-aarch64 -cpu $cpu: expecting kernels $want"
  expect_line "kernels here|int8 kernels checked" "kernels here: $want" \
    env QEMU_CPU=$cpu qemu-aarch64 -L "$sysroot" "$kernels_test" \
    --gtest_filter='NetworkKernelsTest.TheCapLimitsTheChoice:NetworkKernelsTest.Int8*'
  QEMU_CPU=$cpu ctest --test-dir "$build" -j2 --output-on-failure
done

if [[ ${SKINBUS_SKIP_X86_QEMU:-0} != 1 ]]; then
  # Haswell without the features QEMU's TCG lacks (they only add warnings); AVX2 and FMA it has.
  haswell=Haswell-noTSX,-pcid,-x2apic,-tsc-deadline,-invpcid
  [[ -f build/build.ninja ]] || cmake -S . -B build -G Ninja -DSKINBUS_WERROR=ON >/dev/null
  cmake --build build -j2 --target estimators_network_kernels_test estimators_network_runtime_isa_test \
    sim_dipole_sum_test
  echo "arm_test: qemu-x86_64 -cpu Haswell: expecting kernels avx2 (int8 avx2)"
  expect_line "kernels here|int8 kernels checked|PASSED|FAILED" "kernels here: avx2 (int8 avx2)" \
    qemu-x86_64 -cpu "$haswell" build/estimators/estimators_network_kernels_test
  expect_line "kernels in use|PASSED|FAILED" "kernels in use: kernels avx2 int8" \
    qemu-x86_64 -cpu "$haswell" build/estimators/estimators_network_runtime_isa_test
  # The simulator's field evaluation (the host's refinement) picks its AVX2 build there too.
  expect_line "builds checked|PASSED|FAILED" "builds checked against the baseline: 1 (field here: avx2)" \
    qemu-x86_64 -cpu "$haswell" build/sim/sim_dipole_sum_test
fi
echo "arm_test.sh: passed (aarch64 under qemu-aarch64 max and cortex-a53$([[ ${SKINBUS_SKIP_X86_QEMU:-0} == 1 ]] || echo "; x86 AVX2 under qemu-x86_64 Haswell"))"
