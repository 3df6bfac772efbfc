// Blender's Vector Rotate, Vector Transform, Blackbody and Wavelength nodes, and the Texture
// Coordinate / Geometry / Tangent outputs that need the camera or the object's texture space,
// as Cycles evaluates them (its formulas, tables and order of operations).
#pragma once
#include "util/math.h"

namespace pl {

class Camera;
struct ObjectCoords;

// Vector Rotate: type 0 Axis Angle, 1 X Axis, 2 Y Axis, 3 Z Axis, 4 Euler XYZ.
Vec3 vector_rotate(int type, bool invert, Vec3 v, Vec3 center, Vec3 axis, float angle, Vec3 euler);

// Blackbody: scene-linear Rec.709 colour of a temperature in kelvin (Cycles' piecewise fit,
// clamped to non-negative as the node does).
Vec3 blackbody_color(float kelvin);

// Wavelength: the CIE 1931 colour matching functions (5 nm table) -> XYZ -> scene-linear
// Rec.709, scaled by Cycles' 1 / 2.52 and clamped to non-negative.
Vec3 wavelength_color(float nm);

// Vector Transform: type 0 Point, 1 Vector, 2 Normal; spaces 0 World, 1 Object, 2 Camera.
// object: the hit instance (nullptr or singular: object space is world space, as Cycles
// without an object); camera: the render's (nullptr: camera space is world space).
Vec3 vector_transform(int type, int from, int to, Vec3 v, const ObjectCoords* object, const Camera* camera);

// World <-> Cycles' camera space (x right, y up, z forward: Blender's -Z), without scale.
Vec3 world_to_camera_point(const Camera* camera, Vec3 p);

// A direction turned like a normal from object to world space (Cycles'
// object_normal_transform: the inverse transpose, then normalised).
Vec3 object_to_world_normal(const ObjectCoords* object, Vec3 n);
// A world-space normal in object space (Cycles' object_inverse_normal_transform: the
// transpose of the object's matrix, not normalised); world space without a valid object.
Vec3 world_to_object_normal(const ObjectCoords* object, Vec3 n);

// Cycles' tangent-space Normal Map (svm_node_normal_map): color in [0, 1]^3 read as 2c - 1
// over the unnormalised interpolated object-space tangent, sign * cross(normal, tangent) and
// normal (mesh orientation), normalised and turned to world space as a normal. Zero where
// it degenerates (the caller keeps its normal).
Vec3 tangent_space_normal(const ObjectCoords* object, Vec3 tangent, float sign, Vec3 normal, Vec3 color);

// Cycles' Normal Map in space 1 Object, 2 World, 3 Blender Object, 4 Blender World: color read
// as 2c - 1 (the Blender ones with y and z negated), turned as a normal to world space (the
// object ones) or normalised. Zero where it degenerates.
Vec3 object_world_space_normal(int space, const ObjectCoords* object, Vec3 color);

}  // namespace pl
