// Blender's Multiscatter GGX as Cycles 4.x does it (Kulla & Conty 2017's energy compensation on
// top of single-scatter GGX), the Fresnel models of its Principled BSDF (F82-Tint metals, the
// generalized Schlick dielectric) and the albedo estimates its layering uses. The tables are our
// own integrals (tools/gen_microfacet_tables.py), indexed as Cycles indexes its.
#pragma once
#include "scene/microfacet.h"
#include "scene/microfacet_tables.h"

namespace pl {

// Cycles' lookup_table_read: entry i sits at i / (n - 1), linear in between, clamped.
inline float table_1d(const float* t, float x, int n) {
  x = clampf(std::isfinite(x) ? x : 0.0f, 0.0f, 1.0f) * float(n - 1);
  const int i = std::min(int(x), n - 1), j = std::min(i + 1, n - 1);
  const float f = x - float(i);
  return t[i] + (t[j] - t[i]) * f;
}
inline float table_2d(const float* t, float x, float y, int nx, int ny) {
  y = clampf(std::isfinite(y) ? y : 0.0f, 0.0f, 1.0f) * float(ny - 1);
  const int i = std::min(int(y), ny - 1), j = std::min(i + 1, ny - 1);
  const float f = y - float(i);
  const float a = table_1d(t + nx * i, x, nx), b = table_1d(t + nx * j, x, nx);
  return a + (b - a) * f;
}
inline float table_3d(const float* t, float x, float y, float z, int nx, int ny, int nz) {
  z = clampf(std::isfinite(z) ? z : 0.0f, 0.0f, 1.0f) * float(nz - 1);
  const int i = std::min(int(z), nz - 1), j = std::min(i + 1, nz - 1);
  const float f = z - float(i);
  const float a = table_2d(t + nx * ny * i, x, y, nx, ny), b = table_2d(t + nx * ny * j, x, y, nx, ny);
  return a + (b - a) * f;
}

inline float f0_from_ior(float ior) {
  const float r = (ior - 1.0f) / (ior + 1.0f);
  return r * r;
}
inline float ior_from_f0(float f0) {
  const float s = std::sqrt(clampf(f0, 0.0f, 0.99f));
  return (1.0f + s) / (1.0f - s);
}
// The tables' IOR axis: F0^(1/4), which covers IORs 1..inf with most entries at 1..2.
inline float ior_table_coord(float ior) { return std::sqrt(std::fabs((ior - 1.0f) / (ior + 1.0f))); }

// Average of 2 cos F(cos) over the hemisphere for a dielectric (Kulla & Conty's fit, as Cycles).
inline float fresnel_dielectric_fss(float eta) {
  if (eta < 1.0f) return 0.997118f + eta * (0.1014f - eta * (0.965241f + eta * 0.130607f));
  return (eta - 1.0f) / (4.08567f + 1.00071f * eta);
}

// F82-Tint (Kutz et al., "Novel aspects of the Adobe Standard Material"): Schlick's curve from
// f0 less b cos (1 - cos)^6, b chosen so that at cos = 1/7 (about 82 degrees) the curve is
// Schlick's times the tint.
inline Vec3 f82_tint_b(Vec3 f0, Vec3 tint) {
  const float f = 6.0f / 7.0f, f5 = (f * f) * (f * f) * f;
  const Vec3 schlick = f0 + (Vec3(1.0f) - f0) * f5;
  return schlick * (7.0f / (f5 * f)) * (Vec3(1.0f) - tint);
}
inline Vec3 fresnel_f82(float c, Vec3 f0, Vec3 b) {
  const float s = clampf(1.0f - c, 0.0f, 1.0f), s5 = (s * s) * (s * s) * s;
  const Vec3 v = f0 + (Vec3(1.0f) - f0) * s5 - b * (c * s5 * s);
  return vmin(vmax(v, Vec3(0.0f)), Vec3(1.0f));
}
// Its hemispherical average (closed form of 2 int cos F).
inline Vec3 f82_fss(Vec3 f0, Vec3 b) { return f0 + (Vec3(1.0f) - f0) * (1.0f / 21.0f) - b * (1.0f / 126.0f); }

// Exact unpolarized Fresnel reflectance from air onto a conductor of complex IOR n + ik (the
// s and p reflectances averaged; e.g. Born & Wolf), per channel.
inline float fresnel_conductor1(float c, float n, float k) {
  c = clampf(c, 0.0f, 1.0f);
  const float c2 = c * c, s2 = 1.0f - c2;
  const float t0 = n * n - k * k - s2;
  const float a2b2 = std::sqrt(std::max(t0 * t0 + 4.0f * n * n * k * k, 0.0f));
  const float a = std::sqrt(std::max(0.5f * (a2b2 + t0), 0.0f));
  const float t1 = a2b2 + c2, t2 = 2.0f * a * c;
  const float rs = (t1 - t2) / std::max(t1 + t2, 1e-20f);
  const float t3 = c2 * a2b2 + s2 * s2, t4 = t2 * s2;
  const float rp = rs * (t3 - t4) / std::max(t3 + t4, 1e-20f);
  return clampf(0.5f * (rs + rp), 0.0f, 1.0f);
}
inline Vec3 fresnel_conductor(float c, Vec3 n, Vec3 k) {
  return {fresnel_conductor1(c, n.x, k.x), fresnel_conductor1(c, n.y, k.y), fresnel_conductor1(c, n.z, k.z)};
}
// Its average for Multiscatter GGX as Cycles estimates it (fresnel_conductor_Fss): the F82 curve
// through the values at 0 and ~82 degrees (cos 1/7), then that curve's closed-form average.
inline Vec3 conductor_fss(Vec3 n, Vec3 k) {
  const Vec3 F0 = fresnel_conductor(1.0f, n, k), F82 = fresnel_conductor(1.0f / 7.0f, n, k);
  const float f = 6.0f / 7.0f, f5 = (f * f) * (f * f) * f;
  const Vec3 b = (F0 + (Vec3(1.0f) - F0) * f5 - F82) * (7.0f / (f5 * f));
  return vmin(vmax(f82_fss(F0, b), Vec3(0.0f)), Vec3(1.0f));
}

// What Multiscatter GGX does to a lobe seen from the view at cos `mu`: `scale` multiplies the
// single-scatter lobe (the missing energy 1/E - 1 returned with the multiple-bounce Fresnel
// Fms), and `darkening` is the part of it that Cycles folds into the closure weight (what its
// layering sees: scale = darkening * (1 + missing)).
struct EnergyCompensation {
  Vec3 scale{1.0f};
  Vec3 darkening{1.0f};
};

inline EnergyCompensation compensate(float E, float E_avg, Vec3 fss) {
  EnergyCompensation c;
  E = std::max(E, 1e-3f);
  const float missing = (1.0f - E) / E;
  const float energy_scale = 1.0f + missing;
  if (fss.x == 1.0f && fss.y == 1.0f && fss.z == 1.0f) {
    c.scale = Vec3(energy_scale);
    return c;
  }
  const Vec3 denom = Vec3(1.0f) - fss * (1.0f - E_avg);
  const Vec3 fms = {fss.x * E_avg / std::max(denom.x, 1e-6f), fss.y * E_avg / std::max(denom.y, 1e-6f),
                    fss.z * E_avg / std::max(denom.z, 1e-6f)};
  c.scale = Vec3(1.0f) + fms * missing;
  c.darkening = c.scale / energy_scale;
  return c;
}

// GGX reflection; `rough` is Blender's roughness (sqrt(alpha)).
[[gnu::always_inline]] inline EnergyCompensation ggx_reflection_compensation(float rough, float mu, Vec3 fss) {
  const float E = table_2d(tables::ggx_E, rough, mu, 32, 32);
  const float E_avg = table_1d(tables::ggx_Eavg, rough, 32);
  return compensate(E, E_avg, fss);
}

// GGX glass (reflection and transmission) of relative IOR eta (< 1: seen from inside).
// Its single-scatter albedo E (reflection and transmission) seen from the view at cos `mu`.
inline float ggx_glass_E(float rough, float mu, float eta) {
  const bool inv = eta < 1.0f;
  const float z = ior_table_coord(inv ? 1.0f / eta : eta);
  return table_3d(inv ? tables::ggx_glass_inv_E : tables::ggx_glass_E, rough, mu, z, 16, 16, 16);
}
inline EnergyCompensation ggx_glass_compensation(float rough, float mu, float eta, Vec3 fss) {
  const bool inv = eta < 1.0f;
  const float z = ior_table_coord(inv ? 1.0f / eta : eta);
  const float E = ggx_glass_E(rough, mu, eta);
  const float E_avg = table_2d(inv ? tables::ggx_glass_inv_Eavg : tables::ggx_glass_Eavg, rough, z, 16, 16);
  return compensate(E, E_avg, fss);
}

// Cycles' bsdf_microfacet_estimate_albedo for the generalized-Schlick dielectric in its real-
// Fresnel mode: mix(f0, 1, s) with s the table's mean interpolation factor at this roughness,
// view and IOR.
inline Vec3 dielectric_specular_albedo(float rough, float mu, float eta, Vec3 f0) {
  const float s = table_3d(tables::ggx_gen_schlick_ior_s, rough, mu, ior_table_coord(eta), 16, 16, 16);
  return f0 + (Vec3(1.0f) - f0) * s;
}

// Cycles' estimate for F82-Tint (bsdf_microfacet_estimate_albedo; its b term left out, a
// TODO there): mix(f0, 1, s), s the Schlick table's factor read at z = 0.5 (exponent 5).
inline Vec3 f82_specular_albedo(float rough, float mu, Vec3 f0) {
  const float s = table_3d(tables::ggx_gen_schlick_s, rough, mu, 0.5f, 16, 16, 16);
  return f0 + (Vec3(1.0f) - f0) * s;
}

}  // namespace pl
