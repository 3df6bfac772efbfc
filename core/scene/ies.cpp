// IES profiles: the LM-63 reader and Cycles 4.5's lookup (see ies.h).
#include "scene/ies.h"

#include <cerrno>
#include <cstdlib>
#include <cstring>

namespace pl {

namespace {

// Numbers in the text after TILT=, commas as blanks (Cycles' IESTextParser): a failed read sets
// `error` and every later read fails too.
class IesReader {
 public:
  explicit IesReader(const std::string& s) : text_(s.begin(), s.end()) {
    text_.push_back('\0');
    for (char& c : text_)
      if (c == ',') c = ' ';
    pos_ = std::strstr(text_.data(), "\nTILT=");
  }
  bool eof() const { return pos_ == nullptr || *pos_ == '\0'; }
  bool error() const { return error_; }
  char*& pos() { return pos_; }
  double real() {
    if (eof()) return fail();
    char* end = nullptr;
    const double x = std::strtod(pos_, &end);
    if (end == pos_) return fail();
    pos_ = end;
    return x;
  }
  long integer() {
    if (eof()) return long(fail());
    char* end = nullptr;
    errno = 0;
    const long x = std::strtol(pos_, &end, 10);
    if (end == pos_ || errno == ERANGE) return long(fail());
    pos_ = end;
    return x;
  }

 private:
  double fail() {
    error_ = true;
    pos_ = nullptr;
    return 0.0;
  }
  std::vector<char> text_;
  char* pos_ = nullptr;
  bool error_ = false;
};

using Rows = std::vector<std::vector<float>>;  // intensity per horizontal angle

// Type A (Cycles' process_type_a): vertical + 90, horizontal -90..90 onto 270..90 of type C,
// a half mirrored about 0 where the file has no negative angles.
void process_type_a(std::vector<float>& h, std::vector<float>& v, Rows& rows) {
  for (float& a : v) a += 90.0f;
  std::vector<float> nh;
  Rows nr;
  bool negative = false;
  for (size_t i = h.size(); i-- > 0;) {
    negative = negative || h[i] < 0.0f;
    nh.push_back(180.0f - h[i]);
    nr.push_back(rows[i]);
  }
  if (!negative && h[0] == 0.0f) {
    for (size_t i = 1; i < h.size(); ++i) {
      nh.push_back(180.0f + h[i]);
      nr.push_back(rows[i]);
    }
  }
  h.swap(nh);
  rows.swap(nr);
}

// Type B (Cycles' process_type_b): the axes swapped, then each mirrored from 0..90 or shifted
// from -90..90, and the 0 entry repeated at 360.
bool process_type_b(std::vector<float>& h, std::vector<float>& v, Rows& rows) {
  Rows t(v.size(), std::vector<float>(h.size()));
  for (size_t i = 0; i < v.size(); ++i)
    for (size_t j = 0; j < h.size(); ++j) t[i][j] = rows[j][i];
  rows.swap(t);
  h.swap(v);
  if (h.back() != 90.0f) return false;
  if (h.front() == 0.0f) {
    std::vector<float> nh;
    Rows nr;
    for (size_t i = h.size() - 1; i > 0; --i) {
      nh.push_back(90.0f - h[i]);
      nr.push_back(rows[i]);
    }
    for (size_t i = 0; i < h.size(); ++i) {
      nh.push_back(90.0f + h[i]);
      nr.push_back(rows[i]);
    }
    h.swap(nh);
    rows.swap(nr);
  } else if (h.front() == -90.0f) {
    for (float& a : h) a += 90.0f;
  }
  h.push_back(360.0f);
  rows.push_back(rows[0]);
  if (v.back() != 90.0f) return false;
  if (v.front() == 0.0f) {
    const size_t n = v.size();
    std::vector<float> nv;
    for (size_t i = n - 1; i > 0; --i) nv.push_back(90.0f - v[i]);
    for (size_t i = 0; i < n; ++i) nv.push_back(90.0f + v[i]);
    for (auto& row : rows) {
      std::vector<float> nrow;
      for (size_t j = n - 1; j-- > 0;) nrow.push_back(row[j]);
      nrow.insert(nrow.end(), row.begin(), row.end());
      row.swap(nrow);
    }
    v.swap(nv);
  } else if (v.front() == -90.0f) {
    for (float& a : v) a += 90.0f;
  }
  return true;
}

// Type C (Cycles' process_type_c): 90..270 files rotated to 0..180, one quadrant or a half
// mirrored to the full circle, a missing 360 entry restored where the spacing shows it.
bool process_type_c(std::vector<float>& h, std::vector<float>& v, Rows& rows) {
  if (h[0] == 90.0f)
    for (float& a : h) a -= 90.0f;
  if (h[0] != 0.0f) return false;
  if (h.size() == 1) {
    h.push_back(360.0f);
    rows.push_back(rows[0]);
  }
  if (h.back() == 90.0f) {
    for (size_t i = h.size() - 1; i-- > 0;) {
      h.push_back(180.0f - h[i]);
      rows.push_back(rows[i]);
    }
  }
  if (h.back() == 180.0f) {
    for (size_t i = h.size() - 1; i-- > 0;) {
      h.push_back(360.0f - h[i]);
      rows.push_back(rows[i]);
    }
  }
  if (h.back() != 360.0f) {
    const size_t n = h.size();
    const float last_step = h[n - 1] - h[n - 2], first_step = h[1] - h[0];
    const float rest = 360.0f - h[n - 1];
    if (last_step != rest && first_step != rest) return false;
    h.push_back(360.0f);
    rows.push_back(rows[0]);
  }
  // Cycles keeps 90..180 as it is: such a profile lights only the upper hemisphere there.
  if (v[0] == 90.0f) return v.back() == 180.0f;
  return v[0] == 0.0f;
}

inline float cubic_interp(float a, float b, float c, float d, float x) {
  return 0.5f * (((d + 3.0f * (b - c) - a) * x + (2.0f * a - 5.0f * b + 4.0f * c - d)) * x + (c - a)) * x + b;
}

inline float frac_between(float lo, float hi, float x) {
  return hi > lo ? (x - lo) / (hi - lo) : 0.0f;  // equal angles: the lower entry
}

}  // namespace

bool parse_ies(const std::string& text, IesProfile& out, std::string& err) {
  out = IesProfile();
  IesReader r(text);
  if (r.eof()) {
    err = "no TILT= line";
    return false;
  }
  if (std::strncmp(r.pos(), "\nTILT=INCLUDE", 13) == 0) {
    r.pos() += 13;
    r.real();  // lamp-to-luminaire geometry
    const long tilts = r.integer();
    if (tilts < 0 || tilts > kIesMaxAngles) {
      err = "bad tilt count";
      return false;
    }
    for (long i = 0; i < 2 * tilts; ++i) r.real();  // angles and factors, ignored as by Cycles
  } else {
    r.pos() = std::strchr(r.pos() + 1, '\n');
  }
  if (r.eof()) {
    err = "nothing after the TILT line";
    return false;
  }
  ++r.pos();
  r.integer();                  // number of lamps
  r.real();                     // lumens per lamp
  double factor = r.real();     // candela multiplier
  const long nv = r.integer();  // vertical angles
  const long nh = r.integer();  // horizontal angles
  const long type = r.integer();
  if (r.error()) {
    err = "truncated header";
    return false;
  }
  if (type < 1 || type > 3) {
    err = "unknown photometric type " + std::to_string(type);
    return false;
  }
  if (nv < 1 || nh < 1 || nv > kIesMaxAngles || nh > kIesMaxAngles || double(nv) * double(nh) > 1e7) {
    err = "bad angle counts " + std::to_string(nv) + " x " + std::to_string(nh);
    return false;
  }
  r.integer();  // units
  r.real();     // width, length, height
  r.real();
  r.real();
  factor *= r.real();  // ballast factor
  factor *= r.real();  // ballast-lamp photometric factor
  r.real();            // input watts
  // Candela to Cycles' lamp strength: 4 pi / 177.83 (W/sr at D65's luminous efficacy, times 4 pi).
  factor *= 0.0706650768394;
  std::vector<float> v(static_cast<size_t>(nv)), h(static_cast<size_t>(nh));
  for (float& a : v) a = float(r.real());
  for (float& a : h) a = float(r.real());
  if (r.error()) {
    err = "truncated angle lists";
    return false;
  }
  Rows rows(static_cast<size_t>(nh), std::vector<float>(static_cast<size_t>(nv)));
  for (auto& row : rows)
    for (float& x : row) x = float(factor * r.real());
  if (r.error()) {
    err = "truncated candela values";
    return false;
  }
  const auto ascending = [](const std::vector<float>& a) {
    for (size_t i = 0; i < a.size(); ++i)
      if (!std::isfinite(a[i]) || (i > 0 && a[i] < a[i - 1])) return false;
    return true;
  };
  if (!ascending(v) || !ascending(h)) {
    err = "angles not finite or not ascending";
    return false;
  }
  for (const auto& row : rows)
    for (float x : row)
      if (!std::isfinite(x)) {
        err = "candela values or multipliers not finite";
        return false;
      }
  bool ok = true;
  if (type == 1) ok = process_type_c(h, v, rows);
  else if (type == 2) ok = process_type_b(h, v, rows);
  else process_type_a(h, v, rows);
  for (const auto& row : rows) ok = ok && row.size() == v.size();
  if (!ok || rows.size() != h.size()) {
    err = "unsupported angle ranges (Cycles rejects them too)";
    return false;
  }
  // Degrees to radians in float, as Cycles: its wrap tests below depend on the last bit.
  const float to_rad = kPi / 180.0f;
  for (float& a : h) a *= to_rad;
  for (float& a : v) a *= to_rad;
  out.h = h;
  out.v = v;
  out.cd.reserve(h.size() * v.size());
  for (const auto& row : rows) out.cd.insert(out.cd.end(), row.begin(), row.end());
  // Cycles' float tests: 2 pi - 1e-7 rounds to 2 pi, so a table ending at 360 degrees does not
  // wrap (its first and last intervals take 0 beyond the ends), nor one ending at 180 vertically.
  const float two_pi = 6.283185307179586f;
  out.wrap_h = out.h.front() < 1e-7f && out.h.back() > two_pi - 1e-7f;
  out.wrap_vlow = out.v.front() < 1e-7f;
  out.wrap_vhigh = out.v.back() > kPi - 1e-7f;
  // Mean over the sphere (midpoints uniform in cos v and in h), for the light's power estimate.
  constexpr int kRows = 64, kCols = 128;
  double sum = 0.0;
  for (int i = 0; i < kRows; ++i) {
    const float vz = std::acos(1.0f - 2.0f * (i + 0.5f) / kRows);
    for (int j = 0; j < kCols; ++j) sum += ies_lookup(out, 2.0f * kPi * (j + 0.5f) / kCols, vz);
  }
  // Floored by the table's peak, so that a profile lit only between the grid's points still
  // gets light samples.
  float peak = 0.0f;
  for (float x : out.cd) peak = std::max(peak, x);
  out.mean = std::max(float(sum / (kRows * kCols)), 1e-4f * peak);
  return true;
}

float ies_lookup(const IesProfile& p, float h_angle, float v_angle) {
  const int hn = int(p.h.size()), vn = int(p.v.size());
  if (hn < 2 || vn < 2) return 0.0f;
  if (!(v_angle >= p.v.front()) || !(v_angle < p.v.back())) return 0.0f;
  if (!(h_angle >= p.h.front()) || !(h_angle < p.h.back())) return 0.0f;
  int hi = 0, vi = 0;
  while (p.h[hi + 1] < h_angle) ++hi;
  while (p.v[vi + 1] < v_angle) ++vi;
  const float hf = frac_between(p.h[hi], p.h[hi + 1], h_angle);
  const float vf = frac_between(p.v[vi], p.v[vi + 1], v_angle);
  const auto vertical = [&](int h) {
    const float* row = &p.cd[size_t(h) * vn];
    const float a = vi > 0 ? row[vi - 1] : (p.wrap_vlow ? row[1] : 0.0f);
    const float d = vi + 2 < vn ? row[vi + 2] : (p.wrap_vhigh ? row[vn - 2] : 0.0f);
    return cubic_interp(a, row[vi], row[vi + 1], d, vf);
  };
  const float a = hi > 0 ? vertical(hi - 1) : (p.wrap_h ? vertical(hn - 2) : 0.0f);
  const float d = hi + 2 < hn ? vertical(hi + 2) : (p.wrap_h ? vertical(1) : 0.0f);
  return std::max(cubic_interp(a, vertical(hi), vertical(hi + 1), d, hf), 0.0f);
}

}  // namespace pl
