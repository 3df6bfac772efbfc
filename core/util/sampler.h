// Per-pixel sample streams: Owen-scrambled Sobol (Burley 2020, "Practical Hash-based Owen
// Scrambling"), whose sample index is shuffled and whose values are scrambled with hashes of
// (seed, pixel, dimension) -- decorrelated across pixels and dimensions, deterministic per
// (seed, pixel, sample), progressive at any sample count. "Random" is plain PCG32.
// The default (Sobol) is Cycles 4.5's layout: consecutive 2-D draws in twos form 4-D
// Owen-scrambled Sobol sets (Sobol dimensions 0-3 under one shuffled index, as Cycles'
// sobol_burley_sample_4D): pixel + lens (2-D draw 0; draw 1 is the lens, only with an
// aperture, or the shutter time's x with motion blur), then per bounce light choice + light
// point, closure + lobe choice + BSDF direction; past the camera's set the 2-D points take the
// set's Sobol dimensions 0-1, a (0,2)-sequence, and the choices 2-3 (Cycles' rand_light /
// rand_bsdf .xy, .z). The Russian roulette takes the light set's last dimension (Cycles has a
// sequence of its own, PRNG_TERMINATE: Sobol4DCycles; it cost the Cornell box 1-2 %, issue 25).
// Sobol covers the first 16 draws (~3 bounces), PCG32 the rest.
// Opt-in (issue 25, docs/design/sampling.md "Random numbers"): SobolPairs is the layout before
// (every 2-D draw its own shuffled (0,2)-sequence, the roulette on the light choice's .y);
// SobolDeep is those pairs for every bounce; Sobol4D is the sets with the points on dimensions
// 2-3 and the roulette on the light set; Sobol4DDeep is Sobol4D for every bounce;
// Sobol4DRoulette is Sobol4D with the roulette's own number; Sobol4DCycles is the default with
// the roulette's own number.
#pragma once
#include <cstdint>
#if defined(__SSSE3__)
#include <tmmintrin.h>
#endif

#include "util/rng.h"
#include "util/sampling.h"

namespace pl {

// (Sobol was the pairs until issue 25; they are SobolPairs now.)
enum class SamplerType : uint8_t {
  Sobol, Random, SobolDeep, Sobol4D, Sobol4DDeep, Sobol4DRoulette, Sobol4DCycles, SobolPairs
};

inline uint32_t reverse_bits(uint32_t x) {
#if defined(__SSSE3__)
  // Each nibble reversed by a 16-entry shuffle table (the low nibble lands in the high one),
  // then the bytes swapped: 9 instructions instead of 19; three per 2-D sample were 4 % of a
  // Cornell box sample. Checked equal to the shifts below for all 2^32 inputs.
  const __m128i nib = _mm_set1_epi8(0x0F);
  const __m128i rev_to_hi = _mm_setr_epi8(0x00, char(0x80), 0x40, char(0xC0), 0x20, char(0xA0), 0x60, char(0xE0),
                                          0x10, char(0x90), 0x50, char(0xD0), 0x30, char(0xB0), 0x70, char(0xF0));
  const __m128i rev_to_lo = _mm_setr_epi8(0x0, 0x8, 0x4, 0xC, 0x2, 0xA, 0x6, 0xE, 0x1, 0x9, 0x5, 0xD, 0x3, 0xB, 0x7, 0xF);
  const __m128i v = _mm_cvtsi32_si128(int(x));
  const __m128i lo = _mm_and_si128(v, nib), hi = _mm_and_si128(_mm_srli_epi16(v, 4), nib);
  const __m128i r = _mm_or_si128(_mm_shuffle_epi8(rev_to_hi, lo), _mm_shuffle_epi8(rev_to_lo, hi));
  return __builtin_bswap32(uint32_t(_mm_cvtsi128_si32(r)));
#else
  x = ((x >> 1) & 0x55555555u) | ((x & 0x55555555u) << 1);
  x = ((x >> 2) & 0x33333333u) | ((x & 0x33333333u) << 2);
  x = ((x >> 4) & 0x0F0F0F0Fu) | ((x & 0x0F0F0F0Fu) << 4);
  return __builtin_bswap32(x);  // the byte-level swaps in one instruction
#endif
}

// Owen scrambling of a bit-reversed value: a hash in which each bit depends only on the bits
// below it (Laine-Karras style, with Burley's constants).
inline uint32_t laine_karras_permutation(uint32_t x, uint32_t seed) {
  x += seed;
  x ^= x * 0x6c50b47cu;
  x ^= x * 0xb82f1e52u;
  x ^= x * 0xc7afe638u;
  x ^= x * 0x8d22f6e6u;
  return x;
}

inline uint32_t nested_uniform_scramble(uint32_t x, uint32_t seed) {
  return reverse_bits(laine_karras_permutation(reverse_bits(x), seed));
}

// First Sobol dimension: van der Corput.
inline uint32_t sobol_dim0(uint32_t index) { return reverse_bits(index); }

// Sobol dimensions 1-3 from their primitive polynomial (degree s, coefficients a) and initial
// m (Joe-Kuo; the same directions as Burley's code), stored bit-reversed (the value comes out
// already reversed, ready for the scramble, which works on reversed bits) and a byte of the
// index at a time: a bit loop over a scrambled (random-looking) index runs ~16 times and was
// 5 % of a Cornell box sample.
struct SobolDimBytes {
  uint32_t t[4][256];
  constexpr SobolDimBytes(int s, uint32_t a, uint32_t m0, uint32_t m1, uint32_t m2) : t() {
    uint32_t v[32] = {};
    const uint32_t m[3] = {m0, m1, m2};
    for (int i = 0; i < 32; ++i) {
      if (i < s) {
        v[i] = m[i] << (31 - i);
      } else {
        v[i] = v[i - s] ^ (v[i - s] >> s);
        for (int k = 1; k < s; ++k)
          if ((a >> (s - 1 - k)) & 1u) v[i] ^= v[i - k];
      }
    }
    uint32_t r[32] = {};
    for (int i = 0; i < 32; ++i)
      for (int b = 0; b < 32; ++b)
        if (v[i] & (1u << b)) r[i] |= 1u << (31 - b);
    for (int k = 0; k < 4; ++k)
      for (int b = 0; b < 256; ++b) {
        uint32_t x = 0;
        for (int i = 0; i < 8; ++i)
          if (b & (1 << i)) x ^= r[8 * k + i];
        t[k][b] = x;
      }
  }
  uint32_t operator()(uint32_t index) const {
    return t[0][index & 0xFFu] ^ t[1][(index >> 8) & 0xFFu] ^ t[2][(index >> 16) & 0xFFu] ^ t[3][index >> 24];
  }
};
inline constexpr SobolDimBytes kSobolDim1Bytes{1, 0u, 1u, 0u, 0u};  // x + 1: directions d ^= d >> 1
inline constexpr SobolDimBytes kSobolDim2Bytes{2, 1u, 1u, 3u, 0u};
inline constexpr SobolDimBytes kSobolDim3Bytes{3, 1u, 1u, 3u, 1u};
inline uint32_t sobol_dim1_reversed(uint32_t index) { return kSobolDim1Bytes(index); }

inline float u32_to_unit(uint32_t x) { return static_cast<float>(x >> 8) * 0x1p-24f; }

class Sampler {
 public:
  Sampler(SamplerType type, uint32_t seed, uint64_t pixel, uint32_t sample)
      : Sampler(type, seed, pixel, sample, pixel, sample) {}
  // The Sobol draws from sequence `key` at `index` (a pixel pattern's mapping, pixel_pattern.h;
  // key = pixel and index = sample is the pixel's own sequence); the PCG tail stays keyed by
  // (seed, pixel, sample).
  Sampler(SamplerType type, uint32_t seed, uint64_t pixel, uint32_t sample, uint64_t key, uint32_t index)
      : sample_reversed_(reverse_bits(index)),
        sobol_dims_(type == SamplerType::Random ? 0u
                    : type == SamplerType::SobolDeep || type == SamplerType::Sobol4DDeep ? UINT32_MAX
                                                                                         : kSobolDims),
        layout_(type == SamplerType::Sobol || type == SamplerType::Sobol4DCycles ? Layout::Cycles
                : type == SamplerType::Sobol4D || type == SamplerType::Sobol4DDeep || type == SamplerType::Sobol4DRoulette
                    ? Layout::Sets
                    : Layout::Pairs),
        own_roulette_(type == SamplerType::Sobol4DCycles || type == SamplerType::Sobol4DRoulette),
        base_(hash3(seed, key, 0x5EEDull)),
        rng_(hash3(seed, pixel, sample), pixel) {}

  // Low discrepancy matters most for the first bounces; deeper dimensions use the cheaper
  // PCG32 stream of the same (seed, pixel, sample), which keeps results deterministic.
  static constexpr uint32_t kSobolDims = 16;

  // Always inline: in integrator.cpp's five kernels GCC's unit-growth budget ran out and left
  // this per-bounce call out of line (+8 % instructions on the diffuse Cornell box).
  [[gnu::always_inline]] Vec2 get2d() {
    const uint32_t dim = dim_++;
    if (dim >= sobol_dims_) {
      const float a = rng_.next_float();
      return {a, rng_.next_float()};
    }
    if (layout_ != Layout::Cycles) [[unlikely]] return get2d_other(dim);  // (out of line: the default stays small)
    // The set's shuffled index; past the camera's set the first draw (a choice) takes Sobol
    // dimensions 2-3, the second (a 2-D point) 0-1. One code path with selected tables and
    // seeds (the values of sobol_dims01 / sobol_dims23): two inlined bodies at every call site
    // made the kernels 9 % more instructions.
    // A set's second draw reuses its first's hash and shuffled index (not after a skip2d).
    if ((dim >> 1) != set_) {
      set_ = dim >> 1;
      set_h_ = mix64(base_ ^ (uint64_t(set_) * 0x9E3779B97F4A7C15ULL));
      set_index_ = shuffled_index(set_h_);
    }
    const uint64_t h = set_h_;
    const uint32_t index = set_index_;
    const bool high = bool(dim & 1u) != (dim >= 2u);
    const uint64_t m = mix64(high ? h ^ 0xC2B2AE3D27D4EB4FULL : h);
    const SobolDimBytes& ty = high ? kSobolDim3Bytes : kSobolDim1Bytes;
    const uint32_t vx = high ? kSobolDim2Bytes(index) : index;  // (dimension 0: the index itself)
    const uint32_t x = reverse_bits(laine_karras_permutation(vx, uint32_t((high ? m : h) >> 32)));
    const uint32_t y = reverse_bits(laine_karras_permutation(ty(index), high ? uint32_t(m) : uint32_t(m >> 32)));
    return {u32_to_unit(x), u32_to_unit(y)};
  }
  float get1d() { return get2d().x; }
  // A hash of this (seed, pixel, sample) that uses up no dimension: seeds for the few draws
  // that do not follow the path's dimension layout (the Ambient Occlusion node's rays).
  uint64_t path_key() const { return mix64(base_ ^ (uint64_t(sample_reversed_) * 0xD1B54A32D192ED03ULL)); }
  // Moves past one 2-D dimension without computing it: the later dimensions stay the same as
  // after get2d() (kernels that know a draw is unused skip its cost, not its place).
  void skip2d() {
    if (dim_ >= sobol_dims_) {
      rng_.next_u32();
      rng_.next_u32();
    }
    ++dim_;
  }
  // Whether the roulette takes roulette(bounce) rather than the light set's number.
  bool own_roulette() const { return own_roulette_; }
  // The roulette's number at `bounce`, as Cycles' PRNG_TERMINATE: a 1-D Owen-scrambled Sobol
  // sequence of its own per bounce (own shuffle and scramble, keyed apart from the layout's
  // draws), so it is stratified over the samples yet independent of the light and BSDF sets.
  float roulette(int bounce) const {
    const uint64_t h = mix64(base_ ^ ((uint64_t(uint32_t(bounce)) + kRouletteKey) * 0x9E3779B97F4A7C15ULL));
    return u32_to_unit(reverse_bits(laine_karras_permutation(shuffled_index(h), uint32_t(h >> 32))));
  }
  // With 4-D sets, moves to the start of the next set (after the camera's draws, so that each
  // bounce's light and BSDF draws fill whole sets); otherwise nothing.
  void align_set() {
    if (layout_ != Layout::Pairs && (dim_ & 1u)) skip2d();
  }

 private:
  enum class Layout : uint8_t { Cycles, Sets, Pairs };
  // The opt-in layouts. Pairs: each draw its own shuffled index. Sets (sobol4d): the set's
  // first draw on Sobol dimensions 0-1, the second on 2-3.
  [[gnu::noinline]] Vec2 get2d_other(uint32_t dim) const {
    if (layout_ == Layout::Pairs) {
      const uint64_t h = mix64(base_ ^ (uint64_t(dim) * 0x9E3779B97F4A7C15ULL));
      return sobol_dims01(shuffled_index(h), h);
    }
    const uint64_t h = mix64(base_ ^ (uint64_t(dim >> 1) * 0x9E3779B97F4A7C15ULL));
    const uint32_t index = shuffled_index(h);
    return dim & 1u ? sobol_dims23(index, h) : sobol_dims01(index, h);
  }
  // nested_uniform_scramble(sample, h): the draw's shuffled sample index, with the sample's
  // reversal done once per sampler.
  [[gnu::always_inline]] uint32_t shuffled_index(uint64_t h) const {
    return reverse_bits(laine_karras_permutation(sample_reversed_, uint32_t(h)));
  }
  // Owen-scrambled Sobol dimension 0 (van der Corput: the reversed index) and dimension 1 at
  // `index`, scrambled by h; the scramble acts on reversed bits, which dimension 0 already is
  // and dimension 1 is stored as.
  [[gnu::always_inline]] static Vec2 sobol_dims01(uint32_t index, uint64_t h) {
    const uint32_t x = reverse_bits(laine_karras_permutation(index, uint32_t(h >> 32)));
    const uint32_t y = reverse_bits(laine_karras_permutation(sobol_dim1_reversed(index), uint32_t(mix64(h) >> 32)));
    return {u32_to_unit(x), u32_to_unit(y)};
  }
  // Sobol dimensions 2 and 3 at `index`, each with its own scramble from h.
  [[gnu::always_inline]] static Vec2 sobol_dims23(uint32_t index, uint64_t h) {
    const uint64_t h2 = mix64(h ^ 0xC2B2AE3D27D4EB4FULL);
    const uint32_t x = reverse_bits(laine_karras_permutation(kSobolDim2Bytes(index), uint32_t(h2 >> 32)));
    const uint32_t y = reverse_bits(laine_karras_permutation(kSobolDim3Bytes(index), uint32_t(h2)));
    return {u32_to_unit(x), u32_to_unit(y)};
  }
  static constexpr uint64_t kRouletteKey = 1ull << 32;  // above every draw's dimension
  uint32_t sample_reversed_;
  uint32_t sobol_dims_;  // 2-D draws from Sobol; PCG32 after
  Layout layout_;
  bool own_roulette_;
  uint64_t base_;
  uint32_t dim_ = 0;
  uint32_t set_ = UINT32_MAX;  // the 4-D set whose hash and index are below
  uint32_t set_index_ = 0;
  uint64_t set_h_ = 0;
  Pcg32 rng_;
};

}  // namespace pl
