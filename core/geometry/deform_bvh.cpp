#include "geometry/deform_bvh.h"

#include <algorithm>

#include "geometry/bvh_common.h"
#include "geometry/triangle.h"

namespace pl {
namespace {

constexpr uint32_t kLeafSize = 4;
constexpr int kStack = 128;

struct Builder {
  std::vector<BvhNode>& nodes;
  std::vector<uint32_t>& order;
  const std::vector<Aabb>& boxes;
  const std::vector<Vec3>& centers;

  // Median splits on the centroids' widest axis: depth stays near log2(n / kLeafSize).
  void build(uint32_t node, uint32_t begin, uint32_t end) {
    Aabb b, cb;
    for (uint32_t i = begin; i < end; ++i) {
      b.grow(boxes[order[i]]);
      cb.grow(centers[order[i]]);
    }
    nodes[node].lo = b.lo;
    nodes[node].hi = b.hi;
    const uint32_t n = end - begin;
    if (n <= kLeafSize || !(max_component(cb.extent()) > 0.0f)) {
      nodes[node].left_or_first = begin;
      nodes[node].count = n;
      return;
    }
    const int axis = max_axis(cb.extent());
    const uint32_t mid = begin + n / 2;
    std::nth_element(order.begin() + begin, order.begin() + mid, order.begin() + end,
                     [&](uint32_t a, uint32_t c) { return centers[a][axis] < centers[c][axis]; });
    const uint32_t left = uint32_t(nodes.size());
    nodes.emplace_back();
    nodes.emplace_back();
    nodes[node].left_or_first = left;
    nodes[node].count = 0;
    build(left, begin, mid);
    build(left + 1, mid, end);
  }
};

}  // namespace

void DeformBvh::build(const std::vector<std::vector<Vec3>>& steps, const std::vector<std::array<uint32_t, 3>>& prims) {
  nodes_.clear();
  order_.clear();
  verts_.clear();
  steps_ = uint32_t(steps.size());
  if (steps_ < 2 || prims.empty()) return;
  const size_t n = prims.size();
  verts_.resize(n * steps_ * 3);
  std::vector<Aabb> boxes(n);
  std::vector<Vec3> centers(n);
  for (size_t p = 0; p < n; ++p) {
    for (uint32_t s = 0; s < steps_; ++s)
      for (int k = 0; k < 3; ++k) {
        const Vec3 v = steps[s][prims[p][size_t(k)]];
        verts_[(p * steps_ + s) * 3 + size_t(k)] = v;
        // Grown by the interpolation's rounding (a few ulps of the corner).
        const Vec3 e = vabs(v) * 4e-7f;
        boxes[p].grow(v - e);
        boxes[p].grow(v + e);
      }
    centers[p] = boxes[p].center();
  }
  order_.resize(n);
  for (size_t p = 0; p < n; ++p) order_[p] = uint32_t(p);
  nodes_.reserve(2 * (n / kLeafSize + 1));
  nodes_.emplace_back();
  Builder{nodes_, order_, boxes, centers}.build(0, 0, uint32_t(n));
}

template <bool AnyHit>
bool DeformBvh::traverse(const Ray& ray, Hit& hit) const {
  if (nodes_.empty()) return false;
  const RayPrecomp rp(ray.dir);
  const Vec3 inv = bvh_detail::safe_inverse(ray.dir);
  float tmax = ray.tmax;
  bool found = false;
  uint32_t stack[kStack];
  int sp = 0;
  stack[sp++] = 0;
  while (sp > 0) {
    const BvhNode& n = nodes_[stack[--sp]];
    if (!(bvh_detail::intersect_node(n, ray.org, inv, tmax) < kInf)) continue;
    if (n.is_leaf()) {
      for (uint32_t i = n.left_or_first; i < n.left_or_first + n.count; ++i) {
        const uint32_t p = order_[i];
        const TriangleVerts tv = triangle_at(p, ray.time);
        float t, b1, b2;
        if (intersect_triangle(ray.org, rp, tv.v0, tv.v1, tv.v2, tmax, t, b1, b2, AnyHit)) {
          if (AnyHit) return true;
          tmax = t;
          hit.t = t;
          hit.b1 = b1;
          hit.b2 = b2;
          hit.prim = p;
          found = true;
        }
      }
      continue;
    }
    if (sp + 2 > kStack) continue;  // cannot happen with median splits (depth < 64)
    stack[sp++] = n.left_or_first + 1;
    stack[sp++] = n.left_or_first;
  }
  return found;
}

bool DeformBvh::intersect(const Ray& ray, Hit& hit) const { return traverse<false>(ray, hit); }

bool DeformBvh::occluded(const Ray& ray) const {
  Hit unused;
  return traverse<true>(ray, unused);
}

}  // namespace pl
