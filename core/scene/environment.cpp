#include "scene/light.h"

namespace pl {

Environment::Environment(std::vector<Vec3> pixels, int w, int h, float strength, const Mat4& rotation)
    : px_(std::move(pixels)), w_(w), h_(h), rot_(rotation) {
  // Kept finite: a texel that overflows with the strength would make samples non-finite.
  for (Vec3& c : px_) c = vmin(c * strength, Vec3(1e30f));
  std::vector<float> lum(px_.size());
  double lum_sum = 0.0;
  for (size_t i = 0; i < px_.size(); ++i) {
    lum[i] = std::max(0.0f, luminance(px_[i]));
    lum_sum += lum[i];
  }
  // The lookup is bilinear, so a texel's radiance reaches into its neighbours: sample each texel
  // by the brightest of its 3x3 neighbourhood. Then every direction with radiance has density
  // (needed where only light sampling is used) and a bright texel's footprint is sampled well.
  std::vector<float> row_weights(static_cast<size_t>(h_));
  rows_.reserve(size_t(h_));
  for (int y = 0; y < h_; ++y) {
    const float elevation = kPi * ((y + 0.5f) / h_ - 0.5f);
    const float c = std::cos(elevation);
    std::vector<float> wts(static_cast<size_t>(w_));
    double row_sum = 0.0;
    for (int x = 0; x < w_; ++x) {
      float m = 0.0f;
      for (int dy = -1; dy <= 1; ++dy)
        for (int dx = -1; dx <= 1; ++dx) {
          const int yy = std::clamp(y + dy, 0, h_ - 1), xx = ((x + dx) % w_ + w_) % w_;
          m = std::max(m, lum[size_t(yy) * w_ + xx]);
        }
      wts[size_t(x)] = m;
      row_sum += m;
    }
    row_weights[size_t(y)] = static_cast<float>(row_sum * c);
    rows_.emplace_back(wts);
  }
  marginal_ = Distribution1D(row_weights);
  avg_lum_ = static_cast<float>(lum_sum / (double(w_) * h_));
}

void Environment::to_uv(Vec3 t, float& u, float& v) const {
  const float len = length(t);
  u = (std::atan2(t.y, t.x) - kPi) / (-2.0f * kPi);
  v = 0.5f + std::asin(clampf(t.z / len, -1.0f, 1.0f)) / kPi;
}

Vec3 Environment::lookup(float u, float v) const {
  if (!std::isfinite(u) || !std::isfinite(v)) return Vec3(0.0f);  // a NaN direction sees nothing
  // Bilinear, wrapping in u, clamped in v.
  float fx = u * w_ - 0.5f, fy = v * h_ - 0.5f;
  fx -= std::floor(fx / w_) * w_;
  const int x0 = static_cast<int>(std::floor(fx)), y0 = static_cast<int>(std::floor(fy));
  const float tx = fx - x0, ty = fy - y0;
  const int xa = x0 % w_, xb = (x0 + 1) % w_;
  const int ya = std::clamp(y0, 0, h_ - 1), yb = std::clamp(y0 + 1, 0, h_ - 1);
  auto at = [&](int x, int y) { return px_[size_t(y) * w_ + x]; };
  return (at(xa, ya) * (1 - tx) + at(xb, ya) * tx) * (1 - ty) + (at(xa, yb) * (1 - tx) + at(xb, yb) * tx) * ty;
}

Vec3 Environment::eval(Vec3 dir_world) const {
  float u, v;
  to_uv(rot_.vector(dir_world), u, v);
  return lookup(u, v);
}

bool Environment::sample(Vec2 uu, Vec3& dir, Vec3& radiance, float& pdf_out) const {
  if (marginal_.empty()) return false;
  float ry, rx;
  const size_t y = marginal_.sample(uu.y, ry);
  const size_t x = rows_[y].sample(uu.x, rx);
  const float u = (x + rx) / w_, v = (y + ry) / h_;
  const float elevation = kPi * (v - 0.5f), phi = kPi - 2.0f * kPi * u;
  const float ce = std::cos(elevation);
  if (!(ce > 0.0f)) return false;
  const Vec3 t{ce * std::cos(phi), ce * std::sin(phi), std::sin(elevation)};
  // Texture -> world: the rotation is orthonormal, so its transpose inverts it.
  const Mat4& m = rot_;
  dir = normalize(Vec3{m.m[0][0] * t.x + m.m[1][0] * t.y + m.m[2][0] * t.z,
                       m.m[0][1] * t.x + m.m[1][1] * t.y + m.m[2][1] * t.z,
                       m.m[0][2] * t.x + m.m[1][2] * t.y + m.m[2][2] * t.z});
  // pdf over (u, v) is pmf(row) * h * pmf(col | row) * w; d(omega) = 2 pi^2 cos(elev) du dv.
  pdf_out = marginal_.pmf(y) * h_ * rows_[y].pmf(x) * w_ / (2.0f * kPi * kPi * ce);
  radiance = lookup(u, v);
  return pdf_out > 0.0f && std::isfinite(pdf_out);
}

float Environment::pdf(Vec3 dir_world) const {
  if (marginal_.empty()) return 0.0f;
  float u, v;
  const Vec3 t = rot_.vector(dir_world);
  to_uv(t, u, v);
  if (!std::isfinite(u) || !std::isfinite(v)) return 0.0f;
  const int x = std::clamp(static_cast<int>(u * w_), 0, w_ - 1);
  const int y = std::clamp(static_cast<int>(v * h_), 0, h_ - 1);
  const float ce = std::cos(kPi * (v - 0.5f));
  if (!(ce > 0.0f)) return 0.0f;
  return marginal_.pmf(size_t(y)) * h_ * rows_[size_t(y)].pmf(size_t(x)) * w_ / (2.0f * kPi * kPi * ce);
}

}  // namespace pl
