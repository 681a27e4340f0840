# CMake toolchain: 32-bit ARM Linux, hard float (Debian armhf), Debian's cross g++.
# One file serves every ARMv7-A CPU; the CPU is a cache variable:
#   cmake -S . -B build/cross/q7s -DCMAKE_TOOLCHAIN_FILE=cross/armhf.cmake -DRVD_CPU=cortex-a9 \
#         -DRVD_BUILD_PYTHON=OFF
# Executables are static (RVD_STATIC defaults to ON here) so QEMU user mode needs no sysroot, and
# ctest runs each test under `qemu-arm -cpu <RVD_QEMU_CPU>` (CMAKE_CROSSCOMPILING_EMULATOR).
set(CMAKE_SYSTEM_NAME Linux)
set(CMAKE_SYSTEM_PROCESSOR arm)

set(RVD_CPU "cortex-a9" CACHE STRING "Target CPU, passed as -mcpu")
set(RVD_FPU "" CACHE STRING "Target FPU, passed as -mfpu; empty = the usual FPU of RVD_CPU")
set(RVD_QEMU_CPU "" CACHE STRING "QEMU -cpu model that runs the tests; empty = RVD_CPU")
# try_compile projects re-read this file; hand them the same CPU.
list(APPEND CMAKE_TRY_COMPILE_PLATFORM_VARIABLES RVD_CPU RVD_FPU RVD_QEMU_CPU)

# The FPU each CPU has. Cortex-A8 and A9 have VFPv3 (+NEON): code built for VFPv4 (neon-vfpv4, as
# for A7/A15) uses vfma and dies with SIGILL on an A9, e.g. the Q7S's Zynq-7020.
set(_fpu "${RVD_FPU}")
if(NOT _fpu)
  if(RVD_CPU MATCHES "^cortex-a(8|9)$")
    set(_fpu neon)
  elseif(RVD_CPU MATCHES "^cortex-a(5|7|12|15|17)$")
    set(_fpu neon-vfpv4)
  else()
    message(FATAL_ERROR "cross/armhf.cmake: no FPU known for RVD_CPU='${RVD_CPU}'; set -DRVD_FPU=...")
  endif()
endif()

set(CMAKE_C_COMPILER arm-linux-gnueabihf-gcc)
set(CMAKE_CXX_COMPILER arm-linux-gnueabihf-g++)
# -Wno-psabi: GCC's note about a changed ABI for std::vector of doubles in GCC 7 is noise here.
set(_flags "-mcpu=${RVD_CPU} -mfpu=${_fpu} -mfloat-abi=hard -Wno-psabi")
set(CMAKE_C_FLAGS_INIT "${_flags}")
set(CMAKE_CXX_FLAGS_INIT "${_flags}")

set(_rvd_triplet arm-linux-gnueabihf)
set(_rvd_qemu_user qemu-arm)
include(${CMAKE_CURRENT_LIST_DIR}/linux-common.cmake)
