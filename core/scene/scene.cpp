#include "scene/scene.h"

#include "util/lookup3.h"

#include <cstring>
#include <stdexcept>
#include <utility>

#include "util/big_alloc.h"
#include "util/rng.h"
#include "util/parallel.h"

namespace pl {
namespace {

// Emissive triangles are sampled uniformly in the solid angle they subtend, except where that
// angle is tiny (far away: area sampling is as good, cheaper and better conditioned) or close to
// a hemisphere (the spherical construction loses precision there).
inline bool use_spherical_sampling(double omega) { return omega > 2e-4 && omega < 6.2; }

// One of a group's `count` triangles picked by x in [0, the weights' sum) in proportion to
// weight(i), and x rescaled into [0, 1] within its share, so that the sample stays stratified
// over the whole group. False where the pick has no weight.
template <class Weight>
inline bool pick_weighted(uint32_t count, const Weight& weight, double x, uint32_t& i, float& x_in_share) {
  double acc = 0.0;
  i = 0;
  for (; i + 1 < count && !(x < acc + weight(i)); ++i) acc += weight(i);
  const double wi = weight(i);
  if (!(wi > 0.0)) return false;
  x_in_share = float(std::clamp((x - acc) / wi, 0.0, 1.0));
  return true;
}

// The probability of picking triangle `area` of a group of `group_area` by area, times the
// group's own.
inline float area_pmf(float pmf, float area, float group_area) {
  return float(double(pmf) * double(area) / double(group_area));
}

}  // namespace

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
  for (const ShaderOp& op : m.program.ops) {
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

void Scene::add_instance(uint32_t mesh, const Mat4& m, const ObjectInfo& info, std::vector<Mat4> motion) {
  if (mesh >= meshes_.size()) throw std::invalid_argument("add_instance: unknown mesh id");
  instances_.push_back({mesh, m, info, std::move(motion)});
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
  if (geometry_dirty_ || layout != built_layout_ || spatial_splits_ != built_spatial_splits_ ||
      compact_bvh_ != built_compact_bvh_) {
    if (!build_geometry(threads, layout)) return false;
  } else if (top_dirty_) {
    build_instances();
    build_top_level();
    ++stats_.top_level_builds;
  }
  top_dirty_ = false;
  build_lights();
  if (features_.subsurface || !local_bvhs_.empty()) build_local_bvhs(threads);
  update_memory_stats();
  committed_ = true;
  return true;
}

namespace {
// Zero-area or non-finite triangles can never be hit reliably and have no normal. Coordinates
// beyond 1e30 cannot be traced meaningfully in float (their products overflow).
bool usable_triangle(const TriangleVerts& tv) {
  const Vec3 c = cross(tv.v1 - tv.v0, tv.v2 - tv.v0);
  const float big = std::max(max_component(vabs(tv.v0)), std::max(max_component(vabs(tv.v1)), max_component(vabs(tv.v2))));
  return is_finite(tv.v0) && is_finite(tv.v1) && is_finite(tv.v2) && length_sq(c) > 0.0f &&
         std::isfinite(length_sq(c)) && big < 1e30f;
}

// Inverse of an affine matrix, computed in double; false if singular or not finite.
bool affine_inverse(const Mat4& m, Mat4& inv) {
  double a[3][3];
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) a[i][j] = m.m[i][j];
  const double c00 = a[1][1] * a[2][2] - a[1][2] * a[2][1], c01 = a[1][2] * a[2][0] - a[1][0] * a[2][2],
               c02 = a[1][0] * a[2][1] - a[1][1] * a[2][0];
  const double det = a[0][0] * c00 + a[0][1] * c01 + a[0][2] * c02;
  if (!(std::fabs(det) > 0.0) || !std::isfinite(det)) return false;
  const double r = 1.0 / det;
  double b[3][3] = {{c00 * r, (a[0][2] * a[2][1] - a[0][1] * a[2][2]) * r, (a[0][1] * a[1][2] - a[0][2] * a[1][1]) * r},
                    {c01 * r, (a[0][0] * a[2][2] - a[0][2] * a[2][0]) * r, (a[0][2] * a[1][0] - a[0][0] * a[1][2]) * r},
                    {c02 * r, (a[0][1] * a[2][0] - a[0][0] * a[2][1]) * r, (a[0][0] * a[1][1] - a[0][1] * a[1][0]) * r}};
  for (int i = 0; i < 3; ++i) {
    double t = 0.0;
    for (int j = 0; j < 3; ++j) {
      inv.m[i][j] = float(b[i][j]);
      t -= b[i][j] * double(m.m[j][3]);
    }
    inv.m[i][3] = float(t);
  }
  inv.m[3][0] = inv.m[3][1] = inv.m[3][2] = 0.0f;
  inv.m[3][3] = 1.0f;
  return inv.is_finite() && m.is_finite();
}
}  // namespace

bool Scene::build_geometry(int threads, BvhLayout layout) {
  const auto cancelled = [&] {
    if (!cancel_.load(std::memory_order_relaxed)) return false;
    blases_.clear();
    inst_.clear();
    tlas_entries_.clear();
    tlas_.clear();
    use_tlas_ = direct_ = false;
    geometry_dirty_ = true;
    return true;
  };
  blases_.clear();
  tlas_.clear();
  uv_sets_ = 0;
  for (const MeshData& m : meshes_) uv_sets_ = std::max(uv_sets_, m.uvs.size());
  // Cycles' rule: a mesh used once is merged into world space, one used more is instanced
  // (dynamic mode: every one is instanced).
  std::vector<uint32_t> uses(meshes_.size(), 0);
  for (const Instance& inst : instances_) ++uses[inst.mesh];
  inst_.assign(instances_.size(), InstanceData());
  // Motion blur: each moving instance's steps decomposed once; it is then a real instance
  // (traced through its transform at the ray's time).
  motion_.assign(instances_.size(), {});
  stats_.motion_rejected = mesh_motion_rejected_;
  for (size_t i = 0; i < instances_.size(); ++i) {
    const std::vector<Mat4>& steps = instances_[i].motion;
    if (steps.size() < 2) continue;
    bool moves = false;
    for (const Mat4& m : steps) moves = moves || std::memcmp(&m, &steps[0], sizeof(Mat4)) != 0;
    if (!moves) continue;
    if (!decompose_motion(steps, motion_[i])) {
      motion_[i].clear();
      ++stats_.motion_rejected;
    }
  }
  for (size_t i = 0; i < instances_.size(); ++i) {
    inst_[i].mesh = instances_[i].mesh;
    inst_[i].transformed = dynamic_ || uses[instances_[i].mesh] > 1 || !motion_[i].empty() ||
                           !meshes_[instances_[i].mesh].motion_positions.empty();
  }
  size_t dropped = 0;

  // The merged BLAS (index 0 when present): single-use meshes in world space, instance order.
  Blas merged;
  merged.merged = true;
  size_t merged_total = 0;
  for (size_t i = 0; i < instances_.size(); ++i)
    if (!inst_[i].transformed) merged_total += meshes_[instances_[i].mesh].triangles.size();
  merged.tris.reserve(merged_total);
  merged.src_tri.reserve(merged_total);
  advise_huge_pages(merged.tris.data(), merged_total * sizeof(TriangleVerts));
  advise_huge_pages(merged.src_tri.data(), merged_total * sizeof(uint32_t));
  for (size_t i = 0; i < instances_.size(); ++i) {
    if (inst_[i].transformed) continue;
    if (cancelled()) return false;
    const Instance& inst = instances_[i];
    const MeshData& mesh = meshes_[inst.mesh];
    // On all threads (a 1M-triangle mesh takes tens of ms on one): world positions, then every
    // triangle written in place with its source index, UINT32_MAX where unusable; the rare
    // unusable ones are squeezed out afterwards in order.
    RawVector<Vec3> world(mesh.positions.size());  // written in full below: not zeroed on one thread first
    parallel_ranges(world.size(), threads, [&](size_t lo, size_t hi) {
      for (size_t k = lo; k < hi; ++k) world[k] = inst.matrix.point(mesh.positions[k]);
    });
    const size_t base = merged.tris.size(), nt = mesh.triangles.size();
    inst_[i].tri_base = uint32_t(base);
    merged.tris.resize(base + nt);
    merged.src_tri.resize(base + nt);
    std::atomic<size_t> unusable{0};
    parallel_ranges(nt, threads, [&](size_t lo, size_t hi) {
      size_t bad = 0;
      for (size_t t = lo; t < hi; ++t) {
        const auto& idx = mesh.triangles[t];
        const TriangleVerts tv{world[idx[0]], world[idx[1]], world[idx[2]]};
        const bool ok = usable_triangle(tv);
        merged.tris[base + t] = tv;
        merged.src_tri[base + t] = ok ? uint32_t(t) : UINT32_MAX;
        bad += !ok;
      }
      unusable.fetch_add(bad);
    });
    if (unusable.load() > 0) {
      size_t w = base;
      for (size_t t = base; t < base + nt; ++t)
        if (merged.src_tri[t] != UINT32_MAX) {
          merged.tris[w] = merged.tris[t];
          merged.src_tri[w++] = merged.src_tri[t];
        }
      merged.tris.resize(w);
      merged.src_tri.resize(w);
      dropped += unusable.load();
    }
    inst_[i].kept = uint32_t(merged.tris.size()) - inst_[i].tri_base;
    if (inst_[i].kept > 0) {
      merged.run_first.push_back(inst_[i].tri_base);
      merged.run_inst.push_back(uint32_t(i));
    }
    inst_[i].blas = 0;
  }
  if (!merged.tris.empty()) blases_.push_back(std::move(merged));
  else
    for (InstanceData& in : inst_) in.blas = in.transformed ? in.blas : UINT32_MAX;

  // One object-space BLAS per instanced mesh.
  mesh_blas_.assign(meshes_.size(), UINT32_MAX);
  for (size_t i = 0; i < instances_.size(); ++i) {
    const uint32_t mi = instances_[i].mesh;
    if (!inst_[i].transformed || mesh_blas_[mi] != UINT32_MAX) continue;
    if (cancelled()) return false;
    const MeshData& mesh = meshes_[mi];
    Blas b;
    b.mesh = mi;
    b.tris.reserve(mesh.triangles.size());
    b.src_tri.reserve(mesh.triangles.size());
    for (size_t t = 0; t < mesh.triangles.size(); ++t) {
      const auto& idx = mesh.triangles[t];
      const TriangleVerts tv{mesh.positions[idx[0]], mesh.positions[idx[1]], mesh.positions[idx[2]]};
      if (!usable_triangle(tv)) {
        ++b.dropped;
        continue;
      }
      b.tris.push_back(tv);
      b.src_tri.push_back(uint32_t(t));
    }
    if (b.tris.empty()) {
      mesh_blas_[mi] = UINT32_MAX - 1;  // nothing to trace: its instances are left out
      dropped += b.dropped * uses[mi];
      continue;
    }
    if (!mesh.motion_positions.empty()) {  // deformation blur: the kept triangles at every step
      std::vector<std::array<uint32_t, 3>> prims(b.src_tri.size());
      for (size_t k = 0; k < prims.size(); ++k) prims[k] = mesh.triangles[b.src_tri[k]];
      b.deform = std::make_unique<DeformBvh>();
      b.deform->build(mesh.motion_positions, prims);
    }
    dropped += b.dropped * uses[mi];
    mesh_blas_[mi] = uint32_t(blases_.size());
    blases_.push_back(std::move(b));
  }

  BvhBuildOptions opt;
  opt.threads = threads;
  opt.layout = layout;
  opt.cancel = &cancel_;
  opt.spatial_splits = spatial_splits_;
  largest_blas_ = 0;
  size_t blas_tris = 0, blas_refs = 0;
  for (size_t k = 0; k < blases_.size(); ++k) {
    opt.compact = compact_bvh_ == CompactBvh::On ||
                  (compact_bvh_ == CompactBvh::Auto && blases_[k].tris.size() >= kCompactAutoTriangles);
    opt.morton_clusters = build_quality_ == BuildQuality::Fast ||
                          (build_quality_ == BuildQuality::Auto && dynamic_ && blases_[k].tris.size() >= kFastBuildMin);
    if (!blases_[k].bvh.build(blases_[k].tris, opt)) {  // only a cancel makes it fail
      cancelled();
      return false;
    }
    blas_tris += blases_[k].tris.size();
    blas_refs += blases_[k].bvh.stats().references;
    if (blases_[k].tris.size() > blases_[largest_blas_].tris.size()) largest_blas_ = k;
  }
  build_instances();
  build_top_level();

  stats_.dropped_triangles += dropped;
  stats_.instances = instances_.size();
  stats_.meshes = meshes_.size();
  stats_.materials = materials_.size();
  stats_.blases = blases_.size();
  stats_.blas_triangles = blas_tris;
  stats_.blas_references = blas_refs;
  geometry_dirty_ = false;
  built_layout_ = layout;
  built_spatial_splits_ = spatial_splits_;
  built_compact_bvh_ = compact_bvh_;
  ++stats_.geometry_builds;
  return true;
}

void Scene::build_instances() {
  object_coords_.clear();
  object_coords_.reserve(instances_.size());
  uint32_t prim = 0;
  size_t real = 0, moving = 0, deforming = 0;
  // Texture spaces once per mesh, not per instance (the automatic one reads every vertex).
  std::vector<std::pair<Vec3, Vec3>> texspace(meshes_.size());
  std::vector<char> have_texspace(meshes_.size(), 0);
  for (size_t i = 0; i < instances_.size(); ++i) {
    const Instance& inst = instances_[i];
    const MeshData& mesh = meshes_[inst.mesh];
    InstanceData& in = inst_[i];
    // Object and generated texture coordinates of this instance.
    if (!have_texspace[inst.mesh]) {
      Vec3 ts_loc = mesh.texspace_location, ts_size = mesh.texspace_size;
      if (!mesh.has_texspace) auto_texspace(mesh.positions, ts_loc, ts_size);
      texspace[inst.mesh] = {ts_loc, ts_size};
      have_texspace[inst.mesh] = 1;
    }
    object_coords_.push_back(make_object_coords(inst.matrix, texspace[inst.mesh].first, texspace[inst.mesh].second));
    object_coords_.back().info = inst.info;
    const Mat4& m = inst.matrix;
    set_instance_matrix(in, m);
    in.motion = motion_[i].empty() ? nullptr : motion_[i].data();
    in.motion_steps = uint32_t(motion_[i].size());
    if (in.transformed) {
      in.blas = UINT32_MAX;
      in.kept = 0;
      const uint32_t b = mesh_blas_[inst.mesh];
      if (b < blases_.size() && affine_inverse(m, in.to_object)) {
        // Left out where its world box leaves the traceable range (as flattening drops triangles).
        const Aabb bb = blases_[b].deform ? blases_[b].deform->bounds() : blases_[b].bvh.bounds();
        Aabb wb;
        for (int c = 0; c < 8; ++c)
          wb.grow(m.point({(c & 1) ? bb.hi.x : bb.lo.x, (c & 2) ? bb.hi.y : bb.lo.y, (c & 4) ? bb.hi.z : bb.lo.z}));
        if (in.motion) wb.grow(motion_world_box(bb, in.motion, in.motion_steps));
        if (is_finite(wb.lo) && is_finite(wb.hi) && max_component(vmax(vabs(wb.lo), vabs(wb.hi))) < 1e30f) {
          in.blas = b;
          in.kept = uint32_t(blases_[b].tris.size());
          ++real;
          in.deform = blases_[b].deform.get();
          moving += in.motion != nullptr || in.deform != nullptr;
          deforming += in.deform != nullptr;
        }
      }
      in.tri_base = 0;
    }
    in.prim_base = prim;
    prim += in.kept;
  }
  stats_.triangles = prim;
  stats_.real_instances = real;
  stats_.motion_instances = motion_instances_ = moving;
  stats_.deforming_instances = deforming;
}

void Scene::set_instance_matrix(InstanceData& in, const Mat4& m) {
  in.to_world = m;
  const Vec3 c0{m.m[0][0], m.m[1][0], m.m[2][0]}, c1{m.m[0][1], m.m[1][1], m.m[2][1]}, c2{m.m[0][2], m.m[1][2], m.m[2][2]};
  in.nrow[0] = cross(c1, c2);
  in.nrow[1] = cross(c2, c0);
  in.nrow[2] = cross(c0, c1);
  in.negative = dot(c0, in.nrow[0]) < 0;
}

void Scene::build_top_level() {
  tlas_entries_.clear();
  std::vector<TlasInstance> entries;
  if (!blases_.empty() && blases_[0].merged) {
    tlas_entries_.push_back({0, 0, true});
    TlasInstance e;
    e.blas = &blases_[0].bvh;
    e.identity = true;
    entries.push_back(e);
  }
  for (size_t i = 0; i < inst_.size(); ++i) {
    const InstanceData& in = inst_[i];
    if (!in.transformed || in.blas == UINT32_MAX) continue;
    tlas_entries_.push_back({in.blas, uint32_t(i), false});
    TlasInstance e;
    e.blas = &blases_[in.blas].bvh;
    e.to_world = in.to_world;
    e.to_object = in.to_object;
    e.motion = in.motion;
    e.motion_steps = in.motion_steps;
    e.deform = in.deform;
    entries.push_back(e);
  }
  // A lone merged BLAS is traced directly: no top level, no transforms.
  direct_ = entries.size() == 1 && tlas_entries_[0].merged;
  use_tlas_ = !direct_ && !entries.empty();
  if (use_tlas_) {
    tlas_.build(std::move(entries));
    world_bounds_ = tlas_.bounds();
  } else {
    tlas_.clear();
    world_bounds_ = direct_ ? blases_[0].bvh.bounds() : Aabb();
  }
  if (curves_on_) world_bounds_.grow(curve_bvh_.bounds());
  stats_.tlas_instances = use_tlas_ ? tlas_.stats().instances : 0;
}

void Scene::update_memory_stats() {
  size_t bvh = tlas_.memory_bytes() + curve_bvh_.memory_bytes(), geo = 0;
  for (const Blas& b : blases_) {
    bvh += b.bvh.memory_bytes();
    geo += b.tris.capacity() * sizeof(TriangleVerts) + b.src_tri.capacity() * 4 + (b.run_first.capacity() + b.run_inst.capacity()) * 4 +
           b.emitter.capacity() * 4 + b.emissive.capacity() * 4;
  }
  geo += inst_.capacity() * sizeof(InstanceData) + object_coords_.capacity() * sizeof(ObjectCoords) +
         tlas_entries_.capacity() * sizeof(TlasEntry) + instances_.capacity() * sizeof(Instance);
  for (const MeshData& m : meshes_) {
    geo += m.positions.capacity() * sizeof(Vec3) + m.triangles.capacity() * 12 + m.normals.capacity() * sizeof(Vec3) +
           m.normal_indices.capacity() * 12 +
           m.materials.capacity() * 4;
    for (const auto& uv : m.uvs) geo += uv.capacity() * sizeof(Vec2);
    for (const auto& a : m.attributes) geo += a.capacity() * sizeof(Float4);
  }
  stats_.bvh_bytes = bvh;
  stats_.geometry_bytes = geo;
}

namespace {
inline uint32_t material_of(const MeshData& m, uint32_t tri, size_t materials) {
  const uint32_t id = m.materials.empty() ? 0u : m.materials[tri];
  return id < materials ? id : 0u;
}
}  // namespace

void Scene::detect_rect(EmitterGroup& g, const InstanceData& in) const {
  g.rect = false;
  if (g.count != 2 || g.corners != 4) return;
  const auto has = [&](int t, uint8_t c) { return g.tri_corner[t][0] == c || g.tri_corner[t][1] == c || g.tri_corner[t][2] == c; };
  // The corner only triangle 0 has (the origin), the one only triangle 1 has (opposite it), and
  // the shared diagonal's two in triangle 0's order.
  int o = -1, far = -1, a = -1, b = -1;
  for (int k = 0; k < 3; ++k) {
    const uint8_t c = g.tri_corner[0][k];
    if (!has(1, c)) o = c;
    else (a < 0 ? a : b) = c;
    if (!has(0, g.tri_corner[1][k])) far = g.tri_corner[1][k];
  }
  if (o < 0 || far < 0 || b < 0) return;
  DVec3 w[4];
  for (int c = 0; c < 4; ++c) w[c] = DVec3(in.transformed ? in.to_world.point(g.corner[c]) : g.corner[c]);  // as world_triangle
  const DVec3 ex = w[a] - w[o], ey = w[b] - w[o];
  const double lx = dlength(ex), ly = dlength(ey);
  if (!(lx > 0.0) || !(ly > 0.0) || !std::isfinite(lx * ly)) return;
  // A rectangle to 1e-5 of its edges: right-angled, and the fourth corner where the first three
  // put it (planar). Float corners (a rotated quad's) are off by ~1e-7; sheared ones by far more.
  constexpr double kTol = 1e-5;
  const DVec3 off = w[far] - (w[o] + ex + ey);
  if (!(std::fabs(ddot(ex, ey)) <= kTol * lx * ly) || !(dlength(off) <= kTol * std::min(lx, ly))) return;
  g.rect_o = w[o];
  g.rect_x = ex * (1.0 / lx);
  DVec3 y = ey - g.rect_x * ddot(ey, g.rect_x);  // exactly orthogonal for the warp
  if (!dnormalize(y)) return;
  g.rect_y = y;
  g.rect_n = dcross(g.rect_x, g.rect_y);
  g.rect_lx = lx;
  g.rect_ly = ddot(ey, y);
  if (!(g.rect_ly > 0.0) || !dnormalize(g.rect_n)) return;
  g.rect_inv_lx = 1.0 / g.rect_lx;
  g.rect_inv_ly = 1.0 / g.rect_ly;
  const auto rect_index = [&](int c) { return uint8_t(c == o ? 0 : c == a ? 1 : c == b ? 2 : 3); };
  for (int t = 0; t < 2; ++t)
    for (int k = 0; k < 3; ++k) g.rect_corner[t][k] = rect_index(g.tri_corner[t][k]);
  for (int t = 0; t < 2; ++t) {
    const Emitter& em = emitters_[g.first + size_t(t)];
    const TriangleVerts tv = world_triangle(inst_[em.instance], blases_[inst_[em.instance].blas].tris[em.tri]);
    g.rect_tri_n[t] = tv.unit_normal();
  }
  g.rect = true;
}

void Scene::build_lights() {
  any_transparent_ = false;
  any_holdout_ = false;
  for (const Material& m : materials_) {
    any_transparent_ = any_transparent_ || m.transparent;
    any_holdout_ = any_holdout_ || m.holdout;
  }
  stats_.materials = materials_.size();

  // Every light in one distribution, chosen in proportion to an estimate of its power.
  const Aabb bounds = world_bounds_;
  const float radius = bounds.empty() ? 1.0f : std::max(0.5f * length(bounds.extent()), 1e-6f);
  std::vector<float> weights;
  for (const Light& l : lights_) weights.push_back(light_power(l, radius));
  emitters_.clear();
  emitter_areas_.clear();
  const auto emission_weight = [&](uint32_t material) {
    const Vec3 le = materials_[material].emission_estimate;
    const float lum = std::max(luminance(le), max_component(le) * 1e-3f);
    return lum > 0.0f && std::isfinite(lum) ? lum : 0.0f;
  };
  std::vector<float> emitter_weights;
  std::vector<uint32_t> emitter_materials;
  const auto add_emitter = [&](uint32_t instance, uint32_t tri, const TriangleVerts& tv, float lum, uint32_t material) {
    const float area = 0.5f * length(cross(tv.v1 - tv.v0, tv.v2 - tv.v0));
    emitters_.push_back({instance, tri});
    emitter_areas_.push_back(area);
    emitter_weights.push_back(2.0f * kPi * area * lum);  // two-sided
    emitter_materials.push_back(material);
  };
  // Per material once; a scene without emissive materials skips the per-triangle scans.
  std::vector<float> material_lum(materials_.size());
  bool any_emissive = false;
  for (size_t id = 0; id < materials_.size(); ++id) {
    material_lum[id] = emission_weight(uint32_t(id));
    any_emissive = any_emissive || material_lum[id] > 0.0f;
  }
  // Emitters in flattened order for the merged triangles (as one world-space BVH had them),
  // then (instance, triangle) pairs of the real instances.
  for (Blas& b : blases_) {
    b.emitter.clear();
    b.emissive.clear();
    if (!any_emissive) continue;
    if (b.merged) {
      for (size_t r = 0; r < b.run_first.size(); ++r) {  // runs of one instance's triangles
        const uint32_t in = b.run_inst[r];
        const MeshData& mesh = meshes_[inst_[in].mesh];
        const uint32_t end = r + 1 < b.run_first.size() ? b.run_first[r + 1] : uint32_t(b.tris.size());
        for (uint32_t t = b.run_first[r]; t < end; ++t) {
          const uint32_t mat = material_of(mesh, b.src_tri[t], materials_.size());
          const float lum = material_lum[mat];
          if (!(lum > 0.0f)) continue;
          if (b.emitter.empty()) b.emitter.assign(b.tris.size(), -1);
          b.emitter[t] = int32_t(emitters_.size());
          add_emitter(in, t, b.tris[t], lum, mat);
        }
      }
    } else {
      for (uint32_t t = 0; t < b.tris.size(); ++t) {
        if (!(material_lum[material_of(meshes_[b.mesh], b.src_tri[t], materials_.size())] > 0.0f)) continue;
        if (b.emitter.empty()) b.emitter.assign(b.tris.size(), -1);
        b.emitter[t] = int32_t(b.emissive.size());
        b.emissive.push_back(t);
      }
    }
  }
  for (size_t i = 0; i < inst_.size(); ++i) {
    InstanceData& in = inst_[i];
    // Moving instances are no light samples (they would be sampled where the frame has them).
    if (!in.transformed || in.blas == UINT32_MAX || in.motion || in.deform) continue;
    const Blas& b = blases_[in.blas];
    in.emitter_base = uint32_t(emitters_.size());
    for (uint32_t t : b.emissive) {
      const uint32_t mat = material_of(meshes_[b.mesh], b.src_tri[t], materials_.size());
      add_emitter(uint32_t(i), t, world_triangle(in, b.tris[t]), material_lum[mat], mat);
    }
  }
  // Groups: an object's emitters of one material when there are at most kMaxEmitterGroup of
  // them (a quad, a small polygon: sampled as one), else one group per triangle (a big mesh
  // light would cost a solid angle per triangle of the group on every sample). An object's
  // emitters are consecutive in emitters_.
  groups_.clear();
  stats_.rect_emitters = 0;
  emitter_group_.assign(emitters_.size(), 0);
  for (size_t e = 0; e < emitters_.size();) {
    size_t end = e + 1;
    while (end < emitters_.size() && emitters_[end].instance == emitters_[e].instance) ++end;
    bool one = emitter_groups_ && end - e <= kMaxEmitterGroup && end - e > 1;
    for (size_t k = e + 1; k < end && one; ++k) one = emitter_materials[k] == emitter_materials[e];
    for (size_t k = e; k < end; k += one ? end - e : 1) {
      EmitterGroup g;
      g.first = uint32_t(k);
      g.count = one ? uint32_t(end - e) : 1u;
      float w = 0.0f;
      for (size_t j = k; j < k + g.count; ++j) {
        g.area += emitter_areas_[j];
        w += emitter_weights[j];
        emitter_group_[j] = uint32_t(groups_.size());
      }
      if (g.count > 1) {
        const Blas& b = blases_[inst_[emitters_[k].instance].blas];
        for (uint32_t t = 0; t < g.count; ++t) {
          const TriangleVerts& tv = b.tris[emitters_[k + t].tri];
          const Vec3 v[3] = {tv.v0, tv.v1, tv.v2};
          for (int c = 0; c < 3; ++c) {
            uint8_t j = 0;
            while (j < g.corners && !(g.corner[j].x == v[c].x && g.corner[j].y == v[c].y && g.corner[j].z == v[c].z)) ++j;
            if (j == g.corners) {
              g.corner[j] = v[c];
              ++g.corners;
            }
            g.tri_corner[t][c] = j;
          }
        }
      }
      if (g.count == 2 && rect_groups_) detect_rect(g, inst_[emitters_[k].instance]);
      stats_.rect_emitters += g.rect;
      groups_.push_back(g);
      weights.push_back(w);
    }
    e = end;
  }
  env_index_ = SIZE_MAX;
  if (env_.valid() && env_.average_luminance() > 0.0f) {
    env_index_ = weights.size();
    weights.push_back(4.0f * kPi * kPi * radius * radius * env_.average_luminance());
  }
  light_dist_ = Distribution1D(weights);
  build_light_tree(weights);
  stats_.emissive_triangles = emitters_.size();
  stats_.lights = lights_.size();
  ++stats_.light_builds;
  detect_features();
}

void Scene::build_light_tree(const std::vector<float>& weights) {
  // Bounds of every finite entry of light_dist_ (same indices; zero power: left out), and the
  // infinite ones beside the tree.
  std::vector<LightBounds> items(weights.size());
  inf_items_.clear();
  std::vector<float> inf_weights;
  double inf_total = 0.0, total = 0.0;
  const auto finite_weight = [](float w) { return std::isfinite(w) && w > 0.0f ? w : 0.0f; };
  size_t finite = 0;
  for (size_t k = 0; k < weights.size(); ++k) {
    const float w = finite_weight(weights[k]);
    total += w;
    const bool infinite = k == env_index_ || (k < lights_.size() && lights_[k].type == LightType::Sun);
    if (infinite) {
      inf_items_.push_back(uint32_t(k));
      inf_weights.push_back(w);
      inf_total += w;
      continue;
    }
    if (!(w > 0.0f)) continue;
    LightBounds& b = items[k];
    if (k < lights_.size()) {
      const Light& l = lights_[k];
      const float lum = std::max(luminance(l.color), 0.0f);
      switch (l.type) {
        case LightType::Point:
        case LightType::Spot: {
          b.bounds.grow(l.position - Vec3(l.radius));
          b.bounds.grow(l.position + Vec3(l.radius));
          b.phi = 4.0f * kPi * lum;  // a spot's cone is in its direction bounds
          b.cos_theta_o = -1.0f;     // every direction
          b.cos_theta_e = 0.0f;
          if (l.type == LightType::Spot) {
            // The axis: the world direction that to_local takes to local -Z, where to_local is a
            // similarity (rows orthogonal, of one length); else the whole sphere stays.
            const Vec3 r0{l.to_local.m[0][0], l.to_local.m[0][1], l.to_local.m[0][2]};
            const Vec3 r1{l.to_local.m[1][0], l.to_local.m[1][1], l.to_local.m[1][2]};
            const Vec3 r2{l.to_local.m[2][0], l.to_local.m[2][1], l.to_local.m[2][2]};
            const float s0 = length_sq(r0), s1 = length_sq(r1), s2 = length_sq(r2);
            const float tol = 1e-4f * std::max(s0, std::max(s1, s2));
            const bool similar = std::fabs(s0 - s2) <= tol && std::fabs(s1 - s2) <= tol && std::fabs(dot(r0, r1)) <= tol &&
                                 std::fabs(dot(r0, r2)) <= tol && std::fabs(dot(r1, r2)) <= tol && s2 > 0.0f;
            if (similar && l.cos_half_spot > -1.0f) {
              b.w = -r2 / std::sqrt(s2);
              // Full strength inside theta_o (where the blend ends), falling to 0 at the cone's
              // edge theta_o + theta_e (widened by a hair against rounding).
              const float outer = std::acos(std::clamp(l.cos_half_spot, -1.0f, 1.0f));
              const float cos_inner =
                  l.spot_smooth_inv > 0.0f ? std::min(1.0f, l.cos_half_spot + 1.0f / l.spot_smooth_inv) : l.cos_half_spot;
              const float inner = std::acos(std::clamp(cos_inner, -1.0f, 1.0f));
              b.cos_theta_o = std::cos(inner);
              b.cos_theta_e = std::cos(std::min(outer - inner + 1e-3f, kPi));
            }
          }
          break;
        }
        case LightType::Rect:
        case LightType::Ellipse:
          for (int i = 0; i < 4; ++i)
            b.bounds.grow(l.position + l.axis_u * ((i & 1) ? 0.5f : -0.5f) + l.axis_v * ((i & 2) ? 0.5f : -0.5f));
          b.phi = kPi * l.area * lum;
          b.w = l.dir;  // one-sided
          b.cos_theta_o = 1.0f;
          b.cos_theta_e = 0.0f;
          break;
        case LightType::Sun:
          break;
      }
    } else {
      // An emitter group: its world-space triangles, two-sided, normals in one cone.
      const EmitterGroup& g = groups_[k - lights_.size()];
      b.phi = w;
      b.two_sided = true;
      b.cos_theta_e = 0.0f;
      bool any = false;
      for (uint32_t j = g.first; j < g.first + g.count; ++j) {
        const Emitter& em = emitters_[j];
        const InstanceData& in = inst_[em.instance];
        const TriangleVerts tv = world_triangle(in, blases_[in.blas].tris[em.tri]);
        b.bounds.grow(tv.v0);
        b.bounds.grow(tv.v1);
        b.bounds.grow(tv.v2);
        const Vec3 n = cross(tv.v1 - tv.v0, tv.v2 - tv.v0);
        if (!(length_sq(n) > 0.0f) || !is_finite(n)) continue;
        LightBounds t;
        t.w = normalize(n);
        t.phi = 1.0f;
        t.cos_theta_o = 1.0f;
        if (!any) {
          b.w = t.w;
          b.cos_theta_o = 1.0f;
          any = true;
        } else {
          LightBounds c = b;
          c.phi = 1.0f;
          c = light_bounds_union(c, t);
          b.w = c.w;
          b.cos_theta_o = c.cos_theta_o;
        }
      }
      if (!any) b.cos_theta_o = -1.0f;
      b.phi = b.bounds.empty() ? 0.0f : w;
    }
    finite += b.phi > 0.0f;
  }
  const bool want = light_tree_mode_ == LightTreeMode::On ||
                    (light_tree_mode_ == LightTreeMode::Auto && finite > kLightTreeMinLights);
  tree_ = want && finite > 0 ? LightTree(items) : LightTree();
  use_tree_ = !tree_.empty();
  stats_.light_tree_nodes = tree_.node_count();
  stats_.light_tree_depth = size_t(tree_.depth());
  // The infinite lights keep the share of the power the single distribution gives them.
  inf_share_ = !use_tree_ ? 0.0f : inf_items_.empty() ? 0.0f : float(inf_total / total);
  if (use_tree_ && !(inf_share_ < 1.0f)) use_tree_ = false;  // nothing finite has power
  tree_share_ = 1.0f - inf_share_;
  inf_dist_ = Distribution1D(inf_weights);
  inf_pmf_.assign(weights.size(), 0.0f);
  for (size_t j = 0; j < inf_items_.size(); ++j) inf_pmf_[inf_items_[j]] = inf_share_ * inf_dist_.pmf(j);
  if (!(inf_share_ > 0.0f) || inf_dist_.empty()) inf_share_ = 0.0f, tree_share_ = 1.0f;
}

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
          {"mesh lights", f.emission},
          {"point lights", light(LightType::Point)},
          {"spot lights", light(LightType::Spot)},
          {"sun lights", light(LightType::Sun)},
          {"area lights", light(LightType::Rect) || light(LightType::Ellipse)},
          {"environment", f.environment},
          {"world light", f.world_light},
          {"light tree", f.light_tree},
          {"subsurface", f.subsurface}};
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
    for (const CurveSetData& cs : curve_sets_) used[cs.material < materials_.size() ? cs.material : 0] = 1;
  for (size_t id = 0; id < materials_.size(); ++id) {
    if (!used[id]) continue;
    const Material& m = materials_[id];
    f.media = f.media || m.program.has_medium();
    f.volumes = f.volumes || (m.program.has_medium() && (!is_black(m.program.sigma_s) ||
                                                         !is_black(m.program.volume_emission) || m.transparent));
    if (m.constant) {  // the closures it does add
      for (int i = 0; i < m.cached.n; ++i) {
        const Bsdf& b = m.cached.c[size_t(i)].bsdf;
        if (std::holds_alternative<DiffuseBsdf>(b)) f.diffuse = true;
        else if (std::holds_alternative<TranslucentBsdf>(b)) f.diffuse = f.transmission = true;
        else if (std::holds_alternative<ConductorBsdf>(b)) f.glossy = true;
        else if (std::holds_alternative<TransparentBsdf>(b)) f.transparent = true;
        else if (std::holds_alternative<HairChiangBsdf>(b)) f.glossy = f.transmission = true;
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
      f.textures = f.textures || op.code == OpCode::ImageTex;
      f.normal_maps = f.normal_maps || op.code == OpCode::NormalMap || op.code == OpCode::Bump;
      if (m.constant) continue;
      switch (op.code) {  // every kind the op can add
        case OpCode::Diffuse: f.diffuse = true; f.glossy = f.glossy || op.in[3] != kNoReg; break;  // in[3]: Oren-Nayar
        case OpCode::Sheen: case OpCode::Toon: f.diffuse = f.glossy = true; break;
        case OpCode::Translucent: f.diffuse = f.transmission = true; break;
        case OpCode::Glossy: case OpCode::Metallic: f.glossy = true; break;
        case OpCode::Glass: case OpCode::Refraction: f.glossy = f.transmission = true; break;
        case OpCode::Transparent: f.transparent = true; break;
        case OpCode::Principled: f.diffuse = f.glossy = f.transmission = true; break;
        case OpCode::PrincipledHair: f.glossy = f.transmission = true; break;
        default: break;
      }
    }
  }
  f.emission = !emitters_.empty();
  f.environment = env_.valid();
  if (world_volume_.has_medium()) f.media = f.volumes = true;
  f.world_light = !env_.valid() && !is_black(world_color_);
  for (const Light& l : lights_) f.light_kinds |= 1u << uint32_t(l.type);
  f.light_tree = use_tree_;
  features_ = f;
}

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

void Scene::build_curves() {
  std::vector<CurvePiece> pieces;
  curve_first_.clear();
  curve_length_.clear();
  curve_random_.clear();
  curve_coords_.clear();
  std::vector<uint32_t> kept;
  uint32_t strands = 0;
  size_t skipped = 0;
  for (const CurveSetData& cs : curve_sets_) {
    curve_first_.push_back(strands);
    CurveInput in;
    in.points = cs.points.data();
    in.radii = cs.radii.empty() ? nullptr : cs.radii.data();
    in.n_points = cs.points.size();
    in.offsets = cs.offsets.data();
    in.n_curves = cs.offsets.empty() ? 0 : cs.offsets.size() - 1;
    in.type = cs.type;
    in.subdivisions = cs.subdivisions;
    Vec3 loc, size;
    auto_texspace(cs.points, loc, size);
    curve_coords_.push_back(make_object_coords(cs.matrix, loc, size));
    curve_coords_.back().info = cs.info;
    kept.clear();
    const CurveCutStats st = cut_curves(in, cs.matrix, strands, pieces, &kept);
    for (uint32_t c : kept) {
      double len = 0.0;  // object space, as Cycles' Length
      for (int32_t k = cs.offsets[c] + 1; k < cs.offsets[c + 1]; ++k) len += length(cs.points[size_t(k)] - cs.points[size_t(k) - 1]);
      curve_length_.push_back(float(len));
      curve_random_.push_back(float(lookup3::hash(c, 0u)) * (1.0f / float(0xFFFFFFFFu)));  // Cycles' hash_uint2_to_float(i, 0)
    }
    strands += uint32_t(st.curves);
    skipped += st.skipped;
  }
  stats_.curves = strands;
  stats_.skipped_curves = skipped;
  stats_.curve_pieces = pieces.size();
  curve_bvh_.build(std::move(pieces));
  curves_on_ = !curve_bvh_.empty();
  curves_dirty_ = false;
}

void Scene::curve_point(const Hit& h, SurfacePoint& sp) const {
  const CurvePiece& c = curve_bvh_.piece(h.prim);
  // The hit from the ray is only good to its t's error; the point on the surface is better.
  Vec3 n, tangent, p, err;
  float u;
  piece_surface(c, h.b1, h.b2, n, tangent, p, err, u);
  sp.p = p;
  sp.p_error = err;
  sp.ng = sp.ns = n;
  sp.tangent = tangent;
  const uint32_t set = curve_set_of(c.curve);
  sp.material = curve_sets_[set].material < materials_.size() ? curve_sets_[set].material : 0;
  sp.prim = uint32_t(stats_.triangles) + c.curve;
  sp.instance = kCurveInstance;
  sp.tri = h.prim;
}

void Scene::build_local_bvhs(int threads) {
  if (local_built_for_ != stats_.geometry_builds) {
    local_index_.assign(inst_.size(), UINT32_MAX);
    local_bvhs_.clear();
    local_built_for_ = stats_.geometry_builds;
  }
  if (blases_.empty() || !blases_[0].merged) return;
  const Blas& b = blases_[0];
  for (size_t i = 0; i < inst_.size(); ++i) {
    const InstanceData& in = inst_[i];
    if (in.transformed || in.blas != 0 || in.kept == 0 || local_index_[i] != UINT32_MAX) continue;
    const MeshData& mesh = meshes_[in.mesh];
    bool needed = false;
    for (uint32_t t = in.tri_base; t < in.tri_base + in.kept && !needed; ++t)
      needed = materials_[material_of(mesh, b.src_tri[t], materials_.size())].subsurface;
    if (!needed) continue;
    TriangleSpan span;
    span.p = b.tris.data() + in.tri_base;
    span.n = in.kept;
    BvhBuildOptions opt;
    opt.threads = threads;
    opt.layout = built_layout_;
    Bvh bvh;
    bvh.build(span, opt);
    local_index_[i] = uint32_t(local_bvhs_.size());
    local_bvhs_.push_back(std::move(bvh));
  }
}

bool Scene::intersect_local(uint32_t instance, const Ray& r, Hit& h) const {
  if (instance >= inst_.size()) return false;
  const InstanceData& in = inst_[instance];
  if (in.blas == UINT32_MAX) return false;
  if (in.transformed) {  // its own object-space BLAS, the ray carried there (world distances)
    float dt;
    const Ray o = ray_to_object(in.to_object, r, dt);
    if (!blases_[in.blas].bvh.intersect(o, h)) return false;
    h.t += dt;
  } else {
    if (instance >= local_index_.size() || local_index_[instance] == UINT32_MAX) return false;
    if (!local_bvhs_[local_index_[instance]].intersect(r, h)) return false;
    h.prim += in.tri_base;
  }
  h.inst = instance;
  return true;
}

[[gnu::always_inline]] inline void Scene::surface_point_in(const InstanceData& in, const TriangleVerts& tv, const Hit& h,
                                                           SurfacePoint& sp) const {
  const Blas& b = blases_[in.blas];
  const uint32_t st = b.src_tri[h.prim];
  const MeshData& mesh = meshes_[in.mesh];
  const float b0 = 1.0f - h.b1 - h.b2;
  triangle_point(in, tv, h.b1, h.b2, sp.p, sp.p_error);
  if (!in.transformed) {
    sp.ng = tv.unit_normal();
  } else {
    // Cofactors map the object-space edge cross product to the world one (winding included).
    const Vec3 c = cross(tv.v1 - tv.v0, tv.v2 - tv.v0);
    sp.ng = normalize(in.nrow[0] * c.x + in.nrow[1] * c.y + in.nrow[2] * c.z);
  }
  sp.ns = sp.ng;
  if (!mesh.normals.empty()) {
    const std::array<uint32_t, 3>& ni = mesh.normal_indices.empty() ? mesh.triangles[st] : mesh.normal_indices[st];
    Vec3 n[3];
    bool ok = true;
    for (int k = 0; k < 3 && ok; ++k) {
      n[k] = in.normal(mesh.normals[ni[k]]);
      const float l2 = length_sq(n[k]);
      ok = std::isfinite(l2) && l2 > 0.0f;
      n[k] = n[k] / std::sqrt(l2);
    }
    if (ok) {  // bad normals: shade flat
      const Vec3 ni = n[0] * b0 + n[1] * h.b1 + n[2] * h.b2;
      const float l2 = length_sq(ni);
      if (l2 > 1e-12f) sp.ns = ni / std::sqrt(l2);
    }
  }
  sp.material = material_of(mesh, st, materials_.size());
  sp.prim = global_prim(h);
  sp.instance = h.inst;
  sp.tri = h.prim;
}

void Scene::surface_point(const Hit& h, SurfacePoint& sp, float time) const {
  sp.time = time;
  if (h.inst == kCurveInstance) return curve_point(h, sp);  // (curves do not move)
  const InstanceData& in = inst_[h.inst];
  if (__builtin_expect(in.motion != nullptr || in.deform != nullptr, 0)) {  // where the ray met it
    InstanceData moved = in;
    if (in.motion) set_instance_matrix(moved, motion_transform_at(in.motion, in.motion_steps, time));
    const TriangleVerts tv = in.deform ? in.deform->triangle_at(h.prim, time) : blases_[in.blas].tris[h.prim];
    surface_point_in(moved, tv, h, sp);
    if (in.deform && (sp.ns.x != sp.ng.x || sp.ns.y != sp.ng.y || sp.ns.z != sp.ng.z)) {
      // The frame's shading normals turned with their triangle: the rotation that takes the
      // frame's geometric normal to this time's (Rodrigues, w = a x b, c = a . b).
      const TriangleVerts& still = blases_[in.blas].tris[h.prim];
      const Vec3 e = cross(still.v1 - still.v0, still.v2 - still.v0);  // as surface_point_in's ng
      const Vec3 a = normalize(moved.nrow[0] * e.x + moved.nrow[1] * e.y + moved.nrow[2] * e.z);
      const Vec3 b = sp.ng, w = cross(a, b);
      const float c = dot(a, b);
      if (c > -0.99f && is_finite(a)) {
        const Vec3 v = sp.ns, wv = cross(w, v);
        const Vec3 r = v + wv + cross(w, wv) * (1.0f / (1.0f + c));
        const float l2 = length_sq(r);
        if (l2 > 0.0f && std::isfinite(l2)) sp.ns = r / std::sqrt(l2);
      }
    }
    return;
  }
  surface_point_in(in, blases_[in.blas].tris[h.prim], h, sp);
}

// Inlined into sample_direct: as a call it cost a fifth of a light sample in argument passing.
[[gnu::always_inline]] inline bool Scene::group_solid_angles(const EmitterGroup& g, Vec3 p, double (*dirs)[3], double* omega, double& total) const {
  const InstanceData& in = inst_[emitters_[g.first].instance];
  uint32_t bad = 0;  // corners without a direction (p on them)
  for (uint32_t c = 0; c < g.corners; ++c) {
    Vec3 v = g.corner[c];
    if (in.transformed) v = in.to_world.point(v);  // as world_triangle
    DVec3 d = DVec3(v) - DVec3(p);
    if (!dnormalize(d)) bad |= 1u << c;
    dirs[c][0] = d.x;
    dirs[c][1] = d.y;
    dirs[c][2] = d.z;
  }
  total = 0.0;
  bool all = solid_angle_triangles_;
  for (uint32_t i = 0; i < g.count; ++i) {
    const uint8_t* tc = g.tri_corner[i];
    omega[i] = 0.0;  // as spherical_triangle gives for a corner at p
    if (!(bad >> tc[0] & 1u) && !(bad >> tc[1] & 1u) && !(bad >> tc[2] & 1u)) {
      const double *a = dirs[tc[0]], *b = dirs[tc[1]], *c = dirs[tc[2]];
      omega[i] = spherical_triangle_solid_angle({a[0], a[1], a[2]}, {b[0], b[1], b[2]}, {c[0], c[1], c[2]});
    }
    total += omega[i];
    // Only where every triangle would be sampled by solid angle on its own: elsewhere the
    // group falls back to what its triangles alone would do.
    all = all && use_spherical_sampling(omega[i]);
  }
  return all;
}

[[gnu::always_inline]] inline bool Scene::emitter_point_sample(size_t e, Vec3 p, float b1, float b2, Vec3 n, bool spherical,
                                                               float pdf_solid, float pmf_e, DirectSample& s) const {
  const Emitter& em = emitters_[e];
  const InstanceData& in = inst_[em.instance];
  // The light point as a hit on it: position and error bound exactly as a ray would find it
  // (through the instance's transform where it has one); normals only for a shaded emission.
  const Blas& blas = blases_[in.blas];
  const uint32_t lmat = material_of(meshes_[in.mesh], blas.src_tri[em.tri], materials_.size());
  const bool shaded = !materials_[lmat].constant;
  SurfacePoint lp;
  if (shaded) {
    Hit h;
    h.prim = em.tri;
    h.inst = em.instance;
    h.b1 = b1;
    h.b2 = b2;
    surface_point(h, lp);
  } else {
    triangle_point(in, blas.tris[em.tri], b1, b2, lp.p, lp.p_error);
  }
  const Vec3 q = lp.p;
  const Vec3 d = q - p;
  const float dist2 = length_sq(d);
  const float dist = std::sqrt(dist2);
  if (!(dist > 0.0f)) return false;
  s.wi = d / dist;
  const float cos_l = std::fabs(dot(n, s.wi));
  if (!(cos_l > 0.0f)) return false;
  s.dist = dist;
  s.target = q;
  s.target_normal = dot(n, s.wi) < 0.0f ? n : -n;  // the side facing p
  s.target_error = lp.p_error;
  if (!shaded) {
    s.li = materials_[lmat].cached.emission;  // what shade() returns for it, without building closures
  } else {
    // The material's emission at the sampled point (textured emission included).
    ClosureList cl;
    // As Cycles evaluates a light sample's shader: no ray kind set, the path's bounce counts.
    RayState emission = s.path ? *s.path : RayState{};
    emission.flags = 0;
    emission.emission_only = true;
    emission.length = dist;
    shade(lp, b1, b2, -s.wi, cl, emission);
    s.li = cl.emission;
  }
  s.pdf = spherical ? pdf_solid : pmf_e / emitter_areas_[e] * dist2 / cos_l;
  return std::isfinite(s.pdf) && s.pdf > 0.0f;
}

[[gnu::always_inline]] inline bool Scene::sample_emitter(size_t e, Vec3 p, const SphericalTriangle& st, bool spherical,
                                                         float pdf_solid, float pmf_e, Vec2 u, DirectSample& s) const {
  const Emitter& em = emitters_[e];
  const InstanceData& in = inst_[em.instance];
  const TriangleVerts tv = world_triangle(in, blases_[in.blas].tris[em.tri]);
  const Vec3 n = tv.unit_normal();
  float b1, b2;
  DVec3 w;
  if (spherical && sample_spherical_triangle(st, u, w)) {
    // The point where the sampled direction meets the triangle, as barycentrics (clamped into
    // the triangle against rounding: the direction's density stays 1 / omega either way).
    const DVec3 d0(tv.v0), e1 = DVec3(tv.v1) - d0, e2 = DVec3(tv.v2) - d0, nd = dcross(e1, e2);
    const double nn = ddot(nd, nd), wn = ddot(w, nd);
    if (!(std::fabs(wn) > 0.0)) return false;
    const DVec3 r = DVec3(p) + w * (ddot(d0 - DVec3(p), nd) / wn) - d0;
    double db1 = std::max(0.0, ddot(dcross(r, e2), nd) / nn), db2 = std::max(0.0, ddot(dcross(e1, r), nd) / nn);
    const double sum = db1 + db2;
    if (sum > 1.0) {
      db1 /= sum;
      db2 /= sum;
    }
    b1 = float(db1);
    b2 = float(db2);
  } else if (spherical) {
    return false;  // degenerate as seen from p: it subtends no solid angle
  } else {
    sample_triangle_uniform(u, b1, b2);
  }
  return emitter_point_sample(e, p, b1, b2, n, spherical, pdf_solid, pmf_e, s);
}

template <bool kTree>
bool Scene::sample_direct_t(Vec3 p, float u_select, Vec2 u, DirectSample& s, bool bsdf_follows) const {
  if (light_dist_.empty()) return false;
  size_t k;
  float pmf;
  if (!choose_light_t<kTree>(p, s.n, u_select, k, pmf) || !(pmf > 0.0f)) return false;
  s.target_normal = Vec3(0.0f);
  if (k < lights_.size()) {
    const Light& l = lights_[k];
    LightSample ls;
    if (!sample_light(l, p, u, ls, solid_angle_rects_)) return false;
    s.wi = ls.wi;
    s.dist = ls.dist;
    s.target = ls.target;
    s.li = ls.li;
    s.pdf = ls.pdf * pmf;
    // BSDF rays never hit analytic lights (they are not geometry), so the light sample is the
    // only estimator and keeps the full weight: MIS against the BSDF pdf lost energy here.
    s.delta = true;
    s.cast_shadow = l.cast_shadow;
    return true;
  }
  s.delta = false;
  s.cast_shadow = true;
  if (k == env_index_) {
    float pdf;
    if (!env_.sample(u, s.wi, s.li, pdf, !bsdf_follows)) return false;
    s.dist = kInf;
    s.pdf = pdf * pmf;
    return true;
  }
  const EmitterGroup& g = groups_[k - lights_.size()];
  size_t e = g.first;
  if (g.rect && solid_angle_triangles_) {
    // Uniform in the rectangle's solid angle above the triangles' lower limit (its warp stays
    // well conditioned up to a whole hemisphere: tests/test_emitter_groups.py), else by area.
    const SphericalRectLocal sr = group_rect(g, p);
    if (use_spherical_rect(sr.solid_angle)) {
      // One spherical rectangle over both triangles: the point's rectangle coordinates (s, t)
      // give the triangle (s + t <= 1: triangle 0, which has the origin corner) and its
      // barycentrics (the rectangle's corners' weights at (s, t)).
      double xu, yv;
      if (!sample_spherical_rect_local(sr, u, xu, yv)) return false;
      const double rs = std::clamp((xu - sr.x0) * g.rect_inv_lx, 0.0, 1.0), rt = std::clamp((yv - sr.y0) * g.rect_inv_ly, 0.0, 1.0);
      const int i = rs + rt <= 1.0 ? 0 : 1;
      const double w[4] = {std::max(0.0, 1.0 - rs - rt), i == 0 ? rs : 1.0 - rt, i == 0 ? rt : 1.0 - rs, std::max(0.0, rs + rt - 1.0)};
      e += size_t(i);
      return emitter_point_sample(e, p, float(w[g.rect_corner[i][1]]), float(w[g.rect_corner[i][2]]), g.rect_tri_n[i], true,
                                  float(pmf / sr.solid_angle), pmf, s);
    }
    // A speck from p (or p in its plane): by area, as the triangles would be (each subtends
    // less), without their solid angles.
    const auto area = [&](uint32_t i) { return double(emitter_areas_[g.first + i]); };
    uint32_t i;
    if (!pick_weighted(g.count, area, double(u.x) * double(g.area), i, u.x)) return false;
    e += i;
    return sample_emitter(e, p, SphericalTriangle(), false, 0.0f, area_pmf(pmf, emitter_areas_[e], g.area), u, s);
  }
  SphericalTriangle st;
  bool spherical;
  float pdf_solid, pmf_e = pmf;
  if (g.count == 1) {
    const Emitter& em = emitters_[e];
    const InstanceData& in = inst_[em.instance];
    const TriangleVerts tv = world_triangle(in, blases_[in.blas].tris[em.tri]);
    st = spherical_triangle(p, tv.v0, tv.v1, tv.v2);
    spherical = solid_angle_triangles_ && use_spherical_sampling(st.solid_angle);
    pdf_solid = float(pmf / st.solid_angle);
  } else {
    // A group: one triangle chosen by u.x, in proportion to its solid angle (by area where the
    // group is not sampled by solid angle from p), and u.x rescaled into its share, so that the
    // sample stays stratified over the whole group.
    double dirs[3 * kMaxEmitterGroup][3], omega[kMaxEmitterGroup], total;
    const bool whole = group_solid_angles(g, p, dirs, omega, total);
    const auto weight = [&](uint32_t i) { return whole ? omega[i] : double(emitter_areas_[g.first + i]); };
    uint32_t i;
    if (!pick_weighted(g.count, weight, double(u.x) * (whole ? total : double(g.area)), i, u.x)) return false;
    e += i;
    const auto dir = [&](int c) {
      const double* d = dirs[g.tri_corner[i][c]];
      return DVec3(d[0], d[1], d[2]);
    };
    st.a = dir(0);
    st.b = dir(1);
    st.c = dir(2);
    st.solid_angle = omega[i];
    if (whole) {
      spherical = true;
      pdf_solid = float(pmf / total);
    } else {
      spherical = solid_angle_triangles_ && use_spherical_sampling(omega[i]);
      pmf_e = area_pmf(pmf, emitter_areas_[e], g.area);
      pdf_solid = float(pmf_e / omega[i]);
    }
  }
  return sample_emitter(e, p, st, spherical, pdf_solid, pmf_e, u, s);
}

template bool Scene::sample_direct_t<false>(Vec3, float, Vec2, DirectSample&, bool) const;
template bool Scene::sample_direct_t<true>(Vec3, float, Vec2, DirectSample&, bool) const;

void Scene::shade(const SurfacePoint& sp, float b1, float b2, Vec3 wo, ClosureList& out, const RayState& ray) const {
  const Material& mat = materials_[sp.material];
  if (mat.constant) {
    out.n = mat.cached.n;
    out.emission = mat.cached.emission;
    out.holdout = mat.cached.holdout;
    out.has_nondelta = mat.cached.has_nondelta;
    const Frame f = Frame::from_normal(sp.ns);
    for (int i = 0; i < out.n; ++i) {
      Closure& c = out.c[size_t(i)];
      c = mat.cached.c[size_t(i)];
      // Glossy lobes: the normal lifted as eval_shader does (Cycles' valid specular reflection).
      c.frame = bsdf_wants_valid_reflection(c.bsdf) ? Frame::from_normal(valid_specular_normal(sp.ng, wo, sp.ns)) : f;
    }
    if (mat.has_hair) orient_hair(out, sp, wo);
    return;
  }
  ShadingContext ctx;
  ctx.p = sp.p;
  ctx.ng = sp.ng;
  ctx.ns = sp.ns;
  ctx.wo = wo;
  ctx.ray = ray;
  ctx.b1 = b1;
  ctx.b2 = b2;
  ctx.scene = this;  // the Ambient Occlusion node traces
  ctx.instance = sp.instance;
  ctx.p_error = sp.p_error;
  ctx.time = sp.time;
  if (sp.curve()) {  // no triangle, uvs or attributes; world coordinates for Object
    const CurvePiece& pc = curve_bvh_.piece(sp.tri);
    const float u = clampf(b1, 0.0f, 1.0f);  // the axial position (end spheres: beyond [0, 1])
    CurveShading cs;
    cs.intercept = pc.v0 + (pc.v1 - pc.v0) * u;
    cs.length = curve_length_[pc.curve];
    cs.thickness = 2.0f * (pc.r0 + (pc.r1 - pc.r0) * u);
    cs.random = curve_random_[pc.curve];
    const Vec3 across = wo - sp.tangent * dot(sp.tangent, wo);
    cs.tangent_normal = length_sq(across) > 0.0f ? normalize(across) : Vec3(0.0f);
    ctx.curve = &cs;
    ctx.object = &curve_coords_[curve_set_of(pc.curve)];
    eval_shader(mat.program, images_, ctx, out);
    if (mat.has_hair) orient_hair(out, sp, wo);
    return;
  }
  const InstanceData& in = inst_[sp.instance];
  const Blas& blas = blases_[in.blas];
  TriangleVerts tv;
  ctx.object = &object_coords_[sp.instance];
  ObjectCoords moved_coords;
  if (__builtin_expect(in.motion != nullptr || in.deform != nullptr, 0)) {
    // Motion blur: the triangle, and the object's transforms for texture coordinates, at the
    // ray's time (so textures stay on a moving object).
    InstanceData moved = in;
    if (in.motion) {
      set_instance_matrix(moved, motion_transform_at(in.motion, in.motion_steps, sp.time));
      moved_coords = object_coords_[sp.instance];
      const ObjectCoords at = make_object_coords(moved.to_world, Vec3(0.0f), Vec3(1.0f));
      moved_coords.to_world = at.to_world;
      moved_coords.to_object = at.to_object;
      moved_coords.valid = at.valid;
      ctx.object = &moved_coords;
    }
    tv = world_triangle(moved, in.deform ? in.deform->triangle_at(sp.tri, sp.time) : blas.tris[sp.tri]);
  } else {
    tv = world_triangle(in, blas.tris[sp.tri]);
  }
  const Vec3 corners[3] = {tv.v0, tv.v1, tv.v2};
  ctx.tri = corners;  // for the Bump node's offsets
  constexpr int kMaxSets = 8;
  Vec2 uv[kMaxSets];
  Vec2 corner_uvs[3 * kMaxSets];
  Vec3 tangents[kMaxSets];
  float signs[kMaxSets];
  const int sets = static_cast<int>(std::min<size_t>(uv_sets_, kMaxSets));
  if (mat.program.uses_uv && sets > 0) {
    const float b0 = 1.0f - b1 - b2;
    const MeshData& mesh = meshes_[in.mesh];
    const size_t st = blas.src_tri[sp.tri];
    for (int k = 0; k < sets; ++k) {
      if (size_t(k) >= mesh.uvs.size() || mesh.uvs[size_t(k)].empty()) {  // missing: zeros
        uv[k] = {};
        corner_uvs[3 * k] = corner_uvs[3 * k + 1] = corner_uvs[3 * k + 2] = {};
        tangents[k] = Vec3(0.0f);
        signs[k] = 1.0f;
        continue;
      }
      const std::vector<Vec2>& t = mesh.uvs[size_t(k)];
      const Vec2 a = t[3 * st], b = t[3 * st + 1], c = t[3 * st + 2];
      uv[k] = {a.x * b0 + b.x * b1 + c.x * b2, a.y * b0 + b.y * b1 + c.y * b2};
      corner_uvs[3 * k] = a;
      corner_uvs[3 * k + 1] = b;
      corner_uvs[3 * k + 2] = c;
      // Per-triangle tangent from the uv parameterisation (dP/du), sign from the uv winding.
      const Vec3 e1 = tv.v1 - tv.v0, e2 = tv.v2 - tv.v0;
      const float du1 = b.x - a.x, dv1 = b.y - a.y, du2 = c.x - a.x, dv2 = c.y - a.y;
      const float det = du1 * dv2 - du2 * dv1;
      if (std::fabs(det) > 1e-20f) {
        const float inv = 1.0f / det;
        const Vec3 T = (e1 * dv2 - e2 * dv1) * inv;
        const Vec3 B = (e2 * du1 - e1 * du2) * inv;
        tangents[k] = T;
        signs[k] = dot(cross(sp.ns, T), B) < 0.0f ? -1.0f : 1.0f;
      } else {
        tangents[k] = Vec3(0.0f);
        signs[k] = 1.0f;
      }
    }
    ctx.uv = uv;
    ctx.uv_sets = sets;
    ctx.tangents = tangents;
    ctx.tangent_signs = signs;
    ctx.tri_uv = corner_uvs;
  }
  Float4 attrs[kMaxSets];
  if (mat.program.uses_attributes) {
    const MeshData& mesh = meshes_[in.mesh];
    const int n = static_cast<int>(std::min<size_t>(mesh.attributes.size(), kMaxSets));
    const float b0 = 1.0f - b1 - b2;
    const size_t st = blas.src_tri[sp.tri];
    for (int k = 0; k < n; ++k) {
      const std::vector<Float4>& t = mesh.attributes[size_t(k)];
      if (t.empty()) {
        attrs[k] = {};
        continue;
      }
      const Float4 &a = t[3 * st], &b = t[3 * st + 1], &c = t[3 * st + 2];
      attrs[k] = {a.x * b0 + b.x * b1 + c.x * b2, a.y * b0 + b.y * b1 + c.y * b2, a.z * b0 + b.z * b1 + c.z * b2,
                  a.w * b0 + b.w * b1 + c.w * b2};
    }
    ctx.attrs = attrs;
    ctx.attr_sets = n;
  }
  eval_shader(mat.program, images_, ctx, out);
  if (mat.has_hair) orient_hair(out, sp, wo);
}

void orient_hair(ClosureList& out, const SurfacePoint& sp, Vec3 wo) {
  // Cycles' bsdf_hair_chiang_setup: x along the fibre, y = x cross the view, z = x cross y;
  // h the sine of the angle between the normal and z seen along x. On a mesh (no tangent) an
  // arbitrary tangent of the shading normal stands in for the fibre.
  Vec3 x = sp.tangent;
  if (!(length_sq(x) > 0.0f)) {
    Vec3 b;
    make_basis(sp.ns, x, b);
  }
  Vec3 y = cross(x, wo);
  const float l = length(y);
  if (l > 1e-7f) {
    y = y / l;
  } else {  // looking along the fibre: any y across it
    Vec3 b;
    make_basis(x, y, b);
  }
  const Vec3 z = cross(x, y);
  const float h = clampf(dot(cross(sp.ng, x), z), -1.0f, 1.0f);
  for (int i = 0; i < out.n; ++i) {
    Closure& c = out.c[size_t(i)];
    if (auto* hb = std::get_if<HairChiangBsdf>(&c.bsdf)) {
      hb->h = h;
      c.frame.t = x;
      c.frame.b = y;
      c.frame.n = z;
    }
  }
}

Vec3 Scene::transmittance_through(Ray ray) const {
  Vec3 T(1.0f);
  for (int i = 0; i < 64; ++i) {  // bounded: stacked alpha cards
    Hit h;
    if (!intersect(ray, h)) return T;
    SurfacePoint sp;
    surface_point(h, sp, ray.time);
    const Material& mat = materials_[sp.material];
    if (!mat.transparent) return Vec3(0.0f);
    ClosureList cl;
    RayState shadow;
    shadow.flags = kRayShadow;
    shadow.length = h.t * length(ray.dir);
    shade(sp, h.b1, h.b2, -normalize(ray.dir), cl, shadow);
    Vec3 pass(0.0f);
    for (int c = 0; c < cl.n; ++c)
      if (std::holds_alternative<TransparentBsdf>(cl.c[size_t(c)].bsdf)) pass += cl.c[size_t(c)].weight;
    T = T * vmin(pass, Vec3(1.0f));
    if (!(max_component(T) > 0.0f)) return Vec3(0.0f);
    // Continue just past the surface towards the same end point (or to infinity).
    const Vec3 side = dot(ray.dir, sp.ng) > 0.0f ? sp.ng : -sp.ng;
    const Vec3 org = offset_ray_origin(sp.p, sp.p_error, side);
    if (std::isfinite(ray.tmax)) {
      const Vec3 end = ray.org + ray.dir * ray.tmax;
      ray.dir = end - org;
      ray.tmax = 1.0f;
    }
    ray.org = org;
  }
  return Vec3(0.0f);
}

float Scene::pdf_emitter(const SurfacePoint& sp, Vec3 from, Vec3 at, float cos_l, Vec3 from_n) const {
  if (sp.curve()) return 0.0f;  // curves are not light-sampled: their emission is found by BSDF rays alone
  const InstanceData& in = inst_[sp.instance];
  const int32_t e = emitter_of(in, sp.tri);
  if (e < 0 || !(cos_l > 0.0f)) return 0.0f;
  const uint32_t gi = emitter_group_[size_t(e)];
  const EmitterGroup& g = groups_[gi];
  const float pmf = light_pmf(from, from_n, lights_.size() + gi);
  if (!(pmf > 0.0f)) return 0.0f;
  // The same choices sample_direct makes from this point.
  if (g.rect && solid_angle_triangles_) {
    const double omega = group_rect(g, from).solid_angle;
    if (use_spherical_rect(omega)) return float(pmf / omega);
    const float pmf_e = area_pmf(pmf, emitter_areas_[size_t(e)], g.area);  // by area
    return pmf_e / emitter_areas_[size_t(e)] * length_sq(at - from) / cos_l;
  }
  double omega;
  float pmf_e = pmf;
  if (g.count == 1) {
    const TriangleVerts tv = world_triangle(in, blases_[in.blas].tris[sp.tri]);
    omega = spherical_triangle(from, tv.v0, tv.v1, tv.v2).solid_angle;
  } else {
    double dirs[3 * kMaxEmitterGroup][3], omegas[kMaxEmitterGroup], total;
    if (group_solid_angles(g, from, dirs, omegas, total)) return float(pmf / total);
    omega = omegas[size_t(e) - g.first];
    pmf_e = area_pmf(pmf, emitter_areas_[size_t(e)], g.area);
  }
  if (solid_angle_triangles_ && use_spherical_sampling(omega)) return float(pmf_e / omega);
  const float t2 = length_sq(at - from);
  return pmf_e / emitter_areas_[size_t(e)] * t2 / cos_l;
}

float Scene::pdf_environment(Vec3 dir) const {
  if (env_index_ == SIZE_MAX) return 0.0f;
  return (use_tree_ ? inf_pmf_[env_index_] : light_dist_.pmf(env_index_)) * env_.pdf(dir);
}

float trace_ambient_occlusion(const ShadingContext& ctx, Vec3 n, float distance, int samples, bool only_local) {
  // Cycles' svm_ao: cosine-distributed directions about n (a concentric disk point lifted to
  // the hemisphere), each an occlusion ray of length `distance` from the point; the fraction
  // that escapes. Random numbers from the path's, stratified over the samples.
  const Scene& scene = *ctx.scene;
  Vec3 t, b;
  make_basis(n, t, b);
  uint32_t pb[3];
  std::memcpy(pb, &ctx.p, sizeof pb);
  Pcg32 rng(hash3(ctx.ray.rng, pb[0] ^ (uint64_t(pb[1]) << 32), pb[2]), 0xA0u);
  int unoccluded = 0;
  for (int k = 0; k < samples; ++k) {
    const Vec2 u{(float(k) + rng.next_float()) / float(samples), rng.next_float()};
    const Vec2 dsk = sample_disk_concentric({std::min(u.x, 0x1.fffffep-1f), u.y});
    const float z = std::sqrt(std::max(0.0f, 1.0f - dsk.x * dsk.x - dsk.y * dsk.y));
    const Vec3 dir = t * dsk.x + b * dsk.y + n * z;
    Ray ray;
    ray.time = ctx.time;
    ray.org = offset_ray_origin(ctx.p, ctx.p_error, dot(dir, ctx.ng) >= 0.0f ? ctx.ng : -ctx.ng);
    ray.dir = dir;
    ray.tmax = distance;
    if (!only_local) {
      if (!scene.occluded(ray)) ++unoccluded;
      continue;
    }
    // Only Local: walk past the hits on other objects (bounded, like stacked alpha cards).
    bool hit_self = false;
    for (int i = 0; i < 64; ++i) {
      Hit h;
      h.t = ray.tmax;
      if (!scene.intersect(ray, h) || !h.valid()) break;
      if (h.inst == ctx.instance) {
        hit_self = true;
        break;
      }
      const Vec3 q = ray.org + ray.dir * h.t;
      ray.tmax -= h.t;
      ray.org = q + ray.dir * (1e-4f * (1.0f + max_component(vabs(q))));
      if (!(ray.tmax > 0.0f)) break;
    }
    if (!hit_self) ++unoccluded;
  }
  return float(unoccluded) / float(samples);
}

}  // namespace pl

namespace pl {

// Cycles' bevel radius distribution (a planar cubic falloff, (R - r)^3): the radius in [0, 1)
// whose CDF 10x^2 - 20x^3 + 15x^4 - 4x^5 is xi, by Newton's method.
static float bevel_cubic_radius(float xi) {
  float x = 0.25f;
  for (int i = 0; i < 10; ++i) {
    const float x2 = x * x, x3 = x2 * x, nx = 1.0f - x;
    const float f = 10.0f * x2 - 20.0f * x3 + 15.0f * x2 * x2 - 4.0f * x2 * x3 - xi;
    const float df = 20.0f * (x * nx) * (nx * nx);
    if (std::fabs(f) < 1e-6f || df == 0.0f) break;
    x = clampf(x - f / df, 0.0f, 1.0f);
  }
  return x;
}

Vec3 trace_bevel(const ShadingContext& ctx, float radius, int samples) {
  // Cycles' svm_bevel: points on a disk about the point, on one of three axes (the normal's
  // half of the time), each projected onto the instance's own surface by a ray of twice the
  // disk's height; the smooth normals found are summed with the axes' MIS weights and the
  // falloff's ratio at the real distance, and normalised. Blurry indirect rays skip it.
  if (ctx.ray.min_pdf < 8.0f) return ctx.ns;
  const Scene& scene = *ctx.scene;
  uint32_t pb[3];
  std::memcpy(pb, &ctx.p, sizeof pb);
  Pcg32 rng(hash3(ctx.ray.rng, pb[0] ^ (uint64_t(pb[1]) << 32), pb[2]), 0xBEu);
  // The disk's frame as Cycles' make_orthonormals makes it from the view-facing normal: the
  // estimate's mean does not depend on the tangents, but its normalised small-sample bias does
  // (tangents along a cube's edges instead bent the bevel 2 % more).
  const Vec3 ng = dot(ctx.ng, ctx.wo) < 0.0f ? -ctx.ng : ctx.ng;
  Vec3 t0 = (ng.x != ng.y || ng.x != ng.z) ? Vec3{ng.z - ng.y, ng.x - ng.z, ng.y - ng.x}
                                           : Vec3{ng.z - ng.y, ng.x + ng.z, -ng.y - ng.x};
  t0 = normalize(t0);
  const Vec3 b0 = cross(ng, t0);
  Vec3 sum(0.0f);
  // The samples as one randomly shifted (0,2)-sequence net (van der Corput and Sobol's second
  // dimension, XOR-shifted): stratified in every elementary interval, as Cycles' branched
  // samples are. The normalised sum's small-sample bias depends on it: with only 1D strata the
  // bevelled edges came out 2 % off Cycles'.
  const uint32_t shift_x = rng.next_u32(), shift_y = rng.next_u32();
  auto sobol2 = [](uint32_t i) {
    uint32_t r = 0;
    for (uint32_t v = 1u << 31; i; i >>= 1, v ^= v >> 1)
      if (i & 1u) r ^= v;
    return r;
  };
  auto bit_reverse = [](uint32_t v) {
    v = ((v >> 1) & 0x55555555u) | ((v & 0x55555555u) << 1);
    v = ((v >> 2) & 0x33333333u) | ((v & 0x33333333u) << 2);
    v = ((v >> 4) & 0x0F0F0F0Fu) | ((v & 0x0F0F0F0Fu) << 4);
    v = ((v >> 8) & 0x00FF00FFu) | ((v & 0x00FF00FFu) << 8);
    return (v >> 16) | (v << 16);
  };
  auto unit = [](uint32_t v) { return std::min(float(v >> 8) * 0x1p-24f, 0x1.fffffep-1f); };
  for (int k = 0; k < samples; ++k) {
    float ux = unit(bit_reverse(uint32_t(k)) ^ shift_x);
    const float uy = unit(sobol2(uint32_t(k)) ^ shift_y);
    Vec3 n = ng, t = t0, b = b0;
    float pn, pt, pb_;
    if (ux < 0.5f) {
      pn = 0.5f, pt = 0.25f, pb_ = 0.25f;
      ux *= 2.0f;
    } else if (ux < 0.75f) {
      std::swap(n, t);
      pn = 0.25f, pt = 0.5f, pb_ = 0.25f;
      ux = (ux - 0.5f) * 4.0f;
    } else {
      std::swap(n, b);
      pn = 0.25f, pt = 0.25f, pb_ = 0.5f;
      ux = (ux - 0.75f) * 4.0f;
    }
    const float phi = 2.0f * kPi * ux;
    const float disk_r = bevel_cubic_radius(uy) * radius;
    const float height = std::sqrt(std::max(0.0f, radius * radius - disk_r * disk_r));
    Ray ray;
    ray.org = ctx.p + n * height + t * (disk_r * std::cos(phi)) + b * (disk_r * std::sin(phi));
    ray.dir = -n;
    ray.tmax = 2.0f * height;
    if (!(ray.tmax > 0.0f) || !is_finite(ray.org)) continue;
    const float falloff_disk = radius - disk_r;  // the cubic falloff's ratio, as ((R - r) / (R - r_disk))^3
    // Every hit on the instance along the ray (other objects are walked past), bounded.
    for (int i = 0; i < 16; ++i) {
      Hit h;
      h.t = ray.tmax;
      if (!scene.intersect(ray, h) || !h.valid()) break;
      const Vec3 q = ray.org + ray.dir * h.t;
      if (h.inst == ctx.instance) {
        SurfacePoint sp;
        scene.surface_point(h, sp);
        const float an = pn * std::fabs(dot(n, sp.ng)), at = pt * std::fabs(dot(t, sp.ng)),
                    ab = pb_ * std::fabs(dot(b, sp.ng));
        const float mis = an / (an * an + at * at + ab * ab);
        const float r = length(sp.p - ctx.p);
        const float q3 = r < radius ? (radius - r) / falloff_disk : 0.0f;
        const float w = mis * q3 * q3 * q3;
        if (falloff_disk > 0.0f && std::isfinite(w)) sum += sp.ns * w;
      }
      const float step = h.t + 1e-4f * (1.0f + max_component(vabs(q)));
      ray.org = ray.org + ray.dir * step;
      ray.tmax -= step;
      if (!(ray.tmax > 0.0f)) break;
    }
  }
  const float l = length_sq(sum);
  return l > 0.0f && std::isfinite(l) ? sum / std::sqrt(l) : ctx.ns;
}

}  // namespace pl
