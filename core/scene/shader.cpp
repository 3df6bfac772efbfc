// Shader program evaluation: the value ops (coordinates, textures, maths, colour) in registers,
// and the closure ops' closures from them (shader_closures.cpp).
#include "scene/shader.h"
#include "scene/phase.h"
#include "scene/shader_math.h"
#include "scene/shader_closures.h"

#include "scene/camera.h"
#include "scene/tex_gabor.h"
#include "scene/tex_noise.h"
#include "scene/tex_patterns.h"
#include "scene/vector_nodes.h"
#include "util/uninit.h"

namespace pl {

using namespace shader_math;  // this unit's helpers (shader_math.h is included by the shader units alone)

namespace {

// An Attribute node's output (Cycles' svm_node_attr): sub 0 Color / Vector (RGB with alpha),
// 1 Fac (the mean of RGB), 2 Alpha.
inline Float4 attribute_output(const Float4& a, uint8_t sub) {
  if (sub == 0) return a;
  const float v = sub == 1 ? (a.x + a.y + a.z) * (1.0f / 3.0f) : a.w;
  return {v, v, v, 1.0f};
}

// The Normal outputs (Geometry, Texture Coordinate): Cycles' sd->N, the shading normal turned
// to the viewer on a back-facing hit (shader_setup_from_ray), as every normal value of a
// program; the closures turn their Normal inputs back (normal_or).
inline Vec3 viewer_normal(const ShadingContext& ctx) { return ctx.ns * ctx.view_side(); }

// The program's evaluation. kSetsNormal: the program has a SetNormal op, which replaces the
// shading normal of `ctx` (then the caller's copy, `local`) for the ops after it, as Cycles'
// bump from displacement sets sd->N for the rest of the shader.
template <bool kSetsNormal>
[[gnu::always_inline]] inline void eval_program(const ShaderProgram& prog, const std::vector<Image>& images,
                                                const ShadingContext& ctx, ShadingContext* local, ClosureList& out,
                                                Float4* regs) {
  // Registers are written before they are read (the compiler's allocation); zeroed only where
  // the caller reads the file back.
  UninitArray<Float4, kMaxRegs> file;
  Float4* const r = file.data();
  if (regs) std::fill(r, r + kMaxRegs, Float4{});
  out.n = 0;
  out.emission = Vec3(0.0f);
  out.holdout = Vec3(0.0f);
  out.ns = Vec3(0.0f);
  auto reg = [&](int16_t i) -> const Float4& {
    static const Float4 zero{};
    return i == kNoReg ? zero : r[i];
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
  // The undisplaced surface's point at offset s (made already): the same barycentric step along
  // the undisplaced triangle, as Cycles' differentials of the undisplaced position attribute.
  auto undisplaced_at = [&](uint8_t s) {
    const Vec3* u = ctx.undisplaced;
    return s == kAtPoint || s >= 3 ? u[0] : u[0] + (u[2] - u[1]) * db[s][0] + (u[3] - u[1]) * db[s][1];
  };
  // Where Position and Object read it at a bump offset: Cycles' svm_node_tex_coord_bump_dx on
  // the undisplaced point steps along the displaced footprint's axes by the compact (mean)
  // length of the undisplaced differentials (the Bump op's gradient uses the full ones).
  auto undisplaced_bump_at = [&](uint8_t s) {
    const Vec3* u = ctx.undisplaced;
    if (s == kAtPoint || s >= 3) return u[0];
    const float len = 0.5f * (length(undisplaced_at(kOffsetX) - u[0]) + length(undisplaced_at(kOffsetY) - u[0]));
    const float l = length(dp[s]);
    return l > 0.0f ? u[0] + dp[s] * (len / l) : u[0];
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
        const uint8_t s = op.sub & 3;
        if (s != kAtPoint && s < 3) make_offsets();
        d = f4((op.sub & kUndisplaced) && ctx.undisplaced ? undisplaced_bump_at(s) : ctx.p + (s < 3 ? dp[s] : Vec3(0.0f)));
        break;
      }
      case OpCode::Normal: d = f4(viewer_normal(ctx), 0.0f); break;
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
                ? image_texture(images, size_t(op.index), s.x, s.y, Interp(op.sub), Extension(op.ext), op.clamp)
                : Float4{1.0f, 0.0f, 1.0f, 1.0f};  // Blender's "missing texture" magenta
        break;
      }
      case OpCode::ImageProj: {
        const Float4 s = reg(op.in[0]);
        const Vec3 c{(s.x - 0.5f) * 2.0f, (s.y - 0.5f) * 2.0f, (s.z - 0.5f) * 2.0f};  // texco_remap_square
        float u = 0.0f, w = 0.0f;
        if (op.sub == 0) {  // Cycles' map_to_sphere
          const float l = c.x * c.x + c.y * c.y + c.z * c.z;
          if (l > 0.0f) {
            u = c.x == 0.0f && c.y == 0.0f ? 0.0f : 0.5f - std::atan2(c.x, c.y) * (0.5f / kPi);
            w = 1.0f - std::acos(clampf(c.z / std::sqrt(l), -1.0f, 1.0f)) * (1.0f / kPi);
          }
        } else {  // map_to_tube
          const float len = std::sqrt(c.x * c.x + c.y * c.y);
          if (len > 0.0f) {
            u = (1.0f - std::atan2(c.x / len, c.y / len) / kPi) * 0.5f;
            w = (c.z + 1.0f) * 0.5f;
          }
        }
        d = {u, w, 0.0f, 0.0f};
        break;
      }
      case OpCode::ImageBox: {
        const Float4 s = reg(op.in[0]);
        d = op.index >= 0 && size_t(op.index) < images.size()
                ? image_box(images, size_t(op.index), s.xyz(), reg(op.in[1]).xyz(), op.m[0], Interp(op.sub),
                            Extension(op.ext), op.clamp)
                : Float4{1.0f, 0.0f, 1.0f, 1.0f};
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
        // Strength blends the mapped normal towards the shading normal where it is not 1.
        auto blend_strength = [&](Vec3 m) {
          if (strength == 1.0f) return m;
          const float s = std::isfinite(strength) ? std::max(strength, 0.0f) : 0.0f;
          const Vec3 blended = ctx.ns + (m - ctx.ns) * s;
          const float l2 = length_sq(blended);
          return l2 > 0.0f && std::isfinite(l2) ? blended / std::sqrt(l2) : Vec3(0.0f);
        };
        if (op.sub != 0) {
          // Object / world space; Strength blends towards the shading normal (mesh
          // orientation here: Cycles' backface flips cancel).
          const Vec3 m = blend_strength(object_world_space_normal(op.sub, ctx.object, c));
          if (length_sq(m) > 0.0f && is_finite(m)) n = m;
        } else if (ok && ctx.has_mesh_tangent(op.index)) {
          // Cycles' svm_node_normal_map with the mesh's MikkTSpace tangents; Strength blends
          // towards the shading normal only where it is not 1.
          const Float4 t = ctx.mesh_tangents[op.index];
          const Vec3 m = blend_strength(tangent_space_normal(ctx.object, t.xyz(), t.w, ctx.normal_obj, c));
          if (length_sq(m) > 0.0f && is_finite(m)) n = m;
        } else if (ok) {
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
        d = f4(n * ctx.view_side(), 0.0f);  // Cycles: "invert normal for backfacing polygons"
        break;
      }
      case OpCode::ObjectPos:
      case OpCode::Generated: {
        const uint8_t s = op.sub & 3;
        if (s != kAtPoint && s < 3) make_offsets();
        // Generated coordinates are the undisplaced mesh's (Cycles' generated attribute).
        const Vec3 p = !ctx.undisplaced ? ctx.p + (s < 3 ? dp[s] : Vec3(0.0f))
                       : op.code == OpCode::Generated ? undisplaced_at(s)
                       : (op.sub & kUndisplaced) ? undisplaced_bump_at(s) : ctx.p + (s < 3 ? dp[s] : Vec3(0.0f));
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
      case OpCode::PointInfo: {
        // Cycles' svm_node_point_info: zeros off points.
        const PointShading* ps = ctx.point;
        if (op.sub == 0) {
          d = f4(ps ? ps->position : Vec3(0.0f), 0.0f);
        } else {
          const float v = !ps ? 0.0f : op.sub == 1 ? ps->radius : ps->random;
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
        // Cycles' svm_node_geometry: its normals face the viewer (back faces flipped); the
        // side of the mesh (a mirrored instance's turned round), not of its world winding.
        const bool backfacing = ctx.backfacing;
        switch (op.sub) {
          case 0: d = f4(dot(ctx.ng, ctx.wo) < 0.0f ? -ctx.ng : ctx.ng, 0.0f); break;  // True Normal
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
      case OpCode::Attribute:
      case OpCode::ObjectAttribute: {
        // Cycles' svm_node_attr of a mesh or object attribute: Color/Vector (RGB with alpha),
        // Fac (the mean of RGB), Alpha; a missing attribute reads 0.
        const Float4 a = op.code == OpCode::ObjectAttribute ? (ctx.object ? ctx.object->attribute(op.index) : Float4{})
                         : op.index >= 0 && op.index < ctx.attr_sets && ctx.attrs ? ctx.attrs[op.index]
                                                                                   : Float4{};
        d = attribute_output(a, op.sub);
        break;
      }
      case OpCode::VolumeGrid:
        d = attribute_output(read_volume_grid(ctx, op.index, VolumeSampling(op.ext)), op.sub);
        break;
      case OpCode::ObjectNormal: {
        Vec3 n = viewer_normal(ctx);
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
        const bool backfacing = ctx.backfacing;
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
        const float side = ctx.view_side();  // Cycles works with N towards the viewer
        const Vec3 n_in = normal_or(r, op.in[5], ctx) * side;
        // Heights read on the undisplaced surface ('BOTH'): its differentials (Cycles' saved
        // bump state of svm_node_enter_bump_eval).
        const bool undisplaced = op.ext && ctx.undisplaced;
        const Vec3 ox = undisplaced ? undisplaced_at(kOffsetX) - ctx.undisplaced[0] : dp[kOffsetX];
        const Vec3 oy = undisplaced ? undisplaced_at(kOffsetY) - ctx.undisplaced[0] : dp[kOffsetY];
        const Vec3 rx = cross(oy, n_in), ry = cross(n_in, ox);
        const float hc = reg(op.in[0]).x, hx = reg(op.in[1]).x, hy = reg(op.in[2]).x;
        const float det = dot(ox, rx);
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
        d = f4(out_n, 0.0f);
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
      case OpCode::CameraData: {
        // Cycles' svm_node_camera: the shading point (not the camera ray) by worldtocamera, so
        // also past reflections; in a light's or a volume's program the scene's camera.
        const Camera* cam = ctx.ray.camera ? ctx.ray.camera : ctx.scene_camera;
        const Vec3 v = world_to_camera_point(cam, ctx.p);
        const float len = length(v);
        if (op.sub == 0) d = f4(len > 0.0f && std::isfinite(len) ? v / len : Vec3(0.0f), 0.0f);
        else {
          const float x = op.sub == 1 ? v.z : len;
          d = Float4{x, x, x, 1.0f};
        }
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
        } else if (ctx.has_mesh_tangent(op.index) && op.index < ctx.uv_sets) {
          t = object_to_world_normal(ctx.object, ctx.mesh_tangents[op.index].xyz());  // as Cycles
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
      case OpCode::TangentDisplace: {
        // Cycles: x along the uv set's (unnormalised, interpolated) object-space tangent, y along
        // the object-space normal, z along their normalised cross product times the tangent's
        // sign; then to world space as a direction. Without mesh tangents: the triangle's uv
        // tangent, no sign (Cycles' dPdu).
        const Vec3 v = reg(op.in[0]).xyz();
        const ObjectCoords* obj = ctx.object && ctx.object->valid ? ctx.object : nullptr;
        Vec3 n = world_to_object_normal(obj, viewer_normal(ctx));
        n = length_sq(n) > 0.0f ? normalize(n) : n;
        Vec3 t(0.0f);
        float sign = 1.0f;
        if (ctx.has_mesh_tangent(op.index) && op.index < ctx.uv_sets) {
          t = ctx.mesh_tangents[op.index].xyz();
          sign = ctx.mesh_tangents[op.index].w;
        } else if (op.index >= 0 && op.index < ctx.uv_sets && ctx.tangents) {
          t = obj ? obj->to_object.vector(ctx.tangents[op.index]) : ctx.tangents[op.index];
          t = length_sq(t) > 0.0f ? normalize(t) : t;
        }
        const Vec3 c = cross(n, t);
        const Vec3 b = length_sq(c) > 0.0f ? normalize(c) * sign : Vec3(0.0f);
        Vec3 o = t * v.x + n * v.y + b * v.z;
        if (obj) o = obj->to_world.vector(o);
        d = f4(is_finite(o) ? o : Vec3(0.0f), 0.0f);
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
        Vec3 n = op.in[2] == kNoReg ? viewer_normal(ctx) : r[op.in[2]].xyz();
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
        if (op.in[1] != kNoReg) {  // (the given normal faces the viewer: compared on the outward side)
          const Vec3 m = r[op.in[1]].xyz() * ctx.view_side() + (n - ctx.ns);
          n = length_sq(m) > 0.0f && is_finite(m) ? normalize(m) : ctx.ns;
        }
        d = f4(n * ctx.view_side(), 0.0f);
        break;
      }
      case OpCode::AovOutput: {
        d = reg(op.in[0]);
        if (Float4* a = ctx.ray.aovs; a && op.index >= 0 && op.index < kMaxShaderAovs) {
          Float4& slot = a[op.index];
          slot.x += d.x;
          if (op.sub) {  // a colour: (r, g, b, 1), as film_write_aov_pass_color
            slot.y += d.y;
            slot.z += d.z;
            slot.w += 1.0f;
          }
        }
        break;
      }
      case OpCode::SetNormal: {
        const Vec3 n = reg(op.in[0]).xyz() * ctx.view_side();  // (the Bump's, towards the viewer)
        if constexpr (kSetsNormal)
          if (length_sq(n) > 1e-12f && is_finite(n)) local->ns = normalize(n);
        d = f4(ctx.ns, 0.0f);
        break;
      }
      case OpCode::LightFalloff: {
        // Cycles' svm_node_light_falloff: the strength divided by nothing (Quadratic: the
        // light's own 1/r^2 stays), times r (Linear) or r^2 (Constant), and Smooth's
        // r^2 / (smooth + r^2) where r^2 is finite (a sun's r is infinite).
        float strength = reg(op.in[0]).x;
        const float r = ctx.ray.length;
        if (op.sub == 1) strength *= r;
        else if (op.sub == 2) strength *= r * r;
        const float smooth = reg(op.in[1]).x;
        const float r2 = r * r;
        if (smooth > 0.0f && std::isfinite(r2)) strength *= r2 / (smooth + r2);
        if (!std::isfinite(strength)) strength = 0.0f;
        d = {strength, strength, strength, 1.0f};
        break;
      }
      case OpCode::TexIes: {
        // Cycles' svm_node_ies: the profile along the normalised vector, times Strength.
        const float v = size_t(op.index) < prog.ies.size() && prog.ies[size_t(op.index)]
                            ? ies_eval(*prog.ies[size_t(op.index)], reg(op.in[0]).xyz()) * reg(op.in[1]).x
                            : 0.0f;
        d = {v, v, v, 1.0f};
        break;
      }
      case OpCode::EnvUv: {
        const Vec3 v = reg(op.in[0]).xyz();
        const float len = length(v);
        const Vec3 c = len > 0.0f && std::isfinite(len) ? v / len : Vec3(0.0f);
        float u, w;
        if (op.sub == 0) {  // as Environment::to_uv (Cycles' direction_to_equirectangular)
          u = (std::atan2(c.y, c.x) - kPi) / (-2.0f * kPi);
          w = 0.5f + std::asin(clampf(c.z, -1.0f, 1.0f)) / kPi;
        } else {  // Cycles' direction_to_mirrorball
          Vec3 m = c;
          m.y -= 1.0f;
          const float div = 2.0f * std::sqrt(std::max(-0.5f * m.y, 0.0f));
          if (div > 0.0f) m = m / div;
          u = 0.5f * (m.x + 1.0f);
          w = 0.5f * (m.z + 1.0f);
        }
        d = {u, w, 0.0f, 0.0f};
        break;
      }
      case OpCode::BackgroundCamera: {
        // Cycles' svm_node_tex_coord without an object: Camera is P (the direction) from the
        // camera's position; Window is camera_world_to_ndc of P, offset by the position for a
        // perspective camera only (a panorama's reads the direction), and of the ray's origin
        // for an orthographic camera's own rays (its pixel).
        const Camera* cam = ctx.ray.camera;
        Vec3 p = cam ? cam->origin() + ctx.p : ctx.p;
        if (op.sub != 0 && cam && cam->orthographic())
          p = (ctx.ray.flags & kRayCamera) && ctx.ray_p ? *ctx.ray_p : ctx.p;
        d = f4(op.sub == 0 ? world_to_camera_point(cam, p) : cam ? cam->to_ndc(p) : Vec3(0.0f), 0.0f);
        break;
      }
      case OpCode::TexVoxel:
        d = attribute_output(read_voxel_texture(ctx, op.index, VolumeSampling(op.ext), VoxelSpace(op.count),
                                                reg(op.in[0]).xyz()),
                             op.sub);
        break;
      case OpCode::TexSky: {
        // Cycles' svm_node_tex_sky reads its vector as it is (not normalised), as the world's.
        const Vec3 c = size_t(op.index) < prog.skies.size() && prog.skies[size_t(op.index)]
                           ? prog.skies[size_t(op.index)]->eval(reg(op.in[0]).xyz())
                           : Vec3(0.0f);
        d = f4(c, 1.0f);
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
      case OpCode::Diffuse:
      case OpCode::Toon:
      case OpCode::Sheen:
      case OpCode::Metallic:
      case OpCode::Translucent:
      case OpCode::Glossy:
      case OpCode::Glass:
      case OpCode::Refraction:
      case OpCode::Transparent:
      case OpCode::PrincipledExtra:
      case OpCode::Holdout:
      case OpCode::PrincipledHair:
      case OpCode::Hair:
      case OpCode::Emission:
      case OpCode::Principled:
      case OpCode::Subsurface:
      case OpCode::RayPortal:
        detail::eval_closure_op(op, prog, r, ctx, extra, out);
        break;
      case OpCode::VolumeOut: break;  // read by eval_volume
      case OpCode::DisplaceOut: break;  // read by eval_displacement
    }
  }
  out.finalize();
  if constexpr (kSetsNormal) out.ns = local->ns;
  if (regs) std::copy(r, r + kMaxRegs, regs);
}

}  // namespace

void eval_shader(const ShaderProgram& prog, const std::vector<Image>& images, const ShadingContext& ctx,
                 ClosureList& out, Float4* regs) {
  if (__builtin_expect(prog.sets_normal, 0)) {
    ShadingContext local = ctx;
    eval_program<true>(prog, images, local, &local, out, regs);
  } else {
    eval_program<false>(prog, images, ctx, nullptr, out, regs);
  }
}

std::vector<PrincipledInputs> principled_inputs_of(const ShaderOp* ops, size_t n, const Float4* regs) {
  std::vector<PrincipledInputs> v;
  const ShaderOp* extra = nullptr;
  for (size_t i = 0; i < n; ++i) {
    if (ops[i].code == OpCode::PrincipledExtra) {
      extra = &ops[i];
    } else if (ops[i].code == OpCode::Principled) {
      v.push_back(detail::principled_inputs(ops[i], extra, regs));
      extra = nullptr;
    }
  }
  return v;
}

void eval_closures(const ShaderProgram& prog, const ShaderOp* ops, size_t n, const Float4* regs,
                   const PrincipledInputs* principled, const ShadingContext& ctx, ClosureList& out) {
  out.n = 0;
  out.emission = Vec3(0.0f);
  out.holdout = Vec3(0.0f);
  out.ns = Vec3(0.0f);
  const ShaderOp* extra = nullptr;
  for (size_t i = 0; i < n; ++i) {
    if (principled && ops[i].code == OpCode::Principled) {
      detail::principled_closures(*principled++, ops[i], extra, prog, regs, ctx, out);
      extra = nullptr;
    } else {
      detail::eval_closure_op(ops[i], prog, regs, ctx, extra, out);
    }
  }
  out.finalize();
}

void add_phase_lobes(VolumeLobeType type, Float4 params, Vec3 ss, PhaseLobe* lobes, int& n) {
  const auto add = [&](const Phase& ph, Vec3 s) {
    if (is_black(s)) return;
    for (int i = 0; i < n; ++i)
      if (lobes[i].phase == ph) {
        lobes[i].sigma_s += s;
        return;
      }
    if (n < kMaxPhaseLobes) lobes[n++] = {s, ph};
    else lobes[n - 1].sigma_s += s;  // (the compiler keeps within the limit)
  };
  switch (type) {
    case VolumeLobeType::HenyeyGreenstein: add(make_hg_phase(params.x), ss); break;
    case VolumeLobeType::Draine: add(make_draine_phase(params.x, params.y), ss); break;
    case VolumeLobeType::FournierForand: add(make_fournier_forand_phase(params.x, params.y), ss); break;
    case VolumeLobeType::Rayleigh: add(make_rayleigh_phase(), ss); break;
    case VolumeLobeType::Mie: {
      const MieFit m = mie_fit(params.x);
      add(make_hg_phase(m.g_hg), ss * (1.0f - m.w));
      add(make_draine_phase(m.g_d, m.alpha), ss * m.w);
      break;
    }
  }
}

MediumSample eval_volume(const ShaderProgram& vol, const std::vector<Image>& images, const ShadingContext& ctx) {
  MediumSample m;
  if (vol.ops.empty() || vol.ops.back().code != OpCode::VolumeOut) return m;
  Float4 r[kMaxRegs];
  ClosureList unused;
  eval_shader(vol, images, ctx, unused, r);
  const ShaderOp& o = vol.ops.back();
  const auto rgb = [&](int16_t i) {
    if (i == kNoReg) return Vec3(0.0f);
    const Vec3 v = r[i].xyz();
    const auto c = [](float x) { return std::isfinite(x) && x > 0.0f ? x : 0.0f; };
    return Vec3{c(v.x), c(v.y), c(v.z)};
  };
  m.sigma_a = rgb(o.in[0]);
  m.emission = rgb(o.in[2]);
  if (o.count <= 0) {
    m.sigma_s = rgb(o.in[1]);
    m.phase = make_hg_phase(o.in[3] == kNoReg ? 0.0f : r[o.in[3]].x);
    return m;
  }
  const int k_max = std::min<int>(o.count, kMaxVolumeLobeInputs);
  for (int k = 0; k < k_max; ++k) {
    const int16_t pr = o.in[5 + 2 * k];
    const Float4 params = pr == kNoReg ? Float4{} : r[pr];
    add_phase_lobes(VolumeLobeType((uint32_t(o.index) >> (4 * k)) & 15u), params, rgb(o.in[4 + 2 * k]), m.lobes,
                    m.n_lobes);
  }
  for (int i = 0; i < m.n_lobes; ++i) m.sigma_s += m.lobes[i].sigma_s;
  if (m.n_lobes) m.phase = m.lobes[0].phase;
  if (m.n_lobes < 2) m.n_lobes = 0;  // one phase: no mixture
  return m;
}

Vec3 eval_displacement(const ShaderProgram& prog, const std::vector<Image>& images, const ShadingContext& ctx) {
  if (prog.ops.empty() || prog.ops.back().code != OpCode::DisplaceOut) return Vec3(0.0f);
  Float4 r[kMaxRegs];
  ClosureList unused;
  eval_shader(prog, images, ctx, unused, r);
  const int16_t i = prog.ops.back().in[0];
  return i == kNoReg ? Vec3(0.0f) : r[i].xyz();
}

}  // namespace pl
