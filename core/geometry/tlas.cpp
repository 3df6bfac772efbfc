#include "geometry/tlas.h"

#include <algorithm>
#include <chrono>

#include "geometry/bvh_common.h"

namespace pl {
namespace {

constexpr int kBins = 16;
constexpr uint32_t kMaxLeaf = 2;
constexpr int kStackSize = 64;

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
    if (n > kMaxLeaf && depth < kStackSize - 8) {
      const int axis = max_axis(cb.extent());
      const float lo = cb.lo[axis], ext = cb.extent()[axis];
      if (ext > 0.0f) {
        // Binned SAH (Wald 2007) on the centroids.
        Aabb bin_box[kBins];
        uint32_t bin_n[kBins] = {};
        const float k = kBins * (1.0f - 1e-6f) / ext;
        auto bin_of = [&](uint32_t r) { return std::min(kBins - 1, int((centers[r][axis] - lo) * k)); };
        for (uint32_t i = begin; i < end; ++i) {
          const int bi = bin_of(refs[i]);
          bin_box[bi].grow(boxes[refs[i]]);
          ++bin_n[bi];
        }
        float right_cost[kBins] = {};
        Aabb acc;
        uint32_t cnt = 0;
        for (int i = kBins - 1; i > 0; --i) {
          acc.grow(bin_box[i]);
          cnt += bin_n[i];
          right_cost[i] = acc.half_area() * float(cnt);
        }
        acc = Aabb();
        cnt = 0;
        float best = kInf;
        int split = -1;
        for (int i = 0; i < kBins - 1; ++i) {
          acc.grow(bin_box[i]);
          cnt += bin_n[i];
          const float c = acc.half_area() * float(cnt) + right_cost[i + 1];
          if (cnt > 0 && cnt < n && c < best) {
            best = c;
            split = i;
          }
        }
        if (split >= 0)
          mid = uint32_t(std::partition(refs.begin() + begin, refs.begin() + end,
                                        [&](uint32_t r) { return bin_of(r) <= split; }) -
                         refs.begin());
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

}  // namespace

void Tlas::clear() {
  // Released, not just emptied: memory_bytes() reports capacity.
  nodes_ = {};
  refs_ = {};
  insts_ = {};
  bounds_ = Aabb();
  stats_ = TlasStats();
}

void Tlas::build(std::vector<TlasInstance> instances) {
  const auto start = std::chrono::steady_clock::now();
  clear();
  insts_ = std::move(instances);
  std::vector<Aabb> boxes(insts_.size());
  Builder b{nodes_, refs_, boxes, std::vector<Vec3>(insts_.size())};
  for (uint32_t i = 0; i < insts_.size(); ++i) {
    const TlasInstance& in = insts_[i];
    if (!in.blas || in.blas->empty()) continue;
    boxes[i] = in.identity ? in.blas->bounds() : world_box(in.blas->bounds(), in.to_world);
    if (boxes[i].empty() || !is_finite(boxes[i].lo) || !is_finite(boxes[i].hi)) continue;
    b.centers[i] = boxes[i].center();
    refs_.push_back(i);
    bounds_.grow(boxes[i]);
  }
  if (!refs_.empty()) {
    nodes_.reserve(2 * refs_.size());
    nodes_.emplace_back();
    b.build(0, 0, uint32_t(refs_.size()), 0);
  }
  stats_.instances = refs_.size();
  stats_.nodes = nodes_.size();
  stats_.build_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
}

namespace {
// The one traversal of both queries: any_hit stops at the first hit.
template <bool AnyHit>
bool traverse(const std::vector<BvhNode>& nodes, const std::vector<uint32_t>& refs,
              const std::vector<TlasInstance>& insts, const Ray& ray, Hit& hit, TraversalCounters* counters) {
  if (nodes.empty()) return false;
  const Vec3 inv = bvh_detail::safe_inverse(ray.dir);
  float tmax = ray.tmax;
  bool found = false;
  uint32_t stack[kStackSize];
  int sp = 0;
  if (bvh_detail::intersect_node(nodes[0], ray.org, inv, tmax) == kInf) return false;
  uint32_t ni = 0;
  for (;;) {
    const BvhNode& n = nodes[ni];
    if (counters) counters->nodes++;
    if (n.is_leaf()) {
      for (uint32_t i = n.left_or_first, e = n.left_or_first + n.count; i < e; ++i) {
        const TlasInstance& in = insts[refs[i]];
        Ray r = ray;
        r.tmax = tmax;
        float dt = 0.0f;
        if (!in.identity) r = ray_to_object(in.to_object, r, dt);
        if (!(r.tmax > 0.0f)) continue;
        if (AnyHit) {
          if (in.blas->occluded(r)) return true;
          continue;
        }
        Hit h;
        if (in.blas->intersect(r, h, counters)) {
          hit = h;
          hit.t = h.t + dt;
          hit.inst = refs[i];
          tmax = hit.t;
          found = true;
        }
      }
    } else {
      const BvhNode& a = nodes[n.left_or_first];
      const BvhNode& c = nodes[n.left_or_first + 1];
      const float ta = bvh_detail::intersect_node(a, ray.org, inv, tmax);
      const float tc = bvh_detail::intersect_node(c, ray.org, inv, tmax);
      if (ta != kInf && tc != kInf) {
        const bool a_first = ta <= tc;
        ni = a_first ? n.left_or_first : n.left_or_first + 1;
        stack[sp++] = a_first ? n.left_or_first + 1 : n.left_or_first;
        continue;
      }
      if (ta != kInf) {
        ni = n.left_or_first;
        continue;
      }
      if (tc != kInf) {
        ni = n.left_or_first + 1;
        continue;
      }
    }
    if (sp == 0) break;
    ni = stack[--sp];
  }
  return found;
}
}  // namespace

bool Tlas::intersect(const Ray& ray, Hit& hit, TraversalCounters* counters) const {
  return traverse<false>(nodes_, refs_, insts_, ray, hit, counters);
}

bool Tlas::occluded(const Ray& ray) const {
  Hit unused;
  return traverse<true>(nodes_, refs_, insts_, ray, unused, nullptr);
}

}  // namespace pl
