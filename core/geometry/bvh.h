// Binary bounding volume hierarchy over triangles, built with the binned surface area
// heuristic (Wald 2007) and traversed front to back. It knows triangles only: hits name
// triangle indices, and everything else (materials, lights) lives in the scene layer.
#pragma once
#include <cstdint>
#include <vector>

#include "geometry/aabb.h"
#include "geometry/ray.h"

namespace pl {

struct TriangleVerts {
  Vec3 v0, v1, v2;
};

// 32 bytes: two nodes per cache line. Children of an interior node are stored side by side.
struct BvhNode {
  Vec3 lo;
  uint32_t left_or_first;  // interior: index of the left child (right = left + 1); leaf: first triangle
  Vec3 hi;
  uint32_t count;          // 0 for interior nodes
  bool is_leaf() const { return count != 0; }
};

struct BvhBuildOptions {
  int bins = 32;
  int max_leaf_size = 8;
  float traversal_cost = 1.0f;  // SAH cost of visiting a node, relative to one triangle test
  int threads = 0;              // 0 = hardware threads
};

struct BvhStats {
  size_t nodes = 0, leaves = 0, max_depth = 0;
  double sah_cost = 0.0;  // expected cost of a random ray, in triangle tests (traversal weighted)
  double build_ms = 0.0;
};

// Counters for BVH visualisation and statistics.
struct TraversalCounters {
  uint32_t nodes = 0, triangles = 0;
};

class Bvh {
 public:
  // Builds over `tris`; triangle i of the input is reported as hit.prim == i.
  void build(const std::vector<TriangleVerts>& tris, const BvhBuildOptions& opt = {});
  bool empty() const { return nodes_.empty(); }
  const BvhStats& stats() const { return stats_; }
  Aabb bounds() const;
  size_t memory_bytes() const;

  // Closest hit with 0 < t < ray.tmax. Returns true on a hit and fills `hit`.
  bool intersect(const Ray& ray, Hit& hit, TraversalCounters* counters = nullptr) const;
  // Any hit with 0 < t < ray.tmax (shadow rays): stops at the first one found.
  bool occluded(const Ray& ray) const;

 private:
  std::vector<BvhNode> nodes_;
  std::vector<TriangleVerts> tris_;   // in leaf order, for locality
  std::vector<uint32_t> prim_ids_;    // leaf order -> input index
  BvhStats stats_;
};

}  // namespace pl
