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

// The names of the other settings that value ops choose by name, in their enums' or the
// evaluation's order.
inline constexpr const char* kInterpOpNames[] = {"LINEAR", "CLOSEST", "CUBIC"};
static_assert(std::size(kInterpOpNames) == size_t(Interp::Cubic) + 1, "one name per Interp");
// A grid read's interpolation: its index is the VolumeSampling (volume_grid.h).
inline constexpr const char* kVolumeInterpOpNames[] = {"CLOSEST", "LINEAR", "CUBIC"};
inline constexpr const char* kVoxelSpaces[] = {"WORLD", "OBJECT", "TEXTURE"};  // VoxelSpace
inline constexpr const char* kExtensionOpNames[] = {"REPEAT", "EXTEND", "CLIP", "MIRROR"};
static_assert(std::size(kExtensionOpNames) == size_t(Extension::Mirror) + 1, "one name per Extension");
inline constexpr const char* kLightPathOutputs[] = {
    "IS_CAMERA_RAY", "IS_SHADOW_RAY", "IS_DIFFUSE_RAY", "IS_GLOSSY_RAY", "IS_SINGULAR_RAY",
    "IS_REFLECTION_RAY", "IS_TRANSMISSION_RAY", "IS_VOLUME_SCATTER_RAY", "RAY_LENGTH",
    "RAY_DEPTH", "DIFFUSE_DEPTH", "GLOSSY_DEPTH", "TRANSPARENT_DEPTH", "TRANSMISSION_DEPTH"};
inline constexpr const char* kGeometryOutputs[] = {"TRUE_NORMAL", "INCOMING", "PARAMETRIC", "BACKFACING", "REFLECTION"};
inline constexpr const char* kCurvesInfoOutputs[] = {"IS_STRAND", "INTERCEPT", "LENGTH", "THICKNESS",
                                                     "TANGENT_NORMAL", "RANDOM"};
inline constexpr const char* kPointInfoOutputs[] = {"POSITION", "RADIUS", "RANDOM"};
inline constexpr const char* kObjectInfoOutputs[] = {"LOCATION", "COLOR", "ALPHA", "OBJECT_INDEX", "RANDOM"};
inline constexpr const char* kAttributeOutputs[] = {"COLOR", "FAC", "ALPHA"};
inline constexpr const char* kLayerWeightOutputs[] = {"FRESNEL", "FACING"};
inline constexpr const char* kNoiseTypes[] = {"MULTIFRACTAL", "FBM", "HYBRID_MULTIFRACTAL", "RIDGED_MULTIFRACTAL",
                                              "HETERO_TERRAIN"};
inline constexpr const char* kWaveTypes[] = {"BANDS", "RINGS"};
inline constexpr const char* kWaveBandsDirections[] = {"X", "Y", "Z", "DIAGONAL"};
inline constexpr const char* kWaveRingsDirections[] = {"X", "Y", "Z", "SPHERICAL"};
inline constexpr const char* kWaveProfiles[] = {"SIN", "SAW", "TRI"};
inline constexpr const char* kColorOrFac[] = {"COLOR", "FAC"};  // Checker and Brick outputs
inline constexpr const char* kGradientTypes[] = {"LINEAR", "QUADRATIC", "EASING", "DIAGONAL", "SPHERICAL",
                                                 "QUADRATIC_SPHERE", "RADIAL"};
inline constexpr const char* kVoronoiDimensions[] = {"1D", "2D", "3D", "4D"};
inline constexpr const char* kVoronoiFeatures[] = {"F1", "F2", "SMOOTH_F1", "DISTANCE_TO_EDGE", "N_SPHERE_RADIUS"};
inline constexpr const char* kVoronoiMetrics[] = {"EUCLIDEAN", "MANHATTAN", "CHEBYCHEV", "MINKOWSKI"};
inline constexpr const char* kVoronoiOutputs[] = {"DISTANCE", "COLOR", "POSITION", "W", "RADIUS"};
inline constexpr const char* kVectorRotateTypes[] = {"AXIS_ANGLE", "X_AXIS", "Y_AXIS", "Z_AXIS", "EULER_XYZ"};
inline constexpr const char* kVectorTransformTypes[] = {"POINT", "VECTOR", "NORMAL"};
inline constexpr const char* kTransformSpaces[] = {"WORLD", "OBJECT", "CAMERA"};
inline constexpr const char* kCameraCoordOutputs[] = {"CAMERA", "WINDOW"};
inline constexpr const char* kCameraDataOutputs[] = {"VIEW_VECTOR", "VIEW_Z_DEPTH", "VIEW_DISTANCE"};
inline constexpr const char* kTangentDirections[] = {"X", "Y", "Z", "UV_MAP"};  // X, Y, Z: radial
inline constexpr const char* kGaborTypes[] = {"2D", "3D"};  // sub 2 and 3 (the dimensions)
inline constexpr const char* kGaborOutputs[] = {"VALUE", "PHASE", "INTENSITY"};
inline constexpr const char* kAoOutputs[] = {"COLOR", "AO"};
inline constexpr const char* kAovTypes[] = {"VALUE", "COLOR"};
inline constexpr const char* kLightFalloffOutputs[] = {"QUADRATIC", "LINEAR", "CONSTANT"};

// The schema of the value ops (issue 22). A value op's tuple is `(name, dst, registers...,
// parameters...)` (docs/core_api.md): `registers` register operands fill in[0..], then each
// parameter in turn is checked by its kind and fills its ShaderOp field. The bindings parse every
// value op with one loop over this table, and expose it (pathlight_core.shader_op_table): the
// add-on's dead-code elimination and register allocation read the register counts.
enum class ParamKind : uint8_t {
  Choice,       // a name from `names` (Blender's enum identifier): its index + `offset`
  Int,          // an integer in [lo, hi]
  Bool,         // true ORs `bit` into the field (1: a plain flag)
  Float,        // a finite float
  ImageId,      // an image id below the scene's image count
  Values,       // 1 to 4 floats (Const: missing ones repeat the first, alpha 1; NaN becomes 0)
  Matrix3x4,    // a 3x4 float array, finite (Mapping's transform, row-major)
  RampTable,    // an (N, 4) float array, 2 <= N <= 4096, appended to the program's tables
  FilterWidth,  // a float >= 0: the program's Bump filter width (its first Bump op's)
  Ies,          // an IesProfile: appended to the program's ies (index)
  Sky,          // a SkyTexture: appended to the program's skies (index)
};
inline constexpr const char* kParamKindNames[] = {"choice", "int", "bool", "float", "image", "values",
                                                  "matrix3x4", "ramp_table", "filter_width", "ies_profile", "sky"};
static_assert(std::size(kParamKindNames) == size_t(ParamKind::Sky) + 1, "one name per ParamKind");

// The ShaderOp field a parameter fills (Values: value; Matrix3x4: m[0..11]; RampTable: index
// and count; FilterWidth: the program's bump_filter_width).
enum class OpField : uint8_t { Sub, Ext, Index, Count, Clamp, M0, M1, Value, Matrix, Table, Program };
inline constexpr const char* kOpFieldNames[] = {"sub", "ext", "index", "count", "clamp", "m0", "m1",
                                                "value", "m", "table", "program"};
static_assert(std::size(kOpFieldNames) == size_t(OpField::Program) + 1, "one name per OpField");

// What a value op tells its program (ShaderProgram's flags).
enum ProgFlag : uint8_t { kVarying = 1, kUsesUv = 2, kUsesAttributes = 4, kSetsNormal = 8 };

struct OpParam {
  ParamKind kind;
  OpField field;
  const char* what;  // in errors: "unknown <what> 'X'", "<what> must be in [lo, hi]"
  const char* const* names = nullptr;  // Choice: the names, or
  const SubOpName* sub_ops = nullptr;  //   a sub-operation table's
  uint8_t n_names = 0;
  uint8_t offset = 0;  // Choice: added to the index
  uint8_t bit = 1;     // Bool
  int32_t lo = 0, hi = 0;  // Int
  bool optional = false;   // may be left off the tuple's end (the field keeps its default)
  // Choice: the names (and what) when the op's sub is nonzero (Wave: the rings' directions).
  const char* const* alt_names = nullptr;
  uint8_t n_alt = 0;
  const char* alt_what = nullptr;
  // Program flags set when the parameter's value is `when` (Tangent's UV_MAP reads uv sets).
  int8_t when = -1;
  uint8_t when_flags = 0;
  constexpr const char* name(size_t i) const { return sub_ops ? sub_ops[i].name : names[i]; }
};

namespace param {  // the schema's parameter kinds, spelled short
template <size_t N>
constexpr OpParam choice(OpField f, const char* what, const char* const (&names)[N], uint8_t offset = 0) {
  OpParam p{ParamKind::Choice, f, what};
  p.names = names;
  p.n_names = uint8_t(N);
  p.offset = offset;
  return p;
}
template <size_t N>
constexpr OpParam sub_op(OpField f, const char* what, const SubOpName (&table)[N]) {
  OpParam p{ParamKind::Choice, f, what};
  p.sub_ops = table;
  p.n_names = uint8_t(N);
  return p;
}
constexpr OpParam int_in(OpField f, const char* what, int32_t lo, int32_t hi) {
  OpParam p{ParamKind::Int, f, what};
  p.lo = lo;
  p.hi = hi;
  return p;
}
constexpr OpParam flag(OpField f, const char* what, uint8_t bit = 1) {
  OpParam p{ParamKind::Bool, f, what};
  p.bit = bit;
  return p;
}
constexpr OpParam finite(OpField f, const char* what) { return {ParamKind::Float, f, what}; }
constexpr OpParam of(ParamKind k, OpField f, const char* what) { return {k, f, what}; }
constexpr OpParam uv_set(OpField f) { return int_in(f, "uv set index", 0, 7); }
// A trailing BumpOffset: where the op reads the shading point (the Bump node's offsets).
constexpr OpParam bump_offset(OpField f) {
  OpParam p = int_in(f, "bump offset", 0, 2);
  p.optional = true;
  return p;
}
constexpr OpParam optional(OpParam p) {
  p.optional = true;
  return p;
}
}  // namespace param

struct OpParams {
  const OpParam* p = nullptr;
  uint8_t n = 0;
  constexpr OpParams() = default;
  template <size_t N>
  constexpr OpParams(const OpParam (&a)[N]) : p(a), n(uint8_t(N)) {}
  constexpr const OpParam* begin() const { return p; }
  constexpr const OpParam* end() const { return p + n; }
};

struct ValueOpSchema {
  const char* name;
  OpCode code;
  uint8_t registers;  // register operands after the destination (in[0..registers))
  OpParams params;
  uint8_t flags = 0;  // ProgFlag
  uint8_t ext = 0;    // the ext it starts from (Map Range per component)
  // Parsed by hand in the bindings, not from `params` (which it leaves empty): see there.
  bool hand_parsed = false;
};

namespace schema {  // the parameter lists of the ops below
using namespace param;
using F = OpField;
using K = ParamKind;
inline constexpr OpParam kConst[] = {of(K::Values, F::Value, "const values")};
inline constexpr OpParam kUv[] = {uv_set(F::Index), bump_offset(F::Sub)};
inline constexpr OpParam kAtOffset[] = {bump_offset(F::Sub)};  // Generated
// Position, Object: a bump offset, plus kUndisplaced for the undisplaced surface.
inline constexpr OpParam kAtOffsetUndisplaced[] = {optional(int_in(F::Sub, "bump offset", 0, 6))};
inline constexpr OpParam kLightPath[] = {choice(F::Sub, "light path output", kLightPathOutputs)};
inline constexpr OpParam kObjectInfo[] = {choice(F::Sub, "object info output", kObjectInfoOutputs)};
inline constexpr OpParam kCurvesInfo[] = {choice(F::Sub, "curves info output", kCurvesInfoOutputs)};
inline constexpr OpParam kPointInfo[] = {choice(F::Sub, "point info output", kPointInfoOutputs)};
inline constexpr OpParam kAttribute[] = {int_in(F::Index, "attribute set index", 0, 7),
                                         choice(F::Sub, "attribute output", kAttributeOutputs)};
inline constexpr OpParam kGeometry[] = {choice(F::Sub, "geometry output", kGeometryOutputs)};
inline constexpr OpParam kMapping[] = {of(K::Matrix3x4, F::Matrix, "mapping matrix")};
inline constexpr OpParam kImage[] = {of(K::ImageId, F::Index, "image id"),
                                     choice(F::Sub, "interpolation", kInterpOpNames),
                                     choice(F::Ext, "extension", kExtensionOpNames),
                                     optional(flag(F::Clamp, "unassociate alpha"))};
inline constexpr const char* kImageProjections[] = {"SPHERE", "TUBE"};
inline constexpr OpParam kImageProj[] = {choice(F::Sub, "image projection", kImageProjections)};
inline constexpr OpParam kImageBox[] = {of(K::ImageId, F::Index, "image id"),
                                        choice(F::Sub, "interpolation", kInterpOpNames),
                                        choice(F::Ext, "extension", kExtensionOpNames),
                                        finite(F::M0, "box blend"),
                                        optional(flag(F::Clamp, "unassociate alpha"))};
inline constexpr OpParam kMath[] = {sub_op(F::Sub, "math op", kMathOpNames), flag(F::Clamp, "clamp")};
inline constexpr OpParam kMix[] = {sub_op(F::Sub, "mix blend type", kMixOpNames), flag(F::Clamp, "clamp")};
inline constexpr OpParam kLayerWeight[] = {choice(F::Sub, "layer weight output", kLayerWeightOutputs)};
// ext: the heights were read on the undisplaced surface (kUndisplaced ops): its offsets then.
inline constexpr OpParam kBump[] = {flag(F::Clamp, "invert"),
                                    optional(of(K::FilterWidth, F::Program, "bump filter width")),
                                    optional(flag(F::Ext, "bump undisplaced"))};
// Ramp: the table, clamp (bit 1), constant interpolation (bit 2), the range, extrapolate (bit 4).
inline constexpr OpParam kRamp[] = {of(K::RampTable, F::Table, "ramp table"), flag(F::Sub, "ramp clamp", 1),
                                    flag(F::Sub, "ramp constant", 2), finite(F::M0, "ramp range start"),
                                    finite(F::M1, "ramp range end"), flag(F::Sub, "ramp extrapolate", 4)};
inline constexpr OpParam kSeparate[] = {int_in(F::Sub, "separate axis", 0, 2)};
inline constexpr OpParam kCombine[] = {flag(F::Sub, "combine colour")};  // a colour (alpha 1) or a vector
inline constexpr OpParam kColorSpace[] = {sub_op(F::Sub, "colour conversion", kColorSpaceOpNames)};
inline constexpr OpParam kClamp[] = {sub_op(F::Sub, "clamp type", kClampOpNames)};
inline constexpr OpParam kMapRange[] = {sub_op(F::Sub, "map range type", kMapRangeOpNames), flag(F::Clamp, "clamp")};
inline constexpr OpParam kVectorMath[] = {sub_op(F::Sub, "vector math op", kVectorMathOpNames)};
inline constexpr OpParam kDimensions = int_in(F::Sub, "texture dimensions", 1, 4);
inline constexpr OpParam kTexNoise[] = {kDimensions, choice(F::Ext, "noise type", kNoiseTypes),
                                        flag(F::Clamp, "normalize"), flag(F::Index, "color output")};
constexpr OpParam wave_direction() {
  OpParam p = choice(F::Ext, "bands direction", kWaveBandsDirections);
  p.alt_names = kWaveRingsDirections;
  p.n_alt = uint8_t(std::size(kWaveRingsDirections));
  p.alt_what = "rings direction";
  return p;
}
inline constexpr OpParam kTexWave[] = {choice(F::Sub, "wave type", kWaveTypes), wave_direction(),
                                       choice(F::Index, "wave profile", kWaveProfiles)};
inline constexpr OpParam kTexMagic[] = {int_in(F::Sub, "magic texture depth", 0, 10), flag(F::Index, "color output")};
inline constexpr OpParam kTexWhiteNoise[] = {kDimensions, flag(F::Index, "color output")};
inline constexpr OpParam kChecker[] = {choice(F::Sub, "checker output", kColorOrFac)};
inline constexpr OpParam kGradient[] = {choice(F::Sub, "gradient type", kGradientTypes)};
inline constexpr OpParam kBrick[] = {finite(F::M0, "brick offset"), int_in(F::Index, "brick offset frequency", 1, 99),
                                     finite(F::M1, "brick squash"), int_in(F::Count, "brick squash frequency", 1, 99),
                                     choice(F::Sub, "brick output", kColorOrFac)};
inline constexpr OpParam kVoronoi[] = {choice(F::Ext, "voronoi dimensions", kVoronoiDimensions, 1),
                                       choice(F::Index, "voronoi feature", kVoronoiFeatures),
                                       choice(F::Count, "voronoi distance metric", kVoronoiMetrics),
                                       flag(F::Clamp, "normalize"), choice(F::Sub, "voronoi output", kVoronoiOutputs)};
inline constexpr OpParam kVectorRotate[] = {choice(F::Sub, "vector rotate type", kVectorRotateTypes),
                                            flag(F::Clamp, "invert")};
inline constexpr OpParam kVectorTransform[] = {choice(F::Sub, "vector transform type", kVectorTransformTypes),
                                               choice(F::Index, "vector transform space", kTransformSpaces),
                                               choice(F::Count, "vector transform space", kTransformSpaces)};
inline constexpr OpParam kCameraCoords[] = {choice(F::Sub, "camera coordinates", kCameraCoordOutputs),
                                            bump_offset(F::Ext)};
inline constexpr OpParam kCameraData[] = {choice(F::Sub, "camera data output", kCameraDataOutputs)};
constexpr OpParam tangent_direction() {
  OpParam p = choice(F::Sub, "tangent direction", kTangentDirections);
  p.when = 3;  // UV_MAP
  p.when_flags = kUsesUv;
  return p;
}
inline constexpr OpParam kTangent[] = {tangent_direction(), uv_set(F::Index)};
inline constexpr OpParam kTangentDisplace[] = {uv_set(F::Index)};
inline constexpr OpParam kTexGabor[] = {choice(F::Sub, "gabor type", kGaborTypes, 2),
                                        choice(F::Ext, "gabor output", kGaborOutputs)};
// Ambient Occlusion: samples, inside (bit 1), only local (bit 2), the output.
inline constexpr OpParam kAmbientOcclusion[] = {int_in(F::Index, "ambient occlusion samples", 0, 1024),
                                                flag(F::Sub, "inside", 1), flag(F::Sub, "only local", 2),
                                                choice(F::Ext, "ambient occlusion output", kAoOutputs)};
inline constexpr OpParam kBevel[] = {int_in(F::Index, "bevel samples", 0, 128)};
inline constexpr OpParam kWireframe[] = {flag(F::Ext, "use pixel size"), bump_offset(F::Sub)};
// Object / Instancer attributes: the instance's slot, the output.
inline constexpr OpParam kObjectAttribute[] = {
    int_in(F::Index, "object attribute slot", 0, int32_t(kMaxObjectAttributes) - 1),
    choice(F::Sub, "attribute output", kAttributeOutputs)};
// A scene voxel grid: its id (Scene::add_volume_grid), the output, the interpolation.
inline constexpr OpParam kVolumeGrid[] = {int_in(F::Index, "volume grid id", 0, (1 << 30)),
                                          choice(F::Sub, "attribute output", kAttributeOutputs),
                                          choice(F::Ext, "interpolation", kVolumeInterpOpNames)};
// Point Density: the grid's id, the output, the interpolation, the space (VoxelSpace).
inline constexpr OpParam kTexVoxel[] = {int_in(F::Index, "volume grid id", 0, (1 << 30)),
                                        choice(F::Sub, "attribute output", kAttributeOutputs),
                                        choice(F::Ext, "interpolation", kVolumeInterpOpNames),
                                        choice(F::Count, "voxel space", kVoxelSpaces)};
// AOV Output: the view layer's AOV slot, its type.
inline constexpr OpParam kAovOutput[] = {int_in(F::Index, "aov slot", 0, kMaxShaderAovs - 1),
                                         choice(F::Sub, "aov type", kAovTypes)};
inline constexpr OpParam kLightFalloff[] = {choice(F::Sub, "light falloff output", kLightFalloffOutputs)};
inline constexpr OpParam kTexIes[] = {of(K::Ies, F::Index, "ies profile")};
inline constexpr OpParam kTexSky[] = {of(K::Sky, F::Index, "sky")};
inline constexpr const char* kEnvProjections[] = {"EQUIRECTANGULAR", "MIRROR_BALL"};
inline constexpr OpParam kEnvUv[] = {choice(F::Sub, "environment projection", kEnvProjections)};
inline constexpr OpParam kBackgroundCamera[] = {choice(F::Sub, "camera coordinates", kCameraCoordOutputs)};
}  // namespace schema

// Every value op: its name, OpCode, registers, parameters and program flags. Adding a value op
// means an entry here, its evaluation (shader.cpp) and its test; the parser, the add-on's
// register counts and constant folding follow (an op without kVarying or an image is a pure
// function of its operands, which pathlight_core.fold_constant evaluates; the add-on folds with
// it). tests/blender/test_core_materials.py checks the table both ways.
inline constexpr ValueOpSchema kValueOps[] = {
    {"const", OpCode::Const, 0, schema::kConst},
    {"uv", OpCode::Uv, 0, schema::kUv, kVarying | kUsesUv},
    {"position", OpCode::Position, 0, schema::kAtOffsetUndisplaced, kVarying},
    {"normal", OpCode::Normal, 0, {}, kVarying},
    {"object", OpCode::ObjectPos, 0, schema::kAtOffsetUndisplaced, kVarying},
    {"generated", OpCode::Generated, 0, schema::kAtOffset, kVarying},
    {"light_path", OpCode::LightPath, 0, schema::kLightPath, kVarying},
    {"object_info", OpCode::ObjectInfo, 0, schema::kObjectInfo, kVarying},  // per instance
    {"curves_info", OpCode::CurvesInfo, 0, schema::kCurvesInfo, kVarying},  // per strand and hit
    {"point_info", OpCode::PointInfo, 0, schema::kPointInfo, kVarying},  // per point
    {"attribute", OpCode::Attribute, 0, schema::kAttribute, kVarying | kUsesAttributes},
    {"geometry", OpCode::Geometry, 0, schema::kGeometry, kVarying},
    {"object_normal", OpCode::ObjectNormal, 0, {}, kVarying},
    {"mapping", OpCode::Mapping, 1, schema::kMapping},
    {"image", OpCode::ImageTex, 1, schema::kImage},
    {"image_proj", OpCode::ImageProj, 1, schema::kImageProj},
    {"image_box", OpCode::ImageBox, 2, schema::kImageBox},  // vector, object-space normal
    {"rgb_to_bw", OpCode::RgbToBw, 1, {}},
    {"math", OpCode::Math, 2, schema::kMath},
    {"math3", OpCode::Math, 3, schema::kMath},  // the operations with a third value
    {"mix", OpCode::Mix, 3, schema::kMix},
    {"normal_map", OpCode::NormalMap, 2, {}, kVarying, 0, true},  // uses_uv: its tangent space only
    {"fresnel", OpCode::Fresnel, 2, {}, kVarying},
    {"layer_weight", OpCode::LayerWeight, 2, schema::kLayerWeight, kVarying},
    {"bump", OpCode::Bump, 6, schema::kBump, kVarying},  // heights (3), strength, distance, normal
    {"ramp", OpCode::Ramp, 1, schema::kRamp},
    {"separate", OpCode::Component, 1, schema::kSeparate},
    {"combine", OpCode::Combine, 3, schema::kCombine},
    {"color_space", OpCode::ColorSpace, 1, schema::kColorSpace},
    {"hsv", OpCode::Hsv, 5, {}},
    {"gamma", OpCode::Gamma, 2, {}},
    {"bright_contrast", OpCode::BrightContrast, 3, {}},
    {"clamp", OpCode::Clamp, 3, schema::kClamp},
    {"map_range", OpCode::MapRange, 6, schema::kMapRange},
    {"map_range_vector", OpCode::MapRange, 6, schema::kMapRange, 0, 1},  // ext 1: per component
    {"vector_math", OpCode::VectorMath, 4, schema::kVectorMath},
    // vector, w, scale, detail, roughness, lacunarity, offset, gain, distortion
    {"tex_noise", OpCode::TexNoise, 9, schema::kTexNoise},
    // vector, scale, distortion, detail, detail scale, detail roughness, phase
    {"tex_wave", OpCode::TexWave, 7, schema::kTexWave},
    {"tex_magic", OpCode::TexMagic, 3, schema::kTexMagic},  // vector, scale, distortion
    {"tex_white_noise", OpCode::TexWhiteNoise, 2, schema::kTexWhiteNoise},  // vector, w
    {"checker", OpCode::Checker, 4, schema::kChecker},  // vector, color1, color2, scale
    {"gradient", OpCode::Gradient, 1, schema::kGradient},
    // vector, color1, color2, mortar, scale, mortar size, mortar smooth, bias, brick width, row height
    {"brick", OpCode::Brick, 10, schema::kBrick},
    // vector, w, scale, detail, roughness, lacunarity, smoothness, exponent, randomness
    {"voronoi", OpCode::Voronoi, 9, schema::kVoronoi},
    {"vector_rotate", OpCode::VectorRotate, 5, schema::kVectorRotate},  // vector, center, axis, angle, rotation
    // object and camera space differ per instance and render
    {"vector_transform", OpCode::VectorTransform, 1, schema::kVectorTransform, kVarying},
    {"blackbody", OpCode::Blackbody, 1, {}},
    {"wavelength", OpCode::Wavelength, 1, {}},
    {"camera_coords", OpCode::CameraCoords, 0, schema::kCameraCoords, kVarying},
    {"camera_data", OpCode::CameraData, 0, schema::kCameraData, kVarying},
    {"tangent", OpCode::Tangent, 0, schema::kTangent, kVarying},
    // vector (already less Midlevel, times Scale)
    {"tangent_displacement", OpCode::TangentDisplace, 1, schema::kTangentDisplace, kVarying | kUsesUv},
    // vector, scale, frequency, anisotropy, orientation 2D, 3D
    {"tex_gabor", OpCode::TexGabor, 6, schema::kTexGabor},
    {"ambient_occlusion", OpCode::AmbientOcclusion, 3, schema::kAmbientOcclusion, kVarying},  // color, distance, normal
    {"bevel", OpCode::Bevel, 2, schema::kBevel, kVarying},  // radius, normal
    {"wireframe", OpCode::Wireframe, 1, schema::kWireframe, kVarying},  // size
    {"object_attribute", OpCode::ObjectAttribute, 0, schema::kObjectAttribute, kVarying},  // per instance
    {"set_normal", OpCode::SetNormal, 1, {}, kVarying | kSetsNormal},  // the new shading normal
    {"volume_grid", OpCode::VolumeGrid, 0, schema::kVolumeGrid, kVarying},  // volume objects' grids
    // (kVarying: evaluated at every hit, never folded or cached, so each camera hit adds once)
    {"aov_output", OpCode::AovOutput, 1, schema::kAovOutput, kVarying},
    {"light_falloff", OpCode::LightFalloff, 2, schema::kLightFalloff, kVarying},  // strength, smooth
    // (not folded: a constant vector still reads the profile or sky, which fold_constant lacks)
    {"tex_ies", OpCode::TexIes, 2, schema::kTexIes, kVarying},  // vector, strength
    {"tex_sky", OpCode::TexSky, 1, schema::kTexSky, kVarying},  // vector
    {"env_uv", OpCode::EnvUv, 1, schema::kEnvUv},  // direction
    {"background_camera", OpCode::BackgroundCamera, 0, schema::kBackgroundCamera, kVarying},
    {"tex_voxel", OpCode::TexVoxel, 1, schema::kTexVoxel, kVarying},  // vector (Point Density)
};

// The OpCodes that closure ops (or their companions) produce; every other OpCode is a value op's.
inline constexpr OpCode kClosureOpCodes[] = {
    OpCode::Diffuse, OpCode::Glossy, OpCode::Glass, OpCode::Refraction, OpCode::Transparent,
    OpCode::Emission, OpCode::Principled, OpCode::Translucent, OpCode::Metallic, OpCode::PrincipledExtra,
    OpCode::Holdout, OpCode::PrincipledHair, OpCode::Subsurface, OpCode::Sheen, OpCode::Toon,
    OpCode::Hair,
    OpCode::VolumeOut, OpCode::DisplaceOut, OpCode::RayPortal,
};
inline constexpr size_t kOpCodeCount = size_t(OpCode::TexVoxel) + 1;  // (the last OpCode)

constexpr bool every_value_opcode_has_an_op() {
  for (size_t c = 0; c < kOpCodeCount; ++c) {
    bool found = false;
    for (const OpCode k : kClosureOpCodes) found = found || size_t(k) == c;
    for (const ValueOpSchema& v : kValueOps) found = found || size_t(v.code) == c;
    if (!found) return false;
  }
  return true;
}
static_assert(every_value_opcode_has_an_op(), "every OpCode is a closure's or has a kValueOps entry");

// Each parameter fills a field of its kind's type, choices have names that fit their field,
// optional parameters come last, and hand-parsed entries list no parameters.
constexpr bool param_fits(const OpParam& p) {
  const bool int_field = p.field == OpField::Sub || p.field == OpField::Ext || p.field == OpField::Index ||
                         p.field == OpField::Count || p.field == OpField::Clamp;
  switch (p.kind) {
    case ParamKind::Choice:  // (the helpers set the names with their count; no pointer tests
                             // here: GCC's sanitizer builds cannot fold them as constants)
      return int_field && p.n_names > 0 && p.n_names + p.offset <= 256;
    case ParamKind::Int: {
      const bool wide = p.field == OpField::Index || p.field == OpField::Count;  // int32 fields
      return int_field && p.lo <= p.hi && (wide || (p.lo >= 0 && p.hi <= 255));
    }
    case ParamKind::Bool: return int_field && p.bit != 0;
    case ParamKind::ImageId:
    case ParamKind::Ies:
    case ParamKind::Sky: return p.field == OpField::Index;
    case ParamKind::Float: return p.field == OpField::M0 || p.field == OpField::M1;
    case ParamKind::Values: return p.field == OpField::Value;
    case ParamKind::Matrix3x4: return p.field == OpField::Matrix;
    case ParamKind::RampTable: return p.field == OpField::Table;
    case ParamKind::FilterWidth: return p.field == OpField::Program;
  }
  return false;
}
constexpr bool value_op_schemas_are_consistent() {
  for (const ValueOpSchema& v : kValueOps) {
    if (v.hand_parsed && v.params.n != 0) return false;
    if (v.registers > 16) return false;
    bool optional = false;
    for (const OpParam& p : v.params) {
      if (!param_fits(p) || (optional && !p.optional)) return false;
      optional = optional || p.optional;
    }
  }
  return true;
}
static_assert(value_op_schemas_are_consistent(), "a kValueOps parameter does not fit its field or order");

}  // namespace pl
