// The closed set of BSDFs and the one place that dispatches over all of them.
// To add a BSDF: write a struct with eval/sample below, add it to the `Bsdf` variant, and
// handle it in bsdf_eval/bsdf_sample (std::visit makes a missing case a compile error).
// Directions are in world space; `Frame` holds the shading frame.
#pragma once
#include <string>
#include <variant>

#include "util/sampling.h"

namespace pl {

struct Frame {
  Vec3 t, b, n;
  static Frame from_normal(Vec3 n) {
    Frame f;
    f.n = n;
    make_basis(n, f.t, f.b);
    return f;
  }
  Vec3 to_local(Vec3 v) const { return {dot(v, t), dot(v, b), dot(v, n)}; }
  Vec3 to_world(Vec3 v) const { return t * v.x + b * v.y + n * v.z; }
};

struct BsdfSample {
  Vec3 wi;
  Vec3 weight;  // f * |cos| / pdf
  float pdf = 0.0f;
};

// Lambertian reflection.
struct DiffuseBsdf {
  Vec3 albedo{0.8f};
  Vec3 eval(const Frame& f, Vec3 /*wo*/, Vec3 wi, float& pdf) const {
    const float c = dot(f.n, wi);
    if (c <= 0.0f) {
      pdf = 0.0f;
      return Vec3(0.0f);
    }
    pdf = c * kInvPi;
    return albedo * (c * kInvPi);  // includes the cosine
  }
  bool sample(const Frame& f, Vec3 /*wo*/, Vec2 u, BsdfSample& s) const {
    const Vec3 l = sample_cosine_hemisphere(u);
    if (l.z <= 0.0f) return false;
    s.wi = f.to_world(l);
    s.pdf = l.z * kInvPi;
    s.weight = albedo;
    return true;
  }
};

using Bsdf = std::variant<DiffuseBsdf>;

// f(wo, wi) * |cos(wi)| and the pdf of sampling wi.
inline Vec3 bsdf_eval(const Bsdf& b, const Frame& f, Vec3 wo, Vec3 wi, float& pdf) {
  return std::visit([&](const auto& x) { return x.eval(f, wo, wi, pdf); }, b);
}
inline bool bsdf_sample(const Bsdf& b, const Frame& f, Vec3 wo, Vec2 u, BsdfSample& s) {
  return std::visit([&](const auto& x) { return x.sample(f, wo, u, s); }, b);
}

struct Material {
  std::string name;
  Bsdf bsdf = DiffuseBsdf{};
  Vec3 emission{0.0f};  // radiance, emitted from both sides like Cycles' mesh emission
};

}  // namespace pl
