// Traversal of the wide BVH, written once over a SIMD width S (4 lanes with SSE2, 8 with AVX2)
// and a node type (float WideBvhNode or compressed QuantWideNode: only the box test differs)
// and included by bvh_traverse.cpp (4 wide, every x86-64), bvh8_avx2.cpp (8 wide, under an
// AVX2 target pragma) and bvh8_avx512.cpp (the same 8 wide as AVX-512 code, PL_WIDE_AVX512:
// mask-register comparisons). Everything here has internal linkage so the compilations never
// merge.
//
// Exactness: the box test is the binary tree's (same products, same conservative exit scale);
// the block test (four triangles; under AVX2 eight, two blocks of one leaf) is triangle.h's
// watertight test, operation for operation in lanes (no FMA, same association; it stops early
// only when no lane can pass), and its results are taken lane by lane in triangle order,
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
#include <cstring>
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
  // Four bytes as floats, and the dequantisation origin + scale * q: scale * q is exact (a
  // power of two times a byte), so a multiply and an add round once, as an FMA does.
  static V bytes(const uint8_t* p) {
    int32_t x;
    std::memcpy(&x, p, 4);
    const __m128i v = _mm_cvtsi32_si128(x);
#ifdef __SSE4_1__
    return _mm_cvtepi32_ps(_mm_cvtepu8_epi32(v));
#else
    const __m128i z = _mm_setzero_si128();
    return _mm_cvtepi32_ps(_mm_unpacklo_epi16(_mm_unpacklo_epi8(v, z), z));
#endif
  }
  static V madd(V a, V b, V c) { return _mm_add_ps(_mm_mul_ps(a, b), c); }
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
#ifdef PL_WIDE_AVX512
  // Straight into a mask register (no movemask).
  static unsigned le_mask(V a, V b) { return static_cast<unsigned>(_mm256_cmp_ps_mask(a, b, _CMP_LE_OQ)); }
#else
  static unsigned le_mask(V a, V b) {
    return static_cast<unsigned>(_mm256_movemask_ps(_mm256_cmp_ps(a, b, _CMP_LE_OQ)));
  }
#endif
  static void store(float* p, V v) { _mm256_store_ps(p, v); }
  static V bytes(const uint8_t* p) {
    return _mm256_cvtepi32_ps(_mm256_cvtepu8_epi32(_mm_loadl_epi64(reinterpret_cast<const __m128i*>(p))));
  }
  static V madd(V a, V b, V c) { return _mm256_fmadd_ps(a, b, c); }
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

  // The same on a compressed node: each plane dequantised (one FMA), then the same slab test.
  unsigned test(const QuantWideNode<S::N>& n, float tmax, float* tn) const {
    using V = typename S::V;
    const V sx = S::set1(n.scale[0]), sy = S::set1(n.scale[1]), sz = S::set1(n.scale[2]);
    const V px = S::set1(n.origin[0]), py = S::set1(n.origin[1]), pz = S::set1(n.origin[2]);
    const V tx0 = S::mul(S::sub(S::madd(sx, S::bytes(n.q[nx]), px), ox), ix);
    const V ty0 = S::mul(S::sub(S::madd(sy, S::bytes(n.q[ny]), py), oy), iy);
    const V tz0 = S::mul(S::sub(S::madd(sz, S::bytes(n.q[nz]), pz), oz), iz);
    const V tx1 = S::mul(S::sub(S::madd(sx, S::bytes(n.q[nx ^ 1]), px), ox), ix);
    const V ty1 = S::mul(S::sub(S::madd(sy, S::bytes(n.q[ny ^ 1]), py), oy), iy);
    const V tz1 = S::mul(S::sub(S::madd(sz, S::bytes(n.q[nz ^ 1]), pz), oz), iz);
    const V tmin = S::max(S::max(tx0, ty0), S::max(tz0, S::set1(0.0f)));
    const V tfar = S::mul(S::min(S::min(tx1, ty1), S::min(tz1, S::set1(tmax))), S::set1(bvh_detail::kBoxExitScale));
    S::store(tn, tmin);
    return S::le_mask(tmin, tfar) & n.valid;
  }
};

inline int lowest_bit(unsigned m) { return __builtin_ctz(m); }

#ifdef PL_WIDE_AVX512
// AVX-512VL: the block test's comparisons go straight into mask registers (k0-k7) and are
// combined there, instead of as vectors of all-ones lanes and a movemask at the end. The
// predicates are the vector ones' (the signalling forms only differ in FP flags).
#define PL_LANE_KMASKS(CMP)                                                   \
  using M = __mmask8;                                                         \
  static M eq(V a, V b) { return CMP(a, b, _CMP_EQ_OQ); }                     \
  static M lt(V a, V b) { return CMP(a, b, _CMP_LT_OS); }                     \
  static M gt(V a, V b) { return CMP(a, b, _CMP_GT_OS); }                     \
  static M mor(M a, M b) { return M(a | b); }                                 \
  static M mand(M a, M b) { return M(a & b); }                                \
  static M mandnot(M a, M b) { return M(~a & b); }                            \
  static unsigned bits(M a) { return a; }
#endif

// The watertight test's lane operations: four triangles (one block) with SSE, and under AVX2
// eight (two consecutive blocks of one leaf), the same operations lane for lane, so both give
// the scalar test's bits.
struct Lanes4 {
  static constexpr int N = 4;
  using V = __m128;
  static V row(const TriangleBlock4* b, int r) { return _mm_load_ps(b->v[r]); }
  static V set1(float x) { return _mm_set1_ps(x); }
  static V zero() { return _mm_setzero_ps(); }
  static V add(V a, V b) { return _mm_add_ps(a, b); }
  static V sub(V a, V b) { return _mm_sub_ps(a, b); }
  static V mul(V a, V b) { return _mm_mul_ps(a, b); }
  static V div(V a, V b) { return _mm_div_ps(a, b); }
  static V max(V a, V b) { return _mm_max_ps(a, b); }
  static V min(V a, V b) { return _mm_min_ps(a, b); }
  static V and_(V a, V b) { return _mm_and_ps(a, b); }
  static V or_(V a, V b) { return _mm_or_ps(a, b); }
  static V andnot(V a, V b) { return _mm_andnot_ps(a, b); }
#ifdef PL_WIDE_AVX512
  PL_LANE_KMASKS(_mm_cmp_ps_mask)
#else
  using M = V;
  static M eq(V a, V b) { return _mm_cmpeq_ps(a, b); }
  static M lt(V a, V b) { return _mm_cmplt_ps(a, b); }
  static M gt(V a, V b) { return _mm_cmpgt_ps(a, b); }
  static M mor(M a, M b) { return _mm_or_ps(a, b); }
  static M mand(M a, M b) { return _mm_and_ps(a, b); }
  static M mandnot(M a, M b) { return _mm_andnot_ps(a, b); }
  static unsigned bits(M a) { return static_cast<unsigned>(_mm_movemask_ps(a)); }
#endif
  static void store(float* p, V v) { _mm_store_ps(p, v); }
};

#ifdef PL_WIDE_AVX2
struct Lanes8 {
  static constexpr int N = 8;
  using V = __m256;
  static V row(const TriangleBlock4* b, int r) {
    return _mm256_insertf128_ps(_mm256_castps128_ps256(_mm_load_ps(b[0].v[r])), _mm_load_ps(b[1].v[r]), 1);
  }
  static V set1(float x) { return _mm256_set1_ps(x); }
  static V zero() { return _mm256_setzero_ps(); }
  static V add(V a, V b) { return _mm256_add_ps(a, b); }
  static V sub(V a, V b) { return _mm256_sub_ps(a, b); }
  static V mul(V a, V b) { return _mm256_mul_ps(a, b); }
  static V div(V a, V b) { return _mm256_div_ps(a, b); }
  static V max(V a, V b) { return _mm256_max_ps(a, b); }
  static V min(V a, V b) { return _mm256_min_ps(a, b); }
  static V and_(V a, V b) { return _mm256_and_ps(a, b); }
  static V or_(V a, V b) { return _mm256_or_ps(a, b); }
  static V andnot(V a, V b) { return _mm256_andnot_ps(a, b); }
#ifdef PL_WIDE_AVX512
  PL_LANE_KMASKS(_mm256_cmp_ps_mask)
#else
  using M = V;
  static M eq(V a, V b) { return _mm256_cmp_ps(a, b, _CMP_EQ_OQ); }
  static M lt(V a, V b) { return _mm256_cmp_ps(a, b, _CMP_LT_OS); }
  static M gt(V a, V b) { return _mm256_cmp_ps(a, b, _CMP_GT_OS); }
  static M mor(M a, M b) { return _mm256_or_ps(a, b); }
  static M mand(M a, M b) { return _mm256_and_ps(a, b); }
  static M mandnot(M a, M b) { return _mm256_andnot_ps(a, b); }
  static unsigned bits(M a) { return static_cast<unsigned>(_mm256_movemask_ps(a)); }
#endif
  static void store(float* p, V v) { _mm256_store_ps(p, v); }
};
#endif

// The per-ray constants of the watertight test, broadcast in L's lanes.
template <class L>
struct LaneConsts {
  typename L::V okx, oky, okz, sx, sy, sz;
  LaneConsts(const Ray& ray, const RayPrecomp& rp)
      : okx(L::set1(ray.org[rp.kx])),
        oky(L::set1(ray.org[rp.ky])),
        okz(L::set1(ray.org[rp.kz])),
        sx(L::set1(rp.sx)),
        sy(L::set1(rp.sy)),
        sz(L::set1(rp.sz)) {}
  LaneConsts() = default;
};

// The leaves' per-ray constants: four lanes, and under AVX2 eight (whose low halves are the
// four-lane ones, so they are broadcast once).
struct BlockRay {
  RayPrecomp rp;
#ifdef PL_WIDE_AVX2
  LaneConsts<Lanes8> c8;
  explicit BlockRay(const Ray& ray) : rp(ray.dir), c8(ray, rp) {}
  LaneConsts<Lanes4> c4() const {
    LaneConsts<Lanes4> c;
    c.okx = _mm256_castps256_ps128(c8.okx);
    c.oky = _mm256_castps256_ps128(c8.oky);
    c.okz = _mm256_castps256_ps128(c8.okz);
    c.sx = _mm256_castps256_ps128(c8.sx);
    c.sy = _mm256_castps256_ps128(c8.sy);
    c.sz = _mm256_castps256_ps128(c8.sz);
    return c;
  }
#else
  LaneConsts<Lanes4> c4_;
  explicit BlockRay(const Ray& ray) : rp(ray.dir), c4_(ray, rp) {}
  const LaneConsts<Lanes4>& c4() const { return c4_; }
#endif
};

template <int N>
struct BlockResult {
  alignas(32) float t[N], b1[N], b2[N], T[N], det[N];
  unsigned pass;    // lanes hit with 0 < t < tmax (the tmax given to block_test)
  unsigned scalar;  // lanes that need the scalar test (an edge function is exactly zero)
};

template <class L>
inline typename L::V abs_lanes(typename L::V x) {
  return L::andnot(L::set1(-0.0f), x);
}

// triangle.h's intersect_triangle on the lanes of one block (Lanes4) or of two consecutive
// ones (Lanes8), operation for operation (see it for the why of each step).
template <class L>
inline void block_test(const TriangleBlock4* b, const RayPrecomp& rp, const LaneConsts<L>& r, float tmax,
                       unsigned valid, BlockResult<L::N>& out, bool any_hit = false) {
  using V = typename L::V;
  const V Akx = L::sub(L::row(b, 0 + rp.kx), r.okx);
  const V Aky = L::sub(L::row(b, 0 + rp.ky), r.oky);
  const V Akz = L::sub(L::row(b, 0 + rp.kz), r.okz);
  const V Bkx = L::sub(L::row(b, 3 + rp.kx), r.okx);
  const V Bky = L::sub(L::row(b, 3 + rp.ky), r.oky);
  const V Bkz = L::sub(L::row(b, 3 + rp.kz), r.okz);
  const V Ckx = L::sub(L::row(b, 6 + rp.kx), r.okx);
  const V Cky = L::sub(L::row(b, 6 + rp.ky), r.oky);
  const V Ckz = L::sub(L::row(b, 6 + rp.kz), r.okz);
  const V ax = L::sub(Akx, L::mul(r.sx, Akz)), ay = L::sub(Aky, L::mul(r.sy, Akz));
  const V bx = L::sub(Bkx, L::mul(r.sx, Bkz)), by = L::sub(Bky, L::mul(r.sy, Bkz));
  const V cx = L::sub(Ckx, L::mul(r.sx, Ckz)), cy = L::sub(Cky, L::mul(r.sy, Ckz));
  const V u = L::sub(L::mul(cx, by), L::mul(cy, bx));
  const V v = L::sub(L::mul(ax, cy), L::mul(ay, cx));
  const V w = L::sub(L::mul(bx, ay), L::mul(by, ax));
  const V zero = L::zero();
  using M = typename L::M;  // comparison results: vectors of lanes, or AVX-512 mask registers
  const M any_zero = L::mor(L::mor(L::eq(u, zero), L::eq(v, zero)), L::eq(w, zero));
  const M any_neg = L::mor(L::mor(L::lt(u, zero), L::lt(v, zero)), L::lt(w, zero));
  const M any_pos = L::mor(L::mor(L::gt(u, zero), L::gt(v, zero)), L::gt(w, zero));
  const V det = L::add(L::add(u, v), w);
  const V az = L::mul(r.sz, Akz), bz = L::mul(r.sz, Bkz), cz = L::mul(r.sz, Ckz);
  const V T = L::add(L::add(L::mul(u, az), L::mul(v, bz)), L::mul(w, cz));
  const V tdet = L::mul(L::set1(tmax), det);
  const M det_pos = L::gt(det, zero);
  // det > 0: 0 < T < tmax det; otherwise (det < 0, or NaN which fails both): tmax det < T < 0.
  const M in_pos = L::mand(det_pos, L::mand(L::gt(T, zero), L::lt(T, tdet)));
  const M in_neg = L::mandnot(det_pos, L::mand(L::lt(T, zero), L::gt(T, tdet)));
  M ok = L::mandnot(L::mand(any_neg, any_pos), L::mor(in_pos, in_neg));
  ok = L::mandnot(L::eq(det, zero), ok);
  const unsigned zero_mask = L::bits(any_zero) & valid;
  out.scalar = zero_mask;
  // Most blocks a ray visits have no lane left here: skip t and its error bound (the lanes
  // they could still reject are none).
  if (!(L::bits(ok) & valid & ~zero_mask)) {
    out.pass = 0;
    return;
  }
  const V inv = L::div(L::set1(1.0f), det);
  const V t = L::mul(T, inv);
  const V max_zt = L::max(abs_lanes<L>(az), L::max(abs_lanes<L>(bz), abs_lanes<L>(cz)));
  const V max_zu = L::mul(L::max(abs_lanes<L>(Akz), L::max(abs_lanes<L>(Bkz), abs_lanes<L>(Ckz))), L::set1(rp.shear));
  const V max_xt = L::max(abs_lanes<L>(ax), L::max(abs_lanes<L>(bx), abs_lanes<L>(cx)));
  const V max_yt = L::max(abs_lanes<L>(ay), L::max(abs_lanes<L>(by), abs_lanes<L>(cy)));
  const V g2 = L::set1(gamma_bound(2)), g3 = L::set1(gamma_bound(3)), g5 = L::set1(gamma_bound(5));
  const V delta_z = L::mul(g3, max_zt);
  const V delta_x = L::mul(g5, L::add(max_xt, max_zu));
  const V delta_y = L::mul(g5, L::add(max_yt, max_zu));
  const V delta_e = L::mul(L::set1(2.0f), L::add(L::add(L::mul(L::mul(g2, max_xt), max_yt), L::mul(delta_y, max_xt)),
                                                 L::mul(delta_x, max_yt)));
  const V max_e = L::max(abs_lanes<L>(u), L::max(abs_lanes<L>(v), abs_lanes<L>(w)));
  const V delta_pbrt = L::mul(
      L::mul(L::set1(3.0f),
             L::add(L::add(L::mul(L::mul(g3, max_e), max_zt), L::mul(delta_e, max_zt)), L::mul(delta_z, max_e))),
      abs_lanes<L>(inv));
  const V spread = L::sub(L::max(az, L::max(bz, cz)), L::min(az, L::min(bz, cz)));
  const V delta_t = L::min(delta_pbrt, L::add(spread, L::mul(L::set1(gamma_bound(10)), max_zt)));
  ok = L::mand(ok, L::gt(t, delta_t));
  if (any_hit) ok = L::mand(ok, L::lt(L::add(t, delta_t), L::set1(tmax)));
  out.pass = L::bits(ok) & valid & ~zero_mask;
  if (out.pass) {
    L::store(out.t, t);
    L::store(out.b1, L::mul(v, inv));
    L::store(out.b2, L::mul(w, inv));
    L::store(out.T, T);
    L::store(out.det, det);
  }
}

// Lane l of the blocks from b (l >= 4: the next block's) through the scalar test.
inline bool lane_triangle(const TriangleBlock4* b, int l, const Ray& ray, const RayPrecomp& rp, float tmax, float& t,
                          float& b1, float& b2, bool any_hit = false) {
  const TriangleBlock4& k = b[l >> 2];
  l &= 3;
  const Vec3 v0{k.v[0][l], k.v[1][l], k.v[2][l]}, v1{k.v[3][l], k.v[4][l], k.v[5][l]},
      v2{k.v[6][l], k.v[7][l], k.v[8][l]};
  return intersect_triangle(ray.org, rp, v0, v1, v2, tmax, t, b1, b2, any_hit);
}

// Takes a block test's hits lane by lane in triangle order, updating tmax and best exactly as
// the scalar loop over those triangles would.
template <int N>
inline void take_closest(const BlockResult<N>& r, const TriangleBlock4* b, uint32_t blk, const Ray& ray,
                         const RayPrecomp& rp, float tmax_block, float& tmax, uint32_t& best, float& bb1, float& bb2) {
  unsigned lanes = r.pass | r.scalar;
  while (lanes) {
    const int l = lowest_bit(lanes);
    lanes &= lanes - 1;
    float t, b1, b2;
    if (r.scalar >> l & 1u) {
      if (!lane_triangle(b, l, ray, rp, tmax, t, b1, b2)) continue;
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

// Runs the block tests of a leaf's `count` triangles in blocks from `first`, in triangle order:
// under AVX2 two blocks at once while more than four triangles are left (lanes beyond `count`
// hold NaN and are masked off). take(result, blocks, first block, the tmax tested against)
// returns true to stop; tmax is read again before every test (take may lower it).
template <bool AnyHit, class Take>
inline bool for_each_block_test(const WideBvhView& v, uint32_t first, uint32_t count, const BlockRay& br,
                                const float& tmax, Take&& take) {
  for (uint32_t blk = first, left = count; left > 0;) {
    const TriangleBlock4* b = v.blocks + blk;
    const float tmax_block = tmax;
#ifdef PL_WIDE_AVX2
    if (left > 4) {
      BlockResult<8> r;
      block_test<Lanes8>(b, br.rp, br.c8, tmax_block, left >= 8 ? 0xFFu : (1u << left) - 1u, r, AnyHit);
      if (take(r, b, blk, tmax_block)) return true;
      blk += 2;
      left = left >= 8 ? left - 8 : 0;
      continue;
    }
#endif
    BlockResult<4> r;
    block_test<Lanes4>(b, br.rp, br.c4(), tmax_block, left >= 4 ? 0xFu : (1u << left) - 1u, r, AnyHit);
    if (take(r, b, blk, tmax_block)) return true;
    blk += 1;
    left = left >= 4 ? left - 4 : 0;
  }
  return false;
}

// The closest hit among a leaf's triangles, updating tmax and best exactly as the scalar loop
// over them in order would.
inline void leaf_closest(const WideBvhView& v, uint32_t first, uint32_t count, const Ray& ray, const BlockRay& br,
                         float& tmax, uint32_t& best, float& bb1, float& bb2) {
  for_each_block_test<false>(v, first, count, br, tmax,
                             [&](const auto& r, const TriangleBlock4* b, uint32_t blk, float tmax_block) {
                               take_closest(r, b, blk, ray, br.rp, tmax_block, tmax, best, bb1, bb2);
                               return false;
                             });
}

template <int N>
inline bool any_of(const BlockResult<N>& r, const TriangleBlock4* b, const Ray& ray, const RayPrecomp& rp, float tmax) {
  if (r.pass) return true;
  for (unsigned lanes = r.scalar; lanes; lanes &= lanes - 1) {
    float t, b1, b2;
    if (lane_triangle(b, lowest_bit(lanes), ray, rp, tmax, t, b1, b2, /*any_hit=*/true)) return true;
  }
  return false;
}

inline bool leaf_any(const WideBvhView& v, uint32_t first, uint32_t count, const Ray& ray, const BlockRay& br,
                     float tmax) {
  return for_each_block_test<true>(v, first, count, br, tmax,
                                   [&](const auto& r, const TriangleBlock4* b, uint32_t, float) {
                                     return any_of(r, b, ray, br.rp, tmax);
                                   });
}

template <class S, class Node = WideBvhNode<S::N>>
bool wide_intersect(const WideBvhView& v, const Ray& ray, Hit& hit, TraversalCounters* counters) {
  constexpr int N = S::N;
  const auto* nodes = static_cast<const Node*>(v.nodes);
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
      const Node& n = nodes[ref];
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
        // Go to the nearest hit child; push the others farthest first, so they pop nearest first.
        const int j0 = lowest_bit(mask);
        mask &= mask - 1;
        if (!mask) {  // two (the usual case): one comparison, ordering ties as the sort below does
          const int nr = tn[i] < tn[j0] ? i : j0, fr = nr == i ? j0 : i;
          stack[sp++] = {n.child[fr], n.count[fr], tn[fr]};
          ref = n.child[nr];
          count = n.count[nr];
          continue;
        }
        // Three or more: insertion sort straight onto the stack (no copy), nearest on top.
        const int base = sp;
        stack[sp++] = {n.child[i], n.count[i], tn[i]};
        mask |= 1u << j0;
        while (mask) {
          i = lowest_bit(mask);
          mask &= mask - 1;
          const WideEntry x{n.child[i], n.count[i], tn[i]};
          int j = sp++;
          for (; j > base && stack[j - 1].t < x.t; --j) stack[j] = stack[j - 1];
          stack[j] = x;
        }
        --sp;
        ref = stack[sp].ref;
        count = stack[sp].count;
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

template <class S, class Node = WideBvhNode<S::N>>
bool wide_occluded(const WideBvhView& v, const Ray& ray) {
  constexpr int N = S::N;
  const auto* nodes = static_cast<const Node*>(v.nodes);
  const WideRay<S> wr(ray);
  const BlockRay br(ray);
  const float tmax = ray.tmax;
  WideEntry stack[kWideStackSize];
  int sp = 0;
  uint32_t ref = 0, count = 0;
  alignas(32) float tn[N];
  for (;;) {
    if (count == 0) {
      const Node& n = nodes[ref];
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
