// GGX (Trowbridge-Reitz) microfacet distribution with Smith height-correlated masking and
// visible-normal sampling (Heitz 2018), plus dielectric Fresnel. Local frame: +Z = normal.
#pragma once
#include "util/sampling.h"

namespace pl {

// Exact unpolarised Fresnel reflectance of a dielectric interface. cos_i is measured on the
// side of the incident direction (sign tells the side); eta = n_inside / n_outside.
inline float fresnel_dielectric(float cos_i, float eta) {
  if (cos_i < 0.0f) {
    eta = 1.0f / eta;
    cos_i = -cos_i;
  }
  const float sin2_t = (1.0f - cos_i * cos_i) / (eta * eta);
  if (sin2_t >= 1.0f) return 1.0f;  // total internal reflection
  const float cos_t = std::sqrt(std::max(0.0f, 1.0f - sin2_t));
  const float r_par = (eta * cos_i - cos_t) / (eta * cos_i + cos_t);
  const float r_perp = (cos_i - eta * cos_t) / (cos_i + eta * cos_t);
  return 0.5f * (r_par * r_par + r_perp * r_perp);
}

// Schlick's approximation (the seed's option), evaluated on the optically thinner side so that
// it also gives total internal reflection.
inline float fresnel_schlick_dielectric(float cos_i, float eta) {
  if (cos_i < 0.0f) {
    eta = 1.0f / eta;
    cos_i = -cos_i;
  }
  float c = cos_i;
  if (eta < 1.0f) {  // leaving the denser medium: use the transmitted angle
    const float sin2_t = (1.0f - cos_i * cos_i) / (eta * eta);
    if (sin2_t >= 1.0f) return 1.0f;
    c = std::sqrt(1.0f - sin2_t);
  }
  const float r0 = (eta - 1.0f) / (eta + 1.0f);
  const float f0 = r0 * r0;
  const float m = 1.0f - c;
  return f0 + (1.0f - f0) * (m * m) * (m * m) * m;
}

inline Vec3 fresnel_schlick(Vec3 f0, float cos_i) {
  const float m = clampf(1.0f - cos_i, 0.0f, 1.0f);
  const float m5 = (m * m) * (m * m) * m;
  return f0 + (Vec3(1.0f) - f0) * m5;
}

// alpha is the roughness along the frame's first axis (x, the tangent), alpha_y along its
// second: anisotropic GGX (Heitz 2014) where they differ; the isotropic formulas otherwise.
// Density of visible normals m seen from wo (wo.z > 0), from G1(wo) and D(m): Heitz's
// D_wo(m), shared by the distributions and by callers holding G1 and D already.
inline float visible_normal_pdf(float g1o, float d, Vec3 wo, Vec3 m) {
  return g1o * std::max(0.0f, dot(wo, m)) * d / std::fabs(wo.z);
}

struct Ggx {
  float alpha;
  float alpha_y = alpha;
  bool isotropic() const { return alpha_y == alpha; }
  float D(Vec3 m) const {
    if (isotropic()) {
      const float a2 = alpha * alpha;
      const float c2 = m.z * m.z;
      const float d = c2 * (a2 - 1.0f) + 1.0f;
      return a2 / (kPi * d * d);
    }
    const float x = m.x / alpha, y = m.y / alpha_y;
    const float l2 = x * x + y * y + m.z * m.z;
    return 1.0f / (kPi * alpha * alpha_y * l2 * l2);
  }
  float lambda(Vec3 v) const {
    const float c2 = v.z * v.z;
    if (c2 <= 0.0f) return 0.0f;
    if (isotropic()) {
      const float t2 = std::max(0.0f, 1.0f - c2) / c2;
      return 0.5f * (-1.0f + std::sqrt(1.0f + alpha * alpha * t2));
    }
    const float ax = alpha * v.x, ay = alpha_y * v.y;
    return 0.5f * (-1.0f + std::sqrt(1.0f + (ax * ax + ay * ay) / c2));
  }
  float G1(Vec3 v) const { return 1.0f / (1.0f + lambda(v)); }
  float G(Vec3 wo, Vec3 wi) const { return 1.0f / (1.0f + lambda(wo) + lambda(wi)); }
  // Density of visible normals m as seen from wo (wo.z > 0).
  float pdf_visible(Vec3 wo, Vec3 m) const {
    return visible_normal_pdf(G1(wo), D(m), wo, m);
  }
  // Samples a visible normal for wo (wo.z > 0): the view stretched to the unit-roughness
  // configuration, a visible hemisphere normal there, then unstretched (one code for both).
  Vec3 sample_visible(Vec3 wo, Vec2 u) const {
    const Vec3 vh = normalize(Vec3{alpha * wo.x, alpha_y * wo.y, wo.z});
    const float len2 = vh.x * vh.x + vh.y * vh.y;
    const Vec3 t1 = len2 > 0.0f ? Vec3{-vh.y, vh.x, 0.0f} / std::sqrt(len2) : Vec3{1.0f, 0.0f, 0.0f};
    const Vec3 t2 = cross(vh, t1);
    const float r = std::sqrt(u.x), phi = 2.0f * kPi * u.y;
    const float p1 = r * std::cos(phi);
    float p2 = r * std::sin(phi);
    const float s = 0.5f * (1.0f + vh.z);
    p2 = (1.0f - s) * std::sqrt(std::max(0.0f, 1.0f - p1 * p1)) + s * p2;
    const Vec3 nh = t1 * p1 + t2 * p2 + vh * std::sqrt(std::max(0.0f, 1.0f - p1 * p1 - p2 * p2));
    return normalize(Vec3{alpha * nh.x, alpha_y * nh.y, std::max(1e-6f, nh.z)});
  }
};

// Blender's microfacet distributions (Cycles' closures): GGX (with or without the multiscatter
// compensation, which the shader applies), Beckmann and, for the Glossy BSDF only,
// Ashikhmin-Shirley. The GGX lobes hold one and branch on it.
enum class Microfacet : uint8_t { Ggx, Beckmann, AshikhminShirley };

inline Vec3 reflect(Vec3 wo, Vec3 m) { return m * (2.0f * dot(wo, m)) - wo; }

// Refracts wo through the interface with normal m (on wo's side or not); eta = n_inside/n_outside
// relative to +Z. Returns false on total internal reflection.
inline bool refract(Vec3 wo, Vec3 m, float eta, Vec3& wi, float& etap) {
  float cos_i = dot(m, wo);
  etap = eta;
  if (cos_i < 0.0f) {
    etap = 1.0f / eta;
    cos_i = -cos_i;
    m = -m;
  }
  const float sin2_t = std::max(0.0f, 1.0f - cos_i * cos_i) / (etap * etap);
  if (sin2_t >= 1.0f) return false;
  const float cos_t = std::sqrt(1.0f - sin2_t);
  wi = -wo / etap + m * (cos_i / etap - cos_t);
  return true;
}

}  // namespace pl
