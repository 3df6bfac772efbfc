// The 8-wide traversal compiled for AVX2 (and FMA, which the compressed nodes' dequantisation
// uses) in an otherwise portable build: only the functions defined under the target pragma use
// them, and Bvh calls them only where cpu_has_avx2() (which checks both), so
// one binary runs everywhere and uses 8 lanes where it can. The headers come first, outside
// the pragma, so their inline functions are never emitted as AVX2 code.
#include <immintrin.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <utility>

#include "geometry/bvh.h"
#include "geometry/bvh_common.h"
#include "geometry/triangle.h"

#if defined(__clang__)
#pragma clang attribute push(__attribute__((target("avx2,fma"))), apply_to = function)
#else
#pragma GCC push_options
#pragma GCC target("avx2,fma")
#endif
#define PL_WIDE_AVX2 1
#include "geometry/bvh_wide.inl"

namespace pl {

bool bvh8_intersect(const WideBvhView& v, const Ray& ray, Hit& hit, TraversalCounters* counters) {
  return wide_intersect<Avx8>(v, ray, hit, counters);
}
bool bvh8_occluded(const WideBvhView& v, const Ray& ray) { return wide_occluded<Avx8>(v, ray); }
bool bvh8q_intersect(const WideBvhView& v, const Ray& ray, Hit& hit, TraversalCounters* counters) {
  return wide_intersect<Avx8, Bvh8QNode>(v, ray, hit, counters);
}
bool bvh8q_occluded(const WideBvhView& v, const Ray& ray) { return wide_occluded<Avx8, Bvh8QNode>(v, ray); }

}  // namespace pl
#if defined(__clang__)
#pragma clang attribute pop
#else
#pragma GCC pop_options
#endif
