// HDR accumulation buffer: a running mean per pixel (the seed's progressive converge), updated
// one sample at a time in sample order, so the result does not depend on how samples were
// grouped into passes or on which thread rendered them. Rows are stored bottom-up (Blender's order).
#pragma once
#include <cstdint>
#include <mutex>
#include <vector>

#include "util/math.h"

namespace pl {

struct Rgba {
  float r = 0, g = 0, b = 0, a = 0;
};

class Film {
 public:
  Film(int width, int height, int tile_size) : w_(width), h_(height), tile_(tile_size) {
    mean_.resize(size_t(w_) * size_t(h_));
    count_.assign(size_t(w_) * size_t(h_), 0u);
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

  void add_sample(int x, int y, const Rgba& v) {
    const size_t i = size_t(y) * size_t(w_) + size_t(x);
    const uint32_t n = ++count_[i];
    const float k = 1.0f / static_cast<float>(n);
    Rgba& m = mean_[i];
    m.r += (v.r - m.r) * k;
    m.g += (v.g - m.g) * k;
    m.b += (v.b - m.b) * k;
    m.a += (v.a - m.a) * k;
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
      }
    }
  }

 private:
  int w_, h_, tile_, tiles_x_, tiles_y_;
  std::vector<Rgba> mean_;
  std::vector<uint32_t> count_;
  std::vector<std::mutex> locks_;
};

}  // namespace pl
