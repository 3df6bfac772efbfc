// Image Texture lookups: texel filtering, wrapping and sRGB decoding.
#include "scene/shader.h"
#include "scene/shader_math.h"

namespace pl {

using namespace shader_math;  // wrap, lerp4

Float4 sample_image(const Image& img, float u, float v, Interp interp, Extension ext) {
  if (img.w <= 0 || img.h <= 0 || !std::isfinite(u) || !std::isfinite(v)) return {};
  if (ext == Extension::Clip && (u < 0.0f || u > 1.0f || v < 0.0f || v > 1.0f)) return {};
  auto fetch = [&](int x, int y) -> const Float4& {
    if (ext == Extension::Repeat) {
      x = wrap(x, img.w);
      y = wrap(y, img.h);
    } else {
      x = std::clamp(x, 0, img.w - 1);
      y = std::clamp(y, 0, img.h - 1);
    }
    return img.px[size_t(y) * size_t(img.w) + size_t(x)];
  };
  // Keep coordinates in a range where float->int is exact (Repeat is periodic anyway).
  if (ext == Extension::Repeat) {
    u -= std::floor(u);
    v -= std::floor(v);
  } else {
    u = clampf(u, -1.0f, 2.0f);
    v = clampf(v, -1.0f, 2.0f);
  }
  const float fx = u * img.w, fy = v * img.h;
  if (interp == Interp::Closest) return fetch(int(std::floor(fx)), int(std::floor(fy)));
  const float x = fx - 0.5f, y = fy - 0.5f;
  const int x0 = int(std::floor(x)), y0 = int(std::floor(y));
  const float tx = x - x0, ty = y - y0;
  return lerp4(lerp4(fetch(x0, y0), fetch(x0 + 1, y0), tx), lerp4(fetch(x0, y0 + 1), fetch(x0 + 1, y0 + 1), tx), ty);
}

float srgb_to_linear(float c) {
  // Cycles' color_srgb_to_linear (negative values clamp to 0).
  if (c < 0.04045f) return c < 0.0f ? 0.0f : c * (1.0f / 12.92f);
  return std::pow((c + 0.055f) * (1.0f / 1.055f), 2.4f);
}

Float4 image_lookup(const Image& img, float u, float v, Interp interp, Extension ext, bool unassociate) {
  Float4 r = sample_image(img, u, v, interp, ext);
  if (unassociate && r.w != 1.0f && r.w != 0.0f) {
    const float inv = 1.0f / r.w;
    r = {r.x * inv, r.y * inv, r.z * inv, r.w};
  }
  if (img.srgb) r = {srgb_to_linear(r.x), srgb_to_linear(r.y), srgb_to_linear(r.z), r.w};
  return r;
}

}  // namespace pl
