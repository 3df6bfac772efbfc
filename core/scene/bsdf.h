// The closed set of BSDFs and the one place that dispatches over all of them.
// To add a BSDF: write a struct with eval/sample in local coordinates below, add it to the
// `Bsdf` variant (std::visit then makes every missing case a compile error).
// Local frame: +Z is the closure's shading normal as the mesh orients it. Reflection-only
// BSDFs are two-sided (they mirror to wo's side); dielectrics use the side to tell inside from
// outside. eval returns f * |cos(wi)|.
#pragma once
#include <string>
#include <type_traits>
#include <variant>

#include "scene/ashikhmin_shirley.h"
#include "scene/microfacet_beckmann.h"
#include "scene/microfacet_energy.h"
#include "scene/thin_film.h"

namespace pl {

enum BsdfFlags : uint8_t {
  kReflect = 1,
  kTransmit = 2,
  kDelta = 4,
  kDiffuseLobe = 8,
  kGlossyLobe = 16,
  kTransparentLobe = 32,  // straight pass-through: not a bounce
};

struct BsdfSample {
  Vec3 wi;
  Vec3 weight;     // f * |cos| / pdf (for delta lobes: the lobe's weight / its probability)
  float pdf = 0.0f;
  uint8_t flags = 0;
  float eta = 1.0f;  // relative IOR crossed (transmission), for Russian roulette and media
};

constexpr float kDeltaAlpha = 1e-4f;  // below this roughness a lobe is a perfect mirror/refractor

inline float abs_cos(Vec3 v) { return std::fabs(v.z); }
inline bool same_side(Vec3 a, Vec3 b) { return a.z * b.z > 0.0f; }

// Cycles' bump shadowing term for a diffuse lobe whose normal (+Z) was bent away from the
// smooth normal `ns` (local coordinates) by a normal map or bump: light from behind the smooth
// surface is rejected, and grazing light is softened by a GGX masking term whose roughness
// grows with the bend (Conty Estevez et al., "A Microfacet-Based Shadowing Function to Solve
// the Bump Terminator Problem"), so bent normals do not light up where the surface cannot be lit.
inline float bump_shadowing(Vec3 ns, Vec3 wi) {
  const float cos_ns_i = dot(ns, wi), cos_ns_n = ns.z, cos_n_i = wi.z;
  if (cos_ns_i * cos_ns_n * cos_n_i < 0.0f) return 0.0f;
  const float cos_i = std::fabs(cos_ns_i), cos_d = std::fabs(cos_ns_n);
  if (cos_d >= 1.0f || cos_i >= 1.0f) return 1.0f;
  if (cos_i < 1e-6f) return 0.0f;
  const float tan2_d = 1.0f / (cos_d * cos_d) - 1.0f;
  const float alpha2 = clampf(0.125f * tan2_d, 0.0f, 1.0f);
  const float tan2_i = (1.0f - cos_i * cos_i) / (cos_i * cos_i);
  return 2.0f / (1.0f + std::sqrt(1.0f + alpha2 * tan2_i));
}

// A microfacet lobe's D(m), G1(wo) and G(wo, wi) with D and Lambda(wo) computed once (Ggx or
// Beckmann); pdf_visible gives the distribution's pdf_visible from them.
struct MicrofacetTerms {
  float d, g1o, g;
  float pdf_visible(Vec3 wo, Vec3 m) const { return visible_normal_pdf(g1o, d, wo, m); }
};
template <class Dist>
[[gnu::always_inline]] inline MicrofacetTerms microfacet_terms(const Dist& g, Vec3 wo, Vec3 wi, Vec3 m) {
  const float lo = g.lambda(wo);
  return {g.D(m), 1.0f / (1.0f + lo), 1.0f / (1.0f + lo + g.lambda(wi))};
}

struct DiffuseBsdf {
  Vec3 ns{0.0f, 0.0f, 1.0f};  // the smooth (unbent) normal in the local frame
  bool bent = false;          // the lobe's normal differs from ns: apply bump_shadowing
  // The lobe's side: Cycles flips a backfacing hit's normals, then lights the lobe from its
  // own side whatever the view (a bevelled, bumped or smooth-shaded normal may face away from
  // the viewer at a silhouette). back: the hit is backfacing (Scene::shade sets it).
  bool back = false;
  bool lit_side(Vec3, Vec3 wi) const { return (wi.z < 0.0f) == back; }
  [[gnu::always_inline]] Vec3 eval(Vec3 wo, Vec3 wi, float& pdf) const {
    if (!lit_side(wo, wi)) {
      pdf = 0.0f;
      return Vec3(0.0f);
    }
    pdf = abs_cos(wi) * kInvPi;
    return Vec3(bent ? pdf * bump_shadowing(ns, wi) : pdf);
  }
  bool sample(Vec3, Vec2 u, float, BsdfSample& s) const {  // (the side: back, not the view)
    Vec3 l = sample_cosine_hemisphere(u);
    if (l.z <= 0.0f) return false;
    if (back) l.z = -l.z;
    s.wi = l;
    s.pdf = std::fabs(l.z) * kInvPi;
    s.weight = Vec3(bent ? bump_shadowing(ns, l) : 1.0f);
    s.flags = kReflect | kDiffuseLobe;
    return true;
  }
};

// Diffuse transmission (Blender's Translucent BSDF, Cycles' bsdf_translucent): Lambertian on
// the side opposite wo, cosine-sampled there.
struct TranslucentBsdf {
  Vec3 eval(Vec3 wo, Vec3 wi, float& pdf) const {
    if (same_side(wo, wi) || wo.z == 0.0f) {
      pdf = 0.0f;
      return Vec3(0.0f);
    }
    pdf = abs_cos(wi) * kInvPi;
    return Vec3(pdf);
  }
  bool sample(Vec3 wo, Vec2 u, float, BsdfSample& s) const {
    Vec3 l = sample_cosine_hemisphere(u);
    if (l.z <= 0.0f || wo.z == 0.0f) return false;
    if (wo.z > 0.0f) l.z = -l.z;
    s.wi = l;
    s.pdf = std::fabs(l.z) * kInvPi;
    s.weight = Vec3(1.0f);
    s.flags = kTransmit | kDiffuseLobe;
    s.eta = 1.0f;
    return true;
  }
};

// How a GGX reflection lobe's Fresnel term follows the angle to its microfacet.
enum class ConductorFresnel : uint8_t {
  Constant,    // f0 (Blender's Glossy BSDF)
  Schlick,     // Schlick's curve from f0
  F82Tint,     // Cycles' F82-Tint: Schlick from f0 less b cos (1 - cos)^6 (Principled metal)
  Conductor,   // a physical conductor's exact Fresnel for complex IOR n + ik (Metallic BSDF):
               // f0 holds n and b holds k per channel
  Dielectric,  // Cycles' generalized Schlick in its physical mode: mix(f0, 1, s), s the real
               // Fresnel of eta remapped from [F0(eta), 1] to [0, 1] (Principled specular)
};

// Microfacet reflection (GGX, Beckmann or Ashikhmin-Shirley), tinted by one of the Fresnel
// models above.
struct ConductorBsdf {
  float alpha = 0.0f;     // along the frame's tangent (t)
  float alpha_y = -1.0f;  // along its bitangent (b); negative: isotropic (alpha)
  Vec3 f0{1.0f};
  ConductorFresnel mode = ConductorFresnel::Constant;
  bool exact = true;  // Dielectric: the real Fresnel equations (false: Schlick's approximation)
  Microfacet dist = Microfacet::Ggx;  // in the padding: the variant stays as large
  // Its weight carries Cycles' multiscatter energy compensation (1 / E more than Cycles'
  // closure weight, which the render passes' colours read). In the padding too.
  bool compensated = false;
  float eta = 1.5f;   // Dielectric
  Vec3 b{0.0f};       // F82Tint
  // Dielectric: a thin film on top (Principled's Thin Film), thickness in nm (0: none).
  float film_thickness = 0.0f, film_ior = 1.33f;
  Ggx ggx() const { return Ggx{alpha, alpha_y < 0.0f ? alpha : alpha_y}; }
  Beckmann beckmann() const { return Beckmann{alpha, alpha_y < 0.0f ? alpha : alpha_y}; }
  AshikhminShirley ashikhmin_shirley() const { return AshikhminShirley::from_alpha(alpha, alpha_y < 0.0f ? alpha : alpha_y); }
  // A perfect mirror/refractor below kDeltaAlpha (anisotropic: the two alphas' geometric mean).
  bool is_delta() const { return alpha_y < 0.0f ? alpha < kDeltaAlpha : alpha * alpha_y < kDeltaAlpha * kDeltaAlpha; }
  Vec3 fresnel(float c) const {
    switch (mode) {
      case ConductorFresnel::Constant: return f0;
      case ConductorFresnel::Schlick: return fresnel_schlick(f0, c);
      case ConductorFresnel::F82Tint: return fresnel_f82(c, f0, b);
      case ConductorFresnel::Conductor: return fresnel_conductor(c, f0, b);
      case ConductorFresnel::Dielectric: {
        if (film_thickness > kThinFilmCutoff) return thin_film_dielectric(c, film_ior, eta, film_thickness, f0);
        const float F = exact ? fresnel_dielectric(c, eta) : fresnel_schlick_dielectric(c, eta);
        const float F0 = f0_from_ior(eta);
        const float s = F0 < 1.0f ? clampf((F - F0) / (1.0f - F0), 0.0f, 1.0f) : 1.0f;
        return f0 + (Vec3(1.0f) - f0) * s;
      }
    }
    return f0;
  }
  Vec3 eval(Vec3 wo, Vec3 wi, float& pdf) const {
    pdf = 0.0f;
    if (is_delta() || !same_side(wo, wi)) return Vec3(0.0f);
    if (wo.z < 0.0f) {
      wo.z = -wo.z;
      wi.z = -wi.z;
    }
    if (dist == Microfacet::Ggx) return eval_up(ggx(), wo, wi, pdf);
    if (dist == Microfacet::Beckmann) return eval_up(beckmann(), wo, wi, pdf);
    const float f = ashikhmin_shirley().eval(wo, wi, pdf);
    return pdf > 0.0f ? fresnel(dot(wo, normalize(wo + wi))) * f : Vec3(0.0f);
  }
  bool sample(Vec3 wo, Vec2 u, float, BsdfSample& s) const {
    const bool flip = wo.z < 0.0f;
    if (flip) wo.z = -wo.z;
    if (is_delta()) {
      s.wi = {-wo.x, -wo.y, wo.z};
      s.weight = fresnel(wo.z);
      s.pdf = 1.0f;
      s.flags = kReflect | kDelta | kGlossyLobe;
    } else {
      const bool ok = dist == Microfacet::Ggx        ? sample_up(ggx(), wo, u, s)
                      : dist == Microfacet::Beckmann ? sample_up(beckmann(), wo, u, s)
                                                     : sample_ashikhmin_shirley(wo, u, s);
      if (!ok) return false;
      s.flags = kReflect | kGlossyLobe;
    }
    if (flip) s.wi.z = -s.wi.z;
    return true;
  }

  // A microfacet distribution's lobe (Ggx or Beckmann), wo and wi mirrored above the surface.
  template <class Dist>
  Vec3 eval_up(const Dist& g, Vec3 wo, Vec3 wi, float& pdf) const {
    const Vec3 m = normalize(wo + wi);
    const float wom = dot(wo, m);
    if (!(wom > 0.0f)) return Vec3(0.0f);
    const MicrofacetTerms t = microfacet_terms(g, wo, wi, m);
    pdf = t.pdf_visible(wo, m) / (4.0f * wom);
    return fresnel(wom) * (t.d * t.g / (4.0f * wo.z));
  }
  template <class Dist>
  bool sample_up(const Dist& g, Vec3 wo, Vec2 u, BsdfSample& s) const {
    const Vec3 m = g.sample_visible(wo, u);
    s.wi = reflect(wo, m);
    const float wom = dot(wo, m);
    if (s.wi.z <= 0.0f || !(wom > 0.0f)) return false;
    s.pdf = g.pdf_visible(wo, m) / (4.0f * wom);
    s.weight = fresnel(wom) * (g.G(wo, s.wi) / g.G1(wo));
    return true;
  }
  // Cycles flips a half vector facing away from wo, which does not give a unit direction;
  // such samples fail here instead, so that the pdf (of half vectors facing wo) holds.
  bool sample_ashikhmin_shirley(Vec3 wo, Vec2 u, BsdfSample& s) const {
    const AshikhminShirley a = ashikhmin_shirley();
    const Vec3 h = a.sample_half(u);
    const float woh = dot(wo, h);
    if (!(woh > 0.0f)) return false;
    s.wi = reflect(wo, h);
    if (s.wi.z <= 0.0f) return false;
    const float f = a.eval(wo, s.wi, s.pdf);
    if (!(s.pdf > 0.0f)) return false;
    s.weight = fresnel(woh) * (f / s.pdf);
    return true;
  }
};

// Dielectric interface (Walter et al. 2007 for rough): glass (both lobes), refraction only, or
// a reflection-only coating layer. eta = n_inside / n_outside, the normal pointing outside.
struct DielectricBsdf {
  float alpha = 0.0f;     // along the frame's tangent (t)
  float alpha_y = -1.0f;  // along its bitangent (b); negative: isotropic (alpha)
  float eta = 1.5f;
  bool reflection = true, transmission = true;
  bool fresnel_on_transmission = true;  // false: Blender's Refraction BSDF (all light refracts)
  bool schlick = false;
  Vec3 transmission_tint{1.0f};  // tints refracted light only (Principled: sqrt(base) per crossing)
  // Principled's Specular Tint on its glass: Cycles' generalized Schlick in its physical mode,
  // reflection mix(F0 tint, 1, s) with s the real Fresnel remapped from [F0, 1], transmission
  // the rest (1 white: the plain Fresnel equations).
  Vec3 f0_tint{1.0f};
  // A thin film on the interface (Principled's Thin Film), thickness in nm (0: none); its IOR
  // is relative to the outside, as eta.
  float film_thickness = 0.0f, film_ior = 1.33f;
  Microfacet dist = Microfacet::Ggx;  // Ggx or Beckmann
  // Its weight carries Cycles' multiscatter energy compensation (1 / E of the glass tables more
  // than Cycles' closure weight, which the render passes' colours read). In the padding.
  bool compensated = false;
  Ggx ggx() const { return Ggx{alpha, alpha_y < 0.0f ? alpha : alpha_y}; }
  Beckmann beckmann() const { return Beckmann{alpha, alpha_y < 0.0f ? alpha : alpha_y}; }
  // A perfect mirror/refractor below kDeltaAlpha (anisotropic: the two alphas' geometric mean).
  bool is_delta() const { return alpha_y < 0.0f ? alpha < kDeltaAlpha : alpha * alpha_y < kDeltaAlpha * kDeltaAlpha; }

  // A reflection-only layer (a coat) has no inside: seen from behind it behaves as from the front.
  bool one_sided_coat() const { return !transmission; }

  float fresnel(float cos_i) const {
    return schlick ? fresnel_schlick_dielectric(cos_i, eta) : fresnel_dielectric(cos_i, eta);
  }
  // The lobes at cos_i = dot(wo, m) (its sign: the side), with the film if there is one.
  void lobes_at(float cos_i, Vec3& cr, Vec3& ct, float& pr, float& pt) const {
    if (!(film_thickness > kThinFilmCutoff)) return lobes(fresnel(cos_i), cr, ct, pr, pt);
    // Seen from inside, Cycles puts everything relative to the inside medium.
    const bool inside = cos_i < 0.0f;
    const float base = inside ? 1.0f / eta : eta, film = inside ? film_ior / eta : film_ior;
    cr = thin_film_dielectric(std::fabs(cos_i), film, base, film_thickness, vmin(f0_tint * f0_from_ior(base), Vec3(1.0f)));
    ct = fresnel_on_transmission ? Vec3(1.0f) - cr : Vec3(1.0f);
    pr = reflection ? average(cr) : 0.0f;
    pt = transmission ? average(ct) : 0.0f;
  }
  // Given the real Fresnel term F: the colours of reflection (cr) and transmission (ct, before
  // transmission_tint) and the probabilities of choosing them.
  void lobes(float F, Vec3& cr, Vec3& ct, float& pr, float& pt) const {
    cr = Vec3(F);
    if (!(f0_tint.x == 1.0f && f0_tint.y == 1.0f && f0_tint.z == 1.0f)) {
      const float F0 = f0_from_ior(eta);
      const float t = F0 < 1.0f ? clampf((F - F0) / (1.0f - F0), 0.0f, 1.0f) : 1.0f;
      const Vec3 f0 = vmin(f0_tint * F0, Vec3(1.0f));
      cr = f0 + (Vec3(1.0f) - f0) * t;
    }
    ct = fresnel_on_transmission ? Vec3(1.0f) - cr : Vec3(1.0f);
    pr = reflection ? average(cr) : 0.0f;
    pt = transmission ? average(ct) : 0.0f;
  }

  Vec3 eval(Vec3 wo, Vec3 wi, float& pdf) const {
    return dist == Microfacet::Beckmann ? eval_with(beckmann(), wo, wi, pdf) : eval_with(ggx(), wo, wi, pdf);
  }
  bool sample(Vec3 wo, Vec2 u, float uc, BsdfSample& s) const {
    return dist == Microfacet::Beckmann ? sample_with(beckmann(), wo, u, uc, s) : sample_with(ggx(), wo, u, uc, s);
  }

  // The lobes for one microfacet distribution (Ggx or Beckmann).
  template <class Dist>
  Vec3 eval_with(const Dist& g, Vec3 wo, Vec3 wi, float& pdf) const {
    pdf = 0.0f;
    if (is_delta() || wo.z == 0.0f || wi.z == 0.0f) return Vec3(0.0f);
    if (one_sided_coat() && wo.z < 0.0f) {
      wo.z = -wo.z;
      wi.z = -wi.z;
    }
    const bool refl = same_side(wo, wi);
    if ((refl && !reflection) || (!refl && !transmission)) return Vec3(0.0f);
    const float etap = refl ? 1.0f : (wo.z > 0.0f ? eta : 1.0f / eta);
    Vec3 m = wi * etap + wo;
    if (!(length_sq(m) > 0.0f)) return Vec3(0.0f);
    m = normalize(m);
    if (m.z < 0.0f) m = -m;
    if (dot(m, wi) * wi.z < 0.0f || dot(m, wo) * wo.z < 0.0f) return Vec3(0.0f);  // backfacing microfacet
    Vec3 cr, ct;
    float pr, pt;
    lobes_at(dot(wo, m), cr, ct, pr, pt);
    if (!(pr + pt > 0.0f)) return Vec3(0.0f);
    // Visible-normal density seen from wo mirrored to the outside; m (facing +Z) is then the
    // facet facing it, whichever side wo is on.
    const Vec3 wo_up = wo.z > 0.0f ? wo : -wo;
    const MicrofacetTerms t = microfacet_terms(g, wo, wi, m);  // (Lambda(wo) is Lambda(wo_up))
    const float pdf_m = t.pdf_visible(wo_up, m);
    if (refl) {
      pdf = pdf_m / (4.0f * std::fabs(dot(wo, m))) * pr / (pr + pt);
      return cr * (t.d * t.g / (4.0f * std::fabs(wo.z)));
    }
    const float denom = (dot(wi, m) + dot(wo, m) / etap) * (dot(wi, m) + dot(wo, m) / etap);
    if (!(denom > 0.0f)) return Vec3(0.0f);
    const float dwm_dwi = std::fabs(dot(wi, m)) / denom;
    pdf = pdf_m * dwm_dwi * pt / (pr + pt);
    const float ft = t.d * t.g * std::fabs(dot(wi, m) * dot(wo, m) / (wo.z * denom));
    // No 1/etap^2 (pbrt's radiance compression across the interface), as Cycles'
    // bsdf_microfacet_eval: a path's throughput through refraction is the lobe's alone
    // (docs/materials.md "Refraction: no 1/eta^2, as Cycles"). Light paths, which carry the
    // adjoint, put the factor back (integrator_caustics.cpp, integrator_guided.cpp).
    return transmission_tint * ct * ft;
  }

  template <class Dist>
  bool sample_with(const Dist& g, Vec3 wo, Vec2 u, float uc, BsdfSample& s) const {
    if (wo.z == 0.0f) return false;
    if (one_sided_coat() && wo.z < 0.0f) {  // mirror to the front and back
      wo.z = -wo.z;
      const bool ok = sample_with(g, wo, u, uc, s);
      s.wi.z = -s.wi.z;
      return ok;
    }
    if (is_delta()) {
      Vec3 cr, ct;
      float pr, pt;
      lobes_at(wo.z, cr, ct, pr, pt);
      if (!(pr + pt > 0.0f)) return false;
      if (uc * (pr + pt) < pr) {
        s.wi = {-wo.x, -wo.y, wo.z};
        s.weight = cr * ((pr + pt) / pr);
        s.pdf = pr / (pr + pt);
        s.flags = kReflect | kDelta | kGlossyLobe;
        s.eta = 1.0f;
        return true;
      }
      float etap;
      if (!refract(wo, {0.0f, 0.0f, 1.0f}, eta, s.wi, etap) || s.wi.z == 0.0f) return false;
      s.pdf = pt / (pr + pt);
      s.weight = transmission_tint * ct * ((pr + pt) / pt);  // (no 1/etap^2, as in eval_with)
      s.flags = kTransmit | kDelta | kGlossyLobe;
      s.eta = etap;
      return true;
    }
    const Vec3 wo_up = wo.z > 0.0f ? wo : -wo;
    // The microfacet normal facing outside (+Z side): its sign tells Fresnel and refract
    // whether wo is inside or outside.
    const Vec3 m = g.sample_visible(wo_up, u);
    Vec3 cr, ct;
    float pr, pt;
    lobes_at(dot(wo, m), cr, ct, pr, pt);
    if (!(pr + pt > 0.0f)) return false;
    if (uc * (pr + pt) < pr) {
      s.wi = reflect(wo, m);
      if (!same_side(wo, s.wi)) return false;
      s.flags = kReflect | kGlossyLobe;
      s.eta = 1.0f;
    } else {
      float etap;
      if (!refract(wo, m, eta, s.wi, etap) || same_side(wo, s.wi) || s.wi.z == 0.0f) return false;
      s.flags = kTransmit | kGlossyLobe;
      s.eta = etap;
    }
    const Vec3 f = eval_with(g, wo, s.wi, s.pdf);
    if (!(s.pdf > 0.0f) || is_black(f)) return false;
    s.weight = f / s.pdf;
    return true;
  }
};

// Straight pass-through (Transparent BSDF, alpha).
struct TransparentBsdf {
  Vec3 eval(Vec3, Vec3, float& pdf) const {
    pdf = 0.0f;
    return Vec3(0.0f);
  }
  bool sample(Vec3 wo, Vec2, float, BsdfSample& s) const {
    s.wi = -wo;
    s.weight = Vec3(1.0f);
    s.pdf = 1.0f;
    s.flags = kTransmit | kDelta | kTransparentLobe;
    s.eta = 1.0f;
    return true;
  }
};

// Cycles' Ray Portal BSDF: no scattering of its own. A path that picks it goes on from p along d
// (world space) as through a transparent surface: the integrator moves the ray (trace_path.inl),
// and shadow rays that meet it are blocked (Cycles disables transparent shadows there). 24 bytes.
struct PortalBsdf {
  Vec3 p{0.0f};  // where the path goes on
  Vec3 d{0.0f};  // its direction (unit)
  Vec3 eval(Vec3, Vec3, float& pdf) const {
    pdf = 0.0f;
    return Vec3(0.0f);
  }
  bool sample(Vec3, Vec2, float, BsdfSample&) const { return false; }
};

}  // namespace pl
#include "scene/hair_bsdf.h"  // needs BsdfSample and the lobe flags above
#include "scene/hair_huang.h"  // (the same, and hair_bsdf.h's longitudinal term)
namespace pl {

// A BSSRDF closure (Cycles' Bssrdf): no BSDF of its own. A path that picks it enters the mesh
// and random-walks inside it (render/subsurface.h); it is "delta" for the closure list, so
// that mixtures never evaluate it. 36 bytes: the variant stays as large as before.
struct SubsurfaceBsdf {
  Vec3 radius{0.0f};  // per channel mean free path (Cycles' bssrdf->radius after setup); 0: unused
  Vec3 albedo{0.0f};  // the multiple-scattering albedo the walk reproduces
  float g = 0.0f;     // Henyey-Greenstein anisotropy, in [0, 0.9]
  float ior = 1.4f;   // the entry refraction's IOR, in [1.01, 3.8]
  float alpha = 1.0f; // the entry refraction's GGX roughness; -1: Random Walk (Skin), whose
                      // entry is half diffuse and half refraction at alpha 1; -2: Christensen-
                      // Burley (Cycles' disk sampling; radius is its d per channel)
  Vec3 eval(Vec3, Vec3, float& pdf) const {
    pdf = 0.0f;
    return Vec3(0.0f);
  }
  bool sample(Vec3, Vec2, float, BsdfSample&) const { return false; }
};

}  // namespace pl

#include "scene/bsdf_oren_nayar.h"  // OrenNayarBsdf (rough diffuse)
#include "scene/bsdf_sheen.h"       // SheenBsdf, VelvetBsdf (Sheen BSDF, Principled sheen)
#include "scene/bsdf_toon.h"        // ToonBsdf (Toon BSDF)

namespace pl {

using Bsdf = std::variant<DiffuseBsdf, ConductorBsdf, DielectricBsdf, TransparentBsdf, TranslucentBsdf, HairChiangBsdf,
                          SubsurfaceBsdf, OrenNayarBsdf, SheenBsdf, VelvetBsdf, ToonBsdf, HairBsdf, HairHuangBsdf,
                          PortalBsdf>;

// Cycles' Reflective / Refractive Caustics switched off (RenderSettings): at a point reached by a
// diffuse bounce (Cycles' PATH_RAY_DIFFUSE), its svm_node_closure_bsdf skips glossy reflection
// closures (no reflective caustics) and refraction closures (no refractive ones).
enum CausticsOff : uint8_t { kCausticsNoReflective = 1, kCausticsNoRefractive = 2 };

// Whether closure b survives the caustics toggles `off` (kCausticsNo* bits) there, trimmed to
// the lobes it keeps, as Cycles sets them up: glossy reflection (Glossy, Anisotropic, Metallic,
// Principled's metal, specular and coat: ConductorBsdf; the Toon's glossy) goes without
// reflective caustics; the Refraction BSDF without refractive ones; glass (Glass, Principled's
// transmission) loses the lobe of each toggle that is off (Cycles' zero reflection_tint or
// transmission_tint) and goes when both are. Hair, sheen, diffuse, translucent, subsurface,
// transparency and portals stay.
inline bool caustics_keep(ConductorBsdf&, uint8_t off) { return !(off & kCausticsNoReflective); }
inline bool caustics_keep(DielectricBsdf& d, uint8_t off) {
  if (off & kCausticsNoReflective) d.reflection = false;
  if (off & kCausticsNoRefractive) d.transmission = false;
  return d.reflection || d.transmission;
}
inline bool caustics_keep(ToonBsdf& t, uint8_t off) { return !(t.glossy && (off & kCausticsNoReflective)); }
template <class B>
inline bool caustics_keep(B&, uint8_t) {
  return true;
}
inline bool caustics_keep(Bsdf& b, uint8_t off) {
  return std::visit([off](auto& x) { return caustics_keep(x, off); }, b);
}
// The closure types caustics_keep may drop or trim (the rest never need the test).
template <class B>
constexpr bool kCausticsFiltered = std::is_same_v<B, ConductorBsdf> || std::is_same_v<B, DielectricBsdf> ||
                                   std::is_same_v<B, ToonBsdf> || std::is_same_v<B, Bsdf>;

// Cycles' bsdf_blur (Filter Glossy): the closure's roughness raised to at least `r` (an alpha),
// for the microfacet closures (GGX, Beckmann, Ashikhmin-Shirley; reflection, refraction and
// glass) and the Principled Hair models (Chiang: its longitudinal variances and azimuthal scale,
// compared with r as Cycles compares them; Huang: its roughness). Others stay. A multiscatter
// closure keeps the energy compensation of its set-up roughness in its weight, as Cycles ("TODO:
// Recompute energy preservation after blur?").
inline void bsdf_blur(Bsdf& b, float r) {
  if (auto* c = std::get_if<ConductorBsdf>(&b)) {
    c->alpha = std::max(r, c->alpha);
    if (c->alpha_y >= 0.0f) c->alpha_y = std::max(r, c->alpha_y);
  } else if (auto* d = std::get_if<DielectricBsdf>(&b)) {
    d->alpha = std::max(r, d->alpha);
    if (d->alpha_y >= 0.0f) d->alpha_y = std::max(r, d->alpha_y);
  } else if (auto* h = std::get_if<HairChiangBsdf>(&b)) {
    h->v = std::max(r, h->v);
    h->s = std::max(r, h->s);
    h->v_r = std::max(r, h->v_r);
  } else if (auto* u = std::get_if<HairHuangBsdf>(&b)) {
    u->roughness = std::max(r, u->roughness);
  }
}
// Filter Glossy's roughness at a vertex (Cycles' surface_shader_prepare_closures): with
// filter_glossy (1 / the setting, 0: off) times the path's smallest BSDF pdf so far below 1,
// sqrt(1 - that) / 2; else 0 (no blur).
inline float filter_glossy_roughness(float filter_glossy, float min_pdf) {
  const float blur_pdf = filter_glossy * min_pdf;
  return filter_glossy > 0.0f && blur_pdf < 1.0f ? std::sqrt(1.0f - blur_pdf) * 0.5f : 0.0f;
}

// The Principled BSDF's GGX lobes first, outside the visit: its dispatch over all the kinds
// would otherwise cost the default material a little on every evaluation.
inline Vec3 bsdf_eval(const Bsdf& b, Vec3 wo, Vec3 wi, float& pdf) {
  if (const auto* c = std::get_if<ConductorBsdf>(&b)) return c->eval(wo, wi, pdf);
  return std::visit([&](const auto& x) { return x.eval(wo, wi, pdf); }, b);
}
inline bool bsdf_sample(const Bsdf& b, Vec3 wo, Vec2 u, float uc, BsdfSample& s) {
  if (const auto* c = std::get_if<ConductorBsdf>(&b)) return c->sample(wo, u, uc, s);
  return std::visit([&](const auto& x) { return x.sample(wo, u, uc, s); }, b);
}
inline bool bsdf_is_delta(const Bsdf& b) {
  if (std::holds_alternative<TransparentBsdf>(b) || std::holds_alternative<SubsurfaceBsdf>(b) ||
      std::holds_alternative<PortalBsdf>(b))
    return true;
  if (const auto* c = std::get_if<ConductorBsdf>(&b)) return c->is_delta();
  if (const auto* d = std::get_if<DielectricBsdf>(&b)) return d->is_delta();
  return false;
}
// A rough guess of how much a closure reflects, to choose among closures when sampling.
inline float bsdf_albedo_hint(const Bsdf& b) {
  if (const auto* c = std::get_if<ConductorBsdf>(&b)) return std::max(0.05f, luminance(c->f0));
  return 1.0f;
}

// Whether Cycles lifts a closure's shading normal so that the mirror reflection of the view
// stays above the surface (ensure_valid_specular_reflection): its glossy closures, not diffuse.
inline bool bsdf_wants_valid_reflection(const Bsdf& b) {
  return std::holds_alternative<ConductorBsdf>(b) || std::holds_alternative<DielectricBsdf>(b);
}

// Cycles' ensure_valid_specular_reflection: if the view direction wo mirrored about the shading
// normal n would go below the geometric surface (normal ng), n is rotated towards ng just
// enough that the reflection stays slightly above it. Works on either side (wo decides).
inline Vec3 valid_specular_normal(Vec3 ng, Vec3 wo, Vec3 n) {
  const float side = dot(ng, wo) < 0.0f ? -1.0f : 1.0f;
  const Vec3 Ng = ng * side, N = n * side;
  if (N.x == Ng.x && N.y == Ng.y && N.z == Ng.z) return n;
  const Vec3 R = N * (2.0f * dot(N, wo)) - wo;
  const float iz = dot(wo, Ng);
  const float threshold = std::min(0.9f * iz, 0.01f);  // reflections at least as shallow as wo
  if (!(dot(Ng, R) < threshold)) return n;
  // In the frame (X, Ng) with N in the X-Z plane, solve 2 dot(N', wo) N'.z - wo.z = threshold.
  Vec3 X = N - Ng * dot(N, Ng);
  const float lx = length_sq(X);
  X = lx > 1e-20f ? X / std::sqrt(lx) : N;
  const float ix = dot(wo, X);
  const float a = ix * ix + iz * iz;
  if (!(a > 0.0f)) return n;
  const float b = 2.0f * (a + iz * threshold);
  const float c = (threshold + iz) * (threshold + iz);
  const float disc = std::sqrt(std::max(0.0f, b * b - 4.0f * a * c));
  const float nz2 = ix < 0.0f ? 0.25f * (b + disc) / a : 0.25f * (b - disc) / a;
  const float nx = std::sqrt(std::max(0.0f, 1.0f - nz2)), nz = std::sqrt(std::max(0.0f, nz2));
  const Vec3 out = (X * nx + Ng * nz) * side;
  return is_finite(out) && length_sq(out) > 0.5f ? out : n;
}

struct Frame {
  Vec3 t, b, n;
  static Frame from_normal(Vec3 n) {
    Frame f;
    f.n = n;
    make_basis(n, f.t, f.b);
    return f;
  }
  // An anisotropic lobe's frame (Cycles' make_orthonormals_tangent): b = n x t normalized, t
  // then the tangent made perpendicular to n; a tangent along n (or none) gives any basis.
  static Frame from_normal_tangent(Vec3 n, Vec3 tangent) {
    const Vec3 b = cross(n, tangent);
    const float l2 = length_sq(b);
    if (!(l2 > 1e-20f) || !std::isfinite(l2)) return from_normal(n);
    Frame f;
    f.n = n;
    f.b = b / std::sqrt(l2);
    f.t = cross(f.b, n);
    return f;
  }
  [[gnu::always_inline]] Vec3 to_local(Vec3 v) const { return {dot(v, t), dot(v, b), dot(v, n)}; }
  Vec3 to_world(Vec3 v) const { return t * v.x + b * v.y + n * v.z; }
};

}  // namespace pl
