// The Beckmann microfacet distribution as Cycles 4.5 has it (bsdf_microfacet.h): its D, the
// Smith Lambda by Walter et al.'s rational approximation, and visible-normal sampling by
// Jakob's improved routine (Heitz & d'Eon 2014). Same interface as Ggx, so that the GGX lobes
// take it as a template argument. Local frame: +Z = normal.
#pragma once
#include "scene/microfacet.h"

namespace pl {

// Inverse error function on (-1, 1) (Giles, "Approximating the erfinv function", single
// precision); clamped just inside the interval, so that the ends give large finite values.
inline float erfinv_approx(float x) {
  x = clampf(x, -0.99999994f, 0.99999994f);
  float w = -std::log((1.0f - x) * (1.0f + x)), p;
  if (w < 5.0f) {
    w -= 2.5f;
    p = 2.81022636e-08f;
    p = 3.43273939e-07f + p * w;
    p = -3.5233877e-06f + p * w;
    p = -4.39150654e-06f + p * w;
    p = 0.00021858087f + p * w;
    p = -0.00125372503f + p * w;
    p = -0.00417768164f + p * w;
    p = 0.246640727f + p * w;
    p = 1.50140941f + p * w;
  } else {
    w = std::sqrt(w) - 3.0f;
    p = -0.000200214257f;
    p = 0.000100950558f + p * w;
    p = 0.00134934322f + p * w;
    p = -0.00367342844f + p * w;
    p = 0.00573950773f + p * w;
    p = -0.0076224613f + p * w;
    p = 0.00943887047f + p * w;
    p = 1.00167406f + p * w;
    p = 2.83297682f + p * w;
  }
  return p * x;
}

// alpha along the frame's tangent (x), alpha_y along its bitangent (y), as Ggx.
struct Beckmann {
  float alpha;
  float alpha_y = alpha;
  bool isotropic() const { return alpha_y == alpha; }
  float D(Vec3 m) const {
    const float c2 = std::min(m.z * m.z, 1.0f);
    if (!(c2 > 0.0f)) return 0.0f;
    if (isotropic()) {
      const float a2 = alpha * alpha;
      return 1.0f / (std::exp((1.0f - c2) / (c2 * a2)) * kPi * a2 * (c2 * c2));
    }
    const float x = m.x / alpha, y = m.y / alpha_y;
    return std::exp(-(x * x + y * y) / c2) / (kPi * alpha * alpha_y * (c2 * c2));
  }
  // Walter et al. 2007's fit to the exact Lambda (erf), as Cycles: exactly 0 for a >= 1.6.
  static float lambda_from_sqr_alpha_tan(float s) {
    if (s < 0.39f) return 0.0f;  // a >= 1.6, and s == 0 without a division
    const float a = 1.0f / std::sqrt(s);
    return ((0.396f * a - 1.259f) * a + 1.0f) / ((2.181f * a + 3.535f) * a);
  }
  float lambda(Vec3 v) const {
    const float c2 = v.z * v.z;
    if (c2 <= 0.0f) return 0.0f;
    if (isotropic()) return lambda_from_sqr_alpha_tan(alpha * alpha * std::max(0.0f, 1.0f - c2) / c2);
    const float ax = alpha * v.x, ay = alpha_y * v.y;
    return lambda_from_sqr_alpha_tan((ax * ax + ay * ay) / c2);
  }
  float G1(Vec3 v) const { return 1.0f / (1.0f + lambda(v)); }
  float G(Vec3 wo, Vec3 wi) const { return 1.0f / (1.0f + lambda(wo) + lambda(wi)); }
  // Density of visible normals m as seen from wo (wo.z > 0), with the fitted Lambda (as Cycles).
  float pdf_visible(Vec3 wo, Vec3 m) const {
    return visible_normal_pdf(G1(wo), D(m), wo, m);
  }
  // Samples a visible normal for wo (wo.z > 0): the view stretched to unit roughness, a slope
  // drawn from its visible-slope distribution (x by inverting its CDF with a few safeguarded
  // Newton steps, y as a Gaussian), rotated back to the view's azimuth and unstretched.
  Vec3 sample_visible(Vec3 wo, Vec2 u) const {
    const Vec3 w = normalize(Vec3{alpha * wo.x, alpha_y * wo.y, wo.z});
    float sx, sy, cos_phi = 1.0f, sin_phi = 0.0f;
    if (w.z >= 0.99999f) {  // normal incidence: the slopes are a plain 2D Gaussian
      const float r = std::sqrt(-std::log(std::max(1.0f - u.x, 1e-30f))), phi = 2.0f * kPi * u.y;
      sx = r * std::cos(phi);
      sy = r * std::sin(phi);
    } else {
      const float sin_t = std::sqrt(std::max(0.0f, 1.0f - w.z * w.z));
      const float tan_t = sin_t / w.z, cot_t = w.z / sin_t;
      cos_phi = w.x / sin_t;
      sin_phi = w.y / sin_t;
      const float erf_a = std::erf(cot_t), exp_a2 = std::exp(-cot_t * cot_t);
      constexpr float kInvSqrtPi = 0.56418958354f;
      // The CDF of slope x, as y(b) = 1 + b + K exp(-erfinv(b)^2) over b = erf(slope); its
      // first guess from exp(-erfinv(b)^2) ~ 1 - b^2 (a quadratic in b).
      const float K = tan_t * kInvSqrtPi;
      const float total = 1.0f + erf_a + K * exp_a2;
      const float y_approx = u.x * (1.0f + erf_a + K * (1.0f - erf_a * erf_a));
      const float y = u.x * total;
      float b = K > 0.0f ? (0.5f - std::sqrt(K * (K - y_approx + 1.0f) + 0.25f)) / K : y_approx - 1.0f;
      float inv = erfinv_approx(b);
      float lo = -1.0f, lo_y = -y, hi = erf_a;
      float cur_y = 1.0f + b + K * std::exp(-inv * inv) - y;
      for (int it = 0; it < 3 && std::fabs(cur_y) > 1e-6f; ++it) {
        if ((lo_y < 0.0f) == (cur_y < 0.0f)) {
          lo = b;
          lo_y = cur_y;
        } else {
          hi = b;
        }
        const float newton = b - cur_y / (1.0f - inv * tan_t);  // dy/db = 1 - erfinv(b) tan
        b = newton >= lo && newton <= hi ? newton : 0.5f * (lo + hi);
        inv = erfinv_approx(b);
        cur_y = 1.0f + b + K * std::exp(-inv * inv) - y;
      }
      sx = inv;
      sy = erfinv_approx(2.0f * u.y - 1.0f);
    }
    const float rx = cos_phi * sx - sin_phi * sy, ry = sin_phi * sx + cos_phi * sy;
    return normalize(Vec3{-alpha * rx, -alpha_y * ry, 1.0f});
  }
};

}  // namespace pl
