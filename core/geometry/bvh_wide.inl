// Traversal of the wide BVH, written once over a SIMD width S (4 lanes with SSE2, 8 with AVX2)
// and included by bvh.cpp (4 wide, every x86-64) and bvh8_avx2.cpp (8 wide, under an AVX2
// target pragma). Everything here has internal linkage so the two compilations never merge.
//
// Exactness: the box test is the binary tree's (same products, same conservative exit scale);
// it picks the near and far planes by the sign of the inverse direction, which gives the same
// values as the binary tree's min/max of the two planes since lo <= hi and the rounding of
// (p - o) * inv is monotonic in p. Triangles use the same scalar watertight test. A box is
// only skipped when its entry is at or beyond the closest hit so far, as in the binary tree,
// so both report the same closest triangle (up to exact ties in t).
#include <immintrin.h>

#include <algorithm>
#include <cstdint>
#include <utility>

#include "geometry/bvh.h"
#include "geometry/bvh_common.h"
#include "geometry/triangle.h"

namespace pl {
namespace {

// std::min(a, b) is (b < a) ? b : a and _mm_min_ps(x, y) is (x < y) ? x : y, so the operands
// are swapped to keep std::min's NaN behaviour (likewise for max).
struct Sse4 {
  static constexpr int N = 4;
  using V = __m128;
  static V load(const float* p) { return _mm_load_ps(p); }
  static V set1(float x) { return _mm_set1_ps(x); }
  static V sub(V a, V b) { return _mm_sub_ps(a, b); }
  static V mul(V a, V b) { return _mm_mul_ps(a, b); }
  static V min(V a, V b) { return _mm_min_ps(b, a); }
  static V max(V a, V b) { return _mm_max_ps(b, a); }
  static unsigned le_mask(V a, V b) { return static_cast<unsigned>(_mm_movemask_ps(_mm_cmple_ps(a, b))); }
  static void store(float* p, V v) { _mm_store_ps(p, v); }
};

#ifdef PL_WIDE_AVX2
struct Avx8 {
  static constexpr int N = 8;
  using V = __m256;
  static V load(const float* p) { return _mm256_load_ps(p); }
  static V set1(float x) { return _mm256_set1_ps(x); }
  static V sub(V a, V b) { return _mm256_sub_ps(a, b); }
  static V mul(V a, V b) { return _mm256_mul_ps(a, b); }
  static V min(V a, V b) { return _mm256_min_ps(b, a); }
  static V max(V a, V b) { return _mm256_max_ps(b, a); }
  static unsigned le_mask(V a, V b) {
    return static_cast<unsigned>(_mm256_movemask_ps(_mm256_cmp_ps(a, b, _CMP_LE_OQ)));
  }
  static void store(float* p, V v) { _mm256_store_ps(p, v); }
};
#endif

// Depth of the wide tree is at most the binary tree's (< 100 levels, see bvh.cpp), and each
// level pushes at most N - 1 entries.
constexpr int kWideStackSize = 1024;

struct WideEntry {
  uint32_t ref;    // node index, or first triangle
  uint32_t count;  // 0: interior node; else a leaf of `count` triangles
  float t;         // entry distance of its box
};

template <class S>
struct WideRay {
  typename S::V ox, oy, oz, ix, iy, iz;
  int nx, ny, nz;  // rows of the near planes (the far ones are nx ^ 1, ...)

  explicit WideRay(const Ray& ray) {
    const Vec3 inv = bvh_detail::safe_inverse(ray.dir);
    ox = S::set1(ray.org.x);
    oy = S::set1(ray.org.y);
    oz = S::set1(ray.org.z);
    ix = S::set1(inv.x);
    iy = S::set1(inv.y);
    iz = S::set1(inv.z);
    nx = inv.x >= 0.0f ? 0 : 1;
    ny = inv.y >= 0.0f ? 2 : 3;
    nz = inv.z >= 0.0f ? 4 : 5;
  }

  // Mask of the children whose box the ray enters before tmax; their entry distances in tn.
  unsigned test(const WideBvhNode<S::N>& n, float tmax, float* tn) const {
    using V = typename S::V;
    const V tx0 = S::mul(S::sub(S::load(n.bounds[nx]), ox), ix);
    const V ty0 = S::mul(S::sub(S::load(n.bounds[ny]), oy), iy);
    const V tz0 = S::mul(S::sub(S::load(n.bounds[nz]), oz), iz);
    const V tx1 = S::mul(S::sub(S::load(n.bounds[nx ^ 1]), ox), ix);
    const V ty1 = S::mul(S::sub(S::load(n.bounds[ny ^ 1]), oy), iy);
    const V tz1 = S::mul(S::sub(S::load(n.bounds[nz ^ 1]), oz), iz);
    const V tmin = S::max(S::max(tx0, ty0), S::max(tz0, S::set1(0.0f)));
    const V tfar = S::mul(S::min(S::min(tx1, ty1), S::min(tz1, S::set1(tmax))), S::set1(bvh_detail::kBoxExitScale));
    S::store(tn, tmin);
    return S::le_mask(tmin, tfar);
  }
};

inline int lowest_bit(unsigned m) { return __builtin_ctz(m); }

template <class S>
bool wide_intersect(const WideBvhView& v, const Ray& ray, Hit& hit, TraversalCounters* counters) {
  constexpr int N = S::N;
  const auto* nodes = static_cast<const WideBvhNode<N>*>(v.nodes);
  const WideRay<S> wr(ray);
  const RayPrecomp rp(ray.dir);
  float tmax = ray.tmax;
  uint32_t best = UINT32_MAX;
  float bb1 = 0.0f, bb2 = 0.0f;
  WideEntry stack[kWideStackSize];
  int sp = 0;
  uint32_t ref = 0, count = 0;  // the root is always an interior node
  alignas(32) float tn[N];
  for (;;) {
    if (count == 0) {
      const WideBvhNode<N>& n = nodes[ref];
      if (counters) counters->nodes++;
      unsigned mask = wr.test(n, tmax, tn);
      if (mask) {
        int i = lowest_bit(mask);
        mask &= mask - 1;
        if (!mask) {  // one child: no sorting
          ref = n.child[i];
          count = n.count[i];
          continue;
        }
        // Push the others farthest first so the nearest is popped first; go to the nearest.
        WideEntry e[N];
        int k = 0;
        e[k++] = {n.child[i], n.count[i], tn[i]};
        while (mask) {
          i = lowest_bit(mask);
          mask &= mask - 1;
          WideEntry x{n.child[i], n.count[i], tn[i]};
          int j = k++;
          for (; j > 0 && e[j - 1].t < x.t; --j) e[j] = e[j - 1];
          e[j] = x;
        }
        for (int j = 0; j < k - 1; ++j) stack[sp++] = e[j];
        ref = e[k - 1].ref;
        count = e[k - 1].count;
        continue;
      }
    } else {
      for (uint32_t i = ref, end = ref + count; i < end; ++i) {
        const TriangleVerts& tv = v.tris[i];
        float t, b1, b2;
        if (intersect_triangle(ray.org, rp, tv.v0, tv.v1, tv.v2, tmax, t, b1, b2)) {
          tmax = t;
          best = i;
          bb1 = b1;
          bb2 = b2;
        }
      }
      if (counters) counters->triangles += count;
    }
    // Pop the next box that can still hold a closer hit.
    do {
      if (sp == 0) goto done;
      --sp;
    } while (stack[sp].t >= tmax);
    ref = stack[sp].ref;
    count = stack[sp].count;
  }
done:
  if (best == UINT32_MAX) return false;
  hit.t = tmax;
  hit.b1 = bb1;
  hit.b2 = bb2;
  hit.prim = v.prim_ids[best];
  return true;
}

template <class S>
bool wide_occluded(const WideBvhView& v, const Ray& ray) {
  constexpr int N = S::N;
  const auto* nodes = static_cast<const WideBvhNode<N>*>(v.nodes);
  const WideRay<S> wr(ray);
  const RayPrecomp rp(ray.dir);
  const float tmax = ray.tmax;
  WideEntry stack[kWideStackSize];
  int sp = 0;
  uint32_t ref = 0, count = 0;
  alignas(32) float tn[N];
  for (;;) {
    if (count == 0) {
      const WideBvhNode<N>& n = nodes[ref];
      unsigned mask = wr.test(n, tmax, tn);
      if (mask) {
        // Any order finds an occluder; the nearest child first tends to find it sooner.
        int i = lowest_bit(mask);
        mask &= mask - 1;
        WideEntry first{n.child[i], n.count[i], tn[i]};
        while (mask) {
          i = lowest_bit(mask);
          mask &= mask - 1;
          WideEntry x{n.child[i], n.count[i], tn[i]};
          if (x.t < first.t) std::swap(x, first);
          stack[sp++] = x;
        }
        ref = first.ref;
        count = first.count;
        continue;
      }
    } else {
      for (uint32_t i = ref, end = ref + count; i < end; ++i) {
        const TriangleVerts& tv = v.tris[i];
        float t, b1, b2;
        if (intersect_triangle(ray.org, rp, tv.v0, tv.v1, tv.v2, tmax, t, b1, b2)) return true;
      }
    }
    if (sp == 0) return false;
    --sp;
    ref = stack[sp].ref;
    count = stack[sp].count;
  }
}

}  // namespace
}  // namespace pl
