#include "scene/light.h"

#include <limits>

#include "scene/light_shader.h"
#include "scene/scene.h"
#include "util/parallel.h"

namespace pl {

namespace {

// Bilinear between texel centres, wrapping in u, clamped in v (Cycles' Linear interpolation),
// of at(x, y).
template <class F>
auto bilinear(F at, int w, int h, float u, float v) {
  float fx = u * w - 0.5f, fy = v * h - 0.5f;
  fx -= std::floor(fx / w) * w;
  const int x0 = static_cast<int>(std::floor(fx)), y0 = static_cast<int>(std::floor(fy));
  const float tx = fx - x0, ty = fy - y0;
  const int xa = x0 % w, xb = (x0 + 1) % w;
  const int ya = std::clamp(y0, 0, h - 1), yb = std::clamp(y0 + 1, 0, h - 1);
  return (at(xa, ya) * (1 - tx) + at(xb, ya) * tx) * (1 - ty) + (at(xa, yb) * (1 - tx) + at(xb, yb) * tx) * ty;
}

// The equirectangular texels' values f(t) at their centres' texture-space directions t, rows in
// parallel (chunks of `grain` rows), clamped below 1e30 (a procedural sky's or a world program's
// sampling image).
template <class F>
void fill_texels(std::vector<Vec3>& px, int w, int h, size_t grain, F f) {
  parallel_ranges(
      size_t(h), 0,
      [&](size_t y0, size_t y1) {
        for (size_t y = y0; y < y1; ++y) {
          const float elevation = kPi * ((y + 0.5f) / h - 0.5f), ce = std::cos(elevation);
          for (int x = 0; x < w; ++x) {
            const float phi = kPi - 2.0f * kPi * ((x + 0.5f) / w);
            const Vec3 t{ce * std::cos(phi), ce * std::sin(phi), std::sin(elevation)};
            px[y * w + size_t(x)] = vmin(f(t), Vec3(1e30f));
          }
        }
      },
      grain);
}

}  // namespace

Environment::Environment(std::vector<Vec3> pixels, int w, int h, float strength, const Mat4& rotation, bool srgb)
    : px_(std::move(pixels)), w_(w), h_(h), rot_(rotation) {
  if (srgb) {
    // Kept encoded (lookup decodes); the map's weights from the decoded texels.
    srgb_ = true;
    strength_ = strength;
    for (Vec3& c : px_) c = vmin(c, Vec3(1.0f));
    init_distributions();
    return;
  }
  // Kept finite: a texel that overflows with the strength would make samples non-finite.
  for (Vec3& c : px_) c = vmin(c * strength, Vec3(1e30f));
  init_distributions();
}

Vec3 Environment::decode(Vec3 c) const {
  return Vec3{srgb_to_linear(c.x), srgb_to_linear(c.y), srgb_to_linear(c.z)} * strength_;
}

Environment::Environment(std::shared_ptr<const SkyModel> sky, int w, int h, float strength, const Mat4& rotation)
    : w_(w), h_(h), rot_(rotation) {
  sky_ = std::move(sky);
  strength_ = strength;
  // The sampling image: the sky without its disc at the texel centres.
  px_.resize(size_t(w_) * h_);
  fill_texels(px_, w_, h_, 16, [&](Vec3 t) { return sky_->eval(t, false) * strength_; });
  init_distributions();
  if (sky_->has_sun()) {
    sun_dir_ = sky_->sun_dir();
    make_basis(sun_dir_, sun_a_, sun_b_);
    const double s = std::sin(0.5 * double(sky_->sun_half_angle()));
    sun_one_minus_cos_ = 2.0 * s * s;
    // Its power over the disc (limb darkening averages 0.8 of the centre), in the units of the
    // cells' norm (integral over (u, v) of weight * cos: d(omega) / (2 pi^2)).
    const double solid = 2.0 * kPi * sun_one_minus_cos_;
    const double power = 0.8 * luminance(sky_->sun_center_radiance() * strength_) * solid / (2.0 * kPi * kPi);
    auto share = [&](const Cells& d) {
      if (!(power > 0.0) || !std::isfinite(power)) return 0.0f;
      if (d.marginal.empty()) return 1.0f;
      return static_cast<float>(std::clamp(power / (power + d.norm), 0.05, 0.95));
    };
    sun_share_full_ = share(full_);
    sun_share_comp_ = share(comp_);
    // The scene's choice among lights: the disc's mean over (u, v) as the texels count.
    const float ce = std::max(0.1f, std::sqrt(std::max(0.0f, 1.0f - sun_dir_.z * sun_dir_.z)));
    if (std::isfinite(power)) avg_lum_ += static_cast<float>(power / ce);
  }
}

Environment::Environment(std::shared_ptr<WorldShader> program, int w, int h) : w_(w), h_(h) {
  prog_ = std::move(program);
}

void Environment::bake(const Scene& scene) {
  prog_->scene = &scene;
  // The map: the program at the texel centres with no ray kind (Cycles' background_map bakes
  // so, by shader evaluation on the equirectangular grid).
  px_.assign(size_t(w_) * h_, Vec3(0.0f));
  fill_texels(px_, w_, h_, 4, [&](Vec3 t) { return eval_program(t, nullptr, nullptr); });
  lum_.clear();
  cell_cos_.clear();
  full_ = Cells();
  comp_ = Cells();
  init_distributions();
  baked_ = true;
}

Vec3 Environment::eval_program(Vec3 dir, const RayState* rs, const Vec3* ray_p) const {
  const WorldShader& sh = *prog_;
  ShadingContext ctx;
  const float len = length(dir);
  const Vec3 d = len > 0.0f ? dir / len : Vec3(0.0f, 0.0f, 1.0f);
  ctx.p = d;  // Cycles' shader_setup_from_background: P is the direction
  ctx.ng = ctx.ns = -d;
  ctx.wo = -d;  // Incoming
  ctx.scene = sh.scene;
  ctx.ray_p = ray_p;
  if (rs) {
    ctx.ray = *rs;
    ctx.ray.aovs = nullptr;
    if (!ctx.ray.camera) ctx.ray.camera = sh.camera.load(std::memory_order_relaxed);
  } else {
    // The map (Cycles' background_map: no ray kind, and no Light Path counts, its kernel has
    // no LIGHT_PATH feature).
    ctx.ray.flags = 0;
    ctx.ray.depth = 0;
    ctx.ray.camera = sh.camera.load(std::memory_order_relaxed);
  }
  // Cycles evaluates a background, for an escaped ray, a light sample or the map alike, with
  // PATH_RAY_EMISSION added: its svm_node_light_path reads Ray Depth one bounce further there
  // (the other counts as they are), and shader_setup_from_background's ray length is FLT_MAX.
  ctx.ray.depth = uint16_t(std::min(int(ctx.ray.depth) + 1, 65535));
  ctx.ray.length = std::numeric_limits<float>::max();
  ClosureList out;
  static const std::vector<Image> no_images;
  eval_shader(sh.program, sh.scene ? sh.scene->images() : no_images, ctx, out);
  return is_finite(out.emission) ? vmin(out.emission, Vec3(1e30f)) : Vec3(0.0f);
}

void Environment::init_distributions() {
  lum_.resize(px_.size());
  double lum_sum = 0.0, e_all = 0.0, solid = 0.0;
  for (int y = 0; y < h_; ++y) {
    const double c = std::cos(kPi * ((y + 0.5) / h_ - 0.5));
    for (int x = 0; x < w_; ++x) {
      const size_t i = size_t(y) * w_ + x;
      const float l = luminance(srgb_ ? decode(px_[i]) : px_[i]);
      lum_[i] = l > 0.0f && std::isfinite(l) ? l : 0.0f;
      lum_sum += lum_[i];
      e_all += c * lum_[i];
      solid += c;
    }
  }
  avg_lum_ = static_cast<float>(lum_sum / (double(w_) * h_));
  cell_cos_.resize(size_t(h_) + 1);
  for (int j = 0; j <= h_; ++j) cell_cos_[size_t(j)] = std::max(0.0f, std::cos(kPi * (0.5f * (cell_v0(j) + cell_v1(j)) - 0.5f)));
  build_cells(full_, 0.0f);
  // MIS compensation (Karlik et al. 2019): where a BSDF sample follows, light samples go only
  // where the map is brighter than its mean over the sphere, and the rest, bounded and smooth,
  // is left to the BSDF sample (3.3x lower variance on the HDR bench scene).
  build_cells(comp_, solid > 0.0 ? static_cast<float>(e_all / solid) : 0.0f);
}

float Environment::weight(const Cells& d, int x, int y) const {
  return std::max(0.0f, lum_[size_t(y) * w_ + x] - d.sub);
}

void Environment::build_cells(Cells& d, float sub) {
  d.sub = sub;
  // Cells between texel centres: cell (i, j) has corners at texel columns i, i + 1 (wrapping)
  // and rows j - 1, j (clamped), so that it is one bilinear patch of the lookup.
  std::vector<float> row_weights(size_t(h_) + 1);
  d.rows.reserve(size_t(h_) + 1);
  d.norm = 0.0;
  for (int j = 0; j <= h_; ++j) {
    const int ya = std::clamp(j - 1, 0, h_ - 1), yb = std::clamp(j, 0, h_ - 1);
    std::vector<float> wts(static_cast<size_t>(w_));
    double row_sum = 0.0;
    for (int x = 0; x < w_; ++x) {
      const int xb = (x + 1) % w_;
      const float m = 0.25f * (weight(d, x, ya) + weight(d, xb, ya) + weight(d, x, yb) + weight(d, xb, yb));
      wts[size_t(x)] = m;
      row_sum += m;
    }
    // The cell row's integral over (u, v) times w (its mean over u is row_sum / w).
    const double row_integral = row_sum * cell_cos_[size_t(j)] * (cell_v1(j) - cell_v0(j));
    row_weights[size_t(j)] = static_cast<float>(row_integral);
    d.norm += row_integral / w_;
    d.rows.emplace_back(wts);
  }
  d.marginal = Distribution1D(row_weights);
  if (!(d.norm > 0.0) || !std::isfinite(d.norm)) {
    d.marginal = Distribution1D();
    d.rows.clear();
  }
}

void Environment::to_uv(Vec3 t, float& u, float& v) const {
  const float len = length(t);
  u = (std::atan2(t.y, t.x) - kPi) / (-2.0f * kPi);
  v = 0.5f + std::asin(clampf(t.z / len, -1.0f, 1.0f)) / kPi;
}

Vec3 Environment::lookup(float u, float v) const {
  if (!std::isfinite(u) || !std::isfinite(v)) return Vec3(0.0f);  // a NaN direction sees nothing
  const Vec3 c = bilinear([&](int x, int y) { return px_[size_t(y) * w_ + x]; }, w_, h_, u, v);
  // An 8-bit sRGB image: filtered encoded, then decoded (Cycles' svm_image_texture).
  return srgb_ ? decode(c) : c;
}

Vec3 Environment::eval_map(Vec3 dir_world) const {
  if (sky_) return vmin(sky_->eval(normalize(rot_.vector(dir_world))) * strength_, Vec3(1e30f));
  float u, v;
  to_uv(rot_.vector(dir_world), u, v);
  return lookup(u, v);
}

bool Environment::sample_cells(const Cells& d, Vec2 uu, Vec3& dir, float& u, float& v, float& pdf_out) const {
  if (d.marginal.empty()) return false;
  float ry, rx;
  const int j = static_cast<int>(d.marginal.sample(uu.y, ry));
  const int i = static_cast<int>(d.rows[size_t(j)].sample(uu.x, rx));
  // A point of the cell in proportion to its bilinear weight.
  const int ya = std::clamp(j - 1, 0, h_ - 1), yb = std::clamp(j, 0, h_ - 1), xb = (i + 1) % w_;
  const double w00 = weight(d, i, ya), w10 = weight(d, xb, ya), w01 = weight(d, i, yb), w11 = weight(d, xb, yb);
  double sx, sy;
  sample_bilinear({rx, ry}, w00, w10, w01, w11, sx, sy);
  u = static_cast<float>((i + 0.5 + sx) / w_);
  if (u >= 1.0f) u -= 1.0f;
  const float v0 = cell_v0(j), v1 = cell_v1(j);
  v = std::clamp(static_cast<float>(v0 + sy * (v1 - v0)), 0.0f, 1.0f);
  const float elevation = kPi * (v - 0.5f), phi = kPi - 2.0f * kPi * u;
  const float ce = std::cos(elevation);
  if (!(ce > 0.0f)) return false;
  const Vec3 t{ce * std::cos(phi), ce * std::sin(phi), std::sin(elevation)};
  dir = to_world(t);
  // The density in (u, v) from this cell's own corners (no re-lookup of the cell), then
  // d(omega) = 2 pi^2 cos(elev) du dv.
  const double wt = (w00 * (1 - sx) + w10 * sx) * (1 - sy) + (w01 * (1 - sx) + w11 * sx) * sy;
  pdf_out = static_cast<float>(wt * cell_cos_[size_t(j)] / d.norm / (2.0 * kPi * kPi * ce));
  return pdf_out > 0.0f && std::isfinite(pdf_out);
}

Vec3 Environment::to_world(Vec3 t) const {
  // Texture -> world: the rotation is orthonormal, so its transpose inverts it.
  const Mat4& m = rot_;
  return normalize(Vec3{m.m[0][0] * t.x + m.m[1][0] * t.y + m.m[2][0] * t.z,
                        m.m[0][1] * t.x + m.m[1][1] * t.y + m.m[2][1] * t.z,
                        m.m[0][2] * t.x + m.m[1][2] * t.y + m.m[2][2] * t.z});
}

float Environment::sun_pdf(Vec3 dir_world) const {
  if (!(sun_one_minus_cos_ > 0.0)) return 0.0f;
  const Vec3 t = normalize(rot_.vector(dir_world));
  // 1 - cos of the angle to the sun, from the chord (no cancellation for tiny angles).
  const double chord2 = length_sq(t - sun_dir_);
  if (!(0.5 * chord2 < sun_one_minus_cos_)) return 0.0f;
  return static_cast<float>(1.0 / (2.0 * kPi * sun_one_minus_cos_));
}

bool Environment::sample(Vec2 uu, Vec3& dir, Vec3& radiance, float& pdf_out, bool cover_all, const RayState* rs) const {
  const float share = sun_share(cover_all);
  if (share <= 0.0f) {
    float u, v;
    if (!sample_cells(cover_all ? full_ : comp_, uu, dir, u, v, pdf_out)) return false;
    radiance = sky_ || prog_ ? eval(dir, rs) : lookup(u, v);
    return true;
  }
  // A sky with a sun disc: one of the two strategies, the pdf of their mixture.
  return sample_direction(uu, dir, cover_all) && finish_sample(dir, radiance, pdf_out, cover_all, rs);
}

bool Environment::sample_direction(Vec2 uu, Vec3& dir, bool cover_all) const {
  const float share = sun_share(cover_all);
  if (uu.x < share) {
    dir = sample_sun_disc({std::min(uu.x / share, 0x1.fffffep-1f), uu.y});
    return true;
  }
  float u, v, p;
  uu.x = std::min((uu.x - share) / (1.0f - share), 0x1.fffffep-1f);
  return sample_cells(cover_all ? full_ : comp_, uu, dir, u, v, p);
}

Vec3 Environment::sample_sun_disc(Vec2 uu) const {
  const double omc = double(uu.x) * sun_one_minus_cos_;  // 1 - cos(theta), uniform in the cone
  const double sin_t = std::sqrt(std::max(0.0, omc * (2.0 - omc)));
  // The azimuth in float: the disc is 0.5 degrees wide, so its rounding moves a direction by
  // ~1e-9 rad (double sincos took 3 % of the window room's instructions).
  const float phi = 2.0f * kPi * uu.y;
  const float st = float(sin_t);
  const Vec3 t = sun_a_ * (st * std::cos(phi)) + sun_b_ * (st * std::sin(phi)) + sun_dir_ * float(1.0 - omc);
  return to_world(normalize(t));
}

float Environment::pdf(Vec3 dir_world, bool cover_all) const {
  const float share = sun_share(cover_all);
  const float map = pdf_cells(cover_all ? full_ : comp_, dir_world);
  if (share <= 0.0f) return map;
  return share * sun_pdf(dir_world) + (1.0f - share) * map;
}

Vec3 Environment::eval_with_pdf(Vec3 dir_world, bool cover_all, float& pdf_out, const RayState* rs,
                                const Vec3* ray_p) const {
  if (sky_ || prog_ || sun_share(cover_all) > 0.0f) {
    pdf_out = pdf(dir_world, cover_all);
    return eval(dir_world, rs, ray_p);
  }
  float u, v;
  to_uv(rot_.vector(dir_world), u, v);
  pdf_out = pdf_cells_uv(cover_all ? full_ : comp_, u, v);
  return lookup(u, v);
}

float Environment::pdf_cells(const Cells& d, Vec3 dir_world) const {
  if (d.marginal.empty()) return 0.0f;
  float u, v;
  to_uv(rot_.vector(dir_world), u, v);
  return pdf_cells_uv(d, u, v);
}

float Environment::pdf_cells_uv(const Cells& d, float u, float v) const {
  if (d.marginal.empty()) return 0.0f;
  if (!std::isfinite(u) || !std::isfinite(v)) return 0.0f;
  const float ce = std::cos(kPi * (v - 0.5f));
  if (!(ce > 0.0f)) return 0.0f;
  const int j = std::clamp(static_cast<int>(std::floor(v * h_ + 0.5f)), 0, h_);
  const float wt = bilinear([&](int x, int y) { return weight(d, x, y); }, w_, h_, u, v);
  return static_cast<float>(wt * cell_cos_[size_t(j)] / d.norm / (2.0 * kPi * kPi * ce));
}

}  // namespace pl
