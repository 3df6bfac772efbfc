// Image Texture lookups: texel filtering, wrapping and sRGB decoding.
#include "scene/shader.h"
#include "scene/shader_math.h"

namespace pl {

using namespace shader_math;  // wrap, lerp4

Float4 sample_image(const Image& img, float u, float v, Interp interp, Extension ext) {
  if (img.w <= 0 || img.h <= 0 || !std::isfinite(u) || !std::isfinite(v)) return {};
  // Clip as Cycles' kernel: texels beyond the image read zero, so Linear fades the border
  // texels out over half a texel outside [0, 1] (and everything further out is zero).
  if (ext == Extension::Clip && !(u > -1.0f && u < 2.0f && v > -1.0f && v < 2.0f)) return {};
  static const Float4 kZero{};
  auto fetch = [&](int x, int y) -> const Float4& {
    if (ext == Extension::Repeat) {
      x = wrap(x, img.w);
      y = wrap(y, img.h);
    } else if (ext == Extension::Clip) {
      if (x < 0 || x >= img.w || y < 0 || y >= img.h) return kZero;
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
  } else if (ext == Extension::Extend) {
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

Float4 image_texture(const std::vector<Image>& images, size_t id, float u, float v, Interp interp, Extension ext,
                     bool unassociate) {
  const Image& img = images[id];
  if (img.tiles.empty()) return image_lookup(img, u, v, interp, ext, unassociate);
  // (int) truncates toward zero, as Cycles' kernel; the bounds keep it defined (NaN fails them).
  if (u > -1.0f && u < 10.0f && v > -1.0f && v < 1000.0f) {
    const int tx = int(u), ty = int(v);
    const int number = 1001 + tx + 10 * ty;
    for (const ImageTile& t : img.tiles)
      if (t.number == number)
        return image_lookup(images[size_t(t.image)], u - float(tx), v - float(ty), interp, ext, unassociate);
  }
  return {1.0f, 0.0f, 1.0f, 1.0f};  // Cycles' TEX_IMAGE_MISSING
}

}  // namespace pl
