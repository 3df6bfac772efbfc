// The Principled Hair BSDF, Huang model (Huang, Hullin & Hanika 2022, "A Microfacet-based Hair
// Scattering Model"), as Cycles 4.x evaluates it (bsdf_principled_hair_huang.h): an elliptical
// fibre whose surface is a GGX microfacet surface tilted by the cuticle angle. R is integrated
// over the visible azimuths by Simpson's rule; TT and TRT by Simpson's rule over the entry
// azimuth with one sampled microfacet per node (a fixed LCG sequence per shading point, as
// Cycles' sd->lcg_state); the residual (TRRT+) is a geometric series with Chiang's longitudinal
// term and a uniform azimuth. Sampling traces one path through the fibre and returns its value
// with pdf 1; Cycles' eval also reports pdf 1, so MIS weighs both techniques as Cycles does
// (a deliberate copy: Cycles' picture is the reference).
//
// Far field (integrated over the whole fibre width) for every ray except camera rays on strands
// wider than a pixel, where Cycles integrates over the pixel's footprint (near field).
//
// Local frame (Cycles'): x the major axis (circular fibres: across the view), y along the fibre,
// z = x cross y. theta is the angle from the x-z plane, phi = atan2(x, z).
#pragma once
#include <cmath>
#include <cstdint>

#include "scene/microfacet_energy.h"
#include "util/math.h"
// (included by bsdf.h, after BsdfSample and the lobe flags)

namespace pl {

namespace huang_detail {

constexpr float kTwoPi = 6.28318530717958647692f;

inline float sq(float x) { return x * x; }
inline float cos_theta(Vec3 w) { return std::sqrt(std::max(0.0f, w.x * w.x + w.z * w.z)); }
inline float tan_theta(Vec3 w) { return w.y / cos_theta(w); }
inline float dir_phi(Vec3 w) { return std::atan2(w.x, w.z); }

// Azimuth phi of the ellipse's point at parameter gamma, and back (x = sin g, z = b cos g).
inline float to_phi(float gamma, float b) {
  return b == 1.0f ? gamma : std::atan2(b * std::sin(gamma), std::cos(gamma));
}
inline float to_gamma(float phi, float b) {
  return b == 1.0f ? phi : std::atan2(std::sin(phi), b * std::cos(phi));
}
// The ellipse parameter hit at offset h (divided by the projected radius) from direction wi.
inline float h_to_gamma(float h_div_r, float b, Vec3 wi) {
  h_div_r = clampf(h_div_r, -1.0f, 1.0f);
  return b == 1.0f ? -std::asin(h_div_r) : std::atan2(wi.z, -b * wi.x) - std::acos(-h_div_r);
}
// The distance between the ellipse's points at parameters g0 and g1 (x = sin g, z = b cos g).
inline float chord(float g0, float g1, float b) {
  return std::sqrt(sq(std::sin(g0) - std::sin(g1)) + sq(b * (std::cos(g0) - std::cos(g1))));
}
// The (tilted) normal at ellipse parameter gamma, longitudinal angle theta.
inline Vec3 sphg_dir(float theta, float gamma, float b) {
  const float st = std::sin(theta), ct = std::cos(theta), sg = std::sin(gamma), cg = std::cos(gamma);
  float sp = sg, cp = cg;
  if (b != 1.0f && std::fabs(cg) >= 1e-6f) {
    const float tp = b * sg / cg;
    cp = std::copysign(1.0f, cg) / std::sqrt(tp * tp + 1.0f);
    sp = cp * tp;
  }
  return {sp * ct, st, cp * ct};
}
inline float arc_length(float e2, float gamma) { return e2 == 0.0f ? 1.0f : std::sqrt(1.0f - e2 * sq(std::sin(gamma))); }

// GGX with alpha^2 given, in Cycles' forms (no side tests: the callers test visibility).
inline float ggx_d(float a2, float c) {
  const float c2 = c * c;
  return a2 / (kPi * sq((1.0f - c2) + a2 * c2));
}
inline float ggx_lambda(float a2, float c) {
  const float c2 = c * c;
  return 0.5f * (std::sqrt(1.0f + a2 * (1.0f - c2) / c2) - 1.0f);
}
inline float ggx_g(float a2, float ci, float co) { return 1.0f / (1.0f + ggx_lambda(a2, ci) + ggx_lambda(a2, co)); }
// Shadowing-masking over the incoming direction's masking.
inline float ggx_go(float a2, float ci, float co) {
  const float li = ggx_lambda(a2, ci), lo = ggx_lambda(a2, co);
  return (1.0f + li) / (1.0f + li + lo);
}

// Fresnel of a dielectric seen from cos_i's side with relative IOR eta (no flip: the caller
// passes 1 / eta inside), and the transmitted cosine (negative; unchanged on total reflection).
inline float fresnel(float cos_i, float eta, float* cos_t = nullptr) {
  const float e2 = eta * eta - (1.0f - cos_i * cos_i);
  if (e2 <= 0.0f) return 1.0f;
  cos_i = std::fabs(cos_i);
  const float ct = -std::sqrt(e2) / eta;
  if (cos_t) *cos_t = ct;
  const float rs = (cos_i + eta * ct) / (cos_i - eta * ct);
  const float rp = (ct + eta * cos_i) / (eta * ct - cos_i);
  return 0.5f * (rs * rs + rp * rp);
}
inline Vec3 refract_angle(Vec3 in, Vec3 n, float cos_t, float inv_eta) {
  return n * (inv_eta * dot(n, in) + cos_t) - in * inv_eta;
}
inline Vec3 reflect_about(Vec3 v, Vec3 n) { return v - n * (2.0f * dot(n, v)); }  // Cycles' reflect()

inline bool visible(Vec3 v, Vec3 m, Vec3 h) { return dot(v, h) > 0.0f && dot(v, m) > 0.0f; }
inline bool visible(Vec3 a, Vec3 b, Vec3 m, Vec3 h) { return visible(a, m, h) && visible(b, m, h); }

// Cycles' lcg_step_float.
inline float lcg(uint32_t& s) {
  s = 1103515245u * s + 12345u;
  return float(s) * (1.0f / 4294967296.0f);
}

// The GGX glass albedo's inverse (Cycles treats each crossing as glass); rough = sqrt(alpha).
inline float energy_scale(float mu, float rough, float ior) {
  const bool inv = ior < 1.0f;
  const float z = std::sqrt(std::fabs((ior - 1.0f) / (ior + 1.0f)));
  return 1.0f / table_3d(inv ? tables::ggx_glass_inv_E : tables::ggx_glass_E, rough, mu, z, 16, 16, 16);
}

// A visible GGX normal for direction w about the mesonormal wm.
inline Vec3 sample_wh(float alpha, Vec3 w, Vec3 wm, Vec2 u) {
  Vec3 s, t;
  make_basis(wm, s, t);
  const Vec3 loc{dot(w, s), dot(w, t), dot(w, wm)};
  const Vec3 h = Ggx{alpha}.sample_visible(loc, u);
  return s * h.x + t * h.y + wm * h.z;
}

inline Vec3 vexp(Vec3 v) { return {std::exp(v.x), std::exp(v.y), std::exp(v.z)}; }
inline bool finite3(Vec3 v) { return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z); }

}  // namespace huang_detail

struct HairHuangBsdf {
  Vec3 sigma{0.0f};        // absorption per unit of the major radius
  float roughness = 0.3f;  // GGX alpha, [0.001, 1]
  float tilt = 0.0f;       // cuticle tilt (radians), Cycles' sign (the node's Offset negated)
  float eta = 1.55f;
  float b = 1.0f;          // minor / major axis, (0, 1]
  float h = 0.0f;          // the hit's offset across the fibre (Cycles' bsdf->h)
  float pixel_coverage = 1.0f;  // half a pixel across the fibre, in radii (1: far field)
  float R = 1.0f, TT = 1.0f, TRT = 1.0f;  // lobe weights (>= 0)
  uint32_t seed = 0;       // the shading point's LCG state (Cycles' sd->lcg_state)

  // From the node's inputs as Cycles' svm_node_closure and bsdf_hair_huang_setup clamp them
  // (an aspect ratio above 1 swaps the axes: the scene's orient step does the swap).
  static HairHuangBsdf from_node(Vec3 sigma, float roughness, float offset, float ior, float aspect, float r,
                                 float tt, float trt) {
    HairHuangBsdf x;
    x.sigma = sigma;
    x.roughness = clampf(std::isfinite(roughness) ? roughness : 0.3f, 0.001f, 1.0f);
    x.tilt = std::isfinite(offset) ? -offset : 0.0f;
    x.eta = std::isfinite(ior) && ior > 0.0f ? ior : 1.55f;
    x.b = std::isfinite(aspect) ? clampf(aspect, 1e-3f, 1e3f) : 1.0f;
    x.R = std::isfinite(r) ? std::max(0.0f, r) : 1.0f;
    x.TT = std::isfinite(tt) ? std::max(0.0f, tt) : 1.0f;
    x.TRT = std::isfinite(trt) ? std::max(0.0f, trt) : 1.0f;
    return x;
  }

  float e2() const { return 1.0f - b * b; }
  // The fibre's width seen from wi (local), in major radii.
  float projected_radius(Vec3 wi) const {
    const float e = e2();
    if (e == 0.0f) return 1.0f;
    const float d = wi.x * wi.x + wi.z * wi.z;
    return d > 0.0f ? std::sqrt(std::max(0.0f, 1.0f - e * wi.x * wi.x / d)) : 1.0f;
  }
  bool near_field(float radius) const { return radius > pixel_coverage; }

  float eval_r(Vec3 wi, Vec3 wo, float g0, float g1) const {
    using namespace huang_detail;
    if (R <= 0.0f) return 0.0f;
    const Vec3 wh = normalize(wi + wo);
    const float a2 = sq(roughness), e = e2(), rough = std::sqrt(roughness);
    float res = roughness * 0.7f;
    const float range = g1 - g0;
    const int n = 2 * int(std::ceil(range / res * 0.5f));
    if (n <= 0) return 0.0f;
    res = range / float(n);
    float sum = 0.0f;
    for (int i = 0; i <= n; ++i) {
      const float g = g0 + float(i) * res;
      const Vec3 wm = sphg_dir(tilt, g, b);
      if (!visible(wi, wo, Vec3{wm.x, 0.0f, wm.z}, wh)) continue;
      const float w = (i == 0 || i == n) ? 0.5f : float(i % 2 + 1);
      const float cmi = dot(wm, wi);
      sum += w * ggx_d(a2, dot(wm, wh)) * ggx_g(a2, cmi, dot(wm, wo)) * arc_length(e, g) * energy_scale(cmi, rough, eta);
    }
    sum *= 2.0f / 3.0f * res;
    return R * 0.25f * fresnel(dot(wi, wh), eta) * sum;
  }

  static Vec3 trrt(float T, float Rf, Vec3 A) {
    const float t_avg = std::max(1.0f - Rf, 1e-5f);
    const Vec3 num = A * A * A * (T * Rf * Rf * t_avg);
    return num / (Vec3(1.0f) - A * (1.0f - t_avg));
  }

  Vec3 eval_residual(Vec3 wi, Vec3 wo, float g0, float g1) const {
    using namespace huang_detail;
    if (TT <= 0.0f && TRT <= 0.0f) return Vec3(0.0f);
    const bool circular = b == 1.0f;
    const float inv_eta = 1.0f / eta, a2 = sq(roughness), rough = std::sqrt(roughness), e = e2();
    float res = roughness * 0.8f;
    const float range = g1 - g0;
    const int n = 2 * int(std::ceil(range / res * 0.5f));
    if (n <= 0) return Vec3(0.0f);
    res = range / float(n);
    uint32_t rng = seed;
    Vec3 s_tt(0.0f), s_trt(0.0f), s_trrt(0.0f);
    for (int i = 0; i <= n; ++i) {
      const float gmi = g0 + float(i) * res;
      const Vec3 wmi = sphg_dir(tilt, gmi, b), wmi_ = sphg_dir(0.0f, gmi, b);
      const Vec2 u1{lcg(rng), lcg(rng)};
      const Vec3 wh1 = sample_wh(roughness, wi, wmi, u1);
      const float chi1 = dot(wi, wh1);
      if (!(chi1 > 0.0f)) continue;
      const float cmi1 = dot(wi, wmi);
      float ct1 = 0.0f;
      const float T1 = 1.0f - fresnel(chi1, eta, &ct1);
      const float scale1 = energy_scale(cmi1, rough, eta);
      const Vec3 wt = refract_angle(wi, wh1, ct1, inv_eta);
      const float phi_t = dir_phi(wt);
      const float gmt = 2.0f * to_phi(phi_t, b) - gmi;
      const Vec3 wmt = sphg_dir(-tilt, gmt, b), wmt_ = sphg_dir(0.0f, gmt, b);
      const float cmo1 = dot(-wt, wmi), cmi2 = dot(-wt, wmt);
      const float g1o = ggx_go(a2, cmi1, cmo1);
      if (!visible(wi, -wt, wmi, wh1) || !visible(wi, -wt, wmi_, wh1)) continue;
      const float w = (i == 0 || i == n) ? 0.5f : float(i % 2 + 1);
      const float path = circular ? -2.0f * std::cos(gmi - phi_t)
                                  : chord(gmi, gmt + kPi, b);
      const Vec3 At = vexp(sigma * (-path / cos_theta(wt)));
      const float scale2 = energy_scale(cmi2, rough, inv_eta);
      if (TT > 0.0f && dot(wo, wt) >= inv_eta - 1e-5f) {
        Vec3 wh2 = -wt + wo * inv_eta;
        const float rn = 1.0f / length(wh2);
        wh2 = wh2 * rn;
        const float cmh2 = dot(wmt, wh2);
        if (cmh2 >= 0.0f) {
          const float chi2 = dot(-wt, wh2), cho2 = dot(-wo, wh2), cmo2 = dot(-wo, wmt);
          const float T2 = (1.0f - fresnel(chi2, inv_eta)) * scale2;
          const float D2 = ggx_d(a2, cmh2), G2 = ggx_g(a2, cmi2, cmo2);
          const Vec3 r = At * (w * T1 * scale1 * T2 * D2 * g1o * G2 / cmo1 * cmi1 * chi2 * cho2 * rn * rn);
          if (finite3(r)) s_tt += r * (TT * arc_length(e, gmt));
        }
      }
      if (TRT > 0.0f) {
        const Vec2 u2{lcg(rng), lcg(rng)};
        const Vec3 wh2 = sample_wh(roughness, -wt, wmt, u2);
        const float chi2 = dot(-wt, wh2);
        if (!(chi2 > 0.0f)) continue;
        const float R2 = fresnel(chi2, inv_eta);
        const Vec3 wtr = -reflect_about(wt, wh2);
        if (dot(-wtr, wo) < inv_eta - 1e-5f) {  // total internal reflection
          s_trrt += trrt(T1, R2, At) * w;
          continue;
        }
        if (!visible(-wt, -wtr, wmt, wh2) || !visible(-wt, -wtr, wmt_, wh2)) continue;
        const float phi_tr = dir_phi(wtr);
        const float gmtr = gmi - 2.0f * (to_phi(phi_t, b) - to_phi(phi_tr, b)) + kPi;
        const Vec3 wmtr = sphg_dir(-tilt, gmtr, b), wmtr_ = sphg_dir(0.0f, gmtr, b);
        Vec3 wh3 = wtr + wo * inv_eta;
        const float rn3 = 1.0f / length(wh3);
        wh3 = wh3 * rn3;
        const float cmh3 = dot(wmtr, wh3);
        if (cmh3 < 0.0f || !visible(wtr, -wo, wmtr, wh3) || !visible(wtr, -wo, wmtr_, wh3)) {
          s_trrt += trrt(T1, R2, At) * w;
          continue;
        }
        const float chi3 = dot(wh3, wtr), cho3 = dot(wh3, -wo), cmi3 = dot(wmtr, wtr);
        const float T3 = (1.0f - fresnel(chi3, inv_eta)) * energy_scale(cmi3, rough, inv_eta);
        const float D3 = ggx_d(a2, cmh3);
        const float path2 = circular ? 2.0f * std::fabs(std::cos(phi_tr - gmt))
                                     : chord(gmtr, gmt, b);
        const Vec3 Atr = vexp(sigma * (-path2 / cos_theta(wtr)));
        const float cmo2 = dot(wmt, -wtr);
        const float g2o = ggx_go(a2, cmi2, cmo2), G3 = ggx_g(a2, cmi3, dot(wmtr, -wo));
        const Vec3 r = At * Atr *
                       (w * T1 * scale1 * R2 * scale2 * T3 * D3 * g1o * g2o * G3 / (cmo1 * cmo2) * cmi1 * cmi2 * chi3 *
                        cho3 * rn3 * rn3);
        if (finite3(r)) s_trt += r * (TRT * arc_length(e, gmtr));
        s_trrt += trrt(T1, R2, At) * w;
      }
    }
    const float M = hair_detail::longitudinal(wi.y, cos_theta(wi), wo.y, cos_theta(wo), 4.0f * roughness);
    const float N = 1.0f / kTwoPi;
    return ((s_tt + s_trt) * (inv_eta * inv_eta) + s_trrt * (M * N * 2.0f / kPi)) * (2.0f / 3.0f * res);
  }

  // f * |cos| for view wo and light wi (local); pdf is 1, as Cycles reports it.
  Vec3 eval(Vec3 wo, Vec3 wi, float& pdf) const {
    using namespace huang_detail;
    pdf = 1.0f;
    const Vec3 I = wo, O = wi;  // Cycles' names: I towards the viewer, O towards the light
    const float tan_tilt = std::tan(tilt);
    if (tan_tilt * tan_theta(O) < -1.0f) return Vec3(0.0f);
    const float arg = std::max(-tan_tilt * tan_theta(I), 0.0f);
    if (!(arg <= 1.0f)) return Vec3(0.0f);
    const float half_span = std::acos(arg);
    const float r = projected_radius(I);
    const float phi_i = b == 1.0f ? 0.0f : dir_phi(I);
    float g0 = to_gamma(phi_i - half_span, b), g1 = to_gamma(phi_i + half_span, b);
    if (g1 < g0) g1 += kTwoPi;
    g0 += 1e-3f;
    g1 -= 1e-3f;
    float dh = 2.0f * r;
    if (near_field(r)) {
      // Only the part of the fibre the pixel sees (Yan et al.'s near field, as Cycles).
      const float hmax = std::min(h + pixel_coverage, r), hmin = std::max(h - pixel_coverage, -r);
      dh = hmax - hmin;
      float n0 = h_to_gamma(hmax / r, b, I), n1 = h_to_gamma(hmin / r, b, I);
      if (n1 < n0) n1 += kTwoPi;
      if (g1 - n0 > kTwoPi) {
        g0 -= kTwoPi;
        g1 -= kTwoPi;
      } else if (n1 - g0 > kTwoPi) {
        n0 -= kTwoPi;
        n1 -= kTwoPi;
      }
      g0 = std::max(g0, n0);
      g1 = std::min(g1, n1);
    }
    const float area = cos_theta(I) * dh;
    if (!(area > 0.0f) || !(g1 > g0)) return Vec3(0.0f);
    const Vec3 f = (Vec3(eval_r(I, O, g0, g1)) + eval_residual(I, O, g0, g1)) / area;
    return finite3(f) ? vmax(f, Vec3(0.0f)) : Vec3(0.0f);
  }

  // One path through the fibre (Cycles' bsdf_hair_huang_sample): uc picks the lobe by energy,
  // u.x the offset h (far field), u.y the first microfacet's first coordinate; the other
  // numbers come from the LCG seeded by the point and u.
  bool sample(Vec3 wo, Vec2 u, float uc, BsdfSample& out) const {
    using namespace huang_detail;
    const Vec3 wi = wo;  // Cycles' wi: towards the viewer
    uint32_t rng = seed ^ (uint32_t(u.x * 4294967040.0f) * 0x9E3779B9u) ^ (uint32_t(uc * 4294967040.0f) * 0x85EBCA6Bu);
    lcg(rng);
    const Vec2 u1{u.y, lcg(rng)};
    const Vec2 u2{lcg(rng), lcg(rng)};
    const Vec2 u3{lcg(rng), lcg(rng)};
    const float r = projected_radius(wi);
    const float h_div_r = near_field(r) ? h / r : u.x * 2.0f - 1.0f;
    const float gmi = h_to_gamma(h_div_r, b, wi);
    const Vec3 wmi_ = sphg_dir(0.0f, gmi, b);
    const float st = std::sin(tilt), ct = std::cos(tilt);
    const Vec3 wmi{wmi_.x * ct, st, wmi_.z * ct};
    const float cmi1 = dot(wmi, wi);
    if (cmi1 < 0.0f || dot(wmi_, wi) < 0.0f) return false;
    const bool circular = b == 1.0f;
    const float a2 = sq(roughness), rough = std::sqrt(roughness), inv_eta = 1.0f / eta;
    const Vec3 wh1 = sample_wh(roughness, wi, wmi, u1);
    const Vec3 wr = -reflect_about(wi, wh1);
    if (!visible(wi, wmi_, wh1)) return false;
    float ct1 = 0.0f;
    const float R1 = fresnel(dot(wi, wh1), eta, &ct1);
    const float scale1 = energy_scale(cmi1, rough, eta);
    const float e_r = visible(wr, wmi_, wh1) ? R * R1 * scale1 * ggx_go(a2, cmi1, dot(wmi, wr)) : 0.0f;

    const Vec3 wt = refract_angle(wi, wh1, ct1, inv_eta);
    const float phi_t = dir_phi(wt);
    const float gmt = 2.0f * to_phi(phi_t, b) - gmi;
    const Vec3 wmt = sphg_dir(-tilt, gmt, b), wmt_ = sphg_dir(0.0f, gmt, b);
    const Vec3 wh2 = sample_wh(roughness, -wt, wmt, u2);
    const Vec3 wtr = -reflect_about(wt, wh2);
    Vec3 wtt, wtrt, wtrrt, e_tt(0.0f), e_trt(0.0f), e_trrt(0.0f);
    const float cmi2 = dot(-wt, wmt);
    if (cmi2 > 0.0f && visible(-wt, wmi_, wh1) && visible(-wt, wmt_, wh2)) {
      const float path = circular ? -2.0f * std::cos(phi_t - gmi) : chord(gmi, gmt + kPi, b);
      const Vec3 At = vexp(sigma * (-path / cos_theta(wt)));
      float ct2 = 0.0f;
      const float R2 = fresnel(dot(-wt, wh2), inv_eta, &ct2);
      const float T1 = (1.0f - R1) * scale1 * ggx_go(a2, cmi1, dot(wmi, -wt));
      const float T2 = 1.0f - R2;
      const float scale2 = energy_scale(cmi2, rough, inv_eta);
      wtt = refract_angle(-wt, wh2, ct2, eta);
      if (dot(wmt, -wtt) > 0.0f && T2 > 0.0f && visible(-wtt, wmt_, wh2))
        e_tt = At * (TT * T1 * T2 * scale2 * ggx_go(a2, cmi2, dot(wmt, -wtt)));
      const float phi_tr = dir_phi(wtr);
      const float gmtr = gmi - 2.0f * (to_phi(phi_t, b) - to_phi(phi_tr, b)) + kPi;
      const Vec3 wmtr = sphg_dir(-tilt, gmtr, b);
      const Vec3 wh3 = sample_wh(roughness, wtr, wmtr, u3);
      float ct3 = 0.0f;
      const float R3 = fresnel(dot(wtr, wh3), inv_eta, &ct3);
      wtrt = refract_angle(wtr, wh3, ct3, eta);
      const float cmi3 = dot(wmtr, wtr);
      if (cmi3 > 0.0f) {
        const float path2 = circular ? 2.0f * std::fabs(std::cos(phi_tr - gmt))
                                     : chord(gmt, gmtr, b);
        const Vec3 Atr = vexp(sigma * (-path2 / cos_theta(wtr)));
        const Vec3 TR = At * Atr *
                        (T1 * R2 * scale2 * energy_scale(cmi3, rough, inv_eta) * ggx_go(a2, cmi2, dot(wmt, -wtr)));
        const float T3 = 1.0f - R3;
        if (T3 > 0.0f && visible(wtr, -wtrt, Vec3{wmtr.x, 0.0f, wmtr.z}, wh3))
          e_trt = TR * (TRT * T3 * ggx_go(a2, cmi3, dot(wmtr, -wtrt)));
        // The residual: Chiang's longitudinal sampling, a uniform azimuth.
        const float ut = std::max(lcg(rng), 1e-5f);
        const float fac = 1.0f + 4.0f * roughness * std::log(ut + (1.0f - ut) * std::exp(-0.5f / roughness));
        const float sin_o = -fac * wi.y + hair_detail::cos_from_sin(fac) * std::cos(kTwoPi * lcg(rng)) * cos_theta(wi);
        const float cos_o = hair_detail::cos_from_sin(sin_o);
        const float phi_o = kTwoPi * lcg(rng);
        wtrrt = {std::sin(phi_o) * cos_o, sin_o, std::cos(phi_o) * cos_o};
        Vec3 Aavg{std::sqrt(At.x * Atr.x), std::sqrt(At.y * Atr.y), std::sqrt(At.z * Atr.z)};
        const float t_avg = std::max(0.5f * (T2 + T3), 1e-5f);
        const Vec3 Ares = Aavg * t_avg / (Vec3(1.0f) - Aavg * (1.0f - t_avg));
        e_trrt = TR * Ares * (R3 * ggx_go(a2, cmi3, dot(wmtr, -(wtr - wh3 * (2.0f * dot(wh3, wtr))))));
      }
    }
    const float er = e_r, ett = average3(e_tt), etrt = average3(e_trt), etrrt = average3(e_trrt);
    const float total = er + ett + etrt + etrrt;
    if (!(total > 0.0f) || !std::isfinite(total)) return false;
    float x = uc * total;
    Vec3 w, weight;
    if (x < er) {
      w = wr;
      weight = Vec3(total);
    } else if (x < er + ett) {
      w = wtt;
      weight = e_tt * (total / ett);
    } else if (x < er + ett + etrt) {
      w = wtrt;
      weight = e_trt * (total / etrt);
    } else {
      w = wtrrt;
      weight = e_trrt * (total / etrrt);
    }
    if (!finite3(weight) || !finite3(w)) return false;
    out.wi = w;
    out.weight = weight;
    out.pdf = 1.0f;
    out.flags = uint8_t(kReflect | kGlossyLobe);  // Cycles labels every sample glossy reflection
    out.eta = 1.0f;
    return true;
  }

  static float average3(Vec3 v) { return (v.x + v.y + v.z) * (1.0f / 3.0f); }
};

}  // namespace pl
