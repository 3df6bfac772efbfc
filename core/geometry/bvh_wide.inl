// Traversal of the wide BVH, written once over a SIMD width S (4 lanes with SSE2, 8 with AVX2)
// and included by bvh.cpp (4 wide, every x86-64) and bvh8_avx2.cpp (8 wide, under an AVX2
// target pragma). Everything here has internal linkage so the two compilations never merge.
//
// Exactness: the box test is the binary tree's (same products, same conservative exit scale);
// the four-triangle test is triangle.h's watertight test, operation for operation in lanes
// (no FMA, same association), and its results are taken lane by lane in triangle order,
// re-checking each against the closest hit so far exactly as the scalar loop would; lanes whose
// edge functions round to zero go through the scalar test itself (its double fallback).
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

// The per-ray constants of the watertight test, in lanes.
struct BlockRay {
  RayPrecomp rp;
  __m128 okx, oky, okz, sx, sy, sz;
  explicit BlockRay(const Ray& ray) : rp(ray.dir) {
    okx = _mm_set1_ps(ray.org[rp.kx]);
    oky = _mm_set1_ps(ray.org[rp.ky]);
    okz = _mm_set1_ps(ray.org[rp.kz]);
    sx = _mm_set1_ps(rp.sx);
    sy = _mm_set1_ps(rp.sy);
    sz = _mm_set1_ps(rp.sz);
  }
};

struct BlockResult {
  alignas(16) float t[4], b1[4], b2[4], T[4], det[4];
  unsigned pass;    // lanes hit with 0 < t < tmax (the tmax given to block_test)
  unsigned scalar;  // lanes that need the scalar test (an edge function is exactly zero)
};

inline __m128 abs4(__m128 x) { return _mm_andnot_ps(_mm_set1_ps(-0.0f), x); }

// triangle.h's intersect_triangle on the four lanes of a block (see it for the why of each step).
inline void block_test(const TriangleBlock4& b, const BlockRay& r, float tmax, unsigned valid, BlockResult& out,
                       bool any_hit = false) {
  const RayPrecomp& rp = r.rp;
  const __m128 Akx = _mm_sub_ps(_mm_load_ps(b.v[0 + rp.kx]), r.okx);
  const __m128 Aky = _mm_sub_ps(_mm_load_ps(b.v[0 + rp.ky]), r.oky);
  const __m128 Akz = _mm_sub_ps(_mm_load_ps(b.v[0 + rp.kz]), r.okz);
  const __m128 Bkx = _mm_sub_ps(_mm_load_ps(b.v[3 + rp.kx]), r.okx);
  const __m128 Bky = _mm_sub_ps(_mm_load_ps(b.v[3 + rp.ky]), r.oky);
  const __m128 Bkz = _mm_sub_ps(_mm_load_ps(b.v[3 + rp.kz]), r.okz);
  const __m128 Ckx = _mm_sub_ps(_mm_load_ps(b.v[6 + rp.kx]), r.okx);
  const __m128 Cky = _mm_sub_ps(_mm_load_ps(b.v[6 + rp.ky]), r.oky);
  const __m128 Ckz = _mm_sub_ps(_mm_load_ps(b.v[6 + rp.kz]), r.okz);
  const __m128 ax = _mm_sub_ps(Akx, _mm_mul_ps(r.sx, Akz)), ay = _mm_sub_ps(Aky, _mm_mul_ps(r.sy, Akz));
  const __m128 bx = _mm_sub_ps(Bkx, _mm_mul_ps(r.sx, Bkz)), by = _mm_sub_ps(Bky, _mm_mul_ps(r.sy, Bkz));
  const __m128 cx = _mm_sub_ps(Ckx, _mm_mul_ps(r.sx, Ckz)), cy = _mm_sub_ps(Cky, _mm_mul_ps(r.sy, Ckz));
  const __m128 u = _mm_sub_ps(_mm_mul_ps(cx, by), _mm_mul_ps(cy, bx));
  const __m128 v = _mm_sub_ps(_mm_mul_ps(ax, cy), _mm_mul_ps(ay, cx));
  const __m128 w = _mm_sub_ps(_mm_mul_ps(bx, ay), _mm_mul_ps(by, ax));
  const __m128 zero = _mm_setzero_ps();
  const __m128 any_zero = _mm_or_ps(_mm_or_ps(_mm_cmpeq_ps(u, zero), _mm_cmpeq_ps(v, zero)), _mm_cmpeq_ps(w, zero));
  const __m128 any_neg = _mm_or_ps(_mm_or_ps(_mm_cmplt_ps(u, zero), _mm_cmplt_ps(v, zero)), _mm_cmplt_ps(w, zero));
  const __m128 any_pos = _mm_or_ps(_mm_or_ps(_mm_cmpgt_ps(u, zero), _mm_cmpgt_ps(v, zero)), _mm_cmpgt_ps(w, zero));
  const __m128 det = _mm_add_ps(_mm_add_ps(u, v), w);
  const __m128 az = _mm_mul_ps(r.sz, Akz), bz = _mm_mul_ps(r.sz, Bkz), cz = _mm_mul_ps(r.sz, Ckz);
  const __m128 T = _mm_add_ps(_mm_add_ps(_mm_mul_ps(u, az), _mm_mul_ps(v, bz)), _mm_mul_ps(w, cz));
  const __m128 tdet = _mm_mul_ps(_mm_set1_ps(tmax), det);
  const __m128 det_pos = _mm_cmpgt_ps(det, zero);
  // det > 0: 0 < T < tmax det; otherwise (det < 0, or NaN which fails both): tmax det < T < 0.
  const __m128 in_pos = _mm_and_ps(det_pos, _mm_and_ps(_mm_cmpgt_ps(T, zero), _mm_cmplt_ps(T, tdet)));
  const __m128 in_neg = _mm_andnot_ps(det_pos, _mm_and_ps(_mm_cmplt_ps(T, zero), _mm_cmpgt_ps(T, tdet)));
  __m128 ok = _mm_andnot_ps(_mm_and_ps(any_neg, any_pos), _mm_or_ps(in_pos, in_neg));
  ok = _mm_andnot_ps(_mm_cmpeq_ps(det, zero), ok);
  const __m128 inv = _mm_div_ps(_mm_set1_ps(1.0f), det);
  const __m128 t = _mm_mul_ps(T, inv);
  const __m128 max_zt = _mm_max_ps(abs4(az), _mm_max_ps(abs4(bz), abs4(cz)));
  const __m128 max_xt = _mm_max_ps(abs4(ax), _mm_max_ps(abs4(bx), abs4(cx)));
  const __m128 max_yt = _mm_max_ps(abs4(ay), _mm_max_ps(abs4(by), abs4(cy)));
  const __m128 g2 = _mm_set1_ps(gamma_bound(2)), g3 = _mm_set1_ps(gamma_bound(3)), g5 = _mm_set1_ps(gamma_bound(5));
  const __m128 delta_z = _mm_mul_ps(g3, max_zt);
  const __m128 delta_x = _mm_mul_ps(g5, _mm_add_ps(max_xt, max_zt));
  const __m128 delta_y = _mm_mul_ps(g5, _mm_add_ps(max_yt, max_zt));
  const __m128 delta_e = _mm_mul_ps(
      _mm_set1_ps(2.0f), _mm_add_ps(_mm_add_ps(_mm_mul_ps(_mm_mul_ps(g2, max_xt), max_yt), _mm_mul_ps(delta_y, max_xt)),
                                    _mm_mul_ps(delta_x, max_yt)));
  const __m128 max_e = _mm_max_ps(abs4(u), _mm_max_ps(abs4(v), abs4(w)));
  const __m128 delta_t = _mm_mul_ps(
      _mm_mul_ps(_mm_set1_ps(3.0f), _mm_add_ps(_mm_add_ps(_mm_mul_ps(_mm_mul_ps(g3, max_e), max_zt),
                                                          _mm_mul_ps(delta_e, max_zt)),
                                               _mm_mul_ps(delta_z, max_e))),
      abs4(inv));
  ok = _mm_and_ps(ok, _mm_cmpgt_ps(t, delta_t));
  if (any_hit) ok = _mm_and_ps(ok, _mm_cmplt_ps(_mm_add_ps(t, delta_t), _mm_set1_ps(tmax)));
  const unsigned zero_mask = static_cast<unsigned>(_mm_movemask_ps(any_zero)) & valid;
  out.scalar = zero_mask;
  out.pass = static_cast<unsigned>(_mm_movemask_ps(ok)) & valid & ~zero_mask;
  if (out.pass) {
    _mm_store_ps(out.t, t);
    _mm_store_ps(out.b1, _mm_mul_ps(v, inv));
    _mm_store_ps(out.b2, _mm_mul_ps(w, inv));
    _mm_store_ps(out.T, T);
    _mm_store_ps(out.det, det);
  }
}

inline bool lane_triangle(const TriangleBlock4& b, int l, const Ray& ray, const RayPrecomp& rp, float tmax, float& t,
                          float& b1, float& b2, bool any_hit = false) {
  const Vec3 v0{b.v[0][l], b.v[1][l], b.v[2][l]}, v1{b.v[3][l], b.v[4][l], b.v[5][l]},
      v2{b.v[6][l], b.v[7][l], b.v[8][l]};
  return intersect_triangle(ray.org, rp, v0, v1, v2, tmax, t, b1, b2, any_hit);
}

// The closest hit among a leaf's `count` triangles in blocks from `first`, updating tmax and
// best exactly as the scalar loop over them in order would.
inline void leaf_closest(const WideBvhView& v, uint32_t first, uint32_t count, const Ray& ray, const BlockRay& br,
                         float& tmax, uint32_t& best, float& bb1, float& bb2) {
  for (uint32_t blk = first, left = count; left > 0; ++blk) {
    const unsigned valid = left >= 4 ? 0xFu : (1u << left) - 1u;
    left = left >= 4 ? left - 4 : 0;
    BlockResult r;
    const float tmax_block = tmax;
    block_test(v.blocks[blk], br, tmax_block, valid, r);
    unsigned lanes = r.pass | r.scalar;
    while (lanes) {
      const int l = lowest_bit(lanes);
      lanes &= lanes - 1;
      float t, b1, b2;
      if (r.scalar >> l & 1u) {
        if (!lane_triangle(v.blocks[blk], l, ray, br.rp, tmax, t, b1, b2)) continue;
      } else {
        // Passed against tmax_block; an earlier lane may have lowered tmax since.
        if (tmax != tmax_block && !(r.det[l] > 0.0f ? r.T[l] < tmax * r.det[l] : r.T[l] > tmax * r.det[l])) continue;
        t = r.t[l];
        b1 = r.b1[l];
        b2 = r.b2[l];
      }
      tmax = t;
      best = blk * 4 + uint32_t(l);
      bb1 = b1;
      bb2 = b2;
    }
  }
}

inline bool leaf_any(const WideBvhView& v, uint32_t first, uint32_t count, const Ray& ray, const BlockRay& br,
                     float tmax) {
  for (uint32_t blk = first, left = count; left > 0; ++blk) {
    const unsigned valid = left >= 4 ? 0xFu : (1u << left) - 1u;
    left = left >= 4 ? left - 4 : 0;
    BlockResult r;
    block_test(v.blocks[blk], br, tmax, valid, r, /*any_hit=*/true);
    if (r.pass) return true;
    for (unsigned lanes = r.scalar; lanes; lanes &= lanes - 1) {
      float t, b1, b2;
      if (lane_triangle(v.blocks[blk], lowest_bit(lanes), ray, br.rp, tmax, t, b1, b2, /*any_hit=*/true)) return true;
    }
  }
  return false;
}

template <class S>
bool wide_intersect(const WideBvhView& v, const Ray& ray, Hit& hit, TraversalCounters* counters) {
  constexpr int N = S::N;
  const auto* nodes = static_cast<const WideBvhNode<N>*>(v.nodes);
  const WideRay<S> wr(ray);
  const BlockRay br(ray);
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
      leaf_closest(v, ref, count, ray, br, tmax, best, bb1, bb2);
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
  hit.prim = v.block_prims[best];
  return true;
}

template <class S>
bool wide_occluded(const WideBvhView& v, const Ray& ray) {
  constexpr int N = S::N;
  const auto* nodes = static_cast<const WideBvhNode<N>*>(v.nodes);
  const WideRay<S> wr(ray);
  const BlockRay br(ray);
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
      if (leaf_any(v, ref, count, ray, br, tmax)) return true;
    }
    if (sp == 0) return false;
    --sp;
    ref = stack[sp].ref;
    count = stack[sp].count;
  }
}

}  // namespace
}  // namespace pl
