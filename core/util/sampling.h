// Warps from the unit square and small Monte Carlo helpers.
#pragma once
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
