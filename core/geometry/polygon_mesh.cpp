#include "geometry/polygon_mesh.h"

#include "util/big_alloc.h"
#include "util/parallel.h"

#if defined(__SSE2__)
#include <immintrin.h>
#endif

#include <algorithm>
#include <atomic>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

namespace pl {
namespace {

// Below this many corners per thread, polygon work stays on fewer threads.
constexpr size_t kMinCornersPerThread = 32768;

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
  // Branch-free reductions first (vectorised: this runs on every export call); the loops that
  // name the first bad entry only when one exists.
  int64_t smallest = 3;
  for (size_t f = 0; f < m.faces; ++f) smallest = std::min(smallest, int64_t(m.offsets[f + 1]) - int64_t(m.offsets[f]));
  if (smallest < 3)
    for (size_t f = 0; f < m.faces; ++f)
      if (int64_t(m.offsets[f + 1]) - int64_t(m.offsets[f]) < 3)
        throw std::invalid_argument("face " + std::to_string(f) + " has fewer than 3 corners");
  if (size_t(m.offsets[m.faces]) != m.corners)
    throw std::invalid_argument("face offsets end at " + std::to_string(m.offsets[m.faces]) + ", not at the " +
                                std::to_string(m.corners) + " corners");
  // As unsigned, negative vertex indices are out of range too.
  uint32_t largest = 0;
  for (size_t c = 0; c < m.corners; ++c) largest = std::max(largest, uint32_t(m.corner_verts[c]));
  if (m.corners > 0 && size_t(largest) >= m.vertices)
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
    // Triangle `tri` from corners (a, b, c): its corner indices and/or its vertex indices.
    const auto emit = [&](size_t tri, uint32_t a, uint32_t b, uint32_t c) {
      if (out != nullptr) out[3 * tri] = a, out[3 * tri + 1] = b, out[3 * tri + 2] = c;
      if (verts != nullptr)
        verts[3 * tri] = uint32_t(m.corner_verts[a]), verts[3 * tri + 1] = uint32_t(m.corner_verts[b]),
                    verts[3 * tri + 2] = uint32_t(m.corner_verts[c]);
    };
    for (size_t f = begin; f < end; ++f) {
      const uint32_t b = uint32_t(m.offsets[f]), size = uint32_t(m.offsets[f + 1]) - b;
      const size_t t = size_t(b) - 2 * f;
      if (size == 4) {
        // Blender's is_quad_flip_v3_first_third_fast: do triangles (0 1 2) and (0 2 3) face
        // away from each other? Same operations in the same order (no FMA: -ffp-contract=off).
        const Vec3 v1 = m.positions[m.corner_verts[b]], v2 = m.positions[m.corner_verts[b + 1]],
                   v3 = m.positions[m.corner_verts[b + 2]], v4 = m.positions[m.corner_verts[b + 3]];
        const Vec3 d12 = v2 - v1, d13 = v3 - v1, d14 = v4 - v1;
        if (dot(cross(d12, d13), cross(d14, d13)) > 0.0f) {
          emit(t, b, b + 1, b + 3);
          emit(t + 1, b + 1, b + 2, b + 3);
        } else {
          emit(t, b, b + 1, b + 2);
          emit(t + 1, b, b + 2, b + 3);
        }
      } else {
        n += size > 4;
        for (uint32_t k = 0; k + 2 < size; ++k) emit(t + k, b, b + k + 1, b + k + 2);
      }
    }
    total.fetch_add(n);
  });
  return total.load();
}

bool polygon_offsets_from_triangle_faces(const int32_t* tri_faces, size_t tris, size_t faces, size_t corners,
                                         int32_t* offsets) {
  if (corners > size_t(INT32_MAX)) return false;
  offsets[0] = 0;
  size_t t = 0;
  for (size_t f = 0; f < faces; ++f) {
    const size_t first = t;
    while (t < tris && tri_faces[t] == int32_t(f)) ++t;
    const size_t next = size_t(offsets[f]) + (t - first) + 2;
    if (t == first || next > corners) return false;  // a face without a triangle, or too many corners
    offsets[f + 1] = int32_t(next);
  }
  return t == tris && size_t(offsets[faces]) == corners;
}

namespace {
#if defined(__SSE2__)
// add_face_normal for a triangle or quad of distinct vertices: its edges' normalisations and
// corner angles four lanes at a time. Every lane does the scalar code's IEEE operations in its
// order (division, square root, no FMA), so the normals are bit for bit the scalar ones.
template <int N>
inline void small_face_normal_and_weights(const PolygonMesh& m, const int32_t* v, Vec3& face_n, float* w) {
  Vec3 p[4];
  for (int k = 0; k < N; ++k) p[k] = m.positions[v[k]];
  if (N == 3) p[3] = p[2];  // an unused lane
  // Newell's normal, as face_normal.
  Vec3 fn(0.0f);
  Vec3 prev = p[N - 1];
  for (int k = 0; k < N; ++k) {
    const Vec3 cur = p[k];
    fn.x += (prev.y - cur.y) * (prev.z + cur.z);
    fn.y += (prev.z - cur.z) * (prev.x + cur.x);
    fn.z += (prev.x - cur.x) * (prev.y + cur.y);
    prev = cur;
  }
  if (normalize_v3(fn) == 0.0f) fn.z = 1.0f;
  face_n = fn;
  // Edge k runs from corner k to the next one: normalize_div(p[next] - p[k]).
  const int n1 = 1 % N, n2 = 2 % N, n3 = 3 % N;
  const __m128 x = _mm_setr_ps(p[0].x, p[1].x, p[2].x, p[3].x), y = _mm_setr_ps(p[0].y, p[1].y, p[2].y, p[3].y),
               z = _mm_setr_ps(p[0].z, p[1].z, p[2].z, p[3].z);
  const __m128 ex0 = _mm_sub_ps(_mm_setr_ps(p[n1].x, p[n2].x, p[n3].x, p[0].x), x),
               ey0 = _mm_sub_ps(_mm_setr_ps(p[n1].y, p[n2].y, p[n3].y, p[0].y), y),
               ez0 = _mm_sub_ps(_mm_setr_ps(p[n1].z, p[n2].z, p[n3].z, p[0].z), z);
  const __m128 d = _mm_add_ps(_mm_add_ps(_mm_mul_ps(ex0, ex0), _mm_mul_ps(ey0, ey0)), _mm_mul_ps(ez0, ez0));
  const __m128 ok = _mm_cmpgt_ps(d, _mm_set1_ps(1.0e-35f));
  const __m128 len = _mm_sqrt_ps(d);
  const __m128 ex = _mm_and_ps(ok, _mm_div_ps(ex0, len)), ey = _mm_and_ps(ok, _mm_div_ps(ey0, len)),
               ez = _mm_and_ps(ok, _mm_div_ps(ez0, len));
  // The edge into corner k: edge N - 1 for corner 0, else edge k - 1.
  __m128 ix, iy, iz;
  if (N == 4) {
    ix = _mm_shuffle_ps(ex, ex, _MM_SHUFFLE(2, 1, 0, 3));
    iy = _mm_shuffle_ps(ey, ey, _MM_SHUFFLE(2, 1, 0, 3));
    iz = _mm_shuffle_ps(ez, ez, _MM_SHUFFLE(2, 1, 0, 3));
  } else {
    ix = _mm_shuffle_ps(ex, ex, _MM_SHUFFLE(3, 1, 0, 2));
    iy = _mm_shuffle_ps(ey, ey, _MM_SHUFFLE(3, 1, 0, 2));
    iz = _mm_shuffle_ps(ez, ez, _MM_SHUFFLE(3, 1, 0, 2));
  }
  // safe_acos_approx(-dot(in, out)).
  const __m128 sign = _mm_set1_ps(-0.0f), one = _mm_set1_ps(1.0f);
  const __m128 c = _mm_xor_ps(sign, _mm_add_ps(_mm_add_ps(_mm_mul_ps(ix, ex), _mm_mul_ps(iy, ey)), _mm_mul_ps(iz, ez)));
  const __m128 f = _mm_andnot_ps(sign, c);
  const __m128 lt = _mm_cmplt_ps(f, one);
  const __m128 mm = _mm_or_ps(_mm_and_ps(lt, _mm_sub_ps(one, _mm_sub_ps(one, f))), _mm_andnot_ps(lt, one));
  __m128 poly = _mm_add_ps(_mm_set1_ps(0.077980478f), _mm_mul_ps(mm, _mm_set1_ps(-0.02164095f)));
  poly = _mm_add_ps(_mm_set1_ps(-0.213300989f), _mm_mul_ps(mm, poly));
  poly = _mm_add_ps(_mm_set1_ps(1.5707963267f), _mm_mul_ps(mm, poly));
  const __m128 a = _mm_mul_ps(_mm_sqrt_ps(_mm_sub_ps(one, mm)), poly);
  const __m128 neg = _mm_cmplt_ps(c, _mm_setzero_ps());
  const __m128 w4 = _mm_or_ps(_mm_and_ps(neg, _mm_sub_ps(_mm_set1_ps(3.14159265359f), a)), _mm_andnot_ps(neg, a));
  _mm_storeu_ps(w, w4);
}

// Whether face f is a triangle or quad of distinct vertices (those take the four-lane path).
inline int small_face(const PolygonMesh& m, size_t f) {
  const int32_t* v = m.corner_verts + m.offsets[f];
  const int32_t n = m.offsets[f + 1] - m.offsets[f];
  if (n == 4 && v[0] != v[1] && v[0] != v[2] && v[0] != v[3] && v[1] != v[2] && v[1] != v[3] && v[2] != v[3]) return 4;
  if (n == 3 && v[0] != v[1] && v[0] != v[2] && v[1] != v[2]) return 3;
  return 0;
}

template <int N>
inline void add_small_face_normal(const PolygonMesh& m, const int32_t* v, uint32_t lo, uint32_t hi, Vec3* out,
                                  uint8_t* used) {
  Vec3 fn;
  alignas(16) float w[4];
  small_face_normal_and_weights<N>(m, v, fn, w);
  for (int k = 0; k < N; ++k) {
    if (uint32_t(v[k]) < lo || uint32_t(v[k]) >= hi) continue;
    out[v[k]] += fn * w[k];
    used[size_t(v[k])] = 1;
  }
}
#endif

// The unit edge directions of the face of corners [b, b + n): edge k from corner k to the next.
inline void face_edges(const PolygonMesh& m, int32_t b, int32_t n, std::vector<Vec3>& edge) {
  edge.resize(size_t(n));
  for (int32_t k = 0; k < n; ++k) {
    const int32_t next = k + 1 == n ? b : b + k + 1;
    edge[size_t(k)] = normalize_div(m.positions[m.corner_verts[next]] - m.positions[m.corner_verts[b + k]]);
  }
}

// The face's angle at corner k, taken at the face's first corner at that vertex, as Blender's
// face_find_adjacent_verts finds it (another one only where a face visits a vertex twice).
inline float corner_angle(const PolygonMesh& m, int32_t b, int32_t n, int32_t k, const std::vector<Vec3>& edge) {
  const int32_t v = m.corner_verts[b + k];
  int32_t first = 0;
  while (m.corner_verts[b + first] != v) ++first;
  const Vec3 in = edge[size_t(first == 0 ? n - 1 : first - 1)], out_dir = edge[size_t(first)];
  return safe_acos_approx(-dot(in, out_dir));
}

// Face normals and each corner's angle weight. lanes: triangles and quads of distinct vertices
// four lanes at a time (the same bits; false keeps the scalar code, the tests' reference).
void face_normals_and_weights(const PolygonMesh& m, std::vector<Vec3>& fn, std::vector<float>& weight, int threads,
                              bool lanes = false) {
  fn.resize(m.faces);
  weight.resize(m.corners);
  // Face normals and each corner's angle, face by face. Each edge's unit direction serves both
  // corners it touches: normalize(p - q) is exactly -normalize(q - p), and so are the dots.
  parallel_ranges(m.faces, threads, [&](size_t begin, size_t end) {
    std::vector<Vec3> edge;
    for (size_t f = begin; f < end; ++f) {
#if defined(__SSE2__)
      if (const int small = lanes ? small_face(m, f) : 0) {
        alignas(16) float w[4];
        const int32_t b = m.offsets[f];
        if (small == 4) small_face_normal_and_weights<4>(m, m.corner_verts + b, fn[f], w);
        else small_face_normal_and_weights<3>(m, m.corner_verts + b, fn[f], w);
        for (int k = 0; k < small; ++k) weight[size_t(b + k)] = w[k];
        continue;
      }
#else
      (void)lanes;
#endif
      fn[f] = face_normal(m, f);
      const int32_t b = m.offsets[f], n = m.offsets[f + 1] - b;
      face_edges(m, b, n, edge);
      for (int32_t k = 0; k < n; ++k) weight[size_t(b + k)] = corner_angle(m, b, n, k, edge);
    }
  });
}

// Adds face f's unit normal, weighted by its angle at each corner, to the normals of the
// corners' vertices in [lo, hi) (marking them used): the same operations as
// face_normals_and_weights followed by the sum, for one face. edge: scratch space.
inline void add_face_normal(const PolygonMesh& m, size_t f, uint32_t lo, uint32_t hi, Vec3* out, uint8_t* used,
                            std::vector<Vec3>& edge) {
  const int32_t b = m.offsets[f], e = m.offsets[f + 1], n = e - b;
#if defined(__SSE2__)
  if (const int small = small_face(m, f))
    return small == 4 ? add_small_face_normal<4>(m, m.corner_verts + b, lo, hi, out, used)
                      : add_small_face_normal<3>(m, m.corner_verts + b, lo, hi, out, used);
#endif
  const Vec3 fn = face_normal(m, f);
  face_edges(m, b, n, edge);
  for (int32_t k = 0; k < n; ++k) {
    const int32_t v = m.corner_verts[b + k];
    if (uint32_t(v) < lo || uint32_t(v) >= hi) continue;
    out[v] += fn * corner_angle(m, b, n, k, edge);
    used[size_t(v)] = 1;
  }
}
// Threads owning ranges of what the corners name (index[c]: their vertices or their edges), each
// walking the faces in order and doing only the work at its own: per-vertex (per-edge) results
// in face order on any number of threads, without atomics or per-thread copies. A thread skips
// the blocks of faces that never reach its range (meshes usually number faces, vertices and
// edges in similar orders).
struct OwnerRanges {
  static constexpr size_t kBlock = 512;
  const PolygonMesh& m;
  const int32_t* index;
  size_t n;                // indices are in [0, n)
  size_t parts = 1;        // 1: one thread does it all (lo 0, hi all)
  bool scattered = false;  // the indices are spread over the faces: each thread would walk most
  std::vector<uint32_t> block_lo, block_hi;

  OwnerRanges(const PolygonMesh& mesh, const int32_t* idx, size_t count, int threads) : m(mesh), index(idx), n(count) {
    const size_t hw = threads > 0 ? size_t(threads) : std::max(1u, std::thread::hardware_concurrency());
    parts = std::min(hw, std::max<size_t>(1, m.corners / kMinCornersPerThread));
    if (parts <= 1) return;
    const size_t blocks = (m.faces + kBlock - 1) / kBlock;
    block_lo.resize(blocks), block_hi.resize(blocks);
    parallel_ranges(blocks, int(parts), [&](size_t begin, size_t end) {
      for (size_t k = begin; k < end; ++k) {
        uint32_t lo = UINT32_MAX, hi = 0;
        for (int32_t c = m.offsets[k * kBlock], e = m.offsets[std::min(m.faces, (k + 1) * kBlock)]; c < e; ++c) {
          lo = std::min(lo, uint32_t(index[c]));
          hi = std::max(hi, uint32_t(index[c]));
        }
        block_lo[k] = lo, block_hi[k] = hi;
      }
    }, 64);
    size_t visits = 0;
    for (size_t p = 0; p < parts; ++p)
      for (size_t k = 0; k < blocks; ++k) visits += block_lo[k] < lo(p + 1) && block_hi[k] >= lo(p);
    scattered = visits * 4 > blocks * 5;  // more than 25 % of the faces done twice
  }
  uint32_t lo(size_t p) const { return uint32_t(n * p / parts); }
  // fn(lo, hi, for_faces) for every part on its own thread (one part: lo 0, hi all, every face);
  // for_faces(g) calls g(f) for the faces, in order, that may name an index in [lo, hi).
  template <class F>
  void run(F&& fn) const {
    if (parts <= 1 || scattered) {
      fn(0u, UINT32_MAX, [&](auto&& g) {
        for (size_t f = 0; f < m.faces; ++f) g(f);
      });
      return;
    }
    parallel_ranges(parts, int(parts), [&](size_t begin, size_t end) {
      for (size_t p = begin; p < end; ++p) {
        const uint32_t l = lo(p), h = lo(p + 1);
        const auto for_faces = [&](auto&& g) {
          for (size_t k = 0; k < block_lo.size(); ++k) {
            if (block_lo[k] >= h || block_hi[k] < l) continue;
            for (size_t f = k * kBlock, e = std::min(m.faces, (k + 1) * kBlock); f < e; ++f) g(f);
          }
        };
        fn(l, h, for_faces);
      }
    }, 1);
  }
};
}  // namespace

void polygon_vertex_normals(const PolygonMesh& m, Vec3* out, int threads) {
  // Every vertex sums its faces' weighted normals in face order (as Blender's vertex-to-face
  // map orders them), so the result is the same on any number of threads: each thread owns a
  // range of vertices and walks the faces in order, adding only to its own vertices.
  std::fill(out, out + m.vertices, Vec3(0.0f));
  std::vector<uint8_t> used(m.vertices, 0);
  const OwnerRanges ranges(m, m.corner_verts, m.vertices, threads);
  if (!ranges.scattered) {
    ranges.run([&](uint32_t lo, uint32_t hi, const auto& for_faces) {
      std::vector<Vec3> scratch;
      for_faces([&](size_t f) { add_face_normal(m, f, lo, hi, out, used.data(), scratch); });
    });
  } else {
    // Vertices scattered over the faces: face normals and corner weights on all threads,
    // summed on one.
    std::vector<Vec3> fn;
    std::vector<float> weight;
    face_normals_and_weights(m, fn, weight, threads);
    for (size_t f = 0; f < m.faces; ++f)
      for (int32_t c = m.offsets[f]; c < m.offsets[f + 1]; ++c) {
        const int32_t v = m.corner_verts[c];
        out[v] += fn[f] * weight[size_t(c)];
        used[size_t(v)] = 1;
      }
  }
  parallel_ranges(m.vertices, threads, [&](size_t begin, size_t end) {
    for (size_t v = begin; v < end; ++v) out[v] = normalize_div(used[v] ? out[v] : m.positions[v]);
  });
}

void polygon_corner_normals(const PolygonMesh& m, const int32_t* corner_edges, size_t edges,
                            const uint8_t* sharp_edges, const uint8_t* sharp_faces, Vec3* out, int threads) {
  uint32_t largest = 0;  // as unsigned, negative edge indices are out of range too
  for (size_t c = 0; c < m.corners; ++c) largest = std::max(largest, uint32_t(corner_edges[c]));
  if (m.corners > 0 && size_t(largest) >= edges)
    for (size_t c = 0; c < m.corners; ++c)
      if (corner_edges[c] < 0 || size_t(corner_edges[c]) >= edges)
        throw std::invalid_argument("corner edge " + std::to_string(corner_edges[c]) + " out of range for " +
                                    std::to_string(edges) + " edges");
  std::vector<Vec3> fn;
  std::vector<float> weight;
  face_normals_and_weights(m, fn, weight, threads, true);
  // Big scratch arrays, each written before it is read: no serial initialisation.
  RawVector<uint32_t> face_of(m.corners), next(m.corners), parent(m.corners), count(m.corners);
  RawVector<Vec3> sum(m.corners);
  parallel_ranges(m.faces, threads, [&](size_t begin, size_t end) {
    for (size_t f = begin; f < end; ++f)
      for (int32_t c = m.offsets[f]; c < m.offsets[f + 1]; ++c) {
        face_of[size_t(c)] = uint32_t(f);
        next[size_t(c)] = uint32_t(c + 1 == m.offsets[f + 1] ? m.offsets[f] : c + 1);
        parent[size_t(c)] = uint32_t(c);
      }
  });
  // How many corners use each edge, and the first two (read only where exactly two do): threads
  // owning ranges of edges.
  RawVector<uint32_t> user0(edges), user1(edges), users(edges);
  parallel_ranges(edges, threads, [&](size_t begin, size_t end) { std::fill(users.begin() + begin, users.begin() + end, 0u); });
  OwnerRanges(m, corner_edges, edges, threads).run([&](uint32_t lo, uint32_t hi, const auto& for_faces) {
    for_faces([&](size_t f) {
      for (int32_t c = m.offsets[f]; c < m.offsets[f + 1]; ++c) {
        const uint32_t e = uint32_t(corner_edges[c]);
        if (e < lo || e >= hi) continue;
        if (users[e] == 0) user0[e] = uint32_t(c);
        else if (users[e] == 1) user1[e] = uint32_t(c);
        ++users[e];
      }
    });
  });
  // Corners joined across smooth edges share a fan (union-find). A fan's corners all use one
  // vertex, and each corner joins (at its own vertex) the corner after the edge's other user,
  // so threads that own ranges of vertices join and sum their own corners only; a fan's root is
  // its first corner and it sums its corners in order, whatever the split.
  const auto find = [&](uint32_t c) {
    while (parent[c] != c) c = parent[c] = parent[parent[c]];
    return c;
  };
  const auto join = [&](uint32_t a, uint32_t b) {
    a = find(a), b = find(b);
    if (a != b) parent[std::max(a, b)] = std::min(a, b);
  };
  OwnerRanges(m, m.corner_verts, m.vertices, threads).run([&](uint32_t lo, uint32_t hi, const auto& for_faces) {
    for_faces([&](size_t f) {
      for (int32_t ci = m.offsets[f]; ci < m.offsets[f + 1]; ++ci) {
        const uint32_t c = uint32_t(ci);
        const int32_t a = m.corner_verts[c];
        if (uint32_t(a) < lo || uint32_t(a) >= hi) continue;
        const size_t e = size_t(corner_edges[c]);
        if (users[e] != 2 || (sharp_edges && sharp_edges[e])) continue;
        const uint32_t o = user0[e] == c ? user1[e] : user0[e];  // the edge's other user
        const uint32_t f1 = face_of[c], f2 = face_of[o];
        if (f1 == f2 || (sharp_faces && (sharp_faces[f1] || sharp_faces[f2]))) continue;
        // Used in opposite directions (consistent winding), else the edge is sharp.
        if (m.corner_verts[o] != m.corner_verts[next[c]] || m.corner_verts[next[o]] != a) continue;
        join(c, next[o]);  // both at vertex a
      }
    });
    for_faces([&](size_t f) {
      for (int32_t ci = m.offsets[f]; ci < m.offsets[f + 1]; ++ci) {
        const uint32_t c = uint32_t(ci);
        if (uint32_t(m.corner_verts[c]) < lo || uint32_t(m.corner_verts[c]) >= hi) continue;
        const uint32_t r = parent[c] = find(c);  // every corner now points at its root
        if (r == c) {  // the root: its fan's first corner, so the first one summed here
          sum[r] = Vec3(0.0f);
          count[r] = 0;
        }
        sum[r] += fn[f] * weight[c];
        ++count[r];
      }
    });
  });
  parallel_ranges(m.corners, threads, [&](size_t begin, size_t end) {
    for (size_t c = begin; c < end; ++c) {
      const uint32_t r = parent[c];
      out[c] = count[r] == 1 ? fn[face_of[c]] : normalize_div(sum[r]);
    }
  });
}

}  // namespace pl
