// Unidirectional path tracer: BSDF sampling plus next-event estimation to emissive triangles,
// combined with multiple importance sampling (power heuristic), Russian roulette on the path
// throughput, and Blender's "Total" bounce limit (0 = direct light only).
#pragma once
#include <cstdint>

#include "scene/scene.h"
#include "util/rng.h"

namespace pl {

struct IntegratorSettings {
  int max_bounces = 12;
  bool use_nee = true;
  int rr_start_bounce = 3;  // Russian roulette from this bounce on
};

struct PathCounters {
  uint64_t rays = 0;
};

Vec3 trace_path(const Scene& scene, Ray ray, Pcg32& rng, const IntegratorSettings& s, PathCounters& c);

}  // namespace pl
