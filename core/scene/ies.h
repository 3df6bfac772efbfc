// IES light profiles (IESNA LM-63: 1986, 1991, 1995, 2002), read and looked up as Cycles 4.5's
// IES Texture does (util/ies.cpp, kernel/svm/ies.h): candelas times 4 pi / 177.83 (the D65
// luminous efficacy, per unit of Cycles' lamp strength), types A, B and C mapped onto type C's
// angles (vertical 0 = straight down, the light's local -Z), symmetric profiles mirrored to the
// full circle, and Catmull-Rom interpolation in both angles with Cycles' edge rules.
#pragma once
#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

#include "util/math.h"

namespace pl {

struct IesProfile {
  std::vector<float> h, v;  // ascending angles, radians (Cycles' convention after processing)
  std::vector<float> cd;    // intensity per (h, v), h-major: cd[i * v.size() + j]
  // Cycles' neighbours beyond the table's ends: mirrored at the low vertical end, wrapped
  // around horizontally / mirrored at the high vertical end only where its float tests say so.
  bool wrap_h = false, wrap_vlow = false, wrap_vhigh = false;
  float mean = 0.0f;  // mean value over the sphere of directions (for choosing among lights)
};

// Parses and processes an IES file's text; false (and a reason in err) where Cycles would reject
// it or where it is unusable (counts beyond kIesMaxAngles, angles not finite or not ascending,
// intensities not finite).
bool parse_ies(const std::string& text, IesProfile& out, std::string& err);

constexpr int kIesMaxAngles = 100000;  // per axis; real files have a few hundred at most

// The profile's value at Cycles' angles (h = atan2(x, y) + pi, v = acos(-z) of the local
// direction), 0 outside the table's ranges.
float ies_lookup(const IesProfile& p, float h_angle, float v_angle);

// The value towards the local direction d (any length) from the light, as the IES Texture node
// evaluates it with its default Vector (the light's local emission direction).
inline float ies_eval(const IesProfile& p, Vec3 d) {
  const float len = length(d);
  if (!(len > 0.0f)) return 0.0f;
  d = d / len;
  const float v_angle = std::acos(std::clamp(-d.z, -1.0f, 1.0f));
  const float h_angle = std::atan2(d.x, d.y) + kPi;
  return ies_lookup(p, h_angle, v_angle);
}

}  // namespace pl
