#include "scene/shader.h"
#include "scene/shader_math.h"

#include "scene/bssrdf.h"

#include "scene/camera.h"
#include "scene/tex_gabor.h"
#include "scene/tex_noise.h"
#include "scene/tex_patterns.h"
#include "scene/vector_nodes.h"

namespace pl {

using namespace shader_math;  // this unit's helpers (shader_math.h is included by it alone)

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

ObjectCoords make_object_coords(const Mat4& to_world, Vec3 loc, Vec3 size) {
  ObjectCoords oc;
  oc.to_world = to_world;
  // Inverse of the affine 3x4 part: adjugate / determinant, then the translation.
  const float(&m)[4][4] = to_world.m;
  const Vec3 c0{m[0][0], m[1][0], m[2][0]}, c1{m[0][1], m[1][1], m[2][1]}, c2{m[0][2], m[1][2], m[2][2]};
  const Vec3 r0 = cross(c1, c2), r1 = cross(c2, c0), r2 = cross(c0, c1);
  const float det = dot(c0, r0);
  if (!(std::fabs(det) > 1e-30f) || !std::isfinite(det)) return oc;
  const Vec3 rows[3] = {r0 / det, r1 / det, r2 / det};  // rows of the inverse 3x3
  const Vec3 t{m[0][3], m[1][3], m[2][3]};
  for (int i = 0; i < 3; ++i) {
    oc.to_object.m[i][0] = rows[i].x;
    oc.to_object.m[i][1] = rows[i].y;
    oc.to_object.m[i][2] = rows[i].z;
    oc.to_object.m[i][3] = -dot(rows[i], t);
  }
  auto axis = [](float l, float sz, float& scale, float& offset) {
    scale = sz != 0.0f && std::isfinite(sz) ? 0.5f / sz : 0.0f;
    offset = 0.5f - (std::isfinite(l) ? l : 0.0f) * scale;
  };
  axis(loc.x, size.x, oc.gen_scale.x, oc.gen_offset.x);
  axis(loc.y, size.y, oc.gen_scale.y, oc.gen_offset.y);
  axis(loc.z, size.z, oc.gen_scale.z, oc.gen_offset.z);
  oc.valid = oc.to_object.is_finite();
  return oc;
}

void auto_texspace(const std::vector<Vec3>& positions, Vec3& location, Vec3& size) {
  Vec3 lo(-1.0f), hi(1.0f);  // Blender's fallback for an empty mesh
  bool any = false;
  for (const Vec3& p : positions) {
    if (!is_finite(p)) continue;
    lo = any ? vmin(lo, p) : p;
    hi = any ? vmax(hi, p) : p;
    any = true;
  }
  location = (lo + hi) * 0.5f;
  size = (hi - lo) * 0.5f;
  auto fix = [](float& x) {  // BKE_mesh_texspace_calc's guards against flat boxes
    if (x == 0.0f) x = 1.0f;
    else if (x > 0.0f && x < 1e-5f) x = 1e-5f;
  };
  fix(size.x);
  fix(size.y);
  fix(size.z);
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
  out.holdout = Vec3(0.0f);
  auto reg = [&](int16_t i) -> const Float4& {
    static const Float4 zero{};
    return i == kNoReg ? zero : r[i];
  };
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
    if (n.x != ctx.ns.x || n.y != ctx.ns.y || n.z != ctx.ns.z) {
      d.bent = true;
      d.ns = f.to_local(ctx.ns);
      d.back = dot(ctx.ng, ctx.wo) < 0.0f;
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
  // The Bump node's offsets (made on first use): small steps along the triangle's two edges
  // from the shading point, as barycentric steps (for uvs) and world vectors. Their length is
  // tiny against the scene but far above float rounding at the point's magnitude.
  bool offsets_made = false;
  Vec3 dp[3] = {Vec3(0.0f), Vec3(0.0f), Vec3(0.0f)};
  float db[3][2] = {{0.0f, 0.0f}, {0.0f, 0.0f}, {0.0f, 0.0f}};
  auto make_offsets = [&]() {
    if (offsets_made) return;
    offsets_made = true;
    if (!ctx.tri) return;
    const Vec3 e1 = ctx.tri[1] - ctx.tri[0], e2 = ctx.tri[2] - ctx.tri[0];
    // Cycles' bump offsets: Filter Width times the ray's footprint at the point, along the
    // make_orthonormals axes of the view-facing normal (differential_from_compact), with the
    // barycentric steps that move the same way in the triangle's plane.
    const float fp = ctx.ray.footprint() * prog.bump_filter_width;
    if (fp > 0.0f && std::isfinite(fp)) {
      const Vec3 ng = dot(ctx.ng, ctx.wo) < 0.0f ? -ctx.ng : ctx.ng;
      Vec3 a = (ng.x != ng.y || ng.x != ng.z) ? Vec3{ng.z - ng.y, ng.x - ng.z, ng.y - ng.x}
                                              : Vec3{ng.z - ng.y, ng.x + ng.z, -ng.y - ng.x};
      a = normalize(a);
      const Vec3 axes[2] = {a * fp, cross(ng, a) * fp};
      const float g11 = dot(e1, e1), g12 = dot(e1, e2), g22 = dot(e2, e2);
      const float det = g11 * g22 - g12 * g12;
      if (det > 0.0f && std::isfinite(det) && is_finite(axes[0]) && is_finite(axes[1])) {
        for (int k = 0; k < 2; ++k) {
          const float r1 = dot(e1, axes[k]), r2 = dot(e2, axes[k]);
          db[1 + k][0] = (g22 * r1 - g12 * r2) / det;
          db[1 + k][1] = (g11 * r2 - g12 * r1) / det;
          dp[1 + k] = axes[k];
        }
        return;
      }
    }
    const float step = 1e-4f * (1.0f + max_component(vabs(ctx.p)));
    const float l1 = length(e1), l2 = length(e2);
    if (!(l1 > 0.0f) || !(l2 > 0.0f) || !std::isfinite(l1 * l2) || !std::isfinite(step)) return;
    db[kOffsetX][0] = step / l1;
    db[kOffsetY][1] = step / l2;
    dp[kOffsetX] = e1 * db[kOffsetX][0];
    dp[kOffsetY] = e2 * db[kOffsetY][1];
  };
  const ShaderOp* extra = nullptr;  // the PrincipledExtra op before a Principled op, if any
  for (const ShaderOp& op : prog.ops) {
    Float4& d = r[op.dst];
    switch (op.code) {
      case OpCode::Const: d = op.value; break;
      case OpCode::Uv: {
        const bool ok = op.index >= 0 && op.index < ctx.uv_sets && ctx.uv;
        Vec2 uv = ok ? ctx.uv[op.index] : Vec2{};
        if (ok && op.sub != kAtPoint && op.sub < 3 && ctx.tri_uv) {
          make_offsets();
          const Vec2* t = ctx.tri_uv + 3 * op.index;
          const float s1 = db[op.sub][0], s2 = db[op.sub][1];
          uv = {uv.x + (t[1].x - t[0].x) * s1 + (t[2].x - t[0].x) * s2,
                uv.y + (t[1].y - t[0].y) * s1 + (t[2].y - t[0].y) * s2};
        }
        d = {uv.x, uv.y, 0.0f, 0.0f};
        break;
      }
      case OpCode::Position: {
        if (op.sub != kAtPoint && op.sub < 3) make_offsets();
        d = f4(ctx.p + (op.sub < 3 ? dp[op.sub] : Vec3(0.0f)));
        break;
      }
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
        float v = math_op(MathOp(op.sub), reg(op.in[0]).x, reg(op.in[1]).x, reg(op.in[2]).x);
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
      case OpCode::ObjectPos:
      case OpCode::Generated: {
        if (op.sub != kAtPoint && op.sub < 3) make_offsets();
        const Vec3 p = ctx.p + (op.sub < 3 ? dp[op.sub] : Vec3(0.0f));
        if (!ctx.object || !ctx.object->valid) {
          d = f4(p);  // no object space known: world coordinates
          break;
        }
        const Vec3 o = ctx.object->to_object.point(p);
        d = f4(op.code == OpCode::ObjectPos ? o : o * ctx.object->gen_scale + ctx.object->gen_offset);
        break;
      }
      case OpCode::LightPath: {
        // Cycles' svm_node_light_path: the ray's kind (flags) and its bounce counts.
        const RayState& ray = ctx.ray;
        static constexpr uint8_t kFlagOf[] = {kRayCamera, kRayShadow, kRayDiffuse, kRayGlossy,
                                              kRaySingular, kRayReflect, kRayTransmit};
        float v = 0.0f;
        if (op.sub < 7) v = (ray.flags & kFlagOf[op.sub]) ? 1.0f : 0.0f;
        else if (op.sub == 7) v = (ray.flags & kRayVolume) ? 1.0f : 0.0f;  // Is Volume Scatter Ray
        else if (op.sub == 8) v = ray.length;
        else {
          const uint16_t counts[] = {ray.depth, ray.diffuse, ray.glossy, ray.transparent, ray.transmission};
          v = float(counts[std::min(op.sub - 9, 4)]);
        }
        d = {v, v, v, 1.0f};
        break;
      }
      case OpCode::CurvesInfo: {
        // Cycles' svm_node_hair_info: zeros off curves.
        const CurveShading* cs = ctx.curve;
        if (op.sub == 4) {
          d = f4(cs ? cs->tangent_normal : Vec3(0.0f), 0.0f);
        } else {
          const float v = !cs ? 0.0f
                          : op.sub == 0 ? 1.0f
                          : op.sub == 1 ? cs->intercept
                          : op.sub == 2 ? cs->length
                          : op.sub == 3 ? cs->thickness
                                        : cs->random;
          d = {v, v, v, 1.0f};
        }
        break;
      }
      case OpCode::ObjectInfo: {
        // Cycles' svm_node_object_info: the hit instance's location, colour, alpha, pass index
        // and random number (Material Index is a constant of the material, folded by the add-on).
        static const ObjectInfo none;
        const ObjectInfo& info = ctx.object ? ctx.object->info : none;
        switch (op.sub) {
          case 0: d = f4(ctx.object ? ctx.object->to_world.point(Vec3(0.0f)) : Vec3(0.0f), 0.0f); break;
          case 1: d = {info.color.x, info.color.y, info.color.z, 1.0f}; break;
          default: {
            const float v = op.sub == 2 ? info.color.w : op.sub == 3 ? info.pass_index : info.random;
            d = {v, v, v, 1.0f};
          }
        }
        break;
      }
      case OpCode::Geometry: {
        // Cycles' svm_node_geometry: its normals face the viewer (back faces flipped).
        const bool backfacing = dot(ctx.ng, ctx.wo) < 0.0f;
        switch (op.sub) {
          case 0: d = f4(backfacing ? -ctx.ng : ctx.ng, 0.0f); break;  // True Normal
          case 1: d = f4(ctx.wo, 0.0f); break;                           // Incoming
          case 2: d = {1.0f - ctx.b1 - ctx.b2, ctx.b1, 0.0f, 0.0f}; break;  // Parametric
          case 3: {                                                       // Backfacing
            const float v = backfacing ? 1.0f : 0.0f;
            d = {v, v, v, 1.0f};
            break;
          }
          default: {  // Texture Coordinate's Reflection: the view mirrored about the normal
            const Vec3 n = backfacing ? -ctx.ns : ctx.ns;
            d = f4(n * (2.0f * dot(n, ctx.wo)) - ctx.wo, 0.0f);
          }
        }
        break;
      }
      case OpCode::Attribute: {
        // Cycles' svm_node_attr of a mesh attribute: Color/Vector (RGB with alpha), Fac (the
        // mean of RGB), Alpha; a missing attribute reads 0.
        const Float4 a = op.index >= 0 && op.index < ctx.attr_sets && ctx.attrs ? ctx.attrs[op.index] : Float4{};
        if (op.sub == 0) {
          d = a;
        } else {
          const float v = op.sub == 1 ? (a.x + a.y + a.z) * (1.0f / 3.0f) : a.w;
          d = {v, v, v, 1.0f};
        }
        break;
      }
      case OpCode::ObjectNormal: {
        Vec3 n = ctx.ns;
        if (ctx.object && ctx.object->valid) {
          const float(&m)[4][4] = ctx.object->to_world.m;  // transpose: n_obj ~ M^T n_world
          const Vec3 t{m[0][0] * n.x + m[1][0] * n.y + m[2][0] * n.z, m[0][1] * n.x + m[1][1] * n.y + m[2][1] * n.z,
                       m[0][2] * n.x + m[1][2] * n.y + m[2][2] * n.z};
          if (length_sq(t) > 1e-30f && is_finite(t)) n = normalize(t);
        }
        d = f4(n, 0.0f);
        break;
      }
      case OpCode::Fresnel:
      case OpCode::LayerWeight: {
        // Cycles' nodes: the view against the (unnormalised, as Cycles) input or shading normal.
        const Vec3 n = op.in[1] == kNoReg ? ctx.ns : r[op.in[1]].xyz();
        const bool backfacing = dot(ctx.ng, ctx.wo) < 0.0f;
        const float c = dot(ctx.wo, n);
        const float x = reg(op.in[0]).x;
        float f;
        if (op.code == OpCode::Fresnel) {
          float eta = std::max(std::isfinite(x) ? x : 1.0f, 1e-5f);
          f = fresnel_node(c, backfacing ? 1.0f / eta : eta);
        } else if (op.sub == 0) {  // Fresnel output
          const float eta = std::max(1.0f - (std::isfinite(x) ? x : 0.0f), 1e-5f);
          f = fresnel_node(c, backfacing ? eta : 1.0f / eta);
        } else {  // Facing output
          f = std::fabs(c);
          float blend = std::isfinite(x) ? x : 0.5f;
          if (blend != 0.5f) {
            blend = clampf(blend, 0.0f, 1.0f - 1e-5f);
            blend = blend < 0.5f ? 2.0f * blend : 0.5f / (1.0f - blend);
            f = std::pow(f, blend);
          }
          f = 1.0f - f;
        }
        if (!std::isfinite(f)) f = 0.0f;
        d = {f, f, f, 1.0f};
        break;
      }
      case OpCode::Bump: {
        // Cycles' svm_node_set_bump with the height at the point and at the two offsets.
        make_offsets();
        const bool backfacing = dot(ctx.ng, ctx.wo) < 0.0f;
        const float side = backfacing ? -1.0f : 1.0f;  // Cycles flips N towards the viewer
        const Vec3 n_in = normal_or(r, op.in[5], ctx.ns) * side;
        const Vec3 rx = cross(dp[kOffsetY], n_in), ry = cross(n_in, dp[kOffsetX]);
        const float hc = reg(op.in[0]).x, hx = reg(op.in[1]).x, hy = reg(op.in[2]).x;
        const float det = dot(dp[kOffsetX], rx);
        const Vec3 surfgrad = rx * (hx - hc) + ry * (hy - hc);
        float strength = op.in[3] == kNoReg ? 1.0f : reg(op.in[3]).x;
        float distance = op.in[4] == kNoReg ? 1.0f : reg(op.in[4]).x;
        if (op.clamp) distance = -distance;  // Invert
        strength = std::isfinite(strength) ? std::max(strength, 0.0f) : 0.0f;
        Vec3 out_n = n_in;
        const Vec3 raw = n_in * std::fabs(det) - surfgrad * (distance * sign_of(det));
        const float l2 = length_sq(raw);
        if (l2 > 0.0f && std::isfinite(l2)) {
          const Vec3 blended = raw / std::sqrt(l2) * strength + n_in * (1.0f - strength);
          if (length_sq(blended) > 1e-20f && is_finite(blended)) out_n = normalize(blended);
        }
        d = f4(out_n * side, 0.0f);
        break;
      }
      case OpCode::Ramp: {
        const Float4 s = reg(op.in[0]);
        const Float4* table = prog.tables.data() + op.index;
        const bool interpolate = op.sub & 1, extrapolate = op.sub & 2, channels = op.sub & 4;
        const float lo = op.m[0], range = op.m[1] - op.m[0];
        auto rel = [&](float v) { return range != 0.0f ? (v - lo) / range : 0.0f; };
        if (channels) {  // RGB Curves: each channel through its own column
          d = {ramp_lookup(table, op.count, rel(s.x), interpolate, extrapolate).x,
               ramp_lookup(table, op.count, rel(s.y), interpolate, extrapolate).y,
               ramp_lookup(table, op.count, rel(s.z), interpolate, extrapolate).z, 1.0f};
        } else {
          d = ramp_lookup(table, op.count, rel(s.x), interpolate, extrapolate);
        }
        break;
      }
      case OpCode::Component: {
        const Float4 s = reg(op.in[0]);
        const float v = op.sub == 0 ? s.x : op.sub == 1 ? s.y : s.z;
        d = {v, v, v, 1.0f};
        break;
      }
      case OpCode::Combine:
        d = {reg(op.in[0]).x, reg(op.in[1]).x, reg(op.in[2]).x, op.sub ? 1.0f : 0.0f};
        break;
      case OpCode::ColorSpace: {
        const Float4 s = reg(op.in[0]);
        Vec3 c = s.xyz();
        switch (ColorSpaceOp(op.sub)) {
          case ColorSpaceOp::RgbToHsv: c = rgb_to_hsv(c); break;
          case ColorSpaceOp::HsvToRgb: c = hsv_to_rgb(c); break;
          case ColorSpaceOp::RgbToHsl: c = rgb_to_hsl(c); break;
          case ColorSpaceOp::HslToRgb: c = hsl_to_rgb(c); break;
        }
        d = f4(c, s.w);
        break;
      }
      case OpCode::Hsv: {  // Cycles' svm_node_hsv
        const Vec3 in = reg(op.in[0]).xyz();
        Vec3 c = rgb_to_hsv(in);
        const float hue = reg(op.in[1]).x, saturation = reg(op.in[2]).x, value = reg(op.in[3]).x;
        const float fac = reg(op.in[4]).x;
        const float h = c.x + hue + 0.5f;
        c = {h - std::floor(h), sat(c.y * saturation), c.z * value};
        c = hsv_to_rgb(c);
        c = c * fac + in * (1.0f - fac);
        d = f4(vmax(c, Vec3(0.0f)), 1.0f);
        break;
      }
      case OpCode::Gamma: {  // Cycles' svm_math_gamma_color
        const Vec3 c = reg(op.in[0]).xyz();
        const float g = reg(op.in[1]).x;
        auto pw = [&](float x) { return x > 0.0f ? std::pow(x, g) : x; };
        const Vec3 o = g == 0.0f ? Vec3(1.0f) : Vec3{pw(c.x), pw(c.y), pw(c.z)};
        d = f4(is_finite(o) ? o : Vec3(0.0f), 1.0f);
        break;
      }
      case OpCode::BrightContrast: {  // Cycles' svm_brightness_contrast
        const Vec3 c = reg(op.in[0]).xyz();
        const float contrast = reg(op.in[2]).x;
        const float a = 1.0f + contrast, b = reg(op.in[1]).x - contrast * 0.5f;
        d = f4(vmax(c * a + Vec3(b), Vec3(0.0f)), 1.0f);
        break;
      }
      case OpCode::Clamp: {
        float lo = reg(op.in[1]).x, hi = reg(op.in[2]).x;
        if (op.sub == 1 && lo > hi) std::swap(lo, hi);  // Range: either order
        const float v = std::min(std::max(reg(op.in[0]).x, lo), hi);
        d = {v, v, v, 1.0f};
        break;
      }
      case OpCode::MapRange:
        if (op.ext == 1) {  // Cycles' svm_node_vector_map_range: per component, safe division
          const Vec3 v = reg(op.in[0]).xyz(), f0 = reg(op.in[1]).xyz(), f1 = reg(op.in[2]).xyz();
          const Vec3 t0 = reg(op.in[3]).xyz(), t1 = reg(op.in[4]).xyz(), steps = reg(op.in[5]).xyz();
          const MapRangeOp mode = MapRangeOp(op.sub);
          auto one = [&](float x, float a, float b, float c, float e, float n) {
            float f = safe_div(x - a, b - a);
            switch (mode) {
              case MapRangeOp::Linear: break;
              case MapRangeOp::Stepped: f = n > 0.0f ? std::floor(f * (n + 1.0f)) / n : 0.0f; break;
              case MapRangeOp::SmoothStep: f = sat(f); f = (3.0f - 2.0f * f) * (f * f); break;
              case MapRangeOp::SmootherStep: f = sat(f); f = f * f * f * (f * (f * 6.0f - 15.0f) + 10.0f); break;
            }
            float res = c + f * (e - c);
            if (op.clamp && (mode == MapRangeOp::Linear || mode == MapRangeOp::Stepped))
              res = c > e ? clampf(res, e, c) : clampf(res, c, e);
            return std::isfinite(res) ? res : 0.0f;
          };
          d = {one(v.x, f0.x, f1.x, t0.x, t1.x, steps.x), one(v.y, f0.y, f1.y, t0.y, t1.y, steps.y),
               one(v.z, f0.z, f1.z, t0.z, t1.z, steps.z), 0.0f};
          break;
        }
        {  // Cycles' svm_node_map_range (float)
        const float v = reg(op.in[0]).x, f0 = reg(op.in[1]).x, f1 = reg(op.in[2]).x;
        const float t0 = reg(op.in[3]).x, t1 = reg(op.in[4]).x, steps = reg(op.in[5]).x;
        float res = 0.0f;
        if (f1 != f0) {
          float factor = v;
          switch (MapRangeOp(op.sub)) {
            case MapRangeOp::Linear: factor = (v - f0) / (f1 - f0); break;
            case MapRangeOp::Stepped:
              factor = (v - f0) / (f1 - f0);
              factor = steps > 0.0f ? std::floor(factor * (steps + 1.0f)) / steps : 0.0f;
              break;
            case MapRangeOp::SmoothStep:
              factor = f0 > f1 ? 1.0f - smoothstep(f1, f0, v) : smoothstep(f0, f1, v);
              break;
            case MapRangeOp::SmootherStep:
              factor = f0 > f1 ? 1.0f - smootherstep(f1, f0, v) : smootherstep(f0, f1, v);
              break;
          }
          res = t0 + factor * (t1 - t0);
          // Blender clamps Linear and Stepped results to the target range (a Clamp node in Cycles).
          if (op.clamp && (MapRangeOp(op.sub) == MapRangeOp::Linear || MapRangeOp(op.sub) == MapRangeOp::Stepped))
            res = std::min(std::max(res, std::min(t0, t1)), std::max(t0, t1));
        }
        if (!std::isfinite(res)) res = 0.0f;
        d = {res, res, res, 1.0f};
        break;
      }
      case OpCode::VectorMath: {
        float value = 0.0f;
        bool is_value = false;
        Vec3 v = vector_math(VectorMathOp(op.sub), reg(op.in[0]).xyz(), reg(op.in[1]).xyz(), reg(op.in[2]).xyz(),
                             op.in[3] == kNoReg ? 1.0f : reg(op.in[3]).x, value, is_value);
        if (is_value) {
          if (!std::isfinite(value)) value = 0.0f;
          d = {value, value, value, 1.0f};
        } else {
          if (!is_finite(v)) v = Vec3(0.0f);
          d = f4(v, 0.0f);
        }
        break;
      }
      case OpCode::TexNoise: {
        NoiseInputs in;
        in.co = reg(op.in[0]).xyz();
        in.w = reg(op.in[1]).x;
        in.scale = reg(op.in[2]).x;
        in.detail = reg(op.in[3]).x;
        in.roughness = reg(op.in[4]).x;
        in.lacunarity = reg(op.in[5]).x;
        in.offset = reg(op.in[6]).x;
        in.gain = reg(op.in[7]).x;
        in.distortion = reg(op.in[8]).x;
        d = f4(noise_texture(op.sub, NoiseType(op.ext), op.clamp, op.index != 0, in));
        break;
      }
      case OpCode::TexWave: {
        const float f = wave_texture(op.sub, op.ext, op.index, reg(op.in[0]).xyz(), reg(op.in[1]).x, reg(op.in[2]).x,
                                     reg(op.in[3]).x, reg(op.in[4]).x, reg(op.in[5]).x, reg(op.in[6]).x);
        d = {f, f, f, 1.0f};
        break;
      }
      case OpCode::TexMagic: {
        const Vec3 c = magic_texture(reg(op.in[0]).xyz(), reg(op.in[1]).x, op.sub, reg(op.in[2]).x);
        const float fac = (c.x + c.y + c.z) * (1.0f / 3.0f);  // Cycles' average()
        d = op.index != 0 ? f4(c) : Float4{fac, fac, fac, 1.0f};
        break;
      }
      case OpCode::TexWhiteNoise:
        d = f4(white_noise_texture(op.sub, op.index != 0, reg(op.in[0]).xyz(), reg(op.in[1]).x));
        break;
      case OpCode::Checker:
      case OpCode::Gradient:
      case OpCode::Brick:
      case OpCode::Voronoi:
        d = tex::eval_pattern_op(op, r);
        break;
      case OpCode::VectorRotate: {
        // in: vector, center, axis, angle, rotation; sub: the type; clamp: Invert.
        const Vec3 v = vector_rotate(op.sub, op.clamp, reg(op.in[0]).xyz(), reg(op.in[1]).xyz(), reg(op.in[2]).xyz(),
                                     reg(op.in[3]).x, reg(op.in[4]).xyz());
        d = f4(is_finite(v) ? v : Vec3(0.0f), 0.0f);
        break;
      }
      case OpCode::VectorTransform: {
        const Vec3 v = vector_transform(op.sub, op.index, op.count, reg(op.in[0]).xyz(), ctx.object, ctx.ray.camera);
        d = f4(is_finite(v) ? v : Vec3(0.0f), 0.0f);
        break;
      }
      case OpCode::Blackbody: d = f4(blackbody_color(reg(op.in[0]).x)); break;
      case OpCode::Wavelength: d = f4(wavelength_color(reg(op.in[0]).x)); break;
      case OpCode::CameraCoords: {
        // Texture Coordinate's Camera (sub 0) and Window (sub 1), at the point or a Bump offset.
        if (op.ext != kAtPoint && op.ext < 3) make_offsets();
        const Vec3 p = ctx.p + (op.ext < 3 ? dp[op.ext] : Vec3(0.0f));
        const Camera* cam = ctx.ray.camera;
        d = f4(op.sub == 0 ? world_to_camera_point(cam, p) : cam ? cam->to_ndc(p) : Vec3(0.0f), 0.0f);
        break;
      }
      case OpCode::Tangent: {
        // Cycles' svm_node_tangent: radial around an object axis (sub 0-2, from the generated
        // coordinates) or a UV map's (sub 3, uv set `index`), turned like a normal, then made
        // perpendicular to the shading normal.
        Vec3 t(0.0f);
        if (op.sub < 3) {
          Vec3 g = ctx.p;
          if (ctx.object && ctx.object->valid)
            g = ctx.object->to_object.point(ctx.p) * ctx.object->gen_scale + ctx.object->gen_offset;
          g = g - Vec3(0.5f);
          t = op.sub == 0 ? Vec3{0.0f, -g.z, g.y} : op.sub == 1 ? Vec3{-g.z, 0.0f, g.x} : Vec3{-g.y, g.x, 0.0f};
          t = object_to_world_normal(ctx.object, t);
        } else if (op.index >= 0 && op.index < ctx.uv_sets && ctx.tangents) {
          t = ctx.tangents[op.index];
        } else {
          d = Float4{};
          break;
        }
        const Vec3 n = ctx.ns;
        t = cross(n, normalize(cross(t, n)));
        d = f4(is_finite(t) ? t : Vec3(0.0f), 0.0f);
        break;
      }
      case OpCode::TexGabor: {
        // in: vector, scale, frequency, anisotropy, orientation 2D, 3D; ext: the output.
        const GaborOutput g = gabor_texture(op.sub, reg(op.in[0]).xyz(), reg(op.in[1]).x, reg(op.in[2]).x,
                                            reg(op.in[3]).x, reg(op.in[4]).x, reg(op.in[5]).xyz());
        float v = op.ext == 0 ? g.value : op.ext == 1 ? g.phase : g.intensity;
        if (!std::isfinite(v)) v = 0.0f;
        d = {v, v, v, 1.0f};
        break;
      }
      case OpCode::AmbientOcclusion: {
        // Cycles' svm_node_ao: in color, distance, normal; sub bit 0 Inside, bit 1 Only Local;
        // index the samples; ext the output (0 Color = AO * Color, 1 AO).
        const bool backfacing = dot(ctx.ng, ctx.wo) < 0.0f;
        Vec3 n = op.in[2] == kNoReg ? (backfacing ? -ctx.ns : ctx.ns) : r[op.in[2]].xyz();
        if (op.sub & 1) n = -n;
        const float dist = reg(op.in[1]).x;
        float ao = 1.0f;
        if (dist > 0.0f && op.index >= 1 && ctx.scene && length_sq(n) > 0.0f && is_finite(n))
          ao = trace_ambient_occlusion(ctx, normalize(n), std::isfinite(dist) ? dist : kInf, op.index, op.sub & 2);
        d = op.ext == 1 ? Float4{ao, ao, ao, 1.0f} : f4(reg(op.in[0]).xyz() * ao);
        break;
      }
      case OpCode::Bevel: {
        // Cycles' svm_node_bevel: in radius and (optional) normal; index the samples. A given
        // normal keeps its own bend: normalize(N_in + (bevel - N)).
        const float radius = reg(op.in[0]).x;
        Vec3 n = ctx.ns;
        if (ctx.scene && radius > 0.0f && std::isfinite(radius) && op.index >= 1) n = trace_bevel(ctx, radius, op.index);
        if (op.in[1] != kNoReg) {
          const Vec3 m = r[op.in[1]].xyz() + (n - ctx.ns);
          n = length_sq(m) > 0.0f && is_finite(m) ? normalize(m) : ctx.ns;
        }
        d = f4(n, 0.0f);
        break;
      }
      case OpCode::Wireframe: {
        // Cycles' svm_wireframe: 1 within Size / 2 of one of the triangle's edges, Size in
        // world units or (ext) in pixels at the point: the footprint's two tangent axes
        // (Cycles' make_orthonormals of the view-facing normal) projected across the view.
        float f = 0.0f;
        if (ctx.tri) {
          Vec3 p = ctx.p;
          if (op.sub != kAtPoint && op.sub < 3) {
            make_offsets();
            p += dp[op.sub];
          }
          float width = 1.0f;
          if (op.ext) {
            const Vec3 ng = dot(ctx.ng, ctx.wo) < 0.0f ? -ctx.ng : ctx.ng;
            Vec3 a = (ng.x != ng.y || ng.x != ng.z) ? Vec3{ng.z - ng.y, ng.x - ng.z, ng.y - ng.x}
                                                    : Vec3{ng.z - ng.y, ng.x + ng.z, -ng.y - ng.x};
            a = normalize(a);
            const Vec3 b = cross(ng, a);
            const float fp = ctx.ray.footprint();
            const float wa = length(a - ctx.wo * dot(a, ctx.wo)), wb = length(b - ctx.wo * dot(b, ctx.wo));
            width = fp * 0.5f * (wa + wb);
          }
          const float size = reg(op.in[0]).x;
          float w2 = 0.5f * size * width;
          w2 *= w2;
          for (int i = 0; i < 3; ++i) {
            const Vec3 edge = ctx.tri[i] - ctx.tri[i ? i - 1 : 2];
            const Vec3 c = cross(edge, p - ctx.tri[i]);
            if (dot(c, c) < dot(edge, edge) * w2) {  // squared distance to the edge's line
              f = 1.0f;
              break;
            }
          }
        }
        d = {f, f, f, 1.0f};
        break;
      }
      case OpCode::Diffuse: {
        Frame f;
        const DiffuseBsdf d = diffuse_lobe(op.in[2], f);
        const Vec3 w = clean_color(col(op.in[0]) * col(op.in[1]));
        // Roughness (in[3]): Cycles' Oren-Nayar from 1e-5 on, with the colour as its albedo.
        const float rough = val(op.in[3], 0.0f);
        if (rough >= 1e-5f) {
          OrenNayarBsdf o = OrenNayarBsdf::setup(rough, clean_color(col(op.in[1])), std::fabs(dot(f.n, ctx.wo)));
          o.ns = d.ns;
          o.bent = d.bent;
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
          const SheenBsdf sh = SheenBsdf::setup(rough, std::fabs(dot(f.n, ctx.wo)), albedo);
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
        const float rough = val(op.in[6], 0.3f) * fr, radial = val(op.in[7], 0.3f) * fr;
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
        HairChiangBsdf h = HairChiangBsdf::from_node(sigma, rough, radial, val(op.in[8], 0.0f), val(op.in[10], 0.0349066f),
                                                     std::isfinite(ior) && ior > 0.0f ? ior : 1.55f);
        out.add(h, clean_color(col(op.in[0])), Frame::from_normal(ctx.ns));
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
            const SheenBsdf sh = SheenBsdf::setup(sat(val(px(kPxSheenRoughness), 0.5f)),
                                                  std::fabs(dot(ns, ctx.wo)), albedo);
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
                           sss_ior, alpha, method, fr, ctx.ray.diffuse_ancestor);
          }
        }
        const Vec3 dw = ssw > 0.0f ? weight * base * (1.0f - ssw) : weight * base;
        if (px(kPxDiffuseRoughness) != kNoReg) {
          // Diffuse Roughness: Cycles' Oren-Nayar (from 1e-5 on) with the base colour as albedo.
          const float dr_in = val(px(kPxDiffuseRoughness), 0.0f);
          const float dr = std::isfinite(dr_in) ? sat(dr_in) : 0.0f;
          if (dr >= 1e-5f) {
            OrenNayarBsdf o = OrenNayarBsdf::setup(dr, base, std::fabs(dot(fd.n, ctx.wo)));
            o.ns = diffuse.ns;
            o.bent = diffuse.bent;
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
                       glossy_frame(op.in[7]), ctx.ray.diffuse_ancestor);
        break;
      }
    }
  }
  out.finalize();
}

}  // namespace pl
