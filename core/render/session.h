// A progressive render: a controller thread runs passes of a few samples per pixel over all
// tiles on a thread pool, folding each sample into the film, until the sample count or the
// time limit is reached or the render is cancelled. Callers poll from their own thread.
#pragma once
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "render/film.h"
#include "render/integrator.h"
#include "render/pixel_filter.h"
#include "util/pixel_pattern.h"
#include "util/thread_pool.h"

namespace pl {

// Bvh: instead of light transport, one camera ray through each pixel centre records the BVH
// nodes it visits and the triangles it tests (passes BvhNodes and BvhTriangles).
enum class DebugView { None, Bvh };

struct RenderSettings {
  int width = 0, height = 0;
  int samples = 64;
  double time_limit = 0.0;  // seconds, 0 = none
  int max_bounces = 12;
  uint32_t seed = 0;
  int threads = 0;
  int tile_size = 32;
  bool use_nee = true;
  bool volume_segment_nee = true;  // IntegratorSettings::volume_segment_nee
  bool volume_shared_shadow = true;  // IntegratorSettings::volume_shared_shadow
  bool volume_light_reach = true;    // IntegratorSettings::volume_light_reach
  bool volume_phase_mis = true;      // IntegratorSettings::volume_phase_mis
  bool volume_pass_through = true;   // IntegratorSettings::volume_pass_through
  int rr_start_bounce = 3;           // IntegratorSettings::rr_start_bounce (measurements)
  // Clamping (Cycles' sample_clamp_direct and sample_clamp_indirect, the same numbers): a
  // contribution whose |r| + |g| + |b| exceeds 3 x the limit is scaled down to it (for grey
  // light: each channel to the limit); IntegratorSettings::clamp_direct, clamp_indirect. 0 = off,
  // the default (unbiased). Negative or non-finite: 0.
  float clamp_direct = 0.0f, clamp_indirect = 0.0f;
  // Cycles' Filter Glossy (blur_glossy, the same number; IntegratorSettings::filter_glossy is
  // 1 / it): 0 = off, Pathlight's default (unbiased; Cycles' is 1). Negative or non-finite: 0.
  float filter_glossy = 0.0f;
  // Cycles' Reflective and Refractive Caustics (caustics_reflective, caustics_refractive): off
  // drops glossy reflection or refraction closures after a diffuse bounce
  // (IntegratorSettings::caustics_off). With Filter Glossy on or either off, the caustic light
  // paths (and their connections) are off: their caustics are what these leave out.
  bool caustics_reflective = true, caustics_refractive = true;
  // Cycles' Fast GI Approximation (docs/design/sampling.md "Fast GI approximation"), its
  // Integrator's sockets: ao_bounces (Replace; the add-on passes ao_bounces_render or, in the
  // viewport, ao_bounces) and ao_factor (0 turns Replace off, as Cycles), ao_additive_factor
  // (Add); their rays' length is ao_distance (below, the world's AO distance). Guiding and the
  // caustic light paths are off with either. Negative or non-finite: 0.
  int ao_bounces = 0;
  float ao_factor = 0.0f, ao_additive_factor = 0.0f;
  // Cycles' film_transparent_glass and film_transparent_roughness (with film_transparent):
  // the world seen through smooth transmission (roughness at most this) is transparent too.
  bool film_transparent_glass = false;
  float film_transparent_roughness = 0.1f;
  SamplerType sampler = SamplerType::Sobol;  // 4-D sets in Cycles' order (util/sampler.h)
  float adaptive_threshold = 0.0f;  // 0 = off
  int adaptive_min_samples = 0;     // 0 = automatic
  int diffuse_bounces = 1024, glossy_bounces = 1024, transmission_bounces = 1024, volume_bounces = 1024;
  int transparent_bounces = 256;  // IntegratorSettings::transparent_bounces
  // Renders sample indices [sample_offset, sample_offset + samples): partial renders of one
  // frame on several machines, merged by sample count, equal one render of all samples.
  int sample_offset = 0;
  // Which sequence and index each pixel's samples take (util/pixel_pattern.h): its own
  // sequence, or blue noise (chunks of one shared sequence, as Cycles' default).
  PixelPattern pixel_pattern = PixelPattern::Independent;
  // Blue noise's chunk length: the frame's total samples, which pieces of a split frame
  // (sample_offset) must share to compose into one render; 0 = sample_offset + samples.
  int pattern_samples = 0;
  FilterType filter_type = FilterType::Box;
  float filter_width = 1.0f;  // pixels
  // Render border: only this rectangle of the width x height frame (pixels from the
  // bottom-left) is rendered, and the film is its size; border_width 0 = the whole frame.
  int border_x = 0, border_y = 0, border_width = 0, border_height = 0;
  uint32_t passes = 0;            // render passes to keep: pass_bit()s (film.h)
  bool film_transparent = false;  // the world seen directly becomes alpha 0 (Cycles' Transparent film)
  float exposure = 1.0f;          // linear multiplier of Combined and the light passes (Cycles' film_exposure)
  // The Mist pass (world.mist_settings): start, depth and falloff exponent (Cycles' 1, 2, 0.5
  // for Linear, Quadratic, Inverse Quadratic); the AO pass: its rays' length (world.light_settings.distance).
  float mist_start = 5.0f, mist_depth = 25.0f, mist_falloff = 2.0f;
  float ao_distance = 10.0f;
  // The UV pass's uv set (the scene's global index of the active render UV map; -1: none, the
  // pass reads 0).
  int uv_pass_set = -1;
  // Shader AOVs (the view layer's, in its order): the channels of each, 4 (COLOR) or 1 (VALUE);
  // AOV Output ops write slot i (at most kMaxShaderAovs).
  std::vector<int> shader_aovs;
  // Light groups (Cycles' View Layer ▸ Light Groups, Combined_<name> passes): how many; lights,
  // objects and the world name theirs by index (Light::light_group, ObjectInfo::light_group,
  // Scene::set_world_light_group). Read with Session.film_light_group(i).
  int light_groups = 0;
  // Cryptomatte layers (kCryptoObject / kCryptoMaterial / kCryptoAsset bits) and their levels
  // (Blender's pass_cryptomatte_depth, 1..16: id / coverage pairs, two per RGBA pass).
  uint32_t cryptomatte = 0;
  int cryptomatte_depth = 6;
  DebugView debug_view = DebugView::None;
  // Run the general integrator kernel even where a specialised one covers the scene (tests and
  // benchmarks compare the two).
  bool force_general_kernel = false;
  // Path guiding (render/guiding.h): learn the incident light during the first samples and
  // sample it at rough vertices (Cycles' Path Guiding; off by default, as there). Training
  // ends at fixed sample counts, so a render stays deterministic for its seed.
  bool guiding = false;
  float guiding_probability = 0.5f;  // of a guided direction at a rough vertex
  // Learn the guide's probability per cell (GuidingField::set_learn_probability) instead of
  // guiding_probability everywhere (it then only starts the cells off).
  bool guiding_learn_probability = false;
  // Record incident radiance times the cosine to the vertex's shading normal, so that a cell's
  // distribution is the cosine product of a diffuse lobe (exact on flat, axis-aligned cells).
  bool guiding_cosine = false;
  // Müller et al.'s directional filter: each record splatted over a box of its quadtree
  // leaf's size (GuidingField::set_directional_filter).
  bool guiding_filter = false;
  // Photon training (render/guide_photons.h): light paths traced at the end of each training
  // iteration, this many per pixel and iteration sample (0: camera records only), and the
  // share of the guide's distributions they make where a cell has camera records too.
  float guiding_photons = 0.0f;
  float guiding_photon_share = 0.5f;
  float guiding_photon_split = 1.0f;  // a photon record's weight in a cell's split count
  // Caustic photons only (L S+ D, trace_guide_photons), kept over the iterations; none where
  // caustic light paths are on (they carry those caustics themselves).
  bool guiding_caustics = false;
  // Caustic lobes (GuidingField::set_caustic_lobes; with guiding_caustics): the probability of
  // a direction from them where a vertex has some (0: none), their cubes' edge over the scene's
  // diagonal, their cones' half-angle in radians.
  float guiding_caustic_lobes = 0.0f;
  float guiding_caustic_cube = 0.01f;
  float guiding_caustic_cone = 0.1f;
  // Measurement only (docs/design/sampling.md, "Where the window room's error is"): with guiding
  // on, the image keeps only the light of these path classes (PathClass bits; 0: all).
  uint32_t guiding_class_mask = 0;
  // Caustic light tracing (IntegratorSettings::caustics): light paths per pixel sample from
  // the environment through smooth surfaces, combined with the path tracer by MIS; 0: off.
  // Only where it can be combined exactly (SessionStats::caustics says why not otherwise).
  float caustic_light_paths = 0.0f;
  // Automatic (where caustic_light_paths is 0): kAutoCausticPaths per sample only where they pay
  // (Session::setup_caustics: an environment map whose bright peak holds most of its power, and
  // smooth surfaces), else off without a warning ("off (automatic): ..."). An explicit number wins.
  bool caustic_light_paths_auto = false;
  // Light-vertex connections (docs/design/sampling.md, "Caustics seen after further rough
  // bounces"): where the caustic light paths run, a camera path connects each of its first this
  // many rough vertices to one rough vertex of the pass's light paths (L S+ D D+ E); 0: off;
  // negative: automatic (kAutoConnections where the automatic light paths run, else off).
  int caustic_connections = -1;
};

// The passes a render keeps: the requested ones plus those a debug view needs, and the colour
// a light component is divided by.
uint32_t effective_passes(const RenderSettings& s);

// Throws std::invalid_argument with a readable message for settings that cannot be rendered.
void validate(const RenderSettings& s);

struct SessionProgress {
  int samples_done = 0, samples_total = 0;
  double elapsed_s = 0.0;
  bool cancelled = false, finished = false;
};

struct SessionStats {
  uint64_t rays = 0, paths = 0, nonfinite_samples = 0;
  int64_t active_pixels = 0;  // pixels adaptive sampling has not stopped yet
  int passes = 0, threads = 0;
  int work_items = 0;  // of a pass: tiles, or bands of their rows (chosen by the constructor)
  int guiding_iterations = 0, guiding_cells = 0;  // training done so far and the field's cells
  int guiding_caustic_cells = 0;  // cubes with caustic lobes
  float guiding_probability = 0.0f;  // the cells' guide probability, weighted by their records
  double elapsed_s = 0.0;
  float focus_distance = 0.0f;  // of the thin lens, after autofocus
  int autofocus = 0;            // 0 off, 1 focused on a surface, 2 missed (kept the camera's)
  std::string kernel;           // the integrator kernel it runs (kernel_name)
  // Caustic light tracing: "" (not asked for), "on", or why it is off for this render.
  std::string caustics;
  // Path guiding asked for but off for this render: why ("" where it runs or was not asked for).
  std::string guiding;
  int caustic_connections = 0;  // light-vertex connections: the rough vertices that connect (0: none)
  // The features of scene and render in use and not in use (SceneFeatures names, then "dof",
  // "pixel filter", "passes", "transparent film", "adaptive sampling").
  std::vector<std::string> features, unused_features;
};

// Baking (docs/design/bake.md, Cycles' integrator_init_from_bake): the film's pixel (x, y) is
// texel y * width + x of a bake image, whose path starts on a given point of one instance's
// surface, seen along its smooth normal, instead of at the camera. Surface: the integrator runs
// from there (Combined and the render passes, read as for a render); Environment: the world along
// the direction from the origin to the point; Roughness: Cycles' Roughness pass, the closures'
// weighted mean roughness.
enum class BakeMode : uint8_t { Surface, Environment, Roughness };
struct BakeInput {
  uint32_t instance = 0;             // the scene instance (add_instance order)
  std::vector<int32_t> triangle;     // per texel: a triangle of the instance's mesh; -1: no texel
  std::vector<float> bary;           // per texel: b1, b2, the weights of the triangle's corners 1 and 2
  // Per texel: db1/dx, db1/dy, db2/dx, db2/dy across the texel (sample 0 takes its centre,
  // later ones a point jittered within it, as Cycles); empty: the centre always.
  std::vector<float> differentials;
  BakeMode mode = BakeMode::Surface;
  // Seen from the camera (Blender's View From 'Active Camera', Cycles' bake use_camera): the
  // direction to the camera, kept above the smooth normal as Cycles does; else the normal.
  bool view_from_camera = false;
};

class GuidingField;
struct GuidePhotonSources;

class Session {
 public:
  // camera: overrides the scene's camera (the viewport's view) when not null.
  // bake: a bake instead of a render (BakeInput; the film is the bake image, no border).
  Session(std::shared_ptr<const Scene> scene, const RenderSettings& settings, const CameraDesc* camera = nullptr,
          std::shared_ptr<const BakeInput> bake = nullptr);
  ~Session();
  Session(const Session&) = delete;
  Session& operator=(const Session&) = delete;

  void start();
  // Blocks until a pass completes after the previous call, the render finishes, or the timeout.
  // Returns true once the render has finished.
  bool wait(double timeout_s);
  void cancel();
  bool finished() const { return finished_.load(); }
  SessionProgress progress() const;
  SessionStats stats() const;
  std::string error() const;
  Film& film() { return film_; }
  // The learnt guiding field (null without guiding); read it only once the render finished.
  const GuidingField* guiding_field() const { return guide_.get(); }
  const RenderSettings& settings() const { return settings_; }

 private:
  void run();
  // Samples [s0, s1) of band `part` of `parts` of a tile's rows (parts 1: the whole tile).
  void render_tile(int tile, int part, int parts, int s0, int s1);
  // Baking: texel `texel`'s surface point for sample `sample` (j: its jitter within the texel),
  // the hit and the ray along the smooth normal onto it, and its footprint (compact dP); false
  // where the texel has none.
  bool bake_point(size_t texel, uint32_t sample, Vec2 j, Ray& ray, Hit& hit, SurfacePoint& sp, float& dp) const;
  // Cycles' Roughness pass at a surface point seen from wo (surface_shader_average_roughness).
  float bake_roughness(const SurfacePoint& sp, Vec3 wo) const;
  // Lays out one sample's pass values as the film's planes expect them.
  void write_aux(const PathAovs& a, float* out) const;
 public:
  // The film's Cryptomatte layer of a kCrypto* bit (-1: not rendered) and the RGBA passes each
  // layer has (Cycles' divide_up(min(16, depth), 2)).
  int crypto_layer(uint32_t bit) const;
  int crypto_passes() const { return film_.crypto_slots() / 2; }

 private:
  double elapsed() const;

  std::shared_ptr<const Scene> scene_;
  RenderSettings settings_;
  std::shared_ptr<const BakeInput> bake_;  // (null: a render)
  std::vector<uint32_t> bake_prims_;       // per texel: its Hit::prim (UINT32_MAX: none)
  Camera camera_;
  Camera camera_pre_, camera_post_;  // the Vector pass's cameras at the previous and next frames
  PixelFilter filter_;
  int region_x_ = 0, region_y_ = 0;  // film pixel (0, 0) in the full frame
  float focus_distance_ = 0.0f;
  bool motion_ = false;  // something moves: camera rays draw a shutter time
  int autofocus_ = 0;
  int total_samples_ = 0;
  PixelPatternMap pattern_map_;
  IntegratorSettings integrator_;
  TraceFn kernel_ = nullptr;  // chosen once per session: no per-ray feature dispatch
  std::unique_ptr<GuidingField> guide_;  // path guiding's learnt field (null: no guiding)
  int guide_end_ = 0, guide_size_ = 1;  // the training iteration ends at this sample; its samples
  std::atomic<int> guide_iterations_{0}, guide_cells_{0}, guide_caustic_cells_{0};
  std::atomic<float> guide_probability_{0.0f};
  std::unique_ptr<GuidePhotonSources> photon_sources_;  // (null: no photon training)
  double photons_per_sample_ = 0.0;  // photons per training sample of the whole film
  void end_guiding_iteration();
  uint32_t kernel_bits_ = kKernelAll;
  std::unique_ptr<CausticLight> caustics_;  // (null: off)
  std::string caustics_note_;
  std::string guiding_note_;
  uint64_t caustic_paths_ = 0;  // light paths per pixel sample (the whole film's)
  // The current pass's splats, one film image per sample of it.
  std::vector<std::vector<Vec3>> caustic_splats_;
  // With light groups: per sample, each group's splats (group g's image at g x pixels).
  std::vector<std::vector<Vec3>> caustic_group_splats_;
  std::vector<CausticCache> caustic_caches_;  // and its light vertices (connections on)
  void setup_caustics(bool guiding);  // (the constructor's, once)
  void trace_caustics(int s0, int k);
  uint64_t connection_chunks() const;  // (light-vertex connections: the chunks they pick from)
  std::vector<std::string> features_, unused_features_;
  Film film_;
  std::unique_ptr<ThreadPool> pool_;
  std::thread controller_;

  std::atomic<bool> cancel_{false}, finished_{false}, started_{false};
  std::atomic<int> samples_done_{0}, passes_{0};
  std::atomic<uint64_t> rays_{0}, paths_{0}, nonfinite_{0};
  int min_samples_ = 0, check_every_ = 1;
  int work_parts_ = 1;  // bands per tile in a pass (the constructor chooses)
  std::vector<int> tile_active_;       // per tile, written by the thread rendering it
  std::atomic<int64_t> active_{0};
  std::chrono::steady_clock::time_point t0_;
  std::atomic<double> end_elapsed_{-1.0};

  mutable std::mutex m_;
  std::condition_variable cv_;
  int passes_seen_ = 0;
  std::string error_;
};

}  // namespace pl
