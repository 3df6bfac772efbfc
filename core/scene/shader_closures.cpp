// The closure ops of shader programs (BSDFs, BSSRDFs, emission, holdout) as Cycles'
// svm_node_closure_* set them up from their inputs, for eval_shader.
#include "scene/shader_closures.h"

#include "scene/bssrdf.h"
#include "scene/shader_math.h"

namespace pl::detail {

namespace {
using namespace shader_math;

// Closure inputs: an omitted register means the input's default.
inline Vec3 col_of(const Float4* r, int16_t i) { return i == kNoReg ? Vec3(1.0f) : r[i].xyz(); }
inline float val_of(const Float4* r, int16_t i, float def) { return i == kNoReg ? def : r[i].x; }

// Closure frames as Cycles sets them up: glossy lobes get a normal whose mirror reflection of
// the view stays above the surface; diffuse lobes with a bent normal get the bump shadowing.
Frame glossy_frame_at(const Float4* r, const ShadingContext& ctx, int16_t normal_reg) {
  return Frame::from_normal(valid_specular_normal(ctx.ng, ctx.wo, normal_or(r, normal_reg, ctx)));
}

// `known`: a frame already built on some normal (nullptr: none), reused where it is on n.
inline DiffuseBsdf diffuse_lobe_at(const Float4* r, const ShadingContext& ctx, const ShaderProgram& prog,
                                   int16_t normal_reg, Frame& f, const Frame* known = nullptr) {
  const Vec3 n = normal_or(r, normal_reg, ctx);
  if (known && known->n.x == n.x && known->n.y == n.y && known->n.z == n.z) f = *known;
  else f = Frame::from_normal(n);
  DiffuseBsdf d;
  d.back = ctx.backfacing;
  // A program that set the shading normal (bump from displacement) lights its lobes from
  // their own side too, as Cycles' sd->N: "bent" against that normal, so no shadowing term
  // unless the lobe's own normal differs from it.
  if (n.x != ctx.ns.x || n.y != ctx.ns.y || n.z != ctx.ns.z || prog.sets_normal) {
    d.bent = true;
    d.ns = f.to_local(ctx.ns);
  }
  return d;
}

// Multiscatter GGX glass: the view's side decides the relative IOR (Cycles' ior or 1 / ior).
inline Vec3 glass_compensation_at(const ShadingContext& ctx, const DielectricBsdf& b, const Frame& f, Vec3 fss) {
  const float c = dot(f.n, ctx.wo);
  return ggx_glass_compensation(std::sqrt(b.alpha), std::fabs(c), c >= 0.0f ? b.eta : 1.0f / b.eta, fss).scale;
}

// An anisotropic lobe's frame: its (valid-reflection) normal n and the tangent register
// turned `rotation` turns about `axis` (Cycles' rotate_around_axis by rotation * 2 pi).
inline Frame aniso_frame_at(const Float4* r, Vec3 n, int16_t tangent_reg, float rotation, Vec3 axis) {
  if (tangent_reg == kNoReg) return Frame::from_normal(n);
  Vec3 t = r[tangent_reg].xyz();
  if (rotation != 0.0f && std::isfinite(rotation)) t = rotate_about_axis(t, axis, rotation * 2.0f * kPi);
  return Frame::from_normal_tangent(n, t);
}

// The tables' roughness of a lobe: Cycles' sqrt(sqrt(alpha_x alpha_y)) (isotropic: sqrt(alpha)).
inline float table_rough(float ax, float ay) { return ay < 0.0f ? std::sqrt(ax) : std::sqrt(std::sqrt(ax * ay)); }

// Cycles' closure_layering_weight: what lies below a layer keeps 1 - max(albedo / weight)
// of the weight (albedo: the layer's, relative to the weight it was given).
[[gnu::always_inline]] inline Vec3 layer_below(Vec3 wt, Vec3 albedo) {
  float top = 0.0f;
  if (wt.x > 0.0f) top = std::max(top, albedo.x);
  if (wt.y > 0.0f) top = std::max(top, albedo.y);
  if (wt.z > 0.0f) top = std::max(top, albedo.z);
  return wt * sat(1.0f - top);
}
}  // namespace

namespace {
// Fills `in` (only the fields its flags say are read: the rest keep what they held).
[[gnu::always_inline]] inline void principled_inputs_impl(PrincipledInputs& in, const ShaderOp& op,
                                                        const ShaderOp* extra, const Float4* r) {
  // The further inputs (PrincipledExtraSlot); kNoReg where there is no extra op.
  auto px = [extra](PrincipledExtraSlot s) { return extra ? extra->in[s] : int16_t(kNoReg); };
  auto col = [&](int16_t i) { return col_of(r, i); };
  auto val = [&](int16_t i, float def) { return val_of(r, i, def); };
  in.w = clean_color(col(op.in[0]));
  in.base = op.in[1] == kNoReg ? Vec3(0.8f) : clean_color(r[op.in[1]].xyz());
  in.base_c = vmin(in.base, Vec3(1.0f));
  in.metallic = sat(val(op.in[2], 0.0f));
  in.alpha = roughness_to_alpha(val(op.in[3], 0.5f));
  const float rough = std::sqrt(in.alpha);
  in.ior = clean_ior(val(op.in[4], 1.5f));
  in.transmission = sat(val(op.in[5], 0.0f));
  const float spec_level = std::isfinite(val(op.in[6], 0.5f)) ? std::max(0.0f, val(op.in[6], 0.5f)) : 0.5f;
  in.spec_tint = clean_color(col(op.in[7]));
  in.multi = op.in[9] != kNoReg && r[op.in[9]].x > 0.5f;  // Blender's Multiscatter GGX
  // Anisotropic (metal and specular lobes; Cycles keeps the transmission isotropic): the
  // aspect sqrt(1 - 0.9 a) stretches alpha along the tangent, turned about the normal.
  in.ax = in.alpha;
  in.ay = -1.0f;
  in.aniso = false;
  if (px(kPxAnisotropic) != kNoReg) {
    const float an = sat(std::isfinite(r[px(kPxAnisotropic)].x) ? r[px(kPxAnisotropic)].x : 0.0f);
    if (an > 0.0f) {
      const float aspect = std::sqrt(1.0f - an * 0.9f);
      in.ax = std::min(in.alpha / aspect, 1.0f);
      in.ay = in.alpha * aspect;
      in.aniso = true;
      in.rotation = val(px(kPxAnisotropicRotation), 0.0f);
    }
  }
  in.rough_a = in.ay < 0.0f ? rough : table_rough(in.ax, in.ay);
  // Thin Film (nm, its IOR): interference on the specular and transmission lobes (Cycles
  // 4.5: not on the metal, not on the coat).
  in.film = 0.0f;
  in.film_ior = 1.33f;
  if (px(kPxThinFilmThickness) != kNoReg) {
    const float t = r[px(kPxThinFilmThickness)].x, fi = val(px(kPxThinFilmIor), 1.33f);
    in.film = std::isfinite(t) ? std::min(std::max(t, 0.0f), 1e5f) : 0.0f;
    in.film_ior = std::isfinite(fi) ? std::max(fi, 1e-5f) : 1.33f;
  }
  const float cw_in = val(op.in[10], 0.0f);
  in.sheen = false;
  if (px(kPxSheenWeight) != kNoReg) {
    const float sw_in = val(px(kPxSheenWeight), 0.0f);
    const float sw = std::isfinite(sw_in) ? std::max(0.0f, sw_in) : 0.0f;
    if (sw > 1e-5f) {
      in.sheen = true;
      in.sheen_weight = sw;
      in.sheen_tint = vmax(clean_color(col(px(kPxSheenTint))), Vec3(0.0f));
      in.sheen_coat = std::isfinite(cw_in) ? sat(cw_in) : 0.0f;
      in.sheen_rough = sat(val(px(kPxSheenRoughness), 0.5f));
    }
  }
  in.coat = std::isfinite(cw_in) ? std::max(0.0f, cw_in) : 0.0f;
  if (in.coat > 1e-5f) {
    in.coat_alpha = roughness_to_alpha(val(op.in[11], 0.03f));
    in.coat_eta = std::max(1.0f, clean_ior(val(op.in[12], 1.5f)));
    in.coat_rough = std::sqrt(in.coat_alpha);
    in.coat_fss = fresnel_dielectric_fss(in.coat_eta);
    in.coat_tint = clean_color(col(op.in[13]));
  }
  in.emits = px(kPxEmission) != kNoReg;
  if (in.emits) in.emission = clean_color(col(px(kPxEmission)));
  if (in.metallic > 0.0f) {
    const Vec3 tint = vmin(in.spec_tint, Vec3(1.0f));
    in.metal_b = tint.x == 1.0f && tint.y == 1.0f && tint.z == 1.0f ? Vec3(0.0f) : f82_tint_b(in.base_c, tint);
    if (in.multi) in.metal_fss = f82_fss(in.base_c, in.metal_b);
  }
  if (in.transmission > 0.0f)
    in.transmission_tint = {std::sqrt(in.base_c.x), std::sqrt(in.base_c.y), std::sqrt(in.base_c.z)};
  // Specular IOR Level scales F0 (0.5 keeps the IOR's own), as an IOR of its own.
  in.eta = in.ior;
  in.f0 = f0_from_ior(in.ior);
  if (spec_level != 0.5f) {
    in.f0 *= 2.0f * spec_level;
    in.eta = ior_from_f0(in.f0);
    if (in.ior < 1.0f) in.eta = 1.0f / in.eta;
  }
  in.spec = in.eta != 1.0f || in.film > kThinFilmCutoff;
  in.spec_f0 = vmin(in.spec_tint * in.f0, Vec3(1.0f));  // Specular Tint tints F0 only (f90 = 1)
  if (in.spec && in.multi) {
    // The mean single-scatter Fresnel: the real curve's average remapped as the lobe's.
    const float F0 = f0_from_ior(in.eta);
    const float s_avg = F0 < 1.0f ? sat((fresnel_dielectric_fss(in.eta) - F0) / (1.0f - F0)) : 1.0f;
    in.spec_fss = in.spec_f0 + (Vec3(1.0f) - in.spec_f0) * s_avg;
  }
  // Subsurface (Cycles: beside the diffuse, under the specular): Subsurface Weight of the
  // base's share becomes a BSSRDF of the clamped base colour, its IOR the specular's (Skin:
  // Subsurface IOR), its entry roughness the specular's.
  in.sss_weight = 0.0f;
  if (px(kPxSubsurfaceWeight) != kNoReg) {
    const float x = r[px(kPxSubsurfaceWeight)].x;
    in.sss_weight = std::isfinite(x) && x > 1e-5f ? std::min(x, 1.0f) : 0.0f;
    if (in.sss_weight > 0.0f) {
      in.sss_ior = in.eta;
      const int16_t rr = px(kPxSubsurfaceRadius);
      in.sss_radius = (rr == kNoReg ? Vec3{1.0f, 0.2f, 0.1f} : r[rr].xyz()) * val(px(kPxSubsurfaceScale), 0.05f);
      in.sss_method = val(px(kPxSubsurfaceMethod), 1.0f);
      if (subsurface_method(in.sss_method) == SubsurfaceMethod::RandomWalkSkin)
        in.sss_ior = val(px(kPxSubsurfaceIor), 1.4f);
      in.sss_aniso = val(px(kPxSubsurfaceAnisotropy), 0.0f);
    }
  }
  in.diffuse_rough = 0.0f;
  if (px(kPxDiffuseRoughness) != kNoReg) {
    // Diffuse Roughness: Cycles' Oren-Nayar (from 1e-5 on) with the base colour as albedo.
    const float dr_in = val(px(kPxDiffuseRoughness), 0.0f);
    in.diffuse_rough = std::isfinite(dr_in) ? sat(dr_in) : 0.0f;
  }
}

// Cycles 4.5's layering (svm_closure.h, CLOSURE_BSDF_PRINCIPLED_ID): a coat over metal, then
// glass, then a dielectric specular layer over diffuse, each taking its share of the weight and
// the coat and specular layers attenuating what lies below by their estimated albedo.
[[gnu::always_inline]] inline void principled_closures_impl(const PrincipledInputs& in, const ShaderOp& op,
                                                          const ShaderOp* extra, const ShaderProgram& prog,
                                                          const Float4* r, const ShadingContext& ctx, ClosureList& out) {
  auto px = [extra](PrincipledExtraSlot s) { return extra ? extra->in[s] : int16_t(kNoReg); };
  const Frame fr = glossy_frame_at(r, ctx, op.in[8]);  // Cycles' valid_reflection_N
  const float mu = std::fabs(dot(fr.n, ctx.wo));
  Frame fd;  // fr's basis where the valid reflection left the normal as it was (the common case)
  const DiffuseBsdf diffuse = diffuse_lobe_at(r, ctx, prog, op.in[8], fd, &fr);
  Frame fa = fr;
  if (in.aniso) fa = aniso_frame_at(r, fr.n, px(kPxTangent), in.rotation, normal_or(r, op.in[8], ctx));
  Vec3 weight = in.w;
  if (in.sheen) {
    // Sheen, the top layer (Cycles' "First layer"): Zeltner et al.'s microfibre lobe on the
    // normal blended towards the coat's by the coat weight; what lies below keeps
    // 1 - its albedo (the closure weight, which holds the fitted albedo).
    const Vec3 n = normal_or(r, op.in[8], ctx);
    const Vec3 nc = normal_or(r, op.in[14] != kNoReg ? op.in[14] : op.in[8], ctx);
    Vec3 ns = n + (nc - n) * in.sheen_coat;
    ns = length_sq(ns) > 1e-12f ? normalize(ns) : n;
    const Frame fs = Frame::from_normal(ns);
    float albedo;
    SheenBsdf sh = SheenBsdf::setup(in.sheen_rough, std::max(dot(ns, ctx.wo) * (ctx.backfacing ? -1.0f : 1.0f), 0.0f),
                                    albedo);
    sh.back = ctx.backfacing;
    const Vec3 layer = in.sheen_tint * (in.sheen_weight * albedo);
    out.add(sh, weight * layer, fs, 1.0f);
    if (!ctx.ray.emission_only) weight = layer_below(weight, layer);
  }
  if (in.coat > 1e-5f) {
    // The coat: a dielectric GGX reflection with its own roughness, IOR and normal, always
    // energy-preserving (Cycles' bsdf_microfacet_setup_fresnel_dielectric), over the rest.
    ConductorBsdf c;
    c.alpha = in.coat_alpha;
    c.mode = ConductorFresnel::Dielectric;
    c.exact = !prog.schlick;
    c.eta = in.coat_eta;
    c.f0 = Vec3(f0_from_ior(c.eta));
    c.compensated = true;  // (its weight carries comp.scale)
    const Frame fc = op.in[14] != kNoReg ? glossy_frame_at(r, ctx, op.in[14]) : fr;  // (fr: the same inputs)
    const float mu_c = std::fabs(dot(fc.n, ctx.wo));
    const EnergyCompensation comp = ggx_reflection_compensation(in.coat_rough, mu_c, Vec3(in.coat_fss));
    const Vec3 albedo = comp.darkening * dielectric_specular_albedo(in.coat_rough, mu_c, c.eta, c.f0);
    // (dropped by Reflective Caustics off, as Cycles skips it: nothing below is dimmed)
    if (out.add(c, weight * (in.coat * comp.scale), fc, average(albedo)) && !ctx.ray.emission_only)
      weight = layer_below(weight, albedo * in.coat);
    const Vec3 tint = in.coat_tint;
    if (!(tint.x == 1.0f && tint.y == 1.0f && tint.z == 1.0f)) {
      // Cycles: the tint is the coat's transmittance at normal incidence (unit thickness);
      // the view's path through it, refracted, is 1 / cos(theta_t) long (Beer's law).
      const float inv = 1.0f / c.eta;
      const float cos_t = std::sqrt(std::max(1e-8f, 1.0f - inv * inv * (1.0f - mu_c * mu_c)));
      const float depth = 1.0f / cos_t;
      const Vec3 through = {std::pow(tint.x, depth), std::pow(tint.y, depth), std::pow(tint.z, depth)};
      weight *= Vec3(1.0f) + (through - Vec3(1.0f)) * in.coat;
    }
  }
  // Emission under a sheen or coat (Cycles: after both layers, so dimmed by them where the
  // closures exist, by the coat's tint always); the add-on passes it here only then, as a
  // plain Emission closure otherwise.
  if (in.emits) out.emission += in.emission * weight;
  if (in.metallic > 0.0f) {
    ConductorBsdf m;
    m.alpha = in.ax;
    m.alpha_y = in.ay;
    m.f0 = in.base_c;
    m.mode = ConductorFresnel::F82Tint;
    m.b = in.metal_b;
    Vec3 mw = weight * in.metallic;
    if (in.multi) mw *= ggx_reflection_compensation(in.rough_a, mu, in.metal_fss).scale;
    m.compensated = in.multi;
    out.add(m, mw, fa, average(fresnel_f82(mu, m.f0, m.b)));
    weight *= 1.0f - in.metallic;
  }
  if (in.transmission > 0.0f) {
    // As Cycles: the reflection stays untinted, refracted light takes sqrt(base) at each
    // crossing (base colour once through a closed object).
    DielectricBsdf g;
    g.alpha = in.alpha;
    g.eta = in.ior;
    g.schlick = prog.schlick;
    g.transmission_tint = in.transmission_tint;
    g.f0_tint = in.spec_tint;
    g.film_thickness = in.film;
    g.film_ior = in.film_ior;
    Vec3 gw = weight * in.transmission;
    if (in.multi) gw *= glass_compensation_at(ctx, g, fr, g.transmission_tint);
    g.compensated = in.multi;
    out.add(g, gw, fr);
    weight *= 1.0f - in.transmission;
  }
  if (in.spec) {
    ConductorBsdf s;
    s.alpha = in.ax;
    s.alpha_y = in.ay;
    s.mode = ConductorFresnel::Dielectric;
    s.exact = !prog.schlick;
    s.eta = in.eta;
    s.f0 = in.spec_f0;
    s.film_thickness = in.film;
    s.film_ior = in.film_ior;
    Vec3 sw = weight, darkening(1.0f);
    s.compensated = in.multi;
    if (in.multi) {
      const EnergyCompensation c = ggx_reflection_compensation(in.rough_a, mu, in.spec_fss);
      sw *= c.scale;
      darkening = c.darkening;
    }
    // With a film Cycles has no table: the film's reflectance seen from the view.
    const Vec3 albedo = darkening * (in.film > kThinFilmCutoff ? thin_film_dielectric(mu, in.film_ior, in.eta, in.film, s.f0)
                                                               : dielectric_specular_albedo(in.rough_a, mu, in.eta, s.f0));
    if (out.add(s, sw, fa, average(albedo))) weight = layer_below(weight, albedo);  // (as the coat)
  }
  // Subsurface: its normal the glossy one.
  const float ssw = in.sss_weight;
  if (ssw > 0.0f)
    add_subsurface(out, weight * (in.base_c * ssw), in.base_c, in.sss_radius, in.sss_aniso, in.sss_ior, in.alpha,
                   subsurface_method(in.sss_method), fr, ctx.ray.diffuse_ancestor, ctx.backfacing);
  const Vec3 dw = ssw > 0.0f ? weight * in.base * (1.0f - ssw) : weight * in.base;
  if (in.diffuse_rough >= 1e-5f) {
    OrenNayarBsdf o = OrenNayarBsdf::setup(in.diffuse_rough, in.base,
                                           std::max(dot(fd.n, ctx.wo) * (diffuse.back ? -1.0f : 1.0f), 0.0f));
    o.ns = diffuse.ns;
    o.bent = diffuse.bent;
    o.back = diffuse.back;
    out.add(o, dw, fd);
    return;
  }
  out.add(diffuse, dw, fd);
}
}  // namespace

PrincipledInputs principled_inputs(const ShaderOp& op, const ShaderOp* extra, const Float4* r) {
  PrincipledInputs in{};  // (kept: every field defined)
  principled_inputs_impl(in, op, extra, r);
  return in;
}

void principled_closures(const PrincipledInputs& in, const ShaderOp& op, const ShaderOp* extra, const ShaderProgram& prog,
                         const Float4* r, const ShadingContext& ctx, ClosureList& out) {
  principled_closures_impl(in, op, extra, prog, r, ctx, out);
}

void eval_closure_op(const ShaderOp& op, const ShaderProgram& prog, const Float4* r, const ShadingContext& ctx,
                     const ShaderOp*& extra, ClosureList& out) {
  using namespace shader_math;
  auto glossy_frame = [&](int16_t normal_reg) { return glossy_frame_at(r, ctx, normal_reg); };
  // Blender's Multiscatter GGX: the add-on passes a register holding 1 for it.
  auto multiscatter = [&](int16_t i) { return i != kNoReg && r[i].x > 0.5f; };
  auto glass_compensation = [&](const DielectricBsdf& b, const Frame& f, Vec3 fss) {
    return glass_compensation_at(ctx, b, f, fss);
  };
  auto diffuse_lobe = [&](int16_t normal_reg, Frame& f) { return diffuse_lobe_at(r, ctx, prog, normal_reg, f); };
  auto col = [&](int16_t i) { return col_of(r, i); };
  auto val = [&](int16_t i, float def) { return val_of(r, i, def); };
  auto aniso_frame = [&](Vec3 n, int16_t tangent_reg, float rotation, Vec3 axis) {
    return aniso_frame_at(r, n, tangent_reg, rotation, axis);
  };
  switch (op.code) {
    case OpCode::Diffuse: {
      Frame f;
      const DiffuseBsdf d = diffuse_lobe(op.in[2], f);
      const Vec3 w = clean_color(col(op.in[0]) * col(op.in[1]));
      // Roughness (in[3]): Cycles' Oren-Nayar from 1e-5 on, with the colour as its albedo.
      const float rough = val(op.in[3], 0.0f);
      if (rough >= 1e-5f) {
        OrenNayarBsdf o = OrenNayarBsdf::setup(rough, clean_color(col(op.in[1])),
                                               std::max(dot(f.n, ctx.wo) * (d.back ? -1.0f : 1.0f), 0.0f));
        o.ns = d.ns;
        o.bent = d.bent;
        o.back = d.back;
        out.add(o, w, f);
      } else {
        out.add(d, w, f);
      }
      break;
    }
    case OpCode::Toon: {
      // Cycles' CLOSURE_BSDF_DIFFUSE_TOON_ID / GLOSSY_TOON_ID: in color, size, smooth, normal.
      const Frame f = Frame::from_normal(normal_or(r, op.in[4], ctx));
      out.add(ToonBsdf::setup(val(op.in[2], 0.5f), val(op.in[3], 0.0f), op.sub == 1),
              clean_color(col(op.in[0]) * col(op.in[1])), f);
      break;
    }
    case OpCode::Sheen: {
      // Cycles' CLOSURE_BSDF_SHEEN_ID (sub 0) and ASHIKHMIN_VELVET_ID (sub 1): in color,
      // roughness, normal; the plain normal (no valid-reflection lift).
      const Frame f = Frame::from_normal(normal_or(r, op.in[3], ctx));
      const Vec3 w = clean_color(col(op.in[0]) * col(op.in[1]));
      const float rough = val(op.in[2], 0.5f);
      if (op.sub == 1) {
        out.add(VelvetBsdf::setup(rough), w, f);
      } else {
        float albedo;
        SheenBsdf sh = SheenBsdf::setup(rough, std::max(dot(f.n, ctx.wo) * (ctx.backfacing ? -1.0f : 1.0f), 0.0f), albedo);
        sh.back = ctx.backfacing;
        out.add(sh, w * albedo, f, 1.0f);
      }
      break;
    }
    case OpCode::Metallic: {
      // Blender 4.x's Metallic BSDF (Cycles' CLOSURE_BSDF_F82_CONDUCTOR / PHYSICAL_CONDUCTOR):
      // GGX whose Fresnel is F82-Tint from Base Color and Edge Tint, or a conductor's exact
      // Fresnel from IOR and Extinction; the node's colour is all in the Fresnel.
      ConductorBsdf m;
      m.alpha = roughness_to_alpha(val(op.in[5], 0.5f));
      m.dist = Microfacet(op.sub);
      Frame f = glossy_frame(op.in[6]);
      {  // Anisotropy as the Principled's: aspect sqrt(1 - 0.9 a), the tangent turned about N
        const float an = sat(std::isfinite(val(op.in[9], 0.0f)) ? val(op.in[9], 0.0f) : 0.0f);
        if (an > 0.0f && op.in[11] != kNoReg) {
          const float aspect = std::sqrt(1.0f - an * 0.9f), a = m.alpha;
          m.alpha = std::min(a / aspect, 1.0f);
          m.alpha_y = a * aspect;
          f = aniso_frame(f.n, op.in[11], val(op.in[10], 0.0f), normal_or(r, op.in[6], ctx));
        }
      }
      const bool physical = op.in[8] != kNoReg && r[op.in[8]].x > 0.5f;
      Vec3 fss;
      if (physical) {
        m.mode = ConductorFresnel::Conductor;
        m.f0 = vmax(clean_color(col(op.in[3])), Vec3(0.0f));
        m.b = vmax(clean_color(col(op.in[4])), Vec3(0.0f));
        if (multiscatter(op.in[7])) fss = conductor_fss(m.f0, m.b);
      } else {
        m.mode = ConductorFresnel::F82Tint;
        m.f0 = vmin(clean_color(col(op.in[1])), Vec3(1.0f));
        const Vec3 tint = vmin(clean_color(col(op.in[2])), Vec3(1.0f));
        if (!(tint.x == 1.0f && tint.y == 1.0f && tint.z == 1.0f)) m.b = f82_tint_b(m.f0, tint);
        if (multiscatter(op.in[7])) fss = f82_fss(m.f0, m.b);
      }
      const float mu = std::fabs(dot(f.n, ctx.wo));
      Vec3 w = clean_color(col(op.in[0]));
      if (multiscatter(op.in[7])) w *= ggx_reflection_compensation(table_rough(m.alpha, m.alpha_y), mu, fss).scale;
      m.compensated = multiscatter(op.in[7]);
      out.add(m, w, f, average(m.fresnel(mu)));
      break;
    }
    case OpCode::Translucent: {
      Frame f;
      diffuse_lobe(op.in[2], f);  // its frame only: Cycles applies no bump shadowing here
      out.add(TranslucentBsdf{}, clean_color(col(op.in[0]) * col(op.in[1])), f);
      break;
    }
    case OpCode::Glossy: {
      ConductorBsdf g;
      g.alpha = roughness_to_alpha(val(op.in[2], 0.5f));
      g.dist = Microfacet(op.sub);
      Frame f = glossy_frame(op.in[3]);
      {  // Cycles' Glossy anisotropy in [-0.99, 0.99]: positive narrows the lobe along the
         // tangent and widens it across, negative the other way; rotated about the normal.
        const float an = clampf(std::isfinite(val(op.in[5], 0.0f)) ? val(op.in[5], 0.0f) : 0.0f, -0.99f, 0.99f);
        if (op.in[7] != kNoReg && std::fabs(an) > 1e-4f) {
          const float a = g.alpha;
          g.alpha = std::min(an < 0.0f ? a / (1.0f + an) : a * (1.0f - an), 1.0f);
          g.alpha_y = std::min(an < 0.0f ? a * (1.0f + an) : a / (1.0f - an), 1.0f);
          f = aniso_frame(f.n, op.in[7], val(op.in[6], 0.0f), f.n);
        }
      }
      Vec3 w = clean_color(col(op.in[0]) * col(op.in[1]));
      if (multiscatter(op.in[4])) {  // Cycles: the colour is the lobe's Fresnel (Fss)
        w *= ggx_reflection_compensation(table_rough(g.alpha, g.alpha_y), std::fabs(dot(f.n, ctx.wo)),
                                         clean_color(col(op.in[1]))).scale;
        g.compensated = true;
      }
      out.add(g, w, f);
      break;
    }
    case OpCode::Glass:
    case OpCode::Refraction: {
      DielectricBsdf b;
      b.alpha = roughness_to_alpha(val(op.in[2], 0.0f));
      b.eta = clean_ior(val(op.in[3], 1.5f));
      b.schlick = prog.schlick;
      b.dist = Microfacet(op.sub);
      if (op.code == OpCode::Refraction) {
        b.reflection = false;
        b.fresnel_on_transmission = false;
      }
      const Frame f = glossy_frame(op.in[4]);
      Vec3 w = clean_color(col(op.in[0]) * col(op.in[1]));
      if (op.code == OpCode::Glass && multiscatter(op.in[5])) {
        w *= glass_compensation(b, f, clean_color(col(op.in[1])));
        b.compensated = true;
      }
      out.add(b, w, f);
      break;
    }
    case OpCode::Transparent:
      out.add(TransparentBsdf{}, clean_color(col(op.in[0]) * col(op.in[1])), Frame::from_normal(ctx.ns));
      break;
    case OpCode::RayPortal: {
      // Cycles' bsdf_ray_portal_setup: the Position input (unlinked: the shading point), the
      // Direction input normalised (zero: the incoming ray's, straight on).
      PortalBsdf pb;
      pb.p = op.in[2] == kNoReg ? ctx.p : r[op.in[2]].xyz();
      const Vec3 d = op.in[3] == kNoReg ? Vec3(0.0f) : r[op.in[3]].xyz();
      pb.d = d.x == 0.0f && d.y == 0.0f && d.z == 0.0f ? -ctx.wo : d / std::sqrt(length_sq(d));
      if (!is_finite(pb.p) || !is_finite(pb.d) || !(length_sq(pb.d) > 0.0f)) break;
      out.add(pb, clean_color(col(op.in[0]) * col(op.in[1])), Frame::from_normal(ctx.ns));
      break;
    }
    case OpCode::PrincipledExtra:
      extra = &op;
      break;
    case OpCode::Holdout:
      out.holdout += clean_color(col(op.in[0]));
      break;
    case OpCode::PrincipledHair: {
      // Cycles' svm_node_closure (CLOSURE_BSDF_HAIR_CHIANG_ID): the absorption from the
      // parametrization, roughness randomised per strand, Coat as a share of the R lobe's
      // roughness. Its frame and offset h are set by the scene from the hit (orient_hair).
      const float random = val(op.in[13], 0.5f);
      const float fr = 1.0f + 2.0f * (random - 0.5f) * val(op.in[12], 0.0f);
      const float rough = val(op.in[6], 0.3f) * fr;
      const float radial = op.ext != 0 ? rough : val(op.in[7], 0.3f) * fr;  // Huang: Roughness
      Vec3 sigma;
      if (op.sub == 0) {
        sigma = vmax(clean_color(col(op.in[5])), Vec3(0.0f));
      } else if (op.sub == 1) {
        float melanin = val(op.in[2], 0.8f) * (1.0f + 2.0f * (random - 0.5f) * clampf(val(op.in[11], 0.0f), 0.0f, 1.0f));
        melanin = -std::log(std::max(1.0f - melanin, 1e-4f));
        const float red = val(op.in[3], 1.0f);
        sigma = hair_sigma_from_concentration(melanin * (1.0f - red), melanin * red) +
                hair_sigma_from_reflectance(clean_color(col(op.in[4])), radial);
      } else {
        sigma = hair_sigma_from_reflectance(clean_color(col(op.in[1])), radial);
      }
      if (!is_finite(sigma)) sigma = Vec3(0.0f);
      const float ior = val(op.in[9], 1.55f);
      if (op.ext != 0) {
        // Huang (CLOSURE_BSDF_HAIR_HUANG_ID): Coat's slot holds Aspect Ratio, Radial Roughness'
        // the TRT weight (the colour fit above used Roughness for it, as Cycles); no closure
        // when every lobe weight is <= 0. Its frame, h and near field: orient_hair.
        const float wr = val(op.in[14], 1.0f), wtt = val(op.in[15], 1.0f), wtrt = val(op.in[7], 1.0f);
        if (!(wr > 0.0f) && !(wtt > 0.0f) && !(wtrt > 0.0f)) break;
        out.add(HairHuangBsdf::from_node(sigma, rough, val(op.in[10], 0.0349066f), ior, val(op.in[8], 0.85f), wr, wtt,
                                         wtrt),
                clean_color(col(op.in[0])), Frame::from_normal(ctx.ns));
        break;
      }
      HairChiangBsdf h = HairChiangBsdf::from_node(sigma, rough, radial, val(op.in[8], 0.0f), val(op.in[10], 0.0349066f),
                                                   std::isfinite(ior) && ior > 0.0f ? ior : 1.55f);
      out.add(h, clean_color(col(op.in[0])), Frame::from_normal(ctx.ns));
      break;
    }
    case OpCode::Hair: {
      // Cycles' svm_node_closure (CLOSURE_BSDF_HAIR_*): N the valid-reflection shading normal;
      // T the Tangent input, else the strand's direction (dPdu) on curves, else the triangle's
      // dPdv (corners 2 - 0, as Cycles 4.x' triangle_dPdudv) with the Offset dropped.
      // (N facing the view, as Cycles flips a backfacing hit's normals: the components'
      // sides are N's.)
      const Vec3 n = valid_specular_normal(ctx.ng, ctx.wo, ctx.ns);
      const Frame f = Frame::from_normal(dot(ctx.ng, ctx.wo) < 0.0f ? -n : n);
      float offset = -val(op.in[2], 0.0f);
      Vec3 t(0.0f);
      if (op.in[5] != kNoReg) {
        t = r[op.in[5]].xyz();
      } else if (ctx.curve) {
        t = ctx.curve->tangent;
      } else {
        if (ctx.tri) t = ctx.tri[2] - ctx.tri[0];
        offset = 0.0f;
      }
      const float l2 = length_sq(t);
      if (!(l2 > 1e-30f) || !std::isfinite(l2)) break;  // no fibre direction: nothing scatters
      out.add(HairBsdf::setup(f.to_local(t / std::sqrt(l2)), val(op.in[3], 0.1f), val(op.in[4], 1.0f), offset,
                              op.sub == 1),
              clean_color(col(op.in[0]) * col(op.in[1])), f);
      break;
    }
    case OpCode::Emission:
      out.emission += clean_color(col(op.in[0]) * col(op.in[1]));
      break;
    case OpCode::Principled: {
      // (`extra` is cleared for the next op; the closures keep their own copy.)
      const ShaderOp* ex = extra;
      extra = nullptr;
      PrincipledInputs in;  // (per hit: only the fields its flags say are read are filled)
      principled_inputs_impl(in, op, ex, r);
      principled_closures_impl(in, op, ex, prog, r, ctx, out);
      break;
    }
    case OpCode::Subsurface: {
      // The Subsurface Scattering node (Cycles' CLOSURE_BSSRDF_*): in weight, colour, scale,
      // radius, IOR, roughness (the entry's GGX alpha as it is), anisotropy, normal.
      const Vec3 color = clean_color(col(op.in[1]));
      const Vec3 radius = (op.in[3] == kNoReg ? Vec3{1.0f, 0.2f, 0.1f} : r[op.in[3]].xyz()) * val(op.in[2], 0.05f);
      add_subsurface(out, clean_color(col(op.in[0])) * color, color, radius, val(op.in[6], 0.0f), val(op.in[4], 1.4f),
                     val(op.in[5], 1.0f), subsurface_method(val(op.in[8], 1.0f)),
                     glossy_frame(op.in[7]), ctx.ray.diffuse_ancestor, ctx.backfacing);
      break;
    }
    default: break;  // the value ops: eval_shader's own
  }
}

}  // namespace pl::detail
