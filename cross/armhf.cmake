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

set(CMAKE_FIND_ROOT_PATH /usr/arm-linux-gnueabihf)
set(CMAKE_FIND_ROOT_PATH_MODE_PROGRAM NEVER)
set(CMAKE_FIND_ROOT_PATH_MODE_LIBRARY ONLY)
set(CMAKE_FIND_ROOT_PATH_MODE_INCLUDE ONLY)
set(CMAKE_FIND_ROOT_PATH_MODE_PACKAGE ONLY)

set(RVD_STATIC ON CACHE BOOL "Link executables statically (cross targets)")

set(_qemu_cpu "${RVD_QEMU_CPU}")
if(NOT _qemu_cpu)
  set(_qemu_cpu "${RVD_CPU}")
endif()
# The dynamic qemu-arm (package qemu-user), not qemu-arm-static: TCG plugins load only in it.
find_program(RVD_QEMU_ARM qemu-arm NO_CMAKE_FIND_ROOT_PATH)
if(RVD_QEMU_ARM)
  set(CMAKE_CROSSCOMPILING_EMULATOR "${RVD_QEMU_ARM};-cpu;${_qemu_cpu}")
endif()
