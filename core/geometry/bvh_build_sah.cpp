// The binned SAH builder (Wald 2007): the references and root boxes, each node's bins on all
// three axes in one pass (in chunks on several threads near the root), the sweep over the
// bins, the partition, and the recursion (subtrees on threads of their own near the root).
#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <thread>
#include <utility>
#include <vector>
#if defined(__SSE2__)
#include <emmintrin.h>
#endif
#if defined(__AVX__)
#include <immintrin.h>
#endif

#include "geometry/bvh_build.h"
#include "util/big_alloc.h"
#include "util/parallel.h"

namespace pl {
namespace {

// Beyond this depth splits are by count (halving), which adds at most 32 more levels, so
// traversal stacks of kStackSize entries (bvh_traverse.cpp) never overflow.
constexpr int kMaxDepth = 64;
constexpr uint32_t kSmallNode = 32;       // nodes this small clear and sweep only the bins they use
constexpr uint32_t kCopyPartition = 256;  // nodes this small are partitioned through a stack buffer
constexpr uint32_t kAlternateBins = 1024; // ranges this big are binned into two sets alternately

}  // namespace

namespace bvh_detail {

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
Builder::Builder(TriangleSpan tris, const BvhBuildOptions& opt, std::vector<uint32_t>& order)
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
bool Builder::run() {
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

// The bins packed by V4::bins(), keeping the reference's weight (bits 24-31).
uint32_t Builder::pack_bins(uint32_t packed, uint32_t old) {
  return (packed & 0x00ffffffu) | (old & 0xff000000u);
}

void Builder::make_leaf(BvhNode& node, uint32_t begin, uint32_t end) {
  node.left_or_first = begin;
  node.count = end - begin;
}

// Gives each side of an object split a share of the node's spare slots [end, cap_end) in
// proportion to its references, moving the right side up to make the left side's room.
void Builder::place(Split& sp, uint32_t begin, uint32_t end, uint32_t cap_end) {
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
Builder::Built Builder::build(uint32_t node_index, uint32_t begin, uint32_t end, uint32_t cap_end, int depth,
                              const Aabb& bounds, const Aabb& cbounds, uint32_t nt, uint32_t& next) {
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

uint32_t Builder::weight_sum(uint32_t begin, uint32_t end) const {
  uint32_t w = 0;
  for (uint32_t i = begin; i < end; ++i) w += refs_[i].weight();
  return w;
}

bool Builder::split_by_count(uint32_t begin, uint32_t end, Split& sp) const {
  sp.mid = begin + (end - begin) / 2;
  sp.lt = weight_sum(begin, sp.mid);
  sp.rt = weight_sum(sp.mid, end);
  range_bounds(begin, sp.mid, sp.lb, sp.lcb);
  range_bounds(sp.mid, end, sp.rb, sp.rcb);
  return true;
}

// One reference into `bins` (all three axes); the reference keeps its bins.
void Builder::bin_one(PrimRef& r, V4 lo, V4 scale, V4 top, BinSet& bins) {
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
void Builder::bin_range(uint32_t begin, uint32_t end, V4 lo, V4 scale, V4 top, int B, BinSet& bins) {
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
bool Builder::split(const Aabb& bounds, const Aabb& cbounds, uint32_t begin, uint32_t end, uint32_t cap_end,
                    int depth, uint32_t nt, Split& sp) {
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

}  // namespace bvh_detail
}  // namespace pl
