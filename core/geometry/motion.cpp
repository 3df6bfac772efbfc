#include "geometry/motion.h"

#include <algorithm>
#include <cmath>

#include "geometry/tlas.h"

namespace pl {
namespace {

using D3 = double[3][3];

double det3(const D3& a) {
  return a[0][0] * (a[1][1] * a[2][2] - a[1][2] * a[2][1]) - a[0][1] * (a[1][0] * a[2][2] - a[1][2] * a[2][0]) +
         a[0][2] * (a[1][0] * a[2][1] - a[1][1] * a[2][0]);
}

// The transpose of a's inverse (cofactors / det); false when singular.
bool inverse_transpose(const D3& a, D3& out) {
  const double d = det3(a);
  if (!(std::fabs(d) > 0.0) || !std::isfinite(d)) return false;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) {
      const int i1 = (i + 1) % 3, i2 = (i + 2) % 3, j1 = (j + 1) % 3, j2 = (j + 2) % 3;
      out[i][j] = (a[i1][j1] * a[i2][j2] - a[i1][j2] * a[i2][j1]) / d;
    }
  return true;
}

// Shoemake's quaternion of a rotation matrix.
void quat_from_rotation(const D3& r, double q[4]) {
  const double tr = r[0][0] + r[1][1] + r[2][2];
  if (tr > 0.0) {
    const double s = 0.5 / std::sqrt(tr + 1.0);
    q[3] = 0.25 / s;
    q[0] = (r[2][1] - r[1][2]) * s;
    q[1] = (r[0][2] - r[2][0]) * s;
    q[2] = (r[1][0] - r[0][1]) * s;
  } else if (r[0][0] > r[1][1] && r[0][0] > r[2][2]) {
    const double s = 2.0 * std::sqrt(1.0 + r[0][0] - r[1][1] - r[2][2]);
    q[3] = (r[2][1] - r[1][2]) / s;
    q[0] = 0.25 * s;
    q[1] = (r[0][1] + r[1][0]) / s;
    q[2] = (r[0][2] + r[2][0]) / s;
  } else if (r[1][1] > r[2][2]) {
    const double s = 2.0 * std::sqrt(1.0 + r[1][1] - r[0][0] - r[2][2]);
    q[3] = (r[0][2] - r[2][0]) / s;
    q[0] = (r[0][1] + r[1][0]) / s;
    q[1] = 0.25 * s;
    q[2] = (r[1][2] + r[2][1]) / s;
  } else {
    const double s = 2.0 * std::sqrt(1.0 + r[2][2] - r[0][0] - r[1][1]);
    q[3] = (r[1][0] - r[0][1]) / s;
    q[0] = (r[0][2] + r[2][0]) / s;
    q[1] = (r[1][2] + r[2][1]) / s;
    q[2] = 0.25 * s;
  }
  const double n = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
  for (int k = 0; k < 4; ++k) q[k] /= n;
}

void rotation_from_quat(const float q[4], float r[3][3]) {
  const float x = q[0], y = q[1], z = q[2], w = q[3];
  r[0][0] = 1.0f - 2.0f * (y * y + z * z);
  r[0][1] = 2.0f * (x * y - z * w);
  r[0][2] = 2.0f * (x * z + y * w);
  r[1][0] = 2.0f * (x * y + z * w);
  r[1][1] = 1.0f - 2.0f * (x * x + z * z);
  r[1][2] = 2.0f * (y * z - x * w);
  r[2][0] = 2.0f * (x * z - y * w);
  r[2][1] = 2.0f * (y * z + x * w);
  r[2][2] = 1.0f - 2.0f * (x * x + y * y);
}

// Cycles' quat_interpolate (CPU): slerp, normalised lerp when the two are within ~1.8 degrees.
void quat_interpolate(const float a[4], const float b[4], float t, float out[4]) {
  const float c = a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3];
  if (c > 0.9995f) {
    float n = 0.0f;
    for (int k = 0; k < 4; ++k) {
      out[k] = (1.0f - t) * a[k] + t * b[k];
      n += out[k] * out[k];
    }
    n = 1.0f / std::sqrt(n);
    for (int k = 0; k < 4; ++k) out[k] *= n;
    return;
  }
  const float theta = std::acos(clampf(c, -1.0f, 1.0f));
  float perp[4], n = 0.0f;
  for (int k = 0; k < 4; ++k) {
    perp[k] = b[k] - a[k] * c;
    n += perp[k] * perp[k];
  }
  n = 1.0f / std::sqrt(n);
  const float ct = std::cos(theta * t), st = std::sin(theta * t);
  for (int k = 0; k < 4; ++k) out[k] = a[k] * ct + perp[k] * n * st;
}

// The rotation angle between two steps' quaternions (radians, 0..pi).
float rotation_angle(const DecomposedTransform& a, const DecomposedTransform& b) {
  const float c = std::fabs(a.q[0] * b.q[0] + a.q[1] * b.q[1] + a.q[2] * b.q[2] + a.q[3] * b.q[3]);
  return 2.0f * std::acos(std::min(c, 1.0f));
}

Mat4 compose(const float q[4], const Vec3& t, const float s[3][3]) {
  float r[3][3];
  rotation_from_quat(q, r);
  Mat4 m;
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) m.m[i][j] = r[i][0] * s[0][j] + r[i][1] * s[1][j] + r[i][2] * s[2][j];
    m.m[i][3] = t[i];
  }
  return m;
}

}  // namespace

bool decompose_transform(const Mat4& m, DecomposedTransform& out) {
  if (!m.is_finite()) return false;
  D3 a, r;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) a[i][j] = r[i][j] = m.m[i][j];
  if (!(std::fabs(det3(a)) > 0.0)) return false;
  for (int it = 0; it < 100; ++it) {
    D3 rit;
    if (!inverse_transpose(r, rit)) return false;
    double norm = 0.0;
    for (int i = 0; i < 3; ++i) {
      double row = 0.0;
      for (int j = 0; j < 3; ++j) {
        const double next = 0.5 * (r[i][j] + rit[i][j]);
        row += std::fabs(r[i][j] - next);
        r[i][j] = next;
      }
      norm = std::max(norm, row);
    }
    if (norm < 1e-12) break;
  }
  if (det3(r) < 0.0)  // a mirror: the rotation of -M, the mirror kept in the scale
    for (auto& row : r)
      for (double& v : row) v = -v;
  double q[4];
  quat_from_rotation(r, q);
  for (int k = 0; k < 4; ++k) out.q[k] = float(q[k]);
  out.t = {m.m[0][3], m.m[1][3], m.m[2][3]};
  for (int i = 0; i < 3; ++i)  // s = R^T M
    for (int j = 0; j < 3; ++j) out.s[i][j] = float(r[0][i] * a[0][j] + r[1][i] * a[1][j] + r[2][i] * a[2][j]);
  for (float v : out.q)
    if (!std::isfinite(v)) return false;
  return true;
}

bool decompose_motion(const std::vector<Mat4>& steps, std::vector<DecomposedTransform>& out) {
  out.assign(steps.size(), DecomposedTransform());
  for (size_t i = 0; i < steps.size(); ++i)
    if (!decompose_transform(steps[i], out[i])) return false;
  // The short way round between steps: a negated quaternion is the same rotation (Cycles flips
  // the earlier step of a pair; flipping the later one, in order, keeps every pair matched).
  for (size_t i = 1; i < out.size(); ++i) {
    const float* a = out[i - 1].q;
    float* b = out[i].q;
    if (a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3] < 0.0f)
      for (int k = 0; k < 4; ++k) b[k] = -b[k];
  }
  return true;
}

Mat4 motion_transform_at(const DecomposedTransform* steps, uint32_t n, float time) {
  const int maxstep = int(n) - 1;
  const float x = clampf(time, 0.0f, 1.0f) * float(maxstep);
  const int step = std::min(int(x), maxstep - 1);
  const float t = x - float(step);
  const DecomposedTransform& a = steps[step];
  const DecomposedTransform& b = steps[step + 1];
  float q[4], s[3][3];
  quat_interpolate(a.q, b.q, t, q);
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) s[i][j] = (1.0f - t) * a.s[i][j] + t * b.s[i][j];
  return compose(q, a.t * (1.0f - t) + b.t * t, s);
}

Mat4 affine_inverse_fast(const Mat4& m) {
  const Vec3 c0{m.m[0][0], m.m[1][0], m.m[2][0]}, c1{m.m[0][1], m.m[1][1], m.m[2][1]}, c2{m.m[0][2], m.m[1][2], m.m[2][2]};
  const Vec3 r0 = cross(c1, c2), r1 = cross(c2, c0), r2 = cross(c0, c1);
  const float det = dot(c0, r0);
  Mat4 inv;
  const float k = det != 0.0f ? 1.0f / det : 0.0f;
  const Vec3 rows[3] = {r0 * k, r1 * k, r2 * k};
  const Vec3 t{m.m[0][3], m.m[1][3], m.m[2][3]};
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) inv.m[i][j] = rows[i][j];
    inv.m[i][3] = -dot(rows[i], t);
  }
  return inv;
}

Aabb motion_world_box(const Aabb& box, const DecomposedTransform* steps, uint32_t n) {
  Aabb out;
  if (box.empty() || n < 2) return out;
  Vec3 corner[8];
  for (int c = 0; c < 8; ++c)
    corner[c] = {(c & 1) ? box.hi.x : box.lo.x, (c & 2) ? box.hi.y : box.lo.y, (c & 4) ? box.hi.z : box.lo.z};
  // One step's box of the corners, grown by twice the transform's rounding (as Tlas's world box)
  // and a relative margin for the float inverse that carries rays into object space.
  const auto step_box = [&](const Mat4& m) {
    Aabb b;
    for (const Vec3& p : corner) {
      const Vec3 w = m.point(p);
      const Vec3 e = transform_point_error(m, p, Vec3(0.0f)) * 2.0f + vabs(w) * 1e-6f;
      b.grow(w - e);
      b.grow(w + e);
    }
    return b;
  };
  for (uint32_t k = 0; k + 1 < n; ++k) {
    const DecomposedTransform& a = steps[k];
    const DecomposedTransform& b = steps[k + 1];
    // The largest |S p| over the segment: S is linear in t, its norm convex, so an end's.
    float r = 0.0f;
    for (const Vec3& p : corner)
      for (const DecomposedTransform* d : {&a, &b}) {
        Vec3 sp;
        for (int i = 0; i < 3; ++i) sp[i] = d->s[i][0] * p.x + d->s[i][1] * p.y + d->s[i][2] * p.z;
        r = std::max(r, length(sp));
      }
    const float theta = rotation_angle(a, b);
    const int sub = std::clamp(int(std::ceil(theta / 0.03f)), 1, 512);
    // Between two sub-steps the point R(t) S(t) p + T(t) stays within 2 delta of the hull of its
    // ends, delta = |R(t) - R(t0)| |S(t) p| <= 2 sin(dtheta / 2) r (with 10 % to spare for the
    // normalised lerp of nearly equal rotations).
    const float dtheta = 1.1f * theta / float(sub);
    const float pad = 2.0f * 2.0f * std::sin(std::min(dtheta, kPi) * 0.5f) * r;
    const float span = 1.0f / float(n - 1);
    Aabb prev = step_box(motion_transform_at(steps, n, float(k) * span));
    for (int j = 1; j <= sub; ++j) {
      const float time = (float(k) + float(j) / float(sub)) * span;
      const Aabb cur = step_box(motion_transform_at(steps, n, std::min(time, 1.0f)));
      Aabb seg = prev;
      seg.grow(cur);
      seg.lo = seg.lo - Vec3(pad);
      seg.hi = seg.hi + Vec3(pad);
      out.grow(seg);
      prev = cur;
    }
  }
  return out;
}

void ShutterTable::set_curve(const std::vector<float>& curve) {
  // Cycles' shutter_curve_eval over kSize - 1 evenly spaced times, its CDF, then that CDF
  // inverted at kSize midpoints (util_cdf_inverted); zero or negative-only curves: a box.
  bool any = false;
  for (float v : curve) any = any || (std::isfinite(v) && v != 0.0f);
  const auto eval = [&](float x) -> float {
    if (!any) return 1.0f;
    const int size = int(curve.size());
    x = clampf(x, 0.0f, 1.0f) * float(size) - 1.0f;
    const int index = std::max(int(x), 0);
    const float frac = x - float(int(x));
    const auto at = [&](int i) { return std::isfinite(curve[size_t(i)]) ? curve[size_t(i)] : 0.0f; };
    if (index < size - 1) return at(index) + frac * (at(index + 1) - at(index));
    return at(size - 1);
  };
  const int res = kSize - 1;
  std::vector<float> cdf(size_t(res) + 1);
  cdf[0] = 0.0f;
  for (int i = 0; i < res; ++i) {
    const float x = float(i) / float(res - 1);
    cdf[size_t(i) + 1] = cdf[size_t(i)] + std::fabs(eval(x));
  }
  const float fac = cdf[size_t(res)] == 0.0f ? 0.0f : 1.0f / cdf[size_t(res)];
  for (float& c : cdf) c *= fac;
  cdf[size_t(res)] = 1.0f;
  const int cdf_size = res + 1;
  for (int i = 0; i < kSize; ++i) {
    const float x = (float(i) + 0.5f) / float(kSize);
    int index = int(std::upper_bound(cdf.begin(), cdf.end(), x) - cdf.begin()) - 1;
    float t;
    if (index < cdf_size - 1) {
      t = (x - cdf[size_t(index)]) / (cdf[size_t(index) + 1] - cdf[size_t(index)]);
    } else {
      t = 0.0f;
      index = kSize;
    }
    table_[i] = clampf((float(index) + t) / float(kSize), 0.0f, 1.0f);
  }
}

}  // namespace pl
