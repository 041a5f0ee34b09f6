# Cross build for 64-bit ARM (Jetson, Raspberry Pi 4/5, RK3588 boards) with
# Debian's cross compiler:
#   apt install g++-aarch64-linux-gnu
#   cmake -S . -B build-arm64 -G Ninja -DCMAKE_TOOLCHAIN_FILE=toolchains/aarch64-linux-gnu.cmake
# Libraries for the target come either from Debian multiarch packages
# (dpkg --add-architecture arm64; apt install libopencv-dev:arm64 libyaml-cpp-dev:arm64 ...)
# or from a target root file system given as -DHXMAP_SYSROOT=/path/to/rootfs.
# -DHXMAP_ALGORITHMS_ONLY=ON builds just the algorithms libraries and needs
# only libopencv-core-dev:arm64 and libopencv-imgproc-dev:arm64 (what CI
# checks, see .ci/cross).
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
if(HXMAP_SYSROOT)
  if(NOT EXISTS "${HXMAP_SYSROOT}/usr/include")
    message(FATAL_ERROR "HXMAP_SYSROOT=${HXMAP_SYSROOT} is not a target root file system (no usr/include)")
  endif()
  set(CMAKE_SYSROOT ${HXMAP_SYSROOT})
  set(CMAKE_FIND_ROOT_PATH ${HXMAP_SYSROOT})
else()
  # Debian multiarch: target libraries in /usr/lib/aarch64-linux-gnu.
  set(CMAKE_LIBRARY_ARCHITECTURE ${_triple})
  set(ENV{PKG_CONFIG_LIBDIR} "/usr/lib/${_triple}/pkgconfig:/usr/share/pkgconfig")
endif()
set(CMAKE_FIND_ROOT_PATH_MODE_PROGRAM NEVER)
set(CMAKE_FIND_ROOT_PATH_MODE_LIBRARY ONLY)
set(CMAKE_FIND_ROOT_PATH_MODE_INCLUDE BOTH)
set(CMAKE_FIND_ROOT_PATH_MODE_PACKAGE BOTH)
