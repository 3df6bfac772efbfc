// Warps from the unit square and small Monte Carlo helpers.
#pragma once
#include <algorithm>
#include <cmath>
#include <vector>

#include "util/math.h"

namespace pl {

struct Vec2 {
  float x = 0, y = 0;
};

// Concentric mapping (Shirley-Chiu): low distortion, keeps stratification.
inline Vec2 sample_disk_concentric(Vec2 u) {
  const float a = 2.0f * u.x - 1.0f, b = 2.0f * u.y - 1.0f;
  if (a == 0.0f && b == 0.0f) return {0.0f, 0.0f};
  float r, phi;
  if (std::fabs(a) > std::fabs(b)) {
    r = a;
    phi = (kPi / 4.0f) * (b / a);
  } else {
    r = b;
    phi = (kPi / 2.0f) - (kPi / 4.0f) * (a / b);
  }
  return {r * std::cos(phi), r * std::sin(phi)};
}

// Cosine-weighted hemisphere around +Z; pdf = cos(theta) / pi.
inline Vec3 sample_cosine_hemisphere(Vec2 u) {
  const Vec2 d = sample_disk_concentric(u);
  const float z = std::sqrt(std::max(0.0f, 1.0f - d.x * d.x - d.y * d.y));
  return {d.x, d.y, z};
}

// Uniform barycentrics on a triangle (Heitz 2019: area preserving, no sqrt, low distortion).
inline void sample_triangle_uniform(Vec2 u, float& b1, float& b2) {
  if (u.y > u.x) {
    b1 = u.x * 0.5f;
    b2 = u.y - b1;
  } else {
    b2 = u.y * 0.5f;
    b1 = u.x - b2;
  }
}

// Spherical triangles (Arvo 1995, "Stratified sampling of spherical triangles"): directions
// uniform in the solid angle a triangle subtends. Sampling emissive triangles this way keeps the
// estimate bounded near a light, where uniform area sampling has a 1/r^2 tail (fireflies on
// walls next to the light). Computed in double: the angles lose all precision in float when the
// triangle is small or nearly edge-on, and the extra cost is a few dozen flops per light sample.
struct DVec3 {
  double x = 0, y = 0, z = 0;
  DVec3() = default;
  DVec3(double a, double b, double c) : x(a), y(b), z(c) {}
  explicit DVec3(Vec3 v) : x(v.x), y(v.y), z(v.z) {}
  DVec3 operator+(DVec3 o) const { return {x + o.x, y + o.y, z + o.z}; }
  DVec3 operator-(DVec3 o) const { return {x - o.x, y - o.y, z - o.z}; }
  DVec3 operator*(double s) const { return {x * s, y * s, z * s}; }
  Vec3 to_float() const { return {float(x), float(y), float(z)}; }
};
inline double ddot(DVec3 a, DVec3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
inline DVec3 dcross(DVec3 a, DVec3 b) { return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x}; }
inline double dlength(DVec3 a) { return std::sqrt(ddot(a, a)); }
// Normalised, or false when v is zero (or not finite).
inline bool dnormalize(DVec3& v) {
  const double l = dlength(v);
  if (!(l > 0.0) || !std::isfinite(l)) return false;
  v = v * (1.0 / l);
  return true;
}

// Solid angle of the triangle (v0, v1, v2) seen from p (Van Oosterom & Strackee 1983); 0 when
// degenerate or p lies in its plane.
inline double spherical_triangle_solid_angle(Vec3 p, Vec3 v0, Vec3 v1, Vec3 v2) {
  DVec3 a = DVec3(v0) - DVec3(p), b = DVec3(v1) - DVec3(p), c = DVec3(v2) - DVec3(p);
  if (!dnormalize(a) || !dnormalize(b) || !dnormalize(c)) return 0.0;
  const double triple = std::fabs(ddot(a, dcross(b, c)));
  const double denom = 1.0 + ddot(a, b) + ddot(b, c) + ddot(c, a);
  const double omega = 2.0 * std::atan2(triple, denom);
  return std::isfinite(omega) && omega > 0.0 ? omega : 0.0;
}

// Angle between unit vectors, accurate for nearly (anti)parallel ones.
inline double angle_between(DVec3 a, DVec3 b) {
  if (ddot(a, b) < 0.0) return kPi - 2.0 * std::asin(std::min(1.0, 0.5 * dlength(a + b)));
  return 2.0 * std::asin(std::min(1.0, 0.5 * dlength(b - a)));
}

// A unit direction from p, uniform over the solid angle of triangle (v0, v1, v2), for u in
// [0,1)^2; false when the triangle is degenerate as seen from p. The density is
// 1 / spherical_triangle_solid_angle(p, v0, v1, v2).
inline bool sample_spherical_triangle(Vec3 p, Vec3 v0, Vec3 v1, Vec3 v2, Vec2 u, DVec3& dir) {
  DVec3 a = DVec3(v0) - DVec3(p), b = DVec3(v1) - DVec3(p), c = DVec3(v2) - DVec3(p);
  if (!dnormalize(a) || !dnormalize(b) || !dnormalize(c)) return false;
  // Normals of the great circles through the edges, and the triangle's interior angles.
  DVec3 n_ab = dcross(a, b), n_bc = dcross(b, c), n_ca = dcross(c, a);
  if (!dnormalize(n_ab) || !dnormalize(n_bc) || !dnormalize(n_ca)) return false;
  const double alpha = angle_between(n_ab, n_ca * -1.0);
  const double beta = angle_between(n_bc, n_ab * -1.0);
  const double gamma = angle_between(n_ca, n_bc * -1.0);
  // Pick the sub-triangle (a, b, c') with area u.x * A: c' lies on the arc from a to c.
  const double area_pi = alpha + beta + gamma;  // A + pi
  if (!(area_pi > kPi)) return false;
  const double sub_pi = kPi + double(u.x) * (area_pi - kPi);  // A' + pi
  const double cos_alpha = std::cos(alpha), sin_alpha = std::sin(alpha);
  const double sin_phi = std::sin(sub_pi) * cos_alpha - std::cos(sub_pi) * sin_alpha;
  const double cos_phi = std::cos(sub_pi) * cos_alpha + std::sin(sub_pi) * sin_alpha;
  const double k1 = cos_phi + cos_alpha;
  const double k2 = sin_phi - sin_alpha * ddot(a, b);
  double cos_b = (k2 + (k2 * cos_phi - k1 * sin_phi) * cos_alpha) / ((k2 * sin_phi + k1 * cos_phi) * sin_alpha);
  if (!std::isfinite(cos_b)) return false;
  cos_b = std::clamp(cos_b, -1.0, 1.0);
  const double sin_b = std::sqrt(std::max(0.0, 1.0 - cos_b * cos_b));
  DVec3 c_perp = c - a * ddot(c, a);
  if (!dnormalize(c_perp)) return false;
  const DVec3 c2 = a * cos_b + c_perp * sin_b;
  // Then uniformly in solid angle along the arc from b towards c'.
  const double cos_t = 1.0 - double(u.y) * (1.0 - ddot(c2, b));
  const double sin_t = std::sqrt(std::max(0.0, 1.0 - cos_t * cos_t));
  DVec3 c2_perp = c2 - b * ddot(c2, b);
  if (!dnormalize(c2_perp)) return false;
  dir = b * cos_t + c2_perp * sin_t;
  return dnormalize(dir);
}

inline float power_heuristic(float pdf_a, float pdf_b) {
  const float a = pdf_a * pdf_a, b = pdf_b * pdf_b;
  if (std::isinf(a)) return 1.0f;
  return a + b > 0.0f ? a / (a + b) : 0.0f;
}

// Piecewise-constant 1-D distribution over discrete items, sampled by binary search on the CDF.
class Distribution1D {
 public:
  Distribution1D() = default;
  explicit Distribution1D(const std::vector<float>& weights) {
    const size_t n = weights.size();
    cdf_.assign(n + 1, 0.0);
    pmf_.assign(n, 0.0f);
    double sum = 0.0;
    for (size_t i = 0; i < n; ++i) {
      const float w = std::isfinite(weights[i]) && weights[i] > 0.0f ? weights[i] : 0.0f;
      sum += w;
      cdf_[i + 1] = sum;
    }
    total_ = sum;
    if (sum > 0.0) {
      for (size_t i = 0; i < n; ++i) pmf_[i] = static_cast<float>((cdf_[i + 1] - cdf_[i]) / sum);
      for (size_t i = 1; i <= n; ++i) cdf_[i] /= sum;
    }
  }
  bool empty() const { return total_ <= 0.0; }
  size_t size() const { return pmf_.size(); }
  float pmf(size_t i) const { return pmf_[i]; }
  // Returns an index with probability pmf(i); `u` in [0,1).
  size_t sample(float u) const {
    const double target = u;
    size_t lo = 0, hi = pmf_.size();
    while (lo + 1 < hi) {  // largest i with cdf[i] <= u, skipping zero-weight items
      const size_t mid = (lo + hi) / 2;
      if (cdf_[mid] <= target) lo = mid; else hi = mid;
    }
    while (lo + 1 < pmf_.size() && pmf_[lo] == 0.0f) ++lo;
    return lo;
  }
  // Same, also returning u's position inside the chosen item's interval, in [0, 1).
  size_t sample(float u, float& remapped) const {
    const size_t i = sample(u);
    const double w = cdf_[i + 1] - cdf_[i];
    remapped = w > 0.0 ? static_cast<float>(std::min(0.99999994, std::max(0.0, (u - cdf_[i]) / w))) : 0.5f;
    return i;
  }

 private:
  std::vector<double> cdf_;
  std::vector<float> pmf_;
  double total_ = 0.0;
};

}  // namespace pl
