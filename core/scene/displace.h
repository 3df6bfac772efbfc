// True displacement (Cycles' mesh_displace.cpp, without adaptive subdivision): every vertex of
// a triangle whose material has a displacement program moves by that program's offset at the
// vertex, before the BVH is built (docs/design/displacement.md).
#pragma once
#include <cstdint>
#include <vector>

#include "scene/scene.h"

namespace pl {

struct DisplaceStats {
  size_t displaced = 0;  // vertices moved (evaluated)
  size_t clamped = 0;    // offsets that were non-finite (dropped) or longer than kMaxDisplacement
};
// Offsets longer than this (world units) are shortened to it: the BVH's float bounds and the
// ray offsets stay meaningful.
constexpr float kMaxDisplacement = 1e4f;

// Displaces `mesh` (object space) in place by its materials' displacement programs
// (Material::displacement), shaded as the instance `to_world` places it: the program runs at each
// vertex once, at the corner of the first displaced triangle that uses it (its uvs, attributes
// and shading normal; flat[t] true: triangle t is flat shaded, the normal its face's), and the
// world offset moves the vertex (and its deformation-blur steps) in object space. Then the
// shading normals: flat triangles take their displaced face's; smooth corners of vertices that a
// 'DISPLACEMENT' material moved take the mean of the displaced unit face normals around them
// (those triangles only); the rest keep theirs ('BOTH': the bump does the rest), as Cycles.
// `flat` may be empty (all smooth). Nothing changes where no triangle's material displaces.
DisplaceStats displace_mesh(MeshData& mesh, const Scene& scene, const Mat4& to_world, const std::vector<uint8_t>& flat);

}  // namespace pl
