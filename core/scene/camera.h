// Perspective and orthographic cameras with Blender's conventions: looks down local -Z with +Y
// up, view plane from sensor size (or ortho scale), fit, focal length and shift exactly as
// Blender computes it (BKE_camera_params_compute_viewplane), near/far clipping measured along
// the view axis. Optional thin lens (Cycles' model): a disk or polygonal aperture of a given
// radius, every ray through a pixel meets the pinhole ray at the focal plane, which lies at
// focus_distance along the view axis. Panoramic cameras map the raster to a direction as
// Cycles' camera_sample_panorama does (kernel/camera/projection.h), in Cycles' panorama space
// (x forward, y left, z up; a mirror ball's: x right, y back, z up).
#pragma once
#include <string>

#include <vector>

#include "geometry/motion.h"
#include "geometry/ray.h"
#include "util/sampling.h"

namespace pl {

enum class SensorFit { Auto, Horizontal, Vertical };
enum class CameraType { Perspective, Orthographic, Panoramic };
// Blender's Camera.panorama_type, in its order.
enum class PanoramaType {
  Equirectangular,
  EquiangularCubemapFace,
  Mirrorball,
  FisheyeEquidistant,
  FisheyeEquisolid,
  FisheyeLensPolynomial,
  CentralCylindrical
};
// Which eye a spherical-stereo camera renders (Cycles' Camera::StereoEye).
enum class StereoEye { None, Left, Right };

struct CameraDesc {
  Mat4 matrix_world;
  CameraType type = CameraType::Perspective;
  float lens = 50.0f;  // mm
  float ortho_scale = 6.0f;  // view width (or height, by the fit) of an orthographic camera
  float sensor_width = 36.0f, sensor_height = 24.0f;
  SensorFit sensor_fit = SensorFit::Auto;
  float shift_x = 0.0f, shift_y = 0.0f;
  float clip_start = 0.1f, clip_end = 1000.0f;
  float pixel_aspect_x = 1.0f, pixel_aspect_y = 1.0f;
  // Thin lens, in world units (the add-on converts Blender's F-stop as Cycles does).
  float aperture_size = 0.0f;     // aperture radius; 0 = pinhole
  float focus_distance = 10.0f;   // along the view axis
  int aperture_blades = 0;        // < 3: round aperture
  float aperture_rotation = 0.0f; // radians
  float aperture_ratio = 1.0f;    // anamorphic bokeh: > 1 squeezes it horizontally
  // Autofocus: the session sets focus_distance from the surface seen through this point
  // (0..1 over the full frame, from the bottom-left).
  bool use_autofocus = false;
  float autofocus_x = 0.5f, autofocus_y = 0.5f;
  // Motion blur: the camera's matrix_world at each motion step over the shutter (>= 2; empty:
  // static), and the shutter curve sampled evenly over the shutter (empty: a box shutter), which
  // also times the objects' motion.
  std::vector<Mat4> motion;
  std::vector<float> shutter_curve;
  // Cycles' rolling shutter ('TOP': rows read from the top of the frame down) and its
  // duration (0: every row at one instant; 1: the plain shutter, no rolling).
  bool rolling_shutter = false;
  float rolling_shutter_duration = 0.1f;
  // Vector pass: matrix_world at the previous and next frames (2; empty: still).
  std::vector<Mat4> pass_motion;
  // Panoramic cameras (type Panoramic), Blender's fields and units (radians, mm).
  PanoramaType panorama_type = PanoramaType::FisheyeEquisolid;
  float fisheye_fov = kPi, fisheye_lens = 10.5f;
  float latitude_min = -0.5f * kPi, latitude_max = 0.5f * kPi;
  float longitude_min = -kPi, longitude_max = kPi;
  float fisheye_polynomial[5] = {0.0f, 0.0f, 0.0f, 0.0f, 0.0f};  // k0..k4
  float cylinder_u_min = -kPi, cylinder_u_max = kPi, cylinder_v_min = -1.0f, cylinder_v_max = 1.0f,
        cylinder_radius = 1.0f;
  // The part of the panorama the frame spans, in units where the camera's frame is [0, 1]^2
  // (left, right, bottom, top): the viewport's region around the camera border; shift adds.
  float pano_viewplane[4] = {0.0f, 1.0f, 0.0f, 1.0f};
  // Width over height (pixel aspect included) the fisheye sensor is fitted to; 0: the frame's.
  float pano_fit_aspect = 0.0f;
  // Spherical stereo (Blender's camera.stereo with Spherical Stereo; Cycles'
  // spherical_stereo_transform): a panorama's (or a perspective camera's) every ray starts half
  // the interocular distance to its own side (left eye -, right eye +; none: mono), and turns
  // toward the point at convergence_distance along the centre ray (inf: parallel rays). Pole
  // merge fades the offset out between the two altitudes (radians) toward the poles.
  StereoEye stereo_eye = StereoEye::None;
  float interocular_distance = 0.065f;
  float convergence_distance = 1.95f;
  bool use_pole_merge = false;
  float pole_merge_angle_from = kPi / 3.0f, pole_merge_angle_to = 5.0f * kPi / 12.0f;
};

class Camera {
 public:
  // The camera's position and orthonormal world axes at one shutter time (motion blur).
  struct Frame {
    Vec3 origin, right, up, back;
  };
  Camera() = default;
  Camera(const CameraDesc& d, int width, int height);
  // Ray through raster position (x, y), measured in pixels from the bottom-left corner of the
  // full frame; `lens` (unit square) picks the point on the aperture (ignored for a pinhole).
  Ray generate(float x, float y, Vec2 lens = {0.5f, 0.5f}) const;
  // The same at shutter time `time` (0..1): where the camera moves, from its frame then; the
  // ray carries the time.
  Ray generate(float x, float y, Vec2 lens, float time) const;
  bool has_motion() const { return !motion_.empty(); }
  const ShutterTable& shutter() const { return shutter_; }
  // Cycles' camera_sample: the shutter time t of a ray in pixel row `row` (0: the bottom row of
  // the full frame) under the rolling shutter; t where it is off.
  bool rolling_shutter() const { return rolling_; }
  float rolling_time(float t, int row) const {
    const float r = 1.0f - float(row) / winy_;  // the top row first (0), the bottom last
    return rolling_duration_ != 0.0f ? (t - 0.5f) * rolling_duration_ + (r - 0.5f) * (1.0f - rolling_duration_) + 0.5f
                                     : r;
  }
  // The same ray through the lens centre: what autofocus and the focal plane are defined by.
  Ray generate_pinhole(float x, float y) const;
  bool has_aperture() const { return aperture_ > 0.0f; }
  bool orthographic() const { return type_ == CameraType::Orthographic; }
  float focus_distance() const { return focus_; }
  float clip_start() const { return clip_start_; }
  void set_focus_distance(float d);
  // Distance of a world point from the camera along the view axis.
  float view_depth(Vec3 p) const { return -dot(p - origin_, back_); }
  // The Depth pass (Cycles' camera_z_depth): the view depth, or a panorama's distance.
  float z_depth(Vec3 p) const { return type_ == CameraType::Panoramic ? length(p - origin_) : view_depth(p); }
  bool is_panoramic() const { return type_ == CameraType::Panoramic; }
  // Spherical stereo on: each ray has its own centre of projection (no inverse map here).
  bool has_spherical_stereo() const { return stereo_offset_ != 0.0f; }
  // Cycles' spherical_stereo_transform of a ray from p along d, in a space whose +z is up (a
  // panorama's own space; the world for a perspective camera): p moves sideways by the eye's
  // offset (faded by the pole merge), d turns toward the convergence point.
  void spherical_stereo(Vec3& p, Vec3& d) const;
  // The camera's position and unit view axis (at shutter open; the Mist pass measures from them).
  Vec3 origin() const { return origin_; }
  Vec3 forward() const { return -back_; }
  // Point on the aperture (camera-plane offsets along right/up, before scaling by the radius).
  Vec2 sample_aperture(Vec2 u) const;
  // Cycles' camera space (x right, y up, z forward: Blender's -Z; a panorama's own space),
  // without the object's scale: what the Texture Coordinate and Vector Transform nodes call
  // Camera.
  Vec3 dir_to_camera(Vec3 v) const { return {dot(v, cam_x_), dot(v, cam_y_), dot(v, cam_z_)}; }
  Vec3 to_camera(Vec3 p) const { return dir_to_camera(p - origin_); }
  Vec3 dir_from_camera(Vec3 v) const { return cam_x_ * v.x + cam_y_ * v.y + cam_z_ * v.z; }
  Vec3 from_camera(Vec3 p) const { return origin_ + dir_from_camera(p); }
  // Cycles' compact ray differentials of a camera ray along `dir` (a cone: the footprint's
  // radius at the ray's start and its growth per unit of distance), for the Wireframe node's
  // pixel size and what else measures a pixel at the shading point.
  void differentials(Vec3 dir, float& dp, float& dd) const;
  // Where a world point projects in the frame, 0..1 from the bottom-left corner (Cycles'
  // NDC, the Texture Coordinate node's Window; z is 0). A panorama's: its (u, v) of the
  // direction, as Cycles (no viewplane, no shift).
  Vec3 to_ndc(Vec3 p) const;
  // A still pinhole perspective camera's view of world point p (light tracing): raster
  // position (pixels from the bottom-left of the full frame), distance from the camera, and
  // the solid-angle density of a pixel's uniform sample there (1 / (pixel area on the view plane
  // at distance 1 x cos^3 of the angle to the view axis)). False: behind the camera or outside
  // the clipping range.
  bool pinhole_view(Vec3 p, float& rx, float& ry, float& dist, float& pixel_pdf) const {
    return pinhole_view(still_frame(), p, rx, ry, dist, pixel_pdf);
  }
  // A still thin-lens camera's view of world point p through the aperture point that
  // sample_aperture(u) picks (light tracing: pbrt-v4's PerspectiveCamera::SampleWi): the lens
  // point `eye` that the camera ray through p leaves (a perspective camera's: the aperture
  // offset from the origin; an orthographic one's moves with the pixel), the raster position
  // of that ray (it meets the pinhole ray of that position at the focal plane), the distance
  // d from eye, and pixel_pdf: a perspective camera's pixel density per unit solid angle of
  // the ray's direction (pinhole_pixel_pdf), an orthographic one's d^2 / (pixel area x cos),
  // so that for both pixel_pdf / d^2 is the pixel's density per unit area across the ray at p.
  // False: outside the clipping range.
  bool lens_view(Vec3 p, Vec2 u, Vec3& eye, float& rx, float& ry, float& dist, float& pixel_pdf) const {
    return lens_view(still_frame(), p, u, eye, rx, ry, dist, pixel_pdf);
  }
  // The same from the camera's frame at one shutter time (frame_at), pinhole or lens, and a
  // pinhole panorama's view (pano_view). The light tracer's one entry point.
  bool lens_view(const Frame& f, Vec3 p, Vec2 u, Vec3& eye, float& rx, float& ry, float& dist, float& pixel_pdf) const;
  bool pinhole_view(const Frame& f, Vec3 p, float& rx, float& ry, float& dist, float& pixel_pdf) const;
  // A pinhole panorama's view of p: the raster position of the direction (pano_uv inverted
  // through the viewplane), the distance from the camera, and the pixel density per unit solid
  // angle there (pano_pixel_pdf). False: outside the clipping range, or a direction whose
  // raster position the camera gives no ray (outside a fisheye's circle, its field of view, a
  // cube face).
  bool pano_view(const Frame& f, Vec3 p, float& rx, float& ry, float& dist, float& pixel_pdf) const;
  // pixel_pdf of a camera ray with unit direction dir at distance dist from its lens point.
  float lens_pixel_pdf(Vec3 dir, float dist) const { return lens_pixel_pdf(still_frame(), dir, dist); }
  float lens_pixel_pdf(const Frame& f, Vec3 dir, float dist) const {
    if (type_ == CameraType::Panoramic) return pano_pixel_pdf(f, dir);
    if (type_ != CameraType::Orthographic) return pinhole_pixel_pdf(f, dir);
    const float c = -dot(dir, f.back);
    return c > 0.0f ? dist * dist / (dx_ * dy_ * c) : 0.0f;
  }
  // That density for a unit direction from the camera (what a camera ray had).
  float pinhole_pixel_pdf(Vec3 dir) const { return pinhole_pixel_pdf(still_frame(), dir); }
  float pinhole_pixel_pdf(const Frame& f, Vec3 dir) const {
    const float c = -dot(dir, f.back);
    return c > 0.0f ? 1.0f / (dx_ * dy_ * c * c * c) : 0.0f;
  }
  // A panorama's pixel density per unit solid angle along world direction dir (unit) from
  // frame f: 1 / (|du dv| |d omega / d(u, v)|), the Jacobian of its (u, v) -> direction map
  // (docs/design/sampling.md, "Caustic light paths with motion blur and panoramic cameras").
  float pano_pixel_pdf(const Frame& f, Vec3 dir) const;
  // The camera's frame at shutter time t (0..1): its motion's there, else the still one.
  Frame frame_at(float t) const {
    return motion_.empty() ? still_frame() : frame_of(motion_transform_at(motion_.data(), uint32_t(motion_.size()), t));
  }
  Frame still_frame() const { return {origin_, right_, up_, back_}; }
  // The share of the segment eye -> p (a camera ray's lens point and its hit) that lies before
  // the near clip: the view depth's clip plane, a panorama's sphere of radius clip_start.
  float near_fraction(const Frame& f, Vec3 p, Vec3 eye) const {
    if (type_ == CameraType::Panoramic) return clip_start_ / length(p - eye);
    return clip_start_ / -dot(p - f.origin, f.back);
  }
  // Whether a panorama's camera sample at raster (x, y) is where pano_view puts its direction:
  // its angles within the range the inverse map returns (atan2's, acos's), not a pixel filter's
  // tail past an equirectangular or cylindrical seam or pole, or a cube face's tangent's period
  // (the light tracer never splats there); a lens polynomial's by a round trip.
  bool pano_raster_is_canonical(float x, float y) const;
  // A panorama's direction (its own space, not unit) at raster (x, y); zero outside the image
  // circle or the lens's field of view.
  Vec3 pano_direction(float x, float y) const;
  // The inverse: (u, v) of a direction in panorama space.
  Vec2 pano_uv(Vec3 d) const;

 private:
  static Frame frame_of(const Mat4& m);
  Ray generate_pinhole_in(const Frame& f, float x, float y) const;
  Ray stereo_pinhole(Vec3 org, Vec3 dir, float z_inv) const;
  Ray generate_in(const Frame& f, float x, float y, Vec2 lens) const;
  Ray generate_pano_in(const Frame& f, float x, float y, Vec2 lens, bool use_lens) const;
  // Panorama space -> the frame's world axes, and back.
  Vec3 pano_to_world(const Frame& f, Vec3 d) const;
  Vec3 pano_from_world(const Frame& f, Vec3 w) const;
  // |d omega / d(u, v)| of a panorama at its own-space direction d (unit); 0 where undefined.
  float pano_jacobian(Vec3 d) const;
  std::vector<DecomposedTransform> motion_;  // empty: static
  ShutterTable shutter_;
  bool rolling_ = false;
  float rolling_duration_ = 0.0f;
  CameraType type_ = CameraType::Perspective;
  Vec3 origin_, right_, up_, back_;  // orthonormal world axes of the camera
  // View plane at distance 1 (perspective) or in world units (orthographic): left, bottom,
  // size per pixel.
  float x0_ = 0, y0_ = 0, dx_ = 0, dy_ = 0;
  float clip_start_ = 0, clip_len_ = kInf;
  float aperture_ = 0.0f, focus_ = 10.0f, blade_rotation_ = 0.0f, inv_aperture_ratio_ = 1.0f;
  int blades_ = 0;
  float winx_ = 1.0f, winy_ = 1.0f;  // the full frame in pixels
  Vec3 cam_x_, cam_y_, cam_z_;       // Cycles' camera space axes in the world
  // Panorama: raster -> (u, v) = (u0 + x du, v0 + y dv), and Cycles' kernel parameters.
  PanoramaType pano_ = PanoramaType::Equirectangular;
  float u0_ = 0, du_ = 1, v0_ = 0, dv_ = 1;
  float range_[4] = {0, 0, 0, 0};  // equirectangular or central cylindrical range
  float fov_ = kPi, fisheye_lens_ = 10.5f, sensor_w_ = 36.0f, sensor_h_ = 24.0f;
  float poly_[5] = {0, 0, 0, 0, 0};
  // Spherical stereo: the signed sideways offset (0: mono), convergence distance (inf:
  // parallel), pole merge altitudes (to <= 0: off).
  float stereo_offset_ = 0.0f, convergence_ = kInf, pole_from_ = -1.0f, pole_to_ = -1.0f;
};

}  // namespace pl
