// The 8-wide traversal compiled for AVX-512 (F, VL, BW, DQ) in an otherwise portable build, as
// bvh8_avx2.cpp is for AVX2: the same templates (bvh_wide.inl) on the same 256-bit lanes, but
// with EVEX encoding, so 32 vector registers hold the node test's and the triangle test's ray
// constants together (AVX2's 16 reload some from the stack), and comparisons go into mask
// registers. Same operations lane for lane (no FMA contraction: -ffp-contract=off), so hits
// are bit for bit the AVX2 kernel's. Bvh calls these only where bvh8_use_avx512() (the CPU has
// them and PL_BVH_KERNEL / set_bvh8_kernel did not ask for AVX2). The headers come first,
// outside the pragma, so their inline functions are never emitted as AVX-512 code.
#include <immintrin.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <utility>

#include "geometry/bvh.h"
#include "geometry/bvh_common.h"
#include "geometry/triangle.h"

#if defined(__clang__)
#pragma clang attribute push(__attribute__((target("avx2,fma,avx512f,avx512vl,avx512bw,avx512dq"))), \
                             apply_to = function)
#else
#pragma GCC push_options
#pragma GCC target("avx2,fma,avx512f,avx512vl,avx512bw,avx512dq")
#endif
#define PL_WIDE_AVX2 1
#define PL_WIDE_AVX512 1
#include "geometry/bvh_wide.inl"

namespace pl {

bool bvh8_intersect_avx512(const WideBvhView& v, const Ray& ray, Hit& hit, TraversalCounters* counters) {
  return wide_intersect<Avx8>(v, ray, hit, counters);
}
bool bvh8_occluded_avx512(const WideBvhView& v, const Ray& ray) { return wide_occluded<Avx8>(v, ray); }
bool bvh8q_intersect_avx512(const WideBvhView& v, const Ray& ray, Hit& hit, TraversalCounters* counters) {
  return wide_intersect<Avx8, Bvh8QNode>(v, ray, hit, counters);
}
bool bvh8q_occluded_avx512(const WideBvhView& v, const Ray& ray) {
  return wide_occluded<Avx8, Bvh8QNode>(v, ray);
}

}  // namespace pl
#if defined(__clang__)
#pragma clang attribute pop
#else
#pragma GCC pop_options
#endif
