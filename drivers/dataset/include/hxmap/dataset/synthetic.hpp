// Synthetic RGB-D sequences with exact ground truth.
//
// The scene is a room of analytic primitives (walls, box furniture, a sphere,
// thin legs and rods 1-3 cm thick as capsules) with procedural textures. Each
// primitive has an exact signed distance and an exact ray intersection, so
// rendered depth is exact before the sensor model is applied. The sensor model
// follows a Kinect v1: noise sigma(z) = 0.0012 + 0.0019 (z - 0.4)^2 m, depth
// quantized in 1/8 pixel disparity steps (fx * 0.075 m baseline), invalid
// pixels at depth edges and grazing angles, optional missing-depth blobs.
// Everything is deterministic from the seed.
#pragma once

#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "hxmap/core/expected.hpp"
#include "hxmap/core/frame.hpp"
#include "hxmap/core/parallel.hpp"
#include "hxmap/geometry/camera.hpp"
#include "hxmap/geometry/mesh.hpp"

namespace hxmap::drv {

struct SyntheticParams {
  int frames = 150;
  double fps = 30.0;
  uint64_t seed = 1;
  /// "orbit" (around the table), "sweep" (along a wall), "inspect" (along
  /// the back wall and back, rising once to glance over a shelf; made for
  /// SyntheticScene::qualityRoom) or "fast" (hand-held around the table:
  /// surges to about 1.2 m/s and 50 deg/s with a hand's shake on top) or
  /// "loop" (10 s laps in the middle of the room looking out at the walls:
  /// the start comes back into view once per lap) or "street" (made for
  /// SyntheticScene::street: walks the street end to end and back, 144 m
  /// each way at 1 m/s on average, weaving across it and turning to look at
  /// either side).
  std::string trajectory = "orbit";
  /// Frames from blackout_start_s for blackout_s seconds have no valid
  /// depth and black color (a covered lens, a sensor restart); the ground
  /// truth goes on. blackout_s 0: none.
  double blackout_start_s = 0.0, blackout_s = 0.0;
  /// Every drop_every-th frame (the 2nd, 4th, ... for 2) is rendered into
  /// the ground truth but left out of rgb.txt and depth.txt, as a camera
  /// that drops frames. 0: none.
  int drop_every = 0;
  /// A hand-held color camera's imperfections (all 0: an ideal camera
  /// exposed at the depth's instant). The color image is exposed
  /// color_delay_s after the depth (its stamp in rgb.txt says so, as an
  /// unsynchronized sensor's does); its rows are read out one after the
  /// other over rolling_shutter_s (top first, the stamp at the middle row);
  /// each row integrates light over exposure_s (motion blur, 5 samples);
  /// and auto exposure scales its brightness by up to +-gain_variation,
  /// changing over a few seconds. Depth stays a global-shutter image at
  /// the ground truth's stamp.
  double color_delay_s = 0.0;
  double rolling_shutter_s = 0.0;
  double exposure_s = 0.0;
  double gain_variation = 0.0;
  /// Camera positions (and look-at targets) scaled about the origin, for a
  /// scene scaled the same way (SyntheticScene::scaled).
  double scale = 1.0;
  bool noise = true;                ///< apply the sensor model (false: exact depth)
  double noise_scale = 1.0;         ///< multiplies the depth noise sigma
  int missing_blobs_per_frame = 0;  ///< elliptic holes in depth
  double min_depth_m = 0.3, max_depth_m = 6.0;
  double grazing_cos = 0.1;       ///< invalid when |cos(incidence)| is below
  double edge_jump_ratio = 0.04;  ///< invalid next to depth jumps larger than this * z
  alg::PinholeCamera camera{525.0, 525.0, 319.5, 239.5, 640, 480, {0, 0, 0, 0, 0}};
};

struct Primitive {
  enum class Kind { kBox, kRoom, kSphere, kCapsule } kind = Kind::kBox;
  Eigen::Vector3f a = Eigen::Vector3f::Zero();  ///< box/room center, sphere center, capsule end
  Eigen::Vector3f b = Eigen::Vector3f::Zero();  ///< box/room half extents, capsule other end
  float radius = 0.0f;
  alg::Color3 color{200, 200, 200};
  int texture = 0;           ///< 0 plain with grain, 1 checker walls, 2 floor planks
  float noise_scale = 1.0f;  ///< multiplies the depth noise on this primitive
  /// Known-bad for the explicit map by construction (quality validation):
  /// the whole primitive, or (boxes) only the edges off the floor.
  enum class Bad { kNo, kWhole, kEdges } bad = Bad::kNo;
  float bad_margin_m = 0.0f;  ///< the known-bad region extends this far (e.g. the band noisy depth lands in)
};

class SyntheticScene {
 public:
  /// The default room (4 x 3 x 2.6 m) with a table, a cabinet, a stool, a
  /// sphere and thin rods.
  static SyntheticScene room();
  /// A wide room whose back wall and floor are clean, with the regions
  /// fusion reconstructs badly placed by construction: thin rods (1.5-3 cm),
  /// a free-standing board whose edges are occlusion boundaries, a wall patch
  /// with 4x depth noise (its known-bad region includes the +-2 sigma band
  /// its depth lands in), and a shelf whose top is only seen at a grazing
  /// angle during one rise of the "inspect" trajectory.
  static SyntheticScene qualityRoom();
  /// A pedestrian street 160 m long (x from -80 to 80, 7 m between the
  /// facades at y = +-3.5, z up, ground at z = 0) closed by a wall at either
  /// end: buildings 8-16 m wide and 5-12 m high with setbacks, alleys,
  /// half columns, doors and ledges, and planters, lamp posts, bushes and bins
  /// along both facades, all from a fixed seed. A scene for long flights
  /// under a memory budget.
  static SyntheticScene street();
  /// The primitives that can be hit within `radius` of `center` (whose
  /// bounding spheres reach into it), as a scene of their own that renders
  /// them exactly as this one does: what a camera there sees up to its
  /// maximum range, at the cost of a few primitives instead of all.
  SyntheticScene near(const Eigen::Vector3f& center, float radius) const;
  /// This scene scaled by `s` about the world origin: every length, and the
  /// texture patterns with it (0.5 and 1 cm voxels see the quality room's
  /// structures as thin as 2 cm voxels see them at full size; pair with
  /// SyntheticParams::scale). The sensor model is not scaled: depth noise
  /// follows the real distances.
  SyntheticScene scaled(float s) const;
  /// Distance to the nearest known-bad region (Primitive::bad), or +inf;
  /// `primitive` (optional) receives that region's primitive index.
  float badDistance(const Eigen::Vector3f& p_world, int* primitive = nullptr) const;

  const std::vector<Primitive>& primitives() const { return primitives_; }
  /// Signed distance in meters (positive in free space).
  float sdf(const Eigen::Vector3f& p_world) const;
  /// First surface along origin + t * dir (|dir| = 1); false when none.
  bool raycast(const Eigen::Vector3f& origin, const Eigen::Vector3f& dir, float& t, Eigen::Vector3f& normal,
               int& primitive) const;
  /// Shaded color of a surface point (view independent: a fixed light).
  alg::Color3 color(const Eigen::Vector3f& p_world, const Eigen::Vector3f& normal, int primitive) const;
  /// Ground-truth mesh: every primitive tessellated (curved ones within 1 mm).
  alg::TriangleMesh mesh() const;

  std::vector<Primitive>& mutablePrimitives() { return primitives_; }

 private:
  std::vector<Primitive> primitives_;
  /// The index each primitive has in the scene it was taken from (near());
  /// textures are seeded by it. Empty: the primitives' own indices.
  std::vector<int> source_index_;
  float scale_ = 1.0f;  ///< texture coordinates are divided by this
};

/// Smooth camera trajectory (camera-to-world, stamps from fps).
Trajectory syntheticTrajectory(const SyntheticParams& params);

/// The trajectory's camera-to-world pose at `t_s` seconds from its start.
Eigen::Isometry3d syntheticPose(const SyntheticParams& params, double t_s);

/// True when the color camera has any of SyntheticParams' imperfections.
bool hasColorEffects(const SyntheticParams& params);

/// Peak linear (m/s) and angular (deg/s) speed of a trajectory, from
/// consecutive poses.
struct TrajectorySpeeds {
  double max_linear_mps = 0, max_angular_dps = 0, mean_linear_mps = 0, mean_angular_dps = 0;
};
TrajectorySpeeds trajectorySpeeds(const Trajectory& trajectory);

struct RenderedFrame {
  cv::Mat rgb;         ///< CV_8UC3, RGB
  cv::Mat depth_true;  ///< CV_32F meters, 0 where no surface or out of range
  cv::Mat depth;       ///< CV_32F meters after the sensor model (== depth_true without noise)
};

/// Depth at T_world_cam; color there too, or, with color effects
/// (hasColorEffects), along the trajectory around frame_index / fps.
RenderedFrame renderFrame(const SyntheticScene& scene, const alg::PinholeCamera& camera,
                          const Eigen::Isometry3d& T_world_cam, const SyntheticParams& params, int frame_index,
                          const ParallelFor& parallel = serialFor);

/// Writes a sequence in the TUM layout: rgb/, depth/ (uint16, 5000 per m),
/// rgb.txt, depth.txt, groundtruth.txt, calibration.yaml, gt_mesh.ply.
/// `progress(done, total)` is called after each frame when given.
Status writeSyntheticSequence(const std::string& dir, const SyntheticScene& scene, const SyntheticParams& params,
                              const ParallelFor& parallel = serialFor,
                              const std::function<void(int, int)>& progress = nullptr);

}  // namespace hxmap::drv
