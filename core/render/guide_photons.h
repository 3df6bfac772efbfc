// Photon training for path guiding (Jensen 1995, "Importance driven path tracing using the
// photon map"; Vorba et al. 2014): light paths from the scene's lights record, at every rough
// surface they reach after at least one bounce, the flux they bring and its direction into the
// guiding field. Light that comes the long way round (sun -> metal bowl -> wall) then has many
// records per cell, whatever the image's resolution. Only the sampling pdf changes: unbiased.
#pragma once
#include <atomic>
#include <cstdint>
#include <memory>
#include <vector>

#include "render/guiding.h"
#include "scene/scene.h"

namespace pl {

// Where photons start: the analytic lights, the environment or world colour, chosen by power
// (emissive triangles are left out: camera records still learn them).
struct GuidePhotonSources {
  std::vector<uint32_t> items;  // light index, or kWorld
  Distribution1D choice;
  float power = 0.0f;  // the estimated total: photons carry flux / power (about 1 each)
  Vec3 center;
  float radius = 1.0f;  // the scene's bounding sphere, for distant sources
  static constexpr uint32_t kWorld = 0xffffffffu;
  bool empty() const { return choice.empty() || !(power > 0.0f); }
  // A distant source's disk is mostly wasted (photons that miss the room, or hit its outside:
  // a window takes a few percent of the sun's): each is a kGrid x kGrid grid of cells, drawn in
  // proportion to the records their photons made in the last iteration, with a uniform share
  // kUniform. (The flux carries the inverse pdf: training sees the light as it is.)
  static constexpr int kGrid = 64;
  static constexpr float kUniform = 0.1f;
  std::vector<Distribution1D> disk;  // per item (empty: uniform)
  std::unique_ptr<std::atomic<uint64_t>[]> hits;  // per item and cell: the records made
  // The iteration's hits become the disks' distributions (between iterations).
  void end_iteration();
};
GuidePhotonSources guide_photon_sources(const Scene& scene);

// Traces photons [first, last) of one training iteration into `guide` (record_photon). Photon
// i draws from its own stream (seed, i): the records, summed in fixed point, do not depend on
// the threads. Returns the rays traced.
// caustics: only L S+ D photons, the light that camera paths find worst (sun -> metal bowl ->
// wall): a photon goes on only through smooth lobes (those guiding leaves alone), records at
// the first guidable surface after at least one of them and stops there; the records are kept
// over the iterations (GuidingField::keep_photons) and the adaptive disks aim at what records.
uint64_t trace_guide_photons(const Scene& scene, GuidePhotonSources& src, GuidingField& guide, uint64_t seed,
                             uint64_t first, uint64_t last, int max_bounces, bool caustics = false);

}  // namespace pl
