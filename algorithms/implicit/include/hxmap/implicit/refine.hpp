// One ROI refinement job (paper 3.3): a neural field initialized from a
// snapshot of the ROI's blocks, trained on the rays of the keyframes that
// see it, written back as a TSDF patch (eq 11).
//
// Cooperative: the caller runs iterate() in slices and may stop between
// them (the runtime's scheduler pauses or sheds jobs; the time budget is
// the caller's, since algorithms/ keep no clocks). result() can be taken
// at any point: the field starts as the snapshot, so an early result is a
// smaller correction, never a worse map.
#pragma once

#include <cstdint>
#include <utility>
#include <vector>

#include "hxmap/implicit/neural_field.hpp"
#include "hxmap/implicit/params.hpp"
#include "hxmap/implicit/render.hpp"
#include "hxmap/tsdf/patch.hpp"
#include "hxmap/tsdf/tsdf_map.hpp"

namespace hxmap::alg {

struct RefineStats {
  int iterations = 0;
  bool converged = false;  ///< stopped early: the loss stopped improving
  LossTerms first, last;   ///< loss of the first and the last iteration
  size_t rays = 0;         ///< candidate rays from the keyframes
  size_t parameters = 0;
  size_t memory_bytes = 0;  ///< field, optimizer state and rays
  /// Mean |rendered - observed| depth over a fixed set of rays, with the
  /// field as initialized (the TSDF) and as trained (meters).
  double depth_l1_before_m = 0, depth_l1_after_m = 0;
  size_t patch_entries = 0;
};

struct RefineResult {
  TsdfPatch patch;
  /// sigma_Neural per block (RMS depth error of the trained field's
  /// renderings of the rays landing in the block), for the UF indicator.
  std::vector<std::pair<BlockKey, float>> neural_sigma;
  RefineStats stats;
};

class RoiRefiner {
 public:
  /// `map`: the map or a snapshot holding the ROI's blocks; `box_world`:
  /// the ROI box (Roi::box_world); `keyframes`: those that observe it.
  RoiRefiner(const TsdfMap& map, const Eigen::AlignedBox3f& box_world, const std::vector<KeyframeImages>& keyframes,
             const ImplicitParams& params);

  /// Runs up to n iterations; false once finished (converged, iteration
  /// cap, or nothing to learn from).
  bool iterate(int n);
  bool finished() const { return finished_; }
  int iterations() const { return stats_.iterations; }
  const LossTerms& lastLoss() const { return stats_.last; }
  const NeuralField& field() const { return field_; }
  const std::vector<TrainingRay>& rays() const { return rays_; }

  /// Write-back (eq 11): the field's signed distance at every voxel center
  /// the snapshot had observed and a training sample reached (its grid
  /// node was updated), truncated to mu, and its color, fused with
  /// writeback_weight_ratio times the snapshot's weight, fading to 0 at the
  /// box border.
  RefineResult result() const;

 private:
  double evalDepthL1(std::vector<float>* per_ray) const;

  ImplicitParams params_;
  NeuralField field_;
  std::vector<TrainingRay> rays_;
  std::vector<float> snapshot_weight_;  ///< per voxel of the box
  std::vector<int32_t> eval_rays_;
  // Adam state.
  std::vector<float> grad_, m_, v_;
  std::vector<uint32_t> node_stamp_;
  std::vector<int32_t> touched_;
  uint64_t rng_;
  std::vector<double> smoothed_loss_;
  bool finished_ = false;
  RefineStats stats_;
};

}  // namespace hxmap::alg
