// MurmurHash3_x86_32 (Austin Appleby's public-domain hash), written from its description, and the
// Cryptomatte specification's conversion of a 32-bit hash to a float id. Cryptomatte names
// objects, materials and assets by these (tests/core/test_core_cryptomatte.py checks published
// values).
#pragma once
#include <cstddef>
#include <cstdint>
#include <cstring>

namespace pl {

inline uint32_t murmur3_32(const void* data, size_t len, uint32_t seed = 0) {
  const unsigned char* p = static_cast<const unsigned char*>(data);
  constexpr uint32_t c1 = 0xcc9e2d51u, c2 = 0x1b873593u;
  auto rotl = [](uint32_t x, int r) { return (x << r) | (x >> (32 - r)); };
  uint32_t h = seed;
  const size_t blocks = len / 4;
  for (size_t i = 0; i < blocks; ++i) {
    uint32_t k;
    std::memcpy(&k, p + 4 * i, 4);  // little-endian blocks, as the reference on x86
    k = rotl(k * c1, 15) * c2;
    h = rotl(h ^ k, 13) * 5u + 0xe6546b64u;
  }
  const unsigned char* tail = p + 4 * blocks;
  uint32_t k = 0;
  switch (len & 3) {
    case 3: k ^= uint32_t(tail[2]) << 16; [[fallthrough]];
    case 2: k ^= uint32_t(tail[1]) << 8; [[fallthrough]];
    case 1:
      k ^= uint32_t(tail[0]);
      h ^= rotl(k * c1, 15) * c2;
  }
  h ^= uint32_t(len);
  h ^= h >> 16;
  h *= 0x85ebca6bu;
  h ^= h >> 13;
  h *= 0xc2b2ae35u;
  h ^= h >> 16;
  return h;
}

// Cryptomatte's "uint32_to_float32": the hash's bits as a float with the exponent kept inside
// 1..254, so that no id is a denormal, an infinity or a NaN (and none is 0, "no id").
inline float cryptomatte_float(uint32_t hash) {
  uint32_t exponent = (hash >> 23) & 0xffu;
  exponent = exponent < 1u ? 1u : exponent > 254u ? 254u : exponent;
  const uint32_t bits = (hash & 0x807fffffu) | (exponent << 23);
  float f;
  std::memcpy(&f, &bits, 4);
  return f;
}

}  // namespace pl
