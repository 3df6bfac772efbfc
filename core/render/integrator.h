// Unidirectional path tracer: BSDF sampling plus next-event estimation to every light
// (analytic lights, emissive triangles, the environment), combined with multiple importance
// sampling (power heuristic), Russian roulette on the path throughput, and Blender's bounce
// limits (total and per type; bounce 0 is direct light).
#pragma once
#include <cstdint>

#include "scene/scene.h"
#include "util/sampler.h"

namespace pl {

struct IntegratorSettings {
  int max_bounces = 12;
  int diffuse_bounces = 1024;
  int glossy_bounces = 1024;
  int transmission_bounces = 1024;
  bool use_nee = true;
  int rr_start_bounce = 3;  // Russian roulette from this bounce on
};

struct PathCounters {
  uint64_t rays = 0;
};

Vec3 trace_path(const Scene& scene, Ray ray, Sampler& sampler, const IntegratorSettings& s, PathCounters& c);

}  // namespace pl
