#include "scene/sky.h"

#include "util/parallel.h"

namespace pl {

namespace {

// Blender's atmosphere (intern/sky, sky_nishita.cpp): scale heights, coefficients, 21 sampled
// wavelengths 380-780 nm with the sun's spectral irradiance, Rayleigh and ozone spectra and the
// CIE 1931 matching functions at those wavelengths.
constexpr float kRayleighHeight = 8e3f, kMieHeight = 1.2e3f, kMieCoeff = 2e-5f, kMieG = 0.76f;
constexpr float kEarthRadius = 6360e3f, kAtmosphereRadius = 6420e3f;
constexpr int kSteps = 32, kWavelengths = 21;
constexpr float kStepLambda = (780 - 380) / (kWavelengths - 1);

constexpr float kIrradiance[kWavelengths] = {
    1.45756829855592995315f, 1.56596305559738380175f, 1.65148449067670455293f, 1.71496242737209314555f,
    1.75797983805020541226f, 1.78256407885924539336f, 1.79095108475838560302f, 1.78541550133410664714f,
    1.76815554864306845317f, 1.74122069647250410362f, 1.70647127164943679389f, 1.66556087452739887134f,
    1.61993437242451854274f, 1.57083597368892080581f, 1.51932335059305478886f, 1.46628494965214395407f,
    1.41245852740172450623f, 1.35844961970384092709f, 1.30474913844739281998f, 1.25174963272610817455f,
    1.19975998755420620867f};
constexpr float kRayleigh[kWavelengths] = {
    0.00005424820087636473f, 0.00004418549866505454f, 0.00003635151910165377f, 0.00003017929012024763f,
    0.00002526320226989157f, 0.00002130859310621843f, 0.00001809838025320633f, 0.00001547057129129042f,
    0.00001330284977336850f, 0.00001150184784075764f, 0.00000999557429990163f, 0.00000872799973630707f,
    0.00000765513700977967f, 0.00000674217203751443f, 0.00000596134125832052f, 0.00000529034598065810f,
    0.00000471115687557433f, 0.00000420910481110487f, 0.00000377218381260133f, 0.00000339051255477280f,
    0.00000305591531679811f};
constexpr float kOzone[kWavelengths] = {
    0.00000000325126849861f, 0.00000000585395365047f, 0.00000001977191155085f, 0.00000007309568762914f,
    0.00000020084561514287f, 0.00000040383958096161f, 0.00000063551335912363f, 0.00000096707041180970f,
    0.00000154797400424410f, 0.00000209038647223331f, 0.00000246128056164565f, 0.00000273551299461512f,
    0.00000215125863128643f, 0.00000159051840791988f, 0.00000112356197979857f, 0.00000073527551487574f,
    0.00000046450130357806f, 0.00000033096079921048f, 0.00000022512612292678f, 0.00000014879129266490f,
    0.00000016828623364192f};
constexpr float kCmf[kWavelengths][3] = {
    {0.00136800000f, 0.00003900000f, 0.00645000100f}, {0.01431000000f, 0.00039600000f, 0.06785001000f},
    {0.13438000000f, 0.00400000000f, 0.64560000000f}, {0.34828000000f, 0.02300000000f, 1.74706000000f},
    {0.29080000000f, 0.06000000000f, 1.66920000000f}, {0.09564000000f, 0.13902000000f, 0.81295010000f},
    {0.00490000000f, 0.32300000000f, 0.27200000000f}, {0.06327000000f, 0.71000000000f, 0.07824999000f},
    {0.29040000000f, 0.95400000000f, 0.02030000000f}, {0.59450000000f, 0.99500000000f, 0.00390000000f},
    {0.91630000000f, 0.87000000000f, 0.00165000100f}, {1.06220000000f, 0.63100000000f, 0.00080000000f},
    {0.85444990000f, 0.38100000000f, 0.00019000000f}, {0.44790000000f, 0.17500000000f, 0.00002000000f},
    {0.16490000000f, 0.06100000000f, 0.00000000000f}, {0.04677000000f, 0.01700000000f, 0.00000000000f},
    {0.01135916000f, 0.00410200000f, 0.00000000000f}, {0.00289932700f, 0.00104700000f, 0.00000000000f},
    {0.00069007860f, 0.00024920000f, 0.00000000000f}, {0.00016615050f, 0.00006000000f, 0.00000000000f},
    {0.00004150994f, 0.00001499000f, 0.00000000000f}};
// Optical depth towards the sun: 8-point Gauss-Laguerre nodes (as fractions of the path to the
// top of the atmosphere) and weights with exp(x) folded in (Blender 4.x).
constexpr float kQuadNodes[8] = {0.006811185292f, 0.03614807107f, 0.09004346519f, 0.1706680068f,
                                 0.2818362161f,   0.4303406404f,  0.6296271457f,  0.9145252695f};
constexpr float kQuadWeights[8] = {0.01750893642f, 0.04135477391f, 0.06678839063f, 0.09507698807f,
                                   0.1283416365f,  0.1707430204f,  0.2327233347f,  0.3562490486f};

using Spectrum = float[kWavelengths];

Vec3 from_lat_lon(float lat, float lon) {
  return {std::cos(lat) * std::cos(lon), std::cos(lat) * std::sin(lon), std::sin(lat)};
}

Vec3 spectrum_xyz(const Spectrum& s) {
  Vec3 xyz(0.0f);
  for (int i = 0; i < kWavelengths; ++i) xyz += Vec3(kCmf[i][0], kCmf[i][1], kCmf[i][2]) * s[i];
  return xyz * kStepLambda;
}

// Relative densities (air, dust, ozone) at a height above sea level; ozone is a tent between
// 10 and 40 km peaking at 25 km.
Vec3 densities(float h) {
  float ozone = 0.0f;
  if (h >= 10000.0f && h < 25000.0f)
    ozone = h / 15000.0f - 2.0f / 3.0f;
  else if (h >= 25000.0f && h < 40000.0f)
    ozone = 8.0f / 3.0f - h / 15000.0f;
  return {std::exp(-h / kRayleighHeight), std::exp(-h / kMieHeight), ozone};
}

float phase_rayleigh(float mu) { return 3.0f / (16.0f * kPi) * (1.0f + mu * mu); }
float phase_mie(float mu) {
  const float g2 = kMieG * kMieG;
  return 3.0f * (1.0f - g2) * (1.0f + mu * mu) /
         (8.0f * kPi * (2.0f + g2) * std::pow(1.0f + g2 - 2.0f * kMieG * mu, 1.5f));
}

// Distance from p along unit d to the top of the atmosphere (p inside it).
float to_atmosphere_top(Vec3 p, Vec3 d) {
  const float b = 2.0f * dot(d, p), c = length_sq(p) - kAtmosphereRadius * kAtmosphereRadius;
  return 0.5f * (-b + std::sqrt(b * b - 4.0f * c));
}

// Whether the ray from p along d (pointing down) meets the ground.
bool hits_ground(Vec3 p, Vec3 d) {
  if (d.z >= 0.0f) return false;
  const float b = 2.0f * dot(d, p), c = length_sq(p) - kEarthRadius * kEarthRadius;
  return b * b - 4.0f * c >= 0.0f;
}

// Integrated (air, dust, ozone) densities from p to the top of the atmosphere along d.
Vec3 optical_depth(Vec3 p, Vec3 d) {
  const float len = length(p + d * to_atmosphere_top(p, d) - p);
  Vec3 sum(0.0f);
  for (int i = 0; i < 8; ++i) sum += densities(length(p + d * (kQuadNodes[i] * len)) - kEarthRadius) * kQuadWeights[i];
  return sum * len;
}

// Light scattered once towards the camera at `origin` along `dir`, midpoint rule in 32 steps.
void single_scattering(Vec3 dir, Vec3 sun, Vec3 origin, Vec3 scale, Spectrum& out) {
  const float len = length(origin + dir * to_atmosphere_top(origin, dir) - origin);
  const float step = len / kSteps;
  const Vec3 seg = dir * step;
  const float mu = dot(dir, sun);
  const float ph_r = phase_rayleigh(mu), ph_m = phase_mie(mu);
  for (float& s : out) s = 0.0f;
  Vec3 depth(0.0f);
  Vec3 p = origin + seg * 0.5f;
  for (int i = 0; i < kSteps; ++i, p += seg) {
    const Vec3 dens = scale * densities(length(p) - kEarthRadius);
    depth += dens * step;
    if (hits_ground(p, sun)) continue;
    const Vec3 total = depth + scale * optical_depth(p, sun);
    for (int w = 0; w < kWavelengths; ++w) {
      const float ext = total.x * kRayleigh[w] + total.y * (1.11f * kMieCoeff) + total.z * kOzone[w];
      const float scatter = ph_r * dens.x * kRayleigh[w] + ph_m * dens.y * kMieCoeff;
      out[w] += std::exp(-ext) * scatter * kIrradiance[w] * step;
    }
  }
}

// XYZ radiance of the sun seen along dir: its irradiance spread over the disc's solid angle,
// attenuated by air and dust (Blender leaves ozone out here).
Vec3 sun_radiance(Vec3 dir, float altitude, float air, float dust, float solid_angle) {
  const Vec3 depth = optical_depth(Vec3(0.0f, 0.0f, kEarthRadius + altitude), dir);
  Spectrum s;
  for (int w = 0; w < kWavelengths; ++w)
    s[w] = kIrradiance[w] * std::exp(-(kRayleigh[w] * depth.x * air + 1.11f * kMieCoeff * depth.y * dust)) / solid_angle;
  return spectrum_xyz(s);
}

}  // namespace

SkyModel::SkyModel(const SkyParams& p, const float xyz_to_rgb[9], int threads) {
  std::copy(xyz_to_rgb, xyz_to_rgb + 9, m_);
  auto finite = [](float v, float fallback) { return std::isfinite(v) ? v : fallback; };
  // Cycles' node setup: the elevation wrapped into [-pi/2, pi/2] (the sun keeps its place in
  // the sky, turned half way round), the rotation into [0, 2 pi) and reversed (clockwise from +y seen from above), the altitude
  // kept in (1 m, 60 km), the disc at most a hemisphere wide.
  float elev = finite(p.sun_elevation, 0.0f), rot = finite(p.sun_rotation, 0.0f);
  elev = std::fmod(elev, 2.0f * kPi);
  if (std::fabs(elev) >= kPi) elev -= std::copysign(2.0f * kPi, elev);
  if (elev >= 0.5f * kPi || elev <= -0.5f * kPi) {
    elev = std::copysign(kPi, elev) - elev;
    rot += kPi;
  }
  rot = std::fmod(rot, 2.0f * kPi);
  if (rot < 0.0f) rot += 2.0f * kPi;
  rot = 2.0f * kPi - rot;
  elevation_ = elev;
  rotation_ = rot;
  const float altitude = clampf(finite(p.altitude, 0.0f), 1.0f, 59999.0f);
  const float air = std::max(0.0f, finite(p.air, 0.0f)), dust = std::max(0.0f, finite(p.dust, 0.0f));
  const float ozone = std::max(0.0f, finite(p.ozone, 0.0f));
  const float size = std::min(std::max(0.0f, finite(p.sun_size, 0.0f)), 0.5f * kPi);
  diameter_ = p.sun_disc ? size : -1.0f;
  half_angle_ = 0.5f * size;
  intensity_ = std::max(0.0f, finite(p.sun_intensity, 0.0f));

  // The texture: row y at latitude (pi/2 + half a row) (y / H)^2, column x at longitude
  // 2 pi x / W - pi; the sun at longitude 0, so the left half is computed and mirrored.
  xyz_.assign(size_t(kWidth) * kHeight, Vec3(0.0f));
  const Vec3 cam(0.0f, 0.0f, kEarthRadius + altitude), sun = from_lat_lon(elevation_, 0.0f);
  const Vec3 scale(air, dust, ozone);
  const float lat_step = 0.5f * kPi / kHeight, lon_step = 2.0f * kPi / kWidth;
  parallel_ranges(
      size_t(kHeight), threads,
      [&](size_t y0, size_t y1) {
        Spectrum s;
        for (size_t y = y0; y < y1; ++y) {
          const float f = float(y) / kHeight;
          const float lat = (0.5f * kPi + 0.5f * lat_step) * f * f;
          for (int x = 0; x < kWidth / 2; ++x) {
            single_scattering(from_lat_lon(lat, lon_step * x - kPi), sun, cam, scale, s);
            const Vec3 c = spectrum_xyz(s);
            xyz_[y * kWidth + size_t(x)] = c;
            xyz_[y * kWidth + size_t(kWidth - 1 - x)] = c;
          }
        }
      },
      4);

  // The disc's radiance at its lowest and highest points (both at least on the horizon).
  const float solid = 2.0f * kPi * (1.0f - std::cos(half_angle_));
  const float lo = std::max(0.0f, elevation_ - half_angle_), hi = std::max(0.0f, elevation_ + half_angle_);
  if (solid > 0.0f) {
    sun_bottom_ = sun_radiance(from_lat_lon(lo, 0.0f), altitude, air, dust, solid);
    sun_top_ = sun_radiance(from_lat_lon(hi, 0.0f), altitude, air, dust, solid);
  }
  // The kernel's sun direction: elevation up from the horizon, rotation about z from +y.
  sun_dir_ = {-std::cos(elevation_) * std::sin(rotation_), std::cos(elevation_) * std::cos(rotation_),
              std::sin(elevation_)};
  sun_visible_ = p.sun_disc && size > 0.0f && elevation_ + half_angle_ > 0.0f && intensity_ > 0.0f;
}

namespace {

float perez(const float lam[5], float theta, float gamma) {
  const float cg = std::cos(gamma);
  return (1.0f + lam[0] * std::exp(lam[1] / std::cos(theta))) * (1.0f + lam[2] * std::exp(lam[3] * gamma) + lam[4] * cg * cg);
}

}  // namespace

SkyModel::SkyModel(Vec3 sun_direction, float turbidity, const float xyz_to_rgb[9]) : kind_(Kind::kPreetham) {
  std::copy(xyz_to_rgb, xyz_to_rgb + 9, m_);
  const float len = length(sun_direction);
  const Vec3 d = len > 0.0f && std::isfinite(len) ? sun_direction / len : Vec3(0.0f, 0.0f, 1.0f);
  const float theta = std::acos(clampf(d.z, -1.0f, 1.0f)), phi = std::atan2(d.x, d.y);
  sun_theta_ = theta;
  sun_phi_ = phi;
  const float T = std::isfinite(turbidity) ? turbidity : 2.2f, T2 = T * T;
  const float t2 = theta * theta, t3 = t2 * theta;
  // Zenith luminance (kcd/m^2, Blender's 0.06 scale) and chromaticity (Preetham's fits).
  const float chi = (4.0f / 9.0f - T / 120.0f) * (kPi - 2.0f * theta);
  float zY = ((4.0453f * T - 4.9710f) * std::tan(chi) - 0.2155f * T + 2.4192f) * 0.06f;
  float zx = (0.00166f * t3 - 0.00375f * t2 + 0.00209f * theta) * T2 +
             (-0.02903f * t3 + 0.06377f * t2 - 0.03202f * theta + 0.00394f) * T +
             (0.11693f * t3 - 0.21196f * t2 + 0.06052f * theta + 0.25886f);
  float zy = (0.00275f * t3 - 0.00610f * t2 + 0.00317f * theta) * T2 +
             (-0.04214f * t3 + 0.08970f * t2 - 0.04153f * theta + 0.00516f) * T +
             (0.15346f * t3 - 0.26756f * t2 + 0.06670f * theta + 0.26688f);
  const float c[3][5][2] = {{{0.1787f, -1.4630f}, {-0.3554f, 0.4275f}, {-0.0227f, 5.3251f}, {0.1206f, -2.5771f}, {-0.0670f, 0.3703f}},
                            {{-0.0193f, -0.2592f}, {-0.0665f, 0.0008f}, {-0.0004f, 0.2125f}, {-0.0641f, -0.8989f}, {-0.0033f, 0.0452f}},
                            {{-0.0167f, -0.2608f}, {-0.0950f, 0.0092f}, {-0.0079f, 0.2102f}, {-0.0441f, -1.6537f}, {-0.0109f, 0.0529f}}};
  for (int k = 0; k < 3; ++k)
    for (int i = 0; i < 5; ++i) perez_[k][i] = c[k][i][0] * T + c[k][i][1];
  // Normalised so that the zenith has the zenith values.
  zY /= perez(perez_[0], 0.0f, theta);
  zx /= perez(perez_[1], 0.0f, theta);
  zy /= perez(perez_[2], 0.0f, theta);
  zenith_ = {zY, zx, zy};
}

void SkyModel::sun_angles(Vec3 t, float& theta, float& gamma) const {
  theta = std::acos(clampf(t.z, -1.0f, 1.0f));
  const float phi = 0.5f * kPi - std::atan2(t.y, t.x);
  const float cos_psi = std::sin(theta) * std::sin(sun_theta_) * std::cos(sun_phi_ - phi) + std::cos(theta) * std::cos(sun_theta_);
  gamma = std::acos(clampf(cos_psi, -1.0f, 1.0f));
  theta = std::min(theta, 0.5f * kPi - 0.001f);  // below the horizon: the horizon's colour
}

Vec3 SkyModel::eval_preetham(Vec3 t) const {
  float theta, gamma;
  sun_angles(t, theta, gamma);
  const float Y = zenith_.x * perez(perez_[0], theta, gamma);
  const float x = zenith_.y * perez(perez_[1], theta, gamma), y = zenith_.z * perez(perez_[2], theta, gamma);
  const float X = y != 0.0f ? x / y * Y : 0.0f, Z = y != 0.0f && Y != 0.0f ? (1.0f - x - y) / y * Y : 0.0f;
  return to_rgb(Vec3(X, Y, Z));
}

Vec3 SkyModel::to_rgb(Vec3 c) const {
  const Vec3 rgb = vmax(Vec3(m_[0] * c.x + m_[1] * c.y + m_[2] * c.z, m_[3] * c.x + m_[4] * c.y + m_[5] * c.z,
                             m_[6] * c.x + m_[7] * c.y + m_[8] * c.z),
                        Vec3(0.0f));
  return is_finite(rgb) ? rgb : Vec3(0.0f);  // extreme settings (turbidity 1e6) see nothing
}

Vec3 SkyModel::texel(float x, float y) const {
  const float fx = x * kWidth - 0.5f, fy = y * kHeight - 0.5f;
  const float ix = std::floor(fx), iy = std::floor(fy);
  const float tx = fx - ix, ty = fy - iy;
  auto at = [&](float i, float j) {
    const int xi = int(clampf(i, 0.0f, kWidth - 1.0f)), yi = int(clampf(j, 0.0f, kHeight - 1.0f));
    return xyz_[size_t(yi) * kWidth + size_t(xi)];
  };
  return (at(ix, iy) * (1.0f - tx) + at(ix + 1.0f, iy) * tx) * (1.0f - ty) +
         (at(ix, iy + 1.0f) * (1.0f - tx) + at(ix + 1.0f, iy + 1.0f) * tx) * ty;
}

Vec3 SkyModel::eval(Vec3 t, bool with_sun) const {
  if (!is_finite(t)) return Vec3(0.0f);
  if (kind_ == Kind::kPreetham) return eval_preetham(t);
  if (kind_ == Kind::kHosek) return eval_hosek(t);
  const float phi = std::atan2(t.y, t.x);
  float x = (-phi - 0.5f * kPi + rotation_) / (2.0f * kPi);
  x -= std::floor(x);
  if (t.z < 0.0f) {
    // Below the horizon: the horizon's colour fading to black at z = -0.4.
    if (t.z < -0.4f) return Vec3(0.0f);
    const float f = 1.0f + 2.5f * t.z;
    return to_rgb(texel(x, -0.5f) * (f * f * f));
  }
  const float elev = 0.5f * kPi - std::acos(std::min(1.0f, t.z));
  if (with_sun && diameter_ >= 0.0f) {
    const float angle = 2.0f * std::atan2(length(t - sun_dir_), length(t + sun_dir_));
    if (angle < half_angle_) {
      Vec3 c(0.0f);
      if (elevation_ - half_angle_ > 0.0f)
        c = sun_bottom_ + (sun_top_ - sun_bottom_) * ((elev - elevation_) / diameter_ + 0.5f);
      else if (elevation_ + half_angle_ > 0.0f)
        c = sun_bottom_ + (sun_top_ - sun_bottom_) * (elev / (elevation_ + half_angle_));
      const float r = angle / half_angle_;
      const float limb = 1.0f - 0.6f * (1.0f - std::sqrt(std::max(0.0f, 1.0f - r * r)));
      return to_rgb(c * (intensity_ * limb));
    }
  }
  return to_rgb(texel(x, std::sqrt(std::max(0.0f, elev / (0.5f * kPi)))));
}

Vec3 SkyModel::sun_center_radiance() const {
  return to_rgb((sun_bottom_ + sun_top_) * (0.5f * intensity_));
}

}  // namespace pl
