// The scene features in use (for kernel choice and logs), found at commit.
#include "scene/scene.h"
#include "scene/scene_detail.h"
#include "scene/light_shader.h"

namespace pl {

using detail::material_of;

namespace {
// (name, in use) for every scene feature, in the order logs list them.
std::vector<std::pair<const char*, bool>> feature_table(const SceneFeatures& f) {
  const auto light = [&](LightType t) { return (f.light_kinds >> uint32_t(t) & 1u) != 0; };
  return {{"diffuse", f.diffuse},
          {"glossy", f.glossy},
          {"glass", f.transmission},
          {"transparent", f.transparent},
          {"varying shaders", f.varying},
          {"textures", f.textures},
          {"normal maps", f.normal_maps},
          {"media", f.media},
          {"volumes", f.volumes},
          {"heterogeneous volumes", f.heterogeneous_volumes},
          {"mesh lights", f.emission},
          {"point lights", light(LightType::Point)},
          {"spot lights", light(LightType::Spot)},
          {"sun lights", light(LightType::Sun)},
          {"area lights", light(LightType::Rect) || light(LightType::Ellipse)},
          {"environment", f.environment},
          {"world light", f.world_light},
          {"light tree", f.light_tree},
          {"light hits", f.light_hits},
          {"light linking", f.light_links},
          {"light bounce limits", f.light_bounce_limits},
          {"subsurface", f.subsurface},
          {"shadow terminator", f.terminator},
          {"shadow catcher", f.shadow_catcher},
          {"holdout objects", f.object_holdout},
          {"indirect only objects", f.camera_invisible}};
}
}  // namespace

std::vector<std::string> SceneFeatures::names() const {
  std::vector<std::string> out;
  for (const auto& [name, on] : feature_table(*this))
    if (on) out.emplace_back(name);
  return out;
}

std::vector<std::string> SceneFeatures::all_names() {
  std::vector<std::string> out;
  for (const auto& e : feature_table(SceneFeatures{})) out.emplace_back(e.first);
  return out;
}

void Scene::detect_features() {
  SceneFeatures f;
  std::vector<uint8_t> used(materials_.size(), 0);
  // Meshes of one material (the common case) need no per-triangle look-up: one sequential
  // scan says so (0: not scanned, 1: one material, 2: several).
  std::vector<uint8_t> uniform(meshes_.size(), 0);
  const auto one_material = [&](uint32_t mi) {
    if (uniform[mi] == 0) {
      const std::vector<uint32_t>& ids = meshes_[mi].materials;
      bool same = true;
      for (size_t t = 1; t < ids.size(); ++t) same &= ids[t] == ids[0];
      uniform[mi] = same ? 1 : 2;
    }
    return uniform[mi] == 1;
  };
  for (const Blas& b : blases_) {
    // Merged: runs of one instance's triangles (no run search per triangle); else one run.
    const size_t runs = b.merged ? b.run_first.size() : 1;
    for (size_t r = 0; r < runs; ++r) {
      const uint32_t mi = b.merged ? inst_[b.run_inst[r]].mesh : b.mesh;
      const MeshData& mesh = meshes_[mi];
      const size_t begin = b.merged ? b.run_first[r] : 0;
      const size_t end = b.merged && r + 1 < runs ? b.run_first[r + 1] : b.src_tri.size();
      if (begin < end && one_material(mi)) {
        used[material_of(mesh, b.src_tri[begin], materials_.size())] = 1;
        continue;
      }
      for (size_t t = begin; t < end; ++t) used[material_of(mesh, b.src_tri[t], materials_.size())] = 1;
    }
  }
  if (curves_on_)
    for (const uint32_t m : curve_material_) used[m < materials_.size() ? m : 0] = 1;
  if (points_on_)
    for (const PointSetData& ps : point_sets_) used[ps.material < materials_.size() ? ps.material : 0] = 1;
  for (size_t id = 0; id < materials_.size(); ++id) {
    if (!used[id]) continue;
    const Material& m = materials_[id];
    f.media = f.media || m.program.has_medium();
    f.volumes = f.volumes || (m.program.has_medium() && (!is_black(m.program.sigma_s) ||
                                                         !is_black(m.program.volume_emission) || m.transparent)) ||
                m.program.volume != nullptr;
    f.heterogeneous_volumes = f.heterogeneous_volumes || m.program.volume != nullptr;
    if (m.constant) {  // the closures it does add
      for (int i = 0; i < m.cached.n; ++i) {
        const Bsdf& b = m.cached.c[size_t(i)].bsdf;
        if (std::holds_alternative<DiffuseBsdf>(b)) f.diffuse = true;
        else if (std::holds_alternative<TranslucentBsdf>(b)) f.diffuse = f.transmission = true;
        else if (std::holds_alternative<ConductorBsdf>(b)) f.glossy = true;
        else if (std::holds_alternative<TransparentBsdf>(b)) f.transparent = true;
        else if (std::holds_alternative<HairChiangBsdf>(b) || std::holds_alternative<HairBsdf>(b) ||
                 std::holds_alternative<HairHuangBsdf>(b))
          f.glossy = f.transmission = true;
        else if (std::holds_alternative<SubsurfaceBsdf>(b)) f.subsurface = true;
        // Rough diffuse and sheen: diffuse bounces, but not the diffuse-only kernel's lobe.
        else if (std::holds_alternative<OrenNayarBsdf>(b) || std::holds_alternative<SheenBsdf>(b) ||
                 std::holds_alternative<VelvetBsdf>(b) || std::holds_alternative<ToonBsdf>(b))
          f.diffuse = f.glossy = true;
        else if (std::get<DielectricBsdf>(b).transmission) f.transmission = true;
        else f.glossy = true;
      }
    }
    f.varying = f.varying || m.program.varying;
    f.subsurface = f.subsurface || m.subsurface;
    for (const ShaderOp& op : m.program.ops) {
      f.textures = f.textures || op.code == OpCode::ImageTex || op.code == OpCode::ImageBox;
      f.normal_maps = f.normal_maps || op.code == OpCode::NormalMap || op.code == OpCode::Bump;
      f.footprints = f.footprints || (op.code == OpCode::Bump && m.program.bump_filter_width > 0.0f) ||
                     (op.code == OpCode::Wireframe && op.ext != 0) ||
                     (op.code == OpCode::PrincipledHair && op.ext != 0);  // Huang's near field
      f.path_state = f.path_state || op.code == OpCode::LightPath || op.code == OpCode::AmbientOcclusion ||
                     op.code == OpCode::Bevel || op.code == OpCode::LightFalloff;  // (the ray's length)
      if (m.constant) continue;
      switch (op.code) {  // every kind the op can add
        case OpCode::Diffuse: f.diffuse = true; f.glossy = f.glossy || op.in[3] != kNoReg; break;  // in[3]: Oren-Nayar
        case OpCode::Sheen: case OpCode::Toon: f.diffuse = f.glossy = true; break;
        case OpCode::Translucent: f.diffuse = f.transmission = true; break;
        case OpCode::Glossy: case OpCode::Metallic: f.glossy = true; break;
        case OpCode::Glass: case OpCode::Refraction: f.glossy = f.transmission = true; break;
        case OpCode::Transparent: case OpCode::RayPortal: f.transparent = true; break;
        case OpCode::Principled: f.diffuse = f.glossy = f.transmission = true; break;
        case OpCode::PrincipledHair: case OpCode::Hair:
          f.glossy = f.transmission = true;
          f.transparent = f.transparent || (op.code == OpCode::PrincipledHair && op.ext != 0);  // Huang's off-ellipse hits
          break;
        default: break;
      }
    }
  }
  // A program world reads the escaped ray's state (Light Path) where it has such ops; Window
  // the ray's kind too (an orthographic camera's own rays read their origin).
  if (const WorldShader* ws = env_.world_shader())
    for (const ShaderOp& op : ws->program.ops)
      f.path_state = f.path_state || op.code == OpCode::LightPath || op.code == OpCode::AmbientOcclusion ||
                     (op.code == OpCode::BackgroundCamera && op.sub != 0);
  f.emission = !emitters_.empty();
  f.environment = env_.valid();
  if (world_volume_.has_medium()) f.media = f.volumes = true;
  f.heterogeneous_volumes = f.heterogeneous_volumes || world_volume_.volume != nullptr;
  f.world_light = !env_.valid() && !is_black(world_color_);
  for (const Light& l : lights_) {
    f.light_kinds |= 1u << uint32_t(l.type);
    f.light_bounce_limits = f.light_bounce_limits || l.max_bounces < 1024;
  }
  f.light_tree = lc_.use_tree;
  for (const LightChoice& c : set_lc_) f.light_tree = f.light_tree || c.use_tree;
  f.light_links = links_;
  for (size_t i = 0; i < inst_.size() && i < object_coords_.size(); ++i)  // smooth meshes only
    f.terminator = f.terminator || (inst_[i].blas != UINT32_MAX && object_coords_[i].info.terminator > 0.0f);
  f.light_hits = !hit_lights_.empty() || !hit_suns_.empty();
  for (size_t i = 0; i < inst_.size() && i < object_coords_.size(); ++i) {
    if (inst_[i].blas == UINT32_MAX) continue;
    f.shadow_catcher = f.shadow_catcher || object_coords_[i].info.shadow_catcher;
    f.object_holdout = f.object_holdout || object_coords_[i].info.holdout;
    f.camera_invisible = f.camera_invisible || object_coords_[i].info.camera_invisible;
  }
  for (const CurveSetData& cs : curve_sets_) {
    f.shadow_catcher = f.shadow_catcher || cs.info.shadow_catcher;
    f.object_holdout = f.object_holdout || cs.info.holdout;
    f.camera_invisible = f.camera_invisible || cs.info.camera_invisible;
  }
  for (const PointSetData& ps : point_sets_) {
    f.shadow_catcher = f.shadow_catcher || ps.info.shadow_catcher;
    f.object_holdout = f.object_holdout || ps.info.holdout;
    f.camera_invisible = f.camera_invisible || ps.info.camera_invisible;
  }
  features_ = f;
}

}  // namespace pl
