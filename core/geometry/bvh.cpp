#include "geometry/bvh.h"

#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstring>
#include <cstdlib>
#include <functional>
#include <memory>
#include <new>
#include <thread>
#include <type_traits>
#if defined(__SSE2__)
#include <emmintrin.h>
#endif
#if defined(__AVX__)
#include <immintrin.h>
#endif

#include "geometry/bvh_common.h"
#include "geometry/triangle.h"
#include "util/parallel.h"
#if defined(__x86_64__) || defined(__i386__)
#include "geometry/bvh_wide.inl"
#endif

namespace pl {
namespace {

using bvh_detail::intersect_node;
using bvh_detail::safe_inverse;

constexpr int kMaxBins = 64;
constexpr int kStackSize = 128;
// Beyond this depth splits are by count (halving), which adds at most 32 more levels, so
// traversal stacks of kStackSize entries never overflow.
constexpr int kMaxDepth = 64;
constexpr uint32_t kParallelMin = 16384;  // subtrees smaller than this are built serially
constexpr uint32_t kChunkMin = 65536;     // fewest triangles per thread when one node is binned by several
constexpr uint32_t kSmallNode = 32;       // nodes this small clear and sweep only the bins they use
constexpr uint32_t kCopyPartition = 256;  // nodes this small are partitioned through a stack buffer
constexpr uint32_t kAlternateBins = 1024; // ranges this big are binned into two sets alternately
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

// A bin's box. With AVX one register holds lo and -hi, so growing it is one min instead of a
// min and a max: -max(a, b) = min(-a, -b) bit for bit (also for NaN, where both return the
// second operand, and for zeros of either sign), so the boxes are those of the pair.
#if defined(__AVX__)
struct BinBox {
  __m256 v;
  static __m128 sign() { return _mm_set1_ps(-0.0f); }
  static BinBox empty() { return {_mm256_set1_ps(kInf)}; }  // lo = +inf, -hi = +inf
  static BinBox of(V4 l, V4 h) { return {_mm256_insertf128_ps(_mm256_castps128_ps256(l.v), _mm_xor_ps(h.v, sign()), 1)}; }
  void grow(BinBox b) { v = _mm256_min_ps(v, b.v); }
  V4 lo() const { return {_mm256_castps256_ps128(v)}; }
  V4 hi() const { return {_mm_xor_ps(_mm256_extractf128_ps(v, 1), sign())}; }
};
#else
struct BinBox {
  V4 l, h;
  static BinBox empty() { return {V4::set1(kInf), V4::set1(-kInf)}; }
  static BinBox of(V4 lo, V4 hi) { return {lo, hi}; }
  void grow(BinBox b) {
    l = vmin(l, b.l);
    h = vmax(h, b.h);
  }
  V4 lo() const { return l; }
  V4 hi() const { return h; }
};
#endif

// The bins of all three axes, filled in one pass over a range of triangles. Not initialised on
// construction: reset() clears only the bins in use (small nodes are many, their bins few).
// Cache-line aligned: the root's chunks bin into neighbouring BinSets on different threads.
struct alignas(64) BinSet {
  BinBox box[3][kMaxBins];
  uint32_t count[3][kMaxBins];
  void reset(int bins) {
    for (int a = 0; a < 3; ++a)
      for (int b = 0; b < bins; ++b) {
        box[a][b] = BinBox::empty();
        count[a][b] = 0;
      }
  }
  void merge(const BinSet& o, int bins) {
    for (int a = 0; a < 3; ++a)
      for (int b = 0; b < bins; ++b) {
        box[a][b].grow(o.box[a][b]);
        count[a][b] += o.count[a][b];
      }
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

// The bins of a spatial split (Stich et al. 2009) on all three axes: each bin's box holds the
// parts of the triangles inside its slab; entry / exit count the references starting / ending
// in it.
struct SpatialBinSet {
  V4 lo[3][kMaxBins], hi[3][kMaxBins];
  uint32_t entry[3][kMaxBins], exit[3][kMaxBins];
  void reset(int bins) {
    for (int a = 0; a < 3; ++a)
      for (int b = 0; b < bins; ++b) {
        lo[a][b] = V4::set1(kInf);
        hi[a][b] = V4::set1(-kInf);
        entry[a][b] = exit[a][b] = 0;
      }
  }
  void merge(const SpatialBinSet& o, int bins) {
    for (int a = 0; a < 3; ++a)
      for (int b = 0; b < bins; ++b) {
        lo[a][b] = vmin(lo[a][b], o.lo[a][b]);
        hi[a][b] = vmax(hi[a][b], o.hi[a][b]);
        entry[a][b] += o.entry[a][b];
        exit[a][b] += o.exit[a][b];
      }
  }
};

inline float round_down(double d) {
  const float f = static_cast<float>(d);
  return std::nextafter(static_cast<double>(f) > d ? std::nextafter(f, -kInf) : f, -kInf);
}
inline float round_up(double d) {
  const float f = static_cast<float>(d);
  return std::nextafter(static_cast<double>(f) < d ? std::nextafter(f, kInf) : f, kInf);
}

// The box of the part of the triangle with plo <= x[axis] <= phi, intersected with `box` (the
// reference's box). The real triangle is clipped (in double, then rounded outwards one ulp
// more than needed), so the box always contains that part of it: a hit in it is never culled
// by the slab tests. Empty (lo > hi) when nothing of the triangle is left.
Aabb clip_triangle(const TriangleVerts& t, int axis, float plo, float phi, const Aabb& box) {
  const Vec3* v[3] = {&t.v0, &t.v1, &t.v2};
  double lo[3] = {kInf, kInf, kInf}, hi[3] = {-kInf, -kInf, -kInf};
  const auto grow = [&](const double p[3]) {
    for (int k = 0; k < 3; ++k) {
      lo[k] = std::min(lo[k], p[k]);
      hi[k] = std::max(hi[k], p[k]);
    }
  };
  for (int i = 0; i < 3; ++i) {
    const Vec3& a = *v[i];
    const Vec3& b = *v[i == 2 ? 0 : i + 1];
    const double pa[3] = {a.x, a.y, a.z}, pb[3] = {b.x, b.y, b.z};
    if (pa[axis] >= plo && pa[axis] <= phi) grow(pa);
    for (const float q : {plo, phi}) {
      if (!std::isfinite(q)) continue;
      const double da = pa[axis] - q, db = pb[axis] - q;
      if (!((da < 0 && db > 0) || (da > 0 && db < 0))) continue;  // the edge does not cross the plane
      const double s = da / (da - db);
      double p[3];
      for (int k = 0; k < 3; ++k) p[k] = pa[k] + s * (pb[k] - pa[k]);
      p[axis] = q;
      grow(p);
    }
  }
  Aabb r;
  if (!(lo[0] <= hi[0] && lo[1] <= hi[1] && lo[2] <= hi[2])) return r;  // empty (or NaN)
  r.lo = vmax(Vec3(round_down(lo[0]), round_down(lo[1]), round_down(lo[2])), box.lo);
  r.hi = vmin(Vec3(round_up(hi[0]), round_up(hi[1]), round_up(hi[2])), box.hi);
  if (std::isfinite(plo)) r.lo[axis] = std::max(r.lo[axis], plo);
  if (std::isfinite(phi)) r.hi[axis] = std::min(r.hi[axis], phi);
  if (r.lo.x > r.hi.x || r.lo.y > r.hi.y || r.lo.z > r.hi.z) return Aabb();
  return r;
}

class Builder {
 public:
  Builder(TriangleSpan tris, const BvhBuildOptions& opt, std::vector<uint32_t>& order)
      : opt_(opt), order_(order), tris_(tris) {
    opt_.bins = std::clamp(opt_.bins, 2, kMaxBins);
    opt_.max_leaf_size = std::clamp(opt_.max_leaf_size, 1, 255);
    block_ = static_cast<uint32_t>(std::clamp(opt_.leaf_block, 1, 16));
    for (int k = 0; k < 5; ++k)
      if (block_ == 1u << k) block_shift_ = k;
    hw_ = std::max(1, opt.threads > 0 ? opt.threads : static_cast<int>(std::thread::hardware_concurrency()));
    // Four times as many subtrees as threads, so an unbalanced split leaves no core idle for long;
    // none on one thread (threads = 1 must not start any).
    parallel_depth_ = 0;
    if (hw_ > 1)
      while ((1 << parallel_depth_) < 4 * hw_) ++parallel_depth_;
    const uint32_t n = static_cast<uint32_t>(tris.size());
    // With spatial splits, room for the duplicates: each subtree gets a share of the spare slots
    // after its references, so the budget holds without a shared counter.
    spatial_ = opt_.spatial_splits && n > 1;
    const double extra = spatial_ ? std::clamp(double(opt_.max_duplicates), 0.0, 4.0) * n : 0.0;
    cap_ = uint32_t(std::min<double>(double(n) + std::floor(extra), double(UINT32_MAX / 2)));
    if (cap_ == n) spatial_ = false;
    refs_ = raw_array<PrimRef>(cap_);
    n_refs_ = n;
    n_tris_ = n;
    // The references and the root's boxes, in parallel chunks merged in a fixed order.
    const int chunks = chunk_count(n, 0);
    std::vector<BoxAcc> b(chunks), cb(chunks);
    run_chunks(chunks, [&](int c) {
      const uint32_t lo = chunk_start(n, c, chunks), hi = chunk_start(n, c + 1, chunks);
      // Boxes in locals, stored once: the chunks' accumulators share a cache line, and the
      // reference stores may alias them (__m128 may alias floats), so growing them in place
      // wrote that line on every triangle from both threads (2.5x slower than one thread).
      BoxAcc box, cbox;
      for (uint32_t i = lo; i < hi; ++i) {
        const TriangleVerts& t = tris[i];
        PrimRef& r = refs_[i];
        r.lo = vmin(vmin(t.v0, t.v1), t.v2);
        r.hi = vmax(vmax(t.v0, t.v1), t.v2);
        r.id = i;
        r.bins = 1u << 24;  // weight 1
        box.grow(r.vlo(), r.vhi());
        const V4 ct = r.centroid();
        cbox.grow(ct, ct);
      }
      b[c] = box;
      cb[c] = cbox;
    });
    for (int c = 1; c < chunks; ++c) {
      b[0].grow(b[c]);
      cb[0].grow(cb[c]);
    }
    root_bounds_ = b.empty() ? Aabb() : b[0].aabb();
    root_cbounds_ = cb.empty() ? Aabb() : cb[0].aabb();
    // A subtree of c reference slots has at most 2c - 2 nodes below its root (build()'s node
    // pools): the root's pool ends at 2 cap_ - 1. The clustered build's second phase builds
    // under the first phase's leaves in pools after its nodes, 2t - 2 slots for a leaf of t
    // triangles: at most 2 n_tris_ - 2 more. Nodes used are all written; the gaps between
    // pools are never read, so the storage is left uninitialised (no pass over it first).
    // (Under 2^30 triangles: the clustered build's pools take up to 2 (n + runs) 32-bit indices.)
    if (opt_.morton_clusters && !spatial_ && n > kClusterLeafMax && n < (1u << 30)) make_clusters();
    node_store_ = raw_array<BvhNode>(2 * size_t(std::max<size_t>(cap_, n_tris_)) + (clustered_ ? 2 * size_t(cap_) : 0));
    spatial_min_area_ = std::max(0.0f, opt_.spatial_alpha) * root_bounds_.half_area();
  }

  // Returns false when cancelled (the nodes are then incomplete and must be dropped).
  bool run() {
    uint32_t next = 1;  // the root's pool: [1, 2 cap_ - 1)
    const Built root = build(0, 0, static_cast<uint32_t>(n_refs_), cap_, 0, root_bounds_, root_cbounds_, n_tris_, next);
    max_depth_ = size_t(root.depth);
    n_nodes_ = root.nodes;
    if (cancelled()) return false;
    if (clustered_ && !refine_clusters()) return false;
    if (!spatial_) {
      order_.reserve(n_refs_);
      advise_huge_pages(order_.data(), n_refs_ * sizeof(uint32_t));
      order_.resize(n_refs_);
      parallel_ranges(n_refs_, hw_, [&](size_t lo, size_t hi) {
        for (size_t i = lo; i < hi; ++i) order_[i] = refs_[i].id;
      }, 131072);
    } else {
      // Leaves are spread over the reference array with spare slots between subtrees: packed
      // here in depth-first order.
      order_.clear();
      std::vector<uint32_t> stack{0};
      while (!stack.empty()) {
        BvhNode& nd = node_store_[stack.back()];
        stack.pop_back();
        if (nd.is_leaf()) {
          const uint32_t first = static_cast<uint32_t>(order_.size());
          for (uint32_t i = nd.left_or_first; i < nd.left_or_first + nd.count; ++i) order_.push_back(refs_[i].id);
          nd.left_or_first = first;
        } else {
          stack.push_back(nd.left_or_first + 1);
          stack.push_back(nd.left_or_first);
        }
      }
      order_.shrink_to_fit();
    }
    refs_.reset();
    return true;
  }

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
  // Morton code of a point's cell on a 1024^3 grid: its 10-bit coordinates interleaved.
  static uint32_t morton3(const int q[4]) {
    const auto spread = [](uint32_t x) {
      x = (x | x << 16) & 0x030000FFu;
      x = (x | x << 8) & 0x0300F00Fu;
      x = (x | x << 4) & 0x030C30C3u;
      return (x | x << 2) & 0x09249249u;
    };
    return spread(uint32_t(q[0])) << 2 | spread(uint32_t(q[1])) << 1 | spread(uint32_t(q[2]));
  }

  // The clustered build's first phase (as the bottom of an HLBVH, Pantaleoni & Luebke 2010):
  // the references sorted by the Morton code of their centroid (30 bits, LSD radix sort, stable
  // so equal codes keep input order), then cut top-down at the highest differing code bit (by
  // count where all codes are equal) into runs of at most one leaf block of triangles. Each run
  // becomes one reference (its triangles' box, weight = its triangle count) for the binned SAH,
  // which then bins ~3x fewer references per level and never splits a run: leaves are whole
  // runs. Where triangles are small against their neighbourhood (tessellated surfaces) a run
  // is what the SAH's bottom levels would have made anyway.
  void make_clusters() {
    const uint32_t n = static_cast<uint32_t>(n_refs_);
    const uint32_t C = kClusterSize;
    // Cubic cells (one scale for all axes): a flat scene's thin axis must not get as many cells
    // as its long ones, or its noise would order the curve.
    const float ext = max_component(root_cbounds_.extent());
    const float inv = ext > 0.0f && std::isfinite(ext) ? 1024.0f / ext : 0.0f;
    const V4 lo = V4::set(root_cbounds_.lo.x, root_cbounds_.lo.y, root_cbounds_.lo.z);
    const V4 scale = V4::set1(inv), top = V4::set1(1023.0f);
    // Keys: code << 32 | input position; sorted on bits 32-61, 10 at a time.
    auto keys = raw_array<uint64_t>(n), tmp = raw_array<uint64_t>(n);
    const int chunks = chunk_count(n, 0);
    std::vector<std::array<std::array<uint32_t, 1024>, 3>> part(chunks);
    run_chunks(chunks, [&](int c) {
      auto& h = part[c];
      for (auto& row : h) row.fill(0);
      const uint32_t b = chunk_start(n, c, chunks), e = chunk_start(n, c + 1, chunks);
      alignas(16) int q[4];
      for (uint32_t i = b; i < e; ++i) {
        refs_[i].centroid().bins(lo, scale, top, q);  // clamped to the grid, NaN -> 0
        const uint32_t code = morton3(q);
        keys[i] = uint64_t(code) << 32 | i;
        h[0][code & 1023]++;
      }
    });
    // Each pass scatters on all threads: chunk c of the current order writes its keys of digit
    // k from the keys of digits below k (all chunks) plus those of digit k in chunks before c,
    // so the sort stays stable and its result the same on any thread count. Pass 0's chunk
    // histograms come from the code pass above; the later ones are counted over the new order.
    for (int p = 0; p < 3; ++p) {
      if (cancelled()) return;
      const int shift = 32 + 10 * p;
      if (p > 0)
        run_chunks(chunks, [&](int c) {
          auto& h = part[c][p];
          h.fill(0);
          const uint32_t b = chunk_start(n, c, chunks), e = chunk_start(n, c + 1, chunks);
          for (uint32_t i = b; i < e; ++i) h[(keys[i] >> shift) & 1023]++;
        });
      uint32_t sum = 0;
      for (int k = 0; k < 1024; ++k)
        for (int c = 0; c < chunks; ++c) {
          const uint32_t cnt = part[c][p][k];
          part[c][p][k] = sum;  // now chunk c's first slot for digit k
          sum += cnt;
        }
      run_chunks(chunks, [&](int c) {
        auto& off = part[c][p];
        const uint32_t b = chunk_start(n, c, chunks), e = chunk_start(n, c + 1, chunks);
        for (uint32_t i = b; i < e; ++i) {
          const uint64_t k = keys[i];
          tmp[off[(k >> shift) & 1023]++] = k;
        }
      });
      std::swap(keys, tmp);
    }
    if (cancelled()) return;
    // Runs, in order: cut [b, e) at its highest differing code bit until it fits one block.
    // A range's cuts depend on that range alone, so the top ranges are cut here, breadth-first
    // and kept in order, until there are enough to share out; each is then cut down to runs on
    // whichever thread takes it, and the runs are joined in order: the same runs on any thread
    // count.
    const uint64_t* k = keys.get();
    const auto cut = [k](uint32_t b, uint32_t e) {
      const uint32_t c0 = uint32_t(k[b] >> 32), c1 = uint32_t(k[e - 1] >> 32);
      if (c0 == c1) return b + (e - b) / 2;
      const uint32_t bit = 31u - uint32_t(__builtin_clz(c0 ^ c1));
      return uint32_t(std::partition_point(k + b, k + e, [bit](uint64_t x) { return !((x >> (32 + bit)) & 1); }) - k);
    };
    using Range = std::pair<uint32_t, uint32_t>;
    std::vector<Range> tops{{0u, n}};
    const size_t want = hw_ > 1 && n >= kParallelMin ? 16 * size_t(hw_) : 1;
    for (bool again = true; again && tops.size() < want;) {
      again = false;
      std::vector<Range> next;
      for (const auto& [b, e] : tops) {
        if (e - b <= C) {
          next.push_back({b, e});
          continue;
        }
        const uint32_t mid = cut(b, e);
        next.push_back({b, mid});
        next.push_back({mid, e});
        again = true;
      }
      tops.swap(next);
    }
    std::vector<std::vector<uint32_t>> runs(tops.size());
    std::atomic<size_t> next_range{0};
    run_chunks(tops.size() > 1 ? hw_ : 1, [&](int) {
      std::vector<Range> stack;
      for (size_t r; (r = next_range.fetch_add(1)) < tops.size();) {
        std::vector<uint32_t>& out = runs[r];
        out.reserve((tops[r].second - tops[r].first) / 2 + 1);
        stack.assign(1, tops[r]);
        while (!stack.empty()) {
          const auto [b, e] = stack.back();
          stack.pop_back();
          if (e - b <= C) {
            out.push_back(b);
            continue;
          }
          const uint32_t mid = cut(b, e);
          stack.push_back({mid, e});
          stack.push_back({b, mid});
        }
      }
    });
    std::vector<uint32_t> first;
    size_t total = 1;
    for (const auto& r : runs) total += r.size();
    first.reserve(total);
    for (const auto& r : runs) first.insert(first.end(), r.begin(), r.end());
    const uint32_t m = static_cast<uint32_t>(first.size());
    first.push_back(n);
    if (cancelled()) return;
    // One reference per run; the triangles' references copied in sorted order, so a run's
    // members are read back as one contiguous piece.
    auto crefs = raw_array<PrimRef>(m);
    auto sorted = raw_array<PrimRef>(n);
    const int cchunks = chunk_count(m, 0);
    std::vector<BoxAcc> cb(cchunks);
    run_chunks(cchunks, [&](int c) {
      const uint32_t b = chunk_start(m, c, cchunks), e = chunk_start(m, c + 1, cchunks);
      BoxAcc cbox;  // stored once (as the root's boxes above)
      for (uint32_t k = b; k < e; ++k) {
        BoxAcc box;
        for (uint32_t j = first[k]; j < first[k + 1]; ++j) {
          const PrimRef& r = refs_[uint32_t(keys[j])];
          box.grow(r.vlo(), r.vhi());
          sorted[j] = r;
        }
        PrimRef& cr = crefs[k];
        box.lo.store(&cr.lo.x);  // lane 3 lands on id, set next
        box.hi.store(&cr.hi.x);
        cr.id = k;
        cr.bins = (first[k + 1] - first[k]) << 24;
        const V4 ct = cr.centroid();
        cbox.grow(ct, ct);
      }
      cb[c] = cbox;
    });
    for (int c = 1; c < cchunks; ++c) cb[0].grow(cb[c]);
    root_cbounds_ = cb[0].aabb();
    cluster_first_ = std::move(first);
    tri_refs_ = std::move(sorted);
    refs_ = std::move(crefs);
    n_refs_ = cap_ = m;
    clusters_ = m;
    clustered_ = true;
    pending_max_ = kClusterLeafMax;
  }

  // After the SAH over the runs: the leaves (runs of runs) get their triangles, in leaf order,
  // and each leaf of more than one block is built on by the same binned SAH over its
  // triangles, so the SAH still shapes the tree's bottom levels. Returns false when cancelled.
  bool refine_clusters() {
    const size_t m = n_refs_;
    std::vector<uint32_t> start(m + 1);
    uint32_t sum = 0;
    for (size_t i = 0; i < m; ++i) {
      start[i] = sum;
      sum += refs_[i].weight();
    }
    start[m] = sum;
    auto xrefs = raw_array<PrimRef>(sum);
    parallel_ranges(m, opt_.threads, [&](size_t lo, size_t hi) {
      for (size_t i = lo; i < hi; ++i) {
        const uint32_t c = refs_[i].id;
        std::memcpy(static_cast<void*>(&xrefs[start[i]]), &tri_refs_[cluster_first_[c]],
                    size_t(cluster_first_[c + 1] - cluster_first_[c]) * sizeof(PrimRef));
      }
    }, 8192);
    // Leaves in tree order with their depth, renumbered to triangle ranges.
    struct Leaf {
      uint32_t node, depth;
    };
    std::vector<Leaf> leaves;
    std::vector<Leaf> stack{{0, 0}};
    uint32_t first_free = 1;  // past the first phase's nodes
    while (!stack.empty()) {
      const Leaf it = stack.back();
      stack.pop_back();
      first_free = std::max(first_free, it.node + 1);
      BvhNode& nd = node_store_[it.node];
      if (nd.is_leaf()) {
        const uint32_t f = nd.left_or_first;
        nd.left_or_first = start[f];
        nd.count = start[f + nd.count] - start[f];
        if (nd.count > 1) leaves.push_back(it);  // build() makes one-block leaves at once
      } else {
        stack.push_back({nd.left_or_first + 1, it.depth + 1});
        stack.push_back({nd.left_or_first, it.depth + 1});
      }
    }
    // Node pools after the first phase's nodes: a leaf of t triangles gets 2t - 2 slots, in
    // leaf order. Each thread's range of leaves bumps one counter from its first leaf's pool
    // on, so its nodes are dense, one gap per thread (pools per leaf would leave a gap after
    // every leaf, and their pages would all be touched). On one thread: no gap at all.
    std::vector<uint32_t> pool(leaves.size());
    uint32_t sum_pools = first_free;
    for (size_t k = 0; k < leaves.size(); ++k) {
      pool[k] = sum_pools;
      sum_pools += 2 * node_store_[leaves[k].node].count - 2;
    }
    refs_ = std::move(xrefs);
    n_refs_ = cap_ = sum;
    pending_max_ = 0;
    tri_refs_.reset();
    std::vector<uint32_t>().swap(cluster_first_);
    std::atomic<int> deepest{int(max_depth_)};
    std::atomic<size_t> added{0};
    parallel_ranges(leaves.size(), opt_.threads, [&](size_t lo, size_t hi) {
      int d = 0;
      size_t nodes = 0;
      uint32_t next = lo < hi ? pool[lo] : 0;
      for (size_t k = lo; k < hi && !cancelled(); ++k) {
        const BvhNode nd = node_store_[leaves[k].node];
        Aabb bounds, cbounds;
        range_bounds(nd.left_or_first, nd.left_or_first + nd.count, bounds, cbounds);
        const Built b = build(leaves[k].node, nd.left_or_first, nd.left_or_first + nd.count,
                              nd.left_or_first + nd.count, int(leaves[k].depth), bounds, cbounds, nd.count, next);
        d = std::max(d, b.depth);
        nodes += b.nodes - 1;  // the leaf itself is counted already
      }
      added.fetch_add(nodes);
      int cur = deepest.load();
      while (d > cur && !deepest.compare_exchange_weak(cur, d)) {
      }
    }, 2048);
    max_depth_ = size_t(deepest.load());
    n_nodes_ += added.load();
    return !cancelled();
  }

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

  // The bins packed by V4::bins(), keeping the reference's weight (bits 24-31).
  static uint32_t pack_bins(uint32_t packed, uint32_t old) {
    return (packed & 0x00ffffffu) | (old & 0xff000000u);
  }

  void make_leaf(BvhNode& node, uint32_t begin, uint32_t end) {
    node.left_or_first = begin;
    node.count = end - begin;
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

  // Gives each side of an object split a share of the node's spare slots [end, cap_end) in
  // proportion to its references, moving the right side up to make the left side's room.
  void place(Split& sp, uint32_t begin, uint32_t end, uint32_t cap_end) {
    if (sp.placed) return;
    const uint32_t nl = sp.mid - begin, nr = end - sp.mid, spare = cap_end - end;
    const uint32_t sl = uint32_t(uint64_t(spare) * nl / (uint64_t(nl) + nr));
    if (sl > 0) std::memmove(&refs_[sp.mid + sl], &refs_[sp.mid], size_t(nr) * sizeof(PrimRef));
    sp.lbegin = begin;
    sp.lend = sp.mid;
    sp.lcap = sp.mid + sl;
    sp.rbegin = sp.mid + sl;
    sp.rend = end + sl;
    sp.rcap = cap_end;
    sp.placed = true;
  }

  struct Built {
    int depth;       // the subtree's deepest level
    uint32_t nodes;  // its nodes, root included
  };

  // Builds the subtree of node_index; returns its deepest level and its node count (gathered
  // up the recursion: no shared counter that both threads write).
  // nt: the node's triangles (its references' weights summed; n without clusters).
  // Node pools: a subtree of c = cap_end - begin reference slots has at most 2c - 2 nodes
  // below its root (a full binary tree has 2c - 1 nodes; its children's slots add up to c,
  // each at least 1). `next` is the first free slot of this subtree's pool, at least 2c - 2
  // long; a split takes the children's pair from it. Serial subtrees bump it on (their nodes
  // stay dense, in depth-first order); subtrees built on two threads get pools of their own
  // (2 lc - 2 and 2 rc - 2 slots after the pair), so the threads write separate cache lines
  // and the numbering does not depend on their timing. On return `next` is past the
  // subtree's nodes (after a split on two threads: past its pool).
  Built build(uint32_t node_index, uint32_t begin, uint32_t end, uint32_t cap_end, int depth, const Aabb& bounds,
              const Aabb& cbounds, uint32_t nt, uint32_t& next) {
    // Every node polls the flag: one relaxed load against a binning pass over its triangles.
    if (cancelled()) return {depth, 1};

    BvhNode& node = node_store_[node_index];
    node.lo = bounds.lo;
    node.hi = bounds.hi;
    const uint32_t n = end - begin;
    // One block of triangles is a leaf without binning: a split costs a traversal step (at
    // least one block test) plus its children's tests, never less than the leaf's one test.
    const bool one_block = nt <= block_ && nt <= uint32_t(opt_.max_leaf_size) && opt_.traversal_cost >= 1.0f;
    Split sp;
    if (n <= 1 || (nt <= uint32_t(opt_.max_leaf_size) && depth >= kMaxDepth) || one_block || nt <= pending_max_ ||
        !split(bounds, cbounds, begin, end, cap_end, depth, nt, sp)) {  // split() false: the SAH prefers a leaf
      make_leaf(node, begin, end);
      return {depth, 1};
    }

    const uint32_t left = next;
    next += 2;
    node.left_or_first = left;
    node.count = 0;
    if (!sp.placed) {
      if (cap_end > end) {
        place(sp, begin, end, cap_end);
      } else {  // no spare slots (always so without spatial splits): the children split the range
        sp.lbegin = begin;
        sp.lend = sp.lcap = sp.rbegin = sp.mid;
        sp.rend = sp.rcap = end;
      }
    }
    Built bl, br;
    if (depth < parallel_depth_ && n >= kParallelMin) {
      uint32_t lnext = next, rnext = next + 2 * (sp.lcap - sp.lbegin) - 2;
      next = rnext + 2 * (sp.rcap - sp.rbegin) - 2;
      std::thread t([&] { bl = build(left, sp.lbegin, sp.lend, sp.lcap, depth + 1, sp.lb, sp.lcb, sp.lt, lnext); });
      br = build(left + 1, sp.rbegin, sp.rend, sp.rcap, depth + 1, sp.rb, sp.rcb, sp.rt, rnext);
      t.join();
    } else {
      bl = build(left, sp.lbegin, sp.lend, sp.lcap, depth + 1, sp.lb, sp.lcb, sp.lt, next);
      br = build(left + 1, sp.rbegin, sp.rend, sp.rcap, depth + 1, sp.rb, sp.rcb, sp.rt, next);
    }
    return {std::max(bl.depth, br.depth), 1 + bl.nodes + br.nodes};
  }

  uint32_t weight_sum(uint32_t begin, uint32_t end) const {
    uint32_t w = 0;
    for (uint32_t i = begin; i < end; ++i) w += refs_[i].weight();
    return w;
  }

  bool split_by_count(uint32_t begin, uint32_t end, Split& sp) const {
    sp.mid = begin + (end - begin) / 2;
    sp.lt = weight_sum(begin, sp.mid);
    sp.rt = weight_sum(sp.mid, end);
    range_bounds(begin, sp.mid, sp.lb, sp.lcb);
    range_bounds(sp.mid, end, sp.rb, sp.rcb);
    return true;
  }

  // One reference into `bins` (all three axes); the reference keeps its bins.
  void bin_one(PrimRef& r, V4 lo, V4 scale, V4 top, BinSet& bins) {
    alignas(16) int idx[4];
    const V4 l = r.vlo(), h = r.vhi();
    r.bins = pack_bins((l * V4::set1(0.5f) + h * V4::set1(0.5f)).bins(lo, scale, top, idx), r.bins);
    const uint32_t w = r.weight();
    const BinBox lh = BinBox::of(l, h);
    for (int a = 0; a < 3; ++a) {
      bins.box[a][idx[a]].grow(lh);
      bins.count[a][idx[a]] += w;
    }
  }

  // All three axes binned in one pass over refs_[begin, end) into `bins` (reset).
  void bin_range(uint32_t begin, uint32_t end, V4 lo, V4 scale, V4 top, int B, BinSet& bins) {
    if (end - begin < kAlternateBins) {
      for (uint32_t i = begin; i < end; ++i) bin_one(refs_[i], lo, scale, top, bins);
      return;
    }
    // Neighbouring references mostly share bins, and each update of a bin waits for the last
    // one's store: two bin sets taking every other reference run two such chains at once.
    BinSet odd;
    odd.reset(B);
    uint32_t i = begin;
    for (; i + 1 < end; i += 2) {
      bin_one(refs_[i], lo, scale, top, bins);
      bin_one(refs_[i + 1], lo, scale, top, odd);
    }
    if (i < end) bin_one(refs_[i], lo, scale, top, bins);
    bins.merge(odd, B);
  }

  // Fills `sp` and returns true, or returns false when a leaf is cheaper (and allowed).
  bool split(const Aabb& bounds, const Aabb& cbounds, uint32_t begin, uint32_t end, uint32_t cap_end, int depth,
             uint32_t nt, Split& sp) {
    const uint32_t n = end - begin;
    const Vec3 ext = cbounds.extent();
    const bool too_deep = depth >= kMaxDepth;
    if (max_component(ext) <= 0.0f || too_deep) {
      // All centroids coincide (or the tree is too deep): no plane separates them. Split by
      // count when the range is too big for a leaf, so leaves stay bounded.
      if (nt <= uint32_t(opt_.max_leaf_size)) return false;
      return split_by_count(begin, end, sp);
    }
    const int B = opt_.bins;
    float scale[3], lo[3];
    for (int axis = 0; axis < 3; ++axis) {
      scale[axis] = ext[axis] > 0.0f ? B / ext[axis] : 0.0f;
      lo[axis] = cbounds.lo[axis];
    }
    const V4 vlo = V4::set(lo[0], lo[1], lo[2]), vscale = V4::set(scale[0], scale[1], scale[2]);
    const V4 top = V4::set1(float(B - 1));
    BinSet bins;
    int used[3][kMaxBins], n_used[3] = {0, 0, 0};  // the non-empty bins of each axis, in order
    const int chunks = chunk_count(n, depth);
    if (n <= kSmallNode) {
      // Small nodes (most of them) touch few bins: only those are cleared and listed.
      alignas(16) int idx[kSmallNode][4];
      uint64_t mask[3] = {0, 0, 0};
      for (uint32_t i = 0; i < n; ++i) {
        refs_[begin + i].bins = pack_bins(refs_[begin + i].centroid().bins(vlo, vscale, top, idx[i]), refs_[begin + i].bins);
        for (int a = 0; a < 3; ++a) mask[a] |= uint64_t(1) << idx[i][a];
      }
      for (int a = 0; a < 3; ++a)
        for (uint64_t m = mask[a]; m; m &= m - 1) {
          const int b = __builtin_ctzll(m);
          bins.box[a][b] = BinBox::empty();
          bins.count[a][b] = 0;
          used[a][n_used[a]++] = b;
        }
      for (uint32_t i = 0; i < n; ++i) {
        const BinBox lh = BinBox::of(refs_[begin + i].vlo(), refs_[begin + i].vhi());
        const uint32_t w = refs_[begin + i].weight();
        for (int a = 0; a < 3; ++a) {
          bins.box[a][idx[i][a]].grow(lh);
          bins.count[a][idx[i][a]] += w;
        }
      }
    } else if (chunks == 1) {
      bins.reset(B);
      bin_range(begin, end, vlo, vscale, top, B, bins);
    } else {
      // Chunks merged in a fixed order: min, max and counts give the same bins in any order anyway.
      std::vector<BinSet> part(chunks);
      run_chunks(chunks, [&](int c) {
        part[c].reset(B);
        bin_range(begin + chunk_start(n, c, chunks), begin + chunk_start(n, c + 1, chunks), vlo,
                  vscale, top, B, part[c]);
      });
      bins.reset(B);
      for (const BinSet& p : part) bins.merge(p, B);
    }
    if (n > kSmallNode)
      for (int a = 0; a < 3; ++a)
        for (int b = 0; b < B; ++b) {  // without a branch: which bins are empty is data
          used[a][n_used[a]] = b;
          n_used[a] += bins.count[a][b] != 0;
        }
    // Planes are evaluated between non-empty bins only: the planes inside a run of empty bins
    // all split the triangles alike and cost the same, and the first of them (the one taken
    // before) is the one right after the non-empty bin. Small nodes have few non-empty bins.
    float best_cost = kInf;
    int best_axis = -1, best_bin = 0;
    for (int axis = 0; axis < 3; ++axis) {
      if (ext[axis] <= 0.0f) continue;
      const int* used_bins = used[axis];
      const int m = n_used[axis];
      // Sweep from the right, then from the left.
      float right_cost[kMaxBins];
      BinBox acc = BinBox::empty();
      uint32_t cnt = 0;
      for (int j = m - 1; j > 0; --j) {
        acc.grow(bins.box[axis][used_bins[j]]);
        cnt += bins.count[axis][used_bins[j]];
        right_cost[j] = half_area(acc.lo(), acc.hi()) * tests(cnt);
      }
      acc = BinBox::empty();
      cnt = 0;
      for (int j = 0; j < m - 1; ++j) {
        acc.grow(bins.box[axis][used_bins[j]]);
        cnt += bins.count[axis][used_bins[j]];
        const float cost = half_area(acc.lo(), acc.hi()) * tests(cnt) + right_cost[j + 1];
        if (cost < best_cost) {
          best_cost = cost;
          best_axis = axis;
          best_bin = used_bins[j] + 1;
        }
      }
    }
    const float parent_area = bounds.half_area();
    const float leaf_cost = tests(nt);
    const float split_cost =
        best_axis < 0 ? kInf : opt_.traversal_cost + (parent_area > 0 ? best_cost / parent_area : 0.0f);
    // The object split's child boxes, from the bins.
    BoxAcc lb, rb;
    uint32_t left_tris = 0;
    if (best_axis >= 0)
      for (int k = 0; k < n_used[best_axis]; ++k) {
        const int b = used[best_axis][k];
        (b < best_bin ? lb : rb).grow(bins.box[best_axis][b].lo(), bins.box[best_axis][b].hi());
        if (b < best_bin) left_tris += bins.count[best_axis][b];
      }
    if (cap_end > end) {
      // Spatial splits where the object split's children overlap by a noticeable area (and
      // there are spare slots for the duplicates).
      const Aabb l = lb.aabb(), r = rb.aabb();
      const Aabb overlap{vmax(l.lo, r.lo), vmin(l.hi, r.hi)};
      if (best_axis < 0 || overlap.half_area() > spatial_min_area_) {
        const float cost = split_cost < leaf_cost || nt > uint32_t(opt_.max_leaf_size) ? split_cost : leaf_cost;
        if (spatial_split(bounds, begin, end, cap_end, depth, cost, sp)) return true;
      }
    }
    if (best_axis < 0 || (split_cost >= leaf_cost && nt <= uint32_t(opt_.max_leaf_size))) {
      if (nt <= uint32_t(opt_.max_leaf_size)) return false;
      return split_by_count(begin, end, sp);  // no useful plane and too many for a leaf
    }
    // Partition by the bins the binning pass stored (the same bin_of() of the same centroid).
    const uint32_t shift = 8 * uint32_t(best_axis), split_bin = uint32_t(best_bin);
    const auto goes_left = [shift, split_bin](const PrimRef& r) { return ((r.bins >> shift) & 0xff) < split_bin; };
    BoxAcc lcb, rcb;
    uint32_t i = begin;
    if (n <= kCopyPartition) {
      // Small nodes: branch-free, through a buffer (left side in order, right side reversed);
      // a swapping partition's branches mispredict on about every other reference.
      // Raw bytes, not PrimRef[]: PrimRef's Vec3s would zero all 8 KB on every call.
      alignas(PrimRef) unsigned char tmp[kCopyPartition * sizeof(PrimRef)];
      uint32_t l = 0, r = n;
      for (uint32_t k = begin; k < end; ++k) {
        const bool left = goes_left(refs_[k]);
        std::memcpy(tmp + size_t(left ? l : r - 1) * sizeof(PrimRef), &refs_[k], sizeof(PrimRef));
        l += left;
        r -= !left;
      }
      std::memcpy(static_cast<void*>(&refs_[begin]), tmp, size_t(n) * sizeof(PrimRef));
      i = begin + l;
      for (uint32_t k = begin; k < i; ++k) {
        const V4 c = refs_[k].centroid();
        lcb.grow(c, c);
      }
      for (uint32_t k = i; k < end; ++k) {
        const V4 c = refs_[k].centroid();
        rcb.grow(c, c);
      }
    } else {
      // In place, collecting both sides' centroid boxes on the way (the triangle boxes come
      // from the bins).
      const auto left_side = [&](const PrimRef& r, BoxAcc& lacc, BoxAcc& racc) {
        const V4 c = r.centroid();
        const bool left = goes_left(r);
        (left ? lacc : racc).grow(c, c);
        return left;
      };
      uint32_t j = end;
      for (;;) {
        while (i < j && left_side(refs_[i], lcb, rcb)) ++i;
        while (i < j && !left_side(refs_[j - 1], lcb, rcb)) --j;
        if (i >= j) break;
        // refs_[i] belongs right and refs_[j - 1] left: both were counted; swap and step over them.
        std::swap(refs_[i], refs_[j - 1]);
        ++i;
        --j;
      }
    }
    sp.mid = i;
    if (sp.mid == begin || sp.mid == end) return split_by_count(begin, end, sp);
    sp.lt = left_tris;
    sp.rt = nt - left_tris;
    sp.lb = lb.aabb();
    sp.rb = rb.aabb();
    sp.lcb = lcb.aabb();
    sp.rcb = rcb.aabb();
    return true;
  }

  // First and last spatial bin of a reference on `axis`. References with a non-finite box are
  // never cut (clipping them means nothing): they stay whole in their first bin.
  void span(const PrimRef& r, int axis, float lo, float scale, int& first, int& last) const {
    const int B = opt_.bins;
    first = bin_of(r.lo[axis], lo, scale, B);
    last = is_finite(r.lo) && is_finite(r.hi) ? std::max(first, bin_of(r.hi[axis], lo, scale, B)) : first;
  }

  // Spatial bins of refs_[begin, end) on every axis with scale > 0: each reference's triangle
  // clipped to every bin slab it spans.
  void spatial_bin_range(uint32_t begin, uint32_t end, const float lo[3], const float scale[3], const float step[3],
                         SpatialBinSet& sb) const {
    V4 plo[kMaxBins], phi[kMaxBins];  // the triangle's part in each bin it spans
    for (uint32_t i = begin; i < end; ++i) {
      if ((i & 4095) == 0 && cancelled()) return;  // a big node's clipping takes a while: stay cancellable
      const PrimRef& r = refs_[i];
      const V4 box_lo = r.vlo(), box_hi = r.vhi();
      const bool finite = is_finite(r.lo) && is_finite(r.hi);
      const TriangleVerts& t = tris_[r.id];
      const Vec3* v[3] = {&t.v0, &t.v1, &t.v2};
      V4 vv[3];
      bool loaded = false;
      for (int a = 0; a < 3; ++a) {
        if (!(scale[a] > 0.0f)) continue;
        const int f = bin_of(r.lo[a], lo[a], scale[a], opt_.bins);
        const int l = finite ? std::max(f, bin_of(r.hi[a], lo[a], scale[a], opt_.bins)) : f;  // as span()
        sb.entry[a][f]++;
        sb.exit[a][l]++;
        if (f == l) {
          sb.lo[a][f] = vmin(sb.lo[a][f], box_lo);
          sb.hi[a][f] = vmax(sb.hi[a][f], box_hi);
          continue;
        }
        // The triangle's part in each slab: its vertices there and its edges' crossings of the
        // slab's planes, one walk along each edge (float: the bins only estimate costs; the
        // partition clips exactly).
        if (!loaded) {
          for (int k = 0; k < 3; ++k) vv[k] = V4::set(v[k]->x, v[k]->y, v[k]->z);
          loaded = true;
        }
        for (int b = f; b <= l; ++b) {
          plo[b] = V4::set1(kInf);
          phi[b] = V4::set1(-kInf);
        }
        int vb[3];
        for (int k = 0; k < 3; ++k) {
          vb[k] = std::clamp(bin_of((*v[k])[a], lo[a], scale[a], opt_.bins), f, l);
          plo[vb[k]] = vmin(plo[vb[k]], vv[k]);
          phi[vb[k]] = vmax(phi[vb[k]], vv[k]);
        }
        for (int e = 0; e < 3; ++e) {
          int k0 = e, k1 = e == 2 ? 0 : e + 1;
          if (vb[k0] == vb[k1]) continue;
          if (vb[k0] > vb[k1]) std::swap(k0, k1);
          const float a0 = (*v[k0])[a], da = (*v[k1])[a] - a0;
          const float inv = da > 0.0f ? 1.0f / da : 0.0f;
          const V4 d = vv[k1] - vv[k0];
          for (int j = vb[k0] + 1; j <= vb[k1]; ++j) {  // plane j: between bins j - 1 and j
            const float q = lo[a] + float(j) * step[a];
            const V4 x = vv[k0] + d * V4::set1(std::clamp((q - a0) * inv, 0.0f, 1.0f));
            plo[j - 1] = vmin(plo[j - 1], x);
            phi[j - 1] = vmax(phi[j - 1], x);
            plo[j] = vmin(plo[j], x);
            phi[j] = vmax(phi[j], x);
          }
        }
        for (int b = f; b <= l; ++b) {
          const V4 cl = vmax(plo[b], box_lo), ch = vmin(phi[b], box_hi);
          if (V4::any_gt_xyz(cl, ch)) continue;
          sb.lo[a][b] = vmin(sb.lo[a][b], cl);
          sb.hi[a][b] = vmax(sb.hi[a][b], ch);
        }
      }
    }
  }

  // Looks for a spatial split of refs_[begin, end) (Stich et al. 2009) cheaper than `to_beat`
  // (the SAH cost of the object split or leaf the node would otherwise get, in the same units)
  // whose duplicates fit in the node's spare slots. On success the children's references are
  // written in place (left from begin, right after the left's share of the spare slots), `sp`
  // is filled and placed, and it returns true; else refs_ is untouched.
  bool spatial_split(const Aabb& bounds, uint32_t begin, uint32_t end, uint32_t cap_end, int depth, float to_beat,
                     Split& sp) {
    const uint32_t n = end - begin, room = cap_end - begin;
    const int B = opt_.bins;
    const Vec3 ext = bounds.extent();
    float lo[3], scale[3], step[3];
    for (int a = 0; a < 3; ++a) {
      lo[a] = bounds.lo[a];
      const bool ok = ext[a] > 0.0f && std::isfinite(ext[a]);
      scale[a] = ok ? B / ext[a] : 0.0f;
      step[a] = ok ? ext[a] / B : 0.0f;
    }
    // One bin set per thread, reused: a node's attempt must not cost an allocation.
    thread_local std::unique_ptr<SpatialBinSet> bin_store;
    if (!bin_store) bin_store = std::make_unique<SpatialBinSet>();
    SpatialBinSet* sb = bin_store.get();
    const int chunks = chunk_count(n, depth);
    if (chunks == 1) {
      sb->reset(B);
      spatial_bin_range(begin, end, lo, scale, step, *sb);
    } else {  // merged in a fixed order (min, max and sums: the same bins in any order anyway)
      std::vector<std::unique_ptr<SpatialBinSet>> part(chunks);
      run_chunks(chunks, [&](int c) {
        part[c] = std::make_unique<SpatialBinSet>();
        part[c]->reset(B);
        spatial_bin_range(begin + chunk_start(n, c, chunks), begin + chunk_start(n, c + 1, chunks),
                          lo, scale, step, *part[c]);
      });
      sb->reset(B);
      for (const auto& p : part) sb->merge(*p, B);
    }
    if (cancelled()) return false;
    float best_cost = kInf;
    int best_axis = -1, best_plane = 0;
    for (int a = 0; a < 3; ++a) {
      if (!(scale[a] > 0.0f)) continue;
      float right_cost[kMaxBins];
      uint32_t right_n[kMaxBins];
      BoxAcc acc;
      uint32_t cnt = 0;
      for (int j = B - 1; j > 0; --j) {
        acc.grow(sb->lo[a][j], sb->hi[a][j]);
        cnt += sb->exit[a][j];
        right_cost[j] = half_area(acc.lo, acc.hi) * tests(cnt);  // +inf for an empty box: never chosen
        right_n[j] = cnt;
      }
      acc = BoxAcc();
      cnt = 0;
      for (int j = 1; j < B; ++j) {  // the plane between bins j - 1 and j
        acc.grow(sb->lo[a][j - 1], sb->hi[a][j - 1]);
        cnt += sb->entry[a][j - 1];
        if (cnt == 0 || right_n[j] == 0 || uint64_t(cnt) + right_n[j] > room) continue;
        const float cost = half_area(acc.lo, acc.hi) * tests(cnt) + right_cost[j];
        if (cost < best_cost) {
          best_cost = cost;
          best_axis = a;
          best_plane = j;
        }
      }
    }
    const float parent_area = bounds.half_area();
    const float cost = opt_.traversal_cost + (parent_area > 0 ? best_cost / parent_area : 0.0f);
    if (best_axis < 0) return false;
    if (!(cost < to_beat)) return false;

    // Partition, with reference unsplitting (Stich et al. section 4.4): a triangle the plane
    // cuts goes whole to one side when that costs less than referencing it on both.
    const int a = best_axis;
    const float plane = lo[a] + float(best_plane) * step[a];
    Aabb lbox, rbox;
    uint32_t nl = 0, nr = 0;
    for (int b = 0; b < B; ++b) {
      const Aabb c = BoxAcc{sb->lo[a][b], sb->hi[a][b]}.aabb();
      if (b < best_plane) {
        if (!c.empty()) lbox.grow(c);
        nl += sb->entry[a][b];
      } else {
        if (!c.empty()) rbox.grow(c);
        nr += sb->exit[a][b];
      }
    }
    std::vector<PrimRef> left, right;
    left.reserve(nl);
    right.reserve(nr);
    for (uint32_t i = begin; i < end; ++i) {
      const PrimRef& r = refs_[i];
      int f, l;
      span(r, a, lo[a], scale[a], f, l);
      if (l < best_plane) {
        left.push_back(r);
      } else if (f >= best_plane) {
        right.push_back(r);
      } else {
        const Aabb whole{r.lo, r.hi};
        Aabb l1 = lbox, r1 = rbox;
        l1.grow(whole);
        r1.grow(whole);
        const float c_split = lbox.half_area() * tests(nl) + rbox.half_area() * tests(nr);
        const float c_left = l1.half_area() * tests(nl) + rbox.half_area() * tests(nr - 1);
        const float c_right = lbox.half_area() * tests(nl - 1) + r1.half_area() * tests(nr);
        if (c_left < c_split && c_left <= c_right) {
          left.push_back(r);
          lbox = l1;
          --nr;
        } else if (c_right < c_split) {
          right.push_back(r);
          rbox = r1;
          --nl;
        } else {
          const TriangleVerts& t = tris_[r.id];
          const Aabb cl = clip_triangle(t, a, -kInf, plane, whole), cr = clip_triangle(t, a, plane, kInf, whole);
          PrimRef x = r;
          if (!cl.empty()) {
            x.lo = cl.lo;
            x.hi = cl.hi;
            left.push_back(x);
          }
          if (!cr.empty()) {
            x.lo = cr.lo;
            x.hi = cr.hi;
            right.push_back(x);
          }
          if (cl.empty() && cr.empty()) left.push_back(r);  // cannot happen for a finite triangle; kept whole
        }
      }
    }
    if (left.empty() || right.empty() || left.size() + right.size() > room) return false;
    const uint32_t ln = uint32_t(left.size()), rn = uint32_t(right.size());
    const uint32_t spare = room - ln - rn;
    const uint32_t sl = uint32_t(uint64_t(spare) * ln / (uint64_t(ln) + rn));
    std::copy(left.begin(), left.end(), &refs_[begin]);
    std::copy(right.begin(), right.end(), &refs_[begin + ln + sl]);
    sp.lbegin = begin;
    sp.lend = begin + ln;
    sp.lcap = sp.rbegin = begin + ln + sl;
    sp.rend = sp.rbegin + rn;
    sp.rcap = cap_end;
    sp.placed = true;
    sp.mid = sp.lend;
    sp.lt = ln;  // spatial splits are never clustered: weights of 1
    sp.rt = rn;
    range_bounds(sp.lbegin, sp.lend, sp.lb, sp.lcb);
    range_bounds(sp.rbegin, sp.rend, sp.rb, sp.rcb);
    spatial_splits_.fetch_add(1, std::memory_order_relaxed);
    return true;
  }

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

// The compressed form of float node `f` (k used lanes): per axis the origin is the lanes' lowest
// plane and the step the smallest power of two whose 255 steps reach the highest, both checked
// in float as the traversal computes planes (QuantWideNode::plane); each byte is then rounded
// outwards and moved until its plane lies outside the child's box (never inside it). False
// when the boxes are not finite or too large for the steps (or a leaf is over 255 triangles).
template <int N>
bool quantise_node(const WideBvhNode<N>& f, int k, QuantWideNode<N>& q) {
  std::memset(&q, 0, sizeof(q));
  q.valid = static_cast<uint8_t>((1u << k) - 1u);
  for (int i = 0; i < N; ++i) {
    if (f.count[i] > 255) return false;
    q.child[i] = f.child[i];
    q.count[i] = static_cast<uint8_t>(f.count[i]);
  }
  for (int a = 0; a < 3; ++a) {
    float lo = kInf, hi = -kInf;
    for (int i = 0; i < k; ++i) {
      const float cl = f.bounds[2 * a][i], ch = f.bounds[2 * a + 1][i];
      if (!(std::isfinite(cl) && std::isfinite(ch) && cl <= ch)) return false;
      lo = std::min(lo, cl);
      hi = std::max(hi, ch);
    }
    const float ext = hi - lo;
    if (!std::isfinite(ext)) return false;
    int e = -126;  // 2^-126: the smallest normal step, so scale * q stays exact
    if (ext > 0.0f) {
      std::frexp(ext / 255.0f, &e);  // ext / 255 < 2^e: usually 2^(e - 1) is too short
      e = std::max(e - 1, -126);
    }
    float scale;
    for (;; ++e) {
      if (e > 119) return false;  // 255 * 2^119 < 2^127: the largest step without overflow
      scale = std::ldexp(1.0f, e);
      if (lo + scale * 255.0f >= hi) break;
    }
    q.origin[a] = lo;
    q.scale[a] = scale;
    const auto plane = [&](int b) { return lo + scale * float(b); };  // as QuantWideNode::plane
    for (int i = 0; i < N; ++i) {
      if (i >= k) {  // unused lane: an empty box (the traversal also masks it off)
        q.q[2 * a][i] = 255;
        q.q[2 * a + 1][i] = 0;
        continue;
      }
      const float cl = f.bounds[2 * a][i], ch = f.bounds[2 * a + 1][i];
      int bl = static_cast<int>(std::clamp(std::floor((cl - lo) / scale), 0.0f, 255.0f));
      while (bl > 0 && plane(bl) > cl) --bl;  // plane(0) = lo <= cl
      int bh = static_cast<int>(std::clamp(std::ceil((ch - lo) / scale), 0.0f, 255.0f));
      while (bh < 255 && plane(bh) < ch) ++bh;
      if (plane(bl) > cl || plane(bh) < ch) return false;  // cannot happen: plane(255) >= hi
      q.q[2 * a][i] = static_cast<uint8_t>(bl);
      q.q[2 * a + 1][i] = static_cast<uint8_t>(bh);
    }
  }
  return true;
}

struct LeafJob {
  uint32_t first, count, block;  // the leaf's triangles (leaf order) and its first block
};
struct CollapseItem {
  uint32_t bin, wide;  // a binary node and the wide node it becomes
};

// The wide node of binary node `b` (as float lanes; `k` gets the used lanes): interior children
// are numbered from `next` on and pushed onto `todo` in lane order, leaf children get blocks
// from `n_blocks` on and a job each.
template <int N>
void make_wide_node(const BvhNode* bin, uint32_t b, uint32_t& next, uint32_t& n_blocks,
                    std::vector<CollapseItem>& todo, std::vector<LeafJob>& jobs, WideBvhNode<N>& node, int& k) {
  uint32_t kids[N];
  k = bvh_detail::gather_wide_children(bin, b, kids, N);
  for (int i = 0; i < N; ++i) {
    if (i < k) {
      const BvhNode& c = bin[kids[i]];
      node.bounds[0][i] = c.lo.x;
      node.bounds[1][i] = c.hi.x;
      node.bounds[2][i] = c.lo.y;
      node.bounds[3][i] = c.hi.y;
      node.bounds[4][i] = c.lo.z;
      node.bounds[5][i] = c.hi.z;
      if (c.is_leaf()) {
        node.child[i] = n_blocks;
        node.count[i] = c.count;
        jobs.push_back({c.left_or_first, c.count, n_blocks});
        n_blocks += (c.count + 3) / 4;
      } else {
        node.child[i] = next++;
        node.count[i] = 0;
        todo.push_back({kids[i], node.child[i]});
      }
    } else {  // unused lane: an empty box (lo > hi) that the slab test always rejects
      for (int a = 0; a < 3; ++a) {
        node.bounds[2 * a][i] = kInf;
        node.bounds[2 * a + 1][i] = -kInf;
      }
      node.child[i] = 0;
      node.count[i] = 0;
    }
  }
}

template <int N, class Node>
bool store_wide_node(const WideBvhNode<N>& node, int k, Node& out) {
  if constexpr (std::is_same_v<Node, WideBvhNode<N>>) {
    out = node;
    return true;
  } else {
    return quantise_node(node, k, out);
  }
}

// The references under binary node b: a subtree's leaves are one range of the leaf order, from
// its leftmost leaf's first to its rightmost leaf's last.
inline uint32_t subtree_refs(const BvhNode* bin, uint32_t b) {
  uint32_t l = b, r = b;
  while (!bin[l].is_leaf()) l = bin[l].left_or_first;
  while (!bin[r].is_leaf()) r = bin[r].left_or_first + 1;
  return bin[r].left_or_first + bin[r].count - bin[l].left_or_first;
}

// One subtree of the collapse, made on its own thread: first counted, then, once the top walk
// has given it its place, written straight into the output.
struct CollapsePart {
  uint32_t bin = 0, wide = 0;             // its root: binary node and (global) wide index
  uint32_t nodes = 0, blocks = 0, leaves = 0;  // its size
  uint32_t node_base = 0, block_base = 0;  // where its nodes below the root and its blocks go
  size_t job_base = 0;                     // and its leaves' jobs
};

// Collapses the binary tree into an N-wide one: each wide node takes a binary node's two
// children and keeps opening its largest interior child (the one most rays enter) until it
// has N children or only leaves (Wald et al. 2008, as in Embree and tinybvh). Leaves stay
// the binary leaves; `tris` is the build's input, reached through prim_ids (leaf order).
// Nodes and blocks are numbered in the order of one depth-first pass (a stack: a node's
// interior children get consecutive indices, the last one's subtree is made first), and leaves
// become runs of TriangleBlock4s in that order. On several threads the same numbering comes
// from parts: subtrees of few enough references are counted in parallel, the top of the tree
// is walked as that pass would, each part taking as many indices as it counted, then the
// parts are made in parallel straight into their places; the blocks are filled in parallel.
// So the result is the same on any thread count. Into float nodes (Node = WideBvhNode<N>) or
// compressed ones (QuantWideNode<N>, from the float node of the same lanes); false when a node
// cannot be compressed (quantise_node), the outputs then unspecified.
template <int N, class Node>
bool collapse(const BvhNode* bin, size_t n_bin, TriangleSpan tris,
              const std::vector<uint32_t>& prim_ids, int threads, RawVector<Node>& out,
              RawVector<TriangleBlock4>& blocks, RawVector<uint32_t>& block_prims) {
  const int hw = std::max(1, threads > 0 ? threads : static_cast<int>(std::thread::hardware_concurrency()));
  const uint32_t refs = static_cast<uint32_t>(prim_ids.size());
  // Subtrees of at most this many references are parts (about 8 per thread); none on one thread.
  const uint32_t part_max = hw > 1 && refs >= 65536 ? std::max<uint32_t>(8192, refs / (8 * uint32_t(hw))) : 0;
  const auto is_part = [&](uint32_t b) { return part_max > 0 && b != 0 && subtree_refs(bin, b) <= part_max; };
  std::vector<CollapsePart> parts;
  std::vector<CollapseItem> todo;
  std::vector<LeafJob> jobs;
  WideBvhNode<N> node;
  int k = 0;
  // Runs fn(part) for every part, parts handed out in turn (any thread may take any one).
  const auto for_parts = [&](auto&& fn) {
    std::atomic<size_t> next_part{0};
    run_chunks(std::min<int>(hw, int(parts.size())), [&](int) {
      for (size_t p; (p = next_part.fetch_add(1)) < parts.size();) fn(parts[p]);
    });
  };
  if (part_max > 0) {
    // The top walk, numbering nothing: which subtrees are parts, in the order the pass meets them.
    uint32_t next = 1, nb = 0;
    todo.push_back({0, 0});
    while (!todo.empty()) {
      const CollapseItem it = todo.back();
      todo.pop_back();
      if (is_part(it.bin)) {
        parts.emplace_back();
        parts.back().bin = it.bin;
        continue;
      }
      make_wide_node<N>(bin, it.bin, next, nb, todo, jobs, node, k);
    }
    jobs.clear();
    // Each part's wide nodes, blocks and leaves counted (the same walk, nothing written).
    for_parts([&](CollapsePart& part) {
      uint32_t kids[N];
      std::vector<uint32_t> stack{part.bin};
      uint32_t nodes = 0, blocks = 0, leaves = 0;  // locals: neighbouring parts share cache lines
      while (!stack.empty()) {
        const uint32_t b = stack.back();
        stack.pop_back();
        ++nodes;
        const int m = bvh_detail::gather_wide_children(bin, b, kids, N);
        for (int i = 0; i < m; ++i) {
          const BvhNode& c = bin[kids[i]];
          if (c.is_leaf()) {
            blocks += (c.count + 3) / 4;
            ++leaves;
          } else {
            stack.push_back(kids[i]);
          }
        }
      }
      part.nodes = nodes;
      part.blocks = blocks;
      part.leaves = leaves;
    });
  }
  // The pass itself: the top nodes made, each part given its indices. On one thread (no parts)
  // the nodes go straight into `out`; else the top ones wait until `out` has its final size.
  uint32_t next = 1, n_blocks = 0;
  size_t part_no = 0;
  std::vector<std::pair<uint32_t, int>> top;  // with parts: the top nodes' indices and lanes
  std::vector<WideBvhNode<N>> top_nodes;
  out.clear();
  if (part_max == 0) {
    jobs.reserve((n_bin + 1) / 2);  // one per leaf
    out.reserve((n_bin + 1) / 2);   // at most one wide node per interior binary node
    advise_huge_pages(out.data(), out.capacity() * sizeof(Node));
    out.emplace_back();
  }
  todo.assign(1, {0, 0});
  while (!todo.empty()) {
    const CollapseItem it = todo.back();
    todo.pop_back();
    if (is_part(it.bin)) {
      CollapsePart& part = parts[part_no++];
      part.wide = it.wide;
      part.node_base = next;
      part.block_base = n_blocks;
      next += part.nodes - 1;
      n_blocks += part.blocks;
      continue;
    }
    make_wide_node<N>(bin, it.bin, next, n_blocks, todo, jobs, node, k);
    if (part_max > 0) {
      top.push_back({it.wide, k});
      top_nodes.push_back(node);
    } else {
      out.resize(next);
      if (!store_wide_node<N>(node, k, out[it.wide])) return false;
    }
  }
  if (part_max > 0) {
    out.reserve(next);
    advise_huge_pages(out.data(), out.capacity() * sizeof(Node));
    out.resize(next);
    for (size_t i = 0; i < top.size(); ++i)
      if (!store_wide_node<N>(top_nodes[i], top[i].second, out[top[i].first])) return false;
    size_t n_jobs = jobs.size();
    for (CollapsePart& part : parts) {
      part.job_base = n_jobs;
      n_jobs += part.leaves;
    }
    jobs.resize(n_jobs);
    // The parts made in their places: the same walk as the pass, its root at part.wide, the
    // nodes below from node_base on, the blocks from block_base on.
    std::atomic<bool> ok{true};
    for_parts([&](CollapsePart& part) {
      std::vector<CollapseItem> stack{{part.bin, part.wide}};
      std::vector<LeafJob> part_jobs;
      part_jobs.reserve(part.leaves);
      uint32_t pnext = part.node_base, pblocks = part.block_base;
      WideBvhNode<N> wn;
      int lanes = 0;
      while (!stack.empty()) {
        const CollapseItem it = stack.back();
        stack.pop_back();
        make_wide_node<N>(bin, it.bin, pnext, pblocks, stack, part_jobs, wn, lanes);
        if (!store_wide_node<N>(wn, lanes, out[it.wide])) ok = false;
      }
      std::copy(part_jobs.begin(), part_jobs.end(), jobs.begin() + std::ptrdiff_t(part.job_base));
    });
    if (!ok) return false;
  } else {
    out.shrink_to_fit();
  }
  // Exact sizes, every element written below.
  blocks.clear();
  block_prims.clear();
  blocks.resize(n_blocks);
  block_prims.resize(4 * size_t(n_blocks));
  blocks.shrink_to_fit();
  block_prims.shrink_to_fit();
  const float nan = std::nanf("");
  parallel_ranges(jobs.size(), threads, [&](size_t lo, size_t hi) {
    for (size_t j = lo; j < hi; ++j) {
      const LeafJob& job = jobs[j];
      for (uint32_t b = 0; b < job.count; b += 4) {
        TriangleBlock4& blk = blocks[job.block + b / 4];
        uint32_t* ids = &block_prims[4 * (size_t(job.block) + b / 4)];
        for (uint32_t l = 0; l < 4; ++l) {
          if (b + l < job.count) {
            const uint32_t id = prim_ids[job.first + b + l];
            const TriangleVerts& tv = tris[id];
            const Vec3* v[3] = {&tv.v0, &tv.v1, &tv.v2};
            for (int r = 0; r < 9; ++r) blk.v[r][l] = (*v[r / 3])[r % 3];
            ids[l] = id;
          } else {
            for (int r = 0; r < 9; ++r) blk.v[r][l] = nan;
            ids[l] = UINT32_MAX;
          }
        }
      }
    }
  }, 4096);
  return true;
}

}  // namespace

bool cpu_has_avx2() {
#if defined(PL_HAVE_AVX2_KERNEL) && (defined(__x86_64__) || defined(__i386__))
  static const bool has = __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");  // the 8-wide kernel uses both
  return has;
#else
  return false;
#endif
}

#if defined(__x86_64__) || defined(__i386__)
bool bvh4_intersect(const WideBvhView& v, const Ray& ray, Hit& hit, TraversalCounters* counters) {
  return wide_intersect<Sse4>(v, ray, hit, counters);
}
bool bvh4_occluded(const WideBvhView& v, const Ray& ray) { return wide_occluded<Sse4>(v, ray); }
bool bvh4q_intersect(const WideBvhView& v, const Ray& ray, Hit& hit, TraversalCounters* counters) {
  return wide_intersect<Sse4, Bvh4QNode>(v, ray, hit, counters);
}
bool bvh4q_occluded(const WideBvhView& v, const Ray& ray) { return wide_occluded<Sse4, Bvh4QNode>(v, ray); }
#endif

void Bvh::clear() {
  *this = Bvh();
}

bool Bvh::build(TriangleSpan tris, const BvhBuildOptions& options) {
  const auto t0 = std::chrono::steady_clock::now();
  clear();
  BvhBuildOptions opt = options;
  BvhLayout layout = opt.layout;
#if defined(__x86_64__) || defined(__i386__)
  if (layout == BvhLayout::Auto) layout = cpu_has_avx2() ? BvhLayout::Wide8 : BvhLayout::Wide4;
  if (layout == BvhLayout::Wide8 && !cpu_has_avx2()) layout = BvhLayout::Wide4;
#else
  layout = BvhLayout::Binary;  // the wide kernels are written for x86 SIMD
#endif
  if (opt.leaf_block <= 0) opt.leaf_block = layout == BvhLayout::Binary ? 1 : 4;
  const auto cancelled = [&] { return opt.cancel && opt.cancel->load(); };
  if (tris.empty()) return !cancelled();
  Builder builder(tris, opt, prim_ids_);
  if (!builder.run()) {
    clear();
    return false;
  }
  const BvhNode* bin = builder.nodes();
  const size_t n_bin = builder.node_count();
  if (layout == BvhLayout::Binary) {  // kept; the wide layouts copy the triangles into their blocks instead
    // Renumbered without the pools' gaps, in depth-first order, each pair side by side (as one
    // serial build numbers them).
    nodes_.resize(n_bin);
    std::vector<std::pair<uint32_t, uint32_t>> todo{{0u, 0u}};  // (builder's index, ours)
    uint32_t next = 1;
    while (!todo.empty()) {
      const auto [from, to] = todo.back();
      todo.pop_back();
      BvhNode& nd = nodes_[to];
      nd = bin[from];
      if (!nd.is_leaf()) {
        todo.push_back({nd.left_or_first + 1, next + 1});
        todo.push_back({nd.left_or_first, next});
        nd.left_or_first = next;
        next += 2;
      }
    }
    tris_.resize(prim_ids_.size());
    for (size_t i = 0; i < prim_ids_.size(); ++i) tris_[i] = tris[prim_ids_[i]];
  }

  bounds_ = {bin[0].lo, bin[0].hi};
  stats_.nodes = n_bin;
  stats_.max_depth = builder.max_depth();
  stats_.triangles = tris.size();
  stats_.references = prim_ids_.size();
  stats_.spatial_splits = builder.spatial_splits();
  stats_.clusters = builder.clusters();
  const float root_area = std::max(bounds_.half_area(), 1e-30f);
  // Summed in tree order (the builder's node pools have gaps, and the sum's order must be the
  // same on any thread count).
  double cost = 0.0;
  std::vector<uint32_t> stack{0};
  while (!stack.empty()) {
    const BvhNode& n = bin[stack.back()];
    stack.pop_back();
    const double rel = Aabb{n.lo, n.hi}.half_area() / root_area;
    if (n.is_leaf()) {
      stats_.leaves++;
      cost += rel * n.count;
    } else {
      cost += rel * opt.traversal_cost;
      stack.push_back(n.left_or_first + 1);
      stack.push_back(n.left_or_first);
    }
  }
  stats_.sah_cost = cost;
  if (cancelled()) {
    clear();
    return false;
  }
  if (layout != BvhLayout::Binary && opt.compact) {
    compact_ = layout == BvhLayout::Wide4
                   ? collapse<4>(bin, n_bin, tris, prim_ids_, opt.threads, nodes4q_, blocks_, block_prims_)
                   : collapse<8>(bin, n_bin, tris, prim_ids_, opt.threads, nodes8q_, blocks_, block_prims_);
    if (!compact_) {  // a box that bytes cannot hold: float nodes
      RawVector<Bvh4QNode>().swap(nodes4q_);
      RawVector<Bvh8QNode>().swap(nodes8q_);
    }
  }
  if (layout == BvhLayout::Wide4 && !compact_)
    collapse<4>(bin, n_bin, tris, prim_ids_, opt.threads, nodes4_, blocks_, block_prims_);
  if (layout == BvhLayout::Wide8 && !compact_)
    collapse<8>(bin, n_bin, tris, prim_ids_, opt.threads, nodes8_, blocks_, block_prims_);
  if (layout != BvhLayout::Binary) {
    // The wide tree and its triangle blocks replace the binary tree and the leaf order.
    stats_.wide_nodes = compact_ ? (layout == BvhLayout::Wide4 ? nodes4q_.size() : nodes8q_.size())
                                 : (layout == BvhLayout::Wide4 ? nodes4_.size() : nodes8_.size());
    stats_.compact = compact_;
    std::vector<uint32_t>().swap(prim_ids_);
  }
  triangles_ = tris.size();
  layout_ = stats_.layout = layout;
  stats_.build_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  return true;
}

size_t Bvh::memory_bytes() const {
  return nodes_.capacity() * sizeof(BvhNode) + nodes4_.capacity() * sizeof(Bvh4Node) +
         nodes8_.capacity() * sizeof(Bvh8Node) + nodes4q_.capacity() * sizeof(Bvh4QNode) +
         nodes8q_.capacity() * sizeof(Bvh8QNode) + tris_.capacity() * sizeof(TriangleVerts) +
         prim_ids_.capacity() * sizeof(uint32_t) + blocks_.capacity() * sizeof(TriangleBlock4) +
         block_prims_.capacity() * sizeof(uint32_t);
}

namespace {
template <int N, class Node>
void append_lanes(const RawVector<Node>& nodes, std::vector<Bvh::WideLane>& out) {
  for (const Node& n : nodes) {
    for (int i = 0; i < N; ++i) {
      Bvh::WideLane l;
      for (int r = 0; r < 6; ++r) {
        if constexpr (std::is_same_v<Node, WideBvhNode<N>>) l.box[r] = n.bounds[r][i];
        else l.box[r] = n.plane(r, i);
      }
      l.child = n.child[i];
      l.count = n.count[i];
      if constexpr (std::is_same_v<Node, WideBvhNode<N>>) l.valid = n.bounds[0][i] <= n.bounds[1][i];
      else l.valid = (n.valid >> i) & 1u;
      out.push_back(l);
    }
  }
}
}  // namespace

std::vector<Bvh::WideLane> Bvh::wide_lanes() const {
  std::vector<WideLane> out;
  append_lanes<4>(nodes4_, out);
  append_lanes<8>(nodes8_, out);
  append_lanes<4>(nodes4q_, out);
  append_lanes<8>(nodes8q_, out);
  return out;
}

bool Bvh::intersect_binary(const Ray& ray, Hit& hit, TraversalCounters* counters) const {
  if (nodes_.empty()) return false;
  const Vec3 inv = safe_inverse(ray.dir);
  const RayPrecomp rp(ray.dir);
  float tmax = ray.tmax;
  uint32_t best = UINT32_MAX;
  float bb1 = 0, bb2 = 0;
  struct Entry {
    uint32_t node;
    float t;
  } stack[kStackSize];
  int sp = 0;
  uint32_t ni = 0;
  if (intersect_node(nodes_[0], ray.org, inv, tmax) == kInf) return false;
  for (;;) {
    const BvhNode& n = nodes_[ni];
    if (counters) counters->nodes++;
    if (n.is_leaf()) {
      for (uint32_t i = n.left_or_first, e = n.left_or_first + n.count; i < e; ++i) {
        const TriangleVerts& tv = tris_[i];
        float t, b1, b2;
        if (intersect_triangle(ray.org, rp, tv.v0, tv.v1, tv.v2, tmax, t, b1, b2)) {
          tmax = t;
          best = i;
          bb1 = b1;
          bb2 = b2;
        }
      }
      if (counters) counters->triangles += n.count;
    } else {
      uint32_t c0 = n.left_or_first, c1 = c0 + 1;
      float d0 = intersect_node(nodes_[c0], ray.org, inv, tmax);
      float d1 = intersect_node(nodes_[c1], ray.org, inv, tmax);
      if (d0 > d1) {
        std::swap(d0, d1);
        std::swap(c0, c1);
      }
      if (d0 != kInf) {
        if (d1 != kInf) stack[sp++] = {c1, d1};
        ni = c0;
        continue;
      }
    }
    // Pop the next node that can still hold a closer hit.
    do {
      if (sp == 0) goto done;
      --sp;
    } while (stack[sp].t >= tmax);
    ni = stack[sp].node;
  }
done:
  if (best == UINT32_MAX) return false;
  hit.t = tmax;
  hit.b1 = bb1;
  hit.b2 = bb2;
  hit.prim = prim_ids_[best];
  return true;
}

bool Bvh::occluded_binary(const Ray& ray) const {
  if (nodes_.empty()) return false;
  const Vec3 inv = safe_inverse(ray.dir);
  const RayPrecomp rp(ray.dir);
  uint32_t stack[kStackSize];
  int sp = 0;
  uint32_t ni = 0;
  if (intersect_node(nodes_[0], ray.org, inv, ray.tmax) == kInf) return false;
  for (;;) {
    const BvhNode& n = nodes_[ni];
    if (n.is_leaf()) {
      for (uint32_t i = n.left_or_first, e = n.left_or_first + n.count; i < e; ++i) {
        const TriangleVerts& tv = tris_[i];
        float t, b1, b2;
        if (intersect_triangle(ray.org, rp, tv.v0, tv.v1, tv.v2, ray.tmax, t, b1, b2, /*any_hit=*/true)) return true;
      }
    } else {
      const uint32_t c0 = n.left_or_first, c1 = c0 + 1;
      const bool h0 = intersect_node(nodes_[c0], ray.org, inv, ray.tmax) != kInf;
      const bool h1 = intersect_node(nodes_[c1], ray.org, inv, ray.tmax) != kInf;
      if (h0 || h1) {
        if (h0 && h1) stack[sp++] = c1;
        ni = h0 ? c0 : c1;
        continue;
      }
    }
    if (sp == 0) break;
    ni = stack[--sp];
  }
  return false;
}

}  // namespace pl
