// PLY mesh files: written as binary little endian with per-vertex colors;
// read from ascii or binary_little_endian (float/double coordinates, optional
// uchar colors, triangle or polygon faces fanned into triangles).
#pragma once

#include <string>

#include "hxmap/core/expected.hpp"
#include "hxmap/geometry/mesh.hpp"

namespace hxmap::drv {

Status writePly(const std::string& path, const alg::TriangleMesh& mesh);
Expected<alg::TriangleMesh> readPly(const std::string& path);
/// Parses PLY content; `source` names it in messages.
Expected<alg::TriangleMesh> parsePly(const std::string& content, const std::string& source);

/// Writes `text` to `path` through a temporary file and a rename, so a reader
/// never sees a half-written file.
Status writeTextFile(const std::string& path, const std::string& text);

}  // namespace hxmap::drv
