// The renderable scene: meshes and their instances flattened into world-space triangles,
// materials, emissive triangles as lights, the world and the camera. Built once (commit),
// then read-only and shared by all render threads.
#pragma once
#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "geometry/bvh.h"
#include "scene/bsdf.h"
#include "scene/camera.h"

namespace pl {

struct MeshData {
  std::vector<Vec3> positions;
  std::vector<std::array<uint32_t, 3>> triangles;
  std::vector<Vec3> corner_normals;  // 3 per triangle, or empty for flat shading
  std::vector<uint32_t> materials;   // global material id per triangle
};

struct Instance {
  uint32_t mesh;
  Mat4 matrix;
};

// What the integrator needs about a hit point.
struct SurfacePoint {
  Vec3 p;
  Vec3 ng;  // unit geometric normal (from the winding)
  Vec3 ns;  // unit interpolated shading normal
  uint32_t material = 0;
  uint32_t prim = 0;
};

struct EmitterSample {
  Vec3 p, n, radiance;
  float pdf_area = 0.0f;  // probability density per unit area, including the triangle choice
};

struct SceneStats {
  size_t triangles = 0, instances = 0, meshes = 0, materials = 0, emissive_triangles = 0, dropped_triangles = 0;
};

class Scene {
 public:
  Scene();

  uint32_t add_material(Material m);
  uint32_t add_mesh(MeshData mesh);  // validated by the caller (bindings)
  void add_instance(uint32_t mesh, const Mat4& m);
  void set_world_color(Vec3 c) { world_color_ = c; }
  void set_camera(const CameraDesc& c) { camera_ = c; has_camera_ = true; }
  void add_dropped(size_t n) { stats_.dropped_triangles += n; }

  // Flattens instances, drops degenerate triangles, builds the BVH and the light distribution.
  void commit(int threads = 0);
  bool committed() const { return committed_; }

  bool intersect(const Ray& r, Hit& h, TraversalCounters* c = nullptr) const { return bvh_.intersect(r, h, c); }
  bool occluded(const Ray& r) const { return bvh_.occluded(r); }
  void surface_point(const Hit& h, SurfacePoint& sp) const;

  const Material& material(uint32_t id) const { return materials_[id]; }
  Vec3 world_color() const { return world_color_; }
  const CameraDesc& camera_desc() const { return camera_; }
  bool has_camera() const { return has_camera_; }

  bool has_emitters() const { return !emitter_dist_.empty(); }
  bool sample_emitter(float u_select, Vec2 u, EmitterSample& s) const;
  // Area-measure pdf with which sample_emitter picks a point on triangle `prim`.
  float emitter_pdf_area(uint32_t prim) const;

  const SceneStats& stats() const { return stats_; }
  const Bvh& bvh() const { return bvh_; }

 private:
  struct TriangleShading {
    Vec3 n[3];       // shading normals at the corners (all zero: flat)
    uint32_t material;
    int32_t emitter;  // index into emitter arrays or -1
  };

  std::vector<Material> materials_;
  std::vector<MeshData> meshes_;
  std::vector<Instance> instances_;
  Vec3 world_color_{0.0f};
  CameraDesc camera_;
  bool has_camera_ = false;
  bool committed_ = false;

  std::vector<TriangleVerts> tris_;
  std::vector<TriangleShading> shading_;
  Bvh bvh_;
  std::vector<uint32_t> emitter_prims_;
  std::vector<float> emitter_areas_;
  Distribution1D emitter_dist_;
  SceneStats stats_;
};

}  // namespace pl
