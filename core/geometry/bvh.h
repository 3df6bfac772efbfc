// Bounding volume hierarchy over triangles, built with the binned surface area heuristic
// (Wald 2007) as a binary tree, then collapsed into a 4- or 8-wide tree whose child boxes sit
// in SIMD lanes (tinybvh's and Embree's layouts, our own code). It knows triangles only: hits
// name triangle indices, and everything else (materials, lights) lives in the scene layer.
#pragma once
#include <atomic>
#include <cstdint>
#include <memory>
#include <new>
#include <type_traits>
#include <utility>
#include <vector>

#include "geometry/aabb.h"
#include "geometry/ray.h"
#include "util/big_alloc.h"

namespace pl {

struct TriangleVerts {
  Vec3 v0, v1, v2;
  // The geometric normal, winding included (NaN for a zero-area triangle).
  Vec3 unit_normal() const { return normalize(cross(v1 - v0, v2 - v0)); }
};

// 32 bytes: two nodes per cache line. Children of an interior node are stored side by side.
struct BvhNode {
  Vec3 lo;
  uint32_t left_or_first;  // interior: index of the left child (right = left + 1); leaf: first triangle
  Vec3 hi;
  uint32_t count;          // 0 for interior nodes
  bool is_leaf() const { return count != 0; }
};

// A node of the wide BVH: the boxes of up to N children as six rows of N floats (lo x, hi x,
// lo y, hi y, lo z, hi z), so one SIMD register holds one plane of all children. Unused lanes
// have lo = +inf, hi = -inf, which every ray misses.
template <int N>
struct alignas(32) WideBvhNode {
  float bounds[6][N];
  uint32_t child[N];  // interior: index of the child node; leaf: first triangle (leaf order)
  uint32_t count[N];  // 0: interior child (or unused lane); else number of triangles of the leaf
};
using Bvh4Node = WideBvhNode<4>;  // 128 bytes
using Bvh8Node = WideBvhNode<8>;  // 256 bytes

// A compressed wide node (Ylitie, Karras & Laine 2017; Embree's compact BVH8): the child boxes
// as bytes q, a plane being origin[a] + scale[a] * q with scale a power of two, so scale * q is
// exact and one FMA or a multiply and an add give the same float. The collapse picks each
// byte so that this float lies outside the child's true box (conservative), and the traversal
// runs the float nodes' slab test on it: it visits every box the float tree visits, so hits
// are the same. Half the float node's size (8-wide: 128 bytes, two cache lines; 4-wide: 80).
template <int N>
struct alignas(N == 8 ? 64 : 16) QuantWideNode {
  float origin[3];
  float scale[3];     // powers of two, 2^-126 .. 2^119 (normal: scale * q is exact)
  uint8_t q[6][N];    // rows as WideBvhNode::bounds (lo x, hi x, lo y, ...)
  uint32_t child[N];  // as WideBvhNode
  uint8_t count[N];   // as WideBvhNode (leaves have at most 255 triangles)
  uint8_t valid;      // mask of the used lanes
  float plane(int row, int lane) const { return origin[row >> 1] + scale[row >> 1] * float(q[row][lane]); }
};
using Bvh4QNode = QuantWideNode<4>;  // 80 bytes
using Bvh8QNode = QuantWideNode<8>;  // 128 bytes
static_assert(sizeof(Bvh8QNode) == 128 && sizeof(Bvh4QNode) == 80, "node sizes");

// Four triangles of a leaf of the wide trees, coordinates in SIMD lanes (rows v0.x, v0.y, v0.z,
// v1.x, ..., v2.z), so one watertight test runs on all four. A leaf of n triangles takes
// ceil(n / 4) consecutive blocks; unused lanes hold NaN, which the test rejects.
struct alignas(16) TriangleBlock4 {
  float v[9][4];
};

// Which tree the traversal uses. Auto: the 8-wide one where the CPU has AVX2, else the 4-wide
// (SSE2, every x86-64). Binary is the reference the wide ones are tested against.
enum class BvhLayout : uint8_t { Auto, Binary, Wide4, Wide8 };
bool cpu_has_avx2();
bool cpu_has_avx512();  // F, VL, BW and DQ, as the AVX-512 8-wide kernel uses

// Which code runs the 8-wide tree: AVX-512 where the CPU has it, unless the environment
// variable PL_BVH_KERNEL=avx2 (read once, at load) or set_bvh8_kernel asked for AVX2. The same
// hits either way; for tests and timings. Set it between renders, not during one.
enum class Bvh8Kernel : uint8_t { Auto, Avx2, Avx512 };
// Returns the kernel now used (Avx512 asked of a CPU without it gives Avx2; Auto: the choice at
// load).
Bvh8Kernel set_bvh8_kernel(Bvh8Kernel k);
Bvh8Kernel bvh8_kernel();
namespace bvh_detail {
extern std::atomic<bool> g_bvh8_avx512;
}
inline bool bvh8_use_avx512() { return bvh_detail::g_bvh8_avx512.load(std::memory_order_relaxed); }

struct BvhBuildOptions {
  int bins = 32;
  int max_leaf_size = 8;
  float traversal_cost = 1.0f;  // SAH cost of visiting a node, relative to one triangle test
  int threads = 0;              // 0 = hardware threads
  // Triangles tested together: the SAH charges a leaf ceil(n / leaf_block) tests, so leaves
  // fill whole blocks. 0 = automatic (4 for the wide layouts, whose leaves are TriangleBlock4s).
  int leaf_block = 0;
  BvhLayout layout = BvhLayout::Auto;
  // Compressed (quantised) wide nodes: half the node memory, the same hits. Trees whose boxes
  // are not finite (never the scene's: it drops such triangles) keep float nodes.
  bool compact = false;
  // Spatial splits (SBVH, Stich, Friedrich & Dietrich 2009): where the best object split's
  // children overlap by more than spatial_alpha x the root's surface area, binned planes that
  // cut the triangles themselves are tried too; a cut triangle is referenced by both children
  // (hits still name the input index). At most max_duplicates x triangles extra references,
  // shared out between subtrees (not a global counter), so the tree is the same on any thread
  // count. Slower builds, fewer triangle and node tests on long thin triangles: final renders.
  bool spatial_splits = false;
  // Clustered build (ignored with spatial splits): the triangles sorted along a Morton curve and
  // cut at code bits into runs of at most 8, the binned SAH over the runs (one reference each,
  // weighted by its triangles) down to nodes of 24 triangles, then the binned SAH over those
  // nodes' triangles. About 1.6x less build work on 1M triangles; trees up to ~12 % worse in SAH
  // cost on rough height fields (about 1 % on tessellated objects): for the viewport.
  bool morton_clusters = false;
  float spatial_alpha = 1e-5f;
  float max_duplicates = 0.3f;
  // Polled during the build; when it becomes true the build stops, build() returns false and
  // the Bvh is left empty. May be set from any thread.
  const std::atomic<bool>* cancel = nullptr;
};

struct BvhStats {
  size_t nodes = 0, leaves = 0, max_depth = 0;  // of the binary tree
  size_t wide_nodes = 0;                         // of the wide tree (0 for Binary)
  double sah_cost = 0.0;  // expected cost of a random ray, in triangle tests (traversal weighted)
  double build_ms = 0.0;  // binary build and collapse
  size_t triangles = 0;       // input triangles
  size_t references = 0;      // triangle references in leaves: triangles + duplicates of cut ones
  size_t spatial_splits = 0;  // nodes split by a spatial (cutting) plane
  size_t clusters = 0;        // Morton runs of the clustered build (0: the full binned SAH)
  BvhLayout layout = BvhLayout::Binary;
  bool compact = false;  // the wide nodes are QuantWideNodes
};

// Counters for BVH visualisation and statistics.
struct TraversalCounters {
  uint32_t nodes = 0, triangles = 0;
};

// A read-only view of a build's input triangles (a std::vector or a RawVector of them).
struct TriangleSpan {
  const TriangleVerts* p = nullptr;
  size_t n = 0;
  TriangleSpan() = default;
  template <class Alloc>
  TriangleSpan(const std::vector<TriangleVerts, Alloc>& v) : p(v.data()), n(v.size()) {}
  const TriangleVerts& operator[](size_t i) const { return p[i]; }
  size_t size() const { return n; }
  bool empty() const { return n == 0; }
};

class Bvh {
 public:
  // Builds over `tris`; triangle i of the input is reported as hit.prim == i. Returns false
  // (and leaves the Bvh empty) when cancelled through opt.cancel.
  bool build(TriangleSpan tris, const BvhBuildOptions& opt = {});
  void clear();
  bool empty() const { return triangles_ == 0; }
  const BvhStats& stats() const { return stats_; }
  BvhLayout layout() const { return layout_; }
  bool compact() const { return compact_; }
  // The wide tree's nodes for tests: per node and lane the box (dequantised for compact nodes)
  // as lo x, hi x, lo y, hi y, lo z, hi z, the child and the count (as WideBvhNode's), and
  // whether the lane is used. Empty for the binary layout.
  struct WideLane {
    float box[6];
    uint32_t child, count;
    bool valid;
  };
  int wide_width() const { return layout_ == BvhLayout::Wide8 ? 8 : layout_ == BvhLayout::Wide4 ? 4 : 0; }
  std::vector<WideLane> wide_lanes() const;
  // The wide layouts' triangle blocks and their input indices (4 per block), for tests.
  const RawVector<TriangleBlock4>& blocks() const { return blocks_; }
  const RawVector<uint32_t>& block_prims() const { return block_prims_; }
  Aabb bounds() const { return bounds_; }
  // The binary layout's tree (root at 0, no gaps) and its leaf order's input indices, for
  // tests. Empty for the wide layouts.
  const std::vector<BvhNode>& binary_nodes() const { return nodes_; }
  const std::vector<uint32_t>& leaf_prims() const { return prim_ids_; }
  size_t memory_bytes() const;  // nodes, triangles and index arrays, as allocated

  // Closest hit with 0 < t < ray.tmax. Returns true on a hit and fills `hit`.
  inline bool intersect(const Ray& ray, Hit& hit, TraversalCounters* counters = nullptr) const;
  // Any hit with 0 < t < ray.tmax (shadow rays): stops at the first one found.
  inline bool occluded(const Ray& ray) const;

 private:
  bool intersect_binary(const Ray& ray, Hit& hit, TraversalCounters* counters) const;
  bool occluded_binary(const Ray& ray) const;

  BvhLayout layout_ = BvhLayout::Binary;
  Aabb bounds_;
  std::vector<BvhNode> nodes_;        // the binary tree (kept only for the Binary layout)
  // RawVectors: the collapse writes every node, so resize() must not zero them first (on one
  // thread, ahead of the parallel writes).
  RawVector<Bvh4Node> nodes4_;
  RawVector<Bvh8Node> nodes8_;
  RawVector<Bvh4QNode> nodes4q_;  // compact_: these instead of nodes4_ / nodes8_
  RawVector<Bvh8QNode> nodes8q_;
  bool compact_ = false;
  std::vector<TriangleVerts> tris_;   // in leaf order, for locality (Binary layout)
  std::vector<uint32_t> prim_ids_;    // leaf order -> input index (Binary layout)
  RawVector<TriangleBlock4> blocks_;  // the wide layouts' leaves
  RawVector<uint32_t> block_prims_;   // 4 per block: input index, UINT32_MAX for unused lanes
  size_t triangles_ = 0;
  BvhStats stats_;
};

// The traversal kernels of the wide trees (bvh_wide.inl), one instance per SIMD width.
struct WideBvhView {
  const void* nodes;
  const TriangleBlock4* blocks;
  const uint32_t* block_prims;
};
bool bvh4_intersect(const WideBvhView& v, const Ray& ray, Hit& hit, TraversalCounters* counters);
bool bvh4_occluded(const WideBvhView& v, const Ray& ray);
// Only called where cpu_has_avx2(): compiled for AVX2 in bvh8_avx2.cpp.
bool bvh8_intersect(const WideBvhView& v, const Ray& ray, Hit& hit, TraversalCounters* counters);
bool bvh8_occluded(const WideBvhView& v, const Ray& ray);
// The same over compressed nodes.
bool bvh4q_intersect(const WideBvhView& v, const Ray& ray, Hit& hit, TraversalCounters* counters);
bool bvh4q_occluded(const WideBvhView& v, const Ray& ray);
bool bvh8q_intersect(const WideBvhView& v, const Ray& ray, Hit& hit, TraversalCounters* counters);
bool bvh8q_occluded(const WideBvhView& v, const Ray& ray);
// Only called where bvh8_use_avx512(): compiled for AVX-512 in bvh8_avx512.cpp.
bool bvh8_intersect_avx512(const WideBvhView& v, const Ray& ray, Hit& hit, TraversalCounters* counters);
bool bvh8_occluded_avx512(const WideBvhView& v, const Ray& ray);
bool bvh8q_intersect_avx512(const WideBvhView& v, const Ray& ray, Hit& hit, TraversalCounters* counters);
bool bvh8q_occluded_avx512(const WideBvhView& v, const Ray& ray);

// Inline: the kernel choice is part of every ray's call.
inline bool Bvh::intersect(const Ray& ray, Hit& hit, TraversalCounters* counters) const {
  if (triangles_ == 0) return false;
  switch (layout_) {
#if defined(__x86_64__) || defined(__i386__)
    case BvhLayout::Wide8:
      if (bvh8_use_avx512()) {
        if (compact_)
          return bvh8q_intersect_avx512({nodes8q_.data(), blocks_.data(), block_prims_.data()}, ray, hit, counters);
        return bvh8_intersect_avx512({nodes8_.data(), blocks_.data(), block_prims_.data()}, ray, hit, counters);
      }
      if (compact_) return bvh8q_intersect({nodes8q_.data(), blocks_.data(), block_prims_.data()}, ray, hit, counters);
      return bvh8_intersect({nodes8_.data(), blocks_.data(), block_prims_.data()}, ray, hit, counters);
    case BvhLayout::Wide4:
      if (compact_) return bvh4q_intersect({nodes4q_.data(), blocks_.data(), block_prims_.data()}, ray, hit, counters);
      return bvh4_intersect({nodes4_.data(), blocks_.data(), block_prims_.data()}, ray, hit, counters);
#endif
    default: return intersect_binary(ray, hit, counters);
  }
}

inline bool Bvh::occluded(const Ray& ray) const {
  if (triangles_ == 0) return false;
  switch (layout_) {
#if defined(__x86_64__) || defined(__i386__)
    case BvhLayout::Wide8:
      if (bvh8_use_avx512()) {
        if (compact_) return bvh8q_occluded_avx512({nodes8q_.data(), blocks_.data(), block_prims_.data()}, ray);
        return bvh8_occluded_avx512({nodes8_.data(), blocks_.data(), block_prims_.data()}, ray);
      }
      if (compact_) return bvh8q_occluded({nodes8q_.data(), blocks_.data(), block_prims_.data()}, ray);
      return bvh8_occluded({nodes8_.data(), blocks_.data(), block_prims_.data()}, ray);
    case BvhLayout::Wide4:
      if (compact_) return bvh4q_occluded({nodes4q_.data(), blocks_.data(), block_prims_.data()}, ray);
      return bvh4_occluded({nodes4_.data(), blocks_.data(), block_prims_.data()}, ray);
#endif
    default: return occluded_binary(ray);
  }
}

}  // namespace pl
