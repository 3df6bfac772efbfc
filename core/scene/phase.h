// Participating media: the phase functions (Henyey-Greenstein, Draine, Fournier-Forand) and analytic
// (spectral) free-flight sampling, as pbrt and Cycles' homogeneous volumes do it.
#pragma once
#include <algorithm>
#include <cmath>

#include "scene/bsdf.h"

namespace pl {

// Cycles keeps |g| below 1 so that the lobe stays a finite function.
inline float clamp_phase_g(float g) {
  if (!std::isfinite(g)) return 0.0f;
  return std::copysign(std::min(std::fabs(g), 1.0f - 1e-3f), g);
}

// Density over the sphere of a scattered direction whose cosine to the propagation direction
// is cos_t (g > 0: forward scattering).
inline float hg_phase(float g, float cos_t) {
  const float d = 1.0f + g * g - 2.0f * g * cos_t;
  return (1.0f - g * g) / (4.0f * kPi * d * std::sqrt(std::max(d, 1e-12f)));
}

// A direction about `dir` (unit, the propagation direction) distributed as hg_phase; returns
// it with its pdf (which is also the phase function's value: the sampling is exact).
inline Vec3 hg_sample(float g, Vec3 dir, float u1, float u2, float& pdf) {
  float cos_t;
  if (std::fabs(g) < 1e-3f) {
    cos_t = 1.0f - 2.0f * u1;
  } else {
    const float s = (1.0f - g * g) / (1.0f + g - 2.0f * g * u1);
    cos_t = (1.0f + g * g - s * s) / (2.0f * g);
  }
  cos_t = std::clamp(cos_t, -1.0f, 1.0f);
  const float sin_t = std::sqrt(std::max(0.0f, 1.0f - cos_t * cos_t));
  const float phi = 2.0f * kPi * u2;
  const Frame f = Frame::from_normal(dir);
  pdf = hg_phase(g, cos_t);
  return f.to_world({sin_t * std::cos(phi), sin_t * std::sin(phi), cos_t});
}

// The Volume Scatter node's phase functions (Cycles 4.5's closures), a closed set switched on
// `kind`. Rayleigh is Draine with g 0 and alpha 1 (the same function); Mie is a mixture of an
// HG and a Draine lobe (mie_fit), so it is two phases of one medium.
enum class PhaseKind : uint8_t { HenyeyGreenstein, Draine, FournierForand };
struct Phase {
  PhaseKind kind = PhaseKind::HenyeyGreenstein;
  float g = 0.0f;      // HG, Draine: the anisotropy
  float alpha = 0.0f;  // Draine: the weight of cos^2 (0: HG)
  float ff_n = 0.0f, ff_v = 0.0f, ff_c = 0.0f;  // Fournier-Forand: IOR, exponent v, the cos^2 term
  bool operator==(const Phase& o) const {
    return kind == o.kind && g == o.g && alpha == o.alpha && ff_n == o.ff_n && ff_v == o.ff_v && ff_c == o.ff_c;
  }
  bool operator!=(const Phase& o) const { return !(*this == o); }
};

inline Phase make_hg_phase(float g) {
  Phase p;
  p.g = clamp_phase_g(g);
  return p;
}
// Draine (2003): HG(g) (1 + alpha cos^2) / (1 + alpha (1 + 2 g^2) / 3). Cycles clamps |g| below
// 1 and leaves alpha as given; a negative alpha would make a negative density: 0 here. alpha
// about 0 is HG; |g| below 1e-3 is 0 (the CDF's terms cancel as 1 / g^3).
inline Phase make_draine_phase(float g, float alpha) {
  if (!std::isfinite(alpha) || alpha < 1e-3f) return make_hg_phase(g);
  Phase p;
  p.kind = PhaseKind::Draine;
  p.g = clamp_phase_g(g);
  if (std::fabs(p.g) < 1e-3f) p.g = 0.0f;
  p.alpha = std::min(alpha, 1e6f);
  return p;
}
inline Phase make_rayleigh_phase() { return make_draine_phase(0.0f, 1.0f); }
// Fournier-Forand (1999) from the backscatter fraction B and the particles' IOR, as Cycles'
// setup: B clamped to (0, 0.5) (Cycles: below 0.5; B 0 would be a delta lobe), IOR above 1.
inline Phase make_fournier_forand_phase(float backscatter, float ior) {
  double b = std::isfinite(backscatter) ? std::fabs(double(backscatter)) : 0.1;
  b = std::clamp(b, 1e-4, 0.5 - 1e-3);
  const double n = std::isfinite(ior) ? std::max(double(ior), 1.0 + 1e-3) : 1.33;
  const auto delta = [n](double s) { return 4.0 * s / (3.0 * (n - 1.0) * (n - 1.0)); };
  const double d90 = delta(0.5), d180 = delta(1.0);
  const double v = -std::log(2.0 * b * (d90 - 1.0) + 1.0) / std::log(d90);
  Phase p;
  p.kind = PhaseKind::FournierForand;
  p.ff_n = float(n);
  p.ff_v = float(v);
  p.ff_c = float((std::pow(d180, -v) - 1.0) / (d180 - 1.0));
  return p;
}

// Cycles' fit of the Mie phase function of water droplets of diameter d (micrometres) as
// (1 - w) HG(g_hg) + w Draine(g_d, alpha) (Jendersie and d'Eon 2023, "An approximate Mie
// scattering function for fog and cloud rendering", supplemental eqs. 7-22).
struct MieFit {
  float g_hg, g_d, alpha, w;
};
inline MieFit mie_fit(float diameter) {
  const double d = std::isfinite(diameter) ? std::max(double(diameter), 0.0) : 0.0;
  MieFit m;
  if (d <= 0.1) {
    m.g_hg = float(13.8 * d * d);
    m.g_d = float(1.1456 * d * std::sin(9.29044 * d));
    m.alpha = 250.0f;
    m.w = float(0.252977 - 312.983 * std::pow(d, 4.3));
  } else if (d < 1.5) {
    const double l = std::log(d);
    m.g_hg = float(0.862 - 0.143 * l * l);
    const double a = (l - 0.238604) * (l + 1.00667), b = 0.507522 - 0.15677 * l;
    const double c = 1.19692 * std::cos(a / b) + 1.37932 * l + 0.0625835;
    m.g_d = float(0.379685 * std::cos(c) + 0.344213);
    m.alpha = 250.0f;
    m.w = float(0.146209 * std::cos(3.38707 * l + 2.11193) + 0.316072 + 0.0778917 * l);
  } else if (d < 5.0) {
    const double l = std::log(d), ll = std::log(l);
    m.g_hg = float(0.0604931 * ll + 0.940256);
    m.g_d = float(0.500411 - 0.081287 / (-2.0 * l + std::tan(l) + 1.27551));
    m.alpha = float(7.30354 * l + 6.31675);
    m.w = float(0.026914 * (l - std::cos(5.68947 * (ll - 0.0292149))) + 0.3764);
  } else {
    m.g_hg = float(std::exp(-0.0990567 / (d - 1.67154)));
    m.g_d = float(std::exp(-2.20679 / (d + 3.91029) - 0.428934));
    m.alpha = float(std::exp(3.62489 - 8.29288 / (d + 5.52825)));
    m.w = float(std::exp(-0.599085 / (d - 0.641583) - 0.665888));
  }
  m.w = std::clamp(m.w, 0.0f, 1.0f);
  return m;
}

namespace phase_detail {
constexpr double kPiD = 3.14159265358979323846;
// Draine's CDF over cos theta (double: its closed form cancels as 1 / g^3) and its density.
inline double draine_cdf(double g, double alpha, double mu, double& dens) {
  const double norm = 1.0 + alpha * (1.0 + 2.0 * g * g) / 3.0;
  if (g == 0.0) {
    dens = 0.5 * (1.0 + alpha * mu * mu) / norm;
    return (0.5 * (mu + 1.0) + alpha * (mu * mu * mu + 1.0) / 6.0) / norm;
  }
  const double a = 1.0 + g * g, s = std::max(a - 2.0 * g * mu, 1e-300), s0 = (1.0 + g) * (1.0 + g);
  const double k = 1.0 - g * g;
  dens = 0.5 * k * (1.0 + alpha * mu * mu) / (s * std::sqrt(s)) / norm;
  const double hg = k / (2.0 * g) * (1.0 / std::sqrt(s) - 1.0 / (1.0 + g));
  // The integral of x^2 HG(x) dx: in s = 1 + g^2 - 2 g x it is a sum of powers of s.
  const auto G = [a](double t) {
    const double r = std::sqrt(t);
    return -2.0 * a * a / r - 4.0 * a * r + (2.0 / 3.0) * t * r;
  };
  const double x2 = -k / (16.0 * g * g * g) * (G(s) - G(s0));
  return (hg + alpha * x2) / norm;
}
// Fournier-Forand's density over the sphere at sin^2(theta / 2) = s, and its CDF from
// theta = 0 (the fraction scattered within theta), in double near the forward peak.
inline double ff_eval(const Phase& p, double s, double* cdf) {
  const double n = p.ff_n, v = p.ff_v, c3 = p.ff_c;
  const double mu = 1.0 - 2.0 * s;
  const double delta = 4.0 * s / (3.0 * (n - 1.0) * (n - 1.0));
  const double m_delta = 1.0 - delta;
  double pf, F;
  if (std::fabs(m_delta) < 1e-4) {  // the closed form's 0 / 0 at delta = 1: its Taylor expansion
    pf = v * ((v - 1.0) - (v + 1.0) / s) / (8.0 * kPiD) +
         v * (v + 1.0) * m_delta * (2.0 * (v - 1.0) - (2.0 * v + 1.0) / s) / (24.0 * kPiD);
    F = 1.0 + v * (1.0 - s) * (1.0 - 0.5 * (v + 1.0) * m_delta);
  } else {
    const double dv = std::pow(delta, v), m_dv = 1.0 - dv;
    pf = (v * m_delta - m_dv + (delta * m_dv - v * m_delta) / s) / (4.0 * kPiD * m_delta * m_delta * dv);
    F = (1.0 - dv * delta - m_dv * s) / (m_delta * dv);
  }
  pf += c3 / (16.0 * kPiD) * (3.0 * mu * mu - 1.0);
  if (cdf) *cdf = F + c3 / 8.0 * mu * (1.0 - mu * mu);
  return pf;
}
// Solves F(x) = u for x in [lo, hi] (F increasing, f its derivative): Newton's steps, bisection
// where a step leaves the bracket.
template <class Fn>
inline double invert_cdf(Fn&& F, double u, double lo, double hi, double x) {
  for (int it = 0; it < 100; ++it) {
    double dens;
    const double r = F(x, dens) - u;
    if (r < 0.0) lo = x;
    else hi = x;
    double xn = dens > 0.0 ? x - r / dens : 0.5 * (lo + hi);
    if (!(xn > lo && xn < hi)) xn = 0.5 * (lo + hi);
    if (std::fabs(xn - x) < 1e-13 * std::max(1e-3, std::fabs(x)) || hi - lo < 1e-15) return xn;
    x = xn;
  }
  return x;
}
}  // namespace phase_detail

// The phase function's density over the sphere at cos_t (cosine to the propagation direction).
inline float phase_eval(const Phase& p, float cos_t) {
  switch (p.kind) {
    case PhaseKind::HenyeyGreenstein:
      return hg_phase(p.g, cos_t);
    case PhaseKind::Draine: {
      const float g2 = p.g * p.g, d = 1.0f + g2 - 2.0f * p.g * cos_t;
      return (1.0f - g2) * (1.0f + p.alpha * cos_t * cos_t) /
             ((1.0f + p.alpha * (1.0f + 2.0f * g2) / 3.0f) * 4.0f * kPi * d * std::sqrt(std::max(d, 1e-12f)));
    }
    case PhaseKind::FournierForand: {
      const double s = 0.5 * (1.0 - double(std::clamp(cos_t, -1.0f, 1.0f)));
      if (!(s > 0.0)) return 0.0f;  // the forward peak itself: infinite (Cycles: 0)
      return float(std::max(phase_detail::ff_eval(p, s, nullptr), 0.0));
    }
  }
  return 0.0f;
}

// A direction about unit `dir` distributed as phase_eval (exact: by the inverse of the closed-
// form CDF, numerically where it has no closed inverse), with its pdf (the phase's value).
inline Vec3 phase_sample(const Phase& p, Vec3 dir, float u1, float u2, float& pdf) {
  if (p.kind == PhaseKind::HenyeyGreenstein) return hg_sample(p.g, dir, u1, u2, pdf);
  float cos_t, sin_t;
  if (p.kind == PhaseKind::Draine) {
    const double g = p.g, alpha = p.alpha;
    float hg_pdf;
    // (HG's sample runs from cos 1 at u 0: the guess is its sample of 1 - u)
    const double guess = double(hg_sample(p.g, Vec3(0.0f, 0.0f, 1.0f), 1.0f - u1, 0.0f, hg_pdf).z);
    const double mu = phase_detail::invert_cdf(
        [&](double x, double& d) { return phase_detail::draine_cdf(g, alpha, x, d); }, double(u1), -1.0, 1.0,
        std::clamp(guess, -0.999999, 0.999999));
    cos_t = float(std::clamp(mu, -1.0, 1.0));
    sin_t = float(std::sqrt(std::max(0.0, 1.0 - mu * mu)));
    pdf = phase_eval(p, cos_t);
  } else {
    // In s = sin^2(theta / 2): the CDF from theta = 0 rises steeply at s = 0 (the peak).
    const double s = phase_detail::invert_cdf(
        [&](double x, double& d) {
          double F;
          d = 4.0 * phase_detail::kPiD * phase_detail::ff_eval(p, std::max(x, 1e-300), &F);
          return F;
        },
        double(u1), 0.0, 1.0, 0.5 * double(u1) * double(u1));
    cos_t = float(1.0 - 2.0 * s);
    sin_t = float(2.0 * std::sqrt(std::max(0.0, s * (1.0 - s))));
    pdf = s > 0.0 ? float(std::max(phase_detail::ff_eval(p, s, nullptr), 0.0)) : 0.0f;
  }
  const float phi = 2.0f * kPi * u2;
  const Frame f = Frame::from_normal(dir);
  return f.to_world({sin_t * std::cos(phi), sin_t * std::sin(phi), cos_t});
}

// exp(-sigma * t) per channel; a channel with sigma 0 transmits everything, even to infinity.
inline Vec3 medium_transmittance(Vec3 sigma, float t) {
  const auto tr = [t](float s) { return s > 0.0f ? std::exp(-s * t) : 1.0f; };
  if (sigma.x == sigma.y && sigma.y == sigma.z) return Vec3(tr(sigma.x));  // grey: one exp, same value
  return {tr(sigma.x), tr(sigma.y), tr(sigma.z)};
}

// Free-flight distance in a homogeneous medium of extinction sigma_t: a channel chosen
// uniformly by u_channel, then an exponential distance in it. The pdf of the distance (and
// the probability of passing `t_max`) is the average over channels (one-sample MIS of the
// channels, as pbrt-v3's HomogeneousMedium and Cycles).
inline float sample_free_flight(Vec3 sigma_t, float u_channel, float u) {
  const int c = std::min(int(u_channel * 3.0f), 2);
  const float s = c == 0 ? sigma_t.x : c == 1 ? sigma_t.y : sigma_t.z;
  if (!(s > 0.0f)) return INFINITY;
  return -std::log1p(-std::min(u, 1.0f - 1e-7f)) / s;
}
// The distance density at t (a scattering event there) ...
inline float free_flight_pdf(Vec3 sigma_t, float t) {
  const Vec3 T = medium_transmittance(sigma_t, t);
  return (sigma_t.x * T.x + sigma_t.y * T.y + sigma_t.z * T.z) * (1.0f / 3.0f);
}
// ... and the probability of flying past t.
inline float free_flight_survival(Vec3 sigma_t, float t) {
  const Vec3 T = medium_transmittance(sigma_t, t);
  return (T.x + T.y + T.z) * (1.0f / 3.0f);
}

// Equiangular distances (Kulla and Fajardo 2012), Cycles' volume sampling towards a light: on
// the ray o + d t (d unit), t in [t_min, t_max] (t_max may be infinite), the density of t is
// proportional to 1 / |x(t) - c|^2 for a point c on a light, so scattering points crowd where
// the light is close; 0 outside the interval. EquiangularSegment::valid is false where c lies
// on the ray's line (no finite density) or the interval is empty.
struct EquiangularSegment {
  float delta = 0.0f;  // t of the point on the line closest to c
  float dist = 0.0f;   // c's distance from the line
  float theta_a = 0.0f, theta_b = 0.0f;
  float t_min = 0.0f, t_max = 0.0f;
  bool valid = false;
};
inline EquiangularSegment equiangular_segment(Vec3 o, Vec3 d, float t_min, float t_max, Vec3 c) {
  EquiangularSegment e;
  e.delta = dot(c - o, d);
  const Vec3 off = c - (o + d * e.delta);
  e.dist = length(off);
  const float scale = std::max(std::fabs(e.delta), length(c - o));
  if (!(e.dist > 1e-5f * scale) || !(t_max > t_min) || !(t_min >= 0.0f) || !std::isfinite(e.delta)) return e;
  e.t_min = t_min;
  e.t_max = t_max;
  e.theta_a = std::atan2(t_min - e.delta, e.dist);
  e.theta_b = std::isfinite(t_max) ? std::atan2(t_max - e.delta, e.dist) : 0.5f * kPi;
  e.valid = e.theta_b > e.theta_a;
  return e;
}
inline EquiangularSegment equiangular_segment(Vec3 o, Vec3 d, float t_max, Vec3 c) {
  return equiangular_segment(o, d, 0.0f, t_max, c);
}
inline float sample_equiangular(const EquiangularSegment& e, float u) {
  const float th = e.theta_a + u * (e.theta_b - e.theta_a);
  return e.delta + e.dist * std::tan(th);
}
inline float equiangular_pdf(const EquiangularSegment& e, float t) {
  if (!e.valid || !(t >= e.t_min && t <= e.t_max)) return 0.0f;
  const float x = t - e.delta;
  return e.dist / ((e.theta_b - e.theta_a) * (e.dist * e.dist + x * x));
}

}  // namespace pl
