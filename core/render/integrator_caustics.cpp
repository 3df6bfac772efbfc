// Caustic light tracing (integrator.h CausticLight; docs/design/sampling.md "Caustics by light
// tracing"): the path tracer's kernels with its MIS (kKernelCaustics), the light paths, and the
// caster sphere. A unit of its own, as the guided kernels', so the other kernels stay as they were.
#include "render/guiding.h"
#include "render/integrator.h"
#include "render/subsurface.h"
#include "scene/phase.h"

namespace pl {
namespace {
#include "render/trace_path.inl"
}  // namespace

TraceFn caustic_kernel(uint32_t needed, bool force_general, uint32_t& chosen) {
  constexpr uint32_t kFast = kKernelNonDiffuse | kKernelEnvironment | kKernelCaustics;
  constexpr uint32_t kGuided = kFast | kKernelGuiding;  // (with path guiding)
  if (!force_general && (needed & ~kFast) == 0) {
    chosen = kFast;
    return &trace_path_t<kFast>;
  }
  if (!force_general && (needed & ~kGuided) == 0) {
    chosen = kGuided;
    return &trace_path_t<kGuided>;
  }
  chosen = kKernelAll | kKernelCaustics;
  return &trace_path_t<kKernelAll | kKernelCaustics>;
}

bool caustic_casters(const Scene& scene, int probes, Vec3& center, float& radius, bool motion, bool* delta) {
  const Aabb& b = scene.world_bounds();
  if (delta) *delta = false;
  if (b.empty()) return false;
  std::vector<Vec3> found;
  ClosureList cl;
  RayState rs;
  rs.flags = uint8_t(kRayReflect | kRayGlossy);  // not a camera ray
  Pcg32 rng(0x5EEDCA05u, 7u);
  for (int i = 0; i < probes; ++i) {
    const Vec3 u{rng.next_float(), rng.next_float(), rng.next_float()};
    const float z = 1.0f - 2.0f * rng.next_float(), phi = 2.0f * kPi * rng.next_float();
    const float r = std::sqrt(std::max(0.0f, 1.0f - z * z));
    Ray ray;
    ray.org = b.lo + b.extent() * u;
    ray.dir = {r * std::cos(phi), r * std::sin(phi), z};
    ray.tmax = kInf;
    // Motion blur: times spread over the shutter, so the sphere holds the casters wherever they
    // move (a light path finds them at its own time). Still scenes keep their probes as before.
    if (motion) ray.time = (float(i) + 0.5f) / float(probes);
    Hit hit;
    if (!scene.intersect(ray, hit)) continue;
    SurfacePoint sp;
    scene.surface_point(hit, sp, motion ? ray.time : 0.0f, &ray);
    scene.shade(sp, hit.b1, hit.b2, -ray.dir, cl, rs);
    // (smooth glass and mirrors too: their chains are the light paths' since issue 25's delta vertices)
    if (caustic_vertex(sp, cl) && !guidable(cl) && (cl.has_nondelta || caustic_delta_closure(cl) >= 0) && is_finite(sp.p)) {
      found.push_back(sp.p);
      if (delta && caustic_delta_closure(cl) >= 0) *delta = true;
    }
  }
  if (found.empty()) return false;
  Aabb box;
  for (const Vec3& p : found) box.grow(p);
  center = (box.lo + box.hi) * 0.5f;
  float r2 = 0.0f;
  for (const Vec3& p : found) r2 = std::max(r2, length_sq(p - center));
  // A margin of 0.5 % of the scene's size: the probes see a shape's surface only in part
  // (what they miss is the path tracer's alone: both sides test the same sphere).
  radius = std::sqrt(r2) + 0.005f * length(b.extent()) + 1e-4f;
  return true;
}

namespace {
// A unit direction uniform in the cone about `axis` of solid angle 2 pi one_minus_cos: a lamp's
// light path towards the caster sphere.
Vec3 cone_direction(Vec3 axis, float one_minus_cos, Vec2 u) {
  const float cos_t = 1.0f - u.x * one_minus_cos;
  const float sin_t = std::sqrt(std::max(0.0f, 1.0f - cos_t * cos_t)), phi = 2.0f * kPi * u.y;
  Vec3 t, b;
  make_basis(axis, t, b);
  return normalize(axis * cos_t + (t * std::cos(phi) + b * std::sin(phi)) * sin_t);
}
}  // namespace

bool caustic_lamp(const Light& l, bool light_hits) {
  // With extent: the BSDF ray that finds it is a strategy of its own (Scene::hit_lights).
  if (light_has_extent(l) && !(light_hits && l.mis)) return false;
  constexpr uint8_t kSurfaces = kLightVisDiffuse | kLightVisGlossy | kLightVisTransmission;
  if (!l.cast_shadow || (l.visibility & kSurfaces) != kSurfaces) return false;
  if (l.light_mask != ~uint64_t(0) || l.shadow_mask != ~uint64_t(0)) return false;
  return !(l.type == LightType::Sun && l.shader);
}

float environment_peak_share(const Environment& env, float factor) {
  if (!env.valid()) return 0.0f;
  constexpr int kN = 64;
  std::vector<std::pair<float, double>> s;  // (luminance, luminance / pdf)
  s.reserve(kN * kN);
  double all = 0.0;
  for (int i = 0; i < kN; ++i)
    for (int j = 0; j < kN; ++j) {
      Vec3 dir, rad;
      float pdf = 0.0f;
      if (!env.sample({(float(i) + 0.5f) / kN, (float(j) + 0.5f) / kN}, dir, rad, pdf, true)) continue;
      const float lum = luminance(rad);
      if (!(pdf > 0.0f) || !(lum > 0.0f) || !std::isfinite(lum) || !std::isfinite(pdf)) continue;
      s.emplace_back(lum, double(lum) / double(pdf));
      all += s.back().second;
    }
  if (!(all > 0.0)) return 0.0f;
  // The mean radiance over the sphere: (1 / 4 pi) E[L / pdf] over all kN^2 draws.
  const double bright = double(factor) * all / (4.0 * double(kPi) * double(kN * kN));
  double peak = 0.0;
  for (const auto& [lum, w] : s)
    if (double(lum) > bright) peak += w;
  return float(peak / all);
}

uint64_t trace_caustic_paths(const Scene& scene, const CausticLight& cz, uint64_t seed, uint64_t first,
                             uint64_t last, int film_x, int film_y, int film_w, int film_h,
                             std::vector<CausticSplat>& out, std::vector<CausticVertex>* cache) {
  const Environment& env = scene.environment();
  if (!cz.camera || (cz.lamps.empty() && !(cz.env_pmf > 0.0f && env.valid()))) return 0;
  const bool tree = scene.light_tree_active();  // (its choice reads the shading normal)
  const Camera& cam = *cz.camera;
  const bool lens = cam.has_aperture();
  Camera::Frame frame = cam.still_frame();
  const float disk = kPi * cz.radius * cz.radius;
  const float half = 0.5f * std::sqrt(cz.filter_area);  // the box filter's half width
  // Clamping (CausticLight::clamp): a splat times the paths per sample is the light path's own
  // estimate of the pixel's sample, clamped as a camera path's contribution would be.
  const float splat_limit = cz.clamp > 0.0f ? cz.clamp / cz.paths : 0.0f;
  uint64_t rays = 0;
  ClosureList cl, cle;
  RayState rs;
  rs.flags = uint8_t(kRayReflect | kRayGlossy);
  for (uint64_t i = first; i < last; ++i) {
    Pcg32 rng(seed, i);
    // Motion blur: a shutter time as the camera rays draw theirs (the same density on both
    // sides, so it cancels in the MIS); the scene and the camera at that time. (Still scenes
    // draw nothing: their streams stay as they were.)
    float time = 0.0f;
    if (cz.motion) {
      time = cam.shutter().sample(rng.next_float());
      frame = cam.frame_at(time);
    }
    // The emitter (the environment alone draws nothing: its streams stay as they were).
    const CausticLamp* lamp = nullptr;
    if (cz.sources.size() > 1) {
      const size_t j = cz.sources.sample(rng.next_float());
      if (j > 0) lamp = &cz.lamps[j - 1];
    }
    // Its light group (the world's for the environment): the splats' and cached vertices'.
    const int group = lamp ? int(scene.light(lamp->light).light_group) : scene.world_light_group();
    Vec3 wl, beta;
    float ps;
    // A lamp with extent: its light sample's solid-angle density at the first hit towards the
    // start (the BSDF ray's rival there); 0: a delta start.
    float shape = 0.0f;
    bool area = false;  // an area lamp's start (area_start)
    Vec3 area_start(0.0f);
    Ray ray;
    ray.tmax = kInf;
    if (cz.motion) ray.time = time;
    // A light path from direction wl (the environment's, a sun's): from a point of the caster
    // sphere's disk across wl, outside the scene.
    const auto start_on_disk = [&](Vec2 u) {
      Vec3 t, b;
      make_basis(wl, t, b);
      const Vec2 d = sample_disk_concentric(u);
      ray.org = cz.center + (t * d.x + b * d.y) * cz.radius + wl * cz.far;
      ray.dir = -wl;
    };
    if (!lamp) {
      Vec3 li;
      float pdf;
      const Vec2 ue{rng.next_float(), rng.next_float()}, ud{rng.next_float(), rng.next_float()};
      if (!env.sample(ue, wl, li, pdf, true) || !(pdf > 0.0f)) continue;
      li = scene.background(wl);  // (what the path tracer's escaped rays find)
      if (is_black(li) || !is_finite(li)) continue;
      start_on_disk(ud);
      beta = li * (disk / (pdf * cz.env_pmf));
      ps = cz.env_pmf * pdf / disk;
    } else {
      const Light& l = scene.light(lamp->light);
      const Vec2 ud{rng.next_float(), rng.next_float()};
      if (l.type == LightType::Sun && lamp->extent) {
        // A direction in the sun's cone as its own light sample draws it, then across the
        // caster sphere's disk as the environment's.
        LightSample ls;
        const Vec2 uc{rng.next_float(), rng.next_float()};
        if (!sample_light(l, cz.center, uc, ls) || ls.delta || !(ls.pdf > 0.0f)) continue;
        wl = ls.wi;
        start_on_disk(ud);
        beta = ls.li * (disk / (lamp->pmf * ls.pdf));
        ps = lamp->pmf * ls.pdf / disk;
        shape = ls.pdf;
      } else if (is_area_light(l)) {
        // An area lamp: a point on it by area (as its light samples by area draw it), a
        // direction uniform in the cone the caster sphere subtends from there (one-sided:
        // those behind it give nothing), its spread along that direction.
        Vec2 o{ud.x - 0.5f, ud.y - 0.5f};
        if (l.type == LightType::Ellipse) {
          const Vec2 dsk = sample_disk_concentric(ud);
          o = {0.5f * dsk.x, 0.5f * dsk.y};
        }
        area_start = l.position + l.axis_u * o.x + l.axis_v * o.y;
        const Vec2 uc{rng.next_float(), rng.next_float()};
        const float omc = caustic_cone_from(cz, area_start);
        Vec3 axis = cz.center - area_start;
        axis = length_sq(axis) > 0.0f ? normalize(axis) : l.dir;
        ray.dir = cone_direction(axis, omc, uc);
        ray.org = area_start;
        wl = -ray.dir;
        const float cos0 = dot(ray.dir, l.dir);
        if (!(cos0 > 0.0f)) continue;
        Vec3 le = l.color;
        if (!apply_spread(l, wl, cos0, le)) continue;
        const float pc = caustic_cone_pdf(lamp->pmf, omc);
        beta = le * (cos0 * l.area / pc);
        ps = pc / (l.area * cos0);
        area = true;
      } else if (l.type == LightType::Sun) {
        // A delta direction: across the caster sphere's disk, as the environment's.
        wl = l.dir;
        start_on_disk(ud);
        beta = l.color * (disk / lamp->pmf);
        ps = lamp->pmf / disk;
      } else {
        // A point or spot: uniform in the cone the caster sphere subtends (or every direction
        // from inside it); ps is per unit solid angle until the first hit's distance is known.
        ray.dir = cone_direction(lamp->axis, lamp->one_minus_cos, ud);
        ray.org = l.position;
        wl = -ray.dir;
        float att = 1.0f;
        // (with extent, the lamp's own sample at the first hit applies the cone, below)
        if (l.type == LightType::Spot && !lamp->extent) att = spot_attenuation(l, ray.dir);  // as its light samples
        if (!(att > 0.0f)) continue;
        ps = caustic_cone_pdf(lamp->pmf, lamp->one_minus_cos);
        beta = l.color * (att / ps);
      }
    }
    // The heuristic's products over the smooth vertices (q_rev and q_fwd), and Pb / Pa at the
    // first one (the path tracer's light sample of the world there).
    double prod_r = 1.0, prod_f = 1.0;
    float eb = 0.0f;
    int k = 0;  // smooth vertices so far
    for (;;) {
      Hit hit;
      ++rays;
      if (!scene.intersect(ray, hit)) break;
      SurfacePoint sp;
      scene.surface_point(hit, sp, time, &ray);
      Vec3 wo_l = -ray.dir;  // towards the light
      const ClosureList* cs = &cl;  // the closures this vertex samples from
      if (k == 0) {
        if (!(length_sq(sp.p - cz.center) <= cz.radius * cz.radius)) break;
        if (lamp && lamp->extent && !area && scene.light(lamp->light).type != LightType::Sun) {
          // A point or spot with extent: the ray from its centre found x; the start is the
          // lamp's own light sample from x (the soft disk facing x, or the sphere's cone, with
          // the spot's cone, IES profile and node tree along that sample), seen from x through
          // a shadow ray as the path tracer's. The path (start, x) then has the density
          // ps / d_c^2 (x, per unit area with its cosine to the centre left out) times the
          // sample's solid-angle density at x, whose ratio to the path tracer's light sample
          // is its choice alone; the path tracer tests that the centre sees x
          // (trace_path.inl's caustic_lamp_centre).
          const Light& l = scene.light(lamp->light);
          const float cos_c = std::fabs(dot(sp.ng, ray.dir)), dc2 = length_sq(sp.p - l.position);
          LightSample ls;
          const Vec2 ul{rng.next_float(), rng.next_float()};
          if (!(cos_c > 0.0f) || !(dc2 > 0.0f) ||
              !sample_light(l, sp.p, ul, ls, scene.solid_angle_rect_sampling()) || is_black(ls.li))
            break;
          const float cos_s = std::fabs(dot(sp.ng, ls.wi));
          if (!(cos_s > 0.0f)) break;
          Ray sh;
          sh.org = offset_ray_origin(sp.p, sp.p_error, dot(sp.ng, ls.wi) > 0.0f ? sp.ng : -sp.ng);
          sh.dir = ls.target - sh.org;
          sh.tmax = 1.0f - 1e-4f;
          sh.time = ray.time;
          ++rays;
          const Vec3 vis = l.cast_shadow ? scene.transmittance(sh, rs.shadow_hits()) : Vec3(1.0f);
          if (is_black(vis)) break;
          shape = ls.delta ? 0.0f : ls.pdf;
          wo_l = ls.wi;
          beta = ls.li * vis * (dc2 / (ps * (ls.delta ? 1.0f : ls.pdf)) * cos_s / cos_c);
          // (its heuristic density with the cosine towards the centre over the start's, as the
          // path tracer's caustic_lamp_centre)
          ps = ps / dc2 * (ls.delta ? 1.0f : ls.pdf) * (cos_c / cos_s);
          if (!is_finite(beta) || !std::isfinite(ps) || !(ps > 0.0f)) break;
        } else if (area) {
          // Its profile and node tree towards this point, as its light sample from here sees
          // them; and the lamp's own sample density from here towards the start (Pb's, 0 where
          // its sample cannot draw it: then no strategy of the path tracer's makes this path,
          // and it is left out).
          const Light& l = scene.light(lamp->light);
          const float dist = length(sp.p - area_start);
          if ((l.ies || l.shader) && !apply_light_factors(l, area_start, wo_l, dist, beta)) break;
          float th, pdf;
          Vec3 le;
          if (!intersect_light(l, sp.p, sp.p, wo_l, kInf, th, le, pdf, scene.solid_angle_rect_sampling()) ||
              !(pdf > 0.0f))
            break;
          shape = pdf;
        } else if (lamp && scene.light(lamp->light).type != LightType::Sun) {
          // A point or spot: its profile and node tree towards this point, as its light sample
          // from here sees them, and the density per unit area here.
          const Light& l = scene.light(lamp->light);
          const float d2 = length_sq(sp.p - l.position);
          if ((l.ies || l.shader) && !apply_light_factors(l, l.position, wo_l, std::sqrt(d2), beta)) break;
          ps /= d2;
        }
        scene.shade(sp, hit.b1, hit.b2, wo_l, cl, rs);
        // (a surface whose closures' kinds and roughness do not depend on the view: rough
        // from here too, so no path of the class starts at it)
        if (!caustic_vertex(sp, cl) || guidable(cl)) break;
      } else {
        float rx, ry, dist, ppdf;
        // A thin lens: a point on the aperture as the camera's rays draw it (sample_aperture),
        // and the film position of the camera ray from there through this point (pbrt-v4's
        // PerspectiveCamera::SampleWi). Its density cancels in the MIS: both strategies draw the
        // lens point alike. An orthographic camera's ppdf / dist^2 is its pixel density per
        // unit area across its parallel rays (Camera::lens_view), so the formulas below hold
        // for it too. (A pinhole draws nothing: its streams stay as they were.)
        // A panorama (pinhole): the raster position of the direction by its inverse map and
        // its pixel density per unit solid angle there (Camera::pano_view). Motion blur: the
        // camera's frame at the path's time.
        Vec3 eye = frame.origin;
        Vec2 ua{0.5f, 0.5f};
        if (lens) ua = {rng.next_float(), rng.next_float()};
        const bool seen = cam.lens_view(frame, sp.p, ua, eye, rx, ry, dist, ppdf);
        const Vec3 wc = seen ? (eye - sp.p) / dist : wo_l;
        if (seen) {
          // Shaded as the camera ray that found it (its state and footprint).
          RayState rc;
          rc.camera = &cam;
          if (cz.differentials) cam.differentials(-wc, rc.dp, rc.dd);
          rc.length = dist * (1.0f - cam.near_fraction(frame, sp.p, eye));
          scene.shade(sp, hit.b1, hit.b2, wc, cl, rc);
        } else {
          scene.shade(sp, hit.b1, hit.b2, wc, cl, rs);
        }
        if (!caustic_vertex(sp, cl)) break;
        if (guidable(cl)) {
          // The rough vertex: the camera's first, seen directly (nothing in between).
          if (k + 1 > cz.max_vertices) break;
          // Light-vertex connections: kept whether the camera sees it or not; a camera path's
          // rough vertex shades it again from its own side (trace_path.inl).
          if (cache && is_finite(beta) && !is_black(beta)) {
            const double lr = double(ps) * prod_r / prod_f;
            if (std::isfinite(lr) && lr > 0.0) cache->push_back({sp, wo_l, beta, float(lr), eb, k + 1, group});
          }
          if (!seen) break;
          const float cos_c = dot(sp.ng, wc), cos_l = dot(sp.ng, wo_l);
          const bool reflection = (cos_c > 0.0f) == (cos_l > 0.0f);
          float qf1;
          const Vec3 f1 = eval_mixture(cl, wc, wo_l, reflection, qf1);
          if (is_black(f1) || !(qf1 > 0.0f) || cos_c == 0.0f || cos_l == 0.0f) break;
          if (cz.guide && cz.guide->ready()) {
            // A guided camera path drew wo_l here from the mixture (trace_path.inl's guided_pdf,
            // at the cell of this point facing the camera): its density is the one to compare.
            const GuidingField& g = *cz.guide;
            const Vec3 ng_c = cos_c > 0.0f ? sp.ng : -sp.ng;
            const uint32_t cell = g.cell_of(sp.p, ng_c);
            const float gp = cz.guide_learn_probability ? g.probability(cell) : cz.guide_probability;
            const int32_t cc = cz.guide_caustic_probability > 0.0f ? g.caustic_cell(sp.p, ng_c) : -1;
            qf1 = guided_mixture_pdf(g, qf1, wo_l, gp, cell, -1.0f, cc, cz.guide_caustic_probability);
            if (!(qf1 > 0.0f)) break;
          }
          Ray sh;
          sh.org = offset_ray_origin(sp.p, sp.p_error, cos_c > 0.0f ? sp.ng : -sp.ng);
          const Vec3 near = eye + (sp.p - eye) * cam.near_fraction(frame, sp.p, eye);
          sh.dir = near - sh.org;
          sh.tmax = 1.0f - 1e-4f;
          sh.time = ray.time;
          ++rays;
          if (scene.occluded(sh)) break;
          // The power heuristic's weight of the light path, rho = n Pc / Pa (Pb / Pa = eb).
          const auto light_weight = [eb](double rho) {
            const double rho2 = rho * rho;
            return float(rho2 / (1.0 + double(eb) * eb + rho2));
          };
          if (cz.filter) {
            // Any other filter: pixel j's camera sample lands at p with the filter's density
            // f(p - c_j) (separable: fx fy), so j's measurement importance at p, and the path
            // tracer's camera pdf there, are p_cam_j = f(p - c_j) ppdf (solid angle). Its MIS
            // weight is then per pixel: the path tracer of pixel j weighs the same path with
            // rho_j = n ps d^2 prod_r / (p_cam_j qf1 prod_f) (trace_path.inl's cz_ratio with this
            // sample's density), so for each pixel the weights still sum to 1 (pbrt-v4's and
            // Mitsuba's splat, with the MIS per pixel). The box below is the same with f = 1 / area.
            const PixelFilter& pf = *cz.filter;
            const float fr = pf.radius();
            const Vec3 base = beta * f1 * (std::fabs(cos_c) / std::fabs(cos_l) / (dist * dist) / cz.paths);
            const double rho_f = double(cz.paths) * ps * double(dist) * dist * prod_r / (double(ppdf) * qf1 * prod_f);
            if (!is_finite(base) || is_black(base) || !std::isfinite(rho_f)) break;
            const int x0 = int(std::floor(rx - 0.5f - fr)), x1 = int(std::ceil(rx - 0.5f + fr));
            const int y0 = int(std::floor(ry - 0.5f - fr)), y1 = int(std::ceil(ry - 0.5f + fr));
            for (int y = std::max(y0, film_y); y <= std::min(y1, film_y + film_h - 1); ++y) {
              const float fy = pf.density(ry - (float(y) + 0.5f));
              if (!(fy > 0.0f)) continue;
              for (int x = std::max(x0, film_x); x <= std::min(x1, film_x + film_w - 1); ++x) {
                const float f = pf.density(rx - (float(x) + 0.5f)) * fy;
                if (!(f > 0.0f)) continue;
                const float w = light_weight(rho_f / f);
                const Vec3 v = clamp_light(base * (ppdf * f * w), splat_limit);
                if (is_finite(v) && !is_black(v))
                  out.push_back({uint32_t(y - film_y) * uint32_t(film_w) + uint32_t(x - film_x), v, group});
              }
            }
            break;
          }
          const float p_cam = ppdf / cz.filter_area;
          const float w = light_weight(double(cz.paths) * ps * double(dist) * dist * prod_r / (double(p_cam) * qf1 * prod_f));
          const Vec3 v = clamp_light(beta * f1 * (std::fabs(cos_c) / std::fabs(cos_l) * p_cam / (dist * dist) * w / cz.paths),
                                     splat_limit);
          if (!is_finite(v) || is_black(v)) break;
          // Every pixel whose box holds the point.
          const int x0 = int(std::ceil(rx - 0.5f - half)), x1 = int(std::ceil(rx - 0.5f + half)) - 1;
          const int y0 = int(std::ceil(ry - 0.5f - half)), y1 = int(std::ceil(ry - 0.5f + half)) - 1;
          for (int y = std::max(y0, film_y); y <= std::min(y1, film_y + film_h - 1); ++y)
            for (int x = std::max(x0, film_x); x <= std::min(x1, film_x + film_w - 1); ++x)
              out.push_back({uint32_t(y - film_y) * uint32_t(film_w) + uint32_t(x - film_x), v, group});
          break;
        }
        if (k + 2 > cz.max_vertices) break;  // (no room for this smooth vertex and a rough one)
      }
      // A smooth vertex: on towards the camera's side by one of its closures.
      const bool front = dot(sp.ng, wo_l) > 0.0f;
      const Vec3 ng_out = front ? sp.ng : -sp.ng;
      // On to the next vertex along wi (reflected or transmitted here).
      const auto advance = [&](Vec3 wi, bool reflection) {
        ++k;
        ray.org = offset_ray_origin(sp.p, sp.p_error, reflection ? ng_out : -ng_out);
        ray.self_curve = scene.self_curve(sp);
        ray.dir = wi;
        ray.tmax = kInf;
      };
      float uc = rng.next_float(), acc = cs->c[0].pick;
      int c = 0;
      while (c + 1 < cs->n && uc >= acc) acc += cs->c[size_t(++c)].pick;
      const Closure& ch = cs->c[size_t(c)];
      if (std::holds_alternative<SubsurfaceBsdf>(ch.bsdf) || std::holds_alternative<PortalBsdf>(ch.bsdf)) break;
      if (ch.delta) {
        // Smooth glass or a mirror (docs/design/sampling.md, "Caustic light paths through glass
        // and mirrors"). Next to a delta lamp the path tracer cannot make the path (no light
        // sample passes a delta vertex, no BSDF ray finds the lamp): left out, as before.
        if (k == 0 && lamp && !(shape > 0.0f)) break;
        if (caustic_delta_closure(*cs) != c) break;
        // Past the first vertex the closures were shaded towards the camera where it sees the
        // point (for the choice above): a delta lobe needs them shaded from wo_l, whose view
        // lifts the normal (valid_specular_normal) as the light's arrival does.
        Closure lc = ch;
        if (k > 0) {
          scene.shade(sp, hit.b1, hit.b2, wo_l, cle, rs);
          const int dl = caustic_delta_closure(cle);
          if (dl < 0) break;
          lc = cle.c[size_t(dl)];
        }
        BsdfSample bs;
        const Vec2 u{rng.next_float(), rng.next_float()};
        if (!bsdf_sample(lc.bsdf, lc.frame.to_local(wo_l), u, rng.next_float(), bs) || !(bs.flags & kDelta) ||
            !(bs.pdf > 0.0f))
          break;
        const Vec3 wi = lc.frame.to_world(bs.wi);
        const bool reflection = (bs.flags & kReflect) != 0;
        if ((dot(wi, ng_out) > 0.0f) != reflection) break;
        // (a normal that either side's view would lift: the two sides' mirrors differ there)
        if (!caustic_unbent(sp.ng, lc.frame.n, wo_l) || !caustic_unbent(sp.ng, lc.frame.n, wi)) break;
        // The path tracer's closures here, from the camera's side: its one delta closure's lobe
        // from wi must lead back along wo_l (the same closure), and gives the value and both
        // choices; its pick cancels in the heuristic's ratio.
        scene.shade(sp, hit.b1, hit.b2, wi, cle, rs);
        if (!caustic_vertex(sp, cle) || guidable(cle)) break;
        const int dc = caustic_delta_closure(cle);
        if (dc < 0) break;
        const Closure& cd = cle.c[size_t(dc)];
        const Vec3 wi_c = cd.frame.to_local(wi), wl_c = cd.frame.to_local(wo_l);
        Vec3 vf, vr, of, orv;
        float pf, pr, ef, er;
        if (!caustic_delta_lobe(cd.bsdf, wi_c, !reflection, vf, pf, ef, of) ||
            !caustic_delta_lobe(cd.bsdf, wl_c, !reflection, vr, pr, er, orv) || !(pf > 0.0f) || !(pr > 0.0f) ||
            !(dot(of, wl_c) > 0.9999f))
          break;
        // The light path's throughput: the path tracer's value (f |cos| over its delta: the
        // lobe's colour, no 1 / etap^2, as Cycles') over this sample's choice, times the delta's
        // Jacobian between the two sides' solid angles (etap^2 and the shading cosines) and the
        // geometric normal's adjoint cosines. So importance takes the etap^2 that radiance does
        // not (the adjoint of a BSDF without the 1 / etap^2 has it): into water from the air
        // (etap = 1 / 1.33) the light path keeps 1 / 1.33^2, out of glass 1.5^2, and through a
        // closed object the two cancel (docs/materials.md "Refraction: no 1/eta^2, as Cycles").
        const float cs_l = std::fabs(wl_c.z), cs_c = std::fabs(wi_c.z);
        const float cg_l = std::fabs(dot(sp.ng, wo_l)), cg_c = std::fabs(dot(sp.ng, wi));
        if (!(cs_c > 0.0f) || !(cg_l > 0.0f)) break;
        beta *= cd.weight * vf * (ef * ef * cs_l * cg_c / (cs_c * cg_l * ch.pick * bs.pdf));
        // The heuristic: the reverse choice over the forward one and etap^2 (trace_path.inl's
        // cz_ratio at a delta lobe: the same numbers from the other side). No light sample here.
        prod_r *= pr;
        prod_f *= double(pf) * ef * ef;
        if (!is_finite(beta) || is_black(beta)) break;
        advance(wi, reflection);
        continue;
      }
      BsdfSample bs;
      const Vec2 u{rng.next_float(), rng.next_float()};
      if (!bsdf_sample(ch.bsdf, ch.frame.to_local(wo_l), u, rng.next_float(), bs) || (bs.flags & kDelta)) break;
      const Vec3 wi = ch.frame.to_world(bs.wi);
      const bool reflection = (bs.flags & kReflect) != 0;
      if ((dot(wi, ng_out) > 0.0f) != reflection) break;
      float p_true;
      eval_mixture(*cs, wo_l, wi, reflection, p_true);
      if (!(p_true > 0.0f)) break;
      // The path tracer's closures here (shaded from the camera's side) give the value and
      // the heuristic's pdfs, as there.
      scene.shade(sp, hit.b1, hit.b2, wi, cle, rs);
      if (!caustic_vertex(sp, cle) || guidable(cle)) break;
      float qf, qr;
      const Vec3 f = eval_mixture(cle, wi, wo_l, reflection, qf);
      eval_mixture(cle, wo_l, wi, reflection, qr);
      if (is_black(f) || !(qf > 0.0f) || !(qr > 0.0f)) break;
      if (k == 0 && lamp) {
        // A delta lamp: the path tracer makes this path only by its light sample here, so that
        // sample's choice stands in for the BSDF's density towards the light (and eb is 0).
        // With extent, as the environment: the BSDF's density, and eb its light sample's (the
        // choice times the lamp's own density towards the start) over it.
        const float sel = scene.pick_light_pmf(sp.p, tree ? sp.ns : Vec3(0.0f), lamp->light);
        if (!(sel > 0.0f)) break;
        if (shape > 0.0f) {
          eb = sel * shape / qf;
          prod_f *= qf;
        } else {
          prod_f *= sel;
        }
      } else {
        if (k == 0 && cz.nee) eb = scene.pdf_environment(wl, sp.p) / qf;
        prod_f *= qf;
      }
      beta *= f * (std::fabs(dot(sp.ng, wi)) / std::fabs(dot(sp.ng, wo_l)) / p_true);
      prod_r *= qr;
      if (!is_finite(beta) || is_black(beta)) break;
      advance(wi, reflection);
    }
  }
  return rays;
}

}  // namespace pl
