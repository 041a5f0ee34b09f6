#include "hxmap/preprocess/preprocess.hpp"

#include <cmath>

#include <opencv2/imgproc.hpp>

#include "hxmap/core/simd.hpp"

namespace hxmap::alg {

namespace {

// exp(-x) for x in [0, kMax]: exp(-x/8) by its degree-5 Taylor polynomial,
// squared three times (relative error below 4e-4). DESIGN: a lookup table
// read per tap kept the filter scalar; this is multiplies only, so the tap
// loops below vectorize (the filter went from about half of preprocessing
// to ...).
constexpr float kRangeCut = 4.5f;  // the range kernel is cut at 3 sigma
inline float expNeg(float x) {
  const float y = -0.125f * x;
  float e = 1.0f + y * (1.0f + y * (0.5f + y * (1.0f / 6 + y * (1.0f / 24 + y * (1.0f / 120)))));
  e *= e;
  e *= e;
  return e * e;
}

// One tap of the filter over a row: for u in [u0, u1), neighbour zn[u] of
// centre zc[u] with spatial weight ws.
HXMAP_SIMD_CLONES void addTap(const float* zc, const float* zn, const float* inv2, float ws, int u0, int u1, float* sum,
                              float* wsum) {
  for (int u = u0; u < u1; ++u) {
    const float n = zn[u];
    const float d = n - zc[u];
    const float x = d * d * inv2[u];
    const float e = ws * expNeg(x);  // computed for every tap: no branch
    const float w = ((n > 0.0f) & (x <= kRangeCut)) ? e : 0.0f;
    sum[u] += w * n;
    wsum[u] += w;
  }
}

}  // namespace

cv::Mat bilateralDepth(const cv::Mat& depth, const PreprocessParams& p, const ParallelFor& parallel) {
  const int r = p.bilateral_radius_px;
  if (r <= 0) return depth.clone();
  const int cols = depth.cols;
  cv::Mat out(depth.size(), CV_32F);  // every pixel written below
  std::vector<float> spatial((2 * r + 1) * (2 * r + 1));
  for (int dy = -r; dy <= r; ++dy) {
    for (int dx = -r; dx <= r; ++dx) {
      spatial[(dy + r) * (2 * r + 1) + dx + r] = std::exp(
          -static_cast<float>(dx * dx + dy * dy) / static_cast<float>(2 * p.bilateral_sigma_px * p.bilateral_sigma_px));
    }
  }
  const float k = static_cast<float>(p.bilateral_sigma_depth_factor);
  // DESIGN: taps outside, pixels inside. Each tap (dx, dy) runs over a whole
  // row of output pixels with no branch (invalid neighbours, the image
  // border and values beyond the range cut are weight 0), which the
  // compiler turns into SIMD at the baseline instruction set.
  parallel(static_cast<size_t>(depth.rows), [&](size_t r0, size_t r1) {
    std::vector<float> inv2(cols), sum(cols), wsum(cols);
    for (int v = static_cast<int>(r0); v < static_cast<int>(r1); ++v) {
      const float* row = depth.ptr<float>(v);
      for (int u = 0; u < cols; ++u) {
        const float sr = k * depthSigma(row[u], p);  // > 0 for any z
        inv2[u] = 1.0f / (2 * sr * sr);
      }
      std::fill(sum.begin(), sum.end(), 0.0f);
      std::fill(wsum.begin(), wsum.end(), 0.0f);
      const int dy0 = std::max(-r, -v), dy1 = std::min(r, depth.rows - 1 - v);
      for (int dy = dy0; dy <= dy1; ++dy) {
        const float* nrow = depth.ptr<float>(v + dy);
        for (int dx = -r; dx <= r; ++dx) {
          const float ws = spatial[(dy + r) * (2 * r + 1) + dx + r];
          const int u0 = std::max(0, -dx), u1 = std::min(cols, cols - dx);
          addTap(row, nrow + dx, inv2.data(), ws, u0, u1, sum.data(), wsum.data());
        }
      }
      float* orow = out.ptr<float>(v);
      for (int u = 0; u < cols; ++u) {
        orow[u] = row[u] > 0 ? sum[u] / wsum[u] : 0.0f;  // the centre's own weight is 1
      }
    }
  });
  return out;
}

namespace {

// Confidence from the noise model, incidence angle and distance to depth
// discontinuities (invalid pixels count as discontinuities).
cv::Mat confidenceMap(const cv::Mat& depth, const cv::Mat& vertex, const cv::Mat& normal, const PreprocessParams& p) {
  cv::Mat not_edge(depth.size(), CV_8U, cv::Scalar(255));
  for (int v = 0; v < depth.rows; ++v) {
    const float* row = depth.ptr<float>(v);
    uint8_t* e = not_edge.ptr<uint8_t>(v);
    for (int u = 0; u < depth.cols; ++u) {
      const float z = row[u];
      if (z <= 0) {
        e[u] = 0;
        continue;
      }
      const float jump = static_cast<float>(p.edge_jump_sigmas) * depthSigma(z, p);
      if (u + 1 < depth.cols && row[u + 1] > 0 && std::abs(row[u + 1] - z) > jump) e[u] = 0;
      if (v + 1 < depth.rows) {
        const float zb = depth.ptr<float>(v + 1)[u];
        if (zb > 0 && std::abs(zb - z) > jump) e[u] = 0;
      }
    }
  }
  cv::Mat dist;
  cv::distanceTransform(not_edge, dist, cv::DIST_L2, 3);
  const float sigma_ref = depthSigma(1.0f, p);
  const float cos_min = static_cast<float>(std::cos(p.max_incidence_deg * M_PI / 180.0));
  const float edge_d = static_cast<float>(p.edge_confidence_distance_px);
  cv::Mat conf(depth.size(), CV_32F);  // every pixel written below
  for (int v = 0; v < depth.rows; ++v) {
    const float* row = depth.ptr<float>(v);
    const float* drow = dist.ptr<float>(v);
    const auto* vrow = vertex.ptr<cv::Vec3f>(v);
    const auto* nrow = normal.ptr<cv::Vec3f>(v);
    float* crow = conf.ptr<float>(v);
    for (int u = 0; u < depth.cols; ++u) {
      const float z = row[u];
      crow[u] = 0.0f;
      if (z <= 0) continue;
      const float c_noise = std::min(1.0f, sigma_ref / depthSigma(z, p));
      float c_angle = 0.5f;  // unknown normal (next to an edge)
      const cv::Vec3f& n = nrow[u];
      if (n[0] != 0 || n[1] != 0 || n[2] != 0) {
        const cv::Vec3f& x = vrow[u];
        const float cosi = -(n.dot(x)) / std::sqrt(x.dot(x));
        c_angle = cosi <= cos_min ? 0.0f : cosi;
      }
      const float c_edge = edge_d > 0 ? std::min(1.0f, drow[u] / edge_d) : 1.0f;
      crow[u] = c_noise * c_angle * c_edge;
    }
  }
  return conf;
}

// (I, dI/du, dI/dv) interleaved: the 3x3 Sobel operator scaled by 1/8 (units
// of intensity per pixel), 0 on the one-pixel border.
cv::Mat intensityWithGradient(const cv::Mat& intensity, const ParallelFor& parallel) {
  cv::Mat out(intensity.size(), CV_32FC3);  // every pixel written below
  const int cols = intensity.cols, last = cols - 1;
  parallel(static_cast<size_t>(intensity.rows), [&](size_t v0, size_t v1) {
    // DESIGN: the stencil runs over a row into two plain arrays (SIMD),
    // then the three channels are interleaved; computed in place in the
    // interleaved image it stayed scalar. With the branch-free depth
    // halving and normals below: preprocessing 4.9 -> 4.2 ms per TUM frame
    // on one core.
    std::vector<float> gu(static_cast<size_t>(cols), 0.0f), gv(static_cast<size_t>(cols), 0.0f);
    for (int v = static_cast<int>(v0); v < static_cast<int>(v1); ++v) {
      const float* r1 = intensity.ptr<float>(v);
      auto* o = out.ptr<cv::Vec3f>(v);
      const bool border = v == 0 || v + 1 == intensity.rows;
      if (!border) {
        const float* r0 = intensity.ptr<float>(v - 1);
        const float* r2 = intensity.ptr<float>(v + 1);
        for (int u = 1; u < last; ++u) {
          gu[u] = 0.125f * ((r0[u + 1] - r0[u - 1]) + 2.0f * (r1[u + 1] - r1[u - 1]) + (r2[u + 1] - r2[u - 1]));
          gv[u] = 0.125f * ((r2[u - 1] - r0[u - 1]) + 2.0f * (r2[u] - r0[u]) + (r2[u + 1] - r0[u + 1]));
        }
      }
      for (int u = 0; u <= last; ++u) {
        const bool inside = !border && u > 0 && u < last;
        o[u] = cv::Vec3f(r1[u], inside ? gu[u] : 0.0f, inside ? gv[u] : 0.0f);
      }
    }
  });
  return out;
}

}  // namespace

cv::Mat vertexMap(const cv::Mat& depth, const PinholeCamera& c) {
  cv::Mat vertex(depth.size(), CV_32FC3);  // every pixel written below
  for (int v = 0; v < depth.rows; ++v) {
    const float* row = depth.ptr<float>(v);
    auto* out = vertex.ptr<cv::Vec3f>(v);
    for (int u = 0; u < depth.cols; ++u) {
      const float z = row[u];
      if (z <= 0) {
        out[u] = cv::Vec3f(0.0f, 0.0f, 0.0f);
        continue;
      }
      const Eigen::Vector3f p = c.backproject(static_cast<float>(u), static_cast<float>(v), z);
      out[u] = cv::Vec3f(p.x(), p.y(), p.z());
    }
  }
  return vertex;
}

namespace {

// Three vertex rows as planes: x, y, z of row v - 1 (t), v (m), v + 1 (b).
struct VertexRows {
  const float *xt, *yt, *zt, *xm, *ym, *zm, *xb, *yb, *zb;
};

// Normals of pixels [1, cols - 1) of the middle row into nx, ny, nz (0
// where there is none), with no branch per pixel: the loop vectorizes once
// inlined into computeNormals, which sees that the twelve arrays do not
// overlap (as a separate AVX2 clone it did not vectorize at all).
inline void normalRow(const VertexRows& r, int cols, float k_jump, float sigma_a, float sigma_b, float* nx,
                                 float* ny, float* nz) {
  const float *xt = r.xt, *yt = r.yt, *zt = r.zt, *xm = r.xm, *ym = r.ym, *zm = r.zm, *xb = r.xb, *yb = r.yb,
              *zb = r.zb;
  for (int u = 1; u + 1 < cols; ++u) {
    const float cz = zm[u], lz = zm[u - 1], rz = zm[u + 1], tz = zt[u], bz = zb[u];
    const float d = cz - 0.4f;
    const float jump = k_jump * (sigma_a + sigma_b * d * d);
    // (r - l) x (b - t)
    const float ax = xm[u + 1] - xm[u - 1], ay = ym[u + 1] - ym[u - 1], az = rz - lz;
    const float bx = xb[u] - xt[u], by = yb[u] - yt[u], bzz = bz - tz;
    float x = ay * bzz - az * by, y = az * bx - ax * bzz, z = ax * by - ay * bx;
    const float len = std::sqrt(x * x + y * y + z * z);
    // 1 / len where all five depths are valid, continuous and the normal
    // is defined, else 0 (float selects: the loop vectorizes).
    float ok = len > 0 ? 1.0f : 0.0f;
    ok = cz > 0 ? ok : 0.0f;
    ok = lz > 0 ? ok : 0.0f;
    ok = rz > 0 ? ok : 0.0f;
    ok = tz > 0 ? ok : 0.0f;
    ok = bz > 0 ? ok : 0.0f;
    ok = std::abs(lz - rz) <= jump ? ok : 0.0f;
    ok = std::abs(tz - bz) <= jump ? ok : 0.0f;
    const float inv = ok / (len > 0 ? len : 1.0f);
    x *= inv;
    y *= inv;
    z *= inv;
    const float facing = x * xm[u] + y * ym[u] + z * cz > 0 ? -1.0f : 1.0f;  // face the camera
    nx[u] = facing * x;
    ny[u] = facing * y;
    nz[u] = facing * z;
  }
}

}  // namespace

cv::Mat computeNormals(const cv::Mat& vertex, const PreprocessParams& p) {
  cv::Mat normal(vertex.size(), CV_32FC3, cv::Scalar(0, 0, 0));
  const int cols = vertex.cols;
  if (vertex.rows < 3 || cols < 3) return normal;
  // Rows deinterleaved into planes, three at a time (a ring of row buffers).
  std::vector<float> planes(static_cast<size_t>(9 * cols)), n(static_cast<size_t>(3 * cols), 0.0f);
  const auto plane = [&](int v, int c) { return planes.data() + ((v % 3) * 3 + c) * cols; };
  const auto load = [&](int v) {
    const auto* row = vertex.ptr<cv::Vec3f>(v);
    float *x = plane(v, 0), *y = plane(v, 1), *z = plane(v, 2);
    for (int u = 0; u < cols; ++u) {
      x[u] = row[u][0];
      y[u] = row[u][1];
      z[u] = row[u][2];
    }
  };
  const float k_jump = 2.0f * static_cast<float>(p.edge_jump_sigmas);
  load(0);
  load(1);
  for (int v = 1; v + 1 < vertex.rows; ++v) {
    load(v + 1);
    const VertexRows r{plane(v - 1, 0), plane(v - 1, 1), plane(v - 1, 2), plane(v, 0),     plane(v, 1),
                       plane(v, 2),     plane(v + 1, 0), plane(v + 1, 1), plane(v + 1, 2)};
    float *nx = n.data(), *ny = nx + cols, *nz = ny + cols;
    normalRow(r, cols, k_jump, static_cast<float>(p.noise_sigma_a_m), static_cast<float>(p.noise_sigma_b_per_m), nx, ny,
              nz);
    auto* out = normal.ptr<cv::Vec3f>(v);
    for (int u = 1; u + 1 < cols; ++u) out[u] = cv::Vec3f(nx[u], ny[u], nz[u]);
  }
  return normal;
}

cv::Mat averageDepth2x2(const cv::Mat& depth) {
  cv::Mat out(depth.rows / 2, depth.cols / 2, CV_32F, cv::Scalar(0.0f));
  for (int v = 0; v < out.rows; ++v) {
    const float* r0 = depth.ptr<float>(2 * v);
    const float* r1 = depth.ptr<float>(2 * v + 1);
    float* o = out.ptr<float>(v);
    for (int u = 0; u < out.cols; ++u) {
      const float a = r0[2 * u], b = r0[2 * u + 1], c = r1[2 * u], d = r1[2 * u + 1];
      const float lo = std::min({a, b, c, d}), hi = std::max({a, b, c, d});
      if (lo > 0.0f && hi - lo <= 0.03f * lo) o[u] = 0.25f * (a + b + c + d);
    }
  }
  return out;
}

cv::Mat downsampleDepth(const cv::Mat& depth, const PreprocessParams& p) {
  cv::Mat out(depth.rows / 2, depth.cols / 2, CV_32F);  // every pixel written below
  const float k = static_cast<float>(p.edge_jump_sigmas);
  constexpr float kNone = 1e9f;
  for (int v = 0; v < out.rows; ++v) {
    const float* r0 = depth.ptr<float>(2 * v);
    const float* r1 = depth.ptr<float>(2 * v + 1);
    float* o = out.ptr<float>(v);
    // No branch per pixel (the loop vectorizes): invalid values count as
    // kNone in the minimum and as 0 in the sum.
    for (int u = 0; u < out.cols; ++u) {
      const float z0 = r0[2 * u], z1 = r0[2 * u + 1], z2 = r1[2 * u], z3 = r1[2 * u + 1];
      const float zmin = std::min(std::min(z0 > 0 ? z0 : kNone, z1 > 0 ? z1 : kNone),
                                  std::min(z2 > 0 ? z2 : kNone, z3 > 0 ? z3 : kNone));
      // Values further than a depth discontinuity (edge_jump_sigmas) from
      // the nearest are another surface. DESIGN: a tighter cut (3 sigma)
      // also dropped the far tail of plain sensor noise and biased raw depth
      // towards the camera by a depth-dependent amount, which cost tracking
      // 2-3x in ATE on the noisy synthetic sequences.
      const float jump = k * depthSigma(zmin, p);
      const float w0 = z0 > 0 && z0 - zmin <= jump ? 1.0f : 0.0f, w1 = z1 > 0 && z1 - zmin <= jump ? 1.0f : 0.0f;
      const float w2 = z2 > 0 && z2 - zmin <= jump ? 1.0f : 0.0f, w3 = z3 > 0 && z3 - zmin <= jump ? 1.0f : 0.0f;
      const float sum = w0 * z0 + w1 * z1 + w2 * z2 + w3 * z3;
      const float n = w0 + w1 + w2 + w3;
      o[u] = zmin < kNone ? sum / n : 0.0f;  // the nearest always counts: n >= 1
    }
  }
  return out;
}

PreprocessedFrame preprocessFrame(const RgbdFrame& frame, const PinholeCamera& camera, const PreprocessParams& params,
                                  const ParallelFor& parallel) {
  PreprocessedFrame out;
  out.stamp_ns = frame.stamp_ns;
  out.depth_stamp_ns = frame.depth_stamp_ns > 0 ? frame.depth_stamp_ns : frame.stamp_ns;
  out.seq = frame.seq;
  const cv::Size size(camera.width, camera.height);
  const bool depth_ok = frame.depth.type() == CV_32FC1 && frame.depth.size() == size;
  const bool rgb_ok = frame.rgb.type() == CV_8UC3 && frame.rgb.size() == size;
  out.depth_m = cv::Mat(size, CV_32F);  // every pixel written below
  out.rgb = rgb_ok ? frame.rgb : cv::Mat(size, CV_8UC3, cv::Scalar(0, 0, 0));
  out.has_color = rgb_ok;
  if (depth_ok) {
    const float lo = static_cast<float>(params.min_depth_m), hi = static_cast<float>(params.max_depth_m);
    int valid_pixels = 0, rejected_pixels = 0;
    for (int v = 0; v < size.height; ++v) {
      const float* in = frame.depth.ptr<float>(v);
      float* o = out.depth_m.ptr<float>(v);
      for (int u = 0; u < size.width; ++u) {
        const float z = in[u];
        const bool valid = std::isfinite(z) && z >= lo && z <= hi;
        o[u] = valid ? z : 0.0f;
        valid_pixels += valid;
        rejected_pixels += !valid && z != 0.0f;
      }
    }
    out.valid_pixels = valid_pixels;
    out.rejected_pixels = rejected_pixels;
  } else {
    out.depth_m.setTo(0.0f);
  }
  cv::Mat gray;
  cv::cvtColor(out.rgb, gray, cv::COLOR_RGB2GRAY);
  gray.convertTo(out.intensity, CV_32F, 1.0 / 255.0);

  // DESIGN: the pyramid is filtered from `finest_level` on. Tracking read
  // full-resolution maps at every second pixel only, and fusion reads every
  // second pixel (integration_level), so denoising, normals and confidence
  // at full resolution were mostly thrown away: starting at half resolution
  // (edge-aware 2x2 means of the raw depth, then the bilateral filter)
  // took preprocessing from 17 to ~5 ms per frame on one core, at the same
  // ATE and mesh accuracy (see tracking/params.hpp).
  const int finest = std::clamp(params.finest_level, 0, 2);
  const int levels = finest + std::clamp(params.pyramid_levels, 1, 5);
  out.finest = finest;
  cv::Mat depth = out.depth_m;
  cv::Mat intensity = out.intensity;
  for (int l = 0; l < levels; ++l) {
    FrameLevel L;
    L.camera = camera.level(l);
    if (l > 0) {
      depth = downsampleDepth(depth, params);
      cv::resize(intensity, intensity, depth.size(), 0, 0, cv::INTER_AREA);
    }
    if (l < finest) {  // depth, and intensity for photometric terms
      L.depth = depth;
      if (l == 0) {
        L.intensity = intensity;
        L.intensity_grad = intensityWithGradient(intensity, parallel);
      }
      out.levels.push_back(std::move(L));
      continue;
    }
    if (l == finest) depth = bilateralDepth(depth, params, parallel);
    L.intensity = intensity;
    L.intensity_grad = intensityWithGradient(intensity, parallel);
    L.depth = depth;
    L.vertex = vertexMap(depth, L.camera);
    L.normal = computeNormals(L.vertex, params);
    L.confidence = confidenceMap(depth, L.vertex, L.normal, params);
    out.levels.push_back(std::move(L));
  }
  return out;
}

}  // namespace hxmap::alg
