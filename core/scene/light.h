// Analytic lights (point, spot, sun, rectangle/ellipse area) with Cycles' conventions, and the
// equirectangular environment. Each light knows how to sample a direction towards itself from a
// shading point; the scene picks lights. Lights with extent are also found by the rays that
// cross them (intersect_light), each estimator weighted against the other by MIS.
#pragma once
#include <cstdint>
#include <memory>
#include <vector>

#include "scene/ies.h"
#include "scene/sky.h"

#include "util/sampling.h"

namespace pl {

enum class LightType : uint8_t { Point, Spot, Sun, Rect, Ellipse };

struct LightShader;  // scene/light_shader.h: a light's node tree as a program
struct WorldShader;  // scene/light_shader.h: the world's node tree as a program
struct RayState;     // scene/shader.h
class Scene;

// The rays a light is visible to (Cycles' light object Ray Visibility), as bits of
// Light::visibility and of the kind of a ray that may find it.
enum LightVisibility : uint8_t {
  kLightVisCamera = 1,        // camera rays (also through Transparent BSDFs)
  kLightVisDiffuse = 2,       // after a diffuse bounce
  kLightVisGlossy = 4,        // after a glossy or singular reflection
  kLightVisTransmission = 8,  // after any transmission
  kLightVisVolume = 16,       // after a volume scattering
  kLightVisAll = 31,
};

struct Light {
  LightType type = LightType::Point;
  Vec3 color;            // point/spot: intensity W/sr; sun: irradiance; area: radiance
  Vec3 position;         // point/spot/area centre
  float radius = 0.0f;   // point/spot: radius of the disk facing the shaded point, or of the sphere
  // point/spot with Soft Falloff off (Cycles' is_sphere): an emitting sphere of radiance
  // I / (pi r^2), sampled in the cone it subtends (sample_sphere_light); else the soft disk.
  bool sphere = false;
  Mat4 to_local;         // spot: world direction -> light-local (inverse 3x3 of the matrix)
  float cos_half_spot = -1.0f, spot_smooth_inv = 0.0f;  // spot cone and blend
  // Sphere spots: the world emission axis and 1 - cos of the widest half angle of the cone about
  // it (Cycles' cos_half_larger_spread; 2: every direction). Sampled where smaller than the
  // sphere's cone.
  Vec3 spot_axis;
  float spread_one_minus_cos = 2.0f;
  Vec3 dir;              // sun: unit direction towards the sun; area: unit emission normal (-Z)
  float cos_half_angle = 1.0f, sun_radiance_scale = 0.0f;  // sun: cone and 1 / (pi sin^2 h)
  Vec3 axis_u, axis_v;   // area: full extent vectors
  float area = 0.0f;
  // Area lights' Spread below 180 degrees (Cycles' soft-box grid): radiance along a direction at
  // angle a to the normal times max(0, (tan_half_spread - tan a) * normalize_spread), which keeps
  // the power; inf: 180 degrees, no attenuation.
  float tan_half_spread = kInf, normalize_spread = 0.0f;
  bool cast_shadow = true;
  // Cycles' Multiple Importance: rays other than the camera's may find the light (lights with
  // extent only) and both estimators are MIS-weighted; off: next-event estimation alone.
  bool mis = true;
  uint8_t visibility = kLightVisAll & ~kLightVisCamera;  // LightVisibility bits
  // The light node tree's IES Texture (point, spot, area): the emission times the profile's
  // value towards the light-local direction of the light leaving it, in light samples and ray
  // hits alike (so MIS stays exact). ies_to_local: world -> local as Cycles transforms the
  // shader's normal (the matrix's transposed 3x3).
  std::shared_ptr<const IesProfile> ies;
  Mat4 ies_to_local;
  // The light's node tree where it varies (textures, falloff, direction): its Emission,
  // evaluated at each light sample and ray hit with Cycles' light coordinates, multiplies
  // color (light_shader_emission). nullptr: none (a constant tree is folded into color).
  // shader_power: Cycles' estimate of the tree's emission, for choosing among lights.
  std::shared_ptr<LightShader> shader;
  float shader_power = 1.0f;
  // Light and shadow linking (Cycles' light_set_membership / shadow_set_membership): bit s
  // set: the light reaches receivers of light set s / is blocked by objects of shadow set s.
  uint64_t light_mask = ~uint64_t(0), shadow_mask = ~uint64_t(0);
  // Cycles' light group (View Layer ▸ Light Groups): the Combined_<name> pass its light also
  // goes to (an index into the render's groups; -1: none).
  int16_t light_group = -1;
  // Cycles' light Max Bounces (light.cycles.max_bounces): light samples at path vertices past
  // this many bounces skip the light (light_select_reached_max_bounces); rays still find it.
  int max_bounces = 1024;
};

// The IES factor of light l for light leaving it along from_light (world, any length).
inline float light_ies_factor(const Light& l, Vec3 from_light) {
  return l.ies ? ies_eval(*l.ies, l.ies_to_local.vector(from_light)) : 1.0f;
}

// What the light's node tree emits towards a shading point along wi (unit, from the point to
// the light) from its point q at distance dist (light_shader.cpp; l.shader set).
Vec3 light_shader_emission(const Light& l, Vec3 q, Vec3 wi, float dist);

// Both direction-dependent factors (IES profile, node tree) of a light that has one; false
// where they leave nothing.
inline bool apply_light_factors(const Light& l, Vec3 q, Vec3 wi, float dist, Vec3& li) {
  if (l.ies) {
    const float f = light_ies_factor(l, -wi);
    if (!(f > 0.0f)) return false;
    li = li * f;
  }
  if (l.shader) {
    li = li * light_shader_emission(l, q, wi, dist);
    if (!(max_component(li) > 0.0f)) return false;
  }
  return true;
}

// The factor the light's power estimate takes from its profile and node tree.
inline float light_power_scale(const Light& l) { return (l.ies ? l.ies->mean : 1.0f) * l.shader_power; }

// Direction towards a light sample, as seen from a shading point.
struct LightSample {
  Vec3 wi;                // unit direction from the shading point
  float dist = kInf;      // distance to the sampled point (inf for the sun)
  Vec3 li;                // incident radiance (delta lights: intensity / r^2 or irradiance)
  float pdf = 0.0f;       // solid-angle pdf (ignored for delta lights)
  bool delta = false;     // a point/spot/sun without extent: no BSDF sample can find it
  Vec3 target;            // the sampled point (for the shadow ray; unused for the sun)
};

inline float smoothstep01(float x) {
  x = clampf(x, 0.0f, 1.0f);
  return x * x * (3.0f - 2.0f * x);
}

inline float spot_attenuation(const Light& l, Vec3 from_light) {
  Vec3 local = l.to_local.vector(from_light);
  const float len = length(local);
  if (!(len > 0.0f)) return 0.0f;
  const float c = -local.z / len;
  if (c <= l.cos_half_spot) return 0.0f;
  if (l.spot_smooth_inv <= 0.0f) return 1.0f;  // blend 0: a hard edge
  return smoothstep01((c - l.cos_half_spot) * l.spot_smooth_inv);
}

// Solid angles a rectangle light is sampled over uniformly (spherical rectangles); outside it,
// uniformly by area. Below, the light is a speck and area sampling is as good and cheaper.
inline bool use_spherical_rect(double omega) { return omega > 2e-4; }

inline bool has_spread(const Light& l) { return l.tan_half_spread < kInf; }

// An area light's spread attenuation towards the unit direction wi from a point to the light
// (cos_l: cosine of the emission direction -wi to the normal, > 0). tan a from the cross
// product: accurate at the small angles of narrow spreads.
inline float spread_attenuation(const Light& l, Vec3 wi, float cos_l) {
  const float tan_a = length(cross(wi, l.dir)) / cos_l;
  return std::max((l.tan_half_spread - tan_a) * l.normalize_spread, 0.0f);
}

// Whether an area light's axes are orthogonal (a rectangle, not a sheared parallelogram).
inline bool area_light_rectangular(const Light& l) {
  const float uu = length_sq(l.axis_u), vv = length_sq(l.axis_v), uv = dot(l.axis_u, l.axis_v);
  return uv * uv <= 1e-8f * uu * vv;
}

// What an area light's samples from a point cover (area_light_region).
enum class AreaRegion : uint8_t {
  Whole,  // the whole light
  Rect,   // the rectangle c, au, av (an ellipse: the samples outside it give none)
  Disk,   // the disk inscribed in the square c, au, av (the samples off the light give none)
};

// The part of area light l that can reach p: with a spread below 180 degrees only the disk of
// radius height * tan(half spread) about p's foot on the light's plane emits towards p. As
// Cycles' area_light_spread_clamp_light: rectangles are clipped to that disk's bounding square;
// ellipses take the smallest of that square, the whole ellipse and the spread's disk, round
// ones the rectangle bounding the lens where the two disks overlap. False where nothing is left.
inline bool area_light_region(const Light& l, Vec3 p, Vec3& c, Vec3& au, Vec3& av, AreaRegion& mode) {
  c = l.position;
  au = l.axis_u;
  av = l.axis_v;
  mode = AreaRegion::Whole;
  if (!has_spread(l) || !area_light_rectangular(l)) return true;
  const Vec3 rel = p - l.position;
  const float t = dot(rel, l.dir);  // height above the light's plane
  if (!(t > 0.0f)) return false;
  const float lu = length(l.axis_u), lv = length(l.axis_v);
  const Vec3 eu = l.axis_u / lu, ev = l.axis_v / lv;
  const float r = t * l.tan_half_spread;
  const float su = dot(eu, rel), sv = dot(ev, rel);
  const Vec3 foot = l.position + eu * su + ev * sv;
  const float spread_area = kPi * r * r;
  const auto spread_disk = [&] {
    mode = AreaRegion::Disk;
    c = foot;
    au = eu * (2.0f * r);
    av = ev * (2.0f * r);
  };
  const bool ellipse = l.type == LightType::Ellipse;
  if (ellipse && std::fabs(lu - lv) <= 1e-6f * lu) {  // a round light: two disks
    const float big_r = 0.5f * lu, dist = std::sqrt(su * su + sv * sv);
    if (dist >= big_r + r) return false;
    if (dist <= std::fabs(big_r - r)) {  // one inside the other: the smaller
      if (r < big_r) spread_disk();
      return true;
    }
    const float len_u = big_r + r - dist;  // the lens, along the foot-to-centre axis
    const float lens_w = dist + (r * r - big_r * big_r) / dist;  // twice the foot-to-chord distance
    const float len_v = std::fabs(big_r * big_r - r * r) >= dist * dist
                            ? 2.0f * std::min(big_r, r)
                            : std::sqrt(std::max(0.0f, 4.0f * r * r - lens_w * lens_w));
    if (len_u * len_v < std::min(l.area, spread_area)) {
      const Vec3 axis = (l.position - foot) / dist;
      mode = AreaRegion::Rect;
      c = (l.position + foot + axis * (r - big_r)) * 0.5f;
      au = axis * len_u;
      av = normalize(cross(l.dir, axis)) * len_v;
    } else if (spread_area < l.area) {
      spread_disk();
    }
    return true;
  }
  const float u0 = std::max(su - r, -0.5f * lu), u1 = std::min(su + r, 0.5f * lu);
  const float v0 = std::max(sv - r, -0.5f * lv), v1 = std::min(sv + r, 0.5f * lv);
  if (!(u0 < u1) || !(v0 < v1)) return false;
  const float rect_area = (u1 - u0) * (v1 - v0);
  if (ellipse && !(rect_area < std::min(l.area, spread_area))) {
    if (spread_area < l.area) spread_disk();
    return true;
  }
  mode = AreaRegion::Rect;
  c = l.position + eu * (0.5f * (u0 + u1)) + ev * (0.5f * (v0 + v1));
  au = eu * (u1 - u0);
  av = ev * (v1 - v0);
  return true;
}

// The area of what samples cover in region `mode` (c, au, av).
inline float area_light_region_area(const Light& l, AreaRegion mode, Vec3 au, Vec3 av) {
  if (mode == AreaRegion::Whole) return l.area;
  return length(cross(au, av)) * (mode == AreaRegion::Disk ? kPi / 4.0f : 1.0f);
}

// What light samples from p cover on area light l (one-sided: nothing from behind): the region
// of area_light_region and, for a true rectangle seen under a large enough solid angle, the
// spherical rectangle sampled uniformly. Sampling and the hit pdf share it, so they agree.
struct AreaLightView {
  Vec3 c, au, av;
  AreaRegion mode;
  bool spherical = false;  // sr holds the sampled spherical rectangle
  SphericalRect sr;
};
inline bool area_light_view(const Light& l, Vec3 p, bool solid_angle, AreaLightView& v) {
  if (!(dot(p - l.position, l.dir) > 0.0f)) return false;
  if (!area_light_region(l, p, v.c, v.au, v.av, v.mode)) return false;
  // Needs a true rectangle: a sheared matrix makes a parallelogram (area sampling then).
  if (l.type == LightType::Rect && solid_angle && area_light_rectangular(l)) {
    v.sr = spherical_rect(p, v.c - (v.au + v.av) * 0.5f, v.au, v.av);
    v.spherical = use_spherical_rect(v.sr.solid_angle);
  }
  return true;
}

// Scales le by an area light's spread attenuation towards wi (cos_l: the cosine at the light);
// false where the spread gives nothing.
inline bool apply_spread(const Light& l, Vec3 wi, float cos_l, Vec3& le) {
  if (!has_spread(l)) return true;
  const float att = spread_attenuation(l, wi, cos_l);
  if (!(att > 0.0f)) return false;
  le = le * att;
  return true;
}

// Whether point q of area light l's plane lies on the light (its rectangle or ellipse).
inline bool on_area_light(const Light& l, Vec3 q) {
  const Vec3 r = q - l.position;
  const float uu = length_sq(l.axis_u), vv = length_sq(l.axis_v), uv = dot(l.axis_u, l.axis_v);
  const float ru = dot(r, l.axis_u), rv = dot(r, l.axis_v);
  const float det = uu * vv - uv * uv;
  if (!(det > 0.0f)) return false;
  // Coordinates along the (possibly sheared) axes, in units of their full lengths.
  const float x = (ru * vv - rv * uv) / det, y = (rv * uu - ru * uv) / det;
  return l.type == LightType::Rect ? std::fabs(x) <= 0.5f && std::fabs(y) <= 0.5f : x * x + y * y <= 0.25f;
}

// 1 - cos of the half angle whose sine squared is s2, without cancellation for small angles.
inline float one_minus_cos_from_sin2(float s2) {
  return s2 / (1.0f + std::sqrt(std::max(0.0f, 1.0f - s2)));
}

// A sphere light's solid-angle pdf from a point at squared distance d2c from its centre (as
// Cycles' sphere_light_pdf / spot_light_pdf): uniform over the smaller of the cone the sphere
// subtends and a spot's spread cone outside, uniform over all directions inside (Cycles samples
// a cosine hemisphere there; uniform needs no normal and keeps the MIS pdf exact).
inline float sphere_light_pdf(const Light& l, float d2c) {
  const float r2 = l.radius * l.radius;
  if (!(d2c > r2)) return 1.0f / (4.0f * kPi);
  const float omc = std::min(one_minus_cos_from_sin2(r2 / d2c), l.spread_one_minus_cos);
  return 1.0f / (2.0f * kPi * omc);
}

// The distance along the unit direction dir from org to sphere light l's surface (the near side
// from outside, the far side from inside), or a negative value where the line misses it.
inline float sphere_light_distance(const Light& l, Vec3 org, Vec3 dir) {
  const Vec3 oc = org - l.position;
  const float b = dot(oc, dir);
  const float r2 = l.radius * l.radius;
  const float h2 = r2 - length_sq(oc - dir * b);  // r^2 - the line's squared distance to the centre
  // A little slack for float rounding, so that the rays of samples at the cone's edge still find
  // the sphere (the MIS pdf of their hits).
  const float oc2 = length_sq(oc);
  if (!(h2 >= -1e-6f * (r2 + 4.0f * std::sqrt(oc2) * l.radius))) return -1.0f;
  const float h = std::sqrt(std::max(h2, 0.0f));
  const float c = oc2 - r2;  // roots of t^2 + 2 b t + c, in their stable forms
  if (c > 0.0f) return b < 0.0f ? c / (h - b) : -1.0f;
  return b > 0.0f ? -c / (b + h) : h - b;
}

// Soft Falloff off: the emitting sphere of Cycles' point.h / spot.h. Outside it, uniform in the
// cone it subtends (or in a spot's spread cone where that is smaller, the directions that miss
// the sphere giving no sample), the spot's cone and blend along the sample's direction; inside,
// uniform over all directions, without the spot's attenuation (as Cycles).
inline bool sample_sphere_light(const Light& l, Vec3 p, Vec2 u, LightSample& s) {
  const Vec3 to_c = l.position - p;
  const float d2c = length_sq(to_c);
  const float r2 = l.radius * l.radius;
  Vec3 scale = l.color * (1.0f / (kPi * r2));  // radiance = I / (pi r^2), as the disk's
  float t;
  if (d2c > r2) {
    const float d = std::sqrt(d2c);
    const float omc_sphere = one_minus_cos_from_sin2(r2 / d2c);
    const bool in_spread = l.spread_one_minus_cos <= omc_sphere;
    const float omc = in_spread ? l.spread_one_minus_cos : omc_sphere;
    const Vec3 axis = in_spread ? -l.spot_axis : to_c / d;
    const float omc_t = u.x * omc;  // 1 - cos of the sample's angle to the axis
    const float cos_t = 1.0f - omc_t;
    const float sin2_t = omc_t * (2.0f - omc_t);
    const float sin_t = std::sqrt(std::max(0.0f, sin2_t));
    const float phi = 2.0f * kPi * u.y;
    Vec3 tt, bb;
    make_basis(axis, tt, bb);
    s.wi = normalize(tt * (sin_t * std::cos(phi)) + bb * (sin_t * std::sin(phi)) + axis * cos_t);
    if (in_spread) {
      t = sphere_light_distance(l, p, s.wi);
      if (!(t > 0.0f)) return false;
    } else {  // law of cosines, the near side
      t = std::max(0.0f, d * cos_t - std::sqrt(std::max(0.0f, r2 - d2c * sin2_t)));
    }
    if (l.type == LightType::Spot) {
      const float att = spot_attenuation(l, -s.wi);
      if (att <= 0.0f) return false;
      scale = scale * att;
    }
    s.pdf = 1.0f / (2.0f * kPi * omc);
  } else {
    const float z = 1.0f - 2.0f * u.x, rr = std::sqrt(std::max(0.0f, 1.0f - z * z));
    const float phi = 2.0f * kPi * u.y;
    s.wi = Vec3(rr * std::cos(phi), rr * std::sin(phi), z);
    t = sphere_light_distance(l, p, s.wi);
    if (!(t >= 0.0f)) return false;
    s.pdf = 1.0f / (4.0f * kPi);
  }
  if (!(t > 0.0f) || !std::isfinite(s.pdf)) return false;
  s.dist = t;
  s.target = p + s.wi * t;
  s.li = scale;
  s.delta = false;
  return true;
}

// sample_light without the IES profile.
inline bool sample_light_shape(const Light& l, Vec3 p, Vec2 u, LightSample& s, bool solid_angle) {
  switch (l.type) {
    case LightType::Point:
    case LightType::Spot: {
      Vec3 to_c = l.position - p;
      const float d2c = length_sq(to_c);
      if (!(d2c > 0.0f)) return false;
      Vec3 scale = l.color;
      const float disk_area = kPi * l.radius * l.radius;
      // A radius too small to matter (or to represent) is a point light.
      const bool point = !(l.radius > 1e-6f * std::sqrt(d2c)) || !(disk_area > 1e-30f);
      if (!point && l.sphere) return sample_sphere_light(l, p, u, s);
      if (point) {
        if (l.type == LightType::Spot) {
          const float att = spot_attenuation(l, -to_c);
          if (att <= 0.0f) return false;
          scale = scale * att;
        }
        const float d = std::sqrt(d2c);
        s.wi = to_c / d;
        s.dist = d;
        s.target = l.position;
        s.li = scale / d2c;
        s.pdf = 1.0f;
        s.delta = true;
        return true;
      }
      // A disk of the light's radius facing p (Cycles' soft-falloff point light).
      const Vec3 n = -to_c / std::sqrt(d2c);
      Vec3 t, b;
      make_basis(n, t, b);
      const Vec2 dsk = sample_disk_concentric(u);
      const Vec3 q = l.position + (t * dsk.x + b * dsk.y) * l.radius;
      const Vec3 d = q - p;
      const float dist2 = length_sq(d);
      const float dist = std::sqrt(dist2);
      s.wi = d / dist;
      const float cos_l = std::fabs(dot(n, s.wi));
      if (!(cos_l > 0.0f)) return false;
      if (l.type == LightType::Spot) {  // the cone, seen along this sample's own direction
        const float att = spot_attenuation(l, -s.wi);
        if (att <= 0.0f) return false;
        scale = scale * att;
      }
      s.dist = dist;
      s.target = q;
      s.li = scale / disk_area;  // radiance = I / (pi r^2)
      s.pdf = dist2 / (cos_l * disk_area);
      s.delta = false;
      return true;
    }
    case LightType::Sun: {
      s.dist = kInf;
      if (l.cos_half_angle >= 1.0f) {
        s.wi = l.dir;
        s.li = l.color;
        s.pdf = 1.0f;
        s.delta = true;
        return true;
      }
      // Uniform in the cone around the sun direction.
      const float cos_t = 1.0f - u.x * (1.0f - l.cos_half_angle);
      const float sin_t = std::sqrt(std::max(0.0f, 1.0f - cos_t * cos_t));
      const float phi = 2.0f * kPi * u.y;
      Vec3 t, b;
      make_basis(l.dir, t, b);
      s.wi = normalize(t * (sin_t * std::cos(phi)) + b * (sin_t * std::sin(phi)) + l.dir * cos_t);
      s.li = l.color * l.sun_radiance_scale;
      s.pdf = 1.0f / (2.0f * kPi * (1.0f - l.cos_half_angle));
      s.delta = false;
      return true;
    }
    case LightType::Rect:
    case LightType::Ellipse: {
      AreaLightView v;
      if (!area_light_view(l, p, solid_angle, v)) return false;
      if (v.spherical) {
        DVec3 q;
        if (!sample_spherical_rect(v.sr, u, q)) return false;
        DVec3 d = q - DVec3(p);
        const double dist = dlength(d);
        if (!dnormalize(d)) return false;
        s.wi = d.to_float();
        const float cos_l = -dot(l.dir, s.wi);
        if (!(cos_l > 0.0f)) return false;
        s.li = l.color;
        if (!apply_spread(l, s.wi, cos_l, s.li)) return false;
        s.dist = float(dist);
        s.target = q.to_float();
        s.pdf = float(1.0 / v.sr.solid_angle);
        s.delta = false;
        return true;
      }
      // By area over the region (area_light_region), the samples off the light giving none.
      Vec2 o{u.x - 0.5f, u.y - 0.5f};
      const float area = area_light_region_area(l, v.mode, v.au, v.av);
      if (v.mode == AreaRegion::Disk || (v.mode == AreaRegion::Whole && l.type == LightType::Ellipse)) {
        const Vec2 dsk = sample_disk_concentric(u);
        o = {0.5f * dsk.x, 0.5f * dsk.y};
      }
      const Vec3 q = v.c + v.au * o.x + v.av * o.y;
      if (v.mode != AreaRegion::Whole && !on_area_light(l, q)) return false;
      const Vec3 d = q - p;
      const float dist2 = length_sq(d);
      if (!(dist2 > 0.0f) || !(area > 0.0f)) return false;
      const float dist = std::sqrt(dist2);
      s.wi = d / dist;
      const float cos_l = -dot(l.dir, s.wi);  // one-sided: emits along dir
      if (!(cos_l > 0.0f)) return false;
      s.li = l.color;
      if (!apply_spread(l, s.wi, cos_l, s.li)) return false;
      s.dist = dist;
      s.target = q;
      s.pdf = dist2 / (cos_l * area);
      s.delta = false;
      return std::isfinite(s.pdf);
    }
  }
  return false;
}

// Samples light `l` from point p; returns false if it cannot contribute there. `solid_angle`:
// rectangles by their solid angle where it is large enough (else uniformly by area).
inline bool sample_light(const Light& l, Vec3 p, Vec2 u, LightSample& s, bool solid_angle = true) {
  if (!sample_light_shape(l, p, u, s, solid_angle)) return false;
  if (!l.ies && !l.shader) return true;
  return apply_light_factors(l, s.target, s.wi, s.dist, s.li);
}

// Whether a ray can hit light l at all: it has extent as sample_light sees it (a point or spot
// of zero radius and a sun of zero angle are delta lights).
inline bool light_has_extent(const Light& l) {
  switch (l.type) {
    case LightType::Point:
    case LightType::Spot: return l.radius > 0.0f && kPi * l.radius * l.radius > 1e-30f;
    case LightType::Sun: return l.cos_half_angle < 1.0f;
    case LightType::Rect:
    case LightType::Ellipse: return l.area > 0.0f;
  }
  return false;
}

inline bool intersect_light_shape(const Light& l, Vec3 from, Vec3 org, Vec3 dir, float tmax, float& t, Vec3& le,
                                  float& pdf, bool solid_angle);

// A ray from org along the unit direction dir, up to distance tmax, against the surface of light
// l as a light sample taken at `from` sees it (point and spot disks face `from`; the ray's line
// passes through it). On a hit: the distance t from org, the emitted radiance le towards the
// ray, and the solid-angle pdf with which sample_light(l, from, ..., solid_angle) gives that
// point (the light's choice not included). Suns: only rays that escape (tmax infinite).
inline bool intersect_light(const Light& l, Vec3 from, Vec3 org, Vec3 dir, float tmax, float& t, Vec3& le, float& pdf,
                            bool solid_angle = true) {
  if (!intersect_light_shape(l, from, org, dir, tmax, t, le, pdf, solid_angle)) return false;
  if (!l.ies && !l.shader) return true;
  return apply_light_factors(l, org + dir * t, dir, t, le);
}

inline bool intersect_light_shape(const Light& l, Vec3 from, Vec3 org, Vec3 dir, float tmax, float& t, Vec3& le,
                                  float& pdf, bool solid_angle) {
  switch (l.type) {
    case LightType::Point:
    case LightType::Spot: {
      const Vec3 to_c = l.position - from;
      const float d2c = length_sq(to_c);
      if (!(d2c > 0.0f)) return false;
      const float disk_area = kPi * l.radius * l.radius;
      if (!(l.radius > 1e-6f * std::sqrt(d2c)) || !(disk_area > 1e-30f)) return false;  // a point: delta
      if (l.sphere) {
        const float th = sphere_light_distance(l, org, dir);
        if (!(th > 0.0f) || !(th < tmax)) return false;
        Vec3 scale = l.color * (1.0f / disk_area);
        if (l.type == LightType::Spot && d2c > l.radius * l.radius) {  // inside: unattenuated
          const float att = spot_attenuation(l, -dir);
          if (att <= 0.0f) return false;
          scale = scale * att;
        }
        t = th;
        le = scale;
        pdf = sphere_light_pdf(l, d2c);
        return std::isfinite(pdf) && pdf > 0.0f;
      }
      const Vec3 n = -to_c / std::sqrt(d2c);  // the disk's normal, towards `from`
      const float dn = dot(dir, n);
      if (!(dn < 0.0f)) return false;
      const float th = dot(l.position - org, n) / dn;
      if (!(th > 0.0f) || !(th < tmax)) return false;
      const Vec3 q = org + dir * th;
      if (!(length_sq(q - l.position) <= l.radius * l.radius)) return false;
      Vec3 scale = l.color;
      if (l.type == LightType::Spot) {
        const float att = spot_attenuation(l, -dir);
        if (att <= 0.0f) return false;
        scale = scale * att;
      }
      const float dist2 = length_sq(q - from);
      t = th;
      le = scale / disk_area;
      pdf = dist2 / (-dn * disk_area);
      return std::isfinite(pdf) && pdf > 0.0f;
    }
    case LightType::Sun: {
      if (std::isfinite(tmax) || !(l.cos_half_angle < 1.0f)) return false;
      if (!(dot(dir, l.dir) >= l.cos_half_angle)) return false;
      t = kInf;
      le = l.color * l.sun_radiance_scale;
      pdf = 1.0f / (2.0f * kPi * (1.0f - l.cos_half_angle));
      return true;
    }
    case LightType::Rect:
    case LightType::Ellipse: {
      const float dn = dot(dir, l.dir);
      if (!(dn < 0.0f)) return false;  // one-sided: only rays against the emission normal
      const float th = dot(l.position - org, l.dir) / dn;
      if (!(th > 0.0f) || !(th < tmax)) return false;
      const Vec3 q = org + dir * th;
      if (!on_area_light(l, q)) return false;
      t = th;
      le = l.color;
      if (!apply_spread(l, dir, -dn, le)) return false;
      // The pdf of the sample from `from`: over the same (clipped) region as sample_light.
      AreaLightView v;
      if (!area_light_view(l, from, solid_angle, v)) return false;
      if (v.spherical) {
        pdf = float(1.0 / v.sr.solid_angle);
        return std::isfinite(pdf) && pdf > 0.0f;
      }
      pdf = length_sq(q - from) / (-dn * area_light_region_area(l, v.mode, v.au, v.av));
      return std::isfinite(pdf) && pdf > 0.0f;
    }
  }
  return false;
}

// Rough emitted power, for choosing among lights (only ratios matter). `scene_radius` bounds
// the sun's footprint on the scene.
inline float light_power(const Light& l, float scene_radius) {
  const float lum = std::max(luminance(l.color), 0.0f) * light_power_scale(l);
  float p = 0.0f;
  switch (l.type) {
    case LightType::Point: p = 4.0f * kPi * lum; break;
    case LightType::Spot: p = 4.0f * kPi * lum * std::max(0.05f, 0.5f * (1.0f - l.cos_half_spot)); break;
    case LightType::Sun: p = kPi * scene_radius * scene_radius * lum; break;
    case LightType::Rect:
    case LightType::Ellipse: p = kPi * l.area * lum; break;
  }
  // Kept finite: an overflowing estimate would drop the light from the distribution.
  return std::isnan(p) ? 0.0f : std::min(p, 1e30f);
}

// Equirectangular environment map in Cycles' convention, importance-sampled by luminance. The
// lookup is bilinear between texel centres, so the sampling density is too: the map is split
// into cells between four texel centres (half cells along the poles), a cell is chosen by its
// integral (the mean of its corners times cos(elevation) at its centre) and a point in it in
// proportion to the bilinear weight: the density is weight * cos(cell row) / norm. Two such
// distributions: weight = luminance where no BSDF sample follows (every direction with radiance
// has density), and max(0, luminance - its mean over the sphere) where one does (MIS
// compensation: the dim remainder is left to the BSDF sample).
class Environment {
 public:
  Environment() = default;
  // pixels: w*h RGB, row 0 = bottom. rotation: world -> texture directions.
  // srgb: the pixels are sRGB-encoded (an 8-bit image's byte / 255), interpolated encoded and
  // decoded after, then scaled by the strength (Cycles' NODE_IMAGE_COMPRESS_AS_SRGB); the map
  // weighs the decoded texels.
  Environment(std::vector<Vec3> pixels, int w, int h, float strength, const Mat4& rotation, bool srgb = false);
  // A procedural sky: radiance from the model itself; a w x h equirectangular image of it
  // (without the sun disc) steers the samples, and the disc, far smaller than a texel, gets
  // its own share of them, uniform in its cone.
  Environment(std::shared_ptr<const SkyModel> sky, int w, int h, float strength, const Mat4& rotation);
  // The world's node tree as a program (light_shader.h WorldShader), evaluated per direction with
  // the ray's kind and counts (Cycles' shader_setup_from_background); a w x h equirectangular map
  // of it, baked by bake() at commit with no ray kind (as Cycles'), steers the samples.
  Environment(std::shared_ptr<WorldShader> program, int w, int h);
  bool valid() const { return w_ > 0; }
  bool program() const { return bool(prog_); }
  const WorldShader* world_shader() const { return prog_.get(); }
  bool needs_bake() const { return prog_ && !baked_; }
  void bake(const Scene& scene);  // (images and AO: the scene's)
  // rs: the Light Path state a program world reads: an escaped ray's (its kind and counts) or
  // a light sample's (no ray kind, the sampling vertex's counts: Scene::light_sample_state);
  // nullptr: none (the map: no kind, no counts). Cycles evaluates a background with
  // PATH_RAY_EMISSION added, so Ray Depth reads one more than the counts, and Ray Length
  // FLT_MAX (eval_program). ray_p: the escaped ray's origin (Window of an orthographic camera's
  // rays; nullptr: none). Image and sky worlds ignore both.
  Vec3 eval(Vec3 dir_world, const RayState* rs = nullptr, const Vec3* ray_p = nullptr) const {
    if (prog_) return eval_program(dir_world, rs, ray_p);
    return eval_map(dir_world);
  }
  // Samples a world direction; returns radiance and the solid-angle pdf. cover_all: no BSDF
  // sample follows, so every direction with radiance needs density (else the compensated one).
  // rs: the light sample's Light Path state (eval).
  bool sample(Vec2 u, Vec3& dir, Vec3& radiance, float& pdf, bool cover_all = false,
              const RayState* rs = nullptr) const;
  float pdf(Vec3 dir_world, bool cover_all = false) const;
  // eval() and pdf() of one direction at once (a BSDF ray that escaped): an image map's (u, v)
  // found once, not twice (its atan2 and asin).
  Vec3 eval_with_pdf(Vec3 dir_world, bool cover_all, float& pdf, const RayState* rs = nullptr,
                     const Vec3* ray_p = nullptr) const;
  // sample() in two steps, for a sky with a sun disc (deferrable): the direction alone, then
  // its radiance and pdf, which cost a light sample more than drawing it (the sky model and
  // the map's pdf) and which a light sample needs only once its shadow ray is clear.
  bool deferrable(bool cover_all) const { return sun_share(cover_all) > 0.0f; }
  bool sample_direction(Vec2 u, Vec3& dir, bool cover_all) const;
  bool finish_sample(Vec3 dir, Vec3& radiance, float& pdf, bool cover_all, const RayState* rs = nullptr) const {
    pdf = this->pdf(dir, cover_all);
    radiance = eval(dir, rs);
    return pdf > 0.0f && std::isfinite(pdf);
  }
  float average_luminance() const { return avg_lum_; }
  // Its strategies one by one, for light portals (Scene::sample_world): a sky's sun disc (its
  // share of sample()'s samples; 0: none) and the map without it (cells_samplable: false where
  // it has no density in this mode, e.g. a constant map's compensated part).
  float sun_fraction(bool cover_all) const { return sun_share(cover_all); }
  Vec3 sample_sun_disc(Vec2 u) const;
  float sun_disc_pdf(Vec3 dir_world) const { return sun_pdf(dir_world); }
  bool cells_samplable(bool cover_all) const { return !(cover_all ? full_ : comp_).marginal.empty(); }
  bool sample_map(Vec2 u, Vec3& dir, float& pdf, bool cover_all) const {
    float uu, vv;
    return sample_cells(cover_all ? full_ : comp_, u, dir, uu, vv, pdf);
  }
  float map_pdf(Vec3 dir_world, bool cover_all) const { return pdf_cells(cover_all ? full_ : comp_, dir_world); }

 private:
  struct Cells {  // a piecewise-bilinear distribution over the cells, of max(0, lum - sub)
    std::vector<Distribution1D> rows;  // per cell row, over its w cells
    Distribution1D marginal;           // over the h + 1 cell rows
    double norm = 0.0;                 // integral of weight * cell_cos over (u, v)
    float sub = 0.0f;
  };
  Vec3 lookup(float u, float v) const;
  Vec3 decode(Vec3 encoded) const;  // an sRGB texel's scene-linear radiance (srgb_)
  Vec3 eval_map(Vec3 dir_world) const;
  Vec3 eval_program(Vec3 dir_world, const RayState* rs, const Vec3* ray_p) const;
  void to_uv(Vec3 t, float& u, float& v) const;
  // Cell row j (0..h) spans v in [max(0, (j - 0.5) / h), min(1, (j + 0.5) / h)].
  float cell_v0(int j) const { return std::max(0.0f, (j - 0.5f) / h_); }
  float cell_v1(int j) const { return std::min(1.0f, (j + 0.5f) / h_); }
  float weight(const Cells& d, int x, int y) const;
  void build_cells(Cells& d, float sub);
  bool sample_cells(const Cells& d, Vec2 uu, Vec3& dir, float& u, float& v, float& pdf) const;
  float pdf_cells(const Cells& d, Vec3 dir_world) const;
  float pdf_cells_uv(const Cells& d, float u, float v) const;
  void init_distributions();
  Vec3 to_world(Vec3 t) const;
  // The sun disc's share of the samples and its cone (texture space), for a sky with a disc.
  float sun_pdf(Vec3 dir_world) const;
  float sun_share(bool cover_all) const { return cover_all ? sun_share_full_ : sun_share_comp_; }
  std::shared_ptr<const SkyModel> sky_;
  std::shared_ptr<WorldShader> prog_;
  bool baked_ = false;
  bool srgb_ = false;  // px_ sRGB-encoded (an 8-bit image), not yet times strength_
  float strength_ = 1.0f;
  Vec3 sun_dir_;            // texture space
  Vec3 sun_a_, sun_b_;      // a basis about it, for the disc's samples
  double sun_one_minus_cos_ = 0.0;  // 1 - cos(half angle), exactly
  float sun_share_full_ = 0.0f, sun_share_comp_ = 0.0f;
  std::vector<Vec3> px_;
  std::vector<float> lum_;  // luminance per texel, >= 0
  int w_ = 0, h_ = 0;
  Mat4 rot_;  // world -> texture
  std::vector<float> cell_cos_;  // cos(elevation) at each cell row's centre
  Cells full_, comp_;
  float avg_lum_ = 0.0f;
};

}  // namespace pl
