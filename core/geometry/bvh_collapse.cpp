// The collapse of the binary tree into a 4- or 8-wide one (float or compressed nodes) and the
// leaves' triangle blocks, on several threads with the same result on any count.
#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <thread>
#include <type_traits>
#include <utility>
#include <vector>

#include "geometry/bvh_build.h"
#include "geometry/bvh_common.h"
#include "util/big_alloc.h"
#include "util/parallel.h"

namespace pl {
namespace {

// The compressed form of float node `f` (k used lanes): per axis the origin is the lanes' lowest
// plane and the step the smallest power of two whose 255 steps reach the highest, both checked
// in float as the traversal computes planes (QuantWideNode::plane); each byte is then rounded
// outwards and moved until its plane lies outside the child's box (never inside it). False
// when the boxes are not finite or too large for the steps (or a leaf is over 255 triangles).
template <int N>
bool quantise_node(const WideBvhNode<N>& f, int k, QuantWideNode<N>& q) {
  std::memset(&q, 0, sizeof(q));
  q.valid = static_cast<uint8_t>((1u << k) - 1u);
  for (int i = 0; i < N; ++i) {
    if (f.count[i] > 255) return false;
    q.child[i] = f.child[i];
    q.count[i] = static_cast<uint8_t>(f.count[i]);
  }
  for (int a = 0; a < 3; ++a) {
    float lo = kInf, hi = -kInf;
    for (int i = 0; i < k; ++i) {
      const float cl = f.bounds[2 * a][i], ch = f.bounds[2 * a + 1][i];
      if (!(std::isfinite(cl) && std::isfinite(ch) && cl <= ch)) return false;
      lo = std::min(lo, cl);
      hi = std::max(hi, ch);
    }
    const float ext = hi - lo;
    if (!std::isfinite(ext)) return false;
    int e = -126;  // 2^-126: the smallest normal step, so scale * q stays exact
    if (ext > 0.0f) {
      std::frexp(ext / 255.0f, &e);  // ext / 255 < 2^e: usually 2^(e - 1) is too short
      e = std::max(e - 1, -126);
    }
    float scale;
    for (;; ++e) {
      if (e > 119) return false;  // 255 * 2^119 < 2^127: the largest step without overflow
      scale = std::ldexp(1.0f, e);
      if (lo + scale * 255.0f >= hi) break;
    }
    q.origin[a] = lo;
    q.scale[a] = scale;
    const auto plane = [&](int b) { return lo + scale * float(b); };  // as QuantWideNode::plane
    for (int i = 0; i < N; ++i) {
      if (i >= k) {  // unused lane: an empty box (the traversal also masks it off)
        q.q[2 * a][i] = 255;
        q.q[2 * a + 1][i] = 0;
        continue;
      }
      const float cl = f.bounds[2 * a][i], ch = f.bounds[2 * a + 1][i];
      int bl = static_cast<int>(std::clamp(std::floor((cl - lo) / scale), 0.0f, 255.0f));
      while (bl > 0 && plane(bl) > cl) --bl;  // plane(0) = lo <= cl
      int bh = static_cast<int>(std::clamp(std::ceil((ch - lo) / scale), 0.0f, 255.0f));
      while (bh < 255 && plane(bh) < ch) ++bh;
      if (plane(bl) > cl || plane(bh) < ch) return false;  // cannot happen: plane(255) >= hi
      q.q[2 * a][i] = static_cast<uint8_t>(bl);
      q.q[2 * a + 1][i] = static_cast<uint8_t>(bh);
    }
  }
  return true;
}

struct LeafJob {
  uint32_t first, count, block;  // the leaf's triangles (leaf order) and its first block
};
struct CollapseItem {
  uint32_t bin, wide;  // a binary node and the wide node it becomes
};

// The wide node of binary node `b` (as float lanes; `k` gets the used lanes): interior children
// are numbered from `next` on and pushed onto `todo` in lane order, leaf children get blocks
// from `n_blocks` on and a job each.
template <int N>
void make_wide_node(const BvhNode* bin, uint32_t b, uint32_t& next, uint32_t& n_blocks,
                    std::vector<CollapseItem>& todo, std::vector<LeafJob>& jobs, WideBvhNode<N>& node, int& k) {
  uint32_t kids[N];
  k = bvh_detail::gather_wide_children(bin, b, kids, N);
  for (int i = 0; i < N; ++i) {
    if (i < k) {
      const BvhNode& c = bin[kids[i]];
      node.bounds[0][i] = c.lo.x;
      node.bounds[1][i] = c.hi.x;
      node.bounds[2][i] = c.lo.y;
      node.bounds[3][i] = c.hi.y;
      node.bounds[4][i] = c.lo.z;
      node.bounds[5][i] = c.hi.z;
      if (c.is_leaf()) {
        node.child[i] = n_blocks;
        node.count[i] = c.count;
        jobs.push_back({c.left_or_first, c.count, n_blocks});
        n_blocks += (c.count + 3) / 4;
      } else {
        node.child[i] = next++;
        node.count[i] = 0;
        todo.push_back({kids[i], node.child[i]});
      }
    } else {  // unused lane: an empty box (lo > hi) that the slab test always rejects
      for (int a = 0; a < 3; ++a) {
        node.bounds[2 * a][i] = kInf;
        node.bounds[2 * a + 1][i] = -kInf;
      }
      node.child[i] = 0;
      node.count[i] = 0;
    }
  }
}

template <int N, class Node>
bool store_wide_node(const WideBvhNode<N>& node, int k, Node& out) {
  if constexpr (std::is_same_v<Node, WideBvhNode<N>>) {
    out = node;
    return true;
  } else {
    return quantise_node(node, k, out);
  }
}

// The references under binary node b: a subtree's leaves are one range of the leaf order, from
// its leftmost leaf's first to its rightmost leaf's last.
inline uint32_t subtree_refs(const BvhNode* bin, uint32_t b) {
  uint32_t l = b, r = b;
  while (!bin[l].is_leaf()) l = bin[l].left_or_first;
  while (!bin[r].is_leaf()) r = bin[r].left_or_first + 1;
  return bin[r].left_or_first + bin[r].count - bin[l].left_or_first;
}

// One subtree of the collapse, made on its own thread: first counted, then, once the top walk
// has given it its place, written straight into the output.
struct CollapsePart {
  uint32_t bin = 0, wide = 0;             // its root: binary node and (global) wide index
  uint32_t nodes = 0, blocks = 0, leaves = 0;  // its size
  uint32_t node_base = 0, block_base = 0;  // where its nodes below the root and its blocks go
  size_t job_base = 0;                     // and its leaves' jobs
};

}  // namespace

namespace bvh_detail {

// Collapses the binary tree into an N-wide one: each wide node takes a binary node's two
// children and keeps opening its largest interior child (the one most rays enter) until it
// has N children or only leaves (Wald et al. 2008, as in Embree and tinybvh). Leaves stay
// the binary leaves; `tris` is the build's input, reached through prim_ids (leaf order).
// Nodes and blocks are numbered in the order of one depth-first pass (a stack: a node's
// interior children get consecutive indices, the last one's subtree is made first), and leaves
// become runs of TriangleBlock4s in that order. On several threads the same numbering comes
// from parts: subtrees of few enough references are counted in parallel, the top of the tree
// is walked as that pass would, each part taking as many indices as it counted, then the
// parts are made in parallel straight into their places; the blocks are filled in parallel.
// So the result is the same on any thread count. Into float nodes (Node = WideBvhNode<N>) or
// compressed ones (QuantWideNode<N>, from the float node of the same lanes); false when a node
// cannot be compressed (quantise_node), the outputs then unspecified.
template <int N, class Node>
bool collapse(const BvhNode* bin, size_t n_bin, TriangleSpan tris,
              const std::vector<uint32_t>& prim_ids, int threads, RawVector<Node>& out,
              RawVector<TriangleBlock4>& blocks, RawVector<uint32_t>& block_prims) {
  const int hw = std::max(1, threads > 0 ? threads : static_cast<int>(std::thread::hardware_concurrency()));
  const uint32_t refs = static_cast<uint32_t>(prim_ids.size());
  // Subtrees of at most this many references are parts (about 8 per thread); none on one thread.
  const uint32_t part_max = hw > 1 && refs >= 65536 ? std::max<uint32_t>(8192, refs / (8 * uint32_t(hw))) : 0;
  const auto is_part = [&](uint32_t b) { return part_max > 0 && b != 0 && subtree_refs(bin, b) <= part_max; };
  std::vector<CollapsePart> parts;
  std::vector<CollapseItem> todo;
  std::vector<LeafJob> jobs;
  WideBvhNode<N> node;
  int k = 0;
  // Runs fn(part) for every part, parts handed out in turn (any thread may take any one).
  const auto for_parts = [&](auto&& fn) {
    std::atomic<size_t> next_part{0};
    run_chunks(std::min<int>(hw, int(parts.size())), [&](int) {
      for (size_t p; (p = next_part.fetch_add(1)) < parts.size();) fn(parts[p]);
    });
  };
  if (part_max > 0) {
    // The top walk, numbering nothing: which subtrees are parts, in the order the pass meets them.
    uint32_t next = 1, nb = 0;
    todo.push_back({0, 0});
    while (!todo.empty()) {
      const CollapseItem it = todo.back();
      todo.pop_back();
      if (is_part(it.bin)) {
        parts.emplace_back();
        parts.back().bin = it.bin;
        continue;
      }
      make_wide_node<N>(bin, it.bin, next, nb, todo, jobs, node, k);
    }
    jobs.clear();
    // Each part's wide nodes, blocks and leaves counted (the same walk, nothing written).
    for_parts([&](CollapsePart& part) {
      uint32_t kids[N];
      std::vector<uint32_t> stack{part.bin};
      uint32_t nodes = 0, blocks = 0, leaves = 0;  // locals: neighbouring parts share cache lines
      while (!stack.empty()) {
        const uint32_t b = stack.back();
        stack.pop_back();
        ++nodes;
        const int m = bvh_detail::gather_wide_children(bin, b, kids, N);
        for (int i = 0; i < m; ++i) {
          const BvhNode& c = bin[kids[i]];
          if (c.is_leaf()) {
            blocks += (c.count + 3) / 4;
            ++leaves;
          } else {
            stack.push_back(kids[i]);
          }
        }
      }
      part.nodes = nodes;
      part.blocks = blocks;
      part.leaves = leaves;
    });
  }
  // The pass itself: the top nodes made, each part given its indices. On one thread (no parts)
  // the nodes go straight into `out`; else the top ones wait until `out` has its final size.
  uint32_t next = 1, n_blocks = 0;
  size_t part_no = 0;
  std::vector<std::pair<uint32_t, int>> top;  // with parts: the top nodes' indices and lanes
  std::vector<WideBvhNode<N>> top_nodes;
  out.clear();
  if (part_max == 0) {
    jobs.reserve((n_bin + 1) / 2);  // one per leaf
    out.reserve((n_bin + 1) / 2);   // at most one wide node per interior binary node
    advise_huge_pages(out.data(), out.capacity() * sizeof(Node));
    out.emplace_back();
  }
  todo.assign(1, {0, 0});
  while (!todo.empty()) {
    const CollapseItem it = todo.back();
    todo.pop_back();
    if (is_part(it.bin)) {
      CollapsePart& part = parts[part_no++];
      part.wide = it.wide;
      part.node_base = next;
      part.block_base = n_blocks;
      next += part.nodes - 1;
      n_blocks += part.blocks;
      continue;
    }
    make_wide_node<N>(bin, it.bin, next, n_blocks, todo, jobs, node, k);
    if (part_max > 0) {
      top.push_back({it.wide, k});
      top_nodes.push_back(node);
    } else {
      out.resize(next);
      if (!store_wide_node<N>(node, k, out[it.wide])) return false;
    }
  }
  if (part_max > 0) {
    out.reserve(next);
    advise_huge_pages(out.data(), out.capacity() * sizeof(Node));
    out.resize(next);
    for (size_t i = 0; i < top.size(); ++i)
      if (!store_wide_node<N>(top_nodes[i], top[i].second, out[top[i].first])) return false;
    size_t n_jobs = jobs.size();
    for (CollapsePart& part : parts) {
      part.job_base = n_jobs;
      n_jobs += part.leaves;
    }
    jobs.resize(n_jobs);
    // The parts made in their places: the same walk as the pass, its root at part.wide, the
    // nodes below from node_base on, the blocks from block_base on.
    std::atomic<bool> ok{true};
    for_parts([&](CollapsePart& part) {
      std::vector<CollapseItem> stack{{part.bin, part.wide}};
      std::vector<LeafJob> part_jobs;
      part_jobs.reserve(part.leaves);
      uint32_t pnext = part.node_base, pblocks = part.block_base;
      WideBvhNode<N> wn;
      int lanes = 0;
      while (!stack.empty()) {
        const CollapseItem it = stack.back();
        stack.pop_back();
        make_wide_node<N>(bin, it.bin, pnext, pblocks, stack, part_jobs, wn, lanes);
        if (!store_wide_node<N>(wn, lanes, out[it.wide])) ok = false;
      }
      std::copy(part_jobs.begin(), part_jobs.end(), jobs.begin() + std::ptrdiff_t(part.job_base));
    });
    if (!ok) return false;
  } else {
    out.shrink_to_fit();
  }
  // Exact sizes, every element written below.
  blocks.clear();
  block_prims.clear();
  blocks.resize(n_blocks);
  block_prims.resize(4 * size_t(n_blocks));
  blocks.shrink_to_fit();
  block_prims.shrink_to_fit();
  const float nan = std::nanf("");
  parallel_ranges(jobs.size(), threads, [&](size_t lo, size_t hi) {
    for (size_t j = lo; j < hi; ++j) {
      const LeafJob& job = jobs[j];
      for (uint32_t b = 0; b < job.count; b += 4) {
        TriangleBlock4& blk = blocks[job.block + b / 4];
        uint32_t* ids = &block_prims[4 * (size_t(job.block) + b / 4)];
        for (uint32_t l = 0; l < 4; ++l) {
          if (b + l < job.count) {
            const uint32_t id = prim_ids[job.first + b + l];
            const TriangleVerts& tv = tris[id];
            const Vec3* v[3] = {&tv.v0, &tv.v1, &tv.v2};
            for (int r = 0; r < 9; ++r) blk.v[r][l] = (*v[r / 3])[r % 3];
            ids[l] = id;
          } else {
            for (int r = 0; r < 9; ++r) blk.v[r][l] = nan;
            ids[l] = UINT32_MAX;
          }
        }
      }
    }
  }, 4096);
  return true;
}

template bool collapse<4>(const BvhNode*, size_t, TriangleSpan, const std::vector<uint32_t>&, int,
                          RawVector<Bvh4Node>&, RawVector<TriangleBlock4>&, RawVector<uint32_t>&);
template bool collapse<8>(const BvhNode*, size_t, TriangleSpan, const std::vector<uint32_t>&, int,
                          RawVector<Bvh8Node>&, RawVector<TriangleBlock4>&, RawVector<uint32_t>&);
template bool collapse<4>(const BvhNode*, size_t, TriangleSpan, const std::vector<uint32_t>&, int,
                          RawVector<Bvh4QNode>&, RawVector<TriangleBlock4>&, RawVector<uint32_t>&);
template bool collapse<8>(const BvhNode*, size_t, TriangleSpan, const std::vector<uint32_t>&, int,
                          RawVector<Bvh8QNode>&, RawVector<TriangleBlock4>&, RawVector<uint32_t>&);

}  // namespace bvh_detail
}  // namespace pl
