#include "render/guiding.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <tuple>

namespace pl {

namespace {

// One quadtree node: quadrant q = x + 2 y (x, y in {0, 1}) holds an energy and, unless it is
// a leaf (0), the index of the node that subdivides it. Children come after their parents.
struct QuadNode {
  float sum[4] = {0.0f, 0.0f, 0.0f, 0.0f};
  uint32_t child[4] = {0, 0, 0, 0};
  float total() const { return sum[0] + sum[1] + sum[2] + sum[3]; }
};

// The learnt distribution as sampling reads it: the share of the left half, of the lower
// quadrant in each half, and each quadrant's pdf factor (4 x its share), no divisions left.
struct SampleNode {
  float left = 0.5f;
  float lower[2] = {0.5f, 0.5f};
  float factor[4] = {1.0f, 1.0f, 1.0f, 1.0f};
  uint32_t child[4] = {0, 0, 0, 0};
};

constexpr float kOneMinus = 0x1.fffffep-1f;

// The quadrant of unit-square point s in a node, s rescaled into it.
inline int quadrant(Vec2& s) {
  const int qx = s.x >= 0.5f, qy = s.y >= 0.5f;
  s.x = std::min(s.x * 2.0f - float(qx), kOneMinus);
  s.y = std::min(s.y * 2.0f - float(qy), kOneMinus);
  return qx + 2 * qy;
}

std::vector<SampleNode> sampling_tree(const std::vector<QuadNode>& learnt) {
  std::vector<SampleNode> out(learnt.size());
  for (size_t i = 0; i < learnt.size(); ++i) {
    const QuadNode& n = learnt[i];
    SampleNode& o = out[i];
    const float total = n.total();
    if (!(total > 0.0f)) continue;  // uniform below here (a leaf)
    o.left = (n.sum[0] + n.sum[2]) / total;
    for (int x = 0; x < 2; ++x) {
      const float column = n.sum[x] + n.sum[x + 2];
      o.lower[x] = column > 0.0f ? n.sum[x] / column : 0.5f;
    }
    for (int q = 0; q < 4; ++q) {
      o.factor[q] = 4.0f * n.sum[q] / total;
      o.child[q] = n.sum[q] > 0.0f ? n.child[q] : 0;
    }
  }
  return out;
}

}  // namespace

struct GuidingField::Cell {
  std::vector<QuadNode> learnt;      // the last iteration's energies (empty: none yet)
  std::vector<SampleNode> sampling;  // the same, for sampling (empty: uniform)
  std::vector<QuadNode> building;  // the topology this iteration records into
  std::unique_ptr<std::atomic<uint64_t>[]> sums;  // 4 per building node, fixed point
  std::unique_ptr<std::atomic<uint64_t>[]> photon_sums;  // the same for photon records
  std::atomic<uint64_t> records{0}, photon_records{0};
  float probability = 0.5f;  // of a guided direction (learnt: set_learn_probability)
  std::atomic<uint64_t> moments[kProbabilities];  // per candidate probability, fixed point
  std::atomic<uint64_t> moment_records{0};

  void allocate_sums() {
    if (building.empty()) building.emplace_back();
    sums = std::make_unique<std::atomic<uint64_t>[]>(building.size() * 4);
    photon_sums = std::make_unique<std::atomic<uint64_t>[]>(building.size() * 4);
    for (size_t i = 0; i < building.size() * 4; ++i) {
      sums[i].store(0, std::memory_order_relaxed);
      photon_sums[i].store(0, std::memory_order_relaxed);
    }
    records.store(0, std::memory_order_relaxed);
    photon_records.store(0, std::memory_order_relaxed);
    for (auto& m : moments) m.store(0, std::memory_order_relaxed);
    moment_records.store(0, std::memory_order_relaxed);
  }
  // Adds fixed-point value q at unit-square point s of the building tree; box: spread over a
  // square of the size of s's leaf (the directional filter).
  void add(std::atomic<uint64_t>* to, Vec2 s, uint64_t q, bool box = false);
  void splat(std::atomic<uint64_t>* to, uint32_t n, Vec2 o, float size, const float b[4], double density);
  std::unique_ptr<Cell> copy() const {
    auto c = std::make_unique<Cell>();
    c->learnt = learnt;
    c->sampling = sampling;
    c->building = building;
    c->probability = probability;
    c->allocate_sums();
    return c;
  }
};

GuidingField::GuidingField() = default;
GuidingField::~GuidingField() = default;

Vec2 GuidingField::to_square(Vec3 w) {
  const float z = clampf(w.z, -1.0f, 1.0f);
  float phi = std::atan2(w.y, w.x) * (0.5f / kPi);
  if (phi < 0.0f) phi += 1.0f;
  return {std::min((z + 1.0f) * 0.5f, kOneMinus), std::min(std::max(phi, 0.0f), kOneMinus)};
}

Vec3 GuidingField::from_square(Vec2 s) {
  const float z = 2.0f * s.x - 1.0f;
  const float r = std::sqrt(std::max(0.0f, 1.0f - z * z));
  const float phi = 2.0f * kPi * s.y;
  return {r * std::cos(phi), r * std::sin(phi), z};
}

void GuidingField::reset(const Aabb& bounds, float split_threshold) {
  bounds_ = bounds;
  if (bounds_.empty()) bounds_ = {Vec3(-1.0f), Vec3(1.0f)};
  // A little margin, so that points on the bounds fall inside.
  const Vec3 e = vmax(bounds_.extent(), Vec3(1e-4f));
  bounds_.lo = bounds_.lo - e * 1e-3f;
  bounds_.hi = bounds_.hi + e * 1e-3f;
  const Vec3 ext = bounds_.extent();
  inv_extent_ = {1.0f / ext.x, 1.0f / ext.y, 1.0f / ext.z};
  split_threshold_ = split_threshold;
  scale_ = 65536.0;
  iterations_ = 0;
  photon_records_ = 0;
  photon_map_.clear();
  photon_map_new_ = 0;
  caustic_index_.clear();
  caustic_cells_.clear();
  caustic_lobes_.clear();
  nodes_.assign(1, SpatialNode{});
  cells_.clear();
  for (uint32_t k = 0; k < kNormalClasses; ++k) {
    cells_.push_back(std::make_unique<Cell>());
    cells_.back()->probability = initial_probability_;
    cells_.back()->allocate_sums();
  }
}

void GuidingField::set_learn_probability(bool on, float initial) {
  learn_probability_ = on;
  initial_probability_ = std::isfinite(initial) ? std::clamp(initial, 0.0f, 1.0f) : 0.5f;
  for (auto& c : cells_) c->probability = initial_probability_;
}

float GuidingField::probability(uint32_t cell) const { return cells_[cell]->probability; }

void GuidingField::record_moment(uint32_t cell, float est, float q, float pb, float pg) {
  if (!learn_probability_ || cell >= cells_.size()) return;
  Cell& c = *cells_[cell];
  c.moment_records.fetch_add(1, std::memory_order_relaxed);  // estimates of 0 count too
  if (!(est > 0.0f) || !std::isfinite(est) || !(q > 0.0f) || !std::isfinite(q)) return;
  // In the records' fixed point squared over 2^20 (a mean record's estimate squared: ~2^20),
  // at most 2^40 per candidate and record.
  constexpr double kCap = 1099511627776.0;
  const double e = double(est) * scale_;
  const double base = e * e * (1.0 / 1048576.0) * double(q);
  for (int k = 0; k < kProbabilities; ++k) {
    const double a = 0.1 * k;
    const double qk = a * double(pg) + (1.0 - a) * double(pb);
    const double v = qk > 0.0 ? std::min(base / qk, kCap) : kCap;  // (a direction this mixture never draws)
    c.moments[k].fetch_add(uint64_t(v + 0.5), std::memory_order_relaxed);
  }
}

uint8_t GuidingField::normal_class(Vec3 nrm) {
  const Vec3 a{std::fabs(nrm.x), std::fabs(nrm.y), std::fabs(nrm.z)};
  const int axis = a.x >= a.y && a.x >= a.z ? 0 : a.y >= a.z ? 1 : 2;
  const float along = axis == 0 ? nrm.x : axis == 1 ? nrm.y : nrm.z;
  return uint8_t(2 * axis + (along < 0.0f ? 1 : 0));
}

uint32_t GuidingField::leaf_of(Vec3 p) const {
  const Vec3 x = (p - bounds_.lo) * inv_extent_;
  float c[3] = {clampf(x.x, 0.0f, kOneMinus), clampf(x.y, 0.0f, kOneMinus), clampf(x.z, 0.0f, kOneMinus)};
  if (!(c[0] == c[0]) || !(c[1] == c[1]) || !(c[2] == c[2])) c[0] = c[1] = c[2] = 0.0f;  // NaN
  const SpatialNode* n = &nodes_[0];
  while (n->child != 0) {
    float& v = c[n->axis];
    const bool side = v >= 0.5f;
    v = std::min(v * 2.0f - float(side), kOneMinus);
    n = &nodes_[n->child + uint32_t(side)];
  }
  return n->cell;
}

uint32_t GuidingField::cell_of(Vec3 p, Vec3 nrm) const { return leaf_of(p) + normal_class(nrm); }

void GuidingField::keep_photons(std::vector<PhotonRecord>& records) {
  if (records.empty()) return;
  std::lock_guard<std::mutex> lk(photon_mutex_);
  photon_map_.insert(photon_map_.end(), records.begin(), records.end());
  records.clear();
}

Vec3 GuidingField::sample(uint32_t cell, Vec2 u, float& pdf) const {
  const std::vector<SampleNode>& t = cells_[cell]->sampling;
  float square_pdf = 1.0f;
  Vec2 origin{0.0f, 0.0f};
  float size = 1.0f;
  uint32_t n = 0;
  for (int depth = 0; !t.empty() && depth < kMaxQuadDepth; ++depth) {
    const SampleNode& nd = t[n];
    // Left or right half by u.x, then the quadrant in it by u.y, each rescaled for the next.
    int qx = 0;
    if (u.x < nd.left) {
      u.x /= nd.left;
    } else {
      qx = 1;
      u.x = (u.x - nd.left) / (1.0f - nd.left);
    }
    const float lower = nd.lower[qx];
    int qy = 0;
    if (u.y < lower) {
      u.y /= lower;
    } else {
      qy = 1;
      u.y = (u.y - lower) / (1.0f - lower);
    }
    u = {std::min(std::max(u.x, 0.0f), kOneMinus), std::min(std::max(u.y, 0.0f), kOneMinus)};
    const int q = qx + 2 * qy;
    square_pdf *= nd.factor[q];
    size *= 0.5f;
    origin = {origin.x + float(qx) * size, origin.y + float(qy) * size};
    if (nd.child[q] == 0) break;
    n = nd.child[q];
  }
  pdf = square_pdf * (0.25f / kPi);
  return from_square({origin.x + u.x * size, origin.y + u.y * size});
}

float GuidingField::pdf(uint32_t cell, Vec3 w) const {
  const std::vector<SampleNode>& t = cells_[cell]->sampling;
  Vec2 s = to_square(w);
  float square_pdf = 1.0f;
  uint32_t n = 0;
  for (int depth = 0; !t.empty() && depth < kMaxQuadDepth; ++depth) {
    const SampleNode& nd = t[n];
    const int q = quadrant(s);
    square_pdf *= nd.factor[q];
    if (nd.child[q] == 0) break;
    n = nd.child[q];
  }
  return square_pdf * (0.25f / kPi);
}

void GuidingField::Cell::splat(std::atomic<uint64_t>* to, uint32_t n, Vec2 o, float size, const float b[4],
                               double density) {
  const float h = 0.5f * size;
  for (int k = 0; k < 4; ++k) {
    const float x0 = o.x + float(k & 1) * h, y0 = o.y + float(k >> 1) * h;
    const float w = std::min(b[1], x0 + h) - std::max(b[0], x0), d = std::min(b[3], y0 + h) - std::max(b[2], y0);
    if (!(w > 0.0f) || !(d > 0.0f)) continue;
    const uint32_t child = building[n].child[k];
    if (child == 0) {
      const uint64_t v = uint64_t(density * double(w) * double(d) + 0.5);
      if (v != 0) to[4 * size_t(n) + size_t(k)].fetch_add(v, std::memory_order_relaxed);
    } else {
      splat(to, child, {x0, y0}, h, b, density);
    }
  }
}

void GuidingField::Cell::add(std::atomic<uint64_t>* to, Vec2 s, uint64_t q, bool box) {
  if (box) {
    // The leaf's size at s, then a square of that size about s: x (cos theta) clipped, y (phi)
    // wrapping round in up to two pieces; the value spread by area over the clipped square.
    float size = 1.0f;
    Vec2 t = s;
    for (uint32_t n = 0;;) {
      const int k = quadrant(t);
      size *= 0.5f;
      if (building[n].child[k] == 0) break;
      n = building[n].child[k];
    }
    const float x0 = std::max(0.0f, s.x - 0.5f * size), x1 = std::min(1.0f, s.x + 0.5f * size);
    const float y0 = s.y - 0.5f * size, y1 = s.y + 0.5f * size;
    if (x1 > x0) {
      const double density = double(q) / (double(x1 - x0) * double(size));
      if (y0 < 0.0f) {
        const float a[4] = {x0, x1, y0 + 1.0f, 1.0f}, b[4] = {x0, x1, 0.0f, y1};
        splat(to, 0, {0.0f, 0.0f}, 1.0f, a, density);
        splat(to, 0, {0.0f, 0.0f}, 1.0f, b, density);
      } else if (y1 > 1.0f) {
        const float a[4] = {x0, x1, y0, 1.0f}, b[4] = {x0, x1, 0.0f, y1 - 1.0f};
        splat(to, 0, {0.0f, 0.0f}, 1.0f, a, density);
        splat(to, 0, {0.0f, 0.0f}, 1.0f, b, density);
      } else {
        const float a[4] = {x0, x1, y0, y1};
        splat(to, 0, {0.0f, 0.0f}, 1.0f, a, density);
      }
      return;
    }
  }
  uint32_t n = 0;
  for (;;) {
    const int k = quadrant(s);
    const uint32_t next = building[n].child[k];
    if (next == 0) {
      to[4 * size_t(n) + size_t(k)].fetch_add(q, std::memory_order_relaxed);
      return;
    }
    n = next;
  }
}

void GuidingField::record(uint32_t cell, Vec3 w, float value) {
  Cell& c = *cells_[cell];
  c.records.fetch_add(1, std::memory_order_relaxed);  // paths that found nothing count too
  if (!(value > 0.0f) || !std::isfinite(value) || !is_finite(w)) return;
  // Fixed point, at most 2^36 per record: 2^28 records of that size before a sum overflows.
  const double v = std::min(double(value) * scale_, 68719476736.0);
  const uint64_t q = uint64_t(v + 0.5);
  if (q == 0) return;
  c.add(c.sums.get(), to_square(w), q, filter_);
}

void GuidingField::record_photon(uint32_t cell, Vec3 w, float value) {
  if (cell >= cells_.size() || !(value > 0.0f) || !std::isfinite(value) || !is_finite(w)) return;
  Cell& c = *cells_[cell];
  c.photon_records.fetch_add(1, std::memory_order_relaxed);
  // Photons carry about 1 each (the mean emitted photon): a fixed scale of 2^20 per unit.
  const double v = std::min(double(value) * 1048576.0, 68719476736.0);
  const uint64_t q = uint64_t(v + 0.5);
  if (q == 0) return;
  c.add(c.photon_sums.get(), to_square(w), q, filter_);
}

namespace {

// The refined topology for the next iteration (Müller et al.): a quadrant splits where it holds
// more than kSubdivide of the whole energy, nodes below that merge into leaves. Energies are
// carried down (evenly where the learnt tree had no finer nodes); the new sums start at zero.
void refine(const std::vector<QuadNode>& learnt, std::vector<QuadNode>& out) {
  out.clear();
  out.emplace_back();
  const float total = learnt.empty() ? 0.0f : learnt[0].total();
  if (!(total > 0.0f)) return;
  struct Item {
    uint32_t dst;
    int32_t src;  // the learnt node (-1: none; uniform energy)
    float energy;  // the uniform energy of a src -1 node
    int depth;
  };
  std::vector<Item> stack{{0u, 0, 0.0f, 1}};
  while (!stack.empty()) {
    const Item it = stack.back();
    stack.pop_back();
    for (int q = 0; q < 4; ++q) {
      const float e = it.src >= 0 ? learnt[size_t(it.src)].sum[q] : it.energy * 0.25f;
      if (!(e > GuidingField::kSubdivide * total) || it.depth >= GuidingField::kMaxQuadDepth) continue;
      const uint32_t child = uint32_t(out.size());
      out[it.dst].child[q] = child;
      out.emplace_back();
      const int32_t src_child = it.src >= 0 && learnt[size_t(it.src)].child[q] != 0
                                    ? int32_t(learnt[size_t(it.src)].child[q]) : -1;
      stack.push_back({child, src_child, e, it.depth + 1});
    }
  }
}

}  // namespace

void GuidingField::end_iteration(int samples) {
  // 0. All kept photons, this iteration's and earlier ones', into the cells as they are now.
  for (const PhotonRecord& r : photon_map_) {
    if (!(r.value > 0.0f) || !std::isfinite(r.value) || !is_finite(r.p) || r.normal_class >= kNormalClasses) continue;
    Cell& c = *cells_[leaf_of(r.p) + r.normal_class];
    c.photon_records.fetch_add(1, std::memory_order_relaxed);
    const uint64_t q = uint64_t(std::min(double(r.value) * 1048576.0, 68719476736.0) + 0.5);
    if (q != 0) c.add(c.photon_sums.get(), r.s, q, filter_);
  }
  // Past the cap an iteration's photons count for it alone (all of them: the same set whatever
  // order the threads added them in).
  if (caustic_cube_ > 0.0f) build_caustic_lobes();
  if (photon_map_.size() > kMaxKeptPhotons) photon_map_.resize(photon_map_new_);
  photon_map_new_ = photon_map_.size();
  double all = 0.0, probability_sum = 0.0;
  uint64_t all_records = 0;
  // 1. What each cell recorded becomes its distribution (inner quadrants: their subtree's sum).
  for (auto& cp : cells_) {
    Cell& c = *cp;
    std::vector<QuadNode> learnt = c.building;
    // The leaves' fixed-point sums of camera and photon records, each as a share of its total.
    double cam_total = 0.0, photon_total = 0.0;
    for (size_t i = 0; i < learnt.size() * 4; ++i) {
      cam_total += double(c.sums[i].load());
      photon_total += double(c.photon_sums[i].load());
    }
    photon_records_ += c.photon_records.load();
    const double wp = photon_total > 0.0 ? (cam_total > 0.0 ? double(photon_share_) : 1.0) : 0.0;
    // (without photons: the camera sums as they were, in units of the recorded values)
    const double cam_w = wp == 0.0 ? 1.0 / scale_ : cam_total > 0.0 ? (1.0 - wp) / cam_total : 0.0;
    const double photon_w = photon_total > 0.0 ? wp / photon_total : 0.0;
    for (size_t i = 0; i < learnt.size(); ++i)
      for (int q = 0; q < 4; ++q) {
        const size_t k = 4 * i + size_t(q);
        learnt[i].sum[q] = float(double(c.sums[k].load()) * cam_w + double(c.photon_sums[k].load()) * photon_w);
      }
    for (size_t i = learnt.size(); i-- > 0;)
      for (int q = 0; q < 4; ++q)
        if (learnt[i].child[q] != 0) learnt[i].sum[q] = learnt[learnt[i].child[q]].total();
    if (learn_probability_ && c.moment_records.load() >= kMinMomentRecords) {
      // The candidate of least second moment (ties: the smaller probability, more to the BSDF).
      // Never above the initial probability: measured on the window room, cells learnt to
      // trust the guide (0.9) from records that missed the rare caustic paths, whose BSDF
      // samples then weighed 10x (docs/design/sampling.md, "Learnt guide probability").
      const int top = std::min(kProbabilities - 1, int(initial_probability_ * 10.0f + 1e-3f));
      int best = 0;
      for (int k = 1; k <= top; ++k)
        if (c.moments[k].load() < c.moments[best].load()) best = k;
      c.probability = 0.1f * float(best);
    }
    const float total = learnt[0].total();
    all += wp == 0.0 ? double(total) : cam_total / scale_;  // (the camera records' mean sets the fixed point)
    all_records += c.records.load();
    probability_sum += double(c.probability) * double(c.records.load());
    if (total > 0.0f && std::isfinite(total)) {
      c.learnt = std::move(learnt);
      c.sampling = sampling_tree(c.learnt);
      refine(c.learnt, c.building);
    }
    // (no records: the cell keeps what it had learnt before, and its topology)
  }
  // 2. Crowded cells split in two along x, y, z in turn, both halves starting from their
  // parent's tree; the record count halves per level (Müller et al.'s c sqrt(2^k) rule).
  const double threshold = double(split_threshold_) * std::sqrt(double(std::max(samples, 1)));
  const size_t n_nodes = nodes_.size();
  for (size_t i = 0; i < n_nodes; ++i) {
    if (nodes_[i].child != 0) continue;
    double count = 0.0;  // the records of all its orientations, camera and photon alike
    for (uint32_t k = 0; k < kNormalClasses; ++k)
      count += double(cells_[nodes_[i].cell + k]->records.load()) +
               double(photon_split_weight_) * double(cells_[nodes_[i].cell + k]->photon_records.load());
    std::vector<uint32_t> leaves{uint32_t(i)};
    while (count > threshold && nodes_[leaves[0]].depth < kMaxSpatialDepth &&
           cells_.size() + leaves.size() * kNormalClasses <= kMaxCells * kNormalClasses) {
      std::vector<uint32_t> next;
      for (const uint32_t leaf : leaves) {
        const uint32_t a = uint32_t(nodes_.size());
        SpatialNode left, right;
        left.depth = right.depth = uint8_t(nodes_[leaf].depth + 1);
        left.axis = right.axis = uint8_t(left.depth % 3);
        left.cell = nodes_[leaf].cell;
        right.cell = uint32_t(cells_.size());
        for (uint32_t k = 0; k < kNormalClasses; ++k) cells_.push_back(cells_[left.cell + k]->copy());
        nodes_.push_back(left);
        nodes_.push_back(right);
        nodes_[leaf].child = a;
        next.push_back(a);
        next.push_back(a + 1);
      }
      leaves = std::move(next);
      count *= 0.5;
    }
  }
  mean_probability_ = all_records > 0 ? float(probability_sum / double(all_records)) : initial_probability_;
  for (auto& c : cells_) c->allocate_sums();
  // 3. The next iteration's fixed point: its mean record near 2^20 units.
  if (all_records > 0 && all > 0.0 && std::isfinite(all)) {
    const double mean = all / double(all_records);
    scale_ = std::min(std::max(1048576.0 / mean, 1e-12), 1e24);
  }
  ++iterations_;
}

void GuidingField::set_caustic_lobes(float cube, float cone) {
  caustic_cube_ = std::isfinite(cube) ? std::clamp(cube, 0.0f, 1.0f) : 0.0f;
  const float c = std::isfinite(cone) ? std::clamp(cone, 1e-3f, 1.5f) : 0.1f;
  cos_cone_ = std::cos(c);
  cone_pdf_ = 1.0f / (2.0f * kPi * (1.0f - cos_cone_));
}

uint64_t GuidingField::caustic_key(Vec3 p, uint32_t normal_class) const {
  const Vec3 x = (p - bounds_.lo) * caustic_inv_h_;
  const auto q = [](float v) { return uint64_t(std::clamp(v, 0.0f, 1048575.0f)); };  // 20 bits each
  return (q(x.x) << 43) | (q(x.y) << 23) | (q(x.z) << 3) | uint64_t(normal_class);
}

int32_t GuidingField::caustic_cell(Vec3 p, Vec3 n) const {
  if (caustic_cells_.empty() || !is_finite(p)) return -1;
  const auto it = caustic_index_.find(caustic_key(p, normal_class(n)));
  return it == caustic_index_.end() ? -1 : int32_t(it->second);
}

Vec3 GuidingField::caustic_sample(int32_t cell, float u_lobe, Vec2 u, float& pdf) const {
  const CausticCube& c = caustic_cells_[size_t(cell)];
  uint32_t k = c.first;
  while (k + 1 < c.first + c.count && u_lobe >= caustic_lobes_[k].cdf) ++k;
  // Uniform in the lobe's cone.
  const float cos_t = 1.0f - u.x * (1.0f - cos_cone_);
  const float sin_t = std::sqrt(std::max(0.0f, 1.0f - cos_t * cos_t));
  const float phi = 2.0f * kPi * u.y;
  Vec3 t, b;
  const Vec3 d = caustic_lobes_[k].dir;
  make_basis(d, t, b);
  const Vec3 w = normalize(t * (sin_t * std::cos(phi)) + b * (sin_t * std::sin(phi)) + d * cos_t);
  pdf = caustic_pdf(cell, w);
  return w;
}

float GuidingField::caustic_pdf(int32_t cell, Vec3 w) const {
  const CausticCube& c = caustic_cells_[size_t(cell)];
  float p = 0.0f, prev = 0.0f;
  for (uint32_t k = c.first; k < c.first + c.count; ++k) {
    const CausticLobe& l = caustic_lobes_[k];
    if (dot(w, l.dir) >= cos_cone_) p += l.cdf - prev;
    prev = l.cdf;
  }
  return p * cone_pdf_;
}

void GuidingField::build_caustic_lobes() {
  caustic_index_.clear();
  caustic_cells_.clear();
  caustic_lobes_.clear();
  if (photon_map_.empty()) return;
  caustic_inv_h_ = 1.0f / std::max(caustic_cube_ * length(bounds_.extent()), 1e-6f);
  // Per cube, the photons' flux by arrival direction (a 64 x 64 grid of the unit square), and
  // the flux-weighted sum of their directions. Ordered maps and integer keys: the same lobes
  // whatever order the threads kept the photons in (the sums are float, but each bin's are
  // added in one fixed order after sorting).
  struct Bin {
    double flux = 0.0;
    Vec3 dir{0.0f};
  };
  std::vector<std::tuple<uint64_t, uint32_t, size_t>> order;  // cube, direction bin, record
  order.reserve(photon_map_.size());
  for (size_t i = 0; i < photon_map_.size(); ++i) {
    const PhotonRecord& r = photon_map_[i];
    if (!(r.value > 0.0f) || !std::isfinite(r.value) || !is_finite(r.p) || r.normal_class >= kNormalClasses) continue;
    const uint32_t bx = std::min(uint32_t(r.s.x * 64.0f), 63u), by = std::min(uint32_t(r.s.y * 64.0f), 63u);
    order.emplace_back(caustic_key(r.p, r.normal_class), bx + 64 * by, i);
  }
  // Within a bin, records by their own content (the thread order of equal records is immaterial).
  std::sort(order.begin(), order.end(), [&](const auto& a, const auto& b) {
    if (std::get<0>(a) != std::get<0>(b)) return std::get<0>(a) < std::get<0>(b);
    if (std::get<1>(a) != std::get<1>(b)) return std::get<1>(a) < std::get<1>(b);
    const PhotonRecord &ra = photon_map_[std::get<2>(a)], &rb = photon_map_[std::get<2>(b)];
    return std::tie(ra.value, ra.s.x, ra.s.y, ra.p.x, ra.p.y, ra.p.z) < std::tie(rb.value, rb.s.x, rb.s.y, rb.p.x, rb.p.y, rb.p.z);
  });
  std::vector<std::pair<double, Vec3>> lobes;
  for (size_t i = 0; i < order.size();) {
    const uint64_t key = std::get<0>(order[i]);
    lobes.clear();
    while (i < order.size() && std::get<0>(order[i]) == key) {
      const uint32_t bin = std::get<1>(order[i]);
      Bin b;
      for (; i < order.size() && std::get<0>(order[i]) == key && std::get<1>(order[i]) == bin; ++i) {
        const PhotonRecord& r = photon_map_[std::get<2>(order[i])];
        b.flux += double(r.value);
        b.dir += from_square(r.s) * r.value;
      }
      if (b.flux > 0.0 && length(b.dir) > 0.0f) lobes.emplace_back(b.flux, normalize(b.dir));
    }
    if (lobes.empty()) continue;
    // The strongest kMaxLobes (ties by direction, for a fixed order).
    std::sort(lobes.begin(), lobes.end(), [](const auto& a, const auto& b) {
      if (a.first != b.first) return a.first > b.first;
      return std::tie(a.second.x, a.second.y, a.second.z) < std::tie(b.second.x, b.second.y, b.second.z);
    });
    if (lobes.size() > size_t(kMaxLobes)) lobes.resize(size_t(kMaxLobes));
    double total = 0.0;
    for (const auto& l : lobes) total += l.first;
    CausticCube c;
    c.first = uint32_t(caustic_lobes_.size());
    c.count = uint32_t(lobes.size());
    double acc = 0.0;
    for (const auto& l : lobes) {
      acc += l.first;
      caustic_lobes_.push_back({l.second, float(acc / total)});
    }
    caustic_lobes_.back().cdf = 1.0f;
    caustic_index_.emplace(key, uint32_t(caustic_cells_.size()));
    caustic_cells_.push_back(c);
  }
}

}  // namespace pl
