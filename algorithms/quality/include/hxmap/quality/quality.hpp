// Quality-guided region selection (paper 3.2): four indicators per voxel
// block, updated per keyframe from the keyframe and the model rendered at
// its pose after fusion, min-max normalized over the scored blocks (eq 6),
// combined into a priority S (eq 7, or the largest weighted indicator:
// QualityParams::priority_rule); the top blocks grouped into ROIs.
//
// DESIGN: every indicator is accumulated from one pass over a subsampled
// keyframe plus one scan of the blocks that pass landed in, so a keyframe
// touches only the blocks it observed and costs O(samples + blocks):
// - CGN (eq 2): C_new is how newly covered the block is: 1 - (keyframes
//   that saw it at a usable incidence) / consolidated_views, floored at 0.
//   DESIGN: the first version took the voxels new since the block was last
//   scored, which wiped a surface seen once as soon as a later keyframe saw
//   the same block's other faces; the second took the share of surface
//   voxels whose fused weight was below a threshold, but weights sum
//   per-pixel confidences, which fall with distance, so far walls seen from
//   many viewpoints stayed "new" for good (101 of 541 clean blocks of the
//   quality room at the maximum). Counting usable views per block is what
//   an under-observed surface is: at a 10% budget precision went 81.7 ->
//   100% and recall 24.7 -> 30.3% (of 33% known-bad blocks); at 30%,
//   58.6/52.8 -> 78.7/70.8%. A view is usable where the raycast model's
//   normal meets the pixel's ray below max_view_incidence_deg, credited to
//   the block of the model's surface point. Normal
//   novelty is 1 - |cos| between the keyframe's normal and the fused map's
//   normal at the same pixel, taken after the keyframe is fused, so it
//   measures what the voxel grid cannot represent (edges, rods, curvature
//   below a voxel).
// - UF (eq 3): sigma_TSDF is the pooled standard deviation of the SDF
//   observations (each voxel's Welford statistics) of the voxels next to the
//   surface (|sdf| < one voxel): farther voxels see the surface at
//   view-dependent projective distances, which is not noise. sigma_Neural
//   comes from the neural field of an ROI (setNeuralSigma); without it the
//   weights are renormalized to sigma_TSDF alone.
// - OBG (eq 4): per keyframe the mean signed mismatch z_input - z_render of
//   the block's samples; D_var is its standard deviation across the
//   keyframes that saw the block (a wall agrees from every view; a block on
//   an occlusion edge shows foreground from some views and background from
//   others). B_occ flags the block when at least boundary_full_share of a
//   keyframe's samples there lie on the near side of a depth jump (the
//   occluder's edge, not its shadow; less in proportion), averaged over
//   keyframes: a plain share is diluted by the rest of a 16 cm block.
// - RM (eq 5): running mean of |I_input - I_render| (intensity, the render's
//   color sampled from the map) and |z_input - z_render| over the block's
//   samples; a sample whose ray finds no surface in the map counts as a
//   full-mu mismatch (thin structures fusion erased).
#pragma once

#include <array>
#include <cstdint>
#include <unordered_map>
#include <vector>

#include <Eigen/Geometry>
#include <opencv2/core.hpp>

#include "hxmap/preprocess/preprocess.hpp"
#include "hxmap/quality/params.hpp"
#include "hxmap/tsdf/raycast.hpp"
#include "hxmap/tsdf/tsdf_map.hpp"

namespace hxmap::alg {

enum Indicator { kCgn = 0, kUf, kObg, kRm, kIndicatorCount };
const char* indicatorName(int indicator);  ///< "cgn", "uf", "obg", "rm"

/// What a keyframe contributes: its preprocessed level (depth, camera-frame
/// normals, intensity) and the model raycast at the same pose and pyramid
/// level after the keyframe was fused.
struct KeyframeView {
  uint32_t id = 0;
  Eigen::Isometry3f T_world_cam = Eigen::Isometry3f::Identity();
  const FrameLevel* frame = nullptr;
  const ModelView* model = nullptr;
};

/// Accumulated evidence of one block (raw, before normalization).
struct BlockQuality {
  // CGN
  float coverage_new = 0;    ///< C_new: 1 - good_views / consolidated_views, at least 0
  uint32_t good_views = 0;   ///< keyframes that saw the block at a usable incidence
  float normal_novelty = 0;  ///< running mean of 1 - |cos|
  // UF
  float sigma_tsdf_m = 0;
  float sigma_neural_m = -1;  ///< < 0: no neural field covers the block
  // OBG: Welford statistics over keyframes of the mean signed mismatch
  uint32_t views = 0;
  float view_mean_m = 0, view_m2 = 0;
  float boundary = 0;  ///< running share of samples on occlusion boundaries
  // RM
  float photometric = 0;    ///< running mean |I_input - I_render|
  float depth_error_m = 0;  ///< running mean |z_input - z_render| (capped at mu)
  // Keyframes that observed the block (spread over viewpoints, or the most
  // recent: QualityParams::spread_keyframes), with sample counts and the
  // unit direction from the block's center to the camera.
  static constexpr int kMaxKeyframes = 6;
  std::array<uint32_t, kMaxKeyframes> keyframe_ids{};
  std::array<uint16_t, kMaxKeyframes> keyframe_samples{};
  std::array<Eigen::Vector3f, kMaxKeyframes> keyframe_dirs{};
  uint32_t keyframe_count = 0;
};

using Indicators = std::array<float, kIndicatorCount>;

/// Raw indicator values of a block (eq 2-5), each term in [0, 1].
Indicators indicatorsOf(const BlockQuality& q, float truncation_m, const QualityParams& params);

struct QualityUpdateStats {
  size_t samples = 0;        ///< keyframe pixels with depth that landed in a block
  size_t blocks_scored = 0;  ///< blocks whose indicators this keyframe updated
};

/// One block's scores over the candidate set.
struct BlockScore {
  BlockKey key;
  Indicators raw{};
  Indicators normalized{};  ///< eq 6, in [0, 1]
  float priority = 0;       ///< S, eq 7
};

/// A region of interest for implicit refinement: connected chosen blocks.
struct Roi {
  std::vector<BlockKey> blocks;
  Eigen::AlignedBox3f box_world;    ///< the blocks' extent grown by the margin
  std::vector<uint32_t> keyframes;  ///< the keyframes to train on, best first (see selectRois)
  float priority = 0;               ///< the highest S among its blocks
};

class QualityMap {
 public:
  explicit QualityMap(const QualityParams& params) : params_(params) {}

  const QualityParams& params() const { return params_; }

  /// Scores the blocks the keyframe observed (call after fusing it).
  QualityUpdateStats update(const TsdfMap& map, const KeyframeView& keyframe);

  /// sigma_Neural of a block from the neural field refining it (meters).
  void setNeuralSigma(const BlockKey& key, float sigma_m);

  /// Normalized indicators and priority of every scored block (eq 6-7),
  /// highest priority first.
  std::vector<BlockScore> score(float truncation_m) const;

  /// The top blocks within the budget, grouped into ROIs (highest priority
  /// first). `scores` as returned by score().
  std::vector<Roi> selectRois(const std::vector<BlockScore>& scores, float voxel_size_m) const;

  const BlockQuality* find(const BlockKey& key) const;
  size_t size() const { return blocks_.size(); }
  void clear() {
    blocks_.clear();
    keyframes_.clear();
  }

  /// How many blocks keep the keyframe among theirs (0: none; its images
  /// can go).
  uint32_t keyframeReferences(uint32_t id) const;

 private:
  static uint64_t pack(const BlockKey& k) { return packBlockKey(k); }
  static BlockKey unpack(uint64_t p) { return unpackBlockKey(p); }
  void keepKeyframe(BlockQuality& q, const Eigen::Vector3f& block_center_world, uint32_t id, uint32_t samples,
                    const Eigen::Vector3f& camera_world);

  struct KeptKeyframe {
    Eigen::Vector3f center_world = Eigen::Vector3f::Zero();
    uint32_t blocks = 0;  ///< block slots holding it
  };

  QualityParams params_;
  std::unordered_map<uint64_t, BlockQuality> blocks_;
  std::unordered_map<uint32_t, KeptKeyframe> keyframes_;
};

/// Per pixel of `frame` (a pyramid level of a keyframe at T_world_cam), the
/// value in [0, 1] of `indicator` (kIndicatorCount = priority S) of the block
/// its depth lands in; -1 where no scored block. CV_32F at the level's size.
cv::Mat indicatorImage(const std::vector<BlockScore>& scores, const FrameLevel& frame,
                       const Eigen::Isometry3f& T_world_cam, float block_size_m, int indicator);

/// `values` (from indicatorImage) as a heat map blended over `rgb` (CV_8UC3,
/// any multiple of the values' size); pixels without a value stay gray.
cv::Mat overlayHeatmap(const cv::Mat& rgb, const cv::Mat& values);

/// Draws each ROI box's 12 edges into `image` (pinhole `camera` at
/// T_world_cam; edges behind the camera are clipped).
void drawRoiBoxes(cv::Mat& image, const std::vector<Roi>& rois, const PinholeCamera& camera,
                  const Eigen::Isometry3f& T_world_cam);

}  // namespace hxmap::alg
