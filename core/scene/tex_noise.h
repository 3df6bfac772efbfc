// Blender's Noise, Wave, Magic and White Noise textures, as Cycles evaluates them (the same
// hashes, Perlin gradients, fractal loops and constants), so the same pattern appears at the
// same shading point. Inputs are the node's, after the shader program has read them.
#pragma once
#include "util/math.h"

namespace pl {

// Blender's Noise Type (the order of Cycles' NodeNoiseType).
enum class NoiseType : uint8_t { Multifractal, Fbm, HybridMultifractal, RidgedMultifractal, HeteroTerrain };

struct NoiseInputs {
  Vec3 co{0.0f};
  float w = 0.0f, scale = 5.0f, detail = 2.0f, roughness = 0.5f, lacunarity = 2.0f;
  float offset = 0.0f, gain = 1.0f, distortion = 0.0f;
};

// The Noise Texture node in `dims` (1-4) dimensions: Fac, or with `color` its Color output
// (Fac in red, two offset evaluations in green and blue).
Vec3 noise_texture(int dims, NoiseType type, bool normalize, bool color, const NoiseInputs& in);

// Wave Texture: type 0 Bands, 1 Rings; direction X, Y, Z, then Diagonal (bands) or Spherical
// (rings); profile 0 Sine, 1 Saw, 2 Triangle.
float wave_texture(int type, int direction, int profile, Vec3 co, float scale, float distortion, float detail,
                   float detail_scale, float detail_roughness, float phase);

// Magic Texture's Color (Fac is its average).
Vec3 magic_texture(Vec3 co, float scale, int depth, float distortion);

// White Noise Texture in `dims` (1-4) dimensions: Value in all three, or its Color.
Vec3 white_noise_texture(int dims, bool color, Vec3 co, float w);

}  // namespace pl
