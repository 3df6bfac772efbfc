// Curves (hair, fur): strands of control points with a radius each, traced as Cycles' round
// "3D curves". Each strand is cut into short linear pieces (Catmull-Rom strands: every segment
// between two control points subdivided; poly strands: as they are), and each piece is a swept
// sphere: a cone frustum between the spheres of its two ends, those spheres included, so pieces
// join without gaps. Hits from inside count too (a ray that starts inside a strand meets its
// inside where it leaves), as Cycles' thick curves (Embree's round curves, no back-face culling
// in Blender 4.5); a ray skips the strand it leaves (Ray::self_curve), as Cycles skips the
// primitive it leaves. Pieces live in world space in one binary SAH BVH of
// their own, traced after the triangles: scenes without curves never touch it. Sets with
// motion blur (transform, deformation) get trees of their own, traced at the ray's time.
// Ribbons (Cycles' shape 'RIBBONS'): Catmull-Rom pieces that are flat quads facing each ray,
// as Embree's flat Catmull-Rom curves (what CPU Cycles traces them with).
#pragma once
#include <algorithm>
#include <cstdint>
#include <memory>
#include <vector>

#include "geometry/aabb.h"
#include "geometry/bvh.h"
#include "geometry/motion.h"
#include "geometry/moving_sets.h"
#include "geometry/ray.h"

namespace pl {

enum class CurveType : uint8_t { CatmullRom, Poly };

// One linear piece: a cone frustum from (p0, r0) to (p1, r1). Joints are closed by the
// sphere at p1, only where neither cone covers it (beyond this piece's end disc and before the
// next piece's start disc: the outer wedge of a bend), so a ray inside a strand never "enters"
// a joint sphere that lies inside the tube. A strand's root and tip are cut off flat by discs
// across the axis, as Cycles' thick curves end.
struct CurvePiece {
  Vec3 p0, p1;
  Vec3 next{0.0f};  // the next piece's unit axis; zero at the tip
  Vec3 prev{0.0f};  // the previous piece's unit axis; zero at the root
  float r0 = 0.0f, r1 = 0.0f;
  bool root = false;  // the strand's first piece: closed by a disc at p0
  // A ribbon piece (flat, facing the ray): `prev` and `next` then hold the curve's derivative
  // dP/du at p0 and p1 (u the Catmull-Rom segment's parameter), which orients the quad.
  bool ribbon = false;
  uint32_t curve = 0;     // the strand (in the CurveSet's numbering)
  float v0 = 0.0f, v1 = 0.0f;  // intercept (0 at the root, 1 at the tip) at p0 and p1
  // The curve's normal attribute at p0 and p1 (octahedral, 16 bits a component; kNoCurveNormal:
  // none): the major axis of Huang's elliptical hair, as Cycles reads it.
  uint32_t n0 = 0xFFFFFFFFu, n1 = 0xFFFFFFFFu;
};

constexpr uint32_t kNoCurveNormal = 0xFFFFFFFFu;

// Unit vectors in 32 bits (octahedral map), to keep pieces small.
inline uint32_t encode_unit(Vec3 n) {
  const float l1 = std::fabs(n.x) + std::fabs(n.y) + std::fabs(n.z);
  if (!(l1 > 0.0f) || !std::isfinite(l1)) return kNoCurveNormal;
  float u = n.x / l1, v = n.y / l1;
  if (n.z < 0.0f) {
    const float pu = (1.0f - std::fabs(v)) * (u >= 0.0f ? 1.0f : -1.0f);
    const float pv = (1.0f - std::fabs(u)) * (v >= 0.0f ? 1.0f : -1.0f);
    u = pu;
    v = pv;
  }
  auto q = [](float x) { return uint32_t(std::lround((std::min(std::max(x, -1.0f), 1.0f) * 0.5f + 0.5f) * 65534.0f)); };
  return q(u) | (q(v) << 16);
}
inline Vec3 decode_unit(uint32_t e) {
  const float u = float(e & 0xFFFFu) / 65534.0f * 2.0f - 1.0f, v = float(e >> 16) / 65534.0f * 2.0f - 1.0f;
  Vec3 n{u, v, 1.0f - std::fabs(u) - std::fabs(v)};
  if (n.z < 0.0f) {
    const float x = (1.0f - std::fabs(v)) * (u >= 0.0f ? 1.0f : -1.0f), y = (1.0f - std::fabs(u)) * (v >= 0.0f ? 1.0f : -1.0f);
    n.x = x;
    n.y = y;
  }
  return normalize(n);
}

// Catmull-Rom (uniform, Cycles' and Blender's default curve type) through p[i] with clamped end
// keys: the segment from key k to k + 1 uses keys k - 1 .. k + 2, indices clamped to the strand.
inline Vec3 catmull_rom(const Vec3& a, const Vec3& b, const Vec3& c, const Vec3& d, float t) {
  const float t2 = t * t, t3 = t2 * t;
  const float wa = 0.5f * (-t3 + 2.0f * t2 - t), wb = 0.5f * (3.0f * t3 - 5.0f * t2 + 2.0f);
  const float wc = 0.5f * (-3.0f * t3 + 4.0f * t2 + t), wd = 0.5f * (t3 - t2);
  return a * wa + b * wb + c * wc + d * wd;
}
// dP/dt of the same basis.
inline Vec3 catmull_rom_derivative(const Vec3& a, const Vec3& b, const Vec3& c, const Vec3& d, float t) {
  const float t2 = t * t;
  const float wa = 0.5f * (-3.0f * t2 + 4.0f * t - 1.0f), wb = 0.5f * (9.0f * t2 - 10.0f * t);
  const float wc = 0.5f * (-9.0f * t2 + 8.0f * t + 1.0f), wd = 0.5f * (3.0f * t2 - 2.0f * t);
  return a * wa + b * wb + c * wc + d * wd;
}
inline float catmull_rom(float a, float b, float c, float d, float t) {
  const float t2 = t * t, t3 = t2 * t;
  return 0.5f * ((-t3 + 2.0f * t2 - t) * a + (3.0f * t3 - 5.0f * t2 + 2.0f) * b + (-3.0f * t3 + 4.0f * t2 + t) * c +
                 (t3 - t2) * d);
}

// Strands as the exporter gives them: curve c has points [offsets[c], offsets[c + 1]).
struct CurveInput {
  const Vec3* points = nullptr;
  const float* radii = nullptr;
  const Vec3* normals = nullptr;  // optional, per point (Blender's curve normals)
  size_t n_points = 0;
  const int32_t* offsets = nullptr;  // curves + 1 entries
  size_t n_curves = 0;
  CurveType type = CurveType::CatmullRom;
  int subdivisions = 8;  // pieces per Catmull-Rom segment
  // Strands as ribbons (Cycles' 'RIBBONS'): Catmull-Rom through the points whatever the type
  // (Cycles 4.5 traces poly strands so too), subdivisions then Embree's tessellation rate
  // (quads per segment).
  bool ribbon = false;
};

struct CurveCutStats {
  size_t curves = 0, skipped = 0;  // strands kept; strands left out (bad data, < 2 points)
};

// Appends the pieces of every usable strand (in world space through `to_world`; radii scaled
// by the cube root of its determinant). A strand is left out when it has fewer than 2 points,
// a non-finite point or radius, a radius <= 0 everywhere or zero length. Piece.curve counts
// from curve_base. Throws std::invalid_argument on inconsistent offsets.
// kept (optional) receives the input index of every strand kept, in strand order.
CurveCutStats cut_curves(const CurveInput& in, const Mat4& to_world, uint32_t curve_base, std::vector<CurvePiece>& out,
                         std::vector<uint32_t>* kept = nullptr);

// The nearest hit of a ray on one piece, entering or (cone and joint sphere) leaving, with
// 0 < t < tmax; the end discs are entered only; u: the axial position
// (0 at p0, 1 at p1) of the hit's closest point on the axis; -1 / 2 on the root / tip disc.
bool intersect_piece(const CurvePiece& c, const Vec3& org, const Vec3& dir, float tmax, float& t, float& u);

// The nearest hit of a ray on a ribbon piece, as Embree's flat curves (and Cycles' GPU
// ribbon_intersect): in the ray's frame the piece is the quad p -+ r n at both ends, n the unit
// normal of the derivative's projection, split into two triangles along a diagonal; hits
// nearer than twice the radius are ignored (Embree's self-intersection avoidance factor 2).
// u: along the piece (0 at p0, 1 at p1), v: across it, -1 .. 1 (Cycles' isect->v).
bool intersect_ribbon(const CurvePiece& c, const Vec3& org, const Vec3& dir, float tmax, float& t, float& u, float& v);

// A ribbon hit's shading frame, as Cycles' curve_shader_setup: the unit tangent (dP/du
// interpolated along the piece) and the "rounded" normal sin(v) b - cos(v) (t x b), b the unit
// tangent x view (facing the viewer, as a round fibre's would); dir: the ray's direction.
void ribbon_surface(const CurvePiece& c, float u, float v, const Vec3& dir, Vec3& n, Vec3& tangent);

// A hit as two numbers (Hit::b1, b2) that give its surface point exactly, independent of the
// error of the ray's t: b2 the angle about the axis; b1 the axial position u in [0, 1] on the
// cone, or on the joint spheres -2 - z (at p0) and 3 + z (at p1), z the normal's axial cosine,
// or on the end discs -5 - rho (root) and 5 + rho (tip), rho the radial distance in radii.
void encode_piece_hit(const CurvePiece& c, Vec3 p, float u, float& b1, float& b2);

// The surface at an encoded hit: the outward unit normal (from the axis to the point, tilted
// by the cone's slope), the unit tangent (p0 to p1), the point on the surface and a bound of
// its error, large enough that offset_ray_origin moves spawned rays to the right side of the
// surface for intersect_piece; u: the axial position (0 at p0, 1 at p1).
void piece_surface(const CurvePiece& c, float b1, float b2, Vec3& n, Vec3& tangent, Vec3& p, Vec3& error, float& u);

// The same pieces at deformation steps (cut from the keys at each step): the structure (how
// many pieces, their strands and joins) must agree with the frame's pieces, else they cannot be
// interpolated (false). On success each round piece's prev / next of every step hold its
// neighbours' raw axes (p1 - p0, not unit), so that interpolating them gives the interpolated
// neighbours' axes exactly.
bool prepare_deform_steps(const std::vector<CurvePiece>& frame, std::vector<CurvePiece>& steps, uint32_t n_steps);

// A piece carried to world space by an affine matrix: its points, its radii by the cube root of
// the determinant (as cut_curves), its neighbours' axes or derivatives and its normals.
CurvePiece transform_piece(const CurvePiece& c, const Mat4& to_world);

class CurveBvh {
 public:
  // Hit::prim of a piece of a moving set (add_moving): this bit and the piece's number over all
  // moving sets.
  static constexpr uint32_t kMovingPrim = 0x80000000u;
  // steps (optional): the pieces at n_steps >= 2 deformation steps, step-major (prepared by
  // prepare_deform_steps); the boxes then hold each piece over the whole shutter.
  void build(std::vector<CurvePiece> pieces, std::vector<CurvePiece> steps = {}, uint32_t n_steps = 0);
  // A set with motion blur (after build): its pieces (object space when `xf` has steps, else
  // world space), optionally deformed (steps as build's), entered through its transform at the
  // ray's time (xf: decomposed steps, or none), as moving point clouds are.
  void add_moving(std::vector<CurvePiece> pieces, std::vector<CurvePiece> steps, uint32_t n_steps,
                  std::vector<DecomposedTransform> xf);
  bool has_moving() const { return !moving_.empty(); }
  void clear() { *this = CurveBvh(); }
  bool empty() const { return pieces_.empty() && moving_.empty(); }
  size_t size() const { return pieces_.size() + moving_.end; }
  // The piece of Hit::prim as stored (a moving set's: its frame's, in its own space); what does
  // not move with it (strand, intercepts) is read here.
  const CurvePiece& piece(uint32_t prim) const {
    if (!(prim & kMovingPrim)) return pieces_[prim];
    const uint32_t i = prim & ~kMovingPrim, m = moving_.set_of(i);
    return moving_.trees[m]->pieces_[i - moving_.first[m]];
  }
  // The piece of Hit::prim in world space at shutter time `time` (static pieces as they are).
  CurvePiece piece_at(uint32_t prim, float time) const;
  // A moving set's object-to-world matrix at `time` (identity for static pieces and sets that
  // only deform).
  Mat4 moving_transform(uint32_t prim, float time) const;
  Aabb bounds() const { return bounds_; }
  size_t memory_bytes() const {
    size_t b = nodes_.capacity() * sizeof(Node) + (pieces_.capacity() + steps_.capacity()) * sizeof(CurvePiece);
    for (int j = 0; j < kSlices; ++j) b += slice_nodes_[j].capacity() * sizeof(Node) + slice_refs_[j].capacity() * 4;
    return b + moving_.memory_bytes();
  }
  // Closest hit before ray.tmax, on strands other than ray.self_curve: prim the piece, (b1, b2) as
  // encode_piece_hit (ribbons: u and v as intersect_ribbon).
  bool intersect(const Ray& ray, Hit& hit) const;
  bool occluded(const Ray& ray) const;

 private:
  // 4-wide nodes collapsed from the binary SAH tree, tested four boxes per SSE operation,
  // nearest lane first; a lane with count > 0 is a leaf of `count` pieces from `child`.
  using Node = WideBvhNode<4>;
  std::vector<Node> nodes_;
  std::vector<CurvePiece> pieces_;  // in leaf order (deforming trees: in input order)
  Aabb bounds_;
  // Deformation (inner trees of moving sets only): the pieces at each step, step-major, in
  // input order (as pieces_), and a tree per slice of the shutter (build) whose leaves index
  // them through slice_refs_.
  static constexpr int kSlices = 8;
  std::vector<CurvePiece> steps_;
  uint32_t n_steps_ = 0;
  std::vector<Node> slice_nodes_[kSlices];
  std::vector<uint32_t> slice_refs_[kSlices];
  CurvePiece deformed(uint32_t i, float time) const;
  template <bool Deform>
  const CurvePiece& leaf_piece(uint32_t i, float time, CurvePiece& scratch) const {
    if constexpr (Deform) {
      scratch = deformed(i, time);
      return scratch;
    } else {
      return pieces_[i];
    }
  }
  MovingSets<CurveBvh> moving_;
  template <bool AnyHit, bool Deform>
  bool traverse(const Ray& ray, Hit& hit) const;
  template <bool AnyHit>
  bool traverse_moving(const Ray& ray, Hit& hit) const;
};

}  // namespace pl
