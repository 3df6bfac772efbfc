#include "scene/displace.h"

#include <algorithm>
#include <cmath>

#include "util/parallel.h"

namespace pl {

namespace {

Vec3 unit_or_zero(Vec3 v) {
  const float l2 = length_sq(v);
  return l2 > 0.0f && std::isfinite(l2) ? v / std::sqrt(l2) : Vec3(0.0f);
}

Vec3 face_normal(const std::vector<Vec3>& p, const std::array<uint32_t, 3>& t) {
  return unit_or_zero(cross(p[t[1]] - p[t[0]], p[t[2]] - p[t[0]]));
}

}  // namespace

DisplaceStats displace_mesh(MeshData& mesh, const Scene& scene, const Mat4& to_world, const std::vector<uint8_t>& flat) {
  DisplaceStats stats;
  const size_t nv = mesh.positions.size(), nt = mesh.triangles.size();
  const auto program_of = [&](size_t t) -> const Material* {
    const uint32_t id = t < mesh.materials.size() ? mesh.materials[t] : 0u;
    if (id >= scene.material_count()) return nullptr;
    const Material& m = scene.material(id);
    return m.displacement ? &m : nullptr;
  };
  // Each vertex runs once, at the corner of the first displaced triangle that uses it (Cycles'
  // fill_shader_input): its corner's uvs, attributes and normal.
  constexpr uint32_t kNone = UINT32_MAX;
  std::vector<uint32_t> corner_of(nv, kNone);
  std::vector<uint32_t> order;  // the vertices to run, by first use
  bool any = false;
  for (size_t t = 0; t < nt; ++t) {
    if (!program_of(t)) continue;
    any = true;
    for (int k = 0; k < 3; ++k) {
      const uint32_t v = mesh.triangles[t][size_t(k)];
      if (corner_of[v] != kNone) continue;
      corner_of[v] = uint32_t(3 * t + size_t(k));
      order.push_back(v);
    }
  }
  if (!any) return stats;

  Vec3 tex_loc = mesh.texspace_location, tex_size = mesh.texspace_size;
  if (!mesh.has_texspace) auto_texspace(mesh.positions, tex_loc, tex_size);
  const ObjectCoords coords = make_object_coords(to_world, tex_loc, tex_size);
  const Mat4 to_object = coords.valid ? coords.to_object : Mat4{};
  const bool has_normals = !mesh.normals.empty();
  const auto corner_normal = [&](size_t t, int k) {
    const uint32_t i = mesh.normal_indices.empty() ? mesh.triangles[t][size_t(k)] : mesh.normal_indices[t][size_t(k)];
    return has_normals && i < mesh.normals.size() ? mesh.normals[i] : Vec3(0.0f);
  };
  const bool is_flat_mesh = !has_normals;
  const auto is_flat = [&](size_t t) { return is_flat_mesh || (t < flat.size() && flat[t]); };

  constexpr int kMaxSets = 8;
  const int uv_sets = int(std::min<size_t>(mesh.uvs.size(), kMaxSets));
  const int attr_sets = int(std::min<size_t>(mesh.attributes.size(), kMaxSets));
  std::vector<Vec3> offsets(order.size(), Vec3(0.0f));
  std::vector<uint8_t> clamped(order.size(), 0);
  const std::vector<Image>& images = scene.images();
  parallel_ranges(
      order.size(), 0,
      [&](size_t begin, size_t end) {
        for (size_t i = begin; i < end; ++i) {
          const uint32_t v = order[i], c = corner_of[v];
          const size_t t = c / 3;
          const int k = int(c % 3);
          const Material& mat = *program_of(t);
          // Cycles' shader_setup_from_displace: the vertex in world space, the corner's
          // barycentrics, Ng its triangle's, N the smooth normal (flat: Ng), looking along N.
          ShadingContext ctx;
          ctx.p = to_world.point(mesh.positions[v]);
          const Vec3 ng_obj = face_normal(mesh.positions, mesh.triangles[t]);
          Vec3 n_obj = is_flat(t) ? ng_obj : corner_normal(t, k);
          if (!(length_sq(n_obj) > 0.0f) || !is_finite(n_obj)) n_obj = ng_obj;
          ctx.ng = unit_or_zero(to_world.normal(ng_obj));
          ctx.ns = unit_or_zero(to_world.normal(n_obj));
          if (!(length_sq(ctx.ns) > 0.0f)) ctx.ns = ctx.ng;
          ctx.wo = ctx.ns;
          ctx.normal_obj = n_obj;
          ctx.b1 = k == 1 ? 1.0f : 0.0f;
          ctx.b2 = k == 2 ? 1.0f : 0.0f;
          ctx.object = coords.valid ? &coords : nullptr;
          Vec2 uv[kMaxSets];
          Float4 attrs[kMaxSets], tangents[kMaxSets];
          uint32_t tangent_sets = 0;
          for (int s = 0; s < uv_sets; ++s) {
            const std::vector<Vec2>& u = mesh.uvs[size_t(s)];
            uv[s] = u.size() > c ? u[c] : Vec2{};
            if (size_t(s) < mesh.tangents.size() && mesh.tangents[size_t(s)].size() > c) {
              tangents[s] = mesh.tangents[size_t(s)][c];
              tangent_sets |= 1u << s;
            }
          }
          for (int s = 0; s < attr_sets; ++s) {
            const std::vector<Float4>& a = mesh.attributes[size_t(s)];
            attrs[s] = a.size() > c ? a[c] : Float4{};
          }
          ctx.uv = uv;
          ctx.uv_sets = uv_sets;
          ctx.attrs = attrs;
          ctx.attr_sets = attr_sets;
          if (tangent_sets) {
            ctx.mesh_tangents = tangents;
            ctx.mesh_tangent_sets = tangent_sets;
          }
          ctx.ray.camera = nullptr;
          Vec3 d = eval_displacement(*mat.displacement, images, ctx);
          // Cycles' ensure_finite, and a bound the BVH's float bounds survive.
          if (!is_finite(d)) {
            d = Vec3(0.0f);
            clamped[i] = 1;
          }
          const Vec3 od = to_object.vector(d);  // Cycles' object_inverse_dir_transform
          const float big = max_component(vabs(od));  // (length() of 1e30 overflows)
          if (!std::isfinite(big)) {
            clamped[i] = 1;
            offsets[i] = Vec3(0.0f);
          } else if (big > kMaxDisplacement * 0.5f && length(od / big) * big > kMaxDisplacement) {
            clamped[i] = 1;
            offsets[i] = normalize(od / big) * kMaxDisplacement;
          } else {
            offsets[i] = od;
          }
        }
      },
      256);
  for (size_t i = 0; i < order.size(); ++i) {
    const uint32_t v = order[i];
    mesh.positions[v] += offsets[i];
    for (std::vector<Vec3>& step : mesh.motion_positions)  // the same offset at every step (Cycles)
      if (v < step.size()) step[v] += offsets[i];
    stats.clamped += clamped[i];
  }
  stats.displaced = order.size();

  // Shading normals: [vertex normals made here (nv)] [displaced face normals (nt)] [the mesh's].
  std::vector<Vec3> vn(nv, Vec3(0.0f));
  std::vector<uint8_t> remade(nv, 0);
  for (size_t t = 0; t < nt; ++t) {
    const Material* m = program_of(t);
    if (!m || !m->displacement_normals) continue;
    const Vec3 fn = face_normal(mesh.positions, mesh.triangles[t]);
    for (uint32_t v : mesh.triangles[t]) {
      vn[v] += fn;
      remade[v] = 1;
    }
  }
  const bool any_remade = std::find(remade.begin(), remade.end(), uint8_t(1)) != remade.end();
  bool any_flat = is_flat_mesh;
  for (size_t t = 0; t < nt && !any_flat; ++t) any_flat = is_flat(t);
  if (!any_remade && !any_flat) return stats;
  std::vector<Vec3> normals;
  normals.reserve(nv + nt + mesh.normals.size());
  for (size_t v = 0; v < nv; ++v) normals.push_back(unit_or_zero(vn[v]));
  for (size_t t = 0; t < nt; ++t) normals.push_back(face_normal(mesh.positions, mesh.triangles[t]));
  normals.insert(normals.end(), mesh.normals.begin(), mesh.normals.end());
  std::vector<std::array<uint32_t, 3>> indices(nt);
  const uint32_t base = uint32_t(nv + nt);
  for (size_t t = 0; t < nt; ++t)
    for (int k = 0; k < 3; ++k) {
      const uint32_t v = mesh.triangles[t][size_t(k)];
      uint32_t i;
      if (is_flat(t)) i = uint32_t(nv + t);
      else if (remade[v] && length_sq(normals[v]) > 0.0f) i = v;
      else {
        const uint32_t o = mesh.normal_indices.empty() ? v : mesh.normal_indices[t][size_t(k)];
        i = base + o;
      }
      indices[t][size_t(k)] = i;
    }
  mesh.normals = std::move(normals);
  mesh.normal_indices = std::move(indices);
  return stats;
}

}  // namespace pl
