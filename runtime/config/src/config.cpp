#include "hxmap/config/config.hpp"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <set>
#include <sstream>
#include <vector>

#include <fmt/format.h>
#include <yaml-cpp/yaml.h>

namespace hxmap::rt {

namespace {

// One description of every key drives loading, validation and printing.
class Visitor {
 public:
  virtual ~Visitor() = default;
  virtual void section(const char* name) = 0;
  virtual void number(const char* key, double& v, double lo, double hi) = 0;
  virtual void integer(const char* key, int& v, int lo, int hi) = 0;
  virtual void boolean(const char* key, bool& v) = 0;
  virtual void choice(const char* key, std::string& v, const std::vector<std::string>& choices) = 0;
  /// A ROS-style name: letters, digits, '_' and inner '/' (empty too when
  /// `empty_ok`: written "" and meaning none).
  virtual void name(const char* key, std::string& v, bool empty_ok) = 0;
};

void visit(HxmapConfig& c, Visitor& v) {
  constexpr double kBig = 1e9;
  v.section("camera");
  v.boolean("override_dataset", c.camera.override_dataset);
  v.number("fx", c.camera.fx, 1, 1e5);
  v.number("fy", c.camera.fy, 1, 1e5);
  v.number("cx", c.camera.cx, -1e4, 1e5);
  v.number("cy", c.camera.cy, -1e4, 1e5);
  v.integer("width", c.camera.width, 8, 16384);
  v.integer("height", c.camera.height, 8, 16384);
  v.number("k1", c.camera.k1, -100, 100);
  v.number("k2", c.camera.k2, -100, 100);
  v.number("p1", c.camera.p1, -100, 100);
  v.number("p2", c.camera.p2, -100, 100);
  v.number("k3", c.camera.k3, -100, 100);
  v.number("depth_scale", c.camera.depth_scale, 0, 1e6);

  v.section("dataset");
  v.boolean("skip_bad_frames", c.dataset.skip_bad_frames);
  v.boolean("undistort", c.dataset.undistort);
  v.number("max_association_s", c.dataset.max_association_s, 0, 1);
  v.integer("first_frame", c.dataset.first_frame, 0, 1 << 30);
  v.integer("max_frames", c.dataset.max_frames, 0, 1 << 30);
  v.integer("stride", c.dataset.stride, 1, 1000);
  v.choice("initial_pose", c.dataset.initial_pose, {"ground_truth", "identity"});

  auto& p = c.preprocess;
  v.section("preprocess");
  v.number("min_depth_m", p.min_depth_m, 0, 100);
  v.number("max_depth_m", p.max_depth_m, 0.01, 100);
  v.integer("bilateral_radius_px", p.bilateral_radius_px, 0, 10);
  v.number("bilateral_sigma_px", p.bilateral_sigma_px, 0.1, 20);
  v.number("bilateral_sigma_depth_factor", p.bilateral_sigma_depth_factor, 0.1, 100);
  v.integer("finest_level", p.finest_level, 0, 2);
  v.integer("pyramid_levels", p.pyramid_levels, 1, 5);
  v.number("noise_sigma_a_m", p.noise_sigma_a_m, 1e-6, 1);
  v.number("noise_sigma_b_per_m", p.noise_sigma_b_per_m, 0, 1);
  v.number("edge_jump_sigmas", p.edge_jump_sigmas, 0.5, 1000);
  v.number("edge_confidence_distance_px", p.edge_confidence_distance_px, 0, 100);
  v.number("max_incidence_deg", p.max_incidence_deg, 1, 90);

  auto& t = c.tsdf;
  v.section("tsdf");
  v.number("voxel_size_m", t.voxel_size_m, 0.002, 0.5);
  v.number("truncation_m", t.truncation_m, 0.004, 2);
  v.number("max_weight", t.max_weight, 1, 1e4);
  v.number("max_integration_depth_m", t.max_integration_depth_m, 0.1, 100);
  v.number("min_confidence", t.min_confidence, 0, 1);
  v.integer("integration_level", t.integration_level, -1, 3);
  v.integer("allocation_stride_px", t.allocation_stride_px, 0, 16);
  v.number("max_resident_mib", t.max_resident_mib, 0, 1e7);

  v.section("raycast");
  v.number("min_depth_m", c.raycast.min_depth_m, 0, 100);
  v.number("max_depth_m", c.raycast.max_depth_m, 0.1, 100);
  v.number("step_factor", c.raycast.step_factor, 0.1, 1);
  v.number("min_weight", c.raycast.min_weight, 0, kBig);

  v.section("mesh");
  v.number("min_weight", c.mesh.min_weight, 0, kBig);
  v.boolean("with_colors", c.mesh.with_colors);

  auto& k = c.tracking;
  v.section("tracking");
  v.integer("iterations_finest", k.iterations_finest, 0, 100);
  v.integer("iterations_middle", k.iterations_middle, 0, 100);
  v.integer("iterations_coarsest", k.iterations_coarsest, 0, 100);
  v.integer("model_level", k.model_level, -1, 4);
  v.integer("icp_stride_finest", k.icp_stride_finest, 1, 16);
  v.number("max_correspondence_distance_m", k.max_correspondence_distance_m, 0.001, 2);
  v.number("max_normal_angle_deg", k.max_normal_angle_deg, 1, 90);
  v.number("huber_delta_m", k.huber_delta_m, 1e-5, 1);
  v.number("photometric_scale_m", k.photometric_scale_m, 0, 10);
  v.boolean("photometric_scale_from_residuals", k.photometric_scale_from_residuals);
  v.integer("photometric_scale_window", k.photometric_scale_window, 1, 10000);
  v.number("photometric_huber", k.photometric_huber, 1e-4, 1);
  v.boolean("photometric_keyframe_reference", k.photometric_keyframe_reference);
  v.number("photometric_min_gradient", k.photometric_min_gradient, 0, 1);
  v.number("photometric_reference_gradient_ratio", k.photometric_reference_gradient_ratio, 0, 1);
  v.integer("photometric_stride_finest", k.photometric_stride_finest, 1, 16);
  v.number("convergence_translation_m", k.convergence_translation_m, 0, 1);
  v.number("convergence_rotation_rad", k.convergence_rotation_rad, 0, 1);
  v.number("min_inlier_ratio", k.min_inlier_ratio, 0, 1);
  v.integer("min_inliers", k.min_inliers, 6, 1 << 24);
  v.number("consistent_sigmas", k.consistent_sigmas, 0.5, 100);
  v.number("min_consistent_ratio", k.min_consistent_ratio, 0, 1);
  v.number("min_consistent_ratio_lost", k.min_consistent_ratio_lost, 0, 1);
  v.number("min_inlier_ratio_fused", k.min_inlier_ratio_fused, 0, 1);
  v.number("typical_share_fused", k.typical_share_fused, 0, 1);
  v.number("typical_share_lost", k.typical_share_lost, 0, 1);
  v.integer("consistent_window", k.consistent_window, 1, 100000);
  v.integer("short_loss_frames", k.short_loss_frames, 0, 100000);
  v.number("min_hessian_eigenvalue_ratio", k.min_hessian_eigenvalue_ratio, 0, 1);
  v.number("max_motion_translation_m", k.max_motion_translation_m, 0.001, 10);
  v.number("max_motion_rotation_deg", k.max_motion_rotation_deg, 0.1, 180);
  v.boolean("constant_velocity", k.constant_velocity);
  v.boolean("color_offset_from_motion", k.color_offset_from_motion);
  v.number("keyframe_translation_m", k.keyframe_translation_m, 0, 10);
  v.number("keyframe_translation_voxels", k.keyframe_translation_voxels, 0, 1000);
  v.number("keyframe_baseline_ratio", k.keyframe_baseline_ratio, 0, 10);
  v.number("keyframe_rotation_deg", k.keyframe_rotation_deg, 0, 180);
  v.number("keyframe_interval_s", k.keyframe_interval_s, 0, 3600);

  auto& l = c.relocalization;
  v.section("relocalization");
  v.boolean("enabled", l.enabled);
  v.integer("features", l.features, 50, 10000);
  v.integer("fast_threshold", l.fast_threshold, 1, 255);
  v.integer("max_keyframes", l.max_keyframes, 1, 100000);
  v.number("ratio_test", l.ratio_test, 0.1, 1);
  v.integer("min_matches", l.min_matches, 4, 10000);
  v.integer("min_pnp_inliers", l.min_pnp_inliers, 4, 10000);
  v.number("pnp_reprojection_px", l.pnp_reprojection_px, 0.1, 100);
  v.integer("pnp_iterations", l.pnp_iterations, 1, 100000);
  v.integer("candidates", l.candidates, 0, 100000);
  v.integer("pnp_candidates", l.pnp_candidates, 1, 100000);
  v.number("max_icp_correction_m", l.max_icp_correction_m, 0.001, 10);
  v.number("max_icp_correction_deg", l.max_icp_correction_deg, 0.01, 180);

  auto& lc = c.loop_closure;
  v.section("loop_closure");
  v.boolean("enabled", lc.enabled);
  v.integer("min_keyframe_gap", lc.min_keyframe_gap, 1, 1000000);
  v.number("odometry_sigma_m", lc.odometry_sigma_m, 1e-5, 10);
  v.number("odometry_sigma_deg", lc.odometry_sigma_deg, 1e-4, 90);
  v.number("loop_sigma_m", lc.loop_sigma_m, 1e-5, 10);
  v.number("loop_sigma_deg", lc.loop_sigma_deg, 1e-4, 90);
  v.number("loop_min_information_ratio", lc.loop_min_information_ratio, 0, 1);
  v.number("gate_chi2", lc.gate_chi2, 0.1, 1e6);
  v.number("max_drift_m", lc.max_drift_m, 0, 100);
  v.number("max_drift_per_m", lc.max_drift_per_m, 0, 10);
  v.number("max_drift_deg", lc.max_drift_deg, 0, 180);
  v.number("max_drift_deg_per_m", lc.max_drift_deg_per_m, 0, 180);
  v.number("jump_sigmas", lc.jump_sigmas, 0.1, 1000);
  v.number("min_correction_m", lc.min_correction_m, 0, 10);
  v.number("min_correction_deg", lc.min_correction_deg, 0, 180);
  v.integer("max_stored_keyframes", lc.max_stored_keyframes, 2, 100000);

  auto& q = c.quality;
  v.section("quality");
  v.boolean("enabled", c.quality_enabled);
  v.integer("pixel_stride", q.pixel_stride, 1, 64);
  v.integer("min_samples", q.min_samples, 1, 100000);
  v.number("smoothing", q.smoothing, 0, 1);
  v.number("alpha_coverage", q.alpha_coverage, 0, kBig);
  v.number("alpha_normal", q.alpha_normal, 0, kBig);
  v.integer("consolidated_views", q.consolidated_views, 1, 1000);
  v.number("max_view_incidence_deg", q.max_view_incidence_deg, 0, 90);
  v.number("w_explicit", q.w_explicit, 0, kBig);
  v.number("w_implicit", q.w_implicit, 0, kBig);
  v.number("beta_depth_var", q.beta_depth_var, 0, kBig);
  v.number("beta_boundary", q.beta_boundary, 0, kBig);
  v.number("gamma_photometric", q.gamma_photometric, 0, kBig);
  v.number("gamma_depth", q.gamma_depth, 0, kBig);
  v.number("boundary_jump_ratio", q.boundary_jump_ratio, 1e-4, 10);
  v.integer("boundary_radius_px", q.boundary_radius_px, 1, 16);
  v.number("lambda_cgn", q.lambda_cgn, 0, kBig);
  v.number("lambda_uf", q.lambda_uf, 0, kBig);
  v.number("lambda_obg", q.lambda_obg, 0, kBig);
  v.number("lambda_rm", q.lambda_rm, 0, kBig);
  v.choice("priority_rule", q.priority_rule, {"max", "sum"});
  v.number("top_fraction", q.top_fraction, 0, 1);
  v.integer("max_blocks", q.max_blocks, 0, 1 << 24);
  v.number("min_priority", q.min_priority, 0, kBig);
  v.integer("roi_max_extent_blocks", q.roi_max_extent_blocks, 1, 64);
  v.integer("roi_margin_voxels", q.roi_margin_voxels, 0, 64);
  v.integer("roi_max_keyframes", q.roi_max_keyframes, 1, 64);
  v.boolean("spread_keyframes", q.spread_keyframes);

  auto& r = c.refine;
  auto& m = r.implicit;
  v.section("refine");
  v.boolean("enabled", r.enabled);
  v.integer("max_jobs_per_keyframe", r.max_jobs_per_keyframe, 0, 64);
  v.integer("min_job_keyframes", r.min_job_keyframes, 1, 64);
  v.integer("cooldown_keyframes", r.cooldown_keyframes, 0, 1 << 20);
  v.integer("keyframe_images", r.keyframe_images, 1, 1024);
  v.integer("max_pending_jobs", r.max_pending_jobs, 1, 1024);
  v.integer("fine_per_voxel", m.fine_per_voxel, 1, 8);
  v.integer("fuse_width", m.fuse_width, 1, 256);
  v.integer("hidden_width", m.hidden_width, 1, 256);
  v.integer("encoding_frequencies", m.encoding_frequencies, 0, 8);
  v.integer("rays_per_iteration", m.rays_per_iteration, 1, 1 << 16);
  v.integer("samples_per_ray", m.samples_per_ray, 4, 256);
  v.number("sample_band_voxels", m.sample_band_voxels, 0.1, 100);
  v.number("sharpness_voxels", m.sharpness_voxels, 0.01, 10);
  v.integer("sphere_trace_steps", m.sphere_trace_steps, 1, 1024);
  v.integer("max_rays", m.max_rays, 1, 1 << 24);
  v.integer("free_space_rays", m.free_space_rays, 0, 1 << 24);
  v.number("free_space_share", m.free_space_share, 0, 1);
  v.integer("pixel_stride", m.pixel_stride, 1, 64);
  v.number("lambda_photo", m.lambda_photo, 0, kBig);
  v.number("lambda_depth", m.lambda_depth, 0, kBig);
  v.number("lambda_normal", m.lambda_normal, 0, kBig);
  v.number("lambda_eikonal", m.lambda_eikonal, 0, kBig);
  v.number("depth_huber_voxels", m.depth_huber_voxels, 1e-3, 100);
  v.number("photo_huber", m.photo_huber, 1e-4, 10);
  v.integer("regularizer_points", m.regularizer_points, 0, 1 << 16);
  v.number("learning_rate_grid", m.learning_rate_grid, 0, 10);
  v.number("learning_rate_mlp", m.learning_rate_mlp, 0, 10);
  v.integer("iterations", m.iterations, 0, 1 << 20);
  v.number("time_budget_ms", m.time_budget_ms, 0, 1e7);
  v.integer("slice_iterations", m.slice_iterations, 1, 1 << 16);
  v.number("convergence_rel", m.convergence_rel, 0, 1);
  v.integer("patience", m.patience, 1, 1 << 16);
  {  // initial weights and ray sampling: another seed shows a job's run-to-run spread
    int seed = static_cast<int>(m.seed);
    v.integer("seed", seed, 0, 1 << 30);
    m.seed = static_cast<uint64_t>(seed);
  }
  v.number("writeback_weight_ratio", m.writeback_weight_ratio, 0, kBig);
  v.integer("bias_rays", m.bias_rays, 1, 1 << 20);
  v.boolean("completion", m.completion);
  v.number("border_blend_voxels", m.border_blend_voxels, 0, 64);
  v.number("detail_min_share", m.detail_min_share, 0, 1);

  auto& f = c.feedback;
  v.section("feedback");
  v.boolean("enabled", f.enabled);
  v.integer("window", f.window, 2, 64);
  v.integer("image_level", f.image_level, 0, 3);
  v.integer("base_pixels", f.base_pixels, 16, 1 << 20);
  v.integer("top_pixels", f.top_pixels, 0, 1 << 20);
  v.integer("explore_pixels", f.explore_pixels, 0, 1 << 20);
  v.integer("iterations", f.iterations, 1, 100);
  v.integer("relinearize_every", f.relinearize_every, 1, 100);
  v.boolean("reuse_planes", f.reuse_planes);
  v.number("lambda_photo_explicit", f.lambda_photo_explicit, 0, kBig);
  v.number("lambda_depth_explicit", f.lambda_depth_explicit, 0, kBig);
  v.number("lambda_photo_implicit", f.lambda_photo_implicit, 0, kBig);
  v.number("lambda_depth_implicit", f.lambda_depth_implicit, 0, kBig);
  v.number("depth_sigma_m", f.depth_sigma_m, 1e-5, 1);
  v.number("photo_sigma", f.photo_sigma, 1e-4, 1);
  v.number("depth_gate_m", f.depth_gate_m, 1e-4, 10);
  v.boolean("depth_point_to_plane", f.depth_point_to_plane);
  v.number("photo_gate", f.photo_gate, 1e-3, 1);
  v.number("photo_blur_px", f.photo_blur_px, 0, 10);
  v.number("edge_depth_ratio", f.edge_depth_ratio, 1e-4, 1);
  v.number("min_gradient", f.min_gradient, 0, 1);
  v.number("max_incidence_deg", f.max_incidence_deg, 1, 90);
  v.number("odometry_information_scale", f.odometry_information_scale, 0, kBig);
  v.number("lm_initial_damping", f.lm_initial_damping, 0, kBig);
  v.number("min_correction_chi2", f.min_correction_chi2, 0, kBig);
  v.boolean("require_channel_agreement", f.require_channel_agreement);
  v.integer("verify_stride", f.verify_stride, 0, 64);
  v.number("reintegrate_translation_m", f.reintegrate_translation_m, 0, 10);
  v.number("reintegrate_rotation_deg", f.reintegrate_rotation_deg, 0, 180);

  v.section("synthetic");
  v.integer("frames", c.synthetic.frames, 1, 100000);
  v.number("fps", c.synthetic.fps, 1, 1000);
  v.integer("seed", c.synthetic.seed, 0, 1 << 30);
  v.choice("scene", c.synthetic.scene, {"room", "quality", "street"});
  v.choice("trajectory", c.synthetic.trajectory, {"orbit", "sweep", "inspect", "fast", "loop", "street"});
  v.number("scale", c.synthetic.scale, 0.05, 20);
  v.boolean("noise", c.synthetic.noise);
  v.number("noise_scale", c.synthetic.noise_scale, 0, 100);
  v.integer("missing_blobs_per_frame", c.synthetic.missing_blobs_per_frame, 0, 100);
  v.number("color_delay_s", c.synthetic.color_delay_s, -0.1, 0.1);
  v.number("rolling_shutter_s", c.synthetic.rolling_shutter_s, 0, 0.1);
  v.number("exposure_s", c.synthetic.exposure_s, 0, 0.1);
  v.number("gain_variation", c.synthetic.gain_variation, 0, 0.5);

  v.section("eval");
  v.integer("mesh_samples", c.eval.mesh_samples, 1000, 100000000);
  v.number("threshold_fine_m", c.eval.threshold_fine_m, 1e-4, 1);
  v.number("threshold_coarse_m", c.eval.threshold_coarse_m, 1e-4, 10);
  v.number("rpe_delta_s", c.eval.rpe_delta_s, 0.001, 1000);
  v.number("odometry_bias_deg", c.eval.odometry_bias_deg, -10, 10);
  v.number("odometry_bias_m", c.eval.odometry_bias_m, -1, 1);

  v.section("runtime");
  v.integer("threads", c.runtime.threads, 0, 1024);
  v.integer("refine_workers", c.runtime.refine_workers, 0, 64);
  v.number("deadline_margin_ms", c.runtime.deadline_margin_ms, 0, 1000);
  v.integer("shed_after_periods", c.runtime.shed_after_periods, 1, 100000);
  v.integer("background_nice", c.runtime.background_nice, 0, 19);
  v.number("max_lost_share", c.runtime.max_lost_share, 0, 1);
  v.number("checkpoint_s", c.runtime.checkpoint_s, 0, 1e6);
  v.integer("resume_relocalize_frames", c.runtime.resume_relocalize_frames, 1, 1000000);
  v.choice("resume_otherwise", c.runtime.resume_otherwise, {"fail", "new_map"});

  auto& g = c.rig;
  v.section("rig");
  v.number("color_fx", g.color_fx, 1, 1e5);
  v.number("color_fy", g.color_fy, 1, 1e5);
  v.number("color_cx", g.color_cx, -1e4, 1e5);
  v.number("color_cy", g.color_cy, -1e4, 1e5);
  v.integer("color_width", g.color_width, 8, 16384);
  v.integer("color_height", g.color_height, 8, 16384);
  v.number("color_k1", g.color_k1, -100, 100);
  v.number("color_k2", g.color_k2, -100, 100);
  v.number("color_p1", g.color_p1, -100, 100);
  v.number("color_p2", g.color_p2, -100, 100);
  v.number("color_k3", g.color_k3, -100, 100);
  v.number("depth_fx", g.depth_fx, 1, 1e5);
  v.number("depth_fy", g.depth_fy, 1, 1e5);
  v.number("depth_cx", g.depth_cx, -1e4, 1e5);
  v.number("depth_cy", g.depth_cy, -1e4, 1e5);
  v.integer("depth_width", g.depth_width, 8, 16384);
  v.integer("depth_height", g.depth_height, 8, 16384);
  v.number("depth_k1", g.depth_k1, -100, 100);
  v.number("depth_k2", g.depth_k2, -100, 100);
  v.number("depth_p1", g.depth_p1, -100, 100);
  v.number("depth_p2", g.depth_p2, -100, 100);
  v.number("depth_k3", g.depth_k3, -100, 100);
  v.number("depth_to_color_tx", g.depth_to_color_tx, -10, 10);
  v.number("depth_to_color_ty", g.depth_to_color_ty, -10, 10);
  v.number("depth_to_color_tz", g.depth_to_color_tz, -10, 10);
  v.number("depth_to_color_qx", g.depth_to_color_qx, -1, 1);
  v.number("depth_to_color_qy", g.depth_to_color_qy, -1, 1);
  v.number("depth_to_color_qz", g.depth_to_color_qz, -1, 1);
  v.number("depth_to_color_qw", g.depth_to_color_qw, -1, 1);
  v.number("depth_scale", g.depth_scale, 1e-3, 1e6);
  v.boolean("registered", g.registered);
  v.number("max_sync_gap_s", g.max_sync_gap_s, 0, 1);
  v.number("max_depth_m", g.max_depth_m, 0, 100);
  v.number("fps", g.fps, 1, 1000);
  v.number("reconnect_timeout_s", g.reconnect_timeout_s, 0, 3600);
  v.number("lost_timeout_s", g.lost_timeout_s, 0.1, 3600);

  auto& d = c.dds;
  v.section("dds");
  v.boolean("enabled", d.enabled);
  v.integer("domain_id", d.domain_id, -1, 232);
  v.name("topic_prefix", d.topic_prefix, false);
  v.name("frame_id", d.frame_id, false);
  v.name("child_frame_id", d.child_frame_id, false);
  v.name("base_frame_id", d.base_frame_id, true);
  v.name("odom_frame_id", d.odom_frame_id, true);
  v.number("base_to_camera_x_m", d.base_to_camera_x_m, -100, 100);
  v.number("base_to_camera_y_m", d.base_to_camera_y_m, -100, 100);
  v.number("base_to_camera_z_m", d.base_to_camera_z_m, -100, 100);
  v.number("base_to_camera_roll_deg", d.base_to_camera_roll_deg, -180, 180);
  v.number("base_to_camera_pitch_deg", d.base_to_camera_pitch_deg, -180, 180);
  v.number("base_to_camera_yaw_deg", d.base_to_camera_yaw_deg, -180, 180);
  v.number("map_period_s", d.map_period_s, 0, 3600);
  v.number("trajectory_period_s", d.trajectory_period_s, 0, 3600);
  v.integer("path_max_poses", d.path_max_poses, 0, 10000000);
  v.number("health_period_s", d.health_period_s, 0, 3600);
  v.integer("region_blocks", d.region_blocks, 1, 64);
  v.integer("max_triangles_per_chunk", d.max_triangles_per_chunk, 1, 1 << 22);
  v.integer("queue_capacity", d.queue_capacity, 2, 4096);
}

class Loader : public Visitor {
 public:
  Loader(const YAML::Node& root, std::string source) : root_(root), source_(std::move(source)) {}

  void section(const char* name) override {
    section_ = name;
    sections_.insert(name);
    // Node::operator= on a bound node re-points that node's content (it does
    // not rebind), so nodes are rebound with reset() and looked up through a
    // const view (operator[] on a non-const node may insert keys).
    node_.reset();
    const YAML::Node& root = root_;
    if (root && root.IsMap() && root[name]) {
      node_.reset(root[name]);
      if (!node_.IsMap() && !node_.IsNull()) error(node_, fmt::format("{}: expected a mapping of keys", name));
    }
  }

  void number(const char* key, double& v, double lo, double hi) override {
    YAML::Node n;
    if (!find(key, n)) return;
    double x = 0;
    if (!n.IsScalar() || !YAML::convert<double>::decode(n, x)) {
      error(n, fmt::format("{}.{}: expected a number, got '{}'", section_, key, text(n)));
      return;
    }
    if (!std::isfinite(x) || x < lo || x > hi) {
      error(n, fmt::format("{}.{}: {} is outside the allowed range [{}, {}]", section_, key, text(n), lo, hi));
      return;
    }
    v = x;
  }

  void integer(const char* key, int& v, int lo, int hi) override {
    YAML::Node n;
    if (!find(key, n)) return;
    int x = 0;
    if (!n.IsScalar() || !YAML::convert<int>::decode(n, x)) {
      error(n, fmt::format("{}.{}: expected an integer, got '{}'", section_, key, text(n)));
      return;
    }
    if (x < lo || x > hi) {
      error(n, fmt::format("{}.{}: {} is outside the allowed range [{}, {}]", section_, key, x, lo, hi));
      return;
    }
    v = x;
  }

  void boolean(const char* key, bool& v) override {
    YAML::Node n;
    if (!find(key, n)) return;
    bool x = false;
    if (!n.IsScalar() || !YAML::convert<bool>::decode(n, x)) {
      error(n, fmt::format("{}.{}: expected true or false, got '{}'", section_, key, text(n)));
      return;
    }
    v = x;
  }

  void choice(const char* key, std::string& v, const std::vector<std::string>& choices) override {
    YAML::Node n;
    if (!find(key, n)) return;
    const std::string x = n.IsScalar() ? n.Scalar() : "";
    if (std::find(choices.begin(), choices.end(), x) == choices.end()) {
      error(n, fmt::format("{}.{}: '{}' is not one of: {}", section_, key, text(n), fmt::join(choices, ", ")));
      return;
    }
    v = x;
  }

  void name(const char* key, std::string& v, bool empty_ok) override {
    YAML::Node n;
    if (!find(key, n)) return;
    const std::string x = n.IsScalar() ? n.Scalar() : "";
    if (empty_ok && x.empty() && (n.IsNull() || n.IsScalar())) {
      v.clear();
      return;
    }
    const bool chars_ok = std::all_of(x.begin(), x.end(), [](char ch) {
      return std::isalnum(static_cast<unsigned char>(ch)) != 0 || ch == '_' || ch == '/';
    });
    if (x.empty() || !chars_ok || x.front() == '/' || x.back() == '/' || x.find("//") != std::string::npos ||
        std::isdigit(static_cast<unsigned char>(x.front())) != 0) {
      error(n, fmt::format(
                   "{}.{}: '{}' is not a valid name (letters, digits, '_' and inner '/', not starting with a digit)",
                   section_, key, text(n)));
      return;
    }
    v = x;
  }

  // Unknown sections and keys, after the visit.
  void checkUnknown() {
    if (!root_ || root_.IsNull()) return;
    if (!root_.IsMap()) {
      error(root_, "the configuration must be a mapping of sections (camera:, tsdf:, ...)");
      return;
    }
    std::set<std::string> seen_sections;
    for (const auto& kv : root_) {
      if (!kv.first.IsScalar()) {
        error(kv.first, fmt::format("a section's name must be a word, not {}", text(kv.first)));
        continue;
      }
      const std::string name = kv.first.Scalar();
      if (!seen_sections.insert(name).second) {
        // YAML takes the first and drops the rest without a word.
        error(kv.first, fmt::format("section '{}' appears twice", name));
        continue;
      }
      if (!sections_.count(name)) {
        error(kv.first, fmt::format("unknown section '{}' (known: {})", name, fmt::join(sections_, ", ")));
        continue;
      }
      if (!kv.second.IsMap()) continue;
      std::set<std::string> seen_keys;
      for (const auto& kk : kv.second) {
        if (!kk.first.IsScalar()) {
          error(kk.first, fmt::format("a key in {} must be a word, not {}", name, text(kk.first)));
          continue;
        }
        const std::string key = kk.first.Scalar();
        if (!seen_keys.insert(key).second) {
          error(kk.first, fmt::format("key '{}.{}' appears twice", name, key));
          continue;
        }
        if (!known_.count(name + "." + key)) {
          std::vector<std::string> keys;
          for (const auto& k : known_) {
            if (k.rfind(name + ".", 0) == 0) keys.push_back(k.substr(name.size() + 1));
          }
          error(kk.first, fmt::format("unknown key '{}.{}' (known in {}: {})", name, key, name, fmt::join(keys, ", ")));
        }
      }
    }
  }

  const std::vector<std::string>& errors() const { return errors_; }

 private:
  bool find(const char* key, YAML::Node& out) {
    known_.insert(section_ + "." + key);
    if (!node_ || !node_.IsMap()) return false;
    const YAML::Node& node = node_;
    const YAML::Node n = node[key];
    if (!n) return false;
    out.reset(n);
    return true;
  }
  static std::string text(const YAML::Node& n) {
    if (n.IsScalar()) return n.Scalar();
    if (n.IsSequence()) return "a list";
    if (n.IsMap()) return "a mapping";
    return "nothing";
  }
  void error(const YAML::Node& n, const std::string& what) {
    errors_.push_back(fmt::format("{}:{}: {}", source_, n.Mark().line + 1, what));
  }

  YAML::Node root_, node_;
  std::string source_, section_;
  std::set<std::string> sections_, known_;
  std::vector<std::string> errors_;
};

class Dumper : public Visitor {
 public:
  void section(const char* name) override { out_ += fmt::format("{}:\n", name); }
  void number(const char* key, double& v, double, double) override { out_ += fmt::format("  {}: {}\n", key, v); }
  void integer(const char* key, int& v, int, int) override { out_ += fmt::format("  {}: {}\n", key, v); }
  void boolean(const char* key, bool& v) override { out_ += fmt::format("  {}: {}\n", key, v ? "true" : "false"); }
  void choice(const char* key, std::string& v, const std::vector<std::string>&) override {
    out_ += fmt::format("  {}: {}\n", key, v);
  }
  void name(const char* key, std::string& v, bool) override {
    out_ += fmt::format("  {}: {}\n", key, v.empty() ? std::string("\"\"") : v);
  }
  std::string out_;
};

}  // namespace

Expected<HxmapConfig> loadConfigFromString(const std::string& yaml, const std::string& source) {
  YAML::Node root;
  try {
    root = YAML::Load(yaml);
  } catch (const YAML::ParserException& e) {
    return Error{fmt::format("{}:{}: YAML syntax error: {}", source, e.mark.line + 1, e.msg)};
  }
  HxmapConfig config;
  Loader loader(root, source);
  try {
    visit(config, loader);
    loader.checkUnknown();
    const YAML::Node& r = root;
    config.camera.intrinsics_given = r && r.IsMap() && r["camera"] && r["camera"].IsMap() && r["camera"]["fx"];
  } catch (const YAML::Exception& e) {
    // Every read above checks the node's kind first; this is a last guard
    // so that a document of an unforeseen shape is an error, not an abort.
    return Error{fmt::format("{}:{}: {}", source, e.mark.line + 1, e.msg)};
  }
  if (!loader.errors().empty()) {
    return Error{fmt::format("{} problem(s) in the configuration:\n{}", loader.errors().size(),
                             fmt::join(loader.errors(), "\n"))};
  }
  // Relations between keys.
  std::vector<std::string> errors;
  if (config.preprocess.min_depth_m >= config.preprocess.max_depth_m) {
    errors.push_back(source + ": preprocess.min_depth_m must be below preprocess.max_depth_m");
  }
  if (config.tsdf.truncation_m < 2 * config.tsdf.voxel_size_m) {
    errors.push_back(source + ": tsdf.truncation_m must be at least 2 * tsdf.voxel_size_m");
  }
  const auto& g = config.rig;
  const double qn = std::sqrt(g.depth_to_color_qx * g.depth_to_color_qx + g.depth_to_color_qy * g.depth_to_color_qy +
                              g.depth_to_color_qz * g.depth_to_color_qz + g.depth_to_color_qw * g.depth_to_color_qw);
  if (std::abs(qn - 1.0) > 1e-3) {
    errors.push_back(
        fmt::format("{}: rig.depth_to_color_q{{x,y,z,w}}: the quaternion's norm is {:.6f}, not 1", source, qn));
  }
  if (!errors.empty())
    return Error{fmt::format("{} problem(s) in the configuration:\n{}", errors.size(), fmt::join(errors, "\n"))};
  return config;
}

Expected<HxmapConfig> loadConfig(const std::string& path) {
  std::error_code ec;
  if (std::filesystem::is_directory(path, ec)) return Error{path + ": is a folder, not a configuration file"};
  std::ifstream in(path);
  if (!in) return Error{path + ": configuration file not found or not readable"};
  std::stringstream ss;
  ss << in.rdbuf();
  return loadConfigFromString(ss.str(), path);
}

std::string dumpConfig(const HxmapConfig& config) {
  HxmapConfig copy = config;
  Dumper d;
  visit(copy, d);
  return d.out_;
}

}  // namespace hxmap::rt
