// The binned SAH split (Wald 2007) of the small builders, the top level's (tlas.cpp) and the
// curves' (curves.cpp): one axis, references binned by centroid, then the plane between bins
// of least cost (each side's box area times its count). The triangle BVH has its own,
// SIMD-vectorised builder (bvh_build_sah.cpp).
#pragma once
#include <algorithm>
#include <cstdint>
#include <vector>

#include "geometry/aabb.h"

namespace pl {

// Partitions refs[begin, end) (indices into boxes and centers) at the best of the Bins - 1
// planes between Bins bins of the centroids' range [lo, lo + ext] on `axis` (ext > 0): returns
// the right side's first position, or begin (refs untouched) when no plane leaves references
// on both sides.
template <int Bins>
uint32_t binned_sah_partition(std::vector<uint32_t>& refs, uint32_t begin, uint32_t end,
                              const std::vector<Aabb>& boxes, const std::vector<Vec3>& centers, int axis, float lo,
                              float ext) {
  const uint32_t n = end - begin;
  Aabb bin_box[Bins];
  uint32_t bin_n[Bins] = {};
  const float k = Bins * (1.0f - 1e-6f) / ext;
  auto bin_of = [&](uint32_t r) { return std::min(Bins - 1, int((centers[r][axis] - lo) * k)); };
  for (uint32_t i = begin; i < end; ++i) {
    const int bi = bin_of(refs[i]);
    bin_box[bi].grow(boxes[refs[i]]);
    ++bin_n[bi];
  }
  float right_cost[Bins] = {};
  Aabb acc;
  uint32_t cnt = 0;
  for (int i = Bins - 1; i > 0; --i) {
    acc.grow(bin_box[i]);
    cnt += bin_n[i];
    right_cost[i] = acc.half_area() * float(cnt);
  }
  acc = Aabb();
  cnt = 0;
  float best = kInf;
  int split = -1;
  for (int i = 0; i < Bins - 1; ++i) {
    acc.grow(bin_box[i]);
    cnt += bin_n[i];
    const float c = acc.half_area() * float(cnt) + right_cost[i + 1];
    if (cnt > 0 && cnt < n && c < best) {
      best = c;
      split = i;
    }
  }
  if (split < 0) return begin;
  return uint32_t(std::partition(refs.begin() + begin, refs.begin() + end,
                                 [&](uint32_t r) { return bin_of(r) <= split; }) -
                  refs.begin());
}

}  // namespace pl
