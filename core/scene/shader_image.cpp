// Image Texture lookups: texel filtering, wrapping and sRGB decoding.
#include "scene/shader.h"
#include "scene/shader_math.h"

namespace pl {

using namespace shader_math;  // wrap, lerp4

namespace {

// Cycles' wrap_mirror: ... 2 1 0 | 0 1 2 ... w-1 | w-1 w-2 ...
inline int wrap_mirror(int x, int n) {
  const int m = std::abs(x + (x < 0)) % (2 * n);
  return m >= n ? 2 * n - m - 1 : m;
}

// Cycles' SET_CUBIC_SPLINE_WEIGHTS (uniform cubic B-spline).
inline void cubic_weights(float t, float w[4]) {
  w[0] = (((-1.0f / 6.0f) * t + 0.5f) * t - 0.5f) * t + (1.0f / 6.0f);
  w[1] = ((0.5f * t - 1.0f) * t) * t + (2.0f / 3.0f);
  w[2] = ((-0.5f * t + 0.5f) * t + 0.5f) * t + (1.0f / 6.0f);
  w[3] = (1.0f / 6.0f) * t * t * t;
}

inline Float4 madd4(const Float4& acc, const Float4& a, float w) {
  return {acc.x + a.x * w, acc.y + a.y * w, acc.z + a.z * w, acc.w + a.w * w};
}

}  // namespace

Float4 sample_image(const Image& img, float u, float v, Interp interp, Extension ext) {
  if (img.w <= 0 || img.h <= 0 || !std::isfinite(u) || !std::isfinite(v)) return {};
  // Clip as Cycles' kernel: texels beyond the image read zero, so Linear fades the border
  // texels out over half a texel outside [0, 1] (Cubic over two; everything further is zero).
  if (ext == Extension::Clip && !(u > -1.0f && u < 2.0f && v > -1.0f && v < 2.0f)) return {};
  static const Float4 kZero{};
  auto fetch = [&](int x, int y) -> const Float4& {
    if (ext == Extension::Repeat) {
      x = wrap(x, img.w);
      y = wrap(y, img.h);
    } else if (ext == Extension::Clip) {
      if (x < 0 || x >= img.w || y < 0 || y >= img.h) return kZero;
    } else if (ext == Extension::Mirror) {
      x = wrap_mirror(x, img.w);
      y = wrap_mirror(y, img.h);
    } else {
      x = std::clamp(x, 0, img.w - 1);
      y = std::clamp(y, 0, img.h - 1);
    }
    return img.px[size_t(y) * size_t(img.w) + size_t(x)];
  };
  // Keep coordinates in a range where float->int is exact (Repeat and Mirror are periodic).
  if (ext == Extension::Repeat) {
    u -= std::floor(u);
    v -= std::floor(v);
  } else if (ext == Extension::Mirror) {
    u -= 2.0f * std::floor(0.5f * u);
    v -= 2.0f * std::floor(0.5f * v);
  } else if (ext == Extension::Extend) {
    u = clampf(u, -1.0f, 2.0f);
    v = clampf(v, -1.0f, 2.0f);
  }
  const float fx = u * img.w, fy = v * img.h;
  if (interp == Interp::Closest) return fetch(int(std::floor(fx)), int(std::floor(fy)));
  const float x = fx - 0.5f, y = fy - 0.5f;
  const int x0 = int(std::floor(x)), y0 = int(std::floor(y));
  const float tx = x - x0, ty = y - y0;
  if (interp == Interp::Cubic) {  // Cycles' interp_cubic: 4x4 texels from x0 - 1, y0 - 1
    float wx[4], wy[4];
    cubic_weights(tx, wx);
    cubic_weights(ty, wy);
    Float4 r{};
    for (int j = 0; j < 4; ++j) {
      Float4 row{};
      for (int i = 0; i < 4; ++i) row = madd4(row, fetch(x0 - 1 + i, y0 - 1 + j), wx[i]);
      r = madd4(r, row, wy[j]);
    }
    return r;
  }
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

Float4 image_box(const std::vector<Image>& images, size_t id, Vec3 co, Vec3 n, float blend, Interp interp,
                 Extension ext, bool unassociate) {
  const Image* img = &images[id];
  if (!img->tiles.empty()) {
    const size_t first = size_t(img->tiles.front().image);
    if (first >= images.size()) return {1.0f, 0.0f, 1.0f, 1.0f};
    img = &images[first];
  }
  const Vec3 signed_n = n;
  Vec3 a{std::fabs(n.x), std::fabs(n.y), std::fabs(n.z)};
  a = a / (a.x + a.y + a.z);
  // Cycles' seven zones of the barycentric triangle of the three axes.
  float wx = 0.0f, wy = 0.0f, wz = 0.0f;
  const float limit = 0.5f * (1.0f + blend);
  if (a.x > limit * (a.x + a.y) && a.x > limit * (a.x + a.z)) {
    wx = 1.0f;
  } else if (a.y > limit * (a.x + a.y) && a.y > limit * (a.y + a.z)) {
    wy = 1.0f;
  } else if (a.z > limit * (a.x + a.z) && a.z > limit * (a.y + a.z)) {
    wz = 1.0f;
  } else if (blend > 0.0f) {
    if (a.z < (1.0f - limit) * (a.y + a.x)) {
      wx = clampf((a.x / (a.x + a.y) - 0.5f * (1.0f - blend)) / blend, 0.0f, 1.0f);
      wy = 1.0f - wx;
    } else if (a.x < (1.0f - limit) * (a.y + a.z)) {
      wy = clampf((a.y / (a.y + a.z) - 0.5f * (1.0f - blend)) / blend, 0.0f, 1.0f);
      wz = 1.0f - wy;
    } else if (a.y < (1.0f - limit) * (a.x + a.z)) {
      wx = clampf((a.x / (a.x + a.z) - 0.5f * (1.0f - blend)) / blend, 0.0f, 1.0f);
      wz = 1.0f - wx;
    } else {
      wx = ((2.0f - limit) * a.x + (limit - 1.0f)) / (2.0f * limit - 1.0f);
      wy = ((2.0f - limit) * a.y + (limit - 1.0f)) / (2.0f * limit - 1.0f);
      wz = ((2.0f - limit) * a.z + (limit - 1.0f)) / (2.0f * limit - 1.0f);
    }
  } else {
    wx = 1.0f;  // (Cycles' fallback where no zone holds, e.g. a NaN normal)
  }
  Float4 f{};
  if (wx > 0.0f)
    f = madd4(f, image_lookup(*img, signed_n.x < 0.0f ? 1.0f - co.y : co.y, co.z, interp, ext, unassociate), wx);
  if (wy > 0.0f)
    f = madd4(f, image_lookup(*img, signed_n.y > 0.0f ? 1.0f - co.x : co.x, co.z, interp, ext, unassociate), wy);
  if (wz > 0.0f)
    f = madd4(f, image_lookup(*img, signed_n.z > 0.0f ? 1.0f - co.y : co.y, co.x, interp, ext, unassociate), wz);
  return f;
}

}  // namespace pl
