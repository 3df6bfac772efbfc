// Blender's Toon BSDF as Cycles 4.5 (bsdf_toon.h, from OSL): a constant lobe within Size (x pi/2)
// of the normal (Diffuse) or of the view's mirror direction (Glossy), fading out linearly over
// Smooth (x pi/2), sampled uniformly over the cone it covers. Not energy-conserving, as Cycles'.
// Included by bsdf.h before its variant.
#pragma once
#include "scene/microfacet_energy.h"

namespace pl {

struct ToonBsdf {
  float size = 0.25f * kPi, smooth = 0.0f;  // radians
  bool glossy = false;

  static ToonBsdf setup(float size, float smooth, bool glossy) {
    ToonBsdf t;
    t.size = clampf(std::isfinite(size) ? size : 0.5f, 1e-5f, 1.0f) * (0.5f * kPi);
    t.smooth = clampf(std::isfinite(smooth) ? smooth : 0.0f, 0.0f, 1.0f) * (0.5f * kPi);
    t.glossy = glossy;
    return t;
  }
  float cone_angle() const { return std::min(size + smooth, 0.5f * kPi); }
  float intensity(float angle) const {
    if (angle < size) return 1.0f;
    if (smooth != 0.0f && angle < size + smooth) return 1.0f - (angle - size) / smooth;
    return 0.0f;
  }
  // The cone's uniform pdf (1 - cos underflows for tiny cones: at least a tiny solid angle).
  float cone_pdf() const {
    const float a = cone_angle();
    const float one_minus_cos = std::max(2.0f * std::sin(0.5f * a) * std::sin(0.5f * a), 1e-12f);
    return 1.0f / (2.0f * kPi * one_minus_cos);
  }
  [[gnu::noinline]] Vec3 eval(Vec3 wo, Vec3 wi, float& pdf) const {
    pdf = 0.0f;
    if (!same_side(wo, wi)) return Vec3(0.0f);
    if (wo.z < 0.0f) {  // two-sided: mirrored to the view's side
      wo.z = -wo.z;
      wi.z = -wi.z;
    }
    const Vec3 axis = glossy ? Vec3{-wo.x, -wo.y, wo.z} : Vec3{0.0f, 0.0f, 1.0f};
    const float angle = std::acos(clampf(dot(axis, wi), 0.0f, 1.0f));
    if (!(angle < cone_angle())) return Vec3(0.0f);
    pdf = cone_pdf();
    return Vec3(pdf * intensity(angle));
  }
  [[gnu::noinline]] bool sample(Vec3 wo, Vec2 u, float, BsdfSample& s) const {
    const bool flip = wo.z < 0.0f;
    if (flip) wo.z = -wo.z;
    const Vec3 axis = glossy ? Vec3{-wo.x, -wo.y, wo.z} : Vec3{0.0f, 0.0f, 1.0f};
    const float a = cone_angle();
    const float one_minus_cos = 2.0f * std::sin(0.5f * a) * std::sin(0.5f * a);
    const float cz = 1.0f - u.x * one_minus_cos;
    const float sz = std::sqrt(std::max(0.0f, 1.0f - cz * cz)), phi = 2.0f * kPi * u.y;
    Vec3 t, b;
    make_basis(axis, t, b);
    Vec3 wi = t * (sz * std::cos(phi)) + b * (sz * std::sin(phi)) + axis * cz;
    if (!(wi.z > 0.0f)) return false;
    const Vec3 f = eval(wo, wi, s.pdf);
    if (!(s.pdf > 0.0f)) return false;
    s.weight = f / s.pdf;
    s.flags = kReflect | (glossy ? kGlossyLobe : kDiffuseLobe);
    if (flip) wi.z = -wi.z;
    s.wi = wi;
    return true;
  }
};

}  // namespace pl
