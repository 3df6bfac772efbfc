// Rays, hits and the self-intersection-safe offset of spawned rays.
#pragma once
#include <cstdint>

#include "util/math.h"

namespace pl {

struct Ray {
  Vec3 org;
  Vec3 dir;
  float tmax = kInf;
};

struct Hit {
  float t = kInf;
  float b1 = 0, b2 = 0;          // barycentrics of vertices 1 and 2
  uint32_t prim = UINT32_MAX;    // triangle index in the scene's triangle arrays
  bool valid() const { return prim != UINT32_MAX; }
};

// Offsets a surface point along its geometric normal by an amount proportional to the
// magnitude of its coordinates, so that a ray leaving the surface never re-hits it, at any
// scale (Wächter & Binder, "A Fast and Robust Method for Avoiding Self-Intersection",
// Ray Tracing Gems, 2019). `n` must point to the side the new ray leaves towards.
inline float offset_float(float p, float n) {
  constexpr float origin = 1.0f / 32.0f, float_scale = 1.0f / 65536.0f, int_scale = 256.0f;
  const int of_i = static_cast<int>(int_scale * n);
  int32_t bits;
  std::memcpy(&bits, &p, sizeof(float));
  bits += (p < 0) ? -of_i : of_i;
  float p_i;
  std::memcpy(&p_i, &bits, sizeof(float));
  return std::fabs(p) < origin ? p + float_scale * n : p_i;
}

inline Vec3 offset_ray_origin(Vec3 p, Vec3 n) {
  return {offset_float(p.x, n.x), offset_float(p.y, n.y), offset_float(p.z, n.z)};
}

}  // namespace pl
