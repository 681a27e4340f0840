# The part of the cross toolchain files that does not depend on the architecture. The including
# file sets _rvd_triplet (e.g. arm-linux-gnueabihf) and _rvd_qemu_user (e.g. qemu-arm) first.
set(CMAKE_FIND_ROOT_PATH /usr/${_rvd_triplet})
set(CMAKE_FIND_ROOT_PATH_MODE_PROGRAM NEVER)
set(CMAKE_FIND_ROOT_PATH_MODE_LIBRARY ONLY)
set(CMAKE_FIND_ROOT_PATH_MODE_INCLUDE ONLY)
set(CMAKE_FIND_ROOT_PATH_MODE_PACKAGE ONLY)

set(RVD_STATIC ON CACHE BOOL "Link executables statically (cross targets)")

set(_qemu_cpu "${RVD_QEMU_CPU}")
if(NOT _qemu_cpu)
  set(_qemu_cpu "${RVD_CPU}")
endif()
# The dynamic qemu-<arch> (package qemu-user), not the -static one: TCG plugins load only in it.
find_program(RVD_QEMU_USER ${_rvd_qemu_user} NO_CMAKE_FIND_ROOT_PATH)
if(RVD_QEMU_USER)
  set(CMAKE_CROSSCOMPILING_EMULATOR "${RVD_QEMU_USER};-cpu;${_qemu_cpu}")
endif()
