// Heterogeneous media: a coarse grid of majorants (upper bounds of the extinction) over a
// medium's bounds, walked along a ray with a DDA (pbrt-v4's DDAMajorantIterator), and the
// null-scattering estimators that use it (docs/design/volumes.md): delta tracking for free
// flights, ratio tracking for transmittance. Both stay unbiased where the true extinction
// exceeds the majorant: the null coefficient sigma_n = majorant - sigma_t then goes negative
// and the weights keep its sign.
#pragma once
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <vector>

#include "geometry/aabb.h"
#include "scene/shader.h"
#include "util/rng.h"

namespace pl {

struct MajorantGrid {
  static constexpr int kRes = 16;
  Aabb bounds;               // world space (the medium's object bounds, slightly padded)
  std::vector<float> cells;  // kRes^3, x fastest: the largest extinction component in each
  float at(int x, int y, int z) const { return cells[size_t((z * kRes + y) * kRes + x)]; }
  bool empty() const { return cells.empty() || bounds.empty(); }
};

// The cells that the ray org + t dir (dir unit) crosses within [0, tmax], in order, one piece
// [a, b) with its majorant per call (pbrt-v4's DDAMajorantIterator).
struct MajorantCursor {
  const MajorantGrid* g = nullptr;
  int c[3], step[3], guard = 0;
  float next[3], delta[3], t = 0.0f, t1 = 0.0f;
  bool done = true;

  void start(const MajorantGrid& grid, Vec3 org, Vec3 dir, float tmax) {
    g = &grid;
    done = true;
    guard = 0;
    if (grid.empty()) return;
    float t0 = 0.0f;
    t1 = tmax;
    const float o[3] = {org.x, org.y, org.z}, d[3] = {dir.x, dir.y, dir.z};
    const float lo[3] = {grid.bounds.lo.x, grid.bounds.lo.y, grid.bounds.lo.z};
    const float hi[3] = {grid.bounds.hi.x, grid.bounds.hi.y, grid.bounds.hi.z};
    for (int a = 0; a < 3; ++a) {
      if (d[a] == 0.0f) {
        if (o[a] < lo[a] || o[a] > hi[a]) return;
        continue;
      }
      float ta = (lo[a] - o[a]) / d[a], tb = (hi[a] - o[a]) / d[a];
      if (ta > tb) std::swap(ta, tb);
      t0 = std::max(t0, ta);
      t1 = std::min(t1, tb);
    }
    if (!(t0 < t1)) return;
    constexpr int N = MajorantGrid::kRes;
    for (int a = 0; a < 3; ++a) {
      const float size = (hi[a] - lo[a]) / float(N);
      const float p = o[a] + d[a] * t0;
      c[a] = size > 0.0f ? std::clamp(int((p - lo[a]) / size), 0, N - 1) : 0;
      if (d[a] > 0.0f && size > 0.0f) {
        step[a] = 1;
        next[a] = t0 + (lo[a] + float(c[a] + 1) * size - p) / d[a];
        delta[a] = size / d[a];
      } else if (d[a] < 0.0f && size > 0.0f) {
        step[a] = -1;
        next[a] = t0 + (lo[a] + float(c[a]) * size - p) / d[a];
        delta[a] = -size / d[a];
      } else {
        step[a] = 0;
        next[a] = kInf;
        delta[a] = kInf;
      }
    }
    t = t0;
    done = false;
  }

  // The next piece; false once the ray has left the grid (or tmax).
  bool piece(float& a0, float& b0, float& mu) {
    constexpr int N = MajorantGrid::kRes;
    if (done || ++guard > 3 * N + 3) return false;
    const int a = next[0] < next[1] ? (next[0] < next[2] ? 0 : 2) : (next[1] < next[2] ? 1 : 2);
    const float tn = std::min(std::max(next[a], t), t1);
    a0 = t;
    b0 = tn;
    mu = g->at(c[0], c[1], c[2]);
    if (tn >= t1) {
      done = true;
      return true;
    }
    t = tn;
    c[a] += step[a];
    if (c[a] < 0 || c[a] >= N) done = true;
    next[a] += delta[a];
    return true;
  }
};

// Calls f(t0, t1, majorant) for the cells that the ray org + t dir (dir unit) crosses within
// [0, tmax], in order; stops where f returns false. Returns false if f stopped it.
template <class F>
bool walk_majorants(const MajorantGrid& g, Vec3 org, Vec3 dir, float tmax, F&& f) {
  MajorantCursor cur;
  cur.start(g, org, dir, tmax);
  float t0, t1, mu;
  while (cur.piece(t0, t1, mu))
    if (!f(t0, t1, mu)) return false;
  return true;
}

// The majorant of a stack of overlapping media (Cycles sums every volume a path is in): the
// heterogeneous layers' majorant grids plus a constant for the homogeneous ones. The sum of
// the layers' Poisson processes of tentative collisions is the one of the summed rate.
struct StackMajorants {
  static constexpr int kMax = 4;
  const MajorantGrid* grids[kMax] = {};
  int n = 0;
  float constant = 0.0f;  // the homogeneous layers' summed extinction, its largest channel
};

// As walk_majorants: pieces where none of the summed majorants changes, the sum as majorant.
template <class F>
bool walk_majorants(const StackMajorants& s, Vec3 org, Vec3 dir, float tmax, F&& f) {
  MajorantCursor cur[StackMajorants::kMax];
  float a[StackMajorants::kMax], b[StackMajorants::kMax], mu[StackMajorants::kMax];
  bool live[StackMajorants::kMax];
  for (int i = 0; i < s.n; ++i) {
    cur[i].start(*s.grids[i], org, dir, tmax);
    live[i] = cur[i].piece(a[i], b[i], mu[i]);
  }
  float t = 0.0f;
  while (t < tmax) {
    for (int i = 0; i < s.n; ++i)  // (pieces already behind t, empty ones included)
      while (live[i] && b[i] <= t) live[i] = cur[i].piece(a[i], b[i], mu[i]);
    float tn = tmax, m = s.constant;
    for (int i = 0; i < s.n; ++i) {
      if (!live[i]) continue;
      if (a[i] <= t) {
        m += mu[i];
        tn = std::min(tn, b[i]);
      } else {
        tn = std::min(tn, a[i]);  // (the ray enters this grid later)
      }
    }
    if (!(tn > t)) break;
    if (!f(t, tn, m)) return false;
    t = tn;
  }
  return true;
}

// The first tentative collision of the majorants' process along [0, tmax], conditioned on one
// happening there: density mu(t) exp(-tau(t)) / (1 - exp(-tau(tmax))), deterministic (no
// lookups), so a light sample can be taken in every segment a path crosses (Cycles takes one
// per segment too) instead of only where delta tracking scatters. False where the majorants
// hold no optical depth along the ray.
template <class Majorants>
bool sample_majorant_distance(const Majorants& g, Vec3 org, Vec3 dir, float tmax, float u, float& t, float& pdf) {
  // One walk, its pieces kept (a DDA over 16^3 cells crosses at most 51); a second walk only
  // where more pieces came.
  struct Piece {
    float a, b, mu;
  };
  constexpr int kKeep = 64;
  Piece kept[kKeep];
  int n = 0;
  bool all_kept = true;
  float total = 0.0f;
  walk_majorants(g, org, dir, tmax, [&](float a, float b, float mu) {
    if (!(mu > 0.0f) || !(b > a)) return true;
    total += mu * (b - a);
    if (n < kKeep)
      kept[n++] = {a, b, mu};
    else
      all_kept = false;
    return true;
  });
  if (!(total > 1e-6f) || !std::isfinite(total)) return false;
  const float norm = -std::expm1(-total);
  const float target = std::min(-std::log1p(-u * norm), total);
  float cum = 0.0f;
  Piece last{0.0f, 0.0f, 0.0f};
  bool found = false;
  const auto visit = [&](const Piece& p) {
    last = p;
    const float d = p.mu * (p.b - p.a);
    if (cum + d >= target) {
      t = std::clamp(p.a + (target - cum) / p.mu, p.a, p.b);
      pdf = p.mu * std::exp(-target) / norm;
      found = true;
      return false;
    }
    cum += d;
    return true;
  };
  if (all_kept) {
    for (int i = 0; i < n && visit(kept[i]); ++i) {
    }
  } else {
    walk_majorants(g, org, dir, tmax, [&](float a, float b, float mu) {
      return !(mu > 0.0f) || !(b > a) || visit(Piece{a, b, mu});
    });
  }
  if (!found && last.mu > 0.0f && last.b > last.a) {  // (the sum fell short of total by rounding)
    t = last.b;
    pdf = last.mu * std::exp(-total) / norm;
    found = true;
  }
  return found && pdf > 0.0f && std::isfinite(pdf);
}

// -log(1 - u) / mu: an exponential step of rate mu. (logf, not log1pf: 1 - u is exact for
// the 24-bit u of next_float, and logf costs a third of log1pf, which was 9 % of a smoke render.)
inline float exp_step(Pcg32& rng, float mu) { return -std::log(1.0f - rng.next_float()) / mu; }

// The tentative collisions of rate majorant along [0, tmax], in order: f(t, mu) at each, which
// returns false to stop. Returns false when f stopped, or after kMaxCollisions collisions over
// the whole walk (counted in `steps`: a majorant far too small, a runaway); else true.
constexpr int kMaxCollisions = 1 << 16;
template <class Majorants, class F>
bool walk_collisions(const Majorants& g, Vec3 org, Vec3 dir, float tmax, Pcg32& rng, int& steps, bool& runaway,
                     F&& f, float scale = 1.0f) {
  runaway = false;
  return walk_majorants(g, org, dir, tmax, [&](float t0, float t1, float mu) {
    mu *= scale;
    if (!(mu > 0.0f)) return true;
    for (float t = t0 + exp_step(rng, mu); t < t1; t += exp_step(rng, mu)) {
      if (++steps > kMaxCollisions) {
        runaway = true;
        return false;
      }
      if (!f(t, mu)) return false;
    }
    return true;
  });
}

// Delta tracking (Miller et al. 2019's null-scattering formulation, spectral in RGB): walks
// tentative collisions of rate majorant along [0, tmax]; at each, with the coefficients there
// (eval(t)), adds beta * emission / majorant to L (the collision estimator of the emission),
// then scatters with probability mean(sigma_s) / q or goes on (a null collision) with
// probability mean(|sigma_n|) / q, q their sum, weighting beta by sigma_x / (majorant p_x).
// Absorption stays in those weights (no absorption events). Returns true at a scattering, with
// its distance t and coefficients ms; false when the ray passes tmax (or beta dies).
template <class Majorants, class Eval>
bool delta_track(const Majorants& g, Vec3 org, Vec3 dir, float tmax, Pcg32& rng, Eval&& eval, Vec3& beta,
                 Vec3* L, float& t_out, MediumSample& ms_out, int& steps) {
  bool scattered = false, dead = false, runaway;
  walk_collisions(g, org, dir, tmax, rng, steps, runaway, [&](float t, float mu) {
    const MediumSample ms = eval(t);
    if (L) *L += beta * ms.emission * (1.0f / mu);
    const Vec3 sn = Vec3(mu) - ms.sigma_a - ms.sigma_s;
    const float ps = average(ms.sigma_s), pn = average(vabs(sn));
    const float q = ps + pn;
    if (!(q > 0.0f)) {  // no scattering, the majorant exactly absorbed: nothing goes on
      dead = true;
      return false;
    }
    if (rng.next_float() * q < ps) {
      beta *= ms.sigma_s * (q / (mu * ps));
      t_out = t;
      ms_out = ms;
      scattered = true;
      return false;
    }
    beta *= sn * (q / (mu * pn));
    if (is_black(beta)) {
      dead = true;
      return false;
    }
    return true;
  });
  if (runaway) dead = true;  // (a majorant far too small): give up the path
  if (dead) beta = Vec3(0.0f);
  return scattered;
}

// Ratio tracking: the transmittance over [0, tmax] as the product of sigma_n / majorant over
// tentative collisions (unbiased, signed where the majorant is too small). Its majorants are
// the grid's times kRatioTrackingScale: with a majorant mu = k sigma the estimate's relative
// variance is exp(tau / k) - 1 for k tau lookups, so majorants as tight as delta tracking and
// the light samples' distances want them (k = 1) leave transmittance nearly a coin flip
// (docs/design/volumes.md "Equal time against Cycles").
constexpr float kRatioTrackingScale = 2.0f;
template <class Majorants, class Eval>
Vec3 ratio_track(const Majorants& g, Vec3 org, Vec3 dir, float tmax, Pcg32& rng, Eval&& eval,
                 float scale = kRatioTrackingScale) {
  Vec3 T(1.0f);
  int steps = 0;
  bool runaway;
  walk_collisions(
      g, org, dir, tmax, rng, steps, runaway,
      [&](float t, float mu) {
        const MediumSample ms = eval(t);
        T *= (Vec3(mu) - ms.sigma_a - ms.sigma_s) * (1.0f / mu);
        return !is_black(T);
      },
      scale);
  if (runaway) T = Vec3(0.0f);
  return T;
}

}  // namespace pl
