// The renderable scene: meshes and their instances in a two-level BVH, materials, emissive
// triangles as lights, the world and the camera. Built once (commit), then read-only and
// shared by all render threads.
//
// Geometry layout (as Cycles does it): in a final render, meshes used by exactly one instance
// are transformed into world space and merged into one BLAS; meshes used by two or more
// instances get one object-space BLAS each, shared by their instances through the top level.
// A scene with only the merged BLAS skips the top level at trace time. Dynamic mode (the
// viewport) makes every instance a real one, so a transform edit rebuilds only the top level.
#pragma once
#include <stdexcept>
#include <algorithm>
#include <array>
#include <atomic>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "geometry/bvh.h"
#include "geometry/curves.h"
#include "geometry/points.h"
#include "geometry/tlas.h"
#include "scene/shader.h"
#include "scene/camera.h"
#include "scene/light.h"
#include "scene/light_tree.h"
#include "scene/medium_grid.h"
#include "scene/volume_grid.h"

namespace pl {

struct MeshData {
  std::vector<Vec3> positions;
  std::vector<std::array<uint32_t, 3>> triangles;
  // Shading normals, or empty for flat shading. Corner k of triangle t has
  // normals[normal_indices[t][k]], or normals[triangles[t][k]] when normal_indices is empty (one
  // normal per vertex, the smooth case): shared, not expanded to 36 bytes per triangle.
  std::vector<Vec3> normals;
  std::vector<std::array<uint32_t, 3>> normal_indices;
  std::vector<uint32_t> materials;   // global material id per triangle
  std::vector<std::vector<Vec2>> uvs;  // per global uv set: 3 per triangle, or empty (missing)
  // Per global attribute set (the Attribute and Color Attribute nodes; numbered with the uv
  // sets): RGBA of every triangle corner, 3 per triangle, or empty (missing: reads 0).
  std::vector<std::vector<Float4>> attributes;
  // Per global uv set: Blender's MikkTSpace tangent (xyz, object space) and bitangent sign (w)
  // of every triangle corner, 3 per triangle, or empty (per-triangle uv tangents instead).
  std::vector<std::vector<Float4>> tangents;
  // Texture space for generated coordinates (Blender's texspace_location / texspace_size);
  // without it, Blender's automatic one (the bounding box) is computed at commit.
  bool has_texspace = false;
  Vec3 texspace_location{0.0f}, texspace_size{1.0f};
  // Deformation blur: the vertex positions at each motion step over the shutter (>= 2, each as
  // long as positions; empty: no deformation). Its instances trace the triangles at the ray's
  // time; shading normals stay the frame's.
  std::vector<std::vector<Vec3>> motion_positions;
  // Vector pass: the vertex positions at the previous and next frames (2, each as long as
  // positions; empty: it does not deform). Only the pass reads them, never a ray.
  std::vector<std::vector<Vec3>> pass_positions;
  // True displacement: the vertex positions before it (as long as positions; empty: not
  // displaced), for Generated coordinates and the bump of 'BOTH' (ShadingContext::undisplaced).
  std::vector<Vec3> undisplaced;
  // Velocity blur of a volume object (Cycles' volume motion): the lookup point moves back by
  // velocity x scale x (time + offset), velocity the vector grid `velocity_grid` (object
  // space; -1: none), or where velocity_yz are set, three float grids x, y, z (Cycles merges
  // them), read with `velocity_sampling` (docs/design/motion-blur.md).
  int32_t velocity_grid = -1;
  int32_t velocity_yz[2] = {-1, -1};
  float velocity_scale = 0.0f, velocity_offset = 0.0f;
  VolumeSampling velocity_sampling = VolumeSampling::Trilinear;
};

struct Material {
  std::string name;
  ShaderProgram program;
  Vec3 emission_estimate{0.0f};  // for choosing among lights; the true value is evaluated
  bool transparent = false;      // has a Transparent closure: shadow rays may pass
  bool holdout = false;          // has a Holdout closure: the film's alpha needs the aov kernel
  bool has_hair = false;     // has a hair closure: its frame follows the fibre (orient_hair)
  bool subsurface = false;       // may add a BSSRDF closure: its objects get local BVHs
  bool subsurface_bump = false;  // a BSSRDF with its own normal: walk exits shade for it
  // An op reads the uv sets' tangents (tangent-space Normal Map, Tangent by UV map, tangent
  // displacement): only then does a hit compute them. (In the bools' padding: the other
  // fields keep their offsets.)
  bool uses_tangents = false;
  float pass_index = 0.0f;       // Blender's material pass index (the Material Index pass)
  float crypto = 0.0f;           // Cryptomatte id of its name (the CryptoMaterial pass; 0: none)
  // Programs that read nothing from the shading point are evaluated once; a hit only sets the
  // closures' frames (the common case: constant colours, no textures).
  bool constant = false;
  ClosureList cached;
  // A constant white Transparent closure alone, no emission or holdout: a volume-only
  // boundary (a Volume with no Surface), which rays cross without shading (Cycles'
  // SD_HAS_ONLY_VOLUME).
  bool pass_through = false;
  // Programs varying only through their closures (the view: Principled layering, Oren-Nayar,
  // multiscatter): the registers evaluated once, and the closure ops that run per hit on them.
  bool closures_only = false;
  std::vector<Float4> closure_regs;
  std::vector<ShaderOp> closure_ops;
  std::vector<PrincipledInputs> principled;  // of its Principled ops, in order
  // True displacement (Cycles' 'DISPLACEMENT' and 'BOTH' methods): the program of the offset at
  // a vertex (value ops, then DisplaceOut), run by displace_mesh before the mesh is added;
  // nullptr: none. displacement_normals: the displaced vertices' normals are recomputed
  // ('DISPLACEMENT'; 'BOTH' keeps them, its program's bump does the rest).
  std::shared_ptr<const ShaderProgram> displacement;
  bool displacement_normals = true;
};

// A heterogeneous medium in the committed scene: one per instance and material whose Volume is
// a program (ShaderProgram::volume), with the majorant grid over the instance's world bounds.
struct HeteroMedium {
  const ShaderProgram* program = nullptr;  // the volume program (the material's)
  uint32_t material = 0, instance = 0;
  MajorantGrid grid;  // over the space it covers at any shutter time (world)
  // Motion blur: the instance moves (its transform at the ray's time places the medium), and
  // velocity blur (MeshData::velocity_grid; -1: none).
  bool moving = false;
  int32_t velocity_grid = -1;
  int32_t velocity_yz[2] = {-1, -1};
  float velocity_scale = 0.0f, velocity_offset = 0.0f;
  VolumeSampling velocity_sampling = VolumeSampling::Trilinear;
  // Every cell's majorant is the grid bound (scene_media.cpp): tight enough for the light
  // sample's distances drawn from them (trace_path.inl); the sampled bounds with their floor
  // and safety factor spread those distances into empty space, worse than none.
  bool tight = false;
};

struct SurfacePoint;
// Sets the frame and offset of the hair closures in `out` from the hit (tangent, normal) and
// the view direction wo; pixel_coverage: half the pixel's footprint over the strand's radius
// for camera rays on curves, else 1 (Huang's near field).
// curve_normal: the curve's normal attribute at the hit (zero: none; Huang's major axis).
void orient_hair(ClosureList& out, const SurfacePoint& sp, Vec3 wo, float pixel_coverage = 1.0f,
                 Vec3 curve_normal = Vec3(0.0f));

// Builds the program of a Diffuse BSDF plus Emission with constant colours.
Material make_simple_material(const std::string& name, Vec3 base_color, Vec3 emission);

// A Curves object (hair): strands with a radius per point, one material, object -> world.
struct CurveSetData {
  std::vector<Vec3> points;
  std::vector<float> radii;      // per point
  std::vector<Vec3> normals;     // per point, or none (Blender's curve normals: Huang's major axis)
  std::vector<int32_t> offsets;  // strands + 1: strand c has points [offsets[c], offsets[c + 1])
  CurveType type = CurveType::CatmullRom;
  int subdivisions = 8;          // linear pieces per Catmull-Rom segment (ribbons: quads)
  bool ribbon = false;           // ribbons (Cycles' shape 'RIBBONS'), Catmull-Rom whatever the type
  uint32_t material = 0;
  // Per strand, its material (Cycles' per-curve shader from the material_index attribute);
  // empty: `material` for all.
  std::vector<uint32_t> strand_materials;
  Mat4 matrix;
  ObjectInfo info;              // (attr_first / attr_count unused: attrs holds them)
  std::vector<Float4> attrs;    // Object / Instancer attribute values by slot (<= kMaxObjectAttributes)
  // Per uv set k: one uv per strand (particle hair: the emitter's UV at the root, as Cycles'
  // per-curve UV attribute); empty sets read (0, 0).
  std::vector<std::vector<Vec2>> uvs;
  // Per attribute set k (numbered with the uv sets): one RGBA per strand (particle hair: the
  // emitter's byte colour attribute at the root, Cycles' per-curve vertex colour); empty: 0.
  std::vector<std::vector<Float4>> strand_attrs;
  // Per attribute set k: one RGBA per point (a Curves object's point-domain attribute),
  // linear between a segment's keys at the hit's segment parameter (Cycles'
  // curve_attribute_float4 on ATTR_ELEMENT_CURVE_KEY); empty: the set is per strand (or 0).
  std::vector<std::vector<Float4>> point_attrs;
  // Per uv set k: one uv per point (a point-domain FLOAT2 read as a UV map), interpolated as
  // point_attrs; empty: per strand (or 0). A set index is a uv set or an attribute set.
  std::vector<std::vector<Vec2>> point_uvs;
  // Transform motion blur: the object-to-world matrix at each motion step (>= 2, evenly over
  // the shutter); empty: static. Steps not finite or singular leave it static.
  std::vector<Mat4> motion;
  // Deformation blur (Cycles' motion keys): the points (object space) at each deformation step
  // (>= 2, evenly over the shutter), and their radii (empty: `radii` at every step). Steps of
  // the wrong size, non-finite ones, or ones that cut into other pieces leave it undeformed.
  std::vector<std::vector<Vec3>> deform_points;
  std::vector<std::vector<float>> deform_radii;
  // Vector pass: the object-to-world matrix at the previous and next frames (2; empty: still).
  std::vector<Mat4> pass_motion;
  // Vector pass: the points (object space) at the previous and next frames (2, as `points`;
  // empty, the wrong size or not finite: the strands move with the object's transform alone).
  std::vector<std::vector<Vec3>> pass_points;
};

// Hit::inst of a hit on a curve (Hit::prim: the piece, Hit::b1: its axial position).
constexpr uint32_t kCurveInstance = 0xFFFFFFF0u;

// A point cloud (Blender's POINTCLOUD): spheres of a centre and a radius each, one material,
// object -> world.
struct PointSetData {
  std::vector<Vec3> points;
  std::vector<float> radii;  // per point
  uint32_t material = 0;
  Mat4 matrix;
  ObjectInfo info;            // (attr_first / attr_count unused: attrs holds them)
  std::vector<Float4> attrs;  // Object / Instancer attribute values by slot (<= kMaxObjectAttributes)
  // Per attribute set k: one RGBA per point (the Attribute node's value on that point, as
  // Cycles' ATTR_ELEMENT_VERTEX attributes of point clouds); empty sets read 0.
  std::vector<std::vector<Float4>> point_attrs;
  // Generated coordinates' box (object space); by default the identity: Cycles has no
  // generated attribute on points and gives the object-space position.
  Vec3 texspace_loc{0.5f}, texspace_size{0.5f};
  // Transform motion blur: the object-to-world matrix at each motion step (>= 2, evenly over
  // the shutter); empty: static. Steps not finite or singular leave it static.
  std::vector<Mat4> motion;
  // Deformation blur (Cycles' motion points): the centres (object space) at each deformation
  // step (>= 2, evenly over the shutter) and their radii (empty: `radii` at every step). Steps
  // of the wrong size, with non-finite values or other points left out leave it undeformed.
  std::vector<std::vector<Vec3>> deform_points;
  std::vector<std::vector<float>> deform_radii;
  // Vector pass: the object-to-world matrix at the previous and next frames (2; empty: still).
  std::vector<Mat4> pass_motion;
  // Vector pass: the points (object space) at the previous and next frames (2, as `points`;
  // empty, the wrong size or not finite: the points move with the object's transform alone).
  std::vector<std::vector<Vec3>> pass_points;
};

// Hit::inst of a hit on a point (Hit::prim: the sphere, Hit::b1, b2: its normal, octahedral).
constexpr uint32_t kPointInstance = 0xFFFFFFF1u;

struct Instance {
  uint32_t mesh;
  Mat4 matrix;
  ObjectInfo info;
  // Motion blur: the object-to-world matrix at each motion step over the shutter (>= 2, evenly
  // spaced, ray time 0 at the first); empty: static.
  std::vector<Mat4> motion;
  // Vector pass: the object-to-world matrix at the previous and next frames (2; empty: still).
  std::vector<Mat4> pass_motion;
};

// What the integrator needs about a hit point.
struct SurfacePoint {
  // p, p_error, ng, ns: Scene::surface_point writes them on every path (triangles, curves,
  // points) before anyone reads them, so they are left unconstructed (zeroing them cost about
  // 16 instructions a hit).
  union { Vec3 p; };
  union { Vec3 p_error; };  // bound of p's rounding error, for spawning rays
  union { Vec3 ng; };  // unit geometric normal (from the winding)
  union { Vec3 ns; };  // unit interpolated shading normal
  uint32_t material = 0;
  uint32_t prim = 0;      // the triangle's index in the flattened scene (instance by instance)
  uint32_t instance = 0;  // the hit instance
  uint32_t tri = 0;       // the triangle in its BLAS (internal); curves: the piece
  // Curves (instance == kCurveInstance): the unit tangent along the strand (else zero).
  Vec3 tangent{0.0f};
  float b1 = 0.0f, b2 = 0.0f;  // barycentrics of v1 and v2 in the hit triangle
  bool curve() const { return instance == kCurveInstance; }
  bool point() const { return instance == kPointInstance; }
  float time = 0.5f;      // shutter time of the ray that found it (motion blur)
  SurfacePoint() {}
};

// A next-event-estimation sample towards any light (analytic, emissive triangle, environment).
// wi, target, target_normal, target_error, li and world_p are left unconstructed (zeroing
// them cost about 24 instructions a light sample): a successful sample_direct writes wi,
// target_normal and li (li: unless world_pending), target where dist is finite and
// target_error where target_normal is not zero; world_p where world_pending. A caller that
// fills one itself (the sky samples) sets wi and li and keeps dist infinite.
struct DirectSample {
  union { Vec3 wi; };
  float dist = kInf;      // distance to the light point; inf for the sun and the environment
  union { Vec3 target; };         // light point for the shadow ray (finite distances only)
  union { Vec3 target_normal; };  // its geometric normal (emissive triangles), for the offset; else 0
  union { Vec3 target_error; };   // bound of the target's rounding error (emissive triangles)
  union { Vec3 li; };             // incident radiance (or intensity/r^2, irradiance for delta lights)
  float pdf = 0.0f;       // solid-angle pdf including the light choice
  bool delta = false;      // no BSDF ray can find this light (delta, or Multiple Importance off): full weight
  bool analytic = false;   // an analytic light (not an emissive triangle or the environment)
  uint32_t light = 0;      // analytic: its index (Scene::light), for the caustic light paths' MIS
  // Out: the chosen entry of the light choice (Scene::entry_light_group; left unset by the sky's
  // own samples, which the integrator draws itself).
  uint32_t entry;
  float choice = 0.0f;     // analytic: the probability of its choice (a factor of pdf)
  bool cast_shadow = true;
  // LightVisibility bits of the ray kinds the chosen light is invisible to: closures of those
  // kinds (and volume scattering) get nothing from this sample, as Cycles' light_shader_flags.
  uint8_t exclude = 0;
  // In: the path at the shading point, for textured emitters' Light Path nodes (null: none).
  const RayState* path = nullptr;
  // In: the unit shading normal at the shading point, for the light tree's importance (zero:
  // none); pdf_emitter must be given the same one.
  Vec3 n{0.0f};
  // In: the shading point's light set (light linking; 0: the default), given to pdf_emitter too.
  uint8_t receiver = 0;
  // In: the caller can take a world sample whose radiance and pdf wait for its shadow ray
  // (Scene::finish_world_sample; a sky with a sun disc: most of its samples are blocked indoors).
  // Out: world_pending where it did so (li and pdf are then unset).
  bool defer_world = false;
  bool world_pending = false;
  bool world_cover_all = false;
  float world_pmf = 0.0f;
  union { Vec3 world_p; };  // the shading point (portals' pdf)
  // Out (light linking only): the chosen light's shadow sets; blockers of other sets let it pass.
  uint64_t shadow_mask = kAllLightSets;
  // Out (light linking only): a shadow-linked light with extent, `delta` only because rays do not
  // find it past blockers: surfaces find it by dedicated rays (Scene::dedicated_lights) and
  // weigh this sample by MIS; media keep the full weight.
  bool dedicated = false;
  DirectSample() {}
};

struct SceneStats {
  size_t triangles = 0, instances = 0, meshes = 0, materials = 0, emissive_triangles = 0, dropped_triangles = 0;
  size_t lights = 0;
  size_t rect_emitters = 0;  // emitter groups sampled as spherical rectangles
  size_t light_tree_nodes = 0;  // nodes of the light tree (0: lights chosen by power alone)
  size_t light_tree_depth = 0;  // its deepest leaf's depth
  size_t geometry_builds = 0, light_builds = 0;  // commits that rebuilt the BVH / the light distribution
  size_t top_level_builds = 0;  // commits that rebuilt only the top level (transform edits)
  size_t blases = 0, blas_triangles = 0;  // bottom-level BVHs and the triangles stored in them
  size_t blas_references = 0;  // triangle references in their leaves (> blas_triangles with spatial splits)
  size_t tlas_instances = 0;              // entries of the top level (0: a single BLAS, no top level)
  size_t real_instances = 0;              // instances traced through a transform (not merged)
  size_t bvh_bytes = 0, geometry_bytes = 0;  // BLASes + top level; triangle copies, maps and mesh data
  size_t curves = 0, curve_pieces = 0, skipped_curves = 0;  // strands kept, their linear pieces, strands left out
  size_t points = 0, skipped_points = 0;  // point-cloud spheres kept, points left out (bad position or radius)
  size_t motion_instances = 0;  // instances traced with transform motion blur
  size_t motion_rejected = 0;   // instances (and meshes) whose motion was dropped (non-finite or singular steps)
  size_t deforming_instances = 0;  // instances traced with deformation blur
};

// What a committed scene uses (materials on its triangles, lights, world), so that a render
// can run an integrator compiled without the rest, and say in its log which one it chose.
struct SceneFeatures {
  // Closure kinds the materials in use can produce (varying programs: every kind their ops can
  // add; constant ones: the closures they do add).
  bool diffuse = false, glossy = false, transmission = false, transparent = false;
  bool varying = false;      // programs that read the shading point (evaluated per hit)
  bool textures = false;     // Image Texture nodes
  bool normal_maps = false;  // Normal Map or Bump nodes
  bool media = false;        // Beer's law absorption inside some material
  // Media that scatter or emit, or volume boundaries that shadow rays pass (a Volume without a
  // Surface): shadow rays then sum the media they cross, and paths sample distances in them.
  bool volumes = false;
  bool emission = false;     // emissive triangles (mesh lights)
  bool environment = false;  // an HDR environment (importance-sampled) rather than a constant world
  bool world_light = false;  // a non-black constant world colour
  uint32_t light_kinds = 0;  // bit 1 << LightType of each analytic light kind present
  bool light_tree = false;   // lights chosen by the light tree (many lights)
  bool light_hits = false;   // analytic lights with extent that rays may find (Scene::hit_lights)
  bool subsurface = false;   // BSSRDF closures: random walks inside objects
  // Light or shadow linking in use (objects in light sets, lights with set masks): only the
  // general kernel follows them (kKernelLightLinks).
  bool light_links = false;
  // Some analytic light has a Max Bounces below Cycles' default 1024 (the kKernelTricks
  // kernels skip its light samples past it).
  bool light_bounce_limits = false;
  // Shaders read the ray's footprint (Bump's Filter Width, Wireframe in pixels): only then do
  // camera rays carry ray differentials (not a kernel feature: one test per camera ray).
  bool footprints = false;
  // Shaders read the path's state (Light Path, and the rays Ambient Occlusion and Bevel
  // trace): only then does the integrator keep RayState's kind, counts, length and seed.
  bool path_state = false;
  // Some smooth-shaded instance has Cycles' shadow terminator geometry offset (light samples
  // near the terminator start on the smooth surface: Scene::terminator_origin).
  bool terminator = false;
  // Some object is a shadow catcher (kKernelShadowCatcher: only the general kernel splits
  // paths), or a holdout (the film's alpha needs the aov kernel).
  bool shadow_catcher = false;
  bool object_holdout = false;
  bool camera_invisible = false;  // Some object is invisible to camera rays (Indirect Only).
  // Every closure is a diffuse lobe: no delta, glossy, refracting or transparent lobes.
  bool diffuse_only() const { return !glossy && !transmission && !transparent; }
  // Heterogeneous media (Volume programs): delta and ratio tracking through majorant grids
  // (not a kernel feature: the media kernels test each medium layer).
  bool heterogeneous_volumes = false;
  // Names of the features in use, and of every feature a scene can have (for logs and tests).
  std::vector<std::string> names() const;
  static std::vector<std::string> all_names();
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
  // motion: the instance's transforms over the shutter (Instance::motion). Steps that are not
  // finite or not invertible leave the instance static (counted in stats().motion_rejected);
  // steps that are all equal are no motion.
  // attributes: its Object / Instancer attribute values by slot (at most kMaxObjectAttributes;
  // info's attr_first / attr_count are set here).
  // pass_motion: Instance::pass_motion (the Vector pass), 2 matrices or none.
  void add_instance(uint32_t mesh, const Mat4& m, const ObjectInfo& info = {}, std::vector<Mat4> motion = {},
                    const std::vector<Float4>& attributes = {}, std::vector<Mat4> pass_motion = {});
  // The Vector pass's deformation of mesh `mesh` (MeshData::pass_positions): 2 steps as long as
  // its positions, or none. Returns false (and keeps none) for steps of the wrong length or
  // with non-finite positions.
  bool set_mesh_pass_motion(uint32_t mesh, std::vector<std::vector<Vec3>> steps);
  // A set of curves (validated by the caller). Strands with bad data are left out at commit
  // (counted in stats().skipped_curves).
  uint32_t add_curves(CurveSetData curves) {
    curve_sets_.push_back(std::move(curves));
    curves_dirty_ = true;
    committed_ = false;
    return uint32_t(curve_sets_.size() - 1);
  }
  size_t curve_set_count() const { return curve_sets_.size(); }
  bool has_curves() const { return !curve_bvh_.empty(); }
  const CurveBvh& curve_bvh() const { return curve_bvh_; }
  // The curve set of a strand of a committed scene.
  uint32_t curve_set_of(uint32_t strand) const {
    return uint32_t(std::upper_bound(curve_first_.begin(), curve_first_.end(), strand) - curve_first_.begin()) - 1;
  }
  // A point cloud (validated by the caller). Points with a non-finite position or a radius
  // that is not finite and > 0 are left out at commit (counted in stats().skipped_points).
  uint32_t add_points(PointSetData points) {
    point_sets_.push_back(std::move(points));
    points_dirty_ = true;
    committed_ = false;
    return uint32_t(point_sets_.size() - 1);
  }
  size_t point_set_count() const { return point_sets_.size(); }
  bool has_points() const { return !point_bvh_.empty(); }
  const PointBvh& point_bvh() const { return point_bvh_; }
  // The point set of a point of a committed scene.
  uint32_t point_set_of(uint32_t point) const {
    return uint32_t(std::upper_bound(point_first_.begin(), point_first_.end(), point) - point_first_.begin()) - 1;
  }
  size_t instance_count() const { return instances_.size(); }
  // Deformation blur of mesh `mesh` (MeshData::motion_positions). Steps of the wrong length or
  // with non-finite positions leave it undeformed (counted in stats().motion_rejected).
  void set_mesh_motion(uint32_t mesh, std::vector<std::vector<Vec3>> steps);
  // Instances with transform motion blur in the committed scene: rays then need a time.
  // (Volumes with velocity blur count: their lookups need the ray's time too.)
  bool has_motion() const {
    return motion_instances_ > 0 || velocity_media_ > 0 || point_bvh_.has_moving() || curve_bvh_.has_moving();
  }
  // Velocity blur of a volume object's mesh (MeshData::velocity_grid): scale 0 or a grid
  // id < 0 turns it off. Throws std::invalid_argument on non-finite values.
  // grid_y, grid_z >= 0: `grid` is the x component's float grid, they the y and z ones.
  void set_mesh_velocity(uint32_t mesh, int32_t grid, float scale, float offset, VolumeSampling sampling,
                         int32_t grid_y = -1, int32_t grid_z = -1);
  // Live transform edit. In dynamic mode (or for a mesh that is instanced anyway) the next
  // commit() rebuilds only the top level and the lights; else the merged geometry.
  void set_instance_transform(uint32_t index, const Mat4& m);
  // Dynamic mode (viewport): every instance gets its own transform over a per-mesh BLAS, so
  // transform edits never rebuild bottom-level BVHs. Off (final renders): single-use meshes
  // are merged into world space (faster tracing). Changing it rebuilds the geometry.
  void set_dynamic(bool on) {
    if (on != dynamic_) {
      geometry_dirty_ = true;
      committed_ = false;
    }
    dynamic_ = on;
  }
  bool dynamic() const { return dynamic_; }
  // Spatial splits (SBVH) in the BLAS builds (BvhBuildOptions::spatial_splits): slower builds,
  // faster tracing of long thin triangles; for final renders. Changing it rebuilds the geometry.
  void set_spatial_splits(bool on) {
    if (on != spatial_splits_) committed_ = false;
    spatial_splits_ = on;
  }
  bool spatial_splits() const { return spatial_splits_; }
  // Compressed (quantised) wide BVH nodes (BvhBuildOptions::compact): half the node memory,
  // the same hits, more instructions per ray. Auto: for BLASes of at least
  // kCompactAutoTriangles triangles (float nodes over 64 MB), where memory matters more.
  // Changing it rebuilds the geometry.
  enum class CompactBvh : uint8_t { Auto, Off, On };
  static constexpr size_t kCompactAutoTriangles = size_t(1) << 23;
  void set_compact_bvh(CompactBvh c) {
    if (c != compact_bvh_) committed_ = false;
    compact_bvh_ = c;
  }
  CompactBvh compact_bvh() const { return compact_bvh_; }
  // How the BLASes are built (BvhBuildOptions::morton_clusters): Sah, the full binned SAH;
  // Fast, the clustered build; Auto (default), Fast for the BLASes of kFastBuildMin triangles
  // or more of dynamic (viewport) scenes, where build latency counts, else Sah (final renders
  // keep the best trees). Changing it rebuilds the geometry.
  enum class BuildQuality : uint8_t { Auto, Sah, Fast };
  static constexpr size_t kFastBuildMin = 100000;
  void set_build_quality(BuildQuality q) {
    if (q != build_quality_) geometry_dirty_ = true, committed_ = false;
    build_quality_ = q;
  }
  BuildQuality build_quality() const { return build_quality_; }
  // Live edits (viewport): replace material `id` (not the default 0) or drop every analytic
  // light; the next commit() then rebuilds only the light distribution, not the BVH.
  void set_material(uint32_t id, Material m);
  void clear_lights() {
    lights_.clear();
    portals_.clear();
    committed_ = false;
  }
  // Light portals (Cycles' is_portal area lights): a rectangle or ellipse (Light::type, position,
  // axes, dir: the side it lets the world in towards) that emits nothing; points in front of
  // some portal sample the world through the portals half the time (docs/design/lights.md).
  void add_portal(const Light& portal) {
    portals_.push_back(portal);
    committed_ = false;
  }
  size_t portal_count() const { return portals_.size(); }
  void set_world_color(Vec3 c) { world_color_ = c; }
  // World ▸ Settings ▸ Sampling Method: on (Automatic, Manual) the world map is a light to
  // sample; off (None) it is not, as Cycles adds no background light then: only rays that escape
  // find the world, with weight 1 (and no caustic light paths start from it). With portals
  // Cycles keeps it a light sampled through the portals alone (its map_weight 0), as here.
  void set_world_sampled(bool on) {
    world_sampled_ = on;
    committed_ = false;
  }
  bool world_sampled() const { return world_sampled_; }
  // Light samples of the world drawn first and given radiance and pdf only past their shadow
  // ray where that saves work (finish_world_sample; on by default). Off: all at once, as
  // before (the tests' reference: the two render the same image).
  void set_defer_world_samples(bool on) { defer_world_ = on; }
  bool defer_world_samples() const { return defer_world_; }
  // A constant world colour that is the scene's only light, sampled as a light at every surface
  // vertex by the cosine about the geometric normal, besides the BSDF ray that also finds it
  // (both MIS-weighted; off: the BSDF ray alone, as before). Only a constant world: a map is a
  // light of light_dist_; with other lights the BSDF ray alone finds it (sampling it too did
  // not pay: docs/design/sampling.md "Sky samples").
  void set_world_samples(bool on) { world_samples_ = on; }
  bool world_samples() const { return world_samples_; }
  bool samples_world() const { return world_samples_ && world_sampled_ && features_.world_light; }
  // The world's Volume: a medium filling all space outside objects' media, the camera starts in
  // it. Homogeneous (its medium fields), or a Volume program (ShaderProgram::volume): then a
  // heterogeneous medium over the scene's bounds (world_hetero(); docs/design/volumes.md
  // "World volumes").
  void set_world_volume(const ShaderProgram& v) {
    world_volume_ = v;
    world_het_ = HeteroMedium{};  // (its program was the old one's; the next commit rebuilds it)
    committed_ = false;
  }
  const ShaderProgram& world_volume() const { return world_volume_; }
  void set_environment(Environment env) {
    env_ = std::move(env);
    env_from_color_ = false;
    committed_ = false;
  }
  void add_light(const Light& l) { lights_.push_back(l); committed_ = false; }
  // Light linking of analytic light k (Light::light_mask / shadow_mask); false: no such light.
  bool set_light_group(size_t k, int16_t group) {
    if (k >= lights_.size()) return false;
    lights_[k].light_group = group;
    return true;  // (read per contribution only: nothing to rebuild)
  }
  // Cycles' light Max Bounces of analytic light k; false: no such light.
  bool set_light_max_bounces(size_t k, int max_bounces) {
    if (k >= lights_.size()) return false;
    lights_[k].max_bounces = std::max(max_bounces, 0);
    committed_ = false;  // (the kernel choice reads SceneFeatures::light_bounce_limits)
    return true;
  }
  bool set_light_links(size_t k, uint64_t light_mask, uint64_t shadow_mask) {
    if (k >= lights_.size()) return false;
    lights_[k].light_mask = light_mask;
    lights_[k].shadow_mask = shadow_mask;
    committed_ = false;
    return true;
  }
  // Rays find analytic lights with extent and weigh them against light samples by MIS (default);
  // off: those lights are reached by light samples alone, with the full weight (for tests, and
  // to measure what the hits gain).
  void set_light_hits(bool on) { light_hits_on_ = on; committed_ = false; }
  bool light_hits_enabled() const { return light_hits_on_; }
  void set_camera(const CameraDesc& c) {
    camera_ = c;
    has_camera_ = true;
    shading_camera_ = Camera(c, 1, 1);
  }
  // Emissive triangles are light-sampled uniformly in solid angle (default) or, with false,
  // uniformly by area everywhere (the old technique; kept to compare the two in tests).
  void set_solid_angle_triangle_sampling(bool on) { solid_angle_triangles_ = on; }
  bool solid_angle_triangle_sampling() const { return solid_angle_triangles_; }
  void set_solid_angle_rect_sampling(bool on) { solid_angle_rects_ = on; }
  bool solid_angle_rect_sampling() const { return solid_angle_rects_; }
  // Small mesh lights (up to kMaxEmitterGroup triangles of one material in one object, such as
  // a quad) chosen as one light and sampled over their whole solid angle (on by default).
  // Quads among them that are rectangles are sampled as spherical rectangles (on by default;
  // off: as two spherical triangles, for tests that compare the two).
  void set_rect_groups(bool on) {
    rect_groups_ = on;
    committed_ = false;
  }
  bool rect_groups() const { return rect_groups_; }
  void set_emitter_groups(bool on) {
    emitter_groups_ = on;
    committed_ = false;
  }
  bool emitter_groups() const { return emitter_groups_; }
  // Many-light sampling (light_tree.h) over the analytic lights and emitter groups, with the
  // sun and the environment chosen beside it. Auto: where a scene has more than
  // kLightTreeMinLights finite lights (below, the single distribution by power is as good and
  // cheaper: docs/design/lights.md); On/Off force it. Takes effect at the next commit().
  enum class LightTreeMode : uint8_t { Auto, Off, On };
  static constexpr size_t kLightTreeMinLights = 8;
  void set_light_tree(LightTreeMode m) {
    if (m != light_tree_mode_) committed_ = false;
    light_tree_mode_ = m;
  }
  LightTreeMode light_tree() const { return light_tree_mode_; }
  bool light_tree_active() const { return lc_.use_tree; }
  // The light choice sample_direct makes at p (normal n, zero: none) from u, over the entries
  // [analytic lights | emitter groups | environment], and the probability of each (for tests).
  // set: a light set (light linking; 0: the default).
  size_t light_choices() const { return lc_.dist.size(); }
  bool pick_light(Vec3 p, Vec3 n, float u, size_t& k, float& pmf, uint8_t set = 0) const {
    const LightChoice& c = choice(set);
    return !c.dist.empty() && choose_light(c, p, n, u, k, pmf);
  }
  float pick_light_pmf(Vec3 p, Vec3 n, size_t k, uint8_t set = 0) const {
    const LightChoice& c = choice(set);
    return k < c.dist.size() && !c.dist.empty() ? light_pmf(c, p, n, k) : 0.0f;
  }

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
  // The bounds of everything a ray can hit (after commit).
  const Aabb& world_bounds() const { return world_bounds_; }
  bool committed() const { return committed_; }
  // Holdout closures or objects: alpha below 1 without transparent film.
  bool any_holdout() const { return any_holdout_ || features_.object_holdout; }
  // Shadow catchers (ObjectInfo::shadow_catcher) and holdout objects, by a hit's instance and
  // primitive (curves and points: their set's; the instance alone is enough for meshes).
  bool is_catcher(uint32_t instance, uint32_t prim = 0) const {
    const ObjectInfo* info = hit_info(instance, prim);
    return info && info->shadow_catcher;
  }
  bool is_object_holdout(uint32_t instance, uint32_t prim = 0) const {
    const ObjectInfo* info = hit_info(instance, prim);
    return info && info->holdout;
  }
  bool is_camera_invisible(uint32_t instance, uint32_t prim = 0) const {
    const ObjectInfo* info = hit_info(instance, prim);
    return info && info->camera_invisible;
  }
  // The closest hit along camera ray `r` on an object camera rays see, given `h` (on one they do
  // not see): the objects between are stepped past as Cycles' traversal skips them by visibility;
  // h.t stays a distance along `r` (as given), so media and ray lengths read it as before.
  bool intersect_camera_visible(const Ray& r, Hit& h) const;
  // Closest hit on shadow catchers only (the catcher path of a split, which sees no other
  // object): other hits are stepped past, and `r` starts past the last of them on return.
  bool intersect_catchers(Ray& r, Hit& h) const;
  // transmittance() where only shadow catchers block.
  Vec3 transmittance_catchers(const Ray& ray, int max_hits = kShadowHits) const {
    return transmittance_through(ray, kAllLightSets, true, max_hits);
  }

  // Closest hit: h.prim is the triangle in its BLAS, h.inst the scene instance (surface_point
  // and global_prim read them).
  bool intersect(const Ray& r, Hit& h, TraversalCounters* c = nullptr) const {
    if (curves_on_ || points_on_) return intersect_with_curves(r, h, c);
    return intersect_meshes(r, h, c);
  }
  bool intersect_meshes(const Ray& r, Hit& h, TraversalCounters* c = nullptr) const {
    if (!use_tlas_) {
      if (!direct_ || !blases_[0].bvh.intersect(r, h, c)) return false;
      h.inst = blases_[0].instance_of(h.prim);
      return true;
    }
    if (!tlas_.intersect(r, h, c)) return false;
    const TlasEntry& e = tlas_entries_[h.inst];
    h.inst = e.merged ? blases_[e.blas].instance_of(h.prim) : e.instance;
    return true;
  }
  // Closest hit on instance `instance`'s own triangles only (Cycles' scene_intersect_local, for
  // subsurface random walks): h as intersect() fills it. False where the instance has none or
  // no local BVH (its materials have no subsurface).
  bool intersect_local(uint32_t instance, const Ray& r, Hit& h) const;
  // Whether the viewer along wo sees the hit's back: its winding's side, turned round for a
  // mirrored instance (Cycles flips Ng for negative scales), so it is the normals' side.
  bool backfacing(const SurfacePoint& sp, Vec3 wo) const {
    return (dot(sp.ng, wo) < 0.0f) != (sp.instance < inst_.size() && inst_[sp.instance].negative);
  }
  // Cycles' shadow_ray_offset: how far (0..1) a light sample towards L from a triangle hit
  // is lifted, by its object's shadow terminator geometry offset, onto the parabolic
  // approximation of the smooth surface its vertex normals describe (terminator_lift). n, ng:
  // the shading (after the shader) and geometric normals, both facing the viewer; ng is
  // turned to the light's side where the light is behind n.
  [[gnu::always_inline]] float terminator_amount(const SurfacePoint& sp, Vec3 n, Vec3& ng, Vec3 L) const {
    if (sp.instance >= object_coords_.size()) return 0.0f;  // (curves too)
    const float cutoff = object_coords_[sp.instance].info.terminator;
    if (!(cutoff > 0.0f)) return 0.0f;
    float nl = dot(n, L);
    if (nl < 0.0f) {
      nl = -nl;
      ng = -ng;
    }
    const float ngl = dot(ng, L);
    return nl < cutoff ? clampf(2.0f - (ngl + nl) / cutoff, 0.0f, 1.0f) : clampf(1.0f - ngl / cutoff, 0.0f, 1.0f);
  }
  Vec3 terminator_lift(const SurfacePoint& sp, Vec3 ng, float amount) const;
  bool occluded(const Ray& r) const {
    if (curves_on_ && curve_bvh_.occluded(r)) return true;
    if (points_on_ && point_bvh_.occluded(r)) return true;
    if (!use_tlas_) return direct_ && blases_[0].bvh.occluded(r);
    return tlas_.occluded(r);
  }
  // The strand or point a ray spawned at sp leaves (Ray::self_curve): none off curves and points.
  uint32_t self_curve(const SurfacePoint& sp) const {
    if (sp.point()) return point_bvh_.sphere(sp.tri).point | kSelfPointBit;
    return sp.curve() ? curve_bvh_.piece(sp.tri).curve : UINT32_MAX;
  }
  // A ray passing through the surface at sp: it goes on from just past it on `side` (the ray's
  // side of the geometric normal) towards the same end point, or to infinity.
  void continue_past(Ray& ray, const SurfacePoint& sp, Vec3 side) const {
    const Vec3 org = offset_ray_origin(sp.p, sp.p_error, side);
    ray.self_curve = self_curve(sp);
    if (std::isfinite(ray.tmax)) {
      const Vec3 end = ray.org + ray.dir * ray.tmax;
      ray.dir = end - org;
      ray.tmax = 1.0f;
    }
    ray.org = org;
  }
  // The row of a hit triangle in its mesh's triangles.
  // Curve hits: the strand (numbered over all curve sets).
  uint32_t mesh_triangle(const Hit& h) const {
    if (h.inst == kCurveInstance) return curve_bvh_.piece(h.prim).curve;
    if (h.inst == kPointInstance) return point_bvh_.sphere(h.prim).point;
    return blases_[inst_[h.inst].blas].src_tri[h.prim];
  }
  // Baking (docs/design/bake.md): the BLAS triangle (Hit::prim) of each triangle of instance
  // `instance`'s mesh, in the mesh's order: UINT32_MAX where the commit dropped it (degenerate)
  // or left the instance out. Empty for an unknown instance. After commit.
  std::vector<uint32_t> instance_prims(uint32_t instance) const;
  // The world-space corners of BLAS triangle `prim` (Hit::prim) of instance `instance` as
  // the frame places them (false: no such triangle).
  bool instance_triangle(uint32_t instance, uint32_t prim, Vec3& v0, Vec3& v1, Vec3& v2) const;
  // The flattened-scene index of a hit triangle (what a single world-space BVH would report).
  uint32_t global_prim(const Hit& h) const {
    if (h.inst == kCurveInstance) return uint32_t(stats_.triangles) + curve_bvh_.piece(h.prim).curve;  // after the triangles
    if (h.inst == kPointInstance)  // after the strands
      return uint32_t(stats_.triangles + stats_.curves) + point_bvh_.sphere(h.prim).point;
    const InstanceData& in = inst_[h.inst];
    return in.prim_base + (h.prim - in.tri_base);
  }
  // time: the ray's (Ray::time), for instances that move.
  // ray: the ray that found h (ribbons face it: their point and normal need it; without it
  // a ribbon hit is shaded as seen from across the strand).
  void surface_point(const Hit& h, SurfacePoint& sp, float time = 0.5f, const Ray* ray = nullptr) const;
  // Evaluates the material at a hit: closures (frames from the mesh-oriented shading normal)
  // and emission. wo points towards the viewer.
  // ray: the ray that reached the point, for the Light Path node (a camera ray by default).
  void shade(const SurfacePoint& sp, float b1, float b2, Vec3 wo, ClosureList& out, const RayState& ray = {}) const;
  // The pass index of the object hit at sp (Cycles' Object Index pass).
  // Cycles' UV pass at sp: (u, v, 1) of uv set k, or zero where there is none (curves and
  // points too).
  Vec3 pass_uv(const SurfacePoint& sp, int k) const;
  // Cycles' Vector pass: where sp's point was at the previous frame and will be at the next one
  // (Instance::pass_motion, MeshData::pass_positions; curve and point sets: their pass_motion
  // and pass_points); still objects: sp.p.
  void pass_motion(const SurfacePoint& sp, Vec3& pre, Vec3& post) const;
  float object_pass_index(const SurfacePoint& sp) const { return object_info(sp).pass_index; }
  // The Object Info of what was hit at sp (its instance, curve set or point set).
  const ObjectInfo& object_info(const SurfacePoint& sp) const;
  float hair_pixel_coverage(const SurfacePoint& sp, float b1, const RayState& ray) const;
  Vec3 hair_curve_normal(const SurfacePoint& sp, float b1) const;
  // Fraction of light that passes from ray.org to ray.org + ray.dir * ray.tmax (0 when
  // blocked; Transparent surfaces let part of it through).
  // Inline: without Transparent BSDFs (most scenes) a shadow ray is one any-hit query.
  // max_hits: the transparent surfaces it may pass (RayState::shadow_hits); one more blocks.
  [[gnu::always_inline]] Vec3 transmittance(const Ray& ray, int max_hits = kShadowHits) const {
    if (!any_transparent_) return occluded(ray) ? Vec3(0.0f) : Vec3(1.0f);
    return transmittance_through(ray, kAllLightSets, false, max_hits);
  }
  // The same towards a light with shadow linking: objects whose shadow set is not in
  // shadow_mask let the light pass (Cycles' blocker collections).
  Vec3 transmittance_linked(const Ray& ray, uint64_t shadow_mask, int max_hits = kShadowHits) const {
    return transmittance_through(ray, shadow_mask, false, max_hits);
  }
  const std::vector<Image>& images() const { return images_; }
  // The heterogeneous medium inside `material` on `instance` (after commit), or nullptr.
  const HeteroMedium* hetero_medium(uint32_t instance, uint32_t material) const {
    for (const HeteroMedium& h : hetero_)
      if (h.instance == instance && h.material == material) return &h;
    return nullptr;
  }
  const std::vector<HeteroMedium>& hetero_media() const { return hetero_; }
  // The world's heterogeneous medium (after commit; a Volume program in the world), or nullptr.
  // Its majorants cover the scene's bounds (geometry, lights, camera): beyond them it is empty.
  const HeteroMedium* world_hetero() const { return world_het_.program ? &world_het_ : nullptr; }
  // Of the probe rays cast at commit from the camera and the lights, the fraction that leaves
  // the scene (no hit): where the world's heterogeneous medium depends on what lies beyond its
  // bounds (Cycles then takes one step of the ray's whole length; 0: a closed scene).
  float world_volume_open() const { return world_open_; }
  // Voxel grids of volume objects (read_vdb's), shared with Python; programs read them by id
  // (OpCode::VolumeGrid). Returns the grid's id.
  uint32_t add_volume_grid(std::shared_ptr<const VolumeGrid> grid) {
    grids_.push_back(std::move(grid));
    committed_ = false;
    return uint32_t(grids_.size() - 1);
  }
  size_t volume_grid_count() const { return grids_.size(); }
  const VolumeGrid* volume_grid(int id) const {
    return id >= 0 && size_t(id) < grids_.size() ? grids_[size_t(id)].get() : nullptr;
  }
  // The medium's coefficients at world point p for a ray along dir (unit) at shutter time
  // `time` (motion blur: the instance's transform then, the velocity's displacement).
  MediumSample medium_at(const HeteroMedium& h, Vec3 p, Vec3 dir, float time) const {
    if (__builtin_expect(h.moving || h.velocity_grid >= 0, 0)) return medium_at_moving(h, p, dir, time);
    return medium_at_frame(h, p, dir);
  }
  // At the frame: the commit's transform, no velocity (what the majorants are first built from).
  MediumSample medium_at_frame(const HeteroMedium& h, Vec3 p, Vec3 dir) const;
  // Scales every majorant built at the next commit (tests: below 1 the majorants are too
  // small, and the estimators must stay unbiased).
  void set_majorant_scale(float s) {
    majorant_scale_ = s;
    committed_ = false;
  }

  const Material& material(uint32_t id) const { return materials_[id]; }
  void set_material_cryptomatte(uint32_t id, float v) {
    if (id >= materials_.size()) throw std::invalid_argument("set_material_cryptomatte: unknown material id");
    materials_[id].crypto = std::isfinite(v) ? v : 0.0f;
  }
  void set_material_pass_index(uint32_t id, float v) {
    if (id >= materials_.size()) throw std::invalid_argument("set_material_pass_index: unknown material id");
    materials_[id].pass_index = std::isfinite(v) ? v : 0.0f;
  }
  Vec3 world_color() const { return world_color_; }
  const CameraDesc& camera_desc() const { return camera_; }
  bool has_camera() const { return has_camera_; }
  // The camera's space for programs that no camera ray reaches (lights, volumes): Camera Data.
  const Camera* shading_camera() const { return has_camera_ ? &shading_camera_ : nullptr; }

  bool has_lights() const { return any_lights_; }
  // An analytic light that rays may hit (a compact list built at commit): a bounding sphere for
  // a quick rejection, and what rays see it.
  struct HitLight {
    Vec3 center;
    float radius = 0.0f, radius2 = 0.0f;  // the bounding sphere's radius (padded) and its square
    Vec3 lo, hi;  // bounding box
    uint32_t index = 0;    // into the lights
    uint8_t visibility = 0;
    bool mis = true;
  };
  const std::vector<HitLight>& hit_lights() const { return hit_lights_; }  // finite lights
  // Calls f(h) for every finite hit light whose bounds the segment org + d t, 0 <= t < tmax, may
  // cross (d unit): all of them by their bounding spheres below kHitLightBvhMin, else through a
  // small BVH over their boxes (the light tree's rooms: 50 lamps a segment cost 1.4-1.8x time).
  static constexpr size_t kHitLightBvhMin = 8;
  template <class F>
  void for_hit_lights(Vec3 org, Vec3 d, float tmax, const F& f) const {
    if (hit_nodes_.empty()) {
      for (const HitLight& h : hit_lights_) {
        const Vec3 oc = h.center - org;
        const float tc = dot(oc, d);
        const float r = h.radius;
        if (!(tc + r > 0.0f) || !(tc - r < tmax)) continue;
        const float oc2 = length_sq(oc);
        if (oc2 - tc * tc > h.radius2 + 1e-6f * oc2) continue;
        f(h);
      }
      return;
    }
    const auto inv1 = [](float x) { return std::fabs(x) > 1e-30f ? 1.0f / x : std::copysign(1e30f, x); };
    const Vec3 inv{inv1(d.x), inv1(d.y), inv1(d.z)};
    uint32_t stack[64];
    int sp = 0;
    uint32_t n = 0;
    for (;;) {
      const HitLightNode& node = hit_nodes_[n];
      const float x0 = (node.lo.x - org.x) * inv.x, x1 = (node.hi.x - org.x) * inv.x;
      const float y0 = (node.lo.y - org.y) * inv.y, y1 = (node.hi.y - org.y) * inv.y;
      const float z0 = (node.lo.z - org.z) * inv.z, z1 = (node.hi.z - org.z) * inv.z;
      const float t0 = std::max(std::max(std::min(x0, x1), std::min(y0, y1)), std::max(std::min(z0, z1), 0.0f));
      const float t1 = std::min(std::min(std::max(x0, x1), std::max(y0, y1)), std::min(std::max(z0, z1), tmax));
      if (t0 <= t1 * 1.00001f + 1e-6f) {
        if (node.count) {
          for (uint32_t i = node.first; i < node.first + node.count; ++i) f(hit_lights_[i]);
        } else {
          if (sp < 64) stack[sp++] = node.first;  // the right child; the left one follows n
          n = n + 1;
          continue;
        }
      }
      if (sp == 0) break;
      n = stack[--sp];
    }
  }
  const std::vector<HitLight>& hit_suns() const { return hit_suns_; }      // suns with an angle
  // Shadow-linked lights with extent and Multiple Importance (suns too): rays from surfaces find
  // them by a dedicated shadow ray past the blockers they ignore, as Cycles' shadow linking.
  const std::vector<HitLight>& dedicated_lights() const { return dedicated_lights_; }
  const Light& light(size_t k) const { return lights_[k]; }
  size_t light_count() const { return lights_.size(); }
  const Environment& environment() const { return env_; }  // (invalid: none)
  // The nearest analytic light with Multiple Importance on that the ray from `from` along the
  // unit dir crosses before tmax: its distance, radiance and the MIS pdf (the light's choice at
  // `from` with normal n times sample_light's solid-angle pdf); false for none. For tests (the
  // integrator adds every light a ray crosses).
  bool nearest_light_hit(Vec3 from, Vec3 n, Vec3 dir, float tmax, float& t, Vec3& le, float& pdf) const;
  // The probability that a light sample at p (shading normal n, zero: none) picks light k.
  // set: the point's light set (light linking).
  float light_choice_pmf(Vec3 p, Vec3 n, size_t k, uint8_t set = 0) const {
    const LightChoice& c = choice(set);
    return c.dist.empty() ? 0.0f : light_pmf(c, p, n, k);
  }
  // Radiance arriving from the world along a ray that escapes the scene.
  // rs: the escaped ray's kind and counts, which a program world's Light Path reads (nullptr:
  // none, as a light sample's).
  // ray_p: its origin (a program world's Window for an orthographic camera; nullptr: none).
  Vec3 background(Vec3 dir, const RayState* rs = nullptr, const Vec3* ray_p = nullptr) const {
    return env_.valid() ? env_.eval(dir, rs, ray_p) : world_color_;
  }
  // Picks a light with u_select and samples it from point p.
  // bsdf_follows: a BSDF sample from p will be traced and MIS-weighted against this one; if not,
  // every direction the light can come from must have density here.
  bool sample_direct(Vec3 p, float u_select, Vec2 u, DirectSample& s, bool bsdf_follows = true) const {
    // Two instances: the power sampler's compiles as it did before there was a tree.
    // With light linking, the lights of the point's light set (s.receiver).
    const LightChoice& c = choice(s.receiver);
    return c.use_tree ? sample_direct_t<true>(c, p, u_select, u, s, bsdf_follows)
                      : sample_direct_t<false>(c, p, u_select, u, s, bsdf_follows);
  }
  // A point on a light chosen as sample_direct chooses from p, without its visibility tests (a
  // spot's cone, a one-sided area light's back): equiangular sampling in media crowds distances
  // towards it. False for distant lights (sun, environment). Any point is a valid choice; this
  // one only makes the sampling efficient. [t0, t1] (in: the segment of the ray p + t d, d unit)
  // becomes the part of it the light can reach (a spot's cone widened by its radius, an area
  // light's front), empty (t1 <= t0) where it reaches none. Sampling only there is unbiased as
  // long as the other strategies' MIS weights see the density 0 elsewhere.
  bool light_reference_point(Vec3 p, Vec3 d, float u_select, Vec2 u, Vec3& c, float& t0, float& t1) const;
  // Solid-angle pdfs with which sample_direct, called at `from`, finds the point `at` of emissive
  // triangle `prim` (cos_l: the cosine there), or the environment in direction dir (for MIS of
  // BSDF samples).
  // from_n: the shading normal at `from` that sample_direct was given (DirectSample::n).
  // set: the light set of the point at `from` (DirectSample::receiver).
  float pdf_emitter(const SurfacePoint& sp, Vec3 from, Vec3 at, float cos_l, Vec3 from_n = Vec3(0.0f), uint8_t set = 0) const;
  float pdf_environment(Vec3 dir, Vec3 from, uint8_t set = 0) const;
  // background(dir) and pdf_environment(dir, from, set) at once (one map look-up).
  Vec3 background_with_pdf(Vec3 dir, Vec3 from, uint8_t set, float& env_pdf, const RayState* rs = nullptr,
                           const Vec3* ray_p = nullptr) const;
  // The probability that light set `set`'s choice picks the environment; -1: it cannot.
  float environment_pmf(uint8_t set) const;
  // The world's own sampling from p (its choice among lights not included): through the portals
  // p is in front of and by the map, or by the map alone (no portal faces p). Radiance, solid-angle
  // pdf; cover_all as Environment::sample. world_pdf: the same density for a direction.
  // rs: the light sample's Light Path state (light_sample_state), which a program world reads.
  bool sample_world(Vec3 p, Vec2 u, Vec3& dir, Vec3& li, float& pdf, bool cover_all,
                    const RayState* rs = nullptr) const;
  // What a program world's Light Path reads in a light sample from a vertex whose path state is
  // `path` (Cycles' light_sample_shader_eval: no ray kind, PATH_RAY_EMISSION, and the vertex's
  // bounce counts; Environment::eval adds the emission's one to Ray Depth), written to `buf`;
  // nullptr for image, sky and constant worlds, which read none.
  const RayState* light_sample_state(const RayState* path, RayState& buf) const {
    if (!env_.program()) return nullptr;
    buf = path ? *path : RayState{};
    buf.flags = 0;
    return &buf;
  }
  // sample_world in two steps: the direction alone (portals' choice included), then its
  // radiance and the mixture's pdf at p.
  bool sample_world_direction(Vec3 p, Vec2 u, Vec3& dir, bool cover_all) const;
  // A world_pending light sample's radiance and pdf, as sample_direct would have given them;
  // false where it has none (the sample is then dropped, as sample_direct would have).
  bool finish_world_sample(DirectSample& s) const {
    const float pdf = world_pdf(s.world_p, s.wi, s.world_cover_all);
    if (!(pdf > 0.0f) || !std::isfinite(pdf)) return false;
    RayState rs;
    s.li = env_.eval(s.wi, light_sample_state(s.path, rs));
    s.pdf = pdf * s.world_pmf;
    s.world_pending = false;
    return true;
  }
  float world_pdf(Vec3 p, Vec3 dir, bool cover_all) const;
  // Light linking (after commit): whether any light or object uses it, and an instance's light
  // and shadow sets and, as an emitter, the sets it lights and is blocked by (curves, points:
  // not emitters).
  bool light_links() const { return links_; }
  uint8_t light_set_of(uint32_t instance) const {
    return instance < object_coords_.size() ? object_coords_[instance].info.light_set : 0;
  }
  uint8_t shadow_set_of(uint32_t instance) const {
    return instance < object_coords_.size() ? object_coords_[instance].info.shadow_set : 0;
  }
  // The light set of what is at sp: its instance's, or its curve or point set's (a search by
  // strand or point: only the linking kernel asks).
  uint8_t light_set_at(const SurfacePoint& sp) const {
    return sp.curve() || sp.point() ? object_info(sp).light_set : light_set_of(sp.instance);
  }
  // The object of a hit (instance and primitive; curves and points: their set's), or nullptr.
  const ObjectInfo* hit_info(uint32_t instance, uint32_t prim) const {
    if (instance == kCurveInstance) return &curve_coords_[curve_set_of(curve_bvh_.piece(prim).curve)].info;
    if (instance == kPointInstance) return &point_coords_[point_set_of(point_bvh_.sphere(prim).point)].info;
    return instance < object_coords_.size() ? &object_coords_[instance].info : nullptr;
  }
  // The shadow set of what a hit found (curves and points: their set's), for shadow linking.
  uint8_t shadow_set_of(const Hit& h) const {
    const ObjectInfo* info = hit_info(h.inst, h.prim);
    return info ? info->shadow_set : 0;
  }
  // Light groups (Cycles' View Layer ▸ Light Groups; render/integrator.h PathAovs::groups): the
  // group index of each emitter, -1: none. The world's (World ▸ Settings ▸ Light Group).
  void set_world_light_group(int g) { world_group_ = int16_t(g < 0 ? -1 : g); }
  int world_light_group() const { return world_group_; }
  // Of light sample entry k (DirectSample::entry): an analytic light's, an emitter group's
  // object's, the environment's (the world's).
  int entry_light_group(uint32_t k) const {
    if (k < lights_.size()) return lights_[k].light_group;
    if (k == env_index_) return world_group_;
    const size_t g = size_t(k) - lights_.size();
    return g < groups_.size() ? object_coords_[emitters_[groups_[g].first].instance].info.light_group : -1;
  }
  int instance_light_group(uint32_t instance) const {
    return instance < object_coords_.size() ? object_coords_[instance].info.light_group : -1;
  }
  uint64_t emitter_light_mask(uint32_t instance) const {
    return instance < object_coords_.size() ? object_coords_[instance].info.light_mask : kAllLightSets;
  }
  uint64_t emitter_shadow_mask(uint32_t instance) const {
    return instance < object_coords_.size() ? object_coords_[instance].info.shadow_mask : kAllLightSets;
  }
  const SceneStats& stats() const { return stats_; }
  const SceneFeatures& features() const { return features_; }
  // The largest BLAS (its build statistics stand for the scene's); an empty Bvh when there is none.
  const Bvh& bvh() const { return blases_.empty() ? empty_bvh_ : blases_[largest_blas_].bvh; }
  const Tlas& tlas() const { return tlas_; }

 private:
  // shade()'s per-hit program for materials that are not constant.
  void shade_program(const Material& mat, const ShadingContext& ctx, ClosureList& out) const;
  // A bottom-level BVH and what maps its triangles back to the meshes.
  struct Blas {
    Bvh bvh;
    // In BLAS space (world for the merged one), BVH input order. RawVectors: the merged BLAS's
    // copy is written in full on all threads, so resize() must not zero it first on one.
    RawVector<TriangleVerts> tris;
    RawVector<uint32_t> src_tri;  // the mesh triangle of each
    // Merged BLAS: its triangles are runs, one per instance in instance order; run k starts at
    // triangle run_first[k] (run_first[0] == 0) and belongs to instance run_inst[k]. A search in
    // this small table instead of a per-triangle array: no cache miss per hit, 4 bytes less per
    // triangle.
    std::vector<uint32_t> run_first, run_inst;
    uint32_t instance_of(uint32_t prim) const {  // branchless: the last run starting at or before prim
      const uint32_t* f = run_first.data();
      size_t n = run_first.size();
      while (n > 1) {
        const size_t half = n / 2;
        f = f[half] <= prim ? f + half : f;
        n -= half;
      }
      return run_inst[size_t(f - run_first.data())];
    }
    std::vector<int32_t> emitter;     // per triangle: merged: emitter index; else index among
                                      // this BLAS's emissive triangles; -1 none (empty: none)
    std::vector<uint32_t> emissive;   // object-space BLAS: its emissive triangles
    std::unique_ptr<DeformBvh> deform;  // deformation blur: traced instead of bvh (same numbering)
    size_t dropped = 0;
    uint32_t mesh = 0;  // object-space BLAS: its mesh
    bool merged = false;
  };
  // Per scene instance, made at commit.
  struct InstanceData {
    uint32_t blas = UINT32_MAX;  // UINT32_MAX: left out (singular transform or no triangles)
    uint32_t mesh = 0;
    uint32_t tri_base = 0;       // merged: its first triangle in the merged BLAS
    uint32_t prim_base = 0;      // its first triangle in the flattened scene order
    uint32_t emitter_base = 0;   // object-space BLAS: its first emitter
    uint32_t kept = 0;           // its triangles in the flattened scene
    bool transformed = false;    // a real instance: traced through to_object, hit data in object space
    Mat4 to_world, to_object;
    Vec3 nrow[3];                // cofactors: normal (and cross product) transform
    bool negative = false;       // negative determinant: mirrored
    // Motion blur: decomposed steps (in Scene::motion_), nullptr when static. Such an instance
    // is always a real one, and emits no light samples (its emission is found by BSDF rays).
    const DecomposedTransform* motion = nullptr;
    uint32_t motion_steps = 0;
    const DeformBvh* deform = nullptr;  // deformation blur (its BLAS's), or nullptr
    Vec3 normal(Vec3 n) const {  // Mat4::normal's arithmetic, cofactors precomputed
      const Vec3 out = nrow[0] * n.x + nrow[1] * n.y + nrow[2] * n.z;
      return negative ? -out : out;
    }
  };
  struct TlasEntry {
    uint32_t blas = 0, instance = 0;
    bool merged = false;
  };

  std::vector<Material> materials_;
  std::vector<Image> images_;
  size_t uv_sets_ = 0;  // most uv sets of any mesh
  bool any_transparent_ = false;
  bool any_holdout_ = false;
  // transmittance() through Transparent surfaces (closest hits shaded one by one).
  // catchers_only: only shadow catchers block (the rest is passed as if not there).
  Vec3 transmittance_through(Ray ray, uint64_t shadow_mask = kAllLightSets, bool catchers_only = false,
                             int max_hits = kShadowHits) const;
  std::vector<MeshData> meshes_;
  std::vector<Instance> instances_;
  std::vector<Float4> object_attrs_;  // the instances' object attribute values (ObjectInfo::attr_first)
  // Curves: the sets as added, their pieces' BVH (world space) and per set its first strand.
  std::vector<CurveSetData> curve_sets_;
  CurveBvh curve_bvh_;
  std::vector<uint32_t> curve_first_;
  std::vector<float> curve_length_, curve_random_;  // per strand: Curves Info's Length and Random
  std::vector<uint32_t> curve_material_;  // per strand: its material
  std::vector<Vec2> curve_uv_;  // per strand: curve_uv_sets_ uvs (the sets' per-strand uvs)
  uint32_t curve_uv_sets_ = 0;
  std::vector<Float4> curve_attr_;  // per strand: curve_attr_sets_ values (the sets' per-strand RGBA)
  uint32_t curve_attr_sets_ = 0;
  // Point-domain attributes and uvs (only of curve sets that have some): per curve set the
  // masks of its per-point attribute sets (low byte) and uv sets (high byte); per strand its
  // first key in curve_key_v_ (UINT32_MAX: none) and its key count; per key its intercept (to
  // find the hit's segment and parameter) and curve_key_sets_ values (slot k: attribute or uv
  // set k, a uv in x, y).
  std::vector<uint16_t> curve_point_sets_;
  std::vector<uint32_t> curve_key_first_, curve_key_count_;
  std::vector<float> curve_key_v_;
  std::vector<Float4> curve_key_attr_;
  uint32_t curve_key_sets_ = 0;
  // Vector pass of deforming strands (only where a set has pass_points): per curve set whether
  // it deforms; per key (as curve_key_v_) its object-space point now, at the previous and at
  // the next frame.
  std::vector<uint8_t> curve_pass_deform_;
  std::vector<Vec3> curve_key_pass_;
  // The keys of strand `curve` around intercept v (indices into curve_key_v_) and v's
  // parameter between them; false where the strand has no keys kept.
  bool curve_key_span(uint32_t curve, float v, uint32_t& k0, uint32_t& k1, float& t) const;
  // The per-point slots of strand `curve` interpolated at intercept v into buf
  // (curve_key_sets_ values); its masks (0: no per-point values).
  uint16_t curve_point_values(uint32_t curve, float v, Float4* buf) const;
  std::vector<ObjectCoords> curve_coords_;  // per curve set: its object (Object Info, object coordinates)
  bool curves_dirty_ = false;
  bool curves_on_ = false;  // curve_bvh_ is not empty: traced after the meshes
  void build_curves();
  bool intersect_with_curves(const Ray& r, Hit& h, TraversalCounters* c) const {
    bool found = intersect_meshes(r, h, c);
    Ray rc = r;
    if (found) rc.tmax = h.t;
    Hit hc;
    if (curves_on_ && curve_bvh_.intersect(rc, hc)) {
      h = hc;
      h.inst = kCurveInstance;
      rc.tmax = h.t;
      found = true;
    }
    Hit hp;
    if (points_on_ && point_bvh_.intersect(rc, hp)) {
      h = hp;
      h.inst = kPointInstance;
      found = true;
    }
    return found;
  }
  void curve_point(const Hit& h, SurfacePoint& sp, float time, const Ray* ray) const;
  // Point clouds: the sets as added, their spheres' BVH (world space), per set its first point,
  // and per point its attribute values (point_attr_sets_ each).
  std::vector<PointSetData> point_sets_;
  PointBvh point_bvh_;
  std::vector<uint32_t> point_first_;
  std::vector<Float4> point_attr_;
  uint32_t point_attr_sets_ = 0;
  std::vector<float> point_random_;  // per point: Point Info's Random
  // Vector pass of deforming clouds (only where a set has pass_points): per point set whether
  // it deforms; per point its object-space centre at the previous and at the next frame.
  std::vector<uint8_t> point_pass_deform_;
  std::vector<Vec3> point_pass_;
  // Per point set: Point Info's Radius over the sphere's (Cycles' point_radius, the object
  // radius along (1, 1, 1) / sqrt 3 through the matrix, over the cube root of its determinant).
  std::vector<float> point_radius_scale_;
  std::vector<ObjectCoords> point_coords_;  // per point set: its object (Object Info, object coordinates)
  bool points_dirty_ = false;
  bool points_on_ = false;  // point_bvh_ is not empty: traced after the meshes and curves
  void build_points();
  void sphere_point(const Hit& h, SurfacePoint& sp, float time) const;
  std::vector<uint8_t> point_moving_;  // per point set: it has transform motion blur
  std::vector<uint8_t> curve_moving_;  // per curve set: it has transform motion blur
  // Motion of curve and point sets dropped at their last build (added to stats().motion_rejected).
  size_t curve_motion_rejected_ = 0, point_motion_rejected_ = 0, instance_motion_rejected_ = 0;
  std::vector<ObjectCoords> object_coords_;  // per instance, made at commit
  // Per instance (empty when nothing has any): the Vector pass's world -> world maps to the
  // previous and next frames, or object -> world at them where its mesh deforms.
  struct PassMotion {
    Mat4 pre, post;
    bool moves = false, deform = false;
  };
  std::vector<PassMotion> pass_motion_;
  std::vector<std::vector<DecomposedTransform>> motion_;  // per instance, made at commit (empty: static)
  size_t motion_instances_ = 0;
  size_t mesh_motion_rejected_ = 0;  // set_mesh_motion calls refused
  // Sets in's world transform and its normal cofactors to m.
  static void set_instance_matrix(InstanceData& in, const Mat4& m);
  void surface_point_in(const InstanceData& in, const TriangleVerts& tv, const Hit& h, SurfacePoint& sp) const;
  Vec3 world_color_{0.0f};
  bool world_samples_ = false;  // opt-in: a furnace loses its zero variance (sampling.md)
  bool defer_world_ = true;     // set_defer_world_samples
  bool world_sampled_ = true;   // set_world_sampled
  ShaderProgram world_volume_;
  CameraDesc camera_;
  bool has_camera_ = false;
  Camera shading_camera_;  // camera_ without a frame size (only its space is read)
  bool committed_ = false;
  std::atomic<bool> cancel_{false};
  bool geometry_dirty_ = true;
  bool top_dirty_ = false;  // only instance transforms changed (dynamic / real instances)
  bool dynamic_ = false;
  BvhLayout built_layout_ = BvhLayout::Auto;
  bool spatial_splits_ = false, built_spatial_splits_ = false;
  CompactBvh compact_bvh_ = CompactBvh::Auto, built_compact_bvh_ = CompactBvh::Auto;
  BuildQuality build_quality_ = BuildQuality::Auto;
  bool solid_angle_triangles_ = true;
  bool solid_angle_rects_ = true;
  bool light_hits_on_ = true;
  std::vector<HitLight> hit_lights_, hit_suns_, dedicated_lights_;
  // The BVH over hit_lights_ (empty below kHitLightBvhMin lights): depth first, the left child
  // next to its parent; first: a leaf's first light or an interior node's right child.
  struct HitLightNode {
    Vec3 lo, hi;
    uint32_t first = 0, count = 0;  // count 0: interior
  };
  std::vector<HitLightNode> hit_nodes_;
  uint32_t build_hit_nodes(size_t begin, size_t end);
  bool emitter_groups_ = true;
  bool rect_groups_ = true;

  std::vector<Blas> blases_;
  std::vector<InstanceData> inst_;
  std::vector<uint32_t> mesh_blas_;  // per mesh: its object-space BLAS, or UINT32_MAX
  std::vector<TlasEntry> tlas_entries_;
  // Subsurface objects merged into blases_[0]: a BVH over each one's own run of triangles
  // (index in local_bvhs_ per instance, UINT32_MAX: none), for intersect_local. Built at commit
  // for the instances whose materials have subsurface; real instances use their own BLAS.
  std::vector<uint32_t> local_index_;
  std::vector<Bvh> local_bvhs_;
  std::vector<HeteroMedium> hetero_;  // made at commit (build_media)
  HeteroMedium world_het_;            // the world's Volume program (program null: none)
  float world_open_ = 0.0f;
  void build_world_medium();
  void build_program_majorants(HeteroMedium& h, const Aabb& bounds, uint32_t instance);
  size_t velocity_media_ = 0;         // of them with velocity blur
  MediumSample medium_at_moving(const HeteroMedium& h, Vec3 p, Vec3 dir, float time) const;
  void sweep_majorants(HeteroMedium& h, const Aabb& object_box);
  std::vector<std::shared_ptr<const VolumeGrid>> grids_;  // add_volume_grid
  float majorant_scale_ = 1.0f;
  size_t local_built_for_ = SIZE_MAX;  // stats_.geometry_builds they were made for
  void build_local_bvhs(int threads);
  Tlas tlas_;
  bool use_tlas_ = false;
  bool direct_ = false;  // no top level: the merged BLAS (blases_[0]) alone is traced
  size_t largest_blas_ = 0;
  Bvh empty_bvh_;
  Aabb world_bounds_;
  std::vector<Light> lights_;
  Environment env_;
  std::vector<Light> portals_;
  // A constant world with portals is sampled as a constant map (built at commit, dropped at the
  // next one), so that the portals, the map's MIS and the kernels' environment code apply.
  bool env_from_color_ = false;
  // The summed pdf of the portals facing p that the ray p + t dir crosses (but `skip`), and
  // how many face p.
  double portal_pdf_sum(Vec3 p, Vec3 dir, size_t skip, int& facing) const;
  // One distribution over [analytic lights | emitter groups | environment], by power.
  struct Emitter {
    uint32_t instance, tri;  // tri: in the instance's BLAS
  };
  std::vector<Emitter> emitters_;
  std::vector<float> emitter_areas_;
  // Runs of emitters chosen as one light: a small mesh light's triangles (one object, one
  // material), or a single triangle. Inside a group sample_direct picks a triangle in proportion
  // to the solid angle it subtends (as one spherical polygon: picking one of a quad's two
  // triangles by power alone doubles one triangle's contribution and drops the other's).
  static constexpr uint32_t kMaxEmitterGroup = 4;
  struct EmitterGroup {
    uint32_t first = 0, count = 1;
    float area = 0.0f;
    // The group's distinct corners (shared ones once: a quad has 4, not 6) in BLAS space, and
    // each triangle's corners in that list.
    uint8_t corners = 0;
    uint8_t tri_corner[kMaxEmitterGroup][3] = {};
    Vec3 corner[3 * kMaxEmitterGroup];
    // Two triangles forming a rectangle in world space: sampled as one spherical rectangle
    // (where its solid angle is in the range that sampling is for). rect_o: the corner only
    // triangle 0 has; rect_x, rect_y: unit edge directions from it (lengths rect_lx, rect_ly);
    // rect_n: the unit normal. rect_corner: each triangle's corners as rectangle corners
    // (0: o, 1: o + x, 2: o + y, 3: o + x + y).
    bool rect = false;
    uint8_t rect_corner[2][3] = {};
    DVec3 rect_o, rect_x, rect_y, rect_n;
    double rect_lx = 0.0, rect_ly = 0.0, rect_inv_lx = 0.0, rect_inv_ly = 0.0;
    // Each triangle's unit normal as sample_emitter computes it from its world-space corners
    // (the same float operations), kept so rectangle samples skip the corner loads.
    Vec3 rect_tri_n[2];
  };
  std::vector<EmitterGroup> groups_;
  std::vector<uint32_t> emitter_group_;  // per emitter
  size_t env_index_ = SIZE_MAX;
  int16_t world_group_ = -1;  // set_world_light_group
  // How sample_direct chooses a light: one distribution over [analytic lights | emitter groups |
  // environment] by power, or the light tree over its finite entries (same indices) with the
  // infinite ones (suns, the environment) beside it: chosen with probability inf_share (their
  // share of the power, as the single distribution gives them), then by inf_dist over inf_items.
  struct LightChoice {
    Distribution1D dist;
    bool use_tree = false;
    LightTree tree;
    float inf_share = 0.0f, tree_share = 1.0f;
    Distribution1D inf_dist;
    std::vector<uint32_t> inf_items;
    std::vector<float> inf_pmf;  // per dist entry: its pmf when infinite (tree in use)
  };
  LightTreeMode light_tree_mode_ = LightTreeMode::Auto;
  // Every light; with light linking, those of the default light set 0.
  LightChoice lc_;
  // Light linking: the lights of light sets 1.. (set_lc_[s - 1]), each its own distribution or
  // tree over the lights that reach that set (Cycles specialises its tree per set the same way),
  // so a point picks only lights linked to it and the MIS pdfs are its set's.
  std::vector<LightChoice> set_lc_;
  bool links_ = false;       // some light or object uses light or shadow linking
  bool any_lights_ = false;  // some light set has a light
  const LightChoice& choice(uint8_t set) const { return set == 0 || set > set_lc_.size() ? lc_ : set_lc_[set - 1u]; }
  // The light's index and the probability of that choice, at p with normal n.
  template <bool kTree>
  static bool choose_light_t(const LightChoice& c, Vec3 p, Vec3 n, float u, size_t& k, float& pmf) {
    if constexpr (!kTree) {
      k = c.dist.sample(u);
      pmf = c.dist.pmf(k);
      return true;
    } else {
      if (u < c.inf_share) {
        k = c.inf_items[c.inf_dist.sample(u / c.inf_share)];
        pmf = c.inf_pmf[k];
        return true;
      }
      uint32_t item;
      float tp;
      if (!c.tree.sample(p, n, std::min((u - c.inf_share) / c.tree_share, 0x1.fffffep-1f), item, tp)) return false;
      k = item;
      pmf = c.tree_share * tp;
      return true;
    }
  }
  static bool choose_light(const LightChoice& c, Vec3 p, Vec3 n, float u, size_t& k, float& pmf) {
    return c.use_tree ? choose_light_t<true>(c, p, n, u, k, pmf) : choose_light_t<false>(c, p, n, u, k, pmf);
  }
  template <bool kTree>
  bool sample_direct_t(const LightChoice& c, Vec3 p, float u_select, Vec2 u, DirectSample& s, bool bsdf_follows) const;
  static float light_pmf(const LightChoice& c, Vec3 p, Vec3 n, size_t k) {
    if (!c.use_tree) return c.dist.pmf(k);
    if (c.inf_pmf[k] > 0.0f) return c.inf_pmf[k];
    return c.tree_share * c.tree.pmf(p, n, uint32_t(k));
  }
  // Fills c's tree and infinite lights from the choice weights (zero: left out).
  void build_light_tree(const std::vector<float>& weights, LightChoice& c) const;
  // The light sets an entry of the choice weights reaches and is blocked by (light linking).
  uint64_t entry_light_mask(size_t k) const;
  uint64_t entry_shadow_mask(size_t k) const;
  // The environment's choice weight from its power and the weights before it (build_lights).
  float env_choice_weight(float env_power, const std::vector<float>& others) const;
  SceneStats stats_;
  SceneFeatures features_;

  bool build_geometry(int threads, BvhLayout layout);  // false: cancelled
  void build_instances();  // transforms, object coordinates, flattened offsets
  void build_top_level();
  void build_lights();
  void build_media();  // scene_media.cpp
  void detect_features();
  void update_memory_stats();
  // World-space corners of a BLAS triangle of an instance.
  TriangleVerts world_triangle(const InstanceData& in, const TriangleVerts& tv) const {
    if (!in.transformed) return tv;
    return {in.to_world.point(tv.v0), in.to_world.point(tv.v1), in.to_world.point(tv.v2)};
  }
  // A triangle's point at barycentrics (b1, b2) in world space and its rounding-error bound:
  // what surface_point gives, for light samples that need no normals.
  static void triangle_point(const InstanceData& in, const TriangleVerts& tv, float b1, float b2, Vec3& p,
                             Vec3& p_error);
  // Samples emitter e from p given its spherical triangle (st, from p): the solid-angle pdf is
  // `pdf_solid` where `spherical`, else pmf_e over its area (converted to solid angle).
  bool sample_emitter(size_t e, Vec3 p, const SphericalTriangle& st, bool spherical, float pdf_solid, float pmf_e,
                      Vec2 u, DirectSample& s) const;
  // The light sample at barycentrics (b1, b2) of emitter e (unit normal n), with sample_emitter's pdfs.
  bool emitter_point_sample(size_t e, Vec3 p, float b1, float b2, Vec3 n, bool spherical, float pdf_solid, float pmf_e,
                            DirectSample& s) const;
  // Group g (two or more triangles) as seen from p: the unit directions to its distinct corners
  // and each triangle's solid angle; true when the group is sampled as a whole by solid angle
  // from p (every triangle would be on its own), with `total` the sum of the solid angles.
  bool group_solid_angles(const EmitterGroup& g, Vec3 p, double (*dirs)[3], double* omega, double& total) const;
  // A rectangle group as seen from p (its spherical rectangle).
  static SphericalRectLocal group_rect(const EmitterGroup& g, Vec3 p) {
    const DVec3 d = g.rect_o - DVec3(p);
    SphericalRectLocal r;
    spherical_rect_local(ddot(d, g.rect_x), ddot(d, g.rect_y), ddot(d, g.rect_n), g.rect_lx, g.rect_ly, r);
    return r;
  }
  // Makes g a rectangle group when its two triangles form one (world space, tight tolerance).
  void detect_rect(EmitterGroup& g, const InstanceData& in) const;
  int32_t emitter_of(const InstanceData& in, uint32_t tri) const {
    const Blas& b = blases_[in.blas];
    if (b.emitter.empty() || b.emitter[tri] < 0 || in.motion || in.deform) return -1;
    return b.merged ? b.emitter[tri] : int32_t(in.emitter_base) + b.emitter[tri];
  }
};

}  // namespace pl
