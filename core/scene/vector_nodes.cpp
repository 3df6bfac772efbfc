#include "scene/vector_nodes.h"

#include "scene/camera.h"
#include "scene/shader.h"

namespace pl {
namespace {

Vec3 safe_normalize(Vec3 v) {
  const float l = length(v);
  return l != 0.0f && std::isfinite(l) ? v / l : Vec3(0.0f);
}

// Rodrigues' rotation of p about a unit axis (Cycles' rotate_around_axis, term for term).
Vec3 rotate_around_axis(Vec3 p, Vec3 a, float angle) {
  const float c = std::cos(angle), s = std::sin(angle), k = 1.0f - c;
  return {(c + k * a.x * a.x) * p.x + (k * a.x * a.y - a.z * s) * p.y + (k * a.x * a.z + a.y * s) * p.z,
          (k * a.x * a.y + a.z * s) * p.x + (c + k * a.y * a.y) * p.y + (k * a.y * a.z - a.x * s) * p.z,
          (k * a.x * a.z - a.y * s) * p.x + (k * a.y * a.z + a.x * s) * p.y + (c + k * a.z * a.z) * p.z};
}

// M^T v for the 3x3 part of a row-major matrix.
Vec3 transposed_vector(const Mat4& m, Vec3 v) {
  return {m.m[0][0] * v.x + m.m[1][0] * v.y + m.m[2][0] * v.z, m.m[0][1] * v.x + m.m[1][1] * v.y + m.m[2][1] * v.z,
          m.m[0][2] * v.x + m.m[1][2] * v.y + m.m[2][2] * v.z};
}

// Cycles' blackbody fit (kernel/tables.h): a/t + b t + c for red and green, a cubic in t for
// blue, in seven temperature bands.
constexpr float kBlackbodyR[7][3] = {
    {1.61919106e+03f, -2.05010916e-03f, 5.02995757e+00f}, {2.48845471e+03f, -1.11330907e-03f, 3.22621544e+00f},
    {3.34143193e+03f, -4.86551192e-04f, 1.76486769e+00f}, {4.09461742e+03f, -1.27446582e-04f, 7.25731635e-01f},
    {4.67028036e+03f, 2.91258199e-05f, 1.26703442e-01f},  {4.59509185e+03f, 2.87495649e-05f, 1.50345020e-01f},
    {3.78717450e+03f, 9.35907826e-06f, 3.99075871e-01f}};
constexpr float kBlackbodyG[7][3] = {
    {-4.88999748e+02f, 6.04330754e-04f, -7.55807526e-02f}, {-7.55994277e+02f, 3.16730098e-04f, 4.78306139e-01f},
    {-1.02363977e+03f, 1.20223470e-04f, 9.36662319e-01f},  {-1.26571316e+03f, 4.87340896e-06f, 1.27054498e+00f},
    {-1.42529332e+03f, -4.01150431e-05f, 1.43972784e+00f}, {-1.17554822e+03f, -2.16378048e-05f, 1.30408023e+00f},
    {-5.00799571e+02f, -4.59832026e-06f, 1.09098763e+00f}};
constexpr float kBlackbodyB[7][4] = {
    {5.96945309e-11f, -4.85742887e-08f, -9.70622247e-05f, -4.07936148e-03f},
    {2.40430366e-11f, 5.55021075e-08f, -1.98503712e-04f, 2.89312858e-02f},
    {-1.40949732e-11f, 1.89878968e-07f, -3.56632824e-04f, 9.10767778e-02f},
    {-3.61460868e-11f, 2.84822009e-07f, -4.93211319e-04f, 1.56723440e-01f},
    {-1.97075738e-11f, 1.75359352e-07f, -2.50542825e-04f, -2.22783266e-02f},
    {-1.61997957e-13f, -1.64216008e-08f, 3.86216271e-04f, -7.38077418e-01f},
    {6.72650283e-13f, -2.73078809e-08f, 4.24098264e-04f, -7.52335691e-01f}};

// CIE 1931 2-degree colour matching functions (x, y, z) from 380 to 780 nm in 5 nm steps.
constexpr float kCie[81][3] = {
    {0.0014f, 0.0000f, 0.0065f}, {0.0022f, 0.0001f, 0.0105f}, {0.0042f, 0.0001f, 0.0201f},
    {0.0076f, 0.0002f, 0.0362f}, {0.0143f, 0.0004f, 0.0679f}, {0.0232f, 0.0006f, 0.1102f},
    {0.0435f, 0.0012f, 0.2074f}, {0.0776f, 0.0022f, 0.3713f}, {0.1344f, 0.0040f, 0.6456f},
    {0.2148f, 0.0073f, 1.0391f}, {0.2839f, 0.0116f, 1.3856f}, {0.3285f, 0.0168f, 1.6230f},
    {0.3483f, 0.0230f, 1.7471f}, {0.3481f, 0.0298f, 1.7826f}, {0.3362f, 0.0380f, 1.7721f},
    {0.3187f, 0.0480f, 1.7441f}, {0.2908f, 0.0600f, 1.6692f}, {0.2511f, 0.0739f, 1.5281f},
    {0.1954f, 0.0910f, 1.2876f}, {0.1421f, 0.1126f, 1.0419f}, {0.0956f, 0.1390f, 0.8130f},
    {0.0580f, 0.1693f, 0.6162f}, {0.0320f, 0.2080f, 0.4652f}, {0.0147f, 0.2586f, 0.3533f},
    {0.0049f, 0.3230f, 0.2720f}, {0.0024f, 0.4073f, 0.2123f}, {0.0093f, 0.5030f, 0.1582f},
    {0.0291f, 0.6082f, 0.1117f}, {0.0633f, 0.7100f, 0.0782f}, {0.1096f, 0.7932f, 0.0573f},
    {0.1655f, 0.8620f, 0.0422f}, {0.2257f, 0.9149f, 0.0298f}, {0.2904f, 0.9540f, 0.0203f},
    {0.3597f, 0.9803f, 0.0134f}, {0.4334f, 0.9950f, 0.0087f}, {0.5121f, 1.0000f, 0.0057f},
    {0.5945f, 0.9950f, 0.0039f}, {0.6784f, 0.9786f, 0.0027f}, {0.7621f, 0.9520f, 0.0021f},
    {0.8425f, 0.9154f, 0.0018f}, {0.9163f, 0.8700f, 0.0017f}, {0.9786f, 0.8163f, 0.0014f},
    {1.0263f, 0.7570f, 0.0011f}, {1.0567f, 0.6949f, 0.0010f}, {1.0622f, 0.6310f, 0.0008f},
    {1.0456f, 0.5668f, 0.0006f}, {1.0026f, 0.5030f, 0.0003f}, {0.9384f, 0.4412f, 0.0002f},
    {0.8544f, 0.3810f, 0.0002f}, {0.7514f, 0.3210f, 0.0001f}, {0.6424f, 0.2650f, 0.0000f},
    {0.5419f, 0.2170f, 0.0000f}, {0.4479f, 0.1750f, 0.0000f}, {0.3608f, 0.1382f, 0.0000f},
    {0.2835f, 0.1070f, 0.0000f}, {0.2187f, 0.0816f, 0.0000f}, {0.1649f, 0.0610f, 0.0000f},
    {0.1212f, 0.0446f, 0.0000f}, {0.0874f, 0.0320f, 0.0000f}, {0.0636f, 0.0232f, 0.0000f},
    {0.0468f, 0.0170f, 0.0000f}, {0.0329f, 0.0119f, 0.0000f}, {0.0227f, 0.0082f, 0.0000f},
    {0.0158f, 0.0057f, 0.0000f}, {0.0114f, 0.0041f, 0.0000f}, {0.0081f, 0.0029f, 0.0000f},
    {0.0058f, 0.0021f, 0.0000f}, {0.0041f, 0.0015f, 0.0000f}, {0.0029f, 0.0010f, 0.0000f},
    {0.0020f, 0.0007f, 0.0000f}, {0.0014f, 0.0005f, 0.0000f}, {0.0010f, 0.0004f, 0.0000f},
    {0.0007f, 0.0002f, 0.0000f}, {0.0005f, 0.0002f, 0.0000f}, {0.0003f, 0.0001f, 0.0000f},
    {0.0002f, 0.0001f, 0.0000f}, {0.0002f, 0.0001f, 0.0000f}, {0.0001f, 0.0000f, 0.0000f},
    {0.0001f, 0.0000f, 0.0000f}, {0.0001f, 0.0000f, 0.0000f}, {0.0000f, 0.0000f, 0.0000f},
};

}  // namespace

Vec3 vector_rotate(int type, bool invert, Vec3 v, Vec3 center, Vec3 axis, float angle, Vec3 euler) {
  if (type == 4) {  // Euler XYZ: R = Rz Ry Rx (Cycles' euler_to_transform), transposed to invert
    const float cx = std::cos(euler.x), cy = std::cos(euler.y), cz = std::cos(euler.z);
    const float sx = std::sin(euler.x), sy = std::sin(euler.y), sz = std::sin(euler.z);
    const Vec3 r0{cy * cz, sy * sx * cz - cx * sz, sy * cx * cz + sx * sz};
    const Vec3 r1{cy * sz, sy * sx * sz + cx * cz, sy * cx * sz - sx * cz};
    const Vec3 r2{-sy, cy * sx, cy * cx};
    const Vec3 d = v - center;
    if (invert) return r0 * d.x + r1 * d.y + r2 * d.z + center;
    return Vec3{dot(r0, d), dot(r1, d), dot(r2, d)} + center;
  }
  float axis_length = 1.0f;
  if (type == 1) axis = {1.0f, 0.0f, 0.0f};
  else if (type == 2) axis = {0.0f, 1.0f, 0.0f};
  else if (type == 3) axis = {0.0f, 0.0f, 1.0f};
  else axis_length = length(axis);
  if (invert) angle = -angle;
  if (axis_length == 0.0f) return v;
  return rotate_around_axis(v - center, axis / axis_length, angle) + center;
}

Vec3 blackbody_color(float t) {
  // Below 800 K the light is very dim (OSL's and Cycles' cut-off); above 12000 K constant.
  Vec3 c;
  if (t >= 12000.0f) {
    c = {0.8262954810464208f, 0.9945080501520986f, 1.566307710274283f};
  } else if (t < 800.0f || !std::isfinite(t)) {
    c = {5.413294490189271f, -0.20319390035873933f, -0.0822535242887164f};
  } else {
    const int i = t >= 6365.0f ? 6 : t >= 3315.0f ? 5 : t >= 1902.0f ? 4 : t >= 1449.0f ? 3 : t >= 1167.0f ? 2
                : t >= 965.0f ? 1 : 0;
    const float* r = kBlackbodyR[i];
    const float* g = kBlackbodyG[i];
    const float* b = kBlackbodyB[i];
    const float t_inv = 1.0f / t;
    c = {r[0] * t_inv + r[1] * t + r[2], g[0] * t_inv + g[1] * t + g[2], ((b[0] * t + b[1]) * t + b[2]) * t + b[3]};
  }
  return vmax(c, Vec3(0.0f));  // the fit goes negative outside Rec.709's gamut
}

Vec3 wavelength_color(float nm) {
  float ii = (nm - 380.0f) * (1.0f / 5.0f);
  // Truncation towards zero, as Cycles' float_to_int: 375-380 nm extrapolate the first segment.
  const int i = std::isfinite(ii) && std::fabs(ii) < 1e6f ? int(ii) : -1;
  if (i < 0 || i >= 80) return Vec3(0.0f);
  ii -= float(i);
  const float* a = kCie[i];
  const float* b = kCie[i + 1];
  const Vec3 xyz{(1.0f - ii) * a[0] + ii * b[0], (1.0f - ii) * a[1] + ii * b[1], (1.0f - ii) * a[2] + ii * b[2]};
  // XYZ (D65) -> linear Rec.709, Blender's default scene-linear space.
  const Vec3 rgb{3.2404542f * xyz.x - 1.5371385f * xyz.y - 0.4985314f * xyz.z,
                 -0.9692660f * xyz.x + 1.8760108f * xyz.y + 0.0415560f * xyz.z,
                 0.0556434f * xyz.x - 0.2040259f * xyz.y + 1.0572252f * xyz.z};
  return vmax(rgb * (1.0f / 2.52f), Vec3(0.0f));  // Cycles' empirical scale keeps it <= 1
}

Vec3 world_to_camera_point(const Camera* camera, Vec3 p) { return camera ? camera->to_camera(p) : p; }

Vec3 object_to_world_normal(const ObjectCoords* object, Vec3 n) {
  if (!object || !object->valid) return n;
  return safe_normalize(transposed_vector(object->to_object, n));
}

Vec3 world_to_object_normal(const ObjectCoords* object, Vec3 n) {
  if (!object || !object->valid) return n;
  return transposed_vector(object->to_world, n);
}

Vec3 tangent_space_normal(const ObjectCoords* object, Vec3 tangent, float sign, Vec3 normal, Vec3 color) {
  const Vec3 c = (color - Vec3(0.5f)) * 2.0f;
  const Vec3 b = cross(normal, tangent) * sign;  // no orthogonalisation, as Cycles
  const Vec3 n = safe_normalize(tangent * c.x + b * c.y + normal * c.z);
  return object_to_world_normal(object, n);
}

Vec3 object_world_space_normal(int space, const ObjectCoords* object, Vec3 color) {
  Vec3 n = (color - Vec3(0.5f)) * 2.0f;
  if (space >= 3) n = {n.x, -n.y, -n.z};  // Blender's convention
  const bool object_space = space == 1 || space == 3;
  return object_space && object && object->valid ? object_to_world_normal(object, n) : safe_normalize(n);
}

Vec3 vector_transform(int type, int from, int to, Vec3 v, const ObjectCoords* object, const Camera* camera) {
  // Cycles' svm_node_vector_transform: through world space, object transforms only for an
  // object, normals by the inverse transpose and normalised.
  constexpr int kWorld = 0, kObject = 1, kCamera = 2;
  const bool normal = type == 2, direction = type == 1;
  const bool is_object = object && object->valid;
  auto world_to_camera = [&](Vec3 x) {
    if (!camera) return x;
    if (normal) return safe_normalize(camera->dir_to_camera(x));
    return direction ? camera->dir_to_camera(x) : camera->to_camera(x);
  };
  auto camera_to_world = [&](Vec3 x) {
    if (!camera) return x;
    if (normal) return safe_normalize(camera->dir_from_camera(x));
    return direction ? camera->dir_from_camera(x) : camera->from_camera(x);
  };
  auto world_to_object = [&](Vec3 x) {
    if (!is_object) return x;
    if (normal) return safe_normalize(transposed_vector(object->to_world, x));
    return direction ? object->to_object.vector(x) : object->to_object.point(x);
  };
  auto object_to_world = [&](Vec3 x) {
    if (!is_object) return x;
    if (normal) return safe_normalize(transposed_vector(object->to_object, x));
    return direction ? object->to_world.vector(x) : object->to_world.point(x);
  };
  if (from == kWorld) {
    if (to == kCamera) v = world_to_camera(v);
    else if (to == kObject) v = world_to_object(v);
  } else if (from == kCamera) {
    if (to == kWorld || to == kObject) v = camera_to_world(v);
    if (to == kObject) v = world_to_object(v);
  } else if (from == kObject) {
    if (to == kWorld || to == kCamera) v = object_to_world(v);
    if (to == kCamera) v = world_to_camera(v);
  }
  return v;
}

}  // namespace pl
