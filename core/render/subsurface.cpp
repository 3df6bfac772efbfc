#include "render/subsurface.h"

#include <algorithm>
#include <cmath>

#include "scene/phase.h"
#include "util/rng.h"
#include "util/sampling.h"

namespace pl {

void subsurface_coefficients(float albedo, float d, float g, float& sigma_t, float& alpha) {
  const float g2 = g * g, g3 = g2 * g, g4 = g3 * g, g5 = g4 * g, g6 = g5 * g, g7 = g6 * g;
  // The fit's six curves in g (degree-7 polynomials, two inside an exponential).
  const float A = 1.8260523782f - 1.28451056436f * g - 1.79904629312f * g2 + 9.19393289202f * g3 -
                  22.8215585862f * g4 + 32.0234874259f * g5 - 23.6264803333f * g6 + 7.21067002658f * g7;
  const float B = 4.98511194385f + 0.127355959438f * std::exp(31.1491581433f * g - 201.847017512f * g2 +
                                                               841.576016723f * g3 - 2018.09288505f * g4 +
                                                               2731.71560286f * g5 - 1935.41424244f * g6 +
                                                               559.009054474f * g7);
  const float C = 1.09686102424f - 0.394704063468f * g + 1.05258115941f * g2 - 8.83963712726f * g3 +
                  28.8643230661f * g4 - 46.8802913581f * g5 + 38.5402837518f * g6 - 12.7181042538f * g7;
  const float D = 0.496310210422f + 0.360146581622f * g - 2.15139309747f * g2 + 17.8896899217f * g3 -
                  55.2984010333f * g4 + 82.065982243f * g5 - 58.5106008578f * g6 + 15.8478295021f * g7;
  const float E = 4.23190299701f + 0.00310603949088f * std::exp(76.7316253952f * g - 594.356773233f * g2 +
                                                                2448.8834203f * g3 - 5576.68528998f * g4 +
                                                                7116.60171912f * g5 - 4763.54467887f * g6 +
                                                                1303.5318055f * g7);
  const float F = 2.40602999408f - 2.51814844609f * g + 9.18494908356f * g2 - 79.2191708682f * g3 +
                  259.082868209f * g4 - 403.613804597f * g5 + 302.85712436f * g6 - 87.4370473567f * g7;
  const float blend = std::pow(albedo, 0.25f);
  alpha = (1.0f - blend) * A * std::pow(std::atan(B * albedo), C) +
          blend * D * std::pow(std::atan(E * albedo), F);
  alpha = std::isfinite(alpha) ? std::clamp(alpha, 0.0f, 0.999999f) : 0.0f;
  sigma_t = 1.0f / std::max(d, 1e-16f) / (1.0f - g);
}

namespace {

// The direction into the surface (Cycles' subsurface_entry_bounce): refraction through a GGX
// microfacet normal sampled from the view (the throughput keeps no BSDF / pdf factor, as
// Cycles': only the direction matters); Skin (alpha < 0) enters diffusely half of the time.
bool entry_direction(const SubsurfaceBsdf& b, Vec3 n, Vec3 wo, Vec2 u, Vec3& d) {
  float alpha = b.alpha;
  if (alpha < 0.0f) {
    alpha = 1.0f;
    if (u.x < 0.5f) {
      u.x *= 2.0f;
      const Vec3 l = sample_cosine_hemisphere(u);
      d = Frame::from_normal(-n).to_world(l);
      return true;
    }
    u.x = 2.0f * (u.x - 0.5f);
  }
  const Frame f = Frame::from_normal(n);
  const Vec3 wl = f.to_local(wo);
  if (!(wl.z > 0.0f)) return false;
  const Vec3 h = f.to_world(Ggx{alpha}.sample_visible(wl, u));
  const float neta = 1.0f / b.ior;  // IOR is at least 1.01: no total internal reflection
  const float cos_hi = dot(h, wo);
  const float arg = 1.0f - neta * neta * (1.0f - cos_hi * cos_hi);
  const float k = neta * cos_hi - std::max(std::sqrt(std::max(arg, 0.0f)), 1e-7f);
  d = normalize(h * k - wo * neta);
  return is_finite(d);
}

// Christensen-Burley's radial profile as Cycles normalises it (per unit r, integrating to 1 over
// the plane), truncated at 16 d, and its inverse CDF by Newton's method (Cycles' root find).
constexpr float kBurleyTruncate = 16.0f, kBurleyTruncateCdf = 0.9963790093708328f;
float burley_eval(float d, float r) {
  if (!(d > 0.0f) || r >= kBurleyTruncate * d) return 0.0f;
  const float e3 = std::exp(-r / (3.0f * d));
  return (e3 * e3 * e3 + e3) / (4.0f * d);
}
float burley_pdf(float d, float r) { return r == 0.0f ? 0.0f : burley_eval(d, r) / kBurleyTruncateCdf; }
float burley_root(float xi) {
  float r = xi <= 0.9f ? std::exp(xi * xi * 2.4f) - 1.0f : 15.0f;
  for (int i = 0; i < 10; ++i) {
    const float e3 = std::exp(-r / 3.0f), e = e3 * e3 * e3;
    const float f = 1.0f - 0.25f * e - 0.75f * e3 - xi, df = 0.25f * e + 0.25f * e3;
    if (std::fabs(f) < 1e-6f || df == 0.0f) break;
    r = std::max(r - f / df, 0.0f);
  }
  return r;
}
// The mean of the used channels' pdfs (Cycles' bssrdf_pdf).
float burley_mean_pdf(Vec3 d, float r) {
  float sum = 0.0f, n = 0.0f;
  for (int i = 0; i < 3; ++i)
    if (d[i] > 0.0f) sum += burley_pdf(d[i], r), n += 1.0f;
  return n > 0.0f ? sum / n : 0.0f;
}

// Cycles' subsurface_disk (King et al. 2013's disk importance sampling): a point on a disk about
// one of three axes (the normal half of the time) at a Burley-distributed radius, a probe ray
// through the object along the axis, and one of its hits chosen by its weight: the profile at
// the true distance over the disk pdf, MIS over the axes by the power heuristic. All hits are
// kept (Cycles keeps a random four and scales: the same expectation).
bool subsurface_disk(const Scene& scene, const SurfacePoint& sp, Vec3 ng_out, bool front, const SubsurfaceBsdf& b,
                     Vec2 u, uint64_t seed, Vec3& beta, Hit& exit, Vec3& exit_dir, uint64_t& rays) {
  Vec3 n = ng_out, t, bt;
  make_basis(n, t, bt);
  float pn = 0.5f, pt = 0.25f, pb = 0.25f;
  if (u.y < 0.5f) {
    u.y *= 2.0f;
  } else if (u.y < 0.75f) {
    std::swap(n, t);
    pn = 0.25f, pt = 0.5f;
    u.y = (u.y - 0.5f) * 4.0f;
  } else {
    std::swap(n, bt);
    pn = 0.25f, pb = 0.5f;
    u.y = (u.y - 0.75f) * 4.0f;
  }
  // A channel among the used ones (reusing u.x), then the radius in it.
  const Vec3 d = b.radius;
  const float channels = float((d.x > 0.0f) + (d.y > 0.0f) + (d.z > 0.0f));
  if (channels == 0.0f) return false;
  float xi = u.x * channels, dc = 0.0f, acc = 0.0f;
  for (int i = 0; i < 3 && dc == 0.0f; ++i)
    if (d[i] > 0.0f) {
      if (xi < acc + 1.0f || acc + 1.0f >= channels) {
        xi = std::min(xi - acc, 1.0f);
        dc = d[i];
      }
      acc += 1.0f;
    }
  const float disk_r = burley_root(xi * kBurleyTruncateCdf) * dc;
  const float rm = kBurleyTruncate * dc;
  const float h = std::sqrt(std::max(rm * rm - disk_r * disk_r, 0.0f));
  const float phi = 2.0f * kPi * u.y;
  Ray ray;
  ray.org = sp.p + n * h + (t * std::cos(phi) + bt * std::sin(phi)) * disk_r;
  ray.dir = -n;
  const float disk_pdf = burley_mean_pdf(d, disk_r);
  if (!(disk_pdf > 0.0f) || !is_finite(ray.org)) return false;
  // Every hit of the probe segment on the object (stepping past each; at most 16).
  constexpr int kMaxHits = 16;
  Hit hits[kMaxHits];
  Vec3 weights[kMaxHits], normals[kMaxHits];
  int nh = 0;
  float sum = 0.0f;
  Ray probe = ray;
  float travelled = 0.0f;
  probe.tmax = 2.0f * h;
  while (nh < kMaxHits && probe.tmax > 0.0f) {
    Hit hh;
    ++rays;
    if (!scene.intersect_local(sp.instance, probe, hh)) break;
    SurfacePoint hp;
    scene.surface_point(hh, hp);
    const Vec3 hng = front ? hp.ng : -hp.ng;
    const float qn = pn * std::fabs(dot(n, hng)), qt = pt * std::fabs(dot(t, hng)), qb = pb * std::fabs(dot(bt, hng));
    const float w = qn / (qn * qn + qt * qt + qb * qb);
    const float r = length(hp.p - sp.p);
    Vec3 wt(0.0f);
    for (int i = 0; i < 3; ++i) wt[i] = burley_pdf(d[i], r) / disk_pdf * w;
    if (is_finite(wt)) {
      hits[nh] = hh;
      normals[nh] = hng;
      weights[nh] = wt;
      sum += average(vabs(wt));
      ++nh;
    }
    // On past the hit: from just beyond it, the rest of the segment.
    const float step = hh.t + std::max(1e-5f * (1.0f + max_component(vabs(hp.p))), 4.0f * max_component(hp.p_error));
    travelled += step;
    probe.org = ray.org + ray.dir * travelled;
    probe.tmax = 2.0f * h - travelled;
  }
  if (!(sum > 0.0f)) return false;
  // Importance resampling: one hit in proportion to its weight.
  Pcg32 rng(seed, 0x5354u);
  const float pick = rng.next_float() * sum;
  float partial = 0.0f;
  for (int k = 0; k < nh; ++k) {
    const float sw = average(vabs(weights[k]));
    if (pick < partial + sw || k == nh - 1) {
      if (!(sw > 0.0f)) return false;
      beta = beta * weights[k] * (sum / sw);
      exit = hits[k];
      exit_dir = normals[k];
      return true;
    }
    partial += sw;
  }
  return false;
}

}  // namespace

bool subsurface_walk(const Scene& scene, const SurfacePoint& sp, Vec3 ng_out, Vec3 n, Vec3 wo,
                     const SubsurfaceBsdf& b, Vec2 u, Vec2 u_first, uint64_t seed, Vec3& beta, Hit& exit,
                     Vec3& exit_dir, uint64_t& rays) {
  if (b.alpha < -1.5f)
    return subsurface_disk(scene, sp, ng_out, dot(sp.ng, ng_out) > 0.0f, b, u, seed, beta, exit, exit_dir, rays);
  Ray ray;
  if (!entry_direction(b, n, wo, u, ray.dir) || !(dot(ng_out, ray.dir) < 0.0f)) return false;
  ray.org = offset_ray_origin(sp.p, sp.p_error, -ng_out);

  // The medium: per channel extinction and single-scattering albedo; the throughput loses the
  // albedo the closure weight carries (the walk puts it back by scattering).
  Vec3 sigma_t, alpha, T;
  for (int i = 0; i < 3; ++i) {
    subsurface_coefficients(b.albedo[i], b.radius[i], b.g, sigma_t[i], alpha[i]);
    T[i] = b.albedo[i] > 0.0f ? beta[i] / b.albedo[i] : 0.0f;
    // Cycles: very low albedos would need near-infinite guiding; alpha is raised to 0.2 and the
    // throughput lowered in proportion (its small, deliberate bias, kept to match it).
    if (alpha[i] < 0.2f) {
      T[i] *= alpha[i] / 0.2f;
      alpha[i] = 0.2f;
    }
  }
  const Vec3 sigma_s = sigma_t * alpha;
  // After ten scatterings Cycles goes isotropic through the similarity relation.
  const Vec3 sigma_s_star = sigma_s * (1.0f - b.g);
  const Vec3 sigma_t_star = sigma_t - sigma_s + sigma_s_star;

  // Dwivedi guiding (Krivanek & d'Eon 2014; Meng et al. 2016; d'Eon & Krivanek 2020), as
  // Cycles mixes it with classic sampling: directions peaked towards the entry plane (or, where
  // the first segment found the opposite side near, away from it), distances stretched to
  // match; every step's pdf is the balance heuristic over {classic, forward, backward} x RGB.
  // Not only variance: with the walk cut at kSubsurfaceMaxSteps, how fast walks return decides
  // how much energy the cut loses, so matching Cycles needs its sampling.
  const float amax = max_component(alpha);
  const float v = 1.0f / std::sqrt(1.0f - std::pow(amax, 2.44294f - 0.0215813f * amax + 0.578637f / amax));
  if (!(v > 1.0f) || !std::isfinite(v)) return false;
  const float phase_log = std::log((v + 1.0f) / (v - 1.0f));
  const auto dwivedi_pdf = [&](float cos_t) { return 1.0f / ((v - cos_t) * phase_log); };  // of cos_t
  const float guided_first = 1.0f - std::max(0.5f, std::pow(std::fabs(b.g), 0.125f));
  const Vec3 p0 = ray.org;
  bool opposite = false;
  float opposite_dist = 0.0f;

  Pcg32 rng(seed, 0x5353u);
  for (int step = 0; step < kSubsurfaceMaxSteps; ++step) {
    const bool similar = step > 9;
    const Vec3 st = similar ? sigma_t_star : sigma_t;
    const Vec3 ss = similar ? sigma_s_star : sigma_s;
    const float g = similar ? 0.0f : b.g;
    const float guided_fraction = similar ? 0.75f : guided_first;
    // A channel in proportion to throughput x albedo (Cycles' volume_sample_channel).
    Vec3 cw = vabs(T * alpha);
    const float sum = cw.x + cw.y + cw.z;
    cw = sum > 0.0f ? cw / sum : Vec3(1.0f / 3.0f);
    const float uc = step == 0 && u_first.x >= 0.0f ? u_first.x : rng.next_float();
    const int c = uc < cw.x ? 0 : uc < cw.x + cw.y ? 1 : 2;
    float sample_st = st[c];
    const float ut = step == 0 && u_first.y >= 0.0f ? u_first.y : rng.next_float();
    float back_fraction = 0.0f, fwd_factor = 0.0f, back_factor = 0.0f, fwd_stretch = 1.0f, back_stretch = 1.0f;
    if (step > 0) {  // the first segment goes along the entry direction
      const bool guided = rng.next_float() < guided_fraction;
      bool backward = false;
      if (opposite) {
        const float x = std::clamp(dot(ray.org - p0, -n), 0.0f, opposite_dist);
        back_fraction = 1.0f / (1.0f + std::exp((opposite_dist - 2.0f * x) / v));
        backward = rng.next_float() < back_fraction;
      }
      const float u1 = rng.next_float(), u2 = rng.next_float();
      float cos_t, hg_pdf;
      if (guided) {
        cos_t = v - (v + 1.0f) * std::exp(-u1 * phase_log);
        if (backward) cos_t = -cos_t;
        const float sin_t = std::sqrt(std::max(0.0f, 1.0f - cos_t * cos_t));
        const float phi = 2.0f * kPi * u2;
        const Vec3 nd = Frame::from_normal(n).to_world({sin_t * std::cos(phi), sin_t * std::sin(phi), cos_t});
        hg_pdf = hg_phase(g, dot(ray.dir, nd));
        ray.dir = nd;
      } else {
        ray.dir = hg_sample(g, ray.dir, u1, u2, hg_pdf);
        cos_t = dot(ray.dir, n);
      }
      if (!(hg_pdf > 0.0f)) return false;
      fwd_factor = (0.5f * kInvPi) * dwivedi_pdf(cos_t) / hg_pdf;
      back_factor = (0.5f * kInvPi) * dwivedi_pdf(-cos_t) / hg_pdf;
      fwd_stretch = 1.0f - cos_t / v;
      back_stretch = 1.0f + cos_t / v;
      if (guided) sample_st *= backward ? back_stretch : fwd_stretch;
    }
    float t = -std::log1p(-ut) / sample_st;
    if (!(t >= 0.0f)) return false;  // 0 / 0: an infinite mean free path and ut = 0
    // The first segment looks ten mean free paths ahead for the opposite side.
    ray.tmax = step == 0 ? std::max(t, 10.0f / std::max(min_component(sigma_t), 1e-30f)) : t;
    Hit h;
    ++rays;
    bool hit = scene.intersect_local(sp.instance, ray, h);
    if (step == 0) {
      if (hit) {
        opposite = true;
        opposite_dist = dot(ray.org + ray.dir * h.t - p0, -n);
      }
      hit = hit && h.t < t;
    }
    if (hit) t = h.t;
    const Vec3 tr = medium_transmittance(st, t);
    const auto walk_pdf = [&](Vec3 sig) { return hit ? medium_transmittance(sig, t) : sig * medium_transmittance(sig, t); };
    Vec3 pdf = hit ? tr : st * tr;
    if (step > 0) {
      Vec3 gp = walk_pdf(st * fwd_stretch) * fwd_factor;
      if (opposite) gp = gp * (1.0f - back_fraction) + walk_pdf(st * back_stretch) * (back_factor * back_fraction);
      pdf = pdf * (1.0f - guided_fraction) + gp * guided_fraction;
    }
    const float denom = dot(cw, pdf);
    if (!(denom > 0.0f)) return false;
    T = T * (hit ? tr : ss * tr) * (1.0f / denom);
    if (!is_finite(T)) return false;
    if (hit) {
      exit = h;
      exit_dir = ray.dir;
      beta = T;
      return true;
    }
    if (!std::isfinite(t)) return false;  // no surface ahead: the walk has left for good
    ray.org = ray.org + ray.dir * t;
    if (max_component(T) < 1e-6f) return false;  // Cycles' VOLUME_THROUGHPUT_EPSILON
  }
  return false;
}

}  // namespace pl
