// The `refine:` section of the configuration (paper 3.3), as the frontend
// and the runners use it.
#pragma once

#include "hxmap/implicit/params.hpp"

namespace hxmap::rt {

/// Which ROIs become refinement jobs and what a job keeps: the `refine:`
/// section of the configuration, as the frontend uses it.
struct RefineParams {
  /// Make ROI refinement jobs from each keyframe's ROIs (needs the quality
  /// scoring); the caller runs them and hands the outcomes back.
  bool enabled = true;
  int max_jobs_per_keyframe = 2;
  /// An ROI seen by fewer kept keyframes is not refined (one view gives no
  /// multi-view evidence: the field would only copy that view).
  int min_job_keyframes = 2;
  /// A block refined (or submitted) is not submitted again for this many
  /// keyframes; an ROI goes only when most of its blocks are free.
  int cooldown_keyframes = 10;
  /// Keyframe images kept for jobs (half resolution: about 1.1 MB each).
  int keyframe_images = 24;
  /// Jobs not taken by then are dropped, oldest first, and counted.
  int max_pending_jobs = 8;
  /// The field, its training and its write-back.
  alg::ImplicitParams implicit;
};

}  // namespace hxmap::rt
