#include "scene/light.h"

namespace pl {

namespace {

// Bilinear between texel centres, wrapping in u, clamped in v (Cycles' Linear interpolation).
template <class T>
T bilinear(const std::vector<T>& px, int w, int h, float u, float v) {
  float fx = u * w - 0.5f, fy = v * h - 0.5f;
  fx -= std::floor(fx / w) * w;
  const int x0 = static_cast<int>(std::floor(fx)), y0 = static_cast<int>(std::floor(fy));
  const float tx = fx - x0, ty = fy - y0;
  const int xa = x0 % w, xb = (x0 + 1) % w;
  const int ya = std::clamp(y0, 0, h - 1), yb = std::clamp(y0 + 1, 0, h - 1);
  auto at = [&](int x, int y) { return px[size_t(y) * w + x]; };
  return (at(xa, ya) * (1 - tx) + at(xb, ya) * tx) * (1 - ty) + (at(xa, yb) * (1 - tx) + at(xb, yb) * tx) * ty;
}

}  // namespace

Environment::Environment(std::vector<Vec3> pixels, int w, int h, float strength, const Mat4& rotation)
    : px_(std::move(pixels)), w_(w), h_(h), rot_(rotation) {
  // Kept finite: a texel that overflows with the strength would make samples non-finite.
  for (Vec3& c : px_) c = vmin(c * strength, Vec3(1e30f));
  lum_.resize(px_.size());
  double lum_sum = 0.0;
  for (size_t i = 0; i < px_.size(); ++i) {
    const float l = luminance(px_[i]);
    lum_[i] = l > 0.0f && std::isfinite(l) ? l : 0.0f;
    lum_sum += lum_[i];
  }
  // Cells between texel centres: cell (i, j) has corners at texel columns i, i + 1 (wrapping)
  // and rows j - 1, j (clamped), so that it is one bilinear patch of the lookup.
  std::vector<float> row_weights(size_t(h_) + 1);
  rows_.reserve(size_t(h_) + 1);
  cell_cos_.resize(size_t(h_) + 1);
  norm_ = 0.0;
  for (int j = 0; j <= h_; ++j) {
    const int ya = std::clamp(j - 1, 0, h_ - 1), yb = std::clamp(j, 0, h_ - 1);
    const float v0 = cell_v0(j), v1 = cell_v1(j);
    const float c = std::max(0.0f, std::cos(kPi * (0.5f * (v0 + v1) - 0.5f)));
    std::vector<float> wts(static_cast<size_t>(w_));
    double row_sum = 0.0;
    for (int x = 0; x < w_; ++x) {
      const int xb = (x + 1) % w_;
      const float m = 0.25f * (lum_[size_t(ya) * w_ + x] + lum_[size_t(ya) * w_ + xb] + lum_[size_t(yb) * w_ + x] +
                               lum_[size_t(yb) * w_ + xb]);
      wts[size_t(x)] = m;
      row_sum += m;
    }
    cell_cos_[size_t(j)] = c;
    const double row_integral = row_sum * c * (v1 - v0);  // times w: mean over u is row_sum / w
    row_weights[size_t(j)] = static_cast<float>(row_integral);
    norm_ += row_integral / w_;
    rows_.emplace_back(wts);
  }
  marginal_ = Distribution1D(row_weights);
  if (!(norm_ > 0.0) || !std::isfinite(norm_)) marginal_ = Distribution1D();
  avg_lum_ = static_cast<float>(lum_sum / (double(w_) * h_));
}

void Environment::to_uv(Vec3 t, float& u, float& v) const {
  const float len = length(t);
  u = (std::atan2(t.y, t.x) - kPi) / (-2.0f * kPi);
  v = 0.5f + std::asin(clampf(t.z / len, -1.0f, 1.0f)) / kPi;
}

Vec3 Environment::lookup(float u, float v) const {
  if (!std::isfinite(u) || !std::isfinite(v)) return Vec3(0.0f);  // a NaN direction sees nothing
  return bilinear(px_, w_, h_, u, v);
}

float Environment::pdf_uv(float u, float v) const {
  if (!std::isfinite(u) || !std::isfinite(v)) return 0.0f;
  const int j = std::clamp(static_cast<int>(std::floor(v * h_ + 0.5f)), 0, h_);
  return static_cast<float>(bilinear(lum_, w_, h_, u, v) * cell_cos_[size_t(j)] / norm_);
}

Vec3 Environment::eval(Vec3 dir_world) const {
  float u, v;
  to_uv(rot_.vector(dir_world), u, v);
  return lookup(u, v);
}

bool Environment::sample(Vec2 uu, Vec3& dir, Vec3& radiance, float& pdf_out) const {
  if (marginal_.empty()) return false;
  float ry, rx;
  const int j = static_cast<int>(marginal_.sample(uu.y, ry));
  const int i = static_cast<int>(rows_[size_t(j)].sample(uu.x, rx));
  // A point of the cell in proportion to its bilinear luminance.
  const int ya = std::clamp(j - 1, 0, h_ - 1), yb = std::clamp(j, 0, h_ - 1), xb = (i + 1) % w_;
  auto at = [&](int x, int y) { return double(lum_[size_t(y) * w_ + x]); };
  double sx, sy;
  sample_bilinear({rx, ry}, at(i, ya), at(xb, ya), at(i, yb), at(xb, yb), sx, sy);
  float u = static_cast<float>((i + 0.5 + sx) / w_);
  if (u >= 1.0f) u -= 1.0f;
  const float v0 = cell_v0(j), v1 = cell_v1(j);
  const float v = std::clamp(static_cast<float>(v0 + sy * (v1 - v0)), 0.0f, 1.0f);
  const float elevation = kPi * (v - 0.5f), phi = kPi - 2.0f * kPi * u;
  const float ce = std::cos(elevation);
  if (!(ce > 0.0f)) return false;
  const Vec3 t{ce * std::cos(phi), ce * std::sin(phi), std::sin(elevation)};
  // Texture -> world: the rotation is orthonormal, so its transpose inverts it.
  const Mat4& m = rot_;
  dir = normalize(Vec3{m.m[0][0] * t.x + m.m[1][0] * t.y + m.m[2][0] * t.z,
                       m.m[0][1] * t.x + m.m[1][1] * t.y + m.m[2][1] * t.z,
                       m.m[0][2] * t.x + m.m[1][2] * t.y + m.m[2][2] * t.z});
  // The density in (u, v) from this cell's own corners (no re-lookup of the cell), then
  // d(omega) = 2 pi^2 cos(elev) du dv.
  const double lum = (at(i, ya) * (1 - sx) + at(xb, ya) * sx) * (1 - sy) + (at(i, yb) * (1 - sx) + at(xb, yb) * sx) * sy;
  pdf_out = static_cast<float>(lum * cell_cos_[size_t(j)] / norm_ / (2.0 * kPi * kPi * ce));
  radiance = lookup(u, v);
  return pdf_out > 0.0f && std::isfinite(pdf_out);
}

float Environment::pdf(Vec3 dir_world) const {
  if (marginal_.empty()) return 0.0f;
  float u, v;
  to_uv(rot_.vector(dir_world), u, v);
  const float ce = std::cos(kPi * (v - 0.5f));
  if (!(ce > 0.0f)) return 0.0f;
  return pdf_uv(u, v) / (2.0f * kPi * kPi * ce);
}

}  // namespace pl
