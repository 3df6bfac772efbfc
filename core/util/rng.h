// Random numbers: PCG32 (O'Neill 2014) seeded through a strong integer hash, so that every
// (seed, pixel, sample) triple owns an independent stream. The image is then independent of
// the thread count and of which thread rendered which tile, and sample ranges can be split.
#pragma once
#include <cstdint>

namespace pl {

// 64-bit finaliser of MurmurHash3 / SplitMix64: full avalanche.
inline uint64_t mix64(uint64_t x) {
  x ^= x >> 33;
  x *= 0xff51afd7ed558ccdULL;
  x ^= x >> 33;
  x *= 0xc4ceb9fe1a85ec53ULL;
  x ^= x >> 33;
  return x;
}

inline uint64_t hash3(uint64_t a, uint64_t b, uint64_t c) {
  return mix64(a * 0x9E3779B97F4A7C15ULL ^ mix64(b + 0x632BE59BD9B4E019ULL) ^ mix64(c ^ 0x8CB92BA72F3D8DD7ULL));
}

class Pcg32 {
 public:
  Pcg32() = default;
  Pcg32(uint64_t seed, uint64_t stream) { set(seed, stream); }
  void set(uint64_t seed, uint64_t stream) {
    state_ = 0;
    inc_ = (stream << 1u) | 1u;
    next_u32();
    state_ += seed;
    next_u32();
  }
  uint32_t next_u32() {
    const uint64_t old = state_;
    state_ = old * 6364136223846793005ULL + inc_;
    const uint32_t xorshifted = static_cast<uint32_t>(((old >> 18u) ^ old) >> 27u);
    const uint32_t rot = static_cast<uint32_t>(old >> 59u);
    return (xorshifted >> rot) | (xorshifted << ((~rot + 1u) & 31));
  }
  // Uniform in [0, 1): 24 random bits, so the result is never rounded up to 1.
  float next_float() { return static_cast<float>(next_u32() >> 8) * 0x1p-24f; }

 private:
  uint64_t state_ = 0x853c49e6748fea9bULL, inc_ = 0xda3e39cb94b95bdbULL;
};

}  // namespace pl
