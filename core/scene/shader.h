// Materials as small register programs (like Cycles' SVM): value ops compute float4 registers
// at a shading point (textures, UVs, math, mixing, normal maps), closure ops add weighted BSDFs
// and emission. Programs that read nothing from the shading point are evaluated once.
#pragma once
#include <array>
#include <cstdint>
#include <memory>
#include <string>
#include <type_traits>
#include <vector>

#include "scene/bsdf.h"
#include "scene/phase.h"
#include "scene/ies.h"
#include "scene/sky.h"

namespace pl {

class Camera;
class Scene;

struct Float4 {
  float x = 0, y = 0, z = 0, w = 0;
  Vec3 xyz() const { return {x, y, z}; }
};

// One tile of a UDIM tile set: its number (1001 + u + 10 v) and the scene image holding it.
struct ImageTile {
  int32_t number = 0;
  int32_t image = 0;
};

struct Image {
  int w = 0, h = 0;
  std::vector<Float4> px;  // row 0 = bottom
  // px hold sRGB-encoded colour (8-bit textures, as Cycles keeps them): lookups interpolate the
  // encoded values and decode afterwards, so filtering matches Cycles (not linear-then-filter).
  bool srgb = false;
  // Non-empty: a UDIM tile set (Scene image ids of plain images; w, h, px unused). A lookup
  // picks the tile from the UV's integer part and reads it at the fractional part.
  std::vector<ImageTile> tiles;
};

// Cubic: Cycles' bicubic B-spline (its CPU kernel's interp_cubic; Smart reads as Cubic there).
enum class Interp : uint8_t { Linear, Closest, Cubic };
enum class Extension : uint8_t { Repeat, Extend, Clip, Mirror };

Float4 sample_image(const Image& img, float u, float v, Interp interp, Extension ext);
// What an Image Texture node reads, in Cycles' order: interpolate the stored (associated)
// texels, divide by alpha if `unassociate` (Color with the Alpha output in use), then decode sRGB.
Float4 image_lookup(const Image& img, float u, float v, Interp interp, Extension ext, bool unassociate);
// The Image Texture node's lookup of `images[id]`: image_lookup, or for a tile set (Cycles'
// svm_node_tex_image) the tile int(u) + 10 int(v) (truncated: a UV in (-1, 0) reads tile 1001
// under its extension) at the UV less that, and the missing-texture magenta for a UV outside
// tiles 0..9 in u and >= 0 in v or in a tile the set lacks.
Float4 image_texture(const std::vector<Image>& images, size_t id, float u, float v, Interp interp, Extension ext,
                     bool unassociate);
float srgb_to_linear(float c);
// Cycles' svm_node_tex_image_box: up to three lookups of image_texture weighted by the
// object-space normal `n` (Blend `blend`), at (co.y, co.z), (co.x, co.z), (co.y, co.x) flipped by
// the normal's sign. A tile set reads its first tile only, as Cycles (its first svm slot).
Float4 image_box(const std::vector<Image>& images, size_t id, Vec3 co, Vec3 n, float blend, Interp interp,
                 Extension ext, bool unassociate);

enum class OpCode : uint8_t {
  Const, Uv, Position, Normal, Mapping, ImageTex, Math, Mix, RgbToBw, NormalMap,
  Fresnel, LayerWeight, Bump, Ramp, Component, Combine, ColorSpace, Hsv, Gamma, BrightContrast,
  Clamp, MapRange, VectorMath, ObjectPos, Generated, ObjectNormal, LightPath, ObjectInfo, Attribute, Geometry,
  TexNoise, TexWave, TexMagic, TexWhiteNoise,  // procedural textures: scene/tex_noise.h
  Checker, Gradient, Brick, Voronoi,           // procedural textures: scene/tex_patterns.h
  VectorRotate, VectorTransform, Blackbody, Wavelength, CameraCoords, Tangent,  // scene/vector_nodes.h
  TexGabor,  // scene/tex_gabor.h
  AmbientOcclusion,  // traced by the scene (trace_ambient_occlusion)
  Bevel,             // traced by the scene (trace_bevel)
  Wireframe,
  // Light Falloff (sub: 0 Quadratic, 1 Linear, 2 Constant): in[0] strength, in[1] smooth, by the
  // ray's length (a light sample's distance in light programs).
  LightFalloff,
  // IES Texture: in[0] the vector, in[1] the strength; index: the program's ies profile.
  TexIes,
  // Sky Texture: in[0] the vector; index: the program's sky (the world's SkyModel).
  TexSky,
  Diffuse, Glossy, Glass, Refraction, Transparent, Emission, Principled,
  Translucent, Metallic,
  PrincipledExtra,  // the Principled BSDF's further inputs: the op just before its Principled op
  Holdout,  // no BSDF: its weight makes the film transparent where seen directly
  PrincipledHair,  // Chiang; sub: parametrization (0 absorption, 1 melanin, 2 direct colour)
  CurvesInfo,      // sub: Is Strand, Intercept, Length, Thickness, Tangent Normal, Random
  Subsurface,  // the Subsurface Scattering node: a BSSRDF closure
  Sheen,    // the Sheen BSDF node (sub 0 microfibre, 1 Ashikhmin velvet)
  Toon,     // the Toon BSDF node (sub 0 diffuse, 1 glossy)
  ObjectAttribute,  // the Attribute node's Object / Instancer types: a per-instance slot (index)
  Hair,  // the Hair BSDF node (sub 0 reflection, 1 transmission): scene/hair_bsdf.h HairBsdf
  SetNormal,  // the material's displacement as bump: replaces the shading normal for the ops after it
  // A voxel grid of the scene read at the point (volume objects: docs/design/volumes.md):
  // index the scene's grid id, sub the output (as Attribute), ext the interpolation (Interp).
  VolumeGrid,
  // A volume program's output (its last op): in[0] sigma_a, in[1] sigma_s, in[2] emission (RGB
  // per unit length), in[3] the Henyey-Greenstein anisotropy (.x); eval_volume reads them.
  // Several phase functions (count of them, at most kMaxVolumeLobeInputs): lobe k's scattering
  // in in[4 + 2k] (replacing in[1]), its parameters in in[5 + 2k] (VolumeLobeType: HG g; Draine
  // g, alpha; Fournier-Forand backscatter, IOR; Mie diameter), its type in bits 4k.. of index.
  VolumeOut,
  PointInfo,  // sub: Position, Radius, Random (Cycles' Point Info; zeros off points)
  // The Vector Displacement node in tangent space (Cycles' svm_node_vector_displacement): in[0]
  // the scaled vector over uv set `index`'s tangent, the normal and the bitangent (object
  // space), turned to world space.
  TangentDisplace,
  // The AOV Output node (Cycles' svm_node_aov_color / _value): adds in[0] to shader AOV slot
  // `index` (sub 1: a colour, (r, g, b, 1); 0: a value, in x) where the integrator asks for it
  // (RayState::aovs); its result is in[0] unchanged.
  AovOutput,
  // A displacement program's output (its last op): in[0] the world-space offset of the vertex
  // (true displacement, scene/displace.h).
  DisplaceOut,
  // The Ray Portal BSDF (a closure): in[0] weight, in[1] colour, in[2] position (kNoReg: the
  // shading point), in[3] direction (kNoReg or zero: the incoming ray's), as PortalBsdf.
  RayPortal,
  // The Environment Texture's lookup coordinates (Cycles' svm_node_tex_environment): in[0] the
  // direction (normalised here) to the image's (u, v); sub 0 equirectangular, 1 mirror ball.
  EnvUv,
  // Texture Coordinate's Camera (sub 0) and Window (sub 1) of a world: Cycles' background reads
  // the point camera position + the direction (P is the direction there).
  BackgroundCamera,
  // Camera Data (Cycles' svm_node_camera): the shading point in camera space (the ray's
  // camera, else ShadingContext::scene_camera), sub 0 its direction (View Vector), 1 its z
  // (View Z Depth), 2 its length (View Distance).
  CameraData,
  // The Image Texture's Sphere (sub 0) and Tube (sub 1) projections of in[0] (Cycles'
  // texco_remap_square, then map_to_sphere / map_to_tube) to (u, v, 0, 0).
  ImageProj,
  // The Image Texture's Box projection (image_box): in[0] the vector, in[1] the object-space
  // normal; index, sub, ext, clamp as ImageTex, m[0] the Blend.
  ImageBox,
  // The Point Density texture (Cycles' svm_node_tex_voxel): scene voxel grid `index` read at
  // in[0] taken to the grid's texture space by count (VoxelSpace), sub the output (as
  // Attribute), ext the interpolation (VolumeSampling); 0 outside the grid's box.
  TexVoxel,
};
// Shader AOV slots (view-layer AOVs) a render can keep.
constexpr int kMaxShaderAovs = 16;

enum class MathOp : uint8_t {
  Add, Subtract, Multiply, Divide, Power, Minimum, Maximum, LessThan, GreaterThan, Absolute,
  // The rest of Blender's Math node (Cycles' svm_math); the last five read a third value.
  Logarithm, Sqrt, InverseSqrt, Exponent, Sign, Round, Floor, Ceil, Trunc, Fract, Modulo, FlooredModulo,
  Snap, PingPong, Sine, Cosine, Tangent, Arcsine, Arccosine, Arctangent, Arctan2, Sinh, Cosh, Tanh,
  Radians, Degrees, MultiplyAdd, Compare, SmoothMin, SmoothMax, Wrap,
};
enum class MixOp : uint8_t { Mix, Multiply, Add, Subtract, Screen, Divide, Difference, Darken, Lighten, Overlay };
enum class ColorSpaceOp : uint8_t { RgbToHsv, HsvToRgb, RgbToHsl, HslToRgb };
enum class MapRangeOp : uint8_t { Linear, Stepped, SmoothStep, SmootherStep };
// Blender's Vector Math operations (its enum's order).
enum class VectorMathOp : uint8_t {
  Add, Subtract, Multiply, Divide, MultiplyAdd, CrossProduct, Project, Reflect, Refract, FaceForward,
  DotProduct, Distance, Length, Scale, Normalize, Absolute, Power, Sign, Minimum, Maximum, Floor, Ceil,
  Fraction, Modulo, Wrap, Snap, Sine, Cosine, Tangent,
};
// Where value ops that read the shading point read it: the point itself, or the small surface
// offsets that a Bump node differentiates its height with.
enum BumpOffset : uint8_t { kAtPoint = 0, kOffsetX = 1, kOffsetY = 2 };
// Position and Object ops: with this bit added to their BumpOffset they read the undisplaced
// surface of a truly displaced mesh (Cycles' bump of 'BOTH', svm_node_enter_bump_eval).
constexpr uint8_t kUndisplaced = 4;

// PrincipledExtra's operand slots (in[]), by feature; the Principled op right after it reads
// them. A slot left kNoReg takes the input's Blender default.
enum PrincipledExtraSlot : uint8_t {
  kPxAnisotropic = 0, kPxAnisotropicRotation = 1, kPxTangent = 2,
  kPxThinFilmThickness = 3, kPxThinFilmIor = 4,
  kPxSheenWeight = 5, kPxSheenRoughness = 6, kPxSheenTint = 7,
  kPxDiffuseRoughness = 8,
  kPxSubsurfaceWeight = 9, kPxSubsurfaceRadius = 10, kPxSubsurfaceScale = 11, kPxSubsurfaceIor = 12,
  kPxSubsurfaceAnisotropy = 13,
  kPxSubsurfaceMethod = 14,  // a register holding the SubsurfaceMethod (Random Walk when absent)
  kPxEmission = 15,  // emission (colour x strength) dimmed by the sheen and coat above it
};
// Blender's subsurface methods (Cycles' CLOSURE_BSSRDF_*_ID), as the add-on numbers them.
enum class SubsurfaceMethod : uint8_t { Burley = 0, RandomWalk = 1, RandomWalkSkin = 2 };

constexpr int kNoReg = -1;
constexpr int kMaxRegs = 64;

struct ShaderOp {
  OpCode code = OpCode::Const;
  int16_t dst = 0;
  int16_t in[16] = {kNoReg, kNoReg, kNoReg, kNoReg, kNoReg, kNoReg, kNoReg, kNoReg,
                    kNoReg, kNoReg, kNoReg, kNoReg, kNoReg, kNoReg, kNoReg, kNoReg};
  Float4 value;             // Const
  float m[12] = {};         // Mapping: 3x4 row-major
  int32_t index = 0;        // uv set / image id / Ramp: first entry in ShaderProgram::tables
  int32_t count = 0;        // Ramp: table entries
  uint8_t sub = 0;          // MathOp / MixOp / Interp / BumpOffset (Uv, Position) / ...
  uint8_t ext = 0;          // Extension
  bool clamp = false;        // Math/Mix; ImageTex: unassociate alpha after filtering
};

struct Closure {
  Bsdf bsdf;
  Vec3 weight;
  Frame frame;
  float pick = 0.0f;  // probability of choosing it when sampling
  bool delta = false;
};

constexpr int kMaxClosures = 8;

// Closure slots that construction leaves unset (only the first n of a list are meaningful): a
// std::array of them was zero-filled (a rep stos of 8 closures) for every path traced.
struct ClosureSlots {
  static_assert(std::is_trivially_copyable_v<Closure> && std::is_trivially_destructible_v<Closure>,
                "slots are copied and overwritten as bytes");
  union {
    Closure v[kMaxClosures];
  };
  ClosureSlots() {}
  Closure& operator[](size_t i) { return v[i]; }
  const Closure& operator[](size_t i) const { return v[i]; }
};

struct ClosureList {
  ClosureSlots c;
  int n = 0;
  Vec3 emission{0.0f};
  Vec3 holdout{0.0f};  // Holdout closures' summed weight (Cycles' surface_shader_apply_holdout)
  Vec3 ns{0.0f};       // the shading normal a SetNormal op made (zero: the hit's own)
  bool has_nondelta = false;
  // Cycles' caustics toggles at this shading point (kCausticsNo* bits): the kernel sets them
  // where the path's last bounce was diffuse and a toggle is off, else they stay 0. add drops or
  // trims the closures they exclude as they are made (caustics_keep), so that Principled's
  // layers below a dropped one are not dimmed by it; filter_caustics does it for a list made
  // without them (a constant material's cached closures).
  uint8_t caustics_off = 0;
  // `albedo`: an estimate of how much the BSDF reflects from this view (Cycles' sample weight
  // factor), for choosing among closures; negative: bsdf_albedo_hint's guess.
  // (B: one BSDF type or the Bsdf variant; assigned in place, so a lobe costs the copy of its
  // own bytes, not two copies of the whole variant through a temporary Closure.)
  // False only where the caustics toggles dropped it.
  template <class B>
  [[gnu::always_inline]] bool add(const B& b, Vec3 weight, const Frame& f, float albedo = -1.0f) {
    if constexpr (kCausticsFiltered<B>)
      if (__builtin_expect(caustics_off != 0, 0)) {
        B kept = b;
        if (!caustics_keep(kept, caustics_off)) return false;
        put(kept, weight, f, albedo);
        return true;
      }
    put(b, weight, f, albedo);
    return true;
  }
  template <class B>
  [[gnu::always_inline]] void put(const B& b, Vec3 weight, const Frame& f, float albedo) {
    if (n >= kMaxClosures || !(max_component(weight) > 0.0f) || !is_finite(weight)) return;
    Closure& d = c[size_t(n++)];
    d.bsdf = b;
    d.weight = weight;
    d.frame = f;
    d.pick = albedo;
    d.delta = bsdf_is_delta(d.bsdf);
  }
  // The caustics toggles `caustics_off` applied to the finished list: closures dropped (the
  // others' choice renormalised, as finalize would have made it without them) or trimmed.
  void filter_caustics() {
    int m = 0;
    float kept = 0.0f;
    for (int i = 0; i < n; ++i) {
      Closure& x = c[size_t(i)];
      if (!caustics_keep(x.bsdf, caustics_off)) continue;
      kept += x.pick;
      if (m != i) c[size_t(m)] = x;
      ++m;
    }
    if (m == n) return;
    n = m;
    has_nondelta = false;
    for (int i = 0; i < n; ++i) {
      c[size_t(i)].pick = kept > 0.0f ? c[size_t(i)].pick / kept : 1.0f / float(n);
      has_nondelta = has_nondelta || !c[size_t(i)].delta;
    }
  }
  // Filter Glossy at this point: every closure's roughness raised to at least r (bsdf_blur); a
  // smooth one becomes rough, evaluated and light-sampled as such. Choices stay (Cycles' sample
  // weights do).
  void blur(float r) {
    has_nondelta = false;
    for (int i = 0; i < n; ++i) {
      Closure& x = c[size_t(i)];
      bsdf_blur(x.bsdf, r);
      x.delta = bsdf_is_delta(x.bsdf);
      has_nondelta = has_nondelta || !x.delta;
    }
  }
  bool has_portal() const {
    for (int i = 0; i < n; ++i)
      if (std::holds_alternative<PortalBsdf>(c[size_t(i)].bsdf)) return true;
    return false;
  }
  // Cycles' surface_shader_transparency: the Transparent closures' weight, and the Ray Portals'
  // with it where there is a Transparent closure too (their weights share one extinction, which
  // Cycles reads only where SD_TRANSPARENT is set). What the passes see through.
  Vec3 transparency() const {
    Vec3 t(0.0f), portal(0.0f);
    bool any = false;
    for (int i = 0; i < n; ++i) {
      const Closure& x = c[size_t(i)];
      if (std::holds_alternative<TransparentBsdf>(x.bsdf)) t += x.weight, any = true;
      else if (std::holds_alternative<PortalBsdf>(x.bsdf)) portal += x.weight;
    }
    return any ? t + portal : t;
  }
  // What a shadow ray lets through: the transparency, none where a Ray Portal is (Cycles blocks
  // shadow rays at SD_RAY_PORTAL surfaces).
  Vec3 shadow_pass() const { return has_portal() ? Vec3(0.0f) : transparency(); }
  // Sampling probabilities in proportion to each closure's expected contribution.
  void finalize() {
    float total = 0.0f;
    for (int i = 0; i < n; ++i) {
      const float albedo = c[size_t(i)].pick >= 0.0f ? c[size_t(i)].pick : bsdf_albedo_hint(c[size_t(i)].bsdf);
      c[size_t(i)].pick = luminance(c[size_t(i)].weight) * albedo;
      if (!(c[size_t(i)].pick > 0.0f)) c[size_t(i)].pick = max_component(c[size_t(i)].weight) * 1e-3f;
      total += c[size_t(i)].pick;
    }
    has_nondelta = false;
    for (int i = 0; i < n; ++i) {
      c[size_t(i)].pick = total > 0.0f ? c[size_t(i)].pick / total : 1.0f / n;
      has_nondelta = has_nondelta || !c[size_t(i)].delta;
    }
  }
};

// Per instance: what the Object Info node reads (Blender's object colour, pass index and
// random number; the location comes from the matrix).
struct ObjectInfo {
  Float4 color{1.0f, 1.0f, 1.0f, 1.0f};  // Object ▸ Viewport Display ▸ Color, with alpha
  float pass_index = 0.0f;
  float random = 0.0f;  // in [0, 1]: Cycles' random_id * 2^-32
  // Cryptomatte ids (cryptomatte_float of the MurmurHash3 of the object's and its top parent's
  // names; 0: none): the CryptoObject and CryptoAsset passes.
  float crypto_object = 0.0f, crypto_asset = 0.0f;
  // The Attribute node's Object / Instancer values (constant per instance): attr_count slots
  // from attr_first in the scene's table of them (ObjectCoords::attrs at commit).
  uint32_t attr_first = 0, attr_count = 0;
  // Cycles' Shadow Terminator Geometry Offset of the object (0: off; Blender's default 0.1):
  // light samples of smooth triangles near the terminator start on the smooth surface.
  float terminator = 0.0f;
  // Light linking (Cycles' receiver_light_set / blocker_shadow_set): the object's light set as a
  // receiver and shadow set as a blocker (0..63); as an emitter (its emissive triangles) the
  // sets it lights and is blocked by (bit s: set s).
  uint8_t light_set = 0, shadow_set = 0;
  uint64_t light_mask = ~uint64_t(0), shadow_mask = ~uint64_t(0);
  // Cycles' object visibility: Shadow Catcher (seen by the camera only through the shadows and
  // light other objects cast on it, render/integrator.h) and Holdout (a camera ray that meets
  // it leaves the film transparent there and stops, as Cycles' SD_OBJECT_HOLDOUT_MASK).
  bool shadow_catcher = false, holdout = false;
  // Cycles' object visibility without PATH_RAY_CAMERA (a collection's Indirect Only): camera rays
  // and their transparent continuations pass it as if it were not there; other rays see it.
  bool camera_invisible = false;
  // Cycles' light group of the object as an emitter (its emission, mesh light samples): the
  // render's group index, -1: none (render/integrator.h PathAovs::groups).
  int16_t light_group = -1;
  // Cycles' object AO Distance (Visibility ▸ Fast GI Approximation): the reach of Fast GI's
  // Replace rays that leave this object's surfaces; 0: the world's.
  float ao_distance = 0.0f;
};
constexpr uint64_t kAllLightSets = ~uint64_t(0);
// Shadow rays: the transparent surfaces one passes when no path gives a limit (RayState::
// shadow_hits), and a bound on all its crossings (shadow-linked blockers it passes included).
constexpr int kShadowHits = 63;
constexpr int kMaxShadowCrossings = 4096;
constexpr uint32_t kMaxObjectAttributes = 8;
// Object Info's Random from a 32-bit id as Cycles makes it: (float)id / (float)0xFFFFFFFF,
// whose divisor rounds to 2^32 in float.
inline float object_random(uint32_t id) { return float(id) * (1.0f / 4294967296.0f); }

// Per instance: what the Texture Coordinate node's Object, Generated and Normal outputs and the
// Object Info node need.
struct ObjectCoords {
  Mat4 to_object;                  // world -> object space (the inverse of the instance matrix)
  Mat4 to_world;                   // object -> world (object normals: n_obj ~ to_world^T n)
  Vec3 gen_scale{1.0f}, gen_offset{0.0f};  // object -> generated: p * gen_scale + gen_offset
  bool valid = false;              // false: the matrix is singular (world coordinates used)
  ObjectInfo info;
  const Float4* attrs = nullptr;   // info.attr_count object attribute values (nullptr: none)
  // Object attribute `slot` (Cycles: a name found nowhere reads 0, alpha too).
  Float4 attribute(int slot) const {
    return attrs && slot >= 0 && uint32_t(slot) < info.attr_count ? attrs[slot] : Float4{};
  }
};
// Cycles' generated coordinates: the object-space position in the mesh's texture space
// (Blender's auto texture space is its bounding box), mapped to [0, 1]:
// (p - location) / size * 0.5 + 0.5, with size 0 axes giving 0 (Cycles' mesh_texture_space).
ObjectCoords make_object_coords(const Mat4& to_world, Vec3 texspace_location, Vec3 texspace_size);
// Blender's automatic texture space of vertex positions: (location, size) of the bounding box.
void auto_texspace(const std::vector<Vec3>& positions, Vec3& location, Vec3& size);

// The ray that reached a shading point, as Cycles' path state tells it to the Light Path node:
// what the last scattering was (flags) and the bounces so far of each kind.
enum RayFlags : uint8_t {
  kRayCamera = 1,     // the camera ray, and its continuations through Transparent BSDFs
  kRayShadow = 2,     // a shadow ray shading a surface's transparency
  kRayDiffuse = 4,    // after a diffuse bounce
  kRayGlossy = 8,     // after a glossy (or singular) bounce
  kRaySingular = 16,  // after a delta (sharp mirror or glass) bounce
  kRayReflect = 32,   // after a reflection
  kRayTransmit = 64,  // after a transmission
  kRayVolume = 128,   // after a scattering in a volume
};
struct RayState {
  uint8_t flags = kRayCamera;
  uint16_t depth = 0, diffuse = 0, glossy = 0, transmission = 0, transparent = 0;
  // Blender's Transparent max bounces: shadow rays from this vertex pass at most
  // shadow_hits() transparent surfaces (Cycles' integrate_shadow_max_transparent_hits, whose
  // kernel limit is the setting + 1).
  uint16_t transparent_max = 256;
  int shadow_hits() const { return std::max(int(transparent_max) - int(transparent), 0); }
  float length = 0.0f;  // distance from the ray's origin to the hit
  // The render's camera (Texture Coordinate's Camera and Window, Vector Transform's camera
  // space); nullptr where none is known (camera space is then world space).
  const Camera* camera = nullptr;
  uint32_t rng = 0;  // a random number of this path and bounce (the Ambient Occlusion node's rays)
  // Cycles' compact ray differentials: the footprint radius where the ray started and its
  // growth per unit length (a camera ray's pixel cone; bounces keep the growth and restart
  // from the footprint they hit). The footprint at the hit is dp + length * dd.
  float dp = 0.0f, dd = 0.0f;
  // The smallest BSDF pdf along the path so far (Cycles' min_ray_pdf; delta lobes leave it):
  // Bevel does nothing below 8 (blurry indirect rays).
  float min_pdf = kInf;
  float footprint() const { return dp + length * dd; }
  // A diffuse bounce came before (Cycles' PATH_RAY_DIFFUSE_ANCESTOR): BSSRDFs become diffuse.
  bool diffuse_ancestor = false;
  // Cycles evaluates light samples and a path's last vertex without closure storage, so the
  // layers whose albedo comes from a closure (sheen, coat) do not dim emission there.
  bool emission_only = false;
  // The camera path's surfaces up to the data passes' one (Cycles' svm_node_aov_check): the
  // shader AOV slots (kMaxShaderAovs) that AOV Output ops add to; nullptr elsewhere.
  Float4* aovs = nullptr;
};

// What a program can read at a shading point.
// What the Curves Info node reads at a hit on a curve (Cycles' curve attributes).
struct CurveShading {
  float intercept = 0.0f;  // 0 at the root, 1 at the tip (by length along the control points)
  float length = 0.0f;     // the strand's length (its control polygon, in object space)
  float thickness = 0.0f;  // the diameter at the hit (world space)
  float random = 0.0f;     // per strand, as Cycles: hash of its index in its object
  Vec3 tangent_normal{0.0f};  // the view direction across the strand
  Vec3 tangent{0.0f};         // the unit direction along the strand (Cycles' dPdu)
};

// What the Point Info node reads at a hit on a point cloud's sphere.
struct PointShading {
  Vec3 position{0.0f};  // the sphere's centre (world space)
  float radius = 0.0f;  // its radius, world space, as Cycles' point_radius
  float random = 0.0f;  // per point, as Cycles: hash of its index in its cloud
};

struct ShadingContext {
  Vec3 p, ng, ns;            // world position, geometric and shading normal (mesh orientation)
  Vec3 wo;                   // direction towards the viewer (unit)
  bool backfacing = false;   // the viewer sees the hit's back (Scene::backfacing): diffuse lobes' side
  // The programs' normal values face the viewer, as Cycles' sd->N (flipped on a back-facing
  // hit, a mirrored instance's winding turned round first); ns, and the closures' frames, keep
  // the outward side: values times this convert.
  float view_side() const { return backfacing ? -1.0f : 1.0f; }
  const Vec2* uv = nullptr;  // per uv set: the interpolated uv (nullptr entries: missing)
  int uv_sets = 0;
  const Vec3* tangents = nullptr;  // per uv set: tangent (xyz) with the bitangent sign folded in
  const float* tangent_signs = nullptr;
  // MikkTSpace tangents, per uv set whose bit is set in mesh_tangent_sets: the interpolated
  // object-space tangent (xyz, unnormalised) and bitangent sign (w) that the mesh gave, as
  // Cycles' tangent attributes; normal_obj the unnormalised interpolated object-space smooth
  // normal (flat shading: the geometric one), mesh orientation. Sets without them use the
  // per-triangle tangents above.
  const Float4* mesh_tangents = nullptr;
  uint32_t mesh_tangent_sets = 0;
  Vec3 normal_obj{0.0f};
  bool has_mesh_tangent(int k) const { return mesh_tangents && k >= 0 && k < 32 && ((mesh_tangent_sets >> k) & 1u); }
  // The triangle hit (world vertices) and per uv set its 3 corner uvs (uv_sets * 3 entries):
  // the Bump node's offsets move along its edges. nullptr: no offsets (heights not differentiated).
  const Vec3* tri = nullptr;
  const Vec2* tri_uv = nullptr;
  // A truly displaced mesh's undisplaced surface (world): the point, then the triangle's three
  // vertices (Cycles' ATTR_STD_POSITION_UNDISPLACED); nullptr: not displaced. Generated
  // coordinates always read it, Position and Object ops where flagged kUndisplaced.
  const Vec3* undisplaced = nullptr;
  const ObjectCoords* object = nullptr;  // the hit instance's (nullptr: world coordinates)
  const Float4* attrs = nullptr;  // per attribute set: the interpolated value (nullptr: none)
  int attr_sets = 0;
  RayState ray;  // the ray that hit (Light Path node)
  float b1 = 0.0f, b2 = 0.0f;  // barycentrics of the hit in its triangle (Geometry ▸ Parametric)
  // What the Ambient Occlusion node traces against (nullptr: nothing, AO reads 1): the scene,
  // the hit instance and the bound of the position's rounding error (ray offsets).
  const Scene* scene = nullptr;
  uint32_t instance = 0;
  Vec3 p_error{0.0f};
  const CurveShading* curve = nullptr;  // hits on curves (nullptr: not a strand)
  const PointShading* point = nullptr;  // hits on points (nullptr: not a point)
  float time = 0.5f;  // the ray's shutter time (motion blur): AO rays trace at it
  // Majorant building: where set, VolumeGrid ops read the grid's largest value (over its
  // channels) in this world box instead of a sample at p.
  const Vec3* grid_bound = nullptr;  // {lo, hi}
  // The scene's camera where no ray brings one (light and volume programs): Camera Data's.
  const Camera* scene_camera = nullptr;
  // A world program's escaped ray: its origin (Cycles' sd->ray_P, which Window reads for an
  // orthographic camera's rays); nullptr: none.
  const Vec3* ray_p = nullptr;
};

// The Ambient Occlusion node's fraction of `samples` rays over the hemisphere about n (cosine
// distributed, as Cycles) that travel `distance` without a hit (only_local: ignoring other
// objects). Implemented by the scene (scene.cpp).
float trace_ambient_occlusion(const ShadingContext& ctx, Vec3 n, float distance, int samples, bool only_local);

enum class VolumeSampling;  // scene/volume_grid.h
// Scene voxel grid `grid` at the context's point in its instance's object space (RGBA: a float
// grid reads (v, v, v, 1), a vector grid (x, y, z, 1); a missing grid 0), or with
// ctx.grid_bound its maximum over that box. Implemented by the scene (scene_media.cpp).
Float4 read_volume_grid(const ShadingContext& ctx, int grid, VolumeSampling interp);
// Point Density: how the vector reaches the grid's own space (its transform maps that space to
// voxel indices): as it is (0, world space: the grid's transform holds Cycles' texture
// space), the shading object's space (1), or that object's generated coordinates (2: Cycles'
// volume_normalized_position, for materials with a volume).
enum class VoxelSpace : uint8_t { World = 0, Object = 1, Texture = 2 };
Float4 read_voxel_texture(const ShadingContext& ctx, int grid, VolumeSampling interp, VoxelSpace space, Vec3 v);

// The Bevel node's normal: Cycles' svm_bevel, the smooth normals of the instance's surface
// within `radius` of the point, found by `samples` short rays (mesh orientation, as ctx.ns).
Vec3 trace_bevel(const ShadingContext& ctx, float radius, int samples);

// Phase function types of VolumeOut's lobes (Mie becomes two lobes: HG and Draine).
enum class VolumeLobeType : uint8_t { HenyeyGreenstein, Draine, FournierForand, Rayleigh, Mie };
constexpr int kMaxVolumeLobeInputs = 6;

// One phase function of a medium and the scattering that follows it: a material's Volume
// Scatter nodes of different phases (or anisotropies), Mie's two lobes. The medium's phase is,
// per channel, the lobes' phases weighted by their sigma_s in that channel.
struct PhaseLobe {
  Vec3 sigma_s{0.0f};
  Phase phase;
};
constexpr int kMaxPhaseLobes = 4;
// Appends the lobes of a phase of `type` with parameters `params` and scattering ss to
// lobes[0..n) (merging equal phases; at most kMaxPhaseLobes: further ones join the last).
void add_phase_lobes(VolumeLobeType type, Float4 params, Vec3 ss, PhaseLobe* lobes, int& n);

struct ShaderProgram {
  std::vector<ShaderOp> ops;
  bool varying = false;  // reads the shading point (else evaluated once)
  // A value op reads the shading point (textures, geometry, the path): without it a varying
  // program varies only through its closures' view dependence, and its registers are the same
  // at every hit (Material::closure_regs).
  bool reads_point = false;
  bool uses_uv = false;
  bool uses_attributes = false;
  bool sets_normal = false;  // has a SetNormal op (Cycles' bump from displacement)
  bool schlick = false;
  Vec3 sigma_a{0.0f};    // Beer's law absorption inside (per unit length)
  // The homogeneous medium inside (the material's Volume): scattering (per unit length), its
  // phase function and the emitted radiance per unit length. Several phase functions: phase_lobes
  // (two or more, their sigma_s summing to sigma_s); phase is then the first's.
  Vec3 sigma_s{0.0f};
  Phase phase;
  std::vector<PhaseLobe> phase_lobes;
  Vec3 volume_emission{0.0f};
  // A heterogeneous medium inside (a Volume whose inputs vary in space): the program that gives
  // its coefficients at a point (value ops, then a VolumeOut op; eval_volume). The constant
  // fields above are then zero. nullptr: the medium (if any) is the homogeneous one above.
  std::shared_ptr<const ShaderProgram> volume;
  bool has_medium() const {
    return !is_black(sigma_a) || !is_black(sigma_s) || !is_black(volume_emission) || volume != nullptr;
  }
  std::vector<Float4> tables;  // Ramp lookup tables (Color Ramp, RGB Curves), as Cycles bakes them
  // What IES Texture and Sky Texture ops read (their index): shared with Python and other programs.
  std::vector<std::shared_ptr<const IesProfile>> ies;
  std::vector<std::shared_ptr<const SkyModel>> skies;
  // The Bump node's Filter Width: its heights are read this many pixel footprints away (<= 0:
  // a tiny fixed step, where the ray's footprint is unknown too).
  float bump_filter_width = 0.0f;
};

// Runs `prog` at `ctx`, filling `out` (closures plus emission), with closure frames built from
// the given or the context's shading normal; `regs` (kMaxRegs entries), where given, receives
// the registers (the add-on's constant folding).
void eval_shader(const ShaderProgram& prog, const std::vector<Image>& images, const ShadingContext& ctx,
                 ClosureList& out, Float4* regs = nullptr);

// The Principled BSDF's inputs read from its registers, as its closures use them: the part of
// its setup that does not depend on the hit (Material caches it where the registers are
// constant); shader_closures.cpp's principled_inputs makes it.
struct PrincipledInputs {
  Vec3 w, base, base_c, spec_tint;
  float metallic, alpha, ior, transmission;
  bool multi;
  bool aniso;  // anisotropic lobes (ax, ay; the tangent turned by `rotation` turns)
  float ax, ay, rotation, rough_a;  // rough_a: the tables' roughness of the metal / specular lobes
  float film, film_ior;  // Thin Film
  bool sheen;
  float sheen_weight, sheen_rough, sheen_coat;
  Vec3 sheen_tint;
  float coat, coat_alpha, coat_eta, coat_rough, coat_fss;
  Vec3 coat_tint;
  bool emits;
  Vec3 emission;
  Vec3 metal_b, metal_fss;  // F82-Tint's b; the metal's mean Fresnel (Multiscatter)
  Vec3 transmission_tint;
  bool spec;  // a dielectric specular layer
  float eta, f0;
  Vec3 spec_f0, spec_fss;
  float sss_weight, sss_method, sss_ior, sss_aniso;
  Vec3 sss_radius;
  float diffuse_rough;  // Oren-Nayar's from 1e-5 on (else Lambert)
};

// The closure ops of a program (BSDFs, BSSRDFs, emission, holdout).
constexpr bool is_closure_op(OpCode c) {
  switch (c) {
    case OpCode::Diffuse: case OpCode::Toon: case OpCode::Sheen: case OpCode::Metallic:
    case OpCode::Translucent: case OpCode::Glossy: case OpCode::Glass: case OpCode::Refraction:
    case OpCode::Transparent: case OpCode::PrincipledExtra: case OpCode::Holdout:
    case OpCode::PrincipledHair: case OpCode::Hair: case OpCode::Emission: case OpCode::Principled:
    case OpCode::Subsurface: case OpCode::RayPortal:
      return true;
    default:
      return false;
  }
}

// Runs only the closure ops `ops` (n of them, in program order) of `prog` on registers `regs`
// that hold its values already: eval_shader for a program that does not read the point.
// Each Principled op's inputs among the closure ops `ops` (n, in program order) on registers regs.
std::vector<PrincipledInputs> principled_inputs_of(const ShaderOp* ops, size_t n, const Float4* regs);
// `principled`: each Principled op's inputs, in order, made from `regs` beforehand (or nullptr).
void eval_closures(const ShaderProgram& prog, const ShaderOp* ops, size_t n, const Float4* regs,
                   const PrincipledInputs* principled, const ShadingContext& ctx, ClosureList& out);

// A medium's coefficients at a point: absorption and scattering (per unit length), emitted
// radiance per unit length and the phase function; several (n_lobes >= 2): lobes, whose sigma_s
// sum to sigma_s.
struct MediumSample {
  Vec3 sigma_a{0.0f}, sigma_s{0.0f}, emission{0.0f};
  Phase phase;
  int n_lobes = 0;
  PhaseLobe lobes[kMaxPhaseLobes];
};
// Runs a volume program (ShaderProgram::volume) at ctx (p the point, wo the reverse of the ray's
// direction, normals 0, as Cycles' volume shader data): negative or non-finite coefficients
// read 0, the phases' parameters are clamped as Cycles' setups do.
MediumSample eval_volume(const ShaderProgram& vol, const std::vector<Image>& images, const ShadingContext& ctx);

// Runs a displacement program (value ops, then a DisplaceOut op) at ctx: the world-space offset
// it gives (zero for a program without that output).
Vec3 eval_displacement(const ShaderProgram& prog, const std::vector<Image>& images, const ShadingContext& ctx);

}  // namespace pl
