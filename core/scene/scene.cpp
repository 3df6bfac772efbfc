#include "scene/scene.h"

#include <stdexcept>

namespace pl {

Scene::Scene() {
  // Material 0: the fallback grey diffuse for unassigned or out-of-range slots.
  materials_.push_back(Material{"Default", DiffuseBsdf{Vec3(0.8f)}, Vec3(0.0f)});
}

uint32_t Scene::add_material(Material m) {
  materials_.push_back(std::move(m));
  committed_ = false;
  return static_cast<uint32_t>(materials_.size() - 1);
}

uint32_t Scene::add_mesh(MeshData mesh) {
  meshes_.push_back(std::move(mesh));
  committed_ = false;
  return static_cast<uint32_t>(meshes_.size() - 1);
}

void Scene::add_instance(uint32_t mesh, const Mat4& m) {
  if (mesh >= meshes_.size()) throw std::invalid_argument("add_instance: unknown mesh id");
  instances_.push_back({mesh, m});
  committed_ = false;
}

void Scene::commit(int threads) {
  tris_.clear();
  shading_.clear();
  size_t dropped = 0;
  size_t total = 0;
  for (const Instance& inst : instances_) total += meshes_[inst.mesh].triangles.size();
  tris_.reserve(total);
  shading_.reserve(total);
  for (const Instance& inst : instances_) {
    const MeshData& mesh = meshes_[inst.mesh];
    std::vector<Vec3> world(mesh.positions.size());
    for (size_t i = 0; i < world.size(); ++i) world[i] = inst.matrix.point(mesh.positions[i]);
    const bool smooth = !mesh.corner_normals.empty();
    for (size_t t = 0; t < mesh.triangles.size(); ++t) {
      const auto& idx = mesh.triangles[t];
      const TriangleVerts tv{world[idx[0]], world[idx[1]], world[idx[2]]};
      const Vec3 c = cross(tv.v1 - tv.v0, tv.v2 - tv.v0);
      // Zero-area or non-finite triangles can never be hit reliably and have no normal.
      if (!is_finite(tv.v0) || !is_finite(tv.v1) || !is_finite(tv.v2) || !(length_sq(c) > 0.0f) ||
          !std::isfinite(length_sq(c))) {
        ++dropped;
        continue;
      }
      TriangleShading sh{};
      sh.material = mesh.materials.empty() ? 0u : mesh.materials[t];
      if (sh.material >= materials_.size()) sh.material = 0;
      sh.emitter = -1;
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
    }
  }
  stats_.dropped_triangles += dropped;
  stats_.triangles = tris_.size();
  stats_.instances = instances_.size();
  stats_.meshes = meshes_.size();
  stats_.materials = materials_.size();

  BvhBuildOptions opt;
  opt.threads = threads;
  bvh_.build(tris_, opt);

  // Every light in one distribution, chosen in proportion to an estimate of its power.
  const Aabb bounds = bvh_.bounds();
  const float radius = bounds.empty() ? 1.0f : std::max(0.5f * length(bounds.extent()), 1e-6f);
  std::vector<float> weights;
  for (const Light& l : lights_) weights.push_back(light_power(l, radius));
  emitter_prims_.clear();
  emitter_areas_.clear();
  for (uint32_t i = 0; i < tris_.size(); ++i) {
    const Vec3 le = materials_[shading_[i].material].emission;
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
  committed_ = true;
}

void Scene::surface_point(const Hit& h, SurfacePoint& sp) const {
  const TriangleVerts& tv = tris_[h.prim];
  const TriangleShading& sh = shading_[h.prim];
  const float b0 = 1.0f - h.b1 - h.b2;
  // From barycentrics rather than org + t * dir: the error does not grow with the distance.
  sp.p = tv.v0 * b0 + tv.v1 * h.b1 + tv.v2 * h.b2;
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
  float b1, b2;
  sample_triangle_uniform(u, b1, b2);
  const Vec3 q = tv.v0 * (1.0f - b1 - b2) + tv.v1 * b1 + tv.v2 * b2;
  const Vec3 n = normalize(cross(tv.v1 - tv.v0, tv.v2 - tv.v0));
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
  s.li = materials_[shading_[prim].material].emission;
  s.pdf = pmf / emitter_areas_[e] * dist2 / cos_l;
  return std::isfinite(s.pdf) && s.pdf > 0.0f;
}

float Scene::pdf_emitter(uint32_t prim, float t, float cos_l) const {
  const int32_t k = shading_[prim].emitter;
  if (k < 0 || !(cos_l > 0.0f)) return 0.0f;
  return light_dist_.pmf(size_t(k)) / emitter_areas_[size_t(k) - lights_.size()] * t * t / cos_l;
}

float Scene::pdf_environment(Vec3 dir) const {
  if (env_index_ == SIZE_MAX) return 0.0f;
  return light_dist_.pmf(env_index_) * env_.pdf(dir);
}

}  // namespace pl
