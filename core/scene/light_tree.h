// Many-light sampling: a BVH over the finite emitters (analytic lights and emitter groups) with
// bounds on their emitted power, position and emission directions, traversed stochastically by an
// importance that bounds each node's contribution at the shading point (Conty Estevez and Kulla
// 2018, "Importance Sampling of Many Lights with Adaptive Tree Splitting"; the variant pbrt-v4's
// BVHLightSampler and Cycles' light tree follow). Up to kLeafMax emitters per leaf (as Cycles),
// so the probability of an emitter at a point is the product of the child choices on its path
// from the root times its share of its leaf's importance, which pmf() recomputes exactly (the
// same importance function on the same inputs) for MIS.
#pragma once
#include <cstdint>
#include <vector>

#include "geometry/aabb.h"

namespace pl {

// What a node (or one emitter) emits, bounded: positions in `bounds`, total power `phi`, normals
// within theta_o of `w`, emission within theta_e of its normals (pi/2 for a diffuse surface).
struct LightBounds {
  Aabb bounds;
  Vec3 w{0.0f, 0.0f, 1.0f};
  float phi = 0.0f;
  Vec3 moment{0.0f};  // sum of power times position (the tree sets it): the power's centroid
  float cos_theta_o = 1.0f, cos_theta_e = 0.0f;
  bool two_sided = false;
};

// The union of two bounds (the smallest cone around both cones, as pbrt-v4's DirectionCone).
LightBounds light_bounds_union(const LightBounds& a, const LightBounds& b);

class LightTree {
 public:
  LightTree() = default;
  // items[i] bounds emitter i; emitters with phi <= 0 (or non-finite bounds) are left out and
  // have pmf 0 everywhere.
  explicit LightTree(const std::vector<LightBounds>& items);
  bool empty() const { return nodes_.empty(); }
  size_t node_count() const { return nodes_.size(); }
  int depth() const { return depth_; }
  // Picks an emitter at point p with unit normal n (zero: no normal) from u in [0, 1): its index
  // and the probability of that choice. False when no emitter can reach p.
  bool sample(Vec3 p, Vec3 n, float u, uint32_t& item, float& pmf) const;
  // The probability that sample(p, n, .) picks `item`.
  float pmf(Vec3 p, Vec3 n, uint32_t item) const;

 private:
  struct Node {  // a LightBounds with what importance() derives from it precomputed
    Vec3 center, w;
    float radius;  // of the bounding sphere; pbrt-v4's distance-squared floor too
    float phi, cos_theta_o, sin_theta_o, cos_theta_e;
    uint32_t index;  // interior: the second child (the first follows the node); leaf: first slot in items_
    uint8_t leaf, two_sided;  // leaf: how many emitters (items_[index, index + leaf)); 0: interior
  };
  // A leaf's emitters are chosen among by their own importance: exact for each one, where a
  // split below would have bounded pairs of them (up to kLeafMax per leaf).
  static constexpr int kLeafMax = 8;
  double pick_in_leaf(const Node& leaf, Vec3 p, Vec3 n, float u, uint32_t& item) const;
  double pmf_in_leaf(const Node& leaf, Vec3 p, Vec3 n, uint32_t item) const;
  // Not inlined on purpose: sample() and pmf() must round it identically.
  // In double: far nodes' importances underflow float, and both children at 0 ends the walk.
  double importance(const Node& node, Vec3 p, Vec3 n) const;
  uint32_t build(std::vector<std::pair<LightBounds, uint32_t>>& items, size_t begin, size_t end, uint64_t trail,
                 int depth);
  std::vector<Node> nodes_;
  static Node make_node(const LightBounds& b, uint32_t idx, int leaf);
  std::vector<Node> items_;  // one per emitter in the tree, by leaf; index: the emitter
  std::vector<uint64_t> trail_;  // per item: the child choices from the root (bit d at depth d)
  std::vector<uint8_t> in_tree_;
  int depth_ = 0;
};

}  // namespace pl
