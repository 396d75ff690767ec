#!/usr/bin/env bash
# Installs every Debian (bookworm) package skinbus needs to build, test and run its demo.
# Idempotent and quick when everything is installed: apt is touched only for missing packages.
set -euo pipefail

packages=(
  # build
  g++ cmake ninja-build ccache pkg-config clang-format git
  # libraries
  libcli11-dev libgtest-dev libgmock-dev libbenchmark-dev libyaml-cpp-dev nlohmann-json3-dev
  # patch node: GPIO lines (libgpiod 1.6 C++ bindings)
  libgpiod-dev
  # body map: robot descriptions (URDF) and calibration (Ceres Solver 2.1, Eigen)
  liburdfdom-dev libceres-dev libeigen3-dev
  # models: LibTorch for training (with OpenBLAS: the reference BLAS is ~10x slower), oneDNN
  libtorch-dev libopenblas0-openmp libdnnl-dev
  # host aggregator: Eclipse Cyclone DDS (C API and idlc)
  cyclonedds-dev cyclonedds-tools
  # the DDS interoperability test's peer: eProsima Fast DDS, ROS 2's default middleware
  libfastrtps-dev libfastcdr-dev
  # fuzzing (libFuzzer ships with clang's runtime)
  clang libclang-rt-14-dev
  # CAN: can-utils are the real peer in tests; the kernel tests boot Debian's kernel in QEMU
  can-utils iproute2 kmod qemu-system-x86 busybox-static xz-utils zstd cpio
  # the deploying guide's VM test: systemd-udevd in the guest, and the emulated CTU CAN FD
  # controller's driver, built against Debian's kernel headers (scripts/can_vm.sh --ctucanfd)
  udev make gcc-12
  # the Arm build of the network runtime, its tests under user-mode QEMU (scripts/arm_test.sh;
  # GoogleTest for arm64 is built from libgtest-dev's sources)
  g++-aarch64-linux-gnu qemu-user
  # reports and plots
  python3 python3-matplotlib
  # the red-team suite and the soak measure peak memory (GNU time)
  time
  # the web view's test drives the page in headless Chromium
  chromium
)

missing=()
for p in "${packages[@]}"; do
  if [[ $(dpkg-query -W -f='${Status}' "$p" 2>/dev/null) != "install ok installed" ]]; then
    missing+=("$p")
  fi
done
# The web view's libraries come from the npm registry (Debian's npm when no npm is installed).
command -v npm >/dev/null || missing+=(npm)
if ((${#missing[@]})); then
  echo "setup: installing ${missing[*]}"
  sudo_cmd=()
  [[ $(id -u) -ne 0 ]] && sudo_cmd=(sudo)
  "${sudo_cmd[@]}" apt-get update -q
  DEBIAN_FRONTEND=noninteractive "${sudo_cmd[@]}" apt-get install -y -q --no-install-recommends "${missing[@]}"
else
  echo "setup: all ${#packages[@]} packages present"
fi

# npm packages, pinned in their package-lock.json, installed with npm ci (again only when the
# lock file changed): the web view's libraries (view/web: three.js, urdf-loader), served locally
# to its page, and the independent readers of the interoperability tests (tests/interop:
# @mcap/core, @foxglove/rosmsg2-serialization, @foxglove/ws-protocol), run with Node.js.
root=$(cd "$(dirname "$0")/.." && pwd)
for dir in "$root/view/web" "$root/tests/interop"; do
  if ! cmp -s "$dir/package-lock.json" "$dir/node_modules/.skinbus-installed-lock" 2>/dev/null; then
    echo "setup: installing the npm packages of ${dir#"$root"/} (npm ci)"
    (cd "$dir" && npm ci --no-audit --no-fund --loglevel=error)
    cp "$dir/package-lock.json" "$dir/node_modules/.skinbus-installed-lock"
  fi
done
