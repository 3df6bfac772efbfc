// Bvh::build: the binary SAH tree (Builder, bvh_build.h), its statistics, and the collapse
// into the layout the traversal uses; the wide tree's lanes for tests.
#include "geometry/bvh.h"

#include <algorithm>
#include <chrono>
#include <cstdint>
#include <type_traits>
#include <utility>
#include <vector>

#include "geometry/bvh_build.h"

namespace pl {

using bvh_detail::Builder;
using bvh_detail::collapse;

void Bvh::clear() {
  *this = Bvh();
}

bool Bvh::build(TriangleSpan tris, const BvhBuildOptions& options) {
  const auto t0 = std::chrono::steady_clock::now();
  clear();
  BvhBuildOptions opt = options;
  BvhLayout layout = opt.layout;
#if defined(__x86_64__) || defined(__i386__)
  if (layout == BvhLayout::Auto) layout = cpu_has_avx2() ? BvhLayout::Wide8 : BvhLayout::Wide4;
  if (layout == BvhLayout::Wide8 && !cpu_has_avx2()) layout = BvhLayout::Wide4;
#else
  layout = BvhLayout::Binary;  // the wide kernels are written for x86 SIMD
#endif
  if (opt.leaf_block <= 0) opt.leaf_block = layout == BvhLayout::Binary ? 1 : 4;
  const auto cancelled = [&] { return opt.cancel && opt.cancel->load(); };
  if (tris.empty()) return !cancelled();
  Builder builder(tris, opt, prim_ids_);
  if (!builder.run()) {
    clear();
    return false;
  }
  const BvhNode* bin = builder.nodes();
  const size_t n_bin = builder.node_count();
  if (layout == BvhLayout::Binary) {  // kept; the wide layouts copy the triangles into their blocks instead
    // Renumbered without the pools' gaps, in depth-first order, each pair side by side (as one
    // serial build numbers them).
    nodes_.resize(n_bin);
    std::vector<std::pair<uint32_t, uint32_t>> todo{{0u, 0u}};  // (builder's index, ours)
    uint32_t next = 1;
    while (!todo.empty()) {
      const auto [from, to] = todo.back();
      todo.pop_back();
      BvhNode& nd = nodes_[to];
      nd = bin[from];
      if (!nd.is_leaf()) {
        todo.push_back({nd.left_or_first + 1, next + 1});
        todo.push_back({nd.left_or_first, next});
        nd.left_or_first = next;
        next += 2;
      }
    }
    tris_.resize(prim_ids_.size());
    for (size_t i = 0; i < prim_ids_.size(); ++i) tris_[i] = tris[prim_ids_[i]];
  }

  bounds_ = {bin[0].lo, bin[0].hi};
  stats_.nodes = n_bin;
  stats_.max_depth = builder.max_depth();
  stats_.triangles = tris.size();
  stats_.references = prim_ids_.size();
  stats_.spatial_splits = builder.spatial_splits();
  stats_.clusters = builder.clusters();
  const float root_area = std::max(bounds_.half_area(), 1e-30f);
  // Summed in tree order (the builder's node pools have gaps, and the sum's order must be the
  // same on any thread count).
  double cost = 0.0;
  std::vector<uint32_t> stack{0};
  while (!stack.empty()) {
    const BvhNode& n = bin[stack.back()];
    stack.pop_back();
    const double rel = Aabb{n.lo, n.hi}.half_area() / root_area;
    if (n.is_leaf()) {
      stats_.leaves++;
      cost += rel * n.count;
    } else {
      cost += rel * opt.traversal_cost;
      stack.push_back(n.left_or_first + 1);
      stack.push_back(n.left_or_first);
    }
  }
  stats_.sah_cost = cost;
  if (cancelled()) {
    clear();
    return false;
  }
  if (layout != BvhLayout::Binary && opt.compact) {
    compact_ = layout == BvhLayout::Wide4
                   ? collapse<4>(bin, n_bin, tris, prim_ids_, opt.threads, nodes4q_, blocks_, block_prims_)
                   : collapse<8>(bin, n_bin, tris, prim_ids_, opt.threads, nodes8q_, blocks_, block_prims_);
    if (!compact_) {  // a box that bytes cannot hold: float nodes
      RawVector<Bvh4QNode>().swap(nodes4q_);
      RawVector<Bvh8QNode>().swap(nodes8q_);
    }
  }
  if (layout == BvhLayout::Wide4 && !compact_)
    collapse<4>(bin, n_bin, tris, prim_ids_, opt.threads, nodes4_, blocks_, block_prims_);
  if (layout == BvhLayout::Wide8 && !compact_)
    collapse<8>(bin, n_bin, tris, prim_ids_, opt.threads, nodes8_, blocks_, block_prims_);
  if (layout != BvhLayout::Binary) {
    // The wide tree and its triangle blocks replace the binary tree and the leaf order.
    stats_.wide_nodes = compact_ ? (layout == BvhLayout::Wide4 ? nodes4q_.size() : nodes8q_.size())
                                 : (layout == BvhLayout::Wide4 ? nodes4_.size() : nodes8_.size());
    stats_.compact = compact_;
    std::vector<uint32_t>().swap(prim_ids_);
  }
  triangles_ = tris.size();
  layout_ = stats_.layout = layout;
  stats_.build_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  return true;
}

size_t Bvh::memory_bytes() const {
  return nodes_.capacity() * sizeof(BvhNode) + nodes4_.capacity() * sizeof(Bvh4Node) +
         nodes8_.capacity() * sizeof(Bvh8Node) + nodes4q_.capacity() * sizeof(Bvh4QNode) +
         nodes8q_.capacity() * sizeof(Bvh8QNode) + tris_.capacity() * sizeof(TriangleVerts) +
         prim_ids_.capacity() * sizeof(uint32_t) + blocks_.capacity() * sizeof(TriangleBlock4) +
         block_prims_.capacity() * sizeof(uint32_t);
}

namespace {
template <int N, class Node>
void append_lanes(const RawVector<Node>& nodes, std::vector<Bvh::WideLane>& out) {
  for (const Node& n : nodes) {
    for (int i = 0; i < N; ++i) {
      Bvh::WideLane l;
      for (int r = 0; r < 6; ++r) {
        if constexpr (std::is_same_v<Node, WideBvhNode<N>>) l.box[r] = n.bounds[r][i];
        else l.box[r] = n.plane(r, i);
      }
      l.child = n.child[i];
      l.count = n.count[i];
      if constexpr (std::is_same_v<Node, WideBvhNode<N>>) l.valid = n.bounds[0][i] <= n.bounds[1][i];
      else l.valid = (n.valid >> i) & 1u;
      out.push_back(l);
    }
  }
}
}  // namespace

std::vector<Bvh::WideLane> Bvh::wide_lanes() const {
  std::vector<WideLane> out;
  append_lanes<4>(nodes4_, out);
  append_lanes<8>(nodes8_, out);
  append_lanes<4>(nodes4q_, out);
  append_lanes<8>(nodes8q_, out);
  return out;
}

}  // namespace pl
