// Point clouds: spheres of a centre and a radius each, as Cycles renders Blender's POINTCLOUD
// objects. Spheres live in world space in a 4-wide BVH of their own (as the curve pieces,
// beside them), traced after the triangles and the curves: scenes without points never touch it.
// Clouds with motion blur (transform, deformation) get trees of their own, traced at the ray's time.
// Hits from inside count (the exit of a sphere the ray starts in), as Embree's sphere points
// on Cycles' CPU. A ray skips the sphere it leaves (Ray::self_curve with kSelfPointBit), its
// far side too: Cycles' Embree reports one root per sphere and rejects the primitive a ray
// leaves, so a ray refracted into a point never meets its exit (docs/design/points.md).
#pragma once
#include <cstdint>
#include <memory>
#include <vector>

#include "geometry/aabb.h"
#include "geometry/bvh.h"
#include "geometry/motion.h"
#include "geometry/moving_sets.h"
#include "geometry/ray.h"

namespace pl {

// Ray::self_curve of a ray leaving point k: k | kSelfPointBit (strands are numbered below it).
constexpr uint32_t kSelfPointBit = 0x80000000u;

// A point's sphere: round (world centre and radius), or, for clouds whose matrix scales
// unevenly, the object-space sphere seen through it (an ellipsoid about the world centre, r
// the object-space radius), as Cycles intersects such clouds in object space.
struct PointSphere {
  Vec3 c;
  float r = 0.0f;
  uint32_t point = 0;  // in the scene's numbering of points (all point sets)
  uint32_t frame = kRoundPoint;  // kRoundPoint, or the PointFrame of its cloud
  static constexpr uint32_t kRoundPoint = UINT32_MAX;
};

// World -> object directions of a cloud whose matrix does not scale evenly (rows of the
// inverse of its 3x3 part).
struct PointFrame {
  Vec3 row[3];
  Vec3 apply(Vec3 v) const { return {dot(row[0], v), dot(row[1], v), dot(row[2], v)}; }
};

// The nearest hit of a ray on a sphere with 0 < t < tmax: where it enters, or where it leaves
// when it starts inside. Solved in double about the ray's closest approach to the centre, so
// tiny spheres far from the origin and far from the ray's origin keep their accuracy. The unit
// outward normal at the hit is returned too (from the double-precision point).
bool intersect_sphere(const Vec3& c, float r, const Vec3& org, const Vec3& dir, float tmax, float& t, Vec3& n);

// The hit of a ray on the ellipsoid of object-space sphere (centre c in world space, radius r)
// through the frame f, as intersect_sphere's; n: the unit direction from the centre to the
// hit (Cycles' point normal, normalize(P - centre), also on ellipsoids).
bool intersect_ellipsoid(const Vec3& c, float r, const PointFrame& f, const Vec3& org, const Vec3& dir, float tmax,
                         float& t, Vec3& n);

// A unit normal as two floats (Hit::b1, b2), continuous octahedral map (no quantisation).
void encode_sphere_normal(Vec3 n, float& b1, float& b2);
Vec3 decode_sphere_normal(float b1, float b2);

// The surface at an encoded hit: the outward unit normal, the point c + r n and a bound of its
// rounding error (for offset_ray_origin).
// f: the sphere's frame (ellipsoids; nullptr for round spheres).
void sphere_surface(const PointSphere& s, const PointFrame* f, float b1, float b2, Vec3& n, Vec3& p, Vec3& error);

// Spheres of the usable points (finite centre, finite radius > 0) in world space through
// `to_world`, numbered from point_base in input order; kept (optional) gets the input index of
// each. A matrix that scales evenly (rotation, mirror and one scale) gives round spheres,
// radii scaled by it; else the spheres are ellipsoids of the object-space radii through a new
// frame appended to `frames`. Returns how many were left out (all for a singular matrix).
size_t transform_points(const Vec3* points, const float* radii, size_t n, const Mat4& to_world, uint32_t point_base,
                        std::vector<PointSphere>& out, std::vector<PointFrame>& frames,
                        std::vector<uint32_t>* kept = nullptr);

class PointBvh {
 public:
  // Hit::prim of a sphere of a moving cloud (add_moving): this bit and the sphere's number
  // over all moving clouds.
  static constexpr uint32_t kMovingPrim = 0x80000000u;
  // steps (optional, moving clouds' trees): the spheres at n_steps >= 2 deformation steps,
  // step-major in `spheres`' order; the boxes then hold each sphere over the whole shutter.
  void build(std::vector<PointSphere> spheres, std::vector<PointFrame> frames = {}, std::vector<PointSphere> steps = {},
             uint32_t n_steps = 0);
  // A cloud with transform motion blur (after build): its spheres in object space (round
  // there, r the object radius), entered through its transform at the ray's time, interpolated
  // from the decomposed steps as moving instances are (geometry/motion.h); so under uneven
  // scales they are ellipsoids, as Cycles' object-space spheres.
  // deform (optional): the spheres (object space) at n_deform deformation steps, as build's
  // (Cycles' motion points: centre and radius interpolated linearly between steps).
  void add_moving(std::vector<PointSphere> spheres, std::vector<DecomposedTransform> steps,
                  std::vector<PointSphere> deform = {}, uint32_t n_deform = 0);
  bool has_moving() const { return !moving_.empty(); }
  void clear() { *this = PointBvh(); }
  bool empty() const { return spheres_.empty() && moving_.empty(); }
  size_t size() const { return spheres_.size() + moving_.end; }
  // The sphere of Hit::prim (a moving one: in its object space).
  const PointSphere& sphere(uint32_t prim) const {
    if (!(prim & kMovingPrim)) return spheres_[prim];
    const uint32_t i = prim & ~kMovingPrim, m = moving_.set_of(i);
    return moving_.trees[m]->spheres_[i - moving_.first[m]];
  }
  const PointFrame* frame(const PointSphere& s) const {
    return s.frame == PointSphere::kRoundPoint ? nullptr : &frames_[s.frame];
  }
  // The sphere of Hit::prim in world space at shutter time `time` (moving clouds: its centre
  // and its object frame at that time, r the object radius; else sphere(prim)), and its frame
  // (nullptr: round) in `frame`'s storage.
  PointSphere world_sphere(uint32_t prim, float time, PointFrame& frame_storage, const PointFrame*& frame) const;
  // A moving cloud's object-to-world matrix at `time` (prim: one of its spheres).
  Mat4 moving_transform(uint32_t prim, float time) const;
  Aabb bounds() const { return bounds_; }
  size_t memory_bytes() const {
    size_t b = nodes_.capacity() * sizeof(Node) + (spheres_.capacity() + steps_.capacity()) * sizeof(PointSphere) +
               frames_.capacity() * sizeof(PointFrame);
    for (int j = 0; j < kSlices; ++j) b += slice_nodes_[j].capacity() * sizeof(Node) + slice_refs_[j].capacity() * 4;
    return b + moving_.memory_bytes();
  }
  // Closest hit before ray.tmax on spheres other than the one the ray leaves: prim the sphere
  // (leaf order; kMovingPrim: of a moving cloud), (b1, b2) its normal (encode_sphere_normal).
  bool intersect(const Ray& ray, Hit& hit) const;
  bool occluded(const Ray& ray) const;

 private:
  using Node = WideBvhNode<4>;
  std::vector<Node> nodes_;
  std::vector<PointSphere> spheres_;  // in leaf order (deforming trees: in input order)
  std::vector<PointFrame> frames_;
  Aabb bounds_;
  // Deformation (inner trees of moving clouds only): the spheres at each step, step-major, in
  // input order (as spheres_), and a tree per slice of the shutter (build) whose leaves index
  // them through slice_refs_.
  static constexpr int kSlices = 8;
  std::vector<PointSphere> steps_;
  uint32_t n_steps_ = 0;
  std::vector<Node> slice_nodes_[kSlices];
  std::vector<uint32_t> slice_refs_[kSlices];
  PointSphere deformed(uint32_t i, float time) const {
    const size_t n = spheres_.size();
    const float f = clampf(time, 0.0f, 1.0f) * float(n_steps_ - 1);
    const uint32_t k = std::min(uint32_t(f), n_steps_ - 2);
    const float w = f - float(k);
    const PointSphere &a = steps_[size_t(k) * n + i], &b = steps_[size_t(k + 1) * n + i];
    PointSphere s = spheres_[i];
    s.c = a.c + (b.c - a.c) * w;
    s.r = std::max(0.0f, a.r + (b.r - a.r) * w);
    return s;
  }
  MovingSets<PointBvh> moving_;
  template <bool AnyHit, bool Deform>
  bool traverse(const Ray& ray, Hit& hit) const;
  template <bool AnyHit>
  bool traverse_moving(const Ray& ray, Hit& hit) const;
};

}  // namespace pl
