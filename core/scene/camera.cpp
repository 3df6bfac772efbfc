#include "scene/camera.h"

namespace pl {

Camera::Camera(const CameraDesc& d, int width, int height) {
  const Mat4& m = d.matrix_world;
  origin_ = {m.m[0][3], m.m[1][3], m.m[2][3]};
  // Blender ignores the camera object's scale: keep only its rotation (orthonormalised).
  right_ = normalize(Vec3{m.m[0][0], m.m[1][0], m.m[2][0]});
  up_ = Vec3{m.m[0][1], m.m[1][1], m.m[2][1]};
  up_ = normalize(up_ - right_ * dot(up_, right_));
  back_ = cross(right_, up_);

  const float winx = static_cast<float>(width), winy = static_cast<float>(height);
  const float ycor = d.pixel_aspect_y / d.pixel_aspect_x;
  const float sensor = d.sensor_fit == SensorFit::Vertical ? d.sensor_height : d.sensor_width;
  SensorFit fit = d.sensor_fit;
  if (fit == SensorFit::Auto)
    fit = d.pixel_aspect_x * winx >= d.pixel_aspect_y * winy ? SensorFit::Horizontal : SensorFit::Vertical;
  const float viewfac = fit == SensorFit::Horizontal ? winx : ycor * winy;
  const float pixsize = sensor / d.lens / viewfac;  // view-plane units per pixel at distance 1
  const float shx = d.shift_x * viewfac, shy = d.shift_y * viewfac;
  x0_ = (-0.5f * winx + shx) * pixsize;
  y0_ = (-0.5f * ycor * winy + shy) * pixsize;
  dx_ = pixsize;
  dy_ = ycor * pixsize;
  clip_start_ = d.clip_start;
  clip_len_ = d.clip_end - d.clip_start;
}

Ray Camera::generate(float x, float y) const {
  const Vec3 local{x0_ + x * dx_, y0_ + y * dy_, -1.0f};
  const float inv_len = 1.0f / length(local);
  // Unit direction; -local.z * inv_len is the cosine to the view axis.
  const Vec3 dir = (right_ * local.x + up_ * local.y + back_ * local.z) * inv_len;
  const float z_inv = 1.0f / inv_len;  // distance along the ray per unit of view depth
  Ray r;
  r.org = origin_ + dir * (clip_start_ * z_inv);
  r.dir = dir;
  r.tmax = clip_len_ * z_inv;
  return r;
}

}  // namespace pl
