// The scene's lights: the light distribution and tree built at commit over analytic lights,
// emitter groups and the environment, and direct light sampling and its pdfs.
#include "scene/scene.h"
#include "scene/light_shader.h"

#include <algorithm>
#include <optional>

#include "scene/scene_detail.h"

namespace pl {

using detail::material_of;

namespace {

// Emissive triangles are sampled uniformly in the solid angle they subtend, except where that
// angle is tiny (far away: area sampling is as good, cheaper and better conditioned) or close to
// a hemisphere (the spherical construction loses precision there).
inline bool use_spherical_sampling(double omega) { return omega > 2e-4 && omega < 6.2; }

// One of a group's `count` triangles picked by x in [0, the weights' sum) in proportion to
// weight(i), and x rescaled into [0, 1] within its share, so that the sample stays stratified
// over the whole group. False where the pick has no weight.
template <class Weight>
inline bool pick_weighted(uint32_t count, const Weight& weight, double x, uint32_t& i, float& x_in_share) {
  double acc = 0.0;
  i = 0;
  for (; i + 1 < count && !(x < acc + weight(i)); ++i) acc += weight(i);
  const double wi = weight(i);
  if (!(wi > 0.0)) return false;
  x_in_share = float(std::clamp((x - acc) / wi, 0.0, 1.0));
  return true;
}

// The probability of picking triangle `area` of a group of `group_area` by area, times the
// group's own.
inline float area_pmf(float pmf, float area, float group_area) {
  return float(double(pmf) * double(area) / double(group_area));
}

}  // namespace

void Scene::detect_rect(EmitterGroup& g, const InstanceData& in) const {
  g.rect = false;
  if (g.count != 2 || g.corners != 4) return;
  const auto has = [&](int t, uint8_t c) { return g.tri_corner[t][0] == c || g.tri_corner[t][1] == c || g.tri_corner[t][2] == c; };
  // The corner only triangle 0 has (the origin), the one only triangle 1 has (opposite it), and
  // the shared diagonal's two in triangle 0's order.
  int o = -1, far = -1, a = -1, b = -1;
  for (int k = 0; k < 3; ++k) {
    const uint8_t c = g.tri_corner[0][k];
    if (!has(1, c)) o = c;
    else (a < 0 ? a : b) = c;
    if (!has(0, g.tri_corner[1][k])) far = g.tri_corner[1][k];
  }
  if (o < 0 || far < 0 || b < 0) return;
  DVec3 w[4];
  for (int c = 0; c < 4; ++c) w[c] = DVec3(in.transformed ? in.to_world.point(g.corner[c]) : g.corner[c]);  // as world_triangle
  const DVec3 ex = w[a] - w[o], ey = w[b] - w[o];
  const double lx = dlength(ex), ly = dlength(ey);
  if (!(lx > 0.0) || !(ly > 0.0) || !std::isfinite(lx * ly)) return;
  // A rectangle to 1e-5 of its edges: right-angled, and the fourth corner where the first three
  // put it (planar). Float corners (a rotated quad's) are off by ~1e-7; sheared ones by far more.
  constexpr double kTol = 1e-5;
  const DVec3 off = w[far] - (w[o] + ex + ey);
  if (!(std::fabs(ddot(ex, ey)) <= kTol * lx * ly) || !(dlength(off) <= kTol * std::min(lx, ly))) return;
  g.rect_o = w[o];
  g.rect_x = ex * (1.0 / lx);
  DVec3 y = ey - g.rect_x * ddot(ey, g.rect_x);  // exactly orthogonal for the warp
  if (!dnormalize(y)) return;
  g.rect_y = y;
  g.rect_n = dcross(g.rect_x, g.rect_y);
  g.rect_lx = lx;
  g.rect_ly = ddot(ey, y);
  if (!(g.rect_ly > 0.0) || !dnormalize(g.rect_n)) return;
  g.rect_inv_lx = 1.0 / g.rect_lx;
  g.rect_inv_ly = 1.0 / g.rect_ly;
  const auto rect_index = [&](int c) { return uint8_t(c == o ? 0 : c == a ? 1 : c == b ? 2 : 3); };
  for (int t = 0; t < 2; ++t)
    for (int k = 0; k < 3; ++k) g.rect_corner[t][k] = rect_index(g.tri_corner[t][k]);
  for (int t = 0; t < 2; ++t) {
    const Emitter& em = emitters_[g.first + size_t(t)];
    const TriangleVerts tv = world_triangle(inst_[em.instance], blases_[inst_[em.instance].blas].tris[em.tri]);
    g.rect_tri_n[t] = tv.unit_normal();
  }
  g.rect = true;
}

// The environment's weight beside the other lights' (`others`, by power). Cycles' light tree
// picks between its local and distant lights by the mean of two probabilities, one from upper
// bounds of their importance (as a power share) and one from lower bounds, in which the
// environment has none: a local light in front of a point gets at least half of its light
// samples. By power alone the environment's estimate, which grows with the scene's size, took
// 80 % of them beside the bench's point light, and the rough glass that shows that light by
// refraction (and its caustic) had 1.5x Cycles' per-sample variance (issue 25). So where local
// lights exist, the environment keeps half its power share: others / (env + 2 others) times
// its power. Suns count as others (their lower bound is not 0); without a local light nothing
// changes.
float Scene::env_choice_weight(float env_power, const std::vector<float>& others) const {
  double all = 0.0, local = 0.0;
  for (size_t k = 0; k < others.size(); ++k) {
    const double w = std::isfinite(others[k]) && others[k] > 0.0f ? double(others[k]) : 0.0;
    all += w;
    if (!(k < lights_.size() && lights_[k].type == LightType::Sun)) local += w;
  }
  if (!(local > 0.0) || !(env_power > 0.0f) || !std::isfinite(env_power)) return env_power;
  return float(double(env_power) * all / (double(env_power) + 2.0 * all));
}

void Scene::build_lights() {
  for (Light& l : lights_)
    if (l.shader) l.shader->scene = this;  // (images, ambient occlusion: this scene's)
  if (env_.needs_bake()) env_.bake(*this);  // a program world's map, once its images are in
  any_transparent_ = false;
  any_holdout_ = false;
  for (const Material& m : materials_) {
    any_transparent_ = any_transparent_ || m.transparent;
    any_holdout_ = any_holdout_ || m.holdout;
  }
  stats_.materials = materials_.size();

  // Every light in one distribution, chosen in proportion to an estimate of its power.
  const Aabb bounds = world_bounds_;
  const float radius = bounds.empty() ? 1.0f : std::max(0.5f * length(bounds.extent()), 1e-6f);
  std::vector<float> weights;
  for (const Light& l : lights_) weights.push_back(light_power(l, radius));
  emitters_.clear();
  emitter_areas_.clear();
  const auto emission_weight = [&](uint32_t material) {
    const Vec3 le = materials_[material].emission_estimate;
    const float lum = std::max(luminance(le), max_component(le) * 1e-3f);
    return lum > 0.0f && std::isfinite(lum) ? lum : 0.0f;
  };
  std::vector<float> emitter_weights;
  std::vector<uint32_t> emitter_materials;
  const auto add_emitter = [&](uint32_t instance, uint32_t tri, const TriangleVerts& tv, float lum, uint32_t material) {
    const float area = 0.5f * length(cross(tv.v1 - tv.v0, tv.v2 - tv.v0));
    emitters_.push_back({instance, tri});
    emitter_areas_.push_back(area);
    emitter_weights.push_back(2.0f * kPi * area * lum);  // two-sided
    emitter_materials.push_back(material);
  };
  // Per material once; a scene without emissive materials skips the per-triangle scans.
  std::vector<float> material_lum(materials_.size());
  bool any_emissive = false;
  for (size_t id = 0; id < materials_.size(); ++id) {
    material_lum[id] = emission_weight(uint32_t(id));
    any_emissive = any_emissive || material_lum[id] > 0.0f;
  }
  // Emitters in flattened order for the merged triangles (as one world-space BVH had them),
  // then (instance, triangle) pairs of the real instances.
  for (Blas& b : blases_) {
    b.emitter.clear();
    b.emissive.clear();
    if (!any_emissive) continue;
    if (b.merged) {
      for (size_t r = 0; r < b.run_first.size(); ++r) {  // runs of one instance's triangles
        const uint32_t in = b.run_inst[r];
        const MeshData& mesh = meshes_[inst_[in].mesh];
        const uint32_t end = r + 1 < b.run_first.size() ? b.run_first[r + 1] : uint32_t(b.tris.size());
        for (uint32_t t = b.run_first[r]; t < end; ++t) {
          const uint32_t mat = material_of(mesh, b.src_tri[t], materials_.size());
          const float lum = material_lum[mat];
          if (!(lum > 0.0f)) continue;
          if (b.emitter.empty()) b.emitter.assign(b.tris.size(), -1);
          b.emitter[t] = int32_t(emitters_.size());
          add_emitter(in, t, b.tris[t], lum, mat);
        }
      }
    } else {
      for (uint32_t t = 0; t < b.tris.size(); ++t) {
        if (!(material_lum[material_of(meshes_[b.mesh], b.src_tri[t], materials_.size())] > 0.0f)) continue;
        if (b.emitter.empty()) b.emitter.assign(b.tris.size(), -1);
        b.emitter[t] = int32_t(b.emissive.size());
        b.emissive.push_back(t);
      }
    }
  }
  for (size_t i = 0; i < inst_.size(); ++i) {
    InstanceData& in = inst_[i];
    // Moving instances are no light samples (they would be sampled where the frame has them).
    if (!in.transformed || in.blas == UINT32_MAX || in.motion || in.deform) continue;
    const Blas& b = blases_[in.blas];
    in.emitter_base = uint32_t(emitters_.size());
    for (uint32_t t : b.emissive) {
      const uint32_t mat = material_of(meshes_[b.mesh], b.src_tri[t], materials_.size());
      add_emitter(uint32_t(i), t, world_triangle(in, b.tris[t]), material_lum[mat], mat);
    }
  }
  // Groups: an object's emitters of one material when there are at most kMaxEmitterGroup of
  // them (a quad, a small polygon: sampled as one), else one group per triangle (a big mesh
  // light would cost a solid angle per triangle of the group on every sample). An object's
  // emitters are consecutive in emitters_.
  groups_.clear();
  stats_.rect_emitters = 0;
  emitter_group_.assign(emitters_.size(), 0);
  for (size_t e = 0; e < emitters_.size();) {
    size_t end = e + 1;
    while (end < emitters_.size() && emitters_[end].instance == emitters_[e].instance) ++end;
    bool one = emitter_groups_ && end - e <= kMaxEmitterGroup && end - e > 1;
    for (size_t k = e + 1; k < end && one; ++k) one = emitter_materials[k] == emitter_materials[e];
    for (size_t k = e; k < end; k += one ? end - e : 1) {
      EmitterGroup g;
      g.first = uint32_t(k);
      g.count = one ? uint32_t(end - e) : 1u;
      float w = 0.0f;
      for (size_t j = k; j < k + g.count; ++j) {
        g.area += emitter_areas_[j];
        w += emitter_weights[j];
        emitter_group_[j] = uint32_t(groups_.size());
      }
      if (g.count > 1) {
        const Blas& b = blases_[inst_[emitters_[k].instance].blas];
        for (uint32_t t = 0; t < g.count; ++t) {
          const TriangleVerts& tv = b.tris[emitters_[k + t].tri];
          const Vec3 v[3] = {tv.v0, tv.v1, tv.v2};
          for (int c = 0; c < 3; ++c) {
            uint8_t j = 0;
            while (j < g.corners && !(g.corner[j].x == v[c].x && g.corner[j].y == v[c].y && g.corner[j].z == v[c].z)) ++j;
            if (j == g.corners) {
              g.corner[j] = v[c];
              ++g.corners;
            }
            g.tri_corner[t][c] = j;
          }
        }
      }
      if (g.count == 2 && rect_groups_) detect_rect(g, inst_[emitters_[k].instance]);
      stats_.rect_emitters += g.rect;
      groups_.push_back(g);
      weights.push_back(w);
    }
    e = end;
  }
  links_ = false;
  uint8_t max_set = 0;
  for (const Light& l : lights_) links_ = links_ || l.light_mask != kAllLightSets || l.shadow_mask != kAllLightSets;
  for (const ObjectCoords& oc : object_coords_) {
    const ObjectInfo& in = oc.info;
    links_ = links_ || in.light_set || in.shadow_set || in.light_mask != kAllLightSets || in.shadow_mask != kAllLightSets;
    max_set = std::max(max_set, in.light_set);
  }
  for (const auto* sets : {&curve_coords_, &point_coords_})  // (emitters only to rays that hit them)
    for (const ObjectCoords& oc : *sets) {
      links_ = links_ || oc.info.light_set || oc.info.shadow_set || oc.info.light_mask != kAllLightSets ||
               oc.info.shadow_mask != kAllLightSets;
      max_set = std::max(max_set, oc.info.light_set);
    }
  env_index_ = SIZE_MAX;
  // A constant world seen through portals: a constant map, so that it is a light to sample.
  if (env_from_color_) {
    env_ = Environment();
    env_from_color_ = false;
  }
  if (!portals_.empty() && !env_.valid() && !is_black(world_color_) && is_finite(world_color_)) {
    env_ = Environment(std::vector<Vec3>(8, world_color_), 4, 2, 1.0f, Mat4());
    env_from_color_ = true;
  }
  const float env_power = env_.valid() ? 4.0f * kPi * kPi * radius * radius * env_.average_luminance() : 0.0f;
  // (Sampling Method None: no light to sample, rays that escape find the world with weight 1;
  // with portals Cycles keeps the world as a light sampled through them alone: map_weight 0.)
  const bool env = (world_sampled_ || !portals_.empty()) && env_.valid() && env_.average_luminance() > 0.0f;
  set_lc_.clear();
  if (!links_) {
    if (env) {
      env_index_ = weights.size();
      weights.push_back(env_choice_weight(env_power, weights));
    }
    lc_.dist = Distribution1D(weights);
    build_light_tree(weights, lc_);
    any_lights_ = !lc_.dist.empty();
  } else {
    // Light linking: one choice per light set in use, over the lights that reach it (the
    // environment reaches every set; its share is weighed against that set's lights).
    if (env) env_index_ = weights.size();
    any_lights_ = false;
    set_lc_.resize(max_set);
    for (uint32_t set = 0; set <= max_set; ++set) {
      std::vector<float> w(weights.size());
      for (size_t k = 0; k < weights.size(); ++k) w[k] = (entry_light_mask(k) >> set) & 1u ? weights[k] : 0.0f;
      if (env) w.push_back(env_choice_weight(env_power, w));
      LightChoice& c = set == 0 ? lc_ : set_lc_[set - 1];
      c.dist = Distribution1D(w);
      build_light_tree(w, c);
      any_lights_ = any_lights_ || !c.dist.empty();
    }
  }
  stats_.light_tree_nodes = lc_.tree.node_count();
  stats_.light_tree_depth = size_t(lc_.tree.depth());
  // The lights rays may find: with extent, seen by the camera or (Multiple Importance on) by
  // other rays; each with a bounding sphere (a point or spot disk faces the ray's origin, so
  // its sphere; an area light's corners).
  hit_lights_.clear();
  hit_suns_.clear();
  dedicated_lights_.clear();
  for (size_t k = 0; k < lights_.size() && light_hits_on_; ++k) {
    const Light& l = lights_[k];
    // Shadow-linked lights: other rays than the camera's find them by dedicated rays instead.
    const bool mis = l.mis && l.shadow_mask == kAllLightSets;
    if (l.mis && !mis && light_has_extent(l) && max_component(l.color) > 0.0f) {
      HitLight d;
      d.index = uint32_t(k);
      d.visibility = l.visibility;
      d.mis = true;
      dedicated_lights_.push_back(d);
    }
    if (!light_has_extent(l) || !(mis || (l.visibility & kLightVisCamera))) continue;
    if (!(max_component(l.color) > 0.0f)) continue;
    HitLight h;
    h.index = uint32_t(k);
    h.visibility = l.visibility;
    h.mis = mis;
    h.center = l.position;
    if (l.type == LightType::Sun) {
      hit_suns_.push_back(h);
      continue;
    }
    const bool area = l.type == LightType::Rect || l.type == LightType::Ellipse;
    const float r = area ? 0.5f * (length(l.axis_u) + length(l.axis_v)) : l.radius;
    h.radius = r * 1.0001f + 1e-6f;
    h.radius2 = h.radius * h.radius;
    Aabb b;
    if (area) {
      for (int i = 0; i < 4; ++i)
        b.grow(l.position + l.axis_u * ((i & 1) ? 0.5f : -0.5f) + l.axis_v * ((i & 2) ? 0.5f : -0.5f));
    } else {
      b.grow(l.position - Vec3(r));
      b.grow(l.position + Vec3(r));
    }
    const Vec3 pad = vmax(b.extent() * 1e-4f, Vec3(1e-6f)) + vmax(vmax(b.lo, -b.lo), vmax(b.hi, -b.hi)) * 1e-6f;
    h.lo = b.lo - pad;
    h.hi = b.hi + pad;
    hit_lights_.push_back(h);
  }
  hit_nodes_.clear();
  if (hit_lights_.size() >= kHitLightBvhMin) build_hit_nodes(0, hit_lights_.size());
  stats_.emissive_triangles = emitters_.size();
  stats_.lights = lights_.size();
  ++stats_.light_builds;
  detect_features();
}

uint64_t Scene::entry_light_mask(size_t k) const {
  if (k < lights_.size()) return lights_[k].light_mask;
  if (k - lights_.size() < groups_.size()) return emitter_light_mask(emitters_[groups_[k - lights_.size()].first].instance);
  return kAllLightSets;  // the environment
}

uint64_t Scene::entry_shadow_mask(size_t k) const {
  if (k < lights_.size()) return lights_[k].shadow_mask;
  if (k - lights_.size() < groups_.size()) return emitter_shadow_mask(emitters_[groups_[k - lights_.size()].first].instance);
  return kAllLightSets;
}

void Scene::build_light_tree(const std::vector<float>& weights, LightChoice& out) const {
  // Bounds of every finite entry of the distribution (same indices; zero power: left out), and the
  // infinite ones beside the tree.
  std::vector<LightBounds> items(weights.size());
  out.inf_items.clear();
  std::vector<float> inf_weights;
  double inf_total = 0.0, total = 0.0;
  const auto finite_weight = [](float w) { return std::isfinite(w) && w > 0.0f ? w : 0.0f; };
  size_t finite = 0;
  for (size_t k = 0; k < weights.size(); ++k) {
    const float w = finite_weight(weights[k]);
    total += w;
    const bool infinite = k == env_index_ || (k < lights_.size() && lights_[k].type == LightType::Sun);
    if (infinite) {
      out.inf_items.push_back(uint32_t(k));
      inf_weights.push_back(w);
      inf_total += w;
      continue;
    }
    if (!(w > 0.0f)) continue;
    LightBounds& b = items[k];
    if (k < lights_.size()) {
      const Light& l = lights_[k];
      const float lum = std::max(luminance(l.color), 0.0f) * light_power_scale(l);
      switch (l.type) {
        case LightType::Point:
        case LightType::Spot: {
          b.bounds.grow(l.position - Vec3(l.radius));
          b.bounds.grow(l.position + Vec3(l.radius));
          b.phi = 4.0f * kPi * lum;  // a spot's cone is in its direction bounds
          b.cos_theta_o = -1.0f;     // every direction
          b.cos_theta_e = 0.0f;
          if (l.type == LightType::Spot) {
            // The axis: the world direction that to_local takes to local -Z, where to_local is a
            // similarity (rows orthogonal, of one length); else the whole sphere stays.
            const Vec3 r0{l.to_local.m[0][0], l.to_local.m[0][1], l.to_local.m[0][2]};
            const Vec3 r1{l.to_local.m[1][0], l.to_local.m[1][1], l.to_local.m[1][2]};
            const Vec3 r2{l.to_local.m[2][0], l.to_local.m[2][1], l.to_local.m[2][2]};
            const float s0 = length_sq(r0), s1 = length_sq(r1), s2 = length_sq(r2);
            const float tol = 1e-4f * std::max(s0, std::max(s1, s2));
            const bool similar = std::fabs(s0 - s2) <= tol && std::fabs(s1 - s2) <= tol && std::fabs(dot(r0, r1)) <= tol &&
                                 std::fabs(dot(r0, r2)) <= tol && std::fabs(dot(r1, r2)) <= tol && s2 > 0.0f;
            if (similar && l.cos_half_spot > -1.0f) {
              b.w = -r2 / std::sqrt(s2);
              // Full strength inside theta_o (where the blend ends), falling to 0 at the cone's
              // edge theta_o + theta_e (widened by a hair against rounding).
              const float outer = std::acos(std::clamp(l.cos_half_spot, -1.0f, 1.0f));
              const float cos_inner =
                  l.spot_smooth_inv > 0.0f ? std::min(1.0f, l.cos_half_spot + 1.0f / l.spot_smooth_inv) : l.cos_half_spot;
              const float inner = std::acos(std::clamp(cos_inner, -1.0f, 1.0f));
              b.cos_theta_o = std::cos(inner);
              b.cos_theta_e = std::cos(std::min(outer - inner + 1e-3f, kPi));
            }
          }
          break;
        }
        case LightType::Rect:
        case LightType::Ellipse:
          for (int i = 0; i < 4; ++i)
            b.bounds.grow(l.position + l.axis_u * ((i & 1) ? 0.5f : -0.5f) + l.axis_v * ((i & 2) ? 0.5f : -0.5f));
          b.phi = kPi * l.area * lum;
          b.w = l.dir;  // one-sided
          b.cos_theta_o = 1.0f;
          // A spread below 180 degrees emits within its half angle of the normal only.
          b.cos_theta_e = has_spread(l) ? 1.0f / std::sqrt(1.0f + l.tan_half_spread * l.tan_half_spread) : 0.0f;
          break;
        case LightType::Sun:
          break;
      }
    } else {
      // An emitter group: its world-space triangles, two-sided, normals in one cone.
      const EmitterGroup& g = groups_[k - lights_.size()];
      b.phi = w;
      b.two_sided = true;
      b.cos_theta_e = 0.0f;
      bool any = false;
      for (uint32_t j = g.first; j < g.first + g.count; ++j) {
        const Emitter& em = emitters_[j];
        const InstanceData& in = inst_[em.instance];
        const TriangleVerts tv = world_triangle(in, blases_[in.blas].tris[em.tri]);
        b.bounds.grow(tv.v0);
        b.bounds.grow(tv.v1);
        b.bounds.grow(tv.v2);
        const Vec3 n = cross(tv.v1 - tv.v0, tv.v2 - tv.v0);
        if (!(length_sq(n) > 0.0f) || !is_finite(n)) continue;
        LightBounds t;
        t.w = normalize(n);
        t.phi = 1.0f;
        t.cos_theta_o = 1.0f;
        if (!any) {
          b.w = t.w;
          b.cos_theta_o = 1.0f;
          any = true;
        } else {
          LightBounds c = b;
          c.phi = 1.0f;
          c = light_bounds_union(c, t);
          b.w = c.w;
          b.cos_theta_o = c.cos_theta_o;
        }
      }
      if (!any) b.cos_theta_o = -1.0f;
      b.phi = b.bounds.empty() ? 0.0f : w;
    }
    finite += b.phi > 0.0f;
  }
  const bool want = light_tree_mode_ == LightTreeMode::On ||
                    (light_tree_mode_ == LightTreeMode::Auto && finite > kLightTreeMinLights);
  out.tree = want && finite > 0 ? LightTree(items) : LightTree();
  out.use_tree = !out.tree.empty();
  // The infinite lights keep the share of the power the single distribution gives them.
  out.inf_share = !out.use_tree ? 0.0f : out.inf_items.empty() ? 0.0f : float(inf_total / total);
  if (out.use_tree && !(out.inf_share < 1.0f)) out.use_tree = false;  // nothing finite has power
  out.tree_share = 1.0f - out.inf_share;
  out.inf_dist = Distribution1D(inf_weights);
  out.inf_pmf.assign(weights.size(), 0.0f);
  for (size_t j = 0; j < out.inf_items.size(); ++j) out.inf_pmf[out.inf_items[j]] = out.inf_share * out.inf_dist.pmf(j);
  if (!(out.inf_share > 0.0f) || out.inf_dist.empty()) out.inf_share = 0.0f, out.tree_share = 1.0f;
}


// Inlined into sample_direct: as a call it cost a fifth of a light sample in argument passing.
[[gnu::always_inline]] inline bool Scene::group_solid_angles(const EmitterGroup& g, Vec3 p, double (*dirs)[3], double* omega, double& total) const {
  const InstanceData& in = inst_[emitters_[g.first].instance];
  uint32_t bad = 0;  // corners without a direction (p on them)
  for (uint32_t c = 0; c < g.corners; ++c) {
    Vec3 v = g.corner[c];
    if (in.transformed) v = in.to_world.point(v);  // as world_triangle
    DVec3 d = DVec3(v) - DVec3(p);
    if (!dnormalize(d)) bad |= 1u << c;
    dirs[c][0] = d.x;
    dirs[c][1] = d.y;
    dirs[c][2] = d.z;
  }
  total = 0.0;
  bool all = solid_angle_triangles_;
  for (uint32_t i = 0; i < g.count; ++i) {
    const uint8_t* tc = g.tri_corner[i];
    omega[i] = 0.0;  // as spherical_triangle gives for a corner at p
    if (!(bad >> tc[0] & 1u) && !(bad >> tc[1] & 1u) && !(bad >> tc[2] & 1u)) {
      const double *a = dirs[tc[0]], *b = dirs[tc[1]], *c = dirs[tc[2]];
      omega[i] = spherical_triangle_solid_angle({a[0], a[1], a[2]}, {b[0], b[1], b[2]}, {c[0], c[1], c[2]});
    }
    total += omega[i];
    // Only where every triangle would be sampled by solid angle on its own: elsewhere the
    // group falls back to what its triangles alone would do.
    all = all && use_spherical_sampling(omega[i]);
  }
  return all;
}

[[gnu::always_inline]] inline bool Scene::emitter_point_sample(size_t e, Vec3 p, float b1, float b2, Vec3 n, bool spherical,
                                                               float pdf_solid, float pmf_e, DirectSample& s) const {
  const Emitter& em = emitters_[e];
  const InstanceData& in = inst_[em.instance];
  // The light point as a hit on it: position and error bound exactly as a ray would find it
  // (through the instance's transform where it has one); normals only for a shaded emission.
  const Blas& blas = blases_[in.blas];
  const uint32_t lmat = material_of(meshes_[in.mesh], blas.src_tri[em.tri], materials_.size());
  const bool shaded = !materials_[lmat].constant;
  std::optional<SurfacePoint> lp;  // (a whole hit only for a shaded emission)
  Vec3 q, q_error;
  if (shaded) {
    Hit h;
    h.prim = em.tri;
    h.inst = em.instance;
    h.b1 = b1;
    h.b2 = b2;
    surface_point(h, lp.emplace());
    q = lp->p;
    q_error = lp->p_error;
  } else {
    triangle_point(in, blas.tris[em.tri], b1, b2, q, q_error);
  }
  const Vec3 d = q - p;
  const float dist2 = length_sq(d);
  const float dist = std::sqrt(dist2);
  if (!(dist > 0.0f)) return false;
  s.wi = d / dist;
  const float cos_l = std::fabs(dot(n, s.wi));
  if (!(cos_l > 0.0f)) return false;
  s.dist = dist;
  s.target = q;
  s.target_normal = dot(n, s.wi) < 0.0f ? n : -n;  // the side facing p
  s.target_error = q_error;
  if (!shaded) {
    s.li = materials_[lmat].cached.emission;  // what shade() returns for it, without building closures
  } else {
    // The material's emission at the sampled point (textured emission included).
    ClosureList cl;
    // As Cycles evaluates a light sample's shader: no ray kind set, the path's bounce counts.
    RayState emission = s.path ? *s.path : RayState{};
    emission.flags = 0;
    emission.emission_only = true;
    emission.length = dist;
    shade(*lp, b1, b2, -s.wi, cl, emission);
    s.li = cl.emission;
  }
  s.pdf = spherical ? pdf_solid : pmf_e / emitter_areas_[e] * dist2 / cos_l;
  return std::isfinite(s.pdf) && s.pdf > 0.0f;
}

[[gnu::always_inline]] inline bool Scene::sample_emitter(size_t e, Vec3 p, const SphericalTriangle& st, bool spherical,
                                                         float pdf_solid, float pmf_e, Vec2 u, DirectSample& s) const {
  const Emitter& em = emitters_[e];
  const InstanceData& in = inst_[em.instance];
  const TriangleVerts tv = world_triangle(in, blases_[in.blas].tris[em.tri]);
  const Vec3 n = tv.unit_normal();
  float b1, b2;
  DVec3 w;
  if (spherical && sample_spherical_triangle(st, u, w)) {
    // The point where the sampled direction meets the triangle, as barycentrics (clamped into
    // the triangle against rounding: the direction's density stays 1 / omega either way).
    const DVec3 d0(tv.v0), e1 = DVec3(tv.v1) - d0, e2 = DVec3(tv.v2) - d0, nd = dcross(e1, e2);
    const double nn = ddot(nd, nd), wn = ddot(w, nd);
    if (!(std::fabs(wn) > 0.0)) return false;
    const DVec3 r = DVec3(p) + w * (ddot(d0 - DVec3(p), nd) / wn) - d0;
    double db1 = std::max(0.0, ddot(dcross(r, e2), nd) / nn), db2 = std::max(0.0, ddot(dcross(e1, r), nd) / nn);
    const double sum = db1 + db2;
    if (sum > 1.0) {
      db1 /= sum;
      db2 /= sum;
    }
    b1 = float(db1);
    b2 = float(db2);
  } else if (spherical) {
    return false;  // degenerate as seen from p: it subtends no solid angle
  } else {
    sample_triangle_uniform(u, b1, b2);
  }
  return emitter_point_sample(e, p, b1, b2, n, spherical, pdf_solid, pmf_e, s);
}

namespace {
// A portal lets the world in towards p (p in front of its plane): Scene::sample_world below.
inline bool portal_faces(const Light& portal, Vec3 p) { return dot(portal.dir, p - portal.position) > 1e-4f; }
}  // namespace

template <bool kTree>
bool Scene::sample_direct_t(const LightChoice& c, Vec3 p, float u_select, Vec2 u, DirectSample& s, bool bsdf_follows) const {
  if (c.dist.empty()) return false;
  size_t k;
  float pmf;
  if (!choose_light_t<kTree>(c, p, s.n, u_select, k, pmf) || !(pmf > 0.0f)) return false;
  s.entry = uint32_t(k);  // (its light group: entry_light_group)
  s.target_normal = Vec3(0.0f);
  if (k < lights_.size()) {
    const Light& l = lights_[k];
    LightSample ls;
    if (!sample_light(l, p, u, ls, solid_angle_rects_)) return false;
    s.wi = ls.wi;
    s.dist = ls.dist;
    s.target = ls.target;
    s.li = ls.li;
    s.pdf = ls.pdf * pmf;
    // Rays find lights with extent whose Multiple Importance is on (Scene::hit_lights), so the
    // light sample is weighted against the BSDF's; delta lights and the others keep the full
    // weight (no ray can find them: MIS against the BSDF pdf would lose energy there).
    s.delta = ls.delta || !l.mis || !light_hits_on_;
    s.analytic = true;
    s.light = uint32_t(k);
    s.choice = pmf;
    s.exclude = uint8_t(~l.visibility & (kLightVisDiffuse | kLightVisGlossy | kLightVisTransmission | kLightVisVolume));
    s.cast_shadow = l.cast_shadow;
    if (links_) {
      // Shadow linking: rays find it only by dedicated rays (dedicated_lights_, surfaces only).
      s.shadow_mask = l.shadow_mask;
      s.dedicated = !s.delta && l.shadow_mask != kAllLightSets;
      s.delta = s.delta || l.shadow_mask != kAllLightSets;
    }
    return true;
  }
  s.delta = false;
  s.analytic = false;
  s.exclude = 0;
  s.cast_shadow = true;
  if (links_) {
    // A shadow-linked mesh light: light samples alone too (the integrator adds no BSDF hits).
    s.shadow_mask = entry_shadow_mask(k);
    s.delta = s.shadow_mask != kAllLightSets;
  }
  if (k == env_index_) {
    // Deferred where the radiance and pdf cost more than the draw: a sky with a sun disc (the
    // model and the mixture's pdf) or portals (every facing portal's intersection); a plain map's
    // sample already has both from its cell.
    bool defer = s.defer_world && defer_world_ && env_.deferrable(!bsdf_follows);
    if (s.defer_world && defer_world_ && !defer)  // (behind every portal: the map's one-step sample)
      for (const Light& portal : portals_) defer = defer || portal_faces(portal, p);
    if (defer) {
      if (!sample_world_direction(p, u, s.wi, !bsdf_follows)) return false;
      s.dist = kInf;
      s.world_pending = true;
      s.world_cover_all = !bsdf_follows;
      s.world_pmf = pmf;
      s.world_p = p;
      return true;
    }
    float pdf;
    RayState rs;  // (a program world's Light Path reads the vertex's counts)
    if (!sample_world(p, u, s.wi, s.li, pdf, !bsdf_follows, light_sample_state(s.path, rs))) return false;
    s.dist = kInf;
    s.pdf = pdf * pmf;
    return true;
  }
  const EmitterGroup& g = groups_[k - lights_.size()];
  size_t e = g.first;
  if (g.rect && solid_angle_triangles_) {
    // Uniform in the rectangle's solid angle above the triangles' lower limit (its warp stays
    // well conditioned up to a whole hemisphere: tests/test_emitter_groups.py), else by area.
    const SphericalRectLocal sr = group_rect(g, p);
    if (use_spherical_rect(sr.solid_angle)) {
      // One spherical rectangle over both triangles: the point's rectangle coordinates (s, t)
      // give the triangle (s + t <= 1: triangle 0, which has the origin corner) and its
      // barycentrics (the rectangle's corners' weights at (s, t)).
      double xu, yv;
      if (!sample_spherical_rect_local(sr, u, xu, yv)) return false;
      const double rs = std::clamp((xu - sr.x0) * g.rect_inv_lx, 0.0, 1.0), rt = std::clamp((yv - sr.y0) * g.rect_inv_ly, 0.0, 1.0);
      const int i = rs + rt <= 1.0 ? 0 : 1;
      const double w[4] = {std::max(0.0, 1.0 - rs - rt), i == 0 ? rs : 1.0 - rt, i == 0 ? rt : 1.0 - rs, std::max(0.0, rs + rt - 1.0)};
      e += size_t(i);
      return emitter_point_sample(e, p, float(w[g.rect_corner[i][1]]), float(w[g.rect_corner[i][2]]), g.rect_tri_n[i], true,
                                  float(pmf / sr.solid_angle), pmf, s);
    }
    // A speck from p (or p in its plane): by area, as the triangles would be (each subtends
    // less), without their solid angles.
    const auto area = [&](uint32_t i) { return double(emitter_areas_[g.first + i]); };
    uint32_t i;
    if (!pick_weighted(g.count, area, double(u.x) * double(g.area), i, u.x)) return false;
    e += i;
    return sample_emitter(e, p, SphericalTriangle(), false, 0.0f, area_pmf(pmf, emitter_areas_[e], g.area), u, s);
  }
  SphericalTriangle st;
  bool spherical;
  float pdf_solid, pmf_e = pmf;
  if (g.count == 1) {
    const Emitter& em = emitters_[e];
    const InstanceData& in = inst_[em.instance];
    const TriangleVerts tv = world_triangle(in, blases_[in.blas].tris[em.tri]);
    st = spherical_triangle(p, tv.v0, tv.v1, tv.v2);
    spherical = solid_angle_triangles_ && use_spherical_sampling(st.solid_angle);
    pdf_solid = float(pmf / st.solid_angle);
  } else {
    // A group: one triangle chosen by u.x, in proportion to its solid angle (by area where the
    // group is not sampled by solid angle from p), and u.x rescaled into its share, so that the
    // sample stays stratified over the whole group.
    double dirs[3 * kMaxEmitterGroup][3], omega[kMaxEmitterGroup], total;
    const bool whole = group_solid_angles(g, p, dirs, omega, total);
    const auto weight = [&](uint32_t i) { return whole ? omega[i] : double(emitter_areas_[g.first + i]); };
    uint32_t i;
    if (!pick_weighted(g.count, weight, double(u.x) * (whole ? total : double(g.area)), i, u.x)) return false;
    e += i;
    const auto dir = [&](int c) {
      const double* d = dirs[g.tri_corner[i][c]];
      return DVec3(d[0], d[1], d[2]);
    };
    st.a = dir(0);
    st.b = dir(1);
    st.c = dir(2);
    st.solid_angle = omega[i];
    if (whole) {
      spherical = true;
      pdf_solid = float(pmf / total);
    } else {
      spherical = solid_angle_triangles_ && use_spherical_sampling(omega[i]);
      pmf_e = area_pmf(pmf, emitter_areas_[e], g.area);
      pdf_solid = float(pmf_e / omega[i]);
    }
  }
  return sample_emitter(e, p, st, spherical, pdf_solid, pmf_e, u, s);
}

template bool Scene::sample_direct_t<false>(const LightChoice&, Vec3, float, Vec2, DirectSample&, bool) const;
template bool Scene::sample_direct_t<true>(const LightChoice&, Vec3, float, Vec2, DirectSample&, bool) const;

float Scene::pdf_emitter(const SurfacePoint& sp, Vec3 from, Vec3 at, float cos_l, Vec3 from_n, uint8_t set) const {
  // Curves and points are not light-sampled: their emission is found by BSDF rays alone.
  if (sp.curve() || sp.point()) return 0.0f;
  const InstanceData& in = inst_[sp.instance];
  const int32_t e = emitter_of(in, sp.tri);
  if (e < 0 || !(cos_l > 0.0f)) return 0.0f;
  const uint32_t gi = emitter_group_[size_t(e)];
  const EmitterGroup& g = groups_[gi];
  const LightChoice& c = choice(set);
  if (c.dist.empty()) return 0.0f;
  const float pmf = light_pmf(c, from, from_n, lights_.size() + gi);
  if (!(pmf > 0.0f)) return 0.0f;
  // The same choices sample_direct makes from this point.
  if (g.rect && solid_angle_triangles_) {
    const double omega = group_rect(g, from).solid_angle;
    if (use_spherical_rect(omega)) return float(pmf / omega);
    const float pmf_e = area_pmf(pmf, emitter_areas_[size_t(e)], g.area);  // by area
    return pmf_e / emitter_areas_[size_t(e)] * length_sq(at - from) / cos_l;
  }
  double omega;
  float pmf_e = pmf;
  if (g.count == 1) {
    const TriangleVerts tv = world_triangle(in, blases_[in.blas].tris[sp.tri]);
    omega = spherical_triangle(from, tv.v0, tv.v1, tv.v2).solid_angle;
  } else {
    double dirs[3 * kMaxEmitterGroup][3], omegas[kMaxEmitterGroup], total;
    if (group_solid_angles(g, from, dirs, omegas, total)) return float(pmf / total);
    omega = omegas[size_t(e) - g.first];
    pmf_e = area_pmf(pmf, emitter_areas_[size_t(e)], g.area);
  }
  if (solid_angle_triangles_ && use_spherical_sampling(omega)) return float(pmf_e / omega);
  const float t2 = length_sq(at - from);
  return pmf_e / emitter_areas_[size_t(e)] * t2 / cos_l;
}

uint32_t Scene::build_hit_nodes(size_t begin, size_t end) {
  const uint32_t id = uint32_t(hit_nodes_.size());
  hit_nodes_.emplace_back();
  Aabb box, centres;
  for (size_t i = begin; i < end; ++i) {
    box.grow(hit_lights_[i].lo);
    box.grow(hit_lights_[i].hi);
    centres.grow((hit_lights_[i].lo + hit_lights_[i].hi) * 0.5f);
  }
  hit_nodes_[id].lo = box.lo;
  hit_nodes_[id].hi = box.hi;
  if (end - begin <= 2) {
    hit_nodes_[id].first = uint32_t(begin);
    hit_nodes_[id].count = uint32_t(end - begin);
    return id;
  }
  // Median split along the centres' longest axis.
  const Vec3 e = centres.extent();
  const int axis = e.x >= e.y && e.x >= e.z ? 0 : e.y >= e.z ? 1 : 2;
  const auto key = [axis](const HitLight& h) {
    const Vec3 c = (h.lo + h.hi) * 0.5f;
    return axis == 0 ? c.x : axis == 1 ? c.y : c.z;
  };
  const size_t mid = begin + (end - begin) / 2;
  std::nth_element(hit_lights_.begin() + long(begin), hit_lights_.begin() + long(mid), hit_lights_.begin() + long(end),
                   [&](const HitLight& a, const HitLight& b) { return key(a) < key(b); });
  build_hit_nodes(begin, mid);
  const uint32_t right = build_hit_nodes(mid, end);
  hit_nodes_[id].first = right;
  hit_nodes_[id].count = 0;
  return id;
}

bool Scene::nearest_light_hit(Vec3 from, Vec3 n, Vec3 dir, float tmax, float& t, Vec3& le, float& pdf) const {
  bool any = false;
  t = tmax;
  const auto one = [&](const HitLight& h) {
    if (!h.mis) return;
    float th, p;
    Vec3 l;
    if (!intersect_light(lights_[h.index], from, from, dir, t, th, l, p, solid_angle_rects_)) return;
    if (any && !(th < t)) return;
    any = true;
    t = th;
    le = l;
    pdf = light_choice_pmf(from, n, h.index) * p;
  };
  for_hit_lights(from, dir, tmax, one);
  if (!any && std::isinf(tmax))
    for (const HitLight& h : hit_suns_) one(h);
  return any;
}

namespace {
// Narrows [t0, t1] to the part of the ray o + t d inside the cone of apex a, unit axis v and
// half angle acos(cos_half) below 90 degrees (convex, so one interval, possibly unbounded):
// the roots of (w.v)^2 = cos^2 |w|^2 cut the interval, and a point of each piece tells whether
// it lies inside. False where nothing does.
bool clip_to_cone(Vec3 o, Vec3 d, Vec3 a, Vec3 v, float cos_half, float& t0, float& t1) {
  const double wx = double(o.x) - a.x, wy = double(o.y) - a.y, wz = double(o.z) - a.z;
  const double dv = double(d.x) * v.x + double(d.y) * v.y + double(d.z) * v.z;
  const double wv = wx * v.x + wy * v.y + wz * v.z, dw = wx * d.x + wy * d.y + wz * d.z;
  const double ww = wx * wx + wy * wy + wz * wz, dd = double(d.x) * d.x + double(d.y) * d.y + double(d.z) * d.z;
  const double c2 = double(cos_half) * cos_half;
  const double A = dv * dv - c2 * dd, B = 2.0 * (wv * dv - c2 * dw), C = wv * wv - c2 * ww;
  double br[4];
  int n = 0;
  br[n++] = t0;
  const auto root = [&](double r) {
    if (r > t0 && r < t1) br[n++] = r;
  };
  if (std::fabs(A) > 1e-12 * (std::fabs(B) + std::fabs(C) + 1e-30)) {
    const double disc = B * B - 4.0 * A * C;
    if (disc >= 0.0) {
      const double q = -0.5 * (B + std::copysign(std::sqrt(disc), B));
      root(q / A);
      if (q != 0.0) root(C / q);
    }
  } else if (B != 0.0) {
    root(-C / B);
  }
  br[n++] = t1;
  std::sort(br, br + n);
  const auto inside = [&](double t) {
    const double px = wx + t * d.x, py = wy + t * d.y, pz = wz + t * d.z;
    const double pv = px * v.x + py * v.y + pz * v.z;
    return pv >= 0.0 && pv * pv >= c2 * (px * px + py * py + pz * pz);
  };
  double lo = INFINITY, hi = -INFINITY;
  for (int i = 0; i + 1 < n; ++i) {
    const double x0 = br[i], x1 = br[i + 1];
    if (!(x1 > x0)) continue;
    const double mid = std::isfinite(x1) ? 0.5 * (x0 + x1) : x0 + std::max(1.0, std::fabs(x0));
    if (inside(mid)) {
      lo = std::min(lo, x0);
      hi = std::max(hi, x1);
    }
  }
  if (!(hi > lo)) return false;
  t0 = float(lo);
  t1 = float(hi);
  return t1 > t0;
}
}  // namespace

bool Scene::light_reference_point(Vec3 p, Vec3 d, float u_select, Vec2 u, Vec3& c, float& t0, float& t1) const {
  size_t k;
  float pmf;
  if (lc_.dist.empty() || !choose_light(lc_, p, Vec3(0.0f), u_select, k, pmf) || !(pmf > 0.0f)) return false;
  if (k == env_index_) return false;
  if (k < lights_.size()) {
    const Light& l = lights_[k];
    switch (l.type) {
      case LightType::Point: c = l.position; return true;
      case LightType::Spot: {
        c = l.position;
        // The widest cone of the spot (its spread about the axis), its apex moved back so that
        // it holds every cone from a point of the light's disk or sphere: the fog outside gets
        // no light from it, and equiangular distances there were wasted.
        const float cos_half = 1.0f - l.spread_one_minus_cos;
        if (!(cos_half > 0.02f) || !(length_sq(l.spot_axis) > 0.5f)) return true;
        const float sin_half = std::sqrt(std::max(0.0f, 1.0f - cos_half * cos_half));
        const Vec3 apex = l.position - l.spot_axis * (l.radius * 1.001f / sin_half + 1e-6f);
        if (is_finite(apex) && !clip_to_cone(p, d, apex, l.spot_axis, cos_half, t0, t1)) t1 = t0;
        return true;
      }
      case LightType::Rect:
      case LightType::Ellipse: {
        c = l.position + l.axis_u * (u.x - 0.5f) + l.axis_v * (u.y - 0.5f);
        // Only its front is lit (one-sided).
        const float h = dot(p - l.position, l.dir), dn = dot(d, l.dir);
        if (dn > 0.0f) t0 = std::max(t0, -h / dn);
        else if (dn < 0.0f) t1 = std::min(t1, -h / dn);
        else if (!(h > 0.0f)) t1 = t0;
        return true;
      }
      case LightType::Sun: return false;
    }
    return false;
  }
  // An emitter group: the centre of one of its triangles.
  const EmitterGroup& g = groups_[k - lights_.size()];
  const size_t e = g.first + std::min<size_t>(size_t(u.x * float(g.count)), size_t(g.count) - 1);
  const Emitter& em = emitters_[e];
  const InstanceData& in = inst_[em.instance];
  const TriangleVerts tv = world_triangle(in, blases_[in.blas].tris[em.tri]);
  c = (tv.v0 + tv.v1 + tv.v2) * (1.0f / 3.0f);
  return is_finite(c);
}

float Scene::environment_pmf(uint8_t set) const {
  if (env_index_ == SIZE_MAX) return -1.0f;
  const LightChoice& c = choice(set);
  if (c.dist.empty()) return -1.0f;
  return c.use_tree ? c.inf_pmf[env_index_] : c.dist.pmf(env_index_);
}

float Scene::pdf_environment(Vec3 dir, Vec3 from, uint8_t set) const {
  const float pmf = environment_pmf(set);
  return pmf < 0.0f ? 0.0f : pmf * world_pdf(from, dir, false);
}

Vec3 Scene::background_with_pdf(Vec3 dir, Vec3 from, uint8_t set, float& env_pdf, const RayState* rs,
                                const Vec3* ray_p) const {
  env_pdf = 0.0f;
  const float pmf = environment_pmf(set);
  if (pmf < 0.0f) return background(dir, rs, ray_p);
  if (!portals_.empty() || !env_.valid()) {
    env_pdf = pmf * world_pdf(from, dir, false);
    return background(dir, rs, ray_p);
  }
  float p;
  const Vec3 le = env_.eval_with_pdf(dir, false, p, rs, ray_p);
  env_pdf = pmf * p;
  return le;
}

// Light portals, as Cycles' background.h: a portal lets the world in towards its emission side
// (Light::dir; Cycles' side test, 1e-4 in front of its plane). A point in front of n portals
// keeps a sky's sun disc share and splits the rest: half through one portal picked uniformly,
// sampled by its solid angle (the rectangle's spherical warp, as the area lights; ellipses by
// area), half by the map (the portals take it all where the map has nothing to give, e.g. a
// constant world's compensated map). The pdf is the mixture's: every facing portal the direction
// crosses counts, so MIS with BSDF rays that escape through or beside a portal stays exact.
// Points behind every portal sample the world as without portals.

double Scene::portal_pdf_sum(Vec3 p, Vec3 dir, size_t skip, int& facing) const {
  double sum = 0.0;
  facing = 0;
  for (size_t i = 0; i < portals_.size(); ++i) {
    const Light& portal = portals_[i];
    if (!portal_faces(portal, p)) continue;
    ++facing;
    float t, pdf;
    Vec3 le;
    if (i != skip && intersect_light(portal, p, p, dir, kInf, t, le, pdf, solid_angle_rects_)) sum += double(pdf);
  }
  return sum;
}

bool Scene::sample_world(Vec3 p, Vec2 u, Vec3& dir, Vec3& li, float& pdf, bool cover_all, const RayState* rs) const {
  if (portals_.empty()) return env_.sample(u, dir, li, pdf, cover_all, rs);
  int facing = 0;
  for (const Light& portal : portals_) facing += portal_faces(portal, p);
  if (facing == 0) return world_sampled_ && env_.sample(u, dir, li, pdf, cover_all, rs);
  if (!sample_world_direction(p, u, dir, cover_all)) return false;
  // The mixture's pdf, as world_pdf (every facing portal the direction crosses counts).
  pdf = world_pdf(p, dir, cover_all);
  li = env_.eval(dir, rs);
  return pdf > 0.0f && std::isfinite(pdf);
}

bool Scene::sample_world_direction(Vec3 p, Vec2 u, Vec3& dir, bool cover_all) const {
  int facing = 0;
  for (const Light& portal : portals_) facing += portal_faces(portal, p);
  if (facing == 0) return world_sampled_ && env_.sample_direction(u, dir, cover_all);
  // A sky's sun disc keeps its share; the rest is split between the portals and the map
  // (Sampling Method None: the portals alone).
  const float sun = world_sampled_ ? env_.sun_fraction(cover_all) : 0.0f;
  const float a = (1.0f - sun) * (world_sampled_ && env_.cells_samplable(cover_all) ? 0.5f : 1.0f);  // the portals' share
  if (u.x < sun) {
    dir = env_.sample_sun_disc({std::min(u.x / sun, 0x1.fffffep-1f), u.y});
  } else if (u.x < sun + a) {
    // The portal by u.x, rescaled into its share (the sample stays stratified).
    const float ux = std::min((u.x - sun) / a, 0x1.fffffep-1f) * float(facing);
    const int pick = std::min(int(ux), facing - 1);
    size_t i = 0;
    for (int k = -1; i < portals_.size(); ++i)
      if (portal_faces(portals_[i], p) && ++k == pick) break;
    if (i == portals_.size()) return false;
    LightSample ls;
    if (!sample_light(portals_[i], p, {std::min(ux - float(pick), 0x1.fffffep-1f), u.y}, ls, solid_angle_rects_))
      return false;
    dir = ls.wi;
  } else {
    float map_pdf;
    if (!env_.sample_map({std::min((u.x - sun - a) / (1.0f - sun - a), 0x1.fffffep-1f), u.y}, dir, map_pdf, cover_all))
      return false;
  }
  return true;
}

float Scene::world_pdf(Vec3 p, Vec3 dir, bool cover_all) const {
  if (portals_.empty()) return env_.pdf(dir, cover_all);
  int facing;
  const double portal_pdf = portal_pdf_sum(p, dir, SIZE_MAX, facing);
  if (facing == 0) return world_sampled_ ? env_.pdf(dir, cover_all) : 0.0f;
  const float sun = world_sampled_ ? env_.sun_fraction(cover_all) : 0.0f;
  const bool map = world_sampled_ && env_.cells_samplable(cover_all);
  const float a = (1.0f - sun) * (map ? 0.5f : 1.0f);
  double pdf = double(a) * portal_pdf / facing;
  if (sun > 0.0f) pdf += double(sun) * env_.sun_disc_pdf(dir);
  if (map) pdf += double(1.0f - sun - a) * env_.map_pdf(dir, cover_all);
  return float(pdf);
}

}  // namespace pl
