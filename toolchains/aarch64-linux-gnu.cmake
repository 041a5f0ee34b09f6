# Cross build for 64-bit ARM (Jetson, Raspberry Pi 4/5, RK3588 boards) with
# Debian's cross compiler:
#   apt install g++-aarch64-linux-gnu qemu-user-static
#   bash .ci/arm64-sysroot build-arm64/sysroot
#   cmake -S . -B build-arm64 -G Ninja -DCMAKE_TOOLCHAIN_FILE=toolchains/aarch64-linux-gnu.cmake \
#         -DHXMAP_SYSROOT=$PWD/build-arm64/sysroot
# Target libraries come from a target root file system (-DHXMAP_SYSROOT: the
# one .ci/arm64-sysroot makes from Debian's arm64 packages, or a board's) or,
# without one, from Debian multiarch packages installed on the host
# (dpkg --add-architecture arm64; apt install libopencv-core-dev:arm64 ...),
# which is enough for -DHXMAP_ALGORITHMS_ONLY=ON but not for the whole
# program (libopencv-dev cannot be installed for two architectures at once).
set(CMAKE_SYSTEM_NAME Linux)
set(CMAKE_SYSTEM_PROCESSOR aarch64)

set(_triple aarch64-linux-gnu)
find_program(_cxx ${_triple}-g++)
find_program(_cc ${_triple}-gcc)
if(NOT _cxx OR NOT _cc)
  message(FATAL_ERROR "aarch64 cross compiler not found (${_triple}-g++). Install it with: apt install g++-${_triple}")
endif()
set(CMAKE_C_COMPILER ${_cc})
set(CMAKE_CXX_COMPILER ${_cxx})

set(HXMAP_SYSROOT "" CACHE PATH "Target root file system (empty: Debian multiarch)")
# try_compile() projects read this file again: they must see the same sysroot.
list(APPEND CMAKE_TRY_COMPILE_PLATFORM_VARIABLES HXMAP_SYSROOT)
# Target libraries live in /usr/lib/aarch64-linux-gnu, in a sysroot as on the host.
set(CMAKE_LIBRARY_ARCHITECTURE ${_triple})
if(HXMAP_SYSROOT)
  if(NOT EXISTS "${HXMAP_SYSROOT}/usr/include")
    message(FATAL_ERROR "HXMAP_SYSROOT=${HXMAP_SYSROOT} is not a target root file system (no usr/include)")
  endif()
  set(CMAKE_SYSROOT ${HXMAP_SYSROOT})
  set(CMAKE_FIND_ROOT_PATH ${HXMAP_SYSROOT})
  set(ENV{PKG_CONFIG_SYSROOT_DIR} "${HXMAP_SYSROOT}")
  set(ENV{PKG_CONFIG_LIBDIR}
      "${HXMAP_SYSROOT}/usr/lib/${_triple}/pkgconfig:${HXMAP_SYSROOT}/usr/lib/pkgconfig:${HXMAP_SYSROOT}/usr/share/pkgconfig")
else()
  set(ENV{PKG_CONFIG_LIBDIR} "/usr/lib/${_triple}/pkgconfig:/usr/share/pkgconfig")
endif()

# Test binaries (and gtest's test discovery at build time) run under QEMU's
# user-mode emulator when it is installed (apt install qemu-user-static).
find_program(HXMAP_QEMU NAMES qemu-aarch64-static qemu-aarch64)
if(HXMAP_QEMU)
  if(HXMAP_SYSROOT)
    set(CMAKE_CROSSCOMPILING_EMULATOR ${HXMAP_QEMU} -L ${HXMAP_SYSROOT})
  else()
    set(CMAKE_CROSSCOMPILING_EMULATOR ${HXMAP_QEMU})
  endif()
endif()
set(CMAKE_FIND_ROOT_PATH_MODE_PROGRAM NEVER)
set(CMAKE_FIND_ROOT_PATH_MODE_LIBRARY ONLY)
set(CMAKE_FIND_ROOT_PATH_MODE_INCLUDE BOTH)
set(CMAKE_FIND_ROOT_PATH_MODE_PACKAGE BOTH)
