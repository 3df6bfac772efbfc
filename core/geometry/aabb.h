#pragma once
#include "util/math.h"

namespace pl {

struct Aabb {
  Vec3 lo{kInf}, hi{-kInf};
  void grow(const Vec3& p) { lo = vmin(lo, p); hi = vmax(hi, p); }
  void grow(const Aabb& b) { lo = vmin(lo, b.lo); hi = vmax(hi, b.hi); }
  bool empty() const { return lo.x > hi.x || lo.y > hi.y || lo.z > hi.z; }
  Vec3 extent() const { return hi - lo; }
  Vec3 center() const { return (lo + hi) * 0.5f; }
  // Half the surface area: the SAH only uses ratios.
  float half_area() const {
    if (empty()) return 0.0f;
    const Vec3 e = extent();
    return e.x * e.y + e.y * e.z + e.z * e.x;
  }
};

}  // namespace pl
