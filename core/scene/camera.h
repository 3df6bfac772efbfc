// Perspective camera with Blender's conventions: looks down local -Z with +Y up, view plane
// from sensor size, fit, focal length and shift exactly as Blender computes it
// (BKE_camera_params_compute_viewplane), near/far clipping measured along the view axis.
#pragma once
#include <string>

#include "geometry/ray.h"

namespace pl {

enum class SensorFit { Auto, Horizontal, Vertical };

struct CameraDesc {
  Mat4 matrix_world;
  float lens = 50.0f;  // mm
  float sensor_width = 36.0f, sensor_height = 24.0f;
  SensorFit sensor_fit = SensorFit::Auto;
  float shift_x = 0.0f, shift_y = 0.0f;
  float clip_start = 0.1f, clip_end = 1000.0f;
  float pixel_aspect_x = 1.0f, pixel_aspect_y = 1.0f;
};

class Camera {
 public:
  Camera() = default;
  Camera(const CameraDesc& d, int width, int height);
  // Ray through raster position (x, y), measured in pixels from the bottom-left corner.
  Ray generate(float x, float y) const;

 private:
  Vec3 origin_, right_, up_, back_;  // orthonormal world axes of the camera
  float x0_ = 0, y0_ = 0, dx_ = 0, dy_ = 0;  // view plane at distance 1: left, bottom, size per pixel
  float clip_start_ = 0, clip_len_ = kInf;
};

}  // namespace pl
