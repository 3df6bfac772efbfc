// The scene's geometry at commit: the merged and per-mesh BLASes, the instances, the top level,
// the curves and the local BVHs for subsurface.
#include "scene/scene.h"
#include "scene/scene_detail.h"

#include "util/lookup3.h"

#include <algorithm>
#include <cstring>

#include "util/big_alloc.h"
#include "util/parallel.h"

namespace pl {

using detail::material_of;

namespace {
// Transform motion of a curve or point set: 1 when its steps differ and decompose (steps set),
// 0 when it has none or they are all equal, -1 when they are singular or not finite.
int set_motion(const std::vector<Mat4>& motion, std::vector<DecomposedTransform>& steps) {
  steps.clear();
  if (motion.size() < 2) return 0;
  bool moves = false;
  for (const Mat4& m : motion) moves = moves || std::memcmp(&m, &motion[0], sizeof(Mat4)) != 0;
  if (!moves) return 0;
  if (decompose_motion(motion, steps)) return 1;
  steps.clear();
  return -1;
}

// Whether deformation steps change anything (else the set is still, as Cycles drops motion
// keys equal to the frame's): any step's point or radius unlike the frame's, or bad steps
// (which the caller rejects). Radii may be empty (the frame's, or a default).
bool deforms(const std::vector<Vec3>& points, const std::vector<float>& radii, const std::vector<std::vector<Vec3>>& steps,
             const std::vector<std::vector<float>>& step_radii) {
  for (const std::vector<Vec3>& s : steps) {
    if (s.size() != points.size() || std::memcmp(s.data(), points.data(), s.size() * sizeof(Vec3)) != 0) return true;
  }
  for (const std::vector<float>& r : step_radii) {
    if (r.size() != radii.size() || std::memcmp(r.data(), radii.data(), r.size() * sizeof(float)) != 0) return true;
  }
  return false;
}

// Vector pass points of a curve or point set (the set's points at the previous and next
// frames): used where there are two steps of its size, all finite, and they differ from it.
uint8_t pass_points_usable(const std::vector<std::vector<Vec3>>& steps, const std::vector<Vec3>& points) {
  if (steps.size() != 2) return 0;
  for (const std::vector<Vec3>& s : steps) {
    if (s.size() != points.size()) return 0;
    for (const Vec3& p : s)
      if (!is_finite(p)) return 0;
  }
  return deforms(points, {}, steps, {}) ? 1 : 0;
}

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
  instance_motion_rejected_ = 0;
  for (size_t i = 0; i < instances_.size(); ++i) {
    const std::vector<Mat4>& steps = instances_[i].motion;
    if (steps.size() < 2) continue;
    bool moves = false;
    for (const Mat4& m : steps) moves = moves || std::memcmp(&m, &steps[0], sizeof(Mat4)) != 0;
    if (!moves) continue;
    if (!decompose_motion(steps, motion_[i])) {
      motion_[i].clear();
      ++stats_.motion_rejected;
      ++instance_motion_rejected_;
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

namespace {
// Whether some triangle of the mesh has corner normals that differ (smooth shading): only those
// get Cycles' shadow terminator offset (its SHADER_SMOOTH_NORMAL faces).
bool has_smooth_triangles(const MeshData& m) {
  if (m.normals.empty()) return false;
  for (size_t t = 0; t < m.triangles.size(); ++t) {
    const std::array<uint32_t, 3>& ni = m.normal_indices.empty() ? m.triangles[t] : m.normal_indices[t];
    const Vec3 a = m.normals[ni[0]], b = m.normals[ni[1]], c = m.normals[ni[2]];
    if (a.x != b.x || a.y != b.y || a.z != b.z || a.x != c.x || a.y != c.y || a.z != c.z) return true;
  }
  return false;
}
}  // namespace

void Scene::build_instances() {
  object_coords_.clear();
  object_coords_.reserve(instances_.size());
  uint32_t prim = 0;
  size_t real = 0, moving = 0, deforming = 0;
  // Texture spaces once per mesh, not per instance (the automatic one reads every vertex).
  std::vector<std::pair<Vec3, Vec3>> texspace(meshes_.size());
  std::vector<char> have_texspace(meshes_.size(), 0);
  std::vector<char> smooth(meshes_.size(), -1);  // has_smooth_triangles, where some instance asks
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
    if (inst.info.terminator > 0.0f) {
      if (smooth[inst.mesh] < 0) smooth[inst.mesh] = has_smooth_triangles(mesh) ? 1 : 0;
      if (!smooth[inst.mesh]) object_coords_.back().info.terminator = 0.0f;  // flat: nothing to lift
    }
    if (inst.info.attr_count) object_coords_.back().attrs = object_attrs_.data() + inst.info.attr_first;
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
  // The Vector pass's maps, only where some instance or mesh moves between frames.
  pass_motion_.clear();
  bool any_pass_motion = false;
  for (const Instance& inst : instances_)
    any_pass_motion = any_pass_motion || !inst.pass_motion.empty() || !meshes_[inst.mesh].pass_positions.empty();
  if (any_pass_motion) {
    pass_motion_.resize(instances_.size());
    for (size_t i = 0; i < instances_.size(); ++i) {
      const Instance& inst = instances_[i];
      PassMotion& pm = pass_motion_[i];
      const Mat4 pre = inst.pass_motion.empty() ? inst.matrix : inst.pass_motion[0];
      const Mat4 post = inst.pass_motion.empty() ? inst.matrix : inst.pass_motion[1];
      pm.deform = !meshes_[inst.mesh].pass_positions.empty();
      if (pm.deform) {  // object space positions at those frames, to world by those frames' matrices
        pm.pre = pre;
        pm.post = post;
        pm.moves = pre.is_finite() && post.is_finite();
      } else if (!inst.pass_motion.empty() && object_coords_[i].valid) {
        pm.pre = mat_mul(pre, object_coords_[i].to_object);
        pm.post = mat_mul(post, object_coords_[i].to_object);
        pm.moves = pm.pre.is_finite() && pm.post.is_finite();
      }
    }
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
  if (points_on_) world_bounds_.grow(point_bvh_.bounds());
  stats_.tlas_instances = use_tlas_ ? tlas_.stats().instances : 0;
}

void Scene::update_memory_stats() {
  size_t bvh = tlas_.memory_bytes() + curve_bvh_.memory_bytes() + point_bvh_.memory_bytes(), geo = 0;
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
    for (const auto& a : m.tangents) geo += a.capacity() * sizeof(Float4);
  }
  stats_.bvh_bytes = bvh;
  stats_.geometry_bytes = geo;
}

void Scene::build_points() {
  std::vector<PointSphere> spheres;
  std::vector<PointFrame> frames;
  point_first_.clear();
  point_attr_.clear();
  point_coords_.clear();
  point_random_.clear();
  point_radius_scale_.clear();
  point_moving_.clear();
  point_pass_deform_.clear();
  point_pass_.clear();
  for (const PointSetData& ps : point_sets_) point_pass_deform_.push_back(pass_points_usable(ps.pass_points, ps.points));
  const bool any_pass = std::find(point_pass_deform_.begin(), point_pass_deform_.end(), 1) != point_pass_deform_.end();
  if (!any_pass) point_pass_deform_.clear();
  struct Moving {
    std::vector<PointSphere> spheres;
    std::vector<DecomposedTransform> steps;
    std::vector<PointSphere> deform;
    uint32_t n_deform;
  };
  std::vector<Moving> moving;
  point_motion_rejected_ = 0;
  point_attr_sets_ = 0;
  for (const PointSetData& ps : point_sets_) point_attr_sets_ = std::max(point_attr_sets_, uint32_t(ps.point_attrs.size()));
  uint32_t base = 0;
  size_t skipped = 0;
  std::vector<uint32_t> kept;
  for (const PointSetData& ps : point_sets_) {
    point_first_.push_back(base);
    point_coords_.push_back(make_object_coords(ps.matrix, ps.texspace_loc, ps.texspace_size));
    point_coords_.back().info = ps.info;
    // The object attributes live in the set itself (point_sets_ changes only with a rebuild).
    point_coords_.back().info.attr_first = 0;
    point_coords_.back().info.attr_count = uint32_t(std::min<size_t>(ps.attrs.size(), kMaxObjectAttributes));
    point_coords_.back().attrs = ps.attrs.empty() ? nullptr : ps.attrs.data();
    kept.clear();
    const size_t n = std::min(ps.points.size(), ps.radii.size());
    const size_t first = spheres.size();
    const size_t n_frames = frames.size();
    // Transform motion blur: steps that decompose and differ (else the cloud stays static).
    std::vector<DecomposedTransform> steps;
    const int state = set_motion(ps.motion, steps);
    bool moves = state > 0;
    if (state < 0) ++point_motion_rejected_;
    // Deformation blur: centres (and radii) at the steps, every step keeping the same points.
    std::vector<PointSphere> deform;
    uint32_t n_deform = 0;
    if (!ps.deform_points.empty() && deforms(ps.points, ps.radii, ps.deform_points, ps.deform_radii)) {
      n_deform = uint32_t(ps.deform_points.size());
      bool ok = n_deform >= 2 && (ps.deform_radii.empty() || ps.deform_radii.size() == n_deform);
      std::vector<uint32_t> kept_frame, kept_step;
      std::vector<PointFrame> none;
      std::vector<PointSphere> frame_spheres;
      if (ok) transform_points(ps.points.data(), ps.radii.data(), n, Mat4(), 0, frame_spheres, none, &kept_frame);
      for (uint32_t k = 0; k < n_deform && ok; ++k) {
        const std::vector<float>& r = ps.deform_radii.empty() ? ps.radii : ps.deform_radii[k];
        ok = ps.deform_points[k].size() == ps.points.size() && r.size() == ps.radii.size();
        if (!ok) break;
        for (size_t i = 0; i < n && ok; ++i) ok = is_finite(ps.deform_points[k][i]) && std::isfinite(r[i]);
        if (!ok) break;
        kept_step.clear();
        transform_points(ps.deform_points[k].data(), r.data(), n, Mat4(), 0, deform, none, &kept_step);
        ok = kept_step == kept_frame;
      }
      if (!ok) {
        deform.clear();
        n_deform = 0;
        ++point_motion_rejected_;
      }
    }
    if (n_deform && !moves) {  // deformed only: its constant transform as the steps
      moves = decompose_motion({ps.matrix, ps.matrix}, steps);
      if (!moves) deform.clear(), n_deform = 0;
    }
    point_moving_.push_back(moves ? 1 : 0);
    if (moves) {  // its spheres in object space, in a BVH of their own (PointBvh::add_moving)
      moving.push_back({{}, std::move(steps), std::move(deform), n_deform});
      std::vector<PointFrame> none;
      skipped += transform_points(ps.points.data(), ps.radii.data(), n, Mat4(), base, moving.back().spheres, none, &kept);
      for (size_t k = 0; k < moving.back().spheres.size(); ++k) moving.back().spheres[k].point = base + uint32_t(k);
    } else {
      skipped += transform_points(ps.points.data(), ps.radii.data(), n, ps.matrix, base, spheres, frames, &kept);
    }
    // Kept points are numbered densely: sphere k of this set is point base + k.
    for (size_t k = first; k < spheres.size(); ++k) spheres[k].point = base + uint32_t(k - first);
    {
      const Mat4& m = ps.matrix;
      const Vec3 c0{m.m[0][0], m.m[1][0], m.m[2][0]}, c1{m.m[0][1], m.m[1][1], m.m[2][1]}, c2{m.m[0][2], m.m[1][2], m.m[2][2]};
      const float det = std::cbrt(std::fabs(dot(c0, cross(c1, c2))));
      const float s = length(m.vector(Vec3(1.0f / std::sqrt(3.0f))));
      // (Ellipsoids keep the object radius.)
      const float over = frames.size() > n_frames || moves ? 1.0f : det;
      point_radius_scale_.push_back(over > 0.0f && std::isfinite(s / over) ? s / over : 1.0f);
    }
    for (uint32_t i : kept) point_random_.push_back(float(lookup3::hash(i, 0u)) * (1.0f / float(0xFFFFFFFFu)));
    if (any_pass) {
      const bool deforms_pass = point_pass_deform_[point_first_.size() - 1];
      for (uint32_t i : kept) {
        point_pass_.push_back(deforms_pass ? ps.pass_points[0][i] : ps.points[i]);
        point_pass_.push_back(deforms_pass ? ps.pass_points[1][i] : ps.points[i]);
      }
    }
    for (uint32_t i : kept)
      for (uint32_t a = 0; a < point_attr_sets_; ++a)
        point_attr_.push_back(a < ps.point_attrs.size() && i < ps.point_attrs[a].size() ? ps.point_attrs[a][i] : Float4{});
    base += uint32_t(kept.size());
  }
  stats_.points = base;
  stats_.skipped_points = skipped;
  point_bvh_.build(std::move(spheres), std::move(frames));
  for (Moving& m : moving) point_bvh_.add_moving(std::move(m.spheres), std::move(m.steps), std::move(m.deform), m.n_deform);
  points_on_ = !point_bvh_.empty();
  points_dirty_ = false;
}

void Scene::build_curves() {
  std::vector<CurvePiece> pieces;
  struct Moving {
    std::vector<CurvePiece> pieces, steps;
    uint32_t n_steps;
    std::vector<DecomposedTransform> xf;
  };
  std::vector<Moving> moving;
  curve_motion_rejected_ = 0;
  curve_moving_.clear();
  curve_first_.clear();
  curve_length_.clear();
  curve_random_.clear();
  curve_material_.clear();
  curve_uv_.clear();
  curve_coords_.clear();
  curve_uv_sets_ = 0;
  curve_attr_.clear();
  curve_attr_sets_ = 0;
  curve_point_sets_.clear();
  curve_key_first_.clear();
  curve_key_count_.clear();
  curve_key_v_.clear();
  curve_key_attr_.clear();
  curve_pass_deform_.clear();
  curve_key_pass_.clear();
  for (const CurveSetData& cs : curve_sets_) {
    curve_uv_sets_ = std::max(curve_uv_sets_, uint32_t(std::max(cs.uvs.size(), cs.point_uvs.size())));
    curve_attr_sets_ = std::max(curve_attr_sets_, uint32_t(std::max(cs.strand_attrs.size(), cs.point_attrs.size())));
  }
  curve_uv_sets_ = std::min(curve_uv_sets_, 8u);  // (the bindings' limit; masks are 8 bits)
  curve_attr_sets_ = std::min(curve_attr_sets_, 8u);
  curve_key_sets_ = std::max(curve_uv_sets_, curve_attr_sets_);
  bool any_point_sets = false;  // (else no per-strand key ranges at all)
  for (const CurveSetData& cs : curve_sets_) any_point_sets |= !cs.point_attrs.empty() || !cs.point_uvs.empty();
  // The Vector pass's deformation: per key, like point attributes (only where a set has it).
  for (const CurveSetData& cs : curve_sets_) curve_pass_deform_.push_back(pass_points_usable(cs.pass_points, cs.points));
  const bool any_pass = std::find(curve_pass_deform_.begin(), curve_pass_deform_.end(), 1) != curve_pass_deform_.end();
  any_point_sets |= any_pass;
  if (!any_pass) curve_pass_deform_.clear();
  std::vector<uint32_t> kept;
  uint32_t strands = 0;
  size_t skipped = 0;
  for (const CurveSetData& cs : curve_sets_) {
    const bool pass_keys = any_pass && curve_pass_deform_[curve_first_.size()];
    curve_first_.push_back(strands);
    CurveInput in;
    in.points = cs.points.data();
    in.radii = cs.radii.empty() ? nullptr : cs.radii.data();
    in.normals = cs.normals.empty() ? nullptr : cs.normals.data();
    in.n_points = cs.points.size();
    in.offsets = cs.offsets.data();
    in.n_curves = cs.offsets.empty() ? 0 : cs.offsets.size() - 1;
    in.type = cs.type;
    in.subdivisions = cs.subdivisions;
    in.ribbon = cs.ribbon;
    Vec3 loc, size;
    auto_texspace(cs.points, loc, size);
    curve_coords_.push_back(make_object_coords(cs.matrix, loc, size));
    curve_coords_.back().info = cs.info;
    // The object attributes live in the set itself (curve_sets_ changes only with a rebuild).
    curve_coords_.back().info.attr_first = 0;
    curve_coords_.back().info.attr_count = uint32_t(std::min<size_t>(cs.attrs.size(), kMaxObjectAttributes));
    curve_coords_.back().attrs = cs.attrs.empty() ? nullptr : cs.attrs.data();
    uint16_t point_sets = 0;
    for (uint32_t k = 0; k < curve_attr_sets_ && k < cs.point_attrs.size(); ++k)
      if (cs.point_attrs[k].size() == cs.points.size() && !cs.points.empty()) point_sets |= uint16_t(1u << k);
    for (uint32_t k = 0; k < curve_uv_sets_ && k < cs.point_uvs.size(); ++k)
      if (cs.point_uvs[k].size() == cs.points.size() && !cs.points.empty() && !(point_sets >> k & 1u))
        point_sets |= uint16_t(1u << (k + 8));
    curve_point_sets_.push_back(point_sets);
    kept.clear();
    // Motion blur: the transform's steps (the strands then stay in object space) and the
    // pieces cut at each deformation step, which must match the frame's one for one.
    std::vector<DecomposedTransform> xf;
    const int state = set_motion(cs.motion, xf);
    if (state < 0) ++curve_motion_rejected_;
    const bool moves = state > 0;
    std::vector<CurvePiece> frame, steps;
    uint32_t n_steps = deforms(cs.points, cs.radii, cs.deform_points, cs.deform_radii) ? uint32_t(cs.deform_points.size()) : 0;
    const Mat4 space = moves ? Mat4() : cs.matrix;
    CurveCutStats st = cut_curves(in, space, strands, frame, &kept);
    if (n_steps) {
      bool ok = n_steps >= 2 && (cs.deform_radii.empty() || cs.deform_radii.size() == n_steps);
      std::vector<uint32_t> kept_step;
      for (uint32_t k = 0; k < n_steps && ok; ++k) {
        CurveInput sin = in;
        ok = cs.deform_points[k].size() == cs.points.size() &&
             (cs.deform_radii.empty() || cs.deform_radii[k].size() == cs.points.size());
        if (!ok) break;
        sin.points = cs.deform_points[k].data();
        if (!cs.deform_radii.empty()) sin.radii = cs.deform_radii[k].data();
        kept_step.clear();
        const size_t before = steps.size();
        cut_curves(sin, space, strands, steps, &kept_step);
        ok = kept_step == kept && steps.size() - before == frame.size();
      }
      ok = ok && prepare_deform_steps(frame, steps, n_steps);
      if (!ok) {
        steps.clear();
        ++curve_motion_rejected_;
      }
      if (steps.empty()) n_steps = 0;
    }
    curve_moving_.push_back(moves ? 1 : 0);
    if (moves || n_steps) {
      moving.push_back({std::move(frame), std::move(steps), n_steps, std::move(xf)});
    } else {
      pieces.insert(pieces.end(), frame.begin(), frame.end());
    }
    for (uint32_t c : kept) {
      double len = 0.0;  // object space, as Cycles' Length
      for (int32_t k = cs.offsets[c] + 1; k < cs.offsets[c + 1]; ++k) len += length(cs.points[size_t(k)] - cs.points[size_t(k) - 1]);
      curve_length_.push_back(float(len));
      curve_random_.push_back(float(lookup3::hash(c, 0u)) * (1.0f / float(0xFFFFFFFFu)));  // Cycles' hash_uint2_to_float(i, 0)
      const uint32_t m = c < cs.strand_materials.size() ? cs.strand_materials[c] : cs.material;
      curve_material_.push_back(m < materials_.size() ? m : 0);
      for (uint32_t k = 0; k < curve_uv_sets_; ++k)
        curve_uv_.push_back(k < cs.uvs.size() && c < cs.uvs[k].size() ? cs.uvs[k][c] : Vec2{});
      for (uint32_t k = 0; k < curve_attr_sets_; ++k)
        curve_attr_.push_back(k < cs.strand_attrs.size() && c < cs.strand_attrs[k].size() ? cs.strand_attrs[k][c]
                                                                                          : Float4{});
      if (!point_sets && !pass_keys) {
        if (any_point_sets) {
          curve_key_first_.push_back(UINT32_MAX);
          curve_key_count_.push_back(0);
        }
        continue;
      }
      // The keys' intercepts as cut_curves computes them (world-space polygon length), so
      // a piece's intercept gives back its segment and the segment's parameter (Cycles' u).
      const size_t b = size_t(cs.offsets[c]), e = size_t(cs.offsets[c + 1]);
      curve_key_first_.push_back(uint32_t(curve_key_v_.size()));
      curve_key_count_.push_back(uint32_t(e - b));
      const size_t v_first = curve_key_v_.size();
      float total = 0.0f;
      Vec3 prev = cs.matrix.point(cs.points[b]);
      for (size_t i = b; i < e; ++i) {
        const Vec3 p = cs.matrix.point(cs.points[i]);
        if (i > b) total += length(p - prev);
        prev = p;
        curve_key_v_.push_back(total);
        if (any_pass) {
          curve_key_pass_.push_back(cs.points[i]);
          curve_key_pass_.push_back(pass_keys ? cs.pass_points[0][i] : cs.points[i]);
          curve_key_pass_.push_back(pass_keys ? cs.pass_points[1][i] : cs.points[i]);
        }
        for (uint32_t k = 0; k < curve_key_sets_; ++k) {
          const Vec2 uv = point_sets >> (k + 8) & 1u ? cs.point_uvs[k][i] : Vec2{};
          curve_key_attr_.push_back(point_sets >> k & 1u ? cs.point_attrs[k][i] : Float4{uv.x, uv.y, 0.0f, 0.0f});
        }
      }
      for (size_t i = v_first; i < curve_key_v_.size(); ++i) curve_key_v_[i] /= total;  // (kept: total > 0)
    }
    strands += uint32_t(st.curves);
    skipped += st.skipped;
  }
  stats_.curves = strands;
  stats_.skipped_curves = skipped;
  stats_.curve_pieces = pieces.size();
  for (const Moving& m : moving) stats_.curve_pieces += m.pieces.size();
  curve_bvh_.build(std::move(pieces));
  for (Moving& m : moving) curve_bvh_.add_moving(std::move(m.pieces), std::move(m.steps), m.n_steps, std::move(m.xf));
  curves_on_ = !curve_bvh_.empty();
  curves_dirty_ = false;
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

}  // namespace pl
