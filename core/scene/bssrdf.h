// Subsurface scattering closures set up as Cycles 4.5 does (kernel/closure/bssrdf.h,
// bssrdf_setup and bssrdf_setup_radius): the clamps, the per-channel fallback to diffuse for
// radii too small to walk, the diffuse fallback after a diffuse bounce, and each method's
// radius scaling. Our own code after the published formulas.
#pragma once
#include <algorithm>
#include <cmath>

#include "scene/shader.h"

namespace pl {

constexpr float kBssrdfMinRadius = 1e-8f;  // Cycles' BSSRDF_MIN_RADIUS

// The method a register holds (the add-on's numbers; anything else: Random Walk).
inline SubsurfaceMethod subsurface_method(float v) {
  return v > 1.5f && v < 2.5f ? SubsurfaceMethod::RandomWalkSkin
         : v > -0.5f && v < 0.5f ? SubsurfaceMethod::Burley
                                 : SubsurfaceMethod::RandomWalk;
}

// Jensen et al.'s dipole diffuse reflectance for reduced albedo a (Cycles' bssrdf_dipole_compute_Rd).
inline float bssrdf_dipole_rd(float a, float four_thirds_A) {
  const float s = std::sqrt(3.0f * (1.0f - a));
  return 0.5f * a * (1.0f + std::exp(-four_thirds_A * s)) * std::exp(-s);
}
// Its inverse by bisection (12 steps, as Cycles' bssrdf_dipole_compute_alpha_prime).
inline float bssrdf_dipole_alpha_prime(float rd, float four_thirds_A) {
  if (!(rd >= 1e-4f)) return 0.0f;
  if (rd >= 0.995f) return 0.999999f;
  float x0 = 0.0f, x1 = 1.0f, xm = 0.5f;
  for (int i = 0; i < 12; ++i) {
    xm = 0.5f * (x0 + x1);
    if (bssrdf_dipole_rd(xm, four_thirds_A) < rd) x0 = xm;
    else x1 = xm;
  }
  return xm;
}

// Adds the BSSRDF closure of weight w (albedo, radius = Radius x Scale, anisotropy g, entry IOR
// and GGX alpha) to `out` as Cycles' bssrdf_setup: channels whose radius is below
// kBssrdfMinRadius (or NaN), and the whole closure after a diffuse bounce, become a diffuse
// closure of the same normal. `frame` is the closure's (Cycles' valid specular normal).
inline void add_subsurface(ClosureList& out, Vec3 w, Vec3 albedo, Vec3 radius, float g, float ior, float alpha,
                           SubsurfaceMethod method, const Frame& frame, bool diffuse_ancestor, bool back = false) {
  if (!is_finite(w)) return;
  g = std::isfinite(g) ? std::clamp(g, 0.0f, 0.9f) : 0.0f;
  ior = std::isfinite(ior) ? std::clamp(ior, 1.01f, 3.8f) : 1.4f;
  alpha = std::isfinite(alpha) ? std::clamp(alpha, 0.0f, 1.0f) : 1.0f;
  for (int i = 0; i < 3; ++i) albedo[i] = std::isfinite(albedo[i]) ? std::max(albedo[i], 0.0f) : 0.0f;
  Vec3 diffuse(0.0f);
  int channels = 0;
  for (int i = 0; i < 3; ++i) {
    if (diffuse_ancestor || !(radius[i] >= kBssrdfMinRadius)) {
      diffuse[i] = w[i];
      w[i] = 0.0f;
      radius[i] = 0.0f;
    } else {
      ++channels;
    }
  }
  if (!is_black(diffuse)) {
    DiffuseBsdf d;
    d.back = back;  // (the side the viewer sees, as every diffuse lobe)
    out.add(d, diffuse, frame);
  }
  if (channels == 0) return;
  SubsurfaceBsdf s;
  s.albedo = albedo;
  s.g = g;
  s.ior = ior;
  s.alpha = alpha;
  if (method == SubsurfaceMethod::RandomWalkSkin) {
    // Skin: the radius follows the albedo through the dipole's diffusion length (Jensen's Fdr
    // for the subsurface IOR); the entry is half diffuse, half refraction at roughness 1.
    const float inv = 1.0f / ior;
    const float fdr = inv * (-1.440f * inv + 0.710f) + 0.668f + 0.0636f * ior;
    const float a43 = (4.0f / 3.0f) * (1.0f + fdr) / (1.0f - fdr);
    for (int i = 0; i < 3; ++i) radius[i] *= std::sqrt(3.0f * (1.0f - bssrdf_dipole_alpha_prime(albedo[i], a43)));
    s.alpha = -1.0f;
  } else {
    // Random Walk and Burley: the mean free path scaled as Cycles' older models looked.
    radius = radius * (0.25f * kInvPi);
    if (method == SubsurfaceMethod::Burley) s.alpha = -2.0f;  // the disk, not a walk
  }
  s.radius = radius;
  out.add(s, w, frame);
}

}  // namespace pl
