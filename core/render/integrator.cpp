#include "render/integrator.h"

namespace pl {
namespace {

inline Vec2 next2(Pcg32& rng) {
  const float a = rng.next_float();
  return {a, rng.next_float()};
}

}  // namespace

Vec3 trace_path(const Scene& scene, Ray ray, Pcg32& rng, const IntegratorSettings& s, PathCounters& c) {
  Vec3 L(0.0f), beta(1.0f);
  float prev_pdf = 0.0f;  // solid-angle pdf of the BSDF sample that produced `ray`
  const bool nee = s.use_nee && scene.has_emitters();
  for (int bounce = 0;; ++bounce) {
    Hit hit;
    ++c.rays;
    if (!scene.intersect(ray, hit)) {
      L += beta * scene.world_color();
      break;
    }
    SurfacePoint sp;
    scene.surface_point(hit, sp);
    const Material& mat = scene.material(sp.material);
    const Vec3 wo = -ray.dir;

    // Emission found by the BSDF ray: weighted against the light sample that could have found it.
    if (!is_black(mat.emission)) {
      float w = 1.0f;
      if (nee && bounce > 0) {
        const float cos_l = std::fabs(dot(sp.ng, wo));
        const float pdf_light = scene.emitter_pdf_area(sp.prim) * hit.t * hit.t / cos_l;
        w = power_heuristic(prev_pdf, pdf_light);
      }
      L += beta * mat.emission * w;
    }
    // Without light sampling, the vertex past the limit only collects emission.
    if (bounce > s.max_bounces) break;

    // Surfaces are two-sided: shade the side the ray arrived from.
    if (dot(sp.ng, wo) < 0.0f) {
      sp.ng = -sp.ng;
      sp.ns = -sp.ns;
    }
    if (dot(sp.ns, sp.ng) <= 0.0f) sp.ns = sp.ng;
    const Frame frame = Frame::from_normal(sp.ns);
    const bool last = bounce == s.max_bounces;

    if (nee) {
      EmitterSample es;
      const float u_sel = rng.next_float();
      const Vec2 u_pt = next2(rng);
      if (scene.sample_emitter(u_sel, u_pt, es)) {
        Vec3 d = es.p - sp.p;
        const float dist2 = length_sq(d);
        const float dist = std::sqrt(dist2);
        const Vec3 wi = d / dist;
        const float cos_l = std::fabs(dot(es.n, wi));
        if (dist > 0.0f && cos_l > 0.0f && dot(sp.ng, wi) > 0.0f) {
          float bsdf_pdf;
          const Vec3 f = bsdf_eval(mat.bsdf, frame, wo, wi, bsdf_pdf);
          if (!is_black(f)) {
            const float pdf_light = es.pdf_area * dist2 / cos_l;
            // Offset both ends off their surfaces so neither triangle blocks the segment.
            const Vec3 o = offset_ray_origin(sp.p, sp.ng);
            const Vec3 target = offset_ray_origin(es.p, dot(es.n, wi) < 0.0f ? es.n : -es.n);
            Ray shadow;
            shadow.org = o;
            shadow.dir = target - o;
            shadow.tmax = 1.0f;
            ++c.rays;
            if (!scene.occluded(shadow)) {
              // At the last bounce no BSDF ray follows, so the light sample takes all the weight.
              const float w = last ? 1.0f : power_heuristic(pdf_light, bsdf_pdf);
              L += beta * f * es.radiance * (w / pdf_light);
            }
          }
        }
      }
      if (last) break;
    }

    BsdfSample bs;
    if (!bsdf_sample(mat.bsdf, frame, wo, next2(rng), bs)) break;
    // A direction below the geometric surface would leak light through it.
    if (dot(bs.wi, sp.ng) <= 0.0f) break;
    beta *= bs.weight;
    prev_pdf = bs.pdf;

    if (bounce + 1 >= s.rr_start_bounce) {
      const float survive = std::min(1.0f, max_component(beta));
      if (!(survive > 0.0f) || rng.next_float() >= survive) break;
      beta = beta / survive;
    }
    ray.org = offset_ray_origin(sp.p, sp.ng);
    ray.dir = bs.wi;
    ray.tmax = kInf;
  }
  return L;
}

}  // namespace pl
