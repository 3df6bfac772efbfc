// The path tracer's body, a template over its kernel features, shared by integrator.cpp and
// integrator_tree.cpp (the light tree's kernels: in a unit of their own, the other kernels
// keep the inlining they had; one big unit made GCC stop inlining their helpers).
// Included into an anonymous namespace of each; not a public header.


// Sum of all non-delta closures: f * |cos| and the mixture pdf, counting only lobes on the side
// (reflection or transmission) that the geometric normal allows, so that shading normals never
// let light through a surface or reflect it from behind. kDiffuseOnly (diffuse-only kernels):
// every closure is a DiffuseBsdf, whose eval is called directly rather than through the
// variant's dispatch (the same arithmetic, so the same result).
// `skip`: a closure left out (one whose sample carries its own value, Huang's hair).
template <bool kDiffuseOnly = false>
[[gnu::always_inline]] inline Vec3 eval_mixture(const ClosureList& cl, Vec3 wo, Vec3 wi, bool reflection, float& pdf,
                                                const Closure* skip = nullptr) {
  Vec3 f(0.0f);
  pdf = 0.0f;
  for (int i = 0; i < cl.n; ++i) {
    const Closure& c = cl.c[size_t(i)];
    if (!kDiffuseOnly && (c.delta || &c == skip)) continue;
    const Vec3 lo = c.frame.to_local(wo), li = c.frame.to_local(wi);
    float p;
    Vec3 v;
    // Diffuse lobes reflect only, from the side their eval picks (a bent one's may face away
    // from the view); the others' side must agree with the geometric one.
    if constexpr (kDiffuseOnly) {
      // Only diffuse-only scenes get here; anything else (unreachable) would add nothing.
      const DiffuseBsdf* d = std::get_if<DiffuseBsdf>(&c.bsdf);
      if (!d || !reflection) continue;
      v = d->eval(lo, li, p);
    } else if (const DiffuseBsdf* d = std::get_if<DiffuseBsdf>(&c.bsdf)) {
      if (!reflection) continue;
      v = d->eval(lo, li, p);  // the common lobe without the variant's out-of-line visit
    } else {
      // Hair lobes span the whole sphere (their frame's z is no surface normal); Cycles' Hair
      // BSDF tests its normal's side itself; rough diffuse reflects from its own side, as plain
      // diffuse (the view may be below its normal at a smooth silhouette).
      if (same_side(lo, li) != reflection && !std::holds_alternative<HairChiangBsdf>(c.bsdf) &&
          !std::holds_alternative<HairHuangBsdf>(c.bsdf) && !std::holds_alternative<HairBsdf>(c.bsdf) && !(reflection && (std::holds_alternative<OrenNayarBsdf>(c.bsdf) || std::holds_alternative<SheenBsdf>(c.bsdf))))
        continue;
      v = bsdf_eval(c.bsdf, lo, li, p);
    }
    f += c.weight * v;
    pdf += c.pick * p;
  }
  return f;
}

// The media a path is inside, innermost last (nested glass, volumes in volumes): each layer is
// a material's homogeneous medium, or (het) a heterogeneous one tracked through its majorants.
// lobes: a homogeneous medium's several phase functions (n_lobes >= 2), else phase alone.
struct MediumLayer {
  Vec3 sigma_a, sigma_s, emission;
  Phase phase;
  uint32_t material;
  const HeteroMedium* het;
  const PhaseLobe* lobes;
  int n_lobes;
  // The layer's instance (light linking: scattering uses the innermost one's light set, as
  // Cycles' volume shading object); UINT32_MAX: the world's.
  uint32_t instance;
};
constexpr uint32_t kWorldMedium = 0xFFFFFFFFu;  // the world's Volume: never left

// One of n scatterers at a point (ss: each one's sigma_s; beta carries their sum): picks k with
// probability P_k = mean(ss_k) / sum_j mean(ss_j), weights `beta` by ss_k / (sum_j ss_j P_k) per
// channel, and rescales u for a further choice. The expectation is, per channel, their phase
// functions weighted by their scattering in that channel (Cycles 4.5 weights them by channel
// means instead: docs/design/volumes.md). -1: nothing scatters.
inline int choose_scatterer(int n, const Vec3* ss, float& u, Vec3& beta) {
  float w[kMaxPhaseLobes > 4 ? kMaxPhaseLobes : 4], total = 0.0f;
  for (int i = 0; i < n; ++i) total += (w[i] = average(ss[i]));
  if (!(total > 0.0f)) return -1;
  int k = n - 1;
  float acc = 0.0f;
  for (int i = 0; i < n; ++i) {
    acc += w[i];
    if (u * total < acc && w[i] > 0.0f) {
      k = i;
      break;
    }
  }
  while (k > 0 && !(w[k] > 0.0f)) --k;  // (u rounding past the last non-empty one)
  float before = 0.0f;
  for (int i = 0; i < k; ++i) before += w[i];
  u = std::clamp((u * total - before) / w[k], 0.0f, 1.0f - 1e-7f);
  Vec3 all(0.0f);
  for (int i = 0; i < n; ++i) all += ss[i];
  const float inv_p = total / w[k];
  const auto share = [&](float a, float b) { return b > 0.0f ? a / b * inv_p : 0.0f; };
  beta *= Vec3(share(ss[k].x, all.x), share(ss[k].y, all.y), share(ss[k].z, all.z));
  return k;
}
// A phase among lobes (their sigma_s sum to the scattering that beta carries), as above.
inline Phase choose_lobe(int n, const PhaseLobe* lobes, float u, Vec3& beta) {
  Vec3 ss[kMaxPhaseLobes];
  for (int i = 0; i < n; ++i) ss[i] = lobes[i].sigma_s;
  const int k = choose_scatterer(n, ss, u, beta);
  return k < 0 ? lobes[0].phase : lobes[k].phase;
}
// Overlapping layers that scatter at a point (ss: each one's sigma_s, phase: its phase or, with
// n_lobes[i] >= 2, lobes[i] its several): a layer as choose_scatterer, then one of its lobes.
inline Phase choose_layer_phase(int n, const Vec3* ss, const Phase* phase, const PhaseLobe* const* lobes,
                                const int* n_lobes, float u, Vec3& beta) {
  const int k = choose_scatterer(n, ss, u, beta);
  if (k < 0) return Phase{};
  if (n_lobes[k] >= 2) return choose_lobe(n_lobes[k], lobes[k], u, beta);
  return phase[k];
}

struct Medium {
  MediumLayer layer[4];
  int n = 0;
  uint32_t inner_instance() const { return n ? layer[n - 1].instance : UINT32_MAX; }
  // What a point inside all the layers sees. Cycles' volume stack sums every volume the path is
  // in (overlapping objects, a volume inside the world's fog, absorbing glass in fog), so
  // homogeneous layers add up: coefficients and emission summed, the phase their common one
  // (else a scattering picks a layer per channel, phases_differ). A stack
  // holding a heterogeneous layer is `mixed`: sum then holds its homogeneous layers' sum, its
  // het the innermost heterogeneous layer, and the tracking sums every layer per point
  // (MediumStack below).
  MediumLayer sum{};
  bool mixed = false;
  // Homogeneous layers that scatter with different phase functions, or one with several
  // (lobes): sum.phase is then not the mixture's phase per channel; choose_phase picks one.
  bool phases_differ = false;
  const MediumLayer* top() const { return n ? (n == 1 ? &layer[0] : &sum) : nullptr; }
  Vec3 current() const { return n ? top()->sigma_a : Vec3(0.0f); }  // Beer's law only
  void combine() {
    mixed = false;
    phases_differ = n == 1 && !layer[0].het && layer[0].n_lobes >= 2;
    if (n < 2) return;
    const HeteroMedium* het = nullptr;
    for (int i = 0; i < n; ++i) het = layer[i].het ? layer[i].het : het;
    sum = layer[n - 1];
    sum.sigma_a = sum.sigma_s = sum.emission = Vec3(0.0f);
    sum.lobes = nullptr;
    sum.n_lobes = 0;
    for (int i = 0; i < n; ++i) {
      if (layer[i].het) continue;
      sum.sigma_a += layer[i].sigma_a;
      sum.sigma_s += layer[i].sigma_s;
      sum.emission += layer[i].emission;
      if (!is_black(layer[i].sigma_s)) sum.phase = layer[i].phase;
    }
    sum.het = het;
    mixed = het != nullptr;
    for (int i = 0; i < n && !mixed; ++i) {
      const bool si = !is_black(layer[i].sigma_s);
      phases_differ = phases_differ || (si && layer[i].n_lobes >= 2);
      for (int j = 0; j < i; ++j)
        phases_differ = phases_differ || (layer[i].phase != layer[j].phase && si && !is_black(layer[j].sigma_s));
    }
  }
  // A homogeneous stack's scattering at a point (phases_differ): choose_layer_phase over its layers.
  Phase choose_phase(float u, Vec3& beta) const {
    Vec3 ss[4];
    Phase ph[4];
    const PhaseLobe* lobes[4];
    int nl[4];
    for (int i = 0; i < n; ++i) {
      ss[i] = layer[i].sigma_s;
      ph[i] = layer[i].phase;
      lobes[i] = layer[i].lobes;
      nl[i] = layer[i].n_lobes;
    }
    return choose_layer_phase(n, ss, ph, lobes, nl, u, beta);
  }
  void enter(uint32_t m, const ShaderProgram& p, const HeteroMedium* het = nullptr, uint32_t inst = UINT32_MAX) {
    if (n < 4) {
      const int nl = het ? 0 : int(p.phase_lobes.size());
      layer[n++] = {p.sigma_a, p.sigma_s, p.volume_emission, p.phase, m, het, nl ? p.phase_lobes.data() : nullptr, nl,
                    inst};
    }
    combine();
  }
  void leave(uint32_t m) {
    for (int i = n - 1; i >= 0; --i)
      if (layer[i].material == m) {
        for (int j = i; j + 1 < n; ++j) layer[j] = layer[j + 1];
        --n;
        combine();
        return;
      }
  }
  // Crossing a surface of material m (front: from outside, along its normal's opposite).
  void cross(uint32_t m, const ShaderProgram& p, bool front, const HeteroMedium* het = nullptr,
             uint32_t inst = UINT32_MAX) {
    if (!p.has_medium()) return;
    if (front) enter(m, p, het, inst);
    else leave(m);
  }
  // Only the layers of shadow catchers' volumes: a shadow catcher split's catcher path, whose
  // scene has no other object (Cycles re-initialises its volume stack there with the catchers
  // alone and leaves out the world's volume).
  void keep_catchers(const Scene& scene) {
    int k = 0;
    for (int i = 0; i < n; ++i)
      if (scene.is_catcher(layer[i].instance)) layer[k++] = layer[i];
    n = k;
    combine();
  }
  // Crossing the surface at sp: a Volume program's medium is the one built for its instance.
  void cross(const Scene& scene, const SurfacePoint& sp, bool front) {
    const ShaderProgram& p = scene.material(sp.material).program;
    cross(sp.material, p, front, p.volume && front ? scene.hetero_medium(sp.instance, sp.material) : nullptr,
          sp.instance);
  }
};

// A mixed stack (Medium::mixed) along the ray org + t d: every layer's coefficients summed at a
// point, majorants summed along the ray (scene/medium_grid.h's StackMajorants), and at a
// scattering the layer whose phase function continues, chosen by its share of the scattering.
struct MediumStack {
  const Scene& scene;
  const Medium& medium;
  Vec3 org, d;
  float time;  // the ray's shutter time (moving media)
  StackMajorants majorants;
  Vec3 ss[4];  // each layer's sigma_s and phase(s) at the last point evaluated
  Phase phase[4];
  const PhaseLobe* lobes[4];
  int n_lobes[4];
  PhaseLobe het_lobes[4][kMaxPhaseLobes];  // a heterogeneous layer's several phases there

  MediumStack(const Scene& sc, const Medium& m, Vec3 o, Vec3 dir, float tm)
      : scene(sc), medium(m), org(o), d(dir), time(tm) {
    for (int i = 0; i < m.n; ++i)
      if (m.layer[i].het) majorants.grids[majorants.n++] = &m.layer[i].het->grid;
    majorants.constant = max_component(m.sum.sigma_a + m.sum.sigma_s);
  }
  MediumSample at(float t) {
    const Vec3 p = org + d * t;
    MediumSample sum;
    sum.sigma_a = medium.sum.sigma_a;
    sum.sigma_s = medium.sum.sigma_s;
    sum.emission = medium.sum.emission;
    for (int i = 0; i < medium.n; ++i) {
      const MediumLayer& l = medium.layer[i];
      if (!l.het) {
        ss[i] = l.sigma_s;
        phase[i] = l.phase;
        lobes[i] = l.lobes;
        n_lobes[i] = l.n_lobes;
        continue;
      }
      const MediumSample ms = scene.medium_at(*l.het, p, d, time);
      sum.sigma_a += ms.sigma_a;
      sum.sigma_s += ms.sigma_s;
      sum.emission += ms.emission;
      ss[i] = ms.sigma_s;
      phase[i] = ms.phase;
      n_lobes[i] = ms.n_lobes;
      lobes[i] = het_lobes[i];
      for (int j = 0; j < ms.n_lobes; ++j) het_lobes[i][j] = ms.lobes[j];
    }
    return sum;
  }
  // After a scattering at the last point evaluated (beta already weighted by the summed
  // sigma_s): picks layer i with probability P_i = mean(sigma_s,i) / mean(sigma_s), weights
  // beta by sigma_s,i / (sigma_s P_i) per channel, and returns its phase (or one of its lobes,
  // likewise). The expectation is, per channel, the scattering-weighted mixture of the layers'
  // phase functions.
  Phase choose_phase(float u, Vec3& beta) const {
    return choose_layer_phase(medium.n, ss, phase, lobes, n_lobes, u, beta);
  }
};

// Radiance a homogeneous medium emits along a segment of length t, seen through its own
// extinction: the integral of exp(-sigma_t s) Le ds from 0 to t.
inline Vec3 medium_emission(const MediumLayer& m, float t) {
  const Vec3 st = m.sigma_a + m.sigma_s;
  const auto one = [t](float s, float e) {
    if (e == 0.0f) return 0.0f;
    if (s > 0.0f) return e * -std::expm1(-s * std::min(t, 1e30f)) / s;
    return std::isfinite(t) ? e * t : 0.0f;  // no extinction, unbounded: nothing sensible
  };
  return {one(st.x, m.emission.x), one(st.y, m.emission.y), one(st.z, m.emission.z)};
}

// Transmittance of a shadow ray that starts in `medium`: surfaces must be transparent (as
// Scene::transmittance_through), and the media between them attenuate by Beer's law; crossing
// a surface with a medium enters or leaves it. occlude false: the ray sees no surfaces, only
// the medium it starts in.
// Heterogeneous layers: ratio tracking with `rng` (transmittance estimates, unbiased).
Vec3 layer_transmittance(const Scene& scene, const Medium& medium, Vec3 org, Vec3 dir, float seg, Pcg32* rng,
                         float time) {
  const MediumLayer& m = *medium.top();
  if (!m.het) return medium_transmittance(m.sigma_a + m.sigma_s, seg);
  if (!rng) return Vec3(1.0f);
  const float len = length(dir);
  const Vec3 d = dir / len;
  if (medium.mixed) {
    MediumStack st(scene, medium, org, d, time);
    return ratio_track(st.majorants, org, d, seg, *rng, [&](float t) { return st.at(t); });
  }
  return ratio_track(m.het->grid, org, d, seg, *rng,
                     [&](float t) { return scene.medium_at(*m.het, org + d * t, d, time); });
}

// shadow_mask: the light's shadow sets (shadow linking): blockers of other sets let it pass.
// catchers_only: only shadow catchers block (a shadow catcher split's catcher path).
// max_hits: the transparent surfaces (volume boundaries included) it may pass, as
// Scene::transmittance.
Vec3 shadow_transmittance(const Scene& scene, Ray ray, Medium medium, bool occlude, Pcg32* rng = nullptr,
                          uint64_t shadow_mask = kAllLightSets, bool catchers_only = false,
                          int max_hits = kShadowHits) {
  Vec3 T(1.0f);
  if (!occlude) {
    if (medium.top())
      T = layer_transmittance(scene, medium, ray.org, ray.dir, ray.tmax * length(ray.dir), rng, ray.time);
    return T;
  }
  int hits = 0;
  for (int i = 0; i < kMaxShadowCrossings; ++i) {
    const float len = length(ray.dir);  // each crossing shortens it (the end point stays)
    Hit h;
    const bool found = scene.intersect(ray, h);
    if (medium.top()) {
      const float seg = found ? h.t * len : ray.tmax * len;
      T = T * layer_transmittance(scene, medium, ray.org, ray.dir, seg, rng, ray.time);
    }
    if (!found) return T;
    SurfacePoint sp;
    scene.surface_point(h, sp, ray.time, &ray);
    const Material& mat = scene.material(sp.material);
    const bool passed = (shadow_mask != kAllLightSets && !((shadow_mask >> scene.shadow_set_of(h)) & 1u)) ||
                        (catchers_only && !scene.is_catcher(h.inst, h.prim));
    if (!mat.transparent && !passed) return Vec3(0.0f);
    if (!passed) {
      // Blender's Transparent max bounces; volume-only boundaries count here (Cycles' shadow
      // rays record them as transparent hits), though not on the camera path.
      if (++hits > max_hits) return Vec3(0.0f);
      // A volume-only boundary (Material::pass_through) passes everything: T * 1, unshaded.
      if (!mat.pass_through) {
        ClosureList cl;
        RayState shadow;
        shadow.flags = kRayShadow;
        shadow.length = h.t * len;
        scene.shade(sp, h.b1, h.b2, -ray.dir / len, cl, shadow);
        T = T * vmin(cl.shadow_pass(), Vec3(1.0f));
      }
      if (is_black(T)) return Vec3(0.0f);  // (ratio tracking's estimates may be negative)
    }
    const bool front = dot(ray.dir, sp.ng) < 0.0f;
    medium.cross(scene, sp, front);
    scene.continue_past(ray, sp, front ? -sp.ng : sp.ng);
  }
  return Vec3(0.0f);
}

// The direct light along a homogeneous segment has three strategies, each a distance t and a
// direction w (power heuristic over their joint densities): a free-flight distance (density pd)
// with a light sample (pl), an equiangular distance (pe) with a light sample, and the free-flight
// distance's phase sample (pp) finding the light. Weighing the equiangular and free-flight
// distances against each other alone, then the light sample against the phase sample, left the
// phase sample's whole share to the free-flight distances: a scattering point next to a small
// lamp (rare) found it by its phase ray at weight about 1, beta times the lamp's radiance, the
// fog box's worst fireflies; with pe in the weights, the equiangular light samples crowded there
// take that share. A point's light sample weight is a pl^2 / (k2 pl^2 + s2 pp^2): at the
// free-flight point a = s2 = pd^2, k2 = pd^2 + pe^2, at the equiangular point a = pe^2; the
// phase sample's is pp^2 s2 / (s2 pp^2 + k2 pl^2), i.e. the usual heuristic with pp scaled by
// sqrt(s2 / k2) (`phase_pdf_scale`). Where there is no equiangular distance all three are 1.
struct SegmentMis {
  float a = 1.0f, k2 = 1.0f, s2 = 1.0f;
  bool plain = true;  // one strategy for the distance: the light and phase samples' heuristic alone
  static SegmentMis at_distance(float pd, float pe) {
    const double d2 = double(pd) * pd, e2 = double(pe) * pe;
    return from(d2, d2 + e2, d2);
  }
  static SegmentMis at_equiangular(float pd, float pe) {
    const double d2 = double(pd) * pd, e2 = double(pe) * pe;
    return from(e2, d2 + e2, d2);
  }
  // The light sample's weight (light pdf pl, phase pdf pp; pp 0 where no phase sample follows).
  float light_weight(float pl, float pp) const {
    if (plain) return pp > 0.0f ? power_heuristic(pl, pp) : 1.0f;
    const double l2 = double(pl) * pl, p2 = double(pp) * pp;
    const double den = double(k2) * l2 + double(s2) * p2;
    return den > 0.0 ? float(double(a) * l2 / den) : 0.0f;
  }
  // What the phase sample's pdf is multiplied by in the heuristic against the light's pdf.
  float phase_pdf_scale() const { return plain ? 1.0f : std::sqrt(s2 / k2); }

 private:
  static SegmentMis from(double a, double k2, double s2) {
    // Normalised by k2 (its largest term), so that nothing overflows.
    if (!(k2 > 0.0) || !std::isfinite(k2)) return SegmentMis{};
    SegmentMis m;
    m.a = float(a / k2), m.k2 = 1.0f, m.s2 = float(s2 / k2), m.plain = false;
    return m;
  }
};

// Direct light at a scattering point p in a medium (the path arrived along unit d): one light
// sample through the media and pass-through surfaces, times the phase function, weighted
// against the phase function's own sample by the power heuristic (weight 1 at the last bounce,
// where no phase sample follows). Not yet multiplied by the path's throughput.
// In two halves: medium_light_sample prepares the sample and its shadow ray (li * factor is what
// it adds unshadowed), medium_light_trace traces it; homogeneous segments trace one of two.
struct MediumLightSample {
  Vec3 li;
  float factor = 0.0f;
  Ray shadow;
  bool cast_shadow = true;
  uint64_t shadow_mask = kAllLightSets;  // shadow linking
  int max_hits = kShadowHits;            // RayState::shadow_hits
  uint32_t entry;                        // DirectSample::entry (its light group), set with li
};
// receiver: the medium's light set (light linking). mis: the point's share where its distance
// came from one of several strategies (SegmentMis), 1 where it is the only one.
inline bool medium_light_sample(const Scene& scene, Vec3 p, Vec3 d, const Phase& phase, bool last, float u_sel,
                                Vec2 u_pt, const RayState& ray_state, float time, MediumLightSample& ls,
                                uint8_t receiver = 0, const SegmentMis& mis = SegmentMis{}, int bounce = -1) {
  DirectSample ds;
  ds.path = &ray_state;
  ds.receiver = receiver;
  if (!scene.sample_direct(p, u_sel, u_pt, ds, !last) || (ds.exclude & kLightVisVolume)) return false;
  // A light's Max Bounces (bounce >= 0: the kKernelTricks kernels' vertices).
  if (bounce >= 0 && ds.analytic && bounce > scene.light(ds.light).max_bounces) return false;
  const float ph = phase_eval(phase, dot(d, ds.wi));
  if (!(ph > 0.0f) || is_black(ds.li)) return false;
  Ray& shadow = ls.shadow;
  shadow.time = time;
  shadow.org = p;
  if (std::isinf(ds.dist)) {
    shadow.dir = ds.wi;
    shadow.tmax = kInf;
  } else {
    const bool tri = !is_black(ds.target_normal);
    const Vec3 target = tri ? offset_ray_origin(ds.target, ds.target_error, ds.target_normal) : ds.target;
    shadow.dir = target - shadow.org;
    shadow.tmax = 1.0f - 1e-4f;
  }
  ls.cast_shadow = ds.cast_shadow;
  ls.shadow_mask = ds.shadow_mask;
  ls.max_hits = ray_state.shadow_hits();
  ls.li = ds.li;
  ls.entry = ds.entry;
  // (no phase sample can find a delta light, nor follow the last bounce)
  const float w = mis.light_weight(ds.pdf, (ds.delta || last) ? 0.0f : ph);
  ls.factor = ph * w / ds.pdf;
  return true;
}
inline Vec3 medium_light_trace(const Scene& scene, const MediumLightSample& ls, const Medium& medium, PathCounters& c,
                               Pcg32* rng) {
  ++c.rays;
  const Vec3 vis = shadow_transmittance(scene, ls.shadow, medium, ls.cast_shadow, rng, ls.shadow_mask, false, ls.max_hits);
  if (is_black(vis)) return Vec3(0.0f);
  return ls.li * vis * ls.factor;
}
Vec3 medium_direct(const Scene& scene, Vec3 p, Vec3 d, const Phase& phase, bool last, const Medium& medium, float u_sel,
                   Vec2 u_pt, const RayState& ray_state, float time, PathCounters& c, Pcg32* rng, uint8_t receiver = 0,
                   const SegmentMis& mis = SegmentMis{}, int bounce = -1) {
  MediumLightSample ls;
  if (!medium_light_sample(scene, p, d, phase, last, u_sel, u_pt, ray_state, time, ls, receiver, mis, bounce))
    return Vec3(0.0f);
  return medium_light_trace(scene, ls, medium, c, rng);
}
// The same for light groups (pass kernels only): `entry` gets the sample's DirectSample::entry
// where it drew one (left as it was where not).
Vec3 medium_direct_entry(const Scene& scene, Vec3 p, Vec3 d, const Phase& phase, bool last, const Medium& medium,
                         float u_sel, Vec2 u_pt, const RayState& ray_state, float time, PathCounters& c, Pcg32* rng,
                         uint8_t receiver, const SegmentMis& mis, uint32_t& entry, int bounce = -1) {
  MediumLightSample ls;
  if (!medium_light_sample(scene, p, d, phase, last, u_sel, u_pt, ray_state, time, ls, receiver, mis, bounce))
    return Vec3(0.0f);
  entry = ls.entry;
  return medium_light_trace(scene, ls, medium, c, rng);
}

inline Vec3 beer(Vec3 sigma, float t) {
  return {std::exp(-sigma.x * t), std::exp(-sigma.y * t), std::exp(-sigma.z * t)};
}

// The table roughness of a lobe: Cycles' sqrt(sqrt(alpha_x alpha_y)) (isotropic: sqrt(alpha)).
inline float lobe_table_rough(float alpha, float alpha_y) {
  return alpha_y < 0.0f ? std::sqrt(alpha) : std::sqrt(std::sqrt(alpha * alpha_y));
}

// A glass lobe's reflected and transmitted albedo seen from wo at |cos| mu (Cycles'
// bsdf_microfacet_estimate_albedo): the reflection's mean Fresnel from the table (generalized
// Schlick's mix(F0 tint, 1, s)) where the IOR is above 1 and there is no film, else the Fresnel
// at the view; the transmission the rest of the Fresnel at the view (before transmission_tint).
inline void dielectric_albedo(const DielectricBsdf& d, float mu, Vec3& cr, Vec3& ct) {
  float pr, pt;
  d.lobes_at(mu, cr, ct, pr, pt);
  if (d.reflection && d.eta > 1.0f && !(d.film_thickness > kThinFilmCutoff) && !is_black(cr))
    cr = dielectric_specular_albedo(lobe_table_rough(d.alpha, d.alpha_y), mu, d.eta,
                                    vmin(d.f0_tint * f0_from_ior(d.eta), Vec3(1.0f)));
}

// How much a closure reflects and transmits in total (Cycles' bsdf_albedo): the closure weight
// times the BSDF's own albedo estimated from wo, as Cycles' bsdf_microfacet_estimate_albedo:
// the tables' mean Fresnel for the generalized-Schlick dielectric (Principled specular, coat,
// glass reflection) and F82-Tint (metals), without a thin film; the Fresnel at the view for the
// rest (physical conductors, films, transmission).
inline Vec3 closure_albedo(const Closure& c, Vec3 wo) {
  const float mu = std::fabs(dot(wo, c.frame.n));
  if (const auto* m = std::get_if<ConductorBsdf>(&c.bsdf)) {
    if (m->mode == ConductorFresnel::Dielectric) {
      if (m->film_thickness > kThinFilmCutoff) return c.weight * m->fresnel(mu);
      if (m->eta == 1.0f) return Vec3(0.0f);  // (no reflection: Cycles' is_zero(reflectance))
      return c.weight * dielectric_specular_albedo(lobe_table_rough(m->alpha, m->alpha_y), mu, m->eta, m->f0);
    }
    if (m->mode == ConductorFresnel::F82Tint) {
      if (is_black(m->fresnel(mu))) return Vec3(0.0f);
      return c.weight * f82_specular_albedo(lobe_table_rough(m->alpha, m->alpha_y), mu, m->f0);
    }
    if (m->mode == ConductorFresnel::Conductor) return c.weight * m->fresnel(mu);
    return c.weight * m->f0;
  }
  if (const auto* d = std::get_if<DielectricBsdf>(&c.bsdf)) {
    Vec3 cr, ct;
    dielectric_albedo(*d, mu, cr, ct);
    return c.weight * ((d->reflection ? cr : Vec3(0.0f)) + (d->transmission ? d->transmission_tint * ct : Vec3(0.0f)));
  }
  return c.weight;  // diffuse, transparent
}

// Cycles' threshold between specular-like and rough closures (on alpha, Blender's roughness^2).
inline bool closure_is_rough(const Closure& c) {
  if (std::holds_alternative<DiffuseBsdf>(c.bsdf) || std::holds_alternative<TranslucentBsdf>(c.bsdf) ||
      std::holds_alternative<SubsurfaceBsdf>(c.bsdf) ||
      std::holds_alternative<OrenNayarBsdf>(c.bsdf) || std::holds_alternative<SheenBsdf>(c.bsdf) ||
      std::holds_alternative<VelvetBsdf>(c.bsdf) || std::holds_alternative<ToonBsdf>(c.bsdf))
    return true;
  if (const auto* m = std::get_if<ConductorBsdf>(&c.bsdf)) return m->alpha > 0.075f;
  if (const auto* d = std::get_if<DielectricBsdf>(&c.bsdf)) return d->alpha > 0.075f;
  return false;  // transparent
}

// The LightVisibility bit a closure's light needs (Cycles' _shader_bsdf_exclude: diffuse,
// glossy and transmission closures; glass lobes that both reflect and refract, hair and
// transparency are never excluded).
inline uint8_t closure_light_kind(const Closure& c) {
  if (std::holds_alternative<DiffuseBsdf>(c.bsdf) || std::holds_alternative<OrenNayarBsdf>(c.bsdf) ||
      std::holds_alternative<SheenBsdf>(c.bsdf) || std::holds_alternative<TranslucentBsdf>(c.bsdf))
    return kLightVisDiffuse;
  if (const auto* t = std::get_if<ToonBsdf>(&c.bsdf)) return t->glossy ? kLightVisGlossy : kLightVisDiffuse;
  if (std::holds_alternative<ConductorBsdf>(c.bsdf) || std::holds_alternative<VelvetBsdf>(c.bsdf)) return kLightVisGlossy;
  if (const auto* d = std::get_if<DielectricBsdf>(&c.bsdf)) {
    if (d->reflection && !d->transmission) return kLightVisGlossy;
    if (d->transmission && !d->reflection) return kLightVisTransmission;
  }
  return 0;
}

// eval_mixture without the closures of the kinds in `exclude` (a light invisible to them):
// their value and their pdf, as Cycles' _shader_bsdf_multi_eval.
[[gnu::noinline]] inline Vec3 eval_mixture_excluding(const ClosureList& cl, Vec3 wo, Vec3 wi, bool reflection,
                                                     uint8_t exclude, float& pdf) {
  ClosureList kept;
  kept.n = 0;
  for (int i = 0; i < cl.n; ++i)
    if (!(closure_light_kind(cl.c[size_t(i)]) & exclude)) kept.c[size_t(kept.n++)] = cl.c[size_t(i)];
  return eval_mixture<false>(kept, wo, wi, reflection, pdf);
}

// Cycles' render-pass kind of a closure: 0 diffuse (CLOSURE_IS_BSDF_DIFFUSE, translucent and
// subsurface included), 1 glossy, 2 transmission (refraction, hair transmission, transparency).
// Glass counts as glossy where it reflects, as transmission where it refracts (bsdf_eval_init).
inline int closure_pass_kind(const Closure& c, bool reflection) {
  const Bsdf& b = c.bsdf;
  if (std::holds_alternative<DiffuseBsdf>(b) || std::holds_alternative<OrenNayarBsdf>(b) ||
      std::holds_alternative<SheenBsdf>(b) || std::holds_alternative<TranslucentBsdf>(b) ||
      std::holds_alternative<SubsurfaceBsdf>(b))
    return 0;
  if (const auto* t = std::get_if<ToonBsdf>(&b)) return t->glossy ? 1 : 0;
  if (const auto* h = std::get_if<HairBsdf>(&b)) return h->transmission ? 2 : 1;
  if (const auto* d = std::get_if<DielectricBsdf>(&b)) {
    if (!d->transmission) return 1;
    if (!d->reflection) return 2;
    return reflection ? 1 : 2;
  }
  if (std::holds_alternative<TransparentBsdf>(b)) return 2;
  return 1;  // conductors (Glossy, Metallic, Principled's specular), velvet, Chiang and Huang hair
}

inline Vec3 safe_ratio(Vec3 a, Vec3 b) {
  return {b.x != 0.0f ? a.x / b.x : 0.0f, b.y != 0.0f ? a.y / b.y : 0.0f, b.z != 0.0f ? a.z / b.z : 0.0f};
}

// Cycles' pass weights of a mixture's value along wi: the diffuse and glossy closures' shares of
// it per channel (the rest is transmission). Only render passes call this (one eval per closure).
[[gnu::noinline]] inline void pass_weights(const ClosureList& cl, Vec3 wo, Vec3 wi, bool reflection, uint8_t exclude,
                                           Vec3& dw, Vec3& gw) {
  Vec3 fd(0.0f), fg(0.0f), sum(0.0f);
  ClosureList one;
  one.n = 1;
  for (int i = 0; i < cl.n; ++i) {
    const Closure& c = cl.c[size_t(i)];
    if (c.delta || (exclude && (closure_light_kind(c) & exclude))) continue;
    one.c[0] = c;
    float p;
    const Vec3 f = eval_mixture<false>(one, wo, wi, reflection, p);
    sum += f;
    const int k = closure_pass_kind(c, reflection);
    if (k == 0) fd += f;
    if (k == 1) fg += f;
  }
  dw = safe_ratio(fd, sum);
  gw = safe_ratio(fg, sum);
}

// Cycles' Diffuse, Glossy and Transmission Color of a surface: its closures' albedos by kind,
// glass split into its reflected and refracted parts (transparency belongs to none).
[[gnu::noinline]] inline void pass_colors(const ClosureList& cl, Vec3 wo, Vec3& diffuse, Vec3& glossy, Vec3& transmission) {
  for (int i = 0; i < cl.n; ++i) {
    const Closure& c = cl.c[size_t(i)];
    if (std::holds_alternative<TransparentBsdf>(c.bsdf) || std::holds_alternative<PortalBsdf>(c.bsdf)) continue;
    // Cycles' albedo leaves out the 1 / E of the energy compensation (E: the single-scatter
    // lobe's directional albedo), which Pathlight's closure weight carries.
    const float cos_n = dot(wo, c.frame.n), mu = std::fabs(cos_n);
    if (const auto* d = std::get_if<DielectricBsdf>(&c.bsdf)) {
      Vec3 cr, ct;
      dielectric_albedo(*d, mu, cr, ct);
      const Vec3 w = d->compensated ? c.weight * ggx_glass_E(std::sqrt(d->alpha), mu, cos_n >= 0.0f ? d->eta : 1.0f / d->eta)
                                    : c.weight;
      if (d->reflection) glossy += w * cr;
      if (d->transmission) transmission += w * d->transmission_tint * ct;
      continue;
    }
    const int k = closure_pass_kind(c, true);
    Vec3 a = closure_albedo(c, wo);
    if (const auto* m = std::get_if<ConductorBsdf>(&c.bsdf); m && m->compensated)
      a *= table_2d(tables::ggx_E, lobe_table_rough(m->alpha, m->alpha_y), mu, 32, 32);
    (k == 0 ? diffuse : k == 1 ? glossy : transmission) += a;
  }
}

// Cycles' Clamping (film_clamp_light): a contribution to the film whose components' absolute
// sum exceeds `limit` is scaled down to it, each contribution on its own (limit 0: unchanged,
// bit for bit). IntegratorSettings::clamp_direct, clamp_indirect.
[[gnu::always_inline]] inline Vec3 clamp_light(Vec3 v, float limit) {
  if (limit > 0.0f) {
    const float sum = std::fabs(v.x) + std::fabs(v.y) + std::fabs(v.z);
    if (sum > limit) v = v * (limit / sum);
  }
  return v;
}

// Adds v to the light component of a path whose first scattering had pass weights dw, gw (or
// was in a volume): direct or indirect.
inline void add_light_component(PathAovs& a, Vec3 v, bool direct, Vec3 dw, Vec3 gw, bool volume) {
  if (!is_finite(v)) return;
  const int k = direct ? 0 : 1;
  if (volume) {
    a.light[kVolumeDirect + k] += v;
    return;
  }
  a.light[kDiffuseDirect + k] += dw * v;
  a.light[kGlossyDirect + k] += gw * v;
  a.light[kTransmissionDirect + k] += (Vec3(1.0f) - dw - gw) * v;
}

// The light tracer's density of a path leaving the environment along -dir (dir: towards the
// light) and first meeting a surface at x: the environment's pdf of dir over the area of its
// disk across the caster sphere (0 where x is outside the sphere: the light tracer never
// reaches it).
inline float caustic_source_pdf(const Scene& scene, const CausticLight& cz, Vec3 dir, Vec3 x) {
  if (!(cz.env_pmf > 0.0f) || !(length_sq(x - cz.center) <= cz.radius * cz.radius)) return 0.0f;
  return cz.env_pmf * scene.environment().pdf(dir, true) / (kPi * cz.radius * cz.radius);
}
// 1 - cos of the cone that the caster sphere subtends from q (2: q inside it, every direction):
// an area lamp's light paths leave its point q uniformly in it.
inline float caustic_cone_from(const CausticLight& cz, Vec3 q) {
  const float d2 = length_sq(cz.center - q), r2 = cz.radius * cz.radius;
  return d2 > r2 ? one_minus_cos_from_sin2(r2 / d2) : 2.0f;
}
inline bool is_area_light(const Light& l) { return l.type == LightType::Rect || l.type == LightType::Ellipse; }
// The same for a path leaving lamp `light` (CausticLamp): its choice times its direction's
// solid-angle density over the squared distance to x (a sun: over its disk's area, as the
// environment), times `shape` (with extent: the lamp's own sample density at x towards the start
// x0; 1 for a delta lamp); an area lamp's: its choice, 1 / its area and its cone's density at
// x0, over the cosine there (per unit solid angle at x, x's cosine left out); 0 where the lamp
// sends none.
inline float caustic_lamp_pdf(const Scene& scene, const CausticLight& cz, uint32_t light, Vec3 x, Vec3 x0,
                              float shape) {
  if (light >= cz.lamp_of.size() || cz.lamp_of[light] < 0) return 0.0f;
  if (!(length_sq(x - cz.center) <= cz.radius * cz.radius)) return 0.0f;
  const CausticLamp& m = cz.lamps[size_t(cz.lamp_of[light])];
  const Light& l = scene.light(light);
  if (l.type == LightType::Sun) return m.pmf / (kPi * cz.radius * cz.radius) * shape;
  if (is_area_light(l)) {
    const Vec3 w = x - x0;
    const float len = length(w), cos0 = dot(w, l.dir) / len;
    if (!(cos0 > 0.0f) || !(l.area > 0.0f)) return 0.0f;
    return caustic_cone_pdf(m.pmf, caustic_cone_from(cz, x0)) / (l.area * cos0);
  }
  return caustic_cone_pdf(m.pmf, m.one_minus_cos) / length_sq(x - l.position) * shape;
}

// A point's or spot's light path with extent (CausticLamp) leaves the lamp's centre, so it finds
// x (normal ng) only where the centre sees it (from org, x offset towards the lamp), and its
// density there has the cosine towards the centre, not towards its start (wi, from x): the
// factor cos_c / cos_s that the light path's heuristic density takes over the other lamps'
// (both sides; a light path that meets x at a grazing angle from the centre then weighs
// little). 0 where the centre is hidden; 1 for any other lamp.
inline float caustic_lamp_centre(const Scene& scene, const CausticLight& cz, uint32_t light, Vec3 org, Vec3 ng,
                                 Vec3 wi, float time) {
  const CausticLamp& m = cz.lamps[size_t(cz.lamp_of[light])];
  const Light& l = scene.light(light);
  if (!m.extent || l.type == LightType::Sun || is_area_light(l)) return 1.0f;
  const Vec3 dc = l.position - org;
  const float cos_s = std::fabs(dot(ng, wi)), cos_c = std::fabs(dot(ng, dc)) / length(dc);
  if (!(cos_s > 0.0f) || !(cos_c > 0.0f)) return 0.0f;
  Ray r;
  r.org = org;
  r.dir = dc;
  r.tmax = 1.0f - 1e-4f;
  r.time = time;  // (motion blur: the path's shutter time)
  return scene.occluded(r) ? 0.0f : cos_c / cos_s;
}
// light_hits' third strategy (kKernelCaustics): a lamp's light path, for a BSDF ray that left the
// last smooth vertex of a caustic path (ratio: the kernel's cz_ratio there, n Pc / Pa less the
// light path's density of the vertex and the start; ng: the vertex's geometric normal).
struct CausticHitMis {
  const CausticLight* cz = nullptr;
  float ratio = 0.0f;
  Vec3 ng;
  bool delta = false;  // the vertex scattered by a delta lobe: two strategies (no light sample)
};

// The power heuristic over the caustic paths' three strategies, for the one whose density is 1
// when the other two's are a and b (relative to it): 1 / (1 + a^2 + b^2).
inline float caustic_mis_weight(float a, float b) { return 1.0f / (1.0f + a * a + b * b); }

// Light groups (PathAovs::groups): light_hits and dedicated_light_hits hand each light's
// contribution to a sink (light index, value); the kernels without passes take this one, which
// does nothing (their code stays as without groups).
struct NoGroupSink {
  void operator()(uint32_t, Vec3) const {}
};

// Emission of the analytic lights that a ray crosses before distance t_end (in units of
// ray.dir; infinite: the ray escaped, and suns with an angle count too), of the lights visible
// to its kind `vis` (LightVisibility; the camera's: those visible to the camera, else those
// with Multiple Importance on). `through(t)`: the path's throughput to distance t (world
// units). weigh: MIS against the light sample at `from` (normal from_n) that could have found
// the same point, as pdf_emitter does for mesh lights; else (camera rays, delta lobes, no
// light sampling) the full weight. kLinks: light linking, `set` the light set of the point at
// `from` (lights not linked to it add nothing but to camera rays; its set's pdfs). clamp: each
// light's contribution clamped at it (clamp_light; 0: none). sink(light, value): each one's
// contribution (light groups).
template <bool kLinks = false, bool kClamp = false, bool kFastGI = false, class Through, class Sink = NoGroupSink>
[[gnu::noinline]] Vec3 light_hits(const Scene& scene, const Ray& ray, float t_end, uint8_t vis, bool weigh, float prev_pdf,
                                  Vec3 from, Vec3 from_n, const Through& through, uint8_t set = 0,
                                  const CausticHitMis* caus = nullptr, float clamp = 0.0f, const Sink& sink = Sink{}) {
  Vec3 sum(0.0f);
  // kFastGI: a negative t_end (-0 too) is a ray Fast GI shortened to -t_end that found nothing
  // there: an escaped ray for the suns. (The other kernels' code and calls are as before.)
  [[maybe_unused]] bool escaped = false;
  if constexpr (kFastGI)
    if (std::signbit(t_end)) t_end = -t_end, escaped = true;
  const float len = length(ray.dir);
  if (!(len > 0.0f)) return sum;
  const Vec3 d = ray.dir / len;
  float tmax = t_end * len;
  const bool camera = vis == kLightVisCamera;
  const bool rects = scene.solid_angle_rect_sampling();
  const auto add = [&](const Scene::HitLight& h) {
    if (camera ? !(h.visibility & kLightVisCamera) : (!h.mis || (h.visibility & vis) != vis)) return;
    if constexpr (kLinks)
      if (!camera && !((scene.light(h.index).light_mask >> set) & 1u)) return;
    float t, pdf;
    Vec3 le;
    if (!intersect_light(scene.light(h.index), from, ray.org, d, tmax, t, le, pdf, rects)) return;
    float w = 1.0f;
    if (caus && caus->delta) {
      // After glass or a mirror in a caustic chain: the BSDF ray against the light path alone.
      float ps = caustic_lamp_pdf(scene, *caus->cz, h.index, from, ray.org + d * t, pdf);
      if (ps > 0.0f) ps *= caustic_lamp_centre(scene, *caus->cz, h.index, ray.org, caus->ng, d, ray.time);
      if (ps > 0.0f) w = caustic_mis_weight(0.0f, caus->ratio * ps);
    } else if (weigh) {
      const float pl = scene.light_choice_pmf(from, from_n, h.index, kLinks ? set : 0) * pdf;
      w = power_heuristic(prev_pdf, pl);
      if (caus) {
        // A lamp with extent that sends caustic light paths: three strategies (the light
        // path's density times its start's, the lamp's own sample density pdf here).
        float ps = caustic_lamp_pdf(scene, *caus->cz, h.index, from, ray.org + d * t, pdf);
        if (ps > 0.0f) ps *= caustic_lamp_centre(scene, *caus->cz, h.index, ray.org, caus->ng, d, ray.time);
        if (ps > 0.0f) w = caustic_mis_weight(pl / prev_pdf, caus->ratio * ps);
      }
    }
    const Vec3 c = kClamp ? clamp_light(through(t) * le * w, clamp) : through(t) * le * w;
    if (is_finite(c)) {
      sum += c;
      sink(h.index, c);
    }
  };
  scene.for_hit_lights(ray.org, d, tmax, add);  // (bounding spheres or boxes first)
  if constexpr (kFastGI)
    if (escaped) tmax = kInf;  // (suns lie past any reach: add reads tmax)
  if (std::isinf(tmax))
    for (const Scene::HitLight& h : scene.hit_suns()) add(h);
  return sum;
}

// Shadow-linked lights along a ray leaving surface point sp (side: the normal on its side, d
// unit): each one the ray's line crosses, seen through a shadow ray that passes the blockers it
// ignores (`transmit(ray, mask)`), its emission times `beta`, weighted as light_hits weighs
// (against the light sample at `from` of light set `set`), each clamped at `clamp` (0: none),
// each handed to sink(light, value) too (light groups).
template <class Transmit, class Sink = NoGroupSink>
[[gnu::noinline]] Vec3 dedicated_light_hits(const Scene& scene, const SurfacePoint& sp, Vec3 side, Vec3 d, float time,
                                            uint8_t vis, bool weigh, float prev_pdf, Vec3 from, Vec3 from_n,
                                            uint8_t set, Vec3 beta, float clamp, const Transmit& transmit,
                                            const Sink& sink = Sink{}) {
  Vec3 sum(0.0f);
  if (scene.dedicated_lights().empty()) return sum;
  const Vec3 org = offset_ray_origin(sp.p, sp.p_error, side);
  for (const Scene::HitLight& h : scene.dedicated_lights()) {
    const Light& l = scene.light(h.index);
    if ((h.visibility & vis) != vis || !((l.light_mask >> set) & 1u)) continue;
    float t, pdf;
    Vec3 le;
    if (!intersect_light(l, from, org, d, kInf, t, le, pdf, scene.solid_angle_rect_sampling())) continue;
    Ray shadow;
    shadow.time = time;
    shadow.org = org;
    shadow.self_curve = scene.self_curve(sp);
    if (std::isinf(t)) {
      shadow.dir = d;
      shadow.tmax = kInf;
    } else {
      shadow.dir = d * t;
      shadow.tmax = 1.0f - 1e-4f;
    }
    const Vec3 vis_t = l.cast_shadow ? transmit(shadow, l.shadow_mask) : Vec3(1.0f);
    if (is_black(vis_t)) continue;
    const float w = weigh ? power_heuristic(prev_pdf, scene.light_choice_pmf(from, from_n, h.index, set) * pdf) : 1.0f;
    const Vec3 c = clamp_light(beta * le * vis_t * w, clamp);
    if (is_finite(c)) {
      sum += c;
      sink(h.index, c);
    }
  }
  return sum;
}

// Diffuse-like vertices (diffuse, rough diffuse, translucent lobes only) find analytic lights by
// their light samples alone: their rays would find a small light rarely, and splitting the weight
// with them cost the Sobol-stratified light samples of a soft shadow 30 % more error. Their light
// samples of such lights keep the full weight and their rays add none (a valid MIS too).
inline bool lights_by_samples_only(const ClosureList& cl) {
  for (int i = 0; i < cl.n; ++i) {
    const Bsdf& b = cl.c[size_t(i)].bsdf;
    if (!std::holds_alternative<DiffuseBsdf>(b) && !std::holds_alternative<OrenNayarBsdf>(b) &&
        !std::holds_alternative<TranslucentBsdf>(b))
      return false;
  }
  return true;
}

// Path guiding (render/guiding.h) steers only vertices whose closures are all rough and
// reflect or transmit without refraction (diffuse, sheen, translucent, rough glossy): the
// learnt distribution knows incident light, not the refraction's eta or a hair's lobes.
inline bool guidable(const ClosureList& cl) {
  if (cl.n == 0) return false;
  for (int i = 0; i < cl.n; ++i) {
    const Closure& c = cl.c[size_t(i)];
    if (std::holds_alternative<DiffuseBsdf>(c.bsdf) || std::holds_alternative<OrenNayarBsdf>(c.bsdf) ||
        std::holds_alternative<TranslucentBsdf>(c.bsdf) || std::holds_alternative<SheenBsdf>(c.bsdf) ||
        std::holds_alternative<VelvetBsdf>(c.bsdf))
      continue;
    const auto* m = std::get_if<ConductorBsdf>(&c.bsdf);
    if (!m || !(m->alpha > 0.075f) || c.delta) return false;
  }
  return true;
}

// What a guided path remembers of a vertex it may train the guide with: the radiance that
// arrives there along wi is what the path gathers afterwards (L now less L then) over the
// throughput then. As gathered, i.e. MIS-weighted: the guide learns what the BSDF's side has to
// find, not the light that the vertex's own light samples already find (learning the sun's full
// radiance too sent guided rays at the sun and made the window-lit room noisier).
struct GuideRecord {
  Vec3 wi, beta, L;
  float pdf;
  uint32_t cell;
  float pb, pg;  // the BSDF's and the guide's pdfs of wi (for the learnt probability)
  float fq;  // the vertex's BSDF value (luminance) over pdf: the estimate is this x the radiance
  float cos_n;  // the cosine to the shading normal (guide_cosine), else 1
};

// Measurement only (IntegratorSettings::path_class_mask): the class of the light a path adds,
// by the kinds of its scattering vertices from the camera (rough: what guiding samples; smooth:
// the rest), so that an image's error can be split by the paths that carry it.
struct PathClass {
  enum : int { kDirect, kCaustic, kCausticLong, kCausticSeen, kSmoothFirst, kRough, kCount };
  uint8_t n = 0;
  bool first_rough = true, last_rough = true, any_rough = false, rough_before_last = false, smooth_after_rough = false;
  void append(bool rough) {
    if (n == 0) first_rough = rough;
    else rough_before_last = rough_before_last || last_rough;
    smooth_after_rough = smooth_after_rough || (!rough && any_rough);
    any_rough = any_rough || rough;
    last_rough = rough;
    n = uint8_t(std::min(n + 1, 255));
  }
  int id() const {
    if (n <= 1) return kDirect;  // emission seen or light at the first vertex
    if (!last_rough && rough_before_last) return n == 2 ? kCaustic : kCausticLong;  // L S D E, L S+ D .. E
    if (smooth_after_rough) return kCausticSeen;  // L D .. S .. D E
    if (!first_rough) return kSmoothFirst;  // L .. S E: a smooth surface seen reflecting indirect light
    return kRough;  // L D D+ E
  }
};

// Caustic light tracing (CausticLight): a vertex that may be one of the class's (no hair
// lobes, whose samples carry their own values), and whether it is its rough one.
inline bool caustic_vertex(const SurfacePoint& sp, const ClosureList& cl) {
  if (sp.curve() || sp.point() || cl.n == 0) return false;
  for (int i = 0; i < cl.n; ++i) {
    const Bsdf& b = cl.c[size_t(i)].bsdf;
    if (std::holds_alternative<HairChiangBsdf>(b) || std::holds_alternative<HairHuangBsdf>(b) ||
        std::holds_alternative<HairBsdf>(b))
      return false;
  }
  return true;
}

// A delta vertex of a caustic chain (smooth glass, a mirror): the index of the vertex's one
// delta closure, a perfect mirror or a smooth dielectric; -1 where there is none, or another
// delta closure beside it (Transparent, Subsurface, a Ray Portal, a second mirror): there the
// chain ends, on both sides alike.
inline int caustic_delta_closure(const ClosureList& cl) {
  int found = -1;
  for (int i = 0; i < cl.n; ++i) {
    const Closure& c = cl.c[size_t(i)];
    if (!c.delta) continue;
    if (found >= 0 || !(std::holds_alternative<ConductorBsdf>(c.bsdf) || std::holds_alternative<DielectricBsdf>(c.bsdf)))
      return -1;
    found = i;
  }
  return found;
}

// Whether a delta closure's normal n (its frame's) is the one shading from direction w gives it,
// not one that Cycles' ensure_valid_specular_reflection (valid_specular_normal) bent towards ng
// for w: that lift depends on the view, so the light path (shading from the light's side) would
// mirror or refract about another normal than the path tracer. A delta vertex is in the chain
// only where neither side's direction bends it (a margin past the lift's threshold, so that a
// normal the lift made for one side fails too): the same test on both sides.
inline bool caustic_unbent(Vec3 ng, Vec3 n, Vec3 w) {
  const float side = dot(ng, w) < 0.0f ? -1.0f : 1.0f;
  const Vec3 Ng = ng * side, N = n * side;
  if (N.x == Ng.x && N.y == Ng.y && N.z == Ng.z) return true;
  const Vec3 R = N * (2.0f * dot(N, w)) - w;
  const float threshold = std::min(0.9f * dot(w, Ng), 0.01f);
  return dot(Ng, R) > threshold + 1e-3f;
}

// The lobe of a delta closure (caustic_delta_closure's) that its sample from w (local) takes:
// reflection or, transmit, refraction; prob its probability there (the Fresnel choice, thin film
// included), value its sample's weight times prob (f |cos| over the delta: the lobe's colour, no
// 1 / etap^2, as DielectricBsdf's), etap refraction's relative IOR from w's side (1: reflection),
// out the direction it leaves along (local). False where the lobe cannot be taken.
inline bool caustic_delta_lobe(const Bsdf& b, Vec3 w, bool transmit, Vec3& value, float& prob, float& etap, Vec3& out) {
  etap = 1.0f;
  if (w.z == 0.0f) return false;
  if (const auto* m = std::get_if<ConductorBsdf>(&b)) {
    if (transmit) return false;
    value = m->fresnel(std::fabs(w.z));
    prob = 1.0f;
    out = {-w.x, -w.y, w.z};
    return true;
  }
  const auto* d = std::get_if<DielectricBsdf>(&b);
  if (!d) return false;
  Vec3 wl = w;
  if (d->one_sided_coat() && wl.z < 0.0f) wl.z = -wl.z;  // (as its sample: mirrored to the front)
  Vec3 cr, ct;
  float pr, pt;
  d->lobes_at(wl.z, cr, ct, pr, pt);
  if (!(pr + pt > 0.0f)) return false;
  if (!transmit) {
    if (!(pr > 0.0f)) return false;
    value = cr;
    prob = pr / (pr + pt);
    out = {-wl.x, -wl.y, wl.z};
  } else {
    if (!(pt > 0.0f) || !refract(wl, {0.0f, 0.0f, 1.0f}, d->eta, out, etap) || out.z == 0.0f) return false;
    value = d->transmission_tint * ct;
    prob = pt / (pr + pt);
  }
  if (wl.z != w.z) out.z = -out.z;
  return true;
}

// The passes written at each surface the camera path meets (through Transparent BSDFs), as
// Cycles' film_write_data_passes and AO pass: the colours, Mist, AO (beta: the throughput there).
[[gnu::noinline]] inline void camera_hit_passes(const Scene& scene, const IntegratorSettings& s, const SurfacePoint& sp,
                                               const ClosureList& cl, Vec3 wo, Vec3 beta, uint64_t path_key,
                                               int layer, float time, bool colors, PathAovs& aov) {
  if (colors) {
    Vec3 d(0.0f), g(0.0f), t(0.0f);
    pass_colors(cl, wo, d, g, t);
    aov.diffuse_color += beta * d;
    aov.glossy_color += beta * g;
    aov.transmission_color += beta * t;
  }
  if (!s.mist && !s.ao) return;
  const Vec3 transparency = cl.transparency();
  const Vec3 alpha = vmax(Vec3(0.0f), vmin(Vec3(1.0f), Vec3(1.0f) - transparency));
  const float weight = average(beta * alpha);
  if (s.mist) {
    // Cycles' camera distance: from the camera (orthographic: along its axis).
    const Vec3 rel = sp.p - s.mist_origin;
    const float dist = is_black(s.mist_axis) ? length(rel) : dot(rel, s.mist_axis);
    float m = s.mist_depth > 0.0f ? clampf((dist - s.mist_start) / s.mist_depth, 0.0f, 1.0f)
                                  : (dist >= s.mist_start ? 1.0f : 0.0f);
    if (s.mist_falloff == 2.0f) m = m * m;
    else if (s.mist_falloff == 0.5f) m = std::sqrt(m);
    else if (s.mist_falloff != 1.0f) m = std::pow(m, s.mist_falloff);
    aov.mist += (1.0f - m) * weight;
  }
  if (s.ao && weight > 0.0f) {
    // A cosine-distributed ray about the normal (facing the view) of at most ao_distance; its
    // own random numbers, so the path's sample streams stay as without the pass.
    const bool front = dot(sp.ng, wo) > 0.0f;
    const Vec3 ng = front ? sp.ng : -sp.ng;
    Vec3 n = !is_black(cl.ns) ? cl.ns : sp.ns;
    if (dot(n, wo) < 0.0f) n = -n;
    Pcg32 rng;
    rng.set(path_key ^ 0xA0A0A0A0A0A0A0A0ULL, 0x5851F42D4C957F2DULL + 2u * uint64_t(layer));
    const float u1 = rng.next_float(), u2 = rng.next_float();
    const float r = std::sqrt(u1), phi = 2.0f * kPi * u2;
    const Frame f = Frame::from_normal(n);
    const Vec3 dir = f.to_world(Vec3(r * std::cos(phi), r * std::sin(phi), std::sqrt(std::max(0.0f, 1.0f - u1))));
    if (dot(dir, ng) > 0.0f && s.ao_distance > 0.0f) {
      Ray ray;
      ray.org = offset_ray_origin(sp.p, sp.p_error, ng);
      ray.dir = dir;
      ray.tmax = s.ao_distance;  // (infinite: unbounded)
      ray.time = time;
      ray.self_curve = scene.self_curve(sp);
      // Through transparent surfaces and the volumes it enters (Cycles traces it as a shadow ray);
      // a camera path inside a volume is rare enough to ignore the one it starts in.
      aov.ao += beta * alpha * shadow_transmittance(scene, ray, Medium{}, true, &rng);
    }
  }
}

// Cold parts of the path kernels, out of line: inlined, code that few vertices run made GCC
// keep the surfaces kernel's path state in memory (docs/design/kernels.md, "What keeps the hot
// kernels hot"). Each computes what the kernel computed in place, in the same arithmetic.

// A cosine sample of the sky about ng_out (Scene::samples_world; lights are light-sampled
// instead), its numbers the sampler's next two: false where its pdf is 0.
[[gnu::noinline, gnu::cold]] bool sky_light_sample(const Scene& scene, Sampler& sampler, Vec3 ng_out, DirectSample& ds) {
  const Vec3 l = sample_cosine_hemisphere(sampler.get2d());
  ds.pdf = l.z * kInvPi;
  if (!(ds.pdf > 0.0f)) return false;
  ds.wi = Frame::from_normal(ng_out).to_world(l);
  ds.li = scene.world_color();
  return true;
}

// A Ray Portal's continuation (Cycles' integrate_surface_ray_portal): from the portal's position
// along its direction, or from the surface itself where the portal is there.
[[gnu::noinline, gnu::cold]] void portal_ray(const Scene& scene, const SurfacePoint& sp, const PortalBsdf& portal,
                                             Vec3 ng_out, Ray& ray) {
  if (length_sq(sp.p - portal.p) > 1e-9f) {
    ray.org = portal.p;  // elsewhere: it may find the same surface again
    ray.self_curve = UINT32_MAX;
  } else {
    ray.org = offset_ray_origin(sp.p, sp.p_error, dot(portal.d, ng_out) > 0.0f ? ng_out : -ng_out);
    ray.self_curve = scene.self_curve(sp);
  }
  ray.dir = portal.d;
  ray.tmax = kInf;
}

// Cycles' Hair BSDF carries its sample's value along the direction it drew itself
// (hair_bsdf.h): what that changes in the mixture's value and pdf, where it replaces the
// closure's evaluation.
struct HairSampled {
  Vec3 f;
  float pdf;
};
[[gnu::noinline, gnu::cold]] HairSampled hair_sampled(const Closure& ch, const HairBsdf& hb, Vec3 wo, Vec3 wi) {
  const Vec3 lo = ch.frame.to_local(wo), li = ch.frame.to_local(wi);
  float pe, ps;
  const Vec3 fe = hb.eval(lo, li, pe), fs = hb.eval_sampled(lo, li, ps);
  return {ch.weight * (fs - fe), ch.pick * (ps - pe)};
}

// The roulette's number where no light sample drew it (few vertices: without light samples).
[[gnu::noinline, gnu::cold]] float roulette_number(Sampler& sampler) { return sampler.get2d().x; }

// Cycles' Transparent Glass (bsdf_sample's LABEL_TRANSMIT_TRANSPARENT): a transmission sampled
// from closure c that is not diffuse and whose alpha_x alpha_y (bsdf_get_specular_roughness_
// squared: 0 for delta lobes, 1 for closures without a microfacet roughness) is at most
// `threshold` (negative: off) keeps the path's world the transparent film's.
inline bool transmit_transparent(const Closure& c, uint32_t flags, float threshold) {
  if (!(threshold >= 0.0f) || !(flags & kTransmit) || (flags & kDiffuseLobe)) return false;
  float r2 = 1.0f;
  if (c.delta) r2 = 0.0f;
  else if (const auto* d = std::get_if<DielectricBsdf>(&c.bsdf)) r2 = d->alpha * (d->alpha_y < 0.0f ? d->alpha : d->alpha_y);
  return r2 <= threshold;
}

// Fast GI, Add (Cycles' integrate_surface_ao with KERNEL_FEATURE_AO_ADDITIVE): a cosine ray
// about the diffuse closures' mean normal (surface_shader_ao: CLOSURE_IS_BSDF_DIFFUSE, each
// normal weighted by its mean weight; the shading normal without any) of at most
// ao_bounces_distance; where it reaches no surface (transparent ones let it through, as
// Cycles' shadow ray), the light is the diffuse closures' weight times ao_additive_factor, times
// the throughput and the surface's alpha (clamped as a light sample at this vertex). Its own
// random numbers, so the path's sample streams stay as without it. Volumes on the way are not
// traced (the ray is a surface shadow ray).
[[gnu::noinline]] inline Vec3 fast_gi_additive(const Scene& scene, const IntegratorSettings& s, const SurfacePoint& sp,
                                               const ClosureList& cl, Vec3 wo, Vec3 ng_out, Vec3 beta, float time,
                                               uint64_t path_key, int bounce, float clamp) {
  Vec3 weight(0.0f), n(0.0f);
  for (int i = 0; i < cl.n; ++i) {
    const Closure& c = cl.c[size_t(i)];
    if (closure_pass_kind(c, true) != 0 || std::holds_alternative<SubsurfaceBsdf>(c.bsdf)) continue;
    weight += c.weight;
    // (Cycles' closure normals face the viewer; a translucent closure's the other side)
    Vec3 cn = dot(c.frame.n, wo) < 0.0f ? -c.frame.n : c.frame.n;
    if (std::holds_alternative<TranslucentBsdf>(c.bsdf)) cn = -cn;
    n += cn * std::fabs(average(c.weight));
  }
  if (is_black(weight)) return Vec3(0.0f);
  const float nl = length(n);
  if (nl > 0.0f && std::isfinite(nl)) n = n / nl;
  else n = dot(sp.ns, wo) < 0.0f ? -sp.ns : sp.ns;
  Pcg32 rng(path_key ^ 0xFA57C1A0FA57C1A0ULL, 0x2545F4914F6CDD1DULL + 2u * uint64_t(bounce));
  const float u1 = rng.next_float(), u2 = rng.next_float();
  const float r = std::sqrt(u1), phi = 2.0f * kPi * u2;
  const Frame f = Frame::from_normal(n);
  Ray ray;
  ray.dir = f.to_world(Vec3(r * std::cos(phi), r * std::sin(phi), std::sqrt(std::max(0.0f, 1.0f - u1))));
  ray.org = offset_ray_origin(sp.p, sp.p_error, dot(ray.dir, ng_out) > 0.0f ? ng_out : -ng_out);
  ray.tmax = std::max(s.ao_bounces_distance, 0.0f);
  ray.time = time;
  ray.self_curve = scene.self_curve(sp);
  const Vec3 vis = scene.transmittance(ray, kShadowHits);
  if (is_black(vis)) return Vec3(0.0f);
  const Vec3 alpha = vmax(Vec3(0.0f), vmin(Vec3(1.0f), Vec3(1.0f) - cl.transparency()));
  return clamp_light(beta * alpha * vis, clamp) * weight * s.ao_additive_factor;
}

// The path tracer, compiled for the kernel features F (KernelFeature bits): what a scene does
// not use is left out with if constexpr; kKernelAll is the general kernel.
template <uint32_t F>
Vec3 trace_path_t(const Scene& scene, Ray ray, Sampler& sampler, const IntegratorSettings& s, PathCounters& c,
                  PathAovs* aov_in) {
  constexpr bool kMedia = (F & kKernelMedia) != 0;
  constexpr bool kAovs = (F & kKernelAovs) != 0;
  constexpr bool kNonDiffuse = (F & kKernelNonDiffuse) != 0;
  constexpr bool kEnv = (F & kKernelEnvironment) != 0;
  constexpr bool kTree = (F & kKernelLightTree) != 0;
  constexpr bool kSubsurface = (F & kKernelSubsurface) != 0;
  constexpr bool kGuide = (F & kKernelGuiding) != 0;
  constexpr bool kLinks = (F & kKernelLightLinks) != 0;
  constexpr bool kCatcher = (F & kKernelShadowCatcher) != 0;
  constexpr bool kCaus = (F & kKernelCaustics) != 0;
  // Clamping, Filter Glossy and the caustics toggles (the general kernels): without them the
  // clamp limits below are constant 0, and clamp_light leaves no code.
  constexpr bool kTricks = (F & kKernelTricks) != 0;
  // A bake's given first hit (PathCounters::first_hit): bake sessions run the general kernels
  // (Session forces them), so the others carry no load and branch per ray for it.
  constexpr bool kBake = (F & kKernelAll) == kKernelAll;
  // Cycles' Fast GI Approximation (the general kernels): without it none of its code is here.
  constexpr bool kFastGI = (F & kKernelFastGI) != 0;
  [[maybe_unused]] const int ao_bounces = kFastGI ? s.ao_bounces : 0;
  [[maybe_unused]] int ao_from_bounce = -1;  // the bounce whose AO ray started at ao_from
  [[maybe_unused]] Vec3 ao_from(0.0f);
  // The reach of an AO ray from the last surface hit (its object's AO Distance, else the world's;
  // the world's after a volume scattering), as Cycles' intersect_closest.
  [[maybe_unused]] float ao_reach = kFastGI ? s.ao_bounces_distance : 0.0f;
  // Caustic light tracing: the vertices of the path's L S+ D E prefix so far (0: it is not one),
  // and n Pc / Pa without the light's end: n d01^2 prod q_rev / (p_camera prod q_fwd).
  const CausticLight* const cz = kCaus ? s.caustics : nullptr;
  int cz_k = 0;
  float cz_ratio = 0.0f;
  Vec3 cz_ng(0.0f);  // the last vertex's geometric normal (CausticHitMis)
  bool cz_delta = false;  // the last vertex scattered by a delta lobe (glass, a mirror): no light sample there
  int cz_max = 0;  // the chain's vertices at most (the class's; less past a connection vertex's bounces)
  // Light-vertex connections (CausticLight::connections): the rough vertices so far, and where
  // the last vertex x connected, the vertices its BSDF ray's rough hit y may start (0: none).
  int lvc_rough = 0, lvc_next = 0;
  Pcg32 lrng;  // (the picks' own stream: the sampler's dimensions stay as they were)
  bool lrng_set = false;
  // (the catcher path of a split writes its passes into a scratch record: see below)
  PathAovs* aov = kAovs ? aov_in : nullptr;
  GuidingField* const guide = kGuide ? s.guide : nullptr;
  bool guide_sampling = false, guide_training = false;
  if constexpr (kGuide) {
    guide_sampling = guide && guide->ready();
    guide_training = guide && s.guide_training;
  }
  const float guide_prob = s.guide_probability;
  constexpr int kMaxGuideRecords = kGuide ? 16 : 0;
  std::array<GuideRecord, kMaxGuideRecords> rec;  // (none in the other kernels)
  int n_rec = 0;
  Vec3 L(0.0f), beta(1.0f);
  // Measurement only (guided kernels): the film keeps the light of the path classes in
  // class_mask (PathClass bits; 0: all), the guide still trains with all of it.
  const uint32_t class_mask = kGuide ? s.path_class_mask : 0u;
  Vec3 L_kept(0.0f), L_flushed(0.0f);
  PathClass path_class;
  const auto flush_class = [&]() {
    if ((class_mask >> path_class.id()) & 1u) L_kept += L - L_flushed;
    L_flushed = L;
  };
  float prev_pdf = 0.0f;    // solid-angle pdf of the BSDF sample that produced `ray`
  bool prev_delta = true;   // camera rays and delta lobes: no light sample could find the hit
  bool prev_samples_only = false;  // the last vertex found analytic lights by light samples only
  Vec3 mis_org = ray.org;   // the last vertex that scattered (light samples start there)
  Vec3 mis_n(0.0f);         // its shading normal (the light tree's choice depends on it)
                            // (without the tree: stays zero, unused)
  // Light linking: the light set of that vertex (media and the camera: the default 0).
  const bool links = kLinks && scene.features().light_links;
  uint8_t mis_set = 0;
  const bool nee = s.use_nee && scene.has_lights();
  // A constant world colour that is the only light is light-sampled (Scene::samples_world), by
  // the cosine about sky_n, the geometric normal of the last vertex that scattered (zero: it drew
  // no such sample). Besides lights it does not pay: docs/design/sampling.md "Sky samples".
  const bool sky = s.use_nee && !nee && scene.samples_world();
  Vec3 sky_n(0.0f);
  // Analytic lights with extent that rays may cross (lights never occlude: a ray finds every one
  // before its hit), and the kind of the ray for their visibility (the camera's runs on through
  // Transparent BSDFs).
  const bool hits = scene.features().light_hits;
  uint8_t ray_vis = kLightVisCamera;
  // Media that scatter or emit, or volume-only boundaries: distance sampling and shadow rays
  // through media (else the media kernel keeps plain Beer's law, as before volumes).
  const bool volumes = kMedia && scene.features().volumes;
  const bool terminator = scene.features().terminator;  // Cycles' shadow terminator offset
  int diffuse = 0, glossy = 0, transmission = 0, transparent = 0, volume_count = 0;
  // Volume-only boundaries crossed: not transparent bounces (Cycles' volume_bounds_bounce), only
  // bounded against a ray stuck on one surface (VOLUME_BOUNDS_MAX).
  int volume_bounds = 0;
  RayState ray_state;  // what the Light Path node reads: the kind of the last bounce, counts
  ray_state.camera = s.camera;
  ray_state.transparent_max = uint16_t(std::min(s.transparent_bounces, 65535));
  if (kBake && c.first_hit && c.first_dp >= 0.0f) ray_state.dp = c.first_dp, ray_state.dd = 0.0f;  // a baked texel's
  else if (s.camera && s.differentials) s.camera->differentials(ray.dir, ray_state.dp, ray_state.dd);  // the pixel's cone
  const uint64_t path_key = sampler.path_key();
  float length_before = 0.0f;  // Ray Length runs on through transparent crossings (as Cycles')
  bool emission_only = false;
  // A transparent crossing at p (Transparent BSDF, Ray Portal, volume-only boundary), counted as
  // Cycles' path_state_next: past Blender's Transparent max bounces (Cycles' kernel limit is the
  // setting + 1) the ray finds one more surface, for its emission only (Cycles'
  // PATH_RAY_TERMINATE_ON_NEXT_SURFACE); volume-only boundaries are not counted
  // (path_state_volume_next). False: a ray stuck on volume boundaries, to stop.
  const auto count_crossing = [&](const SurfacePoint& p) {
    const Material& m = scene.material(p.material);
    if (m.pass_through && m.program.has_medium()) return ++volume_bounds <= 1024;
    if (++transparent > s.transparent_bounces) emission_only = true;
    ray_state.transparent = uint16_t(std::min(transparent, 65535));  // the ray keeps its kind, as Cycles'
    return true;
  };
  Medium medium;
  // Heterogeneous media's own random numbers (delta and ratio tracking take as many as their
  // collisions need), one stream per path: the sampler's dimensions stay as they were.
  Pcg32 vrng;
  if constexpr (kMedia)
    if (volumes) vrng.set(path_key, 0x9E3779B97F4A7C15ULL);
  if constexpr (kMedia)
    if (volumes && scene.world_volume().has_medium()) {
      // A world Volume program is a heterogeneous layer over the scene's bounds (none: no bounds).
      const HeteroMedium* wh = scene.world_hetero();
      if (wh || !scene.world_volume().volume) medium.enter(kWorldMedium, scene.world_volume(), wh);
    }
  ClosureList cl;
  // The camera ray and its continuations through Transparent BSDFs: what it finds is "seen
  // directly" (transparent film, Emit, Env and the data passes).
  bool direct = true;
  // Cycles' PATH_RAY_TRANSPARENT_BACKGROUND: the world this path finds is the transparent film's
  // (camera rays, Transparent BSDFs, and with Transparent Glass smooth transmission too).
  bool film_bg = true;
  bool want_data = aov != nullptr, want_features = aov != nullptr;
  Vec3 feature_throughput(1.0f);
  // Light passes (PathAovs::light): the path's pass weights from its first scattering.
  const bool lp = kAovs && aov && s.light_passes;
  Vec3 lp_dw(0.0f), lp_gw(0.0f);
  bool lp_volume = false;
  // Light groups (PathAovs::groups, pass kernels only): each contribution to L from an emitter
  // in group g goes to lg[g] too, as it went to L (clamped alike). Null after a shadow catcher
  // split (Cycles writes no light group past PATH_RAY_SHADOW_CATCHER_HIT).
  Vec3* lg = kAovs && aov ? aov->groups : nullptr;
  const auto to_group = [&](int g, Vec3 v) {
    if constexpr (kAovs)
      if (lg && g >= 0 && g < s.light_groups) lg[g] += v;  // (a group the render keeps)
  };
  // light_hits' sink: the lights' own groups (NoGroupSink, doing nothing, in the other kernels).
  const auto hit_sink = [&]() {
    if constexpr (kAovs) return [&](uint32_t light, Vec3 v) { to_group(scene.light(light).light_group, v); };
    else return NoGroupSink{};
  }();
  int bounce = 0;
  // Clamping (clamp_light), as Cycles' bounce for film_clamp_light: a light sample at a vertex
  // after `bounce` scatterings is direct at the camera's first vertex (bounce 0); light a ray
  // finds, after `bounce` scatterings counting the one it left, is direct up to bounce 1 (the
  // camera's own, and the first vertex's ray). Transparent crossings are no scatterings.
  const float clamp_direct = kTricks ? s.clamp_direct : 0.0f, clamp_indirect = kTricks ? s.clamp_indirect : 0.0f;
  // Filter Glossy: the path's smallest BSDF pdf so far (Cycles' min_ray_pdf: of the unguided
  // BSDF or phase pdf at each scattering, a delta lobe's its probability times 1e6 as Cycles'
  // singular pdf; transparent crossings leave it). The caustics toggles: the last scattering
  // was by a diffuse lobe (Cycles' PATH_RAY_DIFFUSE; transparent crossings keep it).
  [[maybe_unused]] float blur_min_pdf = kInf;
  [[maybe_unused]] bool after_diffuse = false;
  [[maybe_unused]] const uint8_t caustics_off = kTricks ? s.caustics_off : uint8_t(0);
  [[maybe_unused]] const float filter_glossy = kTricks ? s.filter_glossy : 0.0f;
  // (an object that only the tricks kernels fill: lambdas capturing `bounce` cost the others)
  struct NoLimits {
    float sample() const { return 0.0f; }
    float found() const { return 0.0f; }
  };
  struct Limits {
    const int* bounce = nullptr;
    float direct = 0.0f, indirect = 0.0f;
    float sample() const { return *bounce > 0 ? indirect : direct; }
    float found() const { return *bounce > 1 ? indirect : direct; }
  };
  std::conditional_t<kTricks, Limits, NoLimits> lim;
  if constexpr (kTricks) lim = Limits{&bounce, clamp_direct, clamp_indirect};
  // Shadow catchers, as Cycles' integrator_split_shadow_catcher: the first catcher the camera
  // path meets directly splits it (after the media on the way to it, as Cycles' split after
  // shade_volume). The path goes on as it would without catchers (Combined); then a copy of it
  // taken at the split, in which no object but the catchers exists (its rays and shadow rays
  // pass everything else, and it is in no volume but the catchers' own: not the world's fog),
  // gives the catcher pass. The copy starts from the same state and random numbers, so the two
  // stay correlated as in Cycles.
  const bool catchers = kCatcher && aov && s.shadow_catcher;
  bool split = false, catcher_only = false, resume = false;
  struct Split {
    Vec3 beta, mis_org, mis_n, sky_n, feature_throughput, lp_dw, lp_gw;
    float prev_pdf, length_before;
    bool prev_delta, prev_samples_only, emission_only, direct, want_data, want_features, lp_volume;
    uint8_t mis_set, ray_vis;
    int diffuse, glossy, transmission, transparent, volume_count, bounce;
    RayState ray_state;
    Medium medium;
    Pcg32 vrng;
    Ray ray;
    Hit hit;
  };
  struct CatcherState {
    std::optional<Split> at;
    std::optional<Sampler> sampler;
    Vec3 L_combined{0.0f};
    std::optional<PathAovs> scratch;  // (made at a split only: zeroing one per path cost 2 %)
  };
  struct NoCatcher {};
  std::conditional_t<kCatcher, CatcherState, NoCatcher> cs;  // (nothing in the other kernels)
restart: __attribute__((unused));
  for (;;) {
    // Light a ray finds (emission, the world, lights it crosses): the camera's own goes to Emit
    // and Env, the ray after the first scattering's is direct. A light sample at a volume point
    // of this segment: the first scattering's, direct, or the path's component's, indirect.
    const auto lp_found = [&](Vec3 v) {
      if (bounce > 0) add_light_component(*aov, v, bounce == 1, lp_dw, lp_gw, lp_volume);
      else if (direct) aov->emission += v;
    };
    // Emission along a medium segment: Emit when the camera sees it, else as lp_found.
    const auto emit_found = [&](Vec3 v) {
      if (lp) lp_found(v);
      else if (direct) aov->emission += v;
    };
    const auto lp_volume_sample = [&](Vec3 v) {
      if (bounce == 0) add_light_component(*aov, v, true, Vec3(0.0f), Vec3(0.0f), true);
      else add_light_component(*aov, v, false, lp_dw, lp_gw, lp_volume);
    };
    Hit hit;
    ++c.rays;
    // Fast GI (Replace), Cycles' path_state_ao_bounce: past ao_bounces (less transmission, and
    // one glossy bounce) this ray reaches at most ao_bounces_distance from the vertex that sent
    // it (transparent crossings on the way count towards it, as Cycles keeps its origin).
    [[maybe_unused]] bool ao_ray = false;
    if constexpr (kFastGI)
      if (ao_bounces > 0 && bounce - transmission - (glossy > 0 ? 1 : 0) + 1 > ao_bounces) {
        ao_ray = true;
        if (ao_from_bounce != bounce) ao_from = ray.org, ao_from_bounce = bounce;
        const float left = ao_reach - length(ray.org - ao_from);
        ray.tmax = std::min(ray.tmax, std::max(left, 0.0f) / length(ray.dir));
      }
    // (the catcher path resumes at the split's hit; later rays see the catchers alone)
    bool found;
    if (kBake && __builtin_expect(c.first_hit != nullptr, 0)) {  // baking: the texel's surface
      hit = *c.first_hit, found = true;
      c.first_hit = nullptr;
    } else if constexpr (kCatcher) {
      if (resume) hit = cs.at->hit, found = true;
      else found = catcher_only ? scene.intersect_catchers(ray, hit) : scene.intersect(ray, hit);
      // Indirect Only objects: not there for camera rays (Cycles' visibility without
      // PATH_RAY_CAMERA); only this kernel steps past them (kernel_features), the others pay nothing.
      if (found && !resume && direct && scene.features().camera_invisible && scene.is_camera_invisible(hit.inst, hit.prim))
        found = scene.intersect_camera_visible(ray, hit);
    } else {
      found = scene.intersect(ray, hit);
    }
    Vec3 sigma(0.0f);
    const Vec3 beta_in = beta;           // (light hits: the throughput at the ray's origin)
    const MediumLayer* seg_medium = nullptr;
    Vec3 seg_sigma(0.0f);
    // The throughput to distance tl along this ray (world units) where the ray gets there.
    bool lights_counted = false;  // (a heterogeneous segment counts its lights itself)
    const auto through = [&](float tl) -> Vec3 {
      if constexpr (kMedia) {
        if (seg_medium) {
          const Vec3 st = seg_medium->sigma_a + seg_medium->sigma_s;
          if (is_black(seg_medium->sigma_s)) return beta_in * medium_transmittance(st, tl);
          const float pass = free_flight_survival(st, tl);
          return pass > 0.0f ? beta_in * medium_transmittance(st, tl) / pass : Vec3(0.0f);
        }
        if (!is_black(seg_sigma)) return beta_in * beer(seg_sigma, tl);
      }
      (void)tl;
      return beta_in;
    };
    if constexpr (kMedia) {
      sigma = kCatcher && resume ? Vec3(0.0f) : medium.current();  // (the split's segment is done)
      seg_sigma = sigma;
      const MediumLayer* m = kCatcher && resume ? nullptr : medium.top();
      if (m && volumes) seg_medium = m;
      // Light linking: the light set of the innermost volume's object (the world's: 0).
      const uint8_t vset = kLinks && links ? scene.light_set_of(medium.inner_instance()) : 0;
      if (m && volumes) {
        // A homogeneous medium: its emission along the segment (analytic), then a free-flight
        // distance that either scatters before the surface or reaches it.
        sigma = Vec3(0.0f);  // this surface's light samples go through shadow_transmittance
        const float len = length(ray.dir);
        const float seg = found ? hit.t * len : kInf;
        bool scatter = false;
        float nee_weight = 1.0f;  // the distance sample's share of the direct light (equiangular MIS)
        SegmentMis dist_mis;      // (volume_phase_mis: its light sample's and phase sample's weights)
        // The equiangular light sample waiting for its shadow ray (IntegratorSettings::
        // volume_shared_shadow): eq_w times what the ray finds, eq_value unshadowed.
        MediumLightSample eq_ls;
        Vec3 eq_w(0.0f), eq_value(0.0f);
        bool eq_pending = false;
        float t = 0.0f;
        Phase phase = m->phase;
        bool direct_done = false;  // the segment's light sample already taken (heterogeneous)
        float u_rr_seg = -1.0f;
        if (m->het) {
          // A heterogeneous medium: delta tracking through its majorants, emission by the
          // collision estimator (scene/medium_grid.h).
          const Vec3 d = ray.dir / len;
          MediumSample ms;
          int steps = 0;
          // Lights with extent along the whole segment, whatever the tracking does, each through
          // a ratio-tracking estimate of the transmittance to it (unbiased; the passes after the
          // segment and after a collision then add none). Then delta tracking.
          const auto track = [&](const auto& majorants, const auto& density) {
            const Vec3 L0 = L;
            if (hits && !(nee && !prev_delta && prev_samples_only)) {
              const auto through_het = [&](float tl) {
                return beta * ratio_track(majorants, ray.org, d, tl, vrng, density);
              };
              L += light_hits<kLinks, kTricks>(scene, ray, found ? hit.t : kInf, ray_vis, nee && !prev_delta, prev_pdf, mis_org,
                                      mis_n, through_het, mis_set, nullptr, lim.found(), hit_sink);
              lights_counted = true;
            }
            const Vec3 L1 = L;
            const bool r = delta_track(majorants, ray.org, d, seg, vrng, density, beta, &L, t, ms, steps);
            if (lim.found() > 0.0f) {
              // The segment's emission is one contribution (Cycles' film_write_volume_emission);
              // L is left as it was unless the clamp cuts it.
              const Vec3 e = L - L1, ec = clamp_light(e, lim.found());
              if (ec.x != e.x || ec.y != e.y || ec.z != e.z) L = L1 + ec;
            }
            // (its emission: the innermost layer's object's group, as Cycles writes a segment's
            // emission with one object's)
            if constexpr (kAovs)
              if (lg) to_group(scene.instance_light_group(medium.inner_instance()), L - L1);
            if (kAovs && aov) emit_found(L - L0);  // (the lights and the medium's emission)
            return r;
          };
          if (!medium.mixed) {
            const auto density = [&](float tt) { return scene.medium_at(*m->het, ray.org + d * tt, d, ray.time); };
            if (nee && !emission_only && s.volume_segment_nee && m->het->tight) {
              // The segment's light sample, at a distance drawn from the majorants' collision
              // density within it (every segment gets one, as in Cycles; delta tracking alone
              // lit only the paths that scattered, few where the smoke is thin), through a
              // ratio-tracked transmittance to it. The phase sample's share of the same light
              // stays with the path's own scattering below (the power heuristic's weights are
              // per point and direction, so the two parts still sum to the direct light).
              const Vec2 u_sel = sampler.get2d(), u_pt = sampler.get2d();
              u_rr_seg = u_sel.y;
              direct_done = true;
              float te, pe;
              if (sample_majorant_distance(m->het->grid, ray.org, d, seg, vrng.next_float(), te, pe)) {
                const MediumSample me = density(te);
                if (!is_black(me.sigma_s)) {
                  const Vec3 tr = ratio_track(m->het->grid, ray.org, d, te, vrng, density);
                  Vec3 ss = me.sigma_s;
                  const Phase pe_phase = me.n_lobes >= 2 ? choose_lobe(me.n_lobes, me.lobes, vrng.next_float(), ss) : me.phase;
                  if (!is_black(tr)) {
                    uint32_t entry = UINT32_MAX;
                    const Vec3 li = kAovs && lg ? medium_direct_entry(scene, ray.org + d * te, d, pe_phase,
                                                                      bounce >= s.max_bounces, medium, u_sel.x, u_pt,
                                                                      ray_state, ray.time, c, &vrng, vset, SegmentMis{},
                                                                      entry, kTricks ? bounce : -1)
                                                : medium_direct(scene, ray.org + d * te, d, pe_phase,
                                                                bounce >= s.max_bounces, medium, u_sel.x, u_pt,
                                                                ray_state, ray.time, c, &vrng, vset, SegmentMis{}, kTricks ? bounce : -1);
                    const Vec3 v = clamp_light(beta * tr * ss * li * (1.0f / pe), lim.sample());
                    L += v;
                    if constexpr (kAovs)
                      if (lg) to_group(scene.entry_light_group(entry), v);
                    if (kAovs && lp) lp_volume_sample(v);
                  }
                }
              }
            }
            scatter = track(m->het->grid, density);
            if (is_black(beta)) break;
            phase = ms.phase;
            if (scatter && ms.n_lobes >= 2) phase = choose_lobe(ms.n_lobes, ms.lobes, vrng.next_float(), beta);
          } else {
            // Overlapping layers, one of them heterogeneous: all of them summed per point.
            MediumStack stack(scene, medium, ray.org, d, ray.time);
            scatter = track(stack.majorants, [&](float tt) { return stack.at(tt); });
            if (is_black(beta)) break;
            if (scatter) phase = stack.choose_phase(vrng.next_float(), beta);
          }
        } else {
          if (!is_black(m->emission)) {
            const Vec3 v = clamp_light(beta * medium_emission(*m, seg), lim.found());
            L += v;
            if constexpr (kAovs)
              if (aov) emit_found(v);
            if constexpr (kAovs)
              if (lg) {
                // Each layer's share (the emission is linear in each layer's): its object's group.
                if (medium.n == 1) {
                  to_group(scene.instance_light_group(medium.layer[0].instance), v);
                } else {
                  for (int i = 0; i < medium.n; ++i)
                    if (!is_black(medium.layer[i].emission))
                      to_group(scene.instance_light_group(medium.layer[i].instance),
                               v * safe_ratio(medium.layer[i].emission, m->emission));
                }
              }
          }
          const Vec3 st = m->sigma_a + m->sigma_s;
          if (!is_black(m->sigma_s)) {
            // Direct light by equiangular distances too (Cycles' default volume sampling, Multiple
            // Importance): a point c on a light, sampled from the segment's start, draws a second
            // scattering point crowded near it, whose light sample is weighted against the distance
            // sample's by the power heuristic over the two distance densities (the light-sample
            // and phase MIS at each point is the same for both, so the two share its direct-light
            // share exactly). Random numbers from the path's own stream: the sampler's dimensions
            // stay as they were.
            EquiangularSegment eq;
            if (nee && !emission_only) {
              const Vec3 d = ray.dir / len;
              const float uc = vrng.next_float();
              const Vec2 uc2{vrng.next_float(), vrng.next_float()};
              Vec3 cref;
              float t0 = 0.0f, t1 = seg;  // where the light can reach along the segment
              if (scene.light_reference_point(ray.org, d, uc, uc2, cref, t0, t1)) {
                if (!s.volume_light_reach) t0 = 0.0f, t1 = seg;
                eq = equiangular_segment(ray.org, d, t0, t1, cref);
              }
              if (eq.valid) {
                const float te = sample_equiangular(eq, vrng.next_float());
                const float pe = equiangular_pdf(eq, te), pd = free_flight_pdf(st, te);
                if (te >= 0.0f && te < seg && pe > 0.0f && std::isfinite(pe)) {
                  const Vec2 ue{vrng.next_float(), vrng.next_float()};
                  Vec3 ss = m->sigma_s;
                  const Phase pe_phase = medium.phases_differ ? medium.choose_phase(vrng.next_float(), ss) : m->phase;
                  // (one phase function for both points, or the phase sample's pdf differs)
                  const bool three = s.volume_phase_mis && !medium.phases_differ;
                  const SegmentMis eq_mis = three ? SegmentMis::at_equiangular(pd, pe) : SegmentMis{};
                  const Vec3 w = beta * ss * medium_transmittance(st, te) *
                                 (three ? 1.0f / pe : pe / (pe * pe + pd * pd));
                  if (s.volume_shared_shadow) {
                    // Traced below: alone, or sharing one shadow ray with the distance sample's.
                    if (medium_light_sample(scene, ray.org + d * te, d, pe_phase, bounce >= s.max_bounces,
                                            vrng.next_float(), ue, ray_state, ray.time, eq_ls, vset, eq_mis, kTricks ? bounce : -1)) {
                      eq_w = w;
                      eq_value = w * eq_ls.li * eq_ls.factor;
                      eq_pending = !is_black(eq_value);
                    }
                  } else {
                    uint32_t entry = UINT32_MAX;
                    const Vec3 li = kAovs && lg
                                        ? medium_direct_entry(scene, ray.org + d * te, d, pe_phase, bounce >= s.max_bounces,
                                                              medium, vrng.next_float(), ue, ray_state, ray.time, c, &vrng,
                                                              vset, eq_mis, entry, kTricks ? bounce : -1)
                                        : medium_direct(scene, ray.org + d * te, d, pe_phase, bounce >= s.max_bounces,
                                                        medium, vrng.next_float(), ue, ray_state, ray.time, c, &vrng, vset,
                                                        eq_mis, kTricks ? bounce : -1);
                    const Vec3 v = clamp_light(w * li, lim.sample());
                    L += v;
                    if constexpr (kAovs)
                      if (lg) to_group(scene.entry_light_group(entry), v);
                    if (kAovs && lp) lp_volume_sample(v);
                  }
                }
              }
            }
            const Vec2 ud = sampler.get2d();
            t = sample_free_flight(st, ud.x, ud.y);
            const float pdf_t = t < seg ? free_flight_pdf(st, t) : 0.0f;
            if (eq_pending && !(pdf_t > 0.0f)) {  // no scattering here: the equiangular sample alone
              const Vec3 v = clamp_light(eq_w * medium_light_trace(scene, eq_ls, medium, c, &vrng), lim.sample());
              L += v;
              if constexpr (kAovs)
                if (lg) to_group(scene.entry_light_group(eq_ls.entry), v);
              if (kAovs && lp) lp_volume_sample(v);
              eq_pending = false;
            }
            if (t < seg) {
              if (eq.valid) {
                const float pd = free_flight_pdf(st, t), pe = equiangular_pdf(eq, t);
                if (s.volume_phase_mis && !medium.phases_differ) {
                  if (pe > 0.0f) dist_mis = SegmentMis::at_distance(pd, pe);
                } else {
                  nee_weight = pd * pd / (pd * pd + pe * pe);
                }
              }
              if (hits && !(nee && !prev_delta && prev_samples_only)) {
                const Vec3 v = light_hits<kLinks, kTricks>(scene, ray, t / len, ray_vis, nee && !prev_delta, prev_pdf, mis_org, mis_n,
                                                  through, mis_set, nullptr, lim.found(), hit_sink);
                L += v;
                if (kAovs && lp) lp_found(v);
              }
              const float pdf = pdf_t;
              if (!(pdf > 0.0f)) break;
              beta *= m->sigma_s * medium_transmittance(st, t) / pdf;
              scatter = true;
              if (medium.phases_differ) phase = medium.choose_phase(vrng.next_float(), beta);
            } else {
              const float pass = free_flight_survival(st, seg);
              if (!(pass > 0.0f)) break;
              beta *= medium_transmittance(st, seg) / pass;
            }
          } else if (!is_black(st)) {
            beta *= medium_transmittance(st, seg);
          }
        }
        if (scatter) {
          if (emission_only) break;
          const Vec3 d = ray.dir / len;
          const Vec3 p = ray.org + d * t;
          direct = false;
          film_bg = false;
          want_data = false;
          const bool last = bounce >= s.max_bounces;
          float u_rr = u_rr_seg;
          const Vec3 L_scatter = L;
          if (nee && !direct_done) {  // a light sample, weighted against the phase function's sample
            const Vec2 u_sel = sampler.get2d();
            u_rr = u_sel.y;
            const Vec2 u_pt = sampler.get2d();
            if (eq_pending) {
              // Two light samples, one shadow ray: traced for one of them, picked with probability
              // proportional to its unshadowed contribution and divided by that probability, so
              // the sum of both is estimated without bias; where both see the light alike (fog
              // without occluders) that costs almost no variance (docs/design/volumes.md).
              MediumLightSample ls;
              Vec3 value(0.0f);
              if (medium_light_sample(scene, p, d, phase, last, u_sel.x, u_pt, ray_state, ray.time, ls, vset, dist_mis, kTricks ? bounce : -1))
                value = beta * nee_weight * ls.li * ls.factor;
              const float a_d = average(vabs(value)), a_e = average(vabs(eq_value));
              const float p_d = a_d + a_e > 0.0f ? a_d / (a_d + a_e) : 0.0f;
              if (vrng.next_float() < p_d) {
                const Vec3 v = clamp_light(beta * nee_weight * medium_light_trace(scene, ls, medium, c, &vrng) * (1.0f / p_d),
                                           lim.sample());
                L += v;
                if constexpr (kAovs)
                  if (lg) to_group(scene.entry_light_group(ls.entry), v);
              } else {
                const Vec3 v = clamp_light(eq_w * medium_light_trace(scene, eq_ls, medium, c, &vrng) * (1.0f / (1.0f - p_d)),
                                           lim.sample());
                L += v;
                if constexpr (kAovs)
                  if (lg) to_group(scene.entry_light_group(eq_ls.entry), v);
              }
            } else {
              uint32_t entry = UINT32_MAX;
              const Vec3 li = kAovs && lg ? medium_direct_entry(scene, p, d, phase, last, medium, u_sel.x, u_pt, ray_state,
                                                                ray.time, c, &vrng, vset, dist_mis, entry, kTricks ? bounce : -1)
                                          : medium_direct(scene, p, d, phase, last, medium, u_sel.x, u_pt, ray_state,
                                                          ray.time, c, &vrng, vset, dist_mis, kTricks ? bounce : -1);
              const Vec3 v = clamp_light(beta * li * nee_weight, lim.sample());
              L += v;
              if constexpr (kAovs)
                if (lg) to_group(scene.entry_light_group(entry), v);
            }
          }
          if (kAovs && lp) lp_volume_sample(L - L_scatter);
          if (last && nee) break;
          const Vec2 u = sampler.get2d();
          float ph_pdf;
          const Vec3 wi = phase_sample(phase, d, u.x, u.y, ph_pdf);  // exact: the weight is 1
          if (!(ph_pdf > 0.0f)) break;
          prev_pdf = ph_pdf * dist_mis.phase_pdf_scale();  // (its weight against lights it finds)
          prev_delta = false;
          prev_samples_only = false;
          ray_vis = kLightVisVolume;
          if constexpr (kFastGI) ao_reach = s.ao_bounces_distance;
          if (kAovs && lp && bounce == 0) lp_volume = true;
          mis_org = p;
          mis_n = Vec3(0.0f);  // a medium point has no normal: the tree chose without one
          sky_n = Vec3(0.0f);  // nor did it sample the sky
          mis_set = vset;
          // Past Volume bounces the phase ray still collects emission, then stops (as lobes).
          if (volume_count >= s.volume_bounces) emission_only = true;
          ++volume_count;
          ++bounce;
          ray_state.dp += (length_before + t) * ray_state.dd;  // the footprint at the scattering
          length_before = 0.0f;
          if (s.path_state) {
            ray_state.min_pdf = std::min(ray_state.min_pdf, ph_pdf);
            ray_state.flags = kRayVolume;
            ray_state.depth = uint16_t(std::min(bounce, 65535));
          }
          if constexpr (kTricks) {  // (Cycles' shade_volume: the phase pdf; a volume scattering is not diffuse)
            blur_min_pdf = std::min(blur_min_pdf, ph_pdf);
            after_diffuse = false;
          }
          if (last) emission_only = true;
          if (bounce >= s.rr_start_bounce) {  // as at surfaces, below
            const float survive = std::min(1.0f, std::sqrt(max_component(vabs(beta))));
            if (sampler.own_roulette()) u_rr = sampler.roulette(bounce);
            else if (u_rr < 0.0f) u_rr = sampler.get2d().x;
            if (!(survive > 0.0f) || u_rr >= survive) break;
            beta = beta / survive;
          }
          if (!is_finite(beta)) break;
          ray.org = p;
          ray.dir = wi;
          ray.tmax = kInf;
          ray.self_curve = UINT32_MAX;  // scattered in the medium: it leaves no strand
          continue;
        }
      } else if (!is_black(sigma)) {
        beta *= beer(sigma, found ? hit.t * length(ray.dir) : kInf);
      }
    }
    if (hits && !lights_counted && !(nee && !prev_delta && prev_samples_only) && !(kCatcher && resume)) {
      CausticHitMis chm;
      if constexpr (kCaus)
        if (cz_k >= 2 && (!prev_delta || cz_delta) && !cz->lamps.empty()) chm = {cz, cz_ratio, cz_ng, prev_delta};
      const float t_end = found ? hit.t : (kFastGI && ao_ray ? -ray.tmax : kInf);
      const Vec3 lh = light_hits<kLinks, kTricks, kFastGI>(scene, ray, t_end, ray_vis, nee && !prev_delta, prev_pdf,
                                         mis_org, mis_n, through, mis_set, chm.cz ? &chm : nullptr, lim.found(),
                                         hit_sink);
      L += lh;
      if constexpr (kAovs) {
        if (lp) lp_found(lh);
        else if (direct && aov) aov->emission += lh;  // lights seen by the camera: the Emit pass, as emitters
      }
    }
    if (!found) {
      // Escaped: the world, weighted against the environment light sample that could find it
      // (without an environment that pdf is 0 and the weight 1).
      float w = 1.0f;
      Vec3 bg;
      bool bg_found = false;
      float env_pdf = 0.0f;
      if constexpr (kEnv)
        if (nee && !prev_delta) {
          bg = scene.background_with_pdf(ray.dir, mis_org, mis_set, env_pdf, &ray_state, &ray.org);
          bg_found = true;
          w = power_heuristic(prev_pdf, env_pdf);
        }
      if constexpr (kCaus)
        if (cz_k >= 2 && (!prev_delta || cz_delta)) {
          // (after a delta vertex no light sample rivals the BSDF's ray: eb is 0)
          const float ps = caustic_source_pdf(scene, *cz, ray.dir, mis_org);
          if (ps > 0.0f) {
            const float rho = cz_ratio * ps, eb = bg_found ? env_pdf / prev_pdf : 0.0f;  // n Pc / Pa, Pb / Pa
            w = caustic_mis_weight(eb, rho);
          }
        }
      if (sky && !prev_delta) {
        const float cos_sky = dot(ray.dir, sky_n);  // (a scattered ray's direction is a unit vector)
        if (cos_sky > 0.0f) w = power_heuristic(prev_pdf, cos_sky * kInvPi);
      }
      if (!bg_found) bg = scene.background(ray.dir, &ray_state, &ray.org);
      // Fast GI (Replace): the world an AO ray reaches, times ao_factor (Cycles' integrate_background).
      if constexpr (kFastGI)
        if (ao_ray) bg = bg * s.ao_factor;
      // (each use clamped where it is made, as before clamping: a shared value cost the surfaces
      // kernel without clamping 0.2 % instructions)
      if constexpr (kAovs) {
        if (direct && aov) aov->environment = clamp_light(beta * bg, lim.found());
        // Alpha is 1 less what reaches the film transparently (the world and holdouts).
        const bool film_world = film_bg && s.transparent_background;
        if (film_world && aov) aov->alpha = clampf(aov->alpha - average(beta), 0.0f, 1.0f);
        const Vec3 bg_value = clamp_light(beta * bg * w, lim.found());
        if (!film_world) L += bg_value;
        if (lp && bounce > 0 && !film_world) lp_found(bg_value);
        // (on a transparent film the world seen directly is not in Combined, but Cycles evaluates
        // it and writes it to the world's group where the Env pass is on: integrate_background)
        if (lg && (!film_world || s.groups_transparent_world))
          to_group(scene.world_light_group(), bg_value);
      } else {
        L += clamp_light(beta * bg * w, lim.found());  // transparent film always comes with the aov kernel
      }
      break;
    }
    if constexpr (kCatcher) {
      if (resume) {
        resume = false;
      } else if (catchers && direct && !split && scene.is_catcher(hit.inst, hit.prim)) {
        // The split, before the catcher is shaded: what the path found so far is the matte's,
        // and the split itself counts as transparent there (film_write_shadow_catcher_bounce_data).
        split = true;
        lg = nullptr;  // (no light groups past a catcher, as Cycles)
        aov->catcher_samples = 1.0f;
        aov->matte = L;
        aov->matte_alpha = clampf(aov->alpha - average(beta), 0.0f, 1.0f);
        if (s.catcher_background) aov->environment += clamp_light(beta * scene.background(ray.dir, &ray_state, &ray.org), lim.found());
        cs.at = Split{beta, mis_org, mis_n, sky_n, feature_throughput, lp_dw, lp_gw, prev_pdf,
                         length_before, prev_delta, prev_samples_only, emission_only, direct, want_data,
                         want_features, lp_volume, mis_set, ray_vis, diffuse, glossy, transmission, transparent,
                         volume_count, bounce, ray_state, medium, vrng, ray, hit};
        cs.sampler = sampler;
      }
    }
    // A holdout object seen directly, as Cycles' integrate_surface_holdout with
    // SD_OBJECT_HOLDOUT_MASK: the film is transparent where it is, and the path ends there.
    if constexpr (kAovs)
      if (film_bg && aov && scene.features().object_holdout && scene.is_object_holdout(hit.inst, hit.prim)) {
        aov->alpha = clampf(aov->alpha - average(beta), 0.0f, 1.0f);
        break;
      }
    SurfacePoint sp;
    scene.surface_point(hit, sp, ray.time, &ray);
    if constexpr (kFastGI)
      if (ao_bounces > 0) {
        const float d = scene.object_info(sp).ao_distance;
        ao_reach = d > 0.0f ? d : s.ao_bounces_distance;
      }
    if constexpr (kMedia && kNonDiffuse && !kGuide && !kCatcher) {
      // A volume-only boundary (Material::pass_through), crossed as its Transparent closure
      // would be but without shading it, in the same arithmetic and with the same sample
      // dimensions drawn: the same image (Cycles likewise skips SD_HAS_ONLY_VOLUME surfaces).
      if (volumes && s.volume_pass_through && !(kAovs && aov) && scene.material(sp.material).pass_through) {
        if (s.path_state || s.differentials) ray_state.length = length_before + hit.t * length(ray.dir);
        if (s.path_state) ray_state.rng = uint32_t(mix64(path_key + uint64_t(bounce)));
        ray_state.emission_only = emission_only;
        if (emission_only) break;
        if (bounce >= s.max_bounces && (nee || sky)) break;  // (the last vertex: light samples only)
        sampler.skip2d();  // the closure choice's and the lobe's numbers
        sampler.skip2d();
        const Vec3 wo = -ray.dir;
        const bool front = dot(sp.ng, wo) > 0.0f;
        const Vec3 ng_out = front ? sp.ng : -sp.ng;
        const Frame f = Frame::from_normal(sp.ns);
        const Vec3 wi = f.to_world(-f.to_local(wo));
        if (dot(wi, ng_out) > 0.0f) break;
        if (!count_crossing(sp)) break;
        length_before = ray_state.length;
        medium.cross(scene, sp, front);
        if (!is_finite(beta)) break;
        ray.org = offset_ray_origin(sp.p, sp.p_error, -ng_out);
        ray.self_curve = scene.self_curve(sp);
        ray.dir = wi;
        ray.tmax = kInf;
        continue;
      }
    }
    Vec3 wo = -ray.dir;  // (a subsurface exit moves the vertex: see below)
    // (the footprint grows with the length too)
    if (s.path_state || s.differentials) ray_state.length = length_before + hit.t * length(ray.dir);
    if (s.path_state) ray_state.rng = uint32_t(mix64(path_key + uint64_t(bounce)));
    ray_state.emission_only = emission_only;
    if constexpr (kAovs) ray_state.aovs = aov && direct && want_data ? aov->shader_aovs : nullptr;
    if constexpr (kTricks) cl.caustics_off = after_diffuse ? caustics_off : uint8_t(0);
    scene.shade(sp, hit.b1, hit.b2, wo, cl, ray_state);
    if constexpr (kAovs) ray_state.aovs = nullptr;
    if constexpr (kTricks) {
      // The caustics toggles (a constant material's cached closures: the rest were made without
      // what they exclude), then Filter Glossy (Cycles' surface_shader_prepare_closures): the
      // closures every use below samples and evaluates, light samples and MIS included.
      if (cl.caustics_off) cl.filter_caustics();
      const float blur = filter_glossy_roughness(filter_glossy, blur_min_pdf);
      if (blur > 0.0f) cl.blur(blur);
    }

    // Light linking, as Cycles: rays other than the camera's get no emission from a mesh light not
    // linked to the vertex they left, nor from a shadow-linked one (its light samples have the
    // full weight: Cycles reaches it by dedicated rays instead).
    // Curves and point clouds as emitters too (their set's masks; Cycles' light_link_object_match
    // of any object), though no light sample reaches them.
    if constexpr (kLinks)
      if (links && !direct && !is_black(cl.emission)) {
        const bool set_of_object = sp.curve() || sp.point();
        const uint64_t lm = set_of_object ? scene.object_info(sp).light_mask : scene.emitter_light_mask(sp.instance);
        const uint64_t sm = set_of_object ? scene.object_info(sp).shadow_mask : scene.emitter_shadow_mask(sp.instance);
        if (!((lm >> mis_set) & 1u) || sm != kAllLightSets) cl.emission = Vec3(0.0f);
      }
    // Emission found by the BSDF ray: weighted against the light sample that could have found it.
    if (!is_black(cl.emission)) {
      float w = 1.0f;
      if (nee && !prev_delta) {
        // Seen from the last real scattering: transparent crossings in between are part of the
        // same light-sample segment (which saw them through its transmittance).
        w = power_heuristic(prev_pdf, scene.pdf_emitter(sp, mis_org, sp.p, std::fabs(dot(sp.ng, wo)), mis_n, mis_set));
      }
      L += clamp_light(beta * cl.emission * w, lim.found());
      if constexpr (kAovs) {
        const Vec3 v = clamp_light(beta * cl.emission * w, lim.found());
        if (direct && aov) aov->emission += clamp_light(beta * cl.emission, lim.found());
        else if (lp) lp_found(v);
        if (lg) to_group(scene.object_info(sp).light_group, v);  // (the object's, whatever its material)
      }
    }
    // Holdout seen directly (also through Transparent BSDFs), as Cycles' film_write_holdout:
    // its weight times the throughput leaves the film transparent; other closures go on.
    if constexpr (kAovs)
      if (film_bg && aov && !is_black(cl.holdout)) aov->alpha = clampf(aov->alpha - average(beta * cl.holdout), 0.0f, 1.0f);
    if (kAovs && aov && (want_data || want_features)) {
      const bool flip = dot(sp.ng, wo) < 0.0f;  // normals face the viewer, as Cycles' sd->N
      if (want_data && direct) {
        const Vec3 transparency = cl.transparency();
        if (average(transparency) <= 0.5f) {  // Cycles' default pass alpha threshold
          want_data = false;
          aov->hit = true;
          aov->position = sp.p;
          // Cycles' surface_shader_average_normal: the closures' normals (bump and normal maps
          // included) weighted by their mean weights; the surface's own without any.
          Vec3 an(0.0f);
          for (int i = 0; i < cl.n; ++i) an += cl.c[size_t(i)].frame.n * std::fabs(average(cl.c[size_t(i)].weight));
          const float al = length(an);
          const Vec3 n = al > 0.0f && std::isfinite(al) ? an / al : sp.ns;
          aov->normal = flip ? -n : n;
          if (s.indices) {
            aov->object_index = scene.object_pass_index(sp);
            aov->material_index = scene.material(sp.material).pass_index;
          }
          if (s.uv_pass) aov->uv = scene.pass_uv(sp, s.uv_set);
          if (s.vector_pass) scene.pass_motion(sp, aov->motion_pre, aov->motion_post);
        }
      }
      if (want_features) {
        Vec3 n, diffuse, specular;
        if (denoising_features(cl, wo, flip, n, diffuse, specular)) {
          want_features = false;
          aov->denoising_normal = n;
          aov->denoising_albedo = feature_throughput * diffuse;
        } else {
          feature_throughput *= specular;
        }
      }
    }
    if constexpr (kAovs)
      if (aov && direct && s.cryptomatte && aov->crypto_count < kMaxCryptoHits) {
        // Every surface the camera ray meets, as Cycles' film_write_data_passes: weighted by
        // the throughput to it and by its own opacity (its Transparent closures let the rest on).
        const float weight = average(beta) * (1.0f - average(cl.transparency()));
        if (weight > 0.0f) {
          const ObjectInfo& info = scene.object_info(sp);
          aov->crypto[aov->crypto_count++] = {info.crypto_object, scene.material(sp.material).crypto, info.crypto_asset,
                                              weight};
        }
      }
    if constexpr (kAovs)
      if (aov && direct && (lp || s.mist || s.ao)) camera_hit_passes(scene, s, sp, cl, wo, beta, path_key, transparent, ray.time, lp, *aov);
    if constexpr (kFastGI)
      if (ao_ray) {
        // Fast GI (Replace), Cycles' integrator_intersect_terminate: a surface the AO ray reaches
        // ends the path; one with emission or transparency is shaded for those alone (its
        // emission above; PATH_RAY_TERMINATE_AFTER_TRANSPARENT), and its transparency goes on.
        const Vec3 tr = cl.transparency();
        if (emission_only || is_black(tr)) break;
        beta *= tr;
        if (!is_finite(beta) || !count_crossing(sp)) break;
        length_before = ray_state.length;
        const bool front_ao = dot(sp.ng, wo) > 0.0f;
        if constexpr (kMedia) medium.cross(scene, sp, front_ao);
        ray.org = offset_ray_origin(sp.p, sp.p_error, front_ao ? -sp.ng : sp.ng);
        ray.self_curve = scene.self_curve(sp);
        ray.tmax = kInf;
        continue;
      }
    if (emission_only || cl.n == 0) break;

    if constexpr (kCaus) {
      if (cz) {
        if (bounce == 0 && transparent == 0 && caustic_vertex(sp, cl) && guidable(cl)) {
          // The camera's first vertex, rough: the light tracer's connection vertex.
          // (a thin lens: from the lens point this camera ray left, back from the near clip;
          // motion blur: the camera's frame at the ray's shutter time, as the light path's)
          const Camera& cc = *cz->camera;
          const Camera::Frame fr = cc.frame_at(ray.time);
          const Vec3 eye = cc.has_aperture() ? ray.org - ray.dir * (cc.clip_start() / dot(ray.dir, -fr.back))
                                             : fr.origin;
          const float d01 = length(sp.p - eye);
          // (a panorama's sample where no light path splats: a filter's tail past its seam)
          cz_k = c.caustic_raster ? 1 : 0;
          // The camera's density is this sample's pixel filter density (the caller's
          // c.filter_area is its inverse) over the pixel's solid angle: the light tracer weighs
          // its splat into this pixel with the same (trace_caustic_paths). A thin lens's
          // lens point has the same density on both sides: it cancels. (An orthographic
          // camera's lens_pixel_pdf / d01^2 is its density per unit area across the ray.)
          cz_ratio = cz->paths * d01 * d01 * c.filter_area / cc.lens_pixel_pdf(fr, ray.dir, d01);
          cz_max = cz->max_vertices;
          if (!std::isfinite(cz_ratio)) cz_k = 0;
        } else if (cz_k > 0 && cz_k < cz_max && caustic_vertex(sp, cl) && !guidable(cl)) {
          ++cz_k;  // a smooth vertex after it
        } else if (lvc_next > 0 && !prev_delta && caustic_vertex(sp, cl) && guidable(cl)) {
          // A rough vertex y that the BSDF ray of a connecting rough vertex x (mis_org) found:
          // the light-vertex connection's y (docs/design/sampling.md, "Caustics seen after
          // further rough bounces"). Its n Pd / Pa without the light's end: the connection's
          // count d_xy^2 / (x's pdf towards y, the guided mixture's where guided), the camera's
          // ratio with x in the camera's place.
          cz_k = 1;
          cz_max = lvc_next;
          cz_ratio = cz->connection_count * length_sq(sp.p - mis_org) / prev_pdf;
          if (!std::isfinite(cz_ratio) || !(prev_pdf > 0.0f)) cz_k = 0;
        } else {
          cz_k = 0;
        }
        lvc_next = 0;
      }
    }
    bool sss_exit = false;  // a random walk has just left the object: scatter at its exit
  scatter:  // a subsurface exit point scatters from here on, with a diffuse closure
    const bool front = dot(sp.ng, wo) > 0.0f;
    const Vec3 ng_out = front ? sp.ng : -sp.ng;  // geometric normal on the viewer's side
    // The last vertex that scatters: no BSDF ray follows, so light samples take all the weight.
    const bool last = bounce >= s.max_bounces;
    const bool samples_only = hits && lights_by_samples_only(cl);
    float u_rr = -1.0f;
    bool guided = false;  // this vertex samples the guide too (one-sample MIS with the BSDF)
    uint32_t guide_cell = 0;
    int32_t caustic_cell = -1;  // the vertex's caustic lobes (GuidingField::caustic_cell; -1: none)
    // The mixture's pdf towards w: BSDF and SD-tree guide, and the caustic lobes where there are
    // some (sd_pdf: the SD-tree's pdf where known, else negative).
    float gp = guide_prob;  // this vertex's guide probability (learnt per cell, or the render's)
    const auto guided_pdf = [&](float bsdf_pdf, Vec3 w, float sd_pdf) {
      return guided_mixture_pdf(*guide, bsdf_pdf, w, gp, guide_cell, sd_pdf, caustic_cell, s.guide_caustic_probability);
    };
    if constexpr (kGuide) {
      guided = guide && (guide_sampling || guide_training) && !sp.curve() && guidable(cl);
      if (guided) guide_cell = guide->cell_of(sp.p, ng_out);
      if (guided && s.guide_learn_probability) gp = guide->probability(guide_cell);
      if (guided && guide_sampling && s.guide_caustic_probability > 0.0f) caustic_cell = guide->caustic_cell(sp.p, ng_out);
      if (class_mask) {  // what came before this vertex is done; its light samples on are one vertex longer
        flush_class();
        path_class.append(!sp.curve() && guidable(cl));
      }
    }
    if constexpr (kCaus)
      if (cz && cz->connections > 0 && !last && !sp.curve() && caustic_vertex(sp, cl) && guidable(cl) &&
          ++lvc_rough <= cz->connections) {
        // A light-vertex connection (docs/design/sampling.md, "Caustics seen after further rough
        // bounces"): x here, y a rough vertex of this pixel sample's light paths, for the path
        // L S+ y x .. E. The path tracer makes it only within the bounce limits: y, its chain
        // and the light sample at its end must fit after x (the counts as if every later vertex
        // took each kind), and it weighs its own such paths alike (lvc_next, above).
        const int kmax = std::min({cz->max_vertices, s.max_bounces - bounce - 1, s.glossy_bounces - glossy,
                                   s.transmission_bounces - transmission});
        const CausticCache* cache = c.caustic_cache;
        if (kmax >= 2 && diffuse + 2 <= s.diffuse_bounces) {
          lvc_next = kmax;
          if (cache && !cache->v.empty() && cache->paths > 0) {
            if (!lrng_set) {
              lrng.set(path_key, 0x3C0DE5EEDULL);
              lrng_set = true;
            }
            // One of the m vertices, uniformly, weighed by m / paths: each light path's y once
            // in expectation, so the estimate is unbiased whatever m came out; the heuristic
            // takes the fixed connection_count, never this pass's m.
            const uint64_t m = cache->v.size();
            const uint64_t u64 = (uint64_t(lrng.next_u32()) << 32) | lrng.next_u32();
            const CausticVertex& v = cache->v[size_t((unsigned __int128)u64 * m >> 64)];
            const Vec3 dxy = v.sp.p - sp.p;
            const float d2 = length_sq(dxy);
            const Vec3 w = dxy / std::sqrt(d2);
            const bool refl_x = dot(w, ng_out) > 0.0f;
            float px;
            const Vec3 fx = v.k <= kmax && d2 > 0.0f ? eval_mixture<!kNonDiffuse>(cl, wo, w, refl_x, px) : Vec3(0.0f);
            if (!is_black(fx) && px > 0.0f) {
              if constexpr (kGuide)
                if (guided && guide_sampling) px = guided_pdf(px, w, -1.0f);
              // y shaded from x's side, as the path tracer's BSDF ray from x would shade it.
              ClosureList cy;
              RayState ry;
              ry.flags = uint8_t(kRayReflect | kRayGlossy);
              scene.shade(v.sp, v.sp.b1, v.sp.b2, -w, cy, ry);
              const float cyx = dot(v.sp.ng, -w), cyl = dot(v.sp.ng, v.wl);
              float qy = 0.0f;
              Vec3 fy(0.0f);
              if (caustic_vertex(v.sp, cy) && guidable(cy) && cyx != 0.0f && cyl != 0.0f)
                fy = eval_mixture<!kNonDiffuse>(cy, -w, v.wl, (cyx > 0.0f) == (cyl > 0.0f), qy);
              if constexpr (kGuide)
                if (guide_sampling && qy > 0.0f) {
                  // (y's guided mixture towards the chain, at its cell facing x)
                  const Vec3 ny = cyx > 0.0f ? v.sp.ng : -v.sp.ng;
                  const uint32_t cell = guide->cell_of(v.sp.p, ny);
                  const float gpy = s.guide_learn_probability ? guide->probability(cell) : guide_prob;
                  const int32_t ccy = s.guide_caustic_probability > 0.0f ? guide->caustic_cell(v.sp.p, ny) : -1;
                  qy = guided_mixture_pdf(*guide, qy, v.wl, gpy, cell, -1.0f, ccy, s.guide_caustic_probability);
                }
              if (!is_black(fy) && qy > 0.0f) {
                Ray sh;
                sh.time = ray.time;
                sh.org = offset_ray_origin(sp.p, sp.p_error, refl_x ? ng_out : -ng_out);
                sh.self_curve = scene.self_curve(sp);
                sh.dir = offset_ray_origin(v.sp.p, v.sp.p_error, cyx > 0.0f ? v.sp.ng : -v.sp.ng) - sh.org;
                sh.tmax = 1.0f - 1e-4f;
                ++c.rays;
                if (!scene.occluded(sh)) {
                  // The power heuristic over the light sample at the chain's end (eb), the path
                  // tracer's BSDF ray (1) and this connection (rho = count Pl / Pa).
                  const double rho = double(cz->connection_count) * v.lr * d2 / (double(px) * qy);
                  const double rho2 = rho * rho;
                  const float wd = float(rho2 / (1.0 + double(v.eb) * v.eb + rho2));
                  // (its light arrives at x after y's scattering: indirect)
                  const Vec3 add = clamp_light(beta * fx * fy * v.beta *
                                                   (std::fabs(cyx) / (d2 * std::fabs(cyl)) * wd *
                                                    float(double(m) / double(cache->paths))),
                                               clamp_indirect);
                  if (is_finite(add)) {
                    L += add;
                    if constexpr (kAovs) to_group(v.group, add);  // (its light path's emitter's)
                  }
                }
              }
            }
          }
        }
      }

    bool sky_here = false;  // this vertex sampled the sky: the BSDF ray's escape is weighed against it
    if ((nee || sky) && (!kNonDiffuse || cl.has_nondelta)) {
      // A light sample: its shadow ray and its weight against the BSDF's sample.
      // (limit: Clamping's for this vertex's light samples, a parameter, not a capture: naming a
      // local here grew the closure, and GCC then kept the surfaces kernel's state in memory,
      // +3 % instructions on the glass Cornell box)
      const auto add_sample = [&](DirectSample& ds, float limit) {
        const bool above = dot(ds.wi, ng_out) > 0.0f;
        bool reflection = above;
        Vec3 org = sp.p;
        if (terminator) {
          // Cycles' shadow terminator geometry offset: near the terminator of a smooth
          // triangle the sample starts on the smooth surface its vertex normals describe, and
          // Cycles evaluates the closures whatever the triangle's side, so light just below
          // the triangle's plane but above the shading normal reaches the reflection lobes.
          Vec3 n_sh = !is_black(cl.ns) ? cl.ns : sp.ns;
          if (!front) n_sh = -n_sh;
          Vec3 ng_l = ng_out;
          const float amount = scene.terminator_amount(sp, n_sh, ng_l, ds.wi);
          if (amount > 0.0f) {
            org = scene.terminator_lift(sp, ng_l, amount);
            if (!above && dot(n_sh, ds.wi) > 0.0f) reflection = true;
          }
        }
        float bsdf_pdf;
        const Vec3 f = ds.exclude ? eval_mixture_excluding(cl, wo, ds.wi, reflection, ds.exclude, bsdf_pdf)
                                  : eval_mixture<!kNonDiffuse>(cl, wo, ds.wi, reflection, bsdf_pdf);
        if (is_black(f) || (!ds.world_pending && is_black(ds.li))) return;
        Vec3 vis(1.0f);
        Ray shadow;
        shadow.time = ray.time;
        shadow.org = offset_ray_origin(org, sp.p_error, reflection ? ng_out : -ng_out);
        shadow.self_curve = scene.self_curve(sp);
        if (std::isinf(ds.dist)) {
          shadow.dir = ds.wi;
          shadow.tmax = kInf;
        } else {
          // Offset the light end too, so an emissive triangle never blocks its own sample.
          const bool tri = !is_black(ds.target_normal);
          const Vec3 target = tri ? offset_ray_origin(ds.target, ds.target_error, ds.target_normal) : ds.target;
          shadow.dir = target - shadow.org;
          shadow.tmax = 1.0f - 1e-4f;  // pbrt's ShadowEpsilon, on top of both offsets
        }
        if (kMedia && volumes) {
          // Through the media on the sample's side of the surface and the volumes beyond.
          Medium side = medium;
          if (!reflection) side.cross(scene, sp, front);
          ++c.rays;
          vis = shadow_transmittance(scene, shadow, side, ds.cast_shadow, &vrng, kLinks ? ds.shadow_mask : kAllLightSets,
                                     kCatcher && catcher_only, ray_state.shadow_hits());
        } else if (ds.cast_shadow) {
          ++c.rays;
          const int max_hits = ray_state.shadow_hits();
          if (kCatcher && catcher_only) vis = scene.transmittance_catchers(shadow, max_hits);
          else if (kLinks && ds.shadow_mask != kAllLightSets) vis = scene.transmittance_linked(shadow, ds.shadow_mask, max_hits);
          else vis = scene.transmittance(shadow, max_hits);
        }
        // Light inside an absorbing medium (only reachable when the segment stays inside it).
        if constexpr (kMedia) {
          const Vec3 msig = reflection ? sigma : Vec3(0.0f);
          if (!is_black(msig) && std::isfinite(ds.dist)) vis = vis * beer(msig, ds.dist);
        }
        if (!is_black(vis)) {
          // A deferred world sample's radiance and pdf, now that its shadow ray is clear.
          if (ds.world_pending && (!scene.finish_world_sample(ds) || is_black(ds.li))) return;
          if constexpr (kGuide)
            if (guided && guide_sampling && !last)
              bsdf_pdf = guided_pdf(bsdf_pdf, ds.wi, -1.0f);
          const bool full = ds.delta && !(kLinks && ds.dedicated);  // (dedicated rays find those)
          float w = (full || last || (samples_only && ds.analytic)) ? 1.0f : power_heuristic(ds.pdf, bsdf_pdf);
          if constexpr (kCaus)
            if (cz_k >= 2 && !last) {
              // The world or a delta lamp lighting the last smooth vertex: the light tracer's
              // path too. A delta lamp's has no BSDF strategy (its Pa is 0).
              float ps = 0.0f, ab = 0.0f;
              if (!full && std::isinf(ds.dist) && !ds.analytic) {
                ps = caustic_source_pdf(scene, *cz, ds.wi, sp.p);
                ab = bsdf_pdf / ds.pdf;  // Pa / Pb
              } else if (ds.analytic && !cz->lamps.empty()) {
                // A lamp's: with extent (not full) its light path's start has the lamp's own
                // sample density here, so Pc / Pb keeps only the choice (ds.pdf / the density).
                ps = caustic_lamp_pdf(scene, *cz, ds.light, sp.p, ds.target, full ? 1.0f : ds.pdf / ds.choice);
                if (!full && ps > 0.0f) {
                  ab = bsdf_pdf / ds.pdf;
                  ++c.rays;
                  ps *= caustic_lamp_centre(scene, *cz, ds.light, shadow.org, sp.ng, ds.wi, shadow.time);
                }
              }
              if (ps > 0.0f) {
                float pr;
                eval_mixture<!kNonDiffuse>(cl, ds.wi, wo, reflection, pr);  // its direction here
                const float rb = cz_ratio * pr * ps / ds.pdf;  // n Pc / Pb
                w = caustic_mis_weight(ab, rb);
              }
            }
          // (for delta lights pdf is the choice probability)
          const Vec3 v = clamp_light(beta * f * ds.li * vis * (w / ds.pdf), limit);
          L += v;
          if constexpr (kAovs)
            if (lg) to_group(nee ? scene.entry_light_group(ds.entry) : scene.world_light_group(), v);  // (sky: the world's)
          if constexpr (kAovs) {
            if (lp && bounce == 0) {  // the first scattering's: shares of this light direction's value
              Vec3 dw, gw;
              pass_weights(cl, wo, ds.wi, reflection, ds.exclude, dw, gw);
              add_light_component(*aov, v, true, dw, gw, false);
            } else if (lp) {
              add_light_component(*aov, v, false, lp_dw, lp_gw, lp_volume);
            }
          }
        }
      };
      // Drawing a light sample (or the sky's), shared by both call structures below. Inlined
      // early, so that GCC sees the kernel as it was written out twice: left to its later
      // inlining, the diffuse kernels' add_sample went out of line (+3 % on the Cornell box).
      const auto draw_light = [&](DirectSample& ds) __attribute__((always_inline)) {
        ds.path = &ray_state;
        if constexpr (kTree) ds.n = sp.ns;
        if constexpr (kLinks) ds.receiver = scene.light_set_at(sp);
        ds.defer_world = true;
        const Vec2 u_sel = sampler.get2d();  // .y: Russian roulette, below
        u_rr = u_sel.y;
        const Vec2 u_pt = sampler.get2d();
        if constexpr (kTricks)  // Cycles' light_select_reached_max_bounces: the sample is lost
          return scene.sample_direct(sp.p, u_sel.x, u_pt, ds, !last) &&
                 !(ds.analytic && bounce > scene.light(ds.light).max_bounces);
        return scene.sample_direct(sp.p, u_sel.x, u_pt, ds, !last);
      };
      const auto draw_sky = [&](DirectSample& ds) __attribute__((always_inline)) {
        sky_here = true;
        return sky_light_sample(scene, sampler, ng_out, ds);
      };
      if constexpr (kNonDiffuse) {
        // Two add_sample calls: inlined here (one call) it cost these kernels 0.3-2.5 % more,
        // and their images changed at float rounding.
        DirectSample ds;
        if (nee) {
          if (draw_light(ds)) add_sample(ds, lim.sample());
        } else if (draw_sky(ds)) {  // (sky)
          add_sample(ds, lim.sample());
        }
      } else {
        // The diffuse kernels call add_sample once, for either kind of sample: with two calls
        // (above) GCC kept it out of line, which cost the Cornell box 3 % of its instructions.
        DirectSample ds;
        if (nee ? draw_light(ds) : draw_sky(ds)) add_sample(ds, lim.sample());
      }
    }
    // The last vertex does light samples only; one with a BSSRDF still walks to its exit, which
    // samples the lights there (Cycles: the walk is no bounce of its own).
    if constexpr (kFastGI)
      if (s.ao_additive_factor != 0.0f && !catcher_only)
        L += fast_gi_additive(scene, s, sp, cl, wo, ng_out, beta, ray.time, path_key, bounce, lim.sample());
    bool sss_here = false;
    if constexpr (kSubsurface)
      for (int i = 0; i < cl.n; ++i) sss_here = sss_here || std::holds_alternative<SubsurfaceBsdf>(cl.c[size_t(i)].bsdf);
    if (last && (nee || sky) && !sss_here) break;

    // Choose a closure in proportion to its weight, then sample it.
    // Closure choice, then reflect-or-refract: neither is read for a lone diffuse closure, so
    // its draw is skipped (every kernel alike: they keep the same sample streams).
    Vec2 u_lobe{0.0f, 0.0f};
    const bool lobe_drawn = cl.n > 1 || (kNonDiffuse && !std::holds_alternative<DiffuseBsdf>(cl.c[0].bsdf));
    if (lobe_drawn) u_lobe = sampler.get2d();
    else sampler.skip2d();
    const Vec2 u = sampler.get2d();
    const float uc = u_lobe.x, ul = u_lobe.y;
    int k = 0;
    float acc = cl.c[0].pick;
    while (k + 1 < cl.n && uc >= acc) acc += cl.c[size_t(++k)].pick;
    const Closure& ch = cl.c[size_t(k)];
    if constexpr (kSubsurface) {
      if (const SubsurfaceBsdf* ss = std::get_if<SubsurfaceBsdf>(&ch.bsdf)) {
        // Cycles' subsurface_bounce and random walk: into the object and out elsewhere, where
        // a diffuse closure of weight 1 takes over (no shader, no emission there).
        beta *= ch.weight / ch.pick;
        if constexpr (kCaus) cz_k = 0;
        Hit exit;
        Vec3 exit_dir;
        const uint64_t seed = mix64(path_key ^ (uint64_t(bounce + 1) * 0x9E3779B97F4A7C15ULL));
        // The closure choice's number rescaled within this closure's share, and the unused
        // reflect-or-refract one: stratified numbers for the walk's first segment.
        const float u_share = std::min((uc - (acc - ch.pick)) / ch.pick, 0x1.fffffep-1f);
        const Vec2 u_first = lobe_drawn && std::isfinite(u_share) ? Vec2{std::max(u_share, 0.0f), ul} : Vec2{-1.0f, -1.0f};
        if (!subsurface_walk(scene, sp, ng_out, front ? ch.frame.n : -ch.frame.n, wo, *ss, u, u_first, seed, beta,
                             exit, exit_dir, c.rays))
          break;
        scene.surface_point(exit, sp, ray.time);
        wo = exit_dir;
        // The exit's diffuse normal: the smooth one, or where the BSSRDF has a normal of its own
        // (Cycles' SD_HAS_BSSRDF_BUMP) the BSSRDF closures' mean normal there, bump-shadowed.
        Vec3 n_exit = sp.ns;
        if (scene.material(sp.material).subsurface_bump) {
          scene.shade(sp, exit.b1, exit.b2, wo, cl, ray_state);
          Vec3 sum(0.0f);
          for (int i = 0; i < cl.n; ++i)
            if (std::holds_alternative<SubsurfaceBsdf>(cl.c[size_t(i)].bsdf))
              sum += cl.c[size_t(i)].frame.n * std::fabs(average(cl.c[size_t(i)].weight));
          if (length_sq(sum) > 0.0f && is_finite(sum)) n_exit = normalize(sum);
        }
        DiffuseBsdf exit_lobe;
        exit_lobe.back = scene.backfacing(sp, wo);
        const Frame exit_frame = Frame::from_normal(n_exit);
        if (n_exit.x != sp.ns.x || n_exit.y != sp.ns.y || n_exit.z != sp.ns.z) {
          exit_lobe.bent = true;
          exit_lobe.ns = exit_frame.to_local(sp.ns);
        }
        cl.n = 0;
        cl.emission = Vec3(0.0f);
        cl.add(exit_lobe, Vec3(1.0f), exit_frame);
        cl.finalize();
        direct = false;
        film_bg = false;
        want_data = false;
        sss_exit = true;
      } else if (last && (nee || sky)) {
        break;  // another lobe at the last vertex: its light sample above had all the weight
      }
    }
    if (kSubsurface && sss_exit) {
      sss_exit = false;
      goto scatter;
    }
    if constexpr (kNonDiffuse) {
      if (const PortalBsdf* portal = std::get_if<PortalBsdf>(&ch.bsdf)) {
        // Cycles' integrate_surface_ray_portal: the path goes on from the portal's position
        // along its direction, weighted by the closure over its choice. path_state_next counts
        // it as a transparent bounce (the ray keeps its kind: a camera ray stays one) and skips
        // MIS at what it finds next: the light samples before could not see through it.
        beta *= ch.weight / ch.pick;
        if constexpr (kCaus) cz_k = 0;
        if (!is_finite(beta) || !count_crossing(sp)) break;
        prev_delta = true;
        if constexpr (kMedia) medium.cross(scene, sp, front);  // (LABEL_TRANSMIT: the volume stack)
        // A new ray: its length restarts there, from the footprint it hit (Cycles' dP).
        ray_state.dp = ray_state.footprint();
        length_before = 0.0f;
        portal_ray(scene, sp, *portal, ng_out, ray);
        continue;
      }
    }
    BsdfSample bs;
    bool from_guide = false;
    float guide_pdf = 0.0f;  // the guide's pdf of a direction it sampled
    if constexpr (kGuide) {
      const float pc = caustic_cell >= 0 ? s.guide_caustic_probability : 0.0f;
      const float u_guide = guided && guide_sampling ? sampler.get1d() : 1.0f;
      if (u_guide < pc) {
        // A direction from a caustic lobe (its pdf is the mixture's, not the SD-tree's).
        from_guide = true;
        float mixture_share;  // (the mixture's pdf is evaluated below, with the other strategies)
        bs.wi = ch.frame.to_local(guide->caustic_sample(caustic_cell, u_guide / pc, u, mixture_share));
        guide_pdf = -1.0f;
      } else if (guided && guide_sampling && (u_guide - pc) / (1.0f - pc) < gp) {
        // A direction from the guide; its side and the chosen closure's kind name the bounce.
        from_guide = true;
        bs.wi = ch.frame.to_local(guide->sample(guide_cell, u, guide_pdf));
      }
      if (from_guide) {
        const bool up = dot(ch.frame.to_world(bs.wi), ng_out) > 0.0f;
        bs.flags = uint8_t((up ? kReflect : kTransmit) |
                           (std::holds_alternative<ConductorBsdf>(ch.bsdf) ? kGlossyLobe : kDiffuseLobe));
      }
    }
    if (from_guide) {
      // (sampled above)
    } else if constexpr (kNonDiffuse) {
      // Diffuse lobes directly (inlined), the rest through the variant: the same arithmetic.
      const DiffuseBsdf* d = std::get_if<DiffuseBsdf>(&ch.bsdf);
      if (!(d ? d->sample(ch.frame.to_local(wo), u, ul, bs) : bsdf_sample(ch.bsdf, ch.frame.to_local(wo), u, ul, bs)))
        break;
    } else {
      const DiffuseBsdf* d = std::get_if<DiffuseBsdf>(&ch.bsdf);
      if (!d || !d->sample(ch.frame.to_local(wo), u, ul, bs)) break;  // (!d: unreachable, ends the path)
    }
    const Vec3 wi = ch.frame.to_world(bs.wi);
    // On curves the side is the geometry's (hair lobes' flags name R or TT, not a side), and
    // so it is for the Hair BSDF, whose samples Cycles never tests against a side.
    const bool reflection = sp.curve() || (kNonDiffuse && std::holds_alternative<HairBsdf>(ch.bsdf))
                                ? dot(wi, ng_out) > 0.0f
                                : (bs.flags & kReflect) != 0;
    // The sampled side must agree with the geometric normal, or light would leak.
    if ((dot(wi, ng_out) > 0.0f) != reflection) break;
    if (kNonDiffuse && (bs.flags & kDelta)) {
      beta *= ch.weight * bs.weight / ch.pick;
      if constexpr (kCaus)
        if (cz_k > 0) {
          // Smooth glass or a mirror in the chain (docs/design/sampling.md, "Caustic light paths
          // through glass and mirrors"): the chain's Jacobian cancels between the strategies, so
          // the light path's density over this one's gains the lobe's reverse choice over its
          // forward one (the closure's pick cancels) and, for refraction, 1 / etap^2 (a density
          // ratio: the delta's Jacobian, whatever the BSDF's convention).
          Vec3 v, o;
          float pr = 0.0f, e;
          const bool ok = cz_k >= 2 && !(bs.flags & kTransparentLobe) && caustic_delta_closure(cl) == int(&ch - &cl.c[0]) &&
                          caustic_unbent(sp.ng, ch.frame.n, wo) && caustic_unbent(sp.ng, ch.frame.n, wi) &&
                          caustic_delta_lobe(ch.bsdf, bs.wi, (bs.flags & kTransmit) != 0, v, pr, e, o) && pr > 0.0f &&
                          bs.pdf > 0.0f;
          if (ok) {
            cz_ratio = cz_ratio * pr / (bs.pdf * bs.eta * bs.eta);
            cz_ng = sp.ng;
            cz_delta = true;
          }
          if (!ok || !(cz_ratio >= 0.0f) || !std::isfinite(cz_ratio)) cz_k = 0;
        }
      if constexpr (kAovs)
        if (lp && bounce == 0 && !(bs.flags & kTransparentLobe)) {
          const int k = closure_pass_kind(ch, reflection);
          lp_dw = Vec3(k == 0 ? 1.0f : 0.0f);
          lp_gw = Vec3(k == 1 ? 1.0f : 0.0f);
        }
      // A transparent crossing is not a scattering event: MIS keeps the last real vertex
      // (but where a Ray Portal shares the surface, Cycles skips MIS after it: shadow rays
      // could not pass there).
      if (!(bs.flags & kTransparentLobe)) {
        prev_delta = true;
        if constexpr (kTricks) blur_min_pdf = std::min(blur_min_pdf, 1e6f * bs.pdf * ch.pick);  // (Cycles' singular)
        mis_org = sp.p;
        if constexpr (kTree) mis_n = sp.ns;
        if constexpr (kLinks) mis_set = scene.light_set_at(sp);
      } else if (cl.has_portal()) {
        prev_delta = true;
      }
    } else {
      float pdf;
      // Cycles' Huang hair returns its sample's value with pdf 1 (its eval could not tell the
      // density): that value stands for the chosen closure, the others are evaluated.
      const bool huang = kNonDiffuse && !from_guide && std::holds_alternative<HairHuangBsdf>(ch.bsdf);
      Vec3 f = eval_mixture<!kNonDiffuse>(cl, wo, wi, reflection, pdf, huang ? &ch : nullptr);
      if (huang) {
        f += ch.weight * bs.weight * bs.pdf;
        pdf += ch.pick * bs.pdf;
      }
      if constexpr (kNonDiffuse)
        if (const HairBsdf* hb = std::get_if<HairBsdf>(&ch.bsdf)) {
          // Cycles' Hair BSDF: its sampled value in place of its evaluation, the others' unchanged.
          const HairSampled h = hair_sampled(ch, *hb, wo, wi);
          f += h.f;
          pdf += h.pdf;
        }
      float rec_pb = pdf, rec_pg = 0.0f;
      if constexpr (kGuide) {
        if (guided && ((guide_sampling && gp > 0.0f) || (guide_training && s.guide_learn_probability)))
          rec_pg = from_guide && guide_pdf >= 0.0f ? guide_pdf : guide->pdf(guide_cell, wi);
        if (guided && guide_sampling) pdf = guided_pdf(pdf, wi, rec_pg);
      }
      if (!(pdf > 0.0f) || is_black(f)) break;
      beta *= f / pdf;
      if constexpr (kCaus)
        if (cz_k > 0) {
          // q_fwd of this vertex, and (past the rough one) the light tracer's way back.
          float pr = 1.0f;
          if (cz_k >= 2) eval_mixture<!kNonDiffuse>(cl, wi, wo, reflection, pr);
          cz_ratio = cz_ratio * pr / pdf;
          cz_ng = sp.ng;  // (the BSDF ray may find a lamp with extent: light_hits)
          cz_delta = false;
          if (!(cz_ratio >= 0.0f) || !std::isfinite(cz_ratio)) cz_k = 0;
        }
      if constexpr (kAovs)
        if (lp && bounce == 0) pass_weights(cl, wo, wi, reflection, 0, lp_dw, lp_gw);
      if constexpr (kGuide)
        if (guided && guide_training && n_rec < kMaxGuideRecords) {
          float cos_n = 1.0f;
          if (s.guide_cosine) cos_n = std::fabs(dot(wi, !is_black(cl.ns) ? cl.ns : sp.ns));
          rec[n_rec++] = {wi, beta, L, pdf, guide_cell, rec_pb, rec_pg, average(f) / pdf, cos_n};
        }
      prev_pdf = pdf;
      if (s.path_state) ray_state.min_pdf = std::min(ray_state.min_pdf, pdf);
      if constexpr (kTricks) blur_min_pdf = std::min(blur_min_pdf, rec_pb);  // (unguided, as Cycles')
      prev_delta = false;
      prev_samples_only = samples_only;
      mis_org = sp.p;
      if constexpr (kTree) mis_n = sp.ns;
      sky_n = sky_here ? ng_out : Vec3(0.0f);
      if constexpr (kLinks) mis_set = scene.light_set_at(sp);
    }

    // Bounce bookkeeping, as Blender's light paths: a lobe past its own limit still lets its
    // ray collect emission (so the light sample above keeps its MIS weight), then stops.
    if (kNonDiffuse && (bs.flags & kTransparentLobe)) {
      if (!count_crossing(sp)) break;
      length_before = ray_state.length;
    } else {
      direct = false;
      // Transparent Glass (Cycles' bsdf_sample: LABEL_TRANSMIT_TRANSPARENT) keeps the film's world
      if constexpr (kAovs) film_bg = film_bg && transmit_transparent(ch, bs.flags, s.transparent_roughness_squared_threshold);
      else film_bg = false;
      want_data = false;
      if constexpr (kTricks) after_diffuse = (bs.flags & kDiffuseLobe) != 0;
      // Cycles' light visibility: diffuse (any diffuse lobe), glossy reflection, transmission.
      ray_vis = uint8_t(((bs.flags & kTransmit) ? kLightVisTransmission : 0) |
                        ((bs.flags & kDiffuseLobe) ? kLightVisDiffuse : (bs.flags & kTransmit) ? 0 : kLightVisGlossy));
      // Cycles' path_state_next: any transmission (Translucent's too) is a transmission bounce.
      int& count = (bs.flags & kTransmit) ? transmission : (bs.flags & kDiffuseLobe) ? diffuse : glossy;
      if constexpr (kSubsurface)
        if (bs.flags & kDiffuseLobe) ray_state.diffuse_ancestor = true;
      const int limit = (bs.flags & kTransmit)      ? s.transmission_bounces
                        : (bs.flags & kDiffuseLobe) ? s.diffuse_bounces
                                                    : s.glossy_bounces;
      if (count >= limit) emission_only = true;
      ++count;
      ++bounce;
      ray_state.dp = ray_state.footprint();  // the next ray starts from the footprint it hit
      length_before = 0.0f;
      if (s.path_state) {
        // Cycles' path_state_next: reflection or transmission, diffuse, glossy or singular.
        ray_state.flags = uint8_t(((bs.flags & kReflect) ? kRayReflect : kRayTransmit) |
                                  ((bs.flags & kDiffuseLobe) ? kRayDiffuse
                                   : (bs.flags & kDelta)     ? (kRayGlossy | kRaySingular)
                                                             : kRayGlossy));
        ray_state.depth = uint16_t(std::min(bounce, 65535));
        ray_state.diffuse = uint16_t(std::min(diffuse, 65535));
        ray_state.glossy = uint16_t(std::min(glossy, 65535));
        ray_state.transmission = uint16_t(std::min(transmission, 65535));
      }
      if (last) emission_only = true;  // no light sampling: the limit still ends the path
    }
    if constexpr (kNonDiffuse && kMedia) {
      if (bs.flags & kTransmit) {  // crossing the surface: entering or leaving its medium
        medium.cross(scene, sp, front);
      }
    }

    // Shadow linking: the new ray finds shadow-linked lights by a dedicated shadow ray each,
    // past the blockers they ignore (Cycles' intersect_dedicated_light), weighed against their
    // light samples here. Transparent crossings were covered by the vertex before.
    if constexpr (kLinks)
      if (links && !direct && !(kNonDiffuse && (bs.flags & kTransparentLobe)) && !(nee && !prev_delta && prev_samples_only))
        L += dedicated_light_hits(scene, sp, reflection ? ng_out : -ng_out, wi, ray.time, ray_vis,
                                  nee && !prev_delta, prev_pdf, mis_org, mis_n, mis_set, beta, lim.found(),
                                  [&](const Ray& r, uint64_t mask) {
                                    if constexpr (kMedia)
                                      if (volumes)
                                        return shadow_transmittance(scene, r, medium, true, &vrng, mask, false,
                                                                    ray_state.shadow_hits());
                                    return scene.transmittance_linked(r, mask, ray_state.shadow_hits());
                                  },
                                  hit_sink);
    // No roulette after delta lobes (glass, mirrors, transparency): they barely change the
    // throughput, so a roll there (the square root's survival below 1 again) only re-kills
    // what the last rough vertex already rolled for, and amplifies what survives: in glass it
    // cut the caustic chains before they reach the light. The next rough vertex rolls instead.
    if (bounce >= s.rr_start_bounce && !(kNonDiffuse && (bs.flags & kDelta))) {
      // The throughput as it is (refraction scales nothing, as in Cycles: no pbrt etaScale to
      // undo; the decisions are the ones beta times etaScale gave before). Its square root, as
      // Cycles: the first roulette sees the product of three bounces' albedos (0.73^3 = 0.39 in a
      // white Cornell box) and plain throughput killed most paths there, which in a closed, bright
      // room still carry a large share of the light. Per-sample variance x rays per path, the
      // equal-time error, is 11 % lower on the Cornell box (measured with
      // tests/bench/variance_per_sample.py); later bounces converge to the same survival (the
      // albedo) either way.
      // (|beta|: heterogeneous media with majorants too small give signed weights, which the
      // roulette must not cut; the same value elsewhere)
      const float survive = std::min(1.0f, std::sqrt(max_component(vabs(beta))));
      if (sampler.own_roulette()) u_rr = sampler.roulette(bounce);  // (Cycles' PRNG_TERMINATE)
      else if (u_rr < 0.0f) u_rr = roulette_number(sampler);
      if (!(survive > 0.0f) || u_rr >= survive) break;
      beta = beta / survive;
    }
    if (!is_finite(beta)) break;
    ray.org = offset_ray_origin(sp.p, sp.p_error, reflection ? ng_out : -ng_out);
    ray.self_curve = scene.self_curve(sp);
    ray.dir = wi;
    ray.tmax = kInf;
  }
  if constexpr (kGuide) {
    for (int i = 0; i < n_rec && !catcher_only; ++i) {  // (only a training path has records)
      const GuideRecord& r = rec[i];
      const Vec3 in = L - r.L;
      float sum = 0.0f;
      int n = 0;
      if (r.beta.x > 0.0f) sum += in.x / r.beta.x, ++n;
      if (r.beta.y > 0.0f) sum += in.y / r.beta.y, ++n;
      if (r.beta.z > 0.0f) sum += in.z / r.beta.z, ++n;
      const float li = n ? sum / float(n) : 0.0f;  // the radiance that arrived along wi
      guide->record(r.cell, r.wi, n ? (s.guide_cosine ? li * r.cos_n / r.pdf : sum / (float(n) * r.pdf)) : 0.0f);
      if (s.guide_learn_probability) guide->record_moment(r.cell, li * r.fq, r.pdf, r.pb, r.pg);
    }
    if (class_mask) {
      flush_class();
      return L_kept;
    }
  }
  if constexpr (kCatcher) {
    if (catchers && !catcher_only) {
      if (!split) {  // never met a catcher: all of it is the matte's
        aov->matte = L;
        aov->matte_alpha = aov->alpha;
        return L;
      }
      // The path with the catcher is done: now its copy from the split, catchers alone.
      cs.L_combined = L;
      const Split& a = *cs.at;
      L = Vec3(0.0f);  // (the copy's light is the catcher pass alone)
      beta = a.beta, mis_org = a.mis_org, mis_n = a.mis_n, sky_n = a.sky_n;
      feature_throughput = a.feature_throughput, lp_dw = a.lp_dw, lp_gw = a.lp_gw;
      prev_pdf = a.prev_pdf, length_before = a.length_before;
      prev_delta = a.prev_delta, prev_samples_only = a.prev_samples_only, emission_only = a.emission_only;
      direct = a.direct, film_bg = a.direct, want_data = a.want_data, want_features = a.want_features, lp_volume = a.lp_volume;
      mis_set = a.mis_set, ray_vis = a.ray_vis;
      diffuse = a.diffuse, glossy = a.glossy, transmission = a.transmission, transparent = a.transparent;
      volume_count = a.volume_count, bounce = a.bounce;
      // (a split is at a surface the camera sees directly: no scattering before it)
      blur_min_pdf = kInf, after_diffuse = false;
      ray_state = a.ray_state, medium = a.medium, vrng = a.vrng, ray = a.ray;
      medium.keep_catchers(scene);  // (Cycles' volume stack re-initialised for the catcher pass)
      sampler = *cs.sampler;
      n_rec = 0;
      catcher_only = resume = true;
      aov = &cs.scratch.emplace();  // its passes are no pass's: Cycles writes the copy to the catcher pass only
      goto restart;
    }
    if (catcher_only) {
      aov_in->catcher = L;
      return cs.L_combined;
    }
  }
  return L;
}
