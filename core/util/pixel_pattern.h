// Which Sobol sequence, and which index of it, a (pixel, sample) takes (Cycles' sampling
// patterns; docs/design/sampling.md "Blue-noise pattern"). The Sampler itself does not change:
// it takes the (sequence key, index) computed here.
//
// - Independent: every pixel its own Owen-scrambled sequence (key = pixel), index = sample.
// - BlueNoise: the pixels of a block share one sequence, and pixel p takes its consecutive
//   chunk [k(p) L, k(p) L + L), k(p) the pixel's place on a base-4 Owen-scrambled Morton curve
//   of the block and L the frame's total samples. Neighbours then hold neighbouring chunks,
//   which together are stratified, so their errors cancel across a region (blue noise). For
//   L a power of two each chunk is an aligned block of the shuffled sequence, a (0,m,2)-net as
//   before, so a pixel is no noisier. Blocks (up to 1024 x 1024 pixels, fewer where the chunks
//   would overflow the 32-bit index) each get a sequence of their own.
// - BlueNoiseFirst (Cycles' viewport choice): sample 0 from a 1-spp blue-noise sequence, the
//   rest in chunks of L - 1 of another.
// The PCG tail (draws past the Sobol dimensions) stays keyed by the pixel in every pattern.
#pragma once
#include <algorithm>
#include <cstdint>

#include "util/rng.h"

namespace pl {

// BlueNoiseRound: BlueNoise with the chunk length rounded up to a power of two (Cycles'
// Blue-Noise Round), so that every chunk is a net.
enum class PixelPattern : uint8_t { Independent, BlueNoise, BlueNoiseRound, BlueNoiseFirst };

struct SobolIndex {
  uint64_t key;    // selects the sequence's scrambles (Sampler's base hash)
  uint32_t index;  // index into that sequence
};

// Base-4 nested uniform (Owen) scramble of the low 2 * levels bits of a Morton code: each
// base-4 digit is permuted by one of the 24 permutations, picked by a hash of the digits above
// it, so the curve's quadrants are shuffled at every level and nearby pixels stay nearby.
// The digits of levels top .. 0 only (the rest of the result 0).
inline uint32_t owen_scramble_base4_levels(uint32_t code, int levels, int top, uint64_t seed) {
  static constexpr uint8_t kPerm[24][4] = {
      {0, 1, 2, 3}, {0, 1, 3, 2}, {0, 2, 1, 3}, {0, 2, 3, 1}, {0, 3, 1, 2}, {0, 3, 2, 1},
      {1, 0, 2, 3}, {1, 0, 3, 2}, {1, 2, 0, 3}, {1, 2, 3, 0}, {1, 3, 0, 2}, {1, 3, 2, 0},
      {2, 0, 1, 3}, {2, 0, 3, 1}, {2, 1, 0, 3}, {2, 1, 3, 0}, {2, 3, 0, 1}, {2, 3, 1, 0},
      {3, 0, 1, 2}, {3, 0, 2, 1}, {3, 1, 0, 2}, {3, 1, 2, 0}, {3, 2, 0, 1}, {3, 2, 1, 0}};
  uint32_t out = 0;
  for (int i = top; i >= 0; --i) {
    // The digits above this one, with a leading 1 so that levels do not share hashes.
    const uint64_t prefix = (uint64_t(code) >> (2 * i + 2)) | (uint64_t(1) << (2 * (levels - i - 1)));
    const uint32_t p = uint32_t((mix64(seed ^ (prefix * 0x9E3779B97F4A7C15ULL)) >> 32) % 24u);
    out |= uint32_t(kPerm[p][(code >> (2 * i)) & 3u]) << (2 * i);
  }
  return out;
}

inline uint32_t morton2d(uint32_t x, uint32_t y) {
  auto spread = [](uint32_t v) {
    v &= 0xFFFFu;
    v = (v | (v << 8)) & 0x00FF00FFu;
    v = (v | (v << 4)) & 0x0F0F0F0Fu;
    v = (v | (v << 2)) & 0x33333333u;
    v = (v | (v << 1)) & 0x55555555u;
    return v;
  };
  return (spread(y) << 1) | spread(x);
}

// The mapping of one render, set up once from its settings.
class PixelPatternMap {
 public:
  PixelPatternMap() = default;
  // length: the chunk length, the frame's total sample count (>= 1).
  PixelPatternMap(PixelPattern pattern, uint32_t seed, uint32_t length) : pattern_(pattern), seed_(seed) {
    if (pattern_ == PixelPattern::BlueNoiseRound) {
      pattern_ = PixelPattern::BlueNoise;
      uint64_t n = 1;
      while (n < length) n <<= 1;
      length = uint32_t(std::min<uint64_t>(n, uint64_t(1) << 31));
    }
    if (pattern_ == PixelPattern::BlueNoiseFirst) {
      if (length <= 1) length = 1;  // one sample: only the first's sequence is used
      else length -= 1;
    }
    length_ = length < 1 ? 1 : length;
    // Blocks of 2^levels pixels a side, as large as 1024 while 4^levels chunks fit in 2^32.
    levels_ = 0;
    while (levels_ < 10 && (uint64_t(1) << (2 * (levels_ + 1))) * uint64_t(length_) <= (uint64_t(1) << 32))
      ++levels_;
  }
  PixelPattern pattern() const { return pattern_; }
  uint32_t length() const { return length_; }
  int block_levels() const { return levels_; }

  // Per pixel (x, y in the full frame), independent of the sample: the pixel's key and its
  // first index (k(p) * length); for the First pattern also the 1-spp index.
  struct PixelBase {
    uint64_t key = 0, first_key = 0;
    uint32_t base = 0, first_index = 0;
  };
  // One pixel's (width: the frame's, for the independent key y * width + x); every level of its
  // scramble hashed afresh.
  PixelBase pixel_base(int x, int y, int width) const {
    PixelBase b;
    row_bases(x, x + 1, y, width, &b);
    return b;
  }
  // The bases of the pixels (x0 .. x1 - 1, y) into out: after a block's first pixel, a pixel's
  // scramble reuses the digits above the first that differs from its left neighbour's code
  // (about 2 of 10 levels hashed instead of all). Keys of shared sequences live above the pixel
  // keys' range (a frame has < 2^33 pixels).
  void row_bases(int x0, int x1, int y, int width, PixelBase* out) const {
    if (pattern_ == PixelPattern::Independent) {
      for (int x = x0; x < x1; ++x) {
        out[x - x0] = PixelBase{};
        out[x - x0].key = uint64_t(y) * uint64_t(width) + uint64_t(x);
      }
      return;
    }
    const uint32_t mask = (1u << levels_) - 1u;
    const uint32_t by = uint32_t(y) >> levels_;
    uint64_t block = ~uint64_t(0), seed = 0, seed_first = 0;
    uint32_t last_code = 0, last_out = 0, last_first = 0;
    for (int x = x0; x < x1; ++x) {
      PixelBase& b = out[x - x0];
      const uint64_t blk = (uint64_t(1) << 63) | (uint64_t(by) << 32) | uint64_t(uint32_t(x) >> levels_);
      const uint32_t code = morton2d(uint32_t(x) & mask, uint32_t(y) & mask);
      int top = levels_ - 1;  // the highest base-4 digit to scramble again
      if (blk != block) {
        block = blk;
        seed = hash3(seed_, block, 0xB1Eull);
        seed_first = hash3(seed_, block, 0xF125ull);
      } else {
        const uint32_t diff = code ^ last_code;
        top = diff ? (31 - __builtin_clz(diff)) / 2 : -1;
      }
      const uint32_t keep = top + 1 >= 16 ? 0u : ~((1u << (2 * (top + 1))) - 1u);
      last_out = (last_out & keep) | owen_scramble_base4_levels(code, levels_, top, seed);
      if (pattern_ == PixelPattern::BlueNoiseFirst)
        last_first = (last_first & keep) | owen_scramble_base4_levels(code, levels_, top, seed_first);
      last_code = code;
      b.key = block;
      b.base = last_out * length_;
      if (pattern_ == PixelPattern::BlueNoiseFirst) {
        b.first_key = block ^ (uint64_t(1) << 62);
        b.first_index = last_first;
      }
    }
  }
  SobolIndex map(const PixelBase& b, uint32_t sample) const {
    switch (pattern_) {
      case PixelPattern::Independent: return {b.key, sample};
      case PixelPattern::BlueNoise:
      case PixelPattern::BlueNoiseRound: return {b.key, b.base + sample};
      case PixelPattern::BlueNoiseFirst:
        if (sample == 0) return {b.first_key, b.first_index};
        return {b.key, b.base + (sample - 1)};
    }
    return {b.key, sample};
  }

 private:
  PixelPattern pattern_ = PixelPattern::Independent;
  uint32_t seed_ = 0;
  uint32_t length_ = 1;
  int levels_ = 0;
};

}  // namespace pl
