#include "geometry/curves.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#if defined(__SSE2__)
#include <immintrin.h>
#endif

#include "geometry/binned_sah.h"
#include "geometry/bvh_common.h"
#include "geometry/wide4.h"
#include "util/parallel.h"

namespace pl {
namespace {

// Hits closer than this fraction of the piece's radius are taken for the surface the ray left
// (a ray spawned on the outside that grazes it): a bias of 1e-4 radii at most.
constexpr float kSelfFraction = 1e-4f;

// Both hits of a sphere (centre q, radius r), computed from the ray's closest approach to q so
// the error does not grow with the distance (Haines et al., Ray Tracing Gems ch. 7).
inline bool sphere_hits(const Vec3& q, float r, const Vec3& org, const Vec3& dir, float dd, float& t0, float& t1) {
  if (!(r > 0.0f)) return false;
  const Vec3 w = org - q;
  const float tc = -dot(w, dir) / dd;
  const Vec3 l = w + dir * tc;
  const float disc = r * r - dot(l, l);
  if (!(disc >= 0.0f)) return false;
  const float h = std::sqrt(disc / dd);
  t0 = tc - h;
  t1 = tc + h;
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
  const bool tip = !(length_sq(c.next) > 0.0f);
  // On the inner side of a bend a piece's cone runs on inside its neighbour (within the
  // neighbour's slab and radius): not the strand's surface. Rays from outside never reached
  // it first; rays from inside would (the neighbour's radius taken as at the joint). Only
  // points clearly inside (5e-5 radii) are dropped, so rounding never drops both cones at
  // the seam where they cross.
  constexpr float kInsideMargin = 1.0f - 1e-4f;
  const auto inside_neighbour = [&](const Vec3& x) {
    if (!tip) {
      const Vec3 w = x - c.p1;
      const float s = dot(w, c.next);
      if (s > 0.0f && dot(w, w) - s * s < c.r1 * c.r1 * kInsideMargin) return true;
    }
    if (length_sq(c.prev) > 0.0f) {
      const Vec3 w = x - c.p0;
      const float s = dot(w, c.prev);
      if (s < 0.0f && dot(w, w) - s * s < c.r0 * c.r0 * kInsideMargin) return true;
    }
    return false;
  };
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
      // Both roots without cancellation: (-B -+ sqrt) / A or C / (-B +- sqrt). The far one is
      // where a ray inside the strand leaves it: Cycles (Embree's round curves) reports it.
      const float sq = std::sqrt(disc);
      const float q = B > 0.0f ? -(B + sq) : sq - B;
      const float near = B > 0.0f ? q / A : C / q, far = B > 0.0f ? C / q : q / A;
      for (const float tl : {near, far}) {
        const float s = ws + tl * ds;
        const float t = t0 + tl;
        if (s >= 0.0f && s <= len && c.r0 + k * s > 0.0f && t > tmin && t < best && !inside_neighbour(org + dir * t)) {
          best = t;
          u_out = s / len;
          found = true;
          break;  // (the near root first: the far one is farther)
        }
      }
    }
  }
  float t;
  const Vec3 ah = len2 > 0.0f ? axis / std::sqrt(len2) : Vec3(0.0f);
  // A strand's root and tip are cut off flat, as Cycles' thick curves end: a disc across the
  // axis, entered from outside only (u -1: the root disc, 2: the tip's). A ray leaving through
  // an end finds nothing, as through Cycles' open ends.
  if ((c.root || tip) && len2 > 0.0f) {
    const float dn = dot(dir, ah);
    const auto disc = [&](const Vec3& q, float r, float u) {
      t = dot(q - org, ah) / dn;
      if (!(t > tmin && t < best)) return;
      const Vec3 x = org + dir * t - q;
      if (!(dot(x, x) <= r * r)) return;
      best = t;
      u_out = u;
      found = true;
    };
    if (c.root && dn > 0.0f) disc(c.p0, c.r0, -1.0f);
    if (tip && dn < 0.0f) disc(c.p1, c.r1, 2.0f);
  }
  float te0, te1;
  if (!tip && sphere_hits(c.p1, c.r1, org, dir, dd, te0, te1)) {
    for (const float te : {te0, te1}) {
      if (!(te > tmin && te < best)) continue;
      const Vec3 x = org + dir * te - c.p1;
      if (dot(x, ah) >= 0.0f && dot(x, c.next) <= 0.0f) {  // the wedge no cone covers
        best = te;
        u_out = 1.0f;
        found = true;
        break;
      }
    }
  }
  if (found) t_out = best;
  return found;
}

namespace {
// Embree's self-intersection avoidance for flat curves (EMBREE_CURVE_SELF_INTERSECTION_AVOIDANCE_FACTOR,
// 2 by default; Cycles' GPU ribbon_intersect copies it): hits nearer than this many radii are
// ignored.
constexpr float kRibbonAvoidance = 2.0f;

struct V2 {
  float x, y;
};
}  // namespace

bool intersect_ribbon(const CurvePiece& c, const Vec3& org, const Vec3& dir, float tmax, float& t_out, float& u_out,
                      float& v_out) {
  const float dd = dot(dir, dir);
  if (!(dd > 0.0f)) return false;
  const float inv_len = 1.0f / std::sqrt(dd);
  const Vec3 d = dir * inv_len;
  // The ray's frame (Embree's frame(), Cycles' ribbon_ray_space): x, y across the ray, z along.
  const Vec3 dx0{0.0f, d.z, -d.y}, dx1{-d.z, 0.0f, d.x};
  const Vec3 sx = normalize(dot(dx0, dx0) > dot(dx1, dx1) ? dx0 : dx1);
  const Vec3 sy = normalize(cross(d, sx));
  const Vec3 a = c.p0 - org, b = c.p1 - org;
  const Vec3 q0{dot(sx, a), dot(sy, a), dot(d, a)}, q1{dot(sx, b), dot(sy, b), dot(d, b)};
  // Culling by the cylinder about the chord (as Embree: also drops quad corners beyond it).
  const float rmax = std::max(c.r0, c.r1);
  const V2 dp{q1.x - q0.x, q1.y - q0.y};
  const float num = dp.x * q0.y - dp.y * q0.x;
  if (!(num * num <= rmax * rmax * (dp.x * dp.x + dp.y * dp.y))) return false;
  const float eps = 4.0f * std::numeric_limits<float>::epsilon() *
                    std::max(std::max(max_component(vabs(q0)), max_component(vabs(q1))), rmax);
  // The ends' half-widths: the radius along the projected derivative's normal (the chord where
  // the derivative vanishes).
  const auto half_width = [&](const Vec3& deriv, float r, V2& w) {
    Vec3 e{dot(sx, deriv), dot(sy, deriv), dot(d, deriv)};
    if (max_component(vabs(e)) < eps) e = q1 - q0;
    const float l = std::sqrt(e.y * e.y + e.x * e.x);
    if (!(l > 0.0f) || !std::isfinite(l)) return false;
    w = {e.y / l * r, -e.x / l * r};
    return true;
  };
  V2 w0, w1;
  if (!half_width(c.prev, c.r0, w0) || !half_width(c.next, c.r1, w1)) return false;
  // The quad lp0, lp1, up1, up0 as two triangles, the diagonal lp1-up0 choosing which one the
  // ray meets (Embree's intersect_quad_backface_culling with the ray along z from the origin).
  const Vec3 va{q0.x + w0.x, q0.y + w0.y, q0.z}, vb{q1.x + w1.x, q1.y + w1.y, q1.z};
  const Vec3 vc{q1.x - w1.x, q1.y - w1.y, q1.z}, vd{q0.x - w0.x, q0.y - w0.y, q0.z};
  const Vec3 edb = vb - vd;
  const float ww = cross(vd, edb).z;
  const bool first = ww <= 0.0f;
  const Vec3 v0 = first ? va : vc, v1 = first ? vb : vd, v2 = first ? vd : vb;
  const Vec3 e0 = v2 - v0, e1 = v0 - v1;
  const float uu = cross(v0, e0).z, vv = cross(v1, e1).z;
  if (!(std::max(uu, vv) <= 0.0f)) return false;
  const Vec3 ng = cross(e1, e0);
  const float den = ng.z;
  if (!(den != 0.0f)) return false;
  const float t = dot(v0, ng) / den;  // distance along the unit direction
  if (!(t >= 0.0f && t <= tmax / inv_len)) return false;
  float u = uu / den, v = vv / den;
  if (!first) {
    u = 1.0f - u;
    v = 1.0f - v;
  }
  if (!(t > kRibbonAvoidance * (c.r0 + (c.r1 - c.r0) * u))) return false;
  const float tp = t * inv_len;
  if (!(tp < tmax)) return false;
  t_out = tp;
  u_out = u;
  v_out = 2.0f * v - 1.0f;
  return true;
}

void ribbon_surface(const CurvePiece& c, float u, float v, const Vec3& dir, Vec3& n, Vec3& tangent) {
  u = clampf(u, 0.0f, 1.0f);
  v = clampf(v, -1.0f, 1.0f);
  Vec3 dpdu = c.prev + (c.next - c.prev) * u;
  float l = length(dpdu);
  if (!(l > 0.0f) || !std::isfinite(l)) {
    dpdu = c.p1 - c.p0;
    l = length(dpdu);
  }
  tangent = l > 0.0f && std::isfinite(l) ? dpdu / l : Vec3(0.0f, 0.0f, 1.0f);
  const float dl = length(dir);
  const Vec3 wi = dl > 0.0f && std::isfinite(dl) ? -dir / dl : Vec3(0.0f);
  Vec3 bt = cross(tangent, wi);
  float bl = length(bt);
  if (!(bl > 1e-7f)) {  // looking along the strand: any direction across it
    Vec3 x, y;
    make_basis(tangent, x, y);
    bt = x;
    bl = 1.0f;
  }
  bt = bt / bl;
  const Vec3 across = normalize(cross(tangent, bt));  // the view's part across the strand, reversed
  // Cycles: N = sin b - cos (t x b) with sin = v.
  n = normalize(bt * v - across * std::sqrt(std::max(0.0f, 1.0f - v * v)));
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
  if (u < 0.0f || u > 1.0f) {  // an end disc: -5 - rho / r0 at the root, 5 + rho / r1 at the tip
    const float r = u > 1.0f ? c.r1 : c.r0;
    float rho = r > 0.0f ? clampf(length(d - tg * dot(d, tg)) / r, 0.0f, 1.0f) : 0.0f;
    if (!std::isfinite(rho)) rho = 0.0f;
    b1 = u > 1.0f ? 5.0f + rho : -5.0f - rho;
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
  } else if (b1 <= -5.0f || b1 >= 5.0f) {  // an end disc
    const bool end = b1 > 0.0f;
    u = end ? 1.0f : 0.0f;
    const float rho = clampf(end ? b1 - 5.0f : -5.0f - b1, 0.0f, 1.0f);
    n = end ? tangent : -tangent;
    p = (end ? c.p1 : c.p0) + rhat * (rho * (end ? c.r1 : c.r0));
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

namespace {
// A strand's ribbon pieces: each Catmull-Rom segment cut into `sub` quads at equal parameter
// steps (Embree's tessellation of flat curves), with the derivative at both ends.
void cut_ribbon(const std::vector<Vec3>& p, const std::vector<float>& r, const std::vector<float>& v,
                const std::vector<Vec3>& nrm, bool normals, int sub, uint32_t id, std::vector<CurvePiece>& out) {
  const size_t n = p.size();
  for (size_t k = 0; k + 1 < n; ++k) {
    const size_t a = k > 0 ? k - 1 : 0, d = std::min(k + 2, n - 1);
    Vec3 prev = p[k], prev_d = catmull_rom_derivative(p[a], p[k], p[k + 1], p[d], 0.0f);
    float prev_r = r[k], prev_v = v[k];
    for (int j = 1; j <= sub; ++j) {
      const float t = float(j) / float(sub);
      const Vec3 q = j == sub ? p[k + 1] : catmull_rom(p[a], p[k], p[k + 1], p[d], t);
      const float rq = j == sub ? r[k + 1] : std::max(0.0f, catmull_rom(r[a], r[k], r[k + 1], r[d], t));
      const Vec3 dq = catmull_rom_derivative(p[a], p[k], p[k + 1], p[d], t);
      const float vq = v[k] + (v[k + 1] - v[k]) * t;
      if (prev_r > 0.0f || rq > 0.0f) {
        CurvePiece pc;
        pc.p0 = prev;
        pc.p1 = q;
        pc.r0 = prev_r;
        pc.r1 = rq;
        pc.prev = prev_d;
        pc.next = dq;
        pc.ribbon = true;
        pc.curve = id;
        pc.v0 = prev_v;
        pc.v1 = vq;
        if (normals) {
          const float t0 = float(j - 1) / float(sub);
          pc.n0 = encode_unit(nrm[k] + (nrm[k + 1] - nrm[k]) * t0);
          pc.n1 = encode_unit(nrm[k] + (nrm[k + 1] - nrm[k]) * t);
        }
        out.push_back(pc);
      }
      prev = q;
      prev_d = dq;
      prev_r = rq;
      prev_v = vq;
    }
  }
}
}  // namespace

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
  // Ribbons are Catmull-Rom through the points whatever the type, as Cycles 4.5's (checked).
  const bool ribbon = in.ribbon;
  const int sub = in.type == CurveType::CatmullRom || ribbon ? std::max(1, std::min(in.subdivisions, 64)) : 1;
  std::vector<Vec3> p;
  std::vector<float> r, v;
  std::vector<Vec3> nrm;
  for (size_t c = 0; c < in.n_curves; ++c) {
    const size_t b = size_t(in.offsets[c]), e = size_t(in.offsets[c + 1]), n = e - b;
    bool ok = n >= 2 && std::isfinite(rscale) && rscale > 0.0f;
    float rmax = 0.0f, total = 0.0f;
    p.resize(n);
    r.resize(n);
    v.resize(n);
    nrm.assign(n, Vec3(0.0f));
    for (size_t i = 0; i < n && ok; ++i) {
      p[i] = to_world.point(in.points[b + i]);
      r[i] = in.radii ? in.radii[b + i] * rscale : 0.005f * rscale;
      if (in.normals) nrm[i] = to_world.vector(in.normals[b + i]);  // (bad ones: no normal, not a bad strand)
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
    const auto push = [&](CurvePiece pc) {
      if (last != SIZE_MAX) {
        float l;
        out[last].next = piece_tangent(pc, l);
        pc.prev = piece_tangent(out[last], l);
      }
      out.push_back(pc);
      out.back().root = last == SIZE_MAX;
      last = out.size() - 1;
    };
    if (ribbon) {
      cut_ribbon(p, r, v, nrm, in.normals != nullptr, sub, id, out);
      continue;
    }
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
          if (in.normals) {  // linear between the segment's keys (Cycles' curve_attribute_float3)
            const float t0 = float(j - 1) / float(sub);
            pc.n0 = encode_unit(nrm[k] + (nrm[k + 1] - nrm[k]) * t0);
            pc.n1 = encode_unit(nrm[k] + (nrm[k + 1] - nrm[k]) * t);
          }
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



void CurveBvh::build(std::vector<CurvePiece> pieces, std::vector<CurvePiece> steps, uint32_t n_steps) {
  *this = CurveBvh();
  if (pieces.empty()) return;
  const size_t n = pieces.size();
  const bool deform = n_steps >= 2 && steps.size() == size_t(n_steps) * n;
  if (!deform) {
    std::vector<Aabb> boxes(n);
    std::vector<uint32_t> refs;
    for (size_t i = 0; i < n; ++i) boxes[i] = piece_box(pieces[i]);
    bounds_ = bvh_detail::build_wide4(boxes, nodes_, refs);
    pieces_.resize(n);
    for (size_t i = 0; i < n; ++i) pieces_[i] = pieces[refs[i]];
    return;
  }
  // Deforming: the pieces stay in input order, with a tree per slice of the shutter (between
  // steps a piece's ends and radii interpolate linearly: build_wide4_slices).
  pieces_ = std::move(pieces);
  steps_ = std::move(steps);
  n_steps_ = n_steps;
  bounds_ = bvh_detail::build_wide4_slices(
      n, n_steps, [&](uint32_t i, float t) { return piece_box(deformed(i, t)); },
      [&](uint32_t k, size_t i) { return piece_box(steps_[size_t(k) * n + i]); }, slice_nodes_, slice_refs_);
}

template <bool AnyHit, bool Deform>
bool CurveBvh::traverse(const Ray& ray, Hit& hit) const {
  // (Deforming trees: the slice of the shutter the ray's time falls in; its leaves index pieces.)
  const int slice = Deform ? std::min(int(clampf(ray.time, 0.0f, 1.0f) * float(kSlices)), kSlices - 1) : 0;
  CurvePiece scratch;
  return bvh_detail::traverse_wide4<AnyHit>(
      Deform ? slice_nodes_[slice] : nodes_, Deform ? slice_refs_[slice].data() : nullptr, ray,
      [&](uint32_t i, float& tmax) {
        if (pieces_[i].curve == ray.self_curve) return false;  // the strand the ray leaves
        // (Deforming sets: the piece at the ray's time; a copy only there.)
        const CurvePiece& pc = leaf_piece<Deform>(i, ray.time, scratch);
        float t, u, v = 0.0f;
        if (!(pc.ribbon ? intersect_ribbon(pc, ray.org, ray.dir, tmax, t, u, v)
                        : intersect_piece(pc, ray.org, ray.dir, tmax, t, u)))
          return false;
        if (AnyHit) return true;
        tmax = t;
        hit.t = t;
        hit.b1 = u;
        if (pc.ribbon) hit.b2 = v;
        hit.prim = i;
        return true;
      });
}

namespace {
Vec3 lerp3(const Vec3& a, const Vec3& b, float w) { return a + (b - a) * w; }
// A unit vector along v, or `fallback` where it has no length (as piece_tangent).
Vec3 unit_or(const Vec3& v, const Vec3& fallback) {
  const float l2 = length_sq(v);
  return l2 > 0.0f && std::isfinite(l2) ? v / std::sqrt(l2) : fallback;
}
}  // namespace

bool prepare_deform_steps(const std::vector<CurvePiece>& frame, std::vector<CurvePiece>& steps, uint32_t n_steps) {
  const size_t n = frame.size();
  if (n_steps < 2 || steps.size() != size_t(n_steps) * n) return false;
  for (uint32_t s = 0; s < n_steps; ++s) {
    CurvePiece* st = steps.data() + size_t(s) * n;
    for (size_t i = 0; i < n; ++i) {
      const CurvePiece &f = frame[i], &c = st[i];
      const bool joins_next = length_sq(f.next) > 0.0f, joins_prev = length_sq(f.prev) > 0.0f;
      if (c.curve != f.curve || c.root != f.root || c.ribbon != f.ribbon ||
          (!f.ribbon && (joins_next != (length_sq(c.next) > 0.0f) || joins_prev != (length_sq(c.prev) > 0.0f))))
        return false;
      // Joined round pieces follow each other in cut order (cut_curves' push).
      if (!f.ribbon && ((joins_next && i + 1 >= n) || (joins_prev && i == 0))) return false;
    }
    for (size_t i = 0; i < n; ++i) {  // (raw axes from the step's own neighbours)
      CurvePiece& c = st[i];
      if (c.ribbon) continue;
      if (length_sq(frame[i].next) > 0.0f) c.next = st[i + 1].p1 - st[i + 1].p0;
      if (length_sq(frame[i].prev) > 0.0f) c.prev = st[i - 1].p1 - st[i - 1].p0;
    }
  }
  return true;
}

CurvePiece CurveBvh::deformed(uint32_t i, float time) const {
  const size_t n = pieces_.size();
  const float f = clampf(time, 0.0f, 1.0f) * float(n_steps_ - 1);
  const uint32_t k = std::min(uint32_t(f), n_steps_ - 2);
  const float w = f - float(k);
  const CurvePiece &a = steps_[size_t(k) * n + i], &b = steps_[size_t(k + 1) * n + i];
  CurvePiece c = pieces_[i];  // (strand, intercepts, normals: the frame's)
  c.p0 = lerp3(a.p0, b.p0, w);
  c.p1 = lerp3(a.p1, b.p1, w);
  c.r0 = std::max(0.0f, a.r0 + (b.r0 - a.r0) * w);
  c.r1 = std::max(0.0f, a.r1 + (b.r1 - a.r1) * w);
  if (c.ribbon) {  // derivatives are linear in the keys
    c.prev = lerp3(a.prev, b.prev, w);
    c.next = lerp3(a.next, b.next, w);
  } else {  // the interpolated neighbours' axes (prepare_deform_steps), made unit again
    if (length_sq(c.prev) > 0.0f) c.prev = unit_or(lerp3(a.prev, b.prev, w), Vec3(0.0f, 0.0f, 1.0f));
    if (length_sq(c.next) > 0.0f) c.next = unit_or(lerp3(a.next, b.next, w), Vec3(0.0f, 0.0f, 1.0f));
  }
  return c;
}

CurvePiece transform_piece(const CurvePiece& c, const Mat4& m) {
  CurvePiece w = c;
  w.p0 = m.point(c.p0);
  w.p1 = m.point(c.p1);
  const Vec3 c0{m.m[0][0], m.m[1][0], m.m[2][0]}, c1{m.m[0][1], m.m[1][1], m.m[2][1]}, c2{m.m[0][2], m.m[1][2], m.m[2][2]};
  float s = std::cbrt(std::fabs(dot(c0, cross(c1, c2))));
  if (!std::isfinite(s)) s = 0.0f;
  w.r0 = c.r0 * s;
  w.r1 = c.r1 * s;
  if (c.ribbon) {
    w.prev = m.vector(c.prev);
    w.next = m.vector(c.next);
  } else {
    if (length_sq(c.prev) > 0.0f) w.prev = unit_or(m.vector(c.prev), Vec3(0.0f, 0.0f, 1.0f));
    if (length_sq(c.next) > 0.0f) w.next = unit_or(m.vector(c.next), Vec3(0.0f, 0.0f, 1.0f));
  }
  if (c.n0 != kNoCurveNormal) w.n0 = encode_unit(m.vector(decode_unit(c.n0)));
  if (c.n1 != kNoCurveNormal) w.n1 = encode_unit(m.vector(decode_unit(c.n1)));
  return w;
}

void CurveBvh::add_moving(std::vector<CurvePiece> pieces, std::vector<CurvePiece> steps, uint32_t n_steps,
                          std::vector<DecomposedTransform> xf) {
  if (pieces.empty()) return;
  auto bvh = std::make_unique<CurveBvh>();
  const uint32_t n = uint32_t(pieces.size());
  bvh->build(std::move(pieces), std::move(steps), n_steps);
  bounds_.grow(moving_.add(std::move(bvh), n, std::move(xf)));
}

Mat4 CurveBvh::moving_transform(uint32_t prim, float time) const {
  return prim & kMovingPrim ? moving_.transform_at(moving_.set_of(prim & ~kMovingPrim), time) : Mat4();
}

CurvePiece CurveBvh::piece_at(uint32_t prim, float time) const {
  if (!(prim & kMovingPrim)) return pieces_[prim];
  const uint32_t i = prim & ~kMovingPrim, m = moving_.set_of(i);
  const CurveBvh& b = *moving_.trees[m];
  const uint32_t local = i - moving_.first[m];
  const CurvePiece c = b.steps_.empty() ? b.pieces_[local] : b.deformed(local, time);
  return moving_.xf[m].empty() ? c : transform_piece(c, moving_.transform_at(m, time));
}

template <bool AnyHit>
bool CurveBvh::traverse_moving(const Ray& ray, Hit& hit) const {
  return moving_.traverse<AnyHit>(ray, [&](uint32_t m, const CurveBvh& inner, const Ray& ro, const Mat4&, float& tmax) {
    Hit h;
    if (!(inner.steps_.empty() ? inner.traverse<AnyHit, false>(ro, h) : inner.traverse<AnyHit, true>(ro, h)))
      return false;
    tmax = h.t;
    hit = h;
    hit.prim = kMovingPrim | (moving_.first[m] + h.prim);
    return true;
  });
}

bool CurveBvh::intersect(const Ray& ray, Hit& hit) const {
  bool found = traverse<false, false>(ray, hit);
  if (__builtin_expect(!moving_.empty(), 0)) {
    Ray r = ray;
    if (found) r.tmax = hit.t;
    found = traverse_moving<false>(r, hit) || found;
  }
  if (!found) return false;
  if (!(hit.prim & kMovingPrim)) {
    if (pieces_[hit.prim].ribbon) return true;  // (b1, b2): u and v, the point is the ray's
    encode_piece_hit(pieces_[hit.prim], ray.org + ray.dir * hit.t, hit.b1, hit.b1, hit.b2);
    return true;
  }
  // A moving piece's hit, encoded on the piece in world space at the ray's time.
  const CurvePiece c = piece_at(hit.prim, ray.time);
  if (!c.ribbon) encode_piece_hit(c, ray.org + ray.dir * hit.t, hit.b1, hit.b1, hit.b2);
  return true;
}
bool CurveBvh::occluded(const Ray& ray) const {
  Hit h;
  return traverse<true, false>(ray, h) || (!moving_.empty() && traverse_moving<true>(ray, h));
}

}  // namespace pl
