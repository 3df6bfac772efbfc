#include "scene/light_tree.h"

#include <algorithm>
#include <cmath>

namespace pl {

namespace {

float safe_sqrt(float x) { return std::sqrt(std::max(0.0f, x)); }
float safe_acos(float x) { return std::acos(std::clamp(x, -1.0f, 1.0f)); }

// cos(max(0, a - b)) and sin(max(0, a - b)) from the sines and cosines of angles a, b in [0, pi].
float cos_sub_clamped(float sin_a, float cos_a, float sin_b, float cos_b) {
  if (cos_a > cos_b) return 1.0f;  // a < b
  return cos_a * cos_b + sin_a * sin_b;
}
float sin_sub_clamped(float sin_a, float cos_a, float sin_b, float cos_b) {
  if (cos_a > cos_b) return 0.0f;
  return sin_a * cos_b - cos_a * sin_b;
}

// v rotated by angle theta about the unit axis k (Rodrigues).
Vec3 rotate(Vec3 v, Vec3 k, float theta) {
  const float c = std::cos(theta), s = std::sin(theta);
  return v * c + cross(k, v) * s + k * (dot(k, v) * (1.0f - c));
}

// The cost of a node with bounds b (pbrt-v4's EvaluateCost: power times the solid angle its
// cone can emit into, times its surface area, stretched along thin axes by kr).
float split_cost(const LightBounds& b, const Aabb& node, int axis) {
  const float theta_o = safe_acos(b.cos_theta_o), theta_e = safe_acos(b.cos_theta_e);
  const float theta_w = std::min(theta_o + theta_e, kPi);
  const float sin_o = safe_sqrt(1.0f - b.cos_theta_o * b.cos_theta_o);
  const float m_omega = 2.0f * kPi * (1.0f - b.cos_theta_o) +
                        0.5f * kPi * (2.0f * theta_w * sin_o - std::cos(theta_o - 2.0f * theta_w) -
                                      2.0f * theta_o * sin_o + b.cos_theta_o);
  const Vec3 d = node.extent();
  const float kr = d[axis] > 0.0f ? max_component(d) / d[axis] : 1.0f;
  const Vec3 e = b.bounds.extent();
  const float area = 2.0f * (e.x * e.y + e.y * e.z + e.z * e.x);
  return b.phi * m_omega * kr * area;
}

// cos(angle(w, b.w) + theta_o(b)), or -1 past pi: the cone about w that holds b's cone has at
// least this angle (no trigonometry: cos(a + b) from the sines and cosines).
float cone_cos_about(Vec3 w, const LightBounds& b) {
  const float c = std::clamp(dot(w, b.w), -1.0f, 1.0f);
  if (c < -b.cos_theta_o) return -1.0f;  // a + theta_o > pi
  return std::max(-1.0f, c * b.cos_theta_o - safe_sqrt(1.0f - c * c) * safe_sqrt(1.0f - b.cos_theta_o * b.cos_theta_o));
}

// Bounds of many items at once (the build's buckets, by slot): positions and powers summed, the
// cone about their power-weighted mean axis (wider than the smallest cone, but two trig-free
// passes instead of a cone union with five transcendental calls per item).
template <typename Slot>
void accumulate_bounds(const std::vector<std::pair<LightBounds, uint32_t>>& items, size_t begin, size_t end,
                       const Slot& slot, LightBounds* out, int slots) {
  std::vector<Vec3> axis(size_t(slots), Vec3(0.0f));
  for (int k = 0; k < slots; ++k) out[k] = LightBounds();
  for (size_t i = begin; i < end; ++i) {
    const LightBounds& b = items[i].first;
    const int k = slot(b);
    LightBounds& o = out[k];
    o.bounds.grow(b.bounds);
    o.phi += b.phi;
    o.moment += b.moment;
    o.cos_theta_e = o.phi == b.phi ? b.cos_theta_e : std::min(o.cos_theta_e, b.cos_theta_e);
    o.two_sided = o.two_sided || b.two_sided;
    axis[size_t(k)] += b.w * b.phi;
  }
  for (int k = 0; k < slots; ++k) {
    const float l2 = length_sq(axis[size_t(k)]);
    out[k].w = l2 > 0.0f ? axis[size_t(k)] / std::sqrt(l2) : Vec3(0.0f, 0.0f, 1.0f);
    out[k].cos_theta_o = l2 > 0.0f ? 1.0f : -1.0f;
  }
  for (size_t i = begin; i < end; ++i) {
    const LightBounds& b = items[i].first;
    LightBounds& o = out[slot(b)];
    o.cos_theta_o = std::min(o.cos_theta_o, cone_cos_about(o.w, b));
  }
  // Rounding must not shrink a cone below its items': widened by a hair.
  for (int k = 0; k < slots; ++k)
    if (out[k].cos_theta_o > -1.0f)
      out[k].cos_theta_o = std::cos(std::min(safe_acos(out[k].cos_theta_o) * 1.0001f + 1e-5f, kPi));
}

}  // namespace

LightBounds light_bounds_union(const LightBounds& a, const LightBounds& b) {
  if (!(a.phi > 0.0f)) return b;
  if (!(b.phi > 0.0f)) return a;
  LightBounds r;
  r.bounds = a.bounds;
  r.bounds.grow(b.bounds);
  r.phi = a.phi + b.phi;
  r.moment = a.moment + b.moment;
  r.cos_theta_e = std::min(a.cos_theta_e, b.cos_theta_e);
  r.two_sided = a.two_sided || b.two_sided;
  // The cone around both cones.
  const float theta_a = safe_acos(a.cos_theta_o), theta_b = safe_acos(b.cos_theta_o);
  const float theta_d = safe_acos(dot(a.w, b.w));
  if (std::min(theta_d + theta_b, kPi) <= theta_a) {
    r.w = a.w;
    r.cos_theta_o = a.cos_theta_o;
    return r;
  }
  if (std::min(theta_d + theta_a, kPi) <= theta_b) {
    r.w = b.w;
    r.cos_theta_o = b.cos_theta_o;
    return r;
  }
  const float theta_o = 0.5f * (theta_a + theta_d + theta_b);
  const Vec3 k = cross(a.w, b.w);
  if (theta_o >= kPi || !(length_sq(k) > 0.0f)) {
    r.w = a.w;
    r.cos_theta_o = -1.0f;  // the whole sphere
    return r;
  }
  r.w = normalize(rotate(a.w, normalize(k), theta_o - theta_a));
  // Rounding must not shrink the cone below either input: widened by a hair.
  r.cos_theta_o = std::cos(std::min(theta_o * 1.0001f + 1e-5f, kPi));
  return r;
}

LightTree::Node LightTree::make_node(const LightBounds& b, uint32_t idx, int leaf) {
  Node n;
  const Vec3 diag = b.bounds.extent();
  n.center = b.bounds.center();
  n.radius = float(0.5 * std::sqrt(double(diag.x) * diag.x + double(diag.y) * diag.y + double(diag.z) * diag.z));
  if (b.phi > 0.0f) {
    // Centred on the power's centroid (where the distance and the receiver's cosine are taken:
    // a cluster's lights are rarely spread evenly over its box), the sphere grown to still
    // hold the box.
    Vec3 c = b.moment / b.phi;
    c = vmin(vmax(c, b.bounds.lo), b.bounds.hi);
    n.radius = (n.radius + length(c - n.center)) * 1.0001f;
    n.center = c;
  }
  n.w = b.w;
  n.phi = b.phi;
  n.cos_theta_o = b.cos_theta_o;
  n.sin_theta_o = safe_sqrt(1.0f - b.cos_theta_o * b.cos_theta_o);
  n.cos_theta_e = b.cos_theta_e;
  n.index = idx;
  n.leaf = uint8_t(leaf);
  n.two_sided = b.two_sided;
  return n;
}

LightTree::LightTree(const std::vector<LightBounds>& items) {
  std::vector<std::pair<LightBounds, uint32_t>> work;
  trail_.assign(items.size(), 0);
  in_tree_.assign(items.size(), 0);
  for (size_t i = 0; i < items.size(); ++i) {
    const LightBounds& b = items[i];
    if (!(b.phi > 0.0f) || !std::isfinite(b.phi) || b.bounds.empty() || !is_finite(b.bounds.lo) ||
        !is_finite(b.bounds.hi))
      continue;
    work.emplace_back(b, uint32_t(i));
    work.back().first.moment = b.bounds.center() * b.phi;
    in_tree_[i] = 1;
  }
  if (work.empty()) return;
  nodes_.reserve(2 * work.size() - 1);
  items_.reserve(work.size());
  build(work, 0, work.size(), 0, 0);
}

uint32_t LightTree::build(std::vector<std::pair<LightBounds, uint32_t>>& items, size_t begin, size_t end,
                          uint64_t trail, int depth) {
  depth_ = std::max(depth_, depth);
  const uint32_t index = uint32_t(nodes_.size());
  nodes_.emplace_back();
  LightBounds all;
  Aabb centroids;
  if (end - begin == 1) {
    all = items[begin].first;
  } else {
    accumulate_bounds(items, begin, end, [](const LightBounds&) { return 0; }, &all, 1);
  }
  for (size_t i = begin; i < end; ++i) centroids.grow(items[i].first.bounds.center());
  const auto store = [&](const LightBounds& b, uint32_t idx, int leaf) { nodes_[index] = make_node(b, idx, leaf); };
  if (end - begin <= size_t(kLeafMax)) {
    const uint32_t first = uint32_t(items_.size());
    for (size_t i = begin; i < end; ++i) {
      trail_[items[i].second] = trail;
      items_.push_back(make_node(items[i].first, items[i].second, 1));
    }
    store(all, first, int(end - begin));
    return index;
  }
  // Binned split by pbrt-v4's cost over 12 buckets per axis; past depth 32 (only for
  // pathological inputs) a median split keeps every path within the 64 bits of a trail.
  constexpr int kBuckets = 12;
  size_t mid = begin + (end - begin) / 2;
  if (depth >= 32) {
    const int axis = max_axis(centroids.extent());
    std::nth_element(items.begin() + std::ptrdiff_t(begin), items.begin() + std::ptrdiff_t(mid),
                     items.begin() + std::ptrdiff_t(end), [&](const auto& a, const auto& b) {
                       return a.first.bounds.center()[axis] < b.first.bounds.center()[axis];
                     });
  } else {
    float best = kInf;
    int best_axis = -1, best_bucket = -1;
    const Vec3 cext = centroids.extent();
    for (int axis = 0; axis < 3; ++axis) {
      if (!(cext[axis] > 0.0f)) continue;
      LightBounds buckets[kBuckets];
      const auto bucket_of = [&](const LightBounds& b) {
        const int k = int(kBuckets * ((b.bounds.center()[axis] - centroids.lo[axis]) / cext[axis]));
        return std::clamp(k, 0, kBuckets - 1);
      };
      accumulate_bounds(items, begin, end, bucket_of, buckets, kBuckets);
      // Prefix and suffix unions: each split's two sides in 2 (kBuckets - 1) unions in all.
      LightBounds prefix[kBuckets], suffix[kBuckets];
      prefix[0] = buckets[0];
      suffix[kBuckets - 1] = buckets[kBuckets - 1];
      for (int k = 1; k < kBuckets; ++k) {
        prefix[k] = light_bounds_union(prefix[k - 1], buckets[k]);
        suffix[kBuckets - 1 - k] = light_bounds_union(suffix[kBuckets - k], buckets[kBuckets - 1 - k]);
      }
      for (int s = 0; s + 1 < kBuckets; ++s) {
        const LightBounds &below = prefix[s], &above = suffix[s + 1];
        if (!(below.phi > 0.0f) || !(above.phi > 0.0f)) continue;
        const float cost = split_cost(below, all.bounds, axis) + split_cost(above, all.bounds, axis);
        if (cost < best) {
          best = cost;
          best_axis = axis;
          best_bucket = s;
        }
      }
    }
    if (best_axis >= 0) {
      const auto it = std::stable_partition(items.begin() + std::ptrdiff_t(begin), items.begin() + std::ptrdiff_t(end),
                                            [&](const std::pair<LightBounds, uint32_t>& e) {
                                              const int k = int(kBuckets * ((e.first.bounds.center()[best_axis] -
                                                                             centroids.lo[best_axis]) /
                                                                            cext[best_axis]));
                                              return std::clamp(k, 0, kBuckets - 1) <= best_bucket;
                                            });
      const size_t m = size_t(it - items.begin());
      if (m > begin && m < end) mid = m;
    }
  }
  build(items, begin, mid, trail, depth + 1);
  const uint32_t second = build(items, mid, end, trail | (uint64_t(1) << depth), depth + 1);
  store(all, second, false);
  return index;
}

[[gnu::noinline]] double LightTree::importance(const Node& node, Vec3 p, Vec3 n) const {
  // pbrt-v4's LightBounds::Importance: power over distance squared (floored by the node's size),
  // times the cosine bounds at the light (its cone against the directions to p) and at p.
  // Distances in double: squares of far-apart float points overflow (a node's importance 0
  // would hide every light below it).
  const double dx = double(p.x) - node.center.x, dy = double(p.y) - node.center.y, dz = double(p.z) - node.center.z;
  const double dc2 = dx * dx + dy * dy + dz * dz;
  const double d2 = std::max(dc2, double(node.radius));  // pbrt-v4's floor: half the diagonal
  Vec3 wi = node.w;
  if (dc2 > 0.0) {
    const double inv = 1.0 / std::sqrt(dc2);
    wi = Vec3(float(dx * inv), float(dy * inv), float(dz * inv));
  }
  float cos_w = dot(node.w, wi);
  if (node.two_sided) cos_w = std::fabs(cos_w);
  const float sin_w = safe_sqrt(1.0f - cos_w * cos_w);
  // The cone of directions from p that the node's bounding sphere subtends.
  float cos_b = -1.0f, sin_b = 0.0f;
  const double r2 = double(node.radius) * node.radius;
  if (dc2 > r2) {
    const double s2 = r2 / dc2;
    cos_b = float(std::sqrt(1.0 - s2));
    sin_b = float(std::sqrt(s2));
  }
  const float sin_o = node.sin_theta_o;
  const float cos_x = cos_sub_clamped(sin_w, cos_w, sin_o, node.cos_theta_o);
  const float sin_x = sin_sub_clamped(sin_w, cos_w, sin_o, node.cos_theta_o);
  const float cos_p = cos_sub_clamped(sin_x, cos_x, sin_b, cos_b);
  if (cos_p <= node.cos_theta_e) return 0.0;
  // In double and capped: a light almost at p must not overflow (inf / inf is NaN).
  double imp = double(node.phi) * double(cos_p) / std::max(d2, 1e-30);
  if (n.x != 0.0f || n.y != 0.0f || n.z != 0.0f) {
    const float cos_i = std::fabs(dot(wi, n));
    const float sin_i = safe_sqrt(1.0f - cos_i * cos_i);
    // The receiver's cosine towards the power's centroid rather than its bound over the whole
    // sphere (which is near 1 for any node that is large as seen from p, and overweighted far
    // clusters at grazing angles 2x), kept within [0.1, 1] x the bound: 0 only where no light
    // of the node can reach p. Measured: per-sample variance 0.85 -> 0.64 on the lamp room.
    const float bound = cos_sub_clamped(sin_i, cos_i, sin_b, cos_b);
    imp *= double(std::clamp(cos_i, 0.1f * bound, bound));
  }
  return imp > 0.0 && std::isfinite(imp) ? imp : 0.0;
}

double LightTree::pick_in_leaf(const Node& leaf, Vec3 p, Vec3 n, float u, uint32_t& item) const {
  double imp[kLeafMax], sum = 0.0;
  for (int j = 0; j < leaf.leaf; ++j) sum += imp[j] = importance(items_[leaf.index + j], p, n);
  if (!(sum > 0.0)) return 0.0;
  const double target = double(u) * sum;
  double acc = 0.0;
  int last = -1;
  for (int j = 0; j < leaf.leaf; ++j) {
    if (!(imp[j] > 0.0)) continue;
    last = j;  // rounding: past the end, the last light that can be chosen
    acc += imp[j];
    if (target < acc) break;
  }
  item = items_[leaf.index + last].index;
  return imp[last] / sum;
}

double LightTree::pmf_in_leaf(const Node& leaf, Vec3 p, Vec3 n, uint32_t item) const {
  double sum = 0.0, own = 0.0;
  for (int j = 0; j < leaf.leaf; ++j) {
    const Node& e = items_[leaf.index + j];
    const double i = importance(e, p, n);
    sum += i;
    if (e.index == item) own = i;
  }
  return sum > 0.0 ? own / sum : 0.0;
}

bool LightTree::sample(Vec3 p, Vec3 n, float u, uint32_t& item, float& pmf) const {
  if (nodes_.empty()) return false;
  uint32_t i = 0;
  float prob = 1.0f;
  while (!nodes_[i].leaf) {
    const uint32_t c0 = i + 1, c1 = nodes_[i].index;
    const double i0 = importance(nodes_[c0], p, n), i1 = importance(nodes_[c1], p, n);
    const double sum = i0 + i1;
    if (!(sum > 0.0)) return false;
    const float p0 = float(i0 / sum), p1 = float(i1 / sum);
    if (u < p0) {
      prob *= p0;
      u = std::min(u / p0, 0x1.fffffep-1f);
      i = c0;
    } else {
      prob *= p1;
      u = std::min((u - p0) / p1, 0x1.fffffep-1f);
      i = c1;
    }
  }
  prob *= float(pick_in_leaf(nodes_[i], p, n, u, item));
  pmf = prob;
  return prob > 0.0f;
}

float LightTree::pmf(Vec3 p, Vec3 n, uint32_t item) const {
  if (item >= in_tree_.size() || !in_tree_[item]) return 0.0f;
  uint64_t trail = trail_[item];
  uint32_t i = 0;
  float prob = 1.0f;
  while (!nodes_[i].leaf) {
    const uint32_t c0 = i + 1, c1 = nodes_[i].index;
    const double i0 = importance(nodes_[c0], p, n), i1 = importance(nodes_[c1], p, n);
    const double sum = i0 + i1;
    if (!(sum > 0.0)) return 0.0f;
    if (trail & 1u) {
      prob *= float(i1 / sum);
      i = c1;
    } else {
      prob *= float(i0 / sum);
      i = c0;
    }
    trail >>= 1;
  }
  return prob * float(pmf_in_leaf(nodes_[i], p, n, item));
}

}  // namespace pl
