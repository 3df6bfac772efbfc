#include "geometry/bvh.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <functional>
#include <thread>

#include "geometry/triangle.h"

namespace pl {
namespace {

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
  Aabb bounds;
  uint32_t count = 0;
};

class Builder {
 public:
  Builder(const std::vector<TriangleVerts>& tris, const BvhBuildOptions& opt, std::vector<BvhNode>& nodes,
          std::vector<uint32_t>& order)
      : opt_(opt), nodes_(nodes), order_(order) {
    const uint32_t n = static_cast<uint32_t>(tris.size());
    prim_bounds_.resize(n);
    centroids_.resize(n);
    order_.resize(n);
    for (uint32_t i = 0; i < n; ++i) {
      Aabb b;
      b.grow(tris[i].v0);
      b.grow(tris[i].v1);
      b.grow(tris[i].v2);
      prim_bounds_[i] = b;
      centroids_[i] = b.lo * 0.5f + b.hi * 0.5f;  // (lo + hi) / 2 would overflow near FLT_MAX
      order_[i] = i;
    }
    nodes_.resize(std::max<size_t>(1, 2 * size_t(n)));
    opt_.bins = std::clamp(opt_.bins, 2, kMaxBins);
    opt_.max_leaf_size = std::clamp(opt_.max_leaf_size, 1, 255);
    int hw = opt.threads > 0 ? opt.threads : static_cast<int>(std::thread::hardware_concurrency());
    parallel_depth_ = 0;
    while ((1 << parallel_depth_) < std::max(1, hw)) ++parallel_depth_;
  }

  void run() {
    next_node_ = 1;
    build(0, 0, static_cast<uint32_t>(order_.size()), 0);
    nodes_.resize(next_node_.load());
    nodes_.shrink_to_fit();
  }

  size_t max_depth() const { return max_depth_.load(); }

 private:
  void make_leaf(BvhNode& node, uint32_t begin, uint32_t end) {
    node.left_or_first = begin;
    node.count = end - begin;
  }

  void build(uint32_t node_index, uint32_t begin, uint32_t end, int depth) {
    size_t d = max_depth_.load();
    while (size_t(depth) > d && !max_depth_.compare_exchange_weak(d, size_t(depth))) {}

    Aabb bounds, cbounds;
    for (uint32_t i = begin; i < end; ++i) {
      bounds.grow(prim_bounds_[order_[i]]);
      cbounds.grow(centroids_[order_[i]]);
    }
    BvhNode& node = nodes_[node_index];
    node.lo = bounds.lo;
    node.hi = bounds.hi;
    const uint32_t n = end - begin;
    if (n <= 1 || (n <= uint32_t(opt_.max_leaf_size) && depth >= kMaxDepth)) return make_leaf(node, begin, end);

    uint32_t mid = split(bounds, cbounds, begin, end, depth);
    if (mid == begin) return make_leaf(node, begin, end);  // the SAH prefers a leaf

    const uint32_t left = next_node_.fetch_add(2);
    node.left_or_first = left;
    node.count = 0;
    if (depth < parallel_depth_ && n >= kParallelMin) {
      std::thread t([&] { build(left, begin, mid, depth + 1); });
      build(left + 1, mid, end, depth + 1);
      t.join();
    } else {
      build(left, begin, mid, depth + 1);
      build(left + 1, mid, end, depth + 1);
    }
  }

  // Returns the partition point, or `begin` when a leaf is cheaper (and allowed).
  uint32_t split(const Aabb& bounds, const Aabb& cbounds, uint32_t begin, uint32_t end, int depth) {
    const uint32_t n = end - begin;
    const Vec3 ext = cbounds.extent();
    const bool too_deep = depth >= kMaxDepth;
    if (max_component(ext) <= 0.0f || too_deep) {
      // All centroids coincide (or the tree is too deep): no plane separates them. Split by
      // count when the range is too big for a leaf, so leaves stay bounded.
      if (n <= uint32_t(opt_.max_leaf_size)) return begin;
      return begin + n / 2;
    }
    const int B = opt_.bins;
    float best_cost = kInf;
    int best_axis = -1, best_bin = 0;
    for (int axis = 0; axis < 3; ++axis) {
      if (ext[axis] <= 0.0f) continue;
      Bin bins[kMaxBins];
      const float scale = B / ext[axis], lo = cbounds.lo[axis];
      for (uint32_t i = begin; i < end; ++i) {
        const uint32_t p = order_[i];
        const int b = bin_of(centroids_[p][axis], lo, scale, B);
        bins[b].count++;
        bins[b].bounds.grow(prim_bounds_[p]);
      }
      // Sweep from the right, then from the left, evaluating every plane between bins.
      float right_cost[kMaxBins];
      Aabb acc;
      uint32_t cnt = 0;
      for (int b = B - 1; b > 0; --b) {
        acc.grow(bins[b].bounds);
        cnt += bins[b].count;
        right_cost[b] = cnt ? acc.half_area() * cnt : 0.0f;
      }
      acc = Aabb();
      cnt = 0;
      for (int b = 0; b < B - 1; ++b) {
        acc.grow(bins[b].bounds);
        cnt += bins[b].count;
        if (cnt == 0 || cnt == n) continue;
        const float cost = acc.half_area() * cnt + right_cost[b + 1];
        if (cost < best_cost) {
          best_cost = cost;
          best_axis = axis;
          best_bin = b + 1;
        }
      }
    }
    const float parent_area = bounds.half_area();
    const float leaf_cost = static_cast<float>(n);
    const float split_cost =
        best_axis < 0 ? kInf : opt_.traversal_cost + (parent_area > 0 ? best_cost / parent_area : 0.0f);
    if (best_axis < 0 || (split_cost >= leaf_cost && n <= uint32_t(opt_.max_leaf_size))) {
      if (n <= uint32_t(opt_.max_leaf_size)) return begin;
      return begin + n / 2;  // no useful plane and too many for a leaf
    }
    const float scale = B / ext[best_axis], lo = cbounds.lo[best_axis];
    auto it = std::partition(order_.begin() + begin, order_.begin() + end, [&](uint32_t p) {
      return bin_of(centroids_[p][best_axis], lo, scale, B) < best_bin;
    });
    const uint32_t mid = static_cast<uint32_t>(it - order_.begin());
    if (mid == begin || mid == end) return begin + n / 2;
    return mid;
  }

  BvhBuildOptions opt_;
  std::vector<BvhNode>& nodes_;
  std::vector<uint32_t>& order_;
  std::vector<Aabb> prim_bounds_;
  std::vector<Vec3> centroids_;
  std::atomic<uint32_t> next_node_{1};
  std::atomic<size_t> max_depth_{0};
  int parallel_depth_ = 0;
};

// Slab test; returns the entry distance or +inf on a miss.
inline float intersect_node(const BvhNode& n, const Vec3& org, const Vec3& inv, float tmax) {
  const float tx0 = (n.lo.x - org.x) * inv.x, tx1 = (n.hi.x - org.x) * inv.x;
  const float ty0 = (n.lo.y - org.y) * inv.y, ty1 = (n.hi.y - org.y) * inv.y;
  const float tz0 = (n.lo.z - org.z) * inv.z, tz1 = (n.hi.z - org.z) * inv.z;
  const float tmin = std::max(std::max(std::min(tx0, tx1), std::min(ty0, ty1)), std::max(std::min(tz0, tz1), 0.0f));
  // Conservative exit (pbrt's 1 + 2 gamma(3)) so float rounding never culls a grazing hit.
  const float tfar = std::min(std::min(std::max(tx0, tx1), std::max(ty0, ty1)), std::min(std::max(tz0, tz1), tmax)) *
                     1.0000004f;
  return tmin <= tfar ? tmin : kInf;
}

// Inverse direction with tiny components clamped: an infinite inverse would turn an origin
// lying exactly on a slab plane into 0 * inf = NaN and cull a box the ray does hit.
inline Vec3 safe_inverse(const Vec3& d) {
  auto inv = [](float v) { return 1.0f / (std::fabs(v) < 1e-20f ? std::copysign(1e-20f, v) : v); };
  return {inv(d.x), inv(d.y), inv(d.z)};
}

}  // namespace

void Bvh::build(const std::vector<TriangleVerts>& tris, const BvhBuildOptions& opt) {
  const auto t0 = std::chrono::steady_clock::now();
  nodes_.clear();
  tris_.clear();
  prim_ids_.clear();
  stats_ = {};
  if (tris.empty()) return;
  Builder builder(tris, opt, nodes_, prim_ids_);
  builder.run();
  tris_.resize(prim_ids_.size());
  for (size_t i = 0; i < prim_ids_.size(); ++i) tris_[i] = tris[prim_ids_[i]];

  stats_.nodes = nodes_.size();
  stats_.max_depth = builder.max_depth();
  const float root_area = std::max(Aabb{nodes_[0].lo, nodes_[0].hi}.half_area(), 1e-30f);
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
  stats_.build_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
}

Aabb Bvh::bounds() const {
  if (nodes_.empty()) return {};
  return {nodes_[0].lo, nodes_[0].hi};
}

size_t Bvh::memory_bytes() const {
  return nodes_.capacity() * sizeof(BvhNode) + tris_.capacity() * sizeof(TriangleVerts) +
         prim_ids_.capacity() * sizeof(uint32_t);
}

bool Bvh::intersect(const Ray& ray, Hit& hit, TraversalCounters* counters) const {
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

bool Bvh::occluded(const Ray& ray) const {
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
        if (intersect_triangle(ray.org, rp, tv.v0, tv.v1, tv.v2, ray.tmax, t, b1, b2)) return true;
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
