// Unidirectional path tracer: BSDF sampling plus next-event estimation to every light
// (analytic lights, emissive triangles, the environment), combined with multiple importance
// sampling (power heuristic), Russian roulette on the path throughput, and Blender's bounce
// limits (total and per type; bounce 0 is direct light).
#pragma once
#include <cstdint>
#include <optional>
#include <string>
#include <type_traits>
#include <vector>

#include "render/pixel_filter.h"
#include "scene/camera.h"
#include "scene/scene.h"
#include "util/sampler.h"

namespace pl {

class GuidingField;

// Caustic light tracing (render/integrator_caustics.cpp, docs/design/sampling.md "Caustics by
// light tracing"): light paths from the environment and lamps through smooth vertices to
// a first rough one, connected to a still pinhole camera and splatted, combined by the power
// heuristic with the path tracer's strategies for the same paths (class L S+ D E: the camera's
// first vertex rough, every later one smooth, the last one lit by the light). Both sides compute
// the same heuristic pdfs from the same path, so the weights sum to 1 (three strategies for the
// environment, two for a delta lamp: the light sample at the last smooth vertex and the path).
//
// A lamp that sends caustic light paths. A delta one's caustics the path tracer makes only by
// its light sample at the last smooth vertex (two strategies); one with extent (a point or spot
// of radius > 0, a sun of angle > 0, an area lamp) also by the BSDF ray that finds it (three).
// A point's or spot's light path leaves its centre towards the caster sphere and, at the first
// hit x, takes the lamp's own light sample from x for its start (the soft disk facing x, or the
// sphere's cone), so the start's density is exact in either model; an area lamp's leaves a
// point on it by area towards the caster sphere.
struct CausticLamp {
  uint32_t light = 0;            // Scene::light index
  float pmf = 0.0f;              // the probability that a light path starts at it
  bool extent = false;           // light_has_extent: rays find it (MIS with the BSDF ray)
  Vec3 axis{0.0f, 0.0f, 1.0f};   // point/spot: the unit direction to the caster sphere's centre
  float one_minus_cos = 2.0f;    // point/spot: of the cone the caster sphere subtends (2: all)
};

// A lamp's light-path density per unit solid angle at its start: its choice pmf times the
// uniform density in the caster cone of solid angle 2 pi one_minus_cos. The light tracer
// (trace_caustic_paths) and the path tracer's MIS (caustic_lamp_pdf) both take it from here, so
// the two sides compute the same number.
inline float caustic_cone_pdf(float pmf, float one_minus_cos) { return pmf / (2.0f * kPi * one_minus_cos); }

struct CausticLight {
  float paths = 0.0f;      // light paths per pixel sample of the film (the n of the heuristic)
  // The emitters: one distribution over [environment | lamps] by the power each sends towards
  // the caster sphere (drawn from only where it has more than one entry).
  float env_pmf = 0.0f;    // the environment's probability (0: no environment map)
  std::vector<CausticLamp> lamps;
  std::vector<int32_t> lamp_of;  // per Scene light: its index in lamps; -1: it sends none
  Distribution1D sources;
  Vec3 center{0.0f};       // the caster sphere: around every smooth surface the probes found
  float radius = 0.0f;
  float far = 0.0f;        // light paths start this far from its centre, outside the scene
  int max_vertices = 0;    // the class's vertices (the rough one and the smooth ones) at most
  float filter_area = 1.0f;  // the box filter's area in pixels (a pixel's sample density is 1 / it)
  // The pixel filter (any type): a splat goes to every pixel whose footprint holds the point,
  // weighted by the filter's density there (PixelFilter::density); the box keeps filter_area.
  const PixelFilter* filter = nullptr;
  const Camera* camera = nullptr;
  bool nee = true;         // the path tracer samples the environment at the last smooth vertex
  bool differentials = false;  // camera rays carry ray differentials (IntegratorSettings::differentials)
  // Motion blur: each light path draws a shutter time as the camera rays do (the camera's
  // shutter curve), traces the scene then and connects to the camera's frame then.
  bool motion = false;
  // Path guiding (a guided kernel): the camera path draws the direction at the rough vertex
  // from the mixture of the BSDF and the guide, so the light path's weight takes that mixture's
  // pdf there, from the field as the same pass's camera paths sample it (light paths are traced
  // before the pass, the field changes only between passes). Null: no guiding.
  const GuidingField* guide = nullptr;
  float guide_probability = 0.0f;       // IntegratorSettings::guide_probability
  bool guide_learn_probability = false;  // per cell (GuidingField::probability) instead
  float guide_caustic_probability = 0.0f;  // the caustic lobes' share (IntegratorSettings)
  // Light-vertex connections (docs/design/sampling.md, "Caustics seen after further rough
  // bounces"): a camera path connects its first `connections` rough vertices x to one rough
  // vertex y of the pass's light paths (CausticVertex), for paths L S+ y x .. E; 0: off. Its
  // heuristic density is `connection_count` times the light path's (a constant per render: the
  // light paths per cached vertex, from a deterministic probe in Session::setup_caustics).
  int connections = 0;
  float connection_count = 1.0f;
  // IntegratorSettings::clamp_indirect (0: none): a light path's light always arrives after a
  // scattering past the camera's first vertex. Each splat into a pixel is one light path's
  // estimate of that pixel's sample divided by `paths`, so it is clamped at clamp / paths.
  float clamp = 0.0f;
};

// A light path's rough vertex y (the first after its smooth chain), cached for the camera
// paths of the same pixel sample to connect to (light-vertex connections): what it needs to be
// shaded again from another direction and weighed.
struct CausticVertex {
  SurfacePoint sp;
  Vec3 wl;     // towards the light (the last smooth vertex)
  Vec3 beta;   // the light path's throughput on arriving (as the camera splat's beta)
  float lr;    // ps prod q_rev / prod q_fwd of the chain: the heuristic's light side
  float eb;    // Pb / Pa at the last smooth vertex (the path tracer's light sample there)
  int k;       // the vertices of the class: y and its smooth chain
  int group;   // the light group of the light path's emitter (PathAovs::groups; -1: none)
};
// The cached vertices of one pixel sample's light paths, in path order, and how many paths
// there were (the pick among them is weighed by size / paths).
struct CausticCache {
  std::vector<CausticVertex> v;
  uint64_t paths = 0;
};

// Light groups a render may keep (RenderSettings::light_groups).
constexpr int kMaxLightGroups = 64;

struct IntegratorSettings {
  int max_bounces = 12;
  int diffuse_bounces = 1024;
  int glossy_bounces = 1024;
  int transmission_bounces = 1024;
  int volume_bounces = 1024;  // scatterings in volumes (Blender's Volume bounces)
  // Transparent crossings (Transparent BSDF, Ray Portal), Blender's Transparent max bounces,
  // as Cycles: the crossing past it ends the path at the next surface (its emission still
  // counts), and a shadow ray passes at most this minus the path's crossings.
  int transparent_bounces = 256;
  bool use_nee = true;
  // Heterogeneous media: a light sample at a point drawn in every segment a path crosses (by
  // the majorants' collision density), not only where delta tracking scatters (docs/design/
  // volumes.md). Off: the light sample at the scattering, as before (tests compare the two).
  bool volume_segment_nee = true;
  // Homogeneous scattering media: the equiangular and the distance-sampled light samples of a
  // segment share one shadow ray, traced for one of them picked by its unshadowed contribution
  // (docs/design/volumes.md). Off: a shadow ray for each, as before (tests compare the two).
  bool volume_shared_shadow = true;
  // Equiangular distances only where the chosen light can shine (a spot's cone, an area
  // light's front: Scene::light_reference_point). Off: along the whole segment, as before.
  bool volume_light_reach = true;
  // The free-flight point's phase sample in the MIS of a segment's equiangular and free-flight
  // light samples (SegmentMis in trace_path.inl). Off: those two weighed against each other
  // only, then each light sample against the phase sample, as before.
  bool volume_phase_mis = true;
  // Volume-only boundaries (Material::pass_through) crossed without shading them, with the
  // same arithmetic and sample dimensions (the same image). Off: shaded as any surface.
  bool volume_pass_through = true;
  int rr_start_bounce = 3;  // Russian roulette from this bounce on
  // Cycles' Clamping (film_clamp_light): each contribution to the film whose component sum
  // |r| + |g| + |b| exceeds the limit is scaled down to it; direct where the light arrives at
  // the camera's first scattering vertex (its light samples, the emission and world its rays
  // find, or the camera's own), indirect after more scatterings. 0: no clamp (the default).
  // These are the kernel's limits on the sum: 3 x the settings (RenderSettings::clamp_direct,
  // Cycles' sample_clamp_direct, which its Integrator multiplies by 3 alike).
  float clamp_direct = 0.0f;
  float clamp_indirect = 0.0f;
  // Cycles' Filter Glossy (docs/design/sampling.md "Filter Glossy and caustics toggles"): 1 /
  // the setting (Cycles' kintegrator->filter_glossy), 0 = off. Where this times the path's
  // smallest BSDF pdf so far (min_ray_pdf) is below 1, every microfacet and Principled hair
  // closure's roughness is raised to at least sqrt(1 - that) / 2 (bsdf_blur).
  float filter_glossy = 0.0f;
  // Cycles' Reflective / Refractive Caustics off (kCausticsNoReflective, kCausticsNoRefractive
  // bits; 0: both on): after a diffuse bounce, glossy reflection (refraction) closures are
  // dropped (ClosureList::caustics_off).
  uint8_t caustics_off = 0;
  // Any of the three: only kernels with kKernelTricks read them (the general ones).
  bool tricks() const {
    return clamp_direct > 0.0f || clamp_indirect > 0.0f || filter_glossy > 0.0f || caustics_off != 0;
  }
  // Cycles' Fast GI Approximation (docs/design/sampling.md "Fast GI approximation"; only kernels
  // with kKernelFastGI read these). Replace (Cycles' kintegrator->ao_bounces, 0: off): once a
  // path's bounces, less its transmission bounces and less one if it had glossy ones, reach
  // ao_bounces (path_state_ao_bounce), its next ray reaches at most ao_distance: a surface there
  // ends the path (its emission and transparency still count), a ray that reaches no surface
  // brings the world times ao_factor. Add (ao_additive_factor, 0: off): every surface adds its
  // diffuse closures' weight times this where a cosine ray of ao_distance finds no surface.
  int ao_bounces = 0;
  float ao_factor = 0.0f;
  float ao_additive_factor = 0.0f;
  float ao_bounces_distance = 3.40282347e+38f;  // (Cycles' FLT_MAX: unbounded)
  bool fast_gi() const { return ao_bounces > 0 || ao_additive_factor != 0.0f; }
  // Transparent film: the world seen by camera rays (also through Transparent BSDFs) is not
  // in the returned radiance; it becomes alpha instead. It still lights the scene.
  bool transparent_background = false;
  // Cycles' Transparent Glass (background.transparent_roughness_squared_threshold; negative:
  // off): with transparent film, a transmission that is not diffuse and whose closure's
  // alpha_x alpha_y (Blender's roughness^4) is at most this keeps the path's world transparent
  // (LABEL_TRANSMIT_TRANSPARENT: PATH_RAY_TRANSPARENT_BACKGROUND stays), as Transparent BSDFs do.
  float transparent_roughness_squared_threshold = -1.0f;
  // The render's camera, for the shader nodes that read camera space (nullptr: world space).
  const Camera* camera = nullptr;
  // Camera rays carry ray differentials (SceneFeatures::footprints: shaders that read them).
  bool differentials = true;
  // Shaders read RayState's kind, counts, length and seed (SceneFeatures::path_state): else
  // the kernels leave them unset.
  bool path_state = true;
  // Path guiding (render/guiding.h; only kernels with kKernelGuiding read these): sample
  // directions at rough vertices from `guide` once it has learnt something, with this
  // probability (one-sample MIS with the BSDF), and record what paths find while training.
  GuidingField* guide = nullptr;
  bool guide_training = false;
  float guide_probability = 0.5f;
  bool guide_learn_probability = false;  // per cell, GuidingField::probability
  bool guide_cosine = false;  // records times the cosine to the shading normal
  // Of a direction from the caustic lobes, where a vertex has some (GuidingField::caustic_cell).
  float guide_caustic_probability = 0.0f;
  // Caustic light tracing on (only kernels with kKernelCaustics read it): MIS with it.
  const CausticLight* caustics = nullptr;
  // Measurement only: the film keeps the light of these PathClass classes (bits; 0: all).
  uint32_t path_class_mask = 0;
  // Render passes beyond the data passes, filled only by the aov kernel (PathAovs): Cycles'
  // light components and colours, Mist (distance from `mist_origin`, 0..1 from mist_start over
  // mist_depth, raised to mist_falloff), AO (a cosine ray of ao_distance at camera hits).
  bool light_passes = false;
  bool mist = false;
  Vec3 mist_origin{0.0f};
  Vec3 mist_axis{0.0f};  // orthographic cameras: distance along this axis (zero: from the origin)
  float mist_start = 5.0f, mist_depth = 25.0f, mist_falloff = 2.0f;
  bool ao = false;
  float ao_distance = 10.0f;
  bool indices = false;  // Object and Material Index
  // UV pass: uv set `uv_set` (the active render UV map; -1: none) at the data passes' surface.
  bool uv_pass = false;
  int uv_set = -1;
  // Vector pass: where that surface was at the frames before and after (Scene::pass_motion).
  bool vector_pass = false;
  uint32_t cryptomatte = 0;  // Cryptomatte layers to record (kCrypto* bits): PathAovs::crypto
  // Shadow catchers (only the general kernel, kKernelShadowCatcher, reads these): a camera
  // path that meets one directly is split as Cycles splits it (PathAovs::matte, catcher).
  // catcher_background: the world behind the catcher goes to PathAovs::environment (Cycles'
  // background pass for the approximate composite over an opaque film).
  bool shadow_catcher = false;
  bool catcher_background = false;
  // Light groups (Cycles' Combined_<name> passes): how many the render keeps; the aov kernel
  // adds each emitter's contribution to PathAovs::groups[its group] too.
  int light_groups = 0;
  // Transparent film with the Env pass on: the world seen directly still goes to the world's
  // group (Cycles evaluates it for the Background pass, and writes its light group then too).
  bool groups_transparent_world = false;
};

// Cryptomatte layers (Cycles' CRYPT_OBJECT, CRYPT_MATERIAL, CRYPT_ASSET).
enum CryptoLayer : uint32_t { kCryptoObject = 1, kCryptoMaterial = 2, kCryptoAsset = 4 };
// The camera path's surfaces a sample records for Cryptomatte: the first one and those seen
// through Transparent BSDFs; deeper ones are dropped (their weight is what the film misses).
constexpr int kMaxCryptoHits = 8;
struct CryptoHit {
  float object, material, asset;  // the ids (ObjectInfo::crypto_*, Material::crypto)
  float weight;  // Cycles' matte weight: average throughput times (1 - average transparency)
};

// Cycles' light components, as the film keeps them (before the division by their colour).
enum LightComponent : int {
  kDiffuseDirect,
  kDiffuseIndirect,
  kGlossyDirect,
  kGlossyIndirect,
  kTransmissionDirect,
  kTransmissionIndirect,
  kVolumeDirect,
  kVolumeIndirect,
  kLightComponents
};

struct PathCounters {
  uint64_t rays = 0;
  // In, not counted: 1 / the pixel filter's density at this camera sample (its offset from
  // the pixel's centre), for the caustic MIS (CausticLight); the box's is its area.
  float filter_area = 1.0f;
  // In: whether the light tracer splats at this camera sample's raster position (false: a
  // panorama's sample that its inverse map puts elsewhere, the path tracer's alone).
  bool caustic_raster = true;
  // In: the light vertices of this pixel sample (light-vertex connections; null: none).
  const CausticCache* caustic_cache = nullptr;
  // In: the camera ray's hit, given instead of traced (baking, docs/design/bake.md: the ray
  // starts on the surface, so it crosses no light or medium on the way). The kernel clears it
  // when it takes it. Only the general kernels read it (a bake session forces them).
  const Hit* first_hit = nullptr;
  // In (with first_hit): the surface's footprint, Cycles' compact dP of the texel (the
  // direction's spread dd is 0); negative: the camera's.
  float first_dp = -1.0f;
};

// What a camera path saw, for render passes (AOVs). trace_path fills it only when the caller
// passes one, so a render without passes does none of this work.
struct PathAovs {
  // First surface that is at least half opaque (Cycles' default pass alpha threshold):
  bool hit = false;
  Vec3 position{0.0f};  // world position
  Vec3 normal{0.0f};    // world shading normal, facing the camera ray
  // Denoising features as Cycles defines them: the first surface that is not mostly specular
  // (at most 75 % of its closure weight in closures with alpha <= 0.075), reached through
  // mirrors, glass and Transparent BSDFs; albedo is the diffuse-like closures' albedo times the
  // specular albedo of the surfaces passed on the way; normal is their weighted mean normal
  // (world space, facing the ray; the session turns it into camera space).
  Vec3 denoising_albedo{0.0f};
  Vec3 denoising_normal{0.0f};
  Vec3 emission{0.0f};     // emission seen directly (through Transparent BSDFs only), Cycles' Emit
  Vec3 environment{0.0f};  // the world seen directly (through Transparent BSDFs only), Cycles' Env
  float alpha = 1.0f;      // 1 - transmittance to the world through Transparent BSDFs (transparent film)
  // IntegratorSettings::light_passes. The first scattering (not a transparent crossing) picks
  // the component: a surface's closures (diffuse, glossy, transmission: the shares of its BSDF
  // value along the sampled or light direction, as Cycles' pass weights) or a volume. Direct:
  // the light samples there and the emission the next ray finds; indirect: the rest. Emit and
  // Env keep what the camera path sees itself, so everything sums to Combined.
  Vec3 light[kLightComponents] = {};
  // Albedo of the closures of each kind at the camera path's surfaces (through Transparent
  // BSDFs, times the throughput): the film divides the components by these, as Cycles.
  Vec3 diffuse_color{0.0f}, glossy_color{0.0f}, transmission_color{0.0f};
  float mist = 0.0f;  // (1 - mist) times the alpha of the camera path's surfaces; the pass is 1 - this
  Vec3 ao{0.0f};      // the camera path's surfaces' unoccluded AO rays (times their alpha)
  float object_index = 0.0f, material_index = 0.0f;  // of the surface `hit` (0: none)
  Vec3 uv{0.0f};  // IntegratorSettings::uv_pass: (u, v, 1) of the surface `hit`, (0, 0, 0) without a UV map
  // IntegratorSettings::vector_pass: the world position of the surface `hit` at the previous
  // and next frames (the session projects them with those frames' cameras).
  Vec3 motion_pre{0.0f}, motion_post{0.0f};
  // Shader AOV slots (kMaxShaderAovs, zeroed by the caller) that the AOV Output ops of the
  // camera path's surfaces add to, up to the surface `hit`; nullptr: no shader AOVs.
  Float4* shader_aovs = nullptr;
  int crypto_count = 0;  // IntegratorSettings::cryptomatte: the first crypto_count of crypto
  CryptoHit crypto[kMaxCryptoHits];  // (left uninitialised: only crypto_count are read)
  // Shadow catcher (IntegratorSettings::shadow_catcher), Cycles' passes: a camera path that
  // meets a catcher directly (through Transparent BSDFs) is split there. The path goes on with
  // the catcher as a plain object (what trace_path returns: Combined); a copy of it goes on
  // where no object but the catchers is there (`catcher`: Cycles' PASS_SHADOW_CATCHER). The
  // path before the split, and paths that never split, are the matte (`matte`, with alpha
  // `matte_alpha`: the split counts as transparent, as film_write_shadow_catcher_bounce_data);
  // catcher_samples is 1 where the path split.
  Vec3 matte{0.0f};
  float matte_alpha = 1.0f;
  Vec3 catcher{0.0f};
  float catcher_samples = 0.0f;
  // Light groups (IntegratorSettings::light_groups slots, zeroed by the caller; nullptr: none):
  // every contribution to the returned radiance from an emitter in group g (a light, an
  // emissive object, the world, an emitting volume; light samples, rays that find them,
  // caustic connections) is added to groups[g] too, clamped as it was (Cycles' lightgroup
  // passes). Not after a shadow catcher split, as Cycles (PATH_RAY_SHADOW_CATCHER_HIT).
  Vec3* groups = nullptr;
};

// The general kernel: every feature compiled in.
Vec3 trace_path(const Scene& scene, Ray ray, Sampler& sampler, const IntegratorSettings& s, PathCounters& c,
                PathAovs* aov = nullptr);

// Scene-specialised kernels: trace_path compiled without the work a render does not need.
// Each bit is a feature that, when absent, is left out of the kernel's per-ray loop.
enum KernelFeature : uint32_t {
  kKernelMedia = 1,        // Beer's law media stack
  kKernelAovs = 2,         // render passes and transparent film (camera-path bookkeeping)
  kKernelNonDiffuse = 4,   // closures other than diffuse (glossy, glass, transparent, delta lobes)
  kKernelEnvironment = 8,  // MIS of escaped rays against the environment light
  kKernelLightTree = 16,   // the shading normals the light tree's choice reads, kept for MIS
  kKernelSubsurface = 32,  // BSSRDF closures: random walks (only the general kernel has them)
  kKernelGuiding = 64,     // path guiding (IntegratorSettings::guide)
  kKernelLightLinks = 128, // light and shadow linking (only the general kernel has them)
  // Cycles' firefly controls (only the general kernels have them): Clamping, Filter Glossy and
  // the Reflective / Refractive Caustics toggles. Without them the other kernels compile to
  // what they were before clamping (docs/design/sampling.md "Clamping").
  kKernelTricks = 1024,
  // Cycles' Fast GI Approximation (IntegratorSettings::ao_bounces, ao_additive_factor): only the
  // general kernels have it; the others compile to what they were before it.
  kKernelFastGI = 2048,
  kKernelAll = 255 | kKernelTricks | kKernelFastGI,  // the general kernel
  // Shadow catchers: paths split at them. Only in a general kernel of their own (every
  // feature and this one): their code cost the general kernel 2 % of its instructions.
  kKernelShadowCatcher = 256,
  kKernelCatcher = kKernelAll | kKernelShadowCatcher,
  // Caustic light tracing's MIS (IntegratorSettings::caustics): kernels of their own.
  kKernelCaustics = 512,
};
using TraceFn = Vec3 (*)(const Scene&, Ray, Sampler&, const IntegratorSettings&, PathCounters&, PathAovs*);
// The kernel features a render of a scene with features f needs (aovs: it asks for PathAovs).
// guiding: the render guides its paths.
// tricks: the render clamps, filters glossy closures or drops caustics (IntegratorSettings).
// fast_gi: the render uses Cycles' Fast GI Approximation (IntegratorSettings::fast_gi).
uint32_t kernel_features(const SceneFeatures& f, bool aovs, bool guiding = false, bool caustics = false,
                         bool tricks = false, bool fast_gi = false);
// The fastest instantiated kernel that has every feature in `needed` (or the general one when
// force_general); `chosen` gets its feature bits. Every kernel gives the general one's result.
TraceFn select_kernel(uint32_t needed, bool force_general, uint32_t& chosen);
// "general", "general+catcher", or "diffuse" / "surfaces" plus "+env", "+tree", "+media", "+passes",
// "+guiding".
std::string kernel_name(uint32_t features);

// The denoising features of one shaded point, split as Cycles does: `diffuse_albedo` of the
// closures rougher than alpha 0.075 and `specular_albedo` of the others; returns true when the
// point is rough enough (over 25 % of the closure weight) to end the search.
// Caustic light paths [first, last) of one pixel sample (stream `seed`, path i its own): the
// splats they make into the film (pixel index of a film `film_w` x `film_h` at full-frame
// (film_x, film_y)), already weighted and divided by the paths per sample, in path order.
// Returns the rays traced.
struct CausticSplat {
  uint32_t pixel;
  Vec3 value;
  int group;  // the light group of the light path's emitter (-1: none)
};
// With `cache`, each path's rough vertex y (seen by the camera or not) is appended to it too.
uint64_t trace_caustic_paths(const Scene& scene, const CausticLight& cz, uint64_t seed, uint64_t first,
                             uint64_t last, int film_x, int film_y, int film_w, int film_h,
                             std::vector<CausticSplat>& out, std::vector<CausticVertex>* cache = nullptr);
// The caster sphere: bounds of the smooth surfaces that `probes` deterministic rays (from
// points in the scene's bounds, in all directions) meet first; false where they met none.
// motion: probe times spread over the shutter (the casters wherever they move). delta (if
// given): whether one of them is smooth glass or a mirror (a delta closure).
bool caustic_casters(const Scene& scene, int probes, Vec3& center, float& radius, bool motion = false,
                     bool* delta = nullptr);
// Whether lamp l may send caustic light paths (CausticLamp): any kind, casting shadows, visible
// to every surface ray (a light path cannot follow a lamp that some closures do not see or that
// shines through blockers), and a sun without a node tree. One with extent also needs rays to
// find it (light_hits: Multiple Importance on and the scene's light hits), so that the BSDF
// strategy its MIS counts exists.
bool caustic_lamp(const Light& l, bool light_hits);
// The share of the environment's power in directions brighter than `factor` times its mean
// radiance over the sphere (a sun's), estimated from 64 x 64 stratified samples of its full
// importance map weighted by luminance / pdf (so right whatever it samples by: texels, a sky's
// disc). 0 without an environment map. Automatic caustic light paths (Session::setup_caustics).
float environment_peak_share(const Environment& env, float factor);

bool denoising_features(const ClosureList& cl, Vec3 wo, bool flip, Vec3& normal, Vec3& diffuse_albedo,
                        Vec3& specular_albedo);

}  // namespace pl
