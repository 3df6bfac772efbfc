// The module: the shared helpers, the module-level functions, Camera, RenderSettings and Session;
// Scene is bound in scene_bindings.cpp. core/python is the only code that sees Python: it converts
// and validates numpy input, turns C++ exceptions into Python ones (pybind11 maps
// std::invalid_argument to ValueError), and releases the GIL around everything that takes time.
#include "bindings.h"

#include "geometry/polygon_mesh.h"

#ifndef PATHLIGHT_SIMD_NAME
#define PATHLIGHT_SIMD_NAME "generic"
#endif
#ifndef PATHLIGHT_VERSION
#define PATHLIGHT_VERSION "0.0.0"
#endif

namespace plpy {

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

Pass pass_by_name(const std::string& name) {
  for (int p = 0; p < kPassCount; ++p)
    if (name == pass_desc(Pass(p)).name) return Pass(p);
  std::string known;
  for (int p = 0; p < kPassCount; ++p) known += std::string(p ? ", " : "") + "'" + pass_desc(Pass(p)).name + "'";
  throw std::invalid_argument("unknown render pass '" + name + "' (known: " + known + ")");
}

}  // namespace plpy

namespace {

using namespace plpy;

// Builds one BSDF from a name and parameters, for the BSDF tests (Mitsuba style).
Bsdf make_test_bsdf(const std::string& kind, const py::dict& p) {
  auto f = [&](const char* k, float d) { return p.contains(k) ? p[k].cast<float>() : d; };
  auto b = [&](const char* k, bool d) { return p.contains(k) ? p[k].cast<bool>() : d; };
  if (kind == "diffuse") return DiffuseBsdf{};
  if (kind == "conductor") {
    ConductorBsdf c;
    c.alpha = f("alpha", 0.3f);
    c.f0 = p.contains("f0") ? to_color(p["f0"], "f0") : Vec3(1.0f);
    c.schlick = b("schlick", false);
    return c;
  }
  if (kind == "dielectric") {
    DielectricBsdf d;
    d.alpha = f("alpha", 0.3f);
    d.eta = f("eta", 1.5f);
    d.reflection = b("reflection", true);
    d.transmission = b("transmission", true);
    d.fresnel_on_transmission = b("fresnel_on_transmission", true);
    d.schlick = b("schlick", false);
    return d;
  }
  if (kind == "transparent") return TransparentBsdf{};
  throw std::invalid_argument("unknown bsdf '" + kind + "'");
}

struct PySession {
  std::shared_ptr<Scene> scene;  // keeps the scene alive and locked against edits
  std::unique_ptr<Session> session;
};

FloatArray film_pass(PySession& self, const std::string& name) {
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
  return out;
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

// The module-level functions.
void bind_functions(py::module_& m) {
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
      "bsdf_eval",
      [](const std::string& kind, const py::dict& params, const py::object& wo_obj, const FloatArray& wi) {
        const Bsdf bsdf = make_test_bsdf(kind, params);
        const Vec3 wo = normalize(to_point(wo_obj, "wo"));
        if (wi.ndim() != 2 || wi.shape(1) != 3) throw std::invalid_argument("wi must have shape (N, 3)");
        const py::ssize_t n = wi.shape(0);
        FloatArray f({n, py::ssize_t(3)});
        py::array_t<float> pdf(n);
        const Vec3* w = reinterpret_cast<const Vec3*>(wi.data());
        for (py::ssize_t i = 0; i < n; ++i) {
          float p;
          const Vec3 v = bsdf_eval(bsdf, wo, w[i], p);
          for (int k = 0; k < 3; ++k) f.mutable_data()[3 * i + k] = v[k];
          pdf.mutable_data()[i] = p;
        }
        return py::make_tuple(f, pdf);
      },
      py::arg("kind"), py::arg("params"), py::arg("wo"), py::arg("wi"),
      "Evaluates f * |cos(wi)| and the sampling pdf of a BSDF in its local frame.");

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
      [](uint32_t seed, uint64_t pixel, uint32_t sample, int dims) {
        if (dims < 0 || dims > 1024) throw std::invalid_argument("dims must be in [0, 1024]");
        Sampler sampler(SamplerType::Sobol, seed, pixel, sample);
        py::array_t<float> out({py::ssize_t(dims), py::ssize_t(2)});
        for (int d = 0; d < dims; ++d) {
          const Vec2 u = sampler.get2d();
          out.mutable_data()[2 * d] = u.x;
          out.mutable_data()[2 * d + 1] = u.y;
        }
        return out;
      },
      py::arg("seed"), py::arg("pixel"), py::arg("sample"), py::arg("dims"),
      "The first `dims` 2-D draws of the Sobol sampler for (seed, pixel, sample): (dims, 2). "
      "Exposed for tests.");
}

// Camera, RenderSettings and render_passes.
void bind_settings(py::module_& m) {
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
      .def_readwrite("aperture_size", &CameraDesc::aperture_size)
      .def_readwrite("focus_distance", &CameraDesc::focus_distance)
      .def_readwrite("aperture_blades", &CameraDesc::aperture_blades)
      .def_readwrite("aperture_rotation", &CameraDesc::aperture_rotation)
      .def_readwrite("aperture_ratio", &CameraDesc::aperture_ratio)
      .def_readwrite("use_autofocus", &CameraDesc::use_autofocus)
      .def_readwrite("autofocus_x", &CameraDesc::autofocus_x)
      .def_readwrite("autofocus_y", &CameraDesc::autofocus_y)
      .def(
          "generate_ray",
          [](const CameraDesc& c, int width, int height, float x, float y, py::object lens) {
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
            const Ray r = pinhole ? cam.generate_pinhole(x, y) : cam.generate(x, y, u);
            return py::make_tuple(py::make_tuple(r.org.x, r.org.y, r.org.z), py::make_tuple(r.dir.x, r.dir.y, r.dir.z),
                                  r.tmax);
          },
          py::arg("width"), py::arg("height"), py::arg("x"), py::arg("y"), py::arg("lens") = py::none(),
          "The camera ray through raster (x, y) of a width x height frame: (origin, direction, tmax). "
          "lens: a point of the unit square on the aperture, or None for the lens centre.");

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
      .def_property(
          "sampler", [](const RenderSettings& s) { return enum_name(s.sampler, kSamplerNames); },
          [](RenderSettings& s, const std::string& v) { s.sampler = enum_from_name(v, "sampler", kSamplerNames); })
      .def_readwrite("adaptive_threshold", &RenderSettings::adaptive_threshold)
      .def_readwrite("adaptive_min_samples", &RenderSettings::adaptive_min_samples)
      .def_readwrite("diffuse_bounces", &RenderSettings::diffuse_bounces)
      .def_readwrite("glossy_bounces", &RenderSettings::glossy_bounces)
      .def_readwrite("transmission_bounces", &RenderSettings::transmission_bounces)
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
      .def_readwrite("exposure", &RenderSettings::exposure)
      .def_property(
          "debug_view", [](const RenderSettings& s) { return enum_name(s.debug_view, kDebugViewNames); },
          [](RenderSettings& s, const std::string& v) { s.debug_view = enum_from_name(v, "debug_view", kDebugViewNames); })
      .def_readwrite("sample_offset", &RenderSettings::sample_offset)
      .def_readwrite("force_general_kernel", &RenderSettings::force_general_kernel,
                     "Run the general integrator kernel, not the scene-specialised one (same image).");

  m.def(
      "render_passes",
      [] {
        py::dict d;
        for (int p = 0; p < kPassCount; ++p) d[pass_desc(Pass(p)).name] = pass_desc(Pass(p)).channels;
        return d;
      },
      "Every render pass the core can keep: {name: channels}, in the core's order.");
}

void bind_session(py::module_& m) {
  py::class_<PySession>(m, "Session")
      .def(py::init([](PyScene& scene, const RenderSettings& settings, const py::object& camera_obj) {
             validate(settings);
             CameraDesc camera;
             const bool override_camera = !camera_obj.is_none();
             if (override_camera) {
               camera = camera_obj.cast<CameraDesc>();
               validate_camera(camera);
             }
             if (!override_camera && !scene.scene->has_camera()) throw std::invalid_argument("the scene has no camera");
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
             s->session = std::make_unique<Session>(scene.scene, settings, override_camera ? &camera : nullptr);
             return s;
           }),
           py::arg("scene"), py::arg("settings"), py::arg("camera") = py::none())
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
             d["elapsed_s"] = s.elapsed_s;
             d["active_pixels"] = s.active_pixels;
             d["focus_distance"] = s.focus_distance;
             d["autofocus"] = s.autofocus == 0 ? "off" : s.autofocus == 1 ? "hit" : "miss";
             d["kernel"] = s.kernel;
             d["features"] = s.features;
             d["unused_features"] = s.unused_features;
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
      .def("film_pass", &film_pass, py::arg("name"),
           "One render pass as float32 (H, W, channels), row 0 = bottom (see render_passes()).");
}

}  // namespace

PYBIND11_MODULE(pathlight_core, m) {
  m.doc() = "Pathlight's compiled core: scene, BVH, path tracer and progressive render sessions.";
  m.attr("__version__") = PATHLIGHT_VERSION;
  m.def("build_info", [] {
    py::dict d;
    d["simd"] = PATHLIGHT_SIMD_NAME;
    // The BVH kernel commit() picks by default on this CPU (run-time detection).
    d["bvh"] = cpu_has_avx2() ? "bvh8" : "bvh4";
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
  bind_functions(m);
  bind_settings(m);
  plpy::bind_scene(m);
  bind_session(m);
}
