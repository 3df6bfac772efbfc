// The clustered build (HLBVH-like, for the viewport): the triangles sorted along a Morton curve
// and cut into runs, the binned SAH over the runs, then over the triangles of its leaves.
#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <utility>
#include <vector>

#include "geometry/bvh_build.h"
#include "util/parallel.h"

namespace pl {
namespace {

// Morton code of a point's cell on a 1024^3 grid: its 10-bit coordinates interleaved.
uint32_t morton3(const int q[4]) {
  const auto spread = [](uint32_t x) {
    x = (x | x << 16) & 0x030000FFu;
    x = (x | x << 8) & 0x0300F00Fu;
    x = (x | x << 4) & 0x030C30C3u;
    return (x | x << 2) & 0x09249249u;
  };
  return spread(uint32_t(q[0])) << 2 | spread(uint32_t(q[1])) << 1 | spread(uint32_t(q[2]));
}

}  // namespace

namespace bvh_detail {

// The clustered build's first phase (as the bottom of an HLBVH, Pantaleoni & Luebke 2010):
// the references sorted by the Morton code of their centroid (30 bits, LSD radix sort, stable
// so equal codes keep input order), then cut top-down at the highest differing code bit (by
// count where all codes are equal) into runs of at most one leaf block of triangles. Each run
// becomes one reference (its triangles' box, weight = its triangle count) for the binned SAH,
// which then bins ~3x fewer references per level and never splits a run: leaves are whole
// runs. Where triangles are small against their neighbourhood (tessellated surfaces) a run
// is what the SAH's bottom levels would have made anyway.
void Builder::make_clusters() {
  const uint32_t n = static_cast<uint32_t>(n_refs_);
  const uint32_t C = kClusterSize;
  // Cubic cells (one scale for all axes): a flat scene's thin axis must not get as many cells
  // as its long ones, or its noise would order the curve.
  const float ext = max_component(root_cbounds_.extent());
  const float inv = ext > 0.0f && std::isfinite(ext) ? 1024.0f / ext : 0.0f;
  const V4 lo = V4::set(root_cbounds_.lo.x, root_cbounds_.lo.y, root_cbounds_.lo.z);
  const V4 scale = V4::set1(inv), top = V4::set1(1023.0f);
  // Keys: code << 32 | input position; sorted on bits 32-61, 10 at a time.
  auto keys = raw_array<uint64_t>(n), tmp = raw_array<uint64_t>(n);
  const int chunks = chunk_count(n, 0);
  std::vector<std::array<std::array<uint32_t, 1024>, 3>> part(chunks);
  run_chunks(chunks, [&](int c) {
    auto& h = part[c];
    for (auto& row : h) row.fill(0);
    const uint32_t b = chunk_start(n, c, chunks), e = chunk_start(n, c + 1, chunks);
    alignas(16) int q[4];
    for (uint32_t i = b; i < e; ++i) {
      refs_[i].centroid().bins(lo, scale, top, q);  // clamped to the grid, NaN -> 0
      const uint32_t code = morton3(q);
      keys[i] = uint64_t(code) << 32 | i;
      h[0][code & 1023]++;
    }
  });
  // Each pass scatters on all threads: chunk c of the current order writes its keys of digit
  // k from the keys of digits below k (all chunks) plus those of digit k in chunks before c,
  // so the sort stays stable and its result the same on any thread count. Pass 0's chunk
  // histograms come from the code pass above; the later ones are counted over the new order.
  for (int p = 0; p < 3; ++p) {
    if (cancelled()) return;
    const int shift = 32 + 10 * p;
    if (p > 0)
      run_chunks(chunks, [&](int c) {
        auto& h = part[c][p];
        h.fill(0);
        const uint32_t b = chunk_start(n, c, chunks), e = chunk_start(n, c + 1, chunks);
        for (uint32_t i = b; i < e; ++i) h[(keys[i] >> shift) & 1023]++;
      });
    uint32_t sum = 0;
    for (int k = 0; k < 1024; ++k)
      for (int c = 0; c < chunks; ++c) {
        const uint32_t cnt = part[c][p][k];
        part[c][p][k] = sum;  // now chunk c's first slot for digit k
        sum += cnt;
      }
    run_chunks(chunks, [&](int c) {
      auto& off = part[c][p];
      const uint32_t b = chunk_start(n, c, chunks), e = chunk_start(n, c + 1, chunks);
      for (uint32_t i = b; i < e; ++i) {
        const uint64_t k = keys[i];
        tmp[off[(k >> shift) & 1023]++] = k;
      }
    });
    std::swap(keys, tmp);
  }
  if (cancelled()) return;
  // Runs, in order: cut [b, e) at its highest differing code bit until it fits one block.
  // A range's cuts depend on that range alone, so the top ranges are cut here, breadth-first
  // and kept in order, until there are enough to share out; each is then cut down to runs on
  // whichever thread takes it, and the runs are joined in order: the same runs on any thread
  // count.
  const uint64_t* k = keys.get();
  const auto cut = [k](uint32_t b, uint32_t e) {
    const uint32_t c0 = uint32_t(k[b] >> 32), c1 = uint32_t(k[e - 1] >> 32);
    if (c0 == c1) return b + (e - b) / 2;
    const uint32_t bit = 31u - uint32_t(__builtin_clz(c0 ^ c1));
    return uint32_t(std::partition_point(k + b, k + e, [bit](uint64_t x) { return !((x >> (32 + bit)) & 1); }) - k);
  };
  using Range = std::pair<uint32_t, uint32_t>;
  std::vector<Range> tops{{0u, n}};
  const size_t want = hw_ > 1 && n >= kParallelMin ? 16 * size_t(hw_) : 1;
  for (bool again = true; again && tops.size() < want;) {
    again = false;
    std::vector<Range> next;
    for (const auto& [b, e] : tops) {
      if (e - b <= C) {
        next.push_back({b, e});
        continue;
      }
      const uint32_t mid = cut(b, e);
      next.push_back({b, mid});
      next.push_back({mid, e});
      again = true;
    }
    tops.swap(next);
  }
  std::vector<std::vector<uint32_t>> runs(tops.size());
  std::atomic<size_t> next_range{0};
  run_chunks(tops.size() > 1 ? hw_ : 1, [&](int) {
    std::vector<Range> stack;
    for (size_t r; (r = next_range.fetch_add(1)) < tops.size();) {
      std::vector<uint32_t>& out = runs[r];
      out.reserve((tops[r].second - tops[r].first) / 2 + 1);
      stack.assign(1, tops[r]);
      while (!stack.empty()) {
        const auto [b, e] = stack.back();
        stack.pop_back();
        if (e - b <= C) {
          out.push_back(b);
          continue;
        }
        const uint32_t mid = cut(b, e);
        stack.push_back({mid, e});
        stack.push_back({b, mid});
      }
    }
  });
  std::vector<uint32_t> first;
  size_t total = 1;
  for (const auto& r : runs) total += r.size();
  first.reserve(total);
  for (const auto& r : runs) first.insert(first.end(), r.begin(), r.end());
  const uint32_t m = static_cast<uint32_t>(first.size());
  first.push_back(n);
  if (cancelled()) return;
  // One reference per run; the triangles' references copied in sorted order, so a run's
  // members are read back as one contiguous piece.
  auto crefs = raw_array<PrimRef>(m);
  auto sorted = raw_array<PrimRef>(n);
  const int cchunks = chunk_count(m, 0);
  std::vector<BoxAcc> cb(cchunks);
  run_chunks(cchunks, [&](int c) {
    const uint32_t b = chunk_start(m, c, cchunks), e = chunk_start(m, c + 1, cchunks);
    BoxAcc cbox;  // stored once (as the root's boxes above)
    for (uint32_t k = b; k < e; ++k) {
      BoxAcc box;
      for (uint32_t j = first[k]; j < first[k + 1]; ++j) {
        const PrimRef& r = refs_[uint32_t(keys[j])];
        box.grow(r.vlo(), r.vhi());
        sorted[j] = r;
      }
      PrimRef& cr = crefs[k];
      box.lo.store(&cr.lo.x);  // lane 3 lands on id, set next
      box.hi.store(&cr.hi.x);
      cr.id = k;
      cr.bins = (first[k + 1] - first[k]) << 24;
      const V4 ct = cr.centroid();
      cbox.grow(ct, ct);
    }
    cb[c] = cbox;
  });
  for (int c = 1; c < cchunks; ++c) cb[0].grow(cb[c]);
  root_cbounds_ = cb[0].aabb();
  cluster_first_ = std::move(first);
  tri_refs_ = std::move(sorted);
  refs_ = std::move(crefs);
  n_refs_ = cap_ = m;
  clusters_ = m;
  clustered_ = true;
  pending_max_ = kClusterLeafMax;
}

// After the SAH over the runs: the leaves (runs of runs) get their triangles, in leaf order,
// and each leaf of more than one block is built on by the same binned SAH over its
// triangles, so the SAH still shapes the tree's bottom levels. Returns false when cancelled.
bool Builder::refine_clusters() {
  const size_t m = n_refs_;
  std::vector<uint32_t> start(m + 1);
  uint32_t sum = 0;
  for (size_t i = 0; i < m; ++i) {
    start[i] = sum;
    sum += refs_[i].weight();
  }
  start[m] = sum;
  auto xrefs = raw_array<PrimRef>(sum);
  parallel_ranges(m, opt_.threads, [&](size_t lo, size_t hi) {
    for (size_t i = lo; i < hi; ++i) {
      const uint32_t c = refs_[i].id;
      std::memcpy(static_cast<void*>(&xrefs[start[i]]), &tri_refs_[cluster_first_[c]],
                  size_t(cluster_first_[c + 1] - cluster_first_[c]) * sizeof(PrimRef));
    }
  }, 8192);
  // Leaves in tree order with their depth, renumbered to triangle ranges.
  struct Leaf {
    uint32_t node, depth;
  };
  std::vector<Leaf> leaves;
  std::vector<Leaf> stack{{0, 0}};
  uint32_t first_free = 1;  // past the first phase's nodes
  while (!stack.empty()) {
    const Leaf it = stack.back();
    stack.pop_back();
    first_free = std::max(first_free, it.node + 1);
    BvhNode& nd = node_store_[it.node];
    if (nd.is_leaf()) {
      const uint32_t f = nd.left_or_first;
      nd.left_or_first = start[f];
      nd.count = start[f + nd.count] - start[f];
      if (nd.count > 1) leaves.push_back(it);  // build() makes one-block leaves at once
    } else {
      stack.push_back({nd.left_or_first + 1, it.depth + 1});
      stack.push_back({nd.left_or_first, it.depth + 1});
    }
  }
  // Node pools after the first phase's nodes: a leaf of t triangles gets 2t - 2 slots, in
  // leaf order. Each thread's range of leaves bumps one counter from its first leaf's pool
  // on, so its nodes are dense, one gap per thread (pools per leaf would leave a gap after
  // every leaf, and their pages would all be touched). On one thread: no gap at all.
  std::vector<uint32_t> pool(leaves.size());
  uint32_t sum_pools = first_free;
  for (size_t k = 0; k < leaves.size(); ++k) {
    pool[k] = sum_pools;
    sum_pools += 2 * node_store_[leaves[k].node].count - 2;
  }
  refs_ = std::move(xrefs);
  n_refs_ = cap_ = sum;
  pending_max_ = 0;
  tri_refs_.reset();
  std::vector<uint32_t>().swap(cluster_first_);
  std::atomic<int> deepest{int(max_depth_)};
  std::atomic<size_t> added{0};
  parallel_ranges(leaves.size(), opt_.threads, [&](size_t lo, size_t hi) {
    int d = 0;
    size_t nodes = 0;
    uint32_t next = lo < hi ? pool[lo] : 0;
    for (size_t k = lo; k < hi && !cancelled(); ++k) {
      const BvhNode nd = node_store_[leaves[k].node];
      Aabb bounds, cbounds;
      range_bounds(nd.left_or_first, nd.left_or_first + nd.count, bounds, cbounds);
      const Built b = build(leaves[k].node, nd.left_or_first, nd.left_or_first + nd.count,
                            nd.left_or_first + nd.count, int(leaves[k].depth), bounds, cbounds, nd.count, next);
      d = std::max(d, b.depth);
      nodes += b.nodes - 1;  // the leaf itself is counted already
    }
    added.fetch_add(nodes);
    int cur = deepest.load();
    while (d > cur && !deepest.compare_exchange_weak(cur, d)) {
    }
  }, 2048);
  max_depth_ = size_t(deepest.load());
  n_nodes_ += added.load();
  return !cancelled();
}

}  // namespace bvh_detail
}  // namespace pl
