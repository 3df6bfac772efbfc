// Heterogeneous media at commit: one majorant grid per instance and Volume program
// (docs/design/volumes.md), and the evaluation of a program at a point in the medium.
#include <algorithm>
#include <cmath>

#include "scene/scene.h"
#include "scene/medium_grid.h"
#include "scene/scene_detail.h"

namespace pl {

MediumSample Scene::medium_at(const HeteroMedium& h, Vec3 p, Vec3 dir) const {
  ShadingContext ctx;
  ctx.p = p;
  ctx.ng = ctx.ns = Vec3(0.0f);  // a point in a volume has no normal (Cycles' volume shader data)
  ctx.wo = -dir;
  ctx.object = h.instance < object_coords_.size() ? &object_coords_[h.instance] : nullptr;
  ctx.scene = this;
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

namespace {
bool reads_grids(const ShaderProgram& p) {
  for (const ShaderOp& op : p.ops)
    if (op.code == OpCode::VolumeGrid) return true;
  return false;
}
}  // namespace

void Scene::build_media() {
  hetero_.clear();
  bool any = false;
  for (const Material& m : materials_) any = any || m.program.volume != nullptr;
  if (!any) return;
  constexpr int N = MajorantGrid::kRes;
  constexpr int kSub = 3;           // lattice points per cell and axis (shared with neighbours)
  constexpr int L = N * kSub + 1;   // lattice points per axis
  constexpr float kSafety = 1.5f;   // the sampled maximum times this
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
    const Vec3 cell = b.extent() * (1.0f / float(N));
    const float diag = length(cell);
    // Inside the bounds no cell's majorant is 0: a cell whose samples all read 0 still gets a
    // tentative collision about every other cell length, so densities between the samples
    // are found (unbiased, with null weights of either sign).
    const float floor_mu = 0.5f / diag, emit_mu = 2.0f / diag;
    for (const uint32_t id : mats) {
      HeteroMedium h;
      h.program = materials_[id].program.volume.get();
      h.material = id;
      h.instance = i;
      h.grid.bounds = b;
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
            const MediumSample ms = medium_at(h, p, Vec3{0.0f, 0.0f, 1.0f});
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
              ctx.object = i < object_coords_.size() ? &object_coords_[i] : nullptr;
              ctx.scene = this;
              ctx.instance = i;
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
      hetero_.push_back(std::move(h));
    }
  }
}

}  // namespace pl
