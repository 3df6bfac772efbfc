// The path tracer's guided kernels (kKernelGuiding): a unit of their own, as the light tree's,
// so that the other kernels' code stays as it was.
#include "render/guide_photons.h"
#include "render/guiding.h"
#include "render/integrator.h"
#include "render/subsurface.h"
#include "scene/phase.h"

namespace pl {
namespace {
#include "render/trace_path.inl"
}  // namespace

constexpr uint32_t kG = kKernelGuiding, kE = kKernelEnvironment, kN = kKernelNonDiffuse, kT = kKernelLightTree;
// Diffuse-only scenes keep the diffuse kernels' direct lobe calls, guided too.
extern const uint32_t kGuidedKernels[4] = {kG | kE, kG | kE | kT, kG | kN | kE, kG | kN | kE | kT};

TraceFn guided_kernel(uint32_t f) {
  switch (f) {
    case kG | kE: return &trace_path_t<kG | kE>;
    case kG | kE | kT: return &trace_path_t<kG | kE | kT>;
    case kG | kN | kE: return &trace_path_t<kG | kN | kE>;
    case kG | kN | kE | kT: return &trace_path_t<kG | kN | kE | kT>;
    default: return &trace_path_t<kKernelAll>;
  }
}



// ---- Photon training (render/guide_photons.h) ----

GuidePhotonSources guide_photon_sources(const Scene& scene) {
  GuidePhotonSources src;
  const Aabb& b = scene.world_bounds();
  if (b.empty()) return src;
  src.center = (b.lo + b.hi) * 0.5f;
  src.radius = std::max(0.5f * length(b.extent()), 1e-4f);
  const float disk = kPi * src.radius * src.radius;
  std::vector<float> w;
  for (size_t k = 0; k < scene.light_count(); ++k) {
    const Light& l = scene.light(k);
    src.items.push_back(uint32_t(k));
    w.push_back(std::isfinite(luminance(l.color)) ? light_power(l, src.radius) : 0.0f);
  }
  const Environment& env = scene.environment();
  float world = 0.0f;
  if (env.valid()) {
    // Its power through the bounding disk by a fixed set of its own samples (the sun disc too).
    double sum = 0.0;
    const int n = 256;
    for (int i = 0; i < n; ++i) {
      Vec3 dir, li;
      float pdf;
      const Vec2 u{(float(i) + 0.5f) / float(n), float((uint32_t(i) * 2654435769u) >> 8) * 0x1p-24f};
      if (env.sample(u, dir, li, pdf, true) && pdf > 0.0f && is_finite(li)) sum += double(luminance(li)) / double(pdf);
    }
    world = float(sum / n) * disk;
  } else if (!is_black(scene.world_color())) {
    world = 4.0f * kPi * std::max(luminance(scene.world_color()), 0.0f) * disk;
  }
  if (world > 0.0f && std::isfinite(world)) {
    src.items.push_back(GuidePhotonSources::kWorld);
    w.push_back(world);
  }
  src.choice = Distribution1D(w);
  double total = 0.0;
  for (float x : w) total += std::isfinite(x) && x > 0.0f ? double(x) : 0.0;
  src.power = float(total);
  const size_t cells = size_t(GuidePhotonSources::kGrid) * size_t(GuidePhotonSources::kGrid);
  src.disk.resize(src.items.size());
  src.hits = std::make_unique<std::atomic<uint64_t>[]>(src.items.size() * cells);
  for (size_t i = 0; i < src.items.size() * cells; ++i) src.hits[i].store(0);
  return src;
}

void GuidePhotonSources::end_iteration() {
  const size_t cells = size_t(kGrid) * size_t(kGrid);
  for (size_t i = 0; i < items.size(); ++i) {
    double all = 0.0;
    for (size_t c = 0; c < cells; ++c) all += double(hits[i * cells + c].load());
    if (all > 0.0) {
      std::vector<float> w(cells);
      for (size_t c = 0; c < cells; ++c)
        w[c] = float((1.0 - kUniform) * double(hits[i * cells + c].load()) / all + kUniform / double(cells));
      disk[i] = Distribution1D(w);
    }  // (no records: the disk keeps what it had)
    for (size_t c = 0; c < cells; ++c) hits[i * cells + c].store(0);
  }
}

namespace {

Vec3 sample_uniform_sphere(Vec2 u) {
  const float z = 1.0f - 2.0f * u.x;
  const float r = std::sqrt(std::max(0.0f, 1.0f - z * z));
  const float phi = 2.0f * kPi * u.y;
  return {r * std::cos(phi), r * std::sin(phi), z};
}

// An emitted photon: where it starts, where it goes, and its flux over the sources' power.
bool emit_photon(const Scene& scene, const GuidePhotonSources& src, Pcg32& rng, Ray& ray, Vec3& flux, size_t& i,
                 int& cell) {
  cell = -1;
  const float u0 = rng.next_float();
  i = src.choice.sample(u0);
  const float pmf = src.choice.pmf(i);
  if (!(pmf > 0.0f)) return false;
  const Vec2 ua{rng.next_float(), rng.next_float()}, ub{rng.next_float(), rng.next_float()};
  const float norm = 1.0f / (pmf * src.power);
  // Distant light along -towards: from a disk across the scene's bounding sphere.
  const auto distant = [&](Vec3 towards, Vec3 power) {
    Vec3 t, b;
    make_basis(towards, t, b);
    constexpr int g = GuidePhotonSources::kGrid;
    float density = 1.0f;  // over the uniform one
    Vec2 sq = ub;
    if (!src.disk[i].empty()) {
      const size_t c = src.disk[i].sample(rng.next_float());
      density = src.disk[i].pmf(c) * float(g * g);
      sq = {std::min((float(c % g) + ub.x) / float(g), 0x1.fffffep-1f), std::min((float(c / g) + ub.y) / float(g), 0x1.fffffep-1f)};
    }
    cell = std::min(int(sq.x * g), g - 1) + g * std::min(int(sq.y * g), g - 1);
    const Vec2 d = sample_disk_concentric(sq);
    ray.org = src.center + (towards + t * d.x + b * d.y) * (src.radius * 1.001f);
    ray.dir = -towards;
    flux = power * (kPi * src.radius * src.radius * norm / density);
  };
  const uint32_t item = src.items[i];
  if (item == GuidePhotonSources::kWorld) {
    const Environment& env = scene.environment();
    if (env.valid()) {
      Vec3 dir, li;
      float pdf;
      if (!env.sample(ua, dir, li, pdf, true) || !(pdf > 0.0f)) return false;
      distant(dir, li / pdf);
    } else {
      const Vec3 dir = sample_uniform_sphere(ua);
      distant(dir, scene.world_color() * (4.0f * kPi));
    }
    return is_finite(flux) && !is_black(flux);
  }
  const Light& l = scene.light(item);
  switch (l.type) {
    case LightType::Point:
    case LightType::Spot: {
      ray.org = l.position;
      ray.dir = sample_uniform_sphere(ua);
      float att = 1.0f;
      if (l.type == LightType::Spot) att = spot_attenuation(l, ray.dir);
      flux = l.color * (4.0f * kPi * att * norm);
      break;
    }
    case LightType::Sun: {
      Vec3 dir = l.dir;
      if (l.cos_half_angle < 1.0f) {
        const float cos_t = 1.0f - ua.x * (1.0f - l.cos_half_angle);
        const float sin_t = std::sqrt(std::max(0.0f, 1.0f - cos_t * cos_t));
        const float phi = 2.0f * kPi * ua.y;
        Vec3 t, b;
        make_basis(l.dir, t, b);
        dir = normalize(t * (sin_t * std::cos(phi)) + b * (sin_t * std::sin(phi)) + l.dir * cos_t);
      }
      distant(dir, l.color);
      break;
    }
    case LightType::Rect:
    case LightType::Ellipse: {
      Vec2 o{ub.x - 0.5f, ub.y - 0.5f};
      if (l.type == LightType::Ellipse) {
        const Vec2 d = sample_disk_concentric(ub);
        o = {0.5f * d.x, 0.5f * d.y};
      }
      const Vec3 q = l.position + l.axis_u * o.x + l.axis_v * o.y;
      Vec3 t, b;
      make_basis(l.dir, t, b);
      const Vec3 c = sample_cosine_hemisphere(ua);
      ray.dir = normalize(t * c.x + b * c.y + l.dir * c.z);
      ray.org = q + l.dir * (1e-4f * std::sqrt(std::max(l.area, 1e-12f)));
      flux = l.color * (kPi * l.area * norm);
      break;
    }
  }
  return is_finite(ray.org) && is_finite(ray.dir) && is_finite(flux) && !is_black(flux);
}

// A lobe a guided vertex would sample (guidable()'s test for one closure).
bool rough_closure(const Closure& c) {
  if (std::holds_alternative<DiffuseBsdf>(c.bsdf) || std::holds_alternative<OrenNayarBsdf>(c.bsdf) ||
      std::holds_alternative<TranslucentBsdf>(c.bsdf) || std::holds_alternative<SheenBsdf>(c.bsdf) ||
      std::holds_alternative<VelvetBsdf>(c.bsdf))
    return true;
  const auto* m = std::get_if<ConductorBsdf>(&c.bsdf);
  return m && m->alpha > 0.075f && !c.delta;
}

}  // namespace

uint64_t trace_guide_photons(const Scene& scene, GuidePhotonSources& src, GuidingField& guide, uint64_t seed,
                             uint64_t first, uint64_t last, int max_bounces, bool caustics) {
  if (src.empty()) return 0;
  uint64_t rays = 0;
  std::vector<GuidingField::PhotonRecord> kept;
  ClosureList cl;
  RayState rs;
  rs.flags = uint8_t(kRayReflect | kRayDiffuse);  // not a camera ray
  for (uint64_t p = first; p < last; ++p) {
    Pcg32 rng(mix64(seed), p);
    Ray ray;
    Vec3 flux;
    size_t item;
    int cell;
    if (!emit_photon(scene, src, rng, ray, flux, item, cell)) continue;
    ray.tmax = kInf;
    uint64_t made = 0;  // records, credited to the photon's disk cell
    for (int bounce = 0; bounce <= max_bounces; ++bounce) {
      Hit hit;
      ++rays;
      if (!scene.intersect(ray, hit)) break;
      SurfacePoint sp;
      scene.surface_point(hit, sp, ray.time, &ray);
      if (sp.curve()) break;  // (hair lobes are not guided)
      const Vec3 wo = -ray.dir;  // towards where the light came from
      scene.shade(sp, hit.b1, hit.b2, wo, cl, rs);
      if (cl.n == 0) break;
      const bool front = dot(sp.ng, wo) > 0.0f;
      const Vec3 ng_out = front ? sp.ng : -sp.ng;
      if (caustics) {
        // Every bounce so far was smooth: at a guidable surface this is L S+ D light (or, at
        // the first hit, direct light, which light samples find), and the photon ends.
        if (guidable(cl)) {
          const float v = average(flux);
          if (bounce > 0 && v > 0.0f && std::isfinite(v) && is_finite(sp.p)) {
            kept.push_back({sp.p, GuidingField::to_square(wo), v, GuidingField::normal_class(ng_out)});
            ++made;
          }
          break;
        }
      } else if (bounce > 0 && guidable(cl)) {
        // After a bounce: light that the vertex's own light samples do not find.
        guide.record_photon(guide.cell_of(sp.p, ng_out), wo, average(flux));
        ++made;
      }
      if (bounce == max_bounces) break;
      // On, as the BSDF samples it: one closure by its pick, its sample's weight.
      float uc = rng.next_float(), acc = cl.c[0].pick;
      int k = 0;
      while (k + 1 < cl.n && uc >= acc) acc += cl.c[size_t(++k)].pick;
      const Closure& ch = cl.c[size_t(k)];
      if (std::holds_alternative<SubsurfaceBsdf>(ch.bsdf) || !(ch.pick > 0.0f)) break;
      if (caustics && rough_closure(ch)) break;  // (L S* D ... light: the camera's records learn it)
      BsdfSample bs;
      const Vec2 u{rng.next_float(), rng.next_float()};
      if (!bsdf_sample(ch.bsdf, ch.frame.to_local(wo), u, rng.next_float(), bs)) break;
      const Vec3 wi = ch.frame.to_world(bs.wi);
      const bool reflection = (bs.flags & kReflect) != 0;
      if ((dot(wi, ng_out) > 0.0f) != reflection) break;
      flux = flux * ch.weight * bs.weight / ch.pick;
      // A photon carries the adjoint: refraction's 1 / etap^2 (etap from the light's side), which
      // the camera paths' BSDF leaves out, as Cycles' (docs/materials.md "Refraction: no 1/eta^2,
      // as Cycles"): into glass the flux per solid angle thins, out of it it gathers.
      if ((bs.flags & kTransmit) && bs.eta != 1.0f) flux = flux / (bs.eta * bs.eta);
      // Russian roulette on the flux (photons start near 1).
      if (bounce >= 2) {
        const float survive = std::min(1.0f, max_component(flux));
        if (!(survive > 0.0f) || rng.next_float() >= survive) break;
        flux = flux / survive;
      }
      if (!is_finite(flux) || is_black(flux)) break;
      ray.org = offset_ray_origin(sp.p, sp.p_error, reflection ? ng_out : -ng_out);
      ray.self_curve = scene.self_curve(sp);
      ray.dir = wi;
      ray.tmax = kInf;
    }
    if (cell >= 0 && made > 0)
      src.hits[item * size_t(GuidePhotonSources::kGrid * GuidePhotonSources::kGrid) + size_t(cell)].fetch_add(
          made, std::memory_order_relaxed);
  }
  guide.keep_photons(kept);
  return rays;
}

}  // namespace pl
