// Object and generated texture coordinate spaces of instances and curve sets.
#include "scene/shader.h"

namespace pl {

ObjectCoords make_object_coords(const Mat4& to_world, Vec3 loc, Vec3 size) {
  ObjectCoords oc;
  oc.to_world = to_world;
  // Inverse of the affine 3x4 part: adjugate / determinant, then the translation.
  const float(&m)[4][4] = to_world.m;
  const Vec3 c0{m[0][0], m[1][0], m[2][0]}, c1{m[0][1], m[1][1], m[2][1]}, c2{m[0][2], m[1][2], m[2][2]};
  const Vec3 r0 = cross(c1, c2), r1 = cross(c2, c0), r2 = cross(c0, c1);
  const float det = dot(c0, r0);
  if (!(std::fabs(det) > 1e-30f) || !std::isfinite(det)) return oc;
  const Vec3 rows[3] = {r0 / det, r1 / det, r2 / det};  // rows of the inverse 3x3
  const Vec3 t{m[0][3], m[1][3], m[2][3]};
  for (int i = 0; i < 3; ++i) {
    oc.to_object.m[i][0] = rows[i].x;
    oc.to_object.m[i][1] = rows[i].y;
    oc.to_object.m[i][2] = rows[i].z;
    oc.to_object.m[i][3] = -dot(rows[i], t);
  }
  auto axis = [](float l, float sz, float& scale, float& offset) {
    scale = sz != 0.0f && std::isfinite(sz) ? 0.5f / sz : 0.0f;
    offset = 0.5f - (std::isfinite(l) ? l : 0.0f) * scale;
  };
  axis(loc.x, size.x, oc.gen_scale.x, oc.gen_offset.x);
  axis(loc.y, size.y, oc.gen_scale.y, oc.gen_offset.y);
  axis(loc.z, size.z, oc.gen_scale.z, oc.gen_offset.z);
  oc.valid = oc.to_object.is_finite();
  return oc;
}

void auto_texspace(const std::vector<Vec3>& positions, Vec3& location, Vec3& size) {
  Vec3 lo(-1.0f), hi(1.0f);  // Blender's fallback for an empty mesh
  bool any = false;
  for (const Vec3& p : positions) {
    if (!is_finite(p)) continue;
    lo = any ? vmin(lo, p) : p;
    hi = any ? vmax(hi, p) : p;
    any = true;
  }
  location = (lo + hi) * 0.5f;
  size = (hi - lo) * 0.5f;
  auto fix = [](float& x) {  // BKE_mesh_texspace_calc's guards against flat boxes
    if (x == 0.0f) x = 1.0f;
    else if (x > 0.0f && x < 1e-5f) x = 1e-5f;
  };
  fix(size.x);
  fix(size.y);
  fix(size.z);
}

}  // namespace pl
