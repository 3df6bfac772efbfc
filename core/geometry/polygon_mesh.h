// Polygon meshes (faces as runs of corners, each corner naming a vertex) turned into what the
// scene takes: triangles and smooth vertex normals. The exporter reads faces as flat arrays,
// which is much cheaper than reading a host application's own triangulation element by element.
#pragma once
#include <cstddef>
#include <cstdint>

#include "util/math.h"

namespace pl {

// Face f has corners [offsets[f], offsets[f + 1]); corner c uses vertex corner_verts[c].
struct PolygonMesh {
  const Vec3* positions = nullptr;
  size_t vertices = 0;
  const int32_t* corner_verts = nullptr;
  size_t corners = 0;
  const int32_t* offsets = nullptr;  // faces + 1 entries
  size_t faces = 0;
};

// Throws std::invalid_argument unless offsets start at 0, end at `corners`, every face has
// 3 or more corners and every corner's vertex is in range.
void validate_polygon_mesh(const PolygonMesh& mesh);

// Triangles are numbered face by face, face f's from offsets[f] - 2 f on (corners - 2 each).
size_t polygon_mesh_triangles(const PolygonMesh& mesh);

// Writes 3 corner indices per triangle into out (polygon_mesh_triangles() * 3 entries).
// Triangles keep their face's winding. A quad is split along its 0-2 diagonal unless the two
// halves face away from each other, then along 1-3, with the same single-precision arithmetic
// and corner order as Blender's tessellation (mesh_tessellate.cc), so the exported triangles are
// the ones Blender shows. Faces of 5 or more corners get a fan from their first corner: the
// caller replaces those (the return value counts them; Blender's n-gon fill is not reproduced).
// out and verts (the triangles' vertex indices, same size) may each be null (not wanted).
size_t triangulate_polygons(const PolygonMesh& mesh, uint32_t* out, uint32_t* verts = nullptr, int threads = 0);

// Face offsets (faces + 1 entries) from the face of every triangle of a triangulation that lists
// them face by face (as triangulate_polygons and Blender's loop triangles do: a face of k corners
// has k - 2 triangles). False, with offsets unspecified, unless tri_faces is in that order, every
// face has a triangle and the corners add up to `corners`.
bool polygon_offsets_from_triangle_faces(const int32_t* tri_faces, size_t tris, size_t faces, size_t corners,
                                         int32_t* offsets);

// Smooth vertex normals: per vertex, the sum of its faces' unit (Newell) normals weighted by
// the face's angle at that corner, normalised; a vertex of no face gets its normalised position.
// The weights use the same arccos approximation as Blender's (within 5e-5 of acos), so the
// normals agree with Blender's vertex normals to float rounding. Each vertex sums in face order, so
// the result is bit for bit the same on any number of threads.
void polygon_vertex_normals(const PolygonMesh& mesh, Vec3* out, int threads = 0);

// Per-corner normals with sharp edges and faces: corners around a vertex form smooth fans across
// edges that are used by exactly two faces in opposite directions and are neither marked sharp
// nor border a sharp face; a fan's normal is the angle-weighted sum of its faces' normals,
// normalised (a fan of one corner: its face's normal). corner_edges[c]: the edge from corner c
// to the next corner of its face (< edges); sharp_edges (edges) and sharp_faces (faces) may be
// null (none sharp). Blender's corner normals without custom normals, to float rounding. Each fan
// sums its corners in corner order, so the result is bit for bit the same on any number of threads.
void polygon_corner_normals(const PolygonMesh& mesh, const int32_t* corner_edges, size_t edges,
                            const uint8_t* sharp_edges, const uint8_t* sharp_faces, Vec3* out, int threads = 0);

}  // namespace pl
