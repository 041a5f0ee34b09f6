# Optional parts. Each defaults ON when its package is found; the summary at
# the end of configuration says what was built and what was left out and why.
find_package(PkgConfig QUIET)
set(HXMAP_SUMMARY_LINES "")

# Parts marked "(not implemented yet)" are detected so that the build is
# ready for them; their code has not landed.
# The option follows detection (a package installed after the first
# configure turns its part on) until the user sets it to something else.
macro(hxmap_optional var description found reason)
  if(${found})
    set(_auto ON)
  else()
    set(_auto OFF)
  endif()
  set(_user_set FALSE)
  if(DEFINED ${var} AND DEFINED ${var}_AUTO)
    if((${var} AND NOT ${var}_AUTO) OR (NOT ${var} AND ${var}_AUTO))
      set(_user_set TRUE)
    endif()
  elseif(DEFINED ${var})
    set(_user_set TRUE)  # given on the first configure's command line
  endif()
  if(NOT _user_set)
    set(${var} ${_auto} CACHE BOOL "${description}" FORCE)
  endif()
  set(${var}_AUTO ${_auto} CACHE INTERNAL "")
  if(${var} AND NOT ${found})
    message(FATAL_ERROR "${var}=ON but ${reason}")
  endif()
  if(${var})
    list(APPEND HXMAP_SUMMARY_LINES "  [x] ${description}")
  elseif(${found})
    list(APPEND HXMAP_SUMMARY_LINES "  [ ] ${description}: turned off by ${var}=OFF")
  else()
    list(APPEND HXMAP_SUMMARY_LINES "  [ ] ${description}: left out, ${reason}")
  endif()
endmacro()

set(_v4l2_found FALSE)
if(PkgConfig_FOUND)
  pkg_check_modules(LIBV4L2 QUIET IMPORTED_TARGET libv4l2)
  pkg_check_modules(LIBCAMERA QUIET IMPORTED_TARGET libcamera)
  pkg_check_modules(OPENNI2 QUIET IMPORTED_TARGET libopenni2)
endif()
include(CheckIncludeFileCXX)
check_include_file_cxx(linux/videodev2.h HXMAP_HAVE_VIDEODEV2_H)
hxmap_optional(HXMAP_WITH_V4L2 "V4L2 camera driver (kernel video4linux2 API)" HXMAP_HAVE_VIDEODEV2_H
  "linux/videodev2.h not found (apt install linux-libc-dev)")
hxmap_optional(HXMAP_WITH_OPENNI2 "OpenNI2 camera driver and .oni playback" OPENNI2_FOUND
  "OpenNI2 not found (apt install libopenni2-dev)")
hxmap_optional(HXMAP_WITH_LIBCAMERA "libcamera color driver (CSI cameras)" LIBCAMERA_FOUND
  "libcamera not found (apt install libcamera-dev)")
find_package(CycloneDDS QUIET)
find_program(HXMAP_IDLC idlc)
set(_dds_found FALSE)
if(CycloneDDS_FOUND AND HXMAP_IDLC)
  set(_dds_found TRUE)
endif()
hxmap_optional(HXMAP_WITH_DDS "Cyclone DDS publishing and hxmap echo" _dds_found
  "Cyclone DDS or its idlc not found (apt install cyclonedds-dev cyclonedds-tools)")
if(HXMAP_WITH_DDS)
  enable_language(C)  # idlc generates C
endif()
find_package(TBB QUIET)
hxmap_optional(HXMAP_WITH_TBB "TBB parallel-for in the hxmap program" TBB_FOUND
  "TBB not found (apt install libtbb-dev)")
# OpenVDB export (hxmap map export): the library, its Imath dependency and
# Boost's headers, which OpenVDB's headers include.
find_path(HXMAP_OPENVDB_INCLUDE openvdb/openvdb.h)
find_library(HXMAP_OPENVDB_LIB openvdb)
find_library(HXMAP_IMATH_LIB NAMES Imath-3_1 Imath)
find_path(HXMAP_BOOST_INCLUDE boost/numeric/conversion/conversion_traits.hpp)
set(_openvdb_found FALSE)
if(HXMAP_OPENVDB_INCLUDE AND HXMAP_OPENVDB_LIB AND HXMAP_IMATH_LIB AND HXMAP_BOOST_INCLUDE AND TBB_FOUND)
  set(_openvdb_found TRUE)
endif()
hxmap_optional(HXMAP_WITH_OPENVDB "OpenVDB export of saved maps (hxmap map export)" _openvdb_found
  "OpenVDB, Imath, Boost headers or TBB not found (apt install libopenvdb-dev libboost-dev libtbb-dev)")
find_package(Open3D QUIET)
hxmap_optional(HXMAP_WITH_OPEN3D_PEER "Open3D TSDF integration as the peer in bench_frontend" Open3D_FOUND
  "Open3D not found (apt install libopen3d-dev)")

function(hxmap_print_summary)
  message(STATUS "hxmap ${PROJECT_VERSION}: build type ${CMAKE_BUILD_TYPE}, generator ${CMAKE_GENERATOR}, "
                 "ccache ${HXMAP_CCACHE}")
  message(STATUS "hxmap optional parts:")
  foreach(l ${HXMAP_SUMMARY_LINES})
    message(STATUS "${l}")
  endforeach()
endfunction()
