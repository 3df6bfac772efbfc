// Per-ray set-up shared by every BVH traversal, so the binary and the wide trees test boxes
// with the same arithmetic and report the same hits. Internal linkage (static): this header is
// also compiled for AVX2 in bvh8_avx2.cpp, and an out-of-line AVX2 copy must never be linked
// into code that runs on other CPUs.
#pragma once
#include <cmath>

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

}  // namespace bvh_detail
}  // namespace pl
