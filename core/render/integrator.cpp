#include "render/integrator.h"

namespace pl {

Vec3 trace_path(const Scene& scene, Ray ray, Sampler& sampler, const IntegratorSettings& s, PathCounters& c) {
  Vec3 L(0.0f), beta(1.0f);
  float prev_pdf = 0.0f;  // solid-angle pdf of the BSDF sample that produced `ray`
  const bool nee = s.use_nee && scene.has_lights();
  int diffuse = 0;  // diffuse scattering events so far
  bool emission_only = false;
  for (int bounce = 0;; ++bounce) {
    Hit hit;
    ++c.rays;
    if (!scene.intersect(ray, hit)) {
      // Escaped: the world, weighted against the environment light sample that could find it.
      float w = 1.0f;
      if (nee && bounce > 0) w = power_heuristic(prev_pdf, scene.pdf_environment(ray.dir));
      L += beta * scene.background(ray.dir) * w;
      break;
    }
    SurfacePoint sp;
    scene.surface_point(hit, sp);
    const Material& mat = scene.material(sp.material);
    const Vec3 wo = -ray.dir;

    // Emission found by the BSDF ray: weighted against the light sample that could have found it.
    if (!is_black(mat.emission)) {
      float w = 1.0f;
      if (nee && bounce > 0) w = power_heuristic(prev_pdf, scene.pdf_emitter(sp.prim, hit.t, std::fabs(dot(sp.ng, wo))));
      L += beta * mat.emission * w;
    }
    // Without light sampling, the vertex past the limit only collects emission.
    if (emission_only) break;

    // Surfaces are two-sided: shade the side the ray arrived from.
    if (dot(sp.ng, wo) < 0.0f) {
      sp.ng = -sp.ng;
      sp.ns = -sp.ns;
    }
    if (dot(sp.ns, sp.ng) <= 0.0f) sp.ns = sp.ng;
    const Frame frame = Frame::from_normal(sp.ns);
    // The last vertex that scatters: no BSDF ray follows (all lobes are diffuse for now).
    const bool last = bounce >= s.max_bounces || diffuse >= s.diffuse_bounces;

    if (nee) {
      DirectSample ds;
      const float u_sel = sampler.get1d();
      const Vec2 u_pt = sampler.get2d();
      if (scene.sample_direct(sp.p, u_sel, u_pt, ds) && dot(sp.ng, ds.wi) > 0.0f) {
        float bsdf_pdf;
        const Vec3 f = bsdf_eval(mat.bsdf, frame, wo, ds.wi, bsdf_pdf);
        if (!is_black(f) && !is_black(ds.li)) {
          bool visible = true;
          if (ds.cast_shadow) {
            Ray shadow;
            shadow.org = offset_ray_origin(sp.p, sp.ng);
            if (std::isinf(ds.dist)) {
              shadow.dir = ds.wi;
              shadow.tmax = kInf;
            } else {
              // Offset the light end too, so an emissive triangle never blocks its own sample.
              const Vec3 target = is_black(ds.target_normal) ? ds.target : offset_ray_origin(ds.target, ds.target_normal);
              shadow.dir = target - shadow.org;
              shadow.tmax = is_black(ds.target_normal) ? 0.9999f : 1.0f;
            }
            ++c.rays;
            visible = !scene.occluded(shadow);
          }
          if (visible) {
            // Delta lights and the last vertex: the light sample is the only technique.
            const float w = (ds.delta || last) ? 1.0f : power_heuristic(ds.pdf, bsdf_pdf);
            L += beta * f * ds.li * (w / ds.pdf);  // for delta lights pdf is the choice probability
          }
        }
      }
    }
    if (last && nee) break;

    BsdfSample bs;
    if (!bsdf_sample(mat.bsdf, frame, wo, sampler.get2d(), bs)) break;
    // A direction below the geometric surface would leak light through it.
    if (dot(bs.wi, sp.ng) <= 0.0f) break;
    beta *= bs.weight;
    prev_pdf = bs.pdf;
    ++diffuse;
    emission_only = last;

    const float u_rr = sampler.get1d();
    if (bounce + 1 >= s.rr_start_bounce) {
      const float survive = std::min(1.0f, max_component(beta));
      if (!(survive > 0.0f) || u_rr >= survive) break;
      beta = beta / survive;
    }
    ray.org = offset_ray_origin(sp.p, sp.ng);
    ray.dir = bs.wi;
    ray.tmax = kInf;
  }
  return L;
}

}  // namespace pl
