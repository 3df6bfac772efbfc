#include "geometry/tlas.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#if defined(__SSE2__)
#include <immintrin.h>
#endif

#include "geometry/binned_sah.h"
#include "geometry/bvh_common.h"
#include "geometry/wide4.h"

namespace pl {
namespace {

constexpr int kBins = 16;
// One instance per leaf: every instance is entered only after a test of its own world box
// (entering one costs a ray transform and a BLAS traversal's set-up, far more than a box).
constexpr uint32_t kMaxLeaf = 1;
constexpr int kSahDepth = 48;
constexpr int kMaxDepth = kSahDepth + 32;
constexpr int kWidth = 8;

// World box of a BLAS's box under an affine transform, grown by the transform's rounding so a
// ray the object-space traversal would hit is never culled here.
Aabb world_box(const Aabb& b, const Mat4& m) {
  Aabb out;
  for (int c = 0; c < 8; ++c) {
    const Vec3 p{(c & 1) ? b.hi.x : b.lo.x, (c & 2) ? b.hi.y : b.lo.y, (c & 4) ? b.hi.z : b.lo.z};
    const Vec3 w = m.point(p), e = transform_point_error(m, p, Vec3(0.0f)) * 2.0f;
    out.grow(w - e);
    out.grow(w + e);
  }
  return out;
}

// Whether the 3x3 part (and, with translation, the last column) is exactly the identity's.
bool is_identity(const Mat4& m, bool translation) {
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < (translation ? 4 : 3); ++j)
      if (m.m[i][j] != (i == j ? 1.0f : 0.0f)) return false;
  return true;
}

struct Builder {
  std::vector<BvhNode>& nodes;
  std::vector<uint32_t>& refs;
  const std::vector<Aabb>& boxes;
  std::vector<Vec3> centers;

  void build(uint32_t node, uint32_t begin, uint32_t end, int depth) {
    Aabb b, cb;
    for (uint32_t i = begin; i < end; ++i) {
      b.grow(boxes[refs[i]]);
      cb.grow(centers[refs[i]]);
    }
    nodes[node].lo = b.lo;
    nodes[node].hi = b.hi;
    const uint32_t n = end - begin;
    uint32_t mid = begin;
    if (n > kMaxLeaf) {
      const int axis = max_axis(cb.extent());
      const float lo = cb.lo[axis], ext = cb.extent()[axis];
      // Deep down, halves by count: the depth (and the traversal stack) stays below
      // kSahDepth + 32 levels however lopsided the SAH splits above were.
      if (ext > 0.0f && depth < kSahDepth) {
        mid = binned_sah_partition<kBins>(refs, begin, end, boxes, centers, axis, lo, ext);
      }
      if (mid == begin || mid == end) {  // coincident centroids: split by count
        mid = begin + n / 2;
        std::nth_element(refs.begin() + begin, refs.begin() + mid, refs.begin() + end,
                         [&](uint32_t a, uint32_t c) { return centers[a][axis] < centers[c][axis]; });
      }
    }
    if (mid == begin) {
      nodes[node].left_or_first = begin;
      nodes[node].count = n;
      return;
    }
    const uint32_t left = uint32_t(nodes.size());
    nodes.emplace_back();
    nodes.emplace_back();
    nodes[node].left_or_first = left;
    nodes[node].count = 0;
    build(left, begin, mid, depth + 1);
    build(left + 1, mid, end, depth + 1);
  }
};

// The binary tree collapsed into 8-wide nodes (bvh_detail::collapse_wide): a room's few objects
// sit in one or two nodes, and a ray tests all of them at once (one AVX or two SSE box tests)
// instead of one binary node per level.

}  // namespace

void Tlas::clear() {
  // Released, not just emptied: memory_bytes() reports capacity.
  nodes_ = {};
  insts_ = {};
  bounds_ = Aabb();
  stats_ = TlasStats();
}

void Tlas::build(std::vector<TlasInstance> instances) {
  const auto start = std::chrono::steady_clock::now();
  clear();
  insts_ = std::move(instances);
  std::vector<Aabb> boxes(insts_.size());
  std::vector<BvhNode> bin;
  std::vector<uint32_t> refs;
  Builder b{bin, refs, boxes, std::vector<Vec3>(insts_.size())};
  for (uint32_t i = 0; i < insts_.size(); ++i) {
    TlasInstance& in = insts_[i];
    // Objects with applied transforms (identity) need no ray transform, moved-only ones
    // (translations) no matrix products.
    if (!in.identity && is_identity(in.to_world, true) && is_identity(in.to_object, true)) in.identity = true;
    if (in.motion && in.motion_steps >= 2) in.identity = false;
    in.space = in.motion && in.motion_steps >= 2 ? TlasSpace::Motion
               : in.identity ? TlasSpace::World
               : is_identity(in.to_world, false) && is_identity(in.to_object, false) ? TlasSpace::Translated
                                                                                    : TlasSpace::Affine;
    in.finite = true;
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 4; ++c) in.finite = in.finite && std::isfinite(in.to_object.m[r][c]);
    if (in.deform ? in.deform->empty() : (!in.blas || in.blas->empty())) continue;
    const Aabb ob = in.deform ? in.deform->bounds() : in.blas->bounds();
    boxes[i] = in.space == TlasSpace::Motion ? motion_world_box(ob, in.motion, in.motion_steps)
               : in.identity ? ob
                             : world_box(ob, in.to_world);
    if (boxes[i].empty() || !is_finite(boxes[i].lo) || !is_finite(boxes[i].hi)) continue;
    b.centers[i] = boxes[i].center();
    refs.push_back(i);
    bounds_.grow(boxes[i]);
  }
  if (!refs.empty()) {
    bin.reserve(2 * refs.size());
    bin.emplace_back();
    b.build(0, 0, uint32_t(refs.size()), 0);
    nodes_.reserve(refs.size() / (kWidth - 1) + 1);  // full nodes; fewer when lanes stay empty
    bvh_detail::collapse_wide(bin, 0, nodes_, [&](const BvhNode& c, uint32_t& child, uint32_t& count) {
      child = refs[c.left_or_first];  // kMaxLeaf == 1: one instance
      count = 1;
    });
    nodes_.shrink_to_fit();
  }
  stats_.instances = refs.size();
  stats_.nodes = nodes_.size();
  stats_.build_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
}

namespace {

// Entry distances of the 8 lanes' boxes and the mask of those hit before tmax: the binary
// slab test (near and far planes picked by the direction's signs, as the wide BVH does; the
// same conservative exit scale), all 8 lanes in one AVX operation or four per SSE one.
struct RayBoxes {
  int near[3], far[3];
  float org[3], inv[3];
  RayBoxes(const Ray& r, const Vec3& iv) {
    for (int a = 0; a < 3; ++a) {
      org[a] = r.org[a];
      inv[a] = iv[a];
      near[a] = iv[a] < 0.0f ? 2 * a + 1 : 2 * a;
      far[a] = near[a] ^ 1;
    }
  }
  unsigned test(const TlasNode& n, float tmax, float* dist) const {
#if defined(__AVX__)
    __m256 tmin = _mm256_setzero_ps(), tfar = _mm256_set1_ps(tmax);
    for (int a = 0; a < 3; ++a) {
      const __m256 o = _mm256_set1_ps(org[a]), iv = _mm256_set1_ps(inv[a]);
      const __m256 t0 = _mm256_mul_ps(_mm256_sub_ps(_mm256_load_ps(n.bounds[near[a]]), o), iv);
      const __m256 t1 = _mm256_mul_ps(_mm256_sub_ps(_mm256_load_ps(n.bounds[far[a]]), o), iv);
      tmin = _mm256_max_ps(t0, tmin);
      tfar = _mm256_min_ps(t1, tfar);
    }
    tfar = _mm256_mul_ps(tfar, _mm256_set1_ps(bvh_detail::kBoxExitScale));
    _mm256_storeu_ps(dist, tmin);
    return unsigned(_mm256_movemask_ps(_mm256_cmp_ps(tmin, tfar, _CMP_LE_OQ)));
#elif defined(__SSE2__)
    unsigned mask = 0;
    for (int h = 0; h < kWidth; h += 4) {
      __m128 tmin = _mm_setzero_ps(), tfar = _mm_set1_ps(tmax);
      for (int a = 0; a < 3; ++a) {
        const __m128 o = _mm_set1_ps(org[a]), iv = _mm_set1_ps(inv[a]);
        const __m128 t0 = _mm_mul_ps(_mm_sub_ps(_mm_load_ps(&n.bounds[near[a]][h]), o), iv);
        const __m128 t1 = _mm_mul_ps(_mm_sub_ps(_mm_load_ps(&n.bounds[far[a]][h]), o), iv);
        tmin = _mm_max_ps(t0, tmin);  // (t0 > tmin) ? t0 : tmin, NaN-safe towards tmin
        tfar = _mm_min_ps(t1, tfar);
      }
      tfar = _mm_mul_ps(tfar, _mm_set1_ps(bvh_detail::kBoxExitScale));
      _mm_storeu_ps(dist + h, tmin);
      mask |= unsigned(_mm_movemask_ps(_mm_cmple_ps(tmin, tfar))) << h;
    }
    return mask;
#else
    unsigned mask = 0;
    for (int k = 0; k < kWidth; ++k) {
      float tmin = 0.0f, tfar = tmax;
      for (int a = 0; a < 3; ++a) {
        const float t0 = (n.bounds[near[a]][k] - org[a]) * inv[a];
        const float t1 = (n.bounds[far[a]][k] - org[a]) * inv[a];
        tmin = t0 > tmin ? t0 : tmin;
        tfar = t1 < tfar ? t1 : tfar;
      }
      dist[k] = tmin;
      if (tmin <= tfar * bvh_detail::kBoxExitScale) mask |= 1u << k;
    }
    return mask;
#endif
  }
};

// One entry of the traversal stack: a node (or, with kLeafBit, an instance) and the distance
// at which the ray enters its box.
constexpr uint32_t kLeafBit = 0x80000000u;
struct StackEntry {
  uint32_t id;
  float t;
};
// A node pops one entry and pushes at most kWidth; the wide tree has at most kMaxDepth + 1 levels.
constexpr int kWideStack = (kMaxDepth + 1) * kWidth;

// A lane's child as a traversal entry: a node, or with kLeafBit an instance.
inline uint32_t child_id(const TlasNode& n, int k) { return n.count[k] ? (n.child[k] | kLeafBit) : n.child[k]; }

// Enters instance `i` with the ray (up to tmax): closest hit into `hit` / any hit.
template <bool AnyHit>
inline bool enter(const TlasInstance& in, uint32_t i, const Ray& ray, float tmax, Hit& hit,
                  TraversalCounters* counters) {
  Ray r = ray;
  r.tmax = tmax;
  float dt = 0.0f;
  if (in.space == TlasSpace::Affine)
    r = in.finite ? ray_to_object_finite(in.to_object, r, dt) : ray_to_object(in.to_object, r, dt);
  else if (in.space == TlasSpace::Translated) r = ray_to_object_translated(in.to_object, r, dt);
  else if (in.space == TlasSpace::Motion)
    r = ray_to_object(affine_inverse_fast(motion_transform_at(in.motion, in.motion_steps, ray.time)), r, dt);
  if (!(r.tmax > 0.0f)) return false;
  if (__builtin_expect(in.deform != nullptr, 0)) {
    if (AnyHit) return in.deform->occluded(r);
    Hit h;
    if (!in.deform->intersect(r, h)) return false;
    hit = h;
    hit.t = h.t + dt;
    hit.inst = i;
    return true;
  }
  if (AnyHit) return in.blas->occluded(r);
  Hit h;
  if (!in.blas->intersect(r, h, counters)) return false;
  hit = h;
  hit.t = h.t + dt;
  hit.inst = i;
  return true;
}

}  // namespace

bool Tlas::intersect(const Ray& ray, Hit& hit, TraversalCounters* counters) const {
  if (nodes_.empty()) return false;
  const RayBoxes rb(ray, bvh_detail::safe_inverse(ray.dir));
  float tmax = ray.tmax;
  bool found = false;
  StackEntry stack[kWideStack];
  int sp = 0;
  uint32_t id = 0;  // the root is a node
  for (;;) {
    if (id & kLeafBit) {
      const uint32_t i = id & ~kLeafBit;
      if (enter<false>(insts_[i], i, ray, tmax, hit, counters)) {
        tmax = hit.t;
        found = true;
      }
    } else {
      const TlasNode& n = nodes_[id];
      if (counters) counters->nodes++;
      alignas(32) float dist[kWidth];
      unsigned mask = rb.test(n, tmax, dist);
      if (mask) {
        // The nearest child next, without a trip through the stack; the others pushed farthest
        // first, ties in lane order as before (the higher lane nearer the top), so instances
        // are entered in the same order and the same hit wins exact ties.
        int k = __builtin_ctz(mask);
        mask &= mask - 1;
        if (!mask) {  // one child (a ray down a single branch, or into one instance)
          id = child_id(n, k);
          continue;
        }
        const int base = sp;
        stack[sp++] = {child_id(n, k), dist[k]};
        while (mask) {
          k = __builtin_ctz(mask);
          mask &= mask - 1;
          const StackEntry x{child_id(n, k), dist[k]};
          int j = sp++;
          for (; j > base && stack[j - 1].t < x.t; --j) stack[j] = stack[j - 1];
          stack[j] = x;
        }
        id = stack[--sp].id;
        continue;
      }
    }
    // The next box that can still hold a closer hit: boxes entered at or beyond the closest
    // hit so far hold nothing closer (the box test's own rule, now that tmax has shrunk).
    do {
      if (sp == 0) return found;
      --sp;
    } while (!(stack[sp].t <= tmax * bvh_detail::kBoxExitScale));
    id = stack[sp].id;
  }
}

bool Tlas::occluded(const Ray& ray) const {
  if (nodes_.empty()) return false;
  const RayBoxes rb(ray, bvh_detail::safe_inverse(ray.dir));
  uint32_t stack[kWideStack];
  int sp = 0;
  uint32_t id = 0;
  Hit unused;
  for (;;) {
    if (id & kLeafBit) {
      const uint32_t i = id & ~kLeafBit;
      if (enter<true>(insts_[i], i, ray, ray.tmax, unused, nullptr)) return true;
    } else {
      const TlasNode& n = nodes_[id];
      alignas(32) float dist[kWidth];
      unsigned mask = rb.test(n, ray.tmax, dist);
      if (mask) {
        // Any order finds an occluder: the same one as before (the highest lane next, the
        // rest pushed), without a trip through the stack.
        const int top = 31 - __builtin_clz(mask);
        mask &= ~(1u << top);
        while (mask) {
          const int k = __builtin_ctz(mask);
          mask &= mask - 1;
          stack[sp++] = child_id(n, k);
        }
        id = child_id(n, top);
        continue;
      }
    }
    if (sp == 0) return false;
    id = stack[--sp];
  }
}

}  // namespace pl
