// What the scene's translation units share: included by scene_build.cpp, scene_lights.cpp,
// scene_features.cpp and scene_surface.cpp alone.
#pragma once

#include "scene/scene.h"

namespace pl {
namespace detail {

// A mesh triangle's material id, the default (0) where it is out of range.
inline uint32_t material_of(const MeshData& m, uint32_t tri, size_t materials) {
  const uint32_t id = m.materials.empty() ? 0u : m.materials[tri];
  return id < materials ? id : 0u;
}

}  // namespace detail

// Inline here, not in one unit: surface points and light samples both compute it per ray.
[[gnu::always_inline]] inline void Scene::triangle_point(const InstanceData& in, const TriangleVerts& tv, float b1, float b2, Vec3& p,
                                  Vec3& p_error) {
  const float b0 = 1.0f - b1 - b2;
  // From barycentrics rather than org + t * dir: the error does not grow with the distance.
  if (!in.transformed) {
    p = tv.v0 * b0 + tv.v1 * b1 + tv.v2 * b2;
    p_error = barycentric_error(tv.v0, tv.v1, tv.v2, b0, b1, b2);
  } else {
    // The object-space point carried to world space with its error bound grown by the transform.
    const Vec3 po = tv.v0 * b0 + tv.v1 * b1 + tv.v2 * b2;
    p = in.to_world.point(po);
    p_error = transform_point_error(in.to_world, po, barycentric_error(tv.v0, tv.v1, tv.v2, b0, b1, b2));
  }
}

}  // namespace pl
