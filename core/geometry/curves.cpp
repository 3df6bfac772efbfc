#include "geometry/curves.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>

#include "geometry/bvh_common.h"

namespace pl {
namespace {

// Hits closer than this fraction of the piece's radius are taken for the surface the ray left
// (a ray spawned on the outside that grazes it): a bias of 1e-4 radii at most.
constexpr float kSelfFraction = 1e-4f;

// The entering hit of a sphere (centre q, radius r): the near root, computed from the ray's
// closest approach to q so the error does not grow with the distance (Haines et al., Ray
// Tracing Gems ch. 7).
inline bool sphere_entry(const Vec3& q, float r, const Vec3& org, const Vec3& dir, float dd, float& t) {
  if (!(r > 0.0f)) return false;
  const Vec3 w = org - q;
  const float tc = -dot(w, dir) / dd;
  const Vec3 l = w + dir * tc;
  const float disc = r * r - dot(l, l);
  if (!(disc >= 0.0f)) return false;
  t = tc - std::sqrt(disc / dd);
  return true;
}

float max_radius(const CurvePiece& c) { return std::max(c.r0, c.r1); }

}  // namespace

bool intersect_piece(const CurvePiece& c, const Vec3& org, const Vec3& dir, float tmax, float& t_out, float& u_out) {
  const float dd = dot(dir, dir);
  if (!(dd > 0.0f)) return false;
  const float tmin = kSelfFraction * std::min(c.r0 > 0.0f ? c.r0 : c.r1, c.r1 > 0.0f ? c.r1 : c.r0) / std::sqrt(dd);
  bool found = false;
  float best = tmax;
  const Vec3 axis = c.p1 - c.p0;
  const float len2 = dot(axis, axis);
  if (len2 > 0.0f) {
    // The cone frustum, solved about the ray's closest approach to the piece's centre.
    const float len = std::sqrt(len2);
    const Vec3 ah = axis / len;
    const float k = (c.r1 - c.r0) / len;  // radius change per unit length along the axis
    const float t0 = dot((c.p0 + c.p1) * 0.5f - org, dir) / dd;
    const Vec3 w = org + dir * t0 - c.p0;
    const float ws = dot(w, ah), ds = dot(dir, ah);
    const Vec3 wp = w - ah * ws, dp = dir - ah * ds;
    const float rr = c.r0 + k * ws;
    const float A = dot(dp, dp) - k * k * ds * ds;
    const float B = dot(wp, dp) - k * ds * rr;
    const float C = dot(wp, wp) - rr * rr;
    const float disc = B * B - A * C;
    if (A > 1e-12f * dd && disc >= 0.0f) {
      // Near root without cancellation: (-B - sqrt) / A or C / (-B + sqrt).
      const float sq = std::sqrt(disc);
      const float tl = B > 0.0f ? -(B + sq) / A : C / (sq - B);
      const float s = ws + tl * ds;
      const float t = t0 + tl;
      if (s >= 0.0f && s <= len && c.r0 + k * s > 0.0f && t > tmin && t < best) {
        best = t;
        u_out = s / len;
        found = true;
      }
    }
  }
  float t;
  const Vec3 ah = len2 > 0.0f ? axis / std::sqrt(len2) : Vec3(0.0f);
  if (c.root && sphere_entry(c.p0, c.r0, org, dir, dd, t) && t > tmin && t < best) {
    const Vec3 x = org + dir * t - c.p0;
    if (dot(x, ah) <= 0.0f) {  // the half beyond the root disc
      best = t;
      u_out = 0.0f;
      found = true;
    }
  }
  if (sphere_entry(c.p1, c.r1, org, dir, dd, t) && t > tmin && t < best) {
    const Vec3 x = org + dir * t - c.p1;
    if (dot(x, ah) >= 0.0f && dot(x, c.next) <= 0.0f) {  // the wedge no cone covers
      best = t;
      u_out = 1.0f;
      found = true;
    }
  }
  if (found) t_out = best;
  return found;
}

namespace {
Vec3 piece_tangent(const CurvePiece& c, float& len) {
  const Vec3 axis = c.p1 - c.p0;
  len = length(axis);
  return len > 0.0f && std::isfinite(len) ? axis / len : Vec3(0.0f, 0.0f, 1.0f);
}
}  // namespace

void encode_piece_hit(const CurvePiece& c, Vec3 p, float u, float& b1, float& b2) {
  float len;
  const Vec3 tg = piece_tangent(c, len);
  Vec3 bx, by;
  make_basis(tg, bx, by);
  const bool cap = u <= 0.0f || u >= 1.0f || !(len > 0.0f);
  const Vec3 q = cap ? (u >= 1.0f ? c.p1 : c.p0) : c.p0 + (c.p1 - c.p0) * u;
  const Vec3 d = p - q;
  b2 = std::atan2(dot(d, by), dot(d, bx));
  if (!std::isfinite(b2)) b2 = 0.0f;
  if (!cap) {
    b1 = u;
    return;
  }
  const float dl = length(d);
  float z = dl > 0.0f ? clampf(dot(d, tg) / dl, -1.0f, 1.0f) : 0.0f;
  if (!std::isfinite(z)) z = 0.0f;
  b1 = u >= 1.0f ? 3.0f + z : -2.0f - z;
}

void piece_surface(const CurvePiece& c, float b1, float b2, Vec3& n, Vec3& tangent, Vec3& p, Vec3& error, float& u) {
  float len;
  tangent = piece_tangent(c, len);
  Vec3 bx, by;
  make_basis(tangent, bx, by);
  const Vec3 rhat = bx * std::cos(b2) + by * std::sin(b2);
  if (b1 >= 0.0f && b1 <= 1.0f) {
    u = b1;
    const float k = len > 0.0f ? (c.r1 - c.r0) / len : 0.0f;
    n = normalize(rhat - tangent * k);  // the cone's slope tilts it
    p = c.p0 + (c.p1 - c.p0) * u + rhat * (c.r0 + (c.r1 - c.r0) * u);
  } else {
    const bool end = b1 > 1.0f;
    u = end ? 1.0f : 0.0f;
    const float z = clampf(end ? b1 - 3.0f : -2.0f - b1, -1.0f, 1.0f);
    n = normalize(rhat * std::sqrt(std::max(0.0f, 1.0f - z * z)) + tangent * z);
    p = (end ? c.p1 : c.p0) + n * (end ? c.r1 : c.r0);
  }
  // The point's own rounding and the intersector's: coordinates of magnitude |p| and lengths of
  // the piece's size enter every term. Far below the kSelfFraction guard of a radius.
  const float scale = max_component(vabs(p)) + max_radius(c) + len;
  error = Vec3(scale * gamma_bound(64));
}

CurveCutStats cut_curves(const CurveInput& in, const Mat4& to_world, uint32_t curve_base, std::vector<CurvePiece>& out,
                         std::vector<uint32_t>* kept) {
  CurveCutStats st;
  if (in.n_curves == 0) return st;
  if (!in.offsets || in.offsets[0] != 0 || size_t(in.offsets[in.n_curves]) != in.n_points)
    throw std::invalid_argument("curve offsets must start at 0 and end at the number of points");
  for (size_t c = 0; c < in.n_curves; ++c)
    if (in.offsets[c + 1] < in.offsets[c]) throw std::invalid_argument("curve offsets must not decrease");
  const Vec3 c0{to_world.m[0][0], to_world.m[1][0], to_world.m[2][0]}, c1{to_world.m[0][1], to_world.m[1][1], to_world.m[2][1]},
      c2{to_world.m[0][2], to_world.m[1][2], to_world.m[2][2]};
  // Radii scale with the transform's mean scale (exact for uniform scales, as Cycles applies
  // an object's scale to curve radii).
  const float det = dot(c0, cross(c1, c2));
  const float rscale = std::cbrt(std::fabs(det));
  const int sub = in.type == CurveType::CatmullRom ? std::max(1, std::min(in.subdivisions, 64)) : 1;
  std::vector<Vec3> p;
  std::vector<float> r, v;
  for (size_t c = 0; c < in.n_curves; ++c) {
    const size_t b = size_t(in.offsets[c]), e = size_t(in.offsets[c + 1]), n = e - b;
    bool ok = n >= 2 && std::isfinite(rscale) && rscale > 0.0f;
    float rmax = 0.0f, total = 0.0f;
    p.resize(n);
    r.resize(n);
    v.resize(n);
    for (size_t i = 0; i < n && ok; ++i) {
      p[i] = to_world.point(in.points[b + i]);
      r[i] = in.radii ? in.radii[b + i] * rscale : 0.005f * rscale;
      ok = is_finite(p[i]) && std::isfinite(r[i]) && max_component(vabs(p[i])) < 1e30f;
      r[i] = std::max(r[i], 0.0f);
      rmax = std::max(rmax, r[i]);
      if (i > 0) total += length(p[i] - p[i - 1]);
      v[i] = total;
    }
    if (!ok || !(rmax > 0.0f) || !(total > 0.0f) || !std::isfinite(total)) {
      ++st.skipped;
      continue;
    }
    for (size_t i = 0; i < n; ++i) v[i] /= total;
    const uint32_t id = curve_base + uint32_t(st.curves++);
    if (kept) kept->push_back(uint32_t(c));
    size_t last = SIZE_MAX;  // this strand's previous piece, while they join
    const auto push = [&](const CurvePiece& pc) {
      if (last != SIZE_MAX) {
        float l;
        out[last].next = piece_tangent(pc, l);
      }
      out.push_back(pc);
      out.back().root = last == SIZE_MAX;
      last = out.size() - 1;
    };
    for (size_t k = 0; k + 1 < n; ++k) {
      const size_t a = k > 0 ? k - 1 : 0, d = std::min(k + 2, n - 1);
      Vec3 prev = p[k];
      float prev_r = r[k], prev_v = v[k];
      for (int j = 1; j <= sub; ++j) {
        const float t = float(j) / float(sub);
        Vec3 q;
        float rq;
        if (j == sub) {  // the key itself, exactly: neighbouring segments share it
          q = p[k + 1];
          rq = r[k + 1];
        } else {
          q = catmull_rom(p[a], p[k], p[k + 1], p[d], t);
          rq = std::max(0.0f, catmull_rom(r[a], r[k], r[k + 1], r[d], t));
        }
        const float vq = v[k] + (v[k + 1] - v[k]) * t;
        if (prev_r > 0.0f || rq > 0.0f) {
          CurvePiece pc;
          pc.p0 = prev;
          pc.p1 = q;
          pc.r0 = prev_r;
          pc.r1 = rq;
          pc.curve = id;
          pc.v0 = prev_v;
          pc.v1 = vq;
          push(pc);
        } else {
          last = SIZE_MAX;  // a gap of zero radius: the next piece starts a new run
        }
        prev = q;
        prev_r = rq;
        prev_v = vq;
      }
    }
  }
  return st;
}

namespace {
constexpr int kBins = 16;
constexpr uint32_t kLeafSize = 4;

Aabb piece_box(const CurvePiece& c) {
  Aabb b;
  b.grow(c.p0 - Vec3(c.r0));
  b.grow(c.p0 + Vec3(c.r0));
  b.grow(c.p1 - Vec3(c.r1));
  b.grow(c.p1 + Vec3(c.r1));
  // Grown by a little more than the rounding of the hit test's coordinates.
  const Vec3 pad = (vabs(b.lo) + vabs(b.hi)) * gamma_bound(4);
  b.lo = b.lo - pad;
  b.hi = b.hi + pad;
  return b;
}
}  // namespace

void CurveBvh::build(std::vector<CurvePiece> pieces) {
  nodes_.clear();
  pieces_.clear();
  if (pieces.empty()) return;
  const size_t n = pieces.size();
  std::vector<Aabb> boxes(n);
  std::vector<Vec3> centers(n);
  std::vector<uint32_t> refs(n);
  for (size_t i = 0; i < n; ++i) {
    boxes[i] = piece_box(pieces[i]);
    centers[i] = boxes[i].center();
    refs[i] = uint32_t(i);
  }
  struct Task {
    uint32_t node, begin, end;
    int depth;
  };
  nodes_.reserve(2 * n / kLeafSize + 1);
  nodes_.emplace_back();
  std::vector<Task> todo{{0, 0, uint32_t(n), 0}};
  while (!todo.empty()) {
    const Task tk = todo.back();
    todo.pop_back();
    Aabb b, cb;
    for (uint32_t i = tk.begin; i < tk.end; ++i) {
      b.grow(boxes[refs[i]]);
      cb.grow(centers[refs[i]]);
    }
    nodes_[tk.node].lo = b.lo;
    nodes_[tk.node].hi = b.hi;
    const uint32_t cnt = tk.end - tk.begin;
    uint32_t mid = tk.begin;
    if (cnt > kLeafSize) {
      const int axis = max_axis(cb.extent());
      const float lo = cb.lo[axis], ext = cb.extent()[axis];
      // Deep down, halves by count: the depth (and the traversal stack) stays below 48 + log2 n.
      if (ext > 0.0f && tk.depth < 48) {  // binned SAH on the centroids
        Aabb bin_box[kBins];
        uint32_t bin_n[kBins] = {};
        const float kk = kBins * (1.0f - 1e-6f) / ext;
        auto bin_of = [&](uint32_t r) { return std::min(kBins - 1, int((centers[r][axis] - lo) * kk)); };
        for (uint32_t i = tk.begin; i < tk.end; ++i) {
          const int bi = bin_of(refs[i]);
          bin_box[bi].grow(boxes[refs[i]]);
          ++bin_n[bi];
        }
        float right[kBins] = {};
        Aabb acc;
        uint32_t m = 0;
        for (int i = kBins - 1; i > 0; --i) {
          acc.grow(bin_box[i]);
          m += bin_n[i];
          right[i] = acc.half_area() * float(m);
        }
        acc = Aabb();
        m = 0;
        float best = kInf;
        int split = -1;
        for (int i = 0; i < kBins - 1; ++i) {
          acc.grow(bin_box[i]);
          m += bin_n[i];
          const float cost = acc.half_area() * float(m) + right[i + 1];
          if (m > 0 && m < cnt && cost < best) {
            best = cost;
            split = i;
          }
        }
        if (split >= 0)
          mid = uint32_t(std::partition(refs.begin() + tk.begin, refs.begin() + tk.end,
                                        [&](uint32_t r) { return bin_of(r) <= split; }) -
                         refs.begin());
      }
      if (mid == tk.begin || mid == tk.end) {
        mid = tk.begin + cnt / 2;
        std::nth_element(refs.begin() + tk.begin, refs.begin() + mid, refs.begin() + tk.end,
                         [&](uint32_t a, uint32_t c) { return centers[a][axis] < centers[c][axis]; });
      }
    }
    if (mid == tk.begin) {
      nodes_[tk.node].first = tk.begin;
      nodes_[tk.node].count = cnt;
      continue;
    }
    const uint32_t left = uint32_t(nodes_.size());
    nodes_.emplace_back();
    nodes_.emplace_back();
    nodes_[tk.node].first = left;
    nodes_[tk.node].count = 0;
    todo.push_back({left, tk.begin, mid, tk.depth + 1});
    todo.push_back({left + 1, mid, tk.end, tk.depth + 1});
  }
  pieces_.resize(n);
  for (size_t i = 0; i < n; ++i) pieces_[i] = pieces[refs[i]];
  nodes_.shrink_to_fit();
}

namespace {
inline bool box_hit(const Vec3& lo, const Vec3& hi, const Vec3& org, const Vec3& inv, float tmax, float& tnear) {
  float t0 = 0.0f, t1 = tmax;
  for (int a = 0; a < 3; ++a) {
    float n = (lo[a] - org[a]) * inv[a], f = (hi[a] - org[a]) * inv[a];
    if (n > f) std::swap(n, f);
    t0 = n > t0 ? n : t0;
    t1 = f < t1 ? f : t1;
  }
  tnear = t0;
  return t0 <= t1 * bvh_detail::kBoxExitScale;
}
}  // namespace

template <bool AnyHit>
bool CurveBvh::traverse(const Ray& ray, Hit& hit) const {
  if (nodes_.empty()) return false;
  const Vec3 inv = bvh_detail::safe_inverse(ray.dir);
  float tmax = ray.tmax;
  bool found = false;
  struct Entry {
    uint32_t node;
    float t;
  };
  constexpr int kStack = 128;
  Entry stack[kStack];
  int sp = 0;
  float t_root;
  if (!box_hit(nodes_[0].lo, nodes_[0].hi, ray.org, inv, tmax, t_root)) return false;
  stack[sp++] = {0, t_root};
  while (sp > 0) {
    const Entry e = stack[--sp];
    if (!(e.t <= tmax * bvh_detail::kBoxExitScale)) continue;
    const Node& nd = nodes_[e.node];
    if (nd.count > 0) {
      for (uint32_t i = nd.first; i < nd.first + nd.count; ++i) {
        float t, u;
        if (intersect_piece(pieces_[i], ray.org, ray.dir, tmax, t, u)) {
          if (AnyHit) return true;
          tmax = t;
          hit.t = t;
          hit.b1 = u;
          hit.prim = i;
          found = true;
        }
      }
      continue;
    }
    float ta, tb;
    const bool ha = box_hit(nodes_[nd.first].lo, nodes_[nd.first].hi, ray.org, inv, tmax, ta);
    const bool hb = box_hit(nodes_[nd.first + 1].lo, nodes_[nd.first + 1].hi, ray.org, inv, tmax, tb);
    if (sp + 2 > kStack) continue;  // unreachable (depth < 48 + log2 n): never overrun
    if (ha && hb) {
      if (ta <= tb) {
        stack[sp++] = {nd.first + 1, tb};
        stack[sp++] = {nd.first, ta};
      } else {
        stack[sp++] = {nd.first, ta};
        stack[sp++] = {nd.first + 1, tb};
      }
    } else if (ha) {
      stack[sp++] = {nd.first, ta};
    } else if (hb) {
      stack[sp++] = {nd.first + 1, tb};
    }
  }
  return found;
}

bool CurveBvh::intersect(const Ray& ray, Hit& hit) const {
  if (!traverse<false>(ray, hit)) return false;
  encode_piece_hit(pieces_[hit.prim], ray.org + ray.dir * hit.t, hit.b1, hit.b1, hit.b2);
  return true;
}
bool CurveBvh::occluded(const Ray& ray) const {
  Hit h;
  return traverse<true>(ray, h);
}

}  // namespace pl
