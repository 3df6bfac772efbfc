// Per-ray set-up shared by every BVH traversal, so the binary and the wide trees test boxes
// with the same arithmetic and report the same hits. Internal linkage (static): this header is
// also compiled for AVX2 in bvh8_avx2.cpp, and an out-of-line AVX2 copy must never be linked
// into code that runs on other CPUs.
#pragma once
#include <algorithm>
#include <cmath>

#include "geometry/bvh.h"
#include "geometry/ray.h"

namespace pl {
namespace bvh_detail {

// Conservative slab exit (pbrt's 1 + 2 gamma(3)) so float rounding never culls a grazing hit.
constexpr float kBoxExitScale = 1.0000004f;

// Inverse direction with tiny components clamped: an infinite inverse would turn an origin
// lying exactly on a slab plane into 0 * inf = NaN and cull a box the ray does hit.
static inline Vec3 safe_inverse(const Vec3& d) {
  auto inv = [](float v) { return 1.0f / (std::fabs(v) < 1e-20f ? std::copysign(1e-20f, v) : v); };
  return {inv(d.x), inv(d.y), inv(d.z)};
}

// Slab test of a binary node's box (the binary BVH and the top level); returns the entry
// distance or +inf on a miss.
static inline float intersect_node(const BvhNode& n, const Vec3& org, const Vec3& inv, float tmax) {
  const float tx0 = (n.lo.x - org.x) * inv.x, tx1 = (n.hi.x - org.x) * inv.x;
  const float ty0 = (n.lo.y - org.y) * inv.y, ty1 = (n.hi.y - org.y) * inv.y;
  const float tz0 = (n.lo.z - org.z) * inv.z, tz1 = (n.hi.z - org.z) * inv.z;
  const float tmin = std::max(std::max(std::min(tx0, tx1), std::min(ty0, ty1)), std::max(std::min(tz0, tz1), 0.0f));
  const float tfar = std::min(std::min(std::max(tx0, tx1), std::max(ty0, ty1)), std::min(std::max(tz0, tz1), tmax)) *
                     kBoxExitScale;
  return tmin <= tfar ? tmin : kInf;
}

constexpr int kMaxGatherWidth = 8;  // the widest node collapsed

// The children of a wide node collapsed from binary node `b` (its index when it is a leaf: one
// lane): its two children, then the interior child with the largest box replaced by its two
// children while fewer than `width` lanes are used. Returns the lane count.
static inline int gather_wide_children(const BvhNode* bin, uint32_t b, uint32_t* kids, int width) {
  int k = 0;
  if (bin[b].is_leaf()) {
    kids[k++] = b;
    return k;
  }
  // Each lane's opening priority computed once, when the lane is added (not again on every
  // round): the same value, so the same lanes are opened in the same order. Leaves: -1, never
  // opened (boxes are never inverted: areas are >= 0 or NaN, which is never opened either).
  float prio[kMaxGatherWidth];
  const auto priority = [&](uint32_t n) {
    const BvhNode& c = bin[n];
    if (c.is_leaf()) return -1.0f;
    float a = Aabb{c.lo, c.hi}.half_area();
    // A child whose two children are leaves would become a wide node of two lanes: opened
    // first, it costs this node one lane and saves a node and a traversal step.
    if (bin[c.left_or_first].is_leaf() && bin[c.left_or_first + 1].is_leaf()) a *= 4.0f;
    return a;
  };
  width = std::min(width, kMaxGatherWidth);
  for (uint32_t c = bin[b].left_or_first; c < bin[b].left_or_first + 2; ++c) {
    prio[k] = priority(c);
    kids[k++] = c;
  }
  while (k < width) {
    int open = -1;
    float best = -1.0f;
    for (int i = 0; i < k; ++i)
      if (prio[i] > best) {
        best = prio[i];
        open = i;
      }
    if (open < 0) break;
    const uint32_t l = bin[kids[open]].left_or_first;
    kids[open] = l;
    prio[open] = priority(l);
    kids[k] = l + 1;
    prio[k++] = priority(l + 1);
  }
  return k;
}

}  // namespace bvh_detail
}  // namespace pl
