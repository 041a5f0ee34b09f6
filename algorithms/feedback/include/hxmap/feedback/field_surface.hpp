// A refined region's neural field as the implicit surface of the pose
// feedback's implicit channels (paper eq 12).
//
// DESIGN: the field is sampled once, when its job finishes, at the nodes of
// its own fine grid (half a voxel apart at the default fine_per_voxel 2)
// within a band around its surface, and rays meet the trilinear
// interpolation of those samples. Evaluating the decoder per residual
// instead costs about 1 us per point and a ray needs about ten points (a
// bracket, secants, a central-difference gradient): at a few hundred pixels
// per keyframe inside refined regions that is tens of milliseconds per
// window evaluation, against the whole solve's 15 ms target. The samples
// keep the field's sub-voxel detail at twice the TSDF's resolution; the
// normal is the gradient of the interpolated field.
#pragma once

#include <vector>

#include <Eigen/Geometry>

#include "hxmap/feedback/residuals.hpp"
#include "hxmap/implicit/neural_field.hpp"

namespace hxmap::alg {

class FieldSurface : public ImplicitSurface {
 public:
  /// Samples `field` at its fine grid's nodes whose initial (TSDF) signed
  /// distance is within band_voxels voxels of the surface.
  /// With `seen` (one flag per coarse node, RoiRefiner::seen()), only where
  /// all the coarse nodes around a fine node were seen by the training
  /// renderings: elsewhere nothing constrained the field.
  explicit FieldSurface(const NeuralField& field, float band_voxels = 3.0f, const std::vector<uint8_t>* seen = nullptr);

  const Eigen::AlignedBox3f& box() const override { return box_; }
  bool intersect(const Eigen::Vector3f& origin, const Eigen::Vector3f& dir, float t_hint, float& t,
                 Eigen::Vector3f& normal, Eigen::Vector3f& rgb) const override;

  /// The sampled field at p (meters; gradient and rgb 0..255 optional);
  /// false outside the box or where a corner node was not sampled.
  bool sample(const Eigen::Vector3f& p, float& sdf_m, Eigen::Vector3f* gradient, Eigen::Vector3f* rgb) const;

  size_t sampledNodes() const { return sampled_; }
  size_t memoryBytes() const { return sdf_.size() * sizeof(float) + rgb_.size() * sizeof(float); }

 private:
  GridLayout grid_;
  Eigen::AlignedBox3f box_;
  float voxel_m_ = 0.02f, mu_ = 0.08f;
  std::vector<float> sdf_;  ///< per node, NaN = not sampled
  std::vector<float> rgb_;  ///< per node, 3 channels 0..255
  size_t sampled_ = 0;
};

}  // namespace hxmap::alg
