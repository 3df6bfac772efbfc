// Light node trees (light_shader.h): the ShadingContext of a light sample, as Cycles'
// shader_setup_from_sample for a lamp (kernel/light/{point,spot,area}.h for the uv).
#include "scene/light_shader.h"

#include "scene/scene.h"

namespace pl {

namespace {

// Cycles' map_to_sphere: u from the azimuth (atan2(x, y)), v from the polar angle.
Vec2 map_to_sphere(Vec3 c) {
  const float l = dot(c, c);
  if (!(l > 0.0f)) return {0.0f, 0.0f};
  const float u = (c.x == 0.0f && c.y == 0.0f) ? 0.0f : 0.5f - std::atan2(c.x, c.y) * (0.5f / kPi);
  const float v = 1.0f - std::acos(clampf(c.z / std::sqrt(l), -1.0f, 1.0f)) * (1.0f / kPi);
  return {u, v};
}

// The emission normal Cycles gives a lamp's sample: a sphere's own normal, the facing disk's
// (towards the shaded point), an area light's, a sun's direction back.
Vec3 light_normal(const Light& l, Vec3 q, Vec3 wi) {
  switch (l.type) {
    case LightType::Point:
    case LightType::Spot:
      if (l.sphere && l.radius > 0.0f) {
        const Vec3 d = q - l.position;
        if (length_sq(d) > 0.0f) return normalize(d);
      }
      return -wi;
    case LightType::Sun: return -wi;
    case LightType::Rect:
    case LightType::Ellipse: return l.dir;
  }
  return -wi;
}

}  // namespace

Vec2 light_parametric(const Light& l, const LightShader& sh, Vec3 q, Vec3 wi, Vec3 n) {
  switch (l.type) {
    case LightType::Point: return map_to_sphere(sh.to_local.vector(n));  // (u, v) = its (x, y)
    case LightType::Spot: {
      // spot_light_uv: the light-local direction the light leaves along (its Z towards the cone's
      // axis), projected so that the cone covers [0, 1]^2.
      const Vec3 r = sh.to_local.vector(-wi);
      const float len = length(r);
      if (!(len > 0.0f)) return {0.5f, 0.5f};
      const Vec3 c{r.x / len, r.y / len, -r.z / len};
      const float f = sh.half_cot_half_spot / c.z;
      if (!std::isfinite(f)) return {0.5f, 0.5f};
      return {c.x * f + 0.5f, c.y * f + 0.5f};
    }
    case LightType::Rect:
    case LightType::Ellipse: {
      const Vec3 rel = q - l.position;
      const float uu = length_sq(l.axis_u), vv = length_sq(l.axis_v);
      return {uu > 0.0f ? dot(rel, l.axis_u) / uu + 0.5f : 0.5f, vv > 0.0f ? dot(rel, l.axis_v) / vv + 0.5f : 0.5f};
    }
    case LightType::Sun: {
      // distant_light_uv: the direction towards the sun on a disk of [-0.5, 0.5]^2 over the
      // cone of half angle a (the light's x and y axes): 0.5 / sin(a / 2) / |wi + axis|.
      const float a = std::acos(clampf(l.cos_half_angle, -1.0f, 1.0f));
      const float s = std::sin(0.5f * a), len = length(wi + l.dir);
      if (!(s > 0.0f) || !(len > 0.0f)) return {0.5f, 0.5f};
      const Vec3 loc = sh.to_local.vector(wi);
      const float fac = 0.5f / s / len;
      return {loc.x * fac + 0.5f, loc.y * fac + 0.5f};
    }
  }
  return {0.5f, 0.5f};
}

Vec3 light_shader_emission(const Light& l, Vec3 q, Vec3 wi, float dist) {
  const LightShader& sh = *l.shader;
  ShadingContext ctx;
  const Vec3 n = light_normal(l, q, wi);
  ctx.p = l.type == LightType::Sun ? -wi : q;  // (Cycles' distant light: P = Ng, a direction)
  ctx.ng = ctx.ns = n;
  ctx.wo = -wi;  // Cycles' sd->wi: from the light towards the shaded point (Incoming)
  const Vec2 uv = light_parametric(l, sh, q, wi, n);
  // Geometry's Parametric is (1 - b1 - b2, b1); a lamp's UV output is the same.
  ctx.b1 = uv.y;
  ctx.b2 = 1.0f - uv.x - uv.y;
  Vec2 uvs[8];
  for (Vec2& x : uvs) x = uv;
  ctx.uv = uvs;
  ctx.uv_sets = 8;
  ctx.object = &sh.object;
  ctx.scene = sh.scene;
  ctx.scene_camera = sh.scene ? sh.scene->shading_camera() : nullptr;
  ctx.ray.flags = 0;  // Cycles evaluates a light's shader with no ray kind (PATH_RAY_EMISSION)
  ctx.ray.length = dist;
  ClosureList out;
  static const std::vector<Image> no_images;
  eval_shader(sh.program, sh.scene ? sh.scene->images() : no_images, ctx, out);
  return is_finite(out.emission) ? out.emission : Vec3(0.0f);
}

}  // namespace pl
