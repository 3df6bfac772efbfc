// HDR accumulation buffer: a running mean per pixel (the seed's progressive converge), updated
// one sample at a time in sample order, so the result does not depend on how samples were
// grouped into passes or on which thread rendered them. Rows are stored bottom-up (Blender's order).
#pragma once
#include <cstdint>
#include <algorithm>
#include <cstring>
#include <mutex>
#include <utility>
#include <vector>

#include "util/math.h"

namespace pl {

struct Rgba {
  float r = 0, g = 0, b = 0, a = 0;
};

// Render passes besides Combined, named as Blender/Cycles name them so that the compositor's
// Render Layers sockets and multilayer EXR layers line up. Each one the render asks for gets
// its own running-mean plane (Sample Count excepted: it is the film's own sample counter).
enum class Pass : int {
  Depth,            // 1: distance along the camera's view axis (Cycles' Z), 1e10 where nothing was hit
  Normal,           // 3: world shading normal, facing the camera ray
  Position,         // 3: world position
  Emit,             // 3: emission seen directly
  Env,              // 3: the world seen directly
  DenoisingNormal,  // 3: camera-space normal of the first rough surface (Cycles' denoising feature)
  DenoisingAlbedo,  // 3: its albedo, times the specular albedo of the surfaces passed on the way
  BvhNodes,         // 1: BVH nodes visited by the camera ray (debug view)
  BvhTriangles,     // 1: triangles tested by the camera ray (debug view)
  SampleCount,      // 1: samples taken in the pixel (not averaged)
  // Cycles' light components (integrator.h LightComponent), read divided by their Color pass
  // (0 where it is 0), and the colours: DiffDir, DiffInd, DiffCol, GlossDir, ...
  DiffuseDirect,
  DiffuseIndirect,
  DiffuseColor,
  GlossyDirect,
  GlossyIndirect,
  GlossyColor,
  TransmissionDirect,
  TransmissionIndirect,
  TransmissionColor,
  VolumeDirect,
  VolumeIndirect,
  Mist,  // 1: kept as the mean of (1 - mist) * alpha, read as 1 minus it (Cycles' order)
  AO,    // 3: unoccluded fraction of the AO rays at the camera path's surfaces
  ObjectIndex,    // 1: pass index of the object first seen (Cycles: of the first sample only)
  MaterialIndex,  // 1: pass index of its material, likewise
  UV,             // 3: (u, v, 1) of the active render UV map at the first surface (0 without one), Cycles' UVA
  // 4: Cycles' motion vectors in raster pixels: (previous - here).xy, (here - next).xy, the
  // frames before and after; read divided by VectorWeight (the samples that hit something).
  Vector,
  VectorWeight,   // 1: kept for Vector (its divisor), not a Blender pass
  // Shadow catcher (integrator.h PathAovs), kept whenever a catcher is in the scene. Shadow
  // Catcher: the catcher path's light, read as Cycles' film_calculate_shadow_catcher (what the
  // catcher receives with the other objects over what it would without them); the matte: RGB and
  // alpha of the paths without the catcher; the sample count: the samples that split.
  ShadowCatcher,
  ShadowCatcherMatte,
  ShadowCatcherSampleCount,
  Count
};
constexpr int kPassCount = int(Pass::Count);
static_assert(kPassCount < 32, "passes are bits of a uint32_t (RenderSettings::passes, pass_bit)");

struct PassDesc {
  const char* name;
  int channels;
  bool exposure;  // light passes scale with the film exposure, data passes do not
  int divide = -1;  // a Pass whose value divides this one's on reading (light components)
  bool first = false;  // keeps the pixel's first sample (ids do not average), as Cycles
};

inline const PassDesc& pass_desc(Pass p) {
  static const PassDesc table[kPassCount] = {
      {"Depth", 1, false},           {"Normal", 3, false},           {"Position", 3, false},
      {"Emit", 3, true},             {"Env", 3, true},               {"Denoising Normal", 3, false},
      {"Denoising Albedo", 3, false}, {"BVH Nodes", 1, false},       {"BVH Triangles", 1, false},
      {"Sample Count", 1, false},
      {"DiffDir", 3, true, int(Pass::DiffuseColor)},   {"DiffInd", 3, true, int(Pass::DiffuseColor)},
      {"DiffCol", 3, false},
      {"GlossDir", 3, true, int(Pass::GlossyColor)},   {"GlossInd", 3, true, int(Pass::GlossyColor)},
      {"GlossCol", 3, false},
      {"TransDir", 3, true, int(Pass::TransmissionColor)}, {"TransInd", 3, true, int(Pass::TransmissionColor)},
      {"TransCol", 3, false},
      {"VolumeDir", 3, true},                          {"VolumeInd", 3, true},
      {"Mist", 1, false},                              {"AO", 3, false},
      {"IndexOB", 1, false, -1, true},                 {"IndexMA", 1, false, -1, true},
      {"UV", 3, false},                                {"Vector", 4, false, int(Pass::VectorWeight)},
      {"Vector Weight", 1, false},
      {"Shadow Catcher", 3, false},                    {"Shadow Catcher Matte", 4, true},
      {"Shadow Catcher Sample Count", 1, false},
  };
  return table[int(p)];
}

inline uint32_t pass_bit(Pass p) { return 1u << uint32_t(p); }

// How Combined is read when the scene has shadow catchers (Cycles' get_actual_display_pass:
// the matte pass instead of Combined, and PassAccessor's approximate shadow catcher).
enum class CatcherCombined : int {
  None,         // no catcher: Combined as rendered
  Matte,        // the Shadow Catcher pass is asked for: the matte alone, for compositing by hand
  Approximate,  // the matte over the shadow: alpha 1 - average(shadow catcher) under the matte
  OverBackground,  // opaque film: that alpha-overed onto the world behind (the Env plane)
};

class Film {
 public:
  // passes: a set of pass_bit()s; exposure scales Combined's RGB and the light passes on reading.
  // aovs: the channels (1 or 4) of each shader AOV plane, kept after the passes' planes.
  // light_groups: Cycles' light group passes (Combined_<name>), an RGB plane each after those.
  Film(int width, int height, int tile_size, uint32_t passes = 0, float exposure = 1.0f,
       const std::vector<int>& aovs = {}, int light_groups = 0)
      : w_(width), h_(height), tile_(tile_size), passes_(passes), exposure_(exposure) {
    for (int p = 0; p < kPassCount; ++p) {
      offset_[p] = -1;
      if ((passes & pass_bit(Pass(p))) && Pass(p) != Pass::SampleCount) {
        offset_[p] = stride_;
        stride_ += pass_desc(Pass(p)).channels;
        for (int c = 0; c < pass_desc(Pass(p)).channels; ++c) first_.push_back(pass_desc(Pass(p)).first);
      }
    }
    for (int ch : aovs) {
      aov_offset_.push_back(stride_);
      aov_channels_.push_back(ch);
      stride_ += ch;
      for (int c = 0; c < ch; ++c) first_.push_back(false);
    }
    group_offset_ = stride_;
    group_count_ = std::max(light_groups, 0);
    stride_ += 3 * group_count_;
    first_.resize(size_t(stride_), false);
    aux_.assign(size_t(w_) * size_t(h_) * size_t(stride_), 0.0f);  // empty without passes
    mean_.resize(size_t(w_) * size_t(h_));
    count_.assign(size_t(w_) * size_t(h_), 0u);
    m2_.assign(size_t(w_) * size_t(h_), 0.0f);
    done_.assign(size_t(w_) * size_t(h_), 0u);
    tiles_x_ = (w_ + tile_ - 1) / tile_;
    tiles_y_ = (h_ + tile_ - 1) / tile_;
    locks_ = std::vector<std::mutex>(size_t(tiles_x_) * size_t(tiles_y_));
  }
  int width() const { return w_; }
  int height() const { return h_; }
  int tile_size() const { return tile_; }
  int tile_count() const { return tiles_x_ * tiles_y_; }
  void tile_rect(int tile, int& x0, int& y0, int& x1, int& y1) const {
    x0 = (tile % tiles_x_) * tile_;
    y0 = (tile / tiles_x_) * tile_;
    x1 = std::min(x0 + tile_, w_);
    y1 = std::min(y0 + tile_, h_);
  }
  // Writers hold the tile's lock while they fold a sample into it; readers take it per tile,
  // so a copy never sees a half-written pixel and never stalls the renderer for long.
  std::mutex& tile_lock(int tile) { return locks_[size_t(tile)]; }

  bool has_pass(Pass p) const { return (passes_ & pass_bit(p)) != 0; }
  // Needs the Shadow Catcher planes (and the Env plane for OverBackground).
  void set_catcher_combined(CatcherCombined m) { catcher_ = m; }
  // Floats per pixel of all pass planes together, and where pass p starts (-1: not kept).
  int aux_stride() const { return stride_; }
  int pass_offset(Pass p) const { return offset_[int(p)]; }
  int aov_count() const { return int(aov_offset_.size()); }
  int aov_offset(int i) const { return aov_offset_[size_t(i)]; }
  int aov_channels(int i) const { return aov_channels_[size_t(i)]; }
  // Light group planes (RGB each, after the shader AOVs): group g at light_group_offset() + 3 g.
  int light_group_count() const { return group_count_; }
  int light_group_offset() const { return group_offset_; }

  // Copies shader AOV plane i (H rows of W * aov_channels(i) floats, bottom-up): the mean of
  // what the samples added (0 where a sample wrote nothing), as Cycles' AOV passes.
  void read_aov(int i, float* out) {
    const int ch = aov_channels_[size_t(i)], off = aov_offset_[size_t(i)];
    each_pixel_locked([&](size_t px) {
      for (int c = 0; c < ch; ++c) out[px * size_t(ch) + size_t(c)] = aux_[px * size_t(stride_) + size_t(off + c)];
    });
  }

  // Copies light group g's plane (H rows of W RGB floats, bottom-up): the mean of the light its
  // emitters sent, scaled by the exposure as Combined (Cycles' Combined_<name> passes).
  void read_light_group(int g, float* out) {
    const int off = group_offset_ + 3 * g;
    each_pixel_locked([&](size_t px) {
      for (int c = 0; c < 3; ++c) out[px * 3 + size_t(c)] = aux_[px * size_t(stride_) + size_t(off + c)] * exposure_;
    });
  }

  // aux: aux_stride() floats of the pass planes' values for this sample (ignored without passes).
  void add_sample(int x, int y, const Rgba& v, const float* aux = nullptr) {
    const size_t i = size_t(y) * size_t(w_) + size_t(x);
    const uint32_t n = ++count_[i];
    const float k = 1.0f / static_cast<float>(n);
    if (stride_ > 0 && aux) {
      float* a = &aux_[i * size_t(stride_)];
      for (int c = 0; c < stride_; ++c)
        if (n == 1 || !first_[size_t(c)]) a[c] += (aux[c] - a[c]) * k;
    }
    Rgba& m = mean_[i];
    // Welford's update of the luminance variance (luminance is linear in the RGB mean).
    const float l = 0.2126f * v.r + 0.7152f * v.g + 0.0722f * v.b;
    const float l_old = 0.2126f * m.r + 0.7152f * m.g + 0.0722f * m.b;
    m.r += (v.r - m.r) * k;
    m.g += (v.g - m.g) * k;
    m.b += (v.b - m.b) * k;
    m.a += (v.a - m.a) * k;
    const float l_new = 0.2126f * m.r + 0.7152f * m.g + 0.0722f * m.b;
    m2_[i] += (l - l_old) * (l - l_new);
  }

  // Cryptomatte (Cycles' film_write_cryptomatte_slots): per pixel, `layers` lists of `slots`
  // (id, summed weight) pairs, filled in sample order; an id takes the first free slot and adds
  // to its own after that; with every slot taken a new id is dropped, as in Cycles.
  void set_cryptomatte(int layers, int slots) {
    crypto_layers_ = layers;
    crypto_slots_ = slots;
    crypto_.assign(size_t(w_) * size_t(h_) * size_t(layers) * size_t(slots) * 2, 0.0f);
  }
  int crypto_layers() const { return crypto_layers_; }
  int crypto_slots() const { return crypto_slots_; }
  // Under the tile's lock, as add_sample. id 0 is "no id" (Cryptomatte's) and is not kept.
  void add_crypto(int x, int y, int layer, float id, float weight) {
    if (id == 0.0f || !(weight > 0.0f)) return;
    float* slot = &crypto_[((size_t(y) * size_t(w_) + size_t(x)) * size_t(crypto_layers_) + size_t(layer)) *
                           size_t(crypto_slots_) * 2];
    for (int k = 0; k < crypto_slots_; ++k, slot += 2) {
      if (slot[0] == id) {
        slot[1] += weight;
        return;
      }
      if (slot[0] == 0.0f) {
        slot[0] = id;
        slot[1] = weight;
        return;
      }
    }
  }
  // Pass `pass` of Cryptomatte layer `layer` (H rows of W RGBA floats, bottom-up), as Cycles
  // writes CryptoObject00, 01, ...: the pixel's slots sorted by weight, heaviest first, two per
  // pass (id, coverage), the coverage the weight over the pixel's samples. False if not kept.
  bool read_crypto(int layer, int pass, float* out) {
    if (layer < 0 || layer >= crypto_layers_ || pass < 0 || 2 * pass >= crypto_slots_) return false;
    std::vector<std::pair<float, float>> pairs(static_cast<size_t>(crypto_slots_));
    each_pixel_locked([&](size_t i) {
      const float* slot = &crypto_[(i * size_t(crypto_layers_) + size_t(layer)) * size_t(crypto_slots_) * 2];
      for (int k = 0; k < crypto_slots_; ++k) pairs[size_t(k)] = {slot[2 * k], slot[2 * k + 1]};
      // Stable: equal weights keep the order their ids were first seen in.
      std::stable_sort(pairs.begin(), pairs.end(), [](const auto& a, const auto& b) { return a.second > b.second; });
      const float inv = count_[i] ? 1.0f / float(count_[i]) : 0.0f;
      float* dst = out + i * 4;
      for (int k = 0; k < 2; ++k) {
        const auto& pr = pairs[size_t(2 * pass + k)];
        dst[2 * k] = pr.first;
        dst[2 * k + 1] = pr.second * inv;
      }
    });
    return true;
  }

  bool converged(int x, int y) const { return done_[size_t(y) * size_t(w_) + size_t(x)] != 0; }
  uint32_t count(int x, int y) const { return count_[size_t(y) * size_t(w_) + size_t(x)]; }

  // Adaptive sampling: marks the pixels of a tile whose estimated error is below `threshold`.
  // The error is the standard error of the mean luminance over the square root of the mean
  // (noise as seen after a perceptual, roughly square-root, tone curve), like Cycles' metric.
  // A pixel only stops when its 4-neighbours inside the tile have converged too, so isolated
  // lucky pixels keep sampling. Returns the number of pixels still sampling.
  int update_convergence(int tile, float threshold) {
    int x0, y0, x1, y1;
    tile_rect(tile, x0, y0, x1, y1);
    const int tw = x1 - x0;
    std::vector<uint8_t> ok(size_t(tw) * size_t(y1 - y0));
    for (int y = y0; y < y1; ++y)
      for (int x = x0; x < x1; ++x) {
        const size_t i = size_t(y) * size_t(w_) + size_t(x);
        const uint32_t n = count_[i];
        const Rgba& m = mean_[i];
        const float lum = std::max(0.0f, 0.2126f * m.r + 0.7152f * m.g + 0.0722f * m.b);
        const float var = n > 1 ? std::max(m2_[i], 0.0f) / float(n - 1) : kInf;
        const float stderr_ = std::sqrt(var / float(std::max(n, 1u)));
        ok[size_t(y - y0) * tw + size_t(x - x0)] = done_[i] || stderr_ / (1e-4f + std::sqrt(lum)) < threshold;
      }
    int active = 0;
    for (int y = y0; y < y1; ++y)
      for (int x = x0; x < x1; ++x) {
        auto at = [&](int xx, int yy) {
          xx = std::clamp(xx, x0, x1 - 1);
          yy = std::clamp(yy, y0, y1 - 1);
          return ok[size_t(yy - y0) * tw + size_t(xx - x0)] != 0;
        };
        const bool stop = at(x, y) && at(x - 1, y) && at(x + 1, y) && at(x, y - 1) && at(x, y + 1);
        uint8_t& d = done_[size_t(y) * size_t(w_) + size_t(x)];
        d = d || stop;
        active += d ? 0 : 1;
      }
    return active;
  }

  // Samples per pixel, rows bottom-up, taking each tile's lock like read_rect.
  void read_counts(uint32_t* out) {
    for (int t = 0; t < tile_count(); ++t) {
      int x0, y0, x1, y1;
      tile_rect(t, x0, y0, x1, y1);
      std::lock_guard<std::mutex> lk(locks_[size_t(t)]);
      for (int y = y0; y < y1; ++y)
        std::memcpy(out + size_t(y) * size_t(w_) + size_t(x0), &count_[size_t(y) * size_t(w_) + size_t(x0)],
                    size_t(x1 - x0) * sizeof(uint32_t));
    }
  }

  // Copies a rectangle (x, y from the bottom-left) into `out` (h rows of w RGBA floats).
  void read_rect(int x, int y, int w, int h, float* out) {
    for (int t = 0; t < tile_count(); ++t) {
      int tx0, ty0, tx1, ty1;
      tile_rect(t, tx0, ty0, tx1, ty1);
      const int ix0 = std::max(tx0, x), iy0 = std::max(ty0, y);
      const int ix1 = std::min(tx1, x + w), iy1 = std::min(ty1, y + h);
      if (ix0 >= ix1 || iy0 >= iy1) continue;
      std::lock_guard<std::mutex> lk(locks_[size_t(t)]);
      for (int py = iy0; py < iy1; ++py) {
        const Rgba* src = &mean_[size_t(py) * size_t(w_) + size_t(ix0)];
        float* dst = out + (size_t(py - y) * size_t(w) + size_t(ix0 - x)) * 4;
        std::memcpy(dst, src, size_t(ix1 - ix0) * sizeof(Rgba));
        if (exposure_ != 1.0f)
          for (int px = 0; px < ix1 - ix0; ++px)
            for (int c = 0; c < 3; ++c) dst[4 * px + c] *= exposure_;
        if (catcher_ != CatcherCombined::None)
          for (int px = ix0; px < ix1; ++px) catcher_combined(size_t(py) * size_t(w_) + size_t(px), dst + 4 * (px - ix0));
      }
    }
  }

  // Copies pass p of the whole film into `out` (H rows of W * channels floats, bottom-up), as
  // Blender and Cycles present it: Depth is 1e10 where no sample hit anything, the light passes
  // are scaled by the exposure, Sample Count is the count. False if the pass is not kept.
  bool read_pass(Pass p, float* out) {
    const int ch = pass_desc(p).channels;
    const int off = offset_[int(p)];
    if (p != Pass::SampleCount && off < 0) return false;
    const float scale = pass_desc(p).exposure ? exposure_ : 1.0f;
    const int div = pass_desc(p).divide >= 0 ? offset_[pass_desc(p).divide] : -1;
    each_pixel_locked([&](size_t i) {
      float* dst = out + i * size_t(ch);
      if (p == Pass::SampleCount) {
        dst[0] = float(count_[i]);
        return;
      }
      if (p == Pass::ShadowCatcher) {
        const Vec3 sc = shadow_catcher(i);
        for (int c = 0; c < 3; ++c) dst[c] = sc[c];
        return;
      }
      const float* src = &aux_[i * size_t(stride_) + size_t(off)];
      for (int c = 0; c < ch; ++c) dst[c] = src[c] * scale;
      if (p == Pass::Depth && dst[0] == 0.0f) dst[0] = 1e10f;  // Cycles' "nothing here"
      if (p == Pass::Mist) dst[0] = 1.0f - dst[0];
      if (p == Pass::ShadowCatcherMatte) dst[3] = src[3];  // (alpha: no exposure)
      if (div >= 0) {  // (the session keeps the colour whenever a component is asked for)
        const float* col = &aux_[i * size_t(stride_) + size_t(div)];
        const bool one = pass_desc(Pass(pass_desc(p).divide)).channels == 1;  // (Vector's weight)
        for (int c = 0; c < ch; ++c) {
          const float d = col[one ? 0 : c];
          dst[c] = d != 0.0f ? dst[c] / d : 0.0f;
        }
      }
    });
    return true;
  }

 private:
  // f(i) for every pixel i (y * W + x), a tile at a time under its lock, as the readers need
  // while render threads write other tiles.
  template <class F>
  void each_pixel_locked(F f) {
    for (int t = 0; t < tile_count(); ++t) {
      int x0, y0, x1, y1;
      tile_rect(t, x0, y0, x1, y1);
      std::lock_guard<std::mutex> lk(locks_[size_t(t)]);
      for (int y = y0; y < y1; ++y)
        for (int x = x0; x < x1; ++x) f(size_t(y) * size_t(w_) + size_t(x));
    }
  }
  const float* plane(size_t i, Pass p) const { return &aux_[i * size_t(stride_) + size_t(offset_[int(p)])]; }
  // Cycles' film_calculate_shadow_catcher: Combined less the matte over the catcher path's
  // light (the film's means: all planes share the pixel's sample count, so their sums' ratio),
  // 1 where that is 0 or no sample split, alpha-overed on white by Combined's alpha.
  Vec3 shadow_catcher(size_t i) const {
    if (offset_[int(Pass::ShadowCatcherSampleCount)] < 0 || !(plane(i, Pass::ShadowCatcherSampleCount)[0] > 0.0f))
      return Vec3(1.0f);
    const float* cat = plane(i, Pass::ShadowCatcher);
    const float* mat = plane(i, Pass::ShadowCatcherMatte);
    const Rgba& m = mean_[i];
    const float comb[3] = {m.r, m.g, m.b};
    Vec3 sc;
    for (int c = 0; c < 3; ++c) sc[c] = cat[c] != 0.0f ? (comb[c] - mat[c]) / cat[c] : 1.0f;
    const float alpha = clampf(m.a, 0.0f, 1.0f);
    return Vec3(1.0f - alpha) + sc * alpha;
  }
  // Combined as Cycles shows it with catchers in the scene (PassAccessor, film/read.h
  // film_calculate_shadow_catcher_matte_with_shadow). out: the RGBA read so far.
  void catcher_combined(size_t i, float* out) const {
    if (offset_[int(Pass::ShadowCatcherMatte)] < 0) return;
    const float* mat = plane(i, Pass::ShadowCatcherMatte);
    const float alpha = clampf(mat[3], 0.0f, 1.0f);
    for (int c = 0; c < 3; ++c) out[c] = mat[c] * exposure_;
    out[3] = alpha;
    if (catcher_ == CatcherCombined::Matte) return;
    const float shadow = clampf(average(shadow_catcher(i)), 0.0f, 1.0f);
    const float alpha_matte = (1.0f - alpha) * (1.0f - shadow) + alpha;
    out[3] = alpha_matte;
    if (catcher_ != CatcherCombined::OverBackground || offset_[int(Pass::Env)] < 0) return;
    const float* env = plane(i, Pass::Env);
    for (int c = 0; c < 3; ++c) out[c] += env[c] * exposure_ * (1.0f - alpha_matte);
    out[3] = 1.0f;
  }
  CatcherCombined catcher_ = CatcherCombined::None;
  int w_, h_, tile_, tiles_x_, tiles_y_;
  uint32_t passes_;
  float exposure_;
  int offset_[kPassCount];
  std::vector<int> aov_offset_, aov_channels_;  // shader AOV planes
  int group_offset_ = 0, group_count_ = 0;       // light group planes
  int stride_ = 0;
  int crypto_layers_ = 0, crypto_slots_ = 0;
  std::vector<float> crypto_;  // per pixel, layer and slot: (id, weight sum); empty without Cryptomatte
  std::vector<float> aux_;  // stride_ floats per pixel: the running means of the pass planes
  std::vector<uint8_t> first_;  // per channel of a pixel's planes: PassDesc::first
  std::vector<Rgba> mean_;
  std::vector<uint32_t> count_;
  std::vector<float> m2_;
  std::vector<uint8_t> done_;
  std::vector<std::mutex> locks_;
};

}  // namespace pl
