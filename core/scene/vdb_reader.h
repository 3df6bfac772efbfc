// A reader of OpenVDB .vdb files (issue 23), standard library and zlib only: what Blender's
// OpenVDB (versions 7-12, file format 222-224) writes with VolumeGrids.save and what Mantaflow's
// caches hold. Reads the header, grid descriptors, grid metadata, the transform (scale,
// translate, uniform scale, affine, unitary maps), the tree (root 4096^3 tiles, internal nodes 5
// and 4, 8^3 leaves), and the leaf buffers under every compression OpenVDB writes: none, ZIP
// (zlib), Blosc 1 (LZ4, BloscLZ is refused; byte shuffle), active-mask compression, half floats.
// Value types: float, double, vec3s, vec3d, int32, int64, bool (as floats); other types are
// skipped with a message. Every malformed input raises std::runtime_error (VdbError); every
// allocation is bounded by the file's size or by the limits in VdbReadOptions.
#pragma once
#include <cstddef>
#include <cstdint>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include "scene/volume_grid.h"

namespace pl {

struct VdbError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

// Per-grid compression flags, as OpenVDB's io/Compression.h.
enum VdbCompression : uint32_t { kVdbZip = 0x1, kVdbActiveMask = 0x2, kVdbBlosc = 0x4 };

struct VdbReadOptions {
  std::string only_grid;          // read only the grid of this name (empty: all)
  bool topology_only = false;     // read descriptors, metadata and transforms, not the voxels
  int64_t max_file_bytes = int64_t(8) << 30;
  VolumeGrid::Limits limits;
};

struct VdbGridRecord {
  std::string name;          // as in the file (OpenVDB's unique-name suffix removed)
  std::string tree_type;     // e.g. "Tree_float_5_4_3"
  uint32_t compression = 0;  // VdbCompression flags of this grid
  bool half_float = false;
  std::string skipped;       // why the grid was not read (empty when it was)
  std::shared_ptr<VolumeGrid> grid;  // null when skipped
};

struct VdbFile {
  uint32_t file_version = 0;
  uint32_t library_major = 0, library_minor = 0;
  std::string uuid;
  std::vector<VdbGridRecord> grids;
};

VdbFile read_vdb_file(const std::string& path, const VdbReadOptions& options = {});
VdbFile read_vdb_memory(const uint8_t* data, size_t size, const VdbReadOptions& options = {});

// The codecs, exposed for tests. Each throws VdbError unless the output is exactly `dst_size`.
void vdb_lz4_decompress(const uint8_t* src, size_t src_size, uint8_t* dst, size_t dst_size);
void vdb_blosc_decompress(const uint8_t* src, size_t src_size, uint8_t* dst, size_t dst_size);
void vdb_zlib_decompress(const uint8_t* src, size_t src_size, uint8_t* dst, size_t dst_size);
bool vdb_zlib_available();

}  // namespace pl
