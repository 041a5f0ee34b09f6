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
#include <memory>
#include <utility>
#include <vector>

#include "hxmap/implicit/detail.hpp"
#include "hxmap/implicit/neural_field.hpp"
#include "hxmap/implicit/params.hpp"
#include "hxmap/implicit/render.hpp"
#include "hxmap/tsdf/patch.hpp"
#include "hxmap/tsdf/tsdf_map.hpp"

namespace hxmap::alg {

struct RefineStats {
  int iterations = 0;
  bool converged = false;      ///< stopped early: the loss stopped improving
  LossTerms first, last;       ///< loss of the first and the last iteration
  size_t rays = 0;             ///< candidate rays from the keyframes
  size_t free_space_rays = 0;  ///< of which cross the box to a surface beyond it
  size_t parameters = 0;
  size_t memory_bytes = 0;  ///< field, optimizer state and rays
  /// Mean |rendered - observed| depth over a fixed set of rays, with the
  /// field as initialized (the TSDF) and as trained (meters).
  double depth_l1_before_m = 0, depth_l1_after_m = 0;
  size_t patch_entries = 0;
  size_t detail_nodes = 0;  ///< fine nodes of the detail layer
  size_t completed = 0;     ///< voxels fusion never observed, written back from the field
};

struct RefineResult {
  TsdfPatch patch;
  /// sigma_Neural per block (RMS depth error of the trained field's
  /// renderings of the rays landing in the block), for the UF indicator.
  std::vector<std::pair<BlockKey, float>> neural_sigma;
  /// What the field resolved below the voxel size (see detail.hpp); null
  /// when there is none.
  std::shared_ptr<const RefinedDetail> detail;
  RefineStats stats;
};

class RoiRefiner {
 public:
  /// Fused weight of a voxel fusion never observed, written back from the
  /// field (completion): one good observation's worth.
  static constexpr float kCompletionWeight = 1.0f;
  /// `map`: the map or a snapshot holding the ROI's blocks; `box_world`:
  /// the ROI box (Roi::box_world); `keyframes`: those that observe it.
  RoiRefiner(const TsdfMap& map, const Eigen::AlignedBox3f& box_world, const std::vector<KeyframeImages>& keyframes,
             const ImplicitParams& params);

  /// Runs up to n iterations; false once finished (converged, iteration
  /// cap, or nothing to learn from). The first calls each run one step of
  /// preparation instead (rendering the TSDF to measure its error and
  /// bias), each about as costly as an iteration.
  bool iterate(int n);
  bool finished() const { return finished_; }
  /// Told of every phase the job enters (null: none); the job leaves each
  /// call with RefinePhase::kOutside.
  void setProbe(RefineProbe* probe) { probe_ = probe; }
  int iterations() const { return stats_.iterations; }
  const LossTerms& lastLoss() const { return stats_.last; }
  const NeuralField& field() const { return field_; }
  const std::vector<TrainingRay>& rays() const { return rays_; }
  /// Per coarse node (voxel of the box): a training sample that light still
  /// reached came near it, i.e. the renderings constrain the field there
  /// (kSeen; kSeenThrough besides when the sample was a free-space ray's).
  const std::vector<uint8_t>& seen() const { return seen_; }
  static constexpr uint8_t kSeen = 1, kSeenThrough = 2;

  /// (Finishes the preparation first if the job was stopped before.)
  /// Write-back (eq 11): the field's signed distance at every voxel center
  /// the snapshot had observed and a visible training sample came near (in
  /// front of the first surface or at it), truncated to mu, and its color.
  /// DESIGN: each is fused with a weight from the evidence, not a constant:
  /// where the TSDF's renderings disagree with the keyframes only by noise
  /// (zero-mean residuals), the TSDF, which averaged every frame, is the
  /// better estimate and the field (trained on a few keyframes, able to fit
  /// their noise) gets one observation's say of n; where they disagree
  /// systematically (a bias: eroded thin parts, bled edges) the field gets
  /// up to writeback_weight_ratio times the TSDF's weight. On the quality
  /// room a constant ratio of 4 cut precision on a noisy wall patch from
  /// 100 % to 40 % at 1 cm. The weight fades to 0 at the box border.
  RefineResult result();

 private:
  /// The rays at stratum centers, no regularizer points (measurements).
  RenderBatch renderRays(const std::vector<int32_t>& which, Rendering& rendering) const;
  double evalDepthL1(std::vector<float>* per_ray) const;
  void markSeen(const RenderBatch& batch);
  void measureTsdfBias(const std::vector<int32_t>& which);
  bool prepareStep();  ///< true once prepared

  static constexpr size_t kPrepareRays = 192;
  std::vector<int32_t> bias_rays_;
  size_t prep_next_ = 0;
  bool prepared_ = false, measured_before_ = false;
  float writebackRatio(int x, int y, int z) const;
  /// Whether a voxel fusion never observed takes the field's value.
  bool completes(int x, int y, int z) const;
  /// The detail layer, from the field's share of each voxel (0 where not
  /// written back).
  std::shared_ptr<const RefinedDetail> makeDetail(const std::vector<float>& share) const;

  /// A sample counts as seen while this much light reaches it.
  static constexpr float kSeenTransmittance = 0.1f;

  ImplicitParams params_;
  RefineProbe* probe_ = nullptr;
  NeuralField field_;
  std::vector<TrainingRay> rays_;
  std::vector<float> snapshot_weight_;           ///< per voxel of the box
  std::vector<float> snapshot_sdf_;              ///< per voxel of the box, clamped to mu
  std::vector<uint32_t> snapshot_updates_;       ///< per voxel: observations fused
  std::vector<Eigen::Vector3f> surface_offset_;  ///< per voxel: to its nearest fused surface
  std::vector<int32_t> eval_rays_;
  // Adam state.
  std::vector<float> grad_, m_, v_;
  TouchedNodes touched_;
  /// Residuals of the TSDF's renderings against the keyframes, pooled per
  /// cell of kCellVoxels^3 voxels: how much of its error is bias.
  static constexpr int kCellVoxels = 4;
  static constexpr int kMinCellRays = 6;
  /// A cell's mean residual counts as bias beyond this many squared
  /// standard errors of the mean (z = 3). A wall patch with 4x depth noise
  /// drew chance "biases" and took the field's noise: at 1 cm voxels its
  /// precision fell from 96 % to 84 % with z = 1, 89 % with z = 2, 93 % with
  /// z = 3 (the rods' and edges' biases are many standard errors).
  static constexpr double kBiasZ2 = 9.0;
  struct Cell {
    double sum = 0, sum_sq = 0;
    int rays = 0;
    uint64_t keyframes = 0;  ///< bit (id % 64) per keyframe seen
    // |rendered - observed| of the rays whose observed surface lies in the
    // cell: the TSDF's (before training) and the field's (training
    // batches, recent iterations weighted most).
    double tsdf_abs = 0, field_abs = 0, field_w = 0;
    int tsdf_abs_rays = 0;
  };
  size_t cellIndex(const Eigen::Vector3f& p_world) const;
  size_t cellOf(const Eigen::Vector3f& q) const;    ///< q in voxels of the box, +0.5 (voxel centers at integers + 0.5)
  static constexpr double kFieldErrorDecay = 0.98;  ///< per iteration
  Eigen::Vector3i cell_dims_ = Eigen::Vector3i::Zero();
  std::vector<Cell> cells_;
  std::vector<uint8_t> seen_;  ///< per coarse node (voxel): a visible sample came near
  Rendering rendering_;
  /// The field's buffers, reused by every rendering of the job (a job runs
  /// on one thread at a time); after a training iteration they hold its
  /// samples' grid corners, which markSeen reads.
  mutable NeuralField::Cache cache_;
  uint64_t rng_;
  std::vector<double> smoothed_loss_;
  bool finished_ = false;
  RefineStats stats_;
};

}  // namespace hxmap::alg
