// Curves' and point clouds' sets with motion blur (CurveBvh::add_moving, PointBvh::add_moving):
// each set in a tree of its own (object space when it has transform steps, else world space),
// entered through its transform at the ray's time, its primitives numbered after one another.
#pragma once
#include <algorithm>
#include <cstdint>
#include <memory>
#include <vector>

#include "geometry/aabb.h"
#include "geometry/motion.h"
#include "geometry/ray.h"

namespace pl {

template <class Tree>
struct MovingSets {
  std::vector<std::unique_ptr<Tree>> trees;
  std::vector<std::vector<DecomposedTransform>> xf;  // decomposed steps; none: the set only deforms
  std::vector<Aabb> boxes;                           // world boxes over the shutter
  std::vector<uint32_t> first;                       // each set's first primitive among the moving ones
  uint32_t end = 0;                                  // the moving primitives' count

  bool empty() const { return trees.empty(); }
  uint32_t set_of(uint32_t i) const { return uint32_t(std::upper_bound(first.begin(), first.end(), i) - first.begin()) - 1; }
  // Adds a set of n primitives; returns its world box over the shutter.
  Aabb add(std::unique_ptr<Tree> tree, uint32_t n, std::vector<DecomposedTransform> steps) {
    if (steps.size() < 2) steps.clear();
    const Aabb box = steps.empty() ? tree->bounds() : motion_world_box(tree->bounds(), steps.data(), uint32_t(steps.size()));
    boxes.push_back(box);
    first.push_back(end);
    end += n;
    xf.push_back(std::move(steps));
    trees.push_back(std::move(tree));
    return box;
  }
  // Set m's object-to-world matrix at `time` (identity for a set that only deforms).
  Mat4 transform_at(uint32_t m, float time) const {
    return xf[m].empty() ? Mat4() : motion_transform_at(xf[m].data(), uint32_t(xf[m].size()), time);
  }
  size_t memory_bytes() const {
    size_t b = 0;
    for (const auto& t : trees) b += t->memory_bytes();
    return b;
  }
  // Every set whose box the ray enters before the nearest hit so far, with the ray carried into
  // its space at the ray's time (t is the same parameter there): visit(m, tree, object_ray,
  // to_world, tmax) returns true on a hit before tmax, having shortened tmax; AnyHit stops at
  // the first. (Defined in wide4.h, beside the trees' traversal.)
  template <bool AnyHit, class Visit>
  bool traverse(const Ray& ray, Visit&& visit) const;
};

}  // namespace pl
