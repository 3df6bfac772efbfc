#include "geometry/polygon_mesh.h"

#include "util/parallel.h"

#include <algorithm>
#include <atomic>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

namespace pl {
namespace {

// Blender's float normalisation: multiply by the reciprocal length, zero below 1e-35.
inline float normalize_v3(Vec3& v) {
  float d = dot(v, v);
  if (d > 1.0e-35f) {
    d = std::sqrt(d);
    v = v * (1.0f / d);
    return d;
  }
  v = Vec3(0.0f);
  return 0.0f;
}

// Blender's math::normalize: per-component division.
inline Vec3 normalize_div(Vec3 v) {
  const float d = dot(v, v);
  if (!(d > 1.0e-35f)) return Vec3(0.0f);
  const float len = std::sqrt(d);
  return {v.x / len, v.y / len, v.z / len};
}

// Blender's safe_acos_approx: a polynomial arccos, within 4.6e-5 rad of acos on [-1, 1].
inline float safe_acos_approx(float x) {
  const float f = std::fabs(x);
  const float m = f < 1.0f ? 1.0f - (1.0f - f) : 1.0f;
  const float a = std::sqrt(1.0f - m) * (1.5707963267f + m * (-0.213300989f + m * (0.077980478f + m * -0.02164095f)));
  return x < 0.0f ? 3.14159265359f - a : a;
}

// Newell's method, as Blender's normal_calc_ngon (degenerate faces get +z).
Vec3 face_normal(const PolygonMesh& m, size_t f) {
  const int32_t b = m.offsets[f], e = m.offsets[f + 1];
  Vec3 n(0.0f);
  Vec3 prev = m.positions[m.corner_verts[e - 1]];
  for (int32_t c = b; c < e; ++c) {
    const Vec3 cur = m.positions[m.corner_verts[c]];
    n.x += (prev.y - cur.y) * (prev.z + cur.z);
    n.y += (prev.z - cur.z) * (prev.x + cur.x);
    n.z += (prev.x - cur.x) * (prev.y + cur.y);
    prev = cur;
  }
  if (normalize_v3(n) == 0.0f) n.z = 1.0f;
  return n;
}

}  // namespace

void validate_polygon_mesh(const PolygonMesh& m) {
  if (m.faces > 0 && m.offsets == nullptr) throw std::invalid_argument("face offsets missing");
  if (m.offsets[0] != 0) throw std::invalid_argument("face offsets must start at 0");
  for (size_t f = 0; f < m.faces; ++f)
    if (int64_t(m.offsets[f + 1]) - int64_t(m.offsets[f]) < 3)
      throw std::invalid_argument("face " + std::to_string(f) + " has fewer than 3 corners");
  if (size_t(m.offsets[m.faces]) != m.corners)
    throw std::invalid_argument("face offsets end at " + std::to_string(m.offsets[m.faces]) + ", not at the " +
                                std::to_string(m.corners) + " corners");
  for (size_t c = 0; c < m.corners; ++c)
    if (m.corner_verts[c] < 0 || size_t(m.corner_verts[c]) >= m.vertices)
      throw std::invalid_argument("corner vertex " + std::to_string(m.corner_verts[c]) + " out of range for " +
                                  std::to_string(m.vertices) + " vertices");
}

size_t polygon_mesh_triangles(const PolygonMesh& m) { return m.corners - 2 * m.faces; }

size_t triangulate_polygons(const PolygonMesh& m, uint32_t* out, uint32_t* verts, int threads) {
  std::atomic<size_t> total{0};
  parallel_ranges(m.faces, threads, [&](size_t begin, size_t end) {
    size_t n = 0;
    for (size_t f = begin; f < end; ++f) {
      const uint32_t b = uint32_t(m.offsets[f]), size = uint32_t(m.offsets[f + 1]) - b;
      uint32_t* t = out + 3 * (size_t(b) - 2 * f);
      if (size == 4) {
        // Blender's is_quad_flip_v3_first_third_fast: do triangles (0 1 2) and (0 2 3) face
        // away from each other? Same operations in the same order (no FMA: -ffp-contract=off).
        const Vec3 v1 = m.positions[m.corner_verts[b]], v2 = m.positions[m.corner_verts[b + 1]],
                   v3 = m.positions[m.corner_verts[b + 2]], v4 = m.positions[m.corner_verts[b + 3]];
        const Vec3 d12 = v2 - v1, d13 = v3 - v1, d14 = v4 - v1;
        if (dot(cross(d12, d13), cross(d14, d13)) > 0.0f) {
          t[0] = b, t[1] = b + 1, t[2] = b + 3;
          t[3] = b + 1, t[4] = b + 2, t[5] = b + 3;
        } else {
          t[0] = b, t[1] = b + 1, t[2] = b + 2;
          t[3] = b, t[4] = b + 2, t[5] = b + 3;
        }
      } else {
        n += size > 4;
        for (uint32_t k = 0; k + 2 < size; ++k) t[3 * k] = b, t[3 * k + 1] = b + k + 1, t[3 * k + 2] = b + k + 2;
      }
      if (verts != nullptr)
        for (size_t k = size_t(b) - 2 * f, e = k + size_t(size) - 2; k < e; ++k)
          for (int j = 0; j < 3; ++j) verts[3 * k + j] = uint32_t(m.corner_verts[out[3 * k + j]]);
    }
    total.fetch_add(n);
  });
  return total.load();
}

namespace {
// Face normals and each corner's angle weight.
void face_normals_and_weights(const PolygonMesh& m, std::vector<Vec3>& fn, std::vector<float>& weight, int threads) {
  fn.resize(m.faces);
  weight.resize(m.corners);
  // Face normals and each corner's angle, face by face. Each edge's unit direction serves both
  // corners it touches: normalize(p - q) is exactly -normalize(q - p), and so are the dots.
  parallel_ranges(m.faces, threads, [&](size_t begin, size_t end) {
    std::vector<Vec3> edge;
    for (size_t f = begin; f < end; ++f) {
      fn[f] = face_normal(m, f);
      const int32_t b = m.offsets[f], e = m.offsets[f + 1], n = e - b;
      edge.resize(size_t(n));
      for (int32_t k = 0; k < n; ++k) {
        const int32_t next = k + 1 == n ? b : b + k + 1;
        edge[size_t(k)] = normalize_div(m.positions[m.corner_verts[next]] - m.positions[m.corner_verts[b + k]]);
      }
      for (int32_t k = 0; k < n; ++k) {
        // The face's first corner at this vertex, as Blender's face_find_adjacent_verts finds
        // it (another one only where a face visits a vertex twice).
        const int32_t v = m.corner_verts[b + k];
        int32_t first = 0;
        while (m.corner_verts[b + first] != v) ++first;
        const Vec3 in = edge[size_t(first == 0 ? n - 1 : first - 1)], out_dir = edge[size_t(first)];
        weight[size_t(b + k)] = safe_acos_approx(-dot(in, out_dir));
      }
    }
  });
}
}  // namespace

void polygon_vertex_normals(const PolygonMesh& m, Vec3* out, int threads) {
  std::vector<Vec3> fn;
  std::vector<float> weight;
  face_normals_and_weights(m, fn, weight, threads);
  // Sums in face order per vertex, as Blender's vertex-to-face map orders them.
  std::fill(out, out + m.vertices, Vec3(0.0f));
  std::vector<char> used(m.vertices, 0);
  for (size_t f = 0; f < m.faces; ++f)
    for (int32_t c = m.offsets[f]; c < m.offsets[f + 1]; ++c) {
      const int32_t v = m.corner_verts[c];
      out[v] += fn[f] * weight[size_t(c)];
      used[size_t(v)] = 1;
    }
  parallel_ranges(m.vertices, threads, [&](size_t begin, size_t end) {
    for (size_t v = begin; v < end; ++v) out[v] = normalize_div(used[v] ? out[v] : m.positions[v]);
  });
}

namespace {
uint32_t find_root(std::vector<uint32_t>& parent, uint32_t c) {
  while (parent[c] != c) c = parent[c] = parent[parent[c]];
  return c;
}
}  // namespace

void polygon_corner_normals(const PolygonMesh& m, const int32_t* corner_edges, size_t edges,
                            const uint8_t* sharp_edges, const uint8_t* sharp_faces, Vec3* out, int threads) {
  for (size_t c = 0; c < m.corners; ++c)
    if (corner_edges[c] < 0 || size_t(corner_edges[c]) >= edges)
      throw std::invalid_argument("corner edge " + std::to_string(corner_edges[c]) + " out of range for " +
                                  std::to_string(edges) + " edges");
  std::vector<Vec3> fn;
  std::vector<float> weight;
  face_normals_and_weights(m, fn, weight, threads);
  std::vector<uint32_t> face_of(m.corners), next(m.corners);
  for (size_t f = 0; f < m.faces; ++f)
    for (int32_t c = m.offsets[f]; c < m.offsets[f + 1]; ++c) {
      face_of[size_t(c)] = uint32_t(f);
      next[size_t(c)] = uint32_t(c + 1 == m.offsets[f + 1] ? m.offsets[f] : c + 1);
    }
  // The (up to) two corners using each edge, and how many do.
  constexpr uint32_t kNone = UINT32_MAX;
  std::vector<uint32_t> user0(edges, kNone), user1(edges, kNone), users(edges, 0);
  for (size_t c = 0; c < m.corners; ++c) {
    const size_t e = size_t(corner_edges[c]);
    if (users[e] == 0) user0[e] = uint32_t(c);
    else if (users[e] == 1) user1[e] = uint32_t(c);
    ++users[e];
  }
  // Corners joined across smooth edges share a fan (union-find).
  std::vector<uint32_t> parent(m.corners);
  for (size_t c = 0; c < m.corners; ++c) parent[c] = uint32_t(c);
  const auto join = [&](uint32_t a, uint32_t b) {
    a = find_root(parent, a), b = find_root(parent, b);
    if (a != b) parent[std::max(a, b)] = std::min(a, b);
  };
  for (size_t e = 0; e < edges; ++e) {
    if (users[e] != 2 || (sharp_edges && sharp_edges[e])) continue;
    const uint32_t c1 = user0[e], c2 = user1[e], f1 = face_of[c1], f2 = face_of[c2];
    if (f1 == f2 || (sharp_faces && (sharp_faces[f1] || sharp_faces[f2]))) continue;
    const int32_t a = m.corner_verts[c1], b = m.corner_verts[next[c1]];
    // Used in opposite directions (consistent winding), else the edge is sharp.
    if (m.corner_verts[c2] != b || m.corner_verts[next[c2]] != a) continue;
    join(c1, next[c2]);  // both at vertex a
    join(next[c1], c2);  // both at vertex b
  }
  std::vector<Vec3> sum(m.corners, Vec3(0.0f));
  std::vector<uint32_t> count(m.corners, 0);
  for (size_t c = 0; c < m.corners; ++c) {
    const uint32_t r = parent[c] = find_root(parent, uint32_t(c));  // every corner now points at its root
    sum[r] += fn[face_of[c]] * weight[c];
    ++count[r];
  }
  parallel_ranges(m.corners, threads, [&](size_t begin, size_t end) {
    for (size_t c = begin; c < end; ++c) {
      const uint32_t r = parent[c];
      out[c] = count[r] == 1 ? fn[face_of[c]] : normalize_div(sum[r]);
    }
  });
}

}  // namespace pl
