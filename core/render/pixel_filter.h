// Pixel reconstruction filter by importance sampling (as Cycles' film filter): each sample's
// position in its pixel is drawn from the filter's profile, separably in x and y, and every
// sample keeps weight 1, so the film stays a plain running mean. Profiles and widths follow
// Cycles (scene/film.cpp): box of `width` pixels; Gaussian with sigma width/4, cut at
// +-1.5 width; Blackman-Harris over +-width.
#pragma once
#include <algorithm>
#include <cmath>
#include <vector>

#include "util/math.h"

namespace pl {

enum class FilterType { Box, Gaussian, BlackmanHarris };

class PixelFilter {
 public:
  PixelFilter(FilterType type = FilterType::Box, float width = 1.0f) : type_(type), width_(width) {
    if (type_ == FilterType::Box) return;
    radius_ = type_ == FilterType::Gaussian ? 1.5f * width_ : width_;
    // Forward CDF of the half profile on a fine grid (bin midpoints); inverted per sample
    // by binary search, so the tails get their exact share (an inverse-CDF table would not).
    cdf_.resize(kBins + 1);
    cdf_[0] = 0.0f;
    double sum = 0.0;
    for (int i = 0; i < kBins; ++i) {
      sum += std::max(0.0, profile((i + 0.5) / kBins * radius_));
      cdf_[size_t(i) + 1] = float(sum);
    }
    for (float& c : cdf_) c = sum > 0.0 ? float(c / sum) : 0.0f;
    cdf_[kBins] = 1.0f;
    // guide_[k]: the first CDF entry (from 1) >= k / kGuide, so the search for v in
    // [k, k + 1) / kGuide only spans guide_[k] .. guide_[k + 1] (the same answer).
    guide_.resize(kGuide + 1);
    for (int k = 0; k <= kGuide; ++k)
      guide_[size_t(k)] = int(std::lower_bound(cdf_.begin() + 1, cdf_.end(), float(k) / float(kGuide)) - cdf_.begin());
    guide_[kGuide] = kBins;  // v = 1 (u = 0) searches to the end, as the full search does
  }

  FilterType type() const { return type_; }
  float width() const { return width_; }
  // Half the footprint: a sample lands at most this far (in x and in y) from its pixel's centre.
  float radius() const { return type_ == FilterType::Box ? 0.5f * width_ : radius_; }
  // The density (per pixel) of a sample's offset d from its pixel's centre along one axis, as
  // jitter draws it: the CDF's bins are uniform within, so it is the bin's share over its
  // width (half of it on each side). The 2-D density is density(dx) density(dy); caustic
  // light paths splat with it, and the path tracer's MIS uses the same.
  float density(float d) const {
    const float a = std::fabs(d);
    if (type_ == FilterType::Box) return a <= 0.5f * width_ ? 1.0f / width_ : 0.0f;
    if (!(a < radius_)) return 0.0f;
    const int i = std::min(int(a / radius_ * float(kBins)), kBins - 1);
    return 0.5f * (cdf_[size_t(i) + 1] - cdf_[size_t(i)]) * float(kBins) / radius_;
  }
  // Position of a sample in its pixel (0..1 is the pixel itself, 0.5 its centre) for a
  // uniform u in [0, 1). The 1-pixel box gives u itself, bit for bit.
  float jitter(float u) const {
    if (type_ == FilterType::Box) return 0.5f + (u - 0.5f) * width_;
    // The sign from u's half, the distance from the rest of it (keeps stratification).
    const float v = std::min(std::fabs(2.0f * u - 1.0f), 1.0f);
    const int g = std::min(int(v * float(kGuide)), kGuide - 1);
    const auto it = std::upper_bound(cdf_.begin() + guide_[size_t(g)],
                                     cdf_.begin() + std::min(guide_[size_t(g) + 1] + 1, kBins + 1), v);
    const int i = std::min(int(it - cdf_.begin()) - 1, kBins - 1);
    const float c0 = cdf_[size_t(i)], c1 = cdf_[size_t(i) + 1];
    const float t = c1 > c0 ? std::clamp((v - c0) / (c1 - c0), 0.0f, 1.0f) : 0.5f;
    const float r = (float(i) + t) / float(kBins) * radius_;
    return u < 0.5f ? 0.5f - r : 0.5f + r;
  }

 private:
  static constexpr int kBins = 2048;
  static constexpr int kGuide = 2048;  // a power of two (exact k / kGuide); as fine as the bins: ~1 search step
  // Cycles' profiles as functions of the distance from the pixel centre, in pixels.
  double profile(double x) const {
    if (type_ == FilterType::Gaussian) {
      const double v = x * 2.0 / width_;  // Cycles: v * 6 / (3 width)
      return std::exp(-2.0 * v * v);
    }
    const double v = 2.0 * kPi * (x / (2.0 * width_) + 0.5);
    return 0.35875 - 0.48829 * std::cos(v) + 0.14128 * std::cos(2.0 * v) - 0.01168 * std::cos(3.0 * v);
  }

  FilterType type_;
  float width_;
  float radius_ = 0.5f;
  std::vector<float> cdf_;
  std::vector<int> guide_;
};

}  // namespace pl
