// Motion blur's transforms and shutter, as Cycles has them: a transform at each motion step
// (steps spread evenly over the shutter, ray time 0 at the first, 1 at the last) decomposed
// into translation, rotation quaternion and a 3x3 scale/shear; a ray at time t interpolates the
// two steps around it (translation and scale linearly, rotation by slerp) and composes them
// again. The shutter curve becomes an inverse-CDF table that maps a uniform number to a time.
#pragma once
#include <cstdint>
#include <vector>

#include "geometry/aabb.h"
#include "util/math.h"

namespace pl {

struct DecomposedTransform {
  float q[4] = {0, 0, 0, 1};  // rotation quaternion (x, y, z, w)
  Vec3 t{0.0f};               // translation
  float s[3][3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}};  // scale and shear: linear part = R(q) s
};

// Polar decomposition of m's linear part (Cycles' iteration R <- (R + R^-T) / 2); false when m
// is singular or not finite.
bool decompose_transform(const Mat4& m, DecomposedTransform& out);
// The steps of a motion, decomposed, each quaternion on the same side as the next one (the
// rotation between two steps takes the short way); false when a step is singular or not finite.
bool decompose_motion(const std::vector<Mat4>& steps, std::vector<DecomposedTransform>& out);
// The object-to-world matrix at `time` in [0, 1] over `n` >= 2 decomposed steps.
Mat4 motion_transform_at(const DecomposedTransform* steps, uint32_t n, float time);
// Its inverse (world to object), in float; a singular transform gives zeros.
Mat4 affine_inverse_fast(const Mat4& m);
// A box holding `box` (object space) under every transform of the motion at any time: the
// step boxes at sub-steps of at most a few degrees of rotation, grown by the arc's largest
// departure from their hull (conservative for the rotation between steps).
Aabb motion_world_box(const Aabb& box, const DecomposedTransform* steps, uint32_t n);

// Cycles' shutter table: kShutterTableSize times by inverse CDF of the shutter curve (its
// values sampled evenly over the shutter; empty or all zero: a box shutter).
class ShutterTable {
 public:
  static constexpr int kSize = 256;
  ShutterTable() { set_curve({}); }
  void set_curve(const std::vector<float>& curve);
  // Time in [0, 1] of the shutter for a uniform number u (linear lookup, as Cycles').
  float sample(float u) const {
    const float x = clampf(u, 0.0f, 1.0f) * float(kSize - 1);
    const int i = std::min(int(x), kSize - 1), j = std::min(i + 1, kSize - 1);
    const float f = x - float(i);
    return f == 0.0f ? table_[i] : (1.0f - f) * table_[i] + f * table_[j];
  }
  const float* table() const { return table_; }

 private:
  float table_[kSize];
};

}  // namespace pl
