// Blender's Sky Texture (Cycles 4.5). Nishita: single scattering through a spherical atmosphere
// of air (Rayleigh), dust (Mie) and ozone, precomputed into a 512 x 128 XYZ texture of the upper
// hemisphere (rows denser towards the horizon), and a sun disc with limb darkening. Preetham:
// the analytic daylight model (Preetham, Shirley, Smits 1999; Perez distribution in xyY), no disc.
// Hosek / Wilkie: the fitted sky-dome model (Hosek, Wilkie 2012; its XYZ datasets), no disc.
// Our own implementation of the published models with Blender's constants, texture layout and
// lookup, so that the same node gives the same radiance.
#pragma once
#include "util/math.h"

#include <vector>

namespace pl {

struct SkyParams {
  float sun_elevation = 0.2618f;  // radians
  float sun_rotation = 0.0f;      // radians, as the node's Sun Rotation
  float sun_size = 0.009512f;     // angular diameter, radians
  float sun_intensity = 1.0f;
  bool sun_disc = true;
  float altitude = 0.0f;  // metres
  float air = 1.0f, dust = 1.0f, ozone = 1.0f;
};

class SkyModel {
 public:
  // Nishita. xyz_to_rgb: row-major 3x3, CIE XYZ -> scene-linear RGB. threads <= 0: all cores.
  SkyModel(const SkyParams& p, const float xyz_to_rgb[9], int threads = 0);
  // Preetham: the node's Sun Direction (any length) and Turbidity.
  SkyModel(Vec3 sun_direction, float turbidity, const float xyz_to_rgb[9]);
  // Hosek / Wilkie: the node's Sun Direction (any length), Turbidity and Ground Albedo
  // (sky_hosek.cpp).
  SkyModel(Vec3 sun_direction, float turbidity, float ground_albedo, const float xyz_to_rgb[9]);
  // Radiance towards unit direction t (texture space), the sun disc included or not.
  Vec3 eval(Vec3 t, bool with_sun = true) const;
  // The disc, for sampling: unit direction, half angle, and whether any of it is visible.
  bool has_sun() const { return sun_visible_; }
  Vec3 sun_dir() const { return sun_dir_; }
  float sun_half_angle() const { return half_angle_; }
  // Radiance at the disc's centre (for the light's share of samples).
  Vec3 sun_center_radiance() const;
  static constexpr int kWidth = 512, kHeight = 128;
  const std::vector<Vec3>& texture() const { return xyz_; }  // XYZ, row 0 = the horizon

 private:
  Vec3 to_rgb(Vec3 xyz) const;
  Vec3 eval_preetham(Vec3 t) const;
  // The analytic models' view angle from the zenith (clamped to the horizon) and from the sun.
  void sun_angles(Vec3 t, float& theta, float& gamma) const;
  Vec3 eval_hosek(Vec3 t) const;
  enum class Kind { kNishita, kPreetham, kHosek };
  Kind kind_ = Kind::kNishita;
  float sun_theta_ = 0.0f, sun_phi_ = 0.0f;
  Vec3 zenith_;                  // Preetham: Y, x, y at the zenith over their Perez value there
  float perez_[3][5] = {};       // Preetham: Perez coefficients of Y, x, y
  float hosek_[3][9] = {};       // Hosek: the distribution's parameters of X, Y, Z
  Vec3 hosek_radiance_;          // Hosek: the overall radiance of X, Y, Z
  Vec3 texel(float x, float y) const;  // bilinear, clamped at the edges (Cycles' Extend)
  std::vector<Vec3> xyz_;
  float m_[9];
  float elevation_ = 0.0f, rotation_ = 0.0f, diameter_ = -1.0f, intensity_ = 1.0f, half_angle_ = 0.0f;
  Vec3 sun_bottom_, sun_top_;  // XYZ of the disc's lowest and highest points
  Vec3 sun_dir_;
  bool sun_visible_ = false;
};

}  // namespace pl
