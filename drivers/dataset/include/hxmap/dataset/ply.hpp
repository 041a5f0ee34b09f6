// PLY mesh files: written as binary little endian with per-vertex colors;
// read from ascii or binary_little_endian (float/double coordinates, optional
// uchar colors, triangle or polygon faces fanned into triangles).
#pragma once

#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "hxmap/core/expected.hpp"
#include "hxmap/geometry/mesh.hpp"

namespace hxmap::drv {

Status writePly(const std::string& path, const alg::TriangleMesh& mesh);
/// Boxes as a PLY wireframe (8 vertices and 12 edges per box, ascii), e.g.
/// ROIs for a viewer such as MeshLab or CloudCompare.
Status writePlyBoxes(const std::string& path, const std::vector<Eigen::AlignedBox3f>& boxes,
                     const alg::Color3& color = {255, 230, 0});
Expected<alg::TriangleMesh> readPly(const std::string& path);
/// Parses PLY content; `source` names it in messages.
Expected<alg::TriangleMesh> parsePly(const std::string& content, const std::string& source);

/// Writes `text` to `path` through a temporary file and a rename, so a reader
/// never sees a half-written file.
Status writeTextFile(const std::string& path, const std::string& text);

}  // namespace hxmap::drv
