// Shading at a hit: the material's closures, shadow transmittance through transparent surfaces,
// and the Ambient Occlusion and Bevel nodes' tracing.
#include "scene/scene.h"

#include <cstring>

#include "scene/vector_nodes.h"
#include "util/uninit.h"
#include "util/rng.h"

namespace pl {


// Cycles' pixel_coverage of the Huang hair closure: half the camera ray's footprint over the
// strand's radius at the hit (only camera rays on curves; 1 otherwise: the far field).
float Scene::hair_pixel_coverage(const SurfacePoint& sp, float b1, const RayState& ray) const {
  // (No footprint, as where the integrator carries no differentials: the far field.)
  if (!sp.curve() || !(ray.flags & kRayCamera) || !(ray.footprint() > 0.0f)) return 1.0f;
  const CurvePiece pc = curve_bvh_.piece_at(sp.tri, sp.time);
  const float u = clampf(b1, 0.0f, 1.0f);
  const float radius = pc.r0 + (pc.r1 - pc.r0) * u;
  const float c = radius > 0.0f ? 0.5f * ray.footprint() / radius : 1.0f;
  return std::isfinite(c) ? c : 1.0f;
}

// The curve's normal attribute at a hit (linear along the piece, as Cycles interpolates it
// between keys); zero off curves or where the strands have none.
Vec3 Scene::hair_curve_normal(const SurfacePoint& sp, float b1) const {
  if (!sp.curve()) return Vec3(0.0f);
  const CurvePiece pc = curve_bvh_.piece_at(sp.tri, sp.time);
  if (pc.n0 == kNoCurveNormal || pc.n1 == kNoCurveNormal) return Vec3(0.0f);
  const float u = clampf(b1, 0.0f, 1.0f);
  const Vec3 a = decode_unit(pc.n0), b = decode_unit(pc.n1);
  return a + (b - a) * u;
}

// A varying material's closures at ctx: its whole program, or only its closure ops on the
// registers evaluated once where no value op reads the point.
void Scene::shade_program(const Material& mat, const ShadingContext& ctx, ClosureList& out) const {
  if (mat.closures_only)
    eval_closures(mat.program, mat.closure_ops.data(), mat.closure_ops.size(), mat.closure_regs.data(),
                  mat.principled.empty() ? nullptr : mat.principled.data(), ctx, out);
  else
    eval_shader(mat.program, images_, ctx, out);
}

bool Scene::curve_key_span(uint32_t curve, float v, uint32_t& k0, uint32_t& k1, float& t) const {
  const uint32_t first = curve < curve_key_first_.size() ? curve_key_first_[curve] : UINT32_MAX;
  if (first == UINT32_MAX) return false;
  // The segment whose keys' intercepts hold v, and v's parameter on it: intercepts are linear
  // in the segment parameter (cut_curves), which Cycles interpolates point attributes by.
  const float* kv = &curve_key_v_[first];
  const uint32_t n = curve_key_count_[curve];
  const uint32_t seg = n < 2 ? 0
                             : uint32_t(std::min<ptrdiff_t>(std::upper_bound(kv + 1, kv + n - 1, v) - (kv + 1), ptrdiff_t(n) - 2));
  const uint32_t next = std::min(seg + 1, n - 1);
  const float span = kv[next] - kv[seg];
  t = span > 0.0f ? clampf((v - kv[seg]) / span, 0.0f, 1.0f) : 0.0f;
  k0 = first + seg;
  k1 = first + next;
  return true;
}

uint16_t Scene::curve_point_values(uint32_t curve, float v, Float4* buf) const {
  uint32_t k0, k1;
  float t;
  if (!curve_key_span(curve, v, k0, k1, t)) return 0;
  const Float4* a0 = &curve_key_attr_[size_t(k0) * curve_key_sets_];
  const Float4* a1 = &curve_key_attr_[size_t(k1) * curve_key_sets_];
  for (uint32_t k = 0; k < curve_key_sets_; ++k) {
    const Float4 &x = a0[k], &y = a1[k];
    buf[k] = {x.x + (y.x - x.x) * t, x.y + (y.y - x.y) * t, x.z + (y.z - x.z) * t, x.w + (y.w - x.w) * t};
  }
  return curve_point_sets_[curve_set_of(curve)];
}

namespace {
// A moving set's object coordinates at the ray's time: the frame's, with the transform at that
// time (built in `storage`, which must outlive their use).
const ObjectCoords* coords_at(const ObjectCoords& frame, const Mat4& to_world, UninitArray<ObjectCoords, 1>& storage) {
  ObjectCoords* mc = new (storage.bytes) ObjectCoords(frame);
  const ObjectCoords at = make_object_coords(to_world, Vec3(0.0f), Vec3(1.0f));
  mc->to_world = at.to_world;
  mc->to_object = at.to_object;
  mc->valid = at.valid;
  return mc;
}
}  // namespace

void Scene::shade(const SurfacePoint& sp, float b1, float b2, Vec3 wo, ClosureList& out, const RayState& ray) const {
  const Material& mat = materials_[sp.material];
  if (mat.constant) {
    out.n = mat.cached.n;
    out.emission = mat.cached.emission;
    out.holdout = mat.cached.holdout;
    out.ns = Vec3(0.0f);
    out.has_nondelta = mat.cached.has_nondelta;
    const Frame f = Frame::from_normal(sp.ns);
    const bool back = backfacing(sp, wo);
    for (int i = 0; i < out.n; ++i) {
      Closure& c = out.c[size_t(i)];
      c = mat.cached.c[size_t(i)];
      // Diffuse lobes are lit from the side the geometry shows the viewer (DiffuseBsdf::back).
      if (auto* d = std::get_if<DiffuseBsdf>(&c.bsdf)) d->back = back;
      // Glossy lobes: the normal lifted as eval_shader does (Cycles' valid specular reflection).
      c.frame = bsdf_wants_valid_reflection(c.bsdf) ? Frame::from_normal(valid_specular_normal(sp.ng, wo, sp.ns)) : f;
    }
    if (mat.has_hair) orient_hair(out, sp, wo, hair_pixel_coverage(sp, b1, ray), hair_curve_normal(sp, b1));
    return;
  }
  ShadingContext ctx;
  ctx.p = sp.p;
  ctx.ng = sp.ng;
  ctx.ns = sp.ns;
  ctx.wo = wo;
  ctx.ray = ray;
  ctx.b1 = b1;
  ctx.b2 = b2;
  ctx.scene = this;  // the Ambient Occlusion node traces
  ctx.instance = sp.instance;
  ctx.p_error = sp.p_error;
  ctx.time = sp.time;
  if (sp.curve()) {  // no triangle, uvs or attributes; world coordinates for Object
    const CurvePiece pc = curve_bvh_.piece_at(sp.tri, sp.time);
    const float u = clampf(b1, 0.0f, 1.0f);  // the axial position (end spheres: beyond [0, 1])
    CurveShading cs;
    cs.intercept = pc.v0 + (pc.v1 - pc.v0) * u;
    cs.length = curve_length_[pc.curve];
    cs.thickness = 2.0f * (pc.r0 + (pc.r1 - pc.r0) * u);
    cs.random = curve_random_[pc.curve];
    const Vec3 across = wo - sp.tangent * dot(sp.tangent, wo);
    cs.tangent_normal = length_sq(across) > 0.0f ? normalize(across) : Vec3(0.0f);
    cs.tangent = sp.tangent;
    ctx.curve = &cs;
    // Per strand (particle hair's root uvs and colours, curve-domain attributes) or
    // interpolated between the segment's keys (point-domain ones).
    Float4 key_buf[8], attr_buf[8];
    Vec2 uv_buf[8];
    const uint16_t per_point = curve_point_values(pc.curve, cs.intercept, key_buf);
    if (curve_uv_sets_) {
      ctx.uv = &curve_uv_[size_t(pc.curve) * curve_uv_sets_];
      ctx.uv_sets = int(curve_uv_sets_);
      if (per_point >> 8) {
        for (uint32_t k = 0; k < curve_uv_sets_; ++k)
          uv_buf[k] = per_point >> (k + 8) & 1u ? Vec2{key_buf[k].x, key_buf[k].y} : ctx.uv[k];
        ctx.uv = uv_buf;
      }
    }
    if (curve_attr_sets_) {
      ctx.attrs = &curve_attr_[size_t(pc.curve) * curve_attr_sets_];
      ctx.attr_sets = int(curve_attr_sets_);
      if (per_point & 0xFFu) {
        for (uint32_t k = 0; k < curve_attr_sets_; ++k) attr_buf[k] = per_point >> k & 1u ? key_buf[k] : ctx.attrs[k];
        ctx.attrs = attr_buf;
      }
    }
    ctx.backfacing = dot(sp.ng, wo) < 0.0f;
    const uint32_t set = curve_set_of(pc.curve);
    ctx.object = &curve_coords_[set];
    UninitArray<ObjectCoords, 1> moved_coords;  // (a moving set's object at the ray's time)
    if (curve_moving_[set])
      ctx.object = coords_at(curve_coords_[set], curve_bvh_.moving_transform(sp.tri, sp.time), moved_coords);
    shade_program(mat, ctx, out);
    if (mat.has_hair) orient_hair(out, sp, wo, hair_pixel_coverage(sp, b1, ray), hair_curve_normal(sp, b1));
    return;
  }
  if (sp.point()) {  // Cycles' points: u = v = 0, per-point attributes, the cloud's object space
    PointFrame moved;
    const PointFrame* frame = nullptr;
    const PointSphere s = point_bvh_.world_sphere(sp.tri, sp.time, moved, frame);
    const uint32_t point = s.point, set = point_set_of(point);
    PointShading ps;
    ps.position = s.c;
    ps.radius = s.r * point_radius_scale_[set];
    ps.random = point_random_[point];
    ctx.point = &ps;
    if (point_attr_sets_) {
      ctx.attrs = &point_attr_[size_t(point) * point_attr_sets_];
      ctx.attr_sets = int(point_attr_sets_);
    }
    ctx.backfacing = dot(sp.ng, wo) < 0.0f;
    ctx.object = &point_coords_[set];
    UninitArray<ObjectCoords, 1> moved_coords;  // (a moving cloud's object at the ray's time)
    if (point_moving_[set])
      ctx.object = coords_at(point_coords_[set], point_bvh_.moving_transform(sp.tri, sp.time), moved_coords);
    shade_program(mat, ctx, out);
    if (mat.has_hair) orient_hair(out, sp, wo);
    return;
  }
  const InstanceData& in = inst_[sp.instance];
  ctx.backfacing = (dot(sp.ng, wo) < 0.0f) != in.negative;  // (Scene::backfacing)
  const Blas& blas = blases_[in.blas];
  TriangleVerts tv;
  ctx.object = &object_coords_[sp.instance];
  UninitArray<ObjectCoords, 1> moved_coords;  // (constructed only for moving objects)
  if (__builtin_expect(in.motion != nullptr || in.deform != nullptr, 0)) {
    // Motion blur: the triangle, and the object's transforms for texture coordinates, at the
    // ray's time (so textures stay on a moving object).
    InstanceData moved = in;
    if (in.motion) {
      set_instance_matrix(moved, motion_transform_at(in.motion, in.motion_steps, sp.time));
      ObjectCoords* mc = new (moved_coords.bytes) ObjectCoords(object_coords_[sp.instance]);
      const ObjectCoords at = make_object_coords(moved.to_world, Vec3(0.0f), Vec3(1.0f));
      mc->to_world = at.to_world;
      mc->to_object = at.to_object;
      mc->valid = at.valid;
      ctx.object = mc;
    }
    tv = world_triangle(moved, in.deform ? in.deform->triangle_at(sp.tri, sp.time) : blas.tris[sp.tri]);
  } else {
    tv = world_triangle(in, blas.tris[sp.tri]);
  }
  const Vec3 corners[3] = {tv.v0, tv.v1, tv.v2};
  ctx.tri = corners;  // for the Bump node's offsets
  Vec3 undisplaced[4];  // a truly displaced mesh's surface before it: the point, the triangle
  if (const MeshData& mesh = meshes_[in.mesh]; __builtin_expect(!mesh.undisplaced.empty(), 0) && ctx.object->valid) {
    const std::array<uint32_t, 3>& t = mesh.triangles[blas.src_tri[sp.tri]];
    for (int k = 0; k < 3; ++k) undisplaced[1 + k] = ctx.object->to_world.point(mesh.undisplaced[t[size_t(k)]]);
    undisplaced[0] = undisplaced[1] * (1.0f - b1 - b2) + undisplaced[2] * b1 + undisplaced[3] * b2;
    ctx.undisplaced = undisplaced;
  }
  if (mat.closures_only) {  // (no uvs or attributes: no value op reads them)
    shade_program(mat, ctx, out);
    if (mat.has_hair) orient_hair(out, sp, wo);
    return;
  }
  constexpr int kMaxSets = 8;
  // (filled below for the sets a program reads; ctx's counts bound every read)
  UninitArray<Vec2, kMaxSets> uv;
  UninitArray<Vec2, 3 * kMaxSets> corner_uvs;
  UninitArray<Vec3, kMaxSets> tangents;
  float signs[kMaxSets];
  UninitArray<Float4, kMaxSets> mesh_tangents;
  uint32_t mesh_tangent_sets = 0;
  const int sets = static_cast<int>(std::min<size_t>(uv_sets_, kMaxSets));
  if (mat.program.uses_uv && sets > 0) {
    const float b0 = 1.0f - b1 - b2;
    const MeshData& mesh = meshes_[in.mesh];
    const size_t st = blas.src_tri[sp.tri];
    for (int k = 0; k < sets; ++k) {
      if (size_t(k) >= mesh.uvs.size() || mesh.uvs[size_t(k)].empty()) {  // missing: zeros
        uv[k] = {};
        corner_uvs[3 * k] = corner_uvs[3 * k + 1] = corner_uvs[3 * k + 2] = {};
        tangents[k] = Vec3(0.0f);
        signs[k] = 1.0f;
        continue;
      }
      const std::vector<Vec2>& t = mesh.uvs[size_t(k)];
      const Vec2 a = t[3 * st], b = t[3 * st + 1], c = t[3 * st + 2];
      uv[k] = {a.x * b0 + b.x * b1 + c.x * b2, a.y * b0 + b.y * b1 + c.y * b2};
      corner_uvs[3 * k] = a;
      corner_uvs[3 * k + 1] = b;
      corner_uvs[3 * k + 2] = c;
      if (!mat.uses_tangents) continue;  // (no op reads them: ctx.tangents stays null)
      if (size_t(k) < mesh.tangents.size() && !mesh.tangents[size_t(k)].empty()) {
        // The mesh's MikkTSpace tangents, interpolated unnormalised in object space (Cycles).
        const std::vector<Float4>& mt = mesh.tangents[size_t(k)];
        const Float4 &ta = mt[3 * st], &tb = mt[3 * st + 1], &tc = mt[3 * st + 2];
        mesh_tangents[k] = {ta.x * b0 + tb.x * b1 + tc.x * b2, ta.y * b0 + tb.y * b1 + tc.y * b2,
                            ta.z * b0 + tb.z * b1 + tc.z * b2, ta.w * b0 + tb.w * b1 + tc.w * b2};
        mesh_tangent_sets |= 1u << k;
        tangents[k] = Vec3(0.0f);
        signs[k] = 1.0f;
        continue;
      }
      // Per-triangle tangent from the uv parameterisation (dP/du), sign from the uv winding.
      const Vec3 e1 = tv.v1 - tv.v0, e2 = tv.v2 - tv.v0;
      const float du1 = b.x - a.x, dv1 = b.y - a.y, du2 = c.x - a.x, dv2 = c.y - a.y;
      const float det = du1 * dv2 - du2 * dv1;
      if (std::fabs(det) > 1e-20f) {
        const float inv = 1.0f / det;
        const Vec3 T = (e1 * dv2 - e2 * dv1) * inv;
        const Vec3 B = (e2 * du1 - e1 * du2) * inv;
        tangents[k] = T;
        signs[k] = dot(cross(sp.ns, T), B) < 0.0f ? -1.0f : 1.0f;
      } else {
        tangents[k] = Vec3(0.0f);
        signs[k] = 1.0f;
      }
    }
    ctx.uv = uv.data();
    ctx.uv_sets = sets;
    if (mat.uses_tangents) {
      ctx.tangents = tangents.data();
      ctx.tangent_signs = signs;
    }
    ctx.tri_uv = corner_uvs.data();
    if (mesh_tangent_sets) {
      // Cycles' normal for tangent space: the unnormalised interpolated smooth normal in
      // object space, or the geometric one turned back to object space (flat shading).
      Vec3 n(0.0f);
      if (!mesh.normals.empty()) {
        const std::array<uint32_t, 3>& ni = mesh.normal_indices.empty() ? mesh.triangles[st] : mesh.normal_indices[st];
        n = mesh.normals[ni[0]] * b0 + mesh.normals[ni[1]] * b1 + mesh.normals[ni[2]] * b2;
      }
      if (!(length_sq(n) > 0.0f) || !is_finite(n)) n = world_to_object_normal(ctx.object, sp.ng);
      ctx.normal_obj = n;
      ctx.mesh_tangents = mesh_tangents.data();
      ctx.mesh_tangent_sets = mesh_tangent_sets;
    }
  }
  UninitArray<Float4, kMaxSets> attrs;
  if (mat.program.uses_attributes) {
    const MeshData& mesh = meshes_[in.mesh];
    const int n = static_cast<int>(std::min<size_t>(mesh.attributes.size(), kMaxSets));
    const float b0 = 1.0f - b1 - b2;
    const size_t st = blas.src_tri[sp.tri];
    for (int k = 0; k < n; ++k) {
      const std::vector<Float4>& t = mesh.attributes[size_t(k)];
      if (t.empty()) {
        attrs[k] = {};
        continue;
      }
      const Float4 &a = t[3 * st], &b = t[3 * st + 1], &c = t[3 * st + 2];
      attrs[k] = {a.x * b0 + b.x * b1 + c.x * b2, a.y * b0 + b.y * b1 + c.y * b2, a.z * b0 + b.z * b1 + c.z * b2,
                  a.w * b0 + b.w * b1 + c.w * b2};
    }
    ctx.attrs = attrs.data();
    ctx.attr_sets = n;
  }
  eval_shader(mat.program, images_, ctx, out);
  if (mat.has_hair) orient_hair(out, sp, wo);
}

namespace {

// Cycles' make_orthonormals: a fixed basis across n (Huang's frame where no major axis is known).
void cycles_orthonormals(Vec3 n, Vec3& a, Vec3& b) {
  a = (n.x != n.y || n.x != n.z) ? Vec3{n.z - n.y, n.x - n.z, n.y - n.x} : Vec3{n.z - n.y, n.x + n.z, -n.y - n.x};
  a = normalize(a);
  b = cross(n, a);
}

uint32_t mix_bits(uint32_t h, float v) {
  uint32_t x;
  std::memcpy(&x, &v, 4);
  h ^= x + 0x9E3779B9u + (h << 6) + (h >> 2);
  h *= 0x85EBCA6Bu;
  return h ^ (h >> 13);
}

// Cycles' bsdf_hair_huang_setup: y along the fibre; x across the view (circular) or the major
// axis (elliptical: the curve's normal made perpendicular to the fibre; without one, Cycles'
// fixed basis of the tangent), z = x cross y; h = -dot(across the view, N). Hits beyond the
// projected radius of an elliptical fibre become transparent, as in Cycles.
void orient_huang(Closure& c, HairHuangBsdf hb, const SurfacePoint& sp, Vec3 tangent, Vec3 wo, float coverage,
                  Vec3 curve_normal, bool& changed) {
  const Vec3 y = tangent;
  Vec3 x = cross(y, wo);
  const float lx = length(x);
  x = lx > 1e-7f ? x / lx : Vec3(0.0f);
  hb.h = clampf(-dot(x, sp.ng), -1.0f, 1.0f);
  if (hb.b != 1.0f && sp.curve()) {
    auto safe_normalize = [](Vec3 v) {
      const float l = length(v);
      return l > 0.0f && std::isfinite(l) ? v / l : Vec3(0.0f);
    };
    x = safe_normalize(cross(y, safe_normalize(cross(curve_normal, y))));
    if (hb.b > 1.0f) {  // the normal names the minor axis: swap
      hb.b = 1.0f / hb.b;
      const Vec3 minor = safe_normalize(cross(y, x));
      x = safe_normalize(cross(minor, y));
    }
  }
  Vec3 z;
  if (!(length_sq(x) > 0.0f)) {
    cycles_orthonormals(y, z, x);
  } else {
    z = normalize(cross(x, y));
  }
  hb.pixel_coverage = coverage;
  const uint32_t seed = mix_bits(mix_bits(mix_bits(0x2545F491u, sp.p.x), sp.p.y), sp.p.z);
  hb.seed = mix_bits(mix_bits(seed, wo.x), wo.y);
  c.frame.t = x;
  c.frame.b = y;
  c.frame.n = z;
  if (std::fabs(hb.h) >= hb.projected_radius(c.frame.to_local(wo))) {
    c.bsdf = TransparentBsdf{};
    c.delta = true;
    changed = true;
    return;
  }
  c.bsdf = hb;
}

}  // namespace

void orient_hair(ClosureList& out, const SurfacePoint& sp, Vec3 wo, float pixel_coverage, Vec3 curve_normal) {
  // Cycles' bsdf_hair_chiang_setup: x along the fibre, y = x cross the view, z = x cross y;
  // h the sine of the angle between the normal and z seen along x. On a mesh (no tangent) an
  // arbitrary tangent of the shading normal stands in for the fibre.
  Vec3 x = sp.tangent;
  // The inside of a strand (a ray that started in it): Cycles turns dPdu round with Ng.
  if (sp.curve() && dot(sp.ng, wo) < 0.0f) x = -x;
  if (!(length_sq(x) > 0.0f)) {
    Vec3 b;
    make_basis(sp.ns, x, b);
  }
  Vec3 y = cross(x, wo);
  const float l = length(y);
  if (l > 1e-7f) {
    y = y / l;
  } else {  // looking along the fibre: any y across it
    Vec3 b;
    make_basis(x, y, b);
  }
  const Vec3 z = cross(x, y);
  const float h = clampf(dot(cross(sp.ng, x), z), -1.0f, 1.0f);
  bool changed = false;
  for (int i = 0; i < out.n; ++i) {
    Closure& c = out.c[size_t(i)];
    if (auto* hb = std::get_if<HairChiangBsdf>(&c.bsdf)) {
      hb->h = h;
      c.frame.t = x;
      c.frame.b = y;
      c.frame.n = z;
    } else if (auto* hh = std::get_if<HairHuangBsdf>(&c.bsdf)) {
      orient_huang(c, *hh, sp, x, wo, pixel_coverage, curve_normal, changed);
    }
  }
  if (changed) {
    out.has_nondelta = false;
    for (int i = 0; i < out.n; ++i) out.has_nondelta = out.has_nondelta || !out.c[size_t(i)].delta;
  }
}

bool Scene::intersect_camera_visible(const Ray& r, Hit& h) const {
  Ray ray = r;
  for (int i = 0; i < 64; ++i) {  // bounded, as intersect_catchers
    if (!is_camera_invisible(h.inst, h.prim)) {
      const Vec3 p = ray.org + ray.dir * h.t;
      h.t = dot(p - r.org, r.dir) / dot(r.dir, r.dir);
      return true;
    }
    SurfacePoint sp;
    surface_point(h, sp, ray.time, &ray);
    continue_past(ray, sp, dot(ray.dir, sp.ng) > 0.0f ? sp.ng : -sp.ng);
    if (!intersect(ray, h)) return false;
  }
  return false;
}

bool Scene::intersect_catchers(Ray& r, Hit& h) const {
  for (int i = 0; i < 64; ++i) {  // bounded, as transmittance_through
    if (!intersect(r, h)) return false;
    if (is_catcher(h.inst, h.prim)) return true;
    SurfacePoint sp;
    surface_point(h, sp, r.time, &r);
    continue_past(r, sp, dot(r.dir, sp.ng) > 0.0f ? sp.ng : -sp.ng);
  }
  return false;
}

Vec3 Scene::transmittance_through(Ray ray, uint64_t shadow_mask, bool catchers_only, int max_hits) const {
  Vec3 T(1.0f);
  int hits = 0;
  for (int i = 0; i < kMaxShadowCrossings; ++i) {  // bounded, passed blockers included
    Hit h;
    if (!intersect(ray, h)) return T;
    SurfacePoint sp;
    surface_point(h, sp, ray.time, &ray);
    const Material& mat = materials_[sp.material];
    // Shadow linking: a blocker outside the light's shadow sets is passed as if not there.
    const bool passed = (shadow_mask != kAllLightSets && !((shadow_mask >> shadow_set_of(h)) & 1u)) ||
                        (catchers_only && !is_catcher(h.inst, h.prim));
    if (!mat.transparent && !passed) return Vec3(0.0f);
    if (!passed) {
      if (++hits > max_hits) return Vec3(0.0f);  // Blender's Transparent max bounces
      ClosureList cl;
      RayState shadow;
      shadow.flags = kRayShadow;
      shadow.length = h.t * length(ray.dir);
      shade(sp, h.b1, h.b2, -normalize(ray.dir), cl, shadow);
      T = T * vmin(cl.shadow_pass(), Vec3(1.0f));
      if (!(max_component(T) > 0.0f)) return Vec3(0.0f);
    }
    continue_past(ray, sp, dot(ray.dir, sp.ng) > 0.0f ? sp.ng : -sp.ng);
  }
  return Vec3(0.0f);
}

float trace_ambient_occlusion(const ShadingContext& ctx, Vec3 n, float distance, int samples, bool only_local) {
  // Cycles' svm_ao: cosine-distributed directions about n (a concentric disk point lifted to
  // the hemisphere), each an occlusion ray of length `distance` from the point; the fraction
  // that escapes. Random numbers from the path's, stratified over the samples.
  const Scene& scene = *ctx.scene;
  Vec3 t, b;
  make_basis(n, t, b);
  uint32_t pb[3];
  std::memcpy(pb, &ctx.p, sizeof pb);
  Pcg32 rng(hash3(ctx.ray.rng, pb[0] ^ (uint64_t(pb[1]) << 32), pb[2]), 0xA0u);
  int unoccluded = 0;
  for (int k = 0; k < samples; ++k) {
    const Vec2 u{(float(k) + rng.next_float()) / float(samples), rng.next_float()};
    const Vec2 dsk = sample_disk_concentric({std::min(u.x, 0x1.fffffep-1f), u.y});
    const float z = std::sqrt(std::max(0.0f, 1.0f - dsk.x * dsk.x - dsk.y * dsk.y));
    const Vec3 dir = t * dsk.x + b * dsk.y + n * z;
    Ray ray;
    ray.time = ctx.time;
    ray.org = offset_ray_origin(ctx.p, ctx.p_error, dot(dir, ctx.ng) >= 0.0f ? ctx.ng : -ctx.ng);
    ray.dir = dir;
    ray.tmax = distance;
    if (!only_local) {
      if (!scene.occluded(ray)) ++unoccluded;
      continue;
    }
    // Only Local: walk past the hits on other objects (bounded, like stacked alpha cards).
    bool hit_self = false;
    for (int i = 0; i < 64; ++i) {
      Hit h;
      h.t = ray.tmax;
      if (!scene.intersect(ray, h) || !h.valid()) break;
      if (h.inst == ctx.instance) {
        hit_self = true;
        break;
      }
      const Vec3 q = ray.org + ray.dir * h.t;
      ray.tmax -= h.t;
      ray.org = q + ray.dir * (1e-4f * (1.0f + max_component(vabs(q))));
      if (!(ray.tmax > 0.0f)) break;
    }
    if (!hit_self) ++unoccluded;
  }
  return float(unoccluded) / float(samples);
}

// Cycles' bevel radius distribution (a planar cubic falloff, (R - r)^3): the radius in [0, 1)
// whose CDF 10x^2 - 20x^3 + 15x^4 - 4x^5 is xi, by Newton's method.
static float bevel_cubic_radius(float xi) {
  float x = 0.25f;
  for (int i = 0; i < 10; ++i) {
    const float x2 = x * x, x3 = x2 * x, nx = 1.0f - x;
    const float f = 10.0f * x2 - 20.0f * x3 + 15.0f * x2 * x2 - 4.0f * x2 * x3 - xi;
    const float df = 20.0f * (x * nx) * (nx * nx);
    if (std::fabs(f) < 1e-6f || df == 0.0f) break;
    x = clampf(x - f / df, 0.0f, 1.0f);
  }
  return x;
}

Vec3 trace_bevel(const ShadingContext& ctx, float radius, int samples) {
  // Cycles' svm_bevel: points on a disk about the point, on one of three axes (the normal's
  // half of the time), each projected onto the instance's own surface by a ray of twice the
  // disk's height; the smooth normals found are summed with the axes' MIS weights and the
  // falloff's ratio at the real distance, and normalised. Blurry indirect rays skip it.
  if (ctx.ray.min_pdf < 8.0f) return ctx.ns;
  const Scene& scene = *ctx.scene;
  uint32_t pb[3];
  std::memcpy(pb, &ctx.p, sizeof pb);
  Pcg32 rng(hash3(ctx.ray.rng, pb[0] ^ (uint64_t(pb[1]) << 32), pb[2]), 0xBEu);
  // The disk's frame as Cycles' make_orthonormals makes it from the view-facing normal: the
  // estimate's mean does not depend on the tangents, but its normalised small-sample bias does
  // (tangents along a cube's edges instead bent the bevel 2 % more).
  const Vec3 ng = dot(ctx.ng, ctx.wo) < 0.0f ? -ctx.ng : ctx.ng;
  Vec3 t0 = (ng.x != ng.y || ng.x != ng.z) ? Vec3{ng.z - ng.y, ng.x - ng.z, ng.y - ng.x}
                                           : Vec3{ng.z - ng.y, ng.x + ng.z, -ng.y - ng.x};
  t0 = normalize(t0);
  const Vec3 b0 = cross(ng, t0);
  Vec3 sum(0.0f);
  // The samples as one randomly shifted (0,2)-sequence net (van der Corput and Sobol's second
  // dimension, XOR-shifted): stratified in every elementary interval, as Cycles' branched
  // samples are. The normalised sum's small-sample bias depends on it: with only 1D strata the
  // bevelled edges came out 2 % off Cycles'.
  const uint32_t shift_x = rng.next_u32(), shift_y = rng.next_u32();
  auto sobol2 = [](uint32_t i) {
    uint32_t r = 0;
    for (uint32_t v = 1u << 31; i; i >>= 1, v ^= v >> 1)
      if (i & 1u) r ^= v;
    return r;
  };
  auto bit_reverse = [](uint32_t v) {
    v = ((v >> 1) & 0x55555555u) | ((v & 0x55555555u) << 1);
    v = ((v >> 2) & 0x33333333u) | ((v & 0x33333333u) << 2);
    v = ((v >> 4) & 0x0F0F0F0Fu) | ((v & 0x0F0F0F0Fu) << 4);
    v = ((v >> 8) & 0x00FF00FFu) | ((v & 0x00FF00FFu) << 8);
    return (v >> 16) | (v << 16);
  };
  auto unit = [](uint32_t v) { return std::min(float(v >> 8) * 0x1p-24f, 0x1.fffffep-1f); };
  for (int k = 0; k < samples; ++k) {
    float ux = unit(bit_reverse(uint32_t(k)) ^ shift_x);
    const float uy = unit(sobol2(uint32_t(k)) ^ shift_y);
    Vec3 n = ng, t = t0, b = b0;
    float pn, pt, pb_;
    if (ux < 0.5f) {
      pn = 0.5f, pt = 0.25f, pb_ = 0.25f;
      ux *= 2.0f;
    } else if (ux < 0.75f) {
      std::swap(n, t);
      pn = 0.25f, pt = 0.5f, pb_ = 0.25f;
      ux = (ux - 0.5f) * 4.0f;
    } else {
      std::swap(n, b);
      pn = 0.25f, pt = 0.25f, pb_ = 0.5f;
      ux = (ux - 0.75f) * 4.0f;
    }
    const float phi = 2.0f * kPi * ux;
    const float disk_r = bevel_cubic_radius(uy) * radius;
    const float height = std::sqrt(std::max(0.0f, radius * radius - disk_r * disk_r));
    Ray ray;
    ray.org = ctx.p + n * height + t * (disk_r * std::cos(phi)) + b * (disk_r * std::sin(phi));
    ray.dir = -n;
    ray.tmax = 2.0f * height;
    if (!(ray.tmax > 0.0f) || !is_finite(ray.org)) continue;
    const float falloff_disk = radius - disk_r;  // the cubic falloff's ratio, as ((R - r) / (R - r_disk))^3
    // Every hit on the instance along the ray (other objects are walked past), bounded.
    for (int i = 0; i < 16; ++i) {
      Hit h;
      h.t = ray.tmax;
      if (!scene.intersect(ray, h) || !h.valid()) break;
      const Vec3 q = ray.org + ray.dir * h.t;
      if (h.inst == ctx.instance) {
        SurfacePoint sp;
        scene.surface_point(h, sp);
        const float an = pn * std::fabs(dot(n, sp.ng)), at = pt * std::fabs(dot(t, sp.ng)),
                    ab = pb_ * std::fabs(dot(b, sp.ng));
        const float mis = an / (an * an + at * at + ab * ab);
        const float r = length(sp.p - ctx.p);
        const float q3 = r < radius ? (radius - r) / falloff_disk : 0.0f;
        const float w = mis * q3 * q3 * q3;
        if (falloff_disk > 0.0f && std::isfinite(w)) sum += sp.ns * w;
      }
      const float step = h.t + 1e-4f * (1.0f + max_component(vabs(q)));
      ray.org = ray.org + ray.dir * step;
      ray.tmax -= step;
      if (!(ray.tmax > 0.0f)) break;
    }
  }
  const float l = length_sq(sum);
  return l > 0.0f && std::isfinite(l) ? sum / std::sqrt(l) : ctx.ns;
}

Vec3 Scene::pass_uv(const SurfacePoint& sp, int k) const {
  if (sp.curve() || sp.point() || k < 0 || sp.instance >= inst_.size()) return Vec3(0.0f);
  const InstanceData& in = inst_[sp.instance];
  const MeshData& mesh = meshes_[in.mesh];
  if (size_t(k) >= mesh.uvs.size() || mesh.uvs[size_t(k)].empty() || in.blas >= blases_.size()) return Vec3(0.0f);
  const size_t st = blases_[in.blas].src_tri[sp.tri];
  const Vec2* t = &mesh.uvs[size_t(k)][3 * st];
  const float b0 = 1.0f - sp.b1 - sp.b2;
  return {t[0].x * b0 + t[1].x * sp.b1 + t[2].x * sp.b2, t[0].y * b0 + t[1].y * sp.b1 + t[2].y * sp.b2, 1.0f};
}

void Scene::pass_motion(const SurfacePoint& sp, Vec3& pre, Vec3& post) const {
  pre = post = sp.p;
  if (sp.curve() || sp.point()) {
    // A curve set or point cloud: its object's transform at those frames (as Cycles' object
    // motion of the pass) and, where it deforms, its keys or centres there (Cycles' motion
    // keys: a strand's point between the segment's two keys at the hit's parameter, a point's
    // centre; primitive_motion_vector). The hit keeps its offset from that point, which
    // stands in for it where the set only moves (only a turn tells them apart).
    const std::vector<Mat4>* steps = nullptr;
    const ObjectCoords* oc = nullptr;
    Vec3 p = sp.p;
    const Vec3* moved = nullptr;  // object space: at the previous and at the next frame
    Vec3 moved_buf[2];
    if (sp.curve()) {
      const CurvePiece pc = curve_bvh_.piece_at(sp.tri, sp.time);
      const uint32_t set = curve_set_of(pc.curve);
      if (set < curve_sets_.size() && set < curve_coords_.size()) steps = &curve_sets_[set].pass_motion, oc = &curve_coords_[set];
      uint32_t k0, k1;
      float t;
      const Vec3 axis = pc.p1 - pc.p0;
      const float u = length_sq(axis) > 0.0f ? clampf(dot(sp.p - pc.p0, axis) / length_sq(axis), 0.0f, 1.0f) : 0.0f;
      if (oc && set < curve_pass_deform_.size() && curve_pass_deform_[set] &&
          curve_key_span(pc.curve, pc.v0 + (pc.v1 - pc.v0) * u, k0, k1, t)) {
        const Vec3* a = &curve_key_pass_[3 * size_t(k0)];
        const Vec3* b = &curve_key_pass_[3 * size_t(k1)];
        p = oc->to_world.point(a[0] * (1.0f - t) + b[0] * t);
        for (int j = 0; j < 2; ++j) moved_buf[j] = a[j + 1] * (1.0f - t) + b[j + 1] * t;
        moved = moved_buf;
      }
    } else {
      PointFrame frame_buf;
      const PointFrame* frame = nullptr;
      const PointSphere ps = point_bvh_.world_sphere(sp.tri, sp.time, frame_buf, frame);
      const uint32_t set = point_set_of(ps.point);
      if (set < point_sets_.size() && set < point_coords_.size()) steps = &point_sets_[set].pass_motion, oc = &point_coords_[set];
      p = ps.c;
      if (oc && set < point_pass_deform_.size() && point_pass_deform_[set]) moved = &point_pass_[2 * size_t(ps.point)];
    }
    if (!oc || !oc->valid) return;
    const bool transformed = steps && steps->size() == 2;
    if (!transformed && !moved) return;
    const Vec3 local = oc->to_object.point(p);
    Vec3 at[2];
    for (int j = 0; j < 2; ++j) at[j] = (transformed ? (*steps)[size_t(j)] : oc->to_world).point(moved ? moved[j] : local);
    if (is_finite(at[0]) && is_finite(at[1])) pre = at[0] + (sp.p - p), post = at[1] + (sp.p - p);
    return;
  }
  if (pass_motion_.empty() || sp.instance >= pass_motion_.size()) return;
  const PassMotion& pm = pass_motion_[sp.instance];
  if (!pm.moves) return;
  if (!pm.deform) {
    pre = pm.pre.point(sp.p);
    post = pm.post.point(sp.p);
    return;
  }
  // A deforming mesh: its triangle at those frames, at the hit's barycentrics (as Cycles reads
  // the motion vertex positions).
  const InstanceData& in = inst_[sp.instance];
  if (in.blas >= blases_.size()) return;
  const MeshData& mesh = meshes_[in.mesh];
  const std::array<uint32_t, 3>& t = mesh.triangles[blases_[in.blas].src_tri[sp.tri]];
  const float b0 = 1.0f - sp.b1 - sp.b2;
  const auto at = [&](const std::vector<Vec3>& v) { return v[t[0]] * b0 + v[t[1]] * sp.b1 + v[t[2]] * sp.b2; };
  pre = pm.pre.point(at(mesh.pass_positions[0]));
  post = pm.post.point(at(mesh.pass_positions[1]));
}

const ObjectInfo& Scene::object_info(const SurfacePoint& sp) const {
  if (sp.curve()) return curve_coords_[curve_set_of(curve_bvh_.piece_at(sp.tri, sp.time).curve)].info;
  if (sp.point()) {
    PointFrame moved;
    const PointFrame* frame = nullptr;
    return point_coords_[point_set_of(point_bvh_.world_sphere(sp.tri, sp.time, moved, frame).point)].info;
  }
  return object_coords_[sp.instance].info;
}

}  // namespace pl
