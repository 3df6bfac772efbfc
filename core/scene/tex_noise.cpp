// Our implementation of the algorithms Cycles' kernel uses for these nodes (svm/noise.h,
// fractal_noise.h, noisetex.h, wave.h, magic.h, white_noise.h): Perlin's improved noise with
// OSL's gradient sets and per-dimension scale factors, hashed with Jenkins' lookup3.
#include "scene/tex_noise.h"

#include <array>
#include <cmath>

#include "util/lookup3.h"

namespace pl {
namespace {

using lookup3::hash;
using lookup3::hash_to_float;

template <size_t N>
using P = std::array<float, N>;

template <size_t N>
P<N> operator*(P<N> p, float s) {
  for (float& x : p) x *= s;
  return p;
}
template <size_t N>
P<N> operator+(P<N> a, const P<N>& b) {
  for (size_t i = 0; i < N; ++i) a[size_t(i)] += b[size_t(i)];
  return a;
}

inline float mixf(float a, float b, float t) { return a + t * (b - a); }  // Cycles' mix()
inline float fade(float t) { return t * t * t * (t * (t * 6.0f - 15.0f) + 10.0f); }
inline float negate_if(float v, uint32_t c) { return c ? -v : v; }

// floor and fraction; a non-finite coordinate (only from non-finite inputs) reads as 0 so the
// float-to-int conversion stays defined.
inline float floorfrac(float x, uint32_t& i) {
  if (!std::isfinite(x)) x = 0.0f;
  const float f = std::floor(x);
  i = uint32_t(int32_t(f));
  return x - f;
}

inline float grad1(uint32_t h, float x) {
  h &= 15u;
  const float g = float(1u + (h & 7u));
  return negate_if(g, h & 8u) * x;
}
inline float grad2(uint32_t h, float x, float y) {
  h &= 7u;
  const float u = h < 4u ? x : y;
  const float v = 2.0f * (h < 4u ? y : x);
  return negate_if(u, h & 1u) + negate_if(v, h & 2u);
}
inline float grad3(uint32_t h, float x, float y, float z) {
  h &= 15u;
  const float u = h < 8u ? x : y;
  const float vt = (h == 12u || h == 14u) ? x : z;
  const float v = h < 4u ? y : vt;
  return negate_if(u, h & 1u) + negate_if(v, h & 2u);
}
inline float grad4(uint32_t h, float x, float y, float z, float w) {
  h &= 31u;
  const float u = h < 24u ? x : y;
  const float v = h < 16u ? y : z;
  const float s = h < 8u ? z : w;
  return negate_if(u, h & 1u) + negate_if(v, h & 2u) + negate_if(s, h & 4u);
}

float perlin(const P<1>& p) {
  uint32_t X;
  const float fx = floorfrac(p[0], X);
  return mixf(grad1(hash(X), fx), grad1(hash(X + 1u), fx - 1.0f), fade(fx));
}

float perlin(const P<2>& p) {
  uint32_t X, Y;
  const float fx = floorfrac(p[0], X), fy = floorfrac(p[1], Y);
  const float u = fade(fx), v = fade(fy);
  const float a = mixf(grad2(hash(X, Y), fx, fy), grad2(hash(X + 1u, Y), fx - 1.0f, fy), u);
  const float b = mixf(grad2(hash(X, Y + 1u), fx, fy - 1.0f), grad2(hash(X + 1u, Y + 1u), fx - 1.0f, fy - 1.0f), u);
  return mixf(a, b, v);
}

// lookup3::hash(x, y, z) of four corners at once (GCC's vector extension: SSE2 on x86-64).
// The eight hashes of a 3-D cell were a third of its Perlin noise's instructions one by one.
using U4 = uint32_t __attribute__((vector_size(16)));
inline U4 hash4(U4 x, U4 y, U4 z) {
  const uint32_t s = lookup3::seed(3);
  U4 a = x + s, b = y + s, c = z + s;
  lookup3::final_mix(a, b, c);
  return c;
}

float perlin(const P<3>& p) {
  uint32_t X, Y, Z;
  const float fx = floorfrac(p[0], X), fy = floorfrac(p[1], Y), fz = floorfrac(p[2], Z);
  const float u = fade(fx), v = fade(fy), w = fade(fz);
  // Corners (X, Y), (X + 1, Y), (X, Y + 1), (X + 1, Y + 1) of layers Z and Z + 1.
  const U4 xs = {X, X + 1u, X, X + 1u}, ys = {Y, Y, Y + 1u, Y + 1u};
  const U4 h[2] = {hash4(xs, ys, U4{Z, Z, Z, Z}), hash4(xs, ys, U4{Z + 1u, Z + 1u, Z + 1u, Z + 1u})};
  float layer[2];
  for (uint32_t k = 0; k < 2; ++k) {
    const float gz = fz - float(k);
    const float a = mixf(grad3(h[k][0], fx, fy, gz), grad3(h[k][1], fx - 1.0f, fy, gz), u);
    const float b = mixf(grad3(h[k][2], fx, fy - 1.0f, gz), grad3(h[k][3], fx - 1.0f, fy - 1.0f, gz), u);
    layer[k] = mixf(a, b, v);
  }
  return mixf(layer[0], layer[1], w);
}

float perlin(const P<4>& p) {
  uint32_t X, Y, Z, W;
  const float fx = floorfrac(p[0], X), fy = floorfrac(p[1], Y), fz = floorfrac(p[2], Z), fw = floorfrac(p[3], W);
  const float u = fade(fx), v = fade(fy), t = fade(fz), s = fade(fw);
  float cube[2];
  for (uint32_t l = 0; l < 2; ++l) {
    const float gw = fw - float(l);
    float layer[2];
    for (uint32_t k = 0; k < 2; ++k) {
      const float gz = fz - float(k);
      const float a = mixf(grad4(hash(X, Y, Z + k, W + l), fx, fy, gz, gw),
                           grad4(hash(X + 1u, Y, Z + k, W + l), fx - 1.0f, fy, gz, gw), u);
      const float b = mixf(grad4(hash(X, Y + 1u, Z + k, W + l), fx, fy - 1.0f, gz, gw),
                           grad4(hash(X + 1u, Y + 1u, Z + k, W + l), fx - 1.0f, fy - 1.0f, gz, gw), u);
      layer[k] = mixf(a, b, v);
    }
    cube[l] = mixf(layer[0], layer[1], t);
  }
  return mixf(cube[0], cube[1], s);
}

// OSL's experimentally found factors that bring each dimension's noise to about [-1, 1].
constexpr float kNoiseScale[5] = {0.0f, 0.25f, 0.6616f, 0.9820f, 0.8344f};

// Cycles repeats the noise every 100000 per axis (fmod keeps the sign) against float precision.
template <size_t N>
float snoise(P<N> p) {
  // (fmod returns |x| < 100000 unchanged: the libm call only beyond it, 0.7 % of the textured
  // model's instructions otherwise)
  for (float& x : p)
    if (!(std::fabs(x) < 100000.0f)) x = std::fmod(x, 100000.0f);
  return kNoiseScale[N] * perlin(p);
}

inline int octaves(float detail) { return int(detail); }  // detail is clamped to [0, 15]

template <size_t N>
float fbm(P<N> p, float detail, float roughness, float lacunarity, bool normalize) {
  float fscale = 1.0f, amp = 1.0f, maxamp = 0.0f, sum = 0.0f;
  for (int i = 0; i <= octaves(detail); ++i) {
    sum += snoise<N>(p * fscale) * amp;
    maxamp += amp;
    amp *= roughness;
    fscale *= lacunarity;
  }
  const float rmd = detail - std::floor(detail);
  if (rmd != 0.0f) {
    const float sum2 = sum + snoise<N>(p * fscale) * amp;
    return normalize ? mixf(0.5f * sum / maxamp + 0.5f, 0.5f * sum2 / (maxamp + amp) + 0.5f, rmd)
                     : mixf(sum, sum2, rmd);
  }
  return normalize ? 0.5f * sum / maxamp + 0.5f : sum;
}

template <size_t N>
float multi_fractal(P<N> p, float detail, float roughness, float lacunarity) {
  float value = 1.0f, pwr = 1.0f;
  for (int i = 0; i <= octaves(detail); ++i) {
    value *= pwr * snoise<N>(p) + 1.0f;
    pwr *= roughness;
    p = p * lacunarity;
  }
  const float rmd = detail - std::floor(detail);
  if (rmd != 0.0f) value *= rmd * pwr * snoise<N>(p) + 1.0f;
  return value;
}

template <size_t N>
float hetero_terrain(P<N> p, float detail, float roughness, float lacunarity, float offset) {
  float pwr = roughness;
  float value = offset + snoise<N>(p);  // the first octave unscaled
  p = p * lacunarity;
  for (int i = 1; i <= octaves(detail); ++i) {
    value += (snoise<N>(p) + offset) * pwr * value;
    pwr *= roughness;
    p = p * lacunarity;
  }
  const float rmd = detail - std::floor(detail);
  if (rmd != 0.0f) value += rmd * ((snoise<N>(p) + offset) * pwr * value);
  return value;
}

template <size_t N>
float hybrid_multi_fractal(P<N> p, float detail, float roughness, float lacunarity, float offset, float gain) {
  float pwr = 1.0f, value = 0.0f, weight = 1.0f;
  for (int i = 0; weight > 0.001f && i <= octaves(detail); ++i) {
    weight = std::min(weight, 1.0f);
    const float signal = (snoise<N>(p) + offset) * pwr;
    pwr *= roughness;
    value += weight * signal;
    weight *= gain * signal;
    p = p * lacunarity;
  }
  const float rmd = detail - std::floor(detail);
  if (rmd != 0.0f && weight > 0.001f) {
    weight = std::min(weight, 1.0f);
    value += rmd * weight * ((snoise<N>(p) + offset) * pwr);
  }
  return value;
}

template <size_t N>
float ridged_multi_fractal(P<N> p, float detail, float roughness, float lacunarity, float offset, float gain) {
  float pwr = roughness;
  float signal = offset - std::fabs(snoise<N>(p));
  signal *= signal;
  float value = signal;
  for (int i = 1; i <= octaves(detail); ++i) {
    p = p * lacunarity;
    const float weight = clampf(signal * gain, 0.0f, 1.0f);
    signal = offset - std::fabs(snoise<N>(p));
    signal *= signal;
    signal *= weight;
    value += signal * pwr;
    pwr *= roughness;
  }
  return value;
}

template <size_t N>
float fractal(NoiseType type, bool normalize, const P<N>& p, const NoiseInputs& in) {
  switch (type) {
    case NoiseType::Multifractal: return multi_fractal<N>(p, in.detail, in.roughness, in.lacunarity);
    case NoiseType::Fbm: return fbm<N>(p, in.detail, in.roughness, in.lacunarity, normalize);
    case NoiseType::HybridMultifractal:
      return hybrid_multi_fractal<N>(p, in.detail, in.roughness, in.lacunarity, in.offset, in.gain);
    case NoiseType::RidgedMultifractal:
      return ridged_multi_fractal<N>(p, in.detail, in.roughness, in.lacunarity, in.offset, in.gain);
    case NoiseType::HeteroTerrain: return hetero_terrain<N>(p, in.detail, in.roughness, in.lacunarity, in.offset);
  }
  return 0.0f;
}

// Cycles' random_float*_offset(seed): per-axis offsets in [100, 200] that decorrelate the
// distortion and colour channels (one hash of the seed in 1D, of (seed, axis) above).
template <size_t N>
P<N> random_offset(float seed) {
  P<N> o;
  if (N == 1) {
    o[0] = 100.0f + hash_to_float(seed) * 100.0f;
  } else {
    for (size_t i = 0; i < N; ++i) o[size_t(i)] = 100.0f + hash_to_float(seed, float(i)) * 100.0f;
  }
  return o;
}

template <size_t N>
Vec3 noise_nd(P<N> p, NoiseType type, bool normalize, bool color, const NoiseInputs& in) {
  if (in.distortion != 0.0f) {
    P<N> d;
    for (size_t i = 0; i < N; ++i) d[size_t(i)] = snoise<N>(p + random_offset<N>(float(i))) * in.distortion;
    p = p + d;
  }
  const float value = fractal<N>(type, normalize, p, in);
  if (!color) return Vec3(value);
  // The colour's seeds follow the distortion's: N and N + 1.
  return {value, fractal<N>(type, normalize, p + random_offset<N>(float(N)), in),
          fractal<N>(type, normalize, p + random_offset<N>(float(N + 1)), in)};
}

}  // namespace

Vec3 noise_texture(int dims, NoiseType type, bool normalize, bool color, const NoiseInputs& raw) {
  NoiseInputs in = raw;
  in.detail = std::isfinite(in.detail) ? clampf(in.detail, 0.0f, 15.0f) : 0.0f;
  in.roughness = std::max(in.roughness, 0.0f);
  const Vec3 v = in.co * in.scale;
  const float w = in.w * in.scale;
  switch (dims) {
    case 1: return noise_nd<1>({w}, type, normalize, color, in);
    case 2: return noise_nd<2>({v.x, v.y}, type, normalize, color, in);
    case 3: return noise_nd<3>({v.x, v.y, v.z}, type, normalize, color, in);
    default: return noise_nd<4>({v.x, v.y, v.z, w}, type, normalize, color, in);
  }
}

float wave_texture(int type, int direction, int profile, Vec3 co, float scale, float distortion, float detail,
                   float detail_scale, float detail_roughness, float phase) {
  Vec3 p = co * scale;
  p = (p + Vec3(0.000001f)) * 0.999999f;  // as Cycles: keeps unit coordinates off band edges
  float n;
  if (type == 0) {
    n = direction == 0 ? p.x * 20.0f
        : direction == 1 ? p.y * 20.0f
        : direction == 2 ? p.z * 20.0f
                         : (p.x + p.y + p.z) * 10.0f;
  } else {
    Vec3 rp = p;
    if (direction == 0) rp = rp * Vec3(0.0f, 1.0f, 1.0f);
    else if (direction == 1) rp = rp * Vec3(1.0f, 0.0f, 1.0f);
    else if (direction == 2) rp = rp * Vec3(1.0f, 1.0f, 0.0f);
    n = length(rp) * 20.0f;
  }
  n += phase;
  if (distortion != 0.0f) {
    // Cycles leaves Detail unclamped here; the node's own range (0-15) bounds the loop.
    detail = std::isfinite(detail) ? clampf(detail, 0.0f, 15.0f) : 0.0f;
    const Vec3 q = p * detail_scale;
    n += distortion * (fbm<3>({q.x, q.y, q.z}, detail, detail_roughness, 2.0f, true) * 2.0f - 1.0f);
  }
  constexpr float k2Pi = 2.0f * kPi;
  if (profile == 0) return 0.5f + 0.5f * std::sin(n - 0.5f * kPi);
  n /= k2Pi;
  if (profile == 1) return n - std::floor(n);
  return std::fabs(n - std::floor(n + 0.5f)) * 2.0f;
}

Vec3 magic_texture(Vec3 co, float scale, int depth, float distortion) {
  // As Cycles: the coordinates are wrapped to one period of sin/cos first (precision, and no
  // NaN from huge inputs), then scaled.
  constexpr float k2Pi = 2.0f * kPi;
  const float px = std::fmod(co.x, k2Pi), py = std::fmod(co.y, k2Pi), pz = std::fmod(co.z, k2Pi);
  float x = std::sin((px + py + pz) * 5.0f * scale);
  float y = std::cos((-px + py - pz) * 5.0f * scale);
  float z = -std::cos((-px - py + pz) * 5.0f * scale);
  const float d = distortion;
  if (depth > 0) {
    x *= d;
    y *= d;
    z *= d;
    y = -std::cos(x - y + z) * d;
    if (depth > 1) x = std::cos(x - y - z) * d;
    if (depth > 2) z = std::sin(-x - y - z) * d;
    if (depth > 3) x = -std::cos(-x + y - z) * d;
    if (depth > 4) y = -std::sin(-x + y + z) * d;
    if (depth > 5) y = -std::cos(-x + y + z) * d;
    if (depth > 6) x = std::cos(x + y + z) * d;
    if (depth > 7) z = std::sin(x + y - z) * d;
    if (depth > 8) x = -std::cos(-x - y + z) * d;
    if (depth > 9) y = -std::sin(x - y + z) * d;
  }
  if (d != 0.0f) {
    const float d2 = d * 2.0f;
    x /= d2;
    y /= d2;
    z /= d2;
  }
  return {0.5f - x, 0.5f - y, 0.5f - z};
}

Vec3 white_noise_texture(int dims, bool color, Vec3 co, float w) {
  // Cycles' hash_float*_to_float (Value) and hash_float*_to_float3 (Color, its component order).
  switch (dims) {
    case 1:
      if (!color) return Vec3(hash_to_float(w));
      return {hash_to_float(w), hash_to_float(w, 1.0f), hash_to_float(w, 2.0f)};
    case 2:
      if (!color) return Vec3(hash_to_float(co.x, co.y));
      return {hash_to_float(co.x, co.y), hash_to_float(co.x, co.y, 1.0f), hash_to_float(co.x, co.y, 2.0f)};
    case 3:
      if (!color) return Vec3(hash_to_float(co.x, co.y, co.z));
      return {hash_to_float(co.x, co.y, co.z), hash_to_float(co.x, co.y, co.z, 1.0f),
              hash_to_float(co.x, co.y, co.z, 2.0f)};
    default:
      if (!color) return Vec3(hash_to_float(co.x, co.y, co.z, w));
      return {hash_to_float(co.x, co.y, co.z, w), hash_to_float(co.z, co.x, w, co.y),
              hash_to_float(w, co.z, co.y, co.x)};
  }
}

}  // namespace pl
