# Cross build for 64-bit Arm Linux with Debian's g++-aarch64-linux-gnu (scripts/arm_test.sh builds
# the network runtime and its LibTorch-free tests with it: -DSKINBUS_RUNTIME_ONLY=ON
# -DSKINBUS_ONEDNN=OFF). Programs come from the host; libraries, headers and packages from the
# aarch64 sysroot and from the prefixes given as GTest_DIR (GoogleTest built from Debian's
# sources by the script). Tests run under qemu-user; QEMU_CPU in the environment picks the CPU.
set(CMAKE_SYSTEM_NAME Linux)
set(CMAKE_SYSTEM_PROCESSOR aarch64)
set(CMAKE_C_COMPILER aarch64-linux-gnu-gcc)
set(CMAKE_CXX_COMPILER aarch64-linux-gnu-g++)

set(CMAKE_FIND_ROOT_PATH /usr/aarch64-linux-gnu)
set(CMAKE_FIND_ROOT_PATH_MODE_PROGRAM NEVER)
set(CMAKE_FIND_ROOT_PATH_MODE_LIBRARY ONLY)
set(CMAKE_FIND_ROOT_PATH_MODE_INCLUDE ONLY)
set(CMAKE_FIND_ROOT_PATH_MODE_PACKAGE ONLY)

# The test programs (and gtest_discover_tests' listing) run under qemu-aarch64 with the cross
# C and C++ runtime libraries.
set(CMAKE_CROSSCOMPILING_EMULATOR qemu-aarch64 -L /usr/aarch64-linux-gnu)

# nlohmann-json is header-only and the same on every architecture: the host's package.
set(nlohmann_json_DIR /usr/share/cmake/nlohmann_json CACHE PATH "nlohmann-json's CMake package")
