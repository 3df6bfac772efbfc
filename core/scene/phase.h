// Homogeneous participating media: the Henyey-Greenstein phase function and analytic
// (spectral) free-flight sampling, as pbrt and Cycles' homogeneous volumes do it.
#pragma once
#include <algorithm>
#include <cmath>

#include "scene/bsdf.h"

namespace pl {

// Cycles keeps |g| below 1 so that the lobe stays a finite function.
inline float clamp_phase_g(float g) {
  if (!std::isfinite(g)) return 0.0f;
  return std::copysign(std::min(std::fabs(g), 1.0f - 1e-3f), g);
}

// Density over the sphere of a scattered direction whose cosine to the propagation direction
// is cos_t (g > 0: forward scattering).
inline float hg_phase(float g, float cos_t) {
  const float d = 1.0f + g * g - 2.0f * g * cos_t;
  return (1.0f - g * g) / (4.0f * kPi * d * std::sqrt(std::max(d, 1e-12f)));
}

// A direction about `dir` (unit, the propagation direction) distributed as hg_phase; returns
// it with its pdf (which is also the phase function's value: the sampling is exact).
inline Vec3 hg_sample(float g, Vec3 dir, float u1, float u2, float& pdf) {
  float cos_t;
  if (std::fabs(g) < 1e-3f) {
    cos_t = 1.0f - 2.0f * u1;
  } else {
    const float s = (1.0f - g * g) / (1.0f + g - 2.0f * g * u1);
    cos_t = (1.0f + g * g - s * s) / (2.0f * g);
  }
  cos_t = std::clamp(cos_t, -1.0f, 1.0f);
  const float sin_t = std::sqrt(std::max(0.0f, 1.0f - cos_t * cos_t));
  const float phi = 2.0f * kPi * u2;
  const Frame f = Frame::from_normal(dir);
  pdf = hg_phase(g, cos_t);
  return f.to_world({sin_t * std::cos(phi), sin_t * std::sin(phi), cos_t});
}

// exp(-sigma * t) per channel; a channel with sigma 0 transmits everything, even to infinity.
inline Vec3 medium_transmittance(Vec3 sigma, float t) {
  const auto tr = [t](float s) { return s > 0.0f ? std::exp(-s * t) : 1.0f; };
  return {tr(sigma.x), tr(sigma.y), tr(sigma.z)};
}

// Free-flight distance in a homogeneous medium of extinction sigma_t: a channel chosen
// uniformly by u_channel, then an exponential distance in it. The pdf of the distance (and
// the probability of passing `t_max`) is the average over channels (one-sample MIS of the
// channels, as pbrt-v3's HomogeneousMedium and Cycles).
inline float sample_free_flight(Vec3 sigma_t, float u_channel, float u) {
  const int c = std::min(int(u_channel * 3.0f), 2);
  const float s = c == 0 ? sigma_t.x : c == 1 ? sigma_t.y : sigma_t.z;
  if (!(s > 0.0f)) return INFINITY;
  return -std::log1p(-std::min(u, 1.0f - 1e-7f)) / s;
}
// The distance density at t (a scattering event there) ...
inline float free_flight_pdf(Vec3 sigma_t, float t) {
  const Vec3 T = medium_transmittance(sigma_t, t);
  return (sigma_t.x * T.x + sigma_t.y * T.y + sigma_t.z * T.z) * (1.0f / 3.0f);
}
// ... and the probability of flying past t.
inline float free_flight_survival(Vec3 sigma_t, float t) {
  const Vec3 T = medium_transmittance(sigma_t, t);
  return (T.x + T.y + T.z) * (1.0f / 3.0f);
}

// Equiangular distances (Kulla and Fajardo 2012), Cycles' volume sampling towards a light: on
// the ray o + d t (d unit), t in [0, t_max] (t_max may be infinite), the density of t is
// proportional to 1 / |x(t) - c|^2 for a point c on a light, so scattering points crowd where
// the light is close. EquiangularSegment::valid is false where c lies on the ray's line (no
// finite density) or the interval is empty.
struct EquiangularSegment {
  float delta = 0.0f;  // t of the point on the line closest to c
  float dist = 0.0f;   // c's distance from the line
  float theta_a = 0.0f, theta_b = 0.0f;
  bool valid = false;
};
inline EquiangularSegment equiangular_segment(Vec3 o, Vec3 d, float t_max, Vec3 c) {
  EquiangularSegment e;
  e.delta = dot(c - o, d);
  const Vec3 off = c - (o + d * e.delta);
  e.dist = length(off);
  const float scale = std::max(std::fabs(e.delta), length(c - o));
  if (!(e.dist > 1e-5f * scale) || !(t_max > 0.0f) || !std::isfinite(e.delta)) return e;
  e.theta_a = std::atan2(-e.delta, e.dist);
  e.theta_b = std::isfinite(t_max) ? std::atan2(t_max - e.delta, e.dist) : 0.5f * kPi;
  e.valid = e.theta_b > e.theta_a;
  return e;
}
inline float sample_equiangular(const EquiangularSegment& e, float u) {
  const float th = e.theta_a + u * (e.theta_b - e.theta_a);
  return e.delta + e.dist * std::tan(th);
}
inline float equiangular_pdf(const EquiangularSegment& e, float t) {
  if (!e.valid) return 0.0f;
  const float x = t - e.delta;
  return e.dist / ((e.theta_b - e.theta_a) * (e.dist * e.dist + x * x));
}

}  // namespace pl
