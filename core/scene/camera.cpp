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

Vec3 Camera::to_ndc(Vec3 p) const {
  const Vec3 c = to_camera(p);
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
  r.org = origin_ + dir * (clip_start_ * z_inv);
  r.dir = dir;
  r.tmax = clip_len_ * z_inv;
  return r;
}

Ray Camera::generate_in(const Frame& f, float x, float y, Vec2 lens) const {
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
  const Vec3 lw = origin_ + right_ * L.x + up_ * L.y;
  // Clipping planes stay planes perpendicular to the view axis, for every lens point (Cycles
  // measures the near clip with the pinhole ray's cosine instead: a negligible difference).
  const float z_inv = 1.0f / dc.z;
  r.org = lw + r.dir * (clip_start_ * z_inv);
  r.tmax = clip_len_ * z_inv;
  return r;
}

}  // namespace pl
