#include "scene/scene.h"

#include <stdexcept>

namespace pl {
namespace {

// Emissive triangles are sampled uniformly in the solid angle they subtend, except where that
// angle is tiny (far away: area sampling is as good, cheaper and better conditioned) or close to
// a hemisphere (the spherical construction loses precision there).
inline bool use_spherical_sampling(double omega) { return omega > 2e-4 && omega < 6.2; }

}  // namespace

Material make_simple_material(const std::string& name, Vec3 base_color, Vec3 emission) {
  Material m;
  m.name = name;
  ShaderOp c0;
  c0.code = OpCode::Const;
  c0.dst = 0;
  c0.value = {base_color.x, base_color.y, base_color.z, 1.0f};
  ShaderOp c1 = c0;
  c1.dst = 1;
  c1.value = {emission.x, emission.y, emission.z, 1.0f};
  ShaderOp diffuse;
  diffuse.code = OpCode::Diffuse;
  diffuse.in[1] = 0;
  ShaderOp emit;
  emit.code = OpCode::Emission;
  emit.in[1] = 1;
  m.program.ops = {c0, c1, diffuse};
  if (!is_black(emission)) m.program.ops.insert(m.program.ops.end(), {emit});
  return m;
}

Scene::Scene() {
  // Material 0: the fallback grey diffuse for unassigned or out-of-range slots.
  materials_.push_back(make_simple_material("Default", Vec3(0.8f), Vec3(0.0f)));
}

namespace {
// Derived fields of a material: emission estimate, transparency, cached constant closures.
void prepare_material(Material& m, const std::vector<Image>& images) {
  // The emission at a neutral shading point, to weigh this material's triangles as lights.
  ShadingContext ctx;
  ctx.ng = ctx.ns = ctx.wo = {0.0f, 0.0f, 1.0f};
  ClosureList cl;
  eval_shader(m.program, images, ctx, cl);
  m.emission_estimate = cl.emission;
  bool emits = false;
  for (const ShaderOp& op : m.program.ops) emits = emits || op.code == OpCode::Emission;
  if (emits && m.program.varying) {
    // Emission that varies (textures): probe a few uvs for the estimate, and never let it be
    // zero, so its triangles stay in the light distribution (light-only vertices need that).
    Vec2 uv[8];
    for (float u : {0.25f, 0.75f})
      for (float v : {0.25f, 0.75f}) {
        for (Vec2& x : uv) x = {u, v};
        ctx.uv = uv;
        ctx.uv_sets = 8;
        eval_shader(m.program, images, ctx, cl);
        m.emission_estimate = vmax(m.emission_estimate, cl.emission);
      }
    if (!(luminance(m.emission_estimate) > 0.0f)) m.emission_estimate = Vec3(1.0f);
  }
  m.transparent = false;
  for (const ShaderOp& op : m.program.ops) m.transparent = m.transparent || op.code == OpCode::Transparent;
  m.constant = !m.program.varying;
  if (m.constant) {
    ctx.uv = nullptr;
    ctx.uv_sets = 0;
    eval_shader(m.program, images, ctx, m.cached);
  }
}
}  // namespace

uint32_t Scene::add_material(Material m) {
  prepare_material(m, images_);
  materials_.push_back(std::move(m));
  committed_ = false;
  return static_cast<uint32_t>(materials_.size() - 1);
}

void Scene::set_material(uint32_t id, Material m) {
  if (id == 0 || id >= materials_.size()) throw std::invalid_argument("set_material: unknown material id");
  prepare_material(m, images_);
  materials_[id] = std::move(m);
  committed_ = false;  // the light distribution depends on the emission estimates
}

uint32_t Scene::add_mesh(MeshData mesh) {
  meshes_.push_back(std::move(mesh));
  committed_ = false;
  geometry_dirty_ = true;
  return static_cast<uint32_t>(meshes_.size() - 1);
}

void Scene::add_instance(uint32_t mesh, const Mat4& m) {
  if (mesh >= meshes_.size()) throw std::invalid_argument("add_instance: unknown mesh id");
  instances_.push_back({mesh, m});
  committed_ = false;
  geometry_dirty_ = true;
}

bool Scene::commit(int threads, BvhLayout layout) {
  cancel_.store(false);
  committed_ = false;
  if (geometry_dirty_ || layout != built_layout_) {
    if (!build_geometry(threads, layout)) return false;
  }
  build_lights();
  committed_ = true;
  return true;
}

size_t Scene::geometry_bytes() const {
  size_t bytes = tris_.capacity() * sizeof(TriangleVerts) + shading_.capacity() * sizeof(TriangleShading) +
                 object_coords_.capacity() * sizeof(ObjectCoords);
  for (const auto& uv : tri_uvs_) bytes += uv.capacity() * sizeof(Vec2);
  for (const MeshData& m : meshes_) {
    bytes += m.positions.capacity() * sizeof(Vec3) + m.triangles.capacity() * sizeof(m.triangles[0]) +
             m.corner_normals.capacity() * sizeof(Vec3) + m.materials.capacity() * sizeof(uint32_t);
    for (const auto& uv : m.uvs) bytes += uv.capacity() * sizeof(Vec2);
  }
  return bytes;
}

bool Scene::build_geometry(int threads, BvhLayout layout) {
  const auto cancelled = [&] {
    if (!cancel_.load(std::memory_order_relaxed)) return false;
    tris_.clear();
    shading_.clear();
    bvh_.clear();
    geometry_dirty_ = true;
    return true;
  };
  tris_.clear();
  shading_.clear();
  size_t dropped = 0;
  size_t total = 0;
  for (const Instance& inst : instances_) total += meshes_[inst.mesh].triangles.size();
  tris_.reserve(total);
  shading_.reserve(total);
  size_t uv_sets = 0;
  for (const MeshData& m : meshes_) uv_sets = std::max(uv_sets, m.uvs.size());
  tri_uvs_.assign(uv_sets, {});
  for (size_t k = 0; k < uv_sets; ++k) {
    bool used = false;
    for (const MeshData& m : meshes_) used = used || (k < m.uvs.size() && !m.uvs[k].empty());
    if (used) tri_uvs_[k].reserve(3 * total);
  }
  object_coords_.clear();
  object_coords_.reserve(instances_.size());
  for (const Instance& inst : instances_) {
    if (cancelled()) return false;
    const MeshData& mesh = meshes_[inst.mesh];
    // Object and generated texture coordinates of this instance.
    Vec3 ts_loc = mesh.texspace_location, ts_size = mesh.texspace_size;
    if (!mesh.has_texspace) auto_texspace(mesh.positions, ts_loc, ts_size);
    object_coords_.push_back(make_object_coords(inst.matrix, ts_loc, ts_size));
    std::vector<Vec3> world(mesh.positions.size());
    for (size_t i = 0; i < world.size(); ++i) world[i] = inst.matrix.point(mesh.positions[i]);
    const bool smooth = !mesh.corner_normals.empty();
    for (size_t t = 0; t < mesh.triangles.size(); ++t) {
      const auto& idx = mesh.triangles[t];
      const TriangleVerts tv{world[idx[0]], world[idx[1]], world[idx[2]]};
      const Vec3 c = cross(tv.v1 - tv.v0, tv.v2 - tv.v0);
      // Zero-area or non-finite triangles can never be hit reliably and have no normal.
      // Coordinates beyond 1e30 cannot be traced meaningfully in float (their products overflow).
      const float big = std::max(max_component(vabs(tv.v0)), std::max(max_component(vabs(tv.v1)), max_component(vabs(tv.v2))));
      if (!is_finite(tv.v0) || !is_finite(tv.v1) || !is_finite(tv.v2) || !(length_sq(c) > 0.0f) ||
          !std::isfinite(length_sq(c)) || !(big < 1e30f)) {
        ++dropped;
        continue;
      }
      TriangleShading sh{};
      sh.material = mesh.materials.empty() ? 0u : mesh.materials[t];
      if (sh.material >= materials_.size()) sh.material = 0;
      sh.emitter = -1;
      sh.instance = uint32_t(object_coords_.size() - 1);
      if (smooth) {
        bool ok = true;
        for (int k = 0; k < 3; ++k) {
          const Vec3 n = inst.matrix.normal(mesh.corner_normals[3 * t + k]);
          const float l2 = length_sq(n);
          ok = ok && std::isfinite(l2) && l2 > 0.0f;
          sh.n[k] = ok ? n / std::sqrt(l2) : Vec3(0.0f);
        }
        if (!ok) sh.n[0] = sh.n[1] = sh.n[2] = Vec3(0.0f);  // bad normals: shade flat
      }
      tris_.push_back(tv);
      shading_.push_back(sh);
      for (size_t k = 0; k < uv_sets; ++k) {
        if (tri_uvs_[k].capacity() == 0) continue;
        const bool has = k < mesh.uvs.size() && !mesh.uvs[k].empty();
        for (int c = 0; c < 3; ++c) tri_uvs_[k].push_back(has ? mesh.uvs[k][3 * t + c] : Vec2{});
      }
    }
  }
  stats_.dropped_triangles += dropped;
  stats_.triangles = tris_.size();
  stats_.instances = instances_.size();
  stats_.meshes = meshes_.size();
  stats_.materials = materials_.size();

  BvhBuildOptions opt;
  opt.threads = threads;
  opt.layout = layout;
  opt.cancel = &cancel_;
  if (!bvh_.build(tris_, opt)) {  // only a cancel makes it fail
    cancelled();
    return false;
  }
  geometry_dirty_ = false;
  built_layout_ = layout;
  ++stats_.geometry_builds;
  return true;
}

void Scene::build_lights() {
  any_transparent_ = false;
  for (const Material& m : materials_) any_transparent_ = any_transparent_ || m.transparent;
  stats_.materials = materials_.size();
  for (TriangleShading& sh : shading_) sh.emitter = -1;

  // Every light in one distribution, chosen in proportion to an estimate of its power.
  const Aabb bounds = bvh_.bounds();
  const float radius = bounds.empty() ? 1.0f : std::max(0.5f * length(bounds.extent()), 1e-6f);
  std::vector<float> weights;
  for (const Light& l : lights_) weights.push_back(light_power(l, radius));
  emitter_prims_.clear();
  emitter_areas_.clear();
  for (uint32_t i = 0; i < tris_.size(); ++i) {
    const Vec3 le = materials_[shading_[i].material].emission_estimate;
    const float lum = std::max(luminance(le), max_component(le) * 1e-3f);
    if (!(lum > 0.0f) || !std::isfinite(lum)) continue;
    const TriangleVerts& tv = tris_[i];
    const float area = 0.5f * length(cross(tv.v1 - tv.v0, tv.v2 - tv.v0));
    shading_[i].emitter = static_cast<int32_t>(weights.size());
    emitter_prims_.push_back(i);
    emitter_areas_.push_back(area);
    weights.push_back(2.0f * kPi * area * lum);  // two-sided
  }
  env_index_ = SIZE_MAX;
  if (env_.valid() && env_.average_luminance() > 0.0f) {
    env_index_ = weights.size();
    weights.push_back(4.0f * kPi * kPi * radius * radius * env_.average_luminance());
  }
  light_dist_ = Distribution1D(weights);
  stats_.emissive_triangles = emitter_prims_.size();
  stats_.lights = lights_.size();
  ++stats_.light_builds;
}

void Scene::surface_point(const Hit& h, SurfacePoint& sp) const {
  const TriangleVerts& tv = tris_[h.prim];
  const TriangleShading& sh = shading_[h.prim];
  const float b0 = 1.0f - h.b1 - h.b2;
  // From barycentrics rather than org + t * dir: the error does not grow with the distance.
  sp.p = tv.v0 * b0 + tv.v1 * h.b1 + tv.v2 * h.b2;
  sp.p_error = barycentric_error(tv.v0, tv.v1, tv.v2, b0, h.b1, h.b2);
  sp.ng = normalize(cross(tv.v1 - tv.v0, tv.v2 - tv.v0));
  sp.ns = sp.ng;
  if (sh.n[0].x != 0.0f || sh.n[0].y != 0.0f || sh.n[0].z != 0.0f) {
    const Vec3 n = sh.n[0] * b0 + sh.n[1] * h.b1 + sh.n[2] * h.b2;
    const float l2 = length_sq(n);
    if (l2 > 1e-12f) sp.ns = n / std::sqrt(l2);
  }
  sp.material = sh.material;
  sp.prim = h.prim;
}

bool Scene::sample_direct(Vec3 p, float u_select, Vec2 u, DirectSample& s) const {
  if (light_dist_.empty()) return false;
  const size_t k = light_dist_.sample(u_select);
  const float pmf = light_dist_.pmf(k);
  if (!(pmf > 0.0f)) return false;
  s.target_normal = Vec3(0.0f);
  if (k < lights_.size()) {
    const Light& l = lights_[k];
    LightSample ls;
    if (!sample_light(l, p, u, ls)) return false;
    s.wi = ls.wi;
    s.dist = ls.dist;
    s.target = ls.target;
    s.li = ls.li;
    s.pdf = ls.pdf * pmf;
    s.delta = ls.delta;
    s.cast_shadow = l.cast_shadow;
    return true;
  }
  s.delta = false;
  s.cast_shadow = true;
  if (k == env_index_) {
    float pdf;
    if (!env_.sample(u, s.wi, s.li, pdf)) return false;
    s.dist = kInf;
    s.pdf = pdf * pmf;
    return true;
  }
  const size_t e = k - lights_.size();
  const uint32_t prim = emitter_prims_[e];
  const TriangleVerts& tv = tris_[prim];
  const Vec3 n = normalize(cross(tv.v1 - tv.v0, tv.v2 - tv.v0));
  float b1, b2;
  const SphericalTriangle st = spherical_triangle(p, tv.v0, tv.v1, tv.v2);
  const double omega = st.solid_angle;
  const bool spherical = solid_angle_triangles_ && use_spherical_sampling(omega);
  DVec3 w;
  if (spherical && sample_spherical_triangle(st, u, w)) {
    // The point where the sampled direction meets the triangle, as barycentrics (clamped into
    // the triangle against rounding: the direction's density stays 1 / omega either way).
    const DVec3 d0(tv.v0), e1 = DVec3(tv.v1) - d0, e2 = DVec3(tv.v2) - d0, nd = dcross(e1, e2);
    const double nn = ddot(nd, nd), wn = ddot(w, nd);
    if (!(std::fabs(wn) > 0.0)) return false;
    const DVec3 r = DVec3(p) + w * (ddot(d0 - DVec3(p), nd) / wn) - d0;
    double db1 = std::max(0.0, ddot(dcross(r, e2), nd) / nn), db2 = std::max(0.0, ddot(dcross(e1, r), nd) / nn);
    const double sum = db1 + db2;
    if (sum > 1.0) {
      db1 /= sum;
      db2 /= sum;
    }
    b1 = float(db1);
    b2 = float(db2);
  } else if (spherical) {
    return false;  // degenerate as seen from p: it subtends no solid angle
  } else {
    sample_triangle_uniform(u, b1, b2);
  }
  const Vec3 q = tv.v0 * (1.0f - b1 - b2) + tv.v1 * b1 + tv.v2 * b2;
  const Vec3 d = q - p;
  const float dist2 = length_sq(d);
  const float dist = std::sqrt(dist2);
  if (!(dist > 0.0f)) return false;
  s.wi = d / dist;
  const float cos_l = std::fabs(dot(n, s.wi));
  if (!(cos_l > 0.0f)) return false;
  s.dist = dist;
  s.target = q;
  s.target_normal = dot(n, s.wi) < 0.0f ? n : -n;  // the side facing p
  s.target_error = barycentric_error(tv.v0, tv.v1, tv.v2, 1.0f - b1 - b2, b1, b2);
  {
    // The material's emission at the sampled point (textured emission included).
    SurfacePoint lp;
    Hit h;
    h.prim = prim;
    h.b1 = b1;
    h.b2 = b2;
    surface_point(h, lp);
    ClosureList cl;
    shade(lp, b1, b2, -s.wi, cl);
    s.li = cl.emission;
  }
  s.pdf = spherical ? float(pmf / omega) : pmf / emitter_areas_[e] * dist2 / cos_l;
  return std::isfinite(s.pdf) && s.pdf > 0.0f;
}

void Scene::shade(const SurfacePoint& sp, float b1, float b2, Vec3 wo, ClosureList& out, bool shadow_ray) const {
  const Material& mat = materials_[sp.material];
  if (mat.constant) {
    out.n = mat.cached.n;
    out.emission = mat.cached.emission;
    out.has_nondelta = mat.cached.has_nondelta;
    const Frame f = Frame::from_normal(sp.ns);
    for (int i = 0; i < out.n; ++i) {
      Closure& c = out.c[size_t(i)];
      c = mat.cached.c[size_t(i)];
      // Glossy lobes: the normal lifted as eval_shader does (Cycles' valid specular reflection).
      c.frame = bsdf_wants_valid_reflection(c.bsdf) ? Frame::from_normal(valid_specular_normal(sp.ng, wo, sp.ns)) : f;
    }
    return;
  }
  ShadingContext ctx;
  ctx.p = sp.p;
  ctx.ng = sp.ng;
  ctx.ns = sp.ns;
  ctx.wo = wo;
  ctx.shadow_ray = shadow_ray;
  const TriangleVerts& hit_tri = tris_[sp.prim];
  const Vec3 corners[3] = {hit_tri.v0, hit_tri.v1, hit_tri.v2};
  ctx.tri = corners;  // for the Bump node's offsets
  ctx.object = &object_coords_[shading_[sp.prim].instance];
  constexpr int kMaxSets = 8;
  Vec2 uv[kMaxSets];
  Vec2 corner_uvs[3 * kMaxSets];
  Vec3 tangents[kMaxSets];
  float signs[kMaxSets];
  const int sets = static_cast<int>(std::min<size_t>(tri_uvs_.size(), kMaxSets));
  if (mat.program.uses_uv && sets > 0) {
    const float b0 = 1.0f - b1 - b2;
    const TriangleVerts& tv = tris_[sp.prim];
    for (int k = 0; k < sets; ++k) {
      const std::vector<Vec2>& t = tri_uvs_[size_t(k)];
      if (t.empty()) {
        uv[k] = {};
        corner_uvs[3 * k] = corner_uvs[3 * k + 1] = corner_uvs[3 * k + 2] = {};
        tangents[k] = Vec3(0.0f);
        signs[k] = 1.0f;
        continue;
      }
      const Vec2 a = t[3 * size_t(sp.prim)], b = t[3 * size_t(sp.prim) + 1], c = t[3 * size_t(sp.prim) + 2];
      uv[k] = {a.x * b0 + b.x * b1 + c.x * b2, a.y * b0 + b.y * b1 + c.y * b2};
      corner_uvs[3 * k] = a;
      corner_uvs[3 * k + 1] = b;
      corner_uvs[3 * k + 2] = c;
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
    ctx.uv = uv;
    ctx.uv_sets = sets;
    ctx.tangents = tangents;
    ctx.tangent_signs = signs;
    ctx.tri_uv = corner_uvs;
  }
  eval_shader(mat.program, images_, ctx, out);
}

Vec3 Scene::transmittance(Ray ray) const {
  if (!any_transparent_) return bvh_.occluded(ray) ? Vec3(0.0f) : Vec3(1.0f);
  Vec3 T(1.0f);
  for (int i = 0; i < 64; ++i) {  // bounded: stacked alpha cards
    Hit h;
    if (!bvh_.intersect(ray, h)) return T;
    SurfacePoint sp;
    surface_point(h, sp);
    const Material& mat = materials_[sp.material];
    if (!mat.transparent) return Vec3(0.0f);
    ClosureList cl;
    shade(sp, h.b1, h.b2, -normalize(ray.dir), cl, true);
    Vec3 pass(0.0f);
    for (int c = 0; c < cl.n; ++c)
      if (std::holds_alternative<TransparentBsdf>(cl.c[size_t(c)].bsdf)) pass += cl.c[size_t(c)].weight;
    T = T * vmin(pass, Vec3(1.0f));
    if (!(max_component(T) > 0.0f)) return Vec3(0.0f);
    // Continue just past the surface towards the same end point (or to infinity).
    const Vec3 side = dot(ray.dir, sp.ng) > 0.0f ? sp.ng : -sp.ng;
    const Vec3 org = offset_ray_origin(sp.p, sp.p_error, side);
    if (std::isfinite(ray.tmax)) {
      const Vec3 end = ray.org + ray.dir * ray.tmax;
      ray.dir = end - org;
      ray.tmax = 1.0f;
    }
    ray.org = org;
  }
  return Vec3(0.0f);
}

float Scene::pdf_emitter(uint32_t prim, Vec3 from, Vec3 at, float cos_l) const {
  const int32_t k = shading_[prim].emitter;
  if (k < 0 || !(cos_l > 0.0f)) return 0.0f;
  const float pmf = light_dist_.pmf(size_t(k));
  // The same choice of technique as sample_direct made from this point.
  const TriangleVerts& tv = tris_[prim];
  const double omega = spherical_triangle(from, tv.v0, tv.v1, tv.v2).solid_angle;
  if (solid_angle_triangles_ && use_spherical_sampling(omega)) return float(pmf / omega);
  const float t2 = length_sq(at - from);
  return pmf / emitter_areas_[size_t(k) - lights_.size()] * t2 / cos_l;
}

float Scene::pdf_environment(Vec3 dir) const {
  if (env_index_ == SIZE_MAX) return 0.0f;
  return light_dist_.pmf(env_index_) * env_.pdf(dir);
}

}  // namespace pl
