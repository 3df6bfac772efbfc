// Watertight ray-triangle intersection (Woop, Benthin & Wald, JCGT 2013): rays through shared
// edges and vertices hit exactly one of the adjacent triangles, never none.
#pragma once
#include <cmath>
#include <utility>

#include "geometry/ray.h"

namespace pl {

// Per-ray constants of the watertight test, computed once per ray.
struct RayPrecomp {
  int kx, ky, kz;
  float sx, sy, sz;
  explicit RayPrecomp(const Vec3& d) {
    const Vec3 a = vabs(d);
    kz = max_axis(a);
    kx = kz == 2 ? 0 : kz + 1;
    ky = kx == 2 ? 0 : kx + 1;
    if (d[kz] < 0.0f) std::swap(kx, ky);  // keep the winding of the projected triangle
    sx = d[kx] / d[kz];
    sy = d[ky] / d[kz];
    sz = 1.0f / d[kz];
    shear = std::sqrt(1.0f + sx * sx + sy * sy);  // |d| / |d[kz]|, in [1, sqrt(3)]
  }
  float shear;
};

// Returns true and fills t, b1, b2 if the ray hits the triangle with 0 < t < tmax.
// any_hit (shadow rays): only a hit certainly before tmax counts, t plus its error bound, so the
// surface a shadow ray ends on cannot block it even when the ray grazes it (t's error grows as
// 1 / cos and a fixed shadow epsilon is then too short).
inline bool intersect_triangle(const Vec3& org, const RayPrecomp& rp, const Vec3& v0, const Vec3& v1,
                               const Vec3& v2, float tmax, float& t_out, float& b1_out, float& b2_out,
                               bool any_hit = false) {
  const Vec3 A = v0 - org, B = v1 - org, C = v2 - org;
  const float ax = A[rp.kx] - rp.sx * A[rp.kz], ay = A[rp.ky] - rp.sy * A[rp.kz];
  const float bx = B[rp.kx] - rp.sx * B[rp.kz], by = B[rp.ky] - rp.sy * B[rp.kz];
  const float cx = C[rp.kx] - rp.sx * C[rp.kz], cy = C[rp.ky] - rp.sy * C[rp.kz];
  float u = cx * by - cy * bx;
  float v = ax * cy - ay * cx;
  float w = bx * ay - by * ax;
  // On an edge the float edge functions can round to zero: redo them in double (the paper's fallback).
  if (u == 0.0f || v == 0.0f || w == 0.0f) {
    u = static_cast<float>(static_cast<double>(cx) * by - static_cast<double>(cy) * bx);
    v = static_cast<float>(static_cast<double>(ax) * cy - static_cast<double>(ay) * cx);
    w = static_cast<float>(static_cast<double>(bx) * ay - static_cast<double>(by) * ax);
  }
  if ((u < 0.0f || v < 0.0f || w < 0.0f) && (u > 0.0f || v > 0.0f || w > 0.0f)) return false;
  const float det = u + v + w;
  if (det == 0.0f) return false;
  const float az = rp.sz * A[rp.kz], bz = rp.sz * B[rp.kz], cz = rp.sz * C[rp.kz];
  const float T = u * az + v * bz + w * cz;
  // Written so that a NaN anywhere (degenerate input) rejects the hit.
  if (det > 0.0f) {
    if (!(T > 0.0f) || !(T < tmax * det)) return false;
  } else if (!(T < 0.0f) || !(T > tmax * det)) {
    return false;
  }
  const float inv = 1.0f / det;
  const float t = T * inv;
  // Conservative bound on t's rounding error (pbrt-v4): a "hit" closer than it may be the
  // surface the ray just left, e.g. on long thin triangles where det is tiny.
  // pbrt-v4 bounds the shear's error in x and y by the scaled z (max_zt), which for a unit
  // direction is max_zu * shear; written so, the bound no longer grows as 1 / |d|^2, which
  // rejected true hits of short directions (unnormalised batch rays, instances scaled up).
  const float max_zt = std::max(std::fabs(az), std::max(std::fabs(bz), std::fabs(cz)));
  const float max_zu = std::max(std::fabs(A[rp.kz]), std::max(std::fabs(B[rp.kz]), std::fabs(C[rp.kz]))) * rp.shear;
  const float max_xt = std::max(std::fabs(ax), std::max(std::fabs(bx), std::fabs(cx)));
  const float max_yt = std::max(std::fabs(ay), std::max(std::fabs(by), std::fabs(cy)));
  const float delta_z = gamma_bound(3) * max_zt;
  const float delta_x = gamma_bound(5) * (max_xt + max_zu);
  const float delta_y = gamma_bound(5) * (max_yt + max_zu);
  const float delta_e = 2.0f * (gamma_bound(2) * max_xt * max_yt + delta_y * max_xt + delta_x * max_yt);
  const float max_e = std::max(std::fabs(u), std::max(std::fabs(v), std::fabs(w)));
  const float delta_pbrt =
      3.0f * (gamma_bound(3) * max_e * max_zt + delta_e * max_zt + delta_z * max_e) * std::fabs(inv);
  // The edge functions share a sign, so t is a convex combination of the scaled z of the
  // vertices (up to the rounding of T and the division): its error is also bounded by their
  // spread. Far tighter for small or distant triangles, where the bound above, loose for
  // slivers seen from afar, rejected true hits. And t > spread + rounding puts every vertex in
  // front of the origin, so a hit on the surface the ray left is still rejected.
  const float spread = std::max(az, std::max(bz, cz)) - std::min(az, std::min(bz, cz));
  const float delta_t = std::min(delta_pbrt, spread + gamma_bound(10) * max_zt);
  if (!(t > delta_t)) return false;
  if (any_hit && !(t + delta_t < tmax)) return false;
  t_out = t;
  b1_out = v * inv;
  b2_out = w * inv;
  return true;
}

}  // namespace pl
