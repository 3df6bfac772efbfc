// Blender's Checker, Gradient, Brick and Voronoi textures, evaluated as Cycles evaluates them
// (same hashes, same float steps, same loop orders), so that the same pattern appears at the
// same shading point. Inputs are the node's socket values after its own clamping is applied
// here; coordinates are the Vector input (and W) before the node's Scale.
#pragma once
#include <cstdint>

#include "util/math.h"

namespace pl {
struct Float4;
struct ShaderOp;
}  // namespace pl

namespace pl::tex {

// Checker: 1 on Color1 squares, 0 on Color2 ones (p already multiplied by Scale).
float checker(Vec3 p);

// Blender's gradient types, in the order of its enum.
enum class GradientType : uint8_t { Linear, Quadratic, Easing, Diagonal, Spherical, QuadraticSphere, Radial };
// The Fac output in [0, 1].
float gradient(Vec3 p, GradientType type);

struct BrickParams {
  float mortar_size = 0.02f, mortar_smooth = 0.1f, bias = 0.0f;
  float brick_width = 0.5f, row_height = 0.25f;
  float offset = 0.5f, squash = 1.0f;
  int offset_frequency = 2, squash_frequency = 2;
};
struct BrickSample {
  float tint;    // how far towards Color2 this brick is, in [0, 1]
  float mortar;  // the Fac output: 1 in the mortar, 0 inside a brick
};
// p already multiplied by Scale.
BrickSample brick(Vec3 p, const BrickParams& params);

enum class VoronoiFeature : uint8_t { F1, F2, SmoothF1, DistanceToEdge, NSphereRadius };
enum class VoronoiMetric : uint8_t { Euclidean, Manhattan, Chebychev, Minkowski };

struct VoronoiParams {
  int dimensions = 3;  // 1 (W), 2 (xy), 3 (xyz) or 4 (xyz and W)
  VoronoiFeature feature = VoronoiFeature::F1;
  VoronoiMetric metric = VoronoiMetric::Euclidean;
  bool normalize = false;
  // The node's inputs as given (the clamps Cycles applies happen inside voronoi()).
  float scale = 5.0f, detail = 0.0f, roughness = 0.5f, lacunarity = 2.0f;
  float smoothness = 1.0f, exponent = 0.5f, randomness = 1.0f;
  // Whether the Color output is read: Smooth F1 otherwise skips hashing every cell's colour
  // (3 of its 7 hashes per cell; the other outputs are unchanged).
  bool need_color = true;
};
struct VoronoiResult {
  float distance = 0.0f;
  Vec3 color{0.0f};
  Vec3 position{0.0f};
  float w = 0.0f;
  float radius = 0.0f;
};
VoronoiResult voronoi(const VoronoiParams& params, Vec3 coord, float w);

// One Checker / Gradient / Brick / Voronoi op of a shader program over its registers `r`
// (operands and settings as bindings.cpp's parse_program lays them out); non-finite results
// read as 0.
Float4 eval_pattern_op(const ShaderOp& op, const Float4* r);

}  // namespace pl::tex
