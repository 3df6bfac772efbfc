// Blender's Sky Texture, type Hosek / Wilkie (Cycles 4.5): the sky-dome model of "An Analytic
// Model for Full Spectral Sky-Dome Radiance" (Hosek, Wilkie 2012) in CIE XYZ, no sun disc. The
// node's settings pick, per channel, nine distribution parameters and an overall radiance out of
// the published datasets (sky_hosek_data.h); the sky is then a closed form in the view's zenith
// angle and its angle to the sun.
#include "scene/sky.h"
#include "scene/sky_hosek_data.h"

namespace pl {

namespace {

// The datasets are quintic Bezier curves over (elevation / (pi / 2))^(1/3), per albedo 0 / 1 and
// integer turbidity 1..10; a setting in between is the bilinear blend of its four neighbours.
struct HosekBlend {
  double bezier[6];
  int turbidity;     // lower integer turbidity, 1..10
  double weight[2][2];  // [albedo 0 / 1][turbidity, turbidity + 1]
};

HosekBlend hosek_blend(double turbidity, double albedo, double elevation) {
  HosekBlend b;
  const double s = std::cbrt(elevation / (0.5 * double(kPi))), r = 1.0 - s;
  constexpr double kBinomial[6] = {1.0, 5.0, 10.0, 10.0, 5.0, 1.0};
  for (int k = 0; k < 6; ++k) b.bezier[k] = kBinomial[k] * std::pow(r, 5 - k) * std::pow(s, k);
  b.turbidity = int(turbidity);
  const double rem = turbidity - b.turbidity;
  for (int a = 0; a < 2; ++a) {
    const double wa = a ? albedo : 1.0 - albedo;
    b.weight[a][0] = wa * (1.0 - rem);
    b.weight[a][1] = b.turbidity < 10 ? wa * rem : 0.0;  // turbidity 10: nothing above it
  }
  return b;
}

// One channel's sky over its overall radiance: zenith angle theta, angle gamma to the sun.
float hosek_distribution(const float c[9], float theta, float gamma) {
  const float ct = std::cos(theta), cg = std::cos(gamma);
  const float mie = (1.0f + cg * cg) / std::pow(1.0f + c[8] * c[8] - 2.0f * c[8] * cg, 1.5f);
  return (1.0f + c[0] * std::exp(c[1] / (ct + 0.01f))) *
         (c[2] + c[3] * std::exp(c[4] * gamma) + c[5] * cg * cg + c[6] * mie + c[7] * std::sqrt(ct));
}

}  // namespace

SkyModel::SkyModel(Vec3 sun_direction, float turbidity, float ground_albedo, const float xyz_to_rgb[9])
    : kind_(Kind::kHosek) {
  std::copy(xyz_to_rgb, xyz_to_rgb + 9, m_);
  const float len = length(sun_direction);
  const Vec3 d = len > 0.0f && std::isfinite(len) ? sun_direction / len : Vec3(0.0f, 0.0f, 1.0f);
  // A sun below the horizon is lit as one on it (Cycles clamps the same way).
  sun_theta_ = std::min(std::acos(clampf(d.z, -1.0f, 1.0f)), 0.5f * kPi);
  sun_phi_ = std::atan2(d.x, d.y);
  // The node's ranges (the datasets hold turbidity 1..10 and albedo 0..1 only).
  const float T = std::isfinite(turbidity) ? clampf(turbidity, 1.0f, 10.0f) : 2.2f;
  const float albedo = std::isfinite(ground_albedo) ? clampf(ground_albedo, 0.0f, 1.0f) : 0.3f;
  const float elevation = 0.5f * kPi - sun_theta_;
  // In double, as the published code; the kernel then evaluates in float.
  const HosekBlend b = hosek_blend(T, albedo, elevation);
  double rad[3] = {};
  for (int ch = 0; ch < 3; ++ch) {
    double cfg[9] = {};
    for (int a = 0; a < 2; ++a)
      for (int j = 0; j < 2; ++j) {
        const double w = b.weight[a][j];
        if (w == 0.0) continue;
        const int t = b.turbidity - 1 + j;
        for (int k = 0; k < 6; ++k) {
          const double wk = w * b.bezier[k];
          for (int i = 0; i < 9; ++i) cfg[i] += wk * hosek::kConfig[ch][a][t][k][i];
          rad[ch] += wk * hosek::kRadiance[ch][a][t][k];
        }
      }
    for (int i = 0; i < 9; ++i) hosek_[ch][i] = float(cfg[i]);
  }
  hosek_radiance_ = Vec3(float(rad[0]), float(rad[1]), float(rad[2]));
}

Vec3 SkyModel::eval_hosek(Vec3 t) const {
  float theta, gamma;
  sun_angles(t, theta, gamma);
  const Vec3 xyz(hosek_distribution(hosek_[0], theta, gamma) * hosek_radiance_.x,
                 hosek_distribution(hosek_[1], theta, gamma) * hosek_radiance_.y,
                 hosek_distribution(hosek_[2], theta, gamma) * hosek_radiance_.z);
  // The model's radiance is in W / (m^2 sr nm) times the CIE matching functions; Blender scales
  // it by 2 pi / 683 (683 lm / W).
  return to_rgb(xyz) * (2.0f * kPi / 683.0f);
}

}  // namespace pl
