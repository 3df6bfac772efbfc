// The 4-wide trees of curves and points (curves.cpp, points.cpp): a binary tree collapsed into
// WideBvhNode<4> (the collapse also builds the TLAS's 8-wide nodes), the per-ray slab test of a
// node's 4 lanes and the nearest-first traversal. Not for bvh8_avx2.cpp: these have external
// linkage, and an AVX2 copy must never be linked into code for other CPUs
// (bvh_common.h).
#pragma once
#include <algorithm>
#include <cstdint>
#include <vector>

#if defined(__SSE2__)
#include <immintrin.h>
#endif

#include "geometry/binned_sah.h"
#include "geometry/bvh_common.h"
#include "geometry/moving_sets.h"
#include "util/parallel.h"

namespace pl {
namespace bvh_detail {

// The binary tree below node b collapsed into W-wide nodes appended to `out` (the largest
// interior child opened first while lanes are free); leaf(c, child, count) fills the lane of a
// binary leaf c. The curves' and points' trees (W = 4) and the TLAS (W = 8).
template <int W, class Leaf>
uint32_t collapse_wide(const std::vector<BvhNode>& bin, uint32_t b, std::vector<WideBvhNode<W>>& out, const Leaf& leaf) {
  uint32_t kids[W];
  const int n = bvh_detail::gather_wide_children(bin.data(), b, kids, W);
  const uint32_t w = uint32_t(out.size());
  out.emplace_back();
  for (int k = 0; k < W; ++k) {
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
      leaf(c, out[w].child[k], out[w].count[k]);
    } else {
      const uint32_t ci = collapse_wide(bin, kids[k], out, leaf);
      out[w].child[k] = ci;
    }
  }
  return w;
}

// The curves' and points' trees: a 4-wide tree over `boxes` (binned SAH, leaves of up to 4,
// halving by count below depth 48); refs: the boxes' indices in leaf order. Returns the
// root's bounds.
inline Aabb build_wide4(const std::vector<Aabb>& boxes, std::vector<WideBvhNode<4>>& nodes, std::vector<uint32_t>& refs) {
  constexpr int kBins = 16;
  constexpr uint32_t kLeafSize = 4;
  const size_t n = boxes.size();
  std::vector<BvhNode> bin;
  std::vector<Vec3> centers(n);
  refs.resize(n);
  for (size_t i = 0; i < n; ++i) {
    centers[i] = boxes[i].center();
    refs[i] = uint32_t(i);
  }
  struct Task {
    uint32_t node, begin, end;
    int depth;
  };
  bin.reserve(2 * n / kLeafSize + 1);
  bin.emplace_back();
  std::vector<Task> todo{{0, 0, uint32_t(n), 0}};
  while (!todo.empty()) {
    const Task tk = todo.back();
    todo.pop_back();
    Aabb b, cb;
    for (uint32_t i = tk.begin; i < tk.end; ++i) {
      b.grow(boxes[refs[i]]);
      cb.grow(centers[refs[i]]);
    }
    bin[tk.node].lo = b.lo;
    bin[tk.node].hi = b.hi;
    const uint32_t cnt = tk.end - tk.begin;
    uint32_t mid = tk.begin;
    if (cnt > kLeafSize) {
      const int axis = max_axis(cb.extent());
      const float lo = cb.lo[axis], ext = cb.extent()[axis];
      // Deep down, halves by count: the depth (and the traversal stack) stays below 48 + log2 n.
      if (ext > 0.0f && tk.depth < 48) {  // binned SAH on the centroids
        mid = binned_sah_partition<kBins>(refs, tk.begin, tk.end, boxes, centers, axis, lo, ext);
      }
      if (mid == tk.begin || mid == tk.end) {
        mid = tk.begin + cnt / 2;
        std::nth_element(refs.begin() + tk.begin, refs.begin() + mid, refs.begin() + tk.end,
                         [&](uint32_t a, uint32_t c) { return centers[a][axis] < centers[c][axis]; });
      }
    }
    if (mid == tk.begin) {
      bin[tk.node].left_or_first = tk.begin;
      bin[tk.node].count = cnt;
      continue;
    }
    const uint32_t left = uint32_t(bin.size());
    bin.emplace_back();
    bin.emplace_back();
    bin[tk.node].left_or_first = left;
    bin[tk.node].count = 0;
    todo.push_back({left, tk.begin, mid, tk.depth + 1});
    todo.push_back({left + 1, mid, tk.end, tk.depth + 1});
  }
  nodes.clear();
  nodes.reserve(bin.size() / 3 + 1);
  collapse_wide(bin, 0, nodes, [](const BvhNode& c, uint32_t& child, uint32_t& count) {
    child = c.left_or_first;
    count = c.count;
  });
  nodes.shrink_to_fit();
  return Aabb{bin[0].lo, bin[0].hi};
}

// Deforming curves and points: a tree per equal slice of the shutter (S of them, built in
// parallel), whose boxes hold each primitive over that slice only: the hull of box_at(i, t) at
// the slice's ends and of step_box(k, i) at the motion steps k inside it (primitives interpolate
// linearly between steps; a box over a thin, fast primitive's whole sweep would be many times
// its size). Returns the union of the slices' bounds.
template <int S, class BoxAt, class StepBox>
Aabb build_wide4_slices(size_t n, uint32_t n_steps, const BoxAt& box_at, const StepBox& step_box,
                        std::vector<WideBvhNode<4>> (&nodes)[S], std::vector<uint32_t> (&refs)[S]) {
  Aabb slice_bounds[S];
  parallel_ranges(size_t(S), 0, [&](size_t begin, size_t end) {  // (independent trees)
    std::vector<Aabb> b(n);
    for (size_t j = begin; j < end; ++j) {
      const float ta = float(j) / float(S), tb = float(j + 1) / float(S);
      for (size_t i = 0; i < n; ++i) {
        b[i] = box_at(uint32_t(i), ta);
        b[i].grow(box_at(uint32_t(i), tb));
        for (uint32_t k = 1; k + 1 < n_steps; ++k) {
          const float tk = float(k) / float(n_steps - 1);
          if (tk > ta && tk < tb) b[i].grow(step_box(k, i));
        }
      }
      slice_bounds[j] = build_wide4(b, nodes[j], refs[j]);
    }
  }, 1);
  Aabb all;
  for (const Aabb& b : slice_bounds) all.grow(b);
  return all;
}

// Whether a ray (inv: its safe inverse direction) enters box b before tmax: the moving sets'
// boxes, with the trees' conservative exit.
inline bool ray_enters_box(const Aabb& b, const Ray& ray, const Vec3& inv, float tmax) {
  float t0 = 0.0f, t1 = tmax;
  for (int a = 0; a < 3; ++a) {
    const float x0 = (b.lo[a] - ray.org[a]) * inv[a], x1 = (b.hi[a] - ray.org[a]) * inv[a];
    t0 = std::max(t0, std::min(x0, x1));
    t1 = std::min(t1, std::max(x0, x1));
  }
  return t0 <= t1 * kBoxExitScale;
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

// Nearest-first traversal of a 4-wide tree (a deforming tree's leaves index primitives through
// refs): leaf(i, tmax) tests primitive i before tmax and returns true on a hit, having
// shortened tmax; AnyHit stops at the first. True if anything was hit.
template <bool AnyHit, class Leaf>
bool traverse_wide4(const std::vector<WideBvhNode<4>>& tree, const uint32_t* refs, const Ray& ray, Leaf&& leaf) {
  if (tree.empty()) return false;
  const LaneTest4 lt(ray, safe_inverse(ray.dir));
  float tmax = ray.tmax;
  bool found = false;
  struct Entry {
    uint32_t id, count;  // count > 0: a leaf of `count` primitives from `id`
    float t;
  };
  // A node pops one entry and pushes at most 4; the tree is under 48 + log2 n binary levels.
  constexpr int kStack = 4 * 128;
  Entry stack[kStack];
  int sp = 0;
  stack[sp++] = {0, 0, 0.0f};
  while (sp > 0) {
    const Entry e = stack[--sp];
    if (!(e.t <= tmax * kBoxExitScale)) continue;
    if (e.count > 0) {
      for (uint32_t k = e.id; k < e.id + e.count; ++k) {
        if (leaf(refs ? refs[k] : k, tmax)) {
          if (AnyHit) return true;
          found = true;
        }
      }
      continue;
    }
    const WideBvhNode<4>& n = tree[e.id];
    alignas(16) float dist[4];
    unsigned mask = lt.test(n, tmax, dist);
    Entry hits[4];
    int nh = 0;
    while (mask) {  // nearest first: pushed farthest first
      const int k = __builtin_ctz(mask);
      mask &= mask - 1;
      const Entry x{n.child[k], n.count[k], dist[k]};
      int j = nh++;
      while (j > 0 && hits[j - 1].t < x.t) {
        hits[j] = hits[j - 1];
        --j;
      }
      hits[j] = x;
    }
    if (sp + nh > kStack) continue;  // unreachable (bounded depth): never overrun
    for (int j = 0; j < nh; ++j) stack[sp++] = hits[j];
  }
  return found;
}

}  // namespace bvh_detail

template <class Tree>
template <bool AnyHit, class Visit>
bool MovingSets<Tree>::traverse(const Ray& ray, Visit&& visit) const {
  bool found = false;
  float tmax = ray.tmax;
  const Vec3 inv = bvh_detail::safe_inverse(ray.dir);
  for (uint32_t m = 0; m < trees.size(); ++m) {
    if (!bvh_detail::ray_enters_box(boxes[m], ray, inv, tmax)) continue;
    Ray ro = ray;
    ro.tmax = tmax;
    Mat4 to_world;
    if (!xf[m].empty()) {
      to_world = motion_transform_at(xf[m].data(), uint32_t(xf[m].size()), ray.time);
      const Mat4 to_object = affine_inverse_fast(to_world);
      ro.org = to_object.point(ray.org);
      ro.dir = to_object.vector(ray.dir);
    }
    if (!visit(m, *trees[m], ro, to_world, tmax)) continue;
    if (AnyHit) return true;
    found = true;
  }
  return found;
}

}  // namespace pl
