// A neural voxel field over one ROI (paper 3.3, eq 8-9): x -> (s, c).
//
//   F_geo(x)  coarse grid, one node per voxel center: TSDF signed distance
//             (in units of mu) and normal, initialized from the map;
//             fine grid, fine_per_voxel nodes per voxel: a signed distance
//             detail below the voxel size, zero at start
//   F_tex(x)  one node per voxel center: the map's color
//   z = Phi_fuse(F_geo, F_tex) = softplus(W_f [F_geo; F_tex] + b_f)
//   h = softplus(W_1 [z; gamma(x)] + b_1),  o = W_2 h + b_2
//   s = mu (sdf_coarse + sdf_fine + o_0),   c = rgb_tex + o_1..3
// with gamma(x) the local position in the box and its sin/cos octaves.
//
// DESIGN: the decoder's output layer starts at zero, so the untrained field
// is exactly the TSDF (trilinear over voxel centers, as the raycaster
// samples it) and its colors: training starts from the explicit map's
// answer instead of from noise (the paper's informative priors), and a job
// shed after a few iterations still writes back a map no worse than it was.
// All parameters (grids and decoder) sit in one flat vector, so the
// optimizer and the finite-difference tests see one thing; the grids are
// updated lazily (only nodes a sample touched), which keeps an iteration
// O(samples) however large the ROI.
#pragma once

#include <cstdint>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "hxmap/implicit/dense.hpp"
#include "hxmap/implicit/params.hpp"
#include "hxmap/tsdf/tsdf_map.hpp"

namespace hxmap::alg {

/// A regular grid of nodes with `channels` values each, trilinearly
/// interpolated. Node (i, j, k) sits at origin + (i, j, k) * cell.
struct GridLayout {
  Eigen::Vector3f origin = Eigen::Vector3f::Zero();
  float cell = 1;
  Eigen::Vector3i nodes = Eigen::Vector3i::Ones();
  int channels = 1;
  size_t nodeCount() const { return static_cast<size_t>(nodes.x()) * nodes.y() * nodes.z(); }
  size_t size() const { return nodeCount() * static_cast<size_t>(channels); }
};

/// body(n, p) for every node of the grid, x fastest: n its index, p its
/// position.
template <typename Body>
void forEachNode(const GridLayout& grid, Body&& body) {
  size_t n = 0;
  for (int z = 0; z < grid.nodes.z(); ++z) {
    for (int y = 0; y < grid.nodes.y(); ++y) {
      for (int x = 0; x < grid.nodes.x(); ++x, ++n) {
        body(n, Eigen::Vector3f(grid.origin + grid.cell * Eigen::Vector3f(static_cast<float>(x), static_cast<float>(y),
                                                                          static_cast<float>(z))));
      }
    }
  }
}

/// The 8 nodes around a point and their trilinear weights (the point is
/// clamped into the grid).
struct Corners {
  int32_t node[8];
  float weight[8];
};
Corners locate(const GridLayout& grid, const Eigen::Vector3f& p);

/// The grid nodes a backward pass touched, each listed once (a stamp per
/// node, so a new set costs nothing to clear).
class TouchedNodes {
 public:
  /// Starts a new, empty set over `node_count` nodes.
  void begin(size_t node_count);
  void add(int32_t node) {
    uint32_t& s = stamp_[static_cast<size_t>(node)];
    if (s == current_) return;
    s = current_;
    nodes_.push_back(node);
  }
  const std::vector<int32_t>& nodes() const { return nodes_; }

 private:
  std::vector<uint32_t> stamp_;
  uint32_t current_ = 0;
  std::vector<int32_t> nodes_;
};

class NeuralField {
 public:
  /// Channels of the coarse grid: sdf / mu, normal (3), rgb in [0, 1] (3).
  static constexpr int kCoarseChannels = 7;
  /// Floats per coarse node: its channels and one unused (always 0, no
  /// gradient), so that a node is one 8-lane vector in the field's loops.
  static constexpr int kCoarseStride = 8;

  NeuralField() = default;
  /// Over the voxel centers voxel_min .. voxel_min + voxel_count - 1
  /// (global voxel coordinates of `map`), initialized from `map` (usually a
  /// snapshot of those blocks). Unobserved voxels start as free space (+mu).
  NeuralField(const TsdfMap& map, const Eigen::Vector3i& voxel_min, const Eigen::Vector3i& voxel_count,
              const ImplicitParams& params);

  /// Where the field is defined (the voxel centers' bounding box).
  const Eigen::AlignedBox3f& box() const { return box_; }
  const Eigen::Vector3i& voxelMin() const { return voxel_min_; }
  const Eigen::Vector3i& voxelCount() const { return voxel_count_; }
  float voxelSize() const { return voxel_size_; }
  float truncation() const { return mu_; }

  std::vector<float>& parameters() { return params_; }
  const std::vector<float>& parameters() const { return params_; }
  /// Parameters [0, gridParameters()) are grid values, the rest the decoder.
  size_t gridParameters() const { return coarse_.size() + fine_.size(); }
  /// Grid nodes, coarse and fine.
  size_t nodeCount() const { return coarse_.nodeCount() + fine_.nodeCount(); }
  const GridLayout& coarseGrid() const { return coarse_; }
  const GridLayout& fineGrid() const { return fine_; }
  size_t fineOffset() const { return coarse_.size(); }
  int inputWidth() const { return kCoarseChannels + 1; }
  int encodingWidth() const { return 3 + 6 * frequencies_; }

  /// What backward needs from forward, and the buffers of both (kept
  /// between calls: a job reuses one, so an iteration allocates nothing).
  struct Cache {
    std::vector<Corners> coarse, fine;
    PointRows X;               ///< grid features (inputWidth rows)
    PointRows A;               ///< a layer's pre-activation (scratch)
    PointRows S0;              ///< softplus'(fuse pre-activation)
    PointRows Zin;             ///< [z; gamma(x)]: z = softplus(fuse pre-activation)
    PointRows H, S1;           ///< softplus(hidden pre-activation), its slope
    PointRows O;               ///< decoder output (4 rows)
    PointRows dO, dH, dZ, dX;  ///< backward's gradients
  };
  /// s (meters) and c (rgb in [0, 1], unclamped) at each column of `points`.
  /// `cache` (optional) keeps what backward needs; without one, a
  /// temporary is used.
  void forward(const Eigen::Matrix3Xf& points, Eigen::VectorXf& sdf_m, Eigen::Matrix3Xf* rgb, Cache* cache) const;

  /// Adds dL/dparameters to `grad` (size parameters()) for the upstream
  /// gradients dL/ds and dL/dc (d_rgb may be empty: no color loss), and
  /// adds the grid nodes it touched to `touched` (begun over nodeCount();
  /// coarse node n is n, fine node n is coarse.nodeCount() + n).
  void backward(Cache& cache, const Eigen::VectorXf& d_sdf, const Eigen::Matrix3Xf& d_rgb, std::vector<float>& grad,
                TouchedNodes* touched) const;

  /// Bytes of parameters (the optimizer keeps three more copies).
  size_t parameterBytes() const { return params_.size() * sizeof(float); }

 private:
  void initDecoder(uint64_t seed);
  /// gamma(x) of every point into rows first .. first + encodingWidth() - 1.
  void encode(const Eigen::Matrix3Xf& points, PointRows& rows, int first) const;

  Eigen::Vector3i voxel_min_ = Eigen::Vector3i::Zero(), voxel_count_ = Eigen::Vector3i::Ones();
  float voxel_size_ = 0.02f, mu_ = 0.08f;
  Eigen::AlignedBox3f box_;
  Eigen::Vector3f center_ = Eigen::Vector3f::Zero(), inv_half_extent_ = Eigen::Vector3f::Ones();
  GridLayout coarse_, fine_;
  int fuse_ = 16, hidden_ = 32, frequencies_ = 2;
  // Offsets of the decoder's tensors in params_.
  size_t wf_ = 0, bf_ = 0, w1_ = 0, b1_ = 0, w2_ = 0, b2_ = 0;
  std::vector<float> params_;
};

}  // namespace hxmap::alg
