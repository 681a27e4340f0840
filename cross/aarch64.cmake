# CMake toolchain: 64-bit ARM Linux (Debian arm64), Debian's cross g++.
# One file serves every ARMv8-A CPU; the CPU is a cache variable:
#   cmake -S . -B build/cross/rpi3 -DCMAKE_TOOLCHAIN_FILE=cross/aarch64.cmake -DRVD_CPU=cortex-a53 \
#         -DRVD_BUILD_PYTHON=OFF
# Executables are static (RVD_STATIC defaults to ON here) so QEMU user mode needs no sysroot, and
# ctest runs each test under `qemu-aarch64 -cpu <RVD_QEMU_CPU>` (CMAKE_CROSSCOMPILING_EMULATOR).
set(CMAKE_SYSTEM_NAME Linux)
set(CMAKE_SYSTEM_PROCESSOR aarch64)

set(RVD_CPU "cortex-a53" CACHE STRING "Target CPU, passed as -mcpu")
set(RVD_QEMU_CPU "" CACHE STRING "QEMU -cpu model that runs the tests; empty = RVD_CPU")
list(APPEND CMAKE_TRY_COMPILE_PLATFORM_VARIABLES RVD_CPU RVD_QEMU_CPU)

set(CMAKE_C_COMPILER aarch64-linux-gnu-gcc)
set(CMAKE_CXX_COMPILER aarch64-linux-gnu-g++)
# AArch64 always has FP and Advanced SIMD (double-precision NEON included): no -mfpu.
set(CMAKE_C_FLAGS_INIT "-mcpu=${RVD_CPU}")
set(CMAKE_CXX_FLAGS_INIT "-mcpu=${RVD_CPU}")

set(_rvd_triplet aarch64-linux-gnu)
set(_rvd_qemu_user qemu-aarch64)
include(${CMAKE_CURRENT_LIST_DIR}/linux-common.cmake)
