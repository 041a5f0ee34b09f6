# hxmap_find_opencv(<module>...): OpenCV's CMake package, or, where there is
# none, the modules' libraries found one by one.
#
# Debian ships OpenCV's CMake package only with the whole libopencv-dev, which
# for another architecture (an arm64 sysroot) pulls in Qt, VTK and GDAL; the
# per-module packages (libopencv-core-dev, libopencv-imgproc-dev, ...) carry
# headers and libraries alone. Both give the same targets: opencv_<module>.
macro(hxmap_find_opencv)
  find_package(OpenCV QUIET COMPONENTS ${ARGN})
  if(NOT OpenCV_FOUND)
    find_path(HXMAP_OPENCV_INCLUDE opencv2/core.hpp PATH_SUFFIXES opencv4 REQUIRED)
    foreach(_hxmap_m ${ARGN})
      find_library(HXMAP_OPENCV_${_hxmap_m} opencv_${_hxmap_m} REQUIRED)
      if(NOT TARGET opencv_${_hxmap_m})
        add_library(opencv_${_hxmap_m} UNKNOWN IMPORTED)
        set_target_properties(opencv_${_hxmap_m} PROPERTIES IMPORTED_LOCATION ${HXMAP_OPENCV_${_hxmap_m}}
                                                          INTERFACE_INCLUDE_DIRECTORIES ${HXMAP_OPENCV_INCLUDE})
      endif()
    endforeach()
    message(STATUS "hxmap: OpenCV modules found one by one (no OpenCV CMake package): ${ARGN}")
  endif()
endmacro()
