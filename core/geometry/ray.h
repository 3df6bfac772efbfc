// Rays, hits and the self-intersection-safe offset of spawned rays.
#pragma once
#include <cstdint>
#include <cstring>
#include <limits>

#include "util/math.h"

namespace pl {

struct Ray {
  Vec3 org;
  Vec3 dir;
  float tmax = kInf;
  // Time in the shutter, 0..1 (motion blur): read only by instances that move.
  float time = 0.5f;
  // The strand a ray leaves (CurvePiece::curve), none: UINT32_MAX. Curve traversal skips all of
  // it, as Cycles skips the primitive (object and curve) a ray leaves. A point cloud's sphere:
  // its point index | kSelfPointBit (geometry/points.h), skipped by the point traversal.
  uint32_t self_curve = UINT32_MAX;
};

struct Hit {
  float t = kInf;
  float b1 = 0, b2 = 0;          // barycentrics of vertices 1 and 2
  uint32_t prim = UINT32_MAX;    // triangle index in the BVH's input (a BLAS's triangle under a Tlas)
  uint32_t inst = 0;             // instance (set by the top level and the scene; 0 for a lone Bvh)
  bool valid() const { return prim != UINT32_MAX; }
};

// Floating-point error bounds (pbrt-v4): gamma(n) bounds the relative error of n operations.
constexpr float kMachineEpsilon = std::numeric_limits<float>::epsilon() * 0.5f;
constexpr float gamma_bound(int n) { return (n * kMachineEpsilon) / (1.0f - n * kMachineEpsilon); }

inline float next_float_up(float v) {
  if (std::isinf(v) && v > 0.0f) return v;
  if (v == -0.0f) v = 0.0f;
  uint32_t bits;
  std::memcpy(&bits, &v, sizeof(float));
  bits = v >= 0.0f ? bits + 1 : bits - 1;
  std::memcpy(&v, &bits, sizeof(float));
  return v;
}
inline float next_float_down(float v) {
  if (std::isinf(v) && v < 0.0f) return v;
  if (v == 0.0f) v = -0.0f;
  uint32_t bits;
  std::memcpy(&bits, &v, sizeof(float));
  bits = v > 0.0f ? bits - 1 : bits + 1;
  std::memcpy(&v, &bits, sizeof(float));
  return v;
}

// Bound of the rounding error of p = b0 v0 + b1 v1 + b2 v2 computed in float.
[[gnu::always_inline]] inline Vec3 barycentric_error(const Vec3& v0, const Vec3& v1, const Vec3& v2, float b0, float b1, float b2) {
  return (vabs(v0 * b0) + vabs(v1 * b1) + vabs(v2 * b2)) * gamma_bound(7);
}

// Moves a surface point off its surface, to the side of `n`, by just more than the error bound
// of its coordinates (pbrt-v4's OffsetRayOrigin): a ray leaving from there cannot re-hit the
// surface (with the triangle test's own conservative t bound), at any scene scale.
[[gnu::always_inline]] inline Vec3 offset_ray_origin(Vec3 p, Vec3 p_error, Vec3 n) {  // hot: see Sampler::get2d
  const float len = length(n);
  if (!(len > 0.0f)) return p;
  n = n / len;
  const float d = dot(vabs(n), p_error);
  const Vec3 offset = n * d;
  Vec3 po = p + offset;
  for (int i = 0; i < 3; ++i) {
    if (offset[i] > 0.0f) po[i] = next_float_up(po[i]);
    else if (offset[i] < 0.0f) po[i] = next_float_down(po[i]);
  }
  return po;
}

}  // namespace pl
