// The 4-wide trees of curves and points (curves.cpp, points.cpp): a binary tree collapsed into
// WideBvhNode<4> and the per-ray slab test of a node's 4 lanes. Not for bvh8_avx2.cpp: these
// have external linkage, and an AVX2 copy must never be linked into code for other CPUs
// (bvh_common.h).
#pragma once
#include <cstdint>
#include <vector>

#if defined(__SSE2__)
#include <immintrin.h>
#endif

#include "geometry/bvh_common.h"

namespace pl {
namespace bvh_detail {

// The binary tree collapsed into 4-wide nodes (the top level's rule: the largest interior
// child opened first while lanes are free).
inline uint32_t collapse_wide4(const std::vector<BvhNode>& bin, uint32_t b, std::vector<WideBvhNode<4>>& out) {
  uint32_t kids[4];
  const int n = bvh_detail::gather_wide_children(bin.data(), b, kids, 4);
  const uint32_t w = uint32_t(out.size());
  out.emplace_back();
  for (int k = 0; k < 4; ++k) {
    for (int r = 0; r < 3; ++r) {
      out[w].bounds[2 * r][k] = kInf;
      out[w].bounds[2 * r + 1][k] = -kInf;
    }
    out[w].child[k] = 0;
    out[w].count[k] = 0;
  }
  for (int k = 0; k < n; ++k) {
    const BvhNode& c = bin[kids[k]];
    for (int r = 0; r < 3; ++r) {
      out[w].bounds[2 * r][k] = c.lo[r];
      out[w].bounds[2 * r + 1][k] = c.hi[r];
    }
    if (c.is_leaf()) {
      out[w].child[k] = c.left_or_first;
      out[w].count[k] = c.count;
    } else {
      const uint32_t ci = collapse_wide4(bin, kids[k], out);
      out[w].child[k] = ci;
    }
  }
  return w;
}

// The 4 lanes' entry distances and the mask of those entered before tmax: the slab test with
// near and far planes picked by the direction's signs (as the top level's), conservative exit.
struct LaneTest4 {
  int near[3], far[3];
  float org[3], inv[3];
  LaneTest4(const Ray& r, const Vec3& iv) {
    for (int a = 0; a < 3; ++a) {
      org[a] = r.org[a];
      inv[a] = iv[a];
      near[a] = iv[a] < 0.0f ? 2 * a + 1 : 2 * a;
      far[a] = near[a] ^ 1;
    }
  }
  unsigned test(const WideBvhNode<4>& n, float tmax, float* dist) const {
#if defined(__SSE2__)
    __m128 tmin = _mm_setzero_ps(), tfar = _mm_set1_ps(tmax);
    for (int a = 0; a < 3; ++a) {
      const __m128 o = _mm_set1_ps(org[a]), iv = _mm_set1_ps(inv[a]);
      tmin = _mm_max_ps(_mm_mul_ps(_mm_sub_ps(_mm_load_ps(n.bounds[near[a]]), o), iv), tmin);
      tfar = _mm_min_ps(_mm_mul_ps(_mm_sub_ps(_mm_load_ps(n.bounds[far[a]]), o), iv), tfar);
    }
    tfar = _mm_mul_ps(tfar, _mm_set1_ps(bvh_detail::kBoxExitScale));
    _mm_storeu_ps(dist, tmin);
    return unsigned(_mm_movemask_ps(_mm_cmple_ps(tmin, tfar)));
#else
    unsigned mask = 0;
    for (int k = 0; k < 4; ++k) {
      float t0 = 0.0f, t1 = tmax;
      for (int a = 0; a < 3; ++a) {
        const float x0 = (n.bounds[near[a]][k] - org[a]) * inv[a], x1 = (n.bounds[far[a]][k] - org[a]) * inv[a];
        t0 = x0 > t0 ? x0 : t0;
        t1 = x1 < t1 ? x1 : t1;
      }
      dist[k] = t0;
      if (t0 <= t1 * bvh_detail::kBoxExitScale) mask |= 1u << k;
    }
    return mask;
#endif
  }
};

}  // namespace bvh_detail
}  // namespace pl
