// Blender's Sheen BSDF lobes (and Principled's Sheen layer): the microfibre sheen of Zeltner,
// Burley and Chiang 2022 as Cycles 4.5 evaluates it, and Ashikhmin's velvet. Included by
// bsdf.h before its variant; local frame as there (+Z the closure's normal, eval = f |cos|).
#pragma once
#include "scene/microfacet_energy.h"
#include "scene/sheen_tables.h"

namespace pl {

// Zeltner et al.'s sheen: a linearly transformed cosine whose inverse matrix
// [[a, 0, b], [0, a, 0], [0, 0, 1]] (in a frame whose x axis is the view's azimuth) is a
// fitted function of the roughness and the view's cosine (scene/sheen_tables.h). The LTC is a
// normalised density, so eval is exactly its pdf; the layer's albedo (the same fit) goes into the
// closure weight, as Cycles' bsdf_sheen_setup puts it there.
struct SheenBsdf {
  float a = 1.0f, b = 0.0f;
  // The hit is backfacing: lit from -Z. As Cycles (which flips a backfacing hit's normal), the
  // lobe stays on the side the geometry shows the viewer, also where a smooth normal turns
  // away from the view at a silhouette (Cycles' view then reads as grazing).
  bool back = false;

  // The fit for Cycles' clamped roughness and the view's cosine; `albedo` the layer's.
  static SheenBsdf setup(float roughness, float cos_view, float& albedo) {
    const float r = clampf(std::isfinite(roughness) ? roughness : 0.5f, 1e-3f, 1.0f);
    SheenBsdf s;
    s.a = table_2d(tables::sheen_ltc_a, cos_view, r, 32, 32);
    s.b = table_2d(tables::sheen_ltc_b, cos_view, r, 32, 32);
    albedo = table_2d(tables::sheen_albedo, cos_view, r, 32, 32);
    // Where the fit has a = 0 its albedo is 0 too; a tiny a keeps the division finite.
    s.a = std::max(s.a, 1e-4f);
    return s;
  }
  // The view's azimuth as the x axis (Cycles' make_orthonormals_tangent(N, wi)).
  static void view_axes(Vec3 wo, Vec3& t, Vec3& s) {
    const float l2 = wo.x * wo.x + wo.y * wo.y;
    if (l2 > 1e-14f) {
      const float inv = 1.0f / std::sqrt(l2);
      t = {wo.x * inv, wo.y * inv, 0.0f};
    } else {
      t = {1.0f, 0.0f, 0.0f};
    }
    s = {-t.y, t.x, 0.0f};
  }
  // The LTC density of a direction (x, y, z) in the view's frame, z > 0.
  float density(float x, float y, float z) const {
    const float u = a * x + b * z, v = a * y;
    const float len2 = u * u + v * v + z * z;
    const float k = a / len2;
    return z * k * k * kInvPi;
  }
  [[gnu::noinline]] Vec3 eval(Vec3 wo, Vec3 wi, float& pdf) const {
    pdf = 0.0f;
    if ((wi.z < 0.0f) != back || wi.z == 0.0f) return Vec3(0.0f);
    if (back) {
      wo.z = -wo.z;
      wi.z = -wi.z;
    }
    Vec3 t, s;
    view_axes(wo, t, s);
    pdf = density(dot(wi, t), dot(wi, s), wi.z);
    return Vec3(pdf);
  }
  [[gnu::noinline]] bool sample(Vec3 wo, Vec2 u, float, BsdfSample& out) const {
    const bool flip = back;
    if (flip) wo.z = -wo.z;
    // A cosine-distributed direction carried through the LTC's matrix (the inverse's inverse).
    const Vec2 d = sample_disk_concentric(u);
    const float dz = std::sqrt(std::max(0.0f, 1.0f - d.x * d.x - d.y * d.y));
    Vec3 l{(d.x - dz * b) / a, d.y / a, dz};
    const float len = length(l);
    if (!(len > 0.0f) || !std::isfinite(len)) return false;
    l = l / len;
    if (!(l.z > 0.0f)) return false;
    Vec3 t, s;
    view_axes(wo, t, s);
    out.wi = t * l.x + s * l.y + Vec3(0.0f, 0.0f, l.z);
    out.pdf = density(l.x, l.y, l.z);
    if (!(out.pdf > 0.0f)) return false;
    out.weight = Vec3(1.0f);
    out.flags = kReflect | kDiffuseLobe;  // Cycles labels it diffuse
    if (flip) out.wi.z = -out.wi.z;
    return true;
  }
};

// Ashikhmin's velvet (Cycles' bsdf_ashikhmin_velvet, from OSL): an inverted-Gaussian-like
// distribution of cot^2 of the half vector, a min(1, ...) shadowing, uniformly sampled.
struct VelvetBsdf {
  float inv_sigma2 = 1.0f;
  static VelvetBsdf setup(float sigma) {
    const float s = std::max(clampf(std::isfinite(sigma) ? sigma : 1.0f, 0.0f, 1.0f), 0.01f);
    return VelvetBsdf{1.0f / (s * s)};
  }
  [[gnu::noinline]] Vec3 eval(Vec3 wo, Vec3 wi, float& pdf) const {
    pdf = 0.0f;
    if (!same_side(wo, wi)) return Vec3(0.0f);
    if (wo.z < 0.0f) {
      wo.z = -wo.z;
      wi.z = -wi.z;
    }
    const float cos_v = wo.z, cos_l = wi.z;
    if (!(cos_v > 0.0f && cos_l > 0.0f)) return Vec3(0.0f);
    const Vec3 h = normalize(wo + wi);
    const float cos_nh = h.z, cos_hv = std::fabs(dot(wo, h));
    if (!(std::fabs(cos_nh) < 1.0f - 1e-5f && cos_hv > 1e-5f)) return Vec3(0.0f);
    pdf = 0.5f * kInvPi;
    const float r = std::max(cos_nh / cos_hv, 1e-5f);
    const float G = std::min(1.0f, std::min(2.0f * std::fabs(r * cos_v), 2.0f * std::fabs(r * cos_l)));
    const float sin2 = 1.0f - cos_nh * cos_nh;
    const float cot2 = cos_nh * cos_nh / sin2;
    const float D = std::exp(-cot2 * inv_sigma2) * inv_sigma2 * kInvPi / (sin2 * sin2);
    return Vec3(0.25f * D * G / cos_v);
  }
  [[gnu::noinline]] bool sample(Vec3 wo, Vec2 u, float, BsdfSample& s) const {
    const bool flip = wo.z < 0.0f;
    if (flip) wo.z = -wo.z;
    const float z = u.x, r = std::sqrt(std::max(0.0f, 1.0f - z * z)), phi = 2.0f * kPi * u.y;
    Vec3 wi{r * std::cos(phi), r * std::sin(phi), z};
    if (!(wi.z > 0.0f)) return false;
    const Vec3 f = eval(wo, wi, s.pdf);
    if (!(s.pdf > 0.0f)) return false;  // (a zero f is a valid sample of the uniform pdf)
    s.weight = f / s.pdf;
    s.flags = kReflect | kDiffuseLobe;
    if (flip) wi.z = -wi.z;
    s.wi = wi;
    return true;
  }
};

}  // namespace pl
