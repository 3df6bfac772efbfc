// The scene's contents (materials, meshes, instances) and commit, which builds the rest
// (scene_build.cpp, scene_lights.cpp, scene_features.cpp).
#include "scene/scene.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <stdexcept>
#include <utility>

namespace pl {

Material make_simple_material(const std::string& name, Vec3 base_color, Vec3 emission) {
  Material m;
  m.name = name;
  ShaderOp c0;
  c0.code = OpCode::Const;
  c0.dst = 0;
  c0.value = {base_color.x, base_color.y, base_color.z, 1.0f};
  ShaderOp c1 = c0;
  c1.dst = 1;
  c1.value = {emission.x, emission.y, emission.z, 1.0f};
  ShaderOp diffuse;
  diffuse.code = OpCode::Diffuse;
  diffuse.in[1] = 0;
  ShaderOp emit;
  emit.code = OpCode::Emission;
  emit.in[1] = 1;
  m.program.ops = {c0, c1, diffuse};
  if (!is_black(emission)) m.program.ops.insert(m.program.ops.end(), {emit});
  return m;
}

Scene::Scene() {
  // Material 0: the fallback grey diffuse for unassigned or out-of-range slots.
  materials_.push_back(make_simple_material("Default", Vec3(0.8f), Vec3(0.0f)));
}

namespace {
// Gives a value op that would overwrite a register some closure op has already read a fresh
// register (its later readers follow), so that every register a closure op reads keeps that
// value to the program's end. False where the kMaxRegs registers run out.
bool rename_closure_inputs(std::vector<ShaderOp>& ops) {
  int16_t cur[kMaxRegs];
  bool read[kMaxRegs] = {};
  int next = 0;
  for (int i = 0; i < kMaxRegs; ++i) cur[i] = int16_t(i);
  const auto valid = [](int16_t r) { return r >= 0 && r < kMaxRegs; };
  for (const ShaderOp& op : ops) {
    for (int16_t r : op.in)
      if (valid(r)) next = std::max(next, r + 1);
    if (valid(op.dst)) next = std::max(next, op.dst + 1);
  }
  for (ShaderOp& op : ops) {
    for (int16_t& r : op.in)
      if (valid(r)) r = cur[r];
    if (is_closure_op(op.code)) {
      for (int16_t r : op.in)
        if (valid(r)) read[r] = true;
      continue;
    }
    if (op.code == OpCode::VolumeOut || !valid(op.dst)) continue;
    if (read[cur[op.dst]]) {
      if (next >= kMaxRegs) return false;
      cur[op.dst] = int16_t(next++);
    }
    op.dst = cur[op.dst];
  }
  return true;
}

// Derived fields of a material: emission estimate, transparency, cached constant closures.
void prepare_material(Material& m, const std::vector<Image>& images) {
  // The emission at a neutral shading point, to weigh this material's triangles as lights.
  ShadingContext ctx;
  ctx.ng = ctx.ns = ctx.wo = {0.0f, 0.0f, 1.0f};
  ClosureList cl;
  eval_shader(m.program, images, ctx, cl);
  m.emission_estimate = cl.emission;
  bool emits = false;
  for (const ShaderOp& op : m.program.ops)
    emits = emits || op.code == OpCode::Emission || (op.code == OpCode::PrincipledExtra && op.in[kPxEmission] != kNoReg);
  if (emits && m.program.varying) {
    // Emission that varies (textures): probe a few uvs for the estimate, and never let it be
    // zero, so its triangles stay in the light distribution (light-only vertices need that).
    Vec2 uv[8];
    for (float u : {0.25f, 0.75f})
      for (float v : {0.25f, 0.75f}) {
        for (Vec2& x : uv) x = {u, v};
        ctx.uv = uv;
        ctx.uv_sets = 8;
        eval_shader(m.program, images, ctx, cl);
        m.emission_estimate = vmax(m.emission_estimate, cl.emission);
      }
    if (!(luminance(m.emission_estimate) > 0.0f)) m.emission_estimate = Vec3(1.0f);
  }
  m.transparent = false;
  m.holdout = false;
  m.has_hair = false;
  m.subsurface = false;
  m.subsurface_bump = false;
  m.uses_tangents = false;
  for (const ShaderOp& op : m.program.ops) {
    m.uses_tangents = m.uses_tangents || (op.code == OpCode::NormalMap && op.sub == 0) ||
                      (op.code == OpCode::Tangent && op.sub == 3) || op.code == OpCode::TangentDisplace;
    m.transparent = m.transparent || op.code == OpCode::Transparent;
    m.holdout = m.holdout || op.code == OpCode::Holdout;
    m.has_hair = m.has_hair || op.code == OpCode::PrincipledHair;
    m.subsurface = m.subsurface || op.code == OpCode::Subsurface ||
                   (op.code == OpCode::PrincipledExtra && op.in[kPxSubsurfaceWeight] != kNoReg);
  }
  for (size_t i = 0; i < m.program.ops.size(); ++i) {  // Cycles' SD_HAS_BSSRDF_BUMP
    const ShaderOp& op = m.program.ops[i];
    const bool principled_sss = op.code == OpCode::Principled && i > 0 &&
                                m.program.ops[i - 1].code == OpCode::PrincipledExtra &&
                                m.program.ops[i - 1].in[kPxSubsurfaceWeight] != kNoReg;
    if ((principled_sss && op.in[8] != kNoReg) || (op.code == OpCode::Subsurface && op.in[7] != kNoReg))
      m.subsurface_bump = true;
  }
  m.constant = !m.program.varying;
  if (m.constant) {
    ctx.uv = nullptr;
    ctx.uv_sets = 0;
    eval_shader(m.program, images, ctx, m.cached);
  }
  m.pass_through = m.constant && m.cached.n == 1 && is_black(m.cached.emission) && is_black(m.cached.holdout) &&
                   std::holds_alternative<TransparentBsdf>(m.cached.c[0].bsdf) && m.cached.c[0].weight.x == 1.0f &&
                   m.cached.c[0].weight.y == 1.0f && m.cached.c[0].weight.z == 1.0f && m.cached.c[0].pick == 1.0f &&
                   !m.has_hair && !m.holdout;
  m.closures_only = !m.constant && !m.program.reads_point && !m.program.sets_normal;
  m.closure_regs.clear();
  m.closure_ops.clear();
  m.principled.clear();
  if (!m.closures_only) return;
  // The add-on's allocator reuses registers a closure op has read: renamed apart, every closure
  // op finds its inputs in the registers as they are at the program's end.
  ShaderProgram renamed = m.program;
  if (!rename_closure_inputs(renamed.ops)) {
    m.closures_only = false;
    return;
  }
  ctx.uv = nullptr;
  ctx.uv_sets = 0;
  m.closure_regs.resize(kMaxRegs);
  eval_shader(renamed, images, ctx, cl, m.closure_regs.data());
  for (const ShaderOp& op : renamed.ops)
    if (is_closure_op(op.code)) m.closure_ops.push_back(op);
  m.principled = principled_inputs_of(m.closure_ops.data(), m.closure_ops.size(), m.closure_regs.data());
}
}  // namespace

uint32_t Scene::add_material(Material m) {
  prepare_material(m, images_);
  materials_.push_back(std::move(m));
  committed_ = false;
  return static_cast<uint32_t>(materials_.size() - 1);
}

void Scene::set_material(uint32_t id, Material m) {
  if (id == 0 || id >= materials_.size()) throw std::invalid_argument("set_material: unknown material id");
  prepare_material(m, images_);
  materials_[id] = std::move(m);
  committed_ = false;  // the light distribution depends on the emission estimates
}

uint32_t Scene::add_mesh(MeshData mesh) {
  meshes_.push_back(std::move(mesh));
  committed_ = false;
  geometry_dirty_ = true;
  return static_cast<uint32_t>(meshes_.size() - 1);
}

void Scene::add_instance(uint32_t mesh, const Mat4& m, const ObjectInfo& info, std::vector<Mat4> motion,
                         const std::vector<Float4>& attributes, std::vector<Mat4> pass_motion) {
  if (mesh >= meshes_.size()) throw std::invalid_argument("add_instance: unknown mesh id");
  if (attributes.size() > kMaxObjectAttributes) throw std::invalid_argument("add_instance: too many object attributes");
  ObjectInfo with_attrs = info;
  with_attrs.attr_first = uint32_t(object_attrs_.size());
  with_attrs.attr_count = uint32_t(attributes.size());
  object_attrs_.insert(object_attrs_.end(), attributes.begin(), attributes.end());
  if (!pass_motion.empty() && pass_motion.size() != 2) throw std::invalid_argument("add_instance: pass_motion takes 2 matrices");
  instances_.push_back({mesh, m, with_attrs, std::move(motion), std::move(pass_motion)});
  committed_ = false;
  geometry_dirty_ = true;
}

void Scene::set_mesh_motion(uint32_t mesh, std::vector<std::vector<Vec3>> steps) {
  if (mesh >= meshes_.size()) throw std::invalid_argument("set_mesh_motion: unknown mesh id");
  MeshData& m = meshes_[mesh];
  bool ok = steps.size() >= 2, moves = false;
  for (const std::vector<Vec3>& s : steps) {
    ok = ok && s.size() == m.positions.size();
    for (size_t k = 0; ok && k < s.size(); ++k) ok = is_finite(s[k]);
    moves = moves || (ok && std::memcmp(s.data(), steps[0].data(), s.size() * sizeof(Vec3)) != 0);
  }
  if (!ok && !steps.empty()) ++mesh_motion_rejected_;
  m.motion_positions = ok && moves ? std::move(steps) : std::vector<std::vector<Vec3>>{};
  committed_ = false;
  geometry_dirty_ = true;
}

bool Scene::set_mesh_pass_motion(uint32_t mesh, std::vector<std::vector<Vec3>> steps) {
  if (mesh >= meshes_.size()) throw std::invalid_argument("set_mesh_pass_motion: unknown mesh id");
  MeshData& m = meshes_[mesh];
  bool ok = steps.empty() || steps.size() == 2;
  for (const std::vector<Vec3>& st : steps) {
    ok = ok && st.size() == m.positions.size();
    for (size_t k = 0; ok && k < st.size(); ++k) ok = is_finite(st[k]);
  }
  m.pass_positions = ok ? std::move(steps) : std::vector<std::vector<Vec3>>{};
  committed_ = false;
  geometry_dirty_ = true;
  return ok;
}

void Scene::set_mesh_velocity(uint32_t mesh, int32_t grid, float scale, float offset, VolumeSampling sampling,
                              int32_t grid_y, int32_t grid_z) {
  if (mesh >= meshes_.size()) throw std::invalid_argument("set_mesh_velocity: unknown mesh id");
  if (!std::isfinite(scale) || !std::isfinite(offset))
    throw std::invalid_argument("set_mesh_velocity: scale and offset must be finite");
  MeshData& m = meshes_[mesh];
  const bool on = grid >= 0 && scale != 0.0f;
  m.velocity_grid = on ? grid : -1;
  m.velocity_scale = on ? scale : 0.0f;
  m.velocity_offset = on ? offset : 0.0f;
  m.velocity_sampling = sampling;
  const bool xyz = on && grid_y >= 0 && grid_z >= 0;
  m.velocity_yz[0] = xyz ? grid_y : -1;
  m.velocity_yz[1] = xyz ? grid_z : -1;
  committed_ = false;  // (media are rebuilt at every commit)
}

void Scene::set_instance_transform(uint32_t index, const Mat4& m) {
  if (index >= instances_.size()) throw std::invalid_argument("set_instance_transform: unknown instance");
  instances_[index].matrix = m;
  committed_ = false;
  // A real instance only moves in the top level; a merged one is baked into the merged BLAS.
  if (!geometry_dirty_ && index < inst_.size() && inst_[index].transformed) top_dirty_ = true;
  else geometry_dirty_ = true;
}

bool Scene::commit(int threads, BvhLayout layout) {
  cancel_.store(false);
  committed_ = false;
  if (curves_dirty_) {
    build_curves();
    top_dirty_ = true;  // the world bounds (and the lights' scene radius) include them
  }
  if (points_dirty_) {
    build_points();
    top_dirty_ = true;  // (as curves)
  }
  if (geometry_dirty_ || layout != built_layout_ || spatial_splits_ != built_spatial_splits_ ||
      compact_bvh_ != built_compact_bvh_) {
    if (!build_geometry(threads, layout)) return false;
  } else if (top_dirty_) {
    build_instances();
    build_top_level();
    ++stats_.top_level_builds;
  }
  top_dirty_ = false;
  stats_.motion_rejected = mesh_motion_rejected_ + instance_motion_rejected_ + curve_motion_rejected_ + point_motion_rejected_;
  build_lights();
  build_media();
  if (features_.subsurface || !local_bvhs_.empty()) build_local_bvhs(threads);
  update_memory_stats();
  committed_ = true;
  return true;
}

}  // namespace pl
