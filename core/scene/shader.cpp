#include "scene/shader.h"

namespace pl {
namespace {

inline Float4 f4(Vec3 v, float w = 1.0f) { return {v.x, v.y, v.z, w}; }
inline Float4 lerp4(const Float4& a, const Float4& b, float t) {
  return {a.x + (b.x - a.x) * t, a.y + (b.y - a.y) * t, a.z + (b.z - a.z) * t, a.w + (b.w - a.w) * t};
}

int wrap(int i, int n) {
  const int r = i % n;
  return r < 0 ? r + n : r;
}

float math_op(MathOp op, float a, float b) {
  switch (op) {
    case MathOp::Add: return a + b;
    case MathOp::Subtract: return a - b;
    case MathOp::Multiply: return a * b;
    case MathOp::Divide: return b != 0.0f ? a / b : 0.0f;  // Blender's safe divide
    case MathOp::Power: {
      if (a >= 0.0f) return std::pow(a, b);
      const float fb = std::floor(b);  // negative base: only integer powers are defined
      return fb == b ? std::pow(a, b) : 0.0f;
    }
    case MathOp::Minimum: return std::min(a, b);
    case MathOp::Maximum: return std::max(a, b);
    case MathOp::LessThan: return a < b ? 1.0f : 0.0f;
    case MathOp::GreaterThan: return a > b ? 1.0f : 0.0f;
    case MathOp::Absolute: return std::fabs(a);
  }
  return 0.0f;
}

float mix_channel(MixOp op, float a, float b, float f) {
  const float g = 1.0f - f;
  switch (op) {
    case MixOp::Mix: return g * a + f * b;
    case MixOp::Multiply: return a * (g + f * b);
    case MixOp::Add: return a + f * b;
    case MixOp::Subtract: return a - f * b;
    case MixOp::Screen: return 1.0f - (g + f * (1.0f - b)) * (1.0f - a);
    case MixOp::Divide: return b != 0.0f ? g * a + f * a / b : a;
    case MixOp::Difference: return g * a + f * std::fabs(a - b);
    case MixOp::Darken: return g * a + f * std::min(a, b);
    case MixOp::Lighten: return g * a + f * std::max(a, b);
    case MixOp::Overlay:
      return a < 0.5f ? a * (g + 2.0f * f * b) : 1.0f - (g + 2.0f * f * (1.0f - b)) * (1.0f - a);
  }
  return a;
}

inline float sat(float x) { return clampf(x, 0.0f, 1.0f); }

Vec3 normal_or(const Float4* r, int16_t reg, Vec3 fallback) {
  if (reg == kNoReg) return fallback;
  const Vec3 n = r[reg].xyz();
  const float l2 = length_sq(n);
  return l2 > 1e-12f && std::isfinite(l2) ? n / std::sqrt(l2) : fallback;
}

float roughness_to_alpha(float r) {
  r = sat(std::isfinite(r) ? r : 0.0f);
  return r * r;
}

float clean_ior(float ior) { return std::isfinite(ior) && ior > 1e-3f ? ior : 1.0f; }

Vec3 clean_color(Vec3 c) {
  auto f = [](float x) { return std::isfinite(x) && x > 0.0f ? x : 0.0f; };
  return {f(c.x), f(c.y), f(c.z)};
}

}  // namespace

Float4 sample_image(const Image& img, float u, float v, Interp interp, Extension ext) {
  if (img.w <= 0 || img.h <= 0 || !std::isfinite(u) || !std::isfinite(v)) return {};
  if (ext == Extension::Clip && (u < 0.0f || u > 1.0f || v < 0.0f || v > 1.0f)) return {};
  auto fetch = [&](int x, int y) -> const Float4& {
    if (ext == Extension::Repeat) {
      x = wrap(x, img.w);
      y = wrap(y, img.h);
    } else {
      x = std::clamp(x, 0, img.w - 1);
      y = std::clamp(y, 0, img.h - 1);
    }
    return img.px[size_t(y) * size_t(img.w) + size_t(x)];
  };
  // Keep coordinates in a range where float->int is exact (Repeat is periodic anyway).
  if (ext == Extension::Repeat) {
    u -= std::floor(u);
    v -= std::floor(v);
  } else {
    u = clampf(u, -1.0f, 2.0f);
    v = clampf(v, -1.0f, 2.0f);
  }
  const float fx = u * img.w, fy = v * img.h;
  if (interp == Interp::Closest) return fetch(int(std::floor(fx)), int(std::floor(fy)));
  const float x = fx - 0.5f, y = fy - 0.5f;
  const int x0 = int(std::floor(x)), y0 = int(std::floor(y));
  const float tx = x - x0, ty = y - y0;
  return lerp4(lerp4(fetch(x0, y0), fetch(x0 + 1, y0), tx), lerp4(fetch(x0, y0 + 1), fetch(x0 + 1, y0 + 1), tx), ty);
}

float srgb_to_linear(float c) {
  // Cycles' color_srgb_to_linear (negative values clamp to 0).
  if (c < 0.04045f) return c < 0.0f ? 0.0f : c * (1.0f / 12.92f);
  return std::pow((c + 0.055f) * (1.0f / 1.055f), 2.4f);
}

Float4 image_lookup(const Image& img, float u, float v, Interp interp, Extension ext, bool unassociate) {
  Float4 r = sample_image(img, u, v, interp, ext);
  if (unassociate && r.w != 1.0f && r.w != 0.0f) {
    const float inv = 1.0f / r.w;
    r = {r.x * inv, r.y * inv, r.z * inv, r.w};
  }
  if (img.srgb) r = {srgb_to_linear(r.x), srgb_to_linear(r.y), srgb_to_linear(r.z), r.w};
  return r;
}

void eval_shader(const ShaderProgram& prog, const std::vector<Image>& images, const ShadingContext& ctx,
                 ClosureList& out) {
  Float4 r[kMaxRegs];
  out.n = 0;
  out.emission = Vec3(0.0f);
  auto reg = [&](int16_t i) -> const Float4& {
    static const Float4 zero{};
    return i == kNoReg ? zero : r[i];
  };
  // Closure frames as Cycles sets them up: glossy lobes get a normal whose mirror reflection of
  // the view stays above the surface; diffuse lobes with a bent normal get the bump shadowing.
  auto glossy_frame = [&](int16_t normal_reg) {
    return Frame::from_normal(valid_specular_normal(ctx.ng, ctx.wo, normal_or(r, normal_reg, ctx.ns)));
  };
  auto diffuse_lobe = [&](int16_t normal_reg, Frame& f) {
    const Vec3 n = normal_or(r, normal_reg, ctx.ns);
    f = Frame::from_normal(n);
    DiffuseBsdf d;
    if (n.x != ctx.ns.x || n.y != ctx.ns.y || n.z != ctx.ns.z) {
      d.bent = true;
      d.ns = f.to_local(ctx.ns);
    }
    return d;
  };
  // Closure inputs: an omitted register means the input's default.
  auto col = [&](int16_t i) { return i == kNoReg ? Vec3(1.0f) : r[i].xyz(); };
  auto val = [&](int16_t i, float def) { return i == kNoReg ? def : r[i].x; };
  for (const ShaderOp& op : prog.ops) {
    Float4& d = r[op.dst];
    switch (op.code) {
      case OpCode::Const: d = op.value; break;
      case OpCode::Uv: {
        const bool ok = op.index >= 0 && op.index < ctx.uv_sets && ctx.uv;
        const Vec2 uv = ok ? ctx.uv[op.index] : Vec2{};
        d = {uv.x, uv.y, 0.0f, 0.0f};
        break;
      }
      case OpCode::Position: d = f4(ctx.p); break;
      case OpCode::Normal: d = f4(ctx.ns, 0.0f); break;
      case OpCode::Mapping: {
        const Float4 s = reg(op.in[0]);
        d = {op.m[0] * s.x + op.m[1] * s.y + op.m[2] * s.z + op.m[3],
             op.m[4] * s.x + op.m[5] * s.y + op.m[6] * s.z + op.m[7],
             op.m[8] * s.x + op.m[9] * s.y + op.m[10] * s.z + op.m[11], s.w};
        break;
      }
      case OpCode::ImageTex: {
        const Float4 s = reg(op.in[0]);
        d = op.index >= 0 && size_t(op.index) < images.size()
                ? image_lookup(images[size_t(op.index)], s.x, s.y, Interp(op.sub), Extension(op.ext), op.clamp)
                : Float4{1.0f, 0.0f, 1.0f, 1.0f};  // Blender's "missing texture" magenta
        break;
      }
      case OpCode::Math: {
        float v = math_op(MathOp(op.sub), reg(op.in[0]).x, reg(op.in[1]).x);
        if (!std::isfinite(v)) v = 0.0f;
        if (op.clamp) v = sat(v);
        d = {v, v, v, 1.0f};
        break;
      }
      case OpCode::Mix: {
        const float f = sat(reg(op.in[0]).x);
        const Float4 a = reg(op.in[1]), b = reg(op.in[2]);
        Float4 o{mix_channel(MixOp(op.sub), a.x, b.x, f), mix_channel(MixOp(op.sub), a.y, b.y, f),
                 mix_channel(MixOp(op.sub), a.z, b.z, f), a.w};
        if (op.clamp) o = {sat(o.x), sat(o.y), sat(o.z), o.w};
        d = o;
        break;
      }
      case OpCode::RgbToBw: {
        const float l = luminance(reg(op.in[0]).xyz());
        d = {l, l, l, 1.0f};
        break;
      }
      case OpCode::NormalMap: {
        const Vec3 c = reg(op.in[0]).xyz();
        const float strength = op.in[1] == kNoReg ? 1.0f : reg(op.in[1]).x;
        Vec3 n = ctx.ns;
        const bool ok = op.index >= 0 && op.index < ctx.uv_sets && ctx.tangents;
        if (ok) {
          Vec3 t = ctx.tangents[op.index];
          t = t - n * dot(t, n);
          const float l2 = length_sq(t);
          if (l2 > 1e-12f) {
            t = t / std::sqrt(l2);
            const Vec3 b = cross(n, t) * ctx.tangent_signs[op.index];
            const Vec3 ts = c * 2.0f - Vec3(1.0f);
            const Vec3 mapped = t * ts.x + b * ts.y + n * ts.z;
            const Vec3 blended = ctx.ns + (mapped - ctx.ns) * (std::isfinite(strength) ? std::max(strength, 0.0f) : 0.0f);
            if (length_sq(blended) > 1e-12f) n = normalize(blended);
          }
        }
        d = f4(n, 0.0f);
        break;
      }
      case OpCode::Diffuse: {
        Frame f;
        const DiffuseBsdf d = diffuse_lobe(op.in[2], f);
        out.add(d, clean_color(col(op.in[0]) * col(op.in[1])), f);
        break;
      }
      case OpCode::Glossy:
        out.add(ConductorBsdf{roughness_to_alpha(val(op.in[2], 0.5f)), Vec3(1.0f), false},
                clean_color(col(op.in[0]) * col(op.in[1])), glossy_frame(op.in[3]));
        break;
      case OpCode::Glass:
      case OpCode::Refraction: {
        DielectricBsdf b;
        b.alpha = roughness_to_alpha(val(op.in[2], 0.0f));
        b.eta = clean_ior(val(op.in[3], 1.5f));
        b.schlick = prog.schlick;
        if (op.code == OpCode::Refraction) {
          b.reflection = false;
          b.fresnel_on_transmission = false;
        }
        out.add(b, clean_color(col(op.in[0]) * col(op.in[1])), glossy_frame(op.in[4]));
        break;
      }
      case OpCode::Transparent:
        out.add(TransparentBsdf{}, clean_color(col(op.in[0]) * col(op.in[1])), Frame::from_normal(ctx.ns));
        break;
      case OpCode::Emission:
        out.emission += clean_color(col(op.in[0]) * col(op.in[1]));
        break;
      case OpCode::Principled: {
        // A layered approximation of Blender's Principled BSDF: metal | (glass | (dielectric
        // specular over diffuse)), the diffuse base keeping what the specular layer lets through.
        const Vec3 w = clean_color(col(op.in[0]));
        const Vec3 base = op.in[1] == kNoReg ? Vec3(0.8f) : clean_color(r[op.in[1]].xyz());
        const float metallic = sat(val(op.in[2], 0.0f));
        const float alpha = roughness_to_alpha(val(op.in[3], 0.5f));
        const float ior = clean_ior(val(op.in[4], 1.5f));
        const float transmission = sat(val(op.in[5], 0.0f));
        const float spec_level = std::isfinite(val(op.in[6], 0.5f)) ? std::max(0.0f, val(op.in[6], 0.5f)) : 0.5f;
        const Vec3 spec_tint = clean_color(col(op.in[7]));
        const Frame fr = glossy_frame(op.in[8]);  // Cycles' valid_reflection_N
        Frame fd;
        const DiffuseBsdf diffuse = diffuse_lobe(op.in[8], fd);
        if (metallic > 0.0f) out.add(ConductorBsdf{alpha, vmin(base, Vec3(1.0f)), true}, w * metallic, fr);
        const float dielectric = 1.0f - metallic;
        if (dielectric * transmission > 0.0f) {
          // As Cycles: the reflection stays untinted, refracted light takes sqrt(base) at each
          // crossing (base colour once through a closed object).
          DielectricBsdf g;
          g.alpha = alpha;
          g.eta = ior;
          g.schlick = prog.schlick;
          g.transmission_tint = {std::sqrt(base.x), std::sqrt(base.y), std::sqrt(base.z)};
          out.add(g, w * (dielectric * transmission), fr);
        }
        const float opaque = dielectric * (1.0f - transmission);
        if (opaque > 0.0f) {
          // Specular IOR Level scales F0; 0.5 keeps the IOR's own reflectance.
          const float r0 = (ior - 1.0f) / (ior + 1.0f);
          const float f0 = std::min(0.999f, r0 * r0 * 2.0f * spec_level);
          float reflected = 0.0f;
          if (f0 > 0.0f) {
            const float s = std::sqrt(f0);
            DielectricBsdf spec;
            spec.alpha = alpha;
            spec.eta = (1.0f + s) / (1.0f - s);
            spec.transmission = false;
            spec.schlick = prog.schlick;
            out.add(spec, w * spec_tint * opaque, fr);
            reflected = fresnel_dielectric(std::fabs(dot(fr.n, ctx.wo)), spec.eta);
          }
          out.add(diffuse, w * base * (opaque * (1.0f - reflected)), fd);
        }
        break;
      }
    }
  }
  out.finalize();
}

}  // namespace pl
