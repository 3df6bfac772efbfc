// Written from the published algorithms as Blender 4.x uses them (Cycles' kernel/svm/checker.h,
// gradient.h, brick.h, voronoi.h say which variant, hash and constants): the order of every
// loop and float step below is Cycles', since smooth F1 blends cells in visiting order and ties
// go to the first cell found.
#include "scene/tex_patterns.h"

#include <cfloat>

#include "scene/shader.h"
#include "util/lookup3.h"

namespace pl::tex {
namespace {

// Cycles' clamp (max then min with a > b comparisons): NaN comes out as the lower bound.
inline float clamp_c(float a, float lo, float hi) {
  const float m = a > lo ? a : lo;
  return m < hi ? m : hi;
}
inline float min_c(float a, float b) { return a < b ? a : b; }
inline float mix_c(float a, float b, float t) { return a + t * (b - a); }
inline float smoothstep_c(float e0, float e1, float x) {
  if (x < e0) return 0.0f;
  if (x >= e1) return 1.0f;
  const float t = (x - e0) / (e1 - e0);
  return (3.0f - 2.0f * t) * (t * t);
}
// (int)floorf(f), defined for every float (Cycles' cast is undefined out of int range).
inline int floor_to_int(float f) {
  const float fl = std::floor(f);
  if (!(fl > -2147483648.0f && fl < 2147483648.0f)) return 0;
  return int(fl);
}

// ---------------------------------------------------------------- checker

// |floor(x)| mod 2 as Cycles takes it through an int (two's complement: i and -i agree).
inline int parity(float f) { return floor_to_int(f) & 1; }

}  // namespace

float checker(Vec3 p) {
  // Cycles' nudge keeps faces at whole coordinates on one side despite rounding.
  const float x = (p.x + 0.000001f) * 0.999999f;
  const float y = (p.y + 0.000001f) * 0.999999f;
  const float z = (p.z + 0.000001f) * 0.999999f;
  const int xi = parity(x), yi = parity(y), zi = parity(z);
  return (xi == yi ? 1 : 0) == zi ? 1.0f : 0.0f;
}

// ---------------------------------------------------------------- gradient

float gradient(Vec3 p, GradientType type) {
  float f = 0.0f;
  switch (type) {
    case GradientType::Linear: f = p.x; break;
    case GradientType::Quadratic: {
      const float r = std::max(p.x, 0.0f);
      f = r * r;
      break;
    }
    case GradientType::Easing: {
      const float r = std::min(std::max(p.x, 0.0f), 1.0f);
      const float t = r * r;
      f = 3.0f * t - 2.0f * t * r;
      break;
    }
    case GradientType::Diagonal: f = (p.x + p.y) * 0.5f; break;
    case GradientType::Radial: f = std::atan2(p.y, p.x) / 6.2831853071795864f + 0.5f; break;
    case GradientType::Spherical:
    case GradientType::QuadraticSphere: {
      // The 0.999999 bias gives exactly 0 on the unit sphere.
      const float r = std::max(0.999999f - std::sqrt(p.x * p.x + p.y * p.y + p.z * p.z), 0.0f);
      f = type == GradientType::Spherical ? r : r * r;
      break;
    }
  }
  return clamp_c(f, 0.0f, 1.0f);
}

// ---------------------------------------------------------------- brick

namespace {

// Cycles' integer noise of a brick's (row, column) key, in [0, 0.5].
float brick_noise(uint32_t n) {
  n = (n + 1013u) & 0x7fffffffu;
  n = (n >> 13) ^ n;
  const uint32_t nn = (n * (n * n * 60493u + 19990303u) + 1376312589u) & 0x7fffffffu;
  return 0.5f * (float(nn) / 1073741824.0f);
}

// The cubic smoothstep on [0, 1], clamped outside.
float smoothstep01(float f) {
  if (f <= 0.0f) return 0.0f;
  if (f >= 1.0f) return 1.0f;
  const float ff = f * f;
  return 3.0f * ff - 2.0f * ff * f;
}

}  // namespace

BrickSample brick(Vec3 p, const BrickParams& bp) {
  float brick_width = bp.brick_width;
  const float row_height = bp.row_height;
  const int rownum = floor_to_int(p.y / row_height);
  float offset = 0.0f;
  if (bp.offset_frequency != 0 && bp.squash_frequency != 0) {
    brick_width *= (rownum % bp.squash_frequency) != 0 ? 1.0f : bp.squash;
    offset = (rownum % bp.offset_frequency) != 0 ? 0.0f : brick_width * bp.offset;
  }
  const int bricknum = floor_to_int((p.x + offset) / brick_width);
  const float x = (p.x + offset) - brick_width * float(bricknum);
  const float y = p.y - row_height * float(rownum);
  const uint32_t key = (uint32_t(rownum) << 16) + (uint32_t(bricknum) & 0xFFFFu);
  BrickSample s;
  s.tint = clamp_c(brick_noise(key) + bp.bias, 0.0f, 1.0f);
  float min_dist = min_c(min_c(x, y), min_c(brick_width - x, row_height - y));
  if (min_dist >= bp.mortar_size) {
    s.mortar = 0.0f;
  } else if (bp.mortar_smooth == 0.0f) {
    s.mortar = 1.0f;
  } else {
    min_dist = 1.0f - min_dist / bp.mortar_size;
    s.mortar = smoothstep01(min_dist / bp.mortar_smooth);
  }
  return s;
}

// ---------------------------------------------------------------- voronoi

namespace {

// The helpers below are forced inline: the cell loops run 3^N to 5^N times per octave, and
// calls to them (GCC kept vlen and the metric out of line) cost 1.3-1.7x in time.
template <int N>
struct V {
  float c[N];
};

template <int N>
[[gnu::always_inline]] inline V<N> operator+(V<N> a, V<N> b) {
  for (int i = 0; i < N; ++i) a.c[i] += b.c[i];
  return a;
}
template <int N>
[[gnu::always_inline]] inline V<N> operator-(V<N> a, V<N> b) {
  for (int i = 0; i < N; ++i) a.c[i] -= b.c[i];
  return a;
}
template <int N>
[[gnu::always_inline]] inline V<N> operator*(V<N> a, float s) {
  for (int i = 0; i < N; ++i) a.c[i] *= s;
  return a;
}
template <int N>
[[gnu::always_inline]] inline V<N> vfloor(V<N> a) {
  for (int i = 0; i < N; ++i) a.c[i] = std::floor(a.c[i]);
  return a;
}
template <int N>
[[gnu::always_inline]] inline V<N> vmix(V<N> a, V<N> b, float t) {
  for (int i = 0; i < N; ++i) a.c[i] = mix_c(a.c[i], b.c[i], t);
  return a;
}
template <int N>
[[gnu::always_inline]] inline V<N> vzero() {
  V<N> v;
  for (int i = 0; i < N; ++i) v.c[i] = 0.0f;
  return v;
}
// Sums in Cycles' order: pairs for four components, left to right otherwise.
template <int N>
[[gnu::always_inline]] inline float vsum(V<N> a) {
  if constexpr (N == 4) return (a.c[0] + a.c[1]) + (a.c[2] + a.c[3]);
  float s = a.c[0];
  for (int i = 1; i < N; ++i) s += a.c[i];
  return s;
}
template <int N>
[[gnu::always_inline]] inline float vdot(V<N> a, V<N> b) {
  V<N> p;
  for (int i = 0; i < N; ++i) p.c[i] = a.c[i] * b.c[i];
  return vsum(p);
}
template <int N>
[[gnu::always_inline]] inline float vlen(V<N> a) {
  return std::sqrt(vdot(a, a));
}

using lookup3::hash_to_float;

// The cell's point in [0, 1]^N, Cycles' hash_floatN_to_floatN.
[[gnu::always_inline]] inline V<1> cell_point(V<1> k) { return {{hash_to_float(k.c[0])}}; }
[[gnu::always_inline]] inline V<2> cell_point(V<2> k) {
  return {{hash_to_float(k.c[0], k.c[1]), hash_to_float(k.c[0], k.c[1], 1.0f)}};
}
[[gnu::always_inline]] inline V<3> cell_point(V<3> k) {
  const float x = k.c[0], y = k.c[1], z = k.c[2];
  return {{hash_to_float(x, y, z), hash_to_float(x, y, z, 1.0f), hash_to_float(x, y, z, 2.0f)}};
}
[[gnu::always_inline]] inline V<4> cell_point(V<4> k) {
  const float x = k.c[0], y = k.c[1], z = k.c[2], w = k.c[3];
  return {{hash_to_float(x, y, z, w), hash_to_float(w, x, y, z), hash_to_float(z, w, x, y),
           hash_to_float(y, z, w, x)}};
}
// The cell's colour, Cycles' hash_floatN_to_float3.
[[gnu::always_inline]] inline Vec3 cell_color(V<1> k) {
  const float x = k.c[0];
  return {hash_to_float(x), hash_to_float(x, 1.0f), hash_to_float(x, 2.0f)};
}
[[gnu::always_inline]] inline Vec3 cell_color(V<2> k) {
  const float x = k.c[0], y = k.c[1];
  return {hash_to_float(x, y), hash_to_float(x, y, 1.0f), hash_to_float(x, y, 2.0f)};
}
[[gnu::always_inline]] inline Vec3 cell_color(V<3> k) {
  const V<3> p = cell_point(k);
  return {p.c[0], p.c[1], p.c[2]};
}
[[gnu::always_inline]] inline Vec3 cell_color(V<4> k) {
  const float x = k.c[0], y = k.c[1], z = k.c[2], w = k.c[3];
  return {hash_to_float(x, y, z, w), hash_to_float(z, x, w, y), hash_to_float(w, z, y, x)};
}

struct Params {
  VoronoiFeature feature;
  VoronoiMetric metric;
  bool normalize, need_color;
  float scale, detail, roughness, lacunarity, smoothness, exponent, randomness;
  float max_distance = 0.0f;
};

// The node's metric (1D: always the absolute difference).
template <int N>
[[gnu::always_inline]] inline float metric_distance(V<N> a, V<N> b, const Params& p) {
  const V<N> d = a - b;
  if constexpr (N == 1) return std::fabs(d.c[0]);
  V<N> ad;
  for (int i = 0; i < N; ++i) ad.c[i] = std::fabs(d.c[i]);
  switch (p.metric) {
    case VoronoiMetric::Euclidean: return vlen(d);
    case VoronoiMetric::Manhattan: return vsum(ad);
    case VoronoiMetric::Chebychev: {
      float m = ad.c[0];
      for (int i = 1; i < N; ++i) m = m > ad.c[i] ? m : ad.c[i];
      return m;
    }
    case VoronoiMetric::Minkowski: {
      V<N> pw;
      for (int i = 0; i < N; ++i) pw.c[i] = std::pow(ad.c[i], p.exponent);
      return std::pow(vsum(pw), 1.0f / p.exponent);
    }
  }
  return 0.0f;
}

// Visits the offsets of [-r, r]^N with the first axis fastest (Cycles' loop nesting).
template <int N, int R, class F>
[[gnu::always_inline]] inline void for_cells(F&& f) {
  constexpr int side = 2 * R + 1;
  constexpr int total = N == 1 ? side : N == 2 ? side * side : N == 3 ? side * side * side : side * side * side * side;
  for (int n = 0; n < total; ++n) {
    V<N> o;
    int rest = n;
    for (int i = 0; i < N; ++i) {
      o.c[i] = float(rest % side - R);
      rest /= side;
    }
    f(o);
  }
}

// Position in Cycles' float4 layout: 1D in w, 2D in xy, 3D in xyz, 4D in all four.
template <int N>
[[gnu::always_inline]] inline V<4> as_position(V<N> v) {
  V<4> p = vzero<4>();
  if constexpr (N == 1) p.c[3] = v.c[0];
  else
    for (int i = 0; i < N; ++i) p.c[i] = v.c[i];
  return p;
}

struct Octave {
  float distance = 0.0f;
  Vec3 color{0.0f};
  V<4> position = vzero<4>();
};

template <int N>
Octave voronoi_f1(const Params& p, V<N> coord) {
  const V<N> cell = vfloor(coord);
  const V<N> local = coord - cell;
  float min_distance = FLT_MAX;
  V<N> target_offset = vzero<N>(), target_position = vzero<N>();
  for_cells<N, 1>([&](V<N> off) {
    const V<N> point = off + cell_point(cell + off) * p.randomness;
    const float d = metric_distance(point, local, p);
    if (d < min_distance) {
      target_offset = off;
      min_distance = d;
      target_position = point;
    }
  });
  Octave o;
  o.distance = min_distance;
  o.color = cell_color(cell + target_offset);
  o.position = as_position(target_position + cell);
  return o;
}

template <int N>
Octave voronoi_smooth_f1(const Params& p, V<N> coord) {
  const V<N> cell = vfloor(coord);
  const V<N> local = coord - cell;
  float smooth_distance = 0.0f;
  Vec3 smooth_color{0.0f};
  V<N> smooth_position = vzero<N>();
  float h = -1.0f;
  for_cells<N, 2>([&](V<N> off) {
    const V<N> point = off + cell_point(cell + off) * p.randomness;
    const float d = metric_distance(point, local, p);
    h = h == -1.0f ? 1.0f : smoothstep_c(0.0f, 1.0f, 0.5f + 0.5f * (smooth_distance - d) / p.smoothness);
    float correction = p.smoothness * h * (1.0f - h);
    smooth_distance = mix_c(smooth_distance, d, h) - correction;
    correction /= 1.0f + 3.0f * p.smoothness;
    if (p.need_color) {
      const Vec3 c = cell_color(cell + off);
      smooth_color = {mix_c(smooth_color.x, c.x, h) - correction, mix_c(smooth_color.y, c.y, h) - correction,
                      mix_c(smooth_color.z, c.z, h) - correction};
    }
    V<N> sp = vmix(smooth_position, point, h);
    for (int i = 0; i < N; ++i) sp.c[i] -= correction;
    smooth_position = sp;
  });
  Octave o;
  o.distance = smooth_distance;
  o.color = smooth_color;
  o.position = as_position(cell + smooth_position);
  return o;
}

template <int N>
Octave voronoi_f2(const Params& p, V<N> coord) {
  const V<N> cell = vfloor(coord);
  const V<N> local = coord - cell;
  float d1 = FLT_MAX, d2 = FLT_MAX;
  V<N> offset1 = vzero<N>(), position1 = vzero<N>(), offset2 = vzero<N>(), position2 = vzero<N>();
  for_cells<N, 1>([&](V<N> off) {
    const V<N> point = off + cell_point(cell + off) * p.randomness;
    const float d = metric_distance(point, local, p);
    if (d < d1) {
      d2 = d1;
      d1 = d;
      offset2 = offset1;
      offset1 = off;
      position2 = position1;
      position1 = point;
    } else if (d < d2) {
      d2 = d;
      offset2 = off;
      position2 = point;
    }
  });
  Octave o;
  o.distance = d2;
  o.color = cell_color(cell + offset2);
  o.position = as_position(position2 + cell);
  return o;
}

template <int N>
float voronoi_distance_to_edge(const Params& p, V<N> coord) {
  const V<N> cell = vfloor(coord);
  const V<N> local = coord - cell;
  if constexpr (N == 1) {
    const float x = cell.c[0], l = local.c[0];
    const float mid = hash_to_float(x) * p.randomness;
    const float left = -1.0f + hash_to_float(x - 1.0f) * p.randomness;
    const float right = 1.0f + hash_to_float(x + 1.0f) * p.randomness;
    const float to_left = std::fabs((mid + left) / 2.0f - l);
    const float to_right = std::fabs((mid + right) / 2.0f - l);
    return min_c(to_left, to_right);
  } else {
    V<N> to_closest = vzero<N>();
    float min_distance = FLT_MAX;
    for_cells<N, 1>([&](V<N> off) {
      const V<N> to_point = (off + cell_point(cell + off) * p.randomness) - local;
      const float d = vdot(to_point, to_point);
      if (d < min_distance) {
        min_distance = d;
        to_closest = to_point;
      }
    });
    min_distance = FLT_MAX;
    for_cells<N, 1>([&](V<N> off) {
      const V<N> to_point = (off + cell_point(cell + off) * p.randomness) - local;
      const V<N> perpendicular = to_point - to_closest;
      if (vdot(perpendicular, perpendicular) > 0.0001f) {
        const float len = vlen(perpendicular);
        V<N> mid = to_closest + to_point, dir;
        for (int i = 0; i < N; ++i) {
          mid.c[i] /= 2.0f;
          dir.c[i] = perpendicular.c[i] / len;
        }
        min_distance = min_c(min_distance, vdot(mid, dir));
      }
    });
    return min_distance;
  }
}

template <int N>
float voronoi_n_sphere_radius(const Params& p, V<N> coord) {
  const V<N> cell = vfloor(coord);
  const V<N> local = coord - cell;
  V<N> closest = vzero<N>(), closest_offset = vzero<N>();
  float min_distance = FLT_MAX;
  for_cells<N, 1>([&](V<N> off) {
    const V<N> point = off + cell_point(cell + off) * p.randomness;
    const float d = vlen(point - local);
    if (d < min_distance) {
      min_distance = d;
      closest = point;
      closest_offset = off;
    }
  });
  min_distance = FLT_MAX;
  V<N> closest_to_closest = vzero<N>();
  for_cells<N, 1>([&](V<N> off) {
    bool centre = true;
    for (int i = 0; i < N; ++i) centre = centre && off.c[i] == 0.0f;
    if (centre) return;
    const V<N> cell_offset = off + closest_offset;
    const V<N> point = cell_offset + cell_point(cell + cell_offset) * p.randomness;
    const float d = vlen(closest - point);
    if (d < min_distance) {
      min_distance = d;
      closest_to_closest = point;
    }
  });
  return vlen(closest_to_closest - closest) / 2.0f;
}

// Fractal Voronoi (Blender 4.0): octaves summed like fBM noise, positions blended by lerps.
template <int N>
Octave fractal_voronoi(const Params& p, V<N> coord) {
  float amplitude = 1.0f, max_amplitude = 0.0f, scale = 1.0f;
  Octave out;
  const bool zero_input = p.detail == 0.0f || p.roughness == 0.0f;
  auto octave_at = [&](V<N> c) {
    if (p.feature == VoronoiFeature::F2) return voronoi_f2(p, c);
    if (p.feature == VoronoiFeature::SmoothF1 && p.smoothness != 0.0f) return voronoi_smooth_f1(p, c);
    return voronoi_f1(p, c);
  };
  auto scaled = [](V<4> v, float s) {
    for (float& x : v.c) x /= s;
    return v;
  };
  for (int i = 0; float(i) <= std::ceil(p.detail); ++i) {
    const Octave o = octave_at(coord * scale);
    if (zero_input) {
      max_amplitude = 1.0f;
      out = o;
      break;
    }
    if (float(i) <= p.detail) {
      max_amplitude += amplitude;
      out.distance += o.distance * amplitude;
      out.color += o.color * amplitude;
      out.position = vmix(out.position, scaled(o.position, scale), amplitude);
      scale *= p.lacunarity;
      amplitude *= p.roughness;
    } else {
      const float remainder = p.detail - std::floor(p.detail);
      if (remainder != 0.0f) {
        max_amplitude = mix_c(max_amplitude, max_amplitude + amplitude, remainder);
        out.distance = mix_c(out.distance, out.distance + o.distance * amplitude, remainder);
        const Vec3 added = out.color + o.color * amplitude;
        out.color = {mix_c(out.color.x, added.x, remainder), mix_c(out.color.y, added.y, remainder),
                     mix_c(out.color.z, added.z, remainder)};
        out.position = vmix(out.position, vmix(out.position, scaled(o.position, scale), amplitude), remainder);
      }
    }
  }
  if (p.normalize) {
    out.distance /= max_amplitude * p.max_distance;
    out.color = {out.color.x / max_amplitude, out.color.y / max_amplitude, out.color.z / max_amplitude};
  }
  for (float& x : out.position.c) x = p.scale != 0.0f ? x / p.scale : 0.0f;
  return out;
}

template <int N>
float fractal_distance_to_edge(const Params& p, V<N> coord) {
  float amplitude = 1.0f, max_amplitude = p.max_distance, scale = 1.0f, distance = 8.0f;
  const bool zero_input = p.detail == 0.0f || p.roughness == 0.0f;
  for (int i = 0; float(i) <= std::ceil(p.detail); ++i) {
    const float d = voronoi_distance_to_edge(p, coord * scale);
    if (zero_input) {
      distance = d;
      break;
    }
    if (float(i) <= p.detail) {
      max_amplitude = mix_c(max_amplitude, p.max_distance / scale, amplitude);
      distance = mix_c(distance, min_c(distance, d / scale), amplitude);
      scale *= p.lacunarity;
      amplitude *= p.roughness;
    } else {
      const float remainder = p.detail - std::floor(p.detail);
      if (remainder != 0.0f) {
        const float lerp_amplitude = mix_c(max_amplitude, p.max_distance / scale, amplitude);
        max_amplitude = mix_c(max_amplitude, lerp_amplitude, remainder);
        const float lerp_distance = mix_c(distance, min_c(distance, d / scale), amplitude);
        distance = mix_c(distance, min_c(distance, lerp_distance), remainder);
      }
    }
  }
  if (p.normalize) distance /= max_amplitude;
  return distance;
}

template <int N>
VoronoiResult voronoi_n(Params& p, V<N> coord) {
  VoronoiResult r;
  const float m = 0.5f + 0.5f * p.randomness;
  switch (p.feature) {
    case VoronoiFeature::DistanceToEdge:
      p.max_distance = m;
      r.distance = fractal_distance_to_edge(p, coord);
      return r;
    case VoronoiFeature::NSphereRadius:
      r.radius = voronoi_n_sphere_radius(p, coord);
      return r;
    default: break;
  }
  V<N> corner;
  for (float& x : corner.c) x = m;
  p.max_distance = metric_distance(vzero<N>(), corner, p) * (p.feature == VoronoiFeature::F2 ? 2.0f : 1.0f);
  const Octave o = fractal_voronoi(p, coord);
  r.distance = o.distance;
  r.color = o.color;
  r.position = {o.position.c[0], o.position.c[1], o.position.c[2]};
  r.w = o.position.c[3];
  return r;
}

}  // namespace

VoronoiResult voronoi(const VoronoiParams& in, Vec3 coord, float w) {
  Params p{in.feature, in.metric, in.normalize, in.need_color, in.scale, in.detail, in.roughness, in.lacunarity,
           in.smoothness, in.exponent, in.randomness};
  p.detail = clamp_c(p.detail, 0.0f, 15.0f);
  p.roughness = clamp_c(p.roughness, 0.0f, 1.0f);
  p.randomness = clamp_c(p.randomness, 0.0f, 1.0f);
  p.smoothness = clamp_c(p.smoothness / 2.0f, 0.0f, 0.5f);
  coord = coord * p.scale;
  w *= p.scale;
  switch (in.dimensions) {
    case 1: return voronoi_n<1>(p, V<1>{{w}});
    case 2: return voronoi_n<2>(p, V<2>{{coord.x, coord.y}});
    case 4: return voronoi_n<4>(p, V<4>{{coord.x, coord.y, coord.z, w}});
    default: return voronoi_n<3>(p, V<3>{{coord.x, coord.y, coord.z}});
  }
}

// ---------------------------------------------------------------- shader ops

namespace {
inline float fin(float x) { return std::isfinite(x) ? x : 0.0f; }
inline Float4 value4(float v) {
  v = fin(v);
  return {v, v, v, 1.0f};
}
inline Float4 vec4(Vec3 v, float w) { return {fin(v.x), fin(v.y), fin(v.z), w}; }
}  // namespace

Float4 eval_pattern_op(const ShaderOp& op, const Float4* r) {
  static const Float4 zero{};
  auto reg = [&](int k) -> const Float4& { return op.in[k] == kNoReg ? zero : r[op.in[k]]; };
  auto val = [&](int k) { return reg(k).x; };
  switch (op.code) {
    case OpCode::Checker: {  // in: vector, color1, color2, scale; sub: 0 Color, 1 Fac
      const float f = checker(reg(0).xyz() * val(3));
      if (op.sub == 1) return value4(f);
      return vec4(f == 1.0f ? reg(1).xyz() : reg(2).xyz(), 1.0f);
    }
    case OpCode::Gradient:  // in: vector; sub: the type (Color and Fac read alike)
      return value4(gradient(reg(0).xyz(), GradientType(op.sub)));
    case OpCode::Brick: {
      // in: vector, color1, color2, mortar, scale, mortar size, mortar smooth, bias, brick
      // width, row height; m[0] offset, m[1] squash; index / count: their frequencies.
      BrickParams bp;
      bp.mortar_size = val(5);
      bp.mortar_smooth = val(6);
      bp.bias = val(7);
      bp.brick_width = val(8);
      bp.row_height = val(9);
      bp.offset = op.m[0];
      bp.squash = op.m[1];
      bp.offset_frequency = op.index;
      bp.squash_frequency = op.count;
      const BrickSample b = brick(reg(0).xyz() * val(4), bp);
      if (op.sub == 1) return value4(b.mortar);
      Vec3 c = reg(1).xyz();
      if (b.mortar != 1.0f) c = c * (1.0f - b.tint) + reg(2).xyz() * b.tint;
      return vec4(c * (1.0f - b.mortar) + reg(3).xyz() * b.mortar, 1.0f);
    }
    case OpCode::Voronoi: {
      // in: vector, w, scale, detail, roughness, lacunarity, smoothness, exponent, randomness;
      // ext: dimensions, index: feature, count: metric, clamp: normalize; sub: the output
      // (0 Distance, 1 Color, 2 Position, 3 W, 4 Radius).
      VoronoiParams vp;
      vp.dimensions = op.ext;
      vp.feature = VoronoiFeature(op.index);
      vp.metric = VoronoiMetric(op.count);
      vp.normalize = op.clamp;
      vp.scale = val(2);
      vp.detail = val(3);
      vp.roughness = val(4);
      vp.lacunarity = val(5);
      vp.smoothness = val(6);
      vp.exponent = val(7);
      vp.randomness = val(8);
      vp.need_color = op.sub == 1;
      const VoronoiResult v = voronoi(vp, reg(0).xyz(), val(1));
      switch (op.sub) {
        case 1: return vec4(v.color, 1.0f);
        case 2: return vec4(v.position, 0.0f);
        case 3: return value4(v.w);
        case 4: return value4(v.radius);
        default: return value4(v.distance);
      }
    }
    default: return zero;
  }
}

}  // namespace pl::tex
