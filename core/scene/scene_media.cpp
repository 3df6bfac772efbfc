// Heterogeneous media at commit: one majorant grid per instance and Volume program
// (docs/design/volumes.md), and the evaluation of a program at a point in the medium.
#include <algorithm>
#include <cmath>

#include "scene/scene.h"
#include "geometry/motion.h"
#include "scene/medium_grid.h"
#include "scene/scene_detail.h"

namespace pl {

MediumSample Scene::medium_at_frame(const HeteroMedium& h, Vec3 p, Vec3 dir) const {
  ShadingContext ctx;
  ctx.p = p;
  ctx.ng = ctx.ns = Vec3(0.0f);  // a point in a volume has no normal (Cycles' volume shader data)
  ctx.wo = -dir;
  ctx.object = h.instance < object_coords_.size() ? &object_coords_[h.instance] : nullptr;
  ctx.scene = this;
  ctx.scene_camera = shading_camera();
  ctx.instance = h.instance;
  return eval_volume(*h.program, images_, ctx);
}

// Cycles samples a grid with voxel i's value at index i + 0.5 (its NanoVDB and dense lookups:
// floor(x) for closest, x - 0.5 for linear), half a voxel above OpenVDB's convention; so does
// the render (docs/design/volumes.md "Volume objects"). Blender's Volume Cube writes its field
// half a voxel low, and this puts it back where its node tree evaluated it.
constexpr double kCyclesVoxelShift = 0.5;

Float4 read_volume_grid(const ShadingContext& ctx, int id, VolumeSampling interp) {
  const VolumeGrid* g = ctx.scene ? ctx.scene->volume_grid(id) : nullptr;
  if (!g) return Float4{};  // Cycles: a grid found nowhere reads 0
  const bool obj = ctx.object && ctx.object->valid;
  if (ctx.grid_bound) {
    // The box's 8 corners into index space; their bounding box, grown by the rounding of the
    // transforms, bounds every sample taken inside.
    double lo[3] = {1e300, 1e300, 1e300}, hi[3] = {-1e300, -1e300, -1e300};
    const std::array<double, 16>& m = g->object_to_index();
    for (int c = 0; c < 8; ++c) {
      Vec3 w{(c & 1) ? ctx.grid_bound[1].x : ctx.grid_bound[0].x, (c & 2) ? ctx.grid_bound[1].y : ctx.grid_bound[0].y,
             (c & 4) ? ctx.grid_bound[1].z : ctx.grid_bound[0].z};
      const Vec3 o = obj ? ctx.object->to_object.point(w) : w;
      for (int a = 0; a < 3; ++a) {
        const double v = m[size_t(a * 4)] * o.x + m[size_t(a * 4 + 1)] * o.y + m[size_t(a * 4 + 2)] * o.z + m[size_t(a * 4 + 3)];
        lo[a] = std::min(lo[a], v);
        hi[a] = std::max(hi[a], v);
      }
    }
    for (int a = 0; a < 3; ++a) {
      const double pad = 1e-3 + 1e-6 * std::max(std::fabs(lo[a]), std::fabs(hi[a]));
      lo[a] -= pad + kCyclesVoxelShift;
      hi[a] += pad - kCyclesVoxelShift;
    }
    const float v = g->max_voxels_in_index_box(lo, hi, interp == VolumeSampling::Tricubic ? 1 : 0);
    return {v, v, v, 1.0f};
  }
  const Vec3 o = obj ? ctx.object->to_object.point(ctx.p) : ctx.p;
  const std::array<double, 16>& m = g->object_to_index();
  double ijk[3];
  for (int a = 0; a < 3; ++a)
    ijk[a] = m[size_t(a * 4)] * o.x + m[size_t(a * 4 + 1)] * o.y + m[size_t(a * 4 + 2)] * o.z + m[size_t(a * 4 + 3)] -
             kCyclesVoxelShift;
  float v[3] = {0.0f, 0.0f, 0.0f};
  g->sample_index(ijk, interp, v);
  return g->channels() == 1 ? Float4{v[0], v[0], v[0], 1.0f} : Float4{v[0], v[1], v[2], 1.0f};
}

Float4 read_voxel_texture(const ShadingContext& ctx, int id, VolumeSampling interp, VoxelSpace space, Vec3 v) {
  const VolumeGrid* g = ctx.scene ? ctx.scene->volume_grid(id) : nullptr;
  if (!g || g->empty()) return Float4{};
  if (space != VoxelSpace::World && ctx.object && ctx.object->valid) {
    v = ctx.object->to_object.point(v);
    if (space == VoxelSpace::Texture) v = v * ctx.object->gen_scale + ctx.object->gen_offset;
  }
  const std::array<double, 16>& m = g->object_to_index();
  double ijk[3];
  for (int a = 0; a < 3; ++a) {
    ijk[a] = m[size_t(a * 4)] * v.x + m[size_t(a * 4 + 1)] * v.y + m[size_t(a * 4 + 2)] * v.z + m[size_t(a * 4 + 3)];
    // Cycles' clip extension: nothing outside the texture's box (voxel centres at integers).
    if (!(ijk[a] >= g->active_min()[size_t(a)] - 0.5 && ijk[a] <= g->active_max()[size_t(a)] + 0.5)) return Float4{};
  }
  float out[3] = {0.0f, 0.0f, 0.0f};
  g->sample_index(ijk, interp, out);
  return g->channels() == 1 ? Float4{out[0], out[0], out[0], 1.0f} : Float4{out[0], out[1], out[2], 1.0f};
}

MediumSample Scene::medium_at_moving(const HeteroMedium& h, Vec3 p, Vec3 dir, float time) const {
  ShadingContext ctx;
  ctx.ng = ctx.ns = Vec3(0.0f);
  ctx.wo = -dir;
  ctx.scene = this;
  ctx.scene_camera = shading_camera();
  ctx.instance = h.instance;
  ctx.time = time;
  const ObjectCoords* frame = h.instance < object_coords_.size() ? &object_coords_[h.instance] : nullptr;
  ctx.object = frame;
  // The object's transforms at the ray's time (as a moving surface's texture coordinates).
  ObjectCoords moved;
  const InstanceData* in = h.instance < inst_.size() ? &inst_[h.instance] : nullptr;
  if (h.moving && frame && in && in->motion) {
    moved = *frame;
    const ObjectCoords at = make_object_coords(motion_transform_at(in->motion, in->motion_steps, time), Vec3(0.0f), Vec3(1.0f));
    moved.to_world = at.to_world;
    moved.to_object = at.to_object;
    moved.valid = at.valid;
    ctx.object = &moved;
  }
  ctx.p = p;
  if (h.velocity_grid >= 0 && ctx.object && ctx.object->valid) {
    // Cycles' volume_shader_motion_blur: first-order semi-Lagrangian advection, the point
    // moved back along the velocity there, then along the velocity at that point (object-space
    // velocity turned into world space by the transform at the ray's time).
    const float k = h.velocity_scale * (time + h.velocity_offset);
    const auto back = [&]() {
      Vec3 v = read_volume_grid(ctx, h.velocity_grid, h.velocity_sampling).xyz();
      if (h.velocity_yz[0] >= 0) {
        v.y = read_volume_grid(ctx, h.velocity_yz[0], h.velocity_sampling).x;
        v.z = read_volume_grid(ctx, h.velocity_yz[1], h.velocity_sampling).x;
      }
      return p - ctx.object->to_world.vector(v) * k;
    };
    ctx.p = back();
    ctx.p = back();
  }
  return eval_volume(*h.program, images_, ctx);
}

namespace {
bool reads_grids(const ShaderProgram& p) {
  for (const ShaderOp& op : p.ops)
    if (op.code == OpCode::VolumeGrid) return true;
  return false;
}
}  // namespace

// Motion blur: the frame's majorants (h.grid, built with the commit's transform and no
// velocity) carried to a grid over all the space the medium covers during the shutter. A cell's
// majorant is the largest frame majorant over the object-space points any of its points can
// show at any time: for each time sample t_j (sub-steps short against a cell), the cell grown
// by delta_j (how far any point of the object moves between t_j and the next sample) taken to
// object space by the inverse transform at t_j, clipped to the object's box, grown by the
// largest velocity displacement, and back to the frame's world space.
void Scene::sweep_majorants(HeteroMedium& h, const Aabb& ob) {
  constexpr int N = MajorantGrid::kRes;
  if (ob.empty() || h.grid.empty()) return;
  const MajorantGrid g0 = h.grid;
  const Mat4& m0 = instances_[h.instance].matrix;
  const InstanceData& in = inst_[h.instance];
  const bool moving = h.moving && in.motion && in.motion_steps >= 2;
  Vec3 disp(0.0f);
  if (h.velocity_grid >= 0) {
    const VolumeGrid* vg = volume_grid(h.velocity_grid);
    const std::array<float, 3> v = vg->max_abs();
    const float k = std::fabs(h.velocity_scale) * std::max(std::fabs(h.velocity_offset), std::fabs(1.0f + h.velocity_offset));
    Vec3 vmax = vg->channels() >= 3 ? Vec3{v[0], v[1], v[2]} : Vec3(v[0]);
    if (h.velocity_yz[0] >= 0)
      vmax = {v[0], volume_grid(h.velocity_yz[0])->max_abs()[0], volume_grid(h.velocity_yz[1])->max_abs()[0]};
    disp = vmax * (k * 1.001f);
    if (!is_finite(disp)) return;  // (the frame's majorants: unbiased, noisier)
  }
  Aabb B = g0.bounds;
  if (moving) {
    B = motion_world_box(ob, in.motion, in.motion_steps);
    if (B.empty() || !is_finite(B.lo) || !is_finite(B.hi)) return;
    const Vec3 pad = B.extent() * 1e-3f + Vec3(1e-5f);
    B.lo = B.lo - pad;
    B.hi = B.hi + pad;
  }
  const Vec3 cell = B.extent() * (1.0f / float(N));
  struct TimeSample {
    Mat4 to_object;
    float delta;
  };
  std::vector<TimeSample> samples;
  if (!moving) {
    samples.push_back({affine_inverse_fast(m0), 0.0f});
  } else {
    Vec3 corner[8];
    for (int c = 0; c < 8; ++c)
      corner[c] = {(c & 1) ? ob.hi.x : ob.lo.x, (c & 2) ? ob.hi.y : ob.lo.y, (c & 4) ? ob.hi.z : ob.lo.z};
    const float cmin = std::max(std::min(cell.x, std::min(cell.y, cell.z)), 1e-12f);
    const uint32_t n = in.motion_steps;
    for (uint32_t k = 0; k + 1 < n; ++k) {
      const DecomposedTransform& a = in.motion[k];
      const DecomposedTransform& b = in.motion[k + 1];
      // Between t_j and t in the step: |M(t) q - M(t_j) q| <= |dT| + |dS q| + 2 sin(dtheta / 2) |S q|
      // (translation and scale linear in t, |dS q| and |S q| largest at a corner).
      float ds = 0.0f, r = 0.0f;
      for (const Vec3& q : corner) {
        Vec3 d, sa, sb;
        for (int i = 0; i < 3; ++i) {
          sa[i] = a.s[i][0] * q.x + a.s[i][1] * q.y + a.s[i][2] * q.z;
          sb[i] = b.s[i][0] * q.x + b.s[i][1] * q.y + b.s[i][2] * q.z;
          d[i] = sb[i] - sa[i];
        }
        ds = std::max(ds, length(d));
        r = std::max(r, std::max(length(sa), length(sb)));
      }
      const float dt = length(b.t - a.t);
      const float c = std::fabs(a.q[0] * b.q[0] + a.q[1] * b.q[1] + a.q[2] * b.q[2] + a.q[3] * b.q[3]);
      const float theta = 2.0f * std::acos(std::min(c, 1.0f));
      const float total = dt + ds + theta * r;
      const int sub = std::clamp(int(std::ceil(total / (0.5f * cmin))), 1, 32);
      const float dtheta = std::min(1.1f * theta / float(sub), kPi);
      const float delta = ((dt + ds) / float(sub) + 2.0f * std::sin(0.5f * dtheta) * r) * 1.01f;
      for (int j = 0; j < sub; ++j) {
        const float time = (float(k) + float(j) / float(sub)) / float(n - 1);
        samples.push_back({affine_inverse_fast(motion_transform_at(in.motion, n, time)), delta});
      }
    }
  }
  const Vec3 cell0 = vmax(g0.bounds.extent() * (1.0f / float(N)), Vec3(1e-30f));
  const Vec3 slop = ob.extent() * 1e-4f + Vec3(1e-6f);
  const auto box_of = [](const Mat4& m, const Aabb& x) {
    Aabb o;
    for (int c = 0; c < 8; ++c)
      o.grow(m.point({(c & 1) ? x.hi.x : x.lo.x, (c & 2) ? x.hi.y : x.lo.y, (c & 4) ? x.hi.z : x.lo.z}));
    return o;
  };
  MajorantGrid g;
  g.bounds = B;
  g.cells.assign(size_t(N) * N * N, 0.0f);
  for (int cz = 0; cz < N; ++cz)
    for (int cy = 0; cy < N; ++cy)
      for (int cx = 0; cx < N; ++cx) {
        const Aabb c{B.lo + Vec3{cell.x * float(cx), cell.y * float(cy), cell.z * float(cz)},
                     B.lo + Vec3{cell.x * float(cx + 1), cell.y * float(cy + 1), cell.z * float(cz + 1)}};
        float mu = 0.0f;
        for (const TimeSample& s : samples) {
          const Aabb grown{c.lo - Vec3(s.delta), c.hi + Vec3(s.delta)};
          Aabb o = box_of(s.to_object, grown);
          o.lo = vmax(o.lo - slop, ob.lo);
          o.hi = vmin(o.hi + slop, ob.hi);
          if (!(o.lo.x <= o.hi.x && o.lo.y <= o.hi.y && o.lo.z <= o.hi.z)) continue;
          o.lo = o.lo - disp;
          o.hi = o.hi + disp;
          const Aabb f = box_of(m0, o);
          int lo[3], hi[3];
          for (int a = 0; a < 3; ++a) {
            lo[a] = std::clamp(int(std::floor((f.lo[a] - g0.bounds.lo[a]) / cell0[a])), 0, N - 1);
            hi[a] = std::clamp(int(std::floor((f.hi[a] - g0.bounds.lo[a]) / cell0[a])), 0, N - 1);
          }
          for (int z = lo[2]; z <= hi[2]; ++z)
            for (int y = lo[1]; y <= hi[1]; ++y)
              for (int x = lo[0]; x <= hi[0]; ++x) mu = std::max(mu, g0.at(x, y, z));
        }
        g.cells[size_t((cz * N + cy) * N + cx)] = mu;
      }
  h.grid = std::move(g);
}

void Scene::build_program_majorants(HeteroMedium& h, const Aabb& b, uint32_t instance) {
  constexpr int N = MajorantGrid::kRes;
  constexpr int kSub = 3;           // lattice points per cell and axis (shared with neighbours)
  constexpr int L = N * kSub + 1;   // lattice points per axis
  constexpr float kSafety = 1.5f;   // the sampled maximum times this
  h.grid.bounds = b;
  const Vec3 cell = b.extent() * (1.0f / float(N));
  const float diag = length(cell);
  // Inside the bounds no cell's majorant is 0: a cell whose samples all read 0 still gets a
  // tentative collision about every other cell length, so densities between the samples
  // are found (unbiased, with null weights of either sign).
  const float floor_mu = 0.5f / diag, emit_mu = 2.0f / diag;
  // Voxel grids: each cell also evaluates the program once with every grid read replaced
  // by the grid's own majorant over the cell (exact bounds for programs that grow with the
  // grid values: a density multiplied in, Map Range up; docs/design/volumes.md).
  const bool grids = reads_grids(*h.program);
  std::vector<float> lat(size_t(L) * L * L);
  std::vector<uint8_t> emit(size_t(L) * L * L);
  bool scatters = false;
  const Vec3 step = b.extent() * (1.0f / float(L - 1));
  for (int z = 0; z < L; ++z)
    for (int y = 0; y < L; ++y)
      for (int x = 0; x < L; ++x) {
        const Vec3 p = b.lo + Vec3{step.x * float(x), step.y * float(y), step.z * float(z)};
        const MediumSample ms = medium_at_frame(h, p, Vec3{0.0f, 0.0f, 1.0f});
        const size_t k = (size_t(z) * L + y) * L + x;
        lat[k] = max_component(ms.sigma_a + ms.sigma_s);
        emit[k] = !is_black(ms.emission);
        scatters = scatters || !is_black(ms.sigma_s);
      }
  h.grid.cells.assign(size_t(N) * N * N, 0.0f);
  h.tight = grids;
  for (int cz = 0; cz < N; ++cz)
    for (int cy = 0; cy < N; ++cy)
      for (int cx = 0; cx < N; ++cx) {
        float mu = 0.0f;
        bool e = false;
        for (int z = cz * kSub; z <= (cz + 1) * kSub; ++z)
          for (int y = cy * kSub; y <= (cy + 1) * kSub; ++y)
            for (int x = cx * kSub; x <= (cx + 1) * kSub; ++x) {
              const size_t k = (size_t(z) * L + y) * L + x;
              mu = std::max(mu, lat[k]);
              e = e || emit[k];
            }
        const float sampled = mu;
        mu *= kSafety;
        if (grids) {
          const Vec3 box[2] = {b.lo + Vec3{cell.x * float(cx), cell.y * float(cy), cell.z * float(cz)},
                               b.lo + Vec3{cell.x * float(cx + 1), cell.y * float(cy + 1), cell.z * float(cz + 1)}};
          ShadingContext ctx;
          ctx.p = (box[0] + box[1]) * 0.5f;
          ctx.ng = ctx.ns = Vec3(0.0f);
          ctx.wo = Vec3{0.0f, 0.0f, -1.0f};
          ctx.object = instance < object_coords_.size() ? &object_coords_[instance] : nullptr;
          ctx.scene = this;
          ctx.scene_camera = shading_camera();
          ctx.instance = instance;
          ctx.grid_bound = box;
          const MediumSample ms = eval_volume(*h.program, images_, ctx);
          const float bound = max_component(ms.sigma_a + ms.sigma_s) * 1.001f;
          e = e || !is_black(ms.emission);
          if (sampled <= bound && !e) {
            // The program grows with the grid values here (no lattice point above the
            // bound): the bound alone, without the sampled maximum's safety factor or
            // the floor, which in sparse smoke made the majorants 12x the mean density
            // (docs/design/volumes.md "Equal time against Cycles"). A floor 10x lower
            // still finds what a program adds between the lattice points.
            h.grid.cells[size_t((cz * N + cy) * N + cx)] =
                std::isfinite(bound) ? std::max(bound, 0.1f * floor_mu) * majorant_scale_ : 0.0f;
            continue;
          }
          mu = std::max(mu, bound);
        }
        h.tight = false;
        mu = std::max(mu, e ? emit_mu : floor_mu) * majorant_scale_;
        h.grid.cells[size_t((cz * N + cy) * N + cx)] = std::isfinite(mu) ? mu : 0.0f;
      }
  // Without scattering, delta tracking is ratio tracking (every collision null): its
  // majorants as loose as ratio tracking's (medium_grid.h kRatioTrackingScale), or the
  // transmittance through a tight bound is nearly a coin flip.
  if (!scatters)
    for (float& c : h.grid.cells) c *= kRatioTrackingScale;
}

void Scene::build_media() {
  hetero_.clear();
  velocity_media_ = 0;
  build_world_medium();
  bool any = false;
  for (const Material& m : materials_) any = any || m.program.volume != nullptr;
  if (!any) return;
  for (uint32_t i = 0; i < instances_.size(); ++i) {
    const Instance& inst = instances_[i];
    const MeshData& mesh = meshes_[inst.mesh];
    std::vector<uint32_t> mats;
    for (size_t t = 0; t < mesh.triangles.size(); ++t) {
      const uint32_t id = detail::material_of(mesh, uint32_t(t), materials_.size());
      if (materials_[id].program.volume && std::find(mats.begin(), mats.end(), id) == mats.end()) mats.push_back(id);
    }
    if (mats.empty()) continue;
    Aabb b;
    for (const Vec3& p : mesh.positions) b.grow(inst.matrix.point(p));
    if (b.empty() || !is_finite(b.lo) || !is_finite(b.hi)) continue;
    const Vec3 pad = b.extent() * 1e-3f + Vec3(1e-5f);
    b.lo = b.lo - pad;
    b.hi = b.hi + pad;
    for (const uint32_t id : mats) {
      HeteroMedium h;
      h.program = materials_[id].program.volume.get();
      h.material = id;
      h.instance = i;
      h.moving = i < inst_.size() && inst_[i].motion != nullptr;
      const bool xyz = mesh.velocity_yz[0] >= 0;
      if (mesh.velocity_grid >= 0 && volume_grid(mesh.velocity_grid) &&
          (!xyz || (volume_grid(mesh.velocity_yz[0]) && volume_grid(mesh.velocity_yz[1])))) {
        h.velocity_grid = mesh.velocity_grid;
        h.velocity_yz[0] = mesh.velocity_yz[0];
        h.velocity_yz[1] = mesh.velocity_yz[1];
        h.velocity_scale = mesh.velocity_scale;
        h.velocity_offset = mesh.velocity_offset;
        h.velocity_sampling = mesh.velocity_sampling;
      }
      build_program_majorants(h, b, i);
      if (h.moving || h.velocity_grid >= 0) {
        h.tight = false;  // swept over the shutter: no longer the grid bound
        Aabb ob;
        for (const Vec3& p : mesh.positions) ob.grow(p);
        sweep_majorants(h, ob);
        velocity_media_ += h.velocity_grid >= 0;
      }
      hetero_.push_back(std::move(h));
    }
  }
}

// The world's Volume program (docs/design/volumes.md "World volumes"): a medium with no bounded
// domain, tracked through majorants over the scene's bounds (geometry, lights, the camera),
// padded; beyond them it is empty. In a closed scene no ray gets there. Cycles 4.5 marches a
// ray that leaves the scene (tmax FLT_MAX) in steps of FLT_MAX / volume_max_steps, reading the
// density about 1e35 units away for the whole ray; nothing sensible matches that, so the
// fraction of probe rays that escape is reported (world_volume_open) for the add-on to warn.
void Scene::build_world_medium() {
  world_het_ = HeteroMedium{};
  world_open_ = 0.0f;
  if (!world_volume_.volume) return;
  Aabb b = world_bounds_;
  std::vector<Vec3> probes;
  if (has_camera_) probes.push_back(camera_.matrix_world.point(Vec3(0.0f)));
  for (const Light& l : lights_) {
    if (l.type == LightType::Sun) continue;
    probes.push_back(l.position);
    if (l.type == LightType::Rect || l.type == LightType::Ellipse) {
      for (int c = 0; c < 4; ++c)
        b.grow(l.position + l.axis_u * ((c & 1) ? 0.5f : -0.5f) + l.axis_v * ((c & 2) ? 0.5f : -0.5f));
    }
    b.grow(l.position - Vec3(l.radius));
    b.grow(l.position + Vec3(l.radius));
  }
  for (const Vec3& p : probes) b.grow(p);
  if (b.empty() || !is_finite(b.lo) || !is_finite(b.hi)) return;  // nothing to bound it: no medium
  const Vec3 pad = b.extent() * 0.01f + Vec3(1e-3f);
  b.lo = b.lo - pad;
  b.hi = b.hi + pad;
  world_het_.program = world_volume_.volume.get();
  world_het_.material = 0xFFFFFFFFu;  // (no material: trace_path's kWorldMedium)
  world_het_.instance = 0xFFFFFFFFu;  // no object: Object coordinates are world positions
  build_program_majorants(world_het_, b, world_het_.instance);
  // Probe rays (a Fibonacci sphere from each probe point): how open the scene is.
  constexpr int kDirs = 128;
  int escaped = 0, cast = 0;
  for (const Vec3& o : probes) {
    for (int k = 0; k < kDirs; ++k) {
      const float z = 1.0f - (2.0f * float(k) + 1.0f) / float(kDirs);
      const float r = std::sqrt(std::max(0.0f, 1.0f - z * z));
      const float phi = 2.39996323f * float(k);
      Ray ray;
      ray.org = o;
      ray.dir = Vec3{r * std::cos(phi), r * std::sin(phi), z};
      ray.tmax = kInf;
      Hit h;
      ++cast;
      escaped += !intersect(ray, h);
    }
  }
  world_open_ = cast ? float(escaped) / float(cast) : 1.0f;
}

}  // namespace pl
