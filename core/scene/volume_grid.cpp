// Sparse brick grid for heterogeneous volumes: see volume_grid.h.
#include "scene/volume_grid.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>

namespace pl {
namespace {

int64_t floor_div(int64_t a, int64_t b) { return a >= 0 ? a / b : -((-a + b - 1) / b); }

bool invert4(const std::array<double, 16>& m, std::array<double, 16>& out) {
  // Affine inverse: the 3x3 part by cofactors, then the translation.
  const double a = m[0], b = m[1], c = m[2], d = m[4], e = m[5], f = m[6], g = m[8], h = m[9], i = m[10];
  const double A = e * i - f * h, B = -(d * i - f * g), C = d * h - e * g;
  const double det = a * A + b * B + c * C;
  if (!std::isfinite(det) || std::fabs(det) < 1e-300) return false;
  const double s = 1.0 / det;
  const double r[9] = {A * s, -(b * i - c * h) * s, (b * f - c * e) * s,
                       B * s, (a * i - c * g) * s,  -(a * f - c * d) * s,
                       C * s, -(a * h - b * g) * s, (a * e - b * d) * s};
  const double t[3] = {m[3], m[7], m[11]};
  out = {r[0], r[1], r[2], -(r[0] * t[0] + r[1] * t[1] + r[2] * t[2]),
         r[3], r[4], r[5], -(r[3] * t[0] + r[4] * t[1] + r[5] * t[2]),
         r[6], r[7], r[8], -(r[6] * t[0] + r[7] * t[1] + r[8] * t[2]),
         0,    0,    0,    1};
  for (double v : out)
    if (!std::isfinite(v)) return false;
  return true;
}

void apply(const std::array<double, 16>& m, const double p[3], double out[3]) {
  for (int r = 0; r < 3; ++r) out[r] = m[4 * r] * p[0] + m[4 * r + 1] * p[1] + m[4 * r + 2] * p[2] + m[4 * r + 3];
}

}  // namespace

void VolumeGrid::set_transform(const std::array<double, 16>& m) {
  std::array<double, 16> inv;
  if (!invert4(m, inv)) throw std::runtime_error("volume grid transform is singular or not finite");
  index_to_object_ = m;
  object_to_index_ = inv;
}

void VolumeGrid::build_dense(int channels, int nx, int ny, int nz, const float* values) {
  if (channels != 1 && channels != 3) throw std::runtime_error("volume grid: 1 or 3 channels");
  if (nx <= 0 || ny <= 0 || nz <= 0 || nx > 4096 || ny > 4096 || nz > 4096)
    throw std::runtime_error("dense volume grid: bad dimensions");
  std::vector<Leaf> leaves;
  for (int bz = 0; bz < nz; bz += kBrick)
    for (int by = 0; by < ny; by += kBrick)
      for (int bx = 0; bx < nx; bx += kBrick) {
        Leaf leaf;
        leaf.origin = {bx, by, bz};
        leaf.active.fill(0);
        leaf.values.assign(size_t(kBrickVoxels) * size_t(channels), 0.0f);
        for (int x = 0; x < kBrick && bx + x < nx; ++x)
          for (int y = 0; y < kBrick && by + y < ny; ++y)
            for (int z = 0; z < kBrick && bz + z < nz; ++z) {
              const int o = x * 64 + y * 8 + z;  // OpenVDB's leaf order
              leaf.active[size_t(o >> 6)] |= uint64_t(1) << (o & 63);
              const size_t src = ((size_t(bz + z) * size_t(ny) + size_t(by + y)) * size_t(nx) + size_t(bx + x)) *
                                 size_t(channels);
              for (int c = 0; c < channels; ++c) leaf.values[size_t(o) * size_t(channels) + size_t(c)] = values[src + size_t(c)];
            }
        leaves.push_back(std::move(leaf));
      }
  build(channels, {0.0f, 0.0f, 0.0f}, leaves, {});
}

void VolumeGrid::build(int channels, const std::array<float, 3>& background, std::vector<Leaf>& leaves,
                       const std::vector<Tile>& tiles, const Limits& limits) {
  if (channels != 1 && channels != 3) throw std::runtime_error("volume grid: 1 or 3 channels");
  channels_ = channels;
  nonfinite_ = 0;
  auto clean = [&](float v) {
    if (std::isfinite(v)) return v;
    ++nonfinite_;
    return 0.0f;
  };
  for (int c = 0; c < 3; ++c) background_[c] = c < channels ? clean(background[c]) : 0.0f;

  // Extent in bricks, and the active bounding box.
  const int64_t big = std::numeric_limits<int64_t>::max() / 4;
  int64_t lo[3] = {big, big, big}, hi[3] = {-big, -big, -big};
  int64_t amin[3] = {big, big, big}, amax[3] = {-big, -big, -big};
  active_voxels_ = 0;
  auto differs = [&](const std::array<float, 3>& v) {
    for (int c = 0; c < channels; ++c)
      if (!(v[c] == background_[c])) return true;
    return false;
  };
  for (const Leaf& l : leaves) {
    if (l.values.size() != size_t(kBrickVoxels) * channels) throw std::runtime_error("volume grid: bad leaf size");
    for (int a = 0; a < 3; ++a) {
      if (l.origin[a] % kBrick != 0) throw std::runtime_error("volume grid: leaf origin not aligned");
      lo[a] = std::min<int64_t>(lo[a], floor_div(l.origin[a], kBrick));
      hi[a] = std::max<int64_t>(hi[a], floor_div(l.origin[a], kBrick));
    }
    for (int n = 0; n < kBrickVoxels; ++n) {
      if (!((l.active[n >> 6] >> (n & 63)) & 1)) continue;
      const int64_t v[3] = {l.origin[0] + (n >> 6), l.origin[1] + ((n >> 3) & 7), l.origin[2] + (n & 7)};
      for (int a = 0; a < 3; ++a) amin[a] = std::min(amin[a], v[a]), amax[a] = std::max(amax[a], v[a]);
      ++active_voxels_;
    }
  }
  for (const Tile& t : tiles) {
    if (t.size < kBrick || t.size % kBrick != 0) throw std::runtime_error("volume grid: bad tile size");
    for (int a = 0; a < 3; ++a)
      if (t.origin[a] % t.size != 0) throw std::runtime_error("volume grid: tile origin not aligned");
    if (t.active) {
      for (int a = 0; a < 3; ++a) {
        amin[a] = std::min<int64_t>(amin[a], t.origin[a]);
        amax[a] = std::max<int64_t>(amax[a], int64_t(t.origin[a]) + t.size - 1);
      }
      active_voxels_ += int64_t(t.size) * t.size * t.size;
    }
    if (!differs(t.value)) continue;
    for (int a = 0; a < 3; ++a) {
      lo[a] = std::min<int64_t>(lo[a], floor_div(t.origin[a], kBrick));
      hi[a] = std::max<int64_t>(hi[a], floor_div(int64_t(t.origin[a]) + t.size - 1, kBrick));
    }
  }
  for (int a = 0; a < 3; ++a) {
    active_min_[a] = active_voxels_ ? int32_t(amin[a]) : 1;
    active_max_[a] = active_voxels_ ? int32_t(amax[a]) : 0;
  }

  table_.clear();
  bricks_.clear();
  constants_.assign(background_.begin(), background_.begin() + channels);
  table_dims_ = {0, 0, 0};
  table_origin_ = {0, 0, 0};
  if (lo[0] <= hi[0]) {
    int64_t entries = 1, dims[3];
    for (int a = 0; a < 3; ++a) {
      dims[a] = hi[a] - lo[a] + 1;
      entries = dims[a] > limits.max_table_entries ? limits.max_table_entries + 1 : entries * dims[a];
      if (entries > limits.max_table_entries) entries = limits.max_table_entries + 1;
    }
    if (entries > limits.max_table_entries)
      throw std::runtime_error("volume grid: extent of " + std::to_string(dims[0]) + " x " + std::to_string(dims[1]) +
                               " x " + std::to_string(dims[2]) + " bricks exceeds the limit");
    if (int64_t(leaves.size()) > limits.max_bricks)
      throw std::runtime_error("volume grid: " + std::to_string(leaves.size()) + " leaves exceed the limit");
    for (int a = 0; a < 3; ++a) table_origin_[a] = lo[a], table_dims_[a] = dims[a];
    table_.assign(size_t(entries), -1);
    // Tiles first (largest first), then leaves, so a leaf wins where a hostile file overlaps them.
    std::vector<const Tile*> order;
    for (const Tile& t : tiles)
      if (differs(t.value)) order.push_back(&t);
    std::stable_sort(order.begin(), order.end(), [](const Tile* a, const Tile* b) { return a->size > b->size; });
    // Overlapping tiles (only in a hostile file) could make the fill far longer than the table.
    int64_t fill = 0;
    for (const Tile* t : order) fill += int64_t(t->size / kBrick) * (t->size / kBrick) * (t->size / kBrick);
    if (fill > 4 * limits.max_table_entries) throw std::runtime_error("volume grid: tiles overlap beyond the limit");
    for (const Tile* t : order) {
      const int32_t id = int32_t(constants_.size() / channels);
      for (int c = 0; c < channels; ++c) constants_.push_back(clean(t->value[c]));
      const int64_t nb = t->size / kBrick;
      int64_t b0[3];
      for (int a = 0; a < 3; ++a) b0[a] = floor_div(t->origin[a], kBrick) - table_origin_[a];
      for (int64_t z = 0; z < nb; ++z)
        for (int64_t y = 0; y < nb; ++y)
          for (int64_t x = 0; x < nb; ++x)
            table_[size_t(((b0[2] + z) * table_dims_[1] + b0[1] + y) * table_dims_[0] + b0[0] + x)] = -(id + 1);
    }
    bricks_.reserve(leaves.size() * size_t(kBrickVoxels) * channels);
    for (Leaf& l : leaves) {
      int64_t b[3];
      for (int a = 0; a < 3; ++a) b[a] = floor_div(l.origin[a], kBrick) - table_origin_[a];
      int32_t& e = table_[size_t((b[2] * table_dims_[1] + b[1]) * table_dims_[0] + b[0])];
      size_t at;
      if (e >= 0) {
        at = size_t(e) * kBrickVoxels * channels;  // duplicate leaf: the last one wins
      } else {
        e = int32_t(bricks_.size() / (size_t(kBrickVoxels) * channels));
        at = bricks_.size();
        bricks_.resize(at + size_t(kBrickVoxels) * channels);
      }
      for (size_t n = 0; n < l.values.size(); ++n) bricks_[at + n] = clean(l.values[n]);
      std::vector<float>().swap(l.values);
    }
  }
  build_majorant();
}

size_t VolumeGrid::memory_bytes() const {
  return table_.size() * sizeof(int32_t) + bricks_.size() * sizeof(float) + constants_.size() * sizeof(float) +
         majorant_.size() * sizeof(float);
}

int32_t VolumeGrid::entry(int64_t bx, int64_t by, int64_t bz) const {
  bx -= table_origin_[0];
  by -= table_origin_[1];
  bz -= table_origin_[2];
  if (bx < 0 || by < 0 || bz < 0 || bx >= table_dims_[0] || by >= table_dims_[1] || bz >= table_dims_[2]) return -1;
  return table_[size_t((bz * table_dims_[1] + by) * table_dims_[0] + bx)];
}

void VolumeGrid::voxel(int64_t i, int64_t j, int64_t k, float* out) const {
  const int32_t e = entry(i >> kBrickLog2, j >> kBrickLog2, k >> kBrickLog2);
  const float* src;
  if (e >= 0) {
    const int n = int(((i & 7) << 6) | ((j & 7) << 3) | (k & 7));
    src = &bricks_[(size_t(e) * kBrickVoxels + n) * channels_];
  } else {
    src = &constants_[size_t(-(e + 1)) * channels_];
  }
  for (int c = 0; c < channels_; ++c) out[c] = src[c];
}

void VolumeGrid::sample_index(const double ijk[3], VolumeSampling mode, float* out) const {
  // Far outside any representable index: the background (and no overflow in the casts).
  for (int a = 0; a < 3; ++a)
    if (!(std::fabs(ijk[a]) < 2.0e9)) {
      for (int c = 0; c < channels_; ++c) out[c] = background_[c];
      return;
    }
  if (mode == VolumeSampling::Closest) {
    voxel(int64_t(std::floor(ijk[0] + 0.5)), int64_t(std::floor(ijk[1] + 0.5)), int64_t(std::floor(ijk[2] + 0.5)), out);
    return;
  }
  const double fx = std::floor(ijk[0]), fy = std::floor(ijk[1]), fz = std::floor(ijk[2]);
  const int64_t x = int64_t(fx), y = int64_t(fy), z = int64_t(fz);
  const float tx = float(ijk[0] - fx), ty = float(ijk[1] - fy), tz = float(ijk[2] - fz);
  float acc[3] = {0, 0, 0}, v[3];
  if (mode == VolumeSampling::Tricubic) {
    // Uniform cubic B-spline weights of voxels floor - 1 .. floor + 2 (Cycles' tricubic lookup).
    const auto weights = [](float t, float w[4]) {
      const float s = 1.0f - t;
      w[0] = s * s * s / 6.0f;
      w[1] = (3.0f * t * t * t - 6.0f * t * t + 4.0f) / 6.0f;
      w[2] = (-3.0f * t * t * t + 3.0f * t * t + 3.0f * t + 1.0f) / 6.0f;
      w[3] = t * t * t / 6.0f;
    };
    float wx[4], wy[4], wz[4];
    weights(tx, wx);
    weights(ty, wy);
    weights(tz, wz);
    for (int k = 0; k < 4; ++k)
      for (int j = 0; j < 4; ++j) {
        const float wjk = wy[j] * wz[k];
        for (int i = 0; i < 4; ++i) {
          voxel(x + i - 1, y + j - 1, z + k - 1, v);
          for (int c = 0; c < channels_; ++c) acc[c] += wx[i] * wjk * v[c];
        }
      }
    for (int c = 0; c < channels_; ++c) out[c] = acc[c];
    return;
  }
  if ((x & 7) < 7 && (y & 7) < 7 && (z & 7) < 7) {
    // The 2x2x2 stencil inside one brick (343 of 512 cells): one table look-up.
    const int32_t e = entry(x >> kBrickLog2, y >> kBrickLog2, z >> kBrickLog2);
    if (e < 0) {
      for (int c = 0; c < channels_; ++c) out[c] = constants_[size_t(-(e + 1)) * channels_ + c];
      return;
    }
    const float* b = &bricks_[size_t(e) * kBrickVoxels * channels_];
    const int base = int(((x & 7) << 6) | ((y & 7) << 3) | (z & 7));
    for (int n = 0; n < 8; ++n) {
      const int dx = n & 1, dy = (n >> 1) & 1, dz = n >> 2;
      const float w = (dx ? tx : 1 - tx) * (dy ? ty : 1 - ty) * (dz ? tz : 1 - tz);
      const float* src = b + size_t(base + (dx << 6) + (dy << 3) + dz) * channels_;
      for (int c = 0; c < channels_; ++c) acc[c] += w * src[c];
    }
    for (int c = 0; c < channels_; ++c) out[c] = acc[c];
    return;
  }
  for (int n = 0; n < 8; ++n) {
    const int dx = n & 1, dy = (n >> 1) & 1, dz = n >> 2;
    const float w = (dx ? tx : 1 - tx) * (dy ? ty : 1 - ty) * (dz ? tz : 1 - tz);
    voxel(x + dx, y + dy, z + dz, v);
    for (int c = 0; c < channels_; ++c) acc[c] += w * v[c];
  }
  for (int c = 0; c < channels_; ++c) out[c] = acc[c];
}

void VolumeGrid::sample(const double p[3], VolumeSampling mode, float* out) const {
  double ijk[3];
  apply(object_to_index_, p, ijk);
  sample_index(ijk, mode, out);
}

std::array<float, 3> VolumeGrid::max_abs() const {
  std::array<float, 3> m{0.0f, 0.0f, 0.0f};
  const auto take = [&](const float* v) {
    for (int c = 0; c < channels_; ++c) m[size_t(c)] = std::max(m[size_t(c)], std::fabs(v[c]));
  };
  take(background_.data());
  for (size_t i = 0; i < constants_.size(); i += size_t(channels_)) take(&constants_[i]);
  for (size_t i = 0; i < bricks_.size(); i += size_t(channels_)) take(&bricks_[i]);
  return m;
}

void VolumeGrid::build_majorant() {
  majorant_.clear();
  float bg = background_[0];
  for (int c = 1; c < channels_; ++c) bg = std::max(bg, background_[c]);
  background_max_ = bg;
  max_value_ = bg;
  if (table_.empty()) {
    maj_dims_ = {0, 0, 0};
    return;
  }
  for (int a = 0; a < 3; ++a) {
    maj_origin_[a] = (table_origin_[a] - 1) * kBrick;
    maj_dims_[a] = table_dims_[a] + 2;
  }
  // Per brick of the table: its own maximum (a constant, or the max over the brick's voxels).
  std::vector<float> own(table_.size());
  for (size_t t = 0; t < table_.size(); ++t) {
    const int32_t e = table_[t];
    float m = -std::numeric_limits<float>::infinity();
    if (e >= 0) {
      const float* b = &bricks_[size_t(e) * kBrickVoxels * channels_];
      for (int n = 0; n < kBrickVoxels * channels_; ++n) m = std::max(m, b[n]);
    } else {
      for (int c = 0; c < channels_; ++c) m = std::max(m, constants_[size_t(-(e + 1)) * channels_ + c]);
    }
    own[t] = m;
    max_value_ = std::max(max_value_, m);
  }
  // A trilinear lookup inside a cell reads voxels at most one voxel beyond it, so the cell's
  // majorant is the maximum over itself and its 26 neighbouring bricks (the background outside).
  majorant_.assign(size_t(maj_dims_[0] * maj_dims_[1] * maj_dims_[2]), bg);
  auto own_at = [&](int64_t x, int64_t y, int64_t z) {  // table coordinates
    if (x < 0 || y < 0 || z < 0 || x >= table_dims_[0] || y >= table_dims_[1] || z >= table_dims_[2]) return bg;
    return own[size_t((z * table_dims_[1] + y) * table_dims_[0] + x)];
  };
  for (int64_t z = 0; z < maj_dims_[2]; ++z)
    for (int64_t y = 0; y < maj_dims_[1]; ++y)
      for (int64_t x = 0; x < maj_dims_[0]; ++x) {
        float m = bg;
        for (int dz = -1; dz <= 1; ++dz)
          for (int dy = -1; dy <= 1; ++dy)
            for (int dx = -1; dx <= 1; ++dx) m = std::max(m, own_at(x - 1 + dx, y - 1 + dy, z - 1 + dz));
        majorant_[size_t((z * maj_dims_[1] + y) * maj_dims_[0] + x)] = m;
      }
}

float VolumeGrid::majorant_at_index(const double ijk[3]) const {
  if (majorant_.empty()) return background_max_;
  int64_t c[3];
  for (int a = 0; a < 3; ++a) {
    if (!(std::fabs(ijk[a]) < 2.0e9)) return background_max_;
    c[a] = floor_div(int64_t(std::floor(ijk[a])) - maj_origin_[a], kMajorantBlock);
    if (c[a] < 0 || c[a] >= maj_dims_[a]) return background_max_;
  }
  return majorant_[size_t((c[2] * maj_dims_[1] + c[1]) * maj_dims_[0] + c[0])];
}

float VolumeGrid::majorant(const double p[3]) const {
  double ijk[3];
  apply(object_to_index_, p, ijk);
  return majorant_at_index(ijk);
}

float VolumeGrid::max_in_index_box(const double lo[3], const double hi[3]) const {
  if (majorant_.empty()) return background_max_;
  int64_t c0[3], c1[3];
  bool beyond = false;  // the box reaches past the majorant cells: the background there too
  for (int a = 0; a < 3; ++a) {
    if (!(lo[a] <= hi[a]) || !(std::fabs(lo[a]) < 2.0e9) || !(std::fabs(hi[a]) < 2.0e9)) return max_value_;
    c0[a] = floor_div(int64_t(std::floor(lo[a])) - maj_origin_[a], kMajorantBlock);
    c1[a] = floor_div(int64_t(std::floor(hi[a])) - maj_origin_[a], kMajorantBlock);
    beyond = beyond || c0[a] < 0 || c1[a] >= maj_dims_[a];
    c0[a] = std::max<int64_t>(c0[a], 0);
    c1[a] = std::min<int64_t>(c1[a], maj_dims_[a] - 1);
    if (c0[a] > c1[a]) return background_max_;
  }
  float m = beyond ? background_max_ : -std::numeric_limits<float>::infinity();
  for (int64_t z = c0[2]; z <= c1[2]; ++z)
    for (int64_t y = c0[1]; y <= c1[1]; ++y)
      for (int64_t x = c0[0]; x <= c1[0]; ++x)
        m = std::max(m, majorant_[size_t((z * maj_dims_[1] + y) * maj_dims_[0] + x)]);
  return m;
}

float VolumeGrid::max_voxels_in_index_box(const double lo[3], const double hi[3], int pad) const {
  int64_t v0[3], v1[3], count = 1;
  for (int a = 0; a < 3; ++a) {
    if (!(lo[a] <= hi[a]) || !(std::fabs(lo[a]) < 2.0e9) || !(std::fabs(hi[a]) < 2.0e9))
      return max_in_index_box(lo, hi);
    v0[a] = int64_t(std::floor(lo[a])) - pad;
    v1[a] = int64_t(std::floor(hi[a])) + 1 + pad;
    count *= v1[a] - v0[a] + 1;
  }
  if (count > (int64_t(1) << 18)) return max_in_index_box(lo, hi);
  float m = -std::numeric_limits<float>::infinity(), v[3];
  for (int64_t z = v0[2]; z <= v1[2]; ++z)
    for (int64_t y = v0[1]; y <= v1[1]; ++y)
      for (int64_t x = v0[0]; x <= v1[0]; ++x) {
        voxel(x, y, z, v);
        for (int c = 0; c < channels_; ++c) m = std::max(m, v[c]);
      }
  return m;
}

}  // namespace pl
