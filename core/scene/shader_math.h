// The value arithmetic of shader programs as Cycles' SVM nodes compute it (Math, Mix,
// colour spaces, Vector Math, Map Range steps, ramps): included by the units that evaluate
// programs alone (shader.cpp, shader_closures.cpp, shader_image.cpp).
#pragma once
#include <algorithm>
#include <cmath>

#include "scene/shader.h"

namespace pl::shader_math {

inline Float4 f4(Vec3 v, float w = 1.0f) { return {v.x, v.y, v.z, w}; }
inline Float4 lerp4(const Float4& a, const Float4& b, float t) {
  return {a.x + (b.x - a.x) * t, a.y + (b.y - a.y) * t, a.z + (b.z - a.z) * t, a.w + (b.w - a.w) * t};
}

inline int wrap(int i, int n) {
  const int r = i % n;
  return r < 0 ? r + n : r;
}

inline float smooth_min(float a, float b, float c) {
  if (c == 0.0f) return std::min(a, b);
  const float h = std::max(c - std::fabs(a - b), 0.0f) / c;
  return std::min(a, b) - h * h * h * c * (1.0f / 6.0f);
}

inline float math_op(MathOp op, float a, float b, float c = 0.0f) {
  switch (op) {
    case MathOp::Logarithm: return a > 0.0f && b > 0.0f && std::log(b) != 0.0f ? std::log(a) / std::log(b) : 0.0f;
    case MathOp::Sqrt: return a > 0.0f ? std::sqrt(a) : 0.0f;
    case MathOp::InverseSqrt: return a > 0.0f ? 1.0f / std::sqrt(a) : 0.0f;
    case MathOp::Exponent: return std::exp(a);
    case MathOp::Sign: return a == 0.0f ? 0.0f : (a > 0.0f ? 1.0f : -1.0f);
    case MathOp::Round: return std::floor(a + 0.5f);
    case MathOp::Floor: return std::floor(a);
    case MathOp::Ceil: return std::ceil(a);
    case MathOp::Trunc: return a >= 0.0f ? std::floor(a) : std::ceil(a);
    case MathOp::Fract: return a - std::floor(a);
    case MathOp::Modulo: return b != 0.0f ? std::fmod(a, b) : 0.0f;
    case MathOp::FlooredModulo: return b != 0.0f ? a - std::floor(a / b) * b : 0.0f;
    case MathOp::Snap: return b != 0.0f ? std::floor(a / b) * b : 0.0f;
    case MathOp::PingPong: {
      if (b == 0.0f) return 0.0f;
      const float x = (a - b) / (b * 2.0f);
      return std::fabs((x - std::floor(x)) * b * 2.0f - b);
    }
    case MathOp::Sine: return std::sin(a);
    case MathOp::Cosine: return std::cos(a);
    case MathOp::Tangent: return std::tan(a);
    case MathOp::Arcsine: return std::asin(clampf(a, -1.0f, 1.0f));
    case MathOp::Arccosine: return std::acos(clampf(a, -1.0f, 1.0f));
    case MathOp::Arctangent: return std::atan(a);
    case MathOp::Arctan2: return std::atan2(a, b);
    case MathOp::Sinh: return std::sinh(a);
    case MathOp::Cosh: return std::cosh(a);
    case MathOp::Tanh: return std::tanh(a);
    case MathOp::Radians: return a * (kPi / 180.0f);
    case MathOp::Degrees: return a * (180.0f / kPi);
    case MathOp::MultiplyAdd: return a * b + c;
    case MathOp::Compare: return a == b || std::fabs(a - b) <= std::max(c, 1.1920929e-7f) ? 1.0f : 0.0f;
    case MathOp::SmoothMin: return smooth_min(a, b, c);
    case MathOp::SmoothMax: return -smooth_min(-a, -b, c);
    case MathOp::Wrap: {
      const float range = b - c;
      return range != 0.0f ? a - range * std::floor((a - c) / range) : c;
    }
    case MathOp::Add: return a + b;
    case MathOp::Subtract: return a - b;
    case MathOp::Multiply: return a * b;
    case MathOp::Divide: return b != 0.0f ? a / b : 0.0f;  // Blender's safe divide
    case MathOp::Power: {
      if (a >= 0.0f) return std::pow(a, b);
      const float fb = std::floor(b);  // negative base: only integer powers are defined
      return fb == b ? std::pow(a, b) : 0.0f;
    }
    case MathOp::Minimum: return std::min(a, b);
    case MathOp::Maximum: return std::max(a, b);
    case MathOp::LessThan: return a < b ? 1.0f : 0.0f;
    case MathOp::GreaterThan: return a > b ? 1.0f : 0.0f;
    case MathOp::Absolute: return std::fabs(a);
  }
  return 0.0f;
}

inline float mix_channel(MixOp op, float a, float b, float f) {
  const float g = 1.0f - f;
  switch (op) {
    case MixOp::Mix: return g * a + f * b;
    case MixOp::Multiply: return a * (g + f * b);
    case MixOp::Add: return a + f * b;
    case MixOp::Subtract: return a - f * b;
    case MixOp::Screen: return 1.0f - (g + f * (1.0f - b)) * (1.0f - a);
    case MixOp::Divide: return b != 0.0f ? g * a + f * a / b : a;
    case MixOp::Difference: return g * a + f * std::fabs(a - b);
    case MixOp::Darken: return g * a + f * std::min(a, b);
    case MixOp::Lighten: return g * a + f * std::max(a, b);
    case MixOp::Overlay:
      return a < 0.5f ? a * (g + 2.0f * f * b) : 1.0f - (g + 2.0f * f * (1.0f - b)) * (1.0f - a);
  }
  return a;
}

inline float sat(float x) { return clampf(x, 0.0f, 1.0f); }

// A normal input in the outward orientation of ctx.ns: a linked value faces the viewer (the
// programs' convention, Cycles' sd->N), so it turns back on a back-facing hit; unlinked (or
// degenerate) the shading normal.
inline Vec3 normal_or(const Float4* r, int16_t reg, const ShadingContext& ctx) {
  if (reg == kNoReg) return ctx.ns;
  const Vec3 n = r[reg].xyz();
  const float l2 = length_sq(n);
  return l2 > 1e-12f && std::isfinite(l2) ? n * (ctx.view_side() / std::sqrt(l2)) : ctx.ns;
}

inline float roughness_to_alpha(float r) {
  r = sat(std::isfinite(r) ? r : 0.0f);
  return r * r;
}

// Rodrigues' rotation of p by `angle` (counter-clockwise) about the unit `axis`.
inline Vec3 rotate_about_axis(Vec3 p, Vec3 axis, float angle) {
  const float c = std::cos(angle), s = std::sin(angle);
  return p * c + cross(axis, p) * s + axis * (dot(axis, p) * (1.0f - c));
}

inline float clean_ior(float ior) { return std::isfinite(ior) && ior > 1e-3f ? ior : 1.0f; }

[[gnu::always_inline]] inline Vec3 clean_color(Vec3 c) {
  auto f = [](float x) { return std::isfinite(x) && x > 0.0f ? x : 0.0f; };
  return {f(c.x), f(c.y), f(c.z)};
}

// Colour conversions as Cycles' util/color.h (hue in [0, 1)).
inline Vec3 rgb_to_hsv(Vec3 rgb) {
  const float cmax = std::max(rgb.x, std::max(rgb.y, rgb.z));
  const float cmin = std::min(rgb.x, std::min(rgb.y, rgb.z));
  const float cdelta = cmax - cmin;
  const float v = cmax;
  const float s = cmax != 0.0f ? cdelta / cmax : 0.0f;
  float h = 0.0f;
  if (s != 0.0f) {
    const Vec3 c = (Vec3(cmax) - rgb) / cdelta;
    if (rgb.x == cmax) h = c.z - c.y;
    else if (rgb.y == cmax) h = 2.0f + c.x - c.z;
    else h = 4.0f + c.y - c.x;
    h /= 6.0f;
    if (h < 0.0f) h += 1.0f;
  }
  return {h, s, v};
}

inline Vec3 hsv_to_rgb(Vec3 hsv) {
  float h = hsv.x;
  const float s = hsv.y, v = hsv.z;
  if (s == 0.0f) return Vec3(v);
  if (h == 1.0f) h = 0.0f;
  h *= 6.0f;
  const float i = std::floor(h), f = h - i;
  const float p = v * (1.0f - s), q = v * (1.0f - s * f), t = v * (1.0f - s * (1.0f - f));
  if (i == 0.0f) return {v, t, p};
  if (i == 1.0f) return {q, v, p};
  if (i == 2.0f) return {p, v, t};
  if (i == 3.0f) return {p, q, v};
  if (i == 4.0f) return {t, p, v};
  return {v, p, q};
}

inline Vec3 rgb_to_hsl(Vec3 rgb) {
  const float cmax = std::max(rgb.x, std::max(rgb.y, rgb.z));
  const float cmin = std::min(rgb.x, std::min(rgb.y, rgb.z));
  const float l = std::min(1.0f, (cmax + cmin) / 2.0f);
  float h = 0.0f, s = 0.0f;
  if (cmax != cmin) {
    const float cdelta = cmax - cmin;
    s = l > 0.5f ? cdelta / (2.0f - cmax - cmin) : cdelta / (cmax + cmin);
    if (cmax == rgb.x) h = (rgb.y - rgb.z) / cdelta + (rgb.y < rgb.z ? 6.0f : 0.0f);
    else if (cmax == rgb.y) h = (rgb.z - rgb.x) / cdelta + 2.0f;
    else h = (rgb.x - rgb.y) / cdelta + 4.0f;
  }
  return {h / 6.0f, s, l};
}

inline Vec3 hsl_to_rgb(Vec3 hsl) {
  const float h = hsl.x, s = hsl.y, l = hsl.z;
  const float nr = sat(std::fabs(h * 6.0f - 3.0f) - 1.0f);
  const float ng = sat(2.0f - std::fabs(h * 6.0f - 2.0f));
  const float nb = sat(2.0f - std::fabs(h * 6.0f - 4.0f));
  const float chroma = (1.0f - std::fabs(2.0f * l - 1.0f)) * s;
  return {(nr - 0.5f) * chroma + l, (ng - 0.5f) * chroma + l, (nb - 0.5f) * chroma + l};
}

// Cycles' fresnel_dielectric_cos (the Fresnel and Layer Weight nodes).
inline float fresnel_node(float cosi, float eta) {
  const float c = std::fabs(cosi);
  float g = eta * eta - 1.0f + c * c;
  if (!(g > 0.0f)) return 1.0f;  // total internal reflection
  g = std::sqrt(g);
  const float A = (g - c) / (g + c);
  const float B = (c * (g + c) - 1.0f) / (c * (g - c) + 1.0f);
  return 0.5f * A * A * (1.0f + B * B);
}

inline float safe_div(float a, float b) { return b != 0.0f ? a / b : 0.0f; }
inline float safe_mod(float a, float b) { return b != 0.0f ? std::fmod(a, b) : 0.0f; }
inline float wrapf(float v, float hi, float lo) {
  const float range = hi - lo;
  return range != 0.0f ? v - range * std::floor((v - lo) / range) : lo;
}
inline float sign_of(float f) { return f == 0.0f ? 0.0f : (f > 0.0f ? 1.0f : -1.0f); }
inline float smoothstep(float e0, float e1, float x) {
  if (x < e0) return 0.0f;
  if (x >= e1) return 1.0f;
  const float t = (x - e0) / (e1 - e0);
  return (3.0f - 2.0f * t) * (t * t);
}
inline float smootherstep(float e0, float e1, float x) {
  x = sat(safe_div(x - e0, e1 - e0));
  return x * x * x * (x * (x * 6.0f - 15.0f) + 10.0f);
}

template <class F>
inline Vec3 per_component(Vec3 a, Vec3 b, Vec3 c, F f) {
  return {f(a.x, b.x, c.x), f(a.y, b.y, c.y), f(a.z, b.z, c.z)};
}

// Blender's Vector Math; `value` is set for the operations whose result is a value.
inline Vec3 vector_math(VectorMathOp op, Vec3 a, Vec3 b, Vec3 c, float scale, float& value, bool& is_value) {
  is_value = false;
  switch (op) {
    case VectorMathOp::Add: return a + b;
    case VectorMathOp::Subtract: return a - b;
    case VectorMathOp::Multiply: return a * b;
    case VectorMathOp::Divide: return per_component(a, b, c, [](float x, float y, float) { return safe_div(x, y); });
    case VectorMathOp::MultiplyAdd: return a * b + c;
    case VectorMathOp::CrossProduct: return cross(a, b);
    case VectorMathOp::Project: {
      const float l2 = dot(b, b);
      return l2 != 0.0f ? b * (dot(a, b) / l2) : Vec3(0.0f);
    }
    case VectorMathOp::Reflect: {
      const float l2 = length_sq(b);
      if (!(l2 > 0.0f)) return a;
      const Vec3 n = b / std::sqrt(l2);
      return a - n * (2.0f * dot(a, n));
    }
    case VectorMathOp::Refract: {
      const float l2 = length_sq(b);
      const Vec3 n = l2 > 0.0f ? b / std::sqrt(l2) : b;
      const float d = dot(n, a);
      const float k = 1.0f - scale * scale * (1.0f - d * d);
      return k < 0.0f ? Vec3(0.0f) : a * scale - n * (scale * d + std::sqrt(k));
    }
    case VectorMathOp::FaceForward: return dot(b, c) < 0.0f ? a : -a;
    case VectorMathOp::DotProduct: is_value = true; value = dot(a, b); return Vec3(0.0f);
    case VectorMathOp::Distance: is_value = true; value = length(a - b); return Vec3(0.0f);
    case VectorMathOp::Length: is_value = true; value = length(a); return Vec3(0.0f);
    case VectorMathOp::Scale: return a * scale;
    case VectorMathOp::Normalize: {
      const float l = length(a);
      return l != 0.0f ? a / l : Vec3(0.0f);
    }
    case VectorMathOp::Absolute: return vabs(a);
    case VectorMathOp::Power:
      return per_component(a, b, c, [](float x, float y, float) { return math_op(MathOp::Power, x, y); });
    case VectorMathOp::Sign: return {sign_of(a.x), sign_of(a.y), sign_of(a.z)};
    case VectorMathOp::Minimum: return vmin(a, b);
    case VectorMathOp::Maximum: return vmax(a, b);
    case VectorMathOp::Floor: return {std::floor(a.x), std::floor(a.y), std::floor(a.z)};
    case VectorMathOp::Ceil: return {std::ceil(a.x), std::ceil(a.y), std::ceil(a.z)};
    case VectorMathOp::Fraction: return a - Vec3{std::floor(a.x), std::floor(a.y), std::floor(a.z)};
    case VectorMathOp::Modulo: return per_component(a, b, c, [](float x, float y, float) { return safe_mod(x, y); });
    case VectorMathOp::Wrap: return per_component(a, b, c, [](float x, float y, float z) { return wrapf(x, y, z); });
    case VectorMathOp::Snap:
      return per_component(a, b, c, [](float x, float y, float) { return std::floor(safe_div(x, y)) * y; });
    case VectorMathOp::Sine: return {std::sin(a.x), std::sin(a.y), std::sin(a.z)};
    case VectorMathOp::Cosine: return {std::cos(a.x), std::cos(a.y), std::cos(a.z)};
    case VectorMathOp::Tangent: return {std::tan(a.x), std::tan(a.y), std::tan(a.z)};
  }
  return Vec3(0.0f);
}

// Cycles' rgb_ramp_lookup over a baked table of n >= 2 entries.
inline Float4 ramp_lookup(const Float4* t, int n, float f, bool interpolate, bool extrapolate) {
  if (extrapolate && (f < 0.0f || f > 1.0f)) {
    const bool low = f < 0.0f;
    const Float4 t0 = low ? t[0] : t[n - 1], t1 = low ? t[1] : t[n - 2];
    const float k = (low ? -f : f - 1.0f) * float(n - 1);
    return {t0.x + (t0.x - t1.x) * k, t0.y + (t0.y - t1.y) * k, t0.z + (t0.z - t1.z) * k, t0.w + (t0.w - t1.w) * k};
  }
  f = std::isfinite(f) ? sat(f) * float(n - 1) : 0.0f;
  const int i = std::clamp(int(f), 0, n - 1);
  const float w = f - float(i);
  return interpolate && w > 0.0f && i + 1 < n ? lerp4(t[i], t[i + 1], w) : t[i];
}


}  // namespace pl::shader_math
