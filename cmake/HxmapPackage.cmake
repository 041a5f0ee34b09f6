# A Debian package for the robot: `cpack` in a build configured with
# -DCMAKE_INSTALL_PREFIX=/usr gives hxmap_<version>_<arch>.deb (amd64, or
# arm64 from the cross build) holding the program, the configuration presets,
# the systemd unit and its settings file /etc/default/hxmap (a conffile: an
# upgrade keeps the robot's edits). Installing it does not start or enable
# the service: `systemctl enable --now hxmap` once /etc/default/hxmap says
# what to map.
#
# Dependencies: computed by dpkg-shlibdeps from the binary where it can
# (a native build); a cross build has no dpkg database for its sysroot and
# declares Debian 12's library packages, the same names on every
# architecture (the CI checks that the two lists agree on amd64).
set(CPACK_GENERATOR DEB)
set(CPACK_PACKAGE_NAME hxmap)
set(CPACK_PACKAGE_VENDOR hxmap)
set(CPACK_PACKAGE_DESCRIPTION_SUMMARY "real-time dense RGB-D mapping for robots")
set(CPACK_PACKAGE_DESCRIPTION
    "hxmap tracks an RGB-D camera and builds a dense TSDF map on the robot's own CPU, at the camera's frame rate, and publishes pose, TF and map over DDS (ROS 2 compatible). It runs on a live camera (V4L2, OpenNI2, libcamera) or a recording, as a command or as a systemd service.")
set(CPACK_DEBIAN_PACKAGE_MAINTAINER "hxmap developers")
set(CPACK_DEBIAN_PACKAGE_SECTION science)
set(CPACK_DEBIAN_FILE_NAME DEB-DEFAULT)
set(CPACK_PACKAGING_INSTALL_PREFIX ${CMAKE_INSTALL_PREFIX})
set(CPACK_STRIP_FILES ON)
set(HXMAP_DEB_DEPENDS
    "libc6, libcamera0.0.3, libceres3, libddsc0debian, libfmt9, libgcc-s1, libgoogle-glog0v6, libimath-3-1-29, libjpeg62-turbo, libopencv-calib3d406, libopencv-core406, libopencv-features2d406, libopencv-imgcodecs406, libopencv-imgproc406, libopenni2-0, libopenvdb10.0, libspdlog1.10-fmt9, libstdc++6, libtbb12, libyaml-cpp0.7, libzstd1"
    CACHE STRING "Depends: of the .deb when dpkg-shlibdeps cannot compute them (cross builds)")
if(CMAKE_CROSSCOMPILING)
  set(CPACK_DEBIAN_PACKAGE_ARCHITECTURE arm64)
  set(CPACK_DEBIAN_PACKAGE_DEPENDS "${HXMAP_DEB_DEPENDS}")
else()
  set(CPACK_DEBIAN_PACKAGE_SHLIBDEPS ON)
endif()
configure_file(${CMAKE_CURRENT_LIST_DIR}/../systemd/debian/postinst ${CMAKE_CURRENT_BINARY_DIR}/debian/postinst COPYONLY)
configure_file(${CMAKE_CURRENT_LIST_DIR}/../systemd/debian/postrm ${CMAKE_CURRENT_BINARY_DIR}/debian/postrm COPYONLY)
set(CPACK_DEBIAN_PACKAGE_CONTROL_EXTRA ${CMAKE_CURRENT_BINARY_DIR}/debian/postinst
                                       ${CMAKE_CURRENT_BINARY_DIR}/debian/postrm)
if(CMAKE_INSTALL_PREFIX STREQUAL "/usr")
  file(WRITE ${CMAKE_CURRENT_BINARY_DIR}/debian/conffiles "${HXMAP_ENV_FILE}\n")
  list(APPEND CPACK_DEBIAN_PACKAGE_CONTROL_EXTRA ${CMAKE_CURRENT_BINARY_DIR}/debian/conffiles)
endif()
set(CPACK_DEBIAN_PACKAGE_CONTROL_STRICT_PERMISSION ON)
include(CPack)
