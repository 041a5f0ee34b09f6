#include "hxmap/dataset/synthetic.hpp"

#include <cmath>
#include <filesystem>
#include <limits>
#include <random>

#include <fmt/format.h>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "hxmap/core/stamp.hpp"
#include "hxmap/dataset/parsers.hpp"
#include "hxmap/dataset/ply.hpp"

namespace hxmap::drv {

using Eigen::Vector3f;
using Kind = Primitive::Kind;

SyntheticScene SyntheticScene::room() {
  SyntheticScene s;
  auto box = [&](Vector3f c, Vector3f h, alg::Color3 col, int tex = 0) {
    s.primitives_.push_back({Kind::kBox, c, h, 0.0f, col, tex});
  };
  auto capsule = [&](Vector3f p0, Vector3f p1, float r, alg::Color3 col) {
    s.primitives_.push_back({Kind::kCapsule, p0, p1, r, col, 0});
  };
  // Room interior; z up, floor at z = 0.
  s.primitives_.push_back({Kind::kRoom, {0, 0, 1.29f}, {2.0f, 1.5f, 1.31f}, 0.0f, {215, 205, 190}, 1});
  // Floor planks as a slab whose top (z = 0) hides the room box floor.
  box({0, 0, -0.05f}, {2.0f, 1.5f, 0.05f}, {150, 110, 70}, 2);
  // Table: top and four legs 3 cm thick.
  box({0.3f, 0.2f, 0.74f}, {0.6f, 0.4f, 0.02f}, {170, 120, 80});
  for (float sx : {-1.0f, 1.0f}) {
    for (float sy : {-1.0f, 1.0f}) {
      capsule({0.3f + sx * 0.55f, 0.2f + sy * 0.35f, 0.0f}, {0.3f + sx * 0.55f, 0.2f + sy * 0.35f, 0.72f}, 0.015f,
              {90, 60, 40});
    }
  }
  box({0.1f, 0.3f, 0.84f}, {0.12f, 0.08f, 0.08f}, {60, 120, 200});  // a box on the table
  box({-1.5f, 1.1f, 0.5f}, {0.35f, 0.3f, 0.5f}, {230, 230, 235});   // cabinet
  box({1.3f, -0.5f, 0.45f}, {0.18f, 0.18f, 0.02f}, {200, 60, 50});  // stool seat
  for (float sx : {-1.0f, 1.0f}) {
    for (float sy : {-1.0f, 1.0f}) {
      capsule({1.3f + sx * 0.15f, -0.5f + sy * 0.15f, 0.0f}, {1.3f + sx * 0.15f, -0.5f + sy * 0.15f, 0.43f}, 0.01f,
              {40, 40, 40});  // stool legs, 2 cm
    }
  }
  s.primitives_.push_back({Kind::kSphere, {-0.8f, -0.5f, 0.25f}, {0, 0, 0}, 0.25f, {80, 170, 90}, 0});
  capsule({-0.6f, 0.9f, 0.0f}, {-0.6f, 0.9f, 1.7f}, 0.005f, {30, 30, 30});     // 1 cm vertical rod
  capsule({-1.2f, 1.3f, 1.1f}, {0.6f, 1.3f, 1.1f}, 0.0075f, {180, 180, 190});  // 1.5 cm horizontal rod
  capsule({1.5f, 1.2f, 0.0f}, {1.1f, 0.9f, 1.4f}, 0.01f, {200, 170, 40});      // 2 cm slanted rod
  return s;
}

SyntheticScene SyntheticScene::qualityRoom() {
  SyntheticScene s;
  using Bad = Primitive::Bad;
  auto add = [&](Kind kind, Vector3f a, Vector3f b, float r, alg::Color3 col, int tex, float noise = 1.0f,
                 Bad bad = Bad::kNo, float margin = 0.0f) {
    s.primitives_.push_back({kind, a, b, r, col, tex, noise, bad, margin});
  };
  add(Kind::kRoom, {0, 0, 1.29f}, {3.5f, 1.5f, 1.31f}, 0, {215, 205, 190}, 1);
  add(Kind::kBox, {0, 0, -0.05f}, {3.5f, 1.5f, 0.05f}, 0, {150, 110, 70}, 2);
  // Thin rods 1.5, 2 and 3 cm thick, 0.4-0.6 m in front of the back wall.
  add(Kind::kCapsule, {-0.8f, 1.0f, 0.0f}, {-0.8f, 1.0f, 1.8f}, 0.0075f, {30, 30, 30}, 0, 1.0f, Bad::kWhole);
  add(Kind::kCapsule, {-0.45f, 0.9f, 0.0f}, {-0.45f, 0.9f, 1.8f}, 0.01f, {200, 170, 40}, 0, 1.0f, Bad::kWhole);
  add(Kind::kCapsule, {1.5f, 1.05f, 0.0f}, {1.5f, 1.05f, 1.8f}, 0.015f, {180, 180, 190}, 0, 1.0f, Bad::kWhole);
  // A board 0.8 m in front of the wall: its edges are occlusion boundaries.
  add(Kind::kBox, {0.8f, 0.7f, 0.75f}, {0.25f, 0.02f, 0.75f}, 0, {60, 120, 200}, 0, 1.0f, Bad::kEdges);
  // A poster on the wall where the sensor is 4x noisier (a dark, shiny
  // material): sigma 3.5 cm at the 2.4 m it is seen from, so its noisy
  // depth lands up to 7 cm (2 sigma) off the wall.
  add(Kind::kBox, {-1.6f, 1.495f, 1.4f}, {0.3f, 0.005f, 0.3f}, 0, {120, 60, 90}, 0, 4.0f, Bad::kWhole, 0.07f);
  // A shelf above eye height: its top is seen only while the camera rises.
  add(Kind::kBox, {0.0f, 1.22f, 1.2f}, {0.5f, 0.25f, 0.015f}, 0, {170, 120, 80}, 0, 1.0f, Bad::kWhole);
  return s;
}

SyntheticScene SyntheticScene::street() {
  SyntheticScene s;
  // Uniform in [lo, hi) from a fixed seed, the same with every standard
  // library (the std distributions are not).
  std::mt19937 rng(20261206u);
  auto uniform = [&](float lo, float hi) {
    return lo + (hi - lo) * static_cast<float>(rng() >> 8) * (1.0f / 16777216.0f);
  };
  auto add = [&](Kind kind, Vector3f a, Vector3f b, float r, alg::Color3 col, int tex) {
    s.primitives_.push_back({kind, a, b, r, col, tex});
  };
  auto color = [&](int lo, int hi) {
    return alg::Color3(static_cast<uint8_t>(uniform(lo, hi)), static_cast<uint8_t>(uniform(lo, hi)),
                       static_cast<uint8_t>(uniform(lo, hi)));
  };
  // A pedestrian street 7 m wide: a Kinect-class sensor's noise at the
  // 2-4 m the facades are seen from is 1-3 cm (at 5 m it would be 4 cm).
  constexpr float kHalfLength = 80.0f, kFacade = 3.5f;
  // Paving in 10 m tiles (a checker of 40 cm stones: planks along the
  // street would look the same wherever along it the camera is) and a wall
  // closing either end.
  for (float x = -kHalfLength; x < kHalfLength; x += 10.0f) {
    add(Kind::kBox, {x + 5.0f, 0, -0.1f}, {5.0f, kFacade + 2.0f, 0.1f}, 0, {150, 140, 130}, 1);
  }
  for (float side : {-1.0f, 1.0f}) {
    add(Kind::kBox, {side * (kHalfLength + 0.5f), 0, 4.0f}, {0.5f, kFacade + 2.0f, 4.0f}, 0, color(150, 230), 1);
  }
  for (float side : {-1.0f, 1.0f}) {
    // Buildings along the side: widths 8-16 m, an alley 2.5 m wide after
    // about one in four, setbacks up to 0.6 m.
    float x = -kHalfLength;
    while (x < kHalfLength - 4.0f) {
      const float width = std::min(uniform(8.0f, 16.0f), kHalfLength - x);
      const float height = uniform(5.0f, 12.0f), setback = uniform(0.0f, 0.6f);
      const float front = kFacade + setback, cx = x + width / 2;
      add(Kind::kBox, {cx, side * (front + 1.5f), height / 2}, {width / 2, 1.5f, height / 2}, 0, color(120, 235), 1);
      // Half columns 30-40 cm thick every 2.5-4 m: a street of planes
      // alone, seen square on, shows no surface facing along it (box sides
      // are edge on), and ICP could not tell where along it the camera is;
      // round columns face every way. Then a door (its frame standing out
      // 12 cm) and a ledge under the first floor's windows.
      for (float px = x + 0.5f; px < x + width - 0.5f; px += uniform(2.5f, 4.0f)) {
        add(Kind::kCapsule, {px, side * front, 0.0f}, {px, side * front, height}, uniform(0.15f, 0.2f), color(100, 220),
            0);
      }
      const float door_x = uniform(x + 1.5f, x + width - 1.5f);
      add(Kind::kBox, {door_x, side * (front - 0.06f), 1.1f}, {0.7f, 0.06f, 1.1f}, 0, color(40, 120), 0);
      add(Kind::kBox, {cx, side * (front - 0.1f), 3.2f}, {width / 2 - 0.5f, 0.1f, 0.08f}, 0, color(180, 240), 0);
      x += width + (uniform(0.0f, 1.0f) < 0.25f ? 2.5f : 0.0f);
    }
    // Along the facades every 3-7 m: a planter, a lamp post, a bush or a
    // bin.
    for (float xc = -kHalfLength + 3.0f; xc < kHalfLength - 3.0f; xc += uniform(3.0f, 7.0f)) {
      const int kind = static_cast<int>(uniform(0.0f, 4.0f));
      if (kind == 0) {
        add(Kind::kBox, {xc, side * 2.95f, 0.3f}, {0.8f, 0.3f, 0.3f}, 0, color(30, 220), 0);
        add(Kind::kSphere, {xc, side * 2.95f, 0.75f}, {0, 0, 0}, 0.3f, color(40, 140), 0);
      } else if (kind == 1) {
        add(Kind::kCapsule, {xc, side * 3.0f, 0.0f}, {xc, side * 3.0f, 4.0f}, 0.06f, {60, 70, 60}, 0);
        add(Kind::kSphere, {xc, side * 3.0f, 4.1f}, {0, 0, 0}, 0.2f, {240, 230, 200}, 0);
      } else if (kind == 2) {
        add(Kind::kSphere, {xc, side * 2.95f, 0.3f}, {0, 0, 0}, uniform(0.3f, 0.45f), color(40, 140), 0);
      } else {
        add(Kind::kBox, {xc, side * 3.1f, 0.45f}, {0.25f, 0.25f, 0.45f}, 0, color(60, 200), 0);
      }
    }
  }
  return s;
}

SyntheticScene SyntheticScene::near(const Vector3f& center, float radius) const {
  SyntheticScene out;
  out.scale_ = scale_;
  for (int k = 0; k < static_cast<int>(primitives_.size()); ++k) {
    const Primitive& pr = primitives_[static_cast<size_t>(k)];
    Vector3f c = pr.a;
    float r = pr.radius;
    if (pr.kind == Kind::kBox || pr.kind == Kind::kRoom) {
      r = pr.b.norm();
    } else if (pr.kind == Kind::kCapsule) {
      c = 0.5f * (pr.a + pr.b);
      r += 0.5f * (pr.b - pr.a).norm();
    }
    // A room is seen from inside: keep it wherever the camera is.
    if (pr.kind != Kind::kRoom && (c - center).norm() > radius + r) continue;
    out.primitives_.push_back(pr);
    out.source_index_.push_back(source_index_.empty() ? k : source_index_[static_cast<size_t>(k)]);
  }
  return out;
}

SyntheticScene SyntheticScene::scaled(float s) const {
  SyntheticScene out = *this;
  for (Primitive& p : out.primitives_) {
    p.a *= s;
    p.b *= s;
    p.radius *= s;
    p.bad_margin_m *= s;
  }
  out.scale_ *= s;
  return out;
}

namespace {

float boxSdf(const Vector3f& p, const Vector3f& c, const Vector3f& h) {
  const Vector3f q = (p - c).cwiseAbs() - h;
  return q.cwiseMax(0.0f).norm() + std::min(q.maxCoeff(), 0.0f);
}

Vector3f closestOnSegment(const Vector3f& p, const Vector3f& a, const Vector3f& b) {
  const Vector3f ab = b - a;
  const float t = std::clamp((p - a).dot(ab) / ab.squaredNorm(), 0.0f, 1.0f);
  return a + t * ab;
}

float primitiveSdf(const Primitive& pr, const Vector3f& p) {
  switch (pr.kind) {
    case Kind::kBox:
      return boxSdf(p, pr.a, pr.b);
    case Kind::kRoom:
      return -boxSdf(p, pr.a, pr.b);
    case Kind::kSphere:
      return (p - pr.a).norm() - pr.radius;
    case Kind::kCapsule:
      return (p - closestOnSegment(p, pr.a, pr.b)).norm() - pr.radius;
  }
  return 1e9f;
}

// Entry of a ray into a sphere, or -1.
float raySphere(const Vector3f& o, const Vector3f& d, const Vector3f& c, float r) {
  const Vector3f oc = o - c;
  const float b = oc.dot(d), cc = oc.squaredNorm() - r * r;
  const float h = b * b - cc;
  if (h < 0) return -1;
  return -b - std::sqrt(h);
}

float rayCapsule(const Vector3f& o, const Vector3f& d, const Vector3f& pa, const Vector3f& pb, float r) {
  // Entry into the union of the finite cylinder's side and the two end spheres.
  float best = -1;
  auto take = [&](float t) {
    if (t > 0 && (best < 0 || t < best)) best = t;
  };
  take(raySphere(o, d, pa, r));
  take(raySphere(o, d, pb, r));
  const Vector3f ba = pb - pa, oa = o - pa;
  const float baba = ba.dot(ba), bard = ba.dot(d), baoa = ba.dot(oa), rdoa = d.dot(oa), oaoa = oa.dot(oa);
  const float a = baba - bard * bard;
  if (a > 1e-10f) {
    const float b = baba * rdoa - baoa * bard, c = baba * oaoa - baoa * baoa - r * r * baba;
    const float h = b * b - a * c;
    if (h >= 0) {
      const float t = (-b - std::sqrt(h)) / a;
      const float y = baoa + t * bard;
      if (y > 0 && y < baba) take(t);
    }
  }
  return best;
}

// Slab test; returns entry (outside) or exit (inside_out) distance, or -1.
float rayBox(const Vector3f& o, const Vector3f& d, const Vector3f& c, const Vector3f& h, bool inside_out) {
  const Vector3f inv = d.cwiseInverse();
  const Vector3f t0 = (c - h - o).cwiseProduct(inv), t1 = (c + h - o).cwiseProduct(inv);
  const float tn = t0.cwiseMin(t1).maxCoeff(), tf = t0.cwiseMax(t1).minCoeff();
  if (tn > tf) return -1;
  if (inside_out) return tf > 0 ? tf : -1;
  return tn > 0 ? tn : -1;
}

Vector3f boxNormal(const Vector3f& p, const Vector3f& c, const Vector3f& h) {
  const Vector3f q = (p - c).cwiseQuotient(h);
  int axis = 0;
  q.cwiseAbs().maxCoeff(&axis);
  Vector3f n = Vector3f::Zero();
  n[axis] = q[axis] > 0 ? 1.0f : -1.0f;
  return n;
}

uint32_t hash3(int x, int y, int z, uint32_t seed) {
  uint32_t h = seed * 0x9E3779B9u ^ static_cast<uint32_t>(x) * 0x85EBCA6Bu ^ static_cast<uint32_t>(y) * 0xC2B2AE35u ^
               static_cast<uint32_t>(z) * 0x27D4EB2Fu;
  h ^= h >> 15;
  h *= 0x2C1B3C6Du;
  h ^= h >> 12;
  h *= 0x297A2D39u;
  h ^= h >> 15;
  return h;
}

// Smooth value noise in [0, 1].
float valueNoise(const Vector3f& p, uint32_t seed) {
  const Eigen::Vector3f f = p.array().floor();
  const Eigen::Vector3i i = f.cast<int>();
  Vector3f t = p - f;
  t = t.array() * t.array() * (3.0f - 2.0f * t.array());
  float v = 0;
  for (int c = 0; c < 8; ++c) {
    const int dx = c & 1, dy = (c >> 1) & 1, dz = (c >> 2) & 1;
    const float w = (dx ? t.x() : 1 - t.x()) * (dy ? t.y() : 1 - t.y()) * (dz ? t.z() : 1 - t.z());
    v += w * static_cast<float>(hash3(i.x() + dx, i.y() + dy, i.z() + dz, seed) & 0xFFFF) / 65535.0f;
  }
  return v;
}

}  // namespace

float SyntheticScene::badDistance(const Vector3f& p, int* primitive) const {
  float d = std::numeric_limits<float>::infinity();
  for (int k = 0; k < static_cast<int>(primitives_.size()); ++k) {
    const Primitive& pr = primitives_[k];
    const float before = d;
    if (pr.bad == Primitive::Bad::kWhole) {
      d = std::min(d, std::max(0.0f, std::abs(primitiveSdf(pr, p)) - pr.bad_margin_m));
    } else if (pr.bad == Primitive::Bad::kEdges && pr.kind == Kind::kBox) {
      // The 12 edges, less those resting on the floor.
      for (int axis = 0; axis < 3; ++axis) {
        const int u = (axis + 1) % 3, v = (axis + 2) % 3;
        for (int su : {-1, 1}) {
          for (int sv : {-1, 1}) {
            Vector3f a = pr.a, b = pr.a;
            a[u] = b[u] = pr.a[u] + su * pr.b[u];
            a[v] = b[v] = pr.a[v] + sv * pr.b[v];
            a[axis] -= pr.b[axis];
            b[axis] += pr.b[axis];
            if (a.z() <= 1e-3f && b.z() <= 1e-3f) continue;
            d = std::min(d, (p - closestOnSegment(p, a, b)).norm());
          }
        }
      }
    }
    if (primitive && d < before) *primitive = k;
  }
  return d;
}

float SyntheticScene::sdf(const Vector3f& p) const {
  float d = 1e9f;
  for (const auto& pr : primitives_) d = std::min(d, primitiveSdf(pr, p));
  return d;
}

bool SyntheticScene::raycast(const Vector3f& o, const Vector3f& d, float& t_hit, Vector3f& normal,
                             int& primitive) const {
  float best = -1;
  int best_k = -1;
  for (int k = 0; k < static_cast<int>(primitives_.size()); ++k) {
    const auto& pr = primitives_[k];
    float t = -1;
    switch (pr.kind) {
      case Kind::kBox:
        t = rayBox(o, d, pr.a, pr.b, false);
        break;
      case Kind::kRoom:
        t = rayBox(o, d, pr.a, pr.b, true);
        break;
      case Kind::kSphere:
        t = raySphere(o, d, pr.a, pr.radius);
        break;
      case Kind::kCapsule:
        t = rayCapsule(o, d, pr.a, pr.b, pr.radius);
        break;
    }
    if (t > 0 && (best < 0 || t < best)) {
      best = t;
      best_k = k;
    }
  }
  if (best_k < 0) return false;
  const auto& pr = primitives_[best_k];
  const Vector3f p = o + best * d;
  switch (pr.kind) {
    case Kind::kBox:
      normal = boxNormal(p, pr.a, pr.b);
      break;
    case Kind::kRoom:
      normal = -boxNormal(p, pr.a, pr.b);
      break;
    case Kind::kSphere:
      normal = (p - pr.a).normalized();
      break;
    case Kind::kCapsule:
      normal = (p - closestOnSegment(p, pr.a, pr.b)).normalized();
      break;
  }
  t_hit = best;
  primitive = best_k;
  return true;
}

alg::Color3 SyntheticScene::color(const Vector3f& p_world, const Vector3f& n, int primitive) const {
  const Primitive& pr = primitives_[primitive];
  const Vector3f p = p_world / scale_;
  Eigen::Vector3f albedo = pr.color.cast<float>() / 255.0f;
  const int seed_index = source_index_.empty() ? primitive : source_index_[static_cast<size_t>(primitive)];
  const float grain = valueNoise(p * 12.0f, 7u + static_cast<uint32_t>(seed_index));
  const float fine = valueNoise(p * 60.0f, 13u);
  if (pr.texture == 1) {  // walls: large checker, posters of noise
    const int cx = static_cast<int>(std::floor(p.x() * 2.5f)), cy = static_cast<int>(std::floor(p.y() * 2.5f)),
              cz = static_cast<int>(std::floor(p.z() * 2.5f));
    const float checker = ((cx + cy + cz) & 1) ? 0.75f : 1.0f;
    const Eigen::Vector3f tint(0.8f + 0.4f * valueNoise(p * 1.5f, 3u), 0.8f + 0.4f * valueNoise(p * 1.5f, 4u),
                               0.8f + 0.4f * valueNoise(p * 1.5f, 5u));
    albedo = albedo.cwiseProduct(tint) * checker * (0.8f + 0.2f * fine);
  } else if (pr.texture == 2) {  // planks along x
    const float plank = valueNoise(Vector3f(0, std::floor(p.y() * 6.0f), 0), 9u);
    const float rings = 0.5f + 0.5f * std::sin(p.x() * 40.0f + 8.0f * valueNoise(p * 3.0f, 11u));
    albedo *= (0.7f + 0.3f * plank) * (0.85f + 0.15f * rings);
  } else {
    albedo *= 0.75f + 0.25f * grain + 0.1f * (fine - 0.5f);
  }
  const Vector3f light = Vector3f(0.3f, 0.5f, 1.0f).normalized();
  const float shade = 0.45f + 0.55f * std::abs(n.dot(light));
  const Eigen::Vector3f c = (albedo * shade * 255.0f).cwiseMax(0.0f).cwiseMin(255.0f);
  return c.array().round().cast<uint8_t>();
}

namespace {

void addBoxMesh(alg::TriangleMesh& m, const Vector3f& c, const Vector3f& h, bool inward) {
  // Each face split in a grid so triangles stay small (better for visibility
  // tests and for PLY viewers).
  for (int axis = 0; axis < 3; ++axis) {
    for (int sign : {-1, 1}) {
      const int u = (axis + 1) % 3, v = (axis + 2) % 3;
      const int nu = std::max(1, static_cast<int>(std::ceil(2 * h[u] / 0.25f)));
      const int nv = std::max(1, static_cast<int>(std::ceil(2 * h[v] / 0.25f)));
      const int base = static_cast<int>(m.vertices.size());
      for (int j = 0; j <= nv; ++j) {
        for (int i = 0; i <= nu; ++i) {
          Vector3f p = c;
          p[axis] += sign * h[axis];
          p[u] += -h[u] + 2 * h[u] * static_cast<float>(i) / static_cast<float>(nu);
          p[v] += -h[v] + 2 * h[v] * static_cast<float>(j) / static_cast<float>(nv);
          m.vertices.push_back(p);
        }
      }
      const bool flip = (sign < 0) != inward;
      for (int j = 0; j < nv; ++j) {
        for (int i = 0; i < nu; ++i) {
          const int a = base + j * (nu + 1) + i, b = a + 1, d = a + nu + 1, e = d + 1;
          if (flip) {
            m.triangles.emplace_back(a, e, b);
            m.triangles.emplace_back(a, d, e);
          } else {
            m.triangles.emplace_back(a, b, e);
            m.triangles.emplace_back(a, e, d);
          }
        }
      }
    }
  }
}

// Unit sphere patch: center + r * direction, latitude rings.
void addSphereMesh(alg::TriangleMesh& m, const Vector3f& c, float r, const Vector3f& axis, const Vector3f& u,
                   const Vector3f& v, float lat0, float lat1, int rings, int segments) {
  const int base = static_cast<int>(m.vertices.size());
  for (int i = 0; i <= rings; ++i) {
    const float lat = lat0 + (lat1 - lat0) * static_cast<float>(i) / static_cast<float>(rings);
    for (int j = 0; j < segments; ++j) {
      const float lon = 2.0f * static_cast<float>(M_PI) * static_cast<float>(j) / static_cast<float>(segments);
      const Vector3f dir = std::sin(lat) * axis + std::cos(lat) * (std::cos(lon) * u + std::sin(lon) * v);
      m.vertices.push_back(c + r * dir);
    }
  }
  for (int i = 0; i < rings; ++i) {
    for (int j = 0; j < segments; ++j) {
      const int a = base + i * segments + j, b = base + i * segments + (j + 1) % segments;
      const int d = a + segments, e = b + segments;
      m.triangles.emplace_back(a, b, e);
      m.triangles.emplace_back(a, e, d);
    }
  }
}

int segmentsFor(float r) {
  // Chord error r (1 - cos(pi / n)) below 0.5 mm.
  int n = 8;
  while (r * (1 - std::cos(static_cast<float>(M_PI) / static_cast<float>(n))) > 0.0005f && n < 256) n += 4;
  return n;
}

}  // namespace

alg::TriangleMesh SyntheticScene::mesh() const {
  alg::TriangleMesh out;
  for (int k = 0; k < static_cast<int>(primitives_.size()); ++k) {
    const auto& pr = primitives_[k];
    alg::TriangleMesh m;
    switch (pr.kind) {
      case Kind::kBox:
        addBoxMesh(m, pr.a, pr.b, false);
        break;
      case Kind::kRoom:
        addBoxMesh(m, pr.a, pr.b, true);
        break;
      case Kind::kSphere: {
        const int n = segmentsFor(pr.radius);
        addSphereMesh(m, pr.a, pr.radius, Vector3f::UnitZ(), Vector3f::UnitX(), Vector3f::UnitY(),
                      -static_cast<float>(M_PI) / 2, static_cast<float>(M_PI) / 2, n / 2, n);
        break;
      }
      case Kind::kCapsule: {
        const Vector3f axis = (pr.b - pr.a).normalized();
        const Vector3f u = axis.unitOrthogonal(), v = axis.cross(u);
        const int n = segmentsFor(pr.radius);
        const float half_pi = static_cast<float>(M_PI) / 2;
        addSphereMesh(m, pr.a, pr.radius, axis, u, v, -half_pi, 0.0f, n / 4, n);
        addSphereMesh(m, pr.b, pr.radius, axis, u, v, 0.0f, half_pi, n / 4, n);
        // Body between the two equators, split along its length.
        const int rings = std::max(1, static_cast<int>(std::ceil((pr.b - pr.a).norm() / 0.1f)));
        const int base = static_cast<int>(m.vertices.size());
        for (int i = 0; i <= rings; ++i) {
          const Vector3f c = pr.a + (pr.b - pr.a) * static_cast<float>(i) / static_cast<float>(rings);
          for (int j = 0; j < n; ++j) {
            const float lon = 2.0f * static_cast<float>(M_PI) * static_cast<float>(j) / static_cast<float>(n);
            m.vertices.push_back(c + pr.radius * (std::cos(lon) * u + std::sin(lon) * v));
          }
        }
        for (int i = 0; i < rings; ++i) {
          for (int j = 0; j < n; ++j) {
            const int a = base + i * n + j, b = base + i * n + (j + 1) % n;
            m.triangles.emplace_back(a, b, b + n);
            m.triangles.emplace_back(a, b + n, a + n);
          }
        }
        break;
      }
    }
    m.colors.assign(m.vertices.size(), pr.color);
    out.append(m);
  }
  return out;
}

Eigen::Isometry3d syntheticPose(const SyntheticParams& params, double t) {
  Eigen::Vector3d eye, target;
  if (params.trajectory == "inspect") {
    // Along the back wall (x -1 -> 1 in 4 s, then back), eye 1 m high,
    // rising to 1.6 m around t = 2 s to glance over the shelf.
    const double x = -1.0 + 2.0 * (0.5 - 0.5 * std::cos(M_PI * t / 4.0));
    const double rise = std::abs(t - 2.0) < 0.5 ? 0.5 + 0.5 * std::cos(M_PI * (t - 2.0) / 0.5) : 0.0;
    eye = {x, -0.9 + 0.05 * std::sin(1.3 * t), 1.0 + 0.6 * rise};
    target = {x + 0.3 * std::sin(0.7 * t), 1.5, eye.z() - 0.1};
  } else if (params.trajectory == "sweep") {
    const double x = -1.1 + 2.2 * (0.5 - 0.5 * std::cos(0.3 * t));  // back and forth along the wall
    eye = {x, -1.1 + 0.05 * std::sin(1.3 * t), 1.25 + 0.1 * std::sin(0.9 * t)};
    target = {x + 0.5 * std::sin(0.7 * t), 1.5, 0.7};
  } else if (params.trajectory == "loop") {
    // Laps of 10 s on a 0.3 m circle in the middle of the room, looking
    // out and down at the walls and the floor (36 deg/s of yaw, 0.2 m/s): a wall seen at the
    // start is out of view until the lap ends, so drift shows when the
    // camera comes back (630 frames at 30 FPS make two laps).
    const double phi = -M_PI / 2 + 2.0 * M_PI * t / 10.0;
    const Eigen::Vector3d out(std::cos(phi), std::sin(phi), 0.0);
    eye = Eigen::Vector3d(0.0, 0.0, 1.2 + 0.1 * std::sin(0.9 * t)) + 0.3 * out;
    target = eye + 1.5 * out + Eigen::Vector3d(0.0, 0.0, -0.85 + 0.15 * std::sin(0.5 * t));
  } else if (params.trajectory == "street") {
    // End to end of SyntheticScene::street (x from -72 to 72 m) and back,
    // 144 s each way (1 m/s on average, 1.6 m/s in the middle, slowing to a
    // stop at either end), weaving 0.8 m either side of the middle. The
    // heading turns through half a circle over each way, fastest at the
    // ends where the camera turns around, and swings 50 degrees to either
    // side every 12 s to look at the facades; the gaze rises and falls
    // between the paving and the upper floors.
    constexpr double kWay = 144.0;
    const double u = t / kWay;
    const double x = -72.0 + 144.0 * (0.5 - 0.5 * std::cos(M_PI * u));
    eye = {x, 0.8 * std::sin(0.25 * t), 1.4 + 0.15 * std::sin(0.7 * t)};
    const double heading =
        M_PI * (u - 0.5 + std::sin(2.0 * M_PI * u) / (2.0 * M_PI)) + 0.87 * std::sin(2.0 * M_PI * t / 12.0);
    target = eye + Eigen::Vector3d(4.0 * std::cos(heading), 4.0 * std::sin(heading), -0.4 + 0.8 * std::sin(0.23 * t));
  } else if (params.trajectory == "fast") {
    // Around the table like the orbit, in surges: the angle's rate swings
    // between -0.24 and 0.84 rad/s (about 1.1 m/s along the circle and as
    // many degrees per second of yaw), with a hand's shake of a few
    // millimeters at 3-5 Hz on the eye and the target.
    const double phi = -2.3 + 0.3 * t + 0.3 * std::sin(1.8 * t);
    const double r = 1.35 + 0.1 * std::sin(0.9 * t);
    eye = {0.3 + r * std::cos(phi), 0.1 + 1.0 * std::sin(phi), 1.35 + 0.15 * std::sin(1.7 * t)};
    eye += Eigen::Vector3d(0.004 * std::sin(2 * M_PI * 4.3 * t), 0.004 * std::sin(2 * M_PI * 3.7 * t + 1.0),
                           0.003 * std::sin(2 * M_PI * 5.1 * t + 2.0));
    target = {0.2 + 0.15 * std::sin(0.8 * t) + 0.012 * std::sin(2 * M_PI * 2.9 * t),
              0.25 + 0.1 * std::cos(0.6 * t) + 0.012 * std::sin(2 * M_PI * 3.3 * t + 0.5), 0.65};
  } else {
    const double phi = -2.3 + 0.3 * t;  // around the table
    eye = {0.3 + 1.35 * std::cos(phi), 0.1 + 1.0 * std::sin(phi), 1.35 + 0.12 * std::sin(1.1 * t)};
    target = {0.2 + 0.15 * std::sin(0.8 * t), 0.25 + 0.1 * std::cos(0.6 * t), 0.65};
  }
  eye *= params.scale;
  target *= params.scale;
  const Eigen::Vector3d forward = (target - eye).normalized();
  const Eigen::Vector3d right = forward.cross(Eigen::Vector3d::UnitZ()).normalized();
  const Eigen::Vector3d down = forward.cross(right);
  Eigen::Isometry3d T_world_cam = Eigen::Isometry3d::Identity();
  T_world_cam.linear().col(0) = right;
  T_world_cam.linear().col(1) = down;
  T_world_cam.linear().col(2) = forward;
  T_world_cam.translation() = eye;
  return T_world_cam;
}

bool hasColorEffects(const SyntheticParams& params) {
  return params.color_delay_s != 0.0 || params.rolling_shutter_s > 0.0 || params.exposure_s > 0.0 ||
         params.gain_variation > 0.0;
}

Trajectory syntheticTrajectory(const SyntheticParams& params) {
  Trajectory traj;
  const int64_t period_ns = static_cast<int64_t>(1e9 / params.fps);
  const int64_t start_ns = 1'000'000'000LL;
  // Speeds are fixed in physical units (about 0.35 m/s, 20 deg/s), so a
  // longer sequence covers more of the room rather than moving faster.
  for (int i = 0; i < params.frames; ++i) {
    StampedPose p;
    p.stamp_ns = start_ns + i * period_ns;
    p.T_world_cam = syntheticPose(params, static_cast<double>(i) / params.fps);
    traj.push_back(p);
  }
  return traj;
}

TrajectorySpeeds trajectorySpeeds(const Trajectory& trajectory) {
  TrajectorySpeeds s;
  size_t n = 0;
  for (size_t i = 1; i < trajectory.size(); ++i) {
    const double dt = static_cast<double>(trajectory[i].stamp_ns - trajectory[i - 1].stamp_ns) * 1e-9;
    if (!(dt > 0)) continue;
    const Eigen::Isometry3d d = trajectory[i - 1].T_world_cam.inverse() * trajectory[i].T_world_cam;
    const double v = d.translation().norm() / dt;
    const double w = Eigen::AngleAxisd(d.linear()).angle() * 180.0 / M_PI / dt;
    s.max_linear_mps = std::max(s.max_linear_mps, v);
    s.max_angular_dps = std::max(s.max_angular_dps, w);
    s.mean_linear_mps += v;
    s.mean_angular_dps += w;
    ++n;
  }
  if (n > 0) {
    s.mean_linear_mps /= static_cast<double>(n);
    s.mean_angular_dps /= static_cast<double>(n);
  }
  return s;
}

namespace {

// The color camera's image with SyntheticParams' imperfections: each row at
// its own time (rolling shutter), averaged over the exposure (motion blur),
// scaled by the auto exposure's gain.
void renderColorWithEffects(const SyntheticScene& scene, const alg::PinholeCamera& cam, const SyntheticParams& params,
                            int frame_index, const ParallelFor& parallel, cv::Mat& rgb) {
  const double t_color = static_cast<double>(frame_index) / params.fps + params.color_delay_s;
  const int samples = params.exposure_s > 0.0 ? 5 : 1;
  const float gain = static_cast<float>(1.0 + params.gain_variation * std::sin(2.0 * M_PI * t_color / 4.0 + 0.7));
  parallel(static_cast<size_t>(cam.height), [&](size_t v0, size_t v1) {
    std::vector<Eigen::Isometry3f> poses(static_cast<size_t>(samples));
    for (int v = static_cast<int>(v0); v < static_cast<int>(v1); ++v) {
      const double t_row =
          t_color + params.rolling_shutter_s * ((static_cast<double>(v) + 0.5) / cam.height - 0.5);
      for (int s = 0; s < samples; ++s) {
        const double t = t_row + params.exposure_s * ((s + 0.5) / samples - 0.5);
        poses[static_cast<size_t>(s)] = syntheticPose(params, t).cast<float>();
      }
      for (int u = 0; u < cam.width; ++u) {
        const Vector3f ray_cam = cam.backproject(static_cast<float>(u), static_cast<float>(v), 1.0f);
        Vector3f sum = Vector3f::Zero();
        for (const Eigen::Isometry3f& T_world_cam : poses) {
          const Vector3f dir = (T_world_cam.linear() * ray_cam).normalized();
          float t = 0;
          Vector3f n;
          int k = -1;
          if (!scene.raycast(T_world_cam.translation(), dir, t, n, k)) continue;
          const alg::Color3 c = scene.color(T_world_cam.translation() + t * dir, n, k);
          sum += Vector3f(c[0], c[1], c[2]);
        }
        sum *= gain / static_cast<float>(samples);
        rgb.at<cv::Vec3b>(v, u) = cv::Vec3b(cv::saturate_cast<uint8_t>(sum.x()), cv::saturate_cast<uint8_t>(sum.y()),
                                            cv::saturate_cast<uint8_t>(sum.z()));
      }
    }
  });
}

}  // namespace

RenderedFrame renderFrame(const SyntheticScene& full_scene, const alg::PinholeCamera& cam,
                          const Eigen::Isometry3d& T_world_cam, const SyntheticParams& params, int frame_index,
                          const ParallelFor& parallel) {
  // A large scene is cut to what the sensor can see from here (its range,
  // and a meter for the color camera's motion within the frame; color
  // beyond that is black, as the sky is); without the sensor model depth is
  // not cut at its range, so nothing is left out.
  constexpr size_t kCullAbove = 64;
  const bool cull = params.noise && full_scene.primitives().size() > kCullAbove;
  const SyntheticScene near_scene =
      cull ? full_scene.near(T_world_cam.translation().cast<float>(), static_cast<float>(params.max_depth_m) + 1.0f)
           : SyntheticScene{};
  const SyntheticScene& scene = cull ? near_scene : full_scene;
  RenderedFrame out;
  out.rgb.create(cam.height, cam.width, CV_8UC3);
  out.depth_true.create(cam.height, cam.width, CV_32F);
  cv::Mat cosine(cam.height, cam.width, CV_32F);
  cv::Mat noise_gain(cam.height, cam.width, CV_32F, cv::Scalar(1.0f));
  const Eigen::Isometry3f T_world_cam_f = T_world_cam.cast<float>();
  const Vector3f origin = T_world_cam_f.translation();
  parallel(static_cast<size_t>(cam.height), [&](size_t v0, size_t v1) {
    for (int v = static_cast<int>(v0); v < static_cast<int>(v1); ++v) {
      for (int u = 0; u < cam.width; ++u) {
        const Vector3f ray_cam = cam.backproject(static_cast<float>(u), static_cast<float>(v), 1.0f);
        const Vector3f dir = (T_world_cam_f.linear() * ray_cam).normalized();
        float t = 0;
        Vector3f n;
        int k = -1;
        auto& px = out.rgb.at<cv::Vec3b>(v, u);
        if (!scene.raycast(origin, dir, t, n, k)) {
          out.depth_true.at<float>(v, u) = 0;
          cosine.at<float>(v, u) = 0;
          px = cv::Vec3b(0, 0, 0);
          continue;
        }
        const Vector3f p = origin + t * dir;
        const float z = t / ray_cam.norm();
        out.depth_true.at<float>(v, u) = z;
        cosine.at<float>(v, u) = std::abs(n.dot(dir));
        noise_gain.at<float>(v, u) = scene.primitives()[k].noise_scale;
        const alg::Color3 c = scene.color(p, n, k);
        px = cv::Vec3b(c[0], c[1], c[2]);
      }
    }
  });
  if (hasColorEffects(params)) renderColorWithEffects(scene, cam, params, frame_index, parallel, out.rgb);
  out.depth = out.depth_true.clone();
  if (!params.noise) return out;

  std::mt19937_64 rng(params.seed * 1000003ULL + static_cast<uint64_t>(frame_index));
  std::normal_distribution<float> gauss(0.0f, 1.0f);
  const float baseline_fx = 0.075f * static_cast<float>(cam.fx);
  for (int v = 0; v < cam.height; ++v) {
    for (int u = 0; u < cam.width; ++u) {
      const float z = out.depth_true.at<float>(v, u);
      float& d = out.depth.at<float>(v, u);
      if (z <= 0) continue;
      bool invalid = z < params.min_depth_m || z > params.max_depth_m || cosine.at<float>(v, u) < params.grazing_cos;
      for (const auto& [du, dv] : {std::pair{1, 0}, {-1, 0}, {0, 1}, {0, -1}}) {
        const int uu = u + du, vv = v + dv;
        if (uu < 0 || vv < 0 || uu >= cam.width || vv >= cam.height) continue;
        const float zn = out.depth_true.at<float>(vv, uu);
        if (zn <= 0 || std::abs(zn - z) > params.edge_jump_ratio * z) invalid = true;
      }
      const float sigma = static_cast<float>(params.noise_scale) * noise_gain.at<float>(v, u) *
                          (0.0012f + 0.0019f * (z - 0.4f) * (z - 0.4f));
      const float noisy = z + sigma * gauss(rng);
      // Disparity quantized to 1/8 pixel, as a Kinect v1.
      const float disparity = std::round(baseline_fx / std::max(noisy, 0.05f) * 8.0f) / 8.0f;
      d = invalid || disparity <= 0 ? 0.0f : baseline_fx / disparity;
    }
  }
  std::uniform_real_distribution<float> uni(0.0f, 1.0f);
  for (int b = 0; b < params.missing_blobs_per_frame; ++b) {
    const cv::Point center(static_cast<int>(uni(rng) * cam.width), static_cast<int>(uni(rng) * cam.height));
    const cv::Size axes(static_cast<int>(10 + 25 * uni(rng)), static_cast<int>(10 + 25 * uni(rng)));
    cv::ellipse(out.depth, center, axes, 180.0 * uni(rng), 0, 360, cv::Scalar(0), cv::FILLED);
  }
  // Mild color noise.
  for (int v = 0; v < cam.height; ++v) {
    for (int u = 0; u < cam.width; ++u) {
      auto& px = out.rgb.at<cv::Vec3b>(v, u);
      const float e = 2.0f * gauss(rng);
      for (int c = 0; c < 3; ++c) px[c] = cv::saturate_cast<uint8_t>(px[c] + e);
    }
  }
  return out;
}

Status writeSyntheticSequence(const std::string& dir, const SyntheticScene& scene, const SyntheticParams& params,
                              const ParallelFor& parallel, const std::function<void(int, int)>& progress) {
  namespace fs = std::filesystem;
  std::error_code ec;
  fs::create_directories(fs::path(dir) / "rgb", ec);
  fs::create_directories(fs::path(dir) / "depth", ec);
  if (ec) return Error{dir + ": cannot create the sequence folders: " + ec.message()};
  const Trajectory traj = syntheticTrajectory(params);
  std::string rgb_list = "# color images\n# timestamp filename\n";
  std::string depth_list = "# depth maps\n# timestamp filename\n";
  for (int i = 0; i < params.frames; ++i) {
    if (params.drop_every > 0 && i % params.drop_every == params.drop_every - 1) {
      if (progress) progress(i + 1, params.frames);
      continue;  // dropped by the "camera": in the ground truth only
    }
    RenderedFrame f = renderFrame(scene, params.camera, traj[i].T_world_cam, params, i, parallel);
    const double t = static_cast<double>(i) / params.fps;
    if (params.blackout_s > 0 && t >= params.blackout_start_s && t < params.blackout_start_s + params.blackout_s) {
      f.depth.setTo(0.0f);
      f.rgb.setTo(cv::Scalar(0, 0, 0));
    }
    const std::string stamp = formatStampS(traj[i].stamp_ns);
    const std::string color_stamp =
        formatStampS(traj[i].stamp_ns + static_cast<int64_t>(std::llround(params.color_delay_s * 1e9)));
    cv::Mat bgr, depth16;
    cv::cvtColor(f.rgb, bgr, cv::COLOR_RGB2BGR);
    f.depth.convertTo(depth16, CV_16U, 5000.0);
    const std::string rgb_rel = "rgb/" + color_stamp + ".png", depth_rel = "depth/" + stamp + ".png";
    if (!cv::imwrite((fs::path(dir) / rgb_rel).string(), bgr) ||
        !cv::imwrite((fs::path(dir) / depth_rel).string(), depth16)) {
      return Error{dir + ": cannot write images (disk full or not writable?)"};
    }
    rgb_list += color_stamp + " " + rgb_rel + "\n";
    depth_list += stamp + " " + depth_rel + "\n";
    if (progress) progress(i + 1, params.frames);
  }
  const auto& c = params.camera;
  const std::string calib = fmt::format(
      "# hxmap synthetic sequence (seed {}, trajectory {}, {} FPS, noise {}, scale {}, blackout {} s from {} s, drop "
      "every {}; color {} s after depth, rolling shutter {} s, exposure {} s, gain +-{})\nfx: {}\nfy: {}\ncx: "
      "{}\ncy: {}\nwidth: "
      "{}\n"
      "height: {}\ndepth_scale: 5000\n"
      "# the sensor returns no depth where |cos(incidence)| is below this\nsensor_grazing_cos: {}\n",
      params.seed, params.trajectory, params.fps, params.noise ? "on" : "off", params.scale, params.blackout_s,
      params.blackout_start_s, params.drop_every, params.color_delay_s, params.rolling_shutter_s, params.exposure_s,
      params.gain_variation, c.fx, c.fy, c.cx, c.cy, c.width, c.height, params.grazing_cos);
  for (const auto& [name, text] : {std::pair{"rgb.txt", rgb_list},
                                   {"depth.txt", depth_list},
                                   {"groundtruth.txt", formatTumTrajectory(traj)},
                                   {"calibration.yaml", calib}}) {
    if (auto s = writeTextFile((fs::path(dir) / name).string(), text); !s) return s;
  }
  return writePly((fs::path(dir) / "gt_mesh.ply").string(), scene.mesh());
}

}  // namespace hxmap::drv
