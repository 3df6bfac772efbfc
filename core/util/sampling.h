// Warps from the unit square and small Monte Carlo helpers.
#pragma once
#include <algorithm>
#include <cmath>
#include <vector>

#if defined(__AVX__)
#include <immintrin.h>
#endif

#include "util/math.h"

namespace pl {

struct Vec2 {
  float x = 0, y = 0;
};

// Concentric mapping (Shirley-Chiu): low distortion, keeps stratification.
inline Vec2 sample_disk_concentric(Vec2 u) {
  const float a = 2.0f * u.x - 1.0f, b = 2.0f * u.y - 1.0f;
  if (a == 0.0f && b == 0.0f) return {0.0f, 0.0f};
  float r, phi;
  if (std::fabs(a) > std::fabs(b)) {
    r = a;
    phi = (kPi / 4.0f) * (b / a);
  } else {
    r = b;
    phi = (kPi / 2.0f) - (kPi / 4.0f) * (a / b);
  }
  return {r * std::cos(phi), r * std::sin(phi)};
}

// Cosine-weighted hemisphere around +Z; pdf = cos(theta) / pi.
inline Vec3 sample_cosine_hemisphere(Vec2 u) {
  const Vec2 d = sample_disk_concentric(u);
  const float z = std::sqrt(std::max(0.0f, 1.0f - d.x * d.x - d.y * d.y));
  return {d.x, d.y, z};
}

// Uniform barycentrics on a triangle (Heitz 2019: area preserving, no sqrt, low distortion).
inline void sample_triangle_uniform(Vec2 u, float& b1, float& b2) {
  if (u.y > u.x) {
    b1 = u.x * 0.5f;
    b2 = u.y - b1;
  } else {
    b2 = u.y * 0.5f;
    b1 = u.x - b2;
  }
}

// Spherical triangles (Arvo 1995, "Stratified sampling of spherical triangles"): directions
// uniform in the solid angle a triangle subtends. Sampling emissive triangles this way keeps the
// estimate bounded near a light, where uniform area sampling has a 1/r^2 tail (fireflies on
// walls next to the light). Computed in double: the angles lose all precision in float when the
// triangle is small or nearly edge-on, and the extra cost is a few dozen flops per light sample.
struct DVec3 {
  double x = 0, y = 0, z = 0;
  DVec3() = default;
  DVec3(double a, double b, double c) : x(a), y(b), z(c) {}
  explicit DVec3(Vec3 v) : x(v.x), y(v.y), z(v.z) {}
  DVec3 operator+(DVec3 o) const { return {x + o.x, y + o.y, z + o.z}; }
  DVec3 operator-(DVec3 o) const { return {x - o.x, y - o.y, z - o.z}; }
  DVec3 operator*(double s) const { return {x * s, y * s, z * s}; }
  Vec3 to_float() const { return {float(x), float(y), float(z)}; }
};
inline double ddot(DVec3 a, DVec3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
inline DVec3 dcross(DVec3 a, DVec3 b) { return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x}; }
inline double dlength(DVec3 a) { return std::sqrt(ddot(a, a)); }
// Normalised, or false when v is zero (or not finite).
inline bool dnormalize(DVec3& v) {
  const double l = dlength(v);
  if (!(l > 0.0) || !std::isfinite(l)) return false;
  v = v * (1.0 / l);
  return true;
}

// Cephes' atan kernel: y + atan(x) for the range-reduced |x| <= 0.66 (a 4/5 rational function);
// `extra` carries the low bits of the reduction's offset y.
inline double atan_reduced(double x, double y, double extra) {
  constexpr double P0 = -8.750608600031904122785e-1, P1 = -1.615753718733365076637e1,
                   P2 = -7.500855792314704667340e1, P3 = -1.228866684490136173410e2,
                   P4 = -6.485021904942025371773e1;
  constexpr double Q0 = 2.485846490142306297962e1, Q1 = 1.650270098316988542046e2,
                   Q2 = 4.328810604912902668951e2, Q3 = 4.853903996359136964868e2,
                   Q4 = 1.945506571482613964425e2;
  const double z = x * x;
  const double p = (((P0 * z + P1) * z + P2) * z + P3) * z + P4;
  const double q = ((((z + Q0) * z + Q1) * z + Q2) * z + Q3) * z + Q4;
  return y + (x * (z * p / q) + x + extra);
}

constexpr double kAtanPiOver2 = 1.57079632679489661923, kAtanPiOver4 = 0.785398163397448309616;
constexpr double kAtanMoreBits = 6.123233995736765886130e-17;  // pi/2 - double(pi/2)

// atan(x) for x >= 0 in double, to within 3e-16 relative (Cephes' atan: range reduction to
// |x| <= 0.66, then atan_reduced). Inline, it is a third of libm's atan2, which was a tenth of
// every light sample.
inline double atan_nonneg(double x) {
  if (x > 2.41421356237309504880) return atan_reduced(-1.0 / x, kAtanPiOver2, kAtanMoreBits);  // tan(3 pi / 8)
  if (x > 0.66) return atan_reduced((x - 1.0) / (x + 1.0), kAtanPiOver4, 0.5 * kAtanMoreBits);
  return atan_reduced(x, 0.0, 0.0);
}

// atan(a / b) for a >= 0, b > 0: atan_nonneg with the quotient folded into its range reduction
// (one division fewer on the dependency chain).
inline double atan_ratio(double a, double b) {
  // Selects rather than branches: the reduction's case is data-dependent (mispredicted).
  const bool big = a > 2.41421356237309504880 * b, mid = a > 0.66 * b;  // tan(3 pi / 8)
  const double num = big ? -b : mid ? a - b : a, den = big ? a : mid ? a + b : b;
  const double y = big ? kAtanPiOver2 : mid ? kAtanPiOver4 : 0.0;
  const double extra = big ? kAtanMoreBits : mid ? 0.5 * kAtanMoreBits : 0.0;
  return atan_reduced(num / den, y, extra);
}

// sin and cos of 0 <= x < 2^20 in double, to within 3e-16 (Cephes' sin/cos: reduction by pi/4
// in three parts, then degree-13/14 polynomials), inline instead of libm's sincos call.
inline void sincos_nonneg(double x, double& s, double& c) {
  constexpr double S0 = 1.58962301576546568060e-10, S1 = -2.50507477628578072866e-8,
                   S2 = 2.75573136213857245213e-6, S3 = -1.98412698295895385996e-4,
                   S4 = 8.33333333332211858878e-3, S5 = -1.66666666666666307295e-1;
  constexpr double C0 = -1.13585365213876817300e-11, C1 = 2.08757008419747316778e-9,
                   C2 = -2.75573141792967388112e-7, C3 = 2.48015872888517045348e-5,
                   C4 = -1.38888888888730564116e-3, C5 = 4.16666666666665929218e-2;
  constexpr double DP1 = 7.85398125648498535156e-1, DP2 = 3.77489470793079817668e-8,
                   DP3 = 2.69515142907905952645e-15;  // pi/4 in three parts
  int j = int(x * 1.27323954473516268615);  // octant: x * 4 / pi
  double y = double(j);
  if (j & 1) {  // to the nearest multiple of pi/2: |z| <= pi/4
    ++j;
    y += 1.0;
  }
  j &= 7;
  const double z = ((x - y * DP1) - y * DP2) - y * DP3;
  const double zz = z * z;
  const double ps = z + z * zz * (((((S0 * zz + S1) * zz + S2) * zz + S3) * zz + S4) * zz + S5);
  const double pc = 1.0 - 0.5 * zz + zz * zz * (((((C0 * zz + C1) * zz + C2) * zz + C3) * zz + C4) * zz + C5);
  double sign_s = 1.0, sign_c = 1.0;
  if (j > 3) {
    j -= 4;
    sign_s = -1.0;
    sign_c = -1.0;
  }
  if (j > 1) sign_c = -sign_c;
  const bool swap = j == 1 || j == 2;
  s = sign_s * (swap ? pc : ps);
  c = sign_c * (swap ? ps : pc);
}

// atan2(y, x) for y >= 0 (an angle in [0, pi]); NaN when an argument is NaN.
inline double atan2_nonneg(double y, double x) {
  if (x > 0.0) return atan_nonneg(y / x);
  if (x < 0.0) return 3.14159265358979323846 - atan_nonneg(y / -x);
  if (x == 0.0 && y >= 0.0) return y > 0.0 ? 1.57079632679489661923 : 0.0;
  return y + x;  // NaN
}

// A triangle as seen from a point: unit directions to its corners and its solid angle.
struct SphericalTriangle {
  DVec3 a, b, c;
  double solid_angle = 0.0;  // 0: degenerate, or the point lies in the triangle's plane
};

// Solid angle by Van Oosterom & Strackee (1983): one atan2, and the same value sampling uses
// for the sub-triangle areas, so the density is exactly 1 / solid_angle.
// From the unit directions to the corners (several triangles sharing corners normalise them once).
inline double spherical_triangle_solid_angle(DVec3 a, DVec3 b, DVec3 c) {
  const double triple = std::fabs(ddot(a, dcross(b, c)));
  const double denom = 1.0 + ddot(a, b) + ddot(b, c) + ddot(c, a);
  const double omega = 2.0 * atan2_nonneg(triple, denom);
  return std::isfinite(omega) && omega > 0.0 ? omega : 0.0;
}

inline SphericalTriangle spherical_triangle(Vec3 p, Vec3 v0, Vec3 v1, Vec3 v2) {
  SphericalTriangle t;
  t.a = DVec3(v0) - DVec3(p);
  t.b = DVec3(v1) - DVec3(p);
  t.c = DVec3(v2) - DVec3(p);
  if (!dnormalize(t.a) || !dnormalize(t.b) || !dnormalize(t.c)) return t;
  t.solid_angle = spherical_triangle_solid_angle(t.a, t.b, t.c);
  return t;
}

// A unit direction (to rounding) uniform over the triangle's solid angle, for u in [0,1]^2
// (Arvo's inversion, with the angle at corner a from the edge planes' normals: one sincos and
// one atan2 in all, both inline).
// False when the triangle is degenerate as seen from the point.
// (Always inlined: its one caller in the light sampler is large, and as a call it cost ~40
// instructions per light sample in argument passing and spills.)
[[gnu::always_inline]] inline bool sample_spherical_triangle(const SphericalTriangle& t, Vec2 u, DVec3& dir) {
  if (!(t.solid_angle > 0.0)) return false;
  const DVec3 &a = t.a, &b = t.b, &c = t.c;
  // Interior angle alpha at a: between the planes through (a, b) and (a, c).
  DVec3 n_ab = dcross(a, b), n_ca = dcross(c, a);
  if (!dnormalize(n_ab) || !dnormalize(n_ca)) return false;
  const double cos_alpha = -ddot(n_ab, n_ca);
  const double sin_alpha = dlength(dcross(n_ab, n_ca));
  if (!(sin_alpha > 0.0)) return false;
  // The sub-triangle (a, b, c') of area u.x * A, with c' on the arc from a to c: its area plus pi
  // is alpha + beta + gamma', and phi = A' - alpha below.
  const double sub = double(u.x) * t.solid_angle;
  double sin_sub, cos_sub;
  sincos_nonneg(sub, sin_sub, cos_sub);  // u.x in [0, 1], so 0 <= sub <= 2 pi
  // sin/cos of (A' + pi) - alpha, using sin(A' + pi) = -sin A', cos(A' + pi) = -cos A'.
  const double sin_phi = -sin_sub * cos_alpha + cos_sub * sin_alpha;
  const double cos_phi = -cos_sub * cos_alpha - sin_sub * sin_alpha;
  const double k1 = cos_phi + cos_alpha;
  const double k2 = sin_phi - sin_alpha * ddot(a, b);
  double cos_b = (k2 + (k2 * cos_phi - k1 * sin_phi) * cos_alpha) / ((k2 * sin_phi + k1 * cos_phi) * sin_alpha);
  if (!std::isfinite(cos_b)) return false;
  cos_b = std::clamp(cos_b, -1.0, 1.0);
  const double sin_b = std::sqrt(std::max(0.0, 1.0 - cos_b * cos_b));
  DVec3 c_perp = c - a * ddot(c, a);
  if (!dnormalize(c_perp)) return false;
  const DVec3 c2 = a * cos_b + c_perp * sin_b;
  // Then uniformly in solid angle along the arc from b towards c'.
  const double cos_t = 1.0 - double(u.y) * (1.0 - ddot(c2, b));
  const double sin_t = std::sqrt(std::max(0.0, 1.0 - cos_t * cos_t));
  DVec3 c2_perp = c2 - b * ddot(c2, b);
  if (!dnormalize(c2_perp)) return false;
  // Unit to rounding already (b and c2_perp are orthonormal): no third normalisation.
  dir = b * cos_t + c2_perp * sin_t;
  return std::isfinite(dir.x) && std::isfinite(dir.y) && std::isfinite(dir.z);
}

// atan(a / b) for b > 0 and any a (odd in a), inline.
inline double atan_signed_ratio(double a, double b) { return std::copysign(atan_ratio(std::fabs(a), b), a); }

#if defined(__AVX__)
// atan_signed_ratio of four pairs at once (atan_ratio and atan_reduced lane by lane, the same
// operations in the same order: the same bits).
[[gnu::always_inline]] inline void atan_signed_ratio4(__m256d a_signed, __m256d b, double* out) {
  const __m256d sign = _mm256_set1_pd(-0.0);
  const __m256d a = _mm256_andnot_pd(sign, a_signed);
  const __m256d big = _mm256_cmp_pd(a, _mm256_mul_pd(_mm256_set1_pd(2.41421356237309504880), b), _CMP_GT_OQ);
  const __m256d mid = _mm256_cmp_pd(a, _mm256_mul_pd(_mm256_set1_pd(0.66), b), _CMP_GT_OQ);
  // blendv(x, y, m): y where m.
  const __m256d num = _mm256_blendv_pd(_mm256_blendv_pd(a, _mm256_sub_pd(a, b), mid), _mm256_xor_pd(b, sign), big);
  const __m256d den = _mm256_blendv_pd(_mm256_blendv_pd(b, _mm256_add_pd(a, b), mid), a, big);
  const __m256d y = _mm256_blendv_pd(_mm256_blendv_pd(_mm256_setzero_pd(), _mm256_set1_pd(kAtanPiOver4), mid),
                                     _mm256_set1_pd(kAtanPiOver2), big);
  const __m256d extra = _mm256_blendv_pd(
      _mm256_blendv_pd(_mm256_setzero_pd(), _mm256_set1_pd(0.5 * kAtanMoreBits), mid), _mm256_set1_pd(kAtanMoreBits), big);
  const __m256d x = _mm256_div_pd(num, den);
  const auto c = [](double v) { return _mm256_set1_pd(v); };
  const __m256d z = _mm256_mul_pd(x, x);
  __m256d p = _mm256_add_pd(_mm256_mul_pd(c(-8.750608600031904122785e-1), z), c(-1.615753718733365076637e1));
  p = _mm256_add_pd(_mm256_mul_pd(p, z), c(-7.500855792314704667340e1));
  p = _mm256_add_pd(_mm256_mul_pd(p, z), c(-1.228866684490136173410e2));
  p = _mm256_add_pd(_mm256_mul_pd(p, z), c(-6.485021904942025371773e1));
  __m256d q = _mm256_add_pd(z, c(2.485846490142306297962e1));
  q = _mm256_add_pd(_mm256_mul_pd(q, z), c(1.650270098316988542046e2));
  q = _mm256_add_pd(_mm256_mul_pd(q, z), c(4.328810604912902668951e2));
  q = _mm256_add_pd(_mm256_mul_pd(q, z), c(4.853903996359136964868e2));
  q = _mm256_add_pd(_mm256_mul_pd(q, z), c(1.945506571482613964425e2));
  const __m256d t = _mm256_add_pd(_mm256_add_pd(_mm256_mul_pd(x, _mm256_div_pd(_mm256_mul_pd(z, p), q)), x), extra);
  const __m256d r = _mm256_add_pd(y, t);
  _mm256_storeu_pd(out, _mm256_or_pd(_mm256_andnot_pd(sign, r), _mm256_and_pd(sign, a_signed)));
}
#endif

// Spherical rectangles (Urena, Fajardo, King 2013, "An area-preserving parametrization for
// spherical rectangles"): directions uniform in the solid angle of a rectangle, for rectangle
// lights close to the shaded point. In double for the same reasons as the triangles.
// In the rectangle's frame at the shaded point (x, y along its edges, z0 < 0 the signed distance
// to its plane) it is [x0, x1] x [y0, y1]; the interior angle at corner (x_i, y_j) is
// pi/2 -+ atan(x_i y_j / (|z0| r_ij)) (Urena's acos of the edge planes' normals, in closed
// form), so the solid angle and the warp's offset k take four inline atans instead of four
// normalised cross products and four acos.
// The part in the rectangle's frame. No default member initialisers: it is built per light sample
// and spherical_rect_local sets solid_angle first (zero-filling it cost a rep stos per sample);
// the other fields are meaningful only where solid_angle > 0.
struct SphericalRectLocal {
  double x0, x1, y0, y1, z0;  // the rectangle in that frame (z0 < 0)
  double b0, b1, k, q;        // q = 1 - b0^2
  double solid_angle;         // 0: degenerate, or the point lies in the rectangle's plane
};
struct SphericalRect : SphericalRectLocal {
  DVec3 o, x, y, z;  // the shaded point; the frame: x, y along the edges, z away from it
};

// The rectangle [x0, x0 + lx] x [y0, y0 + ly] at signed distance z0 (coordinates relative to the
// shaded point in an orthonormal frame with x, y along its edges); only r's local part is set.
[[gnu::always_inline]] inline void spherical_rect_local(double x0, double y0, double z0, double lx, double ly, SphericalRectLocal& r) {
  const double z = std::fabs(z0);
  r.solid_angle = 0.0;
  if (!(z > 0.0) || !(lx > 0.0) || !(ly > 0.0)) return;
  r.z0 = -z;
  r.x0 = x0;
  r.x1 = x0 + lx;
  r.y0 = y0;
  r.y1 = y0 + ly;
  const double z2 = z * z, sy0 = r.y0 * r.y0 + z2, sy1 = r.y1 * r.y1 + z2;
  const double xx0 = r.x0 * r.x0, xx1 = r.x1 * r.x1;
#if defined(__AVX__)
  // The four corners' atans side by side (lanes 00, 01, 10, 11): the scalar code's operations in
  // the same order, so bit for bit its results, with a quarter of the divisions and square roots.
  double a[4];
  atan_signed_ratio4(_mm256_mul_pd(_mm256_setr_pd(r.x0, r.x0, r.x1, r.x1), _mm256_setr_pd(r.y0, r.y1, r.y0, r.y1)),
                     _mm256_mul_pd(_mm256_set1_pd(z), _mm256_sqrt_pd(_mm256_add_pd(_mm256_setr_pd(xx0, xx0, xx1, xx1),
                                                                                   _mm256_setr_pd(sy0, sy1, sy0, sy1)))),
                     a);
  const double a00 = a[0], a01 = a[1], a10 = a[2], a11 = a[3];
#else
  const double a00 = atan_signed_ratio(r.x0 * r.y0, z * std::sqrt(xx0 + sy0));
  const double a01 = atan_signed_ratio(r.x0 * r.y1, z * std::sqrt(xx0 + sy1));
  const double a10 = atan_signed_ratio(r.x1 * r.y0, z * std::sqrt(xx1 + sy0));
  const double a11 = atan_signed_ratio(r.x1 * r.y1, z * std::sqrt(xx1 + sy1));
#endif
  // Angles g0..g3 at (x1,y0), (x1,y1), (x0,y1), (x0,y0); omega = sum - 2 pi, k = 2 pi - g2 - g3.
  const double omega = (a11 - a10) + (a00 - a01);
  r.k = 3.14159265358979323846 + (a01 - a00);
  const double inv0 = 1.0 / std::sqrt(sy0);
  r.b0 = -r.y0 * inv0;
  r.q = z2 * (inv0 * inv0);
  r.b1 = r.y1 / std::sqrt(sy1);
  r.solid_angle = std::isfinite(omega) && omega > 0.0 ? omega : 0.0;
}

// Corner c and orthogonal edges ex, ey, seen from p.
inline SphericalRect spherical_rect(Vec3 p, Vec3 c, Vec3 ex, Vec3 ey) {
  SphericalRect r;
  r.solid_angle = 0.0;
  r.o = DVec3(p);
  r.x = DVec3(ex);
  r.y = DVec3(ey);
  const double exl = dlength(r.x), eyl = dlength(r.y);
  if (!dnormalize(r.x) || !dnormalize(r.y)) return r;
  r.z = dcross(r.x, r.y);
  const DVec3 d = DVec3(c) - r.o;
  double z0 = ddot(d, r.z);
  if (z0 > 0.0) {  // z points away from the rectangle
    r.z = r.z * -1.0;
    z0 = -z0;
  }
  spherical_rect_local(ddot(d, r.x), ddot(d, r.y), z0, exl, eyl, r);
  return r;
}

// The frame coordinates (xu, yv) of a point of the rectangle whose direction from the shaded
// point is uniform in its solid angle, for u in [0, 1]^2 (u.x along x, u.y along y: stratified).
[[gnu::always_inline]] inline bool sample_spherical_rect_local(const SphericalRectLocal& r, Vec2 u, double& xu, double& yv) {
  if (!(r.solid_angle > 0.0)) return false;
  const double au = std::max(0.0, double(u.x) * r.solid_angle + r.k);  // in [0, 4 pi)
  double sin_au, cos_au;
  sincos_nonneg(au, sin_au, cos_au);
  // Urena's fu = (cos au b0 - b1) / sin au, cu = sign(fu) / sqrt(fu^2 + b0^2) and
  // xu = -cu z0 / sqrt(1 - cu^2), folded into one square root and one division (1 - b0^2 is
  // q = z0^2 / (y0^2 + z0^2), kept exact): xu = |z0| sin au sign(nu) / sqrt(nu^2 - q sin^2 au).
  const double nu = cos_au * r.b0 - r.b1;
  const double den = std::sqrt(std::max(0.0, nu * nu - r.q * (sin_au * sin_au)));
  xu = std::copysign(-r.z0 * std::fabs(sin_au), nu * sin_au) / den;
  if (std::isnan(xu)) return false;
  xu = std::clamp(xu, r.x0, r.x1);
  const double dd2 = xu * xu + r.z0 * r.z0, dd = std::sqrt(dd2);
  const double h0 = r.y0 / std::sqrt(dd2 + r.y0 * r.y0), h1 = r.y1 / std::sqrt(dd2 + r.y1 * r.y1);
  const double hv = h0 + double(u.y) * (h1 - h0), hv2 = hv * hv;
  yv = hv2 < 1.0 - 1e-12 ? hv * dd / std::sqrt(1.0 - hv2) : r.y1;
  yv = std::clamp(yv, r.y0, r.y1);
  return std::isfinite(xu) && std::isfinite(yv);
}

// A point of the rectangle whose direction from r.o is uniform in its solid angle.
inline bool sample_spherical_rect(const SphericalRect& r, Vec2 u, DVec3& point) {
  double xu, yv;
  if (!sample_spherical_rect_local(r, u, xu, yv)) return false;
  point = r.o + r.x * xu + r.y * yv + r.z * r.z0;
  return std::isfinite(point.x) && std::isfinite(point.y) && std::isfinite(point.z);
}

// x in [0,1) with density proportional to the line from a (at 0) to b (at 1), a, b >= 0
// (pbrt-v4's SampleLinear, in double: the ends may differ by many orders of magnitude).
inline double sample_linear(double u, double a, double b) {
  if (!(a + b > 0.0)) return u;
  if (u == 0.0 && a == 0.0) return 0.0;
  const double x = u * (a + b) / (a + std::sqrt((1.0 - u) * a * a + u * b * b));
  return std::min(x, 1.0 - 1e-9);
}

// A point of the unit square with density proportional to the bilinear interpolation of the
// corner weights w00 (0,0), w10 (1,0), w01 (0,1), w11 (1,1): the marginal in y, then x given y.
// The density is bilerp(x, y) / mean(w).
inline void sample_bilinear(Vec2 u, double w00, double w10, double w01, double w11, double& x, double& y) {
  y = sample_linear(u.y, w00 + w10, w01 + w11);
  x = sample_linear(u.x, w00 + (w01 - w00) * y, w10 + (w11 - w10) * y);
}

inline float power_heuristic(float pdf_a, float pdf_b) {
  const float a = pdf_a * pdf_a, b = pdf_b * pdf_b;
  if (std::isinf(a)) return 1.0f;
  return a + b > 0.0f ? a / (a + b) : 0.0f;
}

// Piecewise-constant 1-D distribution over discrete items, sampled by binary search on the CDF.
class Distribution1D {
 public:
  Distribution1D() = default;
  explicit Distribution1D(const std::vector<float>& weights) {
    const size_t n = weights.size();
    cdf_.assign(n + 1, 0.0);
    pmf_.assign(n, 0.0f);
    double sum = 0.0;
    for (size_t i = 0; i < n; ++i) {
      const float w = std::isfinite(weights[i]) && weights[i] > 0.0f ? weights[i] : 0.0f;
      sum += w;
      cdf_[i + 1] = sum;
    }
    total_ = sum;
    if (sum > 0.0) {
      for (size_t i = 0; i < n; ++i) pmf_[i] = static_cast<float>((cdf_[i + 1] - cdf_[i]) / sum);
      for (size_t i = 1; i <= n; ++i) cdf_[i] /= sum;
    }
  }
  bool empty() const { return total_ <= 0.0; }
  size_t size() const { return pmf_.size(); }
  float pmf(size_t i) const { return pmf_[i]; }
  // Returns an index with probability pmf(i); `u` in [0,1).
  size_t sample(float u) const {
    const double target = u;
    size_t lo = 0, hi = pmf_.size();
    while (lo + 1 < hi) {  // largest i with cdf[i] <= u, skipping zero-weight items
      const size_t mid = (lo + hi) / 2;
      if (cdf_[mid] <= target) lo = mid; else hi = mid;
    }
    while (lo + 1 < pmf_.size() && pmf_[lo] == 0.0f) ++lo;
    return lo;
  }
  // Same, also returning u's position inside the chosen item's interval, in [0, 1).
  size_t sample(float u, float& remapped) const {
    const size_t i = sample(u);
    const double w = cdf_[i + 1] - cdf_[i];
    remapped = w > 0.0 ? static_cast<float>(std::min(0.99999994, std::max(0.0, (u - cdf_[i]) / w))) : 0.5f;
    return i;
  }

 private:
  std::vector<double> cdf_;
  std::vector<float> pmf_;
  double total_ = 0.0;
};

}  // namespace pl
