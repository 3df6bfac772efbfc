// Traversal: the binary tree's closest-hit and any-hit loops (the reference the wide kernels are
// tested against), the 4-wide SSE kernels' instances and the CPU checks that pick the 8-wide
// tree and its AVX2 or AVX-512 kernel.
#include <algorithm>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <utility>

#include "geometry/bvh.h"
#include "geometry/bvh_common.h"
#include "geometry/triangle.h"
#if defined(__x86_64__) || defined(__i386__)
#include "geometry/bvh_wide.inl"
#endif

namespace pl {
namespace {

using bvh_detail::intersect_node;
using bvh_detail::safe_inverse;

// Entries of the binary traversal's stack: enough, as the builder stops SAH splits at kMaxDepth
// (bvh_build_sah.cpp), below which count splits add at most 32 levels.
constexpr int kStackSize = 128;

}  // namespace

bool cpu_has_avx2() {
#if defined(PL_HAVE_AVX2_KERNEL) && (defined(__x86_64__) || defined(__i386__))
  static const bool has = __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");  // the 8-wide kernel uses both
  return has;
#else
  return false;
#endif
}

bool cpu_has_avx512() {
#if defined(PL_HAVE_AVX512_KERNEL) && (defined(__x86_64__) || defined(__i386__))
  // __builtin_cpu_supports also checks that the OS saves the AVX-512 state (XCR0).
  static const bool has = cpu_has_avx2() && __builtin_cpu_supports("avx512f") &&
                          __builtin_cpu_supports("avx512vl") && __builtin_cpu_supports("avx512bw") &&
                          __builtin_cpu_supports("avx512dq");
  return has;
#else
  return false;
#endif
}

namespace {
bool avx512_at_load() {
  const char* e = std::getenv("PL_BVH_KERNEL");
  if (e && std::strcmp(e, "avx2") == 0) return false;
  return cpu_has_avx512();
}
}  // namespace

namespace bvh_detail {
std::atomic<bool> g_bvh8_avx512{avx512_at_load()};
}

Bvh8Kernel set_bvh8_kernel(Bvh8Kernel k) {
  // Auto: the choice at load (which PL_BVH_KERNEL may have made AVX2).
  bvh_detail::g_bvh8_avx512.store(k == Bvh8Kernel::Auto ? avx512_at_load() : k == Bvh8Kernel::Avx512 && cpu_has_avx512());
  return bvh8_kernel();
}

Bvh8Kernel bvh8_kernel() { return bvh8_use_avx512() ? Bvh8Kernel::Avx512 : Bvh8Kernel::Avx2; }

#if defined(__x86_64__) || defined(__i386__)
bool bvh4_intersect(const WideBvhView& v, const Ray& ray, Hit& hit, TraversalCounters* counters) {
  return wide_intersect<Sse4>(v, ray, hit, counters);
}
bool bvh4_occluded(const WideBvhView& v, const Ray& ray) { return wide_occluded<Sse4>(v, ray); }
bool bvh4q_intersect(const WideBvhView& v, const Ray& ray, Hit& hit, TraversalCounters* counters) {
  return wide_intersect<Sse4, Bvh4QNode>(v, ray, hit, counters);
}
bool bvh4q_occluded(const WideBvhView& v, const Ray& ray) { return wide_occluded<Sse4, Bvh4QNode>(v, ray); }
#endif

bool Bvh::intersect_binary(const Ray& ray, Hit& hit, TraversalCounters* counters) const {
  if (nodes_.empty()) return false;
  const Vec3 inv = safe_inverse(ray.dir);
  const RayPrecomp rp(ray.dir);
  float tmax = ray.tmax;
  uint32_t best = UINT32_MAX;
  float bb1 = 0, bb2 = 0;
  struct Entry {
    uint32_t node;
    float t;
  } stack[kStackSize];
  int sp = 0;
  uint32_t ni = 0;
  if (intersect_node(nodes_[0], ray.org, inv, tmax) == kInf) return false;
  for (;;) {
    const BvhNode& n = nodes_[ni];
    if (counters) counters->nodes++;
    if (n.is_leaf()) {
      for (uint32_t i = n.left_or_first, e = n.left_or_first + n.count; i < e; ++i) {
        const TriangleVerts& tv = tris_[i];
        float t, b1, b2;
        if (intersect_triangle(ray.org, rp, tv.v0, tv.v1, tv.v2, tmax, t, b1, b2)) {
          tmax = t;
          best = i;
          bb1 = b1;
          bb2 = b2;
        }
      }
      if (counters) counters->triangles += n.count;
    } else {
      uint32_t c0 = n.left_or_first, c1 = c0 + 1;
      float d0 = intersect_node(nodes_[c0], ray.org, inv, tmax);
      float d1 = intersect_node(nodes_[c1], ray.org, inv, tmax);
      if (d0 > d1) {
        std::swap(d0, d1);
        std::swap(c0, c1);
      }
      if (d0 != kInf) {
        if (d1 != kInf) stack[sp++] = {c1, d1};
        ni = c0;
        continue;
      }
    }
    // Pop the next node that can still hold a closer hit.
    do {
      if (sp == 0) goto done;
      --sp;
    } while (stack[sp].t >= tmax);
    ni = stack[sp].node;
  }
done:
  if (best == UINT32_MAX) return false;
  hit.t = tmax;
  hit.b1 = bb1;
  hit.b2 = bb2;
  hit.prim = prim_ids_[best];
  return true;
}

bool Bvh::occluded_binary(const Ray& ray) const {
  if (nodes_.empty()) return false;
  const Vec3 inv = safe_inverse(ray.dir);
  const RayPrecomp rp(ray.dir);
  uint32_t stack[kStackSize];
  int sp = 0;
  uint32_t ni = 0;
  if (intersect_node(nodes_[0], ray.org, inv, ray.tmax) == kInf) return false;
  for (;;) {
    const BvhNode& n = nodes_[ni];
    if (n.is_leaf()) {
      for (uint32_t i = n.left_or_first, e = n.left_or_first + n.count; i < e; ++i) {
        const TriangleVerts& tv = tris_[i];
        float t, b1, b2;
        if (intersect_triangle(ray.org, rp, tv.v0, tv.v1, tv.v2, ray.tmax, t, b1, b2, /*any_hit=*/true)) return true;
      }
    } else {
      const uint32_t c0 = n.left_or_first, c1 = c0 + 1;
      const bool h0 = intersect_node(nodes_[c0], ray.org, inv, ray.tmax) != kInf;
      const bool h1 = intersect_node(nodes_[c1], ray.org, inv, ray.tmax) != kInf;
      if (h0 || h1) {
        if (h0 && h1) stack[sp++] = c1;
        ni = h0 ? c0 : c1;
        continue;
      }
    }
    if (sp == 0) break;
    ni = stack[--sp];
  }
  return false;
}

}  // namespace pl
