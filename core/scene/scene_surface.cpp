// Ray hits on the scene's surfaces: the surface point at a hit (triangles and curves) and
// intersection with one instance alone.
#include "scene/scene.h"
#include "scene/scene_detail.h"

namespace pl {

using detail::material_of;

void Scene::curve_point(const Hit& h, SurfacePoint& sp, float time, const Ray* ray) const {
  const CurvePiece c = curve_bvh_.piece_at(h.prim, time);  // (moving sets: where the ray met it)
  if (c.ribbon) {
    // The point on the ray (as Cycles' P + D t), the rounded normal as both normals: Cycles'
    // closures take their side from it on curves (bsdf_sample's Ng = N), and Chiang's and
    // Huang's h from it are Cycles' -v. (Its Ng, the view, only faces the viewer.)
    Vec3 dir, p;
    if (ray) {
      dir = ray->dir;
      p = ray->org + ray->dir * h.t;
      sp.p_error = (vabs(ray->org) + vabs(ray->dir * h.t)) * gamma_bound(8);
    } else {  // seen from across the strand: its point from (u, v)
      const Vec3 axis = c.p1 - c.p0;
      Vec3 x, y;
      make_basis(length_sq(axis) > 0.0f ? normalize(axis) : Vec3(0.0f, 0.0f, 1.0f), x, y);
      dir = -x;
      const float u = clampf(h.b1, 0.0f, 1.0f);
      p = c.p0 + axis * u + y * (clampf(h.b2, -1.0f, 1.0f) * (c.r0 + (c.r1 - c.r0) * u));
      sp.p_error = (vabs(p) + Vec3(std::max(c.r0, c.r1))) * gamma_bound(16);
    }
    Vec3 n, tangent;
    ribbon_surface(c, h.b1, h.b2, dir, n, tangent);
    sp.p = p;
    sp.ng = sp.ns = n;
    sp.tangent = tangent;
  } else {
    // The hit from the ray is only good to its t's error; the point on the surface is better.
    Vec3 n, tangent, p, err;
    float u;
    piece_surface(c, h.b1, h.b2, n, tangent, p, err, u);
    sp.p = p;
    sp.p_error = err;
    sp.ng = sp.ns = n;
    sp.tangent = tangent;
  }
  sp.material = c.curve < curve_material_.size() ? curve_material_[c.curve] : 0;
  sp.prim = uint32_t(stats_.triangles) + c.curve;
  sp.instance = kCurveInstance;
  sp.tri = h.prim;
}

void Scene::sphere_point(const Hit& h, SurfacePoint& sp, float time) const {
  PointFrame moved;
  const PointFrame* frame = nullptr;
  const PointSphere s = point_bvh_.world_sphere(h.prim, time, moved, frame);
  // From the hit's normal: the point lies on the sphere, whatever the error of t.
  Vec3 n, p, err;
  sphere_surface(s, frame, h.b1, h.b2, n, p, err);
  sp.p = p;
  sp.p_error = err;
  sp.ng = sp.ns = n;
  sp.tangent = Vec3(0.0f);
  const uint32_t set = point_set_of(s.point);
  sp.material = point_sets_[set].material < materials_.size() ? point_sets_[set].material : 0;
  sp.prim = uint32_t(stats_.triangles + stats_.curves) + s.point;
  sp.instance = kPointInstance;
  sp.tri = h.prim;
  sp.b1 = sp.b2 = 0.0f;  // Cycles' u, v on points
}

bool Scene::intersect_local(uint32_t instance, const Ray& r, Hit& h) const {
  if (instance >= inst_.size()) return false;
  const InstanceData& in = inst_[instance];
  if (in.blas == UINT32_MAX) return false;
  if (in.transformed) {  // its own object-space BLAS, the ray carried there (world distances)
    float dt;
    const Ray o = ray_to_object(in.to_object, r, dt);
    if (!blases_[in.blas].bvh.intersect(o, h)) return false;
    h.t += dt;
  } else {
    if (instance >= local_index_.size() || local_index_[instance] == UINT32_MAX) return false;
    if (!local_bvhs_[local_index_[instance]].intersect(r, h)) return false;
    h.prim += in.tri_base;
  }
  h.inst = instance;
  return true;
}

[[gnu::always_inline]] inline void Scene::surface_point_in(const InstanceData& in, const TriangleVerts& tv, const Hit& h,
                                                           SurfacePoint& sp) const {
  const Blas& b = blases_[in.blas];
  const uint32_t st = b.src_tri[h.prim];
  const MeshData& mesh = meshes_[in.mesh];
  const float b0 = 1.0f - h.b1 - h.b2;
  triangle_point(in, tv, h.b1, h.b2, sp.p, sp.p_error);
  if (!in.transformed) {
    sp.ng = tv.unit_normal();
  } else {
    // Cofactors map the object-space edge cross product to the world one (winding included).
    const Vec3 c = cross(tv.v1 - tv.v0, tv.v2 - tv.v0);
    sp.ng = normalize(in.nrow[0] * c.x + in.nrow[1] * c.y + in.nrow[2] * c.z);
  }
  sp.ns = sp.ng;
  if (!mesh.normals.empty()) {
    const std::array<uint32_t, 3>& ni = mesh.normal_indices.empty() ? mesh.triangles[st] : mesh.normal_indices[st];
    Vec3 n[3];
    bool ok = true;
    for (int k = 0; k < 3 && ok; ++k) {
      n[k] = in.normal(mesh.normals[ni[k]]);
      const float l2 = length_sq(n[k]);
      ok = std::isfinite(l2) && l2 > 0.0f;
      n[k] = n[k] / std::sqrt(l2);
    }
    if (ok) {  // bad normals: shade flat
      const Vec3 ni = n[0] * b0 + n[1] * h.b1 + n[2] * h.b2;
      const float l2 = length_sq(ni);
      if (l2 > 1e-12f) sp.ns = ni / std::sqrt(l2);
    }
  }
  sp.b1 = h.b1;
  sp.b2 = h.b2;
  sp.material = material_of(mesh, st, materials_.size());
  sp.prim = global_prim(h);
  sp.instance = h.inst;
  sp.tri = h.prim;
}

void Scene::surface_point(const Hit& h, SurfacePoint& sp, float time, const Ray* ray) const {
  sp.time = time;
  if (h.inst == kCurveInstance) return curve_point(h, sp, time, ray);  // (moving sets: at the ray's time)
  if (h.inst == kPointInstance) return sphere_point(h, sp, time);  // (moving clouds: at the ray's time)
  const InstanceData& in = inst_[h.inst];
  if (__builtin_expect(in.motion != nullptr || in.deform != nullptr, 0)) {  // where the ray met it
    InstanceData moved = in;
    if (in.motion) set_instance_matrix(moved, motion_transform_at(in.motion, in.motion_steps, time));
    const TriangleVerts tv = in.deform ? in.deform->triangle_at(h.prim, time) : blases_[in.blas].tris[h.prim];
    surface_point_in(moved, tv, h, sp);
    if (in.deform && (sp.ns.x != sp.ng.x || sp.ns.y != sp.ng.y || sp.ns.z != sp.ng.z)) {
      // The frame's shading normals turned with their triangle: the rotation that takes the
      // frame's geometric normal to this time's (Rodrigues, w = a x b, c = a . b).
      const TriangleVerts& still = blases_[in.blas].tris[h.prim];
      const Vec3 e = cross(still.v1 - still.v0, still.v2 - still.v0);  // as surface_point_in's ng
      const Vec3 a = normalize(moved.nrow[0] * e.x + moved.nrow[1] * e.y + moved.nrow[2] * e.z);
      const Vec3 b = sp.ng, w = cross(a, b);
      const float c = dot(a, b);
      if (c > -0.99f && is_finite(a)) {
        const Vec3 v = sp.ns, wv = cross(w, v);
        const Vec3 r = v + wv + cross(w, wv) * (1.0f / (1.0f + c));
        const float l2 = length_sq(r);
        if (l2 > 0.0f && std::isfinite(l2)) sp.ns = r / std::sqrt(l2);
      }
    }
    return;
  }
  surface_point_in(in, blases_[in.blas].tris[h.prim], h, sp);
}

}  // namespace pl

namespace pl {

Vec3 Scene::terminator_lift(const SurfacePoint& sp, Vec3 ng, float amount) const {
  // Cycles' shadow_ray_smooth_surface_offset (kernel/light/sample.h), in world space.
  if (sp.curve() || sp.point() || sp.instance >= inst_.size()) return sp.p;
  const InstanceData& in = inst_[sp.instance];
  if (in.blas == UINT32_MAX || in.motion != nullptr || in.deform != nullptr) return sp.p;
  const MeshData& mesh = meshes_[in.mesh];
  if (mesh.normals.empty()) return sp.p;
  const Blas& b = blases_[in.blas];
  const TriangleVerts tv = world_triangle(in, b.tris[sp.tri]);
  const uint32_t st = b.src_tri[sp.tri];
  const std::array<uint32_t, 3>& ni = mesh.normal_indices.empty() ? mesh.triangles[st] : mesh.normal_indices[st];
  const Vec3 V[3] = {tv.v0, tv.v1, tv.v2};
  Vec3 N[3];
  for (int k = 0; k < 3; ++k) {
    N[k] = in.normal(mesh.normals[ni[k]]);
    const float l2 = length_sq(N[k]);
    if (!(l2 > 0.0f) || !std::isfinite(l2)) return sp.p;
    N[k] = N[k] / std::sqrt(l2);
  }
  // Barycentrics of V0, V1 (Cycles' u, v) and V2.
  const float u = 1.0f - sp.b1 - sp.b2, v = sp.b1, w = sp.b2;
  const Vec3 P = V[0] * u + V[1] * v + V[2] * w;
  const Vec3 n = N[0] * u + N[1] * v + N[2] * w;  // unnormalised, as Cycles
  // The parabolic approximation of the smooth surface, bounded by its linear envelopes.
  const float a = dot(N[2] - N[0], V[0] - V[2]);
  const float bb = dot(N[2] - N[1], V[1] - V[2]);
  const float c = dot(N[1] - N[0], V[1] - V[0]);
  float h = a * u * (u - 1.0f) + (a + bb + c) * u * v + bb * v * (v - 1.0f);
  if (dot(n, ng) > 0.0f) {
    float h0 = std::max(std::max(dot(V[1] - V[0], N[0]), dot(V[2] - V[0], N[0])), 0.0f);
    float h1 = std::max(std::max(dot(V[0] - V[1], N[1]), dot(V[2] - V[1], N[1])), 0.0f);
    float h2 = std::max(std::max(dot(V[0] - V[2], N[2]), dot(V[1] - V[2], N[2])), 0.0f);
    h0 = std::max(dot(V[0] - P, N[0]) + h0, 0.0f);
    h1 = std::max(dot(V[1] - P, N[1]) + h1, 0.0f);
    h2 = std::max(dot(V[2] - P, N[2]) + h2, 0.0f);
    h = std::max(std::min(std::min(h0, h1), h2), h * 0.5f);
  } else {
    float h0 = std::max(std::max(dot(V[0] - V[1], N[0]), dot(V[0] - V[2], N[0])), 0.0f);
    float h1 = std::max(std::max(dot(V[1] - V[0], N[1]), dot(V[1] - V[2], N[1])), 0.0f);
    float h2 = std::max(std::max(dot(V[2] - V[0], N[2]), dot(V[2] - V[1], N[2])), 0.0f);
    h0 = std::max(dot(P - V[0], N[0]) + h0, 0.0f);
    h1 = std::max(dot(P - V[1], N[1]) + h1, 0.0f);
    h2 = std::max(dot(P - V[2], N[2]) + h2, 0.0f);
    h = std::min(-std::min(std::min(h0, h1), h2), h * 0.5f);
  }
  const Vec3 lifted = sp.p + n * (h * amount);
  return is_finite(lifted) ? lifted : sp.p;
}

}  // namespace pl

namespace pl {

std::vector<uint32_t> Scene::instance_prims(uint32_t instance) const {
  if (instance >= inst_.size() || instance >= instances_.size()) return {};
  const InstanceData& in = inst_[instance];
  const MeshData& mesh = meshes_[instances_[instance].mesh];
  std::vector<uint32_t> out(mesh.triangles.size(), UINT32_MAX);
  if (in.blas == UINT32_MAX) return out;
  // The instance's run of its BLAS (merged: [tri_base, tri_base + kept); its own: all of it).
  const Blas& b = blases_[in.blas];
  for (uint32_t k = in.tri_base; k < in.tri_base + in.kept && k < b.src_tri.size(); ++k)
    if (b.src_tri[k] < out.size()) out[b.src_tri[k]] = k;
  return out;
}

}  // namespace pl

namespace pl {

bool Scene::instance_triangle(uint32_t instance, uint32_t prim, Vec3& v0, Vec3& v1, Vec3& v2) const {
  if (instance >= inst_.size()) return false;
  const InstanceData& in = inst_[instance];
  if (in.blas == UINT32_MAX || prim >= blases_[in.blas].tris.size()) return false;
  const TriangleVerts tv = world_triangle(in, blases_[in.blas].tris[prim]);
  v0 = tv.v0, v1 = tv.v1, v2 = tv.v2;
  return true;
}

}  // namespace pl
