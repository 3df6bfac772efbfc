#include "geometry/bvh.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <functional>
#include <thread>

#include "geometry/bvh_common.h"
#include "geometry/triangle.h"
#if defined(__x86_64__) || defined(__i386__)
#include "geometry/bvh_wide.inl"
#endif

namespace pl {
namespace {

using bvh_detail::safe_inverse;

constexpr int kMaxBins = 64;
constexpr int kStackSize = 128;
// Beyond this depth splits are by count (halving), which adds at most 32 more levels, so
// traversal stacks of kStackSize entries never overflow.
constexpr int kMaxDepth = 64;
constexpr uint32_t kParallelMin = 16384;  // subtrees smaller than this are built serially

// Clamped before the cast: a float outside int's range (or NaN) must never become an index.
inline int bin_of(float c, float lo, float scale, int bins) {
  const float f = (c - lo) * scale;
  return f > 0.0f ? (f < float(bins - 1) ? static_cast<int>(f) : bins - 1) : 0;
}

struct Bin {
  Aabb bounds, cbounds;  // of the triangles, and of their centroids
  uint32_t count = 0;
};

// A triangle's box and input index, moved (not pointed to) by the partitions: every binning
// pass then reads memory in order.
struct PrimRef {
  Vec3 lo;
  uint32_t id;
  Vec3 hi;
  uint32_t pad;
  Vec3 centroid() const { return lo * 0.5f + hi * 0.5f; }  // (lo + hi) / 2 would overflow near FLT_MAX
};

class Builder {
 public:
  Builder(const std::vector<TriangleVerts>& tris, const BvhBuildOptions& opt, std::vector<BvhNode>& nodes,
          std::vector<uint32_t>& order)
      : opt_(opt), nodes_(nodes), order_(order) {
    const uint32_t n = static_cast<uint32_t>(tris.size());
    refs_.resize(n);
    for (uint32_t i = 0; i < n; ++i) {
      Aabb b;
      b.grow(tris[i].v0);
      b.grow(tris[i].v1);
      b.grow(tris[i].v2);
      refs_[i] = {b.lo, i, b.hi, 0};
    }
    nodes_.resize(std::max<size_t>(1, 2 * size_t(n)));
    opt_.bins = std::clamp(opt_.bins, 2, kMaxBins);
    opt_.max_leaf_size = std::clamp(opt_.max_leaf_size, 1, 255);
    block_ = static_cast<uint32_t>(std::clamp(opt_.leaf_block, 1, 16));
    int hw = opt.threads > 0 ? opt.threads : static_cast<int>(std::thread::hardware_concurrency());
    // Four times as many subtrees as threads, so an unbalanced split leaves no core idle for long.
    parallel_depth_ = 2;
    while ((1 << parallel_depth_) < 4 * std::max(1, hw)) ++parallel_depth_;
  }

  // Returns false when cancelled (the nodes are then incomplete and must be dropped).
  bool run() {
    next_node_ = 1;
    Aabb bounds, cbounds;
    range_bounds(0, static_cast<uint32_t>(refs_.size()), bounds, cbounds);
    build(0, 0, static_cast<uint32_t>(refs_.size()), 0, bounds, cbounds);
    if (cancelled()) return false;
    nodes_.resize(next_node_.load());
    nodes_.shrink_to_fit();
    order_.resize(refs_.size());
    for (size_t i = 0; i < refs_.size(); ++i) order_[i] = refs_[i].id;
    return true;
  }

  size_t max_depth() const { return max_depth_.load(); }

 private:
  // Triangle tests of a leaf of n triangles (n / block rounded up: a partial block costs a whole one).
  float tests(uint32_t n) const { return static_cast<float>((n + block_ - 1) / block_); }

  bool cancelled() const { return opt_.cancel && opt_.cancel->load(std::memory_order_relaxed); }

  void range_bounds(uint32_t begin, uint32_t end, Aabb& bounds, Aabb& cbounds) const {
    bounds = cbounds = Aabb();
    for (uint32_t i = begin; i < end; ++i) {
      bounds.grow(Aabb{refs_[i].lo, refs_[i].hi});
      cbounds.grow(refs_[i].centroid());
    }
  }

  void make_leaf(BvhNode& node, uint32_t begin, uint32_t end) {
    node.left_or_first = begin;
    node.count = end - begin;
  }

  struct Split {
    uint32_t mid;
    Aabb lb, lcb, rb, rcb;  // bounds and centroid bounds of both sides
  };

  void build(uint32_t node_index, uint32_t begin, uint32_t end, int depth, const Aabb& bounds, const Aabb& cbounds) {
    // Every node polls the flag: one relaxed load against a binning pass over its triangles.
    if (cancelled()) return;
    size_t d = max_depth_.load();
    while (size_t(depth) > d && !max_depth_.compare_exchange_weak(d, size_t(depth))) {}

    BvhNode& node = nodes_[node_index];
    node.lo = bounds.lo;
    node.hi = bounds.hi;
    const uint32_t n = end - begin;
    if (n <= 1 || (n <= uint32_t(opt_.max_leaf_size) && depth >= kMaxDepth)) return make_leaf(node, begin, end);

    Split sp;
    if (!split(bounds, cbounds, begin, end, depth, sp)) return make_leaf(node, begin, end);  // the SAH prefers a leaf

    const uint32_t left = next_node_.fetch_add(2);
    node.left_or_first = left;
    node.count = 0;
    const uint32_t mid = sp.mid;
    if (depth < parallel_depth_ && n >= kParallelMin) {
      std::thread t([&] { build(left, begin, mid, depth + 1, sp.lb, sp.lcb); });
      build(left + 1, mid, end, depth + 1, sp.rb, sp.rcb);
      t.join();
    } else {
      build(left, begin, mid, depth + 1, sp.lb, sp.lcb);
      build(left + 1, mid, end, depth + 1, sp.rb, sp.rcb);
    }
  }

  bool split_by_count(uint32_t begin, uint32_t end, Split& sp) const {
    sp.mid = begin + (end - begin) / 2;
    range_bounds(begin, sp.mid, sp.lb, sp.lcb);
    range_bounds(sp.mid, end, sp.rb, sp.rcb);
    return true;
  }

  // Fills `sp` and returns true, or returns false when a leaf is cheaper (and allowed).
  bool split(const Aabb& bounds, const Aabb& cbounds, uint32_t begin, uint32_t end, int depth, Split& sp) {
    const uint32_t n = end - begin;
    const Vec3 ext = cbounds.extent();
    const bool too_deep = depth >= kMaxDepth;
    if (max_component(ext) <= 0.0f || too_deep) {
      // All centroids coincide (or the tree is too deep): no plane separates them. Split by
      // count when the range is too big for a leaf, so leaves stay bounded.
      if (n <= uint32_t(opt_.max_leaf_size)) return false;
      return split_by_count(begin, end, sp);
    }
    const int B = opt_.bins;
    // All three axes binned in one pass over the triangles.
    Bin bins[3][kMaxBins];
    float scale[3], lo[3];
    for (int axis = 0; axis < 3; ++axis) {
      scale[axis] = ext[axis] > 0.0f ? B / ext[axis] : 0.0f;
      lo[axis] = cbounds.lo[axis];
    }
    for (uint32_t i = begin; i < end; ++i) {
      const PrimRef& r = refs_[i];
      const Vec3 c = r.centroid();
      const Aabb pb{r.lo, r.hi};
      for (int axis = 0; axis < 3; ++axis) {
        Bin& bin = bins[axis][bin_of(c[axis], lo[axis], scale[axis], B)];
        bin.count++;
        bin.bounds.grow(pb);
        bin.cbounds.grow(c);
      }
    }
    float best_cost = kInf;
    int best_axis = -1, best_bin = 0;
    for (int axis = 0; axis < 3; ++axis) {
      if (ext[axis] <= 0.0f) continue;
      // Sweep from the right, then from the left, evaluating every plane between bins.
      float right_cost[kMaxBins];
      Aabb acc;
      uint32_t cnt = 0;
      for (int b = B - 1; b > 0; --b) {
        acc.grow(bins[axis][b].bounds);
        cnt += bins[axis][b].count;
        right_cost[b] = cnt ? acc.half_area() * tests(cnt) : 0.0f;
      }
      acc = Aabb();
      cnt = 0;
      for (int b = 0; b < B - 1; ++b) {
        acc.grow(bins[axis][b].bounds);
        cnt += bins[axis][b].count;
        if (cnt == 0 || cnt == n) continue;
        const float cost = acc.half_area() * tests(cnt) + right_cost[b + 1];
        if (cost < best_cost) {
          best_cost = cost;
          best_axis = axis;
          best_bin = b + 1;
        }
      }
    }
    const float parent_area = bounds.half_area();
    const float leaf_cost = tests(n);
    const float split_cost =
        best_axis < 0 ? kInf : opt_.traversal_cost + (parent_area > 0 ? best_cost / parent_area : 0.0f);
    if (best_axis < 0 || (split_cost >= leaf_cost && n <= uint32_t(opt_.max_leaf_size))) {
      if (n <= uint32_t(opt_.max_leaf_size)) return false;
      return split_by_count(begin, end, sp);  // no useful plane and too many for a leaf
    }
    const int ax = best_axis;
    auto it = std::partition(refs_.begin() + begin, refs_.begin() + end, [&](const PrimRef& r) {
      return bin_of(r.centroid()[ax], lo[ax], scale[ax], B) < best_bin;
    });
    sp.mid = static_cast<uint32_t>(it - refs_.begin());
    if (sp.mid == begin || sp.mid == end) return split_by_count(begin, end, sp);
    sp.lb = sp.lcb = sp.rb = sp.rcb = Aabb();
    for (int b = 0; b < B; ++b) {
      (b < best_bin ? sp.lb : sp.rb).grow(bins[ax][b].bounds);
      (b < best_bin ? sp.lcb : sp.rcb).grow(bins[ax][b].cbounds);
    }
    return true;
  }

  BvhBuildOptions opt_;
  std::vector<BvhNode>& nodes_;
  std::vector<uint32_t>& order_;
  std::vector<PrimRef> refs_;
  std::atomic<uint32_t> next_node_{1};
  std::atomic<size_t> max_depth_{0};
  int parallel_depth_ = 0;
  uint32_t block_ = 1;
};

// Slab test; returns the entry distance or +inf on a miss.
inline float intersect_node(const BvhNode& n, const Vec3& org, const Vec3& inv, float tmax) {
  const float tx0 = (n.lo.x - org.x) * inv.x, tx1 = (n.hi.x - org.x) * inv.x;
  const float ty0 = (n.lo.y - org.y) * inv.y, ty1 = (n.hi.y - org.y) * inv.y;
  const float tz0 = (n.lo.z - org.z) * inv.z, tz1 = (n.hi.z - org.z) * inv.z;
  const float tmin = std::max(std::max(std::min(tx0, tx1), std::min(ty0, ty1)), std::max(std::min(tz0, tz1), 0.0f));
  // Conservative exit so float rounding never culls a grazing hit.
  const float tfar = std::min(std::min(std::max(tx0, tx1), std::max(ty0, ty1)), std::min(std::max(tz0, tz1), tmax)) *
                     bvh_detail::kBoxExitScale;
  return tmin <= tfar ? tmin : kInf;
}

// Collapses the binary tree into an N-wide one: each wide node takes a binary node's two
// children and keeps opening its largest interior child (the one most rays enter) until it
// has N children or only leaves (Wald et al. 2008, as in Embree and tinybvh). Leaves stay
// the binary leaves, so triangles and their order are shared.
// Leaves become runs of TriangleBlock4s, emitted in the order the collapse reaches them.
template <int N>
void collapse(const std::vector<BvhNode>& bin, const std::vector<TriangleVerts>& tris,
              const std::vector<uint32_t>& prim_ids, std::vector<WideBvhNode<N>>& out,
              std::vector<TriangleBlock4>& blocks, std::vector<uint32_t>& block_prims) {
  out.clear();
  blocks.clear();
  block_prims.clear();
  out.reserve(bin.size() / (N - 1) + 1);
  struct Item {
    uint32_t bin, wide;
  };
  std::vector<Item> todo{{0, 0}};
  out.emplace_back();
  while (!todo.empty()) {
    const Item it = todo.back();
    todo.pop_back();
    uint32_t kids[N];
    int k = 0;
    if (bin[it.bin].is_leaf()) {
      kids[k++] = it.bin;  // a root that is a leaf: one lane
    } else {
      kids[k++] = bin[it.bin].left_or_first;
      kids[k++] = bin[it.bin].left_or_first + 1;
    }
    while (k < N) {
      int open = -1;
      float best = -1.0f;
      for (int i = 0; i < k; ++i) {
        const BvhNode& c = bin[kids[i]];
        const float a = Aabb{c.lo, c.hi}.half_area();
        if (!c.is_leaf() && a > best) {
          best = a;
          open = i;
        }
      }
      if (open < 0) break;
      const uint32_t l = bin[kids[open]].left_or_first;
      kids[open] = l;
      kids[k++] = l + 1;
    }
    WideBvhNode<N> node;
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
          node.child[i] = static_cast<uint32_t>(blocks.size());
          node.count[i] = c.count;
          for (uint32_t b = 0; b < c.count; b += 4) {
            TriangleBlock4 blk;
            for (uint32_t l = 0; l < 4; ++l) {
              const bool used = b + l < c.count;
              const TriangleVerts& tv = tris[c.left_or_first + (used ? b + l : 0)];
              const Vec3* v[3] = {&tv.v0, &tv.v1, &tv.v2};
              for (int r = 0; r < 9; ++r) blk.v[r][l] = used ? (*v[r / 3])[r % 3] : std::nanf("");
              block_prims.push_back(used ? prim_ids[c.left_or_first + b + l] : UINT32_MAX);
            }
            blocks.push_back(blk);
          }
        } else {
          node.child[i] = static_cast<uint32_t>(out.size());
          node.count[i] = 0;
          todo.push_back({kids[i], node.child[i]});
          out.emplace_back();
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
    out[it.wide] = node;
  }
  out.shrink_to_fit();
  blocks.shrink_to_fit();
  block_prims.shrink_to_fit();
}

}  // namespace

const char* bvh_layout_name(BvhLayout l) {
  switch (l) {
    case BvhLayout::Auto: return "auto";
    case BvhLayout::Binary: return "binary";
    case BvhLayout::Wide4: return "bvh4";
    case BvhLayout::Wide8: return "bvh8";
  }
  return "?";
}

bool cpu_has_avx2() {
#if defined(PL_HAVE_AVX2_KERNEL) && (defined(__x86_64__) || defined(__i386__))
  static const bool has = __builtin_cpu_supports("avx2");
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
#endif

void Bvh::clear() {
  *this = Bvh();
}

bool Bvh::build(const std::vector<TriangleVerts>& tris, const BvhBuildOptions& options) {
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
  Builder builder(tris, opt, nodes_, prim_ids_);
  if (!builder.run()) {
    clear();
    return false;
  }
  tris_.resize(prim_ids_.size());
  for (size_t i = 0; i < prim_ids_.size(); ++i) tris_[i] = tris[prim_ids_[i]];

  bounds_ = {nodes_[0].lo, nodes_[0].hi};
  stats_.nodes = nodes_.size();
  stats_.max_depth = builder.max_depth();
  const float root_area = std::max(bounds_.half_area(), 1e-30f);
  double cost = 0.0;
  for (const BvhNode& n : nodes_) {
    const double rel = Aabb{n.lo, n.hi}.half_area() / root_area;
    if (n.is_leaf()) {
      stats_.leaves++;
      cost += rel * n.count;
    } else {
      cost += rel * opt.traversal_cost;
    }
  }
  stats_.sah_cost = cost;
  if (cancelled()) {
    clear();
    return false;
  }
  if (layout == BvhLayout::Wide4) collapse<4>(nodes_, tris_, prim_ids_, nodes4_, blocks_, block_prims_);
  if (layout == BvhLayout::Wide8) collapse<8>(nodes_, tris_, prim_ids_, nodes8_, blocks_, block_prims_);
  if (layout != BvhLayout::Binary) {
    // The wide tree and its triangle blocks replace the binary tree and its triangle arrays.
    stats_.wide_nodes = layout == BvhLayout::Wide4 ? nodes4_.size() : nodes8_.size();
    std::vector<BvhNode>().swap(nodes_);
    std::vector<TriangleVerts>().swap(tris_);
    std::vector<uint32_t>().swap(prim_ids_);
  }
  triangles_ = tris.size();
  layout_ = stats_.layout = layout;
  stats_.build_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  return true;
}

size_t Bvh::memory_bytes() const {
  return nodes_.capacity() * sizeof(BvhNode) + nodes4_.capacity() * sizeof(Bvh4Node) +
         nodes8_.capacity() * sizeof(Bvh8Node) + tris_.capacity() * sizeof(TriangleVerts) +
         prim_ids_.capacity() * sizeof(uint32_t) + blocks_.capacity() * sizeof(TriangleBlock4) +
         block_prims_.capacity() * sizeof(uint32_t);
}

bool Bvh::intersect(const Ray& ray, Hit& hit, TraversalCounters* counters) const {
  if (triangles_ == 0) return false;
  switch (layout_) {
#if defined(__x86_64__) || defined(__i386__)
    case BvhLayout::Wide8: return bvh8_intersect({nodes8_.data(), blocks_.data(), block_prims_.data()}, ray, hit, counters);
    case BvhLayout::Wide4: return bvh4_intersect({nodes4_.data(), blocks_.data(), block_prims_.data()}, ray, hit, counters);
#endif
    default: return intersect_binary(ray, hit, counters);
  }
}

bool Bvh::occluded(const Ray& ray) const {
  if (triangles_ == 0) return false;
  switch (layout_) {
#if defined(__x86_64__) || defined(__i386__)
    case BvhLayout::Wide8: return bvh8_occluded({nodes8_.data(), blocks_.data(), block_prims_.data()}, ray);
    case BvhLayout::Wide4: return bvh4_occluded({nodes4_.data(), blocks_.data(), block_prims_.data()}, ray);
#endif
    default: return occluded_binary(ray);
  }
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
