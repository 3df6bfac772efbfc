// The top level of a two-level BVH: a binned SAH tree over instances (one per leaf), each a
// bottom-level Bvh (in its own object space) and an affine transform, collapsed into 8-wide
// nodes tested four lanes per SSE operation, nearest child first. Traversal carries the ray
// into object space per instance with its direction unnormalised, so hit distances stay world
// distances; identity and translation-only instances skip the matrix products. Like Bvh, it
// knows triangles and transforms only; hits name (instance, triangle).
#pragma once
#include <cstdint>
#include <vector>

#include "geometry/bvh.h"
#include "geometry/deform_bvh.h"
#include "geometry/motion.h"

namespace pl {

// How a ray reaches an instance's BLAS space, decided by Tlas::build from the matrices alone
// (so a moved instance is traced exactly as a freshly added one with the same matrix).
enum class TlasSpace : uint8_t {
  World,      // identity (or `identity`): the ray as it is
  Translated, // the linear part is the identity: the origin only moves
  Affine,     // the full transform
  Motion,     // motion blur: the transform at the ray's time, interpolated between steps
};

struct TlasInstance {
  const Bvh* blas = nullptr;  // must outlive the Tlas (or its next build)
  Mat4 to_world;              // object -> world (affine)
  Mat4 to_object;             // its inverse
  bool identity = false;      // the BLAS is already in world space: no ray transform
  TlasSpace space = TlasSpace::Affine;  // set by Tlas::build
  // Motion blur: motion_steps (>= 2) decomposed transforms over the shutter, which must outlive
  // the Tlas; to_world / to_object are then unused. nullptr: a static instance.
  const DecomposedTransform* motion = nullptr;
  uint32_t motion_steps = 0;
  // Deformation blur: traced instead of `blas` (same triangle numbering; must outlive the Tlas).
  const DeformBvh* deform = nullptr;
  // Set by Tlas::build: to_object is finite (entering the instance skips the rounding bound's
  // terms of the origin's own error, exact zeros then).
  bool finite = false;
};

// Bound of the rounding error of M.point(p) where p itself carries the error p_error
// (pbrt-v4's Transform of a Point3fi): |M| p_error (1 + gamma3) + gamma3 (|M| |p| + |t|).
inline Vec3 transform_point_error(const Mat4& m, Vec3 p, Vec3 p_error) {
  Vec3 e;
  const float g = gamma_bound(3);
  for (int i = 0; i < 3; ++i) {
    const float ap = std::fabs(m.m[i][0] * p.x) + std::fabs(m.m[i][1] * p.y) + std::fabs(m.m[i][2] * p.z) +
                     std::fabs(m.m[i][3]);
    const float ae = std::fabs(m.m[i][0]) * p_error.x + std::fabs(m.m[i][1]) * p_error.y +
                     std::fabs(m.m[i][2]) * p_error.z;
    e[i] = (g + 1.0f) * ae + g * ap;
  }
  return e;
}

// Moves a transformed ray's origin forward past its rounding error `err` (pbrt-v4): the
// transformed origin of a spawned ray cannot land behind the surface it left. `dt` is that move
// in ray parameter units: world t = object t + dt.
inline void offset_past_error(Ray& o, const Vec3& err, float world_tmax, float& dt) {
  const float l2 = length_sq(o.dir);
  dt = l2 > 0.0f ? dot(vabs(o.dir), err) / l2 : 0.0f;
  if (!std::isfinite(dt)) dt = 0.0f;
  o.org += o.dir * dt;
  o.tmax = world_tmax - dt;
}

// The ray in an instance's object space, origin moved forward past its own rounding error.
inline Ray ray_to_object(const Mat4& to_object, const Ray& r, float& dt) {
  Ray o;
  o.time = r.time;
  o.org = to_object.point(r.org);
  o.dir = to_object.vector(r.dir);
  const Vec3 err = transform_point_error(to_object, r.org, Vec3(0.0f));
  offset_past_error(o, err, r.tmax, dt);
  return o;
}

// ray_to_object for a finite to_object: the same bits. The bound's terms of the origin's own
// error are exact zeros there, and (1 + g) * 0 + g * x is g * x.
inline Ray ray_to_object_finite(const Mat4& to_object, const Ray& r, float& dt) {
  Ray o;
  o.time = r.time;
  o.org = to_object.point(r.org);
  o.dir = to_object.vector(r.dir);
  const Mat4& m = to_object;
  const Vec3 p = r.org;
  const float g = gamma_bound(3);
  Vec3 err;
  for (int i = 0; i < 3; ++i)
    err[i] = g * (std::fabs(m.m[i][0] * p.x) + std::fabs(m.m[i][1] * p.y) + std::fabs(m.m[i][2] * p.z) +
                  std::fabs(m.m[i][3]));
  offset_past_error(o, err, r.tmax, dt);
  return o;
}

// ray_to_object for a to_object whose linear part is the identity: the same origin, error bound
// and move (the products by 1 and 0 are exact), without the matrix products.
inline Ray ray_to_object_translated(const Mat4& to_object, const Ray& r, float& dt) {
  Ray o;
  o.time = r.time;
  const Vec3 t{to_object.m[0][3], to_object.m[1][3], to_object.m[2][3]};
  o.org = r.org + t;
  o.dir = r.dir;
  const float g = gamma_bound(3);
  const Vec3 err = (vabs(r.org) + vabs(t)) * g;
  offset_past_error(o, err, r.tmax, dt);
  return o;
}

struct TlasStats {
  size_t instances = 0, nodes = 0;
  double build_ms = 0.0;
};

// Top-level nodes are 8 wide: a node holds the boxes of up to 8 children (interior nodes or
// instances, count 1) in rows, as the wide BVH does.
using TlasNode = WideBvhNode<8>;

class Tlas {
 public:
  // Builds over the instances (copied); hit.inst names the index in `instances`. Instances with
  // an empty BLAS or a non-finite world box are left out.
  void build(std::vector<TlasInstance> instances);
  void clear();
  bool empty() const { return nodes_.empty(); }
  Aabb bounds() const { return bounds_; }
  const TlasStats& stats() const { return stats_; }
  size_t memory_bytes() const { return nodes_.capacity() * sizeof(TlasNode) + insts_.capacity() * sizeof(TlasInstance); }

  // Closest hit with 0 < t < ray.tmax; fills hit (prim: the BLAS's triangle, inst: the instance).
  bool intersect(const Ray& ray, Hit& hit, TraversalCounters* counters = nullptr) const;
  // Any hit certainly before ray.tmax (the BLAS's any-hit contract), stops at the first.
  bool occluded(const Ray& ray) const;

 private:
  std::vector<TlasNode> nodes_;     // 8 wide, root first; a lane with count 1 names an instance
  std::vector<TlasInstance> insts_;
  Aabb bounds_;
  TlasStats stats_;
};

}  // namespace pl
