// A light's node tree as a shader program (Cycles' light shaders): evaluated at each light
// sample and ray hit with the coordinates Cycles' shader_setup_from_sample gives a lamp. Lights
// without one (or whose tree is constant, folded into Light::color) never get here.
#pragma once
#include <atomic>

#include "scene/light.h"
#include "scene/shader.h"

namespace pl {

class Scene;

struct LightShader {
  ShaderProgram program;
  // The light's frame: Texture Coordinate's Object and Normal outputs, Vector Transform's object
  // space (Cycles' lamp transform); Generated reads the object coordinates (lamps have none).
  ObjectCoords object;
  Mat4 to_local;  // world -> light-local directions (inverse 3x3 of the light's matrix)
  // Spots: Cycles' half_cot_half_spot_angle, 0.5 / tan(spot_size / 2): its uv covers the cone.
  float half_cot_half_spot = 0.5f;
  const Scene* scene = nullptr;  // images, ambient occlusion (set at commit)
};

// The world's Surface as a program (Environment's program kind): evaluated per escaped ray and
// light sample with Cycles' background setup (P = the direction, N = Ng = Incoming = -it, no
// object); its emission (Background and Emission closures) is the radiance.
struct WorldShader {
  ShaderProgram program;
  const Scene* scene = nullptr;  // images, ambient occlusion (set at commit)
  // The render's camera (Texture Coordinate's Camera and Window) for light samples and the map;
  // escaped rays carry their own (RayState::camera). Set by the session; nullptr: none. Atomic:
  // sessions on one committed scene (the viewport's restarts) set and clear it while another's
  // threads may still read it.
  mutable std::atomic<const Camera*> camera{nullptr};
};

// Cycles' light uv (Parametric and UV outputs; Cycles' "barycentric" (u, v) turned back into
// the node's (1 - u - v, u)) of light l at its point q, towards unit direction wi from the
// shaded point, with the emission normal n.
Vec2 light_parametric(const Light& l, const LightShader& sh, Vec3 q, Vec3 wi, Vec3 n);

}  // namespace pl
