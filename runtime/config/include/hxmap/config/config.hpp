// The hxmap configuration: every module's parameter struct, filled from YAML
// in this one place. The loader validates types and ranges, rejects unknown
// keys, and reports every problem at once with file and line. Presets in
// config/ list only what differs from the defaults in the structs.
#pragma once

#include <string>

#include "hxmap/core/expected.hpp"
#include "hxmap/feedback/params.hpp"
#include "hxmap/implicit/params.hpp"
#include "hxmap/posegraph/params.hpp"
#include "hxmap/preprocess/params.hpp"
#include "hxmap/quality/params.hpp"
#include "hxmap/refine/params.hpp"
#include "hxmap/relocalization/params.hpp"
#include "hxmap/tracking/params.hpp"
#include "hxmap/tsdf/params.hpp"

namespace hxmap::rt {

/// Camera intrinsics given by the user; used when a dataset carries none, or
/// always when `override_dataset` is set (and for live cameras).
struct CameraConfig {
  bool override_dataset = false;
  double fx = 525.0, fy = 525.0, cx = 319.5, cy = 239.5;
  int width = 640, height = 480;
  double k1 = 0, k2 = 0, p1 = 0, p2 = 0, k3 = 0;
  double depth_scale = 0.0;  ///< depth pixels per meter; 0 = the dataset's own
  /// The configuration file gave intrinsics (camera.fx): only then do they
  /// stand in for a dataset that carries none (never a silent default).
  bool intrinsics_given = false;
};

struct DatasetConfig {
  bool skip_bad_frames = false;  ///< skip (count, log) unreadable frames instead of stopping
  bool undistort = true;
  double max_association_s = 0.02;
  int first_frame = 0;
  int max_frames = 0;             ///< 0 = all
  int stride = 1;                 ///< use every n-th frame
  std::string initial_pose = "ground_truth";  ///< "ground_truth" (when present) or "identity"
};

struct SyntheticConfig {
  int frames = 150;
  double fps = 30.0;  ///< frame rate the trajectory is sampled at (lower: more motion per frame)
  int seed = 1;
  std::string scene = "room";        ///< room | quality | street
  std::string trajectory = "orbit";  ///< orbit | sweep | inspect | fast | loop
  double scale = 1.0;                ///< scene and trajectory scaled about the origin
  bool noise = true;
  double noise_scale = 1.0;
  int missing_blobs_per_frame = 0;
  /// The color camera's imperfections (drv::SyntheticParams): delay after
  /// the depth, rolling-shutter readout, exposure (motion blur), auto
  /// exposure's gain variation. All 0: ideal.
  double color_delay_s = 0.0;
  double rolling_shutter_s = 0.0;
  double exposure_s = 0.0;
  double gain_variation = 0.0;
};

struct EvalConfig {
  /// Evaluation only: drift added to every tracked pose, per frame, on the
  /// right (a rotation about the camera's y axis, a translation along its
  /// x axis), to see how pose feedback and loop closure cope with it.
  double odometry_bias_deg = 0.0;
  double odometry_bias_m = 0.0;
  int mesh_samples = 200000;
  double threshold_fine_m = 0.01;
  double threshold_coarse_m = 0.05;
  double rpe_delta_s = 1.0;
};

struct RuntimeConfig {
  int threads = 0;  ///< data-parallel threads for the offline run; 0 = all cores
  int refine_workers = 1;          ///< background refinement threads (--realtime)
  double deadline_margin_ms = 1.0; ///< kept free before each frame is due
  int shed_after_periods = 8;      ///< background jobs without slack this long are shed (started ones: recent_frames periods more)
  /// Nice value of the background threads (refinement workers, pose
  /// feedback) in --realtime and camera runs: on a loaded CPU the kernel
  /// then gives the sensor and frontend threads the cores first. 0 = as
  /// the process.
  int background_nice = 10;
  /// A run that lost more than this share of its frames exits with 1 (the
  /// outputs are still written). 1 = only a run that fused no frame at all.
  double max_lost_share = 1.0;
  /// The mesh and trajectory go into the run's folder this often (seconds
  /// of wall time; in real time from a map copy made in the frontend's
  /// slack; the poses go to trajectory_live.txt frame by frame), so a
  /// killed run loses at most this much. 0 = at the end only.
  double checkpoint_s = 10;
  /// hxmap run --load-map: frames the run may take to relocalize in the
  /// saved map (nothing is fused before), then `resume_otherwise`: "fail"
  /// (the run stops, exit 1) or "new_map" (the saved map is set aside and
  /// a new one starts at that frame).
  int resume_relocalize_frames = 90;
  std::string resume_otherwise = "fail";
};

/// A live color + depth camera pair (drivers/sync): intrinsics and
/// distortion of each camera, the depth camera's pose in the color camera's
/// frame, the depth unit, and how far apart in time a color and a depth
/// frame may be to pair. With `registered` the device aligns depth to color
/// itself and the depth_* intrinsics and extrinsics are not used.
struct RigConfig {
  double color_fx = 525.0, color_fy = 525.0, color_cx = 319.5, color_cy = 239.5;
  int color_width = 640, color_height = 480;
  double color_k1 = 0, color_k2 = 0, color_p1 = 0, color_p2 = 0, color_k3 = 0;
  double depth_fx = 575.0, depth_fy = 575.0, depth_cx = 319.5, depth_cy = 239.5;
  int depth_width = 640, depth_height = 480;
  double depth_k1 = 0, depth_k2 = 0, depth_p1 = 0, depth_p2 = 0, depth_k3 = 0;
  /// Depth camera to color camera: translation (m) and rotation quaternion.
  double depth_to_color_tx = 0.0, depth_to_color_ty = 0.0, depth_to_color_tz = 0.0;
  double depth_to_color_qx = 0.0, depth_to_color_qy = 0.0, depth_to_color_qz = 0.0, depth_to_color_qw = 1.0;
  double depth_scale = 1000.0;  ///< raw depth units per meter (UVC Z16 and OpenNI2: 1000)
  bool registered = false;
  double max_sync_gap_s = 0.02;
  double max_depth_m = 0;       ///< 0 = no limit
  double fps = 30;              ///< frame rate asked of live cameras
  double reconnect_timeout_s = 5;  ///< V4L2: how long an unplugged camera is reopened
  double lost_timeout_s = 10;      ///< a stream silent this long ends a camera run (outputs are written)
};

/// Publishing over Cyclone DDS (runtime/dds): `hxmap run` publishes when
/// enabled (or with --dds). Topics rt/<topic_prefix>/{pose, trajectory, map,
/// health}; the network comes from CYCLONEDDS_URI (config/cyclonedds.xml).
struct DdsConfig {
  bool enabled = false;
  int domain_id = -1;                  ///< -1: ROS_DOMAIN_ID from the environment (unset: 0)
  std::string topic_prefix = "hxmap";
  std::string frame_id = "map";        ///< header frame of poses and map
  std::string child_frame_id = "hxmap_camera_optical_frame";  ///< the camera on /tf (optical convention)
  /// A robot base (REP 105; e.g. "base_link"): /tf carries frame_id ->
  /// base_frame_id, /tf_static base_frame_id -> child_frame_id, the camera
  /// mounted at base_to_camera_*. Empty: the camera itself on /tf.
  std::string base_frame_id;
  /// An odometry frame (REP 105; e.g. "odom"): /tf carries frame_id ->
  /// odom_frame_id (what loop closures corrected) and odom_frame_id -> the
  /// base or camera (never jumps at a closure). Empty: no odom frame.
  std::string odom_frame_id;
  double base_to_camera_x_m = 0, base_to_camera_y_m = 0, base_to_camera_z_m = 0;
  double base_to_camera_roll_deg = 0, base_to_camera_pitch_deg = 0, base_to_camera_yaw_deg = 0;
  double map_period_s = 1.0;           ///< changed map regions go out at most this often
  double trajectory_period_s = 1.0;
  int path_max_poses = 900;            ///< the Path's newest poses (30 s at 30 FPS; 0: all)
  double health_period_s = 1.0;
  int region_blocks = 4;               ///< map update region: a cube of this many TSDF blocks a side
  int max_triangles_per_chunk = 16384; ///< larger region meshes go out in parts
  int queue_capacity = 16;             ///< work items waiting for the publisher thread
};

struct HxmapConfig {
  CameraConfig camera;
  DatasetConfig dataset;
  alg::PreprocessParams preprocess;
  alg::TsdfParams tsdf;
  alg::RaycastParams raycast;
  alg::MeshParams mesh;
  alg::TrackingParams tracking;
  alg::RelocalizationParams relocalization;
  alg::LoopClosureParams loop_closure;
  bool quality_enabled = true;
  alg::QualityParams quality;
  RefineParams refine;
  alg::FeedbackParams feedback;
  SyntheticConfig synthetic;
  EvalConfig eval;
  RuntimeConfig runtime;
  RigConfig rig;
  DdsConfig dds;
};

/// Loads `path` over the defaults. All problems are reported in one Error,
/// one per line, each "file:line: section.key: what is wrong".
Expected<HxmapConfig> loadConfig(const std::string& path);
Expected<HxmapConfig> loadConfigFromString(const std::string& yaml, const std::string& source);

/// The effective configuration as YAML (every key, with units in the names).
std::string dumpConfig(const HxmapConfig& config);

}  // namespace hxmap::rt
