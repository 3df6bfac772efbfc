#include "scene/camera.h"

#include <algorithm>
#include <cstring>

namespace pl {

Camera::Frame Camera::frame_of(const Mat4& m) {
  Frame f;
  f.origin = {m.m[0][3], m.m[1][3], m.m[2][3]};
  // Blender ignores the camera object's scale: keep only its rotation (orthonormalised).
  f.right = normalize(Vec3{m.m[0][0], m.m[1][0], m.m[2][0]});
  f.up = Vec3{m.m[0][1], m.m[1][1], m.m[2][1]};
  f.up = normalize(f.up - f.right * dot(f.up, f.right));
  f.back = cross(f.right, f.up);
  return f;
}

Camera::Camera(const CameraDesc& d, int width, int height) {
  type_ = d.type;
  const Frame f = frame_of(d.matrix_world);
  origin_ = f.origin;
  right_ = f.right;
  up_ = f.up;
  back_ = f.back;
  // Motion blur: steps that cannot be decomposed (not finite, singular) leave it static.
  bool moves = false;
  for (const Mat4& m : d.motion) moves = moves || std::memcmp(&m, &d.motion[0], sizeof(Mat4)) != 0;
  if (d.motion.size() >= 2 && moves && !decompose_motion(d.motion, motion_)) motion_.clear();
  shutter_.set_curve(d.shutter_curve);
  rolling_ = d.rolling_shutter;
  rolling_duration_ = std::isfinite(d.rolling_shutter_duration) ? clampf(d.rolling_shutter_duration, 0.0f, 1.0f) : 0.0f;

  const float winx = static_cast<float>(width), winy = static_cast<float>(height);
  winx_ = width > 0 ? winx : 1.0f;
  winy_ = height > 0 ? winy : 1.0f;
  const float ycor = d.pixel_aspect_y / d.pixel_aspect_x;
  const float sensor = d.sensor_fit == SensorFit::Vertical ? d.sensor_height : d.sensor_width;
  SensorFit fit = d.sensor_fit;
  if (fit == SensorFit::Auto)
    fit = d.pixel_aspect_x * winx >= d.pixel_aspect_y * winy ? SensorFit::Horizontal : SensorFit::Vertical;
  const float viewfac = fit == SensorFit::Horizontal ? winx : ycor * winy;
  // View-plane units per pixel: at distance 1 (perspective) or in world units (orthographic,
  // where ortho_scale spans the fitted side).
  const float pixsize = (type_ == CameraType::Orthographic ? d.ortho_scale : sensor / d.lens) / viewfac;
  const float shx = d.shift_x * viewfac, shy = d.shift_y * viewfac;
  x0_ = (-0.5f * winx + shx) * pixsize;
  y0_ = (-0.5f * ycor * winy + shy) * pixsize;
  dx_ = pixsize;
  dy_ = ycor * pixsize;
  clip_start_ = d.clip_start;
  clip_len_ = d.clip_end - d.clip_start;

  aperture_ = std::isfinite(d.aperture_size) ? std::max(d.aperture_size, 0.0f) : 0.0f;
  blades_ = d.aperture_blades >= 3 ? d.aperture_blades : 0;
  blade_rotation_ = std::isfinite(d.aperture_rotation) ? d.aperture_rotation : 0.0f;
  inv_aperture_ratio_ = d.aperture_ratio > 0.0f && std::isfinite(d.aperture_ratio) ? 1.0f / d.aperture_ratio : 1.0f;
  set_focus_distance(d.focus_distance);

  // Spherical stereo, as Cycles: +-half the interocular distance (Cycles' interocular_offset),
  // perspective and panoramic cameras only (Blender has none for orthographic ones).
  if (d.stereo_eye != StereoEye::None && type_ != CameraType::Orthographic && std::isfinite(d.interocular_distance)) {
    stereo_offset_ = 0.5f * d.interocular_distance * (d.stereo_eye == StereoEye::Left ? -1.0f : 1.0f);
    convergence_ = d.convergence_distance > 0.0f ? d.convergence_distance : kInf;  // (NaN: parallel too)
    if (d.use_pole_merge && std::isfinite(d.pole_merge_angle_from) && std::isfinite(d.pole_merge_angle_to)) {
      pole_from_ = d.pole_merge_angle_from;
      pole_to_ = d.pole_merge_angle_to;
    }
  }
  cam_x_ = right_;
  cam_y_ = up_;
  cam_z_ = -back_;
  if (type_ == CameraType::Panoramic) {
    pano_ = d.panorama_type;
    if (pano_ == PanoramaType::Mirrorball) {  // Cycles' mirror ball looks down its -y
      cam_x_ = right_;
      cam_y_ = back_;
      cam_z_ = up_;
    } else {  // looks down its +x, as the centre of an environment texture
      cam_x_ = -back_;
      cam_y_ = -right_;
      cam_z_ = up_;
    }
    // Cycles' panorama viewplane: the frame spans [0, 1]^2 of (u, v), shifted by the shift.
    const float* vp = d.pano_viewplane;
    u0_ = vp[0] + d.shift_x;
    du_ = (vp[1] - vp[0]) / winx_;
    v0_ = vp[2] + d.shift_y;
    dv_ = (vp[3] - vp[2]) / winy_;
    if (pano_ == PanoramaType::CentralCylindrical) {
      const float r = d.cylinder_radius;
      range_[0] = -d.cylinder_u_min;
      range_[1] = -d.cylinder_u_max;
      range_[2] = d.cylinder_v_min / r;
      range_[3] = d.cylinder_v_max / r;
    } else {
      range_[0] = d.longitude_min - d.longitude_max;
      range_[1] = -d.longitude_min;
      range_[2] = d.latitude_min - d.latitude_max;
      range_[3] = -d.latitude_min + 0.5f * kPi;
    }
    fov_ = d.fisheye_fov;
    fisheye_lens_ = d.fisheye_lens;
    for (int i = 0; i < 5; ++i) poly_[i] = d.fisheye_polynomial[i];
    // The fisheye sensor, fitted as Cycles' Blender sync does (AUTO: the wider side takes the
    // sensor width).
    const float aspect = d.pano_fit_aspect > 0.0f ? d.pano_fit_aspect
                                                  : (winx_ * d.pixel_aspect_x) / (winy_ * d.pixel_aspect_y);
    const bool horizontal = d.sensor_fit == SensorFit::Horizontal || (d.sensor_fit == SensorFit::Auto && aspect > 1.0f);
    const float size = d.sensor_fit == SensorFit::Vertical ? d.sensor_height : d.sensor_width;
    sensor_w_ = horizontal ? size : size * aspect;
    sensor_h_ = horizontal ? size / aspect : size;
  }
}

namespace {
float safe_acos(float x) { return std::acos(std::clamp(x, -1.0f, 1.0f)); }

// Cycles' fisheye_to_direction: polar angle theta from the axis at the image point (u, v),
// r = |(u, v)|.
Vec3 fisheye_dir(float theta, float u, float v, float r) {
  float phi = safe_acos(r != 0.0f ? u / r : 0.0f);
  if (v < 0.0f) phi = -phi;
  const float st = std::sin(theta);
  return {std::cos(theta), -std::cos(phi) * st, std::sin(phi) * st};
}

// (y, z) of a direction, unit (zero stays zero): where a fisheye puts it around the centre.
Vec2 fisheye_radial(Vec3 d) {
  const float l = std::sqrt(d.y * d.y + d.z * d.z);
  return l > 0.0f ? Vec2{d.y / l, d.z / l} : Vec2{0.0f, 0.0f};
}
}  // namespace

Vec3 Camera::pano_direction(float x, float y) const {
  float u = u0_ + x * du_, v = v0_ + y * dv_;
  Vec3 d(0.0f);
  switch (pano_) {
    case PanoramaType::Equirectangular: {
      const float phi = range_[0] * u + range_[1], theta = range_[2] * v + range_[3];
      const float st = std::sin(theta);
      d = {st * std::cos(phi), st * std::sin(phi), std::cos(theta)};
      break;
    }
    case PanoramaType::EquiangularCubemapFace:
      d = normalize(Vec3{1.0f, std::tan((0.5f - u) * 0.5f * kPi), std::tan((v - 0.5f) * 0.5f * kPi)});
      break;
    case PanoramaType::Mirrorball: {
      // The point of the unit ball seen at (u, v), and the incident direction -y reflected
      // there.
      const Vec3 n{2.0f * u - 1.0f, 0.0f, 2.0f * v - 1.0f};
      const float rr = n.x * n.x + n.z * n.z;
      if (rr > 1.0f) break;
      const Vec3 b{n.x, -std::sqrt(std::max(1.0f - rr, 0.0f)), n.z};
      const Vec3 I{0.0f, -1.0f, 0.0f};
      d = b * (2.0f * dot(b, I)) - I;
      break;
    }
    case PanoramaType::FisheyeEquidistant: {
      u = (u - 0.5f) * 2.0f;
      v = (v - 0.5f) * 2.0f;
      const float r = std::sqrt(u * u + v * v);
      if (r > 1.0f) break;
      d = fisheye_dir(r * fov_ * 0.5f, u, v, r);
      break;
    }
    case PanoramaType::FisheyeEquisolid: {
      u = (u - 0.5f) * sensor_w_;
      v = (v - 0.5f) * sensor_h_;
      const float rmax = 2.0f * fisheye_lens_ * std::sin(fov_ * 0.25f);
      const float r = std::sqrt(u * u + v * v);
      if (r > rmax) break;
      d = fisheye_dir(2.0f * std::asin(std::min(r / (2.0f * fisheye_lens_), 1.0f)), u, v, r);
      break;
    }
    case PanoramaType::FisheyeLensPolynomial: {
      u = (u - 0.5f) * sensor_w_;
      v = (v - 0.5f) * sensor_h_;
      const float r = std::sqrt(u * u + v * v), r2 = r * r;
      const float theta = -(poly_[0] + poly_[1] * r + poly_[2] * r2 + poly_[3] * r2 * r + poly_[4] * r2 * r2);
      if (!(std::fabs(theta) <= 0.5f * fov_)) break;
      d = fisheye_dir(theta, u, v, r);
      break;
    }
    case PanoramaType::CentralCylindrical: {
      const float theta = range_[0] + (range_[1] - range_[0]) * u;
      d = {std::cos(theta), std::sin(theta), range_[2] + (range_[3] - range_[2]) * v};
      break;
    }
  }
  return is_finite(d) ? d : Vec3(0.0f);
}

Vec2 Camera::pano_uv(Vec3 d) const {
  const float len = length(d);
  if (!(len > 0.0f)) return {0.0f, 0.0f};
  d = d / len;
  switch (pano_) {
    case PanoramaType::Equirectangular:
      return {(std::atan2(d.y, d.x) - range_[1]) / range_[0], (safe_acos(d.z) - range_[3]) / range_[2]};
    case PanoramaType::EquiangularCubemapFace:
      return {0.5f - std::atan2(d.y, d.x) * 2.0f / kPi, std::atan2(d.z, d.x) * 2.0f / kPi + 0.5f};
    case PanoramaType::Mirrorball: {
      d.y -= 1.0f;
      const float div = 2.0f * std::sqrt(std::max(-0.5f * d.y, 0.0f));
      if (div > 0.0f) d = d / div;
      return {0.5f * (d.x + 1.0f), 0.5f * (d.z + 1.0f)};
    }
    case PanoramaType::FisheyeEquidistant: {
      const float r = std::atan2(std::sqrt(d.y * d.y + d.z * d.z), d.x) / fov_;
      const Vec2 a = fisheye_radial(d);
      return {0.5f - r * a.x, r * a.y + 0.5f};
    }
    case PanoramaType::FisheyeEquisolid: {
      const float r = 2.0f * fisheye_lens_ * std::sin(safe_acos(d.x) * 0.5f);
      const Vec2 a = fisheye_radial(d);
      return {0.5f - r * a.x / sensor_w_, r * a.y / sensor_h_ + 0.5f};
    }
    case PanoramaType::FisheyeLensPolynomial: {
      // Newton's method on theta = -(k0 + k1 r + ... + k4 r^4), from the linear solution.
      const float theta = -safe_acos(d.x);
      float r = (theta - poly_[0]) / poly_[1];
      for (int i = 0; i < 20; ++i) {
        const float r2 = r * r;
        const float f = theta - (poly_[0] + poly_[1] * r + poly_[2] * r2 + poly_[3] * r2 * r + poly_[4] * r2 * r2);
        const float df = poly_[1] + 2.0f * poly_[2] * r + 3.0f * poly_[3] * r2 + 4.0f * poly_[4] * r2 * r;
        const float step = f / df;
        r += step;
        if (!(std::fabs(step) >= 1e-6f)) break;
      }
      const Vec2 a = fisheye_radial(d);
      return {0.5f - r * a.x / sensor_w_, r * a.y / sensor_h_ + 0.5f};
    }
    case PanoramaType::CentralCylindrical: {
      const float z = d.z / std::sqrt(d.x * d.x + d.y * d.y);
      const float theta = std::atan2(d.y, d.x);
      return {(theta - range_[0]) / (range_[1] - range_[0]), (z - range_[2]) / (range_[3] - range_[2])};
    }
  }
  return {0.0f, 0.0f};
}

Vec3 Camera::pano_to_world(const Frame& f, Vec3 d) const {
  if (pano_ == PanoramaType::Mirrorball) return f.right * d.x + f.back * d.y + f.up * d.z;
  return -f.back * d.x - f.right * d.y + f.up * d.z;
}

// (out of line: the mono camera rays stay as small as before)
[[gnu::noinline]] void Camera::spherical_stereo(Vec3& p, Vec3& d) const {
  float offset = stereo_offset_;
  if (pole_to_ > 0.0f) {
    // Cycles' pole merge: full offset below `from`, none above `to`, a quarter cosine between.
    const float altitude = std::fabs(std::asin(std::clamp(d.z, -1.0f, 1.0f)));
    if (altitude > pole_to_) {
      offset = 0.0f;
    } else if (altitude > pole_from_) {
      offset *= std::cos((altitude - pole_from_) / (pole_to_ - pole_from_) * 0.5f * kPi);
    }
  }
  const Vec3 c = cross(d, Vec3{0.0f, 0.0f, 1.0f});
  const float l2 = length_sq(c);
  if (!(l2 > 0.0f)) return;  // straight up or down: no side to move to (Cycles' would be NaN)
  const Vec3 s = c * (offset / std::sqrt(l2));
  p = p + s;
  if (convergence_ < kInf) d = normalize(d * convergence_ - s);
}

Ray Camera::generate_pano_in(const Frame& f, float x, float y, Vec2 lens, bool use_lens) const {
  Ray r;
  const Vec3 raw = pano_direction(x, y);
  if (raw.x == 0.0f && raw.y == 0.0f && raw.z == 0.0f) {
    // Outside the lens: no ray (Cycles' tmax 0), the pixel stays black.
    r.org = f.origin;
    r.dir = -f.back;
    r.tmax = 0.0f;
    return r;
  }
  Vec3 d = normalize(raw);
  Vec3 p(0.0f);
  if (use_lens && aperture_ > 0.0f) {
    // Cycles' panorama depth of field: the focal surface is the sphere of radius focus_, the
    // lens a disk perpendicular to the ray (its x axis as close to the panorama's x as can be).
    const Vec2 a = sample_aperture(lens);
    Vec3 U = Vec3{1.0f, 0.0f, 0.0f} - d * d.x;
    U = length_sq(U) > 1e-12f ? normalize(U) : Vec3{0.0f, 1.0f, 0.0f};
    const Vec3 V = normalize(cross(d, U));
    p = U * (a.x * aperture_) + V * (a.y * aperture_);
    d = normalize(d * focus_ - p);
  } else if (stereo_offset_ != 0.0f) {
    d = raw;  // Cycles' stereo takes the map's direction as it is (a cylinder's is not unit)
  }
  // Spherical stereo in the panorama's own space (z up), after the lens, as Cycles.
  if (stereo_offset_ != 0.0f) [[unlikely]] spherical_stereo(p, d);
  r.dir = normalize(pano_to_world(f, d));
  // Clipping along the ray, as Cycles does for panoramas.
  r.org = f.origin + pano_to_world(f, p) + r.dir * clip_start_;
  r.tmax = clip_len_;
  return r;
}

void Camera::set_focus_distance(float d) {
  // Cycles clamps the same way: a zero distance would put every ray through one point.
  focus_ = std::isfinite(d) ? std::max(d, 1e-5f) : 1e-5f;
}

Vec2 Camera::sample_aperture(Vec2 u) const {
  Vec2 p;
  if (blades_ == 0) {
    p = sample_disk_concentric(u);
  } else {
    // Regular polygon with unit circumradius (Cycles' layout: corners at rotation + pi/n +
    // 2 pi k / n): pick wedge k, then a uniform point in the triangle (centre, its corners).
    const float n = float(blades_);
    const float k = std::min(std::floor(u.x * n), n - 1.0f);
    const float s = std::sqrt(std::clamp(u.x * n - k, 0.0f, 1.0f));
    const float a = 1.0f - s, b = u.y * s;  // weights of the corners at +half and -half
    const float half = kPi / n;
    const Vec2 q{(a + b) * std::cos(half), (a - b) * std::sin(half)};
    const float rot = blade_rotation_ + k * 2.0f * half;
    const float c = std::cos(rot), sn = std::sin(rot);
    p = {c * q.x - sn * q.y, sn * q.x + c * q.y};
  }
  p.x *= inv_aperture_ratio_;  // anamorphic bokeh, as Cycles
  return p;
}

bool Camera::pinhole_view(const Frame& f, Vec3 p, float& rx, float& ry, float& dist, float& pixel_pdf) const {
  const Vec3 rel = p - f.origin;
  const float depth = -dot(rel, f.back);
  if (!(depth > clip_start_) || !(depth < clip_start_ + clip_len_)) return false;
  dist = length(rel);
  const Vec3 dir = rel / dist;
  rx = (dot(rel, f.right) / depth - x0_) / dx_;
  ry = (dot(rel, f.up) / depth - y0_) / dy_;
  pixel_pdf = pinhole_pixel_pdf(f, dir);
  return std::isfinite(rx) && std::isfinite(ry) && pixel_pdf > 0.0f && std::isfinite(pixel_pdf);
}

bool Camera::lens_view(const Frame& f, Vec3 p, Vec2 u, Vec3& eye, float& rx, float& ry, float& dist,
                       float& pixel_pdf) const {
  if (type_ == CameraType::Panoramic) {
    eye = f.origin;
    return pano_view(f, p, rx, ry, dist, pixel_pdf);
  }
  if (aperture_ <= 0.0f) {
    eye = f.origin;
    return pinhole_view(f, p, rx, ry, dist, pixel_pdf);
  }
  // Camera space: the lens point L = (lx, ly, 0) (an orthographic camera's at the pixel's
  // (px, py) plus that), p at depth z. generate_in's ray leaves L through F = (px, py, 1) focus_
  // (orthographic: (px, py, focus_)).
  const Vec2 a = sample_aperture(u);
  const float lx = a.x * aperture_, ly = a.y * aperture_;
  const Vec3 rel0 = p - f.origin;
  const float z = -dot(rel0, f.back);
  if (!(z > clip_start_) || !(z < clip_start_ + clip_len_)) return false;
  const float x = dot(rel0, f.right), y = dot(rel0, f.up);
  float px, py;
  if (type_ == CameraType::Orthographic) {
    // The ray's direction is (-lx, -ly, focus_) for every pixel: from p back to depth 0.
    const float t = z / focus_;
    eye = f.origin + f.right * (x + lx * t) + f.up * (y + ly * t);
    px = x + lx * (t - 1.0f);
    py = y + ly * (t - 1.0f);
  } else {
    // The line from L through p crosses depth focus_ at L + (p - L) focus_ / z.
    eye = f.origin + f.right * lx + f.up * ly;
    const float inv_f = 1.0f / focus_;
    px = lx * inv_f + (x - lx) / z;
    py = ly * inv_f + (y - ly) / z;
  }
  rx = (px - x0_) / dx_;
  ry = (py - y0_) / dy_;
  const Vec3 rel = p - eye;
  dist = length(rel);
  pixel_pdf = lens_pixel_pdf(f, rel / dist, dist);
  return std::isfinite(rx) && std::isfinite(ry) && pixel_pdf > 0.0f && std::isfinite(pixel_pdf);
}

Vec3 Camera::pano_from_world(const Frame& f, Vec3 w) const {
  if (pano_ == PanoramaType::Mirrorball) return {dot(w, f.right), dot(w, f.back), dot(w, f.up)};
  return {-dot(w, f.back), -dot(w, f.right), dot(w, f.up)};
}

float Camera::pano_jacobian(Vec3 d) const {
  // d omega / d(u, v) of pano_direction's map, per type (u, v before the viewplane's scale).
  switch (pano_) {
    case PanoramaType::Equirectangular: {
      // phi and theta linear in u and v: d omega = sin(theta) dtheta dphi.
      const float st = std::sqrt(std::max(0.0f, 1.0f - d.z * d.z));
      return std::fabs(range_[0] * range_[2]) * st;
    }
    case PanoramaType::EquiangularCubemapFace: {
      // The plane x = 1 at (1, tan a, tan b), a and b linear in u and v (pi / 2 per unit):
      // d omega = dA / r^3, dA = sec^2 a sec^2 b da db.
      if (!(d.x > 0.0f)) return 0.0f;
      const float ta = d.y / d.x, tb = d.z / d.x;
      const float r2 = 1.0f + ta * ta + tb * tb;
      return 0.25f * kPi * kPi * (1.0f + ta * ta) * (1.0f + tb * tb) / (r2 * std::sqrt(r2));
    }
    case PanoramaType::Mirrorball:
      // A mirror ball seen along its axis: d omega = 4 dA of its disk, whose (x, z) are 2u - 1, 2v - 1.
      return 16.0f;
    case PanoramaType::FisheyeEquidistant: {
      // theta = r fov / 2 over (u', v') = 2 (u, v) - 1: d omega = sin(theta) (fov / 2) / r dA'.
      const float theta = safe_acos(d.x);
      const float s = theta > 1e-4f ? std::sin(theta) / theta : 1.0f - theta * theta / 6.0f;
      return fov_ * fov_ * s;
    }
    case PanoramaType::FisheyeEquisolid:
      // r = 2 lens sin(theta / 2) is equal-area: d omega = dA' / lens^2, dA' = sensor w h du dv.
      return sensor_w_ * sensor_h_ / (fisheye_lens_ * fisheye_lens_);
    case PanoramaType::FisheyeLensPolynomial: {
      // theta(r) = -(k0 + k1 r + ...): d omega = sin|theta| |theta'(r)| / r dA'.
      const float theta = safe_acos(d.x);
      const Vec2 uv = pano_uv(d);
      const float u = (uv.x - 0.5f) * sensor_w_, v = (uv.y - 0.5f) * sensor_h_;
      const float r = std::sqrt(u * u + v * v), r2 = r * r;
      const float dt = poly_[1] + 2.0f * poly_[2] * r + 3.0f * poly_[3] * r2 + 4.0f * poly_[4] * r2 * r;
      if (!(r > 1e-6f)) return sensor_w_ * sensor_h_ * dt * dt;  // (sin theta / r -> |theta'|)
      return sensor_w_ * sensor_h_ * std::sin(theta) * std::fabs(dt) / r;
    }
    case PanoramaType::CentralCylindrical: {
      // The cylinder's (theta, z), linear in u and v: d omega = dtheta dz / (1 + z^2)^(3/2).
      const float h2 = d.x * d.x + d.y * d.y;
      if (!(h2 > 0.0f)) return 0.0f;
      const float c = std::sqrt(h2);  // 1 / sqrt(1 + z^2)
      return std::fabs((range_[1] - range_[0]) * (range_[3] - range_[2])) * c * c * c;
    }
  }
  return 0.0f;
}

float Camera::pano_pixel_pdf(const Frame& f, Vec3 dir) const {
  const float j = pano_jacobian(normalize(pano_from_world(f, dir)));
  const float pdf = 1.0f / (std::fabs(du_ * dv_) * j);
  return j > 0.0f && std::isfinite(pdf) ? pdf : 0.0f;
}

bool Camera::pano_view(const Frame& f, Vec3 p, float& rx, float& ry, float& dist, float& pixel_pdf) const {
  const Vec3 rel = p - f.origin;
  dist = length(rel);
  // Clipped along the ray, as generate_pano_in.
  if (!(dist > clip_start_) || !(dist < clip_start_ + clip_len_)) return false;
  const Vec3 dir = rel / dist;
  const Vec3 d = pano_from_world(f, dir);
  const Vec2 uv = pano_uv(d);
  rx = (uv.x - u0_) / du_;
  ry = (uv.y - v0_) / dv_;
  if (!std::isfinite(rx) || !std::isfinite(ry)) return false;
  // The camera's own test at that raster position (a fisheye's circle, its field of view);
  // a cube face's inverse holds only in front of it.
  const Vec3 back = pano_direction(rx, ry);
  if (back.x == 0.0f && back.y == 0.0f && back.z == 0.0f) return false;
  if (pano_ == PanoramaType::EquiangularCubemapFace && !(d.x > 0.0f)) return false;
  pixel_pdf = pano_pixel_pdf(f, dir);
  return pixel_pdf > 0.0f && std::isfinite(pixel_pdf);
}

bool Camera::pano_raster_is_canonical(float x, float y) const {
  const float u = u0_ + x * du_, v = v0_ + y * dv_;
  switch (pano_) {
    case PanoramaType::Equirectangular: {
      const float phi = range_[0] * u + range_[1], theta = range_[2] * v + range_[3];
      return phi > -kPi && phi <= kPi && theta >= 0.0f && theta <= kPi;
    }
    case PanoramaType::CentralCylindrical: {
      const float theta = range_[0] + (range_[1] - range_[0]) * u;
      return theta > -kPi && theta <= kPi;
    }
    case PanoramaType::EquiangularCubemapFace:
      return std::fabs(u - 0.5f) < 1.0f && std::fabs(v - 0.5f) < 1.0f;  // (the tangents' period)
    case PanoramaType::FisheyeLensPolynomial: {
      // theta(r) need not be monotonic: the inverse's Newton root must be this sample's.
      const Vec2 uv = pano_uv(pano_direction(x, y));
      return std::fabs(uv.x - u) < 1e-3f && std::fabs(uv.y - v) < 1e-3f;
    }
    default:  // one raster position per direction where the camera has a ray
      return true;
  }
}

Vec3 Camera::to_ndc(Vec3 p) const {
  const Vec3 c = to_camera(p);
  if (type_ == CameraType::Panoramic) {
    const Vec2 uv = pano_uv(c);
    const Vec3 ndc{uv.x, uv.y, 0.0f};
    return is_finite(ndc) ? ndc : Vec3(0.0f);
  }
  float sx = c.x, sy = c.y;
  if (type_ == CameraType::Perspective) {
    if (c.z == 0.0f) return Vec3(0.0f);  // Cycles' perspective divide gives 0 there
    sx /= c.z;
    sy /= c.z;
  }
  const Vec3 ndc{(sx - x0_) / dx_ / winx_, (sy - y0_) / dy_ / winy_, 0.0f};
  return is_finite(ndc) ? ndc : Vec3(0.0f);
}

void Camera::differentials(Vec3 dir, float& dp, float& dd) const {
  dp = dd = 0.0f;
  if (type_ == CameraType::Orthographic) {
    dp = 0.5f * (dx_ + dy_);  // parallel rays: the footprint is the pixel itself
    return;
  }
  if (type_ == CameraType::Panoramic) {
    // Cycles' panorama differentials: the direction's change to the next pixel in x and in y,
    // found from the raster position the direction came through.
    const Vec3 c = dir_to_camera(dir);
    const Vec2 uv = pano_uv(c);
    const float x = (uv.x - u0_) / du_, y = (uv.y - v0_) / dv_;
    if (!std::isfinite(x) || !std::isfinite(y)) return;
    const Vec3 d0 = normalize(c);
    float sum = 0.0f;
    int n = 0;
    for (const Vec3 dn : {pano_direction(x + 1.0f, y), pano_direction(x, y + 1.0f)}) {
      if (dn.x == 0.0f && dn.y == 0.0f && dn.z == 0.0f) continue;  // past the image circle
      sum += length(normalize(dn) - d0);
      ++n;
    }
    dd = n ? sum / float(n) : 0.0f;
    dp = clip_start_ * dd;
    if (!std::isfinite(dd) || !std::isfinite(dp)) dp = dd = 0.0f;
    return;
  }
  const Vec3 c = dir_to_camera(dir);
  if (!(c.z > 1e-6f)) return;
  // Cycles' camera_sample_perspective: the unit direction's change from one pixel to the next
  // (view plane at depth 1), averaged over x and y; the ray starts at the near clip.
  const Vec3 dc = c / c.z, d0 = normalize(dc);
  dd = 0.5f * (length(normalize(dc + Vec3{dx_, 0.0f, 0.0f}) - d0) + length(normalize(dc + Vec3{0.0f, dy_, 0.0f}) - d0));
  dp = clip_start_ / d0.z * dd;
  if (!std::isfinite(dd) || !std::isfinite(dp)) dp = dd = 0.0f;
}

Ray Camera::generate_pinhole(float x, float y) const { return generate_pinhole_in({origin_, right_, up_, back_}, x, y); }

Ray Camera::generate(float x, float y, Vec2 lens) const { return generate_in({origin_, right_, up_, back_}, x, y, lens); }

Ray Camera::generate(float x, float y, Vec2 lens, float time) const {
  Ray r = motion_.empty() ? generate(x, y, lens)
                          : generate_in(frame_of(motion_transform_at(motion_.data(), uint32_t(motion_.size()), time)), x,
                                        y, lens);
  r.time = time;
  return r;
}

Ray Camera::generate_pinhole_in(const Frame& f, float x, float y) const {
  if (type_ == CameraType::Panoramic) return generate_pano_in(f, x, y, {0.5f, 0.5f}, false);
  const Vec3 &origin_ = f.origin, &right_ = f.right, &up_ = f.up, &back_ = f.back;  // the frame's, shadowing
  const float px = x0_ + x * dx_, py = y0_ + y * dy_;
  Ray r;
  if (type_ == CameraType::Orthographic) {
    r.org = origin_ + right_ * px + up_ * py - back_ * clip_start_;
    r.dir = -back_;
    r.tmax = clip_len_;
    return r;
  }
  const Vec3 local{px, py, -1.0f};
  const float inv_len = 1.0f / length(local);
  // Unit direction; -local.z * inv_len is the cosine to the view axis.
  const Vec3 dir = (right_ * local.x + up_ * local.y + back_ * local.z) * inv_len;
  const float z_inv = 1.0f / inv_len;  // distance along the ray per unit of view depth
  if (stereo_offset_ != 0.0f) [[unlikely]] return stereo_pinhole(origin_, dir, z_inv);
  r.org = origin_ + dir * (clip_start_ * z_inv);
  r.dir = dir;
  r.tmax = clip_len_ * z_inv;
  return r;
}

// Spherical stereo of a perspective pinhole ray: in the world (z up), as Cycles; the clipping
// distance keeps the centre ray's cosine, as Cycles'. (Out of line: mono rays stay as before.)
[[gnu::noinline]] Ray Camera::stereo_pinhole(Vec3 org, Vec3 dir, float z_inv) const {
  spherical_stereo(org, dir);
  Ray r;
  r.org = org + dir * (clip_start_ * z_inv);
  r.dir = dir;
  r.tmax = clip_len_ * z_inv;
  return r;
}

Ray Camera::generate_in(const Frame& f, float x, float y, Vec2 lens) const {
  if (type_ == CameraType::Panoramic) return generate_pano_in(f, x, y, lens, true);
  if (aperture_ <= 0.0f) return generate_pinhole_in(f, x, y);
  const Vec3 &origin_ = f.origin, &right_ = f.right, &up_ = f.up, &back_ = f.back;
  const Vec2 a = sample_aperture(lens);
  const float lx = a.x * aperture_, ly = a.y * aperture_;
  const float px = x0_ + x * dx_, py = y0_ + y * dy_;
  // In camera space (x right, y up, z forward): the ray leaves the lens point L and passes
  // through the pinhole ray's point at depth focus_, so the focal plane is exactly there.
  Vec3 L, F;
  if (type_ == CameraType::Orthographic) {
    L = {px + lx, py + ly, 0.0f};
    F = {px, py, focus_};
  } else {
    L = {lx, ly, 0.0f};
    F = {px * focus_, py * focus_, focus_};
  }
  const Vec3 dc = normalize(F - L);
  Ray r;
  r.dir = right_ * dc.x + up_ * dc.y - back_ * dc.z;
  Vec3 lw = origin_ + right_ * L.x + up_ * L.y;
  // Perspective spherical stereo after the lens, in the world (as Cycles; none for orthographic).
  if (stereo_offset_ != 0.0f && type_ == CameraType::Perspective) [[unlikely]] {
    r.dir = normalize(r.dir);
    spherical_stereo(lw, r.dir);
  }
  // Clipping planes stay planes perpendicular to the view axis, for every lens point (Cycles
  // measures the near clip with the pinhole ray's cosine instead: a negligible difference).
  const float z_inv = 1.0f / dc.z;
  r.org = lw + r.dir * (clip_start_ * z_inv);
  r.tmax = clip_len_ * z_inv;
  return r;
}

}  // namespace pl
