// The Principled Hair BSDF, Chiang model (Chiang, Bitterli, Tappan & Burley 2016, "A practical
// and controllable hair and fur model for production path tracing"), as Cycles 4.x evaluates
// it: lobes R, TT, TRT and the residual TRRT+, each a longitudinal term Mp (d'Eon's, with the
// cuticle tilt applied to the outgoing angle as pbrt-v4 does) times an attenuation Ap (Fresnel
// at the fibre's offset h, absorption along the refracted path) times an azimuthal term Np (a
// trimmed logistic about the lobe's deflection; uniform for the residual). Sampled lobe by lobe
// in proportion to the luminance of Ap; the pdf is the sum over the lobes.
//
// Local frame (the closure's Frame): x along the fibre (the curve tangent), y = x cross the
// view direction, z = x cross y; h = sin(gamma_o) is set from the hit's normal at shading.
// Directions are over the whole sphere: reflection and transmission are one lobe set.
#pragma once
#include <cmath>

#include "scene/microfacet.h"
#include "util/math.h"
// (included by bsdf.h, after BsdfSample and the lobe flags)

namespace pl {

namespace hair_detail {

constexpr float kTwoPi = 6.28318530717958647692f;

inline float sqr(float x) { return x * x; }
inline float cos_from_sin(float s) { return std::sqrt(std::max(0.0f, 1.0f - s * s)); }
inline float safe_asin(float s) { return std::asin(clampf(s, -1.0f, 1.0f)); }

// The angle wrapped to [-pi, pi].
inline float wrap_angle(float a) { return a - kTwoPi * std::floor((a + kPi) / kTwoPi); }

// The azimuthal deflection of lobe p for entry angle gamma_o and refracted gamma_t.
inline float deflection(int p, float gamma_o, float gamma_t) {
  return 2.0f * float(p) * gamma_t - 2.0f * gamma_o + float(p) * kPi;
}

inline float logistic(float x, float s) {
  const float e = std::exp(-std::fabs(x) / s);
  return e / (s * sqr(1.0f + e));
}
inline float logistic_cdf(float x, float s) {
  const float a = -x / s;
  return a > 88.0f ? 0.0f : 1.0f / (1.0f + std::exp(a));
}
// The logistic restricted to [-pi, pi] and renormalised.
inline float trimmed_logistic(float x, float s) {
  const float norm = 1.0f - 2.0f * logistic_cdf(-kPi, s);
  return norm > 0.0f ? logistic(x, s) / norm : 0.0f;
}
inline float sample_trimmed_logistic(float u, float s) {
  const float c = logistic_cdf(-kPi, s);
  const float x = -s * std::log(1.0f / (u * (1.0f - 2.0f * c) + c) - 1.0f);
  return clampf(x, -kPi, kPi);
}

// Modified Bessel function I0 by its series (as many terms as change the float sum).
inline float bessel_i0(float x) {
  const float x2 = x * x;
  float sum = 1.0f + 0.25f * x2, term_pow = x2 * x2;
  double fact2 = 1.0;  // (i!)^2
  float pow4 = 16.0f;
  for (int i = 2; i < 10; ++i) {
    fact2 *= double(i) * double(i);
    const float next = sum + term_pow / float(double(pow4) * fact2);
    if (next == sum) break;
    sum = next;
    term_pow *= x2;
    pow4 *= 4.0f;
  }
  return sum;
}
inline float log_bessel_i0(float x) {
  if (x > 12.0f) return x + 0.5f * (1.0f / (8.0f * x) - std::log(kTwoPi) - std::log(x));  // asymptotic
  return std::log(bessel_i0(x));
}

// d'Eon et al.'s longitudinal scattering for variance v; the log form for small v (no overflow).
inline float longitudinal(float sin_i, float cos_i, float sin_o, float cos_o, float v) {
  const float inv_v = 1.0f / v;
  const float a = cos_i * cos_o * inv_v, b = sin_i * sin_o * inv_v;
  if (v <= 0.1f) return std::exp(log_bessel_i0(a) - b - inv_v + 0.6931f + std::log(0.5f * inv_v));
  return std::exp(-b) * bessel_i0(a) / (std::sinh(inv_v) * 2.0f * v);
}

// Blender's roughness to the logistic variance v, and radial roughness to the scale s.
inline float roughness_to_v(float r) {
  const float r2 = r * r, r4 = r2 * r2, r8 = r4 * r4, r16 = r8 * r8;
  return sqr(0.726f * r + 0.812f * r2 + 3.7f * r16 * r4);
}
inline float radial_roughness_to_s(float r) {
  const float r2 = r * r, r4 = r2 * r2, r8 = r4 * r4, r16 = r8 * r8;
  return (0.265f * r + 1.194f * r2 + 5.372f * r16 * r4 * r2) * 0.626657069f;  // sqrt(pi / 8)
}

}  // namespace hair_detail

// Cycles' bsdf_principled_hair_sigma_from_concentration: absorption of eumelanin and pheomelanin.
inline Vec3 hair_sigma_from_concentration(float eumelanin, float pheomelanin) {
  return Vec3(0.506f, 0.841f, 1.653f) * eumelanin + Vec3(0.343f, 0.733f, 1.924f) * pheomelanin;
}
// ... and _from_reflectance: the absorption that gives a colour at a radial roughness (Chiang's fit).
inline Vec3 hair_sigma_from_reflectance(Vec3 c, float radial_roughness) {
  const float x = radial_roughness;
  const float fac = (((((0.245f * x) + 5.574f) * x - 10.73f) * x + 2.532f) * x - 0.215f) * x + 5.969f;
  auto one = [&](float v) {
    const float l = std::log(std::max(v, 1e-30f)) / fac;
    return l * l;
  };
  return {one(c.x), one(c.y), one(c.z)};
}

struct HairChiangBsdf {
  Vec3 sigma{0.0f};      // absorption coefficient inside the fibre (per unit of diameter)
  float v = 0.1f;        // longitudinal variance (TT uses v / 4, TRT and beyond 4 v)
  float v_r = 0.1f;      // the R lobe's (Coat lowers it)
  float s = 0.1f;        // azimuthal logistic scale
  float alpha = 0.0f;    // cuticle tilt (radians), with Cycles' sign
  float eta = 1.55f;
  float h = 0.0f;        // offset across the fibre, -1..1 (sin gamma_o)

  // From the node's inputs, clamped and remapped as Cycles' bsdf_hair_chiang_setup does.
  static HairChiangBsdf from_node(Vec3 sigma, float roughness, float radial_roughness, float coat, float offset,
                                  float ior) {
    using namespace hair_detail;
    HairChiangBsdf b;
    const float rv = clampf(roughness, 0.001f, 1.0f), rs = clampf(radial_roughness, 0.001f, 1.0f);
    const float m0 = clampf((1.0f - clampf(coat, 0.0f, 1.0f)) * rv, 0.001f, 1.0f);
    b.v = roughness_to_v(rv);
    b.v_r = roughness_to_v(m0);
    b.s = radial_roughness_to_s(rs);
    b.alpha = -offset;  // Cycles negates the node's Offset
    b.eta = ior;
    b.sigma = sigma;
    return b;
  }

  // Per lobe: attenuation Ap (colour) and its share of the sampling (luminance, normalised).
  void attenuation(float sin_o, float cos_o, float& gamma_o, float& gamma_t, Vec3 ap[4], float pe[4]) const {
    using namespace hair_detail;
    const float sin_t = sin_o / eta, cos_t = cos_from_sin(sin_t);
    const float sin_go = h, cos_go = cos_from_sin(h);
    gamma_o = safe_asin(sin_go);
    const float sin_gt = sin_go * cos_o / std::sqrt(std::max(1e-12f, eta * eta - sin_o * sin_o));
    const float cos_gt = cos_from_sin(sin_gt);
    gamma_t = safe_asin(sin_gt);
    const float path = cos_t > 0.0f ? 2.0f * cos_gt / cos_t : 0.0f;
    const Vec3 T{std::exp(-sigma.x * path), std::exp(-sigma.y * path), std::exp(-sigma.z * path)};
    const float f = fresnel_dielectric(cos_o * cos_go, eta);
    ap[0] = Vec3(f);
    ap[1] = T * sqr(1.0f - f);
    ap[2] = ap[1] * T * f;
    const Vec3 tf = T * f;
    const Vec3 ratio{tf.x < 1.0f ? tf.x / (1.0f - tf.x) : 0.0f, tf.y < 1.0f ? tf.y / (1.0f - tf.y) : 0.0f,
                     tf.z < 1.0f ? tf.z / (1.0f - tf.z) : 0.0f};
    ap[3] = ap[2] * ratio;
    float total = 0.0f;
    for (int p = 0; p < 4; ++p) total += pe[p] = p == 0 ? f : luminance(ap[p]);
    const float inv = total > 0.0f ? 1.0f / total : 0.0f;
    for (int p = 0; p < 4; ++p) pe[p] *= inv;
  }

  // sin and cos of the outgoing angle tilted for lobes R, TT, TRT (scales of alpha -2, 1, 4).
  void tilted(float sin_o, float cos_o, float out[6]) const {
    const float s1 = std::sin(alpha), c1 = hair_detail::cos_from_sin(s1);
    const float s2 = 2.0f * s1 * c1, c2 = c1 * c1 - s1 * s1;
    const float s4 = 2.0f * s2 * c2, c4 = c2 * c2 - s2 * s2;
    out[0] = sin_o * c2 - cos_o * s2;
    out[1] = std::fabs(cos_o * c2 + sin_o * s2);
    out[2] = sin_o * c1 + cos_o * s1;
    out[3] = std::fabs(cos_o * c1 - sin_o * s1);
    out[4] = sin_o * c4 + cos_o * s4;
    out[5] = std::fabs(cos_o * c4 - sin_o * s4);
  }

  // f * |cos| (the lobes' sum, Cycles' convention) and the pdf, for view wo and light wi.
  Vec3 eval_angles(float sin_o, float cos_o, float phi_o, float sin_i, float cos_i, float phi_i, float& pdf) const {
    using namespace hair_detail;
    float gamma_o, gamma_t, pe[4], tilt[6];
    Vec3 ap[4];
    attenuation(sin_o, cos_o, gamma_o, gamma_t, ap, pe);
    tilted(sin_o, cos_o, tilt);
    const float phi = phi_i - phi_o;
    Vec3 f(0.0f);
    pdf = 0.0f;
    for (int p = 0; p < 3; ++p) {
      const float vp = p == 0 ? v_r : p == 1 ? 0.25f * v : 4.0f * v;
      const float mp = longitudinal(sin_i, cos_i, tilt[2 * p], tilt[2 * p + 1], vp);
      const float np = trimmed_logistic(wrap_angle(phi - deflection(p, gamma_o, gamma_t)), s);
      f += ap[p] * (mp * np);
      pdf += pe[p] * mp * np;
    }
    const float mp = longitudinal(sin_i, cos_i, sin_o, cos_o, 4.0f * v);
    f += ap[3] * (mp / kTwoPi);
    pdf += pe[3] * mp / kTwoPi;
    if (!std::isfinite(pdf) || !is_finite(f)) {
      pdf = 0.0f;
      return Vec3(0.0f);
    }
    return f;
  }

  Vec3 eval(Vec3 wo, Vec3 wi, float& pdf) const {
    using hair_detail::cos_from_sin;
    const float sin_o = clampf(wo.x, -1.0f, 1.0f), sin_i = clampf(wi.x, -1.0f, 1.0f);
    return eval_angles(sin_o, cos_from_sin(sin_o), std::atan2(wo.z, wo.y), sin_i, cos_from_sin(sin_i),
                       std::atan2(wi.z, wi.y), pdf);
  }

  // u.x: the azimuth, u.y: the longitudinal rotation, uc: the lobe (then reused, rescaled, for
  // the longitudinal angle).
  bool sample(Vec3 wo, Vec2 u, float uc, BsdfSample& out) const {
    using namespace hair_detail;
    const float sin_o = clampf(wo.x, -1.0f, 1.0f), cos_o = cos_from_sin(sin_o);
    const float phi_o = std::atan2(wo.z, wo.y);
    float gamma_o, gamma_t, pe[4], tilt[6];
    Vec3 ap[4];
    attenuation(sin_o, cos_o, gamma_o, gamma_t, ap, pe);
    int p = 0;
    while (p < 3 && uc >= pe[p]) uc -= pe[p++];
    if (!(pe[p] > 0.0f)) return false;
    uc = std::max(std::min(uc / pe[p], 1.0f), 1e-5f);
    // R is sampled with its own variance (Cycles samples it with the others': its pdf then is
    // not its sampling density when Coat > 0).
    const float vp = p == 0 ? v_r : p == 1 ? 0.25f * v : 4.0f * v;
    tilted(sin_o, cos_o, tilt);
    const float so = p < 3 ? tilt[2 * p] : sin_o, co = p < 3 ? tilt[2 * p + 1] : cos_o;
    const float fac = 1.0f + vp * std::log(uc + (1.0f - uc) * std::exp(-2.0f / vp));
    const float sin_i = clampf(-fac * so + cos_from_sin(fac) * std::cos(kTwoPi * u.y) * co, -1.0f, 1.0f);
    const float cos_i = cos_from_sin(sin_i);
    const float phi = p < 3 ? deflection(p, gamma_o, gamma_t) + sample_trimmed_logistic(u.x, s) : kTwoPi * u.x;
    const float phi_i = phi_o + phi;
    float pdf;
    const Vec3 f = eval_angles(sin_o, cos_o, phi_o, sin_i, cos_i, phi_i, pdf);
    if (!(pdf > 0.0f)) return false;
    out.wi = {sin_i, cos_i * std::cos(phi_i), cos_i * std::sin(phi_i)};
    out.pdf = pdf;
    out.weight = f / pdf;
    out.flags = uint8_t((p == 0 ? kReflect : kTransmit) | kGlossyLobe);
    out.eta = 1.0f;
    return true;
  }
};

// Cycles' Hair BSDF node (kernel/closure/bsdf_hair.h, after Open Shading Language's hair
// closures): one component, reflection or transmission, with Cauchy (Lorentzian) longitudinal
// terms about the cuticle-tilted half angle and an azimuthal term of width roughness2. Local
// frame: +Z is the closure's normal N, `tangent` the fibre direction T in that frame. As in
// Cycles, f * |cos| equals the pdf (a sample's weight is the closure's colour), and Cycles'
// sampling and evaluation disagree in two places: a sample is never tested against N's side,
// and a reflection sample may land at an azimuth beyond 90 degrees (roughness2 > 0.5) where the
// evaluation gives 0. Cycles' image follows that pairing (a BSDF-sampled direction carries the
// sample's value, light samples the evaluation), so Pathlight evaluates both: eval (light
// samples, other closures) and eval_sampled (the direction this closure itself sampled).
struct HairBsdf {
  Vec3 tangent{1.0f, 0.0f, 0.0f};  // T in the local frame (unit)
  float roughness1 = 0.1f;         // longitudinal, in [0.001, 1]
  float roughness2 = 1.0f;         // azimuthal, in [0.001, 1]
  float offset = 0.0f;             // radians, Cycles' sign (the node's Offset negated)
  bool transmission = false;

  static HairBsdf setup(Vec3 tangent_local, float r1, float r2, float offset, bool transmission) {
    HairBsdf b;
    b.tangent = tangent_local;
    b.roughness1 = clampf(std::isfinite(r1) ? r1 : 0.1f, 0.001f, 1.0f);
    b.roughness2 = clampf(std::isfinite(r2) ? r2 : 1.0f, 0.001f, 1.0f);
    b.offset = std::isfinite(offset) ? offset : 0.0f;
    b.transmission = transmission;
    return b;
  }

  // The view's longitudinal angle, its azimuthal axis (locy) and the Cauchy range [b, a] that
  // keeps the sampled theta_i within [-pi/2, pi/2].
  struct View {
    float theta_r, a, b;
    Vec3 locy, locx;
    bool ok;
  };
  View view(Vec3 wo) const {
    View v;
    const float iz = clampf(dot(tangent, wo), -1.0f, 1.0f);
    const Vec3 y = wo - tangent * iz;
    const float ly = length(y);
    v.ok = ly > 1e-7f;
    v.locy = v.ok ? y / ly : Vec3(0.0f);
    v.locx = cross(v.locy, tangent);
    v.theta_r = 0.5f * kPi - std::acos(iz);
    const float inv = 1.0f / roughness1;
    v.a = std::atan(((0.5f * kPi + v.theta_r) * 0.5f - offset) * inv);
    v.b = std::atan(((-0.5f * kPi + v.theta_r) * 0.5f - offset) * inv);
    return v;
  }
  float theta_pdf(const View& v, float theta_i) const {
    const float t = 0.5f * (theta_i + v.theta_r) - offset;
    return roughness1 / (2.0f * (t * t + roughness1 * roughness1) * (v.a - v.b) * std::cos(theta_i));
  }
  // The azimuth of wi about the fibre, as the angle from the view's axis (0..pi), and theta_i.
  static bool angles(const View& v, Vec3 tangent, Vec3 wi, float& theta_i, float& cos_phi) {
    const float wz = clampf(dot(tangent, wi), -1.0f, 1.0f);
    const Vec3 y = wi - tangent * wz;
    const float ly = length(y);
    if (!(ly > 1e-7f)) return false;
    theta_i = 0.5f * kPi - std::acos(wz);
    cos_phi = clampf(dot(y / ly, v.locy), -1.0f, 1.0f);
    return 0.5f * kPi - std::fabs(theta_i) >= 0.001f;
  }
  // The azimuthal density of the component's own sampling at azimuth phi (0..pi).
  float phi_pdf_sampled(float phi) const {
    if (!transmission) {
      if (phi > kPi * roughness2) return 0.0f;
      return std::cos(0.5f * phi / roughness2) * 0.25f / roughness2;
    }
    const float p = kPi - phi;  // the sampled p lies within [-pi/2, pi/2]
    if (p > 0.5f * kPi) return 0.0f;
    const float c = 2.0f * std::atan(0.5f * kPi / roughness2);
    return roughness2 / (c * (p * p + roughness2 * roughness2));
  }

  // Cycles' bsdf_hair_*_eval: f * |cos| (= the pdf, per channel) for view wo and light wi.
  Vec3 eval(Vec3 wo, Vec3 wi, float& pdf) const {
    pdf = 0.0f;
    if (transmission ? wi.z >= 0.0f : wi.z < 0.0f) return Vec3(0.0f);
    const View v = view(wo);
    float theta_i, cos_phi;
    if (!v.ok || !angles(v, tangent, wi, theta_i, cos_phi)) return Vec3(0.0f);
    float phi_pdf;
    if (!transmission) {
      if (cos_phi < 0.0f) return Vec3(0.0f);
      const float phi = std::min(std::acos(cos_phi) / roughness2, kPi);
      phi_pdf = std::cos(0.5f * phi) * 0.25f / roughness2;
    } else {
      const float p = kPi - std::acos(cos_phi);
      const float c = 2.0f * std::atan(0.5f * kPi / roughness2);
      phi_pdf = roughness2 / (c * (p * p + roughness2 * roughness2));
    }
    pdf = phi_pdf * theta_pdf(v, theta_i);
    if (!(pdf > 0.0f) || !std::isfinite(pdf)) pdf = 0.0f;
    return Vec3(pdf);
  }

  // What a sample of this closure carries along the direction it drew (Cycles' sample: eval =
  // pdf, on either side of N): the density of its own sampling.
  Vec3 eval_sampled(Vec3 wo, Vec3 wi, float& pdf) const {
    pdf = 0.0f;
    const View v = view(wo);
    float theta_i, cos_phi;
    if (!v.ok || !angles(v, tangent, wi, theta_i, cos_phi)) return Vec3(0.0f);
    pdf = phi_pdf_sampled(std::acos(cos_phi)) * theta_pdf(v, theta_i);
    if (!(pdf > 0.0f) || !std::isfinite(pdf)) pdf = 0.0f;
    return Vec3(pdf);
  }

  bool sample(Vec3 wo, Vec2 u, float, BsdfSample& out) const {
    const View v = view(wo);
    if (!v.ok) return false;
    const float t = roughness1 * std::tan(u.x * (v.a - v.b) + v.b);
    const float theta_i = 2.0f * (t + offset) - v.theta_r;
    float phi;
    if (!transmission) {
      phi = 2.0f * std::asin(clampf(1.0f - 2.0f * u.y, -1.0f, 1.0f)) * roughness2;
    } else {
      const float c = 2.0f * std::atan(0.5f * kPi / roughness2);
      phi = roughness2 * std::tan(c * (u.y - 0.5f)) + kPi;
    }
    const float ct = std::cos(theta_i), st = std::sin(theta_i);
    out.wi = v.locy * (std::cos(phi) * ct) - v.locx * (std::sin(phi) * ct) + tangent * st;
    float pdf;
    eval_sampled(wo, out.wi, pdf);
    if (!(pdf > 0.0f)) return false;
    out.pdf = pdf;
    out.weight = Vec3(1.0f);
    out.flags = uint8_t((out.wi.z >= 0.0f ? kReflect : kTransmit) | kGlossyLobe);
    out.eta = 1.0f;
    return true;
  }
};

}  // namespace pl
