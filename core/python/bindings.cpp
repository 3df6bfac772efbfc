// The only file that sees Python. Converts and validates numpy input, turns C++ exceptions
// into Python ones (pybind11 maps std::invalid_argument to ValueError), and releases the GIL
// around everything that takes time.
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <algorithm>
#include <memory>
#include <mutex>
#include <stdexcept>

#include "geometry/polygon_mesh.h"
#include "render/guiding.h"
#include "render/session.h"
#include "scene/ies.h"
#include "scene/light_shader.h"
#include "scene/displace.h"
#include "geometry/subdivide.h"
#include <cstring>
#include "scene/phase.h"
#include "scene/shader_ops.h"
#include "scene/vdb_reader.h"
#include "util/big_alloc.h"
#include "util/hash.h"
#include "util/lookup3.h"
#include "util/murmur3.h"

namespace py = pybind11;
using namespace pl;

#ifndef PATHLIGHT_SIMD_NAME
#define PATHLIGHT_SIMD_NAME "generic"
#endif
#ifndef PATHLIGHT_VERSION
#define PATHLIGHT_VERSION "0.0.0"
#endif

namespace {

using FloatArray = py::array_t<float, py::array::c_style | py::array::forcecast>;
using IntArray = py::array_t<int64_t, py::array::c_style | py::array::forcecast>;

// Light::visibility from Blender's Ray Visibility flags of a light object.
uint8_t light_visibility(bool camera, bool diffuse, bool glossy, bool transmission, bool volume) {
  return uint8_t((camera ? kLightVisCamera : 0) | (diffuse ? kLightVisDiffuse : 0) | (glossy ? kLightVisGlossy : 0) |
                 (transmission ? kLightVisTransmission : 0) | (volume ? kLightVisVolume : 0));
}

Vec3 to_color(const py::handle& h, const char* what) {
  const auto v = py::cast<std::vector<float>>(h);
  if (v.size() != 3) throw std::invalid_argument(std::string(what) + " must have 3 components");
  // Colours are radiance/albedo: NaN or negative values have no meaning, so they become 0.
  auto clean = [](float x) { return std::isfinite(x) && x > 0.0f ? x : 0.0f; };
  return {clean(v[0]), clean(v[1]), clean(v[2])};
}

Vec3 to_point(const py::handle& h, const char* what) {
  const auto v = py::cast<std::vector<float>>(h);
  if (v.size() != 3) throw std::invalid_argument(std::string(what) + " must have 3 components");
  const Vec3 p{v[0], v[1], v[2]};
  if (!is_finite(p)) throw std::invalid_argument(std::string(what) + " contains NaN or infinite values");
  return p;
}

float finite_nonneg(float x, const char* what) {
  if (!std::isfinite(x) || x < 0.0f) throw std::invalid_argument(std::string(what) + " must be finite and >= 0");
  return x;
}

// A Clamping limit (RenderSettings::clamp_direct, clamp_indirect) or Filter Glossy: 0 is off,
// so a negative or non-finite one is taken as 0 (off), with a Python warning that says so.
float clamp_setting(float v, const char* what, const char* off = "no clamping") {
  if (std::isfinite(v) && v >= 0.0f) return v;
  const std::string msg = std::string(what) + " must be a finite number >= 0 (0: " + off + "); " +
                          std::to_string(v) + " is treated as 0";
  py::module_::import("warnings").attr("warn")(msg);
  return 0.0f;
}

// A setting Python names by strings: its enum's values and their names in one table, read
// both ways; an unknown name is a ValueError that lists the names (quoted, or bare as Blender's
// upper-case enum names have always been listed).
template <class E>
using EnumNames = std::initializer_list<std::pair<E, const char*>>;
template <class E>
const char* enum_name(E v, EnumNames<E> names) {
  for (const auto& [e, n] : names)
    if (e == v) return n;
  return names.begin()->second;
}
template <class E>
E enum_from_name(const std::string& s, const char* setting, EnumNames<E> names, bool quoted = true) {
  const std::string q = quoted ? "'" : "";
  std::string list;
  size_t k = 0;
  for (const auto& [e, n] : names) {
    if (s == n) return e;
    list += std::string(k == 0 ? "" : k + 1 == names.size() ? " or " : ", ") + q + n + q;
    ++k;
  }
  throw std::invalid_argument(std::string(setting) + " must be " + list);
}
constexpr EnumNames<Scene::CompactBvh> kCompactBvhNames = {
    {Scene::CompactBvh::Auto, "auto"}, {Scene::CompactBvh::On, "on"}, {Scene::CompactBvh::Off, "off"}};
constexpr EnumNames<Scene::BuildQuality> kBuildQualityNames = {
    {Scene::BuildQuality::Auto, "auto"}, {Scene::BuildQuality::Sah, "sah"}, {Scene::BuildQuality::Fast, "fast"}};
constexpr EnumNames<BvhLayout> kBvhLayoutNames = {
    {BvhLayout::Auto, "auto"}, {BvhLayout::Binary, "binary"}, {BvhLayout::Wide4, "bvh4"}, {BvhLayout::Wide8, "bvh8"}};
constexpr EnumNames<SamplerType> kSamplerNames = {{SamplerType::Sobol, "sobol"},
                                                   {SamplerType::Random, "random"},
                                                   {SamplerType::SobolDeep, "sobol_deep"},
                                                   {SamplerType::Sobol4D, "sobol4d"},
                                                   {SamplerType::Sobol4DDeep, "sobol4d_deep"},
                                                   {SamplerType::Sobol4DRoulette, "sobol4d_rr"},
                                                   {SamplerType::Sobol4DCycles, "sobol4d_cycles"},
                                                   {SamplerType::SobolPairs, "sobol_pairs"}};
constexpr EnumNames<PixelPattern> kPixelPatternNames = {{PixelPattern::Independent, "independent"},
                                                         {PixelPattern::BlueNoise, "blue_noise"},
                                                         {PixelPattern::BlueNoiseRound, "blue_noise_round"},
                                                         {PixelPattern::BlueNoiseFirst, "blue_noise_first"}};
constexpr EnumNames<FilterType> kFilterNames = {
    {FilterType::Box, "box"}, {FilterType::Gaussian, "gaussian"}, {FilterType::BlackmanHarris, "blackman_harris"}};
constexpr EnumNames<DebugView> kDebugViewNames = {{DebugView::None, "none"}, {DebugView::Bvh, "bvh"}};
constexpr EnumNames<SensorFit> kSensorFitNames = {
    {SensorFit::Auto, "AUTO"}, {SensorFit::Horizontal, "HORIZONTAL"}, {SensorFit::Vertical, "VERTICAL"}};
constexpr EnumNames<CameraType> kCameraTypeNames = {
    {CameraType::Perspective, "PERSP"}, {CameraType::Orthographic, "ORTHO"}, {CameraType::Panoramic, "PANO"}};
constexpr EnumNames<StereoEye> kStereoEyeNames = {
    {StereoEye::None, "NONE"}, {StereoEye::Left, "LEFT"}, {StereoEye::Right, "RIGHT"}};
constexpr EnumNames<PanoramaType> kPanoramaTypeNames = {{PanoramaType::Equirectangular, "EQUIRECTANGULAR"},
                                                        {PanoramaType::EquiangularCubemapFace, "EQUIANGULAR_CUBEMAP_FACE"},
                                                        {PanoramaType::Mirrorball, "MIRRORBALL"},
                                                        {PanoramaType::FisheyeEquidistant, "FISHEYE_EQUIDISTANT"},
                                                        {PanoramaType::FisheyeEquisolid, "FISHEYE_EQUISOLID"},
                                                        {PanoramaType::FisheyeLensPolynomial, "FISHEYE_LENS_POLYNOMIAL"},
                                                        {PanoramaType::CentralCylindrical, "CENTRAL_CYLINDRICAL"}};

Mat4 to_mat4(const FloatArray& a, const char* what);

// A light's IES profile (None: none) and its frame: Cycles evaluates the light shader's normal
// in the light's space by the transposed matrix (transform_direction_transposed).
void set_light_ies(Light& l, const py::object& ies, const Mat4& m) {
  if (ies.is_none()) return;
  l.ies = ies.cast<std::shared_ptr<IesProfile>>();
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) l.ies_to_local.m[i][j] = m.m[j][i];
}

// The inverse of the upper 3x3 of m, for transforming directions into a light's frame.
Mat4 inverse3x3(const Mat4& m, const char* what) {
  const Vec3 c0{m.m[0][0], m.m[1][0], m.m[2][0]}, c1{m.m[0][1], m.m[1][1], m.m[2][1]}, c2{m.m[0][2], m.m[1][2], m.m[2][2]};
  const Vec3 r0 = cross(c1, c2), r1 = cross(c2, c0), r2 = cross(c0, c1);
  const float det = dot(c0, r0);
  if (!(std::fabs(det) > 0.0f) || !std::isfinite(det)) throw std::invalid_argument(std::string(what) + " is singular");
  Mat4 inv;
  for (int j = 0; j < 3; ++j) {
    inv.m[0][j] = r0[j] / det;
    inv.m[1][j] = r1[j] / det;
    inv.m[2][j] = r2[j] / det;
  }
  return inv;
}

// Gram-Schmidt on the rows of a 3x3 rotation (a Mapping node may add scale); singular -> error.
Mat4 orthonormal_rotation(const Mat4& m) {
  Vec3 r0{m.m[0][0], m.m[0][1], m.m[0][2]}, r1{m.m[1][0], m.m[1][1], m.m[1][2]};
  Vec3 r2in{m.m[2][0], m.m[2][1], m.m[2][2]};
  // Scale-free test: normalise the rows first (a uniform scale of 1e-20 is still a rotation).
  for (Vec3* r : {&r0, &r1, &r2in}) {
    const double l = std::sqrt(double(r->x) * r->x + double(r->y) * r->y + double(r->z) * r->z);
    if (!(l > 0.0) || !std::isfinite(l)) throw std::invalid_argument("world texture rotation is singular");
    *r = Vec3{float(r->x / l), float(r->y / l), float(r->z / l)};
  }
  const float det = dot(r0, cross(r1, r2in));
  if (!(std::fabs(det) > 1e-6f)) throw std::invalid_argument("world texture rotation is singular");
  r1 = normalize(r1 - r0 * dot(r1, r0));
  Vec3 r2 = cross(r0, r1);
  if (det < 0.0f) r2 = -r2;  // keep a mirroring mapping a mirror
  Mat4 out;
  const Vec3 rows[3] = {r0, r1, r2};
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) out.m[i][j] = rows[i][j];
  return out;
}

Mat4 to_mat4(const FloatArray& a, const char* what) {
  if (a.ndim() != 2 || a.shape(0) != 4 || a.shape(1) != 4)
    throw std::invalid_argument(std::string(what) + " must be a 4x4 matrix");
  Mat4 m;
  auto r = a.unchecked<2>();
  for (int i = 0; i < 4; ++i)
    for (int j = 0; j < 4; ++j) m.m[i][j] = r(i, j);
  if (!m.is_finite()) throw std::invalid_argument(std::string(what) + " contains NaN or infinite values");
  return m;
}

// Motion steps: None or an (S, 4, 4) array, S >= 2. Values are not checked here: steps that are
// not finite or not invertible leave the object (or camera) static, as the core decides.
std::vector<Mat4> to_motion(const py::object& o, const char* what) {
  std::vector<Mat4> steps;
  if (o.is_none()) return steps;
  const FloatArray a = o.cast<FloatArray>();
  if (a.ndim() != 3 || a.shape(1) != 4 || a.shape(2) != 4 || a.shape(0) < 2 || a.shape(0) > 1025)
    throw std::invalid_argument(std::string(what) + " must be an (S, 4, 4) array of 2 to 1025 matrices");
  auto r = a.unchecked<3>();
  steps.resize(size_t(a.shape(0)));
  for (py::ssize_t k = 0; k < a.shape(0); ++k)
    for (int i = 0; i < 4; ++i)
      for (int j = 0; j < 4; ++j) steps[size_t(k)].m[i][j] = r(k, i, j);
  return steps;
}

// The Vector pass's points of a curve set or cloud (None: none): (2, N, 3), object space.
std::vector<std::vector<Vec3>> to_pass_points(const py::object& o, size_t n, const char* what) {
  std::vector<std::vector<Vec3>> out;
  if (o.is_none()) return out;
  const FloatArray a = o.cast<FloatArray>();
  if (a.ndim() != 3 || a.shape(0) != 2 || size_t(a.shape(1)) != n || a.shape(2) != 3)
    throw std::invalid_argument(std::string(what) + " must be a (2, N, 3) array of the N points");
  const Vec3* p = reinterpret_cast<const Vec3*>(a.data());
  for (size_t k = 0; k < 2; ++k) out.emplace_back(p + k * n, p + (k + 1) * n);
  return out;
}

// The Vector pass's matrices of an object (None: still): (2, 4, 4), as add_instance's pass_motion.
std::vector<Mat4> to_pass_motion(const py::object& o, const char* what) {
  std::vector<Mat4> m = to_motion(o, what);
  if (!m.empty() && m.size() != 2) throw std::invalid_argument(std::string(what) + " must be a (2, 4, 4) array");
  return m;
}

// Deformation steps of a curve or point set: None, or (S, N, 3) positions with S in 2..1025 and N
// the set's point count, and (S, N) radii or None. Values are checked by the core at commit
// (non-finite steps leave the set undeformed).
void to_deform(const py::object& points, const py::object& radii, size_t n, const char* what,
               std::vector<std::vector<Vec3>>& out_points, std::vector<std::vector<float>>& out_radii) {
  if (points.is_none()) {
    if (!radii.is_none()) throw std::invalid_argument(std::string(what) + " radii need motion points");
    return;
  }
  const FloatArray a = points.cast<FloatArray>();
  if (a.ndim() != 3 || a.shape(2) != 3 || size_t(a.shape(1)) != n || a.shape(0) < 2 || a.shape(0) > 1025)
    throw std::invalid_argument(std::string(what) + " motion points must be an (S, N, 3) array with 2 to 1025 steps");
  const size_t steps = size_t(a.shape(0));
  out_points.assign(steps, std::vector<Vec3>(n));
  for (size_t s = 0; s < steps; ++s)
    std::memcpy(static_cast<void*>(out_points[s].data()), a.data() + s * n * 3, n * sizeof(Vec3));
  if (radii.is_none()) return;
  const FloatArray r = radii.cast<FloatArray>();
  if (r.ndim() != 2 || size_t(r.shape(0)) != steps || size_t(r.shape(1)) != n)
    throw std::invalid_argument(std::string(what) + " motion radii must be an (S, N) array");
  out_radii.assign(steps, std::vector<float>(n));
  for (size_t s = 0; s < steps; ++s) std::memcpy(out_radii[s].data(), r.data() + s * n, n * sizeof(float));
}

FloatArray from_mat4(const Mat4& m) {
  FloatArray a({4, 4});
  auto w = a.mutable_unchecked<2>();
  for (int i = 0; i < 4; ++i)
    for (int j = 0; j < 4; ++j) w(i, j) = m.m[i][j];
  return a;
}

void validate_camera(const CameraDesc& c) {
  if (!(c.lens > 0.0f) || !(c.sensor_width > 0.0f) || !(c.sensor_height > 0.0f))
    throw std::invalid_argument("camera lens and sensor size must be positive");
  if (!(c.clip_start >= 0.0f) || !(c.clip_end > c.clip_start))
    throw std::invalid_argument("camera clip_end must be greater than clip_start >= 0");
  if (!(c.pixel_aspect_x > 0.0f) || !(c.pixel_aspect_y > 0.0f))
    throw std::invalid_argument("pixel aspect must be positive");
  for (float v : {c.lens, c.sensor_width, c.sensor_height, c.shift_x, c.shift_y, c.clip_start,
                  c.pixel_aspect_x, c.pixel_aspect_y, c.ortho_scale, c.aperture_size, c.focus_distance,
                  c.aperture_rotation, c.aperture_ratio, c.autofocus_x, c.autofocus_y})
    if (!std::isfinite(v)) throw std::invalid_argument("camera parameters must be finite");
  if (c.type == CameraType::Orthographic && !(c.ortho_scale > 0.0f))
    throw std::invalid_argument("camera ortho_scale must be positive");
  if (c.type == CameraType::Panoramic) {
    for (float v : {c.fisheye_fov, c.fisheye_lens, c.latitude_min, c.latitude_max, c.longitude_min, c.longitude_max,
                    c.fisheye_polynomial[0], c.fisheye_polynomial[1], c.fisheye_polynomial[2], c.fisheye_polynomial[3],
                    c.fisheye_polynomial[4], c.cylinder_u_min, c.cylinder_u_max, c.cylinder_v_min, c.cylinder_v_max,
                    c.cylinder_radius, c.pano_viewplane[0], c.pano_viewplane[1], c.pano_viewplane[2],
                    c.pano_viewplane[3], c.pano_fit_aspect})
      if (!std::isfinite(v)) throw std::invalid_argument("panoramic camera parameters must be finite");
    if (!(c.fisheye_fov > 0.0f)) throw std::invalid_argument("camera fisheye_fov must be positive");
    if (!(c.fisheye_lens > 0.0f)) throw std::invalid_argument("camera fisheye_lens must be positive");
    if (!(c.cylinder_radius > 0.0f)) throw std::invalid_argument("camera central_cylindrical_radius must be positive");
    if (!(c.pano_fit_aspect >= 0.0f)) throw std::invalid_argument("camera pano_fit_aspect must be >= 0");
    if (!(c.pano_viewplane[1] != c.pano_viewplane[0]) || !(c.pano_viewplane[3] != c.pano_viewplane[2]))
      throw std::invalid_argument("camera pano_viewplane must not be empty");
  }
  if (c.stereo_eye != StereoEye::None) {
    if (!std::isfinite(c.interocular_distance) || !(c.interocular_distance >= 0.0f))
      throw std::invalid_argument("camera interocular_distance must be finite and >= 0");
    if (!(c.convergence_distance > 0.0f))  // (inf: parallel)
      throw std::invalid_argument("camera convergence_distance must be positive (inf: parallel)");
    if (!std::isfinite(c.pole_merge_angle_from) || !std::isfinite(c.pole_merge_angle_to))
      throw std::invalid_argument("camera pole merge angles must be finite");
  }
  if (!(c.aperture_size >= 0.0f)) throw std::invalid_argument("camera aperture_size must be >= 0");
  if (!(c.focus_distance > 0.0f)) throw std::invalid_argument("camera focus_distance must be positive");
  if (!(c.aperture_ratio > 0.0f)) throw std::invalid_argument("camera aperture_ratio must be positive");
  if (c.aperture_blades < 0 || c.aperture_blades > 1024)
    throw std::invalid_argument("camera aperture_blades must be in [0, 1024]");
  if (!(c.autofocus_x >= 0.0f && c.autofocus_x <= 1.0f && c.autofocus_y >= 0.0f && c.autofocus_y <= 1.0f))
    throw std::invalid_argument("camera autofocus point must be in [0, 1]");
  if (!c.matrix_world.is_finite()) throw std::invalid_argument("camera matrix must be finite");
  {
    const Mat4& m = c.matrix_world;
    const Vec3 x{m.m[0][0], m.m[1][0], m.m[2][0]}, y{m.m[0][1], m.m[1][1], m.m[2][1]};
    if (!(length_sq(cross(x, y)) > 1e-20f * length_sq(x) * length_sq(y)) || !(length_sq(x) > 0.0f))
      throw std::invalid_argument("camera matrix is singular: it has no orientation");
  }
}

// A scene shared with the sessions that render it; edits are refused while one holds it.
struct PyScene {
  std::shared_ptr<Scene> scene = std::make_shared<Scene>();
  void check_editable() const {
    if (scene.use_count() > 1) throw std::runtime_error("the scene is in use by a render session");
  }
};

// A Scene setting as def_property's getter and setter, through the core's own (writes need an
// editable scene: not one a session is rendering).
template <auto Get>
auto scene_get() {
  return [](const PyScene& self) { return (self.scene.get()->*Get)(); };
}
template <auto Set>
auto scene_flag_set() {
  return [](PyScene& self, bool on) {
    self.check_editable();
    (self.scene.get()->*Set)(on);
  };
}

// An index array read in place when it is C-contiguous int32 (what the add-on exports), so a
// million-triangle mesh is not first converted to int64; any other integer array is converted.
class IndexArray {
 public:
  IndexArray(const py::handle& h, const char* what) {
    if (py::isinstance<py::array_t<int32_t>>(h)) {
      const auto a = py::reinterpret_borrow<py::array>(h);
      if (a.flags() & py::array::c_style) {
        i32_ = py::reinterpret_borrow<py::array_t<int32_t>>(h);
        arr_ = i32_;
        is_i32_ = true;
        return;
      }
    }
    try {
      i64_ = h.cast<IntArray>();
    } catch (const py::cast_error&) {
      throw std::invalid_argument(std::string(what) + " must be an integer array");
    }
    arr_ = i64_;
  }
  int ndim() const { return int(arr_.ndim()); }
  size_t shape(int i) const { return size_t(arr_.shape(i)); }
  // fn(pointer) with a pointer to the int32 or int64 data: loops without a branch per element.
  template <class F>
  void visit(F&& fn) const {
    if (is_i32_) fn(static_cast<const int32_t*>(i32_.data()));
    else fn(static_cast<const int64_t*>(i64_.data()));
  }

 private:
  py::array arr_;
  py::array_t<int32_t> i32_;  // (a default-constructed array_t is an empty array, not null)
  IntArray i64_;
  bool is_i32_ = false;
};

// Object / Instancer attribute values of an instance or Curves object: None, or a (K, 4) float
// array with K <= kMaxObjectAttributes; NaN and inf become 0. `what` names the caller.
std::vector<Float4> to_object_attributes(const py::object& attributes, const char* what) {
  std::vector<Float4> attrs;
  if (attributes.is_none()) return attrs;
  const auto a = attributes.cast<FloatArray>();
  if (a.ndim() != 2 || a.shape(1) != 4 || a.shape(0) > py::ssize_t(kMaxObjectAttributes))
    throw std::invalid_argument(std::string(what) + " attributes must be a (K, 4) array with K <= 8");
  for (py::ssize_t k = 0; k < a.shape(0); ++k) {
    auto clean = [&](py::ssize_t c) { const float x = a.at(k, c); return std::isfinite(x) ? x : 0.0f; };
    attrs.push_back({clean(0), clean(1), clean(2), clean(3)});
  }
  return attrs;
}

// {set index: (rows, 2 or 4) float array} into per-set rows of Vec2 or Float4 (indices in
// [0, 8)); non-finite values read 0. The messages name the array for the ValueError.
template <class T>
void read_sets(const py::dict& sets, size_t rows, const char* index_error, const char* shape_error,
               std::vector<std::vector<T>>& out) {
  constexpr int W = std::is_same_v<T, Vec2> ? 2 : 4;
  auto clean = [](float x) { return std::isfinite(x) ? x : 0.0f; };
  for (const auto& item : sets) {
    const int64_t k = item.first.cast<int64_t>();
    if (k < 0 || k >= 8) throw std::invalid_argument(index_error);
    const auto a = item.second.cast<FloatArray>();
    if (a.ndim() != 2 || size_t(a.shape(0)) != rows || a.shape(1) != W) throw std::invalid_argument(shape_error);
    if (out.size() <= size_t(k)) out.resize(size_t(k) + 1);
    auto& dst = out[size_t(k)];
    dst.resize(rows);
    const float* src = a.data();
    for (size_t i = 0; i < rows; ++i, src += W) {
      if constexpr (W == 2) dst[i] = {clean(src[0]), clean(src[1])};
      else dst[i] = {clean(src[0]), clean(src[1]), clean(src[2]), clean(src[3])};
    }
  }
}

// Cryptomatte's float id of a name (its UTF-8 bytes' MurmurHash3, as Cycles).
float cryptomatte_id_of(const std::string& name) { return cryptomatte_float(murmur3_32(name.data(), name.size(), 0)); }

// An object's Cryptomatte names, (object, asset), or None (no ids).
// An object's Fast GI AO Distance: 0 (the world's) for a negative or non-finite one, as Cycles'
// RNA (min 0) never gives.
float clean_ao_distance(float d) { return std::isfinite(d) && d > 0.0f ? d : 0.0f; }

void set_cryptomatte(ObjectInfo& info, const py::object& names, const char* what) {
  if (names.is_none()) return;
  const auto n = names.cast<std::vector<std::string>>();
  if (n.size() != 2) throw std::invalid_argument(std::string(what) + " cryptomatte takes (object name, asset name)");
  info.crypto_object = cryptomatte_id_of(n[0]);
  info.crypto_asset = cryptomatte_id_of(n[1]);
}

// A light group index (RenderSettings::light_groups' numbering; -1: none).
int16_t to_light_group(int g, const char* what) {
  if (g < -1 || g >= kMaxLightGroups)
    throw std::invalid_argument(std::string(what) + " light_group takes -1 (none) or 0.." + std::to_string(kMaxLightGroups - 1));
  return int16_t(g);
}

// A curve or point set's light linking sets as a receiver and a blocker (0..63; they are no
// emitters, so no masks).
void set_link_sets(ObjectInfo& info, int light_set, int shadow_set, const char* what,
                   uint64_t light_mask = kAllLightSets, uint64_t shadow_mask = kAllLightSets) {
  if (light_set < 0 || light_set > 63 || shadow_set < 0 || shadow_set > 63)
    throw std::invalid_argument(std::string(what) + " light_set and shadow_set take 0..63");
  info.light_set = uint8_t(light_set);
  info.shadow_set = uint8_t(shadow_set);
  info.light_mask = light_mask;  // as an emitter: the sets it lights and is blocked by
  info.shadow_mask = shadow_mask;
}

// A Curves object: points (N, 3), offsets (C + 1) into them, radii (N) or None (Cycles'
// default 0.005), one material, the object's matrix. Strands with bad values are left out at
// commit (stats()["skipped_curves"]); inconsistent shapes or offsets raise ValueError.
uint32_t add_curves(PyScene& self, const FloatArray& points, const IntArray& offsets, const py::object& radii_obj,
                    uint32_t material, const py::object& matrix, const std::string& curve_type, int subdivisions,
                    const py::object& color, float pass_index, uint32_t random_id, const py::object& attributes,
                    const py::object& normals_obj, const py::dict& uvs, const py::dict& strand_attributes,
                    const std::string& shape, const py::object& materials_obj, const py::dict& point_attributes,
                    const py::dict& point_uvs, const py::object& motion, const py::object& motion_points,
                    const py::object& motion_radii, const py::object& cryptomatte, int light_set, int shadow_set,
                    const py::object& pass_motion, uint64_t light_mask, uint64_t shadow_mask,
                    const py::object& pass_points, bool shadow_catcher, bool holdout, int light_group,
                    float ao_distance, bool camera_invisible) {
  self.check_editable();
  if (points.ndim() != 2 || points.shape(1) != 3) throw std::invalid_argument("curve points must have shape (N, 3)");
  const int16_t group = to_light_group(light_group, "curves");
  if (offsets.ndim() != 1 || offsets.shape(0) < 1) throw std::invalid_argument("curve offsets must have shape (C + 1,)");
  const size_t n = size_t(points.shape(0)), nc = size_t(offsets.shape(0)) - 1;
  if (n > UINT32_MAX / 2 || nc > UINT32_MAX / 2) throw std::invalid_argument("curves are too large");
  const int64_t* po = offsets.data();
  if (po[0] != 0 || size_t(po[nc]) != n) throw std::invalid_argument("curve offsets must start at 0 and end at the number of points");
  for (size_t c = 0; c < nc; ++c)
    if (po[c + 1] < po[c]) throw std::invalid_argument("curve offsets must not decrease");
  CurveSetData cs;
  if (curve_type == "catmull_rom") cs.type = CurveType::CatmullRom;
  else if (curve_type == "poly") cs.type = CurveType::Poly;
  else throw std::invalid_argument("curve_type must be 'catmull_rom' or 'poly'");
  cs.subdivisions = std::max(1, std::min(subdivisions, 64));
  if (shape == "ribbon") cs.ribbon = true;
  else if (shape != "thick") throw std::invalid_argument("curve shape must be 'thick' or 'ribbon'");
  const Vec3* pp = reinterpret_cast<const Vec3*>(points.data());
  cs.points.assign(pp, pp + n);
  cs.offsets.resize(nc + 1);
  for (size_t c = 0; c <= nc; ++c) cs.offsets[c] = int32_t(po[c]);
  if (!radii_obj.is_none()) {
    const FloatArray radii = radii_obj.cast<FloatArray>();
    if (radii.ndim() != 1 || size_t(radii.shape(0)) != n) throw std::invalid_argument("curve radii must have shape (N,)");
    cs.radii.assign(radii.data(), radii.data() + n);
  }
  if (!normals_obj.is_none()) {
    const FloatArray nr = normals_obj.cast<FloatArray>();
    if (nr.ndim() != 2 || size_t(nr.shape(0)) != n || nr.shape(1) != 3)
      throw std::invalid_argument("curve normals must have shape (N, 3)");
    const Vec3* np_ = reinterpret_cast<const Vec3*>(nr.data());
    cs.normals.assign(np_, np_ + n);
  }
  if (!matrix.is_none()) cs.matrix = to_mat4(matrix.cast<FloatArray>(), "curves matrix");
  cs.material = material < self.scene->material_count() ? material : 0;
  if (!materials_obj.is_none()) {  // per strand (Cycles' per-curve material index)
    const IntArray mats = materials_obj.cast<IntArray>();
    if (mats.ndim() != 1 || size_t(mats.shape(0)) != nc) throw std::invalid_argument("curve materials must have shape (C,)");
    cs.strand_materials.resize(nc);
    const int64_t* pm = mats.data();
    for (size_t c = 0; c < nc; ++c)  // unknown ids: the set's material (as a bad mesh slot)
      cs.strand_materials[c] = pm[c] >= 0 && uint64_t(pm[c]) < self.scene->material_count() ? uint32_t(pm[c]) : cs.material;
  }
  if (!color.is_none()) {  // the object's, as add_instance takes them (Object Info)
    const auto c = color.cast<std::vector<float>>();
    if (c.size() != 3 && c.size() != 4) throw std::invalid_argument("curves color takes 3 or 4 values");
    auto clean = [](float x) { return std::isfinite(x) ? x : 0.0f; };
    cs.info.color = {clean(c[0]), clean(c[1]), clean(c[2]), c.size() == 4 ? clean(c[3]) : 1.0f};
  }
  cs.info.pass_index = std::isfinite(pass_index) ? pass_index : 0.0f;
  cs.info.random = object_random(random_id);
  set_cryptomatte(cs.info, cryptomatte, "curves");
  set_link_sets(cs.info, light_set, shadow_set, "curves", light_mask, shadow_mask);
  cs.attrs = to_object_attributes(attributes, "curves");
  read_sets(uvs, nc, "uv set index must be in [0, 8)", "curve uvs must have shape (C, 2)", cs.uvs);  // per strand
  read_sets(strand_attributes, nc, "attribute set index must be in [0, 8)",
            "curve strand attributes must have shape (C, 4)", cs.strand_attrs);
  read_sets(point_attributes, n, "attribute set index must be in [0, 8)",
            "curve point attributes must have shape (N, 4)", cs.point_attrs);  // linear along a strand
  read_sets(point_uvs, n, "uv set index must be in [0, 8)", "curve point uvs must have shape (N, 2)", cs.point_uvs);
  cs.motion = to_motion(motion, "curves motion");
  to_deform(motion_points, motion_radii, n, "curves", cs.deform_points, cs.deform_radii);
  cs.pass_motion = to_pass_motion(pass_motion, "curves pass_motion");
  cs.pass_points = to_pass_points(pass_points, n, "curves pass_points");
  cs.info.shadow_catcher = shadow_catcher;
  cs.info.holdout = holdout;
  cs.info.camera_invisible = camera_invisible;
  cs.info.light_group = group;
  cs.info.ao_distance = clean_ao_distance(ao_distance);
  return self.scene->add_curves(std::move(cs));
}

// A point cloud: points (N, 3), radii (N) or None (Cycles' default 0.01), one material, the
// object's matrix. Points with bad values are left out at commit (stats()["skipped_points"]);
// inconsistent shapes raise ValueError.
uint32_t add_points(PyScene& self, const FloatArray& points, const py::object& radii_obj, uint32_t material,
                    const py::object& matrix, const py::object& color, float pass_index, uint32_t random_id,
                    const py::object& attributes, const py::dict& point_attributes, const py::object& texspace,
                    const py::object& motion, const py::object& motion_points, const py::object& motion_radii,
                    const py::object& cryptomatte, int light_set, int shadow_set, const py::object& pass_motion,
                    uint64_t light_mask, uint64_t shadow_mask, const py::object& pass_points,
                    bool shadow_catcher, bool holdout, int light_group, float ao_distance,
                    bool camera_invisible) {
  self.check_editable();
  if (points.ndim() != 2 || points.shape(1) != 3) throw std::invalid_argument("points must have shape (N, 3)");
  const int16_t group = to_light_group(light_group, "points");
  const size_t n = size_t(points.shape(0));
  if (n > UINT32_MAX / 4) throw std::invalid_argument("the point cloud is too large");
  PointSetData ps;
  const Vec3* pp = reinterpret_cast<const Vec3*>(points.data());
  ps.points.assign(pp, pp + n);
  if (!radii_obj.is_none()) {
    const FloatArray radii = radii_obj.cast<FloatArray>();
    if (radii.ndim() != 1 || size_t(radii.shape(0)) != n) throw std::invalid_argument("point radii must have shape (N,)");
    ps.radii.assign(radii.data(), radii.data() + n);
  } else {
    ps.radii.assign(n, 0.01f);
  }
  if (!matrix.is_none()) ps.matrix = to_mat4(matrix.cast<FloatArray>(), "points matrix");
  ps.material = material < self.scene->material_count() ? material : 0;
  if (!color.is_none()) {  // the object's (Object Info)
    const auto c = color.cast<std::vector<float>>();
    if (c.size() != 3 && c.size() != 4) throw std::invalid_argument("points color takes 3 or 4 values");
    auto clean = [](float x) { return std::isfinite(x) ? x : 0.0f; };
    ps.info.color = {clean(c[0]), clean(c[1]), clean(c[2]), c.size() == 4 ? clean(c[3]) : 1.0f};
  }
  ps.info.pass_index = std::isfinite(pass_index) ? pass_index : 0.0f;
  ps.info.random = object_random(random_id);
  set_cryptomatte(ps.info, cryptomatte, "points");
  set_link_sets(ps.info, light_set, shadow_set, "points", light_mask, shadow_mask);
  ps.attrs = to_object_attributes(attributes, "points");
  read_sets(point_attributes, n, "attribute set index must be in [0, 8)", "point attributes must have shape (N, 4)",
            ps.point_attrs);
  if (!texspace.is_none()) {  // (location, size) of the Generated coordinates' box
    const auto ts = texspace.cast<py::tuple>();
    if (ts.size() != 2) throw std::invalid_argument("texspace must be (location, size)");
    ps.texspace_loc = to_point(ts[0], "texspace location");
    ps.texspace_size = to_point(ts[1], "texspace size");
  }
  ps.motion = to_motion(motion, "points motion");
  to_deform(motion_points, motion_radii, n, "points", ps.deform_points, ps.deform_radii);
  ps.pass_motion = to_pass_motion(pass_motion, "points pass_motion");
  ps.pass_points = to_pass_points(pass_points, n, "points pass_points");
  ps.info.shadow_catcher = shadow_catcher;
  ps.info.holdout = holdout;
  ps.info.camera_invisible = camera_invisible;
  ps.info.light_group = group;
  ps.info.ao_distance = clean_ao_distance(ao_distance);
  return self.scene->add_points(std::move(ps));
}

// add_mesh's arrays as the core's MeshData (checked; bad shapes or indices raise ValueError).
MeshData read_mesh(const FloatArray& positions, const py::object& triangles_obj, const py::object& normals,
                   const py::object& material_indices, const std::vector<int64_t>& slots, const py::dict& uvs,
                   const py::object& texspace, const py::object& shared_normals, const py::object& normal_indices,
                   const py::dict& attributes, const py::dict& tangents) {
  const IndexArray triangles(triangles_obj, "triangles");
  if (positions.ndim() != 2 || positions.shape(1) != 3) throw std::invalid_argument("positions must have shape (V, 3)");
  if (triangles.ndim() != 2 || triangles.shape(1) != 3) throw std::invalid_argument("triangles must have shape (T, 3)");
  const size_t nv = size_t(positions.shape(0)), nt = size_t(triangles.shape(0));
  if (nv > UINT32_MAX || nt > UINT32_MAX / 3) throw std::invalid_argument("mesh is too large");
  MeshData mesh;
  // Big meshes' arrays on transparent huge pages: a 1M-triangle mesh's 60 MB are otherwise
  // ~15k page faults.
  const auto huge = [](auto& v, size_t n) {
    v.reserve(n);
    advise_huge_pages(v.data(), n * sizeof(v[0]));
  };
  huge(mesh.positions, nv);
  huge(mesh.triangles, nt);
  mesh.positions.resize(nv);
  if (nv) std::memcpy(static_cast<void*>(mesh.positions.data()), positions.data(), nv * sizeof(Vec3));
  mesh.triangles.resize(nt);
  // Copies (T, 3) indices into `out`, checking each is in [0, n).
  const auto copy_indices = [](const IndexArray& idx, size_t count, size_t n, const char* what, auto& out) {
    idx.visit([&](const auto* p) {
      for (size_t i = 0; i < count; ++i)
        for (int k = 0; k < 3; ++k) {
          const int64_t v = int64_t(p[3 * i + k]);
          if (v < 0 || uint64_t(v) >= n)
            throw std::invalid_argument(std::string(what) + " index " + std::to_string(v) + " out of range for " +
                                        std::to_string(n) + (what[0] == 't' ? " vertices" : " normals"));
          out[i][k] = uint32_t(v);
        }
    });
  };
  copy_indices(triangles, nt, nv, "triangle", mesh.triangles);
  if (!normals.is_none() && !shared_normals.is_none())
    throw std::invalid_argument("give corner_normals or normals with normal_indices, not both");
  if (!normals.is_none()) {
    const auto n = normals.cast<FloatArray>();
    if (n.ndim() != 3 || size_t(n.shape(0)) != nt || n.shape(1) != 3 || n.shape(2) != 3)
      throw std::invalid_argument("corner_normals must have shape (T, 3, 3)");
    mesh.normals.resize(nt * 3);
    if (nt) std::memcpy(static_cast<void*>(mesh.normals.data()), n.data(), nt * 3 * sizeof(Vec3));
    mesh.normal_indices.resize(nt);
    for (size_t t = 0; t < nt; ++t) mesh.normal_indices[t] = {uint32_t(3 * t), uint32_t(3 * t + 1), uint32_t(3 * t + 2)};
  } else if (!shared_normals.is_none()) {
    // Corner k of triangle t gets normals[normal_indices[t, k]] (per-vertex, per-face or
    // per-corner normals). Kept shared; indices equal to the triangles' (per-vertex normals)
    // are not stored at all.
    const auto n = shared_normals.cast<FloatArray>();
    if (n.ndim() != 2 || n.shape(1) != 3) throw std::invalid_argument("normals must have shape (N, 3)");
    if (normal_indices.is_none()) throw std::invalid_argument("normals need normal_indices");
    const IndexArray ni(normal_indices, "normal_indices");
    if (ni.ndim() != 2 || ni.shape(0) != nt || ni.shape(1) != 3)
      throw std::invalid_argument("normal_indices must have shape (T, 3)");
    const size_t nn = size_t(n.shape(0));
    bool per_vertex = true;  // the indices are the triangles' own
    ni.visit([&](const auto* p) {
      const uint32_t* tri = mesh.triangles.empty() ? nullptr : mesh.triangles[0].data();
      for (size_t i = 0; i < 3 * nt && per_vertex; ++i) per_vertex = int64_t(p[i]) == int64_t(tri[i]);
    });
    if (!per_vertex || nn < nv) {  // stored (and checked against the normals' count)
      huge(mesh.normal_indices, nt);
      mesh.normal_indices.resize(nt);
      copy_indices(ni, nt, nn, "normal", mesh.normal_indices);
    }
    huge(mesh.normals, nn);
    mesh.normals.resize(nn);
    if (nn) std::memcpy(static_cast<void*>(mesh.normals.data()), n.data(), nn * sizeof(Vec3));
  } else if (!normal_indices.is_none()) {
    throw std::invalid_argument("normal_indices need normals");
  }
  std::vector<uint32_t> slot_ids;
  for (int64_t s : slots) slot_ids.push_back(s >= 0 && s <= INT32_MAX ? uint32_t(s) : 0u);
  huge(mesh.materials, nt);
  mesh.materials.assign(nt, slot_ids.empty() ? 0u : slot_ids[0]);
  if (!material_indices.is_none()) {
    const IndexArray mi(material_indices, "material_indices");
    if (mi.ndim() != 1 || mi.shape(0) != nt) throw std::invalid_argument("material_indices must have shape (T,)");
    mi.visit([&](const auto* p) {
      for (size_t i = 0; i < nt; ++i) {
        const int64_t v = int64_t(p[i]);
        mesh.materials[i] = v >= 0 && uint64_t(v) < slot_ids.size() ? slot_ids[size_t(v)] : 0u;
      }
    });
  }
  for (const auto& item : uvs) {
    const int64_t k = item.first.cast<int64_t>();
    if (k < 0 || k >= 8) throw std::invalid_argument("uv set index must be in [0, 8)");
    const auto a = item.second.cast<FloatArray>();
    if (a.ndim() != 3 || size_t(a.shape(0)) != nt || a.shape(1) != 3 || a.shape(2) != 2)
      throw std::invalid_argument("uvs must have shape (T, 3, 2)");
    if (mesh.uvs.size() <= size_t(k)) mesh.uvs.resize(size_t(k) + 1);
    auto& dst = mesh.uvs[size_t(k)];
    dst.resize(nt * 3);
    const float* src = a.data();
    for (size_t i = 0; i < nt * 3; ++i) {
      const float u = src[2 * i], v = src[2 * i + 1];
      dst[i] = {std::isfinite(u) ? u : 0.0f, std::isfinite(v) ? v : 0.0f};
    }
  }
  // Per-corner float4 sets by index (attributes; Blender's MikkTSpace tangents xyz, signs w).
  auto corner_sets = [&](const py::dict& sets, std::vector<std::vector<Float4>>& out, const char* what) {
    for (const auto& item : sets) {
      const int64_t k = item.first.cast<int64_t>();
      if (k < 0 || k >= 8) throw std::invalid_argument(std::string(what) + " set index must be in [0, 8)");
      const auto a = item.second.cast<FloatArray>();
      if (a.ndim() != 3 || size_t(a.shape(0)) != nt || a.shape(1) != 3 || a.shape(2) != 4)
        throw std::invalid_argument(std::string(what) + "s must have shape (T, 3, 4)");
      if (out.size() <= size_t(k)) out.resize(size_t(k) + 1);
      auto& dst = out[size_t(k)];
      huge(dst, nt * 3);
      dst.resize(nt * 3);
      const float* src = a.data();
      auto clean = [](float x) { return std::isfinite(x) ? x : 0.0f; };
      for (size_t i = 0; i < nt * 3; ++i)
        dst[i] = {clean(src[4 * i]), clean(src[4 * i + 1]), clean(src[4 * i + 2]), clean(src[4 * i + 3])};
    }
  };
  corner_sets(attributes, mesh.attributes, "attribute");
  corner_sets(tangents, mesh.tangents, "tangent");
  if (!texspace.is_none()) {  // (location, size) of Blender's texture space
    const auto ts = texspace.cast<py::tuple>();
    if (ts.size() != 2) throw std::invalid_argument("texspace must be (location, size)");
    mesh.texspace_location = to_point(ts[0], "texspace location");
    mesh.texspace_size = to_point(ts[1], "texspace size");
    mesh.has_texspace = true;
  }
  return mesh;
}

uint32_t add_mesh(PyScene& self, const FloatArray& positions, const py::object& triangles_obj, const py::object& normals,
                  const py::object& material_indices, const std::vector<int64_t>& slots, const py::dict& uvs,
                  const py::object& texspace, const py::object& shared_normals, const py::object& normal_indices,
                  const py::dict& attributes, const py::dict& tangents, const py::object& undisplaced) {
  self.check_editable();
  MeshData mesh = read_mesh(positions, triangles_obj, normals, material_indices, slots, uvs, texspace,
                            shared_normals, normal_indices, attributes, tangents);
  if (!undisplaced.is_none()) {  // the positions before true displacement (displace_mesh)
    const auto u = undisplaced.cast<FloatArray>();
    if (u.ndim() != 2 || size_t(u.shape(0)) != mesh.positions.size() || u.shape(1) != 3)
      throw std::invalid_argument("undisplaced must have shape (V, 3)");
    const Vec3* p = reinterpret_cast<const Vec3*>(u.data());
    mesh.undisplaced.assign(p, p + mesh.positions.size());
    for (Vec3& v : mesh.undisplaced)
      if (!is_finite(v)) v = Vec3(0.0f);
  }
  return self.scene->add_mesh(std::move(mesh));
}

// True displacement of add_mesh's arrays by their materials' displacement programs, shaded as
// `matrix` places the mesh (scene/displace.h): a dict of the displaced positions, the shading
// normals with their indices, motion_positions (given deformation steps, each moved as the
// frame's vertex), and the counts displaced / clamped; None where no material displaces.
py::object displace_mesh_arrays(PyScene& self, const FloatArray& positions, const py::object& triangles_obj,
                                const py::object& material_indices, const std::vector<int64_t>& slots,
                                const py::object& matrix, const py::object& shared_normals,
                                const py::object& normal_indices, const py::object& flat_obj, const py::dict& uvs,
                                const py::dict& attributes, const py::dict& tangents, const py::object& texspace,
                                const py::object& motion_positions) {
  MeshData mesh = read_mesh(positions, triangles_obj, py::none(), material_indices, slots, uvs, texspace,
                            shared_normals, normal_indices, attributes, tangents);
  const size_t nv = mesh.positions.size(), nt = mesh.triangles.size();
  // (read_mesh leaves per-vertex indices out: displace_mesh reads the triangles then)
  const Mat4 m = matrix.is_none() ? Mat4{} : to_mat4(matrix.cast<FloatArray>(), "displace_mesh matrix");
  std::vector<uint8_t> flat;
  if (!flat_obj.is_none()) {
    const auto f = flat_obj.cast<py::array_t<bool, py::array::c_style | py::array::forcecast>>();
    if (f.ndim() != 1 || size_t(f.shape(0)) != nt) throw std::invalid_argument("flat must have shape (T,)");
    flat.assign(f.data(), f.data() + nt);
  }
  if (!motion_positions.is_none()) {
    const auto mp = motion_positions.cast<FloatArray>();
    if (mp.ndim() != 3 || size_t(mp.shape(1)) != nv || mp.shape(2) != 3)
      throw std::invalid_argument("motion_positions must have shape (S, V, 3)");
    for (py::ssize_t s = 0; s < mp.shape(0); ++s) {
      const Vec3* p = reinterpret_cast<const Vec3*>(mp.data() + size_t(s) * nv * 3);
      mesh.motion_positions.emplace_back(p, p + nv);
    }
  }
  DisplaceStats st;
  {
    py::gil_scoped_release release;
    st = displace_mesh(mesh, *self.scene, m, flat);
  }
  if (!st.displaced) return py::none();
  py::array_t<float> pos({py::ssize_t(nv), py::ssize_t(3)});
  if (nv) std::memcpy(pos.mutable_data(), mesh.positions.data(), nv * sizeof(Vec3));
  py::dict d;
  d["positions"] = pos;
  if (!mesh.normals.empty()) {
    const size_t nn = mesh.normals.size();
    py::array_t<float> nr({py::ssize_t(nn), py::ssize_t(3)});
    std::memcpy(nr.mutable_data(), mesh.normals.data(), nn * sizeof(Vec3));
    py::array_t<int32_t> ni({py::ssize_t(nt), py::ssize_t(3)});
    int32_t* q = ni.mutable_data();
    for (size_t t = 0; t < nt; ++t)
      for (int k = 0; k < 3; ++k)
        q[3 * t + size_t(k)] = int32_t(mesh.normal_indices.empty() ? mesh.triangles[t][size_t(k)] : mesh.normal_indices[t][size_t(k)]);
    d["normals"] = nr;
    d["normal_indices"] = ni;
  }
  if (!mesh.motion_positions.empty()) {
    const size_t ns = mesh.motion_positions.size();
    py::array_t<float> mp({py::ssize_t(ns), py::ssize_t(nv), py::ssize_t(3)});
    for (size_t s = 0; s < ns; ++s)
      if (nv) std::memcpy(mp.mutable_data() + s * nv * 3, mesh.motion_positions[s].data(), nv * sizeof(Vec3));
    d["motion_positions"] = mp;
  }
  d["displaced"] = st.displaced;
  d["clamped"] = st.clamped;
  return d;
}

// What the op parsers share: a register operand (None: no register), validated.
// The volume closure's phase lobe keys, in VolumeLobeType's order.
const std::string kVolumeLobeNames[] = {"hg", "draine", "ff", "rayleigh", "mie"};

int16_t op_register(const py::handle& h) {
  if (h.is_none()) return kNoReg;
  const int64_t r = h.cast<int64_t>();
  if (r < 0 || r >= kMaxRegs) throw std::invalid_argument("register out of range: " + std::to_string(r));
  return int16_t(r);
}
// Throws unless op tuple `t` holds its name and n - 1 arguments.
void op_arity(const std::string& op, const py::tuple& t, size_t n) {
  if (t.size() != n) throw std::invalid_argument("shader op '" + op + "' takes " + std::to_string(n - 1) + " arguments");
}

// The value op named `op` in the core's table (scene/shader_ops.h); nullptr: none.
const ValueOpSchema* find_value_op(const std::string& op) {
  for (const ValueOpSchema& s : kValueOps)
    if (op == s.name) return &s;
  return nullptr;
}

// "A, B or C": the names a Choice parameter takes, for its error message.
std::string name_list(const OpParam& p, bool alt) {
  std::string out;
  const size_t n = alt ? p.n_alt : p.n_names;
  for (size_t i = 0; i < n; ++i)
    out += std::string(i == 0 ? "" : i + 1 == n ? " or " : ", ") + (alt ? p.alt_names[i] : p.name(i));
  return out;
}

// Parses value op tuple `t` by its schema: arity, registers, then each parameter by its kind
// into its field, and the program flags it sets. `n_images`: the scene's image count.
void parse_value_op(const ValueOpSchema& s, const py::tuple& t, ShaderOp& o, ShaderProgram& prog, int64_t n_images) {
  const std::string op = s.name;
  size_t required = 2 + size_t(s.registers);
  const size_t total = required + s.params.n;
  for (const OpParam& p : s.params) required += p.optional ? 0 : 1;
  if (t.size() < required || t.size() > total) {
    const std::string more =
        total == required ? "" : (total == required + 1 ? " or " : " to ") + std::to_string(total - 1);
    const std::string counts = std::to_string(required - 1) + more;
    throw std::invalid_argument("shader op '" + op + "' takes " + counts + " arguments");
  }
  auto fail = [&](const std::string& why) { throw std::invalid_argument("shader op '" + op + "': " + why); };
  o.code = s.code;
  o.ext = s.ext;
  for (size_t k = 0; k < s.registers; ++k) o.in[k] = op_register(t[2 + k]);
  uint8_t flags = s.flags;
  size_t at = 2 + size_t(s.registers);
  for (const OpParam& p : s.params) {
    if (at >= t.size()) break;  // optional parameters left off (the arity says which may be)
    const py::handle h = t[at++];
    int64_t v = 0;  // the value an integer field takes
    switch (p.kind) {
      case ParamKind::Choice: {
        const bool alt = p.alt_names && o.sub != 0;  // the parameters before it are parsed
        const size_t n = alt ? p.n_alt : p.n_names;
        const std::string x = h.cast<std::string>();
        size_t i = 0;
        while (i < n && x != (alt ? p.alt_names[i] : p.name(i))) ++i;
        if (i == n)
          fail(std::string("unknown ") + (alt ? p.alt_what : p.what) + " '" + x + "' (" + name_list(p, alt) + ")");
        v = int64_t(i) + p.offset;
        break;
      }
      case ParamKind::Int:
        v = h.cast<int64_t>();
        if (v < p.lo || v > p.hi)
          fail(std::string(p.what) + " must be in [" + std::to_string(p.lo) + ", " + std::to_string(p.hi) + "], not " +
               std::to_string(v));
        break;
      case ParamKind::Bool:
        v = h.cast<bool>() ? p.bit : 0;
        break;
      case ParamKind::Float: {
        const float x = h.cast<float>();
        if (!std::isfinite(x)) fail(std::string(p.what) + " must be finite");
        (p.field == OpField::M1 ? o.m[1] : o.m[0]) = x;
        continue;
      }
      case ParamKind::ImageId:
        v = h.cast<int64_t>();
        if (v < 0 || v >= n_images) fail("unknown image id " + std::to_string(v));
        break;
      case ParamKind::Values: {
        const auto x = h.cast<std::vector<float>>();
        if (x.empty() || x.size() > 4) fail("const takes 1 to 4 values");
        float f[4] = {x[0], x.size() > 1 ? x[1] : x[0], x.size() > 2 ? x[2] : x[0], x.size() > 3 ? x[3] : 1.0f};
        for (float& c : f) c = std::isfinite(c) ? c : 0.0f;  // NaN node values become 0
        o.value = {f[0], f[1], f[2], f[3]};
        continue;
      }
      case ParamKind::Matrix3x4: {
        const auto m = h.cast<FloatArray>();
        if (m.ndim() != 2 || m.shape(0) != 3 || m.shape(1) != 4) fail("mapping matrix must be 3x4");
        for (int i = 0; i < 12; ++i) {
          o.m[i] = m.data()[i];
          if (!std::isfinite(o.m[i])) fail("mapping matrix contains NaN or infinite values");
        }
        continue;
      }
      case ParamKind::RampTable: {
        const auto table = h.cast<FloatArray>();
        if (table.ndim() != 2 || table.shape(1) != 4 || table.shape(0) < 2 || table.shape(0) > 4096)
          fail("ramp table must have shape (N, 4) with 2 <= N <= 4096");
        o.index = int32_t(prog.tables.size());
        o.count = int32_t(table.shape(0));
        const float* src = table.data();
        auto clean = [](float x) { return std::isfinite(x) ? x : 0.0f; };
        for (int i = 0; i < o.count; ++i)
          prog.tables.push_back({clean(src[4 * i]), clean(src[4 * i + 1]), clean(src[4 * i + 2]), clean(src[4 * i + 3])});
        continue;
      }
      case ParamKind::Ies: {
        if (!py::isinstance<IesProfile>(h)) fail("ies profile must be an IesProfile");
        prog.ies.push_back(h.cast<std::shared_ptr<IesProfile>>());
        o.index = int32_t(prog.ies.size() - 1);
        continue;
      }
      case ParamKind::Sky: {
        if (!py::isinstance<SkyModel>(h)) fail("sky must be a SkyTexture");
        prog.skies.push_back(h.cast<std::shared_ptr<SkyModel>>());
        o.index = int32_t(prog.skies.size() - 1);
        continue;
      }
      case ParamKind::FilterWidth: {
        const float fw = h.cast<float>();
        if (!(fw >= 0.0f) || !std::isfinite(fw)) fail("bump filter width must be >= 0");
        if (prog.bump_filter_width <= 0.0f) prog.bump_filter_width = fw;  // the program's first
        continue;
      }
    }
    if (p.when >= 0 && v == p.when) flags |= p.when_flags;
    // Integer fields; Bool parameters OR their bit in (several may share a field).
    switch (p.field) {
      case OpField::Sub: o.sub = uint8_t(o.sub | v); break;
      case OpField::Ext: o.ext = uint8_t(o.ext | v); break;
      case OpField::Index: o.index = int32_t(o.index | v); break;
      case OpField::Count: o.count = int32_t(o.count | v); break;
      case OpField::Clamp: o.clamp = o.clamp || v != 0; break;
      default: break;  // no other field takes an integer (shader_ops.h checks the schema)
    }
  }
  if (flags & kVarying) prog.varying = prog.reads_point = true;
  if (flags & kUsesUv) prog.uses_uv = true;
  if (flags & kUsesAttributes) prog.uses_attributes = true;
  if (flags & kSetsNormal) prog.sets_normal = true;
}

// Parses a shader program (see docs/core_api.md) into core ops, validating every register.
// `n_images`: the scene's image count, which Image Texture ops must stay below.
ShaderProgram parse_program(const py::list& program, int64_t n_images) {
  ShaderProgram prog;
  const auto regno = op_register;
  auto name_of = [](const py::handle& h) { return h.cast<std::string>(); };
  for (const auto& item : program) {
    const auto t = item.cast<py::tuple>();
    if (t.size() < 2) throw std::invalid_argument("shader op must be a tuple (name, ...)");
    const std::string op = name_of(t[0]);
    ShaderOp o;
    auto need = [&](size_t n) { op_arity(op, t, n); };
    if (op == "closure") {
      need(4);
      const std::string kind = name_of(t[1]);
      o.in[0] = regno(t[2]);
      const auto params = t[3].cast<py::dict>();
      auto p = [&](const char* key) { return params.contains(key) ? regno(params[key]) : kNoReg; };
      // The microfacet lobes' distribution (o.sub, a Microfacet): GGX unless a flag key says
      // "beckmann" or, for the Glossy BSDF only, "ashikhmin_shirley".
      auto distribution = [&](bool ashikhmin_shirley) {
        if (p("ashikhmin_shirley") != kNoReg) {
          if (!ashikhmin_shirley) throw std::invalid_argument("closure '" + kind + "' has no Ashikhmin-Shirley distribution");
          return uint8_t(Microfacet::AshikhminShirley);
        }
        return uint8_t(p("beckmann") != kNoReg ? Microfacet::Beckmann : Microfacet::Ggx);
      };
      if (kind == "diffuse") {
        o.code = OpCode::Diffuse;
        o.in[1] = p("color"); o.in[2] = p("normal"); o.in[3] = p("roughness");
        if (o.in[3] != kNoReg) prog.varying = true;  // Oren-Nayar's terms depend on the view
      } else if (kind == "toon") {
        o.code = OpCode::Toon;
        o.in[1] = p("color"); o.in[2] = p("size"); o.in[3] = p("smooth"); o.in[4] = p("normal");
        if (p("glossy") != kNoReg) {
          o.sub = 1;  // about the view's mirror direction
          prog.varying = true;
        }
      } else if (kind == "sheen") {
        o.code = OpCode::Sheen;
        o.in[1] = p("color"); o.in[2] = p("roughness"); o.in[3] = p("normal");
        if (p("velvet") != kNoReg) o.sub = 1;  // Ashikhmin velvet (else microfibre)
        prog.varying = true;  // the microfibre fit depends on the view
      } else if (kind == "glossy") {
        o.code = OpCode::Glossy;
        o.in[1] = p("color"); o.in[2] = p("roughness"); o.in[3] = p("normal"); o.in[4] = p("multiscatter");
        o.in[5] = p("anisotropy"); o.in[6] = p("rotation"); o.in[7] = p("tangent");
        o.sub = distribution(true);
      } else if (kind == "glass" || kind == "refraction") {
        o.code = kind == "glass" ? OpCode::Glass : OpCode::Refraction;
        o.in[1] = p("color"); o.in[2] = p("roughness"); o.in[3] = p("ior"); o.in[4] = p("normal");
        o.in[5] = p("multiscatter");
        o.sub = distribution(false);
      } else if (kind == "transparent") {
        o.code = OpCode::Transparent;
        o.in[1] = p("color");
      } else if (kind == "ray_portal") {
        o.code = OpCode::RayPortal;
        o.in[1] = p("color"); o.in[2] = p("position"); o.in[3] = p("direction");
        prog.varying = true;  // its defaults are the shading point and the view
      } else if (kind == "metallic") {
        o.code = OpCode::Metallic;
        o.in[1] = p("base_color"); o.in[2] = p("edge_tint"); o.in[3] = p("ior"); o.in[4] = p("extinction");
        o.in[5] = p("roughness"); o.in[6] = p("normal"); o.in[7] = p("multiscatter"); o.in[8] = p("physical");
        o.in[9] = p("anisotropy"); o.in[10] = p("rotation"); o.in[11] = p("tangent");
        o.sub = distribution(false);
      } else if (kind == "translucent") {
        o.code = OpCode::Translucent;
        o.in[1] = p("color"); o.in[2] = p("normal");
      } else if (kind == "principled_hair_absorption" || kind == "principled_hair_melanin" ||
                 kind == "principled_hair_color" || kind == "principled_hair_huang_absorption" ||
                 kind == "principled_hair_huang_melanin" || kind == "principled_hair_huang_color") {
        const bool huang = kind.rfind("principled_hair_huang_", 0) == 0;
        const std::string mode = kind.substr(huang ? 22 : 16);
        o.code = OpCode::PrincipledHair;
        o.ext = huang ? 1 : 0;
        o.in[1] = p("color"); o.in[2] = p("melanin"); o.in[3] = p("melanin_redness"); o.in[4] = p("tint");
        o.in[5] = p("absorption"); o.in[6] = p("roughness");
        o.in[7] = huang ? p("trt") : p("radial_roughness");
        o.in[8] = huang ? p("aspect_ratio") : p("coat");
        o.in[9] = p("ior"); o.in[10] = p("offset"); o.in[11] = p("random_color"); o.in[12] = p("random_roughness");
        o.in[13] = p("random");
        if (huang) {
          o.in[14] = p("r");
          o.in[15] = p("tt");
        }
        o.sub = mode == "absorption" ? 0 : mode == "melanin" ? 1 : 2;
      } else if (kind == "hair_reflection" || kind == "hair_transmission") {
        o.code = OpCode::Hair;
        o.in[1] = p("color"); o.in[2] = p("offset"); o.in[3] = p("roughness_u"); o.in[4] = p("roughness_v");
        o.in[5] = p("tangent");
        o.sub = kind == "hair_transmission" ? 1 : 0;
        prog.varying = true;  // its frame follows the fibre and the view
      } else if (kind == "subsurface") {  // the method: a register of SubsurfaceMethod's number
        o.code = OpCode::Subsurface;
        o.in[1] = p("color"); o.in[2] = p("scale"); o.in[3] = p("radius"); o.in[4] = p("ior");
        o.in[5] = p("roughness"); o.in[6] = p("anisotropy"); o.in[7] = p("normal"); o.in[8] = p("method");
      } else if (kind == "volume") {  // a volume program's output (its last op)
        o.code = OpCode::VolumeOut;
        o.in[0] = p("sigma_a"); o.in[1] = p("sigma_s"); o.in[2] = p("emission"); o.in[3] = p("g");
        // Phase lobes: "ss<k>" the lobe's scattering, "<type><k>" its parameters' register.
        for (int k = 0; k < kMaxVolumeLobeInputs; ++k) {
          const std::string ks = std::to_string(k);
          if (!params.contains("ss" + ks)) break;
          int type = -1;
          for (int t = 0; t < int(std::size(kVolumeLobeNames)); ++t)
            if (params.contains(kVolumeLobeNames[t] + ks)) type = t;
          if (type < 0)
            throw std::invalid_argument("volume lobe " + ks + " has no phase (hg, draine, ff, rayleigh, mie)");
          o.in[4 + 2 * k] = p(("ss" + ks).c_str());
          o.in[5 + 2 * k] = p((kVolumeLobeNames[type] + ks).c_str());
          o.index |= int32_t(type) << (4 * k);
          o.count = k + 1;
        }
      } else if (kind == "displacement") {  // a displacement program's output (its last op)
        o.code = OpCode::DisplaceOut;
        o.in[0] = p("offset");
      } else if (kind == "holdout") {
        o.code = OpCode::Holdout;
      } else if (kind == "emission") {
        o.code = OpCode::Emission;
        o.in[1] = p("color");
      } else if (kind == "principled") {
        o.code = OpCode::Principled;
        o.in[1] = p("base_color"); o.in[2] = p("metallic"); o.in[3] = p("roughness"); o.in[4] = p("ior");
        o.in[5] = p("transmission"); o.in[6] = p("specular_level"); o.in[7] = p("specular_tint");
        o.in[8] = p("normal"); o.in[9] = p("multiscatter");
        o.in[10] = p("coat_weight"); o.in[11] = p("coat_roughness"); o.in[12] = p("coat_ior");
        o.in[13] = p("coat_tint"); o.in[14] = p("coat_normal");
        // The inputs beyond sixteen operands travel in a PrincipledExtra op just before it.
        static const std::pair<const char*, PrincipledExtraSlot> extra_keys[] = {
            {"anisotropic", kPxAnisotropic}, {"anisotropic_rotation", kPxAnisotropicRotation},
            {"tangent", kPxTangent}, {"thin_film_thickness", kPxThinFilmThickness},
            {"thin_film_ior", kPxThinFilmIor}, {"sheen_weight", kPxSheenWeight},
            {"sheen_roughness", kPxSheenRoughness}, {"sheen_tint", kPxSheenTint},
            {"diffuse_roughness", kPxDiffuseRoughness}, {"subsurface_weight", kPxSubsurfaceWeight},
            {"subsurface_radius", kPxSubsurfaceRadius}, {"subsurface_scale", kPxSubsurfaceScale},
            {"subsurface_ior", kPxSubsurfaceIor}, {"subsurface_anisotropy", kPxSubsurfaceAnisotropy},
            {"subsurface_method", kPxSubsurfaceMethod}, {"emission", kPxEmission}};
        ShaderOp x;
        x.code = OpCode::PrincipledExtra;
        bool any = false;
        for (const auto& [key, slot] : extra_keys) {
          x.in[slot] = p(key);
          any = any || x.in[slot] != kNoReg;
        }
        if (any) prog.ops.push_back(x);
      } else {
        throw std::invalid_argument("unknown closure '" + kind + "'");
      }
      for (const auto& kv : params) regno(kv.second);  // validates every register, also of unknown keys
      if (p("normal") != kNoReg || p("coat_normal") != kNoReg || p("tangent") != kNoReg) prog.varying = true;
      if (p("multiscatter") != kNoReg) prog.varying = true;  // its compensation depends on the view
      if (o.code == OpCode::Principled) prog.varying = true;  // its layering depends on the view
      if (o.code == OpCode::Subsurface) prog.varying = true;  // diffuse after a diffuse bounce (the path)
      prog.ops.push_back(o);
      continue;
    }
    // Value ops: the core's op table (scene/shader_ops.h) says how each is parsed.
    const ValueOpSchema* schema = find_value_op(op);
    if (!schema) throw std::invalid_argument("unknown shader op '" + op + "'");
    o.dst = regno(t[1]);
    if (o.dst == kNoReg) throw std::invalid_argument("shader op '" + op + "' needs a destination register");
    if (op == "normal_map") {  // color, strength, uv set [, space]
      // Parsed by hand, not from the schema (its entry holds its registers only): the uv set
      // it reads only in tangent space.
      if (t.size() != 5 && t.size() != 6) throw std::invalid_argument("shader op 'normal_map' takes 4 or 5 arguments");
      o.code = OpCode::NormalMap;
      o.in[0] = regno(t[2]);
      o.in[1] = regno(t[3]);
      o.index = t[4].cast<int32_t>();
      if (o.index < 0 || o.index >= 8) throw std::invalid_argument("uv set index must be in [0, 8)");
      if (t.size() == 6) {
        static const char* const spaces[] = {"TANGENT", "OBJECT", "WORLD", "BLENDER_OBJECT", "BLENDER_WORLD"};
        const std::string x = name_of(t[5]);
        const auto it = std::find_if(std::begin(spaces), std::end(spaces), [&](const char* n) { return x == n; });
        if (it == std::end(spaces)) throw std::invalid_argument("shader op 'normal_map': unknown normal map space '" + x + "'");
        o.sub = uint8_t(it - std::begin(spaces));
      }
      prog.uses_uv = prog.uses_uv || o.sub == 0;
      prog.varying = prog.reads_point = true;
    } else {
      parse_value_op(*schema, t, o, prog, n_images);
    }
    prog.ops.push_back(o);
  }
  return prog;
}

Material make_shader(const PyScene& self, const std::string& name, const py::list& program,
                     const py::object& volume_absorption, bool use_schlick, const py::object& volume = py::none(),
                     const py::object& displacement = py::none(), const std::string& displacement_method = "DISPLACEMENT") {
  Material mat;
  mat.name = name;
  mat.program = parse_program(program, int64_t(self.scene->image_count()));
  mat.program.schlick = use_schlick;
  if (!displacement.is_none()) {
    // True displacement: value ops, then ('closure', 'displacement', None, {'offset': r}).
    auto disp = std::make_shared<ShaderProgram>(parse_program(displacement.cast<py::list>(), int64_t(self.scene->image_count())));
    if (disp->ops.empty() || disp->ops.back().code != OpCode::DisplaceOut)
      throw std::invalid_argument("a displacement program must end with a ('closure', 'displacement', None, {'offset': r}) op");
    for (size_t i = 0; i + 1 < disp->ops.size(); ++i)
      if (disp->ops[i].code == OpCode::DisplaceOut || is_closure_op(disp->ops[i].code) ||
          disp->ops[i].code == OpCode::VolumeOut || disp->ops[i].code == OpCode::SetNormal)
        throw std::invalid_argument("a displacement program has value ops and one closure 'displacement', last");
    if (displacement_method != "DISPLACEMENT" && displacement_method != "BOTH")
      throw std::invalid_argument("displacement_method must be 'DISPLACEMENT' or 'BOTH'");
    mat.displacement_normals = displacement_method == "DISPLACEMENT";
    mat.displacement = std::move(disp);
  }
  if (!volume_absorption.is_none()) {
    const auto t = volume_absorption.cast<py::tuple>();
    if (t.size() != 2) throw std::invalid_argument("volume_absorption must be (color, density)");
    const Vec3 color = vmin(to_color(t[0], "absorption color"), Vec3(1.0f));
    float density = t[1].cast<float>();
    density = std::isfinite(density) && density > 0.0f ? density : 0.0f;
    mat.program.sigma_a = (Vec3(1.0f) - color) * density;
  }
  if (py::isinstance<py::list>(volume)) {
    // A heterogeneous medium: a program of value ops ending in a "volume" closure (its
    // coefficients at a point, docs/core_api.md).
    auto vol = std::make_shared<ShaderProgram>(parse_program(volume.cast<py::list>(), int64_t(self.scene->image_count())));
    if (vol->ops.empty() || vol->ops.back().code != OpCode::VolumeOut)
      throw std::invalid_argument("a volume program must end with a ('closure', 'volume', None, {...}) op");
    for (size_t i = 0; i + 1 < vol->ops.size(); ++i)
      if (vol->ops[i].code == OpCode::VolumeOut ||
          std::any_of(std::begin(kClosureOpCodes), std::end(kClosureOpCodes),
                      [&](OpCode c) { return c == vol->ops[i].code; }))
        throw std::invalid_argument("a volume program has value ops and one closure 'volume', last");
    mat.program.volume = std::move(vol);
  } else if (!volume.is_none()) {
    // The homogeneous medium inside: coefficients per unit length (NaN or negative: 0, as the
    // colours of to_color), anisotropy clamped into (-1, 1).
    const auto d = volume.cast<py::dict>();
    for (const auto& kv : d) {
      const std::string k = kv.first.cast<std::string>();
      if (k == "sigma_a") mat.program.sigma_a = to_color(kv.second, "volume sigma_a");
      else if (k == "sigma_s") mat.program.sigma_s = to_color(kv.second, "volume sigma_s");
      else if (k == "emission") mat.program.volume_emission = to_color(kv.second, "volume emission");
      else if (k == "g") mat.program.phase = make_hg_phase(kv.second.cast<float>());
      else if (k == "phases") {
        // [(type, sigma_s rgb, params), ...]: the medium's phase functions and the scattering
        // of each; they replace sigma_s and g.
        PhaseLobe lobes[kMaxPhaseLobes];
        int n = 0;
        for (const auto& item : kv.second.cast<py::list>()) {
          const auto t = item.cast<py::tuple>();
          if (t.size() != 3) throw std::invalid_argument("a volume phase is (type, sigma_s, params)");
          const std::string type = t[0].cast<std::string>();
          const auto* at = std::find(std::begin(kVolumeLobeNames), std::end(kVolumeLobeNames), type);
          if (at == std::end(kVolumeLobeNames))
            throw std::invalid_argument("unknown volume phase '" + type + "' (hg, draine, ff, rayleigh, mie)");
          const auto prm = t[2].cast<std::vector<float>>();
          Float4 f;
          if (prm.size() > 0) f.x = prm[0];
          if (prm.size() > 1) f.y = prm[1];
          add_phase_lobes(VolumeLobeType(at - std::begin(kVolumeLobeNames)), f, to_color(t[1], "volume phase sigma_s"),
                          lobes, n);
        }
        mat.program.sigma_s = Vec3(0.0f);
        for (int i = 0; i < n; ++i) mat.program.sigma_s += lobes[i].sigma_s;
        mat.program.phase = n ? lobes[0].phase : Phase{};
        mat.program.phase_lobes.assign(lobes, lobes + (n >= 2 ? n : 0));
      } else throw std::invalid_argument("unknown volume key '" + k + "' (sigma_a, sigma_s, g, phases, emission)");
    }
  }
  return mat;
}

// A light's node tree (None: none): a program of value ops and an emission closure, in the
// light's frame m (4x4 world matrix). A constant one multiplies the colour once; else the light
// evaluates it per sample (light_shader.h), its power estimate scaled by `power` (the add-on's
// Cycles-style estimate of the tree's emission).
void set_light_shader(const PyScene& self, Light& l, const py::object& shader, const Mat4& m, float power,
                      float spot_size = 0.0f) {
  if (shader.is_none()) return;
  Material mat = make_shader(self, "light", shader.cast<py::list>(), py::none(), false, py::none(), py::none(),
                             "DISPLACEMENT");
  if (!mat.program.varying) {
    ShadingContext ctx;
    ctx.ng = ctx.ns = ctx.wo = {0.0f, 0.0f, 1.0f};
    ClosureList out;
    eval_shader(mat.program, self.scene->images(), ctx, out);
    l.color = l.color * (is_finite(out.emission) ? out.emission : Vec3(0.0f));
    return;
  }
  auto sh = std::make_shared<LightShader>();
  sh->program = std::move(mat.program);
  sh->object = make_object_coords(m, Vec3(0.0f), Vec3(2.0f));
  sh->object.gen_scale = Vec3(1.0f);  // lamps have no texture space: Generated reads object coordinates
  sh->object.gen_offset = Vec3(0.0f);
  sh->to_local = inverse3x3(m, "light matrix");
  const float half = 0.5f * clampf(spot_size, 1e-6f, kPi - 1e-6f);
  sh->half_cot_half_spot = 0.5f / std::tan(half);
  l.shader = std::move(sh);
  l.shader_power = std::isfinite(power) && power > 0.0f ? power : 1.0f;
}

// The committed heterogeneous medium of (instance, material), or the world's (instance -1).
const HeteroMedium* committed_medium(const PyScene& self, int64_t instance, int64_t material) {
  if (!self.scene->committed()) return nullptr;
  if (instance < 0) return self.scene->world_hetero();
  if (instance > int64_t(UINT32_MAX) || material < 0 || material > int64_t(UINT32_MAX)) return nullptr;
  return self.scene->hetero_medium(uint32_t(instance), uint32_t(material));
}

py::dict scene_stats(const PyScene& self) {
  const SceneStats& s = self.scene->stats();
  const BvhStats& b = self.scene->bvh().stats();
  py::dict d;
  d["triangles"] = s.triangles;
  d["instances"] = s.instances;
  d["meshes"] = s.meshes;
  d["materials"] = s.materials;
  d["emissive_triangles"] = s.emissive_triangles;
  d["dropped_triangles"] = s.dropped_triangles;
  d["lights"] = s.lights;
  if (self.scene->world_hetero()) d["world_volume_open"] = self.scene->world_volume_open();
  d["rect_emitters"] = s.rect_emitters;
  d["light_tree_nodes"] = s.light_tree_nodes;
  d["light_tree_depth"] = s.light_tree_depth;
  d["geometry_builds"] = s.geometry_builds;
  d["light_builds"] = s.light_builds;
  d["top_level_builds"] = s.top_level_builds;
  d["blases"] = s.blases;
  d["blas_triangles"] = s.blas_triangles;
  d["blas_references"] = s.blas_references;
  d["tlas_instances"] = s.tlas_instances;
  d["real_instances"] = s.real_instances;
  d["curves"] = s.curves;
  d["curve_pieces"] = s.curve_pieces;
  d["skipped_curves"] = s.skipped_curves;
  d["points"] = s.points;
  d["skipped_points"] = s.skipped_points;
  d["motion_instances"] = s.motion_instances;
  d["motion_rejected"] = s.motion_rejected;
  d["deforming_instances"] = s.deforming_instances;
  d["dynamic"] = self.scene->dynamic();
  d["geometry_bytes"] = s.geometry_bytes;
  d["bvh_nodes"] = b.nodes;
  d["bvh_leaves"] = b.leaves;
  d["bvh_max_depth"] = b.max_depth;
  d["bvh_sah_cost"] = b.sah_cost;
  d["bvh_build_ms"] = b.build_ms;
  d["bvh_bytes"] = s.bvh_bytes;  // every BLAS and the top level
  d["bvh_layout"] = enum_name(b.layout, kBvhLayoutNames);
  d["bvh_wide_nodes"] = b.wide_nodes;
  d["spatial_splits"] = self.scene->spatial_splits();  // the setting (applies from the next commit)
  d["bvh_triangles"] = b.triangles;                    // of the largest BLAS, as the other bvh_ entries
  d["bvh_references"] = b.references;
  d["bvh_spatial_splits"] = b.spatial_splits;
  d["bvh_compact"] = b.compact;  // the largest BLAS's wide nodes are compressed
  d["bvh_clusters"] = b.clusters;  // Morton runs of the clustered build (0: full SAH)
  d["features"] = self.scene->features().names();  // of the last commit
  return d;
}

py::dict wide_bvh_nodes(const PyScene& self) {
  const Bvh& bvh = self.scene->bvh();
  const int w = bvh.wide_width();
  const std::vector<Bvh::WideLane> lanes = bvh.wide_lanes();
  const size_t m = w ? lanes.size() / size_t(w) : 0;
  py::array_t<float> box({m, size_t(w), size_t(6)});
  py::array_t<uint32_t> child({m, size_t(w)}), count({m, size_t(w)});
  py::array_t<bool> valid({m, size_t(w)});
  for (size_t i = 0; i < lanes.size(); ++i) {
    for (int r = 0; r < 6; ++r) box.mutable_data()[6 * i + r] = lanes[i].box[r];
    child.mutable_data()[i] = lanes[i].child;
    count.mutable_data()[i] = lanes[i].count;
    valid.mutable_data()[i] = lanes[i].valid;
  }
  const size_t nb = bvh.blocks().size();
  py::array_t<float> tris({nb, size_t(4), size_t(3), size_t(3)});
  py::array_t<int64_t> prims({nb, size_t(4)});
  for (size_t b = 0; b < nb; ++b) {
    for (int l = 0; l < 4; ++l) {
      for (int r = 0; r < 9; ++r) tris.mutable_data()[(b * 4 + l) * 9 + r] = bvh.blocks()[b].v[r][l];
      const uint32_t id = bvh.block_prims()[4 * b + l];
      prims.mutable_data()[b * 4 + l] = id == UINT32_MAX ? -1 : int64_t(id);
    }
  }
  py::dict d;
  d["box"] = box;
  d["child"] = child;
  d["count"] = count;
  d["valid"] = valid;
  d["compact"] = bvh.compact();
  d["triangles"] = tris;
  d["prims"] = prims;
  return d;
}

py::dict binary_bvh_nodes(const PyScene& self) {
  const Bvh& bvh = self.scene->bvh();
  const std::vector<BvhNode>& nodes = bvh.binary_nodes();
  const size_t m = nodes.size();
  py::array_t<float> lo({m, size_t(3)}), hi({m, size_t(3)});
  py::array_t<uint32_t> left_or_first(m), count(m);
  for (size_t i = 0; i < m; ++i) {
    for (int a = 0; a < 3; ++a) {
      lo.mutable_data()[3 * i + a] = nodes[i].lo[a];
      hi.mutable_data()[3 * i + a] = nodes[i].hi[a];
    }
    left_or_first.mutable_data()[i] = nodes[i].left_or_first;
    count.mutable_data()[i] = nodes[i].count;
  }
  const std::vector<uint32_t>& ids = bvh.leaf_prims();
  py::array_t<uint32_t> prims(ids.size());
  std::copy(ids.begin(), ids.end(), prims.mutable_data());
  py::dict d;
  d["lo"] = lo;
  d["hi"] = hi;
  d["left_or_first"] = left_or_first;
  d["count"] = count;
  d["prims"] = prims;
  return d;
}

void check_rays(const PyScene& self, const FloatArray& o, const FloatArray& d) {
  if (!self.scene->committed()) throw std::invalid_argument("commit() the scene before tracing rays");
  if (o.ndim() != 2 || o.shape(1) != 3 || d.ndim() != 2 || d.shape(1) != 3 || o.shape(0) != d.shape(0))
    throw std::invalid_argument("origins and directions must both have shape (N, 3)");
}

py::tuple intersect_batch(const PyScene& self, const FloatArray& origins, const FloatArray& dirs, float tmax,
                          bool instances, float time) {
  check_rays(self, origins, dirs);
  const py::ssize_t n = origins.shape(0);
  py::array_t<float> t(n), b1(n), b2(n);
  // The instance outputs only when returned: mesh_triangle reads a table (a cache miss per hit).
  py::array_t<int64_t> prim(n), inst(instances ? n : 0), local(instances ? n : 0);
  int64_t* pi = inst.mutable_data();
  int64_t* pl = local.mutable_data();
  const Vec3* o = reinterpret_cast<const Vec3*>(origins.data());
  const Vec3* d = reinterpret_cast<const Vec3*>(dirs.data());
  float *pt = t.mutable_data(), *pb1 = b1.mutable_data(), *pb2 = b2.mutable_data();
  int64_t* pp = prim.mutable_data();
  {
    py::gil_scoped_release release;
    for (py::ssize_t i = 0; i < n; ++i) {
      Ray r{o[i], d[i], tmax, time};
      Hit h;
      const bool ok = self.scene->intersect(r, h);
      pt[i] = ok ? h.t : kInf;
      pp[i] = ok ? int64_t(self.scene->global_prim(h)) : -1;
      if (instances) {
        pi[i] = ok ? (h.inst == kCurveInstance ? -2 : h.inst == kPointInstance ? -3 : int64_t(h.inst)) : -1;
        pl[i] = ok ? int64_t(self.scene->mesh_triangle(h)) : -1;
      }
      pb1[i] = ok ? h.b1 : 0.0f;
      pb2[i] = ok ? h.b2 : 0.0f;
    }
  }
  if (instances) return py::make_tuple(t, prim, b1, b2, inst, local);
  return py::make_tuple(t, prim, b1, b2);
}

// Light samples from points p with uniforms u (N x 3: light choice, then the 2-D sample), and
// the pdf pdf_emitter gives the emitter the ray along each sample's direction hits (MIS's view of
// the same direction), for tests of the light sampler's densities.
// An optional 3x3 world -> texture rotation, made exactly orthonormal.
Mat4 rotation_or_identity(const py::object& rotation_obj) {
  Mat4 rot;
  if (rotation_obj.is_none()) return rot;
  const FloatArray rotation = rotation_obj.cast<FloatArray>();
  if (rotation.ndim() != 2 || rotation.shape(0) != 3 || rotation.shape(1) != 3)
    throw std::invalid_argument("rotation must be a 3x3 matrix");
  auto r = rotation.unchecked<2>();
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) rot.m[i][j] = r(i, j);
  if (!rot.is_finite()) throw std::invalid_argument("rotation contains NaN or infinite values");
  return orthonormal_rotation(rot);
}

SkyParams sky_params(float elevation, float rotation, float size, float intensity, bool disc, float altitude, float air,
                     float dust, float ozone) {
  SkyParams p;
  p.sun_elevation = elevation;
  p.sun_rotation = rotation;
  p.sun_size = size;
  p.sun_intensity = intensity;
  p.sun_disc = disc;
  p.altitude = altitude;
  p.air = air;
  p.dust = dust;
  p.ozone = ozone;
  return p;  // SkyModel clamps what is out of range, as Cycles does
}

// CIE XYZ -> scene linear: Blender's default (Linear Rec.709, D65, its OCIO config's matrix).
void xyz_matrix(const py::object& obj, float m[9]) {
  static constexpr float kRec709[9] = {3.2404373564920070f,  -1.5371305409000549f, -0.4985288240756933f,
                                       -0.9692674982687597f, 1.8760136862977035f,  0.0415560804587997f,
                                       0.0556434463874256f,  -0.2040259700872272f, 1.0572254813610864f};
  std::copy(kRec709, kRec709 + 9, m);
  if (obj.is_none()) return;
  const FloatArray a = obj.cast<FloatArray>();
  if (a.ndim() != 2 || a.shape(0) != 3 || a.shape(1) != 3) throw std::invalid_argument("xyz_to_rgb must be 3x3");
  auto r = a.unchecked<2>();
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) {
      m[3 * i + j] = r(i, j);
      if (!std::isfinite(m[3 * i + j])) throw std::invalid_argument("xyz_to_rgb contains NaN or infinite values");
    }
}

// The Nishita precomputation (half a second) for these settings, reused while they stay the
// same: the viewport sets the world again on every light edit.
std::shared_ptr<const SkyModel> nishita_sky(const SkyParams& p, const float m[9]) {
  static std::mutex mu;
  static SkyParams last;
  static float last_m[9];
  static std::shared_ptr<const SkyModel> sky;
  const std::lock_guard<std::mutex> lock(mu);
  const bool same = sky && p.sun_elevation == last.sun_elevation && p.sun_rotation == last.sun_rotation &&
                    p.sun_size == last.sun_size && p.sun_intensity == last.sun_intensity &&
                    p.sun_disc == last.sun_disc && p.altitude == last.altitude && p.air == last.air &&
                    p.dust == last.dust && p.ozone == last.ozone && std::equal(m, m + 9, last_m);
  if (!same) {
    sky = std::make_shared<const SkyModel>(p, m);
    last = p;
    std::copy(m, m + 9, last_m);
  }
  return sky;
}

// What the Sky Texture setters share once their own inputs are read: the rotation, the colour
// matrix and the strength, then the sky that `make(xyz_to_rgb)` builds (without the GIL) as the
// environment. check_sky(self, width) first validates what every setter validated first.
void check_sky(PyScene& self, int width) {
  self.check_editable();
  if (width < 8 || width > 16384 || width % 2) throw std::invalid_argument("width must be even, 8..16384");
}
template <class Make>
void set_sky(PyScene& self, float strength, const py::object& rotation_obj, const py::object& xyz_to_rgb, int width,
             Make&& make) {
  const Mat4 rot = rotation_or_identity(rotation_obj);
  float m[9];
  xyz_matrix(xyz_to_rgb, m);
  const float k = std::isfinite(strength) && strength > 0.0f ? strength : 0.0f;
  py::gil_scoped_release release;
  self.scene->set_environment(Environment(make(m), width, width / 2, k, rot));
}


// The sky's radiance (strength 1) along unit directions (N, 3), for tests and tools.
py::array_t<float> sky_radiance(const FloatArray& dirs, float sun_elevation, float sun_rotation, float sun_size,
                                float sun_intensity, bool sun_disc, float altitude, float air, float dust, float ozone,
                                const py::object& xyz_to_rgb) {
  if (dirs.ndim() != 2 || dirs.shape(1) != 3) throw std::invalid_argument("directions must have shape (N, 3)");
  float m[9];
  xyz_matrix(xyz_to_rgb, m);
  const py::ssize_t n = dirs.shape(0);
  py::array_t<float> out({n, py::ssize_t(3)});
  const Vec3* d = reinterpret_cast<const Vec3*>(dirs.data());
  float* o = out.mutable_data();
  {
    py::gil_scoped_release release;
    const SkyModel sky(sky_params(sun_elevation, sun_rotation, sun_size, sun_intensity, sun_disc, altitude, air,
                                    dust, ozone),
                         m);
    for (py::ssize_t i = 0; i < n; ++i) {
      const float len = length(d[i]);
      const Vec3 c = len > 0.0f ? sky.eval(d[i] / len) : Vec3(0.0f);
      o[3 * i] = c.x;
      o[3 * i + 1] = c.y;
      o[3 * i + 2] = c.z;
    }
  }
  return out;
}

py::tuple light_samples(const PyScene& self, const FloatArray& points, const FloatArray& u, const py::object& normals_obj,
                        bool bsdf_follows) {
  check_rays(self, points, u);
  FloatArray normals;
  const Vec3* nn = nullptr;
  if (!normals_obj.is_none()) {
    normals = normals_obj.cast<FloatArray>();
    check_rays(self, points, normals);
    nn = reinterpret_cast<const Vec3*>(normals.data());
  }
  const py::ssize_t n = points.shape(0);
  py::array_t<bool> ok(n);
  py::array_t<float> wi({n, py::ssize_t(3)}), dist(n), pdf(n), pdf_hit(n), t_hit(n);
  const Vec3* p = reinterpret_cast<const Vec3*>(points.data());
  const float* pu = u.data();
  bool* pok = ok.mutable_data();
  float *pw = wi.mutable_data(), *pd = dist.mutable_data(), *pp = pdf.mutable_data(), *ph = pdf_hit.mutable_data(),
        *pt = t_hit.mutable_data();
  {
    py::gil_scoped_release release;
    for (py::ssize_t i = 0; i < n; ++i) {
      DirectSample ds;
      if (nn) ds.n = nn[i];
      const bool good = self.scene->sample_direct(p[i], pu[3 * i], {pu[3 * i + 1], pu[3 * i + 2]}, ds, bsdf_follows);
      pok[i] = good;
      pw[3 * i] = good ? ds.wi.x : 0.0f;
      pw[3 * i + 1] = good ? ds.wi.y : 0.0f;
      pw[3 * i + 2] = good ? ds.wi.z : 0.0f;
      pd[i] = good ? ds.dist : 0.0f;
      pp[i] = good ? ds.pdf : 0.0f;
      ph[i] = 0.0f;
      pt[i] = kInf;
      Hit h;
      if (good && self.scene->intersect(Ray{p[i], ds.wi, kInf}, h)) {
        pt[i] = h.t;
        SurfacePoint sp;
        self.scene->surface_point(h, sp);
        ph[i] = self.scene->pdf_emitter(sp, p[i], sp.p, std::fabs(dot(sp.ng, ds.wi)), ds.n);
      }
      float tl, pl;
      Vec3 le;
      if (good && self.scene->nearest_light_hit(p[i], ds.n, ds.wi, pt[i], tl, le, pl)) {  // an analytic light first
        pt[i] = tl;
        ph[i] = pl;
      }
    }
  }
  return py::make_tuple(ok, wi, dist, pdf, pdf_hit, t_hit);
}

// The light choices from points p (normals n, rows of zeros: none) with uniforms u (N): the
// chosen entry (-1: none) and its probability; and, with all_pmfs, the probability of every
// entry (N, K) at each point.
py::tuple light_choices(const PyScene& self, const FloatArray& points, const FloatArray& normals, const FloatArray& u,
                        bool all_pmfs, int light_set) {
  if (light_set < 0 || light_set > 63) throw std::invalid_argument("light_set takes 0..63");
  const uint8_t set = uint8_t(light_set);
  check_rays(self, points, normals);
  const py::ssize_t n = points.shape(0);
  if (u.ndim() != 1 || u.shape(0) != n) throw std::invalid_argument("u must have shape (N,)");
  const py::ssize_t kk = py::ssize_t(self.scene->light_choices());
  py::array_t<int64_t> idx(n);
  py::array_t<float> pmf(n);
  py::array_t<float> pmfs({all_pmfs ? n : py::ssize_t(0), kk});
  const Vec3* p = reinterpret_cast<const Vec3*>(points.data());
  const Vec3* nn = reinterpret_cast<const Vec3*>(normals.data());
  const float* pu = u.data();
  int64_t* pi = idx.mutable_data();
  float *pp = pmf.mutable_data(), *pa = pmfs.mutable_data();
  {
    py::gil_scoped_release release;
    for (py::ssize_t i = 0; i < n; ++i) {
      size_t k;
      float q;
      const bool ok = self.scene->pick_light(p[i], nn[i], pu[i], k, q, set);
      pi[i] = ok ? int64_t(k) : -1;
      pp[i] = ok ? q : 0.0f;
      if (all_pmfs)
        for (py::ssize_t j = 0; j < kk; ++j) pa[i * kk + j] = self.scene->pick_light_pmf(p[i], nn[i], size_t(j), set);
    }
  }
  return py::make_tuple(idx, pmf, pmfs);
}

// The surfaces that rays hit (for tests of curves and meshes alike): t (inf on a miss), the
// point, geometric normal, tangent (curves; else 0) and the spawn origins a path would use on
// the normal's side and on the other side (offset_ray_origin).
py::dict hit_surfaces(const PyScene& self, const FloatArray& origins, const FloatArray& dirs, float tmax,
                      const py::object& self_obj, float time) {
  check_rays(self, origins, dirs);
  const py::ssize_t n = origins.shape(0);
  // Per ray, the strand it leaves (Ray::self_curve; < 0: none), as hit_surfaces' "strand".
  py::array_t<int64_t, py::array::c_style | py::array::forcecast> self_in;
  if (!self_obj.is_none()) {
    self_in = self_obj.cast<py::array_t<int64_t, py::array::c_style | py::array::forcecast>>();
    if (self_in.ndim() != 1 || self_in.shape(0) != n) throw std::invalid_argument("self_strand must have shape (N,)");
  }
  const int64_t* ps = self_obj.is_none() ? nullptr : self_in.data();
  py::array_t<int64_t> strand(n);
  int64_t* pst = strand.mutable_data();
  py::array_t<float> t(n), p({n, py::ssize_t(3)}), ng({n, py::ssize_t(3)}), tg({n, py::ssize_t(3)}),
      out({n, py::ssize_t(3)}), in({n, py::ssize_t(3)}), hb({n, py::ssize_t(2)});
  py::array_t<bool> curve(n);
  float* phb = hb.mutable_data();
  const Vec3* o = reinterpret_cast<const Vec3*>(origins.data());
  const Vec3* d = reinterpret_cast<const Vec3*>(dirs.data());
  Vec3 *pp = reinterpret_cast<Vec3*>(p.mutable_data()), *pn = reinterpret_cast<Vec3*>(ng.mutable_data()),
       *pt = reinterpret_cast<Vec3*>(tg.mutable_data()), *po = reinterpret_cast<Vec3*>(out.mutable_data()),
       *pi = reinterpret_cast<Vec3*>(in.mutable_data());
  float* ptt = t.mutable_data();
  bool* pc = curve.mutable_data();
  py::array_t<bool> point(n);
  bool* ppt = point.mutable_data();
  {
    py::gil_scoped_release release;
    for (py::ssize_t i = 0; i < n; ++i) {
      Hit h;
      SurfacePoint sp;
      Ray ray{o[i], d[i], tmax, time};
      if (ps && ps[i] >= 0 && ps[i] < int64_t(UINT32_MAX)) ray.self_curve = uint32_t(ps[i]);
      const bool ok = self.scene->intersect(ray, h);
      if (ok) self.scene->surface_point(h, sp, time, &ray);
      pst[i] = ok && (sp.curve() || sp.point()) ? int64_t(self.scene->self_curve(sp)) : -1;
      ptt[i] = ok ? h.t : kInf;
      pp[i] = ok ? sp.p : Vec3(0.0f);
      pn[i] = ok ? sp.ng : Vec3(0.0f);
      pt[i] = ok ? sp.tangent : Vec3(0.0f);
      po[i] = ok ? offset_ray_origin(sp.p, sp.p_error, sp.ng) : Vec3(0.0f);
      pi[i] = ok ? offset_ray_origin(sp.p, sp.p_error, -sp.ng) : Vec3(0.0f);
      pc[i] = ok && sp.curve();
      ppt[i] = ok && sp.point();
      phb[2 * i] = ok ? h.b1 : 0.0f;
      phb[2 * i + 1] = ok ? h.b2 : 0.0f;
    }
  }
  py::dict r;
  r["t"] = t;
  r["hit"] = hb;
  r["p"] = p;
  r["ng"] = ng;
  r["tangent"] = tg;
  r["origin_out"] = out;
  r["origin_in"] = in;
  r["curve"] = curve;
  r["point"] = point;
  r["strand"] = strand;
  return r;
}

py::array_t<bool> occluded_batch(const PyScene& self, const FloatArray& origins, const FloatArray& dirs, float tmax,
                                 float time) {
  check_rays(self, origins, dirs);
  const py::ssize_t n = origins.shape(0);
  py::array_t<bool> out(n);
  const Vec3* o = reinterpret_cast<const Vec3*>(origins.data());
  const Vec3* d = reinterpret_cast<const Vec3*>(dirs.data());
  bool* po = out.mutable_data();
  {
    py::gil_scoped_release release;
    for (py::ssize_t i = 0; i < n; ++i) po[i] = self.scene->occluded(Ray{o[i], d[i], tmax, time});
  }
  return out;
}

// BVH work of a batch of rays (what the BVH debug view shows): nodes visited, triangles tested.
py::tuple traversal_counts(const PyScene& self, const FloatArray& origins, const FloatArray& dirs,
                           const py::object& tmax_obj) {
  check_rays(self, origins, dirs);
  const py::ssize_t n = origins.shape(0);
  FloatArray tmax;
  if (!tmax_obj.is_none()) {
    tmax = tmax_obj.cast<FloatArray>();
    if (tmax.ndim() != 1 || tmax.shape(0) != n) throw std::invalid_argument("tmax must have shape (N,)");
  }
  py::array_t<uint32_t> nodes(n), tris(n);
  const Vec3* o = reinterpret_cast<const Vec3*>(origins.data());
  const Vec3* d = reinterpret_cast<const Vec3*>(dirs.data());
  const float* tm = tmax_obj.is_none() ? nullptr : tmax.data();
  uint32_t *pn = nodes.mutable_data(), *pt = tris.mutable_data();
  {
    py::gil_scoped_release release;
    for (py::ssize_t i = 0; i < n; ++i) {
      TraversalCounters c;
      Hit h;
      self.scene->intersect(Ray{o[i], d[i], tm ? tm[i] : kInf}, h, &c);
      pn[i] = c.nodes;
      pt[i] = c.triangles;
    }
  }
  return py::make_tuple(nodes, tris);
}

// The renderer's camera rays through raster positions (pixels from the bottom-left corner).
py::tuple camera_rays(const PyScene& self, int width, int height, const FloatArray& xy) {
  if (!self.scene->has_camera()) throw std::invalid_argument("the scene has no camera");
  if (width < 1 || height < 1 || width > 65536 || height > 65536) throw std::invalid_argument("bad resolution");
  if (xy.ndim() != 2 || xy.shape(1) != 2) throw std::invalid_argument("xy must have shape (N, 2)");
  const py::ssize_t n = xy.shape(0);
  const Camera cam(self.scene->camera_desc(), width, height);
  FloatArray org({n, py::ssize_t(3)}), dir({n, py::ssize_t(3)}), tmax(n);
  Vec3* po = reinterpret_cast<Vec3*>(org.mutable_data());
  Vec3* pd = reinterpret_cast<Vec3*>(dir.mutable_data());
  float* pt = tmax.mutable_data();
  const float* p = xy.data();
  for (py::ssize_t i = 0; i < n; ++i) {
    const Ray r = cam.generate(p[2 * i], p[2 * i + 1]);
    po[i] = r.org;
    pd[i] = r.dir;
    pt[i] = r.tmax;
  }
  return py::make_tuple(org, dir, tmax);
}

Pass pass_by_name(const std::string& name) {
  for (int p = 0; p < kPassCount; ++p)
    if (name == pass_desc(Pass(p)).name) return Pass(p);
  std::string known;
  for (int p = 0; p < kPassCount; ++p) known += std::string(p ? ", " : "") + "'" + pass_desc(Pass(p)).name + "'";
  throw std::invalid_argument("unknown render pass '" + name + "' (known: " + known + ")");
}

Bsdf make_test_bsdf_of(const std::string& kind, const py::dict& p);
// Builds one BSDF from a name and parameters, for the BSDF tests (Mitsuba style); "blur": Filter
// Glossy's roughness applied to it (bsdf_blur).
Bsdf make_test_bsdf(const std::string& kind, const py::dict& p) {
  Bsdf b = make_test_bsdf_of(kind, p);
  if (p.contains("blur")) bsdf_blur(b, p["blur"].cast<float>());
  return b;
}
Bsdf make_test_bsdf_of(const std::string& kind, const py::dict& p) {
  auto f = [&](const char* k, float d) { return p.contains(k) ? p[k].cast<float>() : d; };
  auto b = [&](const char* k, bool d) { return p.contains(k) ? p[k].cast<bool>() : d; };
  // "distribution": "ggx" (the default), "beckmann" or (conductor only) "ashikhmin_shirley".
  auto dist = [&](bool ashikhmin_shirley) {
    const std::string d = p.contains("distribution") ? p["distribution"].cast<std::string>() : "ggx";
    if (d == "ggx") return Microfacet::Ggx;
    if (d == "beckmann") return Microfacet::Beckmann;
    if (d == "ashikhmin_shirley" && ashikhmin_shirley) return Microfacet::AshikhminShirley;
    throw std::invalid_argument("unknown " + kind + " distribution '" + d + "'");
  };
  if (kind == "diffuse") return DiffuseBsdf{};
  if (kind == "conductor") {
    ConductorBsdf c;
    c.alpha = f("alpha", 0.3f);
    c.alpha_y = f("alpha_y", -1.0f);  // anisotropic (negative: isotropic)
    c.dist = dist(true);
    c.f0 = p.contains("f0") ? to_color(p["f0"], "f0") : Vec3(1.0f);
    if (b("schlick", false)) c.mode = ConductorFresnel::Schlick;
    if (p.contains("f82_tint")) {  // Principled's metal
      c.mode = ConductorFresnel::F82Tint;
      c.b = f82_tint_b(c.f0, to_color(p["f82_tint"], "f82_tint"));
    }
    if (p.contains("conductor_k")) {  // Metallic BSDF's physical conductor (f0: n)
      c.mode = ConductorFresnel::Conductor;
      c.b = to_color(p["conductor_k"], "conductor_k");
    }
    if (p.contains("specular_eta")) {  // Principled's dielectric specular (f0: its tinted F0)
      c.mode = ConductorFresnel::Dielectric;
      c.eta = f("specular_eta", 1.5f);
      c.film_thickness = f("film_thickness", 0.0f);  // Thin Film (nm) and its IOR
      c.film_ior = f("film_ior", 1.33f);
    }
    return c;
  }
  if (kind == "dielectric") {
    DielectricBsdf d;
    d.alpha = f("alpha", 0.3f);
    d.alpha_y = f("alpha_y", -1.0f);
    d.dist = dist(false);
    d.eta = f("eta", 1.5f);
    d.reflection = b("reflection", true);
    d.transmission = b("transmission", true);
    d.fresnel_on_transmission = b("fresnel_on_transmission", true);
    d.schlick = b("schlick", false);
    if (p.contains("f0_tint")) d.f0_tint = to_color(p["f0_tint"], "f0_tint");
    d.film_thickness = f("film_thickness", 0.0f);
    d.film_ior = f("film_ior", 1.33f);
    return d;
  }
  if (kind == "transparent") return TransparentBsdf{};
  if (kind == "translucent") return TranslucentBsdf{};
  if (kind == "hair_chiang") {  // the node's inputs; the local frame: x along the fibre
    HairChiangBsdf h = HairChiangBsdf::from_node(p.contains("sigma") ? to_color(p["sigma"], "sigma") : Vec3(0.0f),
                                                 f("roughness", 0.3f), f("radial_roughness", 0.3f), f("coat", 0.0f),
                                                 f("offset", 0.0349066f), f("ior", 1.55f));
    h.h = f("h", 0.0f);
    return h;
  }
  if (kind == "hair_huang") {  // Cycles' local frame: x across the view (major axis), y along the fibre
    HairHuangBsdf h = HairHuangBsdf::from_node(p.contains("sigma") ? to_color(p["sigma"], "sigma") : Vec3(0.0f),
                                               f("roughness", 0.3f), f("offset", 0.0349066f), f("ior", 1.55f),
                                               f("aspect_ratio", 1.0f), f("r", 1.0f), f("tt", 1.0f), f("trt", 1.0f));
    if (h.b > 1.0f) h.b = 1.0f / h.b;
    h.h = f("h", 0.0f);
    h.pixel_coverage = f("pixel_coverage", 1.0f);
    h.seed = uint32_t(f("seed", 0.0f));
    return h;
  }
  if (kind == "hair_reflection" || kind == "hair_transmission") {  // T in the local frame
    Vec3 t(1.0f, 0.0f, 0.0f);
    if (p.contains("tangent")) t = normalize(to_point(p["tangent"], "tangent"));
    return HairBsdf::setup(t, f("roughness_u", 0.1f), f("roughness_v", 1.0f), f("offset", 0.0f),
                           kind == "hair_transmission");
  }
  // Sheen and rough diffuse set up for a view at cosine `cos_view` (their terms depend on it).
  if (kind == "sheen") {
    float albedo;
    SheenBsdf s = SheenBsdf::setup(f("roughness", 0.5f), f("cos_view", 1.0f), albedo);
    s.back = b("back", false);  // a backfacing hit's lobe: lit from -Z
    return s;
  }
  if (kind == "velvet") return VelvetBsdf::setup(f("sigma", 1.0f));
  if (kind == "toon") return ToonBsdf::setup(f("size", 0.5f), f("smooth", 0.0f), b("glossy", false));
  if (kind == "oren_nayar") {
    const Vec3 c = p.contains("color") ? to_color(p["color"], "color") : Vec3(1.0f);
    OrenNayarBsdf o = OrenNayarBsdf::setup(f("roughness", 0.5f), c, f("cos_view", 1.0f));
    o.back = b("back", false);  // a backfacing hit's lobe: lit from -Z
    return o;
  }
  throw std::invalid_argument("unknown bsdf '" + kind + "'");
}

struct PySession {
  std::shared_ptr<Scene> scene;  // keeps the scene alive and locked against edits
  std::unique_ptr<Session> session;
};

// Cryptomatte layers by Cycles' pass-name stems, in kCrypto* bit order.
constexpr const char* kCryptoNames[3] = {"object", "material", "asset"};
constexpr const char* kCryptoPassStems[3] = {"CryptoObject", "CryptoMaterial", "CryptoAsset"};

// A Cryptomatte pass ("CryptoObject00", ...): its (H, W, 4) floats, or None for another name.
py::object crypto_pass(PySession& self, const std::string& name) {
  for (int k = 0; k < 3; ++k) {
    const std::string stem = kCryptoPassStems[k];
    if (name.size() != stem.size() + 2 || name.compare(0, stem.size(), stem) != 0) continue;
    const char d0 = name[stem.size()], d1 = name[stem.size() + 1];
    if (d0 < '0' || d0 > '9' || d1 < '0' || d1 > '9') continue;
    const int layer = self.session->crypto_layer(1u << k), pass = (d0 - '0') * 10 + (d1 - '0');
    if (layer < 0 || pass >= self.session->crypto_passes())
      throw std::invalid_argument("render pass '" + name + "' was not requested (RenderSettings.cryptomatte, cryptomatte_depth)");
    Film& f = self.session->film();
    FloatArray out({f.height(), f.width(), 4});
    float* dst = out.mutable_data();
    {
      py::gil_scoped_release release;
      f.read_crypto(layer, pass, dst);
    }
    return std::move(out);
  }
  return py::none();
}

// Session's bake dict (see its docstring) as a BakeInput.
std::shared_ptr<BakeInput> parse_bake(const py::object& obj, const RenderSettings& settings) {
  using I32 = py::array_t<int32_t, py::array::c_style | py::array::forcecast>;
  const py::dict d = obj.cast<py::dict>();
  for (const auto& kv : d) {
    const std::string k = kv.first.cast<std::string>();
    if (k != "instance" && k != "triangle" && k != "bary" && k != "differentials" && k != "mode" &&
        k != "view_from_camera")
      throw std::invalid_argument("bake: unknown key '" + k + "'");
  }
  if (!d.contains("instance") || !d.contains("triangle") || !d.contains("bary"))
    throw std::invalid_argument("bake: needs instance, triangle and bary");
  auto b = std::make_shared<BakeInput>();
  const int64_t inst = d["instance"].cast<int64_t>();
  if (inst < 0 || inst > int64_t(UINT32_MAX)) throw std::invalid_argument("bake: instance out of range");
  b->instance = uint32_t(inst);
  const size_t n = size_t(std::max(settings.width, 0)) * size_t(std::max(settings.height, 0));
  const I32 tri = I32::ensure(d["triangle"]);
  const FloatArray bary = FloatArray::ensure(d["bary"]);
  if (!tri || !bary || size_t(tri.size()) != n || size_t(bary.size()) != 2 * n)
    throw std::invalid_argument("bake: triangle must be (width x height,) and bary (width x height, 2)");
  b->triangle.assign(tri.data(), tri.data() + n);
  b->bary.assign(bary.data(), bary.data() + 2 * n);
  if (d.contains("differentials") && !d["differentials"].is_none()) {
    const FloatArray diff = FloatArray::ensure(d["differentials"]);
    if (!diff || size_t(diff.size()) != 4 * n) throw std::invalid_argument("bake: differentials must be (width x height, 4)");
    b->differentials.assign(diff.data(), diff.data() + 4 * n);
  }
  const std::string mode = d.contains("mode") ? d["mode"].cast<std::string>() : "surface";
  if (mode == "surface") b->mode = BakeMode::Surface;
  else if (mode == "environment") b->mode = BakeMode::Environment;
  else if (mode == "roughness") b->mode = BakeMode::Roughness;
  else throw std::invalid_argument("bake: mode must be 'surface', 'environment' or 'roughness', not '" + mode + "'");
  if (d.contains("view_from_camera")) b->view_from_camera = d["view_from_camera"].cast<bool>();
  return b;
}

py::object film_pass(PySession& self, const std::string& name) {
  py::object crypto = crypto_pass(self, name);
  if (!crypto.is_none()) return crypto;
  const Pass p = pass_by_name(name);
  Film& f = self.session->film();
  if (p != Pass::SampleCount && f.pass_offset(p) < 0)
    throw std::invalid_argument("render pass '" + name + "' was not requested (RenderSettings.passes)");
  FloatArray out({f.height(), f.width(), pass_desc(p).channels});
  float* dst = out.mutable_data();
  {
    py::gil_scoped_release release;
    f.read_pass(p, dst);
  }
  return std::move(out);
}

FloatArray film_rect(PySession& self, int x, int y, int w, int h) {
  Film& f = self.session->film();
  if (x < 0 || y < 0 || w < 0 || h < 0 || int64_t(x) + w > f.width() || int64_t(y) + h > f.height())
    throw std::invalid_argument("film_rect outside the image");
  FloatArray out({h, w, 4});
  float* dst = out.mutable_data();
  {
    py::gil_scoped_release release;
    f.read_rect(x, y, w, h, dst);
  }
  return out;
}


// ---------------------------------------------------------------- OpenVDB grids (issue 23)

VolumeSampling parse_sampling(const std::string& mode) {
  if (mode == "linear" || mode == "trilinear") return VolumeSampling::Trilinear;
  if (mode == "closest") return VolumeSampling::Closest;
  if (mode == "cubic" || mode == "tricubic") return VolumeSampling::Tricubic;
  throw std::invalid_argument("sampling mode must be 'linear', 'closest' or 'cubic', not '" + mode + "'");
}

py::array_t<double> matrix_array(const std::array<double, 16>& m) {
  py::array_t<double> out({4, 4});
  std::copy(m.begin(), m.end(), out.mutable_data());
  return out;
}

py::list compression_names(uint32_t flags) {
  py::list out;
  if (flags & kVdbZip) out.append("zip");
  if (flags & kVdbBlosc) out.append("blosc");
  if (flags & kVdbActiveMask) out.append("active_mask");
  return out;
}

py::list vdb_grid_list(const VdbFile& f) {
  py::list out;
  for (const VdbGridRecord& rec : f.grids) {
    py::dict d;
    d["name"] = rec.name;
    d["tree_type"] = rec.tree_type;
    d["compression"] = rec.compression;
    d["compression_names"] = compression_names(rec.compression);
    d["half_float"] = rec.half_float;
    d["file_version"] = f.file_version;
    d["library_version"] = py::make_tuple(f.library_major, f.library_minor);
    d["skipped"] = rec.skipped.empty() ? py::object(py::none()) : py::object(py::str(rec.skipped));
    if (rec.grid) {
      const VolumeGrid& g = *rec.grid;
      d["type"] = g.value_type;
      d["class"] = g.grid_class;
      d["channels"] = g.channels();
      d["voxel_count"] = g.active_voxels();
      d["leaf_count"] = g.leaf_count();
      d["bbox_min"] = py::make_tuple(g.active_min()[0], g.active_min()[1], g.active_min()[2]);
      d["bbox_max"] = py::make_tuple(g.active_max()[0], g.active_max()[1], g.active_max()[2]);
      d["transform"] = matrix_array(g.index_to_object());
      const auto& bg = g.background();
      d["background"] = g.channels() == 1 ? py::object(py::float_(bg[0])) : py::object(py::make_tuple(bg[0], bg[1], bg[2]));
      d["nonfinite_replaced"] = g.nonfinite_replaced();
      d["memory_bytes"] = g.memory_bytes();
      d["grid"] = rec.grid;
    } else {
      d["grid"] = py::none();
    }
    out.append(d);
  }
  return out;
}

VdbReadOptions vdb_options(const py::object& grid, bool topology_only, int64_t max_bricks) {
  VdbReadOptions o;
  if (!grid.is_none()) o.only_grid = grid.cast<std::string>();
  o.topology_only = topology_only;
  if (max_bricks <= 0) throw std::invalid_argument("max_bricks must be positive");
  o.limits.max_bricks = max_bricks;
  return o;
}

// read_vdb and read_vdb_bytes differ only in their source: open(source) runs with the GIL
// (it may copy Python bytes) and returns the reader, which runs without it.
template <class Source, class Open>
void def_read_vdb(py::module_& m, const char* name, const char* source_name, Open open, const char* doc) {
  m.def(name, [open](const Source& source, const py::object& grid, bool topology_only, int64_t max_bricks) {
          const VdbReadOptions o = vdb_options(grid, topology_only, max_bricks);
          const auto read = open(source);
          VdbFile f;
          {
            py::gil_scoped_release release;
            f = read(o);
          }
          return vdb_grid_list(f);
        }, py::arg(source_name), py::arg("grid") = py::none(), py::arg("topology_only") = false,
        py::arg("max_bricks") = int64_t(1) << 19, doc);
}

FloatArray sample_points(const VolumeGrid& g, const FloatArray& points, bool index_space, const std::string& mode,
                         bool majorant) {
  // Points as float64 would be nicer for far-off grids; float32 keeps one array type here.
  if (points.ndim() != 2 || points.shape(1) != 3) throw std::invalid_argument("points must have shape (N, 3)");
  const VolumeSampling s = parse_sampling(mode);
  const py::ssize_t n = points.shape(0);
  const int ch = majorant ? 1 : g.channels();
  FloatArray out = ch == 1 ? FloatArray({n}) : FloatArray({n, py::ssize_t(ch)});
  const float* p = points.data();
  float* o = out.mutable_data();
  {
    py::gil_scoped_release release;
    for (py::ssize_t i = 0; i < n; ++i) {
      const double q[3] = {p[3 * i], p[3 * i + 1], p[3 * i + 2]};
      if (majorant) o[i] = index_space ? g.majorant_at_index(q) : g.majorant(q);
      else if (index_space) g.sample_index(q, s, o + i * ch);
      else g.sample(q, s, o + i * ch);
    }
  }
  return out;
}

void bind_volume_grids(py::module_& m) {
  py::class_<IesProfile, std::shared_ptr<IesProfile>>(m, "IesProfile",
      "An IES light profile (IESNA LM-63 text), read and looked up as Cycles 4.5's IES Texture: values in "
      "Cycles' lamp-strength units (candela x 4 pi / 177.83).")
      .def(py::init([](const py::bytes& text) {
             auto p = std::make_shared<IesProfile>();
             std::string err;
             if (!parse_ies(std::string(text), *p, err)) throw py::value_error("IES profile: " + err);
             return p;
           }),
           py::arg("text"), "Parses the file's bytes; ValueError where it cannot be read (as Cycles rejects it).")
      .def(
          "eval", [](const IesProfile& p, const py::object& d) { return ies_eval(p, to_point(d, "direction")); },
          py::arg("direction"), "The value towards a light-local direction (-Z: straight down, vertical angle 0).")
      .def("lookup", &ies_lookup, py::arg("h_angle"), py::arg("v_angle"), "The value at Cycles' angles (radians).")
      .def_property_readonly("h_angles", [](const IesProfile& p) { return p.h; })
      .def_property_readonly("v_angles", [](const IesProfile& p) { return p.v; })
      .def_readonly("mean", &IesProfile::mean);

  // Sky Texture nodes in materials (op "tex_sky"): the world's sky models, made by sky_texture().
  py::class_<SkyModel, std::shared_ptr<SkyModel>>(m, "SkyTexture",
      "A Sky Texture node's model (Nishita, Preetham or Hosek / Wilkie) for material programs; see "
      "sky_texture.")
      .def(
          "eval",
          [](const SkyModel& sky, const py::object& d) {
            const Vec3 c = sky.eval(to_point(d, "direction"));
            return py::make_tuple(c.x, c.y, c.z);
          },
          py::arg("direction"), "The radiance along a vector (read as it is, as Cycles' svm_node_tex_sky).");

  py::class_<VolumeGrid, std::shared_ptr<VolumeGrid>>(m, "VolumeGrid",
      "One grid of a .vdb file, sparse (8^3 bricks), for sampling in object or index space.")
      .def_static(
          "from_dense",
          [](const FloatArray& values, const py::array_t<double, py::array::c_style | py::array::forcecast>& transform) {
            // values [z, y, x] or [z, y, x, 3]; transform: 4x4 index -> object (voxel centres at integers)
            if ((values.ndim() != 3 && values.ndim() != 4) || (values.ndim() == 4 && values.shape(3) != 3))
              throw std::invalid_argument("from_dense: values must be (nz, ny, nx) or (nz, ny, nx, 3)");
            if (transform.ndim() != 2 || transform.shape(0) != 4 || transform.shape(1) != 4)
              throw std::invalid_argument("from_dense: transform must be 4x4");
            std::array<double, 16> m;
            for (size_t i = 0; i < 16; ++i) m[i] = transform.data()[i];
            auto g = std::make_shared<VolumeGrid>();
            const int ch = values.ndim() == 4 ? 3 : 1;
            {
              py::gil_scoped_release release;
              g->build_dense(ch, int(values.shape(2)), int(values.shape(1)), int(values.shape(0)), values.data());
            }
            g->set_transform(m);  // throws on a singular or non-finite transform
            return g;
          },
          py::arg("values"), py::arg("transform"),
          "A dense grid (the Point Density texture's voxels): values (nz, ny, nx) or (nz, ny, nx, 3) float32, "
          "x fastest; transform 4x4 index -> object (voxel centres at integer indices). ValueError / "
          "RuntimeError on bad shapes, sizes or transforms.")
      .def_readonly("name", &VolumeGrid::name)
      .def_readonly("value_type", &VolumeGrid::value_type)
      .def_readonly("grid_class", &VolumeGrid::grid_class)
      .def_readonly("saved_as_half", &VolumeGrid::saved_as_half)
      .def_property_readonly("channels", &VolumeGrid::channels)
      .def_property_readonly("transform", [](const VolumeGrid& g) { return matrix_array(g.index_to_object()); },
                             "4x4 index -> object matrix (column vectors; voxel centres at integer indices)")
      .def_property_readonly("inverse_transform", [](const VolumeGrid& g) { return matrix_array(g.object_to_index()); })
      .def_property_readonly("bbox_min", [](const VolumeGrid& g) { return g.active_min(); })
      .def_property_readonly("bbox_max", [](const VolumeGrid& g) { return g.active_max(); })
      .def_property_readonly("active_voxels", &VolumeGrid::active_voxels)
      .def_property_readonly("leaf_count", &VolumeGrid::leaf_count)
      .def_property_readonly("nonfinite_replaced", &VolumeGrid::nonfinite_replaced)
      .def_property_readonly("memory_bytes", &VolumeGrid::memory_bytes)
      .def_property_readonly("max_value", &VolumeGrid::max_value)
      .def_property_readonly("max_abs", [](const VolumeGrid& g) { return g.max_abs(); },
                             "Per channel (3), the largest |value| of any voxel, tile or the background.")
      .def_property_readonly("background", [](const VolumeGrid& g) { return g.background(); })
      .def("sample", [](const VolumeGrid& g, const FloatArray& p, const std::string& mode) {
             return sample_points(g, p, false, mode, false); },
           py::arg("points"), py::arg("mode") = "linear",
           "Values at object-space points (N, 3): (N,) or (N, 3) float32; mode 'linear' or 'closest'.")
      .def("sample_index", [](const VolumeGrid& g, const FloatArray& p, const std::string& mode) {
             return sample_points(g, p, true, mode, false); },
           py::arg("points"), py::arg("mode") = "linear", "As sample, at index-space points.")
      .def("majorant", [](const VolumeGrid& g, const FloatArray& p, bool index_space) {
             return sample_points(g, p, index_space, "linear", true); },
           py::arg("points"), py::arg("index_space") = false,
           "The majorant grid's bound at points (N,): >= every trilinear sample in the point's cell.")
      .def("majorant_grid", [](const VolumeGrid& g) {
             const auto& d = g.majorant_dims();
             FloatArray a({py::ssize_t(d[2]), py::ssize_t(d[1]), py::ssize_t(d[0])});
             std::copy(g.majorant_cells().begin(), g.majorant_cells().end(), a.mutable_data());
             return py::make_tuple(g.majorant_origin(), int(VolumeGrid::kMajorantBlock), a);
           }, "(origin in voxels, cell size in voxels, float32 array [z, y, x]).")
      .def("voxels", [](const VolumeGrid& g, std::array<int64_t, 3> lo, std::array<int64_t, 3> hi) {
             int64_t n = 1;
             for (int a = 0; a < 3; ++a) {
               if (hi[a] < lo[a] || hi[a] - lo[a] > (1 << 12)) throw std::invalid_argument("bad voxel box");
               n *= hi[a] - lo[a] + 1;
             }
             if (n > (int64_t(1) << 26)) throw std::invalid_argument("voxel box too large");
             const int ch = g.channels();
             std::vector<py::ssize_t> shape = {py::ssize_t(hi[0] - lo[0] + 1), py::ssize_t(hi[1] - lo[1] + 1),
                                               py::ssize_t(hi[2] - lo[2] + 1)};
             if (ch > 1) shape.push_back(ch);
             FloatArray a(shape);
             float* o = a.mutable_data();
             for (int64_t i = lo[0]; i <= hi[0]; ++i)
               for (int64_t j = lo[1]; j <= hi[1]; ++j)
                 for (int64_t k = lo[2]; k <= hi[2]; ++k, o += ch) g.voxel(i, j, k, o);
             return a;
           }, py::arg("min"), py::arg("max"),
           "Voxel values over the inclusive index box [min, max] as [i, j, k(, channel)].");

  def_read_vdb<std::string>(
      m, "read_vdb", "path",
      [](const std::string& path) { return [&path](const VdbReadOptions& o) { return read_vdb_file(path, o); }; },
      "Reads an OpenVDB file: a list of dicts per grid (name, type, voxel_count, bbox_min/max, "
      "transform 4x4, background, compression, grid: VolumeGrid or None with 'skipped' saying why). "
      "Malformed files raise RuntimeError.");
  def_read_vdb<py::bytes>(
      m, "read_vdb_bytes", "data",
      [](const py::bytes& data) {
        return [s = std::string(data)](const VdbReadOptions& o) {
          return read_vdb_memory(reinterpret_cast<const uint8_t*>(s.data()), s.size(), o);
        };
      },
      "read_vdb on the bytes of a file.");
  m.def("vdb_decompress", [](const std::string& codec, const py::bytes& data, int64_t size) {
          if (size < 0 || size > (int64_t(1) << 30)) throw std::invalid_argument("size out of range");
          const std::string s = data;
          std::string out(size_t(size), '\0');
          auto* src = reinterpret_cast<const uint8_t*>(s.data());
          auto* dst = reinterpret_cast<uint8_t*>(&out[0]);
          if (codec == "lz4") vdb_lz4_decompress(src, s.size(), dst, out.size());
          else if (codec == "blosc") vdb_blosc_decompress(src, s.size(), dst, out.size());
          else if (codec == "zip") vdb_zlib_decompress(src, s.size(), dst, out.size());
          else throw std::invalid_argument("codec must be 'lz4', 'blosc' or 'zip'");
          return py::bytes(out);
        }, py::arg("codec"), py::arg("data"), py::arg("size"),
        "The VDB reader's decompressors (for tests): exactly `size` bytes or RuntimeError.");
}

}  // namespace

PYBIND11_MODULE(pathlight_core, m) {
  m.doc() = "Pathlight's compiled core: scene, BVH, path tracer and progressive render sessions.";
  m.attr("__version__") = PATHLIGHT_VERSION;
  m.def(
      "shader_op_table",
      [] {
        auto names = [](const auto& table) {
          py::list out;
          for (const SubOpName& n : table)
            out.append(py::dict(py::arg("name") = n.name, py::arg("operands") = int(n.operands),
                                py::arg("value_out") = n.value_out, py::arg("reads_scale") = n.reads_scale));
          return out;
        };
        py::dict d;
        d["math"] = names(kMathOpNames);
        d["vector_math"] = names(kVectorMathOpNames);
        d["mix"] = names(kMixOpNames);
        d["color_space"] = names(kColorSpaceOpNames);
        d["map_range"] = names(kMapRangeOpNames);
        d["clamp"] = names(kClampOpNames);
        py::dict ops;
        py::list schema;
        for (const ValueOpSchema& o : kValueOps) {
          ops[o.name] = int(o.registers);
          py::list params, flags;
          for (const OpParam& p : o.params) {
            py::dict e(py::arg("kind") = kParamKindNames[size_t(p.kind)],
                       py::arg("field") = kOpFieldNames[size_t(p.field)], py::arg("what") = p.what,
                       py::arg("optional") = p.optional);
            if (p.kind == ParamKind::Choice) {
              py::list n, alt;
              for (size_t i = 0; i < p.n_names; ++i) n.append(p.name(i));
              for (size_t i = 0; i < p.n_alt; ++i) alt.append(p.alt_names[i]);
              e["names"] = n;
              e["offset"] = int(p.offset);
              if (p.n_alt) e["alt_names"] = alt;  // when the op's sub is nonzero
            }
            if (p.kind == ParamKind::Int) e["range"] = py::make_tuple(p.lo, p.hi);
            if (p.kind == ParamKind::Bool) e["bit"] = int(p.bit);
            if (p.when >= 0) e["when"] = int(p.when);
            params.append(e);
          }
          for (const auto& [bit, name] : {std::pair{kVarying, "varying"}, std::pair{kUsesUv, "uses_uv"},
                                          std::pair{kUsesAttributes, "uses_attributes"}, std::pair{kSetsNormal, "sets_normal"}})
            if (o.flags & bit) flags.append(name);
          schema.append(py::dict(py::arg("name") = o.name, py::arg("code") = int(o.code),
                                 py::arg("registers") = int(o.registers), py::arg("params") = params,
                                 py::arg("flags") = flags, py::arg("ext") = int(o.ext),
                                 py::arg("hand_parsed") = o.hand_parsed));
        }
        // Every entry but "ops" is a list of dicts with a "name" (the add-on indexes them so).
        d["ops"] = ops;
        d["schema"] = schema;
        py::list codes;
        for (size_t c = 0; c < kOpCodeCount; ++c) {
          const bool closure = std::any_of(std::begin(kClosureOpCodes), std::end(kClosureOpCodes),
                                           [&](OpCode k) { return size_t(k) == c; });
          codes.append(py::dict(py::arg("name") = std::to_string(c), py::arg("code") = int(c),
                                py::arg("closure") = closure));
        }
        d["opcodes"] = codes;
        return d;
      },
      "The shader language's table: 'ops' maps each value op's name to its register operand count; "
      "'schema' lists each value op's parse (name, code, registers, params, flags, ext, "
      "hand_parsed); 'opcodes' each OpCode (name: its number, code, closure: made by closure "
      "ops); the sub-operations (Math, Vector Math, Mix, colour space, Map Range and Clamp types) "
      "in the core's order, each a dict of name, operands, value_out, reads_scale.");
  m.def(
      "fold_constant",
      [](const py::list& program, int reg) {
        // The add-on's constant folding: the core's own float evaluation of a program of
        // constants and value ops (no scene, no images), returning one register.
        if (reg < 0 || reg >= kMaxRegs) throw std::invalid_argument("register out of range");
        const ShaderProgram prog = parse_program(program, 0);
        // Only the ops whose value depends on their operands alone: the op table's entries
        // that read nothing of the shading point (no kVarying) and no image.
        for (const ShaderOp& op : prog.ops) {
          bool pure = false;
          for (const ValueOpSchema& v : kValueOps)
            if (v.code == op.code) {
              pure = !(v.flags & kVarying) &&
                     std::none_of(v.params.begin(), v.params.end(), [](const OpParam& p) {
                       return p.kind == ParamKind::ImageId || p.kind == ParamKind::Ies || p.kind == ParamKind::Sky;
                     });
              break;
            }
          if (!pure) throw std::invalid_argument("fold_constant takes constants and pure value ops only");
        }
        ShadingContext ctx;
        ctx.ng = ctx.ns = ctx.wo = {0.0f, 0.0f, 1.0f};
        ClosureList cl;
        Float4 regs[kMaxRegs];
        eval_shader(prog, {}, ctx, cl, regs);
        return py::make_tuple(regs[reg].x, regs[reg].y, regs[reg].z, regs[reg].w);
      },
      py::arg("program"), py::arg("register"),
      "Evaluates a program of constants and value ops as the renderer does (float arithmetic) "
      "and returns register `register` as (x, y, z, w).");
  bind_volume_grids(m);
  m.def(
      "set_bvh_kernel",
      [](const std::string& k) {
        if (k != "auto" && k != "avx2" && k != "avx512")
          throw py::value_error("set_bvh_kernel: 'auto', 'avx2' or 'avx512', not '" + k + "'");
        set_bvh8_kernel(k == "avx2" ? Bvh8Kernel::Avx2 : k == "avx512" ? Bvh8Kernel::Avx512 : Bvh8Kernel::Auto);
        return std::string(!cpu_has_avx2() ? "sse2" : bvh8_use_avx512() ? "avx512" : "avx2");
      },
      py::arg("kernel"),
      "Which code runs the 8-wide BVH, for the whole process (tests, timings; not during a render): "
      "'auto' (the choice at load: AVX-512 where the CPU has it, unless PL_BVH_KERNEL=avx2 was set), "
      "'avx2', or 'avx512' (AVX2 where the CPU lacks it). The same hits either way. Returns the "
      "kernel now used: 'avx512', 'avx2' or 'sse2' (no AVX2: the 4-wide tree).");
  m.def("build_info", [] {
    py::dict d;
    d["simd"] = PATHLIGHT_SIMD_NAME;
    // The BVH kernel commit() picks by default on this CPU (run-time detection).
    d["bvh"] = cpu_has_avx2() ? "bvh8" : "bvh4";
    // The code that runs the 8-wide tree now (set_bvh_kernel), and whether the CPU has AVX-512.
    d["bvh_kernel"] = !cpu_has_avx2() ? "sse2" : bvh8_use_avx512() ? "avx512" : "avx2";
    d["avx512"] = cpu_has_avx512();
    d["zlib"] = vdb_zlib_available();  // ZIP-compressed .vdb grids
#if defined(__clang__)
    d["compiler"] = "clang " __clang_version__;
#elif defined(__GNUC__)
    d["compiler"] = "gcc " __VERSION__;
#else
    d["compiler"] = "unknown";
#endif
#ifdef NDEBUG
    d["build_type"] = "release";
#else
    d["build_type"] = "debug";
#endif
    return d;
  });

  m.def(
      "offset_ray_origin",
      [](const FloatArray& points, const FloatArray& normals, const py::object& errors_obj) {
        if (points.ndim() != 2 || points.shape(1) != 3 || normals.ndim() != 2 || normals.shape(1) != 3 ||
            points.shape(0) != normals.shape(0))
          throw std::invalid_argument("points and normals must both have shape (N, 3)");
        FloatArray errors;
        if (!errors_obj.is_none()) {
          errors = errors_obj.cast<FloatArray>();
          if (errors.ndim() != 2 || errors.shape(1) != 3 || errors.shape(0) != points.shape(0))
            throw std::invalid_argument("errors must have shape (N, 3)");
        }
        FloatArray out({points.shape(0), py::ssize_t(3)});
        const Vec3* p = reinterpret_cast<const Vec3*>(points.data());
        const Vec3* n = reinterpret_cast<const Vec3*>(normals.data());
        const Vec3* e = errors_obj.is_none() ? nullptr : reinterpret_cast<const Vec3*>(errors.data());
        Vec3* o = reinterpret_cast<Vec3*>(out.mutable_data());
        for (py::ssize_t i = 0; i < points.shape(0); ++i)
          o[i] = offset_ray_origin(p[i], e ? e[i] : vabs(p[i]) * gamma_bound(7), n[i]);
        return out;
      },
      py::arg("points"), py::arg("normals"), py::arg("errors") = py::none(),
      "The offset the integrator applies to spawned rays (exposed for self-intersection tests). "
      "errors: bounds of the points' rounding errors; default gamma(7)|p|, right for points "
      "interpolated on triangles whose vertices are no larger than the point.");
  // Polygon meshes: the exporter's cheap path from faces to triangles and smooth normals.
  using I32Array = py::array_t<int32_t, py::array::c_style | py::array::forcecast>;
  const auto polygon_mesh = [](const FloatArray& positions, const I32Array& corner_verts, const I32Array& offsets) {
    if (positions.ndim() != 2 || positions.shape(1) != 3) throw std::invalid_argument("positions must have shape (V, 3)");
    if (corner_verts.ndim() != 1) throw std::invalid_argument("corner_verts must have shape (C,)");
    if (offsets.ndim() != 1 || offsets.shape(0) < 1) throw std::invalid_argument("face_offsets must have shape (F + 1,)");
    PolygonMesh m;
    m.positions = reinterpret_cast<const Vec3*>(positions.data());
    m.vertices = size_t(positions.shape(0));
    m.corner_verts = corner_verts.data();
    m.corners = size_t(corner_verts.shape(0));
    m.offsets = offsets.data();
    m.faces = size_t(offsets.shape(0)) - 1;
    if (m.corners > size_t(INT32_MAX)) throw std::invalid_argument("mesh is too large");
    validate_polygon_mesh(m);
    return m;
  };
  m.def(
      "triangulate_polygons",
      [polygon_mesh](const FloatArray& positions, const I32Array& corner_verts, const I32Array& offsets, int threads,
                     bool want_corners) {
        const PolygonMesh pm = polygon_mesh(positions, corner_verts, offsets);
        const size_t nt = polygon_mesh_triangles(pm);
        py::array_t<int32_t> out, verts({py::ssize_t(nt), py::ssize_t(3)});
        if (want_corners) out = py::array_t<int32_t>({py::ssize_t(nt), py::ssize_t(3)});
        uint32_t* dst = want_corners ? reinterpret_cast<uint32_t*>(out.mutable_data()) : nullptr;
        uint32_t* vdst = reinterpret_cast<uint32_t*>(verts.mutable_data());
        size_t ngons;
        {
          py::gil_scoped_release release;
          ngons = triangulate_polygons(pm, dst, vdst, threads);
        }
        return py::make_tuple(want_corners ? py::object(out) : py::none(), verts, ngons);
      },
      py::arg("positions"), py::arg("corner_verts"), py::arg("face_offsets"), py::arg("threads") = 0,
      py::arg("corners") = true,
      "(corners int32 (T, 3), vertices int32 (T, 3), n-gon count): the corner and vertex indices of the triangles "
      "of a polygon mesh (face f: corners face_offsets[f] to face_offsets[f + 1] - 1), face by face, quads split as "
      "Blender does; faces of 5+ corners get a fan (counted: the caller replaces those). corners=False: None "
      "instead of the corner indices (not computed).");
  m.def(
      "sample_henyey_greenstein",
      [](float g, const FloatArray& u) {
        if (u.ndim() != 2 || u.shape(1) != 2) throw std::invalid_argument("u must have shape (N, 2)");
        const float gc = clamp_phase_g(g);
        FloatArray dirs({u.shape(0), py::ssize_t(3)}), pdfs({u.shape(0)});
        const float* up = u.data();
        float* d = dirs.mutable_data();
        float* p = pdfs.mutable_data();
        for (py::ssize_t i = 0; i < u.shape(0); ++i) {
          const Vec3 w = hg_sample(gc, Vec3(0.0f, 0.0f, 1.0f), up[2 * i], up[2 * i + 1], p[i]);
          d[3 * i] = w.x, d[3 * i + 1] = w.y, d[3 * i + 2] = w.z;
        }
        return py::make_tuple(dirs, pdfs);
      },
      py::arg("g"), py::arg("u"),
      "(directions (N, 3), pdfs (N,)): the integrator's Henyey-Greenstein samples about +z for "
      "uniform numbers u (N, 2) (g clamped as the integrator does); for sampling tests.");
  m.def(
      "henyey_greenstein_pdf",
      [](float g, const FloatArray& cos_t) {
        FloatArray out({cos_t.size()});
        for (py::ssize_t i = 0; i < cos_t.size(); ++i) out.mutable_data()[i] = hg_phase(clamp_phase_g(g), cos_t.data()[i]);
        return out;
      },
      py::arg("g"), py::arg("cos_theta"), "The phase function's density at the given cosines.");
  // The Volume Scatter node's phases by name and parameters, as the integrator builds them: one
  // lobe, or Mie's two (weights: their sigma_s for a white 1).
  struct Lobes {
    PhaseLobe l[kMaxPhaseLobes];
    int n = 0;
  };
  const auto make_lobes = [](const std::string& type, const std::vector<float>& prm) {
    Float4 f;
    if (prm.size() > 0) f.x = prm[0];
    if (prm.size() > 1) f.y = prm[1];
    const auto* at = std::find(std::begin(kVolumeLobeNames), std::end(kVolumeLobeNames), type);
    if (at == std::end(kVolumeLobeNames))
      throw std::invalid_argument("unknown phase '" + type + "' (hg, draine, ff, rayleigh, mie)");
    Lobes lobes;
    add_phase_lobes(VolumeLobeType(at - std::begin(kVolumeLobeNames)), f, Vec3(1.0f), lobes.l, lobes.n);
    return lobes;
  };
  m.def(
      "sample_phase",
      [make_lobes](const std::string& type, const std::vector<float>& params, const FloatArray& u) {
        if (u.ndim() != 2 || u.shape(1) != 2) throw std::invalid_argument("u must have shape (N, 2)");
        const Lobes lobes = make_lobes(type, params);
        FloatArray dirs({u.shape(0), py::ssize_t(3)}), pdfs({u.shape(0)});
        const float* up = u.data();
        float* d = dirs.mutable_data();
        float* p = pdfs.mutable_data();
        for (py::ssize_t i = 0; i < u.shape(0); ++i) {
          // A lobe by its weight (u1 reused), then its sample; the pdf is the mixture's.
          float u1 = up[2 * i], acc = 0.0f;
          int k = lobes.n - 1;
          for (int j = 0; j < lobes.n; ++j) {
            const float w = lobes.l[j].sigma_s.x;
            if (u1 < acc + w) {
              k = j;
              u1 = std::min((u1 - acc) / w, 1.0f - 1e-7f);
              break;
            }
            acc += w;
          }
          float pk;
          const Vec3 w = phase_sample(lobes.l[k].phase, Vec3(0.0f, 0.0f, 1.0f), u1, up[2 * i + 1], pk);
          p[i] = 0.0f;
          for (int j = 0; j < lobes.n; ++j)
            p[i] += lobes.l[j].sigma_s.x * (j == k ? pk : phase_eval(lobes.l[j].phase, w.z));
          d[3 * i] = w.x, d[3 * i + 1] = w.y, d[3 * i + 2] = w.z;
        }
        return py::make_tuple(dirs, pdfs);
      },
      py::arg("type"), py::arg("params"), py::arg("u"),
      "(directions (N, 3), pdfs (N,)): the integrator's samples of a phase function about +z: type 'hg' (g), "
      "'draine' (g, alpha), 'ff' (backscatter, IOR), 'rayleigh' (), 'mie' (diameter: its two lobes by weight); "
      "for sampling tests.");
  m.def(
      "phase_pdf",
      [make_lobes](const std::string& type, const std::vector<float>& params, const FloatArray& cos_t) {
        const Lobes lobes = make_lobes(type, params);
        FloatArray out({cos_t.size()});
        for (py::ssize_t i = 0; i < cos_t.size(); ++i) {
          float v = 0.0f;
          for (int j = 0; j < lobes.n; ++j) v += lobes.l[j].sigma_s.x * phase_eval(lobes.l[j].phase, cos_t.data()[i]);
          out.mutable_data()[i] = v;
        }
        return out;
      },
      py::arg("type"), py::arg("params"), py::arg("cos_theta"), "A phase function's density at the given cosines.");
  m.def(
      "mie_fit",
      [](float d) {
        const MieFit f = mie_fit(d);
        return py::make_tuple(f.g_hg, f.g_d, f.alpha, f.w);
      },
      py::arg("diameter"),
      "(g_hg, g_draine, alpha, draine weight): Cycles' Mie fit for droplets of this diameter (um).");
  m.def(
      "sample_free_flight",
      [](const py::object& sigma_t, const FloatArray& u) {
        if (u.ndim() != 2 || u.shape(1) != 2) throw std::invalid_argument("u must have shape (N, 2)");
        const Vec3 st = to_color(sigma_t, "sigma_t");
        FloatArray t({u.shape(0)});
        for (py::ssize_t i = 0; i < u.shape(0); ++i)
          t.mutable_data()[i] = sample_free_flight(st, u.data()[2 * i], u.data()[2 * i + 1]);
        return t;
      },
      py::arg("sigma_t"), py::arg("u"),
      "The integrator's free-flight distances in a homogeneous medium of RGB extinction sigma_t for "
      "uniform numbers u (N, 2); for sampling tests (their density: the channels' average).");
  m.def(
      "sample_equiangular",
      [](const py::object& origin, const py::object& direction, float t_max, const py::object& light,
         const FloatArray& u) {
        if (u.ndim() != 1) throw std::invalid_argument("u must have shape (N,)");
        const Vec3 o = to_point(origin, "origin"), d = normalize(to_point(direction, "direction"));
        const EquiangularSegment e = equiangular_segment(o, d, t_max, to_point(light, "light"));
        FloatArray t({u.shape(0)}), pdf({u.shape(0)});
        for (py::ssize_t i = 0; i < u.shape(0); ++i) {
          t.mutable_data()[i] = e.valid ? sample_equiangular(e, u.data()[i]) : NAN;
          pdf.mutable_data()[i] = equiangular_pdf(e, t.data()[i]);
        }
        return py::make_tuple(t, pdf);
      },
      py::arg("origin"), py::arg("direction"), py::arg("t_max"), py::arg("light"), py::arg("u"),
      "The integrator's equiangular distances along a ray towards a point on a light (Kulla and "
      "Fajardo), for uniform numbers u (N,): (t, pdf); NaN where the light lies on the ray's line.");
  m.def(
      "cryptomatte_hash",
      [](const std::string& name) { return murmur3_32(name.data(), name.size(), 0); },
      py::arg("name"),
      "MurmurHash3_32 (seed 0) of a name's UTF-8 bytes: its Cryptomatte hash, as Cycles and "
      "Blender's manifests write it (\"%08x\").");
  m.def(
      "cryptomatte_id", [](uint32_t hash) { return cryptomatte_float(hash); }, py::arg("hash"),
      "The float id a Cryptomatte pass stores for a hash (the specification's uint32_to_float32).");
  m.def(
      "object_random_id",
      [](const std::string& name) {
        // Cycles' id of an object that is not an instance: hash_string (i * 37 + c over the
        // name's UTF-8 bytes, unsigned: what Blender's Cycles gives for non-ASCII names) then
        // lookup3 of (that, 0).
        uint32_t h = 0;
        for (const char c : name) h = h * 37u + uint32_t(uint8_t(c));
        return lookup3::hash(h, 0u);
      },
      py::arg("name"), "Cycles' random id of a (non-instanced) object named `name`.");
  m.def(
      "hash_uint2", [](uint32_t a, uint32_t b) { return lookup3::hash(a, b); }, py::arg("a"), py::arg("b"),
      "Cycles' hash_uint2: lookup3 of the two 32-bit words (a view's seed under multiview).");
  m.def(
      "hash_uint2_to_float", [](uint32_t a, uint32_t b) { return lookup3::to_unit(lookup3::hash(a, b)); },
      py::arg("a"), py::arg("b"),
      "Cycles' hash_uint2_to_float: lookup3 of (a, b) over 0xFFFFFFFF, in float (Particle Info's Random "
      "is that of (particle index, 0)).");
  m.def(
      "hash_buffer",
      [](const py::object& data, uint64_t seed) {
        Py_buffer view;  // any C-contiguous buffer (numpy arrays, bytes); others raise BufferError
        if (PyObject_GetBuffer(data.ptr(), &view, PyBUF_C_CONTIGUOUS) != 0) throw py::error_already_set();
        const std::unique_ptr<Py_buffer, void (*)(Py_buffer*)> held(&view, PyBuffer_Release);
        py::gil_scoped_release release;
        return xxh64(view.buf, size_t(view.len), seed);
      },
      py::arg("data"), py::arg("seed") = 0,
      "XXH64 of a C-contiguous buffer's bytes (a numpy array, bytes): a fast non-cryptographic 64-bit hash, "
      "for change detection.");
  m.def(
      "island_random",
      [](int64_t vertices, const I32Array& edges) {
        if (vertices < 0) throw std::invalid_argument("vertices must be >= 0");
        if (edges.ndim() != 2 || edges.shape(1) != 2) throw std::invalid_argument("edges must have shape (E, 2)");
        const size_t n = size_t(vertices), ne = size_t(edges.shape(0));
        const int32_t* e = edges.data();
        for (size_t i = 0; i < 2 * ne; ++i)
          if (e[i] < 0 || size_t(e[i]) >= n) throw std::invalid_argument("edge vertex index out of range");
        py::array_t<float> out{py::ssize_t(vertices)};
        float* o = out.mutable_data();
        {
          py::gil_scoped_release release;
          // Cycles' attr_create_random_per_island: a disjoint set of the vertices joined along
          // the edges in their stored order (union by rank, path compression, as its
          // util/disjoint_set.h), each vertex valued by the hash of its set's root.
          std::vector<uint32_t> parent(n), rank(n, 0);
          for (size_t i = 0; i < n; ++i) parent[i] = uint32_t(i);
          auto find = [&](uint32_t x) {
            uint32_t root = x;
            while (parent[root] != root) root = parent[root];
            while (parent[x] != root) {
              const uint32_t up = parent[x];
              parent[x] = root;
              x = up;
            }
            return root;
          };
          for (size_t i = 0; i < ne; ++i) {
            uint32_t a = find(uint32_t(e[2 * i])), b = find(uint32_t(e[2 * i + 1]));
            if (a == b) continue;
            if (rank[a] < rank[b]) std::swap(a, b);
            parent[b] = a;
            if (rank[a] == rank[b]) ++rank[a];
          }
          for (size_t i = 0; i < n; ++i) o[i] = lookup3::to_unit(lookup3::hash(find(uint32_t(i))));
        }
        return out;
      },
      py::arg("vertices"), py::arg("edges"),
      "Per vertex: Cycles' Random Per Island of its mesh island (islands joined along `edges`).");
  m.def(
      "polygon_face_offsets",
      [](const I32Array& tri_faces, int64_t faces, int64_t corners) -> py::object {
        if (tri_faces.ndim() != 1) throw std::invalid_argument("triangle_faces must have shape (T,)");
        if (faces < 0 || corners < 0) throw std::invalid_argument("faces and corners must be >= 0");
        py::array_t<int32_t> out(py::ssize_t(faces) + 1);
        bool ok;
        {
          py::gil_scoped_release release;
          ok = polygon_offsets_from_triangle_faces(tri_faces.data(), size_t(tri_faces.shape(0)), size_t(faces),
                                                   size_t(corners), out.mutable_data());
        }
        return ok ? py::object(out) : py::none();
      },
      py::arg("triangle_faces"), py::arg("faces"), py::arg("corners"),
      "int32 (F + 1,) face offsets (face f: corners offsets[f] to offsets[f + 1] - 1) from the face of every "
      "triangle of a triangulation listed face by face (Blender's loop_triangle_polygons: a face of k corners has "
      "k - 2 triangles); None unless they are in that order, every face has a triangle and the corners add up.");
  m.def(
      "subdivide_mesh",
      [polygon_mesh](const FloatArray& positions, const I32Array& corner_verts, const I32Array& offsets,
                     const FloatArray& matrix, const py::object& camera_position, float pixel_size, bool ortho,
                     float dicing_rate, int max_level, const py::object& crease_edges_obj,
                     const py::object& crease_sharpness_obj, const py::object& vertex_sharpness_obj,
                     bool catmull_clark, bool smooth_corners, int64_t max_quads, float offscreen_scale,
                     const py::object& camera_axes, const py::object& frame) {
        SubdivisionCage cage;
        cage.mesh = polygon_mesh(positions, corner_verts, offsets);
        cage.catmull_clark = catmull_clark;
        cage.smooth_corners = smooth_corners;
        I32Array ce;
        FloatArray cs, vs;
        if (!crease_edges_obj.is_none()) {
          ce = crease_edges_obj.cast<I32Array>();
          cs = crease_sharpness_obj.cast<FloatArray>();
          if (ce.ndim() != 2 || ce.shape(1) != 2 || cs.ndim() != 1 || cs.shape(0) != ce.shape(0))
            throw std::invalid_argument("crease_edges must have shape (K, 2) and crease_sharpness (K,)");
          cage.crease_edges = ce.data(), cage.crease_sharpness = cs.data(), cage.creases = size_t(ce.shape(0));
        }
        if (!vertex_sharpness_obj.is_none()) {
          vs = vertex_sharpness_obj.cast<FloatArray>();
          if (vs.ndim() != 1 || size_t(vs.shape(0)) != cage.mesh.vertices)
            throw std::invalid_argument("vertex_sharpness must have shape (V,)");
          cage.vertex_sharpness = vs.data();
        }
        DicingCamera cam;
        cam.to_world = to_mat4(matrix, "subdivide_mesh matrix");
        cam.position = to_point(camera_position, "camera_position");
        cam.ortho = ortho;
        if (!(pixel_size > 0.0f) || !std::isfinite(pixel_size)) throw std::invalid_argument("pixel_size must be > 0");
        if (!(dicing_rate > 0.0f) || !std::isfinite(dicing_rate)) throw std::invalid_argument("dicing_rate must be > 0");
        if (max_quads < 1) throw std::invalid_argument("max_quads must be >= 1");
        cam.pixel_size = pixel_size, cam.dicing_rate = dicing_rate, cam.max_level = max_level;
        cam.max_quads = size_t(max_quads);
        if (offscreen_scale > 1.0f) {
          if (!std::isfinite(offscreen_scale)) throw std::invalid_argument("offscreen_scale must be finite");
          if (camera_axes.is_none() || frame.is_none())
            throw std::invalid_argument("offscreen_scale > 1 needs camera_axes and frame");
          const auto axes = camera_axes.cast<py::sequence>();
          const auto fr = frame.cast<py::sequence>();
          if (axes.size() != 3 || fr.size() != 4)
            throw std::invalid_argument("camera_axes must be 3 vectors and frame 4 numbers");
          cam.right = normalize(to_point(axes[0], "camera_axes"));
          cam.up = normalize(to_point(axes[1], "camera_axes"));
          cam.forward = normalize(to_point(axes[2], "camera_axes"));
          for (int i = 0; i < 4; ++i) cam.frame[i] = fr[i].cast<float>();
          if (!(cam.frame[0] < cam.frame[1] && cam.frame[2] < cam.frame[3]))
            throw std::invalid_argument("frame must be (left, right, bottom, top) with left < right, bottom < top");
          cam.offscreen_scale = offscreen_scale;
        }
        DicedMesh d;
        {
          py::gil_scoped_release release;
          d = subdivide_and_dice(cage, cam);
        }
        const py::ssize_t nv = py::ssize_t(d.positions.size()), nt = py::ssize_t(d.tri_face.size());
        FloatArray pos({nv, py::ssize_t(3)}), uv({nt, py::ssize_t(3), py::ssize_t(2)});
        std::memcpy(pos.mutable_data(), d.positions.data(), sizeof(float) * 3 * size_t(nv));
        std::memcpy(uv.mutable_data(), d.tri_uv.data(), sizeof(float) * 6 * size_t(nt));
        py::array_t<int32_t> tris({nt, py::ssize_t(3)}), face(nt), sub(nt);
        std::memcpy(tris.mutable_data(), d.triangles.data(), sizeof(int32_t) * 3 * size_t(nt));
        std::memcpy(face.mutable_data(), d.tri_face.data(), sizeof(int32_t) * size_t(nt));
        std::memcpy(sub.mutable_data(), d.tri_sub.data(), sizeof(int32_t) * size_t(nt));
        py::dict out;
        out["positions"] = pos, out["triangles"] = tris, out["triangle_faces"] = face;
        out["triangle_subpatches"] = sub, out["triangle_uvs"] = uv;
        out["level"] = d.level, out["capped"] = d.capped, out["max_edge_factor"] = d.max_edge_factor;
        return out;
      },
      py::arg("positions"), py::arg("corner_verts"), py::arg("face_offsets"), py::arg("matrix"),
      py::arg("camera_position"), py::arg("pixel_size"), py::arg("ortho") = false, py::arg("dicing_rate") = 1.0f,
      py::arg("max_level") = 12, py::arg("crease_edges") = py::none(), py::arg("crease_sharpness") = py::none(),
      py::arg("vertex_sharpness") = py::none(), py::arg("catmull_clark") = true, py::arg("smooth_corners") = true,
      py::arg("max_quads") = int64_t(1) << 22, py::arg("offscreen_scale") = 1.0f,
      py::arg("camera_axes") = py::none(), py::arg("frame") = py::none(),
      "Adaptive subdivision of a polygon cage (object space; matrix: object to world): its Catmull-Clark limit "
      "surface (or Simple subdivision) diced so edges project to about dicing_rate pixels (pixel_size: a pixel's "
      "world size per unit distance from camera_position, or absolute if ortho), edge factors up to 2^max_level "
      "and shared by neighbouring patches. A dict: positions (V, 3), triangles (T, 3), triangle_faces (T,) cage "
      "face, triangle_subpatches (T,) n-gon corner (0 for quads), triangle_uvs (T, 3, 2) patch coordinates, "
      "level, capped (max_quads lowered the level), max_edge_factor. offscreen_scale > 1 (Cycles' "
      "offscreen_dicing_scale) grows the pixel outside the view: camera_axes (right, up, forward; world) and "
      "frame (left, right, bottom, top of the view at unit depth, or in units if ortho).");
  m.def(
      "dicing_pixel_size",
      [](const py::object& point, const py::object& camera_position, float pixel_size, bool ortho,
         float offscreen_scale, const py::object& camera_axes, const py::object& frame) {
        DicingCamera cam;
        cam.position = to_point(camera_position, "camera_position");
        cam.pixel_size = pixel_size, cam.ortho = ortho, cam.offscreen_scale = offscreen_scale;
        const auto axes = camera_axes.cast<py::sequence>();
        const auto fr = frame.cast<py::sequence>();
        if (axes.size() != 3 || fr.size() != 4) throw std::invalid_argument("camera_axes: 3 vectors, frame: 4");
        cam.right = normalize(to_point(axes[0], "camera_axes"));
        cam.up = normalize(to_point(axes[1], "camera_axes"));
        cam.forward = normalize(to_point(axes[2], "camera_axes"));
        for (int i = 0; i < 4; ++i) cam.frame[i] = fr[i].cast<float>();
        return dicing_pixel_size(cam, to_point(point, "point"));
      },
      py::arg("point"), py::arg("camera_position"), py::arg("pixel_size"), py::arg("ortho"), py::arg("offscreen_scale"),
      py::arg("camera_axes"), py::arg("frame"),
      "The world size of a pixel at point that subdivide_mesh divides edge lengths by (for tests).");
  m.def(
      "polygon_vertex_normals",
      [polygon_mesh](const FloatArray& positions, const I32Array& corner_verts, const I32Array& offsets, int threads) {
        const PolygonMesh pm = polygon_mesh(positions, corner_verts, offsets);
        FloatArray out({py::ssize_t(pm.vertices), py::ssize_t(3)});
        Vec3* dst = reinterpret_cast<Vec3*>(out.mutable_data());
        {
          py::gil_scoped_release release;
          polygon_vertex_normals(pm, dst, threads);
        }
        return out;
      },
      py::arg("positions"), py::arg("corner_verts"), py::arg("face_offsets"), py::arg("threads") = 0,
      "float32 (V, 3): smooth vertex normals of a polygon mesh, corner-angle-weighted face normals (as "
      "Blender's vertex normals).");
  m.def(
      "polygon_corner_normals",
      [polygon_mesh](const FloatArray& positions, const I32Array& corner_verts, const I32Array& offsets,
                     const I32Array& corner_edges, int64_t edges, const py::object& sharp_edges_obj,
                     const py::object& sharp_faces_obj, int threads) {
        const PolygonMesh pm = polygon_mesh(positions, corner_verts, offsets);
        if (corner_edges.ndim() != 1 || size_t(corner_edges.shape(0)) != pm.corners)
          throw std::invalid_argument("corner_edges must have shape (C,)");
        if (edges < 0) throw std::invalid_argument("edges must be >= 0");
        using BoolArray = py::array_t<uint8_t, py::array::c_style | py::array::forcecast>;
        BoolArray sharp_edges, sharp_faces;
        if (!sharp_edges_obj.is_none()) {
          sharp_edges = sharp_edges_obj.cast<BoolArray>();
          if (sharp_edges.ndim() != 1 || sharp_edges.shape(0) != edges)
            throw std::invalid_argument("sharp_edges must have shape (edges,)");
        }
        if (!sharp_faces_obj.is_none()) {
          sharp_faces = sharp_faces_obj.cast<BoolArray>();
          if (sharp_faces.ndim() != 1 || size_t(sharp_faces.shape(0)) != pm.faces)
            throw std::invalid_argument("sharp_faces must have shape (F,)");
        }
        FloatArray out({py::ssize_t(pm.corners), py::ssize_t(3)});
        Vec3* dst = reinterpret_cast<Vec3*>(out.mutable_data());
        const uint8_t* se = sharp_edges_obj.is_none() ? nullptr : sharp_edges.data();
        const uint8_t* sf = sharp_faces_obj.is_none() ? nullptr : sharp_faces.data();
        {
          py::gil_scoped_release release;
          polygon_corner_normals(pm, corner_edges.data(), size_t(edges), se, sf, dst, threads);
        }
        return out;
      },
      py::arg("positions"), py::arg("corner_verts"), py::arg("face_offsets"), py::arg("corner_edges"), py::arg("edges"),
      py::arg("sharp_edges") = py::none(), py::arg("sharp_faces") = py::none(), py::arg("threads") = 0,
      "float32 (C, 3): per-corner normals of a polygon mesh with sharp edges/faces (smooth fans across manifold, "
      "consistently wound, unmarked edges; as Blender's corner normals without custom normals).");
  m.def(
      "sky_texture",
      [](const std::string& sky_type, float sun_elevation, float sun_rotation, float sun_size, float sun_intensity,
         bool sun_disc, float altitude, float air, float dust, float ozone, const py::object& sun_direction,
         float turbidity, float ground_albedo, const py::object& xyz_to_rgb) {
        float mat[9];
        xyz_matrix(xyz_to_rgb, mat);
        std::shared_ptr<const SkyModel> sky;
        if (sky_type == "NISHITA") {
          const SkyParams p = sky_params(sun_elevation, sun_rotation, sun_size, sun_intensity, sun_disc, altitude, air,
                                         dust, ozone);
          py::gil_scoped_release release;
          sky = nishita_sky(p, mat);
        } else if (sky_type == "PREETHAM" || sky_type == "HOSEK_WILKIE") {
          const Vec3 sun = to_point(sun_direction, "sun_direction");
          if (sky_type == "PREETHAM") sky = std::make_shared<const SkyModel>(sun, turbidity, mat);
          else sky = std::make_shared<const SkyModel>(sun, turbidity, ground_albedo, mat);
        } else {
          throw std::invalid_argument("sky_type must be NISHITA, PREETHAM or HOSEK_WILKIE, not '" + sky_type + "'");
        }
        return std::const_pointer_cast<SkyModel>(sky);
      },
      py::arg("sky_type") = "NISHITA", py::arg("sun_elevation") = 0.2617994f, py::arg("sun_rotation") = 0.0f,
      py::arg("sun_size") = 0.009512f, py::arg("sun_intensity") = 1.0f, py::arg("sun_disc") = true,
      py::arg("altitude") = 0.0f, py::arg("air") = 1.0f, py::arg("dust") = 1.0f, py::arg("ozone") = 1.0f,
      py::arg("sun_direction") = py::make_tuple(0.0f, 0.0f, 1.0f), py::arg("turbidity") = 2.2f,
      py::arg("ground_albedo") = 0.3f, py::arg("xyz_to_rgb") = py::none(),
      "A Sky Texture node's SkyTexture for material programs (op 'tex_sky'): the settings of set_world_sky "
      "(NISHITA), set_world_preetham (PREETHAM) or set_world_hosek (HOSEK_WILKIE).");
  m.def("sky_radiance", &sky_radiance, py::arg("directions"), py::arg("sun_elevation") = 0.2617994f,
        py::arg("sun_rotation") = 0.0f, py::arg("sun_size") = 0.009512f, py::arg("sun_intensity") = 1.0f,
        py::arg("sun_disc") = true, py::arg("altitude") = 0.0f, py::arg("air") = 1.0f, py::arg("dust") = 1.0f,
        py::arg("ozone") = 1.0f, py::arg("xyz_to_rgb") = py::none(),
        "Radiance (N, 3) of Blender's Nishita Sky Texture along directions (N, 3), as set_world_sky "
        "evaluates it (strength 1).");
  m.def(
      "motion_transform",
      [](const py::object& steps, float time) {
        std::vector<DecomposedTransform> d;
        if (!decompose_motion(to_motion(steps, "motion"), d)) throw std::invalid_argument("motion steps are singular or not finite");
        return from_mat4(motion_transform_at(d.data(), uint32_t(d.size()), time));
      },
      py::arg("steps"), py::arg("time"),
      "The object-to-world matrix at shutter time `time` of motion steps (S, 4, 4), interpolated as "
      "rays see it (translation and scale linearly, rotation by slerp). For tests.");
  m.def("barycentric_error_bound", [] { return gamma_bound(7); },
        "The relative bound gamma(7): |error(b0 v0 + b1 v1 + b2 v2)| <= gamma(7) (|b0 v0| + |b1 v1| + |b2 v2|).");
  m.def(
      "bsdf_sample",
      [](const std::string& kind, const py::dict& params, const py::object& wo_obj, const FloatArray& u) {
        const Bsdf bsdf = make_test_bsdf(kind, params);
        const Vec3 wo = normalize(to_point(wo_obj, "wo"));
        if (u.ndim() != 2 || u.shape(1) != 3) throw std::invalid_argument("u must have shape (N, 3)");
        const py::ssize_t n = u.shape(0);
        FloatArray wi({n, py::ssize_t(3)}), weight({n, py::ssize_t(3)});
        py::array_t<float> pdf(n);
        py::array_t<int32_t> flags(n);
        const float* pu = u.data();
        for (py::ssize_t i = 0; i < n; ++i) {
          BsdfSample bs;
          const bool ok = bsdf_sample(bsdf, wo, {pu[3 * i], pu[3 * i + 1]}, pu[3 * i + 2], bs);
          const Vec3 w = ok ? bs.wi : Vec3(0.0f), g = ok ? bs.weight : Vec3(0.0f);
          for (int k = 0; k < 3; ++k) {
            wi.mutable_data()[3 * i + k] = w[k];
            weight.mutable_data()[3 * i + k] = g[k];
          }
          pdf.mutable_data()[i] = ok ? bs.pdf : 0.0f;
          flags.mutable_data()[i] = ok ? bs.flags : -1;
        }
        return py::make_tuple(wi, weight, pdf, flags);
      },
      py::arg("kind"), py::arg("params"), py::arg("wo"), py::arg("u"),
      "Samples a BSDF in its local frame (+Z normal): (wi, weight, pdf, flags); flags -1 = no sample.");
  m.def(
      "caustics_keep",
      [](const std::string& kind, const py::dict& params, bool reflective, bool refractive) {
        Bsdf b = make_test_bsdf(kind, params);
        const uint8_t off =
            uint8_t((reflective ? 0 : kCausticsNoReflective) | (refractive ? 0 : kCausticsNoRefractive));
        if (!caustics_keep(b, off)) return py::object(py::none());
        const auto* d = std::get_if<DielectricBsdf>(&b);
        return d ? py::object(py::make_tuple(d->reflection, d->transmission)) : py::object(py::bool_(true));
      },
      py::arg("kind"), py::arg("params"), py::arg("reflective"), py::arg("refractive"),
      "Cycles' caustics toggles on one BSDF after a diffuse bounce (caustics_keep): None where they drop "
      "it, (reflection, transmission) for a dielectric they keep, else True.");
  m.def("filter_glossy_roughness", &filter_glossy_roughness, py::arg("filter_glossy"), py::arg("min_pdf"),
        "Filter Glossy's roughness (alpha) at a vertex: sqrt(1 - filter_glossy min_pdf) / 2 where that product "
        "is below 1, else 0 (filter_glossy: 1 / Cycles' blur_glossy; 0: off).");
  m.def(
      "sheen_albedo",
      [](float roughness, float cos_view) {
        float albedo;
        SheenBsdf::setup(roughness, cos_view, albedo);
        return albedo;
      },
      py::arg("roughness"), py::arg("cos_view"),
      "The microfibre sheen's fitted albedo (Zeltner et al. 2022, Cycles' table) for a view cosine.");
  m.def(
      "bsdf_eval",
      [](const std::string& kind, const py::dict& params, const py::object& wo_obj, const FloatArray& wi,
         bool sampled) {
        const Bsdf bsdf = make_test_bsdf(kind, params);
        const auto* hair = std::get_if<HairBsdf>(&bsdf);
        if (sampled && !hair) throw std::invalid_argument("sampled=True: only the Hair BSDF evaluates a sample apart");
        const Vec3 wo = normalize(to_point(wo_obj, "wo"));
        if (wi.ndim() != 2 || wi.shape(1) != 3) throw std::invalid_argument("wi must have shape (N, 3)");
        const py::ssize_t n = wi.shape(0);
        FloatArray f({n, py::ssize_t(3)});
        py::array_t<float> pdf(n);
        const Vec3* w = reinterpret_cast<const Vec3*>(wi.data());
        for (py::ssize_t i = 0; i < n; ++i) {
          float p;
          const Vec3 v = sampled ? hair->eval_sampled(wo, w[i], p) : bsdf_eval(bsdf, wo, w[i], p);
          for (int k = 0; k < 3; ++k) f.mutable_data()[3 * i + k] = v[k];
          pdf.mutable_data()[i] = p;
        }
        return py::make_tuple(f, pdf);
      },
      py::arg("kind"), py::arg("params"), py::arg("wo"), py::arg("wi"), py::arg("sampled") = false,
      "Evaluates f * |cos(wi)| and the sampling pdf of a BSDF in its local frame (sampled: the Hair "
      "BSDF's value along a direction it sampled itself, which Cycles' evaluation differs from).");

  m.def(
      "spherical_triangle_sample",
      [](const py::object& p_obj, const FloatArray& tri, const FloatArray& u) {
        if (tri.ndim() != 2 || tri.shape(0) != 3 || tri.shape(1) != 3)
          throw std::invalid_argument("tri must have shape (3, 3)");
        if (u.ndim() != 2 || u.shape(1) != 2) throw std::invalid_argument("u must have shape (N, 2)");
        const Vec3 p = to_point(p_obj, "p");
        const Vec3* v = reinterpret_cast<const Vec3*>(tri.data());
        const SphericalTriangle st = spherical_triangle(p, v[0], v[1], v[2]);
        const py::ssize_t n = u.shape(0);
        py::array_t<double> dirs({n, py::ssize_t(3)});
        py::array_t<bool> ok(n);
        const float* pu = u.data();
        for (py::ssize_t i = 0; i < n; ++i) {
          DVec3 d;
          const float ux = pu[2 * i], uy = pu[2 * i + 1];
          // The sampler's contract (the renderer's uniforms always keep it): u in [0, 1]^2.
          const bool in_range = ux >= 0.0f && ux <= 1.0f && uy >= 0.0f && uy <= 1.0f;
          const bool good = in_range && sample_spherical_triangle(st, {ux, uy}, d);
          ok.mutable_data()[i] = good;
          dirs.mutable_data()[3 * i] = good ? d.x : 0.0;
          dirs.mutable_data()[3 * i + 1] = good ? d.y : 0.0;
          dirs.mutable_data()[3 * i + 2] = good ? d.z : 0.0;
        }
        return py::make_tuple(st.solid_angle, dirs, ok);
      },
      py::arg("p"), py::arg("tri"), py::arg("u"),
      "The solid angle a triangle (3 x 3 corners) subtends at p, and the directions the light "
      "sampler draws in it for u (N x 2): (solid_angle, dirs, ok). Exposed for tests.");

  m.def(
      "spherical_rect_sample",
      [](const py::object& p_obj, const py::object& c_obj, const py::object& ex_obj, const py::object& ey_obj,
         const FloatArray& u) {
        if (u.ndim() != 2 || u.shape(1) != 2) throw std::invalid_argument("u must have shape (N, 2)");
        const SphericalRect r =
            spherical_rect(to_point(p_obj, "p"), to_point(c_obj, "corner"), to_point(ex_obj, "ex"), to_point(ey_obj, "ey"));
        const py::ssize_t n = u.shape(0);
        py::array_t<double> pts({n, py::ssize_t(3)});
        py::array_t<bool> ok(n);
        const float* pu = u.data();
        for (py::ssize_t i = 0; i < n; ++i) {
          DVec3 q;
          const float ux = pu[2 * i], uy = pu[2 * i + 1];
          const bool in_range = ux >= 0.0f && ux <= 1.0f && uy >= 0.0f && uy <= 1.0f;  // the sampler's contract
          const bool good = in_range && sample_spherical_rect(r, {ux, uy}, q);
          ok.mutable_data()[i] = good;
          pts.mutable_data()[3 * i] = good ? q.x : 0.0;
          pts.mutable_data()[3 * i + 1] = good ? q.y : 0.0;
          pts.mutable_data()[3 * i + 2] = good ? q.z : 0.0;
        }
        return py::make_tuple(r.solid_angle, pts, ok);
      },
      py::arg("p"), py::arg("corner"), py::arg("ex"), py::arg("ey"), py::arg("u"),
      "The solid angle a rectangle (corner, orthogonal edges ex, ey) subtends at p, and the points "
      "of it the light sampler draws for u (N x 2): (solid_angle, points, ok). Exposed for tests.");

  m.def(
      "sampler_values",
      [](uint32_t seed, uint64_t pixel, uint32_t sample, int dims, const std::string& type) {
        if (dims < 0 || dims > 1024) throw std::invalid_argument("dims must be in [0, 1024]");
        Sampler sampler(enum_from_name(type, "sampler", kSamplerNames), seed, pixel, sample);
        py::array_t<float> out({py::ssize_t(dims), py::ssize_t(2)});
        for (int d = 0; d < dims; ++d) {
          const Vec2 u = sampler.get2d();
          out.mutable_data()[2 * d] = u.x;
          out.mutable_data()[2 * d + 1] = u.y;
        }
        return out;
      },
      py::arg("seed"), py::arg("pixel"), py::arg("sample"), py::arg("dims"), py::arg("sampler") = "sobol",
      "The first `dims` 2-D draws of the sampler (a RenderSettings.sampler name) for (seed, pixel, "
      "sample): (dims, 2). Exposed for tests.");
  m.def(
      "sampler_roulette",
      [](uint32_t seed, uint64_t pixel, uint32_t sample, int bounce, const std::string& type) {
        const Sampler sampler(enum_from_name(type, "sampler", kSamplerNames), seed, pixel, sample);
        return sampler.own_roulette() ? sampler.roulette(bounce) : -1.0f;
      },
      py::arg("seed"), py::arg("pixel"), py::arg("sample"), py::arg("bounce"), py::arg("sampler") = "sobol",
      "The Russian roulette's own number at `bounce` (Cycles' PRNG_TERMINATE), or -1 where the "
      "sampler takes the light set's. Exposed for tests.");

  m.def(
      "pattern_sampler_values",
      [](const std::string& pattern, uint32_t seed, uint32_t length, int x, int y, int width, uint32_t sample,
         int dims, const std::string& type) {
        if (dims < 0 || dims > 1024) throw std::invalid_argument("dims must be in [0, 1024]");
        if (x < 0 || y < 0 || width <= x) throw std::invalid_argument("need 0 <= x < width and y >= 0");
        const PixelPatternMap map(enum_from_name(pattern, "pixel_pattern", kPixelPatternNames), seed, length);
        const uint64_t pixel = uint64_t(y) * uint64_t(width) + uint64_t(x);
        // The row's bases as the session finds them (digits reused from the left), checked
        // against the pixel's own.
        std::vector<PixelPatternMap::PixelBase> row(size_t(x) + 1);
        map.row_bases(0, x + 1, y, width, row.data());
        const PixelPatternMap::PixelBase own = map.pixel_base(x, y, width);
        if (own.key != row[size_t(x)].key || own.base != row[size_t(x)].base ||
            own.first_index != row[size_t(x)].first_index)
          throw std::logic_error("row_bases differs from pixel_base");
        const SobolIndex si = map.map(own, sample);
        Sampler sampler(enum_from_name(type, "sampler", kSamplerNames), seed, pixel, sample, si.key, si.index);
        py::array_t<float> out({py::ssize_t(dims), py::ssize_t(2)});
        for (int d = 0; d < dims; ++d) {
          const Vec2 u = sampler.get2d();
          out.mutable_data()[2 * d] = u.x;
          out.mutable_data()[2 * d + 1] = u.y;
        }
        return py::make_tuple(out, si.key, si.index, map.block_levels());
      },
      py::arg("pattern"), py::arg("seed"), py::arg("length"), py::arg("x"), py::arg("y"), py::arg("width"),
      py::arg("sample"), py::arg("dims"), py::arg("sampler") = "sobol",
      "The first `dims` 2-D draws of pixel (x, y)'s sample under a pixel pattern (a "
      "RenderSettings.pixel_pattern name) with chunk length `length`: (draws (dims, 2), sequence key, "
      "index, block levels). Exposed for tests.");

  py::class_<CameraDesc>(m, "Camera")
      .def(py::init<>())
      .def_property(
          "matrix_world", [](const CameraDesc& c) { return from_mat4(c.matrix_world); },
          [](CameraDesc& c, const FloatArray& a) { c.matrix_world = to_mat4(a, "matrix_world"); })
      .def_readwrite("lens", &CameraDesc::lens)
      .def_readwrite("sensor_width", &CameraDesc::sensor_width)
      .def_readwrite("sensor_height", &CameraDesc::sensor_height)
      .def_property(
          "sensor_fit",
          [](const CameraDesc& c) { return enum_name(c.sensor_fit, kSensorFitNames); },
          [](CameraDesc& c, const std::string& s) { c.sensor_fit = enum_from_name(s, "sensor_fit", kSensorFitNames, false); })
      .def_readwrite("shift_x", &CameraDesc::shift_x)
      .def_readwrite("shift_y", &CameraDesc::shift_y)
      .def_readwrite("clip_start", &CameraDesc::clip_start)
      .def_readwrite("clip_end", &CameraDesc::clip_end)
      .def_readwrite("pixel_aspect_x", &CameraDesc::pixel_aspect_x)
      .def_readwrite("pixel_aspect_y", &CameraDesc::pixel_aspect_y)
      .def_property(
          "type", [](const CameraDesc& c) { return enum_name(c.type, kCameraTypeNames); },
          [](CameraDesc& c, const std::string& s) { c.type = enum_from_name(s, "camera type", kCameraTypeNames, false); })
      .def_readwrite("ortho_scale", &CameraDesc::ortho_scale)
      .def_property(
          "panorama_type", [](const CameraDesc& c) { return enum_name(c.panorama_type, kPanoramaTypeNames); },
          [](CameraDesc& c, const std::string& s) {
            c.panorama_type = enum_from_name(s, "panorama_type", kPanoramaTypeNames, false);
          },
          "Blender's Camera.panorama_type, for type 'PANO'.")
      .def_readwrite("fisheye_fov", &CameraDesc::fisheye_fov)
      .def_readwrite("fisheye_lens", &CameraDesc::fisheye_lens)
      .def_readwrite("latitude_min", &CameraDesc::latitude_min)
      .def_readwrite("latitude_max", &CameraDesc::latitude_max)
      .def_readwrite("longitude_min", &CameraDesc::longitude_min)
      .def_readwrite("longitude_max", &CameraDesc::longitude_max)
      .def_property(
          "fisheye_polynomial",
          [](const CameraDesc& c) {
            const float* k = c.fisheye_polynomial;
            return py::make_tuple(k[0], k[1], k[2], k[3], k[4]);
          },
          [](CameraDesc& c, const std::vector<float>& v) {
            if (v.size() != 5) throw std::invalid_argument("fisheye_polynomial takes 5 values (k0..k4)");
            for (int i = 0; i < 5; ++i) c.fisheye_polynomial[i] = v[size_t(i)];
          },
          "k0..k4 of Blender's lens polynomial (theta = -(k0 + k1 r + ... + k4 r^4), r in mm).")
      .def_readwrite("central_cylindrical_range_u_min", &CameraDesc::cylinder_u_min)
      .def_readwrite("central_cylindrical_range_u_max", &CameraDesc::cylinder_u_max)
      .def_readwrite("central_cylindrical_range_v_min", &CameraDesc::cylinder_v_min)
      .def_readwrite("central_cylindrical_range_v_max", &CameraDesc::cylinder_v_max)
      .def_readwrite("central_cylindrical_radius", &CameraDesc::cylinder_radius)
      .def_property(
          "pano_viewplane",
          [](const CameraDesc& c) {
            const float* v = c.pano_viewplane;
            return py::make_tuple(v[0], v[1], v[2], v[3]);
          },
          [](CameraDesc& c, const std::vector<float>& v) {
            if (v.size() != 4) throw std::invalid_argument("pano_viewplane takes 4 values (left, right, bottom, top)");
            for (int i = 0; i < 4; ++i) c.pano_viewplane[i] = v[size_t(i)];
          },
          "The part of the panorama the frame spans, (left, right, bottom, top) in units where the "
          "camera frame is [0, 1]^2 (the viewport's region around the camera border).")
      .def_readwrite("pano_fit_aspect", &CameraDesc::pano_fit_aspect,
                     "Width over height the fisheye sensor is fitted to; 0: the frame's.")
      .def_property(
          "stereo_eye", [](const CameraDesc& c) { return enum_name(c.stereo_eye, kStereoEyeNames); },
          [](CameraDesc& c, const std::string& s) { c.stereo_eye = enum_from_name(s, "stereo_eye", kStereoEyeNames, false); },
          "Spherical stereo: 'NONE' (mono), 'LEFT' or 'RIGHT' (each ray moves -+ interocular_distance / 2 "
          "to its side; perspective and panoramic cameras).")
      .def_readwrite("interocular_distance", &CameraDesc::interocular_distance)
      .def_readwrite("convergence_distance", &CameraDesc::convergence_distance,
                     "Spherical stereo: where the eyes' rays meet (inf: parallel).")
      .def_readwrite("use_pole_merge", &CameraDesc::use_pole_merge)
      .def_readwrite("pole_merge_angle_from", &CameraDesc::pole_merge_angle_from)
      .def_readwrite("pole_merge_angle_to", &CameraDesc::pole_merge_angle_to)
      .def_readwrite("aperture_size", &CameraDesc::aperture_size)
      .def_readwrite("focus_distance", &CameraDesc::focus_distance)
      .def_readwrite("aperture_blades", &CameraDesc::aperture_blades)
      .def_readwrite("aperture_rotation", &CameraDesc::aperture_rotation)
      .def_readwrite("aperture_ratio", &CameraDesc::aperture_ratio)
      .def_readwrite("use_autofocus", &CameraDesc::use_autofocus)
      .def_readwrite("autofocus_x", &CameraDesc::autofocus_x)
      .def_readwrite("autofocus_y", &CameraDesc::autofocus_y)
      .def_property(
          "motion",
          [](const CameraDesc& c) -> py::object {
            if (c.motion.empty()) return py::none();
            FloatArray a({py::ssize_t(c.motion.size()), py::ssize_t(4), py::ssize_t(4)});
            auto w = a.mutable_unchecked<3>();
            for (size_t k = 0; k < c.motion.size(); ++k)
              for (int i = 0; i < 4; ++i)
                for (int j = 0; j < 4; ++j) w(py::ssize_t(k), i, j) = c.motion[k].m[i][j];
            return std::move(a);
          },
          [](CameraDesc& c, const py::object& o) { c.motion = to_motion(o, "camera motion"); },
          "Motion blur: matrix_world at each motion step over the shutter, (S, 4, 4) with S >= 2, or "
          "None (static). Steps that are not finite or singular leave the camera static.")
      .def_property(
          "pass_motion",
          [](const CameraDesc& c) -> py::object {
            if (c.pass_motion.empty()) return py::none();
            FloatArray a({py::ssize_t(2), py::ssize_t(4), py::ssize_t(4)});
            auto w = a.mutable_unchecked<3>();
            for (size_t k = 0; k < 2; ++k)
              for (int i = 0; i < 4; ++i)
                for (int j = 0; j < 4; ++j) w(py::ssize_t(k), i, j) = c.pass_motion[k].m[i][j];
            return std::move(a);
          },
          [](CameraDesc& c, const py::object& o) {
            std::vector<Mat4> m = to_motion(o, "camera pass_motion");
            if (!m.empty() && m.size() != 2) throw std::invalid_argument("camera pass_motion must be a (2, 4, 4) array");
            for (const Mat4& x : m)
              if (!x.is_finite()) m.clear();  // (not finite: still, as the shutter's motion)
            c.pass_motion = std::move(m);
          },
          "Vector pass: matrix_world at the previous and next frames, (2, 4, 4), or None (still).")
      .def_property(
          "shutter_curve", [](const CameraDesc& c) { return c.shutter_curve; },
          [](CameraDesc& c, const std::vector<float>& v) {
            if (v.size() > 65536) throw std::invalid_argument("shutter_curve takes at most 65536 values");
            c.shutter_curve = v;
          },
          "Motion blur: the shutter curve's values evenly over the shutter (Cycles samples 256); "
          "empty: a box shutter. Non-finite values count as 0; an all-zero curve is a box.")
      .def_readwrite("rolling_shutter", &CameraDesc::rolling_shutter,
                     "Cycles' Rolling Shutter 'TOP' (motion blur only): pixel rows are read from the top "
                     "of the frame down over the shutter.")
      .def_property(
          "rolling_shutter_duration", [](const CameraDesc& c) { return c.rolling_shutter_duration; },
          [](CameraDesc& c, float v) {
            if (!std::isfinite(v) || v < 0.0f || v > 1.0f)
              throw std::invalid_argument("rolling_shutter_duration must be in [0, 1]");
            c.rolling_shutter_duration = v;
          },
          "Cycles' Rolling Shutter Duration (0..1): a row's exposure as a share of the shutter "
          "(0: each row at one instant, 1: no rolling).")
      .def(
          "shutter_time",
          [](const CameraDesc& c, float u) {
            ShutterTable t;
            t.set_curve(c.shutter_curve);
            return t.sample(u);
          },
          py::arg("u"), "The shutter time (0..1) a camera ray gets for the uniform number u (for tests).")
      .def(
          "generate_ray",
          [](const CameraDesc& c, int width, int height, float x, float y, py::object lens, py::object time) {
            if (width < 1 || height < 1 || width > 65536 || height > 65536)
              throw std::invalid_argument("resolution must be in [1, 65536]");
            Vec2 u{0.5f, 0.5f};
            bool pinhole = lens.is_none();
            if (!pinhole) {
              auto t = lens.cast<std::pair<float, float>>();
              u = {t.first, t.second};
              if (!(u.x >= 0.0f && u.x <= 1.0f && u.y >= 0.0f && u.y <= 1.0f))
                throw std::invalid_argument("lens sample must be in [0, 1]^2");
            }
            const Camera cam(c, width, height);
            Ray r;
            if (!time.is_none()) {
              const float t = time.cast<float>();
              if (!(t >= 0.0f && t <= 1.0f)) throw std::invalid_argument("time must be in [0, 1]");
              r = cam.generate(x, y, u, t);
            } else {
              r = pinhole ? cam.generate_pinhole(x, y) : cam.generate(x, y, u);
            }
            return py::make_tuple(py::make_tuple(r.org.x, r.org.y, r.org.z), py::make_tuple(r.dir.x, r.dir.y, r.dir.z),
                                  r.tmax);
          },
          py::arg("width"), py::arg("height"), py::arg("x"), py::arg("y"), py::arg("lens") = py::none(),
          py::arg("time") = py::none(),
          "The camera ray through raster (x, y) of a width x height frame: (origin, direction, tmax). "
          "lens: a point of the unit square on the aperture, or None for the lens centre. tmax 0: no "
          "ray (outside a panorama's lens). time: the shutter time (0..1) of a moving camera "
          "(motion), or None for the still frame.")
      .def(
          "lens_view",
          [](const CameraDesc& c, int width, int height, const py::handle& point, std::pair<float, float> lens,
             py::object time) -> py::object {
            if (width < 1 || height < 1 || width > 65536 || height > 65536)
              throw std::invalid_argument("resolution must be in [1, 65536]");
            if (!(lens.first >= 0.0f && lens.first <= 1.0f && lens.second >= 0.0f && lens.second <= 1.0f))
              throw std::invalid_argument("lens sample must be in [0, 1]^2");
            const Camera cam(c, width, height);
            Camera::Frame f = cam.still_frame();
            if (!time.is_none()) {
              const float t = time.cast<float>();
              if (!(t >= 0.0f && t <= 1.0f)) throw std::invalid_argument("time must be in [0, 1]");
              f = cam.frame_at(t);
            }
            Vec3 eye;
            float rx, ry, dist, pdf;
            if (!cam.lens_view(f, to_point(point, "point"), {lens.first, lens.second}, eye, rx, ry, dist, pdf))
              return py::none();
            return py::make_tuple(rx, ry, dist, pdf, py::make_tuple(eye.x, eye.y, eye.z));
          },
          py::arg("width"), py::arg("height"), py::arg("point"), py::arg("lens") = std::make_pair(0.5f, 0.5f),
          py::arg("time") = py::none(),
          "A camera's view of a world point through the aperture point that the unit-square "
          "sample lens picks (what caustic light paths connect to): (raster x, raster y, distance from "
          "the lens point, pixel density (per unit solid angle; orthographic: distance^2 / (pixel area x "
          "cos)), the lens point), or None outside the "
          "clipping range or a panorama's image (for tests). A pinhole panorama: its inverse map and "
          "its pixel density per unit solid angle. time: the camera's frame at that shutter time.");

  // Path guiding's learnt field on its own, for tests of its sampling against its pdf.
  py::class_<GuidingField>(m, "GuidingField")
      .def(py::init<>())
      .def(
          "reset",
          [](GuidingField& g, const py::handle& lo, const py::handle& hi, float threshold) {
            Aabb b;
            b.grow(to_point(lo, "lo"));
            b.grow(to_point(hi, "hi"));
            g.reset(b, threshold);
          },
          py::arg("lo"), py::arg("hi"), py::arg("split_threshold"))
      .def(
          "record",
          [](GuidingField& g, const py::handle& p, const py::handle& w, float value, const py::handle& n) {
            g.record(to_point(p, "p"), to_point(n, "n"), to_point(w, "w"), value);
          },
          py::arg("p"), py::arg("w"), py::arg("value"), py::arg("n") = py::make_tuple(0.0f, 0.0f, 1.0f))
      .def(
          "record_photon",
          [](GuidingField& g, const py::handle& p, const py::handle& w, float value, const py::handle& n) {
            const Vec3 pp = to_point(p, "p");
            if (is_finite(pp)) g.record_photon(g.cell_of(pp, to_point(n, "n")), to_point(w, "w"), value);
          },
          py::arg("p"), py::arg("w"), py::arg("value"), py::arg("n") = py::make_tuple(0.0f, 0.0f, 1.0f))
      .def(
          "set_learn_probability", &GuidingField::set_learn_probability, py::arg("on"), py::arg("initial") = 0.5f,
          "Learn the guide's probability per cell (the candidate of least estimated second moment).")
      .def(
          "record_moment",
          [](GuidingField& g, const py::handle& p, float est, float q, float pb, float pg, const py::handle& n) {
            const Vec3 pp = to_point(p, "p");
            if (is_finite(pp)) g.record_moment(g.cell_of(pp, to_point(n, "n")), est, q, pb, pg);
          },
          py::arg("p"), py::arg("est"), py::arg("q"), py::arg("pb"), py::arg("pg"),
          py::arg("n") = py::make_tuple(0.0f, 0.0f, 1.0f),
          "A vertex's estimate over the pdf q it was drawn with, and the BSDF's and the guide's pdfs of its "
          "direction (for the learnt probability).")
      .def(
          "probability",
          [](const GuidingField& g, const py::handle& p, const py::handle& n) {
            return g.probability(g.cell_of(to_point(p, "p"), to_point(n, "n")));
          },
          py::arg("p"), py::arg("n") = py::make_tuple(0.0f, 0.0f, 1.0f))
      .def("set_directional_filter", &GuidingField::set_directional_filter, py::arg("on"))
      .def_property("photon_share", &GuidingField::photon_share, &GuidingField::set_photon_share)
      .def_property_readonly("photon_records", &GuidingField::photon_records)
      .def("end_iteration", &GuidingField::end_iteration, py::arg("samples"))
      .def(
          "sample",
          [](const GuidingField& g, const py::handle& p, float u1, float u2, const py::handle& n) {
            if (!(u1 >= 0.0f && u1 < 1.0f && u2 >= 0.0f && u2 < 1.0f))
              throw std::invalid_argument("u must lie in [0, 1)");
            float pdf = 0.0f;
            const Vec3 w = g.sample(to_point(p, "p"), to_point(n, "n"), {u1, u2}, pdf);
            return py::make_tuple(py::make_tuple(w.x, w.y, w.z), pdf);
          },
          py::arg("p"), py::arg("u1"), py::arg("u2"), py::arg("n") = py::make_tuple(0.0f, 0.0f, 1.0f))
      .def(
          "pdf",
          [](const GuidingField& g, const py::handle& p, const py::handle& w, const py::handle& n) {
            return g.pdf(to_point(p, "p"), to_point(n, "n"), normalize(to_point(w, "w")));
          },
          py::arg("p"), py::arg("w"), py::arg("n") = py::make_tuple(0.0f, 0.0f, 1.0f))
      .def_property_readonly("ready", &GuidingField::ready)
      .def_property_readonly("iterations", &GuidingField::iterations)
      .def_property_readonly("cells", &GuidingField::cells);

  py::class_<RenderSettings>(m, "RenderSettings")
      .def(py::init<>())
      .def_readwrite("width", &RenderSettings::width)
      .def_readwrite("height", &RenderSettings::height)
      .def_readwrite("samples", &RenderSettings::samples)
      .def_readwrite("time_limit", &RenderSettings::time_limit)
      .def_readwrite("max_bounces", &RenderSettings::max_bounces)
      .def_readwrite("seed", &RenderSettings::seed)
      .def_readwrite("threads", &RenderSettings::threads)
      .def_readwrite("tile_size", &RenderSettings::tile_size)
      .def_readwrite("use_nee", &RenderSettings::use_nee)
      .def_readwrite("volume_segment_nee", &RenderSettings::volume_segment_nee,
                     "Heterogeneous media: a light sample in every segment crossed, at a distance drawn from the "
                     "majorants (on), or only where delta tracking scatters (off)")
      .def_readwrite("volume_shared_shadow", &RenderSettings::volume_shared_shadow,
                     "Homogeneous scattering media: the equiangular and the distance-sampled light samples of a "
                     "segment share one shadow ray (on), or each traces its own (off)")
      .def_readwrite("volume_light_reach", &RenderSettings::volume_light_reach,
                     "Homogeneous scattering media: equiangular distances only where the light can shine (a "
                     "spot's cone, an area light's front: on), or along the whole segment (off)")
      .def_readwrite("volume_phase_mis", &RenderSettings::volume_phase_mis,
                     "Homogeneous scattering media: the free-flight point's phase sample weighed against both "
                     "light samples of its segment, the equiangular one's too (on), or against its own only (off)")
      .def_readwrite("volume_pass_through", &RenderSettings::volume_pass_through,
                     "Volume-only boundaries (a material with a Volume and no Surface) crossed without shading "
                     "them (on: the same image, faster), or shaded as any surface (off)")
      .def_property(
          "clamp_direct", [](const RenderSettings& s) { return s.clamp_direct; },
          [](RenderSettings& s, float v) { s.clamp_direct = clamp_setting(v, "clamp_direct"); },
          "Cycles' Clamp Direct (sample_clamp_direct, the same numbers): each contribution of light that arrives "
          "at the camera's first scattering vertex (or that the camera sees) is scaled down to |r| + |g| + |b| "
          "of at most 3 x this (grey light: each channel at most this); 0 = off (the default: unbiased). "
          "Negative or non-finite: 0, with a warning")
      .def_property(
          "clamp_indirect", [](const RenderSettings& s) { return s.clamp_indirect; },
          [](RenderSettings& s, float v) { s.clamp_indirect = clamp_setting(v, "clamp_indirect"); },
          "Cycles' Clamp Indirect (sample_clamp_indirect): the same for light that arrives after more "
          "scatterings (caustic light paths and their connections included); 0 = off (the default)")
      .def_property(
          "filter_glossy", [](const RenderSettings& s) { return s.filter_glossy; },
          [](RenderSettings& s, float v) { s.filter_glossy = clamp_setting(v, "filter_glossy", "no filtering"); },
          "Cycles' Filter Glossy (blur_glossy, the same number): after blurry bounces (a small smallest BSDF pdf "
          "along the path, min_ray_pdf), glossy, glass and Principled hair closures are made rougher, by "
          "sqrt(1 - pdf / this) / 2 at least (alpha): fewer fireflies from caustics, at the cost of accuracy "
          "(biased). 0 = off (Pathlight's default: unbiased; Cycles' default is 1). Negative or non-finite: 0, "
          "with a warning. Turns the caustic light paths off")
      .def_readwrite("caustics_reflective", &RenderSettings::caustics_reflective,
                     "Cycles' Reflective Caustics (default on): off drops glossy reflection closures (Glossy, "
                     "Metallic, Principled's metal, specular and coat, glass's reflection) at points a diffuse "
                     "bounce reached (biased, fewer fireflies). Off turns the caustic light paths off")
      .def_readwrite("caustics_refractive", &RenderSettings::caustics_refractive,
                     "Cycles' Refractive Caustics (default on): off drops refraction closures (Refraction, "
                     "glass's and Principled's transmission) at points a diffuse bounce reached. Off turns the "
                     "caustic light paths off")
      .def_readwrite("rr_start_bounce", &RenderSettings::rr_start_bounce,
                     "Russian roulette from this bounce on (default 3; 0 rolls at every vertex, as Cycles); "
                     "for measurements, the add-on leaves it")
      .def_property(
          "sampler", [](const RenderSettings& s) { return enum_name(s.sampler, kSamplerNames); },
          [](RenderSettings& s, const std::string& v) { s.sampler = enum_from_name(v, "sampler", kSamplerNames); })
      .def_property(
          "pixel_pattern", [](const RenderSettings& s) { return enum_name(s.pixel_pattern, kPixelPatternNames); },
          [](RenderSettings& s, const std::string& v) {
            s.pixel_pattern = enum_from_name(v, "pixel_pattern", kPixelPatternNames);
          },
          "Which sequence each pixel's samples take: 'independent' (its own), 'blue_noise' (a chunk of "
          "one sequence the pixels share, as Cycles' default), 'blue_noise_round' (chunks rounded up to "
          "a power of two), 'blue_noise_first' (sample 0 blue noise of its own, as Cycles' viewport)")
      .def_readwrite("pattern_samples", &RenderSettings::pattern_samples,
                     "Blue noise's chunk length: the frame's total samples, which the pieces of a split frame "
                     "must share (0: sample_offset + samples)")
      .def_readwrite("adaptive_threshold", &RenderSettings::adaptive_threshold)
      .def_readwrite("adaptive_min_samples", &RenderSettings::adaptive_min_samples)
      .def_readwrite("diffuse_bounces", &RenderSettings::diffuse_bounces)
      .def_readwrite("glossy_bounces", &RenderSettings::glossy_bounces)
      .def_readwrite("transmission_bounces", &RenderSettings::transmission_bounces)
      .def_readwrite("volume_bounces", &RenderSettings::volume_bounces)
      .def_readwrite("transparent_bounces", &RenderSettings::transparent_bounces,
                     "Transparent crossings (Transparent BSDF, Ray Portal) a path may make, Blender's Transparent "
                     "max bounces: the one past it ends the path at the next surface, and a shadow ray is blocked "
                     "by more transparent surfaces than this minus the path's crossings (as Cycles)")
      .def_property(
          "filter_type", [](const RenderSettings& s) { return enum_name(s.filter_type, kFilterNames); },
          [](RenderSettings& s, const std::string& v) { s.filter_type = enum_from_name(v, "filter_type", kFilterNames); })
      .def_readwrite("filter_width", &RenderSettings::filter_width)
      .def_readwrite("border_x", &RenderSettings::border_x)
      .def_readwrite("border_y", &RenderSettings::border_y)
      .def_readwrite("border_width", &RenderSettings::border_width)
      .def_readwrite("border_height", &RenderSettings::border_height)
      .def_property(
          "passes",
          [](const RenderSettings& s) {
            std::vector<std::string> names;
            for (int p = 0; p < kPassCount; ++p)
              if (s.passes & pass_bit(Pass(p))) names.emplace_back(pass_desc(Pass(p)).name);
            return names;
          },
          [](RenderSettings& s, const std::vector<std::string>& names) {
            uint32_t bits = 0;
            for (const auto& n : names) bits |= pass_bit(pass_by_name(n));
            s.passes = bits;
          })
      .def_readwrite("film_transparent", &RenderSettings::film_transparent)
      .def_readwrite("film_transparent_glass", &RenderSettings::film_transparent_glass,
                     "Cycles' Transparent Glass (with film_transparent): the world seen through transmission "
                     "no rougher than film_transparent_roughness (glass, refraction) is transparent in alpha "
                     "and left out of the colour, as through Transparent BSDFs")
      .def_property(
          "film_transparent_roughness", [](const RenderSettings& s) { return s.film_transparent_roughness; },
          [](RenderSettings& s, float v) {
            s.film_transparent_roughness = clamp_setting(v, "film_transparent_roughness", "smooth glass only");
          },
          "Cycles' Roughness Threshold of Transparent Glass (default 0.1): transmission of a closure whose "
          "roughness (Blender's, its alphas' geometric mean square-rooted) is at most this. Negative or "
          "non-finite: 0, with a warning")
      .def_property(
          "ao_bounces", [](const RenderSettings& s) { return s.ao_bounces; },
          [](RenderSettings& s, int v) {
            if (v < 0) {
              py::module_::import("warnings").attr("warn")("ao_bounces must be >= 0 (0: no Fast GI Replace); " +
                                                           std::to_string(v) + " is treated as 0");
              v = 0;
            }
            s.ao_bounces = v;
          },
          "Cycles' Fast GI Approximation, Replace (its Integrator's ao_bounces: the add-on passes "
          "ao_bounces_render, or ao_bounces in the viewport): after this many bounces (transmission not "
          "counted, glossy at most once) the next ray reaches at most ao_distance; a surface there ends the "
          "path, the world it reaches is times ao_factor. 0 = off (the default), as is ao_factor 0")
      .def_property(
          "ao_factor", [](const RenderSettings& s) { return s.ao_factor; },
          [](RenderSettings& s, float v) { s.ao_factor = clamp_setting(v, "ao_factor", "no Fast GI Replace"); },
          "Fast GI Replace's factor on the world the AO ray reaches (world.light_settings.ao_factor); 0 turns "
          "Replace off, as in Cycles. Negative or non-finite: 0, with a warning")
      .def_property(
          "ao_additive_factor", [](const RenderSettings& s) { return s.ao_additive_factor; },
          [](RenderSettings& s, float v) {
            s.ao_additive_factor = clamp_setting(v, "ao_additive_factor", "no Fast GI Add");
          },
          "Cycles' Fast GI Approximation, Add (its Integrator's ao_additive_factor, the world's AO factor): "
          "every surface adds its diffuse closures' weight times this where a cosine ray of ao_distance "
          "finds no surface. 0 = off (the default). Negative or non-finite: 0, with a warning")
      .def_readwrite("exposure", &RenderSettings::exposure)
      .def_readwrite("mist_start", &RenderSettings::mist_start)
      .def_readwrite("mist_depth", &RenderSettings::mist_depth)
      .def_readwrite("mist_falloff", &RenderSettings::mist_falloff, "Mist falloff exponent: 1 Linear, 2 Quadratic, 0.5 Inverse Quadratic")
      .def_readwrite("ao_distance", &RenderSettings::ao_distance,
                     "The world's AO distance (world.light_settings.distance, >= 0; infinite: unbounded): the "
                     "AO pass's rays and Fast GI's (Cycles' ao_bounces_distance)")
      .def_readwrite("shader_aovs", &RenderSettings::shader_aovs,
                     "Shader AOVs (the view layer's, in order): the channels of each, 4 (COLOR) or 1 (VALUE); "
                     "the aov_output op writes slot i. Read with Session.film_aov(i).")
      .def_readwrite("light_groups", &RenderSettings::light_groups,
                     "Light groups (Cycles' Combined_<name> passes), at most 64: emitters name theirs by index "
                     "(add_instance / add_curves / add_points' light_group, Scene.set_light_group, "
                     "set_world_light_group). Read with Session.film_light_group(i).")
      .def_readwrite("uv_pass_set", &RenderSettings::uv_pass_set,
                     "The UV pass's uv set (the active render UV map's global index; -1: none, the pass reads 0).")
      .def_property(
          "cryptomatte",
          [](const RenderSettings& s) {
            std::vector<std::string> names;
            for (int k = 0; k < 3; ++k)
              if (s.cryptomatte & (1u << k)) names.push_back(kCryptoNames[k]);
            return names;
          },
          [](RenderSettings& s, const std::vector<std::string>& names) {
            uint32_t bits = 0;
            for (const auto& n : names) {
              int k = 0;
              while (k < 3 && n != kCryptoNames[k]) ++k;
              if (k == 3) throw std::invalid_argument("unknown Cryptomatte layer '" + n + "' (object, material, asset)");
              bits |= 1u << k;
            }
            s.cryptomatte = bits;
          },
          "Cryptomatte layers to render: 'object', 'material', 'asset' (film_pass('CryptoObject00'), ...).")
      .def_readwrite("cryptomatte_depth", &RenderSettings::cryptomatte_depth,
                     "Cryptomatte levels (1..16): id / coverage pairs per pixel, two per RGBA pass.")
      .def_property(
          "debug_view", [](const RenderSettings& s) { return enum_name(s.debug_view, kDebugViewNames); },
          [](RenderSettings& s, const std::string& v) { s.debug_view = enum_from_name(v, "debug_view", kDebugViewNames); })
      .def_readwrite("sample_offset", &RenderSettings::sample_offset)
      .def_readwrite("force_general_kernel", &RenderSettings::force_general_kernel,
                     "Run the general integrator kernel, not the scene-specialised one (same image).")
      .def_readwrite("guiding", &RenderSettings::guiding,
                     "Path guiding: learn the incident light during the first samples and sample it.")
      .def_readwrite("guiding_probability", &RenderSettings::guiding_probability)
      .def_readwrite("guiding_learn_probability", &RenderSettings::guiding_learn_probability,
                     "Learn the guide's probability per cell (the one of least estimated second moment).")
      .def_readwrite("guiding_cosine", &RenderSettings::guiding_cosine,
                     "Guide by incident radiance times the cosine to the shading normal.")
      .def_readwrite("guiding_filter", &RenderSettings::guiding_filter,
                     "Splat each guide record over a box of its quadtree leaf's size (Müller et al.).")
      .def_readwrite("guiding_caustic_lobes", &RenderSettings::guiding_caustic_lobes,
                     "With guiding_caustics: the probability of a direction from the caustic photons' lobes.")
      .def_readwrite("guiding_caustic_cube", &RenderSettings::guiding_caustic_cube,
                     "The caustic lobes' cubes: their edge over the scene's diagonal.")
      .def_readwrite("guiding_caustic_cone", &RenderSettings::guiding_caustic_cone,
                     "The caustic lobes' cone half-angle (radians).")
      .def_readwrite("caustic_light_paths", &RenderSettings::caustic_light_paths,
                     "Caustic light tracing: light paths per pixel sample from the environment through smooth "
                     "surfaces, combined with path tracing by MIS (0: off; stats()['caustics'] says whether it ran)")
      .def_readwrite("caustic_light_paths_auto", &RenderSettings::caustic_light_paths_auto,
                     "Automatic caustic light paths (with caustic_light_paths 0): 0.1 per pixel sample where the "
                     "environment has a bright peak and the scene smooth surfaces, else off (stats()['caustics'] "
                     "says which and why)")
      .def_readwrite("caustic_connections", &RenderSettings::caustic_connections,
                     "Light-vertex connections: where the caustic light paths run, connect each camera path's "
                     "first this many rough vertices to a rough vertex of the light paths (caustics seen after "
                     "further rough bounces; 0: off; negative, the default: 2 where the automatic light paths "
                     "run, else off)")
      .def_readwrite("guiding_class_mask", &RenderSettings::guiding_class_mask,
                     "Measurement only: with guiding on, keep the light of these path classes (bits).")
      .def_readwrite("guiding_photons", &RenderSettings::guiding_photons,
                     "Photon training of the guide: light paths per pixel and training sample (0: none).")
      .def_readwrite("guiding_photon_share", &RenderSettings::guiding_photon_share,
                     "The photons' share of a guide cell's distribution where it has camera records too.")
      .def_readwrite("guiding_photon_split", &RenderSettings::guiding_photon_split,
                     "What a photon record counts for towards splitting a guide cell (a camera record: 1).")
      .def_readwrite("guiding_caustics", &RenderSettings::guiding_caustics,
                     "Photon training with caustic (light, smooth bounces, rough surface) photons only, kept "
                     "over the iterations.");

  m.def(
      "render_passes",
      [] {
        py::dict d;
        for (int p = 0; p < kPassCount; ++p) d[pass_desc(Pass(p)).name] = pass_desc(Pass(p)).channels;
        return d;
      },
      "Every render pass the core can keep: {name: channels}, in the core's order.");

  py::class_<PyScene>(m, "Scene")
      .def(py::init([](bool dynamic) {
             PyScene s;
             s.scene->set_dynamic(dynamic);
             return s;
           }),
           py::arg("dynamic") = false)
      .def(
          "add_material",
          [](PyScene& self, const std::string& name, const py::object& base_color, const py::object& emission) {
            self.check_editable();
            const Vec3 albedo = vmin(to_color(base_color, "base_color"), Vec3(1.0f));  // > 1 creates energy
            Material mat = make_simple_material(name, albedo, to_color(emission, "emission"));
            return self.scene->add_material(std::move(mat));
          },
          py::arg("name"), py::arg("base_color") = py::make_tuple(0.8f, 0.8f, 0.8f),
          py::arg("emission") = py::make_tuple(0.0f, 0.0f, 0.0f))
      .def("add_points", &add_points, py::arg("points"), py::arg("radii") = py::none(), py::arg("material") = 0u,
           py::arg("matrix") = py::none(), py::arg("color") = py::none(), py::arg("pass_index") = 0.0f,
           py::arg("random_id") = 0u, py::arg("attributes") = py::none(), py::arg("point_attributes") = py::dict(),
           py::arg("texspace") = py::none(), py::arg("motion") = py::none(), py::arg("motion_points") = py::none(),
           py::arg("motion_radii") = py::none(), py::arg("cryptomatte") = py::none(), py::arg("light_set") = 0,
           py::arg("shadow_set") = 0, py::arg("pass_motion") = py::none(), py::arg("light_mask") = kAllLightSets,
           py::arg("shadow_mask") = kAllLightSets, py::arg("pass_points") = py::none(),
           py::arg("shadow_catcher") = false, py::arg("holdout") = false, py::arg("light_group") = -1,
           py::arg("ao_distance") = 0.0f, py::arg("camera_invisible") = false,
           "Adds a point cloud (Blender's POINTCLOUD), rendered as spheres as Cycles does: points (N, 3), "
           "radii (N; None: 0.01), a material id and the object's 4x4 matrix. color, pass_index, "
           "random_id, attributes, light_set, shadow_set: the object's, as add_curves. point_attributes: {attribute set: (N, 4) "
           "RGBA per point}. texspace: (location, size) of Generated coordinates (None: Generated is "
           "the object-space position, as Cycles gives point clouds). motion: (S, 4, 4) object-to-world "
           "matrices over the shutter (transform motion blur; singular or non-finite steps: static). "
           "motion_points, motion_radii: deformation blur, (S, N, 3) object-space centres and (S, N) radii "
           "(None: the frame's) at S >= 2 steps evenly over the shutter (Cycles' motion points); steps "
           "with non-finite values or that leave out other points: undeformed (stats()['motion_rejected']). "
           "Points with a non-finite position or radius, or a radius <= 0, are left out at commit "
           "(stats()['skipped_points']). pass_motion: (2, 4, 4) object-to-world matrices at the previous and "
           "next frames (the Vector pass; None: still). pass_points: (2, N, 3) object-space centres at those "
           "frames (the Vector pass's deformation, Cycles' motion points; None, non-finite or unchanged: "
           "the points move with pass_motion alone). shadow_catcher, holdout, ao_distance, camera_invisible: as add_instance's. "
           "light_mask, shadow_mask: as an emitter, as "
           "add_instance's (rays other than the camera's get its emission only from vertices it lights, "
           "none where it is shadow-linked).")
      .def("add_curves", &add_curves, py::arg("points"), py::arg("offsets"), py::arg("radii") = py::none(),
           py::arg("material") = 0u, py::arg("matrix") = py::none(), py::arg("curve_type") = "catmull_rom",
           py::arg("subdivisions") = 8, py::arg("color") = py::none(), py::arg("pass_index") = 0.0f,
           py::arg("random_id") = 0u, py::arg("attributes") = py::none(), py::arg("normals") = py::none(),
           py::arg("uvs") = py::dict(), py::arg("strand_attributes") = py::dict(), py::arg("shape") = "thick",
           py::arg("materials") = py::none(), py::arg("point_attributes") = py::dict(),
           py::arg("point_uvs") = py::dict(), py::arg("motion") = py::none(), py::arg("motion_points") = py::none(),
           py::arg("motion_radii") = py::none(), py::arg("cryptomatte") = py::none(), py::arg("light_set") = 0,
           py::arg("shadow_set") = 0, py::arg("pass_motion") = py::none(), py::arg("light_mask") = kAllLightSets,
           py::arg("shadow_mask") = kAllLightSets, py::arg("pass_points") = py::none(),
           py::arg("shadow_catcher") = false, py::arg("holdout") = false, py::arg("light_group") = -1,
           py::arg("ao_distance") = 0.0f, py::arg("camera_invisible") = false,
           "Adds a Curves object (hair): points (N, 3), offsets (C + 1) into them, radii (N; None: 0.005), "
           "a material id and the object's 4x4 matrix. Traced as round curves (Cycles' 3D curves): "
           "Catmull-Rom strands cut into `subdivisions` cones per segment, poly strands as they are. "
           "shape='ribbon': flat ribbons facing each ray (Cycles' 'RIBBONS'), Catmull-Rom through the "
           "points whatever curve_type (as Cycles 4.5), `subdivisions` quads per segment (Embree's "
           "tessellation rate). "
           "color, pass_index, random_id: the object's (Object Info), as add_instance. attributes: its "
           "Object / Instancer attribute values, (K, 4) by slot with K <= 8, as add_instance. light_set, "
           "shadow_set (0..63): its light linking sets as a receiver and a blocker, as add_instance's. normals: "
           "Blender's curve normals (N, 3) or None (the major axis of Huang's elliptical hair). uvs: {uv "
           "set: (C, 2) one uv per strand} (particle hair: the emitter's UV at the root). strand_attributes: "
           "{attribute set: (C, 4) one RGBA per strand} (particle hair: the emitter's colour at the root). "
           "materials: (C,) a material id per strand (ids not in the scene: `material`), or None. "
           "point_attributes: {attribute set: (N, 4) one RGBA per point}, linear between a segment's keys "
           "(a set given per point wins over the same set per strand). point_uvs: {uv set: (N, 2) one uv "
           "per point}, interpolated so too. "
           "motion: (S, 4, 4) object-to-world matrices over the shutter (transform motion blur; singular "
           "or non-finite steps: static). motion_points, motion_radii: deformation blur, (S, N, 3) "
           "object-space points and (S, N) radii (None: the frame's) at S >= 2 steps evenly over the "
           "shutter (Cycles' curve motion keys); steps with non-finite values, or that cut into other "
           "pieces than the frame's, leave it undeformed (stats()['motion_rejected']). pass_motion: as add_points'. pass_points: "
           "(2, N, 3) object-space points at the previous and next frames (the Vector pass's deformation: "
           "a hit moves as the point between its segment's two keys, Cycles' motion keys). shadow_catcher, "
           "holdout, ao_distance, camera_invisible: as add_instance's.")
      .def("displace_mesh", &displace_mesh_arrays, py::arg("positions"), py::arg("triangles"),
           py::arg("material_indices") = py::none(), py::arg("material_slots") = std::vector<int64_t>{},
           py::arg("matrix") = py::none(), py::arg("normals") = py::none(), py::arg("normal_indices") = py::none(),
           py::arg("flat") = py::none(), py::arg("uvs") = py::dict(), py::arg("attributes") = py::dict(),
           py::arg("tangents") = py::dict(), py::arg("texspace") = py::none(),
           py::arg("motion_positions") = py::none(),
           "True displacement (Cycles' 'DISPLACEMENT' / 'BOTH' methods) of add_mesh's arrays before add_mesh: "
           "each vertex of a triangle whose material (add_shader's displacement) displaces moves by its "
           "program's offset at the vertex (the first such triangle's corner: its uvs, attributes, normal), "
           "shaded as the instance `matrix` places it. flat: (T,) bool, flat-shaded triangles (None: smooth). "
           "Returns None where nothing displaces, else a dict: positions (V, 3); normals and normal_indices "
           "(flat triangles their displaced face's, the vertices of 'DISPLACEMENT' triangles recomputed as "
           "Cycles, the rest the given ones); motion_positions (S, V, 3) moved by the same offsets where given; "
           "displaced (vertices) and clamped (non-finite offsets dropped, longer ones shortened to 1e4).")
      .def("add_mesh", &add_mesh, py::arg("positions"), py::arg("triangles"), py::arg("corner_normals") = py::none(),
           py::arg("material_indices") = py::none(), py::arg("material_slots") = std::vector<int64_t>{},
           py::arg("uvs") = py::dict(), py::arg("texspace") = py::none(), py::arg("normals") = py::none(),
           py::arg("normal_indices") = py::none(), py::arg("attributes") = py::dict(),
           py::arg("tangents") = py::dict(), py::arg("undisplaced") = py::none())
      .def(
          "add_image",
          [](PyScene& self, const FloatArray& pixels, bool srgb) {
            self.check_editable();
            if (pixels.ndim() != 3 || pixels.shape(2) != 4 || pixels.shape(0) < 1 || pixels.shape(1) < 1)
              throw std::invalid_argument("image pixels must have shape (H, W, 4)");
            if (pixels.shape(0) > 65536 || pixels.shape(1) > 65536 || pixels.shape(0) * pixels.shape(1) > (1ll << 28))
              throw std::invalid_argument("image is too large");
            Image img;
            img.h = int(pixels.shape(0));
            img.w = int(pixels.shape(1));
            img.px.resize(size_t(img.w) * size_t(img.h));
            const float* src = pixels.data();
            for (size_t i = 0; i < img.px.size(); ++i) {
              float c[4];
              for (int k = 0; k < 4; ++k) c[k] = std::isfinite(src[4 * i + k]) ? src[4 * i + k] : 0.0f;
              img.px[i] = {c[0], c[1], c[2], c[3]};
            }
            img.srgb = srgb;
            return self.scene->add_image(std::move(img));
          },
          py::arg("pixels"), py::arg("srgb") = false)
      .def(
          "add_image_tiles",
          [](PyScene& self, const std::vector<std::pair<int64_t, int64_t>>& tiles) {
            self.check_editable();
            if (tiles.empty()) throw std::invalid_argument("a tile set needs at least one tile");
            Image set;
            for (const auto& [number, id] : tiles) {
              if (number < 1001 || number > 2000)
                throw std::invalid_argument("UDIM tile number " + std::to_string(number) + " outside 1001..2000");
              if (id < 0 || size_t(id) >= self.scene->image_count() || !self.scene->images()[size_t(id)].tiles.empty())
                throw std::invalid_argument("tile " + std::to_string(number) + ": unknown image id " + std::to_string(id));
              for (const ImageTile& t : set.tiles)
                if (t.number == number) throw std::invalid_argument("UDIM tile " + std::to_string(number) + " given twice");
              set.tiles.push_back({int32_t(number), int32_t(id)});
            }
            return self.scene->add_image(std::move(set));
          },
          py::arg("tiles"),
          "A UDIM tile set of images added before (tiles: (number, image id) pairs, numbers 1001 + u + 10 v "
          "in 1001..2000): an image id that Image Texture ops read as Cycles reads a tiled image.")
      .def(
          "set_material_pass_index",
          [](PyScene& self, uint32_t material, float pass_index) {
            self.check_editable();
            self.scene->set_material_pass_index(material, pass_index);
          },
          py::arg("material"), py::arg("pass_index"), "Blender's material pass index (the IndexMA pass).")
      .def(
          "set_material_cryptomatte",
          [](PyScene& self, uint32_t material, const std::string& name) {
            self.check_editable();
            self.scene->set_material_cryptomatte(material, cryptomatte_id_of(name));
          },
          py::arg("material"), py::arg("name"),
          "The name a material has in CryptoMaterial passes (its id: cryptomatte_id(cryptomatte_hash(name))).")
      .def(
          "add_shader",
          [](PyScene& self, const std::string& name, const py::list& program, const py::object& volume_absorption,
             bool use_schlick, const py::object& volume, const py::object& displacement,
             const std::string& displacement_method) {
            self.check_editable();
            Material mat = make_shader(self, name, program, volume_absorption, use_schlick, volume, displacement,
                                       displacement_method);
            return self.scene->add_material(std::move(mat));
          },
          py::arg("name"), py::arg("program"), py::arg("volume_absorption") = py::none(),
          py::arg("use_schlick") = false, py::arg("volume") = py::none(), py::arg("displacement") = py::none(),
          py::arg("displacement_method") = "DISPLACEMENT",
          "volume: the homogeneous medium inside, a dict of sigma_a, sigma_s, emission (RGB per unit "
          "length) and g (Henyey-Greenstein anisotropy); it replaces volume_absorption's sigma_a. Or a "
          "heterogeneous medium: a program (a list of value ops) ending in ('closure', 'volume', None, "
          "{sigma_a, sigma_s, emission, g: registers}), evaluated at points inside. displacement: true "
          "displacement, a program of value ops ending in ('closure', 'displacement', None, {'offset': r}) "
          "(r: the world-space offset at a vertex) that displace_mesh runs; displacement_method "
          "'DISPLACEMENT' (displaced vertices' normals recomputed) or 'BOTH' (kept).")
      .def(
          "shader_evaluation",
          [](PyScene& self, uint32_t id) {
            if (id >= self.scene->material_count()) throw std::invalid_argument("shader_evaluation: unknown material id");
            const Material& m = self.scene->material(id);
            return std::string(m.constant ? "constant" : m.closures_only ? "closures" : "program");
          },
          py::arg("id"),
          "How hits evaluate material `id`: 'constant' (closures made once), 'closures' (registers made "
          "once, the closure ops per hit) or 'program' (the whole program per hit).")
      .def(
          "set_material",
          [](PyScene& self, uint32_t id, const std::string& name, const py::object& base_color,
             const py::object& emission) {
            self.check_editable();
            const Vec3 albedo = vmin(to_color(base_color, "base_color"), Vec3(1.0f));
            self.scene->set_material(id, make_simple_material(name, albedo, to_color(emission, "emission")));
          },
          py::arg("id"), py::arg("name"), py::arg("base_color") = py::make_tuple(0.8f, 0.8f, 0.8f),
          py::arg("emission") = py::make_tuple(0.0f, 0.0f, 0.0f),
          "Replaces material `id` (as add_material); the next commit() keeps the BVH.")
      .def(
          "set_shader",
          [](PyScene& self, uint32_t id, const std::string& name, const py::list& program,
             const py::object& volume_absorption, bool use_schlick, const py::object& volume,
             const py::object& displacement, const std::string& displacement_method) {
            self.check_editable();
            self.scene->set_material(id, make_shader(self, name, program, volume_absorption, use_schlick, volume,
                                                     displacement, displacement_method));
          },
          py::arg("id"), py::arg("name"), py::arg("program"), py::arg("volume_absorption") = py::none(),
          py::arg("use_schlick") = false, py::arg("volume") = py::none(), py::arg("displacement") = py::none(),
          py::arg("displacement_method") = "DISPLACEMENT", "Replaces material `id` (as add_shader); the next commit() keeps the BVH.")
      .def(
          "image_count", [](const PyScene& self) { return self.scene->image_count(); },
          "How many images (add_image) the scene holds.")
      .def(
          "clear_lights",
          [](PyScene& self) {
            self.check_editable();
            self.scene->clear_lights();
          },
          "Removes every analytic light; the next commit() rebuilds only the light distribution.")
      .def(
          "set_light_links",
          [](PyScene& self, size_t index, uint64_t light_mask, uint64_t shadow_mask) {
            self.check_editable();
            if (!self.scene->set_light_links(index, light_mask, shadow_mask)) throw std::out_of_range("no such light");
          },
          py::arg("index"), py::arg("light_mask") = kAllLightSets, py::arg("shadow_mask") = kAllLightSets,
          "Light and shadow linking of analytic light `index` (add order), as Cycles: bit s of "
          "light_mask: it lights objects of light set s (add_instance's light_set); bit s of "
          "shadow_mask: objects of shadow set s block it (others let its light pass).")
      .def(
          "set_light_group",
          [](PyScene& self, size_t index, int group) {
            self.check_editable();
            if (!self.scene->set_light_group(index, to_light_group(group, "light"))) throw std::out_of_range("no such light");
          },
          py::arg("index"), py::arg("light_group"),
          "The light group (Cycles' Light Groups: the Combined_<name> pass its light also goes to; "
          "RenderSettings.light_groups' index, -1: none) of analytic light `index` (add order).")
      .def(
          "set_light_max_bounces",
          [](PyScene& self, size_t index, int max_bounces) {
            self.check_editable();
            if (max_bounces < 0) throw std::invalid_argument("max_bounces must be >= 0");
            if (!self.scene->set_light_max_bounces(index, max_bounces)) throw std::out_of_range("no such light");
          },
          py::arg("index"), py::arg("max_bounces"),
          "Cycles' light Max Bounces (light.cycles.max_bounces, default 1024) of analytic light `index` "
          "(add order): light samples at path vertices past this many bounces skip it, as Cycles' "
          "light_select_reached_max_bounces (rays that find it still count).")
      .def(
          "set_world_light_group",
          [](PyScene& self, int group) {
            self.check_editable();
            self.scene->set_world_light_group(to_light_group(group, "world"));
          },
          py::arg("light_group"),
          "The world's light group (World ▸ Settings ▸ Light Group; -1: none): the environment's light "
          "(seen, found by rays, light-sampled, caustic light paths from it).")
      .def(
          "add_instance",
          [](PyScene& self, uint32_t mesh, const FloatArray& matrix, const py::object& color, float pass_index,
             uint32_t random_id, const py::object& motion, const py::object& attributes, float shadow_terminator,
             int light_set, uint64_t light_mask, int shadow_set, uint64_t shadow_mask, const py::object& pass_motion,
             const py::object& cryptomatte, bool shadow_catcher, bool holdout, int light_group, float ao_distance,
             bool camera_invisible) {
            self.check_editable();
            ObjectInfo info;
            info.camera_invisible = camera_invisible;
            info.light_group = to_light_group(light_group, "instance");
            info.ao_distance = clean_ao_distance(ao_distance);
            set_cryptomatte(info, cryptomatte, "instance");
            info.shadow_catcher = shadow_catcher;
            info.holdout = holdout;
            if (!color.is_none()) {
              const auto c = color.cast<std::vector<float>>();
              if (c.size() != 3 && c.size() != 4) throw std::invalid_argument("instance color takes 3 or 4 values");
              auto clean = [](float x) { return std::isfinite(x) ? x : 0.0f; };
              info.color = {clean(c[0]), clean(c[1]), clean(c[2]), c.size() == 4 ? clean(c[3]) : 1.0f};
            }
            info.pass_index = std::isfinite(pass_index) ? pass_index : 0.0f;
            info.random = object_random(random_id);
            info.terminator = std::isfinite(shadow_terminator) ? clampf(shadow_terminator, 0.0f, 1.0f) : 0.0f;
            if (light_set < 0 || light_set > 63 || shadow_set < 0 || shadow_set > 63)
              throw std::invalid_argument("instance light_set and shadow_set take 0..63");
            info.light_set = uint8_t(light_set);
            info.shadow_set = uint8_t(shadow_set);
            info.light_mask = light_mask;
            info.shadow_mask = shadow_mask;
            std::vector<Mat4> pm = to_motion(pass_motion, "instance pass_motion");
            if (!pm.empty() && pm.size() != 2) throw std::invalid_argument("instance pass_motion must be a (2, 4, 4) array");
            self.scene->add_instance(mesh, to_mat4(matrix, "instance matrix"), info, to_motion(motion, "instance motion"),
                                     to_object_attributes(attributes, "instance"), std::move(pm));
          },
          py::arg("mesh"), py::arg("matrix"), py::arg("color") = py::none(), py::arg("pass_index") = 0.0f,
          py::arg("random_id") = 0u, py::arg("motion") = py::none(), py::arg("attributes") = py::none(),
          py::arg("shadow_terminator") = 0.0f, py::arg("light_set") = 0, py::arg("light_mask") = kAllLightSets,
          py::arg("shadow_set") = 0, py::arg("shadow_mask") = kAllLightSets, py::arg("pass_motion") = py::none(),
          py::arg("cryptomatte") = py::none(), py::arg("shadow_catcher") = false, py::arg("holdout") = false,
          py::arg("light_group") = -1, py::arg("ao_distance") = 0.0f, py::arg("camera_invisible") = false,
          "Adds an instance of `mesh` with its object-to-world matrix and what the Object Info node "
          "reads: the object's RGBA colour, pass index and 32-bit random id (Random = id / 2^32). "
          "motion: its matrices at the motion steps over the shutter, (S, 4, 4) with S >= 2 (motion "
          "blur); steps that are not finite or not invertible leave it static (stats()['motion_rejected']). "
          "attributes: its Object / Instancer attribute values, (K, 4) by slot with K <= 8 (the "
          "object_attribute op; NaN/inf read 0). light_set, shadow_set (0..63): its light linking "
          "sets as a receiver and a blocker; light_mask, shadow_mask: as an emitter (its emissive "
          "triangles), as set_light_links. pass_motion: its matrices at the previous and next frames, "
          "(2, 4, 4), for the Vector pass only (non-finite ones: still there). cryptomatte: (object name, "
          "asset name), the names its Cryptomatte ids hash (Blender: the object's and its top parent's; "
          "None: no id). shadow_catcher: Cycles' Shadow Catcher (the camera sees "
          "it only through the shadows and light that other objects cast on it; passes 'Shadow "
          "Catcher', 'Shadow Catcher Matte', 'Shadow Catcher Sample Count'); holdout: Cycles' "
          "object Holdout (the camera sees through it to a transparent film, alpha 0). light_group: the "
          "light group its emission goes to (RenderSettings.light_groups' index; -1: none), as "
          "add_curves' and add_points'. ao_distance: the object's Fast GI AO Distance (the reach of "
          "Replace's rays that leave it; 0, negative or non-finite: RenderSettings.ao_distance). "

          "camera_invisible: Cycles' visibility without camera rays (a "
          "collection's Indirect Only): camera rays, and their continuations through transparent "
          "surfaces, pass it; every other ray sees it.")
      .def(
          "set_mesh_pass_motion",
          [](PyScene& self, uint32_t mesh, const FloatArray& positions) {
            self.check_editable();
            if (positions.ndim() != 3 || positions.shape(2) != 3 || positions.shape(0) != 2)
              throw std::invalid_argument("mesh pass motion positions must be a (2, V, 3) array");
            const py::ssize_t n = positions.shape(1);
            std::vector<std::vector<Vec3>> out(2, std::vector<Vec3>(static_cast<size_t>(n)));
            const float* p = positions.data();
            for (size_t k = 0; k < 2; ++k)
              std::memcpy(static_cast<void*>(out[k].data()), p + k * size_t(n) * 3, size_t(n) * sizeof(Vec3));
            py::gil_scoped_release release;
            return self.scene->set_mesh_pass_motion(mesh, std::move(out));
          },
          py::arg("mesh"), py::arg("positions"),
          "Vector pass: mesh `mesh`'s vertex positions (object space) at the previous and next frames, "
          "(2, V, 3). Returns False (and keeps none) where V is not its vertex count or a value is NaN/inf.")

      .def(
          "set_mesh_velocity",
          [](PyScene& self, uint32_t mesh, int32_t grid, float scale, float offset, const std::string& interpolation,
             int32_t grid_y, int32_t grid_z) {
            self.check_editable();
            VolumeSampling vs = VolumeSampling::Trilinear;
            if (interpolation == "CUBIC") vs = VolumeSampling::Tricubic;
            else if (interpolation == "CLOSEST") vs = VolumeSampling::Closest;
            else if (interpolation != "LINEAR")
              throw std::invalid_argument("interpolation must be 'LINEAR', 'CUBIC' or 'CLOSEST'");
            self.scene->set_mesh_velocity(mesh, grid, scale, offset, vs, grid_y, grid_z);
          },
          py::arg("mesh"), py::arg("grid"), py::arg("scale"), py::arg("offset") = -0.5f,
          py::arg("interpolation") = "LINEAR", py::arg("grid_y") = -1, py::arg("grid_z") = -1,
          "Velocity blur of a volume object's mesh (Cycles' volume motion): its media look up the point "
          "moved back twice by velocity x scale x (time + offset) (time: the ray's shutter time in [0, 1]; "
          "offset -0.5 for a centred shutter, 0 at the start), velocity the vector grid `grid` (an "
          "add_volume_grid id, object space), or with grid_y and grid_z the float grids of its x, y and z "
          "components. grid < 0 or scale 0: none. Non-finite values raise.")
      .def(
          "set_mesh_motion",
          [](PyScene& self, uint32_t mesh, const FloatArray& positions) {
            self.check_editable();
            if (positions.ndim() != 3 || positions.shape(2) != 3 || positions.shape(0) < 2 || positions.shape(0) > 1025)
              throw std::invalid_argument("mesh motion positions must be an (S, V, 3) array with 2 to 1025 steps");
            const py::ssize_t steps = positions.shape(0), n = positions.shape(1);
            std::vector<std::vector<Vec3>> out(size_t(steps), std::vector<Vec3>(static_cast<size_t>(n)));
            const float* p = positions.data();
            for (py::ssize_t s = 0; s < steps; ++s)
              std::memcpy(static_cast<void*>(out[size_t(s)].data()), p + size_t(s) * size_t(n) * 3, size_t(n) * sizeof(Vec3));
            py::gil_scoped_release release;
            self.scene->set_mesh_motion(mesh, std::move(out));
          },
          py::arg("mesh"), py::arg("positions"),
          "Deformation blur of mesh `mesh`: its vertex positions (object space) at each motion step "
          "over the shutter, (S, V, 3) with S >= 2 and V its vertex count. Steps of another length "
          "or with NaN/inf leave it undeformed (stats()['motion_rejected']).")
      .def(
          "set_instance_transform",
          [](PyScene& self, uint32_t index, const FloatArray& matrix) {
            self.check_editable();
            self.scene->set_instance_transform(index, to_mat4(matrix, "instance matrix"));
          },
          py::arg("index"), py::arg("matrix"),
          "Moves instance `index` (add_instance order). In dynamic mode (or for a mesh with several "
          "instances) the next commit() rebuilds only the top level and the lights.")
      .def_property("spatial_splits", scene_get<&Scene::spatial_splits>(),
                    scene_flag_set<&Scene::set_spatial_splits>(),
          "Spatial splits (SBVH) in the BVH builds of the next commit(): slower builds, fewer "
          "triangle and node tests on long thin triangles (final renders). Default off.")
      .def_property(
          "compact_bvh",
          [](const PyScene& self) { return enum_name(self.scene->compact_bvh(), kCompactBvhNames); },
          [](PyScene& self, const std::string& v) {
            self.check_editable();
            self.scene->set_compact_bvh(enum_from_name(v, "compact_bvh", kCompactBvhNames));
          },
          "Compressed (quantised) wide BVH nodes from the next commit(): 'on', 'off' or 'auto' "
          "(the default: on for BLASes of 8M triangles or more, where memory matters more than the "
          "few percent more work per ray). Same hits.")
      .def("binary_bvh_nodes", &binary_bvh_nodes,
           "The largest BLAS's binary tree for tests (commit(bvh='binary'); empty arrays for the "
           "wide layouts): dict of lo, hi (M, 3 float32), left_or_first, count (M uint32; interior: "
           "left child (right = left + 1) and 0; leaf: first position in the leaf order and its "
           "triangle count) and prims (the leaf order's input indices, uint32).")
      .def("wide_bvh_nodes", &wide_bvh_nodes,
           "The largest BLAS's wide tree for tests: dict of box (M, N, 6: lo x, hi x, lo y, hi y, "
           "lo z, hi z; compressed nodes dequantised as the traversal computes them), child, count "
           "(M, N uint32), valid (M, N bool), compact, and the leaves' triangles (B, 4, 3, 3: "
           "block, lane, vertex, axis) with their input indices prims (B, 4; -1 unused).")
      .def_property(
          "build_quality",
          [](const PyScene& self) { return enum_name(self.scene->build_quality(), kBuildQualityNames); },
          [](PyScene& self, const std::string& q) {
            self.check_editable();
            self.scene->set_build_quality(enum_from_name(q, "build_quality", kBuildQualityNames));
          },
          "How the next commit() builds the BVHs: 'sah' (the full binned SAH), 'fast' (clustered: "
          "the triangles sorted along a Morton curve into runs of up to 8, the binned SAH over the runs, "
          "then over the triangles of nodes of 24 or fewer; less build work, somewhat worse trees), "
          "'auto' (default: 'fast' for the BVHs of 100,000 triangles or more of a dynamic scene, else 'sah').")
      .def_property("dynamic", scene_get<&Scene::dynamic>(),
                    scene_flag_set<&Scene::set_dynamic>(),
          "Every instance its own transform over a per-mesh BLAS (viewport: transform edits rebuild only "
          "the top level); False (default): meshes used once are merged in world space (faster tracing).")
      .def(
          "add_point_light",
          [](PyScene& self, const py::object& position, const py::object& intensity, float radius, bool cast_shadow, bool use_mis, bool visible_camera, bool visible_diffuse, bool visible_glossy,
             bool visible_transmission, bool visible_volume, bool soft_falloff, const py::object& ies,
             const py::object& ies_matrix, const py::object& shader, const py::object& shader_matrix,
             float shader_power) {
            self.check_editable();
            Light l;
            l.type = LightType::Point;
            set_light_ies(l, ies, ies_matrix.is_none() ? Mat4() : to_mat4(ies_matrix.cast<FloatArray>(), "ies_matrix"));
            l.position = to_point(position, "position");
            l.color = to_color(intensity, "intensity");
            l.radius = finite_nonneg(radius, "radius");
            l.sphere = !soft_falloff;
            l.cast_shadow = cast_shadow;
            l.mis = use_mis;
            l.visibility = light_visibility(visible_camera, visible_diffuse, visible_glossy, visible_transmission, visible_volume);
            Mat4 sm;
            if (!shader_matrix.is_none()) sm = to_mat4(shader_matrix.cast<FloatArray>(), "shader_matrix");
            else for (int i = 0; i < 3; ++i) sm.m[i][3] = (&l.position.x)[i];
            set_light_shader(self, l, shader, sm, shader_power);
            self.scene->add_light(l);
          },
          py::arg("position"), py::arg("intensity"), py::arg("radius") = 0.0f, py::arg("cast_shadow") = true, py::arg("use_mis") = true,
          py::arg("visible_camera") = false, py::arg("visible_diffuse") = true, py::arg("visible_glossy") = true,
          py::arg("visible_transmission") = true, py::arg("visible_volume") = true, py::arg("soft_falloff") = true,
          py::arg("ies") = py::none(), py::arg("ies_matrix") = py::none(), py::arg("shader") = py::none(),
          py::arg("shader_matrix") = py::none(), py::arg("shader_power") = 1.0f,
          "soft_falloff=False: Blender's Soft Falloff off, a true emitting sphere of the radius (Cycles' sphere "
          "light); True: the disk facing the shaded point. ies: an IesProfile scaling the intensity by direction in "
          "the frame of ies_matrix (the light's 4x4 world matrix; identity if None). shader: the light's node tree "
          "(a program ending in emission closures) multiplying the intensity, in the frame of shader_matrix (the "
          "light's world matrix; a translation to position if None); shader_power: the tree's emission estimate "
          "that scales the light's power for choosing among lights.")
      .def(
          "add_spot_light",
          [](PyScene& self, const FloatArray& matrix, const py::object& intensity, float radius, float spot_size,
             float spot_blend, bool cast_shadow, bool use_mis, bool visible_camera, bool visible_diffuse, bool visible_glossy,
             bool visible_transmission, bool visible_volume, bool soft_falloff, const py::object& ies,
             const py::object& shader, float shader_power) {
            self.check_editable();
            const Mat4 m = to_mat4(matrix, "spot light matrix");
            Light l;
            set_light_ies(l, ies, m);
            l.type = LightType::Spot;
            l.sphere = !soft_falloff;
            l.position = {m.m[0][3], m.m[1][3], m.m[2][3]};
            l.color = to_color(intensity, "intensity");
            l.radius = finite_nonneg(radius, "radius");
            l.to_local = inverse3x3(m, "spot light matrix");
            const float half = 0.5f * clampf(finite_nonneg(spot_size, "spot_size"), 0.0f, kPi);
            l.cos_half_spot = std::cos(half);
            const float blend = clampf(finite_nonneg(spot_blend, "spot_blend"), 0.0f, 1.0f);
            l.spot_smooth_inv = blend > 0.0f && l.cos_half_spot < 1.0f ? 1.0f / ((1.0f - l.cos_half_spot) * blend) : 0.0f;
            // The sphere's spread cone as Cycles' cos_half_larger_spread: about the -Z column, its
            // tangent stretched by the longer of the X and Y columns over the Z one.
            const auto col2 = [&](int c) {
              return double(m.m[0][c]) * m.m[0][c] + double(m.m[1][c]) * m.m[1][c] + double(m.m[2][c]) * m.m[2][c];
            };
            const Vec3 axis{-m.m[0][2], -m.m[1][2], -m.m[2][2]};
            if (length_sq(axis) > 0.0f) l.spot_axis = normalize(axis);
            const double tan_half = std::tan(0.5 * double(clampf(finite_nonneg(spot_size, "spot_size"), 0.0f, kPi)));
            const double k = tan_half * tan_half * std::max(col2(0), col2(1)) / col2(2);
            l.spread_one_minus_cos = std::isfinite(k) && length_sq(axis) > 0.0f
                                         ? float(k / (std::sqrt(1.0 + k) * (std::sqrt(1.0 + k) + 1.0)))
                                         : 2.0f;
            l.cast_shadow = cast_shadow;
            l.mis = use_mis;
            l.visibility = light_visibility(visible_camera, visible_diffuse, visible_glossy, visible_transmission, visible_volume);
            set_light_shader(self, l, shader, m, shader_power, finite_nonneg(spot_size, "spot_size"));
            self.scene->add_light(l);
          },
          py::arg("matrix"), py::arg("intensity"), py::arg("radius") = 0.0f, py::arg("spot_size") = kPi / 4.0f,
          py::arg("spot_blend") = 0.15f, py::arg("cast_shadow") = true, py::arg("use_mis") = true,
          py::arg("visible_camera") = false, py::arg("visible_diffuse") = true, py::arg("visible_glossy") = true,
          py::arg("visible_transmission") = true, py::arg("visible_volume") = true, py::arg("soft_falloff") = true,
          py::arg("ies") = py::none(), py::arg("shader") = py::none(), py::arg("shader_power") = 1.0f,
          "soft_falloff=False: an emitting sphere of the radius (Cycles' sphere spot light). ies: an IesProfile "
          "scaling the intensity by direction in the light's frame. shader, shader_power: as add_point_light's.")
      .def(
          "add_sun_light",
          [](PyScene& self, const py::object& direction, const py::object& irradiance, float angle, bool cast_shadow, bool use_mis, bool visible_camera, bool visible_diffuse, bool visible_glossy,
             bool visible_transmission, bool visible_volume, const py::object& shader,
             const py::object& shader_matrix, float shader_power) {
            self.check_editable();
            Light l;
            l.type = LightType::Sun;
            const Vec3 d = to_point(direction, "direction");
            if (!(length(d) > 0.0f)) throw std::invalid_argument("sun direction must be non-zero");
            l.dir = normalize(d);
            l.color = to_color(irradiance, "irradiance");
            const float half = 0.5f * clampf(finite_nonneg(angle, "angle"), 0.0f, kPi * 0.999f);
            l.cos_half_angle = half > 0.0f ? std::cos(half) : 1.0f;
            // Cycles' distant light: radiance E / (pi sin^2 h) over the cone of half-angle h,
            // so a surface facing the sun receives exactly E.
            l.sun_radiance_scale = half > 0.0f ? 1.0f / (kPi * std::sin(half) * std::sin(half)) : 0.0f;
            l.cast_shadow = cast_shadow;
            l.mis = use_mis;
            l.visibility = light_visibility(visible_camera, visible_diffuse, visible_glossy, visible_transmission, visible_volume);
            set_light_shader(self, l, shader,
                             shader_matrix.is_none() ? Mat4() : to_mat4(shader_matrix.cast<FloatArray>(), "shader_matrix"),
                             shader_power);
            self.scene->add_light(l);
          },
          py::arg("direction"), py::arg("irradiance"), py::arg("angle") = 0.0f, py::arg("cast_shadow") = true, py::arg("use_mis") = true,
          py::arg("visible_camera") = false, py::arg("visible_diffuse") = true, py::arg("visible_glossy") = true,
          py::arg("visible_transmission") = true, py::arg("visible_volume") = true, py::arg("shader") = py::none(),
          py::arg("shader_matrix") = py::none(), py::arg("shader_power") = 1.0f,
          "shader, shader_matrix, shader_power: as add_point_light's.")
      .def(
          "add_area_light",
          [](PyScene& self, const FloatArray& matrix, float size_x, float size_y, const py::object& radiance,
             bool ellipse, bool cast_shadow, bool use_mis, bool visible_camera, bool visible_diffuse, bool visible_glossy,
             bool visible_transmission, bool visible_volume, float spread, const py::object& ies,
             const py::object& shader, float shader_power) {
            self.check_editable();
            const Mat4 m = to_mat4(matrix, "area light matrix");
            Light l;
            set_light_ies(l, ies, m);
            l.type = ellipse ? LightType::Ellipse : LightType::Rect;
            l.position = {m.m[0][3], m.m[1][3], m.m[2][3]};
            l.axis_u = m.vector({finite_nonneg(size_x, "size_x"), 0.0f, 0.0f});
            l.axis_v = m.vector({0.0f, finite_nonneg(size_y, "size_y"), 0.0f});
            const Vec3 n = cross(l.axis_u, l.axis_v);
            l.area = length(n) * (ellipse ? kPi / 4.0f : 1.0f);
            if (!(l.area > 0.0f) || !std::isfinite(l.area)) return;  // nothing to emit from
            l.dir = -normalize(m.vector({0.0f, 0.0f, 1.0f}));  // emits along local -Z
            l.color = to_color(radiance, "radiance");
            // Cycles' spread (scene/light.cpp): normalized so that the light keeps its power. Below
            // 0.1 degrees clamped there (Cycles 4.5 makes 0 a collimated beam; we do not).
            const double spread_c = std::clamp(double(finite_nonneg(spread, "spread")), 0.1 * kPi / 180.0, double(kPi));
            if (spread_c < double(kPi) * (1.0 - 1e-6)) {
              const double half = 0.5 * spread_c, tan_half = std::tan(half);
              l.tan_half_spread = float(tan_half);
              l.normalize_spread = float(half > 0.05 ? 1.0 / (tan_half - half) : 3.0 / (half * half * half));
            }
            l.cast_shadow = cast_shadow;
            l.mis = use_mis;
            l.visibility = light_visibility(visible_camera, visible_diffuse, visible_glossy, visible_transmission, visible_volume);
            set_light_shader(self, l, shader, m, shader_power);
            self.scene->add_light(l);
          },
          py::arg("matrix"), py::arg("size_x"), py::arg("size_y"), py::arg("radiance"), py::arg("ellipse") = false,
          py::arg("cast_shadow") = true, py::arg("use_mis") = true,
          py::arg("visible_camera") = false, py::arg("visible_diffuse") = true, py::arg("visible_glossy") = true,
          py::arg("visible_transmission") = true, py::arg("visible_volume") = true, py::arg("spread") = kPi,
          py::arg("ies") = py::none(), py::arg("shader") = py::none(), py::arg("shader_power") = 1.0f,
          "shader, shader_power: as add_point_light's. spread: Blender's Spread (radians, 0.1 degrees to pi): below pi the emission is limited to a cone about "
          "the normal, as Cycles' soft-box grid. ies: an IesProfile scaling the radiance by the direction of the "
          "light leaving the light, in its frame.")
      .def(
          "add_portal_light",
          [](PyScene& self, const FloatArray& matrix, float size_x, float size_y, bool ellipse) {
            self.check_editable();
            const Mat4 m = to_mat4(matrix, "portal matrix");
            Light l;
            l.type = ellipse ? LightType::Ellipse : LightType::Rect;
            l.position = {m.m[0][3], m.m[1][3], m.m[2][3]};
            l.axis_u = m.vector({finite_nonneg(size_x, "size_x"), 0.0f, 0.0f});
            l.axis_v = m.vector({0.0f, finite_nonneg(size_y, "size_y"), 0.0f});
            const Vec3 n = cross(l.axis_u, l.axis_v);
            l.area = length(n) * (ellipse ? kPi / 4.0f : 1.0f);
            if (!(l.area > 0.0f) || !std::isfinite(l.area)) return false;  // no opening
            l.dir = -normalize(m.vector({0.0f, 0.0f, 1.0f}));  // lets the world in along local -Z
            if (!is_finite(l.dir)) return false;
            l.color = Vec3(1.0f);
            self.scene->add_portal(l);
            return true;
          },
          py::arg("matrix"), py::arg("size_x"), py::arg("size_y"), py::arg("ellipse") = false,
          "A light portal (Cycles' is_portal area light): the world is sampled through this rectangle or ellipse "
          "(the area light's matrix and sizes) from points on its emission side (local -Z); it emits nothing. "
          "False (nothing added) for a degenerate one.")
      .def_property_readonly("portal_count", [](const PyScene& self) { return self.scene->portal_count(); })
      .def(
          "set_world_texture",
          [](PyScene& self, const FloatArray& pixels, float strength, const py::object& rotation_obj, bool srgb) {
            self.check_editable();
            if (pixels.ndim() != 3 || (pixels.shape(2) != 3 && pixels.shape(2) != 4) || pixels.shape(0) < 1 ||
                pixels.shape(1) < 1)
              throw std::invalid_argument("world texture pixels must have shape (H, W, 3) or (H, W, 4)");
            if (pixels.shape(0) > 65536 || pixels.shape(1) > 65536)
              throw std::invalid_argument("world texture is too large");
            const FloatArray rotation = rotation_obj.is_none()
                                            ? FloatArray(py::array_t<float>(std::vector<py::ssize_t>{3, 3}))
                                            : rotation_obj.cast<FloatArray>();
            if (rotation.ndim() != 2 || rotation.shape(0) != 3 || rotation.shape(1) != 3)
              throw std::invalid_argument("rotation must be a 3x3 matrix");
            const int h = int(pixels.shape(0)), w = int(pixels.shape(1)), c = int(pixels.shape(2));
            std::vector<Vec3> px(size_t(w) * size_t(h));
            const float* src = pixels.data();
            auto clean = [](float x) { return std::isfinite(x) && x > 0.0f ? x : 0.0f; };
            for (size_t i = 0; i < px.size(); ++i)
              px[i] = {clean(src[i * c]), clean(src[i * c + 1]), clean(src[i * c + 2])};
            Mat4 rot;
            auto r = rotation.unchecked<2>();
            for (int i = 0; i < 3; ++i)
              for (int j = 0; j < 3; ++j) rot.m[i][j] = rotation_obj.is_none() ? float(i == j) : r(i, j);
            if (!rot.is_finite()) throw std::invalid_argument("rotation contains NaN or infinite values");
            rot = orthonormal_rotation(rot);
            const float k = std::isfinite(strength) && strength > 0.0f ? strength : 0.0f;
            // A constant image is a constant world: no texture lookups, no light sampling
            // (cosine-weighted BSDF samples are already ideal for it).
            bool constant = true;
            for (size_t i = 1; i < px.size() && constant; ++i)
              constant = px[i].x == px[0].x && px[i].y == px[0].y && px[i].z == px[0].z;
            if (constant) {
              self.scene->set_environment(Environment());
              const Vec3 c = srgb ? Vec3{srgb_to_linear(px[0].x), srgb_to_linear(px[0].y), srgb_to_linear(px[0].z)} : px[0];
              self.scene->set_world_color(c * k);
              return;
            }
            py::gil_scoped_release release;
            self.scene->set_environment(Environment(std::move(px), w, h, k, rot, srgb));
          },
          py::arg("pixels"), py::arg("strength") = 1.0f, py::arg("rotation") = py::none(), py::arg("srgb") = false,
          "An equirectangular world image (H, W, 3 or 4; row 0 = bottom) times strength, turned by rotation "
          "(world -> texture directions). srgb: the pixels are an 8-bit sRGB image's byte / 255 values, kept "
          "encoded: lookups interpolate them and decode after (Cycles' NODE_IMAGE_COMPRESS_AS_SRGB); else "
          "scene-linear values.")
      .def(
          "set_world_sky",
          [](PyScene& self, float sun_elevation, float sun_rotation, float sun_size, float sun_intensity,
             bool sun_disc, float altitude, float air, float dust, float ozone, float strength,
             const py::object& rotation_obj, const py::object& xyz_to_rgb, int width) {
            check_sky(self, width);
            const SkyParams p = sky_params(sun_elevation, sun_rotation, sun_size, sun_intensity, sun_disc, altitude,
                                           air, dust, ozone);
            set_sky(self, strength, rotation_obj, xyz_to_rgb, width, [&](const float* m) { return nishita_sky(p, m); });
          },
          py::arg("sun_elevation") = 0.2617994f, py::arg("sun_rotation") = 0.0f, py::arg("sun_size") = 0.009512f,
          py::arg("sun_intensity") = 1.0f, py::arg("sun_disc") = true, py::arg("altitude") = 0.0f,
          py::arg("air") = 1.0f, py::arg("dust") = 1.0f, py::arg("ozone") = 1.0f, py::arg("strength") = 1.0f,
          py::arg("rotation") = py::none(), py::arg("xyz_to_rgb") = py::none(), py::arg("width") = 1024,
          "Blender's Sky Texture (Nishita) as the world, times strength: angles in radians, altitude in "
          "metres, air/dust/ozone densities as the node's. rotation: world -> sky directions (3x3, as "
          "set_world_texture). xyz_to_rgb: CIE XYZ -> scene linear (3x3; default Blender's Rec.709). width: "
          "of the equirectangular image that steers the samples (the disc is sampled on its own).")
      .def(
          "set_world_preetham",
          [](PyScene& self, const py::object& sun_direction, float turbidity, float strength,
             const py::object& rotation_obj, const py::object& xyz_to_rgb, int width) {
            check_sky(self, width);
            const Vec3 sun = to_point(sun_direction, "sun_direction");
            set_sky(self, strength, rotation_obj, xyz_to_rgb, width,
                    [&](const float* m) { return std::make_shared<const SkyModel>(sun, turbidity, m); });
          },
          py::arg("sun_direction") = py::make_tuple(0.0f, 0.0f, 1.0f), py::arg("turbidity") = 2.2f,
          py::arg("strength") = 1.0f, py::arg("rotation") = py::none(), py::arg("xyz_to_rgb") = py::none(),
          py::arg("width") = 1024,
          "Blender's Sky Texture (Preetham) as the world, times strength: the node's Sun Direction and "
          "Turbidity; rotation, xyz_to_rgb and width as set_world_sky.")
      .def(
          "set_world_hosek",
          [](PyScene& self, const py::object& sun_direction, float turbidity, float ground_albedo, float strength,
             const py::object& rotation_obj, const py::object& xyz_to_rgb, int width) {
            check_sky(self, width);
            const Vec3 sun = to_point(sun_direction, "sun_direction");
            set_sky(self, strength, rotation_obj, xyz_to_rgb, width, [&](const float* m) {
              return std::make_shared<const SkyModel>(sun, turbidity, ground_albedo, m);
            });
          },
          py::arg("sun_direction") = py::make_tuple(0.0f, 0.0f, 1.0f), py::arg("turbidity") = 2.2f,
          py::arg("ground_albedo") = 0.3f, py::arg("strength") = 1.0f, py::arg("rotation") = py::none(),
          py::arg("xyz_to_rgb") = py::none(), py::arg("width") = 1024,
          "Blender's Sky Texture (Hosek / Wilkie) as the world, times strength: the node's Sun Direction, "
          "Turbidity and Ground Albedo; rotation, xyz_to_rgb and width as set_world_sky.")
      .def(
          "set_world_color",
          [](PyScene& self, const py::object& c) {
            self.check_editable();
            self.scene->set_environment(Environment());  // a colour replaces any texture
            self.scene->set_world_color(to_color(c, "world color"));
          },
          py::arg("color"))
      .def(
          "set_world_program",
          [](PyScene& self, const py::list& program, int width, int height) {
            self.check_editable();
            if (width < 8 || width > 16384 || width % 2) throw std::invalid_argument("width must be even, 8..16384");
            if (height <= 0) height = width / 2;
            if (height < 4 || height > 16384) throw std::invalid_argument("height must be 4..16384");
            Material mat = make_shader(self, "world", program, py::none(), false);
            if (!mat.program.varying) {  // a constant world: its colour, as set_world_color
              ShadingContext ctx;
              ctx.ng = ctx.ns = ctx.wo = {0.0f, 0.0f, 1.0f};
              ClosureList out;
              eval_shader(mat.program, self.scene->images(), ctx, out);
              self.scene->set_environment(Environment());
              self.scene->set_world_color(is_finite(out.emission) ? out.emission : Vec3(0.0f));
              return false;
            }
            auto sh = std::make_shared<WorldShader>();
            sh->program = std::move(mat.program);
            self.scene->set_environment(Environment(std::move(sh), width, height));
            return true;
          },
          py::arg("program"), py::arg("width") = 1024, py::arg("height") = 0,
          "The world's Surface as a shader program (add_shader's ops; Background and Emission closures give "
          "the radiance), evaluated per escaped ray with its Light Path state (P = the direction, N = "
          "Incoming = -it, as Cycles' background). A map width x height (0: width / 2) of it (no ray kind), baked at "
          "commit, steers the world's light samples. A constant program becomes the constant world colour "
          "(returns False; True: a program world).")
      .def(
          "world_radiance",
          [](const PyScene& self, const FloatArray& dirs, bool camera_ray) {
            if (!self.scene->committed()) throw std::invalid_argument("commit() the scene first");
            if (dirs.ndim() != 2 || dirs.shape(1) != 3) throw std::invalid_argument("dirs must have shape (N, 3)");
            const size_t n = size_t(dirs.shape(0));
            py::array_t<float> out(std::vector<py::ssize_t>{py::ssize_t(n), 3});
            auto o = out.mutable_unchecked<2>();
            auto d = dirs.unchecked<2>();
            RayState rs;
            rs.flags = camera_ray ? kRayCamera : kRayDiffuse | kRayReflect;
            rs.depth = camera_ray ? 0 : 1;
            for (size_t i = 0; i < n; ++i) {
              const Vec3 v = self.scene->background(Vec3(d(i, 0), d(i, 1), d(i, 2)), &rs);
              o(i, 0) = v.x, o(i, 1) = v.y, o(i, 2) = v.z;
            }
            return out;
          },
          py::arg("dirs"), py::arg("camera_ray") = false,
          "The world's radiance along unit directions (N, 3) for an escaped camera ray, or (camera_ray "
          "False) a diffuse bounce's ray (committed scene).")
      .def(
          "world_sample",
          [](const PyScene& self, const FloatArray& u, bool cover_all) {
            if (!self.scene->committed()) throw std::invalid_argument("commit() the scene first");
            if (u.ndim() != 2 || u.shape(1) != 2) throw std::invalid_argument("u must have shape (N, 2)");
            const Environment& env = self.scene->environment();
            const size_t n = size_t(u.shape(0));
            py::array_t<float> dirs(std::vector<py::ssize_t>{py::ssize_t(n), 3}), rad(std::vector<py::ssize_t>{py::ssize_t(n), 3}),
                pdfs(std::vector<py::ssize_t>{py::ssize_t(n)}), pdf_of(std::vector<py::ssize_t>{py::ssize_t(n)});
            auto a = u.unchecked<2>();
            auto dd = dirs.mutable_unchecked<2>();
            auto rr = rad.mutable_unchecked<2>();
            auto pp = pdfs.mutable_unchecked<1>();
            auto qq = pdf_of.mutable_unchecked<1>();
            for (size_t i = 0; i < n; ++i) {
              Vec3 dir(0.0f), li(0.0f);
              float pdf = 0.0f;
              if (!env.valid() || !env.sample({a(i, 0), a(i, 1)}, dir, li, pdf, cover_all)) pdf = 0.0f, dir = li = Vec3(0.0f);
              dd(i, 0) = dir.x, dd(i, 1) = dir.y, dd(i, 2) = dir.z;
              rr(i, 0) = li.x, rr(i, 1) = li.y, rr(i, 2) = li.z;
              pp(i) = pdf;
              qq(i) = env.valid() && pdf > 0.0f ? env.pdf(dir, cover_all) : 0.0f;
            }
            return py::make_tuple(dirs, rad, pdfs, pdf_of);
          },
          py::arg("u"), py::arg("cover_all") = true,
          "The environment's own light samples for uniforms u (N, 2): (directions, radiance (no ray kind), the "
          "sample's pdf, pdf() of its direction); zeros where it has none (committed scene).")
      .def(
          "world_pdf",
          [](const PyScene& self, const FloatArray& dirs, bool cover_all) {
            if (!self.scene->committed()) throw std::invalid_argument("commit() the scene first");
            if (dirs.ndim() != 2 || dirs.shape(1) != 3) throw std::invalid_argument("dirs must have shape (N, 3)");
            const Environment& env = self.scene->environment();
            const size_t n = size_t(dirs.shape(0));
            py::array_t<float> out(std::vector<py::ssize_t>{py::ssize_t(n)});
            auto o = out.mutable_unchecked<1>();
            auto d = dirs.unchecked<2>();
            for (size_t i = 0; i < n; ++i) o(i) = env.valid() ? env.pdf(Vec3(d(i, 0), d(i, 1), d(i, 2)), cover_all) : 0.0f;
            return out;
          },
          py::arg("dirs"), py::arg("cover_all") = true,
          "The environment's own solid-angle pdf along unit directions (N, 3) (committed scene).")
      .def(
          "set_world_volume",
          [](PyScene& self, const py::object& volume) {
            self.check_editable();
            ShaderProgram v;
            if (!volume.is_none()) v = make_shader(self, "world volume", py::list(), py::none(), false, volume).program;
            self.scene->set_world_volume(v);
          },
          py::arg("volume"),
          "The world's Volume (add_shader's volume dict or program, or None): a medium filling the "
          "scene outside objects' media. A program is tracked over the scene's bounds (geometry, lights, "
          "camera) and is empty beyond them; stats()['world_volume_open'] says how open the scene is.")
      .def(
          "add_volume_grid",
          [](PyScene& self, const std::shared_ptr<VolumeGrid>& grid) {
            self.check_editable();
            if (!grid) throw std::invalid_argument("add_volume_grid: no grid");
            return self.scene->add_volume_grid(grid);
          },
          py::arg("grid"),
          "Adds a VolumeGrid (read_vdb's) that volume programs read by the returned id "
          "(op \"volume_grid\"); a program naming an id not added reads 0.")
      .def_property_readonly("volume_grid_count", [](PyScene& self) { return self.scene->volume_grid_count(); })
      .def(
          "set_majorant_scale",
          [](PyScene& self, float scale) {
            self.check_editable();
            self.scene->set_majorant_scale(finite_nonneg(scale, "scale"));
          },
          py::arg("scale"),
          "Scales the heterogeneous media's majorants at the next commit (tests: below 1 they are too "
          "small, where the estimators must stay unbiased).")
      .def(
          "medium_majorants",
          [](PyScene& self, int64_t instance, int64_t material) {
            const HeteroMedium* h = committed_medium(self, instance, material);
            if (!h) throw std::invalid_argument("no heterogeneous medium of that instance and material (commit first)");
            constexpr int N = MajorantGrid::kRes;
            FloatArray g({N, N, N});
            std::copy(h->grid.cells.begin(), h->grid.cells.end(), g.mutable_data());
            const Aabb& b = h->grid.bounds;
            return py::make_tuple(g, py::make_tuple(b.lo.x, b.lo.y, b.lo.z), py::make_tuple(b.hi.x, b.hi.y, b.hi.z));
          },
          py::arg("instance"), py::arg("material"),
          "(majorants (z, y, x) of the 16^3 grid, bounds lo, hi) of a committed heterogeneous medium "
          "(instance -1: the world's Volume program, whatever the material).")
      .def(
          "medium_at",
          [](PyScene& self, int64_t instance, int64_t material, const py::object& p, const py::object& dir,
             float time) {
            const HeteroMedium* h = committed_medium(self, instance, material);
            if (!h) throw std::invalid_argument("no heterogeneous medium of that instance and material (commit first)");
            if (!(time >= 0.0f && time <= 1.0f)) throw std::invalid_argument("time must be in [0, 1]");
            const MediumSample m = self.scene->medium_at(*h, to_point(p, "p"), normalize(to_point(dir, "dir")), time);
            py::dict d;
            d["sigma_a"] = py::make_tuple(m.sigma_a.x, m.sigma_a.y, m.sigma_a.z);
            d["sigma_s"] = py::make_tuple(m.sigma_s.x, m.sigma_s.y, m.sigma_s.z);
            d["emission"] = py::make_tuple(m.emission.x, m.emission.y, m.emission.z);
            d["g"] = m.phase.g;
            return d;
          },
          py::arg("instance"), py::arg("material"), py::arg("p"), py::arg("dir") = py::make_tuple(0.0f, 0.0f, 1.0f),
          py::arg("time") = 0.5f,
          "A heterogeneous medium's coefficients at world point p (its volume program's outputs) at "
          "shutter time `time` in [0, 1] (motion blur: the instance's transform, the velocity).")
      .def(
          "medium_track",
          [](PyScene& self, int64_t instance, int64_t material, const py::object& org, const py::object& dir,
             float tmax, int64_t n, const std::string& mode, uint64_t seed, const py::object& time_obj) {
            const HeteroMedium* h = committed_medium(self, instance, material);
            if (!h) throw std::invalid_argument("no heterogeneous medium of that instance and material (commit first)");
            // time: a shutter time in [0, 1], or None: each estimate draws its own (a box shutter).
            const bool fixed_time = !time_obj.is_none();
            const float time_value = fixed_time ? time_obj.cast<float>() : 0.5f;
            if (fixed_time && !(time_value >= 0.0f && time_value <= 1.0f))
              throw std::invalid_argument("time must be in [0, 1] or None");
            if (mode != "ratio" && mode != "delta") throw std::invalid_argument("mode must be 'ratio' or 'delta'");
            if (n < 0) throw std::invalid_argument("n must be >= 0");
            const Vec3 o = to_point(org, "org"), d = normalize(to_point(dir, "dir"));
            FloatArray w({py::ssize_t(n), py::ssize_t(3)}), t({py::ssize_t(n)});
            float* wp = w.mutable_data();
            float* tp = t.mutable_data();
            const Scene& scene = *self.scene;
            {
              py::gil_scoped_release release;
              for (int64_t i = 0; i < n; ++i) {
                Pcg32 rng(mix64(seed * 0x9E3779B97F4A7C15ULL + uint64_t(i)), seed);
                const float time = fixed_time ? time_value : rng.next_float();
                const auto eval = [&](float tt) { return scene.medium_at(*h, o + d * tt, d, time); };
                Vec3 v(1.0f);
                float tt = kInf;
                if (mode == "ratio") {
                  v = ratio_track(h->grid, o, d, tmax, rng, eval, 1.0f);  // (the grid's majorants as they are)
                } else {
                  MediumSample ms;
                  int steps = 0;
                  float ts = 0.0f;
                  if (delta_track(h->grid, o, d, tmax, rng, eval, v, nullptr, ts, ms, steps)) tt = ts;
                }
                wp[3 * i] = v.x, wp[3 * i + 1] = v.y, wp[3 * i + 2] = v.z;
                tp[i] = tt;
              }
            }
            return py::make_tuple(t, w);
          },
          py::arg("instance"), py::arg("material"), py::arg("org"), py::arg("dir"), py::arg("tmax"), py::arg("n"),
          py::arg("mode") = "ratio", py::arg("seed") = 0, py::arg("time") = py::float_(0.5),
          "n independent estimates along org + t dir, t in [0, tmax], in a committed heterogeneous medium: "
          "(distances (n,), weights (n, 3)). 'ratio': ratio tracking's transmittance estimates (distances "
          "inf); 'delta': delta tracking's scattering distances (inf: passed tmax) and path weights "
          "(the integrator's estimators, scene/medium_grid.h). time: the shutter time in [0, 1] of every "
          "estimate, or None: a uniform time each (motion blur).")
      .def(
          "set_camera",
          [](PyScene& self, const CameraDesc& c) {
            self.check_editable();
            validate_camera(c);
            self.scene->set_camera(c);
          },
          py::arg("camera"))
      .def(
          "commit",
          [](PyScene& self, int threads, const std::string& bvh) {
            self.check_editable();
            const BvhLayout layout = enum_from_name(bvh, "bvh", kBvhLayoutNames);
            bool done;
            {
              py::gil_scoped_release release;
              done = self.scene->commit(threads, layout);
            }
            if (!done) throw std::runtime_error("commit cancelled");
          },
          py::arg("threads") = 0, py::arg("bvh") = "auto",
          "Builds the BVH and the lights (GIL released). bvh: 'auto' (8-wide with AVX2, else 4-wide), "
          "or 'binary', 'bvh4', 'bvh8' to test one kernel ('bvh8' falls back to 'bvh4' without AVX2). "
          "Raises RuntimeError('commit cancelled') when cancel_commit() stopped it.")
      .def(
          "cancel_commit", [](PyScene& self) { self.scene->cancel_commit(); },
          "Stops a commit() running in another thread; that commit raises RuntimeError and leaves the "
          "scene uncommitted. Has no effect when no commit is running.")
      .def_property("solid_angle_triangle_sampling", scene_get<&Scene::solid_angle_triangle_sampling>(),
                    scene_flag_set<&Scene::set_solid_angle_triangle_sampling>(),
          "Light-sample emissive triangles uniformly in solid angle (True, the default) or by area.")
      .def_property("solid_angle_rect_sampling", scene_get<&Scene::solid_angle_rect_sampling>(),
                    scene_flag_set<&Scene::set_solid_angle_rect_sampling>(),
          "Light-sample rectangle lights uniformly in solid angle where it is not tiny (True, the "
          "default) or always by area.")
      .def_property("light_hits", scene_get<&Scene::light_hits_enabled>(),
                    scene_flag_set<&Scene::set_light_hits>(),
          "Rays find analytic lights with extent (point and spot disks, area lights, suns with an "
          "angle) and weigh them against light samples by MIS (True, the default); False: those "
          "lights are reached by light samples alone, each with the full weight. Takes effect at the "
          "next commit().")
      .def_property("emitter_groups", scene_get<&Scene::emitter_groups>(),
                    scene_flag_set<&Scene::set_emitter_groups>(),
          "Sample a small mesh light (up to 4 triangles of one material in one object, such as a "
          "quad) as one light, each triangle chosen in proportion to its solid angle (True, the "
          "default), or each triangle as a light of its own. Takes effect at the next commit().")
      .def_property("rect_groups", scene_get<&Scene::rect_groups>(),
                    scene_flag_set<&Scene::set_rect_groups>(),
          "Sample an emitter group whose two triangles form a rectangle as one spherical rectangle "
          "(True, the default; same distribution, less work) or as two spherical triangles. Takes "
          "effect at the next commit().")
      .def("light_samples", &light_samples, py::arg("points"), py::arg("u"), py::arg("normals") = py::none(),
           py::arg("bsdf_follows") = true,
           "Light samples (next-event estimation) from points (N, 3) with uniforms u (N, 3: the light "
           "choice and the 2-D sample): (ok, wi (N, 3), dist, pdf, pdf_hit, t_hit), pdf_hit the pdf the "
           "renderer's MIS gives the emitter (or analytic light with extent) the ray p + t wi hits first "
           "at t_hit (0 and inf for none). "
           "normals (N, 3): the shading normals the light tree's choice reads (None: none). "
           "bsdf_follows=False: the distribution used where no BSDF sample follows. Exposed for tests.")
      .def("light_choices", &light_choices, py::arg("points"), py::arg("normals"), py::arg("u"),
           py::arg("all_pmfs") = false, py::arg("light_set") = 0,
           "The light chosen from points (N, 3) with normals (N, 3; zero rows: none) by uniforms u (N,), "
           "over the entries [analytic lights | emitter groups | environment]: (index (-1: none), pmf, "
           "pmfs (N, K) of every entry when all_pmfs), for points of light set light_set (light "
           "linking). Exposed for tests.")
      .def_property(
          "light_tree",
          [](const PyScene& self) {
            const Scene::LightTreeMode m = self.scene->light_tree();
            return std::string(m == Scene::LightTreeMode::On ? "on" : m == Scene::LightTreeMode::Off ? "off" : "auto");
          },
          [](PyScene& self, const std::string& mode) {
            self.check_editable();
            if (mode == "auto") self.scene->set_light_tree(Scene::LightTreeMode::Auto);
            else if (mode == "on") self.scene->set_light_tree(Scene::LightTreeMode::On);
            else if (mode == "off") self.scene->set_light_tree(Scene::LightTreeMode::Off);
            else throw std::invalid_argument("light_tree must be 'auto', 'on' or 'off'");
          },
          "Many-light sampling by a light tree: 'auto' (the default: where the scene has more than "
          "8 finite lights), 'on' or 'off' (one distribution by power). Takes effect at the next commit().")
      .def_property(
          "defer_world_samples", [](const PyScene& self) { return self.scene->defer_world_samples(); },
          [](PyScene& self, bool on) { self.scene->set_defer_world_samples(on); },
          "A surface's light sample of a sky with a sun disc, or through portals, takes its radiance and "
          "pdf only once its shadow ray is clear (the default: the same image, less work where most are "
          "blocked). False: all at once (for measurements and tests).")
      .def_property(
          "world_light_samples", [](const PyScene& self) { return self.scene->world_samples(); },
          [](PyScene& self, bool on) { self.scene->set_world_samples(on); },
          "Light samples of a constant world colour that is the only light, at every surface vertex "
          "besides the BSDF ray (MIS-weighted; the default). False: the BSDF ray alone finds it.")
      .def_property(
          "world_sampled", [](const PyScene& self) { return self.scene->world_sampled(); },
          [](PyScene& self, bool on) { self.scene->set_world_sampled(on); },
          "World ▸ Settings ▸ Sampling Method: True (Automatic, Manual; the default) the world map is a light "
          "to sample; False (None) it is not, as Cycles adds no background light then: only rays that escape "
          "find the world (weight 1), and no caustic light paths start from it; with portals it is sampled through "
          "them alone (Cycles' map_weight 0). Takes effect at the next commit().")
      .def_property_readonly("light_tree_active", [](const PyScene& self) { return self.scene->light_tree_active(); },
                             "Whether the last commit() built a light tree that sample_direct uses.")
      .def("stats", &scene_stats)
      .def("intersect", &intersect_batch, py::arg("origins"), py::arg("directions"), py::arg("tmax") = kInf,
           py::arg("instances") = false, py::arg("time") = 0.5f,
           "Closest hits of a batch of rays (at shutter time `time`, for motion blur): returns (t, prim, b1, b2); prim (the triangle's index in the "
           "flattened scene, instance by instance) is -1 and t inf on a miss. instances=True adds two "
           "int64 arrays: the hit instance (add_instance order) and the triangle's row in its mesh (-1 on a miss).")
      .def("hit_surfaces", &hit_surfaces, py::arg("origins"), py::arg("directions"), py::arg("tmax") = kInf,
           py::arg("self_strand") = py::none(), py::arg("time") = 0.5f,
           "The surfaces a batch of rays hits (at shutter time `time`): a dict of t, p, ng, tangent, origin_out, origin_in (the spawn "
           "origins on the normal's side and the other), curve (bool) and strand (int64, the strand hit, -1: "
           "none), hit (N, 2: the hit's b1, b2; ribbons: u along the piece and v across, -1 .. 1). self_strand: "
           "int (N,), the strand each ray leaves (skipped, as a path's spawned rays; -1: none).")
      .def("occluded", &occluded_batch, py::arg("origins"), py::arg("directions"), py::arg("tmax") = kInf,
           py::arg("time") = 0.5f,
           "Any-hit test of a batch of rays with 0 < t < tmax (directions need not be unit length).")
      .def("traversal_counts", &traversal_counts, py::arg("origins"), py::arg("directions"),
           py::arg("tmax") = py::none(),
           "BVH nodes visited and triangles tested by the closest-hit search of each ray: (nodes, triangles), "
           "uint32 (N,). tmax: float (N,) or None (unbounded).")
      .def("camera_rays", &camera_rays, py::arg("width"), py::arg("height"), py::arg("xy"),
           "The render's camera rays through raster positions xy (N, 2), pixels from the bottom-left: "
           "(origins (N,3), directions (N,3), tmax (N,)).");

  py::class_<PySession>(m, "Session")
      .def(py::init([](PyScene& scene, const RenderSettings& settings, const py::object& camera_obj,
                       const py::object& bake_obj) {
             validate(settings);
             CameraDesc camera;
             const bool override_camera = !camera_obj.is_none();
             if (override_camera) {
               camera = camera_obj.cast<CameraDesc>();
               validate_camera(camera);
             }
             std::shared_ptr<BakeInput> bake;
             if (!bake_obj.is_none()) bake = parse_bake(bake_obj, settings);
             if (!override_camera && !bake && !scene.scene->has_camera()) throw std::invalid_argument("the scene has no camera");
             if (!scene.scene->committed()) {
               scene.check_editable();
               bool done;
               {
                 py::gil_scoped_release release;
                 done = scene.scene->commit(settings.threads);
               }
               if (!done) throw std::runtime_error("commit cancelled");
             }
             auto s = std::make_unique<PySession>();
             s->scene = scene.scene;
             s->session = std::make_unique<Session>(scene.scene, settings, override_camera ? &camera : nullptr, bake);
             return s;
           }),
           py::arg("scene"), py::arg("settings"), py::arg("camera") = py::none(), py::arg("bake") = py::none(),
           "A render of a committed scene (commits it first if needed). camera: a Camera overriding the "
           "scene's. bake: a bake instead (docs/design/bake.md), a dict: instance (int, add_instance "
           "order), triangle (int32 (N,): a triangle of its mesh per texel, -1: none), bary (float32 (N, 2): "
           "the weights b1, b2 of the triangle's corners 1 and 2), differentials (float32 (N, 4): db1/dx, "
           "db1/dy, db2/dx, db2/dy; optional), mode ('surface': Combined and the passes from a path that "
           "starts on the texel's surface; 'environment': the world along the direction to the texel's "
           "point; 'roughness': Cycles' Roughness pass), view_from_camera (bool: seen from the scene's camera, "
           "Blender's View From 'Active Camera'), N = width x height, texel y * width + x.")
      .def("start", [](PySession& self) { self.session->start(); })
      .def(
          "wait",
          [](PySession& self, double timeout_s) {
            bool done;
            {
              py::gil_scoped_release release;
              done = self.session->wait(timeout_s);
            }
            if (done) {
              const std::string err = self.session->error();
              if (!err.empty()) throw std::runtime_error("render failed: " + err);
            }
            return done;
          },
          py::arg("timeout_s"))
      .def("cancel", [](PySession& self) { self.session->cancel(); })
      .def("is_finished", [](PySession& self) { return self.session->finished(); })
      .def("progress",
           [](PySession& self) {
             const SessionProgress p = self.session->progress();
             py::dict d;
             d["samples_done"] = p.samples_done;
             d["samples_total"] = p.samples_total;
             d["elapsed_s"] = p.elapsed_s;
             d["cancelled"] = p.cancelled;
             d["finished"] = p.finished;
             return d;
           })
      .def("stats",
           [](PySession& self) {
             const SessionStats s = self.session->stats();
             py::dict d;
             d["samples_done"] = self.session->progress().samples_done;
             d["paths"] = s.paths;
             d["rays"] = s.rays;
             d["rays_per_s"] = s.elapsed_s > 0 ? double(s.rays) / s.elapsed_s : 0.0;
             d["nonfinite_samples"] = s.nonfinite_samples;
             d["passes"] = s.passes;
             d["threads"] = s.threads;
             d["work_items"] = s.work_items;
             d["elapsed_s"] = s.elapsed_s;
             d["active_pixels"] = s.active_pixels;
             d["focus_distance"] = s.focus_distance;
             d["autofocus"] = s.autofocus == 0 ? "off" : s.autofocus == 1 ? "hit" : "miss";
             d["kernel"] = s.kernel;
             d["caustics"] = s.caustics;
             d["guiding"] = s.guiding;
             d["caustic_connections"] = s.caustic_connections;
             d["features"] = s.features;
             d["unused_features"] = s.unused_features;
             d["guiding_iterations"] = s.guiding_iterations;
             d["guiding_cells"] = s.guiding_cells;
             d["guiding_caustic_cells"] = s.guiding_caustic_cells;
             d["guiding_probability"] = s.guiding_probability;
             return d;
           })
      .def("sample_counts",
           [](PySession& self) {
             Film& f = self.session->film();
             py::array_t<uint32_t> out({f.height(), f.width()});
             uint32_t* dst = out.mutable_data();
             {
               py::gil_scoped_release release;
               f.read_counts(dst);
             }
             return out;
           })
      .def("film",
           [](PySession& self) {
             const Film& f = self.session->film();
             return film_rect(self, 0, 0, f.width(), f.height());
           })
      .def("film_rect", &film_rect, py::arg("x"), py::arg("y"), py::arg("w"), py::arg("h"))
      .def(
          "guiding_pdf",
          [](PySession& self, const py::handle& p, const py::handle& w, const py::handle& n) {
            const GuidingField* g = self.session->guiding_field();
            if (!g || !self.session->finished()) throw std::invalid_argument("no finished guided render");
            return g->ready() ? g->pdf(to_point(p, "p"), to_point(n, "n"), normalize(to_point(w, "w"))) : 0.0f;
          },
          py::arg("p"), py::arg("w"), py::arg("n"),
          "The learnt guiding field's pdf towards w at p on a surface facing n (a finished guided render).")
      .def(
          "film_aov",
          [](PySession& self, int i) {
            Film& f = self.session->film();
            if (i < 0 || i >= f.aov_count()) throw std::invalid_argument("no shader AOV " + std::to_string(i));
            FloatArray out({f.height(), f.width(), f.aov_channels(i)});
            float* dst = out.mutable_data();
            {
              py::gil_scoped_release release;
              f.read_aov(i, dst);
            }
            return out;
          },
          py::arg("i"),
          "Shader AOV i (RenderSettings.shader_aovs) as float32 (H, W, channels), row 0 = bottom: the "
          "mean over samples of what the AOV Output ops of the camera path's first surfaces wrote "
          "(COLOR: (r, g, b, 1); VALUE: the value; 0 where nothing was written).")
      .def(
          "film_light_group",
          [](PySession& self, int i) {
            Film& f = self.session->film();
            if (i < 0 || i >= f.light_group_count()) throw std::invalid_argument("no light group " + std::to_string(i));
            FloatArray out({f.height(), f.width(), 3});
            float* dst = out.mutable_data();
            {
              py::gil_scoped_release release;
              f.read_light_group(i, dst);
            }
            return out;
          },
          py::arg("i"),
          "Light group i (RenderSettings.light_groups) as float32 (H, W, 3), row 0 = bottom: Cycles' "
          "Combined_<name> pass, the light of that group's emitters (times the exposure).")
      .def("film_pass", &film_pass, py::arg("name"),
           "One render pass as float32 (H, W, channels), row 0 = bottom (see render_passes()); "
           "also Cryptomatte's 'CryptoObject00', 'CryptoMaterial01', ... (H, W, 4).");
}
