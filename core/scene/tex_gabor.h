// Blender's Gabor Texture (4.3+) as Cycles evaluates it: sparse Gabor convolution with eight
// impulses per cell (Lagae et al. 2009, Tavernier et al. 2019's Bernoulli weights and
// normalisation), phasor formulation for Phase and Intensity (Tricard et al. 2019), Cycles'
// lookup3 hashes for the impulses, so the same pattern appears at the same point.
#pragma once
#include "util/math.h"

namespace pl {

struct GaborOutput {
  float value = 0.5f, phase = 0.5f, intensity = 0.0f;
};

// dims: 2 or 3; orientation_2d in radians, orientation_3d a direction (normalised here).
GaborOutput gabor_texture(int dims, Vec3 co, float scale, float frequency, float anisotropy, float orientation_2d,
                          Vec3 orientation_3d);

}  // namespace pl
