// A sparse voxel grid for rendering heterogeneous volumes (issue 23): what the OpenVDB reader
// (vdb_reader.h) produces from one grid of a .vdb file, independent of that format.
//
// Layout: the grid's extent (every leaf and every tile whose value differs from the background)
// is covered by a flat table of 8^3-voxel bricks; a table entry is either a brick index into a
// dense array of bricks (512 voxels x channels floats) or a constant (the background, or the
// value of a tile). Index convention as OpenVDB's and Cycles': voxel centres at integer index
// coordinates, index_to_object maps an index-space point to object space.
#pragma once
#include <array>
#include <cstdint>
#include <string>
#include <vector>

namespace pl {

// Tricubic: the uniform cubic B-spline over the 4^3 voxels around the point (Cycles' Cubic
// volume interpolation); its weights are non-negative and sum to 1, so the majorants bound it.
enum class VolumeSampling { Closest = 0, Trilinear = 1, Tricubic = 2 };

class VolumeGrid {
 public:
  static constexpr int kBrickLog2 = 3;
  static constexpr int kBrick = 1 << kBrickLog2;            // voxels per brick side
  static constexpr int kBrickVoxels = kBrick * kBrick * kBrick;
  static constexpr int kMajorantBlock = kBrick;              // majorant cells are the bricks

  // Tree content handed to build(): a leaf (8^3 voxels, values in OpenVDB's x-major order
  // (x * 64 + y * 8 + z), `channels` floats each) or a tile (a cube of `size` voxels of one value).
  struct Leaf {
    std::array<int32_t, 3> origin;
    std::array<uint64_t, 8> active;  // value mask
    std::vector<float> values;       // kBrickVoxels * channels
  };
  struct Tile {
    std::array<int32_t, 3> origin;
    int32_t size;  // 8, 128 or 4096 voxels per side
    bool active;
    std::array<float, 3> value;
  };
  struct Limits {
    int64_t max_table_entries = int64_t(1) << 25;   // 32M bricks of extent (128 MB of table)
    int64_t max_bricks = int64_t(1) << 19;          // 512K stored bricks (1 GB at 1 channel)
  };

  VolumeGrid() = default;
  // Builds the brick table, the active bounding box and the majorant grid. Throws (leaving the
  // grid unusable: discard it)
  // std::runtime_error when the extent or the storage exceeds `limits`. Non-finite values
  // become 0 (counted in nonfinite_replaced()).
  void build(int channels, const std::array<float, 3>& background, std::vector<Leaf>& leaves,
             const std::vector<Tile>& tiles, const Limits& limits);
  void build(int channels, const std::array<float, 3>& background, std::vector<Leaf>& leaves,
             const std::vector<Tile>& tiles) {
    build(channels, background, leaves, tiles, Limits{});
  }
  // A dense grid of nx * ny * nz voxels at indices [0, n) (values x fastest, `channels`
  // floats each; all active, background 0): the Point Density texture's voxels.
  void build_dense(int channels, int nx, int ny, int nz, const float* values);
  // Row-major 4x4, column-vector convention: object = M * (i, j, k, 1). Throws when singular.
  void set_transform(const std::array<double, 16>& index_to_object);

  // Metadata.
  std::string name;       // the grid's name in the file
  std::string value_type; // "float", "double", "vec3s", "int32", "bool", ...
  std::string grid_class; // "fog volume", "level set", "" ...
  bool saved_as_half = false;

  int channels() const { return channels_; }
  const std::array<float, 3>& background() const { return background_; }
  const std::array<double, 16>& index_to_object() const { return index_to_object_; }
  const std::array<double, 16>& object_to_index() const { return object_to_index_; }
  // Inclusive bounding box of the active voxels (min > max when there are none).
  const std::array<int32_t, 3>& active_min() const { return active_min_; }
  const std::array<int32_t, 3>& active_max() const { return active_max_; }
  bool empty() const { return active_voxels_ == 0; }
  int64_t active_voxels() const { return active_voxels_; }
  int64_t nonfinite_replaced() const { return nonfinite_; }
  int64_t leaf_count() const { return int64_t(bricks_.size() / (size_t(kBrickVoxels) * channels_)); }
  size_t memory_bytes() const;

  // The value of voxel (i, j, k) (channels() floats into out); the background outside.
  void voxel(int64_t i, int64_t j, int64_t k, float* out) const;
  // Samples at an object-space point (channels() floats into out).
  void sample(const double p[3], VolumeSampling mode, float* out) const;
  void sample_index(const double ijk[3], VolumeSampling mode, float* out) const;

  // Majorant grid: a cell per 8^3 block of voxels, on the brick grid extended by one cell on
  // every side; each holds the maximum over its voxels and their 1-voxel trilinear footprint
  // (over all channels). Points outside the majorant grid bound the background.
  const std::array<int64_t, 3>& majorant_origin() const { return maj_origin_; }  // in voxels
  const std::array<int64_t, 3>& majorant_dims() const { return maj_dims_; }      // in cells
  const std::vector<float>& majorant_cells() const { return majorant_; }         // x fastest
  float majorant_at_index(const double ijk[3]) const;
  float majorant(const double p[3]) const;  // object space
  // The largest value any sample (closest or trilinear, any channel) can take at an index-space
  // point in the box [lo, hi] (the majorant cells it overlaps; the background beyond them).
  float max_in_index_box(const double lo[3], const double hi[3]) const;
  // The same bound from the voxels themselves: the largest voxel (any channel) of the stencils
  // of samples in [lo, hi] (voxels floor(lo) - pad .. floor(hi) + 1 + pad; pad 1 for tricubic
  // reads). Much tighter than the brick majorants for boxes of a few voxels (they bound a
  // brick and its 26 neighbours); boxes of more than 2^18 voxels use max_in_index_box.
  float max_voxels_in_index_box(const double lo[3], const double hi[3], int pad) const;
  float max_value() const { return max_value_; }
  // Per channel, the largest |value| of any voxel, tile or the background (a velocity grid's
  // largest displacement per axis; samples are convex combinations of voxels).
  std::array<float, 3> max_abs() const;

 private:
  int32_t entry(int64_t bx, int64_t by, int64_t bz) const;
  void build_majorant();

  int channels_ = 1;
  std::array<float, 3> background_{0, 0, 0};
  std::array<double, 16> index_to_object_{1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};
  std::array<double, 16> object_to_index_{1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};
  std::array<int32_t, 3> active_min_{1, 1, 1}, active_max_{0, 0, 0};
  int64_t active_voxels_ = 0;
  int64_t nonfinite_ = 0;
  // Brick table over [table_origin_, table_origin_ + table_dims_) in brick units, x fastest:
  // >= 0 a brick index, < 0 the constant -(entry + 1) (constant 0 is the background).
  std::array<int64_t, 3> table_origin_{0, 0, 0}, table_dims_{0, 0, 0};
  std::vector<int32_t> table_;
  std::vector<float> bricks_;     // kBrickVoxels * channels per brick, x-major like OpenVDB
  std::vector<float> constants_;  // channels per constant
  std::array<int64_t, 3> maj_origin_{0, 0, 0}, maj_dims_{0, 0, 0};
  std::vector<float> majorant_;
  float max_value_ = 0;
  float background_max_ = 0;
};

}  // namespace pl
