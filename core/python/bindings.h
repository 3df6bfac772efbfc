// Private to core/python, the only code that sees Python: what the binding files share.
// Two translation units of similar compile time that the build runs in parallel (in one file the
// bindings were the core's longest compile).
#pragma once
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <initializer_list>
#include <memory>
#include <stdexcept>
#include <string>
#include <utility>

#include "render/session.h"

namespace py = pybind11;
using namespace pl;

namespace plpy {

using FloatArray = py::array_t<float, py::array::c_style | py::array::forcecast>;
using IntArray = py::array_t<int64_t, py::array::c_style | py::array::forcecast>;

Vec3 to_color(const py::handle& h, const char* what);
Vec3 to_point(const py::handle& h, const char* what);
float finite_nonneg(float x, const char* what);

// A setting Python names by strings: its enum's values and their names in one table, read
// both ways; an unknown name is a ValueError that lists the names (quoted, or bare as Blender's
// upper-case enum names have always been listed).
template <class E>
using EnumNames = std::initializer_list<std::pair<E, const char*>>;
template <class E>
inline const char* enum_name(E v, EnumNames<E> names) {
  for (const auto& [e, n] : names)
    if (e == v) return n;
  return names.begin()->second;
}
template <class E>
inline E enum_from_name(const std::string& s, const char* setting, EnumNames<E> names, bool quoted = true) {
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
inline constexpr EnumNames<Scene::CompactBvh> kCompactBvhNames = {
    {Scene::CompactBvh::Auto, "auto"}, {Scene::CompactBvh::On, "on"}, {Scene::CompactBvh::Off, "off"}};
inline constexpr EnumNames<Scene::BuildQuality> kBuildQualityNames = {
    {Scene::BuildQuality::Auto, "auto"}, {Scene::BuildQuality::Sah, "sah"}, {Scene::BuildQuality::Fast, "fast"}};
inline constexpr EnumNames<BvhLayout> kBvhLayoutNames = {
    {BvhLayout::Auto, "auto"}, {BvhLayout::Binary, "binary"}, {BvhLayout::Wide4, "bvh4"}, {BvhLayout::Wide8, "bvh8"}};
inline constexpr EnumNames<SamplerType> kSamplerNames = {{SamplerType::Sobol, "sobol"}, {SamplerType::Random, "random"}};
inline constexpr EnumNames<FilterType> kFilterNames = {
    {FilterType::Box, "box"}, {FilterType::Gaussian, "gaussian"}, {FilterType::BlackmanHarris, "blackman_harris"}};
inline constexpr EnumNames<DebugView> kDebugViewNames = {{DebugView::None, "none"}, {DebugView::Bvh, "bvh"}};
inline constexpr EnumNames<SensorFit> kSensorFitNames = {
    {SensorFit::Auto, "AUTO"}, {SensorFit::Horizontal, "HORIZONTAL"}, {SensorFit::Vertical, "VERTICAL"}};
inline constexpr EnumNames<CameraType> kCameraTypeNames = {{CameraType::Perspective, "PERSP"}, {CameraType::Orthographic, "ORTHO"}};
inline constexpr EnumNames<Interp> kInterpNames = {{Interp::Linear, "LINEAR"}, {Interp::Closest, "CLOSEST"}};
inline constexpr EnumNames<Extension> kExtensionNames = {
    {Extension::Repeat, "REPEAT"}, {Extension::Extend, "EXTEND"}, {Extension::Clip, "CLIP"}};

Mat4 to_mat4(const FloatArray& a, const char* what);
FloatArray from_mat4(const Mat4& m);
void validate_camera(const CameraDesc& c);
Pass pass_by_name(const std::string& name);

// A scene shared with the sessions that render it; edits are refused while one holds it.
struct PyScene {
  std::shared_ptr<Scene> scene = std::make_shared<Scene>();
  void check_editable() const {
    if (scene.use_count() > 1) throw std::runtime_error("the scene is in use by a render session");
  }
};

// PYBIND11_MODULE registers the parts in the original order: a signature names the Python class
// of a type only when that class is already registered.
void bind_scene(py::module_& m);  // Scene (scene_bindings.cpp); the rest is in bindings.cpp

}  // namespace plpy
