#include "scene/tex_gabor.h"

#include "util/lookup3.h"

namespace pl {
namespace {

using lookup3::hash_to_float;

constexpr int kImpulses = 8;  // per cell: stratified, as Tavernier et al. suggest

struct C2 {
  float re = 0.0f, im = 0.0f;  // a phasor: the Gabor value (im) and its cosine twin (re)
};

// The unit-width Gaussian envelope windowed by a Hann window (C1 at the unit radius).
inline float envelope(float d2) {
  const float hann = 0.5f + 0.5f * std::cos(kPi * d2);
  return std::exp(-kPi * d2) * hann;
}

inline C2 phasor(float w, float angle) { return {w * std::cos(angle), w * std::sin(angle)}; }

C2 noise_2d(float x, float y, float frequency, float isotropy, float base_orientation) {
  const float cx = std::floor(x), cy = std::floor(y);
  const float lx = x - cx, ly = y - cy;
  C2 sum;
  for (int j = -1; j <= 1; ++j) {
    for (int i = -1; i <= 1; ++i) {
      const float ox = float(i), oy = float(j);
      const float cellx = cx + ox, celly = cy + oy;
      const float px = lx - ox, py = ly - oy;
      C2 cell;
      for (int k = 0; k < kImpulses; ++k) {
        const float s0 = float(k * 3), s1 = float(k * 3 + 1), s2 = float(k * 3 + 2);
        const float random_orientation = (hash_to_float(cellx, celly, s0) - 0.5f) * kPi;
        const float orientation = base_orientation + random_orientation * isotropy;
        // hash_float3_to_float2: the seed, then its components rotated (z, x, y).
        const float kx = hash_to_float(cellx, celly, s1), ky = hash_to_float(s1, cellx, celly);
        const float qx = px - kx, qy = py - ky;
        const float d2 = qx * qx + qy * qy;
        if (d2 >= 1.0f) continue;  // the window is zero beyond the unit radius
        const float weight = hash_to_float(cellx, celly, s2) < 0.5f ? -1.0f : 1.0f;
        const float fx = frequency * std::cos(orientation), fy = frequency * std::sin(orientation);
        const float angle = 2.0f * kPi * (qx * fx + qy * fy);
        const C2 g = phasor(envelope(d2), angle);
        cell.re += weight * g.re;
        cell.im += weight * g.im;
      }
      sum.re += cell.re;
      sum.im += cell.im;
    }
  }
  return sum;
}

// A random direction about the base one, in spherical coordinates (Cycles' order).
Vec3 orientation_3d(Vec3 o, float isotropy, float sx, float sy, float sz, float sw) {
  if (isotropy == 0.0f) return o;
  float inclination = std::acos(o.z);
  float azimuth = (o.y < 0.0f ? -1.0f : 1.0f) * std::acos(o.x / std::sqrt(o.x * o.x + o.y * o.y));
  // hash_float4_to_float2: the seed, then (z, x, w, y).
  const float ra = hash_to_float(sx, sy, sz, sw) * kPi, rb = hash_to_float(sz, sx, sw, sy) * kPi;
  inclination += ra * isotropy;
  azimuth += rb * isotropy;
  return {std::sin(inclination) * std::cos(azimuth), std::sin(inclination) * std::sin(azimuth), std::cos(inclination)};
}

C2 noise_3d(Vec3 p, float frequency, float isotropy, Vec3 base) {
  const Vec3 c{std::floor(p.x), std::floor(p.y), std::floor(p.z)};
  const Vec3 l = p - c;
  C2 sum;
  for (int m = -1; m <= 1; ++m) {
    for (int j = -1; j <= 1; ++j) {
      for (int i = -1; i <= 1; ++i) {
        const Vec3 off{float(i), float(j), float(m)};
        const Vec3 cell = c + off;
        const Vec3 q0 = l - off;
        C2 acc;
        for (int k = 0; k < kImpulses; ++k) {
          const float s0 = float(k * 3), s1 = float(k * 3 + 1), s2 = float(k * 3 + 2);
          const Vec3 o = orientation_3d(base, isotropy, cell.x, cell.y, cell.z, s0);
          // hash_float4_to_float3: the seed, (z, x, w, y), (w, z, y, x).
          const Vec3 kc{hash_to_float(cell.x, cell.y, cell.z, s1), hash_to_float(cell.z, cell.x, s1, cell.y),
                        hash_to_float(s1, cell.z, cell.y, cell.x)};
          const Vec3 q = q0 - kc;
          const float d2 = dot(q, q);
          if (d2 >= 1.0f) continue;
          const float weight = hash_to_float(cell.x, cell.y, cell.z, s2) < 0.5f ? -1.0f : 1.0f;
          const Vec3 fv = o * frequency;
          const float angle = 2.0f * kPi * dot(q, fv);
          const C2 g = phasor(envelope(d2), angle);
          acc.re += weight * g.re;
          acc.im += weight * g.im;
        }
        sum.re += acc.re;
        sum.im += acc.im;
      }
    }
  }
  return sum;
}

}  // namespace

GaborOutput gabor_texture(int dims, Vec3 co, float scale, float frequency, float anisotropy, float orientation_2d,
                          Vec3 orientation_3d_in) {
  const Vec3 p = co * scale;
  const float isotropy = 1.0f - clampf(anisotropy, 0.0f, 1.0f);
  frequency = std::max(0.001f, frequency);
  C2 ph;
  float sd;
  // Standard deviations of the sum (impulses x Bernoulli second moment x the squared kernel's
  // integral, its high-frequency limit: 1/4 in 2D, 1/(4 sqrt 2) in 3D).
  if (dims == 2) {
    ph = noise_2d(p.x, p.y, frequency, isotropy, orientation_2d);
    sd = std::sqrt(float(kImpulses) * 0.5f * 0.25f);
  } else {
    ph = noise_3d(p, frequency, isotropy, normalize(orientation_3d_in));
    sd = std::sqrt(float(kImpulses) * 0.5f * (1.0f / (4.0f * 1.41421356237309504880f)));
  }
  const float norm = 6.0f * sd;  // Cycles' empirical normalisation to about [-1, 1]
  GaborOutput out;
  out.value = (ph.im / norm) * 0.5f + 0.5f;
  out.phase = (std::atan2(ph.im, ph.re) + kPi) / (2.0f * kPi);
  out.intensity = std::sqrt(ph.re * ph.re + ph.im * ph.im) / norm;
  return out;
}

}  // namespace pl
