// OpenVDB file reader: see vdb_reader.h. Written from the format's public description
// (OpenVDB's io/ and tree/ sources, Blosc 1's frame header, LZ4's block format).
#include "scene/vdb_reader.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <fstream>
#include <limits>
#include <map>

#ifdef PATHLIGHT_HAVE_ZLIB
#include <zlib.h>
#endif

namespace pl {
namespace {

constexpr uint32_t kMinVersion = 222;  // OPENVDB_FILE_VERSION_NODE_MASK_COMPRESSION
constexpr uint32_t kMaxVersion = 299;

[[noreturn]] void fail(const std::string& what) { throw VdbError("VDB file: " + what); }

// ------------------------------------------------------------------ codecs

uint32_t le32(const uint8_t* p) { return uint32_t(p[0]) | uint32_t(p[1]) << 8 | uint32_t(p[2]) << 16 | uint32_t(p[3]) << 24; }

float half_to_float(uint16_t h) {
  const uint32_t sign = uint32_t(h >> 15) << 31;
  const int exp = (h >> 10) & 0x1f;
  const uint32_t mant = h & 0x3ff;
  uint32_t bits;
  if (exp == 0) {
    if (mant == 0) {
      bits = sign;
    } else {  // subnormal: mant * 2^-24
      float f = std::ldexp(float(mant), -24);
      std::memcpy(&bits, &f, 4);
      bits |= sign;
    }
  } else if (exp == 31) {
    bits = sign | 0x7f800000u | (mant << 13);
  } else {
    bits = sign | uint32_t(exp - 15 + 127) << 23 | (mant << 13);
  }
  float f;
  std::memcpy(&f, &bits, 4);
  return f;
}

}  // namespace

void vdb_lz4_decompress(const uint8_t* src, size_t src_size, uint8_t* dst, size_t dst_size) {
  size_t ip = 0, op = 0;
  auto length = [&](size_t len) {
    if (len != 15) return len;
    for (;;) {
      if (ip >= src_size) fail("LZ4: truncated length");
      const uint8_t b = src[ip++];
      len += b;
      if (len > dst_size) fail("LZ4: length beyond the output");
      if (b != 255) return len;
    }
  };
  while (true) {
    if (ip >= src_size) fail("LZ4: truncated block");
    const uint8_t token = src[ip++];
    const size_t lit = length(token >> 4);
    if (lit > src_size - ip || lit > dst_size - op) fail("LZ4: literals beyond the buffers");
    if (lit) std::memcpy(dst + op, src + ip, lit);
    ip += lit;
    op += lit;
    if (ip == src_size) break;  // the last sequence has literals only
    if (src_size - ip < 2) fail("LZ4: truncated offset");
    const size_t offset = size_t(src[ip]) | size_t(src[ip + 1]) << 8;
    ip += 2;
    if (offset == 0 || offset > op) fail("LZ4: match offset outside the output");
    const size_t mlen = length(token & 15) + 4;
    if (mlen > dst_size - op) fail("LZ4: match beyond the output");
    for (size_t n = 0; n < mlen; ++n, ++op) dst[op] = dst[op - offset];  // may overlap
  }
  if (op != dst_size) fail("LZ4: block decompressed to " + std::to_string(op) + " bytes, expected " + std::to_string(dst_size));
}

void vdb_blosc_decompress(const uint8_t* src, size_t src_size, uint8_t* dst, size_t dst_size) {
  if (src_size < 16) fail("Blosc: truncated header");
  const uint8_t version = src[0], flags = src[2];
  const size_t typesize = src[3] ? src[3] : 1;
  const size_t nbytes = le32(src + 4), blocksize = le32(src + 8), cbytes = le32(src + 12);
  (void)version;
  if (nbytes != dst_size) fail("Blosc: frame holds " + std::to_string(nbytes) + " bytes, expected " + std::to_string(dst_size));
  if (cbytes > src_size || cbytes < 16) fail("Blosc: frame size beyond the data");
  if (nbytes == 0) return;
  if (flags & 0x2) {  // memcpyed
    if (cbytes - 16 < nbytes) fail("Blosc: truncated uncompressed frame");
    std::memcpy(dst, src + 16, nbytes);
    return;
  }
  if (blocksize == 0 || blocksize > nbytes) fail("Blosc: bad block size");
  const bool shuffle = (flags & 0x1) && typesize > 1;
  if (flags & 0x4) fail("Blosc: bit shuffle is not supported");
  const int codec = flags >> 5;
  if (codec != 1) fail("Blosc: compressor " + std::to_string(codec) + " is not supported (LZ4 only)");
  const bool dont_split = flags & 0x10;
  const size_t nblocks = (nbytes + blocksize - 1) / blocksize;
  if (16 + 4 * nblocks > cbytes) fail("Blosc: truncated block table");
  std::vector<uint8_t> tmp(blocksize);
  for (size_t b = 0; b < nblocks; ++b) {
    const bool leftover = b == nblocks - 1 && nbytes % blocksize != 0;
    const size_t bsize = leftover ? nbytes % blocksize : blocksize;
    size_t at = le32(src + 16 + 4 * b);
    const size_t nsplits = (!dont_split && typesize <= 16 && blocksize / typesize >= 128 && !leftover) ? typesize : 1;
    const size_t neblock = bsize / nsplits;
    uint8_t* out = shuffle ? tmp.data() : dst + b * blocksize;
    for (size_t s = 0; s < nsplits; ++s) {
      if (at > cbytes || cbytes - at < 4) fail("Blosc: block outside the frame");
      const size_t cs = le32(src + at);
      at += 4;
      if (cs > cbytes - at) fail("Blosc: stream outside the frame");
      if (cs == neblock) std::memcpy(out + s * neblock, src + at, neblock);
      else vdb_lz4_decompress(src + at, cs, out + s * neblock, neblock);
      at += cs;
    }
    if (shuffle) {  // byte unshuffle: stream j holds byte j of every element
      const size_t n = bsize / typesize;
      uint8_t* d = dst + b * blocksize;
      for (size_t j = 0; j < typesize; ++j)
        for (size_t i = 0; i < n; ++i) d[i * typesize + j] = tmp[j * n + i];
      std::memcpy(d + n * typesize, tmp.data() + n * typesize, bsize - n * typesize);
    }
  }
}

bool vdb_zlib_available() {
#ifdef PATHLIGHT_HAVE_ZLIB
  return true;
#else
  return false;
#endif
}

void vdb_zlib_decompress(const uint8_t* src, size_t src_size, uint8_t* dst, size_t dst_size) {
#ifdef PATHLIGHT_HAVE_ZLIB
  uLongf out = uLongf(dst_size);
  if (src_size > 0xffffffffu || dst_size > 0xffffffffu) fail("ZIP: block too large");
  const int rc = uncompress(dst, &out, src, uLong(src_size));
  if (rc != Z_OK) fail("ZIP: zlib error " + std::to_string(rc));
  if (out != dst_size) fail("ZIP: block decompressed to " + std::to_string(out) + " bytes, expected " + std::to_string(dst_size));
#else
  (void)src, (void)src_size, (void)dst, (void)dst_size;
  fail("ZIP-compressed grids are not supported: this build of the core has no zlib");
#endif
}

namespace {

// ------------------------------------------------------------------ byte stream

class Reader {
 public:
  Reader(const uint8_t* d, size_t n) : data_(d), size_(n) {}
  size_t pos() const { return pos_; }
  size_t size() const { return size_; }
  size_t left() const { return size_ - pos_; }
  void seek(int64_t p) {
    if (p < 0 || uint64_t(p) > size_) fail("offset " + std::to_string(p) + " outside the file");
    pos_ = size_t(p);
  }
  const uint8_t* take(size_t n, const char* what) {
    if (n > left()) fail(std::string("truncated (") + what + ")");
    const uint8_t* p = data_ + pos_;
    pos_ += n;
    return p;
  }
  template <class T>
  T get(const char* what) {
    T v;
    std::memcpy(&v, take(sizeof(T), what), sizeof(T));
    return v;
  }
  std::string string(const char* what, size_t max = 1 << 20) {
    const uint32_t n = get<uint32_t>(what);
    if (n > max) fail(std::string("string too long (") + what + ")");
    const uint8_t* p = take(n, what);
    return std::string(reinterpret_cast<const char*>(p), n);
  }

 private:
  const uint8_t* data_;
  size_t size_;
  size_t pos_ = 0;
};

// Value types as stored: bytes per value, components, and whether they may be stored as half.
struct ValueKind {
  std::string name;
  int bytes = 4;       // sizeof(ValueType)
  int components = 1;  // 1 or 3
  bool real = true;    // float or double components (half storage applies)
  bool integer = false;
  bool is_bool = false;
};

bool value_kind(const std::string& tree, ValueKind& k) {
  static const std::map<std::string, ValueKind> kinds = {
      {"float", {"float", 4, 1, true, false, false}},   {"double", {"double", 8, 1, true, false, false}},
      {"vec3s", {"vec3s", 12, 3, true, false, false}},  {"vec3d", {"vec3d", 24, 3, true, false, false}},
      {"int32", {"int32", 4, 1, false, true, false}},   {"int64", {"int64", 8, 1, false, true, false}},
      {"vec3i", {"vec3i", 12, 3, false, true, false}},  {"bool", {"bool", 1, 1, false, false, true}},
  };
  const std::string pre = "Tree_", post = "_5_4_3";
  if (tree.size() <= pre.size() + post.size() || tree.compare(0, pre.size(), pre) != 0 ||
      tree.compare(tree.size() - post.size(), post.size(), post) != 0)
    return false;
  auto it = kinds.find(tree.substr(pre.size(), tree.size() - pre.size() - post.size()));
  if (it == kinds.end()) return false;
  k = it->second;
  return true;
}

// One component value (of `bytes` per component) to float.
float component(const uint8_t* p, const ValueKind& k, bool half) {
  if (half) {
    uint16_t h;
    std::memcpy(&h, p, 2);
    return half_to_float(h);
  }
  const int cb = k.bytes / k.components;
  if (k.is_bool) return p[0] ? 1.0f : 0.0f;
  if (k.integer) {
    if (cb == 4) { int32_t v; std::memcpy(&v, p, 4); return float(v); }
    int64_t v; std::memcpy(&v, p, 8); return float(v);
  }
  if (cb == 4) { float v; std::memcpy(&v, p, 4); return v; }
  double v; std::memcpy(&v, p, 8);
  if (!std::isfinite(v)) return float(v);
  return float(std::clamp(v, -3.0e38, 3.0e38));
}

struct Value {
  std::array<float, 3> c{0, 0, 0};
};

Value read_value(Reader& r, const ValueKind& k, const char* what) {
  const uint8_t* p = r.take(size_t(k.bytes), what);
  Value v;
  const int cb = k.bytes / k.components;
  for (int c = 0; c < k.components; ++c) v.c[c] = component(p + c * cb, k, false);
  return v;
}

template <int kWords>
struct Mask {
  std::array<uint64_t, kWords> w{};
  void load(Reader& r) { std::memcpy(w.data(), r.take(8 * kWords, "node mask"), 8 * kWords); }
  bool on(size_t n) const { return (w[n >> 6] >> (n & 63)) & 1; }
  size_t count() const {
    size_t c = 0;
    for (uint64_t x : w) c += size_t(__builtin_popcountll(x));
    return c;
  }
};

// The grid being read: its value kind, compression and the tree topology gathered so far.
struct GridContext {
  ValueKind kind;
  uint32_t compression = 0;
  bool half = false;
  Value background;
  std::vector<VolumeGrid::Leaf> leaves;
  std::vector<VolumeGrid::Tile> tiles;
};

// readData: `count` values of `elem` bytes under the grid's codec.
void read_data(Reader& r, const GridContext& g, size_t count, size_t elem, std::vector<uint8_t>& out) {
  const size_t bytes = count * elem;
  out.resize(bytes);
  if (g.compression & (kVdbBlosc | kVdbZip)) {
    const int64_t n = r.get<int64_t>("compressed size");
    if (n <= 0) {  // stored uncompressed
      if (n == std::numeric_limits<int64_t>::min() || uint64_t(-n) != bytes) fail("uncompressed block of the wrong size");
      const uint8_t* src = r.take(bytes, "uncompressed block");
      if (bytes) std::memcpy(out.data(), src, bytes);
      return;
    }
    if (uint64_t(n) > r.left()) fail("truncated (compressed block)");
    const uint8_t* src = r.take(size_t(n), "compressed block");
    if (g.compression & kVdbBlosc) vdb_blosc_decompress(src, size_t(n), out.data(), bytes);
    else vdb_zlib_decompress(src, size_t(n), out.data(), bytes);
    return;
  }
  if (bytes) std::memcpy(out.data(), r.take(bytes, "values"), bytes);
}

// readCompressedValues: `count` node values (count = the mask's size) into floats
// (components per value), restoring inactive values under active-mask compression.
template <int kWords>
void read_compressed_values(Reader& r, const GridContext& g, const Mask<kWords>& value_mask, std::vector<float>& out) {
  constexpr size_t count = size_t(kWords) * 64;
  const ValueKind& k = g.kind;
  const int nc = k.components;
  const int8_t meta = r.get<int8_t>("node metadata");
  if (meta < 0 || meta > 6) fail("bad node metadata " + std::to_string(int(meta)));
  Value inactive1 = g.background, inactive0 = g.background;
  if (meta != 0)
    for (int c = 0; c < 3; ++c) inactive0.c[c] = -g.background.c[c];
  if (meta == 2 || meta == 4 || meta == 5) {
    inactive0 = read_value(r, k, "inactive value");
    if (meta == 5) inactive1 = read_value(r, k, "inactive value");
  }
  Mask<kWords> selection;
  if (meta == 3 || meta == 4 || meta == 5) selection.load(r);
  const bool mask_compressed = (g.compression & kVdbActiveMask) && meta != 6;
  const size_t stored = mask_compressed ? value_mask.count() : count;
  const bool half = g.half && k.real;
  const size_t elem = half ? size_t(2 * nc) : size_t(k.bytes);
  static thread_local std::vector<uint8_t> raw;
  read_data(r, g, stored, elem, raw);
  out.resize(count * nc);
  const int cb = int(elem) / nc;
  size_t s = 0;
  for (size_t n = 0; n < count; ++n) {
    if (stored == count || value_mask.on(n)) {
      const uint8_t* p = raw.data() + (s++) * elem;
      for (int c = 0; c < nc; ++c) out[n * nc + c] = component(p + c * cb, k, half);
    } else {
      const Value& v = selection.on(n) ? inactive1 : inactive0;
      for (int c = 0; c < nc; ++c) out[n * nc + c] = v.c[c];
    }
  }
}

// Topology of a leaf: its value mask. Topology of internal nodes: child and value masks, then
// the tile values, then the children in mask order.
void read_leaf_topology(Reader& r, GridContext& g, const std::array<int32_t, 3>& origin) {
  VolumeGrid::Leaf leaf;
  leaf.origin = origin;
  Mask<8> m;
  m.load(r);
  leaf.active = m.w;
  g.leaves.push_back(std::move(leaf));
}

template <int kLog2, int kChildLog2>
void read_internal_topology(Reader& r, GridContext& g, const std::array<int32_t, 3>& origin) {
  constexpr int kWords = (1 << (3 * kLog2)) / 64;
  Mask<kWords> child, value;
  child.load(r);
  value.load(r);
  std::vector<float> values;
  read_compressed_values(r, g, value, values);
  const int nc = g.kind.components;
  const std::array<float, 3>& bg = g.background.c;
  for (size_t n = 0; n < size_t(kWords) * 64; ++n) {
    const std::array<int32_t, 3> o = {origin[0] + int32_t((n >> (2 * kLog2)) << kChildLog2),
                                      origin[1] + int32_t(((n >> kLog2) & ((1 << kLog2) - 1)) << kChildLog2),
                                      origin[2] + int32_t((n & ((1 << kLog2) - 1)) << kChildLog2)};
    if (child.on(n)) {
      if constexpr (kChildLog2 == 3) read_leaf_topology(r, g, o);
      else read_internal_topology<4, 3>(r, g, o);
      continue;
    }
    VolumeGrid::Tile t;
    t.origin = o;
    t.size = 1 << kChildLog2;
    t.active = value.on(n);
    bool differs = false;
    for (int c = 0; c < 3; ++c) {
      t.value[c] = c < nc ? values[n * nc + c] : 0.0f;
      if (c < nc && !(t.value[c] == bg[c])) differs = true;
    }
    if (t.active || differs) g.tiles.push_back(t);
  }
}

void read_leaf_buffers(Reader& r, GridContext& g, VolumeGrid::Leaf& leaf) {
  Mask<8> m;
  m.load(r);  // the value mask again
  leaf.active = m.w;
  const int nc = g.kind.components;
  if (g.kind.is_bool) {
    r.take(12, "bool leaf origin");
    Mask<8> bits;
    bits.load(r);
    leaf.values.resize(512);
    for (size_t n = 0; n < 512; ++n) leaf.values[n] = bits.on(n) ? 1.0f : 0.0f;
    return;
  }
  read_compressed_values(r, g, m, leaf.values);
  leaf.values.resize(size_t(512) * nc);
}

std::array<double, 16> read_transform(Reader& r) {
  const std::string type = r.string("transform type", 256);
  auto vec = [&](double v[3]) {
    for (int a = 0; a < 3; ++a) v[a] = r.get<double>("transform");
  };
  double scale[3] = {1, 1, 1}, trans[3] = {0, 0, 0}, skip[3];
  std::array<double, 16> m = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};
  if (type == "ScaleMap" || type == "UniformScaleMap") {
    vec(scale);
    for (int n = 0; n < 4; ++n) vec(skip);  // voxel size, inverse scale, 1/scale^2, 1/(2 scale)
  } else if (type == "ScaleTranslateMap" || type == "UniformScaleTranslateMap") {
    vec(trans);
    vec(scale);
    for (int n = 0; n < 4; ++n) vec(skip);
  } else if (type == "TranslationMap") {
    vec(trans);
  } else if (type == "AffineMap" || type == "UnitaryMap") {
    // Mat4d, row-vector convention (p' = p M): the transpose is our column-vector matrix.
    double a[16];
    for (double& v : a) v = r.get<double>("transform");
    for (int i = 0; i < 4; ++i)
      for (int j = 0; j < 4; ++j) m[4 * i + j] = a[4 * j + i];
    m[12] = m[13] = m[14] = 0;
    m[15] = 1;
    return m;
  } else {
    fail("transform type '" + type + "' is not supported");
  }
  for (int a = 0; a < 3; ++a) {
    m[5 * a] = scale[a];
    m[4 * a + 3] = trans[a];
  }
  return m;
}

struct Metadata {
  std::string grid_class;
  bool half = false;
};

Metadata read_metadata(Reader& r) {
  Metadata md;
  const uint32_t count = r.get<uint32_t>("metadata count");
  if (count > r.left() / 12) fail("metadata count " + std::to_string(count) + " beyond the file");
  for (uint32_t n = 0; n < count; ++n) {
    const std::string name = r.string("metadata name", 1 << 16);
    const std::string type = r.string("metadata type", 1 << 16);
    const uint32_t size = r.get<uint32_t>("metadata size");
    const uint8_t* p = r.take(size, "metadata value");
    if (name == "class" && type == "string") md.grid_class.assign(reinterpret_cast<const char*>(p), size);
    if (name == "is_saved_as_half_float" && type == "bool" && size >= 1) md.half = p[0] != 0;
  }
  return md;
}

std::shared_ptr<VolumeGrid> read_grid(Reader& r, VdbGridRecord& rec, const ValueKind& kind, const VdbReadOptions& opt) {
  GridContext g;
  g.kind = kind;
  rec.compression = r.get<uint32_t>("grid compression");
  if (rec.compression & ~uint32_t(7)) fail("unknown compression flags " + std::to_string(rec.compression));
  g.compression = rec.compression;
  const Metadata md = read_metadata(r);
  g.half = (rec.half_float || md.half) && kind.real;
  rec.half_float = g.half;
  auto grid = std::make_shared<VolumeGrid>();
  grid->name = rec.name;
  grid->value_type = kind.name;
  grid->grid_class = md.grid_class;
  grid->saved_as_half = g.half;
  grid->set_transform(read_transform(r));

  const int32_t buffers = r.get<int32_t>("buffer count");
  if (buffers != 1) fail("buffer count " + std::to_string(buffers) + " (only 1 is supported)");
  g.background = read_value(r, kind, "background");
  const uint32_t ntiles = r.get<uint32_t>("root tile count");
  const uint32_t nchildren = r.get<uint32_t>("root child count");
  const size_t tile_bytes = 12 + size_t(kind.bytes) + 1;
  if (ntiles > r.left() / tile_bytes) fail("root tile count " + std::to_string(ntiles) + " beyond the file");
  if (nchildren > r.left() / (12 + 8192)) fail("root child count " + std::to_string(nchildren) + " beyond the file");
  auto check_origin = [](const std::array<int32_t, 3>& o) {
    for (int32_t v : o)
      if ((v & 4095) != 0 || v < -(1 << 30) || v > (1 << 30)) fail("root node origin " + std::to_string(v) + " not on the 4096 grid");
  };
  for (uint32_t n = 0; n < ntiles; ++n) {
    VolumeGrid::Tile t;
    for (int a = 0; a < 3; ++a) t.origin[a] = r.get<int32_t>("root tile");
    check_origin(t.origin);
    t.value = read_value(r, kind, "root tile").c;
    t.active = r.get<uint8_t>("root tile") != 0;
    t.size = 4096;
    g.tiles.push_back(t);
  }
  // Children: topology in file order; buffers in the root's (sorted by origin) order.
  struct Child {
    std::array<int32_t, 3> origin;
    size_t first, last;
  };
  std::vector<Child> children;
  for (uint32_t n = 0; n < nchildren; ++n) {
    Child c;
    for (int a = 0; a < 3; ++a) c.origin[a] = r.get<int32_t>("root child");
    check_origin(c.origin);
    c.first = g.leaves.size();
    read_internal_topology<5, 7>(r, g, c.origin);
    c.last = g.leaves.size();
    children.push_back(c);
    if (int64_t(g.leaves.size()) > opt.limits.max_bricks)
      fail(std::to_string(g.leaves.size()) + " leaves exceed the limit");
  }
  grid->saved_as_half = g.half;
  if (opt.topology_only) return grid;
  std::stable_sort(children.begin(), children.end(), [](const Child& a, const Child& b) { return a.origin < b.origin; });
  for (const Child& c : children)
    for (size_t l = c.first; l < c.last; ++l) read_leaf_buffers(r, g, g.leaves[l]);
  grid->build(kind.components, g.background.c, g.leaves, g.tiles, opt.limits);
  return grid;
}

}  // namespace

VdbFile read_vdb_memory(const uint8_t* data, size_t size, const VdbReadOptions& opt) {
  Reader r(data, size);
  VdbFile f;
  const uint64_t magic = r.get<uint64_t>("magic");
  if (magic != 0x56444220ull) fail("not an OpenVDB file (bad magic number)");
  f.file_version = r.get<uint32_t>("version");
  if (f.file_version < kMinVersion || f.file_version > kMaxVersion)
    fail("file format version " + std::to_string(f.file_version) + " is not supported (222 to 224: OpenVDB 3 to 12)");
  f.library_major = r.get<uint32_t>("library version");
  f.library_minor = r.get<uint32_t>("library version");
  const bool offsets = r.get<uint8_t>("grid offsets flag") != 0;
  const uint8_t* uuid = r.take(36, "uuid");
  f.uuid.assign(reinterpret_cast<const char*>(uuid), 36);
  read_metadata(r);  // file metadata
  const int32_t ngrids = r.get<int32_t>("grid count");
  if (ngrids < 0 || size_t(ngrids) > r.left() / 40) fail("grid count " + std::to_string(ngrids) + " beyond the file");
  for (int32_t n = 0; n < ngrids; ++n) {
    VdbGridRecord rec;
    rec.name = r.string("grid name", 1 << 16);
    const size_t sep = rec.name.find('\x1e');  // OpenVDB's unique-name separator
    if (sep != std::string::npos) rec.name.resize(sep);
    rec.tree_type = r.string("grid type", 1 << 16);
    const std::string half_suffix = "_HalfFloat";
    if (rec.tree_type.size() > half_suffix.size() &&
        rec.tree_type.compare(rec.tree_type.size() - half_suffix.size(), half_suffix.size(), half_suffix) == 0) {
      rec.half_float = true;
      rec.tree_type.resize(rec.tree_type.size() - half_suffix.size());
    }
    const std::string parent = r.string("instance parent", 1 << 16);
    const int64_t grid_pos = r.get<int64_t>("grid offset");
    r.get<int64_t>("block offset");
    const int64_t end_pos = r.get<int64_t>("grid end");
    if (offsets) {
      if (grid_pos < int64_t(r.pos()) || end_pos < grid_pos || uint64_t(end_pos) > size) fail("grid offsets outside the file");
    }
    ValueKind kind;
    const bool wanted = opt.only_grid.empty() || opt.only_grid == rec.name;
    if (!wanted) {
      rec.skipped = "not requested";
    } else if (!parent.empty()) {
      // An instance shares its parent's tree; copy the parent's voxels under its own transform.
      auto it = std::find_if(f.grids.begin(), f.grids.end(), [&](const VdbGridRecord& g) { return g.grid && g.name == parent.substr(0, parent.find('\x1e')); });
      if (it == f.grids.end() || !offsets) {
        rec.skipped = "instance of a grid that was not read";
      } else {
        r.seek(grid_pos);
        rec.compression = r.get<uint32_t>("grid compression");
        read_metadata(r);
        auto g = std::make_shared<VolumeGrid>(*it->grid);
        g->name = rec.name;
        g->set_transform(read_transform(r));
        rec.grid = g;
      }
    } else if (!value_kind(rec.tree_type, kind)) {
      rec.skipped = "grid type '" + rec.tree_type + "' is not supported";
    } else {
      if (offsets) r.seek(grid_pos);
      rec.grid = read_grid(r, rec, kind, opt);
      if (offsets && !opt.topology_only && int64_t(r.pos()) != end_pos)
        fail("grid '" + rec.name + "' ends at byte " + std::to_string(r.pos()) + ", its descriptor says " + std::to_string(end_pos));
    }
    if (offsets) r.seek(end_pos);
    else if (!rec.grid) {  // a stream without offsets cannot skip a grid
      f.grids.push_back(std::move(rec));
      break;
    }
    f.grids.push_back(std::move(rec));
  }
  return f;
}

VdbFile read_vdb_file(const std::string& path, const VdbReadOptions& opt) {
  std::ifstream in(path, std::ios::binary | std::ios::ate);
  if (!in) throw VdbError("cannot open VDB file '" + path + "'");
  const std::streamoff size = in.tellg();
  if (size < 0) throw VdbError("cannot read VDB file '" + path + "'");
  if (size > opt.max_file_bytes) throw VdbError("VDB file '" + path + "' is larger than the limit");
  std::vector<uint8_t> data(static_cast<size_t>(size));
  in.seekg(0);
  if (size && !in.read(reinterpret_cast<char*>(data.data()), size)) throw VdbError("cannot read VDB file '" + path + "'");
  try {
    return read_vdb_memory(data.data(), data.size(), opt);
  } catch (const VdbError& e) {
    throw VdbError(std::string(e.what()) + " ('" + path + "')");
  }
}

}  // namespace pl
