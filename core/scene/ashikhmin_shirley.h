// The Ashikhmin-Shirley glossy lobe ("An Anisotropic Phong BRDF Model", 2000) as Cycles 4.5's
// bsdf_ashikhmin_shirley: Phong exponents from the microfacet alphas, the paper's half-vector
// sampling, and no Fresnel (the Glossy BSDF's colour is its weight). Local frame: +Z = normal,
// wo (the view) and wi (the light) both above it.
#pragma once
#include "scene/microfacet.h"

namespace pl {

struct AshikhminShirley {
  float nx, ny;  // Phong exponents along the tangent (x) and the bitangent (y)
  // Cycles clamps the alphas to [1e-4, 1] (alpha 1: exponent 0, a uniform half vector).
  static AshikhminShirley from_alpha(float ax, float ay) {
    auto exponent = [](float a) {
      a = clampf(a, 1e-4f, 1.0f);
      return 2.0f / (a * a) - 2.0f;
    };
    return {exponent(ax), exponent(ay)};
  }
  bool isotropic() const { return nx == ny; }
  // f * cos(wi), and the pdf of sample() (the half vector's density over 4 h.wo).
  float eval(Vec3 wo, Vec3 wi, float& pdf) const {
    pdf = 0.0f;
    if (!(wo.z > 0.0f && wi.z > 0.0f)) return 0.0f;
    const Vec3 h = normalize(wo + wi);
    const float cos_o = std::max(wo.z, 1e-6f), cos_i = std::max(wi.z, 1e-6f);
    const float h_o = std::max(std::fabs(dot(h, wo)), 1e-6f), h_n = std::max(h.z, 1e-6f);
    // The paper's 1 / (h.wo max(cos_o, cos_i)), reciprocal.
    const float pump = 1.0f / std::max(1e-6f, h_o * std::max(cos_o, cos_i));
    float lobe, norm;
    if (isotropic()) {
      lobe = std::pow(h_n, nx);
      norm = (nx + 1.0f) / (8.0f * kPi);
    } else {
      lobe = h_n < 1.0f ? std::pow(h_n, (nx * h.x * h.x + ny * h.y * h.y) / (1.0f - h_n * h_n)) : 1.0f;
      norm = std::sqrt((nx + 1.0f) * (ny + 1.0f)) / (8.0f * kPi);
    }
    pdf = norm * lobe / h_o;
    return cos_i * norm * lobe * pump;
  }
  // The half vector (upper hemisphere): the paper's density, per quadrant where anisotropic.
  Vec3 sample_half(Vec2 u) const {
    float phi, cos_t;
    if (isotropic()) {
      phi = 2.0f * kPi * u.x;
      cos_t = std::pow(u.y, 1.0f / (nx + 1.0f));
    } else {
      // Sample the first quadrant from a remapped u.x, then mirror into the one u.x chose.
      const int q = std::min(int(u.x * 4.0f), 3);
      const float r = q == 0 ? 4.0f * u.x : q == 1 ? 4.0f * (0.5f - u.x) : q == 2 ? 4.0f * (u.x - 0.5f) : 4.0f * (1.0f - u.x);
      const float p = std::atan(std::sqrt((nx + 1.0f) / (ny + 1.0f)) * std::tan(0.5f * kPi * r));
      const float c = std::cos(p), s = std::sin(p);
      cos_t = std::pow(u.y, 1.0f / (nx * c * c + ny * s * s + 1.0f));
      phi = q == 0 ? p : q == 1 ? kPi - p : q == 2 ? kPi + p : 2.0f * kPi - p;
    }
    const float sin_t = std::sqrt(std::max(0.0f, 1.0f - cos_t * cos_t));
    return {sin_t * std::cos(phi), sin_t * std::sin(phi), cos_t};
  }
};

}  // namespace pl
