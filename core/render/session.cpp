#include "render/session.h"
#include "render/guide_photons.h"
#include "render/guiding.h"
#include "scene/light_shader.h"
#include "scene/microfacet_energy.h"
#include "util/rng.h"

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <sys/resource.h>
#include <unistd.h>
#include <stdexcept>

namespace pl {

void validate(const RenderSettings& s) {
  if (s.width < 1 || s.height < 1) throw std::invalid_argument("resolution must be at least 1x1");
  // 20 bytes per pixel of film; refuse before allocating rather than exhausting memory.
  // The film takes ~20 bytes per pixel and its copies to Python and Blender ~32 more: refuse
  // what cannot fit in half the physical memory, before allocating anything.
  double max_pixels = 400e6;
  double memory = 0.0;
  const long pages = sysconf(_SC_PHYS_PAGES), page = sysconf(_SC_PAGE_SIZE);
  if (pages > 0 && page > 0) memory = double(pages) * double(page);
  rlimit rl{};  // an address-space limit (ulimit -v) caps it too
  if (getrlimit(RLIMIT_AS, &rl) == 0 && rl.rlim_cur != RLIM_INFINITY)
    memory = memory > 0.0 ? std::min(memory, double(rl.rlim_cur)) : double(rl.rlim_cur);
  // Pass planes add a running mean and its copies (~12 bytes) per channel.
  int pass_channels = 0;
  for (int p = 0; p < kPassCount; ++p)
    if (effective_passes(s) & pass_bit(Pass(p))) pass_channels += pass_desc(Pass(p)).channels;
  for (int ch : s.shader_aovs) pass_channels += std::max(ch, 0);
  pass_channels += 3 * std::max(s.light_groups, 0);
  if (memory > 0.0) max_pixels = std::min(max_pixels, 0.5 * memory / (52.0 + 12.0 * pass_channels));
  if (s.width > 65536 || s.height > 65536 || double(s.width) * double(s.height) > max_pixels)
    throw std::invalid_argument("resolution " + std::to_string(s.width) + "x" + std::to_string(s.height) +
                                " is too large (at most 65536 per side and " +
                                std::to_string(int64_t(max_pixels / 1e6)) + " megapixels on this machine)");
  if (s.samples < 1) throw std::invalid_argument("samples must be at least 1");
  if (s.max_bounces < 0 || s.max_bounces > 1024) throw std::invalid_argument("max_bounces must be in [0, 1024]");
  if (!(s.time_limit >= 0.0)) throw std::invalid_argument("time_limit must be >= 0");
  if (s.threads < 0 || s.threads > 1024) throw std::invalid_argument("threads must be in [0, 1024]");
  if (s.tile_size < 4 || s.tile_size > 1024) throw std::invalid_argument("tile_size must be in [4, 1024]");
  if (!(s.adaptive_threshold >= 0.0f) || !std::isfinite(s.adaptive_threshold))
    throw std::invalid_argument("adaptive_threshold must be >= 0");
  if (s.adaptive_min_samples < 0) throw std::invalid_argument("adaptive_min_samples must be >= 0");
  if (s.sample_offset < 0 || int64_t(s.sample_offset) + int64_t(s.samples) > int64_t(INT32_MAX))
    throw std::invalid_argument("sample_offset must be >= 0 and sample_offset + samples < 2^31");
  if (s.pattern_samples != 0 && int64_t(s.pattern_samples) < int64_t(s.sample_offset) + int64_t(s.samples))
    throw std::invalid_argument("pattern_samples must be 0 or at least sample_offset + samples");
  if (s.diffuse_bounces < 0 || s.glossy_bounces < 0 || s.transmission_bounces < 0 || s.volume_bounces < 0 ||
      s.transparent_bounces < 0)
    throw std::invalid_argument("bounce limits must be >= 0");
  if (!(s.filter_width > 0.0f) || !(s.filter_width <= 100.0f))
    throw std::invalid_argument("filter_width must be in (0, 100] pixels");
  if (s.border_width != 0 || s.border_height != 0) {
    if (s.border_width < 1 || s.border_height < 1 || s.border_x < 0 || s.border_y < 0 ||
        s.border_x > s.width - s.border_width || s.border_y > s.height - s.border_height)
      throw std::invalid_argument("the render border must be a non-empty rectangle inside the frame");
  }
  if (!(s.exposure >= 0.0f) || !std::isfinite(s.exposure)) throw std::invalid_argument("exposure must be finite and >= 0");
  if (!std::isfinite(s.mist_start) || !(s.mist_depth >= 0.0f) || !std::isfinite(s.mist_depth) ||
      !(s.mist_falloff > 0.0f) || !std::isfinite(s.mist_falloff))
    throw std::invalid_argument("mist settings must be finite (depth >= 0, falloff > 0)");
  if (!(s.ao_distance >= 0.0f)) throw std::invalid_argument("ao_distance must be >= 0");
  if (s.passes >= (1u << kPassCount)) throw std::invalid_argument("unknown render pass");
  if (s.shader_aovs.size() > size_t(kMaxShaderAovs))
    throw std::invalid_argument("at most " + std::to_string(kMaxShaderAovs) + " shader AOVs");
  for (int ch : s.shader_aovs)
    if (ch != 1 && ch != 4) throw std::invalid_argument("a shader AOV has 1 (VALUE) or 4 (COLOR) channels");
  if (s.light_groups < 0 || s.light_groups > kMaxLightGroups)
    throw std::invalid_argument("light_groups must be in [0, " + std::to_string(kMaxLightGroups) + "]");
  if (s.cryptomatte >= 8u) throw std::invalid_argument("unknown Cryptomatte layer");
  if (s.cryptomatte && !(s.cryptomatte_depth >= 1 && s.cryptomatte_depth <= 16))
    throw std::invalid_argument("cryptomatte_depth must be in [1, 16]");
}

uint32_t effective_passes(const RenderSettings& s) {
  uint32_t p = s.passes;
  if (s.debug_view == DebugView::Bvh) p |= pass_bit(Pass::BvhNodes) | pass_bit(Pass::BvhTriangles);
  for (int i = 0; i < kPassCount; ++i)
    if ((p & pass_bit(Pass(i))) && pass_desc(Pass(i)).divide >= 0) p |= pass_bit(Pass(pass_desc(Pass(i)).divide));
  return p;
}

namespace {
// The film's planes: the render's passes, and with shadow catchers in the scene Cycles' three
// catcher planes (and the world behind them for the approximate composite on an opaque film).
uint32_t film_passes(const RenderSettings& s, const Scene* scene) {
  uint32_t p = effective_passes(s);
  if (scene && scene->committed() && scene->features().shadow_catcher && s.debug_view == DebugView::None) {
    if (!(p & pass_bit(Pass::ShadowCatcher)) && !s.film_transparent) p |= pass_bit(Pass::Env);
    p |= pass_bit(Pass::ShadowCatcher) | pass_bit(Pass::ShadowCatcherMatte) | pass_bit(Pass::ShadowCatcherSampleCount);
  }
  return p;
}
// The film's size: the border's, or the whole frame's.
int film_width(const RenderSettings& s) { return s.border_width > 0 ? s.border_width : s.width; }
int film_height(const RenderSettings& s) { return s.border_height > 0 ? s.border_height : s.height; }
}  // namespace

Session::Session(std::shared_ptr<const Scene> scene, const RenderSettings& settings, const CameraDesc* camera,
                 std::shared_ptr<const BakeInput> bake)
    : scene_(std::move(scene)),
      settings_((validate(settings), settings)),
      bake_(std::move(bake)),
      film_(film_width(settings), film_height(settings), settings.tile_size, film_passes(settings, scene_.get()), settings.exposure,
            settings.shader_aovs, settings.debug_view == DebugView::None ? settings.light_groups : 0) {
  if (!scene_ || !scene_->committed()) throw std::invalid_argument("scene is not committed");
  if (bake_) {
    // A texel's path starts on its surface: no border, and nothing that traces from the camera
    // (caustic light paths splat through it, guiding trains on camera paths' pixels).
    const BakeInput& b = *bake_;
    const size_t n = size_t(settings_.width) * size_t(settings_.height);
    if (settings_.border_width > 0) throw std::invalid_argument("bake: no render border");
    if (b.triangle.size() != n || b.bary.size() != 2 * n || (!b.differentials.empty() && b.differentials.size() != 4 * n))
      throw std::invalid_argument("bake: triangle, bary and differentials must have width x height texels (1, 2, 4 values each)");
    const std::vector<uint32_t> prims = scene_->instance_prims(b.instance);
    if (b.instance >= scene_->instance_count())
      throw std::invalid_argument("bake: unknown instance " + std::to_string(b.instance));
    bake_prims_.assign(n, UINT32_MAX);
    for (size_t t = 0; t < n; ++t) {
      const int32_t tri = b.triangle[t];
      if (tri < 0) continue;
      if (size_t(tri) >= prims.size())
        throw std::invalid_argument("bake: triangle " + std::to_string(tri) + " is not one of the instance's mesh (" +
                                    std::to_string(prims.size()) + " triangles)");
      if (!std::isfinite(b.bary[2 * t]) || !std::isfinite(b.bary[2 * t + 1]))
        throw std::invalid_argument("bake: barycentrics must be finite");
      bake_prims_[t] = prims[size_t(tri)];  // (UINT32_MAX where the commit dropped it: degenerate)
    }
    for (float d : b.differentials)
      if (!std::isfinite(d)) throw std::invalid_argument("bake: differentials must be finite");
    settings_.caustic_light_paths = 0.0f;
    settings_.caustic_light_paths_auto = false;
    settings_.guiding = false;
  }
  if (film_.has_pass(Pass::ShadowCatcherMatte)) {
    // Cycles' approximate shadow catcher unless the Shadow Catcher pass is asked for.
    const bool asked = (settings_.passes & pass_bit(Pass::ShadowCatcher)) != 0;
    film_.set_catcher_combined(asked ? CatcherCombined::Matte
                               : settings_.film_transparent ? CatcherCombined::Approximate
                                                            : CatcherCombined::OverBackground);
    integrator_.shadow_catcher = true;
    integrator_.catcher_background = film_.has_pass(Pass::Env) && !settings_.film_transparent;
  }
  // The viewport's camera overrides the scene's (same committed scene, nothing rebuilt).
  const CameraDesc& view = camera ? *camera : scene_->camera_desc();
  camera_ = Camera(view, settings_.width, settings_.height);
  // A program world's light samples read the render's camera (Texture Coordinate's Window).
  if (const WorldShader* ws = scene_->environment().world_shader()) ws->camera = &camera_;
  if (view.use_autofocus) {
    // Focus where the pinhole ray through the chosen point first meets a surface, measured
    // along the view axis, so the focal plane passes exactly through that point.
    const float fx = std::isfinite(view.autofocus_x) ? std::clamp(view.autofocus_x, 0.0f, 1.0f) : 0.5f;
    const float fy = std::isfinite(view.autofocus_y) ? std::clamp(view.autofocus_y, 0.0f, 1.0f) : 0.5f;
    const Ray r = camera_.generate_pinhole(fx * float(settings_.width), fy * float(settings_.height));
    Hit h;
    h.t = r.tmax;
    if (scene_->intersect(r, h) && h.valid()) {
      const Vec3 p = r.org + r.dir * h.t;  // a panorama focuses on a sphere: the distance
      camera_.set_focus_distance(camera_.is_panoramic() ? camera_.z_depth(p) : camera_.view_depth(p));
      autofocus_ = 1;
    } else {
      autofocus_ = 2;
    }
  }
  focus_distance_ = camera_.focus_distance();
  motion_ = scene_->has_motion() || camera_.has_motion();
  filter_ = PixelFilter(settings_.filter_type, settings_.filter_width);
  if (settings_.border_width > 0) {
    region_x_ = settings_.border_x;
    region_y_ = settings_.border_y;
  }
  // The debug view is a deterministic picture of the BVH: one ray per pixel is all it takes.
  total_samples_ = settings_.debug_view == DebugView::Bvh ? 1 : settings_.samples;
  // Adaptive sampling and a time limit keep the chunk length of all samples (as Cycles): a
  // pixel that stops early has used the start of its chunk.
  pattern_map_ = PixelPatternMap(settings_.pixel_pattern, settings_.seed,
                                 uint32_t(std::max<int64_t>(settings_.pattern_samples,
                                                            int64_t(settings_.sample_offset) + settings_.samples)));
  integrator_.transparent_background = settings_.film_transparent;
  integrator_.camera = &camera_;  // Session is neither copied nor moved
  integrator_.max_bounces = settings_.max_bounces;
  integrator_.use_nee = settings_.use_nee;
  integrator_.volume_segment_nee = settings_.volume_segment_nee;
  integrator_.volume_shared_shadow = settings_.volume_shared_shadow;
  integrator_.volume_light_reach = settings_.volume_light_reach;
  integrator_.volume_phase_mis = settings_.volume_phase_mis;
  integrator_.volume_pass_through = settings_.volume_pass_through;
  integrator_.rr_start_bounce = std::max(0, settings_.rr_start_bounce);
  // (the bindings warn where they turn a negative or non-finite limit into 0; x 3, as Cycles'
  // Integrator: the kernel compares the sum of the three channels)
  const auto clamp_limit = [](float v) { return std::isfinite(v) && v > 0.0f ? 3.0f * v : 0.0f; };
  integrator_.clamp_direct = clamp_limit(settings_.clamp_direct);
  integrator_.clamp_indirect = clamp_limit(settings_.clamp_indirect);
  // (Cycles' kintegrator->filter_glossy = 1 / blur_glossy; its FLT_MAX for off is 0 here)
  const float blur = settings_.filter_glossy;
  integrator_.filter_glossy = std::isfinite(blur) && blur > 0.0f ? 1.0f / blur : 0.0f;
  integrator_.caustics_off = uint8_t((settings_.caustics_reflective ? 0 : kCausticsNoReflective) |
                                     (settings_.caustics_refractive ? 0 : kCausticsNoRefractive));
  // Fast GI as Cycles' Integrator::device_update: Replace only with a factor (ao_bounces 0 else).
  const auto non_negative = [](float v) { return std::isfinite(v) && v > 0.0f ? v : 0.0f; };
  integrator_.ao_factor = non_negative(settings_.ao_factor);
  integrator_.ao_bounces = integrator_.ao_factor != 0.0f ? std::max(0, settings_.ao_bounces) : 0;
  integrator_.ao_additive_factor = non_negative(settings_.ao_additive_factor);
  integrator_.ao_bounces_distance = settings_.ao_distance;  // (the constructor refuses a negative one)
  // Transparent Glass (Cycles' Background::device_update): the roughness squared twice.
  if (settings_.film_transparent && settings_.film_transparent_glass) {
    const float r = non_negative(settings_.film_transparent_roughness);
    integrator_.transparent_roughness_squared_threshold = r * r * r * r;
  }
  integrator_.diffuse_bounces = settings_.diffuse_bounces;
  integrator_.glossy_bounces = settings_.glossy_bounces;
  integrator_.transmission_bounces = settings_.transmission_bounces;
  integrator_.volume_bounces = settings_.volume_bounces;
  integrator_.transparent_bounces = std::min(settings_.transparent_bounces, 65535);
  {
    const uint32_t kept = effective_passes(settings_);
    for (int p = int(Pass::DiffuseDirect); p <= int(Pass::VolumeIndirect); ++p)
      integrator_.light_passes = integrator_.light_passes || (kept & pass_bit(Pass(p)));
    integrator_.mist = (kept & pass_bit(Pass::Mist)) != 0;
    integrator_.ao = (kept & pass_bit(Pass::AO)) != 0;
    integrator_.indices = (kept & (pass_bit(Pass::ObjectIndex) | pass_bit(Pass::MaterialIndex))) != 0;
    integrator_.uv_pass = (kept & pass_bit(Pass::UV)) != 0;
    integrator_.uv_set = settings_.uv_pass_set;
    integrator_.vector_pass = (kept & pass_bit(Pass::Vector)) != 0;
    if (integrator_.vector_pass) {
      // The cameras of the frames before and after (Cycles' perspective_pre / _post), still:
      // the scene camera's or an overriding camera's own (a stereo view's steps; the
      // viewport's camera has none).
      CameraDesc d = view;
      d.motion.clear();
      d.shutter_curve.clear();
      d.use_autofocus = false;
      d.focus_distance = focus_distance_;
      const bool moves = view.pass_motion.size() == 2;
      d.matrix_world = moves ? view.pass_motion[0] : view.matrix_world;
      camera_pre_ = Camera(d, settings_.width, settings_.height);
      d.matrix_world = moves ? view.pass_motion[1] : view.matrix_world;
      camera_post_ = Camera(d, settings_.width, settings_.height);
    }
    if (settings_.cryptomatte && settings_.debug_view == DebugView::None) {
      integrator_.cryptomatte = settings_.cryptomatte;
      const int layers = __builtin_popcount(settings_.cryptomatte);
      film_.set_cryptomatte(layers, 2 * ((std::min(16, settings_.cryptomatte_depth) + 1) / 2));
    }
    integrator_.light_groups = film_.light_group_count();
    integrator_.groups_transparent_world = (settings_.passes & pass_bit(Pass::Env)) != 0;
    integrator_.mist_start = settings_.mist_start;
    integrator_.mist_depth = settings_.mist_depth;
    integrator_.mist_falloff = settings_.mist_falloff;
    integrator_.ao_distance = settings_.ao_distance;
    integrator_.mist_origin = camera_.origin();
    integrator_.mist_axis = camera_.orthographic() ? camera_.forward() : Vec3(0.0f);
  }
  if (settings_.adaptive_threshold > 0.0f) {
    // Enough samples to see noisy features before any pixel may stop (Cycles' idea).
    min_samples_ = settings_.adaptive_min_samples > 0
                       ? settings_.adaptive_min_samples
                       // clamped before the cast: a tiny threshold would overflow int (UB)
                       : std::max(16, static_cast<int>(std::min(4.0 / std::sqrt(double(settings_.adaptive_threshold)),
                                                                double(settings_.samples))));
    min_samples_ = std::min(min_samples_, settings_.samples);
    check_every_ = std::max(1, min_samples_ / 4);
  }
  {
    // Work items of a pass: each tile's k samples, or without adaptive sampling bands of a
    // tile's rows, so that a pass has about kItemsPerThread items per thread. A pass ends when
    // its last item does, so few large items leave threads idle (a 96x72 film has 9 tiles of
    // very different cost: on 2 threads 3-6 % of the thread time went idle). Pixels keep their
    // sample order, so the image is the same whatever the split.
    constexpr int kItemsPerThread = 16;
    const int threads = settings_.threads > 0 ? settings_.threads
                                              : std::max(1, int(std::thread::hardware_concurrency()));
    if (min_samples_ == 0 && threads > 1) {
      const int want = kItemsPerThread * threads, tiles = film_.tile_count();
      work_parts_ = std::clamp((want + tiles - 1) / tiles, 1, std::max(1, settings_.tile_size / 4));
    }
  }
  {
    // The kernel: chosen here from what the scene and this render use, never per ray. A bake
    // runs a general kernel: only those take its given first hit (PathCounters::first_hit).
    const bool aovs = film_.aux_stride() > 0 || settings_.film_transparent || scene_->any_holdout() ||
                      integrator_.cryptomatte != 0;
    // Fast GI: guiding off (its field would learn the approximation's light; Cycles' own guiding
    // is not combined with it here either), with the reason in SessionStats::guiding.
    const bool guiding = settings_.guiding && settings_.debug_view == DebugView::None && !integrator_.fast_gi();
    if (settings_.guiding && integrator_.fast_gi()) guiding_note_ = "off: not with Fast GI Approximation";
    integrator_.differentials = scene_->features().footprints;
    setup_caustics(guiding);
    kernel_ = select_kernel(kernel_features(scene_->features(), aovs, guiding, caustics_ != nullptr,
                                            integrator_.tricks(), integrator_.fast_gi()),
                            settings_.force_general_kernel || bake_ != nullptr, kernel_bits_);
    if (guiding) {
      // Müller et al.'s split threshold: cells keep about 12000 records (times the square root
      // of an iteration's samples), enough for a quadtree that follows light, not noise.
      const float threshold = 12000.0f;
      guide_ = std::make_unique<GuidingField>();
      guide_->reset(scene_->world_bounds(), threshold);
      integrator_.guide = guide_.get();
      integrator_.guide_training = true;
      integrator_.guide_probability = std::clamp(settings_.guiding_probability, 0.0f, 1.0f);
      integrator_.guide_learn_probability = settings_.guiding_learn_probability;
      integrator_.guide_cosine = settings_.guiding_cosine;
      guide_->set_learn_probability(settings_.guiding_learn_probability, integrator_.guide_probability);
      guide_->set_directional_filter(settings_.guiding_filter);
      integrator_.path_class_mask = settings_.guiding_class_mask;
      const float lobes = settings_.guiding_caustic_lobes;
      integrator_.guide_caustic_probability =
          settings_.guiding_caustics && std::isfinite(lobes) ? std::clamp(lobes, 0.0f, 0.9f) : 0.0f;
      if (integrator_.guide_caustic_probability > 0.0f)
        guide_->set_caustic_lobes(settings_.guiding_caustic_cube, settings_.guiding_caustic_cone);
      if (caustics_) {
        // The light paths' MIS takes the camera path's mixture pdf at its rough vertex.
        caustics_->guide = guide_.get();
        caustics_->guide_probability = integrator_.guide_probability;
        caustics_->guide_learn_probability = integrator_.guide_learn_probability;
        caustics_->guide_caustic_probability = integrator_.guide_caustic_probability;
      }
      guide_end_ = 1;
      // Caustic photons only where the caustic light paths are off: with them on, the light
      // paths carry the caustics the photons would aim the guide at, and on the window room
      // the photons then cost 15 % more instructions for no less error (docs/design/
      // sampling.md, "Guiding with caustic light paths").
      const float photons = settings_.guiding_caustics && caustics_ ? 0.0f : settings_.guiding_photons;
      if (std::isfinite(photons) && photons > 0.0f) {
        photon_sources_ = std::make_unique<GuidePhotonSources>(guide_photon_sources(*scene_));
        if (photon_sources_->empty()) photon_sources_.reset();  // (no light to start from)
        photons_per_sample_ = double(std::min(photons, 4096.0f)) * double(film_.width()) * double(film_.height());
        const float share = settings_.guiding_photon_share;
        guide_->set_photon_share(std::isfinite(share) ? std::clamp(share, 0.0f, 1.0f) : 0.5f);
        const float split = settings_.guiding_photon_split;
        guide_->set_photon_split_weight(std::isfinite(split) ? std::clamp(split, 0.0f, 1e4f) : 1.0f);
      }
    }
    integrator_.differentials = scene_->features().footprints;
    integrator_.path_state = scene_->features().path_state;
    const bool filter = !(settings_.filter_type == FilterType::Box && settings_.filter_width == 1.0f);
    std::vector<std::pair<std::string, bool>> all;
    const std::vector<std::string> used = scene_->features().names();
    for (const std::string& n : SceneFeatures::all_names())
      all.emplace_back(n, std::find(used.begin(), used.end(), n) != used.end());
    all.emplace_back("dof", camera_.has_aperture());
    all.emplace_back("pixel filter", filter);
    all.emplace_back("passes", film_.aux_stride() > 0);
    all.emplace_back("transparent film", settings_.film_transparent);
    all.emplace_back("adaptive sampling", settings_.adaptive_threshold > 0.0f);
    all.emplace_back("motion blur", motion_);
    all.emplace_back("guiding", guiding);
    all.emplace_back("light path tricks", integrator_.tricks());  // clamping, filter glossy, caustics off
    all.emplace_back("fast gi", integrator_.fast_gi());
    for (const auto& [n, on] : all) (on ? features_ : unused_features_).push_back(n);
  }
  tile_active_.resize(size_t(film_.tile_count()));
  for (int t = 0; t < film_.tile_count(); ++t) {
    int x0, y0, x1, y1;
    film_.tile_rect(t, x0, y0, x1, y1);
    tile_active_[size_t(t)] = (x1 - x0) * (y1 - y0);
  }
  active_.store(int64_t(film_.width()) * film_.height());
}

Session::~Session() {
  cancel_.store(true);
  if (controller_.joinable()) controller_.join();
  if (const WorldShader* ws = scene_ ? scene_->environment().world_shader() : nullptr) {
    const Camera* mine = &camera_;  // cleared only if no later session has set its own
    ws->camera.compare_exchange_strong(mine, nullptr);
  }
}

void Session::cancel() {
  cancel_.store(true);
  std::lock_guard<std::mutex> lk(m_);
  if (!started_.load()) finished_.store(true);  // never started: nothing will ever run
  cv_.notify_all();
}

void Session::start() {
  if (started_.exchange(true)) throw std::logic_error("session already started");
  if (finished_.load()) return;  // cancelled before it started
  t0_ = std::chrono::steady_clock::now();
  controller_ = std::thread([this] { run(); });
}

double Session::elapsed() const {
  const double e = end_elapsed_.load();
  if (e >= 0.0) return e;
  if (!started_.load()) return 0.0;
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0_).count();
}

bool Session::wait(double timeout_s) {
  std::unique_lock<std::mutex> lk(m_);
  const auto ready = [this] { return finished_.load() || passes_.load() != passes_seen_; };
  if (!started_.load() || finished_.load()) {
    passes_seen_ = passes_.load();
    return finished_.load();
  }
  // Clamped: a huge (or infinite) timeout would overflow the clock's representation.
  const double t = std::isfinite(timeout_s) ? std::clamp(timeout_s, 0.0, 1e6) : (timeout_s > 0 ? 1e6 : 0.0);
  cv_.wait_for(lk, std::chrono::duration<double>(t), ready);
  passes_seen_ = passes_.load();
  return finished_.load();
}

SessionProgress Session::progress() const {
  SessionProgress p;
  p.samples_done = samples_done_.load();
  p.samples_total = total_samples_;
  p.elapsed_s = elapsed();
  p.cancelled = cancel_.load();
  p.finished = finished_.load();
  return p;
}

SessionStats Session::stats() const {
  SessionStats s;
  s.rays = rays_.load();
  s.paths = paths_.load();
  s.nonfinite_samples = nonfinite_.load();
  s.passes = passes_.load();
  s.active_pixels = active_.load();
  s.threads = pool_ ? pool_->size() : 0;
  s.guiding_iterations = guide_iterations_.load();
  s.guiding_cells = guide_cells_.load();
  s.guiding_caustic_cells = guide_caustic_cells_.load();
  s.guiding_probability = guide_probability_.load();
  s.elapsed_s = elapsed();
  s.work_items = film_.tile_count() * work_parts_;
  s.focus_distance = focus_distance_;
  s.autofocus = autofocus_;
  s.kernel = kernel_name(kernel_bits_);
  s.caustics = caustics_note_;
  s.guiding = guiding_note_;
  s.caustic_connections = caustics_ ? caustics_->connections : 0;
  s.features = features_;
  s.unused_features = unused_features_;
  return s;
}

std::string Session::error() const {
  std::lock_guard<std::mutex> lk(m_);
  return error_;
}

void Session::write_aux(const PathAovs& a, float* out) const {
  auto put = [&](Pass p, Vec3 v) {
    const int off = film_.pass_offset(p);
    if (off < 0) return;
    const int ch = std::min(pass_desc(p).channels, 3);  // (a Vec3 at most: the matte is written below)
    for (int c = 0; c < ch; ++c) out[off + c] = std::isfinite(v[c]) ? v[c] : 0.0f;
  };
  // Misses add 0, as in Cycles: Depth reads 1e10 only where no sample hit anything.
  const float depth = a.hit ? camera_.z_depth(a.position) : 0.0f;
  put(Pass::Depth, Vec3(depth));
  put(Pass::Normal, a.normal);
  put(Pass::Position, a.position);
  put(Pass::Emit, a.emission);
  put(Pass::Env, a.environment);
  // Camera space as Cycles writes it: x right, y up, z away from the camera (facing: z < 0);
  // a panorama's own camera space.
  put(Pass::DenoisingNormal, camera_.dir_to_camera(a.denoising_normal));
  put(Pass::DenoisingAlbedo, a.denoising_albedo);
  static constexpr Pass kComponent[kLightComponents] = {
      Pass::DiffuseDirect,      Pass::DiffuseIndirect,      Pass::GlossyDirect, Pass::GlossyIndirect,
      Pass::TransmissionDirect, Pass::TransmissionIndirect, Pass::VolumeDirect, Pass::VolumeIndirect};
  for (int k = 0; k < kLightComponents; ++k) put(kComponent[k], a.light[k]);
  put(Pass::DiffuseColor, a.diffuse_color);
  put(Pass::GlossyColor, a.glossy_color);
  put(Pass::TransmissionColor, a.transmission_color);
  put(Pass::Mist, Vec3(a.mist));
  put(Pass::AO, a.ao);
  put(Pass::ObjectIndex, Vec3(a.object_index));
  put(Pass::MaterialIndex, Vec3(a.material_index));
  put(Pass::UV, a.uv);
  if (const int off = film_.pass_offset(Pass::Vector); off >= 0) {
    // Cycles' primitive_motion_vector: raster pixels (from the bottom-left) of the point at the
    // previous and next frames through those frames' cameras, less (or from) where it is now.
    float v[4] = {0.0f, 0.0f, 0.0f, 0.0f};
    if (a.hit) {
      const float w = float(settings_.width), h = float(settings_.height);
      const Vec3 c = camera_.to_ndc(a.position), pre = camera_pre_.to_ndc(a.motion_pre),
                 post = camera_post_.to_ndc(a.motion_post);
      v[0] = (pre.x - c.x) * w;
      v[1] = (pre.y - c.y) * h;
      v[2] = (c.x - post.x) * w;
      v[3] = (c.y - post.y) * h;
    }
    for (int k = 0; k < 4; ++k) out[off + k] = std::isfinite(v[k]) ? v[k] : 0.0f;
    out[film_.pass_offset(Pass::VectorWeight)] = a.hit ? 1.0f : 0.0f;
  }
  put(Pass::ShadowCatcher, a.catcher);
  const int m = film_.pass_offset(Pass::ShadowCatcherMatte);
  if (m >= 0) {  // (RGB and alpha: four channels)
    for (int c = 0; c < 3; ++c) out[m + c] = std::isfinite(a.matte[c]) ? a.matte[c] : 0.0f;
    out[m + 3] = std::isfinite(a.matte_alpha) ? a.matte_alpha : 1.0f;
  }
  put(Pass::ShadowCatcherSampleCount, Vec3(a.catcher_samples));
  for (int i = 0; i < film_.aov_count(); ++i) {
    const Float4 v = a.shader_aovs ? a.shader_aovs[i] : Float4{};
    const float vals[4] = {v.x, v.y, v.z, v.w};
    float* o = out + film_.aov_offset(i);
    for (int c = 0; c < film_.aov_channels(i); ++c) o[c] = std::isfinite(vals[c]) ? vals[c] : 0.0f;
  }
  for (int g = 0; g < film_.light_group_count(); ++g) {
    const Vec3 v = a.groups ? a.groups[g] : Vec3(0.0f);
    float* o = out + film_.light_group_offset() + 3 * g;
    for (int c = 0; c < 3; ++c) o[c] = std::isfinite(v[c]) ? v[c] : 0.0f;
  }
}

int Session::crypto_layer(uint32_t bit) const {
  const uint32_t on = integrator_.cryptomatte;
  if (!(on & bit) || (bit & (bit - 1))) return -1;
  return __builtin_popcount(on & (bit - 1));  // Object, Material, Asset: Cycles' buffer order
}

void Session::render_tile(int tile, int part, int parts, int s0, int s1) {
  int x0, y0, x1, y1;
  film_.tile_rect(tile, x0, y0, x1, y1);
  if (parts > 1) {  // a band of the tile's rows (no adaptive sampling: that judges whole tiles)
    const int rows = y1 - y0;
    y1 = y0 + rows * (part + 1) / parts;
    y0 += rows * part / parts;
    if (y0 >= y1) return;
  }
  const int tw = x1 - x0, th = y1 - y0;
  std::vector<Rgba> local(size_t(tw) * size_t(th));
  // Pass values of one sample per pixel (nothing without passes), and the path outputs that
  // feed them: only asked of trace_path when a pass or the transparent film needs them.
  const size_t stride = size_t(film_.aux_stride());
  std::vector<float> local_aux(size_t(tw) * size_t(th) * stride);
  // Cryptomatte: each pixel's surfaces of this sample (crypto_n of them), added under the lock.
  const bool crypto = integrator_.cryptomatte != 0;
  std::vector<CryptoHit> local_crypto(crypto ? size_t(tw) * size_t(th) * kMaxCryptoHits : 0);
  std::vector<uint8_t> crypto_n(crypto ? size_t(tw) * size_t(th) : 0);
  const int layer_object = crypto_layer(kCryptoObject), layer_material = crypto_layer(kCryptoMaterial),
            layer_asset = crypto_layer(kCryptoAsset);
  const bool want_aovs = stride > 0 || settings_.film_transparent || scene_->any_holdout() || crypto;
  const bool bvh_view = settings_.debug_view == DebugView::Bvh;
  std::array<Float4, kMaxShaderAovs> shader_aovs;
  const int groups = film_.light_group_count();
  std::vector<Vec3> group_light(static_cast<size_t>(groups));  // (PathAovs::groups: one sample's)
  const bool scratch = film_.aov_count() > 0 || groups > 0;
  PathCounters counters;
  if (caustics_) counters.filter_area = caustics_->filter_area;  // (the box's; other filters' per sample)
  uint64_t nonfinite = 0, paths = 0;
  const bool adaptive = min_samples_ > 0;
  // Blue noise: each pixel's sequence and chunk start, found once per tile.
  const bool patterned = pattern_map_.pattern() != PixelPattern::Independent;
  std::vector<PixelPatternMap::PixelBase> pattern_bases(patterned ? size_t(tw) * size_t(th) : 0);
  if (patterned)
    for (int y = y0; y < y1; ++y)
      pattern_map_.row_bases(x0 + region_x_, x1 + region_x_, y + region_y_, settings_.width,
                             &pattern_bases[size_t(y - y0) * size_t(tw)]);
  for (int s = s0; s < s1; ++s) {
    if (cancel_.load(std::memory_order_relaxed)) break;
    if (adaptive && tile_active_[size_t(tile)] == 0) break;
    for (int y = y0; y < y1; ++y)
      for (int x = x0; x < x1; ++x) {
        Rgba& out = local[size_t(y - y0) * size_t(tw) + size_t(x - x0)];
        // done flags only change under this thread's own tile work: safe to read here.
        if (adaptive && film_.converged(x, y)) {
          out.a = -1.0f;  // marks "no sample"
          continue;
        }
        const int fx = x + region_x_, fy = y + region_y_;  // in the full frame
        float* aux = stride ? &local_aux[(size_t(y - y0) * size_t(tw) + size_t(x - x0)) * stride] : nullptr;
        if (bvh_view) {
          // The pixel centre's camera ray, counted by the same traversal that renders.
          TraversalCounters tc;
          Hit hit;
          const Ray r = camera_.generate_pinhole(float(fx) + 0.5f, float(fy) + 0.5f);
          if (r.tmax > 0.0f) scene_->intersect(r, hit, &tc);  // a panorama's no-ray pixel: nothing
          std::fill(aux, aux + stride, 0.0f);
          aux[film_.pass_offset(Pass::BvhNodes)] = float(tc.nodes);
          aux[film_.pass_offset(Pass::BvhTriangles)] = float(tc.triangles);
          out = {0.0f, 0.0f, 0.0f, 1.0f};
          ++paths;
          continue;
        }
        PathAovs aovs;
        if (scratch) {  // (only renders with shader AOVs or light groups clear these)
          if (film_.aov_count()) {
            shader_aovs.fill(Float4{});
            aovs.shader_aovs = shader_aovs.data();
          }
          if (groups) {
            std::fill(group_light.begin(), group_light.end(), Vec3(0.0f));
            aovs.groups = group_light.data();
          }
        }
        if (crypto) crypto_n[size_t(y - y0) * size_t(tw) + size_t(x - x0)] = 0;
        // One independent stream per (seed, pixel, sample): thread- and pass-independent, and
        // keyed by the full-frame pixel, so a border renders exactly its part of the frame.
        const uint64_t pixel = uint64_t(fy) * uint64_t(settings_.width) + uint64_t(fx);
        const uint32_t sample = uint32_t(settings_.sample_offset + s);
        const SobolIndex si = patterned
                                  ? pattern_map_.map(pattern_bases[size_t(y - y0) * size_t(tw) + size_t(x - x0)], sample)
                                  : SobolIndex{pixel, sample};
        Sampler sampler(settings_.sampler, settings_.seed, pixel, sample, si.key, si.index);
        const Vec2 j = sampler.get2d();  // dimension 0: position in the pixel (filter)
        Ray ray;
        Hit bake_hit;
        if (bake_) {
          // Baking: the texel's surface point (its jitter from dimension 0), seen along its
          // smooth normal; the data bakes are read off the point itself.
          SurfacePoint bsp;
          float dp = 0.0f;
          if (!bake_point(size_t(fy) * size_t(settings_.width) + size_t(fx), sample, j, ray, bake_hit, bsp, dp)) {
            out = {0.0f, 0.0f, 0.0f, 0.0f};  // not this object's texel
            if (aux) write_aux(PathAovs{}, aux);
            ++paths;
            continue;
          }
          sampler.align_set();
          if (bake_->mode != BakeMode::Surface) {
            const Vec3 v = bake_->mode == BakeMode::Roughness ? Vec3(bake_roughness(bsp, -ray.dir))
                                                              : scene_->background(normalize(bsp.p));
            out = {v.x, v.y, v.z, 1.0f};
            if (!is_finite(v)) {
              out = {0.0f, 0.0f, 0.0f, 1.0f};
              ++nonfinite;
            }
            if (aux) write_aux(PathAovs{}, aux);
            ++paths;
            continue;
          }
          counters.first_hit = &bake_hit;
          counters.first_dp = dp;
        } else {
          // Dimension 1: the lens, taken only with an aperture, so pinhole renders keep the
          // same streams for their paths.
          const Vec2 lens = camera_.has_aperture() ? sampler.get2d() : Vec2{0.5f, 0.5f};
          const float jx = filter_.jitter(j.x), jy = filter_.jitter(j.y);
          const float rx = float(fx) + jx, ry = float(fy) + jy;
          // The caustic MIS's camera density: the filter's at this offset (the box's is flat).
          if (caustics_ && caustics_->filter)
            counters.filter_area = 1.0f / (filter_.density(jx - 0.5f) * filter_.density(jy - 0.5f));
          // Motion blur: the shutter time from the next dimension, drawn only where something
          // moves (static scenes keep their streams and their rays).
          // A rolling shutter moves each pixel row's times (Cycles' camera_sample).
          if (motion_) {
            float t = camera_.shutter().sample(sampler.get1d());
            if (camera_.rolling_shutter()) t = camera_.rolling_time(t, int(fy));
            ray = camera_.generate(rx, ry, lens, t);
          } else {
            ray = camera_.generate(rx, ry, lens);
          }
          sampler.align_set();
          // A panorama's sample whose direction the light tracer maps elsewhere (a filter's tail
          // past an equirectangular seam or pole) gets no light-path weight.
          if (caustics_ && camera_.is_panoramic()) counters.caustic_raster = camera_.pano_raster_is_canonical(rx, ry);
        }
        if (!(ray.tmax > 0.0f)) {  // outside a panorama's lens: black, as Cycles
          out = {0.0f, 0.0f, 0.0f, 1.0f};
          if (aux) write_aux(PathAovs{}, aux);
          ++paths;
          continue;
        }
        if (caustics_ && caustics_->connections > 0) counters.caustic_cache = &caustic_caches_[size_t(s - s0)];
        Vec3 L = kernel_(*scene_, ray, sampler, integrator_, counters, want_aovs ? &aovs : nullptr);
        counters.first_hit = nullptr;
        if (caustics_) {
          L += caustic_splats_[size_t(s - s0)][size_t(y) * size_t(film_.width()) + size_t(x)];
          if (groups) {  // (the light paths' splats, each to its emitter's group)
            const size_t pixels = size_t(film_.width()) * size_t(film_.height());
            const std::vector<Vec3>& gs = caustic_group_splats_[size_t(s - s0)];
            for (int g = 0; g < groups; ++g)
              group_light[size_t(g)] += gs[size_t(g) * pixels + size_t(y) * size_t(film_.width()) + size_t(x)];
          }
        }
        ++paths;
        const float alpha = std::isfinite(aovs.alpha) ? aovs.alpha : 1.0f;
        if (is_finite(L)) {
          out = {L.x, L.y, L.z, alpha};
        } else {  // dropped and counted: one bad path must not poison a pixel forever
          out = {0.0f, 0.0f, 0.0f, alpha};
          ++nonfinite;
          std::fill(group_light.begin(), group_light.end(), Vec3(0.0f));  // (its groups with it)
        }
        if (aux) write_aux(aovs, aux);
        if (crypto) {
          const size_t px = size_t(y - y0) * size_t(tw) + size_t(x - x0);
          crypto_n[px] = uint8_t(aovs.crypto_count);
          std::copy(aovs.crypto, aovs.crypto + aovs.crypto_count, &local_crypto[px * kMaxCryptoHits]);
        }
      }
    std::lock_guard<std::mutex> lk(film_.tile_lock(tile));
    for (int y = y0; y < y1; ++y)
      for (int x = x0; x < x1; ++x) {
        const Rgba& v = local[size_t(y - y0) * size_t(tw) + size_t(x - x0)];
        if (v.a < 0.0f) continue;
        film_.add_sample(x, y, v, stride ? &local_aux[(size_t(y - y0) * size_t(tw) + size_t(x - x0)) * stride] : nullptr);
        if (crypto) {
          const size_t px = size_t(y - y0) * size_t(tw) + size_t(x - x0);
          for (int k = 0; k < crypto_n[px]; ++k) {
            const CryptoHit& h = local_crypto[px * kMaxCryptoHits + size_t(k)];
            if (layer_object >= 0) film_.add_crypto(x, y, layer_object, h.object, h.weight);
            if (layer_material >= 0) film_.add_crypto(x, y, layer_material, h.material, h.weight);
            if (layer_asset >= 0) film_.add_crypto(x, y, layer_asset, h.asset, h.weight);
          }
        }
      }
    // Convergence is judged at fixed sample counts, so the result stays deterministic.
    const int n = s + 1;
    if (adaptive && n >= min_samples_ && (n - min_samples_) % check_every_ == 0) {
      const int active = film_.update_convergence(tile, settings_.adaptive_threshold);
      active_.fetch_sub(tile_active_[size_t(tile)] - active);
      tile_active_[size_t(tile)] = active;
    }
  }
  paths_.fetch_add(paths, std::memory_order_relaxed);
  rays_.fetch_add(counters.rays, std::memory_order_relaxed);
  nonfinite_.fetch_add(nonfinite, std::memory_order_relaxed);
}

bool Session::bake_point(size_t texel, uint32_t sample, Vec2 j, Ray& ray, Hit& hit, SurfacePoint& sp, float& dp) const {
  const uint32_t prim = bake_prims_[texel];
  if (prim == UINT32_MAX) return false;
  const BakeInput& b = *bake_;
  float b1 = b.bary[2 * texel], b2 = b.bary[2 * texel + 1];
  // Exactly at a corner: nudged towards the centre (Cycles' bake_offset_towards_center), so a
  // ray leaving it does not start on the neighbours' edges.
  if ((b1 == 0.0f || b1 == 1.0f) && (b2 == 0.0f || b2 == 1.0f)) {
    b1 += (1.0f / 3.0f - b1) * 1e-4f;
    b2 += (1.0f / 3.0f - b2) * 1e-4f;
  }
  float d[4] = {0.0f, 0.0f, 0.0f, 0.0f};
  if (!b.differentials.empty()) std::copy_n(&b.differentials[4 * texel], 4, d);
  if (sample > 0 && !b.differentials.empty()) {
    // Cycles' bake_jitter_barycentric: a point of the texel, retried (at most 10 times) until it
    // falls inside the triangle, else the centre.
    Pcg32 rng;
    bool rng_set = false;
    for (int i = 0; i < 10; ++i) {
      const float u1 = b1 + (j.x - 0.5f) * d[0] + (j.y - 0.5f) * d[1];
      const float u2 = b2 + (j.x - 0.5f) * d[2] + (j.y - 0.5f) * d[3];
      if (u1 > 0.0f && u2 > 0.0f && u1 + u2 < 1.0f) {
        b1 = u1, b2 = u2;
        break;
      }
      if (!rng_set) rng.set(uint64_t(texel) * 0x9E3779B97F4A7C15ULL + sample, 0xB4CEB4CEULL), rng_set = true;
      j = Vec2{rng.next_float(), rng.next_float()};
    }
  }
  hit.inst = b.instance;
  hit.prim = prim;
  hit.b1 = b1;
  hit.b2 = b2;
  hit.t = 0.0f;  // the ray starts on the surface: it crosses no light or medium on the way
  scene_->surface_point(hit, sp, 0.5f);
  ray.org = sp.p;
  Vec3 view = sp.ns;  // seen along the smooth normal, as Cycles' bake ray (P + N towards -N)
  if (b.view_from_camera) {
    // Cycles' use_camera: towards the camera, at least 0.2 above the smooth normal, leaning to
    // it on the back side, and never behind the geometric normal.
    const Vec3 n = sp.ns;
    Vec3 d = camera_.orthographic() ? -camera_.forward() : normalize(camera_.origin() - sp.p);
    const float dn = dot(d, n);
    if (dn <= 0.2f) d = normalize(d - n * (dn - 0.2f));
    if (dn <= 0.0f) d = normalize(d + (n - d) * (-dn));
    if (dot(d, sp.ng) <= 1e-5f) d = normalize(d - sp.ng * (dot(d, sp.ng) - 1e-5f));
    if (is_finite(d)) view = d;
  }
  ray.dir = -view;
  ray.tmax = kInf;
  ray.time = 0.5f;
  // The footprint: Cycles' dP = dP/du du + dP/dv dv over the texel, compacted (the mean length).
  Vec3 v0, v1, v2;
  dp = 0.0f;
  if (scene_->instance_triangle(b.instance, prim, v0, v1, v2)) {
    const Vec3 e1 = v1 - v0, e2 = v2 - v0;
    const float l = 0.5f * (length(e1 * d[0] + e2 * d[2]) + length(e1 * d[1] + e2 * d[3]));
    dp = std::isfinite(l) ? l : 0.0f;
  }
  return is_finite(sp.p) && is_finite(sp.ns);
}

float Session::bake_roughness(const SurfacePoint& sp, Vec3 wo) const {
  // Cycles' surface_shader_average_roughness: the BSDFs' roughness (the square root of alpha,
  // Oren-Nayar's sigma, 0 for sharp and transparent lobes, 1 for the others without one) averaged
  // by the closures' mean weights; diffuse lobes have none and are left out; 1 without any.
  ClosureList cl;
  RayState rs;
  rs.camera = integrator_.camera;
  scene_->shade(sp, sp.b1, sp.b2, wo, cl, rs);
  float sum = 0.0f, total = 0.0f;
  for (int i = 0; i < cl.n; ++i) {
    const Closure& c = cl.c[size_t(i)];
    float weight = std::fabs(average(c.weight));
    float r;  // the roughness the pass reads; negative: none
    if (const auto* m = std::get_if<ConductorBsdf>(&c.bsdf)) {
      r = std::sqrt(std::sqrt(m->alpha * (m->alpha_y < 0.0f ? m->alpha : m->alpha_y)));
      // (Cycles' closure weight leaves out the 1 / E Pathlight's carries: see pass_colors)
      if (m->compensated) weight *= table_2d(tables::ggx_E, r, std::fabs(dot(wo, c.frame.n)), 32, 32);
    } else if (const auto* g = std::get_if<DielectricBsdf>(&c.bsdf)) {
      r = std::sqrt(std::sqrt(g->alpha * (g->alpha_y < 0.0f ? g->alpha : g->alpha_y)));
    } else if (const auto* o = std::get_if<OrenNayarBsdf>(&c.bsdf)) {
      r = o->a > 0.0f ? o->b / o->a : 0.0f;  // (a = 1 / (pi + (pi / 2 - 2 / 3) sigma), b = sigma a)
    } else if (std::holds_alternative<TransparentBsdf>(c.bsdf) || std::holds_alternative<PortalBsdf>(c.bsdf)) {
      r = 0.0f;
    } else if (std::holds_alternative<DiffuseBsdf>(c.bsdf) || std::holds_alternative<TranslucentBsdf>(c.bsdf) ||
               std::holds_alternative<SheenBsdf>(c.bsdf) || std::holds_alternative<VelvetBsdf>(c.bsdf) ||
               std::holds_alternative<SubsurfaceBsdf>(c.bsdf)) {
      r = -1.0f;  // diffuse lobes (and the BSSRDF, no BSDF in Cycles)
    } else if (const auto* t = std::get_if<ToonBsdf>(&c.bsdf)) {
      r = t->glossy ? 1.0f : -1.0f;
    } else {
      r = 1.0f;  // hair: no microfacet roughness
    }
    if (r < 0.0f || !std::isfinite(r)) continue;
    sum += weight * r;
    total += weight;
  }
  return total > 0.0f ? sum / total : 1.0f;
}

namespace {
// Automatic caustic light paths (docs/design/sampling.md, "Automatic caustic light paths"): this
// many per pixel sample (the textured model's best), where the environment's directions brighter
// than kAutoPeakFactor x its mean hold at least kAutoPeakShare of its power.
constexpr float kAutoCausticPaths = 0.1f;
constexpr float kAutoPeakFactor = 10.0f;
constexpr float kAutoPeakShare = 0.4f;
// Where the environment's rule does not turn them on: this many per pixel sample where lamps with
// extent (a sun with an angle, points and spots with a radius, area lamps) send at least
// kAutoLampShare of the light paths' power and the probes find smooth glass or mirrors, whose
// caustics the path tracer makes only by BSDF rays that pass the glass and find the lamp
// ("Glass and mirrors under a sun lamp: the automatic rule").
constexpr float kAutoLampPaths = 0.25f;
constexpr float kAutoLampShare = 0.5f;
// Light-vertex connections at the first this many rough vertices where the automatic light paths
// run (docs/design/sampling.md, "Caustics seen after further rough bounces": the window room's
// error at equal instructions 1.55x lower, the textured model's 1.11x).
constexpr int kAutoConnections = 2;
// The light vertices kept per pixel sample (CausticCache), about: ~120 MB. Beyond, whole chunks
// of light paths, fixed per render, are left out of the connections (not of the splats).
constexpr size_t kMaxCachedVertices = size_t(1) << 20;
constexpr uint64_t kCausticChunk = 2048;  // light paths per work item (trace_caustics)
}  // namespace

// Caustic light tracing (CausticLight): on where asked for and where it can be combined exactly
// with the path tracer; else off, with the reason (SessionStats::caustics).
void Session::setup_caustics(bool guiding) {
  float lt = settings_.caustic_light_paths;
  // Automatic: on at kAutoCausticPaths only where they pay (below), else off without a warning.
  const bool automatic = settings_.caustic_light_paths_auto && !(lt > 0.0f);
  if (automatic) lt = kAutoCausticPaths;
  if (!std::isfinite(lt) || !(lt > 0.0f)) return;
  const auto off = [&](const std::string& why) { caustics_note_ = (automatic ? "off (automatic): " : "off: ") + why; };
  // Where it can be combined exactly with the path tracer; else off, with the reason.
  const SceneFeatures& sf = scene_->features();
  const int k_max = std::min({8, settings_.max_bounces, 1 + std::min(settings_.glossy_bounces, settings_.transmission_bounces)});
  // (a world that Sampling Method None keeps from being a light sends no light paths either)
  const bool env = scene_->environment().valid() && scene_->world_sampled();
  const bool nee = settings_.use_nee && scene_->has_lights();
  // The lamps that may send light paths: suns, points, spots and area lamps (with extent, where
  // rays find them), with the settings a light path can follow.
  std::vector<uint32_t> lamps;
  if (nee)
    for (size_t i = 0; i < scene_->light_count(); ++i)
      if (caustic_lamp(scene_->light(i), scene_->light_hits_enabled())) lamps.push_back(uint32_t(i));
  if (settings_.debug_view != DebugView::None) off("debug view");
  else if (guiding && settings_.guiding_class_mask != 0) off("not with path classes (a measurement of guiding)");
  else if (film_.has_pass(Pass::ShadowCatcherMatte)) off("not combined with shadow catchers");
  else if (scene_->features().camera_invisible) off("not combined with Indirect Only objects");
  // Cycles has no light paths: Filter Glossy and the caustics toggles shape what its path tracer
  // makes of caustics, which light paths would add back unfiltered (docs/design/sampling.md,
  // "Filter Glossy and caustics toggles").
  else if (integrator_.filter_glossy > 0.0f || integrator_.caustics_off != 0)
    off("not with Filter Glossy or the Reflective / Refractive Caustics switched off");
  // Fast GI cuts the indirect light short; light paths would bring back what it leaves out.
  else if (integrator_.fast_gi())
    off("not with Fast GI Approximation");
  // A light path's splat lands on rows whose shutter times differ from its own.
  else if (motion_ && camera_.rolling_shutter())
    off("not with a rolling shutter");
  // A light's Max Bounces limits its light samples; light paths from it would add unlimited light.
  else if (sf.light_bounce_limits)
    off("not with a light's Max Bounces");
  // A thin lens connects through a point on its aperture (integrator_caustics.cpp), the
  // orthographic one's too; a pinhole panorama through its inverse map, a moving camera or
  // scene at the light path's own shutter time. An orthographic pinhole's rays are parallel: a
  // light path meets one with probability 0. A panorama's lens (a disk turned with each ray, a
  // spherical focal surface) has no inverse here.
  else if (camera_.has_spherical_stereo())
    off("not with spherical stereo (each camera ray has its own centre of projection, which the "
        "connections to the camera cannot invert)");
  else if (camera_.is_panoramic() && camera_.has_aperture())
    off("not with a panoramic camera's depth of field");
  else if (camera_.orthographic() && !camera_.has_aperture())
    off("not with an orthographic camera without depth of field (light paths cannot meet its parallel rays)");
  else if (env && scene_->environment().program())
    off("not with a world whose node tree is a program (its Light Path state and map)");
  else if (sf.media || sf.path_state || sf.light_links)
    off("not with volumes, Light Path node state or light linking");
  else if (!env && lamps.empty())
    off("only an environment map or a lamp (found by rays where it has extent) sends caustic light paths");
  else if (k_max < 2 || settings_.diffuse_bounces < 1 || settings_.glossy_bounces < 1)
    off("the bounce limits leave no caustic paths");
  std::string peak_note, env_off;
  bool lamp_rule = false;  // automatic, decided by the lamps' share below
  if (automatic && caustics_note_.empty()) {
    // Where they paid by the realistic scenes' measurements (docs/design/sampling.md, "Automatic
    // caustic light paths"): an environment map with a sun, whose bright directions hold most of
    // its power; else lamps with extent over smooth glass or mirrors (below). A dim peak, or
    // lamps without extent or glass, stay off.
    const float share = environment_peak_share(scene_->environment(), kAutoPeakFactor);
    char why[160];
    std::snprintf(why, sizeof why, "the environment's peak holds %.0f %% of its power (%s %.0f %%)", 100.0 * share,
                  share >= kAutoPeakShare ? "at least" : "under", 100.0 * kAutoPeakShare);
    if (env && share >= kAutoPeakShare) {
      peak_note = why;
    } else {
      env_off = env ? why : "no environment map";
      bool extent = false;
      for (const uint32_t i : lamps) extent = extent || light_has_extent(scene_->light(i));
      if (extent) lamp_rule = true;
      else if (lamps.empty()) off(env_off);  // (as before the lamps' rule: no probes)
      // A delta lamp's light paths stop at glass and mirrors: no strategy of the path tracer
      // makes those caustics (docs/design/sampling.md "Caustics from lamps").
      else off(env_off + "; no lamp with extent (a sun with an angle, a radius, an area lamp)");
    }
  }
  if (!caustics_note_.empty()) return;
  Vec3 c;
  float r;
  bool delta = false;
  if (!caustic_casters(*scene_, 32768, c, r, scene_->has_motion(), &delta)) {
    off("no smooth surface to cast caustics");
    return;
  }
  if (lamp_rule && !delta) {
    off(env_off + "; no smooth glass or mirror for the lamps' rule");
    return;
  }
  auto cz = std::make_unique<CausticLight>();
  cz->center = c;
  cz->radius = r;
  // The emitters by the power each sends through the caster sphere (a lamp far from the smooth
  // surfaces gets few paths): the environment's and a sun's through its disk, a point's or
  // spot's into the cone it subtends (a spot's mean attenuation there from a 16 x 16 grid).
  const float disk = kPi * r * r;
  std::vector<float> power{env ? disk * 4.0f * kPi * scene_->environment().average_luminance() : 0.0f};
  cz->lamp_of.assign(scene_->light_count(), -1);
  for (const uint32_t i : lamps) {
    const Light& l = scene_->light(i);
    CausticLamp m;
    m.light = i;
    m.extent = light_has_extent(l);
    const float lum = std::max(luminance(l.color), 0.0f) * light_power_scale(l);
    // The cone the caster sphere subtends from a point's, spot's or area lamp's centre (every
    // direction from inside it).
    const Vec3 to_c = c - l.position;
    const float d = length(to_c);
    const float omc = d > r ? one_minus_cos_from_sin2((r / d) * (r / d)) : 2.0f;
    float p = 0.0f;
    if (l.type == LightType::Sun) {
      p = disk * lum;
    } else if (l.type == LightType::Rect || l.type == LightType::Ellipse) {
      // Its radiance over its area into that cone, by the cosine towards it (a tenth where the
      // sphere is beside or behind it).
      const float cos_c = d > 0.0f ? dot(to_c, l.dir) / d : 1.0f;
      p = lum * l.area * 2.0f * kPi * omc * std::max(0.1f, cos_c);
    } else {
      if (d > r) {
        m.axis = to_c / d;
        m.one_minus_cos = omc;
      }
      float att = 1.0f;
      if (l.type == LightType::Spot) {
        Vec3 t, b;
        make_basis(m.axis, t, b);
        double sum = 0.0;
        for (int u = 0; u < 16; ++u)
          for (int v = 0; v < 16; ++v) {
            const float cos_t = 1.0f - (float(u) + 0.5f) / 16.0f * m.one_minus_cos;
            const float sin_t = std::sqrt(std::max(0.0f, 1.0f - cos_t * cos_t)), phi = 2.0f * kPi * (float(v) + 0.5f) / 16.0f;
            sum += spot_attenuation(l, m.axis * cos_t + (t * std::cos(phi) + b * std::sin(phi)) * sin_t);
          }
        att = float(sum / 256.0);
      }
      p = lum * att * 2.0f * kPi * m.one_minus_cos;
    }
    if (!(p > 0.0f) || !std::isfinite(p)) continue;
    cz->lamp_of[i] = int32_t(cz->lamps.size());
    cz->lamps.push_back(m);
    power.push_back(p);
  }
  cz->sources = Distribution1D(power);
  if (cz->sources.empty()) {
    off("no light reaches the smooth surfaces");
    return;
  }
  cz->env_pmf = cz->sources.pmf(0);
  for (size_t j = 0; j < cz->lamps.size(); ++j) cz->lamps[j].pmf = cz->sources.pmf(j + 1);
  if (lamp_rule) {
    // Lamps with extent by their pmf: delta lamps' paths stop at glass and mirrors (no strategy
    // of the path tracer makes those), and the environment's are the environment rule's.
    float share = 0.0f;
    for (const CausticLamp& m : cz->lamps)
      if (m.extent) share += m.pmf;
    char why[200];
    std::snprintf(why, sizeof why,
                  "lamps with extent send %.0f %% of the light paths' power (%s %.0f %%), over smooth glass or mirrors",
                  100.0 * share, share >= kAutoLampShare ? "at least" : "under", 100.0 * kAutoLampShare);
    if (!(share >= kAutoLampShare)) {
      off(env_off + "; " + why);
      return;
    }
    lt = kAutoLampPaths;
    peak_note = why;
  }
  caustic_paths_ = uint64_t(std::max<double>(1.0, std::llround(double(std::min(lt, 64.0f)) * film_.width() * film_.height())));
  cz->paths = float(caustic_paths_);
  cz->clamp = integrator_.clamp_indirect;
  const Aabb& wb = scene_->world_bounds();
  cz->far = length((wb.lo + wb.hi) * 0.5f - c) + length(wb.extent()) + 2.0f * r;
  cz->max_vertices = k_max;
  cz->filter_area = settings_.filter_width * settings_.filter_width;
  if (settings_.filter_type != FilterType::Box) cz->filter = &filter_;
  cz->camera = &camera_;
  cz->nee = nee;
  cz->differentials = integrator_.differentials;
  cz->motion = motion_;
  const int connections = settings_.caustic_connections >= 0 ? settings_.caustic_connections
                          : automatic && !lamp_rule          ? kAutoConnections
                                                             : 0;
  // (not with motion blur: a cached vertex holds the scene at its light path's own shutter time,
  // which a camera path of another time cannot connect to)
  if (connections > 0 && !motion_) {
    // Light-vertex connections: the heuristic's count, the light paths per cached vertex, from
    // a probe of the light paths with a stream of its own (the same for any threads and passes).
    cz->connections = std::min(connections, 64);
    constexpr uint64_t kProbe = 8192;
    std::vector<CausticSplat> none;
    std::vector<CausticVertex> found;
    trace_caustic_paths(*scene_, *cz, 0x1C0C0A57ULL, 0, kProbe, 0, 0, 0, 0, none, &found);
    cz->connection_count = found.empty() ? 1.0f : float(double(kProbe) / double(found.size()));
  }
  caustics_ = std::move(cz);
  integrator_.caustics = caustics_.get();
  caustics_note_ = automatic ? "on (automatic): " + peak_note : "on";
}

// Light paths of samples [s0, s0 + k): sample s's are indexed (s, i) with their own streams,
// traced in chunks on the pool, and summed into its image in chunk order: the same image for
// any thread count and any split into passes.
// The chunks of light paths whose rough vertices the connections may pick: as many as hold
// about kMaxCachedVertices (by the probe's light paths per vertex), at least one.
uint64_t Session::connection_chunks() const {
  const double c = double(kMaxCachedVertices) * caustics_->connection_count / double(kCausticChunk);
  return std::max<uint64_t>(1, c < 1e15 ? uint64_t(c) : uint64_t(1e15));
}

void Session::trace_caustics(int s0, int k) {
  constexpr uint64_t kChunk = kCausticChunk;
  const uint64_t n = caustic_paths_, chunks = (n + kChunk - 1) / kChunk;
  const size_t pixels = size_t(film_.width()) * size_t(film_.height());
  caustic_splats_.resize(size_t(k));
  const int groups = film_.light_group_count();
  caustic_group_splats_.resize(groups ? size_t(k) : 0);
  const bool lvc = caustics_->connections > 0;
  const uint64_t lvc_chunks = lvc ? std::min(chunks, connection_chunks()) : 0;
  if (lvc) caustic_caches_.resize(size_t(k));
  std::vector<std::vector<CausticSplat>> parts(static_cast<size_t>(chunks));
  std::vector<std::vector<CausticVertex>> vparts(lvc ? static_cast<size_t>(chunks) : 0);
  for (int j = 0; j < k; ++j) {
    const uint32_t sample = uint32_t(settings_.sample_offset + s0 + j);
    const uint64_t seed = mix64(uint64_t(uint32_t(settings_.seed)) * 0x9E3779B97F4A7C15ULL ^
                                (uint64_t(sample) << 20) ^ 0xCA0571CULL);
    pool_->parallel_for(size_t(chunks), [&](size_t c, int) {
      if (cancel_.load(std::memory_order_relaxed)) return;
      parts[c].clear();
      if (lvc) vparts[c].clear();
      const uint64_t first = uint64_t(c) * kChunk, last = std::min(n, first + kChunk);
      rays_.fetch_add(trace_caustic_paths(*scene_, *caustics_, seed, first, last, region_x_, region_y_, film_.width(),
                                          film_.height(), parts[c], c < lvc_chunks ? &vparts[c] : nullptr),
                      std::memory_order_relaxed);
    });
    if (lvc) {
      // Its light vertices in path order (chunk by chunk): the same cache for any threads,
      // from the first lvc_chunks chunks' light paths (a number fixed per render, never this
      // sample's counts: each of those paths' y is picked with probability 1 / paths).
      CausticCache& cache = caustic_caches_[size_t(j)];
      cache.v.clear();
      cache.paths = std::min(n, lvc_chunks * kChunk);
      for (uint64_t c = 0; c < lvc_chunks; ++c) cache.v.insert(cache.v.end(), vparts[c].begin(), vparts[c].end());
    }
    std::vector<Vec3>& img = caustic_splats_[size_t(j)];
    img.assign(pixels, Vec3(0.0f));
    for (const auto& part : parts)
      for (const CausticSplat& sp : part) img[sp.pixel] += sp.value;
    if (groups) {
      std::vector<Vec3>& gi = caustic_group_splats_[size_t(j)];
      gi.assign(size_t(groups) * pixels, Vec3(0.0f));
      for (const auto& part : parts)
        for (const CausticSplat& sp : part)
          if (sp.group >= 0 && sp.group < groups) gi[size_t(sp.group) * pixels + sp.pixel] += sp.value;
    }
  }
}

// Training iterations of 1, 2, 4 ... samples (Müller et al.), each learning from its own
// samples, while the training stays within half the render's samples and at most 255.
void Session::end_guiding_iteration() {
  if (photon_sources_) {
    // The iteration's photons, in chunks; photon i's stream depends on the seed, the iteration
    // and i alone, and records add up in fixed point: the same field for any thread count.
    const uint64_t n = uint64_t(std::llround(photons_per_sample_ * double(guide_size_)));
    const uint64_t chunk = 4096, chunks = (n + chunk - 1) / chunk;
    const uint64_t seed = mix64(uint64_t(uint32_t(settings_.seed)) * 0x9E3779B97F4A7C15ULL + uint64_t(guide_->iterations()) +
                                (uint64_t(uint32_t(settings_.sample_offset)) << 32));
    pool_->parallel_for(size_t(chunks), [&](size_t c, int) {
      const uint64_t first = uint64_t(c) * chunk, last = std::min(n, first + chunk);
      if (cancel_.load(std::memory_order_relaxed)) return;
      rays_.fetch_add(trace_guide_photons(*scene_, *photon_sources_, *guide_, seed, first, last, settings_.max_bounces,
                                          settings_.guiding_caustics),
                      std::memory_order_relaxed);
    });
    photon_sources_->end_iteration();
  }
  guide_->end_iteration(guide_size_);
  guide_iterations_.store(guide_->iterations());
  guide_cells_.store(int(guide_->cells()));
  guide_caustic_cells_.store(int(guide_->caustic_cells()));
  guide_probability_.store(guide_->mean_probability());
  guide_size_ *= 2;
  const int limit = std::min(total_samples_ / 2, 255);
  if (guide_end_ + guide_size_ <= limit) guide_end_ += guide_size_;
  else integrator_.guide_training = false;
}

void Session::run() {
  try {
    pool_ = std::make_unique<ThreadPool>(settings_.threads);
    const int total = total_samples_;
    double sec_per_sample = 0.0;
    while (samples_done_.load() < total && !cancel_.load() && active_.load() > 0) {
      const double now = elapsed();
      const double limit = settings_.time_limit;
      if (limit > 0.0 && now >= limit) break;
      // Passes start at one sample for quick feedback and grow towards ~1 s, never past
      // the time limit, so updates stay frequent and the limit is met closely.
      int k = 1;
      if (sec_per_sample > 0.0) {
        const double target = std::min(1.0, 0.1 + 0.25 * now);
        double budget = target;
        if (limit > 0.0) budget = std::min(budget, limit - now);
        k = std::max(1, static_cast<int>(budget / sec_per_sample));
      }
      const int s0 = samples_done_.load();
      k = std::min(k, total - s0);
      if (integrator_.guide_training) k = std::min(k, guide_end_ - s0);  // iterations end on time
      const double pass_start = elapsed();
      if (caustics_) {
        // The pass's light paths first: a film image of splats per sample (at most ~64 MB).
        const double image = 12.0 * double(film_.width()) * double(film_.height());
        k = std::max(1, std::min(k, int(64e6 / image)));
        if (caustics_->connections > 0) {
          // (and their light vertices: at most kMaxCachedVertices each, ~256 MB in all)
          const double per =
              double(std::min(caustic_paths_, connection_chunks() * kCausticChunk)) / caustics_->connection_count;
          k = std::max(1, std::min(k, int(256e6 / (per * sizeof(CausticVertex) + 1.0))));
        }
        trace_caustics(s0, k);
        if (cancel_.load()) break;
      }
      const int parts = work_parts_;
      pool_->parallel_for(size_t(film_.tile_count()) * size_t(parts), [&](size_t item, int) {
        render_tile(int(item) / parts, int(item) % parts, parts, s0, s0 + k);
      });
      if (cancel_.load()) break;
      sec_per_sample = std::max(1e-6, (elapsed() - pass_start) / k);
      samples_done_.store(s0 + k);
      if (integrator_.guide_training && s0 + k == guide_end_) end_guiding_iteration();
      {
        std::lock_guard<std::mutex> lk(m_);
        passes_.fetch_add(1);
      }
      cv_.notify_all();
    }
  } catch (const std::exception& e) {
    std::lock_guard<std::mutex> lk(m_);
    error_ = e.what();
  } catch (...) {
    std::lock_guard<std::mutex> lk(m_);
    error_ = "unknown error in the render thread";
  }
  end_elapsed_.store(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0_).count());
  {
    std::lock_guard<std::mutex> lk(m_);
    finished_.store(true);
  }
  cv_.notify_all();
}

}  // namespace pl
