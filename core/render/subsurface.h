// Random-walk subsurface scattering as Cycles 4.5 does it (integrator/subsurface.h and
// subsurface_random_walk.h): a path that picks a BSSRDF closure refracts (or diffuses) into the
// mesh, walks through a homogeneous medium made from the closure's radius and albedo, and
// leaves where it meets the same object's surface again; the path goes on there from a diffuse
// closure. Our own implementation of the published method (Chiang, Kutz & Burley 2016; the
// anisotropic albedo fit of Wrenninge, Villemin & Hery), without Cycles' Dwivedi guiding (a
// variance reduction: the walk's expectation is the same).
#pragma once
#include <cstdint>

#include "scene/scene.h"

namespace pl {

constexpr int kSubsurfaceMaxSteps = 256;  // Cycles' BSSRDF_MAX_BOUNCES: the walk always ends

// Cycles' subsurface_random_walk_remap: the single-scattering albedo whose multiple-scattering
// albedo (of a half space lit diffusely) is `albedo`, for Henyey-Greenstein anisotropy g (a
// published fit, its constants as Cycles has them), and the extinction from the mean free
// path d: 1 / (d (1 - g)).
void subsurface_coefficients(float albedo, float d, float g, float& sigma_t, float& alpha);

// The walk from shading point sp (the viewer towards wo; n: the closure's normal and ng_out
// the geometric normal, both on the viewer's side) into instance sp.instance. u: the entry's
// 2D sample; u_first: the first segment's channel and distance (stratified numbers the path
// has left over; negative: drawn from the walk's stream); seed: the walk's own random stream (decorrelated from the path's, as Cycles').
// beta: the path throughput with the closure's weight / pick applied; on success it holds the
// throughput at the exit, `exit` the hit there and exit_dir the walk's last direction
// (pointing out of the surface: the exit vertex's wo). False: no exit found (the path ends).
bool subsurface_walk(const Scene& scene, const SurfacePoint& sp, Vec3 ng_out, Vec3 n, Vec3 wo,
                     const SubsurfaceBsdf& b, Vec2 u, Vec2 u_first, uint64_t seed, Vec3& beta, Hit& exit,
                     Vec3& exit_dir, uint64_t& rays);

}  // namespace pl
