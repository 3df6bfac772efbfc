// Catmull-Clark refinement with Blender's (OpenSubdiv's) rules, limit positions, and dicing of
// each patch with shared edge factors. Only the cage's topology is refined uniformly; the dicing
// density comes from the edge factors (docs/design/displacement.md#adaptive-subdivision).
#include "geometry/subdivide.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <unordered_map>

namespace pl {
namespace {

// One refinement level: faces as corner runs, each corner naming the edge to the next corner.
struct Level {
  std::vector<Vec3> p;
  std::vector<int32_t> fv, fo, fe;  // corner verts, face offsets, corner edges
  std::vector<int32_t> ev;          // 2 per edge
  std::vector<float> es;            // edge sharpness (OpenSubdiv units)
  std::vector<float> vs;            // vertex sharpness
  // Per face from level 1 on: its patch and its corners' integer grid positions in that patch.
  std::vector<int32_t> patch;
  std::vector<int32_t> cp;  // 8 per face: (x, y) of its 4 corners
  size_t faces() const { return fo.size() - 1; }
};

uint64_t edge_key(int32_t a, int32_t b) {
  if (a > b) std::swap(a, b);
  return (uint64_t(uint32_t(a)) << 32) | uint32_t(b);
}

enum class Rule { Smooth, Crease, Corner };

struct VertexRing {  // what the vertex rules read, gathered over a level
  std::vector<int32_t> valence, nfaces, sharp, child_sharp, transitions;
  std::vector<uint8_t> nonmanifold, boundary_corner;
  std::vector<Vec3> sum_fp, sum_mid, sum_sharp, sum_child_sharp;
  std::vector<float> transition_sum;
};

struct Refiner {
  const SubdivisionCage& cage;
  Level cur;
  size_t V0 = 0, E0 = 0, F0 = 0;
  std::vector<int32_t> efc;  // faces per edge at the current level

  explicit Refiner(const SubdivisionCage& c) : cage(c) {
    const PolygonMesh& m = c.mesh;
    V0 = m.vertices;
    F0 = m.faces;
    cur.p.assign(m.positions, m.positions + m.vertices);
    cur.fv.assign(m.corner_verts, m.corner_verts + m.corners);
    cur.fo.assign(m.offsets, m.offsets + m.faces + 1);
    cur.fe.resize(m.corners);
    std::unordered_map<uint64_t, int32_t> edges;
    edges.reserve(m.corners);
    for (size_t f = 0; f < m.faces; ++f) {
      const int32_t b = cur.fo[f], n = cur.fo[f + 1] - b;
      for (int32_t k = 0; k < n; ++k) {
        const int32_t a = cur.fv[b + k], z = cur.fv[b + (k + 1) % n];
        auto it = edges.emplace(edge_key(a, z), int32_t(cur.ev.size() / 2));
        if (it.second) cur.ev.insert(cur.ev.end(), {a, z});
        cur.fe[b + k] = it.first->second;
      }
    }
    E0 = cur.ev.size() / 2;
    cur.es.assign(E0, 0.0f);
    for (size_t i = 0; i < c.creases; ++i) {
      const int32_t a = c.crease_edges[2 * i], b = c.crease_edges[2 * i + 1];
      if (a < 0 || b < 0 || size_t(a) >= V0 || size_t(b) >= V0)
        throw std::invalid_argument("crease_edges name a vertex out of range");
      const float s = c.crease_sharpness[i];
      auto it = edges.find(edge_key(a, b));
      if (it != edges.end() && std::isfinite(s)) cur.es[it->second] = std::max(s, 0.0f);
    }
    cur.vs.assign(V0, 0.0f);
    if (c.vertex_sharpness)
      for (size_t v = 0; v < V0; ++v)
        cur.vs[v] = std::isfinite(c.vertex_sharpness[v]) ? std::max(c.vertex_sharpness[v], 0.0f) : 0.0f;
    // As Cycles (subd/osd.cpp): a vertex of two edges also gets the smaller of their sharpness.
    std::vector<int32_t> valence(V0, 0);
    std::vector<float> lowest(V0, kInf);
    for (size_t e = 0; e < E0; ++e)
      for (int k = 0; k < 2; ++k) {
        const int32_t v = cur.ev[2 * e + k];
        ++valence[v], lowest[v] = std::min(lowest[v], cur.es[e]);
      }
    for (size_t v = 0; v < V0; ++v)
      if (valence[v] == 2 && lowest[v] > 0.0f) cur.vs[v] = std::min(cur.vs[v] + lowest[v], 10.0f);
    count_edge_faces();
  }

  void count_edge_faces() {
    efc.assign(cur.ev.size() / 2, 0);
    for (int32_t e : cur.fe) ++efc[e];
  }

  bool edge_sharp(size_t e, float s) const { return efc[e] != 2 || s > 0.0f; }

  VertexRing ring(const std::vector<Vec3>& fp) const {
    const size_t V = cur.p.size(), E = cur.ev.size() / 2;
    VertexRing r;
    r.valence.assign(V, 0), r.nfaces.assign(V, 0), r.sharp.assign(V, 0), r.child_sharp.assign(V, 0);
    r.transitions.assign(V, 0), r.nonmanifold.assign(V, 0), r.boundary_corner.assign(V, 0);
    r.sum_fp.assign(V, Vec3(0.0f)), r.sum_mid.assign(V, Vec3(0.0f)), r.sum_sharp.assign(V, Vec3(0.0f));
    r.sum_child_sharp.assign(V, Vec3(0.0f)), r.transition_sum.assign(V, 0.0f);
    for (size_t e = 0; e < E; ++e) {
      const int32_t a = cur.ev[2 * e], b = cur.ev[2 * e + 1];
      const float s = cur.es[e];
      const bool sharp = edge_sharp(e, s), child = efc[e] != 2 || s > 1.0f;
      for (int k = 0; k < 2; ++k) {
        const int32_t v = k ? b : a, o = k ? a : b;
        ++r.valence[v];
        r.sum_mid[v] += (cur.p[v] + cur.p[o]) * 0.5f;
        if (efc[e] > 2) r.nonmanifold[v] = 1;
        if (sharp) ++r.sharp[v], r.sum_sharp[v] += cur.p[o];
        if (child) ++r.child_sharp[v], r.sum_child_sharp[v] += cur.p[o];
        if (sharp && !child) ++r.transitions[v], r.transition_sum[v] += s;
      }
    }
    for (size_t f = 0; f + 1 < cur.fo.size(); ++f)
      for (int32_t c = cur.fo[f]; c < cur.fo[f + 1]; ++c) {
        ++r.nfaces[cur.fv[c]];
        if (!fp.empty()) r.sum_fp[cur.fv[c]] += fp[f];
      }
    if (!cage.smooth_corners)  // PRESERVE_CORNERS: a boundary vertex of one face stays put
      for (size_t v = 0; v < V; ++v) r.boundary_corner[v] = r.nfaces[v] == 1 && r.valence[v] == 2;
    return r;
  }

  static Rule rule(int sharp_edges, float vertex_sharpness, bool corner) {
    if (corner || vertex_sharpness > 0.0f || sharp_edges > 2) return Rule::Corner;
    return sharp_edges == 2 ? Rule::Crease : Rule::Smooth;
  }

  void refine() {
    const size_t V = cur.p.size(), E = cur.ev.size() / 2, F = cur.faces();
    Level next;
    std::vector<Vec3> fp(F);
    for (size_t f = 0; f < F; ++f) {
      Vec3 s(0.0f);
      for (int32_t c = cur.fo[f]; c < cur.fo[f + 1]; ++c) s += cur.p[cur.fv[c]];
      fp[f] = s / float(cur.fo[f + 1] - cur.fo[f]);
    }
    std::vector<Vec3> efp(E, Vec3(0.0f));
    for (size_t f = 0; f < F; ++f)
      for (int32_t c = cur.fo[f]; c < cur.fo[f + 1]; ++c) efp[cur.fe[c]] += fp[f];
    next.p.resize(V + E + F);
    for (size_t e = 0; e < E; ++e) {
      const Vec3 a = cur.p[cur.ev[2 * e]], b = cur.p[cur.ev[2 * e + 1]], mid = (a + b) * 0.5f;
      const float s = cur.es[e];
      Vec3 q = mid;
      if (cage.catmull_clark && efc[e] == 2 && s < 1.0f) {
        const Vec3 smooth = (a + b + efp[e]) * 0.25f;
        q = smooth * (1.0f - s) + mid * s;
      }
      next.p[V + e] = q;
    }
    for (size_t f = 0; f < F; ++f) next.p[V + E + f] = fp[f];
    if (!cage.catmull_clark) {
      std::copy(cur.p.begin(), cur.p.end(), next.p.begin());
    } else {
      const VertexRing r = ring(fp);
      for (size_t v = 0; v < V; ++v) {
        const Vec3 P = cur.p[v];
        const int n = r.valence[v];
        if (n == 0) {
          next.p[v] = P;
          continue;
        }
        const bool corner = r.nonmanifold[v] || r.boundary_corner[v];
        const Rule pr = rule(r.sharp[v], cur.vs[v], corner);
        const Rule cr = rule(r.child_sharp[v], cur.vs[v] - 1.0f, corner);
        auto apply = [&](Rule k, const Vec3& sharp_sum) {
          if (k == Rule::Corner) return P;
          if (k == Rule::Crease) return (P * 6.0f + sharp_sum) * 0.125f;
          if (r.nfaces[v] != n) return P;  // (an open fan without boundary edges: cannot be smooth)
          return (r.sum_fp[v] / float(n) + r.sum_mid[v] * (2.0f / float(n)) + P * float(n - 3)) / float(n);
        };
        Vec3 q = apply(pr, r.sum_sharp[v]);
        if (pr != cr) {  // a semi-sharp feature fades out at this level: blend (OpenSubdiv)
          float sum = r.transition_sum[v];
          int count = r.transitions[v];
          if (cur.vs[v] > 0.0f && cur.vs[v] <= 1.0f) sum += cur.vs[v], ++count;
          const float w = count ? clampf(sum / float(count), 0.0f, 1.0f) : 1.0f;
          q = q * w + apply(cr, r.sum_child_sharp[v]) * (1.0f - w);
        }
        next.p[v] = q;
      }
    }
    // Topology: old edge e -> halves 2e (at ev[2e]) and 2e + 1; corner c's inner edge 2E + c.
    const size_t C = cur.fv.size();
    next.ev.resize(2 * (2 * E + C));
    next.es.resize(2 * E + C, 0.0f);
    for (size_t e = 0; e < E; ++e) {
      const int32_t m = int32_t(V + e);
      next.ev[4 * e] = cur.ev[2 * e], next.ev[4 * e + 1] = m;
      next.ev[4 * e + 2] = m, next.ev[4 * e + 3] = cur.ev[2 * e + 1];
      next.es[2 * e] = next.es[2 * e + 1] = std::max(cur.es[e] - 1.0f, 0.0f);
    }
    next.vs.assign(V + E + F, 0.0f);
    for (size_t v = 0; v < V; ++v) next.vs[v] = std::max(cur.vs[v] - 1.0f, 0.0f);
    next.fv.resize(4 * C), next.fe.resize(4 * C), next.fo.resize(C + 1);
    next.patch.resize(C), next.cp.resize(8 * C);
    const bool first = cur.patch.empty();
    for (size_t f = 0; f < F; ++f) {
      const int32_t b = cur.fo[f], n = cur.fo[f + 1] - b;
      for (int32_t j = 0; j < n; ++j) {
        const int32_t c = b + j, cprev = b + (j + n - 1) % n;
        const int32_t ej = cur.fe[c], ep = cur.fe[cprev], v = cur.fv[c];
        const int32_t fp_id = int32_t(V + E + f);
        int32_t* q = &next.fv[4 * c];
        q[0] = v, q[1] = int32_t(V + ej), q[2] = fp_id, q[3] = int32_t(V + ep);
        int32_t* qe = &next.fe[4 * c];
        qe[0] = cur.ev[2 * ej] == v ? 2 * ej : 2 * ej + 1;
        qe[1] = int32_t(2 * E + c);
        qe[2] = int32_t(2 * E + cprev);
        qe[3] = cur.ev[2 * ep] == v ? 2 * ep : 2 * ep + 1;
        next.ev[2 * (2 * E + c)] = int32_t(V + ej), next.ev[2 * (2 * E + c) + 1] = fp_id;
        next.fo[c] = int32_t(4 * c);
        int32_t* g = &next.cp[8 * c];
        if (first) {  // filled in by start_patches
          next.patch[c] = -1;
          continue;
        }
        const int32_t* pc = &cur.cp[8 * f];  // parent is a quad (levels >= 1)
        auto mid = [&](int a, int z, int axis) { return (pc[2 * a + axis] + pc[2 * z + axis]) / 2; };
        const int jn = (j + 1) % 4, jp = (j + 3) % 4;
        g[0] = pc[2 * j], g[1] = pc[2 * j + 1];
        g[2] = mid(j, jn, 0), g[3] = mid(j, jn, 1);
        g[4] = (pc[0] + pc[2] + pc[4] + pc[6]) / 4, g[5] = (pc[1] + pc[3] + pc[5] + pc[7]) / 4;
        g[6] = mid(jp, j, 0), g[7] = mid(jp, j, 1);
        next.patch[c] = cur.patch[f];
      }
    }
    next.fo[C] = int32_t(4 * C);
    cur = std::move(next);
    count_edge_faces();
  }

  // Limit positions of the current level's vertices (all faces quads).
  std::vector<Vec3> limit() const {
    if (!cage.catmull_clark) return cur.p;
    const VertexRing r = ring({});
    const size_t V = cur.p.size();
    std::vector<Vec3> diag(V, Vec3(0.0f)), nb(V, Vec3(0.0f));
    for (size_t f = 0; f < cur.faces(); ++f) {
      const int32_t b = cur.fo[f];
      for (int k = 0; k < 4; ++k) diag[cur.fv[b + k]] += cur.p[cur.fv[b + (k + 2) % 4]];
    }
    for (size_t e = 0; e < cur.ev.size() / 2; ++e) {
      nb[cur.ev[2 * e]] += cur.p[cur.ev[2 * e + 1]];
      nb[cur.ev[2 * e + 1]] += cur.p[cur.ev[2 * e]];
    }
    std::vector<Vec3> out(V);
    for (size_t v = 0; v < V; ++v) {
      const Vec3 P = cur.p[v];
      const int n = r.valence[v];
      const Rule k = rule(r.sharp[v], cur.vs[v], r.nonmanifold[v] || r.boundary_corner[v]);
      if (n == 0 || k == Rule::Corner || (k == Rule::Smooth && r.nfaces[v] != n))
        out[v] = P;
      else if (k == Rule::Crease)
        out[v] = (P * 4.0f + r.sum_sharp[v]) / 6.0f;
      else
        out[v] = (P * float(n * n) + nb[v] * 4.0f + diag[v]) / float(n * (n + 5));
    }
    return out;
  }
};

struct Patch {
  int32_t face, sub, n;  // cage face, sub-patch (n-gon corner), grid segments per side
  size_t grid;           // offset of its (n + 1)^2 vertex ids
};

Vec3 side_uv(int k, float s, float r) {  // side k's (along, inward) -> patch (u, v)
  switch (k) {
    case 0: return {s, r, 0.0f};
    case 1: return {1.0f - r, s, 0.0f};
    case 2: return {1.0f - s, 1.0f - r, 0.0f};
    default: return {r, 1.0f - s, 0.0f};
  }
}

}  // namespace

namespace {

// How far camera-space p (x right, y up, z forward) lies outside the view, as Cycles measures it:
// perspective, the largest distance past one of the four side planes it is in front of (the
// distance to the apex where it is behind one's back edge); orthographic, the distance to the
// view's box (z >= 0) over the half diagonal's RMS side.
float offscreen_distance(const DicingCamera& cam, Vec3 p) {
  const float l = cam.frame[0], r = cam.frame[1], b = cam.frame[2], t = cam.frame[3];
  if (cam.ortho) {
    const Vec3 c{clampf(p.x, l, r), clampf(p.y, b, t), std::max(p.z, 0.0f)};
    return length(p - c) / std::sqrt(0.5f * (r * r + t * t));
  }
  const Vec3 n[4] = {normalize(Vec3{1, 0, -r}), normalize(Vec3{-1, 0, l}), normalize(Vec3{0, 1, -t}),
                     normalize(Vec3{0, -1, b})};  // right, left, top, bottom: outward
  const Vec3 along[4] = {{-n[0].z, 0, n[0].x}, {n[1].z, 0, -n[1].x}, {0, -n[2].z, n[2].y}, {0, n[3].z, -n[3].y}};
  float d[4];
  bool inside = true, behind = true;
  for (int i = 0; i < 4; ++i) {
    d[i] = dot(p, n[i]);
    inside = inside && d[i] <= 0.0f;
    behind = behind && d[i] > 0.0f;
  }
  if (inside) return 0.0f;
  if (behind) return length(p);
  float f = 0.0f;
  bool apex = false;
  for (int i = 0; i < 4; ++i) {
    if (d[i] <= 0.0f) continue;
    if (dot(p, along[i]) >= 0.0f) f = std::max(f, d[i]);
    else apex = true;  // past this side's back edge: the apex may be nearer
  }
  if (apex) f = f > 0.0f ? std::min(f, length(p)) : length(p);
  return f;
}

}  // namespace

float dicing_pixel_size(const DicingCamera& cam, Vec3 wp) {
  const Vec3 v = wp - cam.position;
  const float dist = length(v);
  float w = cam.ortho ? cam.pixel_size : dist * cam.pixel_size;
  if (cam.offscreen_scale > 1.0f) {
    const Vec3 p{dot(v, cam.right), dot(v, cam.up), dot(v, cam.forward)};
    const float f = offscreen_distance(cam, p);
    // Cycles: ortho res *= 1 + f (s - 1); perspective res += (pixel per unit distance) f (s - 1).
    if (f > 0.0f) w += (cam.ortho ? w : cam.pixel_size) * f * (cam.offscreen_scale - 1.0f);
  }
  return std::max(w, 1e-12f);
}

DicedMesh subdivide_and_dice(const SubdivisionCage& cage, const DicingCamera& cam) {
  DicedMesh out;
  const PolygonMesh& m = cage.mesh;
  if (m.faces == 0) return out;
  Refiner R(cage);
  const size_t V0 = R.V0, E0 = R.E0, F0 = R.F0;
  const std::vector<int32_t> fo0 = R.cur.fo, fv0 = R.cur.fv, fe0 = R.cur.fe, ev0 = R.cur.ev;
  std::vector<uint8_t> ngon_edge(E0, 0);
  for (size_t f = 0; f < F0; ++f)
    if (fo0[f + 1] - fo0[f] != 4)
      for (int32_t c = fo0[f]; c < fo0[f + 1]; ++c) ngon_edge[fe0[c]] = 1;

  const int max_level = std::max(0, std::min(cam.max_level, 12));
  // Patches: a cage quad is one, an n-gon n (one per corner, as Cycles splits them).
  std::vector<Patch> patches;
  std::vector<int32_t> face_patch(F0);
  for (size_t f = 0; f < F0; ++f) {
    face_patch[f] = int32_t(patches.size());
    const int32_t n = fo0[f + 1] - fo0[f];
    if (n == 4) patches.push_back({int32_t(f), 0, 0, 0});
    else
      for (int32_t j = 0; j < n; ++j) patches.push_back({int32_t(f), j, 0, 0});
  }
  // Grid positions live at scale 2^L for quads (2^(L-1) for n-gon sub-patches); `start` labels
  // the level-1 faces once the final level is known.
  auto start_patches = [&](Level& l1, int L) {
    const int32_t S = 1 << L, Sh = S / 2;
    for (size_t f = 0; f < F0; ++f) {
      const int32_t b = fo0[f], n = fo0[f + 1] - b;
      for (int32_t j = 0; j < n; ++j) {
        int32_t* g = &l1.cp[8 * (b + j)];
        if (n == 4) {
          const int32_t cx[4] = {0, S, S, 0}, cy[4] = {0, 0, S, S};
          const int jn = (j + 1) % 4, jp = (j + 3) % 4;
          g[0] = cx[j], g[1] = cy[j], g[2] = (cx[j] + cx[jn]) / 2, g[3] = (cy[j] + cy[jn]) / 2;
          g[4] = Sh, g[5] = Sh, g[6] = (cx[jp] + cx[j]) / 2, g[7] = (cy[jp] + cy[j]) / 2;
          l1.patch[b + j] = face_patch[f];
        } else {
          const int32_t h = Sh;  // the sub-patch's own grid, scale 2^(L-1)
          g[0] = 0, g[1] = 0, g[2] = h, g[3] = 0, g[4] = h, g[5] = h, g[6] = 0, g[7] = h;
          l1.patch[b + j] = face_patch[f] + j;
        }
      }
    }
  };

  auto pixel = [&](Vec3 wp) { return dicing_pixel_size(cam, wp); };
  std::vector<Vec3> lim;
  std::vector<int32_t> grid;
  auto build_grids = [&](int L) {
    size_t total = 0;
    for (Patch& p : patches) {
      const int32_t n = fo0[p.face + 1] - fo0[p.face];
      p.n = n == 4 ? (1 << L) : (1 << (L - 1));
      p.grid = total;
      total += size_t(p.n + 1) * size_t(p.n + 1);
    }
    grid.assign(total, -1);
    const Level& l = R.cur;
    for (size_t f = 0; f < l.faces(); ++f) {
      const Patch& p = patches[l.patch[f]];
      for (int k = 0; k < 4; ++k) {
        const int32_t x = l.cp[8 * f + 2 * k], y = l.cp[8 * f + 2 * k + 1];
        grid[p.grid + size_t(y) * (p.n + 1) + x] = l.fv[l.fo[f] + k];
      }
    }
    lim = R.limit();
  };
  auto eval = [&](int32_t pi, float u, float v) {
    const Patch& p = patches[pi];
    const float x = clampf(u, 0.0f, 1.0f) * p.n, y = clampf(v, 0.0f, 1.0f) * p.n;
    const int i = std::min(int(x), p.n - 1), j = std::min(int(y), p.n - 1);
    const float fx = x - i, fy = y - j;
    const int32_t* g = &grid[p.grid];
    const int32_t w = p.n + 1;
    const Vec3 a = lim[g[j * w + i]], b = lim[g[j * w + i + 1]], c = lim[g[(j + 1) * w + i]],
               d = lim[g[(j + 1) * w + i + 1]];
    return (a * (1 - fx) + b * fx) * (1 - fy) + (c * (1 - fx) + d * fx) * fy;
  };
  // Base edge e at t (from ev[2e] to ev[2e + 1]), on the first face that uses it.
  std::vector<int32_t> edge_corner(E0, -1);
  for (size_t f = 0; f < F0; ++f)
    for (int32_t c = fo0[f]; c < fo0[f + 1]; ++c)
      if (edge_corner[fe0[c]] < 0) edge_corner[fe0[c]] = c;
  std::vector<int32_t> corner_face(fv0.size());
  for (size_t f = 0; f < F0; ++f)
    for (int32_t c = fo0[f]; c < fo0[f + 1]; ++c) corner_face[c] = int32_t(f);
  auto eval_edge = [&](size_t e, float t) {
    const int32_t c = edge_corner[e], f = corner_face[c], b = fo0[f], n = fo0[f + 1] - b, j = c - b;
    const float s = fv0[c] == ev0[2 * e] ? t : 1.0f - t;
    if (n == 4) {
      const Vec3 uv = side_uv(j, s, 0.0f);
      return eval(face_patch[f], uv.x, uv.y);
    }
    if (s <= 0.5f) return eval(face_patch[f] + j, 2.0f * s, 0.0f);
    const Vec3 uv = side_uv(3, 2.0f * s - 1.0f, 0.0f);
    return eval(face_patch[f] + (j + 1) % n, uv.x, uv.y);
  };
  auto spoke_point = [&](int32_t f, int32_t j, float t) {  // m_j -> centre: sub-patch j's side 1
    const Vec3 uv = side_uv(1, t, 0.0f);
    return eval(face_patch[f] + j, uv.x, uv.y);
  };
  // DiagSplit::T: three samples, lengths in pixels, the larger estimate.
  auto factor = [&](auto&& point) {
    float lsum = 0.0f, lmax = 0.0f;
    Vec3 last = cam.to_world.point(point(0.0f));
    for (int i = 1; i < 3; ++i) {
      const Vec3 P = cam.to_world.point(point(0.5f * i));
      const float l = length(P - last) / pixel((P + last) * 0.5f);
      lsum += l, lmax = std::max(lmax, l);
      last = P;
    }
    const float rate = std::max(cam.dicing_rate, 1e-3f);
    const float t = std::max(std::ceil(lsum / rate), std::ceil(2.0f * lmax / rate));
    return int(std::min(std::max(t, 1.0f), float(1 << max_level)));
  };
  std::vector<int32_t> spoke_first(F0, -1);
  size_t spokes = 0;
  for (size_t f = 0; f < F0; ++f)
    if (fo0[f + 1] - fo0[f] != 4) spoke_first[f] = int32_t(spokes), spokes += fo0[f + 1] - fo0[f];
  std::vector<int32_t> TE(E0), TS(spokes);
  auto measure = [&]() {
    int tmax = 1;
    for (size_t e = 0; e < E0; ++e) {
      int t;
      if (ngon_edge[e]) {
        t = factor([&](float x) { return eval_edge(e, x); });
        t = std::max(2, t + (t & 1));  // halves for the n-gon's sub-patches
      } else {
        // Cycles 4.5 splits every quad in both directions first (as n-gons), so each half of
        // a quad's edge gets its own factor: at least 2 segments, finer where halves round up.
        // (Cycles' limit_edge_factor: a half may have half of 2^max_subdivisions.)
        const int half_cap = std::max(1, (1 << max_level) / 2);
        t = std::min(factor([&](float x) { return eval_edge(e, 0.5f * x); }), half_cap) +
            std::min(factor([&](float x) { return eval_edge(e, 0.5f + 0.5f * x); }), half_cap);
      }
      TE[e] = t, tmax = std::max(tmax, ngon_edge[e] ? t / 2 : t);
    }
    for (size_t f = 0; f < F0; ++f)
      for (int32_t j = 0; spoke_first[f] >= 0 && j < fo0[f + 1] - fo0[f]; ++j) {
        const int t = factor([&](float x) { return spoke_point(int32_t(f), j, x); });
        TS[spoke_first[f] + j] = t, tmax = std::max(tmax, t);
      }
    return tmax;
  };
  // Level 1 (every face split into quads), an estimate of the factors at level 2, then the level
  // whose grid is at least as fine as the largest factor.
  const size_t corners = fv0.size();
  auto fits = [&](int L) { return corners * (size_t(1) << (2 * (L - 1))) <= cam.max_quads; };
  int L = 1;
  R.refine();
  const int Lest = fits(2) && max_level >= 2 ? 2 : 1;
  start_patches(R.cur, Lest);
  for (; L < Lest; ++L) R.refine();
  build_grids(L);
  int want = 1;
  const int estimate = measure();
  while ((1 << want) < estimate && want < max_level) ++want;
  if (want < max_level) {
    // (n-gon sub-patches have half the segments: one level more where there are n-gons)
    for (size_t f = 0; f < F0; ++f)
      if (spoke_first[f] >= 0) {
        ++want;
        break;
      }
  }
  int target = std::max(1, std::min(want, max_level));
  while (target > L && !fits(target)) --target, out.capped = true;
  if (target > L) {
    // Relabel from level 1: grid scales change with the level.
    Refiner again(cage);
    again.refine();
    start_patches(again.cur, target);
    for (int k = 1; k < target; ++k) again.refine();
    R.cur = std::move(again.cur);
    R.efc = std::move(again.efc);
    L = target;
    build_grids(L);
  }
  out.level = L;
  out.max_edge_factor = measure();

  // Output vertices: cage vertices, then each edge's and spoke's inner points, n-gon centres.
  std::vector<Vec3>& P = out.positions;
  P.assign(lim.begin(), lim.begin() + V0);
  std::vector<std::vector<int32_t>> edge_ids(E0), spoke_ids(spokes);
  for (size_t e = 0; e < E0; ++e) {
    auto& ids = edge_ids[e];
    ids.push_back(ev0[2 * e]);
    for (int k = 1; k < TE[e]; ++k) ids.push_back(int32_t(P.size())), P.push_back(eval_edge(e, float(k) / TE[e]));
    ids.push_back(ev0[2 * e + 1]);
  }
  std::vector<int32_t> centre(F0, -1);
  for (size_t f = 0; f < F0; ++f) {
    if (spoke_first[f] < 0) continue;
    centre[f] = int32_t(P.size());
    P.push_back(eval(face_patch[f], 1.0f, 1.0f));
    const int32_t b = fo0[f], n = fo0[f + 1] - b;
    for (int32_t j = 0; j < n; ++j) {
      const auto& eids = edge_ids[fe0[b + j]];
      auto& ids = spoke_ids[spoke_first[f] + j];
      const int t = TS[spoke_first[f] + j];
      ids.push_back(eids[eids.size() / 2]);
      for (int k = 1; k < t; ++k) ids.push_back(int32_t(P.size())), P.push_back(spoke_point(int32_t(f), j, float(k) / t));
      ids.push_back(centre[f]);
    }
  }
  // A cage edge's points from corner vertex `from`.
  auto oriented = [&](int32_t e, int32_t from) {
    std::vector<int32_t> ids = edge_ids[e];
    if (ids.front() != from) std::reverse(ids.begin(), ids.end());
    return ids;
  };
  auto side = [&](const Patch& p, int k) {
    const int32_t b = fo0[p.face], n = fo0[p.face + 1] - b;
    if (n == 4) return oriented(fe0[b + k], fv0[b + k]);
    const int32_t j = p.sub, jp = (j + n - 1) % n;
    if (k == 0) {
      auto ids = oriented(fe0[b + j], fv0[b + j]);
      ids.resize(ids.size() / 2 + 1);
      return ids;
    }
    if (k == 3) {
      auto ids = oriented(fe0[b + jp], fv0[b + jp]);
      return std::vector<int32_t>(ids.begin() + ids.size() / 2, ids.end());
    }
    if (k == 1) return spoke_ids[spoke_first[p.face] + j];
    auto ids = spoke_ids[spoke_first[p.face] + jp];
    std::reverse(ids.begin(), ids.end());
    return ids;
  };
  auto emit = [&](const Patch& p, int32_t a, Vec3 ua, int32_t b, Vec3 ub, int32_t c, Vec3 uc) {
    out.triangles.insert(out.triangles.end(), {a, b, c});
    out.tri_face.push_back(p.face);
    out.tri_sub.push_back(p.sub);
    out.tri_uv.insert(out.tri_uv.end(), {ua.x, ua.y, ub.x, ub.y, uc.x, uc.y});
  };
  for (const Patch& p : patches) {
    std::vector<int32_t> sides[4];
    int T[4];
    for (int k = 0; k < 4; ++k) sides[k] = side(p, k), T[k] = int(sides[k].size()) - 1;
    const int32_t pi = int32_t(&p - patches.data());
    const Vec3 c00(0, 0, 0), c10(1, 0, 0), c11(1, 1, 0), c01(0, 1, 0);
    if (T[0] == 1 && T[1] == 1 && T[2] == 1 && T[3] == 1) {
      emit(p, sides[0][0], c00, sides[1][0], c10, sides[2][0], c11);
      emit(p, sides[0][0], c00, sides[2][0], c11, sides[3][0], c01);
      continue;
    }
    const int Mu = std::max({2, T[0], T[2]}), Mv = std::max({2, T[1], T[3]});
    std::vector<int32_t> inner(size_t(Mu + 1) * (Mv + 1), -1);
    auto in_id = [&](int i, int j) -> int32_t& { return inner[size_t(j) * (Mu + 1) + i]; };
    for (int j = 1; j < Mv; ++j)
      for (int i = 1; i < Mu; ++i) {
        in_id(i, j) = int32_t(P.size());
        P.push_back(eval(pi, float(i) / Mu, float(j) / Mv));
      }
    auto uv_of = [&](int i, int j) { return Vec3(float(i) / Mu, float(j) / Mv, 0.0f); };
    for (int j = 1; j + 1 < Mv; ++j)
      for (int i = 1; i + 1 < Mu; ++i) {
        emit(p, in_id(i, j), uv_of(i, j), in_id(i + 1, j), uv_of(i + 1, j), in_id(i + 1, j + 1), uv_of(i + 1, j + 1));
        emit(p, in_id(i, j), uv_of(i, j), in_id(i + 1, j + 1), uv_of(i + 1, j + 1), in_id(i, j + 1), uv_of(i, j + 1));
      }
    for (int k = 0; k < 4; ++k) {
      // The inner row along side k, in the side's direction: (grid i, grid j, along-side s).
      std::vector<int32_t> ids;
      std::vector<Vec3> uvs;
      std::vector<float> si;
      const int along = (k % 2 == 0) ? Mu : Mv;
      for (int q = 1; q < along; ++q) {
        int i, j;
        if (k == 0) i = q, j = 1;
        else if (k == 1) i = Mu - 1, j = q;
        else if (k == 2) i = Mu - q, j = Mv - 1;
        else i = 1, j = Mv - q;
        ids.push_back(in_id(i, j)), uvs.push_back(uv_of(i, j)), si.push_back(float(q) / along);
      }
      const auto& O = sides[k];
      const int n = int(O.size()) - 1, mm = int(ids.size()) - 1;
      auto ouv = [&](int i) { return side_uv(k, float(i) / n, 0.0f); };
      int i = 0, j = 0;
      while (i < n || j < mm) {
        const bool outer = j == mm || (i < n && float(2 * i + 1) / n < si[j] + si[j + 1]);
        if (outer) emit(p, O[i], ouv(i), O[i + 1], ouv(i + 1), ids[j], uvs[j]), ++i;
        else emit(p, O[i], ouv(i), ids[j + 1], uvs[j + 1], ids[j], uvs[j]), ++j;
      }
    }
  }
  return out;
}

}  // namespace pl
