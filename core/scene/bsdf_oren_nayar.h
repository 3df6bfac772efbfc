// Rough diffuse as Cycles 4.5 does it (bsdf_oren_nayar.h): Fujii's improved Oren-Nayar single
// scattering plus the energy-preserving multiple-scattering term of the OpenPBR specification
// (Portsmouth et al. 2024, "EON"), cosine-sampled. Included by bsdf.h before its variant.
#pragma once
#include "scene/microfacet_energy.h"

namespace pl {

// Fujii's directional-albedo helper: E(cos) = a pi + b G(cos).
inline float oren_nayar_G(float c) {
  if (c < 1e-6f) return (0.5f * kPi - 2.0f / 3.0f) - c;  // tan(theta) misbehaves at grazing
  const float s = std::sqrt(std::max(0.0f, 1.0f - c * c));
  const float theta = std::acos(clampf(c, -1.0f, 1.0f));
  return s * (theta - 2.0f / 3.0f - s * c) + (2.0f / 3.0f) * (s / c) * (1.0f - s * s * s);
}

struct OrenNayarBsdf {
  Vec3 ns{0.0f, 0.0f, 1.0f};  // as DiffuseBsdf: the smooth normal, for the bump shadowing
  bool bent = false;
  bool back = false;  // the hit is backfacing: lit from -Z (as DiffuseBsdf::back)
  float a = kInvPi, b = 0.0f;
  Vec3 ms{0.0f};  // the multiple-scattering term's colour times (1 - E(view))

  // Roughness sigma in [0, 1], the albedo (the closure's colour, clamped to [0, 1]) and the
  // view's cosine to the lobe's normal.
  static OrenNayarBsdf setup(float roughness, Vec3 color, float cos_view) {
    OrenNayarBsdf o;
    const float sigma = clampf(std::isfinite(roughness) ? roughness : 0.0f, 0.0f, 1.0f);
    o.a = 1.0f / (kPi + sigma * (0.5f * kPi - 2.0f / 3.0f));
    o.b = sigma * o.a;
    const Vec3 rho = vmin(vmax(color, Vec3(0.0f)), Vec3(1.0f));
    const float e_avg = o.a * kPi + ((2.0f * kPi - 5.6f) / 3.0f) * o.b;
    const Vec3 denom = Vec3(1.0f) - rho * (1.0f - e_avg);
    const Vec3 e_ms = rho * rho * (kInvPi * e_avg / (1.0f - e_avg)) / vmax(denom, Vec3(1e-6f));
    const float e_v = o.a * kPi + o.b * oren_nayar_G(std::max(cos_view, 0.0f));
    o.ms = e_ms * (1.0f - e_v);
    return o;
  }
  Vec3 value(Vec3 wo, Vec3 wi) const {
    const float nl = std::max(wi.z, 0.0f), nv = std::max(wo.z, 0.0f);
    float t = dot(wi, wo) - nl * nv;
    if (t > 0.0f) t /= std::max(nl, nv) + 1e-30f;
    const float single = a + b * t;
    const float e_l = a * kPi + b * oren_nayar_G(nl);
    return (Vec3(single) + ms * (1.0f - e_l)) * nl;
  }
  [[gnu::noinline]] Vec3 eval(Vec3 wo, Vec3 wi, float& pdf) const {
    pdf = 0.0f;
    // Lit from the side the geometry shows the viewer (Cycles flips a backfacing hit's normal);
    // a view below the lobe (a smooth silhouette) counts as grazing, Cycles' max(N.V, 0).
    if ((wi.z < 0.0f) != back) return Vec3(0.0f);
    const float side = back ? -1.0f : 1.0f;
    const Vec3 f = value({wo.x, wo.y, wo.z * side}, {wi.x, wi.y, wi.z * side});
    pdf = std::fabs(wi.z) * kInvPi;
    return bent ? f * bump_shadowing(ns, wi) : f;
  }
  [[gnu::noinline]] bool sample(Vec3 wo, Vec2 u, float, BsdfSample& s) const {
    Vec3 l = sample_cosine_hemisphere(u);
    if (l.z <= 0.0f) return false;
    const bool flip = back;
    if (flip) wo.z = -wo.z;
    const Vec3 f = value(wo, l);
    s.pdf = l.z * kInvPi;
    s.weight = f / s.pdf;
    s.flags = kReflect | kDiffuseLobe;
    if (flip) l.z = -l.z;
    if (bent) s.weight *= bump_shadowing(ns, l);
    s.wi = l;
    return true;
  }
};

}  // namespace pl
