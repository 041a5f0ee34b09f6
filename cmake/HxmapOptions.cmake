# Compiler flags shared by every hxmap target, via the interface target
# hxmap_flags (linked privately by each module).
add_library(hxmap_flags INTERFACE)
target_compile_options(hxmap_flags INTERFACE -Wall -Wextra -Wpedantic)
# No errno from libm: lets sqrt and friends inline (hxmap never reads errno
# after math calls).
target_compile_options(hxmap_flags INTERFACE -fno-math-errno)
# No floating-point traps either (hxmap never enables or reads them): lets
# GCC turn `cond ? a : b` over floats into a blend, which is what vectorizes
# branch-free loops such as the depth filter's taps. Values are unchanged
# (this is not -ffast-math); clang already assumes it.
target_compile_options(hxmap_flags INTERFACE -fno-trapping-math)
if(HXMAP_WERROR)
  target_compile_options(hxmap_flags INTERFACE -Werror)
endif()
if(HXMAP_NATIVE)
  target_compile_options(hxmap_flags INTERFACE -march=native)
endif()
if(HXMAP_SANITIZE)
  string(REPLACE ";" "," _san "${HXMAP_SANITIZE}")
  # Applied globally so that every object (and GoogleTest's main) agrees.
  add_compile_options(-fsanitize=${_san} -fno-omit-frame-pointer -fno-sanitize-recover=undefined)
  add_link_options(-fsanitize=${_san})
  message(STATUS "hxmap: sanitizers: ${_san}")
endif()

# oneTBB's concurrent_hash_map (inside OpenVDB's trees) casts marker values
# such as 0x3 to node pointers as it walks its buckets; clang's
# UndefinedBehaviorSanitizer reports that as a misaligned downcast, in
# Debian's headers. Off for the sources that use OpenVDB.
set(HXMAP_OPENVDB_SANITIZE_OPTIONS "")
if(CMAKE_CXX_COMPILER_ID MATCHES "Clang" AND (HXMAP_SANITIZE MATCHES "undefined" OR HXMAP_FUZZ))
  set(HXMAP_OPENVDB_SANITIZE_OPTIONS -fno-sanitize=alignment)
endif()

if(HXMAP_FUZZ)
  # Coverage for the libraries the fuzz targets call; the targets add -fsanitize=fuzzer.
  add_compile_options(-fsanitize=fuzzer-no-link,address,undefined -fno-omit-frame-pointer)
  add_link_options(-fsanitize=address,undefined)
endif()

# hxmap_module(NAME DEPS...): a static library algorithms/<name> with a public
# include/ folder and sources in src/.
function(hxmap_module name)
  cmake_parse_arguments(M "" "" "DEPS;PRIVATE_DEPS" ${ARGN})
  file(GLOB _src CONFIGURE_DEPENDS ${CMAKE_CURRENT_SOURCE_DIR}/src/*.cpp)
  add_library(hxmap_${name} STATIC ${_src})
  add_library(hxmap::${name} ALIAS hxmap_${name})
  target_include_directories(hxmap_${name} PUBLIC ${CMAKE_CURRENT_SOURCE_DIR}/include)
  target_link_libraries(hxmap_${name} PUBLIC ${M_DEPS} PRIVATE hxmap_flags ${M_PRIVATE_DEPS})
endfunction()
