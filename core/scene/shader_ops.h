#pragma once
// The names of the shader language's sub-operations, in their enums' order (shader.h): the
// bindings parse op tuples with these tables and expose them (pathlight_core.shader_op_table),
// and the add-on's compiler reads them from there, so no second list has to be kept in order.
// They are the identifiers of the Blender node settings the ops implement.
#include <cstddef>
#include <cstdint>

#include "scene/shader.h"

namespace pl {

struct SubOpName {
  const char* name;
  uint8_t operands;  // the values (Math) or vectors (Vector Math) it reads
  bool value_out = false;   // Vector Math: the result is a float (Dot Product, Distance, Length)
  bool reads_scale = false;  // Vector Math: it reads the Scale input too
};

inline constexpr SubOpName kMathOpNames[] = {
    {"ADD", 2}, {"SUBTRACT", 2}, {"MULTIPLY", 2}, {"DIVIDE", 2}, {"POWER", 2}, {"MINIMUM", 2},
    {"MAXIMUM", 2}, {"LESS_THAN", 2}, {"GREATER_THAN", 2}, {"ABSOLUTE", 1}, {"LOGARITHM", 2},
    {"SQRT", 1}, {"INVERSE_SQRT", 1}, {"EXPONENT", 1}, {"SIGN", 1}, {"ROUND", 1}, {"FLOOR", 1},
    {"CEIL", 1}, {"TRUNC", 1}, {"FRACT", 1}, {"MODULO", 2}, {"FLOORED_MODULO", 2}, {"SNAP", 2},
    {"PINGPONG", 2}, {"SINE", 1}, {"COSINE", 1}, {"TANGENT", 1}, {"ARCSINE", 1}, {"ARCCOSINE", 1},
    {"ARCTANGENT", 1}, {"ARCTAN2", 2}, {"SINH", 1}, {"COSH", 1}, {"TANH", 1}, {"RADIANS", 1},
    {"DEGREES", 1}, {"MULTIPLY_ADD", 3}, {"COMPARE", 3}, {"SMOOTH_MIN", 3}, {"SMOOTH_MAX", 3},
    {"WRAP", 3},
};
static_assert(std::size(kMathOpNames) == size_t(MathOp::Wrap) + 1, "one name per MathOp");

inline constexpr SubOpName kVectorMathOpNames[] = {
    {"ADD", 2}, {"SUBTRACT", 2}, {"MULTIPLY", 2}, {"DIVIDE", 2}, {"MULTIPLY_ADD", 3},
    {"CROSS_PRODUCT", 2}, {"PROJECT", 2}, {"REFLECT", 2}, {"REFRACT", 2, false, true}, {"FACEFORWARD", 3},
    {"DOT_PRODUCT", 2, true}, {"DISTANCE", 2, true}, {"LENGTH", 1, true}, {"SCALE", 1, false, true},
    {"NORMALIZE", 1}, {"ABSOLUTE", 1}, {"POWER", 2}, {"SIGN", 1}, {"MINIMUM", 2}, {"MAXIMUM", 2},
    {"FLOOR", 1}, {"CEIL", 1}, {"FRACTION", 1}, {"MODULO", 2}, {"WRAP", 3}, {"SNAP", 2},
    {"SINE", 1}, {"COSINE", 1}, {"TANGENT", 1},
};
static_assert(std::size(kVectorMathOpNames) == size_t(VectorMathOp::Tangent) + 1, "one name per VectorMathOp");

inline constexpr SubOpName kMixOpNames[] = {
    {"MIX", 2}, {"MULTIPLY", 2}, {"ADD", 2}, {"SUBTRACT", 2}, {"SCREEN", 2}, {"DIVIDE", 2},
    {"DIFFERENCE", 2}, {"DARKEN", 2}, {"LIGHTEN", 2}, {"OVERLAY", 2},
};
static_assert(std::size(kMixOpNames) == size_t(MixOp::Overlay) + 1, "one name per MixOp");

inline constexpr SubOpName kColorSpaceOpNames[] = {
    {"RGB_TO_HSV", 1}, {"HSV_TO_RGB", 1}, {"RGB_TO_HSL", 1}, {"HSL_TO_RGB", 1},
};
static_assert(std::size(kColorSpaceOpNames) == size_t(ColorSpaceOp::HslToRgb) + 1, "one name per ColorSpaceOp");

inline constexpr SubOpName kMapRangeOpNames[] = {
    {"LINEAR", 5}, {"STEPPED", 6}, {"SMOOTHSTEP", 5}, {"SMOOTHERSTEP", 5},
};
static_assert(std::size(kMapRangeOpNames) == size_t(MapRangeOp::SmootherStep) + 1, "one name per MapRangeOp");

inline constexpr SubOpName kClampOpNames[] = {{"MINMAX", 3}, {"RANGE", 3}};

// The value ops of the program language (op tuples `(name, dst, registers..., parameters...)`,
// docs/core_api.md) and how many register operands follow the destination: the add-on's dead-code
// elimination and register allocation read these; the bindings' parser accepts exactly these
// names (tests/blender/test_core_materials.py checks both ways).
struct OpSignature {
  const char* name;
  uint8_t registers;
};
inline constexpr OpSignature kValueOps[] = {
    {"const", 0}, {"uv", 0}, {"position", 0}, {"normal", 0}, {"object", 0}, {"generated", 0},
    {"light_path", 0}, {"object_info", 0}, {"curves_info", 0}, {"attribute", 0}, {"geometry", 0},
    {"object_normal", 0}, {"mapping", 1}, {"image", 1}, {"rgb_to_bw", 1}, {"math", 2},
    {"math3", 3}, {"mix", 3}, {"normal_map", 2}, {"fresnel", 2}, {"layer_weight", 2}, {"bump", 6},
    {"ramp", 1}, {"separate", 1}, {"combine", 3}, {"color_space", 1}, {"hsv", 5}, {"gamma", 2},
    {"bright_contrast", 3}, {"clamp", 3}, {"map_range", 6}, {"map_range_vector", 6},
    {"vector_math", 4}, {"tex_noise", 9}, {"tex_wave", 7}, {"tex_magic", 3},
    {"tex_white_noise", 2}, {"checker", 4}, {"gradient", 1}, {"brick", 10}, {"voronoi", 9},
    {"vector_rotate", 5}, {"vector_transform", 1}, {"blackbody", 1}, {"wavelength", 1},
    {"camera_coords", 0}, {"tangent", 0}, {"tex_gabor", 6}, {"ambient_occlusion", 3},
    {"bevel", 2}, {"wireframe", 1}, {"object_attribute", 0},
};

}  // namespace pl
