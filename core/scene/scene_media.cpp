// Heterogeneous media at commit: one majorant grid per instance and Volume program
// (docs/design/volumes.md), and the evaluation of a program at a point in the medium.
#include <algorithm>
#include <cmath>

#include "scene/scene.h"
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
      std::vector<float> lat(size_t(L) * L * L);
      std::vector<uint8_t> emit(size_t(L) * L * L);
      const Vec3 step = b.extent() * (1.0f / float(L - 1));
      for (int z = 0; z < L; ++z)
        for (int y = 0; y < L; ++y)
          for (int x = 0; x < L; ++x) {
            const Vec3 p = b.lo + Vec3{step.x * float(x), step.y * float(y), step.z * float(z)};
            const MediumSample ms = medium_at(h, p, Vec3{0.0f, 0.0f, 1.0f});
            const size_t k = (size_t(z) * L + y) * L + x;
            lat[k] = max_component(ms.sigma_a + ms.sigma_s);
            emit[k] = !is_black(ms.emission);
          }
      h.grid.cells.assign(size_t(N) * N * N, 0.0f);
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
            mu = std::max(mu * kSafety, e ? emit_mu : floor_mu) * majorant_scale_;
            h.grid.cells[size_t((cz * N + cy) * N + cx)] = std::isfinite(mu) ? mu : 0.0f;
          }
      hetero_.push_back(std::move(h));
    }
  }
}

}  // namespace pl
