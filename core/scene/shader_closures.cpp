// The closure ops of shader programs (BSDFs, BSSRDFs, emission, holdout) as Cycles'
// svm_node_closure_* set them up from their inputs, for eval_shader.
#include "scene/shader_closures.h"

#include "scene/bssrdf.h"
#include "scene/shader_math.h"

namespace pl::detail {

void eval_closure_op(const ShaderOp& op, const ShaderProgram& prog, const Float4* r, const ShadingContext& ctx,
                     const ShaderOp*& extra, ClosureList& out) {
  using namespace shader_math;
  // Closure frames as Cycles sets them up: glossy lobes get a normal whose mirror reflection of
  // the view stays above the surface; diffuse lobes with a bent normal get the bump shadowing.
  auto glossy_frame = [&](int16_t normal_reg) {
    return Frame::from_normal(valid_specular_normal(ctx.ng, ctx.wo, normal_or(r, normal_reg, ctx.ns)));
  };
  // Blender's Multiscatter GGX: the add-on passes a register holding 1 for it.
  auto multiscatter = [&](int16_t i) { return i != kNoReg && r[i].x > 0.5f; };
  // Multiscatter GGX glass: the view's side decides the relative IOR (Cycles' ior or 1 / ior).
  auto glass_compensation = [&](const DielectricBsdf& b, const Frame& f, Vec3 fss) {
    const float c = dot(f.n, ctx.wo);
    return ggx_glass_compensation(std::sqrt(b.alpha), std::fabs(c), c >= 0.0f ? b.eta : 1.0f / b.eta, fss).scale;
  };
  auto diffuse_lobe = [&](int16_t normal_reg, Frame& f) {
    const Vec3 n = normal_or(r, normal_reg, ctx.ns);
    f = Frame::from_normal(n);
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
  };
  // Closure inputs: an omitted register means the input's default.
  auto col = [&](int16_t i) { return i == kNoReg ? Vec3(1.0f) : r[i].xyz(); };
  auto val = [&](int16_t i, float def) { return i == kNoReg ? def : r[i].x; };
  // An anisotropic lobe's frame: its (valid-reflection) normal n and the tangent register
  // turned `rotation` turns about `axis` (Cycles' rotate_around_axis by rotation * 2 pi).
  // The tables' roughness of a lobe: Cycles' sqrt(sqrt(alpha_x alpha_y)) (isotropic: sqrt(alpha)).
  auto table_rough = [](float ax, float ay) { return ay < 0.0f ? std::sqrt(ax) : std::sqrt(std::sqrt(ax * ay)); };
  auto aniso_frame = [&](Vec3 n, int16_t tangent_reg, float rotation, Vec3 axis) {
    if (tangent_reg == kNoReg) return Frame::from_normal(n);
    Vec3 t = r[tangent_reg].xyz();
    if (rotation != 0.0f && std::isfinite(rotation)) t = rotate_about_axis(t, axis, rotation * 2.0f * kPi);
    return Frame::from_normal_tangent(n, t);
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
      const Frame f = Frame::from_normal(normal_or(r, op.in[4], ctx.ns));
      out.add(ToonBsdf::setup(val(op.in[2], 0.5f), val(op.in[3], 0.0f), op.sub == 1),
              clean_color(col(op.in[0]) * col(op.in[1])), f);
      break;
    }
    case OpCode::Sheen: {
      // Cycles' CLOSURE_BSDF_SHEEN_ID (sub 0) and ASHIKHMIN_VELVET_ID (sub 1): in color,
      // roughness, normal; the plain normal (no valid-reflection lift).
      const Frame f = Frame::from_normal(normal_or(r, op.in[3], ctx.ns));
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
          f = aniso_frame(f.n, op.in[11], val(op.in[10], 0.0f), normal_or(r, op.in[6], ctx.ns));
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
      if (multiscatter(op.in[4]))  // Cycles: the colour is the lobe's Fresnel (Fss)
        w *= ggx_reflection_compensation(table_rough(g.alpha, g.alpha_y), std::fabs(dot(f.n, ctx.wo)),
                                         clean_color(col(op.in[1]))).scale;
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
      if (op.code == OpCode::Glass && multiscatter(op.in[5]))
        w *= glass_compensation(b, f, clean_color(col(op.in[1])));
      out.add(b, w, f);
      break;
    }
    case OpCode::Transparent:
      out.add(TransparentBsdf{}, clean_color(col(op.in[0]) * col(op.in[1])), Frame::from_normal(ctx.ns));
      break;
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
      // Cycles 4.5's layering (svm_closure.h, CLOSURE_BSDF_PRINCIPLED_ID): a coat over metal,
      // then glass, then a dielectric specular layer over diffuse, each taking its share of
      // the weight and the coat and specular layers attenuating what lies below by their
      // estimated albedo.
      // The further inputs (PrincipledExtraSlot); kNoReg where there is no extra op.
      // (The lambda keeps its own copy of the pointer: `extra` is cleared for the next op.)
      auto px = [ex = extra](PrincipledExtraSlot s) { return ex ? ex->in[s] : int16_t(kNoReg); };
      extra = nullptr;
      const Vec3 w = clean_color(col(op.in[0]));
      const Vec3 base = op.in[1] == kNoReg ? Vec3(0.8f) : clean_color(r[op.in[1]].xyz());
      const Vec3 base_c = vmin(base, Vec3(1.0f));
      const float metallic = sat(val(op.in[2], 0.0f));
      const float alpha = roughness_to_alpha(val(op.in[3], 0.5f));
      const float rough = std::sqrt(alpha);
      const float ior = clean_ior(val(op.in[4], 1.5f));
      const float transmission = sat(val(op.in[5], 0.0f));
      const float spec_level = std::isfinite(val(op.in[6], 0.5f)) ? std::max(0.0f, val(op.in[6], 0.5f)) : 0.5f;
      const Vec3 spec_tint = clean_color(col(op.in[7]));
      const bool multi = multiscatter(op.in[9]);
      const Frame fr = glossy_frame(op.in[8]);  // Cycles' valid_reflection_N
      const float mu = std::fabs(dot(fr.n, ctx.wo));
      Frame fd;
      const DiffuseBsdf diffuse = diffuse_lobe(op.in[8], fd);
      // Anisotropic (metal and specular lobes; Cycles keeps the transmission isotropic): the
      // aspect sqrt(1 - 0.9 a) stretches alpha along the tangent, turned about the normal.
      float ax = alpha, ay = -1.0f;
      Frame fa = fr;
      if (px(kPxAnisotropic) != kNoReg) {
        const float an = sat(std::isfinite(r[px(kPxAnisotropic)].x) ? r[px(kPxAnisotropic)].x : 0.0f);
        if (an > 0.0f) {
          const float aspect = std::sqrt(1.0f - an * 0.9f);
          ax = std::min(alpha / aspect, 1.0f);
          ay = alpha * aspect;
          fa = aniso_frame(fr.n, px(kPxTangent), val(px(kPxAnisotropicRotation), 0.0f), normal_or(r, op.in[8], ctx.ns));
        }
      }
      const float rough_a = ay < 0.0f ? rough : table_rough(ax, ay);
      // Thin Film (nm, its IOR): interference on the specular and transmission lobes (Cycles
      // 4.5: not on the metal, not on the coat).
      float film = 0.0f, film_ior = 1.33f;
      if (px(kPxThinFilmThickness) != kNoReg) {
        const float t = r[px(kPxThinFilmThickness)].x, fi = val(px(kPxThinFilmIor), 1.33f);
        film = std::isfinite(t) ? std::min(std::max(t, 0.0f), 1e5f) : 0.0f;
        film_ior = std::isfinite(fi) ? std::max(fi, 1e-5f) : 1.33f;
      }
      Vec3 weight = w;
      // Cycles' closure_layering_weight: what lies below a layer keeps 1 - max(albedo / weight)
      // of the weight (albedo: the layer's, relative to the weight it was given).
      auto layer_below = [](Vec3 wt, Vec3 albedo) {
        float top = 0.0f;
        if (wt.x > 0.0f) top = std::max(top, albedo.x);
        if (wt.y > 0.0f) top = std::max(top, albedo.y);
        if (wt.z > 0.0f) top = std::max(top, albedo.z);
        return wt * sat(1.0f - top);
      };
      if (px(kPxSheenWeight) != kNoReg) {
        // Sheen, the top layer (Cycles' "First layer"): Zeltner et al.'s microfibre lobe on the
        // normal blended towards the coat's by the coat weight; what lies below keeps
        // 1 - its albedo (the closure weight, which holds the fitted albedo).
        const float sw_in = val(px(kPxSheenWeight), 0.0f);
        const float sw = std::isfinite(sw_in) ? std::max(0.0f, sw_in) : 0.0f;
        if (sw > 1e-5f) {
          const Vec3 tint = vmax(clean_color(col(px(kPxSheenTint))), Vec3(0.0f));
          const Vec3 n = normal_or(r, op.in[8], ctx.ns);
          const Vec3 nc = normal_or(r, op.in[14] != kNoReg ? op.in[14] : op.in[8], ctx.ns);
          const float cw_in = val(op.in[10], 0.0f);
          const float cw = std::isfinite(cw_in) ? sat(cw_in) : 0.0f;
          Vec3 ns = n + (nc - n) * cw;
          ns = length_sq(ns) > 1e-12f ? normalize(ns) : n;
          const Frame fs = Frame::from_normal(ns);
          float albedo;
          SheenBsdf sh = SheenBsdf::setup(sat(val(px(kPxSheenRoughness), 0.5f)),
                                          std::max(dot(ns, ctx.wo) * (ctx.backfacing ? -1.0f : 1.0f), 0.0f), albedo);
          sh.back = ctx.backfacing;
          const Vec3 layer = tint * (sw * albedo);
          out.add(sh, weight * layer, fs, 1.0f);
          if (!ctx.ray.emission_only) weight = layer_below(weight, layer);
        }
      }
      const float coat_in = val(op.in[10], 0.0f);
      const float coat = std::isfinite(coat_in) ? std::max(0.0f, coat_in) : 0.0f;
      if (coat > 1e-5f) {
        // The coat: a dielectric GGX reflection with its own roughness, IOR and normal, always
        // energy-preserving (Cycles' bsdf_microfacet_setup_fresnel_dielectric), over the rest.
        ConductorBsdf c;
        c.alpha = roughness_to_alpha(val(op.in[11], 0.03f));
        c.mode = ConductorFresnel::Dielectric;
        c.exact = !prog.schlick;
        c.eta = std::max(1.0f, clean_ior(val(op.in[12], 1.5f)));
        c.f0 = Vec3(f0_from_ior(c.eta));
        const Frame fc = glossy_frame(op.in[14] != kNoReg ? op.in[14] : op.in[8]);
        const float mu_c = std::fabs(dot(fc.n, ctx.wo));
        const float rc = std::sqrt(c.alpha);
        const EnergyCompensation comp =
            ggx_reflection_compensation(rc, mu_c, Vec3(fresnel_dielectric_fss(c.eta)));
        const Vec3 albedo = comp.darkening * dielectric_specular_albedo(rc, mu_c, c.eta, c.f0);
        out.add(c, weight * (coat * comp.scale), fc, average(albedo));
        if (!ctx.ray.emission_only) weight = layer_below(weight, albedo * coat);
        const Vec3 tint = clean_color(col(op.in[13]));
        if (!(tint.x == 1.0f && tint.y == 1.0f && tint.z == 1.0f)) {
          // Cycles: the tint is the coat's transmittance at normal incidence (unit thickness);
          // the view's path through it, refracted, is 1 / cos(theta_t) long (Beer's law).
          const float inv = 1.0f / c.eta;
          const float cos_t = std::sqrt(std::max(1e-8f, 1.0f - inv * inv * (1.0f - mu_c * mu_c)));
          const float depth = 1.0f / cos_t;
          const Vec3 through = {std::pow(tint.x, depth), std::pow(tint.y, depth), std::pow(tint.z, depth)};
          weight *= Vec3(1.0f) + (through - Vec3(1.0f)) * coat;
        }
      }
      // Emission under a sheen or coat (Cycles: after both layers, so dimmed by them where the
      // closures exist, by the coat's tint always); the add-on passes it here only then, as a
      // plain Emission closure otherwise.
      if (px(kPxEmission) != kNoReg) out.emission += clean_color(col(px(kPxEmission))) * weight;
      if (metallic > 0.0f) {
        ConductorBsdf m;
        m.alpha = ax;
        m.alpha_y = ay;
        m.f0 = base_c;
        m.mode = ConductorFresnel::F82Tint;
        const Vec3 tint = vmin(spec_tint, Vec3(1.0f));
        if (!(tint.x == 1.0f && tint.y == 1.0f && tint.z == 1.0f)) m.b = f82_tint_b(m.f0, tint);
        Vec3 mw = weight * metallic;
        if (multi) mw *= ggx_reflection_compensation(rough_a, mu, f82_fss(m.f0, m.b)).scale;
        out.add(m, mw, fa, average(fresnel_f82(mu, m.f0, m.b)));
        weight *= 1.0f - metallic;
      }
      if (transmission > 0.0f) {
        // As Cycles: the reflection stays untinted, refracted light takes sqrt(base) at each
        // crossing (base colour once through a closed object).
        DielectricBsdf g;
        g.alpha = alpha;
        g.eta = ior;
        g.schlick = prog.schlick;
        g.transmission_tint = {std::sqrt(base_c.x), std::sqrt(base_c.y), std::sqrt(base_c.z)};
        g.f0_tint = spec_tint;
        g.film_thickness = film;
        g.film_ior = film_ior;
        Vec3 gw = weight * transmission;
        if (multi) gw *= glass_compensation(g, fr, g.transmission_tint);
        out.add(g, gw, fr);
        weight *= 1.0f - transmission;
      }
      // Specular IOR Level scales F0 (0.5 keeps the IOR's own), as an IOR of its own.
      float eta = ior, f0 = f0_from_ior(ior);
      if (spec_level != 0.5f) {
        f0 *= 2.0f * spec_level;
        eta = ior_from_f0(f0);
        if (ior < 1.0f) eta = 1.0f / eta;
      }
      if (eta != 1.0f || film > kThinFilmCutoff) {
        ConductorBsdf s;
        s.alpha = ax;
        s.alpha_y = ay;
        s.mode = ConductorFresnel::Dielectric;
        s.exact = !prog.schlick;
        s.eta = eta;
        s.f0 = vmin(spec_tint * f0, Vec3(1.0f));  // Specular Tint tints F0 only (f90 = 1)
        s.film_thickness = film;
        s.film_ior = film_ior;
        Vec3 sw = weight, darkening(1.0f);
        if (multi) {
          // The mean single-scatter Fresnel: the real curve's average remapped as the lobe's.
          const float F0 = f0_from_ior(eta);
          const float s_avg = F0 < 1.0f ? sat((fresnel_dielectric_fss(eta) - F0) / (1.0f - F0)) : 1.0f;
          const EnergyCompensation c =
              ggx_reflection_compensation(rough_a, mu, s.f0 + (Vec3(1.0f) - s.f0) * s_avg);
          sw *= c.scale;
          darkening = c.darkening;
        }
        // With a film Cycles has no table: the film's reflectance seen from the view.
        const Vec3 albedo = darkening * (film > kThinFilmCutoff ? thin_film_dielectric(mu, film_ior, eta, film, s.f0)
                                                                : dielectric_specular_albedo(rough_a, mu, eta, s.f0));
        out.add(s, sw, fa, average(albedo));
        weight = layer_below(weight, albedo);
      }
      // Subsurface (Cycles: beside the diffuse, under the specular): Subsurface Weight of the
      // base's share becomes a BSSRDF of the clamped base colour, its IOR the specular's (Skin:
      // Subsurface IOR), its entry roughness the specular's, its normal the glossy one.
      float ssw = 0.0f;
      if (px(kPxSubsurfaceWeight) != kNoReg) {
        const float x = r[px(kPxSubsurfaceWeight)].x;
        ssw = std::isfinite(x) && x > 1e-5f ? std::min(x, 1.0f) : 0.0f;
        if (ssw > 0.0f) {
          const int16_t rr = px(kPxSubsurfaceRadius);
          const Vec3 radius = (rr == kNoReg ? Vec3{1.0f, 0.2f, 0.1f} : r[rr].xyz()) * val(px(kPxSubsurfaceScale), 0.05f);
          const float m = val(px(kPxSubsurfaceMethod), 1.0f);
          const SubsurfaceMethod method = subsurface_method(m);
          const float sss_ior = method == SubsurfaceMethod::RandomWalkSkin ? val(px(kPxSubsurfaceIor), 1.4f) : eta;
          add_subsurface(out, weight * (base_c * ssw), base_c, radius, val(px(kPxSubsurfaceAnisotropy), 0.0f),
                         sss_ior, alpha, method, fr, ctx.ray.diffuse_ancestor, ctx.backfacing);
        }
      }
      const Vec3 dw = ssw > 0.0f ? weight * base * (1.0f - ssw) : weight * base;
      if (px(kPxDiffuseRoughness) != kNoReg) {
        // Diffuse Roughness: Cycles' Oren-Nayar (from 1e-5 on) with the base colour as albedo.
        const float dr_in = val(px(kPxDiffuseRoughness), 0.0f);
        const float dr = std::isfinite(dr_in) ? sat(dr_in) : 0.0f;
        if (dr >= 1e-5f) {
          OrenNayarBsdf o = OrenNayarBsdf::setup(dr, base, std::max(dot(fd.n, ctx.wo) * (diffuse.back ? -1.0f : 1.0f), 0.0f));
          o.ns = diffuse.ns;
          o.bent = diffuse.bent;
          o.back = diffuse.back;
          out.add(o, dw, fd);
          break;
        }
      }
      out.add(diffuse, dw, fd);
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
