// Deformation motion blur: a mesh's triangles at each motion step (same topology), a ray at
// time t meeting each triangle with its corners interpolated linearly between the two steps
// around t (as Cycles' motion triangles). A binary BVH whose boxes hold every triangle over the
// whole shutter (the union of its step boxes: a linearly interpolated triangle stays inside the
// hull of its two steps' corners). Meant for the few deforming objects of a shot; static
// geometry keeps the wide BVH.
#pragma once
#include <array>
#include <cstdint>
#include <vector>

#include "geometry/bvh.h"
#include "geometry/ray.h"

namespace pl {

class DeformBvh {
 public:
  // steps: >= 2 arrays of vertex positions (object space), each as long as the mesh's; prims:
  // the triangles to trace, as vertex indices (the BLAS's order: hit.prim indexes it).
  void build(const std::vector<std::vector<Vec3>>& steps, const std::vector<std::array<uint32_t, 3>>& prims);
  bool empty() const { return nodes_.empty(); }
  Aabb bounds() const { return nodes_.empty() ? Aabb() : Aabb{nodes_[0].lo, nodes_[0].hi}; }
  uint32_t steps() const { return steps_; }
  // Closest hit with 0 < t < ray.tmax at ray.time (prim: index in `prims`).
  bool intersect(const Ray& ray, Hit& hit) const;
  bool occluded(const Ray& ray) const;
  // Triangle `prim` at shutter time `time` (0..1).
  TriangleVerts triangle_at(uint32_t prim, float time) const {
    const uint32_t maxstep = steps_ - 1;
    const float x = clampf(time, 0.0f, 1.0f) * float(maxstep);
    const uint32_t s = std::min(uint32_t(x), maxstep - 1);
    const float f = x - float(s);
    const Vec3* a = &verts_[(size_t(prim) * steps_ + s) * 3];
    const Vec3* b = a + 3;
    return {a[0] * (1.0f - f) + b[0] * f, a[1] * (1.0f - f) + b[1] * f, a[2] * (1.0f - f) + b[2] * f};
  }
  size_t memory_bytes() const {
    return nodes_.capacity() * sizeof(BvhNode) + order_.capacity() * 4 + verts_.capacity() * sizeof(Vec3);
  }

 private:
  template <bool AnyHit>
  bool traverse(const Ray& ray, Hit& hit) const;
  std::vector<BvhNode> nodes_;  // binary, root first; leaves name runs of order_
  std::vector<uint32_t> order_;
  std::vector<Vec3> verts_;     // per prim, per step, its 3 corners
  uint32_t steps_ = 0;
};

}  // namespace pl
