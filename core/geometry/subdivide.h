// Adaptive subdivision (Cycles' experimental feature set): a polygon cage's Catmull-Clark limit
// surface (or its Simple, bilinear subdivision) diced into triangles whose edges project to about
// `dicing_rate` pixels, with one edge factor per shared edge so neighbouring patches meet exactly
// (docs/design/displacement.md#adaptive-subdivision).
#pragma once
#include <cstddef>
#include <cstdint>
#include <vector>

#include "geometry/polygon_mesh.h"
#include "util/math.h"

namespace pl {

struct SubdivisionCage {
  PolygonMesh mesh;                      // object space; validated by the caller
  const int32_t* crease_edges = nullptr;  // vertex pairs (2 per crease)
  const float* crease_sharpness = nullptr;
  size_t creases = 0;
  const float* vertex_sharpness = nullptr;  // per vertex or null
  bool catmull_clark = true;                // false: Simple (bilinear)
  bool smooth_corners = true;               // Blender's boundary_smooth 'ALL' (else PRESERVE_CORNERS)
};

// Where the edge factors come from: the edge's length in pixels, measured as Cycles'
// DiagSplit::T does (three samples, the camera's pixel footprint at each midpoint).
struct DicingCamera {
  Mat4 to_world;             // object to world
  Vec3 position;             // camera position (world)
  bool ortho = false;
  float pixel_size = 1e-3f;  // world size of a pixel: per unit distance (perspective) or absolute
  float dicing_rate = 1.0f;  // target edge length in pixels
  int max_level = 12;        // edge factors up to 2^max_level
  // Cycles' offscreen_dicing_scale (Camera::world_to_raster_size): outside the camera's view the
  // pixel footprint grows with the distance to the view, so off-screen geometry (seen only in
  // reflections and shadows) is diced coarser. <= 1: off.
  float offscreen_scale = 1.0f;
  Vec3 right{1, 0, 0}, up{0, 1, 0}, forward{0, 0, -1};  // camera axes (world, unit)
  float frame[4] = {-1, 1, -1, 1};  // view's left, right, bottom, top: at unit depth / in units (ortho)
  size_t max_quads = size_t(1) << 22;  // limit-grid quads the refinement may make (~1 GB)
};

struct DicedMesh {
  std::vector<Vec3> positions;      // object space
  std::vector<int32_t> triangles;   // 3 per triangle, wound as their cage face
  std::vector<int32_t> tri_face;    // cage face of each triangle
  std::vector<int32_t> tri_sub;     // n-gon sub-patch (the corner it starts at), 0 for quads
  std::vector<float> tri_uv;        // (u, v) in its patch per triangle corner (6 per triangle)
  int level = 0;                    // refinement level of the limit grid
  bool capped = false;              // max_quads lowered the level
  int max_edge_factor = 0;
};

// Throws std::invalid_argument on bad crease input.
DicedMesh subdivide_and_dice(const SubdivisionCage& cage, const DicingCamera& camera);

// World size of a pixel at world point p: the footprint the edge factors divide by.
float dicing_pixel_size(const DicingCamera& camera, Vec3 p);

}  // namespace pl
