// The BVH builder's internals, shared by its files (none of this is API): the SIMD boxes and
// triangle references the binned SAH moves around, and the Builder, whose parts are in
// bvh_build_sah.cpp (the binned SAH: the binary tree), bvh_build_clusters.cpp (the clustered
// build's Morton runs) and bvh_spatial_split.cpp (SBVH); collapse() (bvh_collapse.cpp) turns
// its tree into a wide one. Inline functions with external linkage: include it only from code
// compiled with the library's own flags (never from bvh8_avx2.cpp).
#pragma once
#include <algorithm>
#include <atomic>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <new>
#include <thread>
#include <type_traits>
#include <vector>
#if defined(__SSE2__)
#include <emmintrin.h>
#endif
#if defined(__AVX__)
#include <immintrin.h>
#endif

#include "geometry/aabb.h"
#include "geometry/bvh.h"
#include "util/big_alloc.h"

namespace pl {
namespace bvh_detail {

constexpr int kMaxBins = 64;
constexpr uint32_t kParallelMin = 16384;  // subtrees smaller than this are built serially
constexpr uint32_t kChunkMin = 65536;     // fewest triangles per thread when one node is binned by several
// Clustered build: the most triangles in a Morton run, and the node size (in triangles) at which
// the SAH over the runs stops and the SAH over triangles takes over. Measured on bench_rays' 1M
// scene and a 1M height field (K = 4..32, T = 0..48): smaller runs or a larger T are slower,
// larger runs cost quality.
constexpr uint32_t kClusterSize = 8;
constexpr uint32_t kClusterLeafMax = 24;

// Clamped before the cast: a float outside int's range (or NaN) must never become an index.
// The SIMD binning below computes exactly this per lane.
inline int bin_of(float c, float lo, float scale, int bins) {
  const float f = (c - lo) * scale;
  return f > 0.0f ? (f < float(bins - 1) ? static_cast<int>(f) : bins - 1) : 0;
}

// Four floats in one SSE register (x, y, z and an unused lane); plain floats elsewhere.
#if defined(__SSE2__)
struct V4 {
  __m128 v;
  static V4 load(const float* p) { return {_mm_load_ps(p)}; }
  static V4 set1(float f) { return {_mm_set1_ps(f)}; }
  static V4 set(float x, float y, float z) { return {_mm_setr_ps(x, y, z, 0.0f)}; }
  void store(float* p) const { _mm_store_ps(p, v); }
  // Lane 3 of a PrimRef holds its id bits (a denormal as a float): cleared before arithmetic.
  V4 xyz() const { return {_mm_and_ps(v, _mm_castsi128_ps(_mm_setr_epi32(-1, -1, -1, 0)))}; }
  friend V4 operator+(V4 a, V4 b) { return {_mm_add_ps(a.v, b.v)}; }
  friend V4 operator-(V4 a, V4 b) { return {_mm_sub_ps(a.v, b.v)}; }
  friend V4 operator*(V4 a, V4 b) { return {_mm_mul_ps(a.v, b.v)}; }
  // NaN in a: b (as _mm_min_ps / _mm_max_ps), which the bin clamp relies on.
  friend V4 vmin(V4 a, V4 b) { return {_mm_min_ps(a.v, b.v)}; }
  friend V4 vmax(V4 a, V4 b) { return {_mm_max_ps(a.v, b.v)}; }
  // Whether a > b in any of lanes 0-2 (an empty box when a = lo, b = hi).
  static bool any_gt_xyz(V4 a, V4 b) { return (_mm_movemask_ps(_mm_cmpgt_ps(a.v, b.v)) & 7) != 0; }
  // bin_of() on each lane: clamp to [0, bins - 1] (NaN -> 0), then truncate.
  // Returns them packed too, lane k in byte k (bins < 256), packed in registers: reading the
  // stored ints back to pack them waited on the store.
  uint32_t bins(V4 lo, V4 scale, V4 top, int out[4]) const {
    const __m128 f = _mm_mul_ps(_mm_sub_ps(v, lo.v), scale.v);
    const __m128i i = _mm_cvttps_epi32(_mm_min_ps(_mm_max_ps(f, _mm_setzero_ps()), top.v));
    _mm_storeu_si128(reinterpret_cast<__m128i*>(out), i);
    const __m128i w = _mm_packs_epi32(i, i);
    return uint32_t(_mm_cvtsi128_si32(_mm_packus_epi16(w, w)));
  }
};
#else
struct V4 {
  float f[4];
  static V4 load(const float* p) { return {{p[0], p[1], p[2], p[3]}}; }
  static V4 set1(float x) { return {{x, x, x, x}}; }
  static V4 set(float x, float y, float z) { return {{x, y, z, 0.0f}}; }
  void store(float* p) const { for (int i = 0; i < 4; ++i) p[i] = f[i]; }
  V4 xyz() const { return {{f[0], f[1], f[2], 0.0f}}; }
  template <class Op>
  static V4 map(V4 a, V4 b, Op op) { return {{op(a.f[0], b.f[0]), op(a.f[1], b.f[1]), op(a.f[2], b.f[2]), op(a.f[3], b.f[3])}}; }
  friend V4 operator+(V4 a, V4 b) { return map(a, b, [](float x, float y) { return x + y; }); }
  friend V4 operator-(V4 a, V4 b) { return map(a, b, [](float x, float y) { return x - y; }); }
  friend V4 operator*(V4 a, V4 b) { return map(a, b, [](float x, float y) { return x * y; }); }
  friend V4 vmin(V4 a, V4 b) { return map(a, b, [](float x, float y) { return x < y ? x : y; }); }
  friend V4 vmax(V4 a, V4 b) { return map(a, b, [](float x, float y) { return x > y ? x : y; }); }
  static bool any_gt_xyz(V4 a, V4 b) { return a.f[0] > b.f[0] || a.f[1] > b.f[1] || a.f[2] > b.f[2]; }
  uint32_t bins(V4 lo, V4 scale, V4 top, int out[4]) const {
    for (int i = 0; i < 3; ++i) out[i] = bin_of(f[i], lo.f[i], scale.f[i], static_cast<int>(top.f[i]) + 1);
    return uint32_t(out[0]) | uint32_t(out[1]) << 8 | uint32_t(out[2]) << 16;
  }
};
#endif

// A triangle's box and input index, moved (not pointed to) by the partitions: every binning
// pass then reads memory in order. 32 bytes; lo and hi load as one SIMD register each.
struct alignas(16) PrimRef {
  Vec3 lo;
  uint32_t id;
  Vec3 hi;
  // The centroid's bin on x, y, z (one byte each, bits 0-23) in the node binned last: the
  // binning pass writes it, so the partition that follows compares a byte instead of
  // recomputing the bin. Bits 24-31: the triangles the reference stands for (1, or up to a
  // leaf block for a cluster of the clustered build), which the SAH counts.
  uint32_t bins;
  uint32_t weight() const { return bins >> 24; }
  V4 vlo() const { return V4::load(&lo.x).xyz(); }
  V4 vhi() const { return V4::load(&hi.x).xyz(); }
  // (lo + hi) / 2 would overflow near FLT_MAX.
  V4 centroid() const { return vlo() * V4::set1(0.5f) + vhi() * V4::set1(0.5f); }
};

// Box and centroid box accumulated in SIMD registers; lanes 0-2 are x, y, z.
struct BoxAcc {
  V4 lo = V4::set1(kInf), hi = V4::set1(-kInf);
  void grow(V4 l, V4 h) { lo = vmin(lo, l); hi = vmax(hi, h); }
  void grow(const BoxAcc& b) { grow(b.lo, b.hi); }
  Aabb aabb() const {
    alignas(16) float l[4], h[4];
    lo.store(l);
    hi.store(h);
    return {{l[0], l[1], l[2]}, {h[0], h[1], h[2]}};
  }
};

// Half the surface area of the box (lo, hi), the same arithmetic as Aabb::half_area() on a
// non-empty box, so SIMD accumulation picks the same splits as the scalar code did.
inline float half_area(V4 lo, V4 hi) {
#if defined(__SSE2__)
  // In registers (a store and three loads waited on the store): e0 e1 + e1 e2 + e2 e0, summed
  // in that order as below.
  const __m128 e = _mm_sub_ps(hi.v, lo.v);
  const __m128 p = _mm_mul_ps(e, _mm_shuffle_ps(e, e, _MM_SHUFFLE(3, 0, 2, 1)));
  const __m128 s = _mm_add_ss(p, _mm_shuffle_ps(p, p, _MM_SHUFFLE(1, 1, 1, 1)));
  return _mm_cvtss_f32(_mm_add_ss(s, _mm_movehl_ps(p, p)));
#else
  alignas(16) float e[4];
  (hi - lo).store(e);
  return e[0] * e[1] + e[1] * e[2] + e[2] * e[0];
#endif
}

// Where chunk c of `chunks` equal chunks of [0, n) starts (c = chunks: n).
inline uint32_t chunk_start(uint32_t n, int c, int chunks) {
  return uint32_t(uint64_t(n) * uint32_t(c) / uint32_t(chunks));
}

// Runs fn(chunk) for chunk in [0, chunks) on that many threads (this one included).
template <class F>
void run_chunks(int chunks, F&& fn) {
  std::vector<std::thread> threads;
  threads.reserve(chunks > 0 ? chunks - 1 : 0);
  for (int c = 1; c < chunks; ++c) threads.emplace_back([&fn, c] { fn(c); });
  fn(0);
  for (std::thread& t : threads) t.join();
}

// Raw storage for arrays the builder writes in full before reading: no pass that zeroes them
// first, and their pages are first touched by the (parallel) code that fills them.
struct FreeRaw {
  void operator()(void* p) const { big_free(p); }
};
template <class T>
std::unique_ptr<T[], FreeRaw> raw_array(size_t n) {
  static_assert(std::is_trivially_copyable_v<T>, "raw storage holds trivially copyable types only");
  static_assert(alignof(T) <= alignof(std::max_align_t), "big_alloc aligns to max_align_t");
  std::unique_ptr<T[], FreeRaw> p(static_cast<T*>(big_alloc(std::max<size_t>(1, n) * sizeof(T))));
  if (!p) throw std::bad_alloc();
  return p;
}

// Filled in bvh_build_sah.cpp and bvh_spatial_split.cpp.
struct BinSet;
struct SpatialBinSet;

// Builds the binary tree of binned SAH splits over a span of triangles (Wald 2007), optionally
// over Morton runs first (make_clusters) or with spatial splits (spatial_split).
class Builder {
 public:
  Builder(TriangleSpan tris, const BvhBuildOptions& opt, std::vector<uint32_t>& order);
  bool run();

  size_t spatial_splits() const { return spatial_splits_.load(); }
  size_t clusters() const { return clusters_; }

  // The binary tree (root at 0; children of an interior node side by side), valid after run().
  // Reached through child indices only: subtrees built apart sit in separate pools with
  // unused (unwritten) slots between them, so the node_count() nodes are spread over more
  // slots than that.
  const BvhNode* nodes() const { return node_store_.get(); }
  size_t node_count() const { return n_nodes_; }

  size_t max_depth() const { return max_depth_; }

 private:
  // The clustered build (bvh_build_clusters.cpp).
  void make_clusters();
  bool refine_clusters();

  // Triangle tests of a leaf of n triangles (n / block rounded up: a partial block costs a whole one).
  float tests(uint32_t n) const {
    return static_cast<float>(block_shift_ >= 0 ? (n + block_ - 1) >> block_shift_ : (n + block_ - 1) / block_);
  }

  bool cancelled() const { return opt_.cancel && opt_.cancel->load(std::memory_order_relaxed); }

  // Threads that share the work on one node of n triangles at `depth`: only near the root,
  // where fewer subtrees than threads are being built at once.
  int chunk_count(uint32_t n, int depth) const {
    const int idle = depth < 30 ? std::max(1, hw_ >> depth) : 1;
    return std::max(1, std::min<int>(idle, static_cast<int>(n / kChunkMin)));
  }

  void range_bounds(uint32_t begin, uint32_t end, Aabb& bounds, Aabb& cbounds) const {
    BoxAcc b, cb;
    for (uint32_t i = begin; i < end; ++i) {
      b.grow(refs_[i].vlo(), refs_[i].vhi());
      const V4 c = refs_[i].centroid();
      cb.grow(c, c);
    }
    bounds = b.aabb();
    cbounds = cb.aabb();
  }

  struct Split {
    uint32_t mid;
    Aabb lb, lcb, rb, rcb;  // bounds and centroid bounds of both sides
    // Spatial splits: where the children's references now lie ([lbegin, lend) and [rbegin,
    // rend)) and the end of each one's spare slots. Object splits leave placed false (left
    // [begin, mid), right [mid, end)) and build() hands out the spare slots.
    bool placed = false;
    uint32_t lbegin, lend, lcap, rbegin, rend, rcap;
    uint32_t lt, rt;  // triangles of each side (the references' weights summed)
  };

  struct Built {
    int depth;       // the subtree's deepest level
    uint32_t nodes;  // its nodes, root included
  };

  // The binned SAH (bvh_build_sah.cpp).
  static uint32_t pack_bins(uint32_t packed, uint32_t old);
  void make_leaf(BvhNode& node, uint32_t begin, uint32_t end);
  void place(Split& sp, uint32_t begin, uint32_t end, uint32_t cap_end);
  Built build(uint32_t node_index, uint32_t begin, uint32_t end, uint32_t cap_end, int depth, const Aabb& bounds,
              const Aabb& cbounds, uint32_t nt, uint32_t& next);
  uint32_t weight_sum(uint32_t begin, uint32_t end) const;
  bool split_by_count(uint32_t begin, uint32_t end, Split& sp) const;
  void bin_one(PrimRef& r, V4 lo, V4 scale, V4 top, BinSet& bins);
  void bin_range(uint32_t begin, uint32_t end, V4 lo, V4 scale, V4 top, int B, BinSet& bins);
  bool split(const Aabb& bounds, const Aabb& cbounds, uint32_t begin, uint32_t end, uint32_t cap_end, int depth,
             uint32_t nt, Split& sp);

  // Spatial splits (bvh_spatial_split.cpp).
  void span(const PrimRef& r, int axis, float lo, float scale, int& first, int& last) const;
  void spatial_bin_range(uint32_t begin, uint32_t end, const float lo[3], const float scale[3], const float step[3],
                         SpatialBinSet& sb) const;
  bool spatial_split(const Aabb& bounds, uint32_t begin, uint32_t end, uint32_t cap_end, int depth, float to_beat,
                     Split& sp);

  BvhBuildOptions opt_;
  std::vector<uint32_t>& order_;
  TriangleSpan tris_;
  bool spatial_ = false;
  uint32_t cap_ = 0;                // reference slots: triangles plus the duplicate budget
  float spatial_min_area_ = 0.0f;   // alpha x the root's half area
  std::atomic<size_t> spatial_splits_{0};
  std::unique_ptr<PrimRef[], FreeRaw> refs_;
  size_t n_refs_ = 0;
  uint32_t n_tris_ = 0;  // triangles under the root (n_refs_ without clusters)
  uint32_t pending_max_ = 0;  // while building over the runs: nodes of this many triangles or fewer become leaves (refined later)
  bool clustered_ = false;                          // refs_ are Morton runs (make_clusters)
  size_t clusters_ = 0;                             // Morton runs made (0: full SAH)
  std::unique_ptr<PrimRef[], FreeRaw> tri_refs_;    // while clustered: the triangles' references, run after run
  std::vector<uint32_t> cluster_first_;             // run k: tri_refs_[first[k], first[k + 1])
  std::unique_ptr<BvhNode[], FreeRaw> node_store_;  // the node pools (constructor); those used are all written
  Aabb root_bounds_, root_cbounds_;
  size_t n_nodes_ = 0;  // nodes in the tree (the pools' used slots)
  size_t max_depth_ = 0;
  int parallel_depth_ = 0;
  int hw_ = 1;
  uint32_t block_ = 1;
  int block_shift_ = -1;  // log2(block_) when it is a power of two
};

// Collapses the binary tree into an N-wide one (bvh_collapse.cpp, where it is described):
// float nodes (Node = WideBvhNode<N>) or compressed ones (QuantWideNode<N>). Instantiated
// there for the 4- and 8-wide nodes of both kinds.
template <int N, class Node>
bool collapse(const BvhNode* bin, size_t n_bin, TriangleSpan tris, const std::vector<uint32_t>& prim_ids, int threads,
              RawVector<Node>& out, RawVector<TriangleBlock4>& blocks, RawVector<uint32_t>& block_prims);

}  // namespace bvh_detail
}  // namespace pl
