// Bob Jenkins' lookup3 hash (public domain, burtleburtle.net/bob/c/lookup3.c) on 1-4 words,
// and the float hashes built on it that Blender's procedural textures use (Noise, Voronoi,
// White Noise...): the same bits give the same pattern as Cycles.
#pragma once
#include <cstdint>
#include <cstring>

namespace pl::lookup3 {

// (Templates so that vectors of 32-bit lanes, GCC's vector extension, hash several keys at once.)
template <class U>
constexpr U rotl(U x, int k) { return (x << k) | (x >> (32 - k)); }

// lookup3's mix() and final() rounds.
inline void mix(uint32_t& a, uint32_t& b, uint32_t& c) {
  a -= c; a ^= rotl(c, 4);  c += b;
  b -= a; b ^= rotl(a, 6);  a += c;
  c -= b; c ^= rotl(b, 8);  b += a;
  a -= c; a ^= rotl(c, 16); c += b;
  b -= a; b ^= rotl(a, 19); a += c;
  c -= b; c ^= rotl(b, 4);  b += a;
}
template <class U>
inline void final_mix(U& a, U& b, U& c) {
  c ^= b; c -= rotl(b, 14);
  a ^= c; a -= rotl(c, 11);
  b ^= a; b -= rotl(a, 25);
  c ^= b; c -= rotl(b, 16);
  a ^= c; a -= rotl(c, 4);
  b ^= a; b -= rotl(a, 14);
  c ^= b; c -= rotl(b, 24);
}

// hashword() of n words with initval 13, unrolled for n = 1..4.
constexpr uint32_t seed(uint32_t words) { return 0xdeadbeefu + (words << 2) + 13u; }

inline uint32_t hash(uint32_t x) {
  uint32_t a = seed(1), b = a, c = a;
  a += x;
  final_mix(a, b, c);
  return c;
}
inline uint32_t hash(uint32_t x, uint32_t y) {
  uint32_t a = seed(2), b = a, c = a;
  a += x;
  b += y;
  final_mix(a, b, c);
  return c;
}
inline uint32_t hash(uint32_t x, uint32_t y, uint32_t z) {
  uint32_t a = seed(3), b = a, c = a;
  a += x;
  b += y;
  c += z;
  final_mix(a, b, c);
  return c;
}
inline uint32_t hash(uint32_t x, uint32_t y, uint32_t z, uint32_t w) {
  uint32_t a = seed(4), b = a, c = a;
  a += x;
  b += y;
  c += z;
  mix(a, b, c);
  a += w;
  final_mix(a, b, c);
  return c;
}

inline uint32_t bits(float f) {
  uint32_t u;
  std::memcpy(&u, &f, sizeof u);
  return u;
}
// [0, 2^32 - 1] -> [0, 1], both ends included (Blender's mapping of these hashes).
inline float to_unit(uint32_t h) { return float(h) * (1.0f / float(0xFFFFFFFFu)); }

// Floats hashed by their bit patterns to [0, 1].
inline float hash_to_float(float x) { return to_unit(hash(bits(x))); }
inline float hash_to_float(float x, float y) { return to_unit(hash(bits(x), bits(y))); }
inline float hash_to_float(float x, float y, float z) { return to_unit(hash(bits(x), bits(y), bits(z))); }
inline float hash_to_float(float x, float y, float z, float w) {
  return to_unit(hash(bits(x), bits(y), bits(z), bits(w)));
}

}  // namespace pl::lookup3
