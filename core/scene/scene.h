// The renderable scene: meshes and their instances flattened into world-space triangles,
// materials, emissive triangles as lights, the world and the camera. Built once (commit),
// then read-only and shared by all render threads.
#pragma once
#include <array>
#include <atomic>
#include <cstdint>
#include <string>
#include <vector>

#include "geometry/bvh.h"
#include "scene/shader.h"
#include "scene/camera.h"
#include "scene/light.h"

namespace pl {

struct MeshData {
  std::vector<Vec3> positions;
  std::vector<std::array<uint32_t, 3>> triangles;
  std::vector<Vec3> corner_normals;  // 3 per triangle, or empty for flat shading
  std::vector<uint32_t> materials;   // global material id per triangle
  std::vector<std::vector<Vec2>> uvs;  // per global uv set: 3 per triangle, or empty (missing)
  // Texture space for generated coordinates (Blender's texspace_location / texspace_size);
  // without it, Blender's automatic one (the bounding box) is computed at commit.
  bool has_texspace = false;
  Vec3 texspace_location{0.0f}, texspace_size{1.0f};
};

struct Material {
  std::string name;
  ShaderProgram program;
  Vec3 emission_estimate{0.0f};  // for choosing among lights; the true value is evaluated
  bool transparent = false;      // has a Transparent closure: shadow rays may pass
  // Programs that read nothing from the shading point are evaluated once; a hit only sets the
  // closures' frames (the common case: constant colours, no textures).
  bool constant = false;
  ClosureList cached;
};

// Builds the program of a Diffuse BSDF plus Emission with constant colours.
Material make_simple_material(const std::string& name, Vec3 base_color, Vec3 emission);

struct Instance {
  uint32_t mesh;
  Mat4 matrix;
};

// What the integrator needs about a hit point.
struct SurfacePoint {
  Vec3 p;
  Vec3 p_error;  // bound of p's rounding error, for spawning rays
  Vec3 ng;  // unit geometric normal (from the winding)
  Vec3 ns;  // unit interpolated shading normal
  uint32_t material = 0;
  uint32_t prim = 0;
};

// A next-event-estimation sample towards any light (analytic, emissive triangle, environment).
struct DirectSample {
  Vec3 wi;
  float dist = kInf;      // distance to the light point; inf for the sun and the environment
  Vec3 target;            // light point for the shadow ray (finite distances only)
  Vec3 target_normal;     // its geometric normal (emissive triangles), for the offset; else 0
  Vec3 target_error;      // bound of the target's rounding error (emissive triangles)
  Vec3 li;                // incident radiance (or intensity/r^2, irradiance for delta lights)
  float pdf = 0.0f;       // solid-angle pdf including the light choice
  bool delta = false;
  bool cast_shadow = true;
};

struct SceneStats {
  size_t triangles = 0, instances = 0, meshes = 0, materials = 0, emissive_triangles = 0, dropped_triangles = 0;
  size_t lights = 0;
  size_t geometry_builds = 0, light_builds = 0;  // commits that rebuilt the BVH / the light distribution
};

class Scene {
 public:
  Scene();

  uint32_t add_material(Material m);
  uint32_t add_image(Image img) {
    images_.push_back(std::move(img));
    return static_cast<uint32_t>(images_.size() - 1);
  }
  size_t material_count() const { return materials_.size(); }
  size_t image_count() const { return images_.size(); }
  uint32_t add_mesh(MeshData mesh);  // validated by the caller (bindings)
  void add_instance(uint32_t mesh, const Mat4& m);
  // Live edits (viewport): replace material `id` (not the default 0) or drop every analytic
  // light; the next commit() then rebuilds only the light distribution, not the BVH.
  void set_material(uint32_t id, Material m);
  void clear_lights() { lights_.clear(); committed_ = false; }
  void set_world_color(Vec3 c) { world_color_ = c; }
  void set_environment(Environment env) { env_ = std::move(env); committed_ = false; }
  void add_light(const Light& l) { lights_.push_back(l); committed_ = false; }
  void set_camera(const CameraDesc& c) { camera_ = c; has_camera_ = true; }
  // Emissive triangles are light-sampled uniformly in solid angle (default) or, with false,
  // uniformly by area everywhere (the old technique; kept to compare the two in tests).
  void set_solid_angle_triangle_sampling(bool on) { solid_angle_triangles_ = on; }
  bool solid_angle_triangle_sampling() const { return solid_angle_triangles_; }

  // Flattens instances, drops degenerate triangles, builds the BVH and the light distribution.
  // Returns false when cancel_commit() stopped it: the scene is then uncommitted (as if commit
  // had not been called) and can be committed again. `layout` picks the BVH kernel (tests).
  // Geometry (flattening and BVH) is rebuilt only when meshes or instances (or the layout)
  // changed since the last commit; materials, lights and the environment only rebuild the
  // light distribution.
  bool commit(int threads = 0, BvhLayout layout = BvhLayout::Auto);
  // Stops a commit running on another thread within milliseconds. It only affects a commit in
  // progress: commit() clears the request when it starts.
  void cancel_commit() { cancel_.store(true); }
  bool committed() const { return committed_; }

  bool intersect(const Ray& r, Hit& h, TraversalCounters* c = nullptr) const { return bvh_.intersect(r, h, c); }
  bool occluded(const Ray& r) const { return bvh_.occluded(r); }
  void surface_point(const Hit& h, SurfacePoint& sp) const;
  // Evaluates the material at a hit: closures (frames from the mesh-oriented shading normal)
  // and emission. wo points towards the viewer.
  // shadow_ray: shading for a shadow ray's transparency (the Light Path node's Is Shadow Ray).
  void shade(const SurfacePoint& sp, float b1, float b2, Vec3 wo, ClosureList& out, bool shadow_ray = false) const;
  // Fraction of light that passes from ray.org to ray.org + ray.dir * ray.tmax (0 when
  // blocked; Transparent surfaces let part of it through).
  Vec3 transmittance(Ray ray) const;
  const std::vector<Image>& images() const { return images_; }

  const Material& material(uint32_t id) const { return materials_[id]; }
  Vec3 world_color() const { return world_color_; }
  const CameraDesc& camera_desc() const { return camera_; }
  bool has_camera() const { return has_camera_; }

  bool has_lights() const { return !light_dist_.empty(); }
  // Radiance arriving from the world along a ray that escapes the scene.
  Vec3 background(Vec3 dir) const { return env_.valid() ? env_.eval(dir) : world_color_; }
  // Picks a light with u_select and samples it from point p.
  bool sample_direct(Vec3 p, float u_select, Vec2 u, DirectSample& s) const;
  // Solid-angle pdfs with which sample_direct, called at `from`, finds the point `at` of emissive
  // triangle `prim` (cos_l: the cosine there), or the environment in direction dir (for MIS of
  // BSDF samples).
  float pdf_emitter(uint32_t prim, Vec3 from, Vec3 at, float cos_l) const;
  float pdf_environment(Vec3 dir) const;
  const SceneStats& stats() const { return stats_; }
  const Bvh& bvh() const { return bvh_; }
  // Bytes allocated for geometry besides the BVH (bvh().memory_bytes()): the meshes as added
  // and, once committed, the world-space triangles with their shading data and uvs.
  size_t geometry_bytes() const;

 private:
  struct TriangleShading {
    Vec3 n[3];       // shading normals at the corners (all zero: flat)
    uint32_t material;
    int32_t emitter;  // index in the light distribution, or -1
    uint32_t instance;  // index in object_coords_ (texture coordinates)
  };

  std::vector<Material> materials_;
  std::vector<Image> images_;
  std::vector<std::vector<Vec2>> tri_uvs_;  // per uv set: 3 per scene triangle (empty if unused)
  bool any_transparent_ = false;
  std::vector<MeshData> meshes_;
  std::vector<Instance> instances_;
  std::vector<ObjectCoords> object_coords_;  // per instance, made at commit
  Vec3 world_color_{0.0f};
  CameraDesc camera_;
  bool has_camera_ = false;
  bool committed_ = false;
  std::atomic<bool> cancel_{false};
  bool geometry_dirty_ = true;
  BvhLayout built_layout_ = BvhLayout::Auto;
  bool solid_angle_triangles_ = true;

  std::vector<TriangleVerts> tris_;
  std::vector<TriangleShading> shading_;
  Bvh bvh_;
  std::vector<Light> lights_;
  Environment env_;
  // One distribution over [analytic lights | emissive triangles | environment], by power.
  std::vector<uint32_t> emitter_prims_;
  std::vector<float> emitter_areas_;
  Distribution1D light_dist_;
  size_t env_index_ = SIZE_MAX;
  SceneStats stats_;

  bool build_geometry(int threads, BvhLayout layout);  // false: cancelled
  void build_lights();
};

}  // namespace pl
