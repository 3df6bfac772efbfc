#include "geometry/points.h"

#include <algorithm>
#include <cmath>
#if defined(__SSE2__)
#include <immintrin.h>
#endif

#include "geometry/binned_sah.h"
#include "geometry/bvh_common.h"
#include "geometry/wide4.h"
#include "util/parallel.h"

namespace pl {

namespace {
// The nearest t in (0, tmax) where |t d - f| = r (f: the centre from the ray's origin): the
// entry, or the exit from inside. Solved about the closest approach tc, so the error does not
// grow with the distance (Haines et al., Ray Tracing Gems ch. 7), in double: a few more
// cycles per sphere (the box tests dominate), and neither the distance to the origin nor the
// ray's length eats a tiny radius' digits.
inline bool solve_sphere(const double f[3], const double d[3], double rr, float tmax, double& t) {
  const double dd = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
  if (!(dd > 0.0)) return false;
  const double tc = (f[0] * d[0] + f[1] * d[1] + f[2] * d[2]) / dd;
  const double px = f[0] - tc * d[0], py = f[1] - tc * d[1], pz = f[2] - tc * d[2];
  const double disc = rr - (px * px + py * py + pz * pz);
  if (!(disc >= 0.0)) return false;  // (NaN too)
  const double h = std::sqrt(disc / dd);
  t = tc - h;
  if (!(t > 0.0)) t = tc + h;  // inside: where it leaves
  if (!(t > 0.0) || !(t < double(tmax))) return false;
  const float tf = float(t);
  return tf > 0.0f && tf < tmax;
}

// The unit direction from the centre to the hit: t d - f.
inline bool hit_direction(const double f[3], const double d[3], double t, Vec3& n) {
  const double nx = t * d[0] - f[0], ny = t * d[1] - f[1], nz = t * d[2] - f[2];
  const double nl = std::sqrt(nx * nx + ny * ny + nz * nz);
  if (!(nl > 0.0) || !std::isfinite(nl)) return false;
  n = Vec3(float(nx / nl), float(ny / nl), float(nz / nl));
  return true;
}
}  // namespace

bool intersect_sphere(const Vec3& c, float r, const Vec3& org, const Vec3& dir, float tmax, float& t_out, Vec3& n) {
  if (!(r > 0.0f)) return false;
  const double f[3] = {double(c.x) - org.x, double(c.y) - org.y, double(c.z) - org.z};
  const double d[3] = {dir.x, dir.y, dir.z};
  double t;
  if (!solve_sphere(f, d, double(r) * r, tmax, t) || !hit_direction(f, d, t, n)) return false;
  t_out = float(t);
  return true;
}

bool intersect_ellipsoid(const Vec3& c, float r, const PointFrame& fr, const Vec3& org, const Vec3& dir, float tmax,
                         float& t_out, Vec3& n) {
  if (!(r > 0.0f)) return false;
  // In the cloud's object space (t is the same parameter there), from the world centre.
  const double f[3] = {double(c.x) - org.x, double(c.y) - org.y, double(c.z) - org.z};
  const double d[3] = {dir.x, dir.y, dir.z};
  double fo[3], dob[3];
  for (int i = 0; i < 3; ++i) {
    const Vec3& a = fr.row[i];
    fo[i] = a.x * f[0] + a.y * f[1] + a.z * f[2];
    dob[i] = a.x * d[0] + a.y * d[1] + a.z * d[2];
  }
  double t;
  if (!solve_sphere(fo, dob, double(r) * r, tmax, t) || !hit_direction(f, d, t, n)) return false;
  t_out = float(t);
  return true;
}

void encode_sphere_normal(Vec3 n, float& b1, float& b2) {
  const float l1 = std::fabs(n.x) + std::fabs(n.y) + std::fabs(n.z);
  if (!(l1 > 0.0f) || !std::isfinite(l1)) {
    b1 = b2 = 0.0f;
    return;
  }
  float u = n.x / l1, v = n.y / l1;
  if (n.z < 0.0f) {
    const float pu = (1.0f - std::fabs(v)) * (u >= 0.0f ? 1.0f : -1.0f);
    const float pv = (1.0f - std::fabs(u)) * (v >= 0.0f ? 1.0f : -1.0f);
    u = pu;
    v = pv;
  }
  b1 = u;
  b2 = v;
}

Vec3 decode_sphere_normal(float u, float v) {
  Vec3 n{u, v, 1.0f - std::fabs(u) - std::fabs(v)};
  if (n.z < 0.0f) {
    n.x = (1.0f - std::fabs(v)) * (u >= 0.0f ? 1.0f : -1.0f);
    n.y = (1.0f - std::fabs(u)) * (v >= 0.0f ? 1.0f : -1.0f);
  }
  const float l2 = length_sq(n);
  return l2 > 0.0f && std::isfinite(l2) ? n / std::sqrt(l2) : Vec3(0.0f, 0.0f, 1.0f);
}

void sphere_surface(const PointSphere& s, const PointFrame* f, float b1, float b2, Vec3& n, Vec3& p, Vec3& error) {
  n = decode_sphere_normal(b1, b2);
  // On an ellipsoid the point along n lies where its object-space image has length r.
  float dist = s.r;
  if (f) {
    const float l = length(f->apply(n));
    dist = l > 0.0f && std::isfinite(s.r / l) ? s.r / l : 0.0f;
  }
  p = s.c + n * dist;
  // The centre's rounding in the sum, and the normal's (a few ulps) times the distance.
  error = (vabs(s.c) + Vec3(dist)) * gamma_bound(8);
}

size_t transform_points(const Vec3* points, const float* radii, size_t n, const Mat4& to_world, uint32_t point_base,
                        std::vector<PointSphere>& out, std::vector<PointFrame>& frames, std::vector<uint32_t>* kept) {
  const float(&m)[4][4] = to_world.m;
  const Vec3 c0{m[0][0], m[1][0], m[2][0]}, c1{m[0][1], m[1][1], m[2][1]}, c2{m[0][2], m[1][2], m[2][2]};
  const Vec3 x0 = cross(c1, c2), x1 = cross(c2, c0), x2 = cross(c0, c1);
  const float det = dot(c0, x0);
  const float rscale = std::cbrt(std::fabs(det));
  if (!(rscale > 0.0f) || !std::isfinite(rscale) || !to_world.is_finite()) return n;  // all left out
  // Even scales (columns orthogonal and of one length): round spheres in world space.
  const float s2 = rscale * rscale, tol = 1e-5f * s2;
  const bool round = std::fabs(length_sq(c0) - s2) < tol && std::fabs(length_sq(c1) - s2) < tol &&
                     std::fabs(length_sq(c2) - s2) < tol && std::fabs(dot(c0, c1)) < tol &&
                     std::fabs(dot(c1, c2)) < tol && std::fabs(dot(c0, c2)) < tol;
  uint32_t frame = PointSphere::kRoundPoint;
  if (!round) {  // the inverse's rows: the cofactor columns over the determinant
    frames.push_back({{x0 / det, x1 / det, x2 / det}});
    frame = uint32_t(frames.size() - 1);
  }
  size_t skipped = 0;
  out.reserve(out.size() + n);
  for (size_t i = 0; i < n; ++i) {
    const float r = round ? radii[i] * rscale : radii[i];
    const Vec3 c = to_world.point(points[i]);
    if (!is_finite(points[i]) || !is_finite(c) || !(r > 0.0f) || !std::isfinite(r)) {
      ++skipped;
      continue;
    }
    out.push_back({c, r, point_base + uint32_t(i), frame});
    if (kept) kept->push_back(uint32_t(i));
  }
  return skipped;
}

namespace {

Aabb sphere_box(const PointSphere& s, const std::vector<PointFrame>& frames) {
  Vec3 e(s.r);
  if (s.frame != PointSphere::kRoundPoint) {
    // The ellipsoid's extent along world axis i: r times the length of row i of the forward
    // matrix, the inverse of the frame (its cofactors over the determinant).
    const PointFrame& f = frames[s.frame];
    const Vec3 a = f.row[0], b = f.row[1], c = f.row[2];
    const Vec3 y0 = cross(b, c), y1 = cross(c, a), y2 = cross(a, b);
    const float det = dot(a, y0);
    // The forward matrix's columns are y_k / det: its row i is (y0[i], y1[i], y2[i]) / det.
    for (int i = 0; i < 3; ++i)
      e[i] = s.r * std::sqrt(y0[i] * y0[i] + y1[i] * y1[i] + y2[i] * y2[i]) / std::fabs(det);
  }
  Aabb b;
  b.grow(s.c - e);
  b.grow(s.c + e);
  // Grown by a little more than the rounding of the box's own coordinates.
  const Vec3 pad = (vabs(b.lo) + vabs(b.hi)) * gamma_bound(4);
  b.lo = b.lo - pad;
  b.hi = b.hi + pad;
  return b;
}

}  // namespace

void PointBvh::build(std::vector<PointSphere> spheres, std::vector<PointFrame> frames, std::vector<PointSphere> steps,
                     uint32_t n_steps) {
  *this = PointBvh();
  frames_ = std::move(frames);
  if (spheres.empty()) return;
  const size_t n = spheres.size();
  const bool deform = n_steps >= 2 && steps.size() == size_t(n_steps) * n;
  if (!deform) {
    std::vector<uint32_t> refs;
    std::vector<Aabb> boxes(n);
    for (size_t i = 0; i < n; ++i) boxes[i] = sphere_box(spheres[i], frames_);
    bounds_ = bvh_detail::build_wide4(boxes, nodes_, refs);
    spheres_.resize(n);
    for (size_t i = 0; i < n; ++i) spheres_[i] = spheres[refs[i]];
    return;
  }
  // Deforming: the spheres stay in input order, and each slice of the shutter gets a tree
  // whose boxes hold them over that slice only (centre and radius interpolate linearly: the
  // hull of the slice's ends and the steps inside it), as deforming curves.
  spheres_ = std::move(spheres);
  steps_ = std::move(steps);
  n_steps_ = n_steps;
  bounds_ = bvh_detail::build_wide4_slices(
      n, n_steps, [&](uint32_t i, float t) { return sphere_box(deformed(i, t), frames_); },
      [&](uint32_t k, size_t i) { return sphere_box(steps_[size_t(k) * n + i], frames_); }, slice_nodes_,
      slice_refs_);
}

template <bool AnyHit, bool Deform>
bool PointBvh::traverse(const Ray& ray, Hit& hit) const {
  // (Deforming trees: the slice of the shutter the ray's time falls in; its leaves index spheres.)
  const int slice = Deform ? std::min(int(clampf(ray.time, 0.0f, 1.0f) * float(kSlices)), kSlices - 1) : 0;
  return bvh_detail::traverse_wide4<AnyHit>(
      Deform ? slice_nodes_[slice] : nodes_, Deform ? slice_refs_[slice].data() : nullptr, ray,
      [&](uint32_t i, float& tmax) {
        PointSphere moved_sphere;  // (deforming clouds: the sphere at the ray's time)
        if constexpr (Deform) moved_sphere = deformed(i, ray.time);
        const PointSphere& s = Deform ? moved_sphere : spheres_[i];
        if ((s.point | kSelfPointBit) == ray.self_curve) return false;  // the sphere the ray leaves
        float t;
        Vec3 n;
        const bool h = s.frame == PointSphere::kRoundPoint
                           ? intersect_sphere(s.c, s.r, ray.org, ray.dir, tmax, t, n)
                           : intersect_ellipsoid(s.c, s.r, frames_[s.frame], ray.org, ray.dir, tmax, t, n);
        if (!h) return false;
        if (AnyHit) return true;
        tmax = t;
        hit.t = t;
        encode_sphere_normal(n, hit.b1, hit.b2);
        hit.prim = i;
        return true;
      });
}

void PointBvh::add_moving(std::vector<PointSphere> spheres, std::vector<DecomposedTransform> steps,
                          std::vector<PointSphere> deform, uint32_t n_deform) {
  if (spheres.empty() || steps.size() < 2) return;
  auto bvh = std::make_unique<PointBvh>();
  const uint32_t n = uint32_t(spheres.size());
  bvh->build(std::move(spheres), {}, std::move(deform), n_deform);
  bounds_.grow(moving_.add(std::move(bvh), n, std::move(steps)));
}

Mat4 PointBvh::moving_transform(uint32_t prim, float time) const {
  return prim & kMovingPrim ? moving_.transform_at(moving_.set_of(prim & ~kMovingPrim), time) : Mat4();
}

PointSphere PointBvh::world_sphere(uint32_t prim, float time, PointFrame& storage, const PointFrame*& frame) const {
  if (!(prim & kMovingPrim)) {
    const PointSphere& s = spheres_[prim];
    frame = this->frame(s);
    return s;
  }
  const uint32_t i = prim & ~kMovingPrim, m = moving_.set_of(i);
  const PointBvh& cloud = *moving_.trees[m];
  PointSphere s = cloud.steps_.empty() ? cloud.spheres_[i - moving_.first[m]] : cloud.deformed(i - moving_.first[m], time);
  const Mat4 to_world = moving_.transform_at(m, time);
  const Mat4 to_object = affine_inverse_fast(to_world);
  for (int r = 0; r < 3; ++r) storage.row[r] = Vec3(to_object.m[r][0], to_object.m[r][1], to_object.m[r][2]);
  s.c = to_world.point(s.c);
  frame = &storage;
  return s;
}

// Moving clouds: the hit's direction from the centre carried back to world space.
template <bool AnyHit>
bool PointBvh::traverse_moving(const Ray& ray, Hit& hit) const {
  return moving_.traverse<AnyHit>(ray, [&](uint32_t m, const PointBvh& cloud, const Ray& ro, const Mat4& to_world, float& tmax) {
    Hit h;
    if (!(cloud.steps_.empty() ? cloud.traverse<AnyHit, false>(ro, h) : cloud.traverse<AnyHit, true>(ro, h))) return false;
    if (AnyHit) return true;
    // The object-space direction from the centre, through the matrix: world P - centre's.
    const Vec3 n = to_world.vector(decode_sphere_normal(h.b1, h.b2));
    const float l2 = length_sq(n);
    if (!(l2 > 0.0f) || !std::isfinite(l2)) return false;
    tmax = h.t;
    hit.t = h.t;
    encode_sphere_normal(n / std::sqrt(l2), hit.b1, hit.b2);
    hit.prim = kMovingPrim | (moving_.first[m] + h.prim);
    return true;
  });
}

bool PointBvh::intersect(const Ray& ray, Hit& hit) const {
  bool found = traverse<false, false>(ray, hit);
  if (!moving_.empty()) {
    Ray r = ray;
    if (found) r.tmax = hit.t;
    found = traverse_moving<false>(r, hit) || found;
  }
  return found;
}

bool PointBvh::occluded(const Ray& ray) const {
  Hit h;
  return traverse<true, false>(ray, h) || (!moving_.empty() && traverse_moving<true>(ray, h));
}

}  // namespace pl
