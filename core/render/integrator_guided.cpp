// The path tracer's guided kernels (kKernelGuiding): a unit of their own, as the light tree's,
// so that the other kernels' code stays as it was.
#include "render/guiding.h"
#include "render/integrator.h"
#include "render/subsurface.h"
#include "scene/phase.h"

namespace pl {
namespace {
#include "render/trace_path.inl"
}  // namespace

constexpr uint32_t kG = kKernelGuiding, kE = kKernelEnvironment, kN = kKernelNonDiffuse, kT = kKernelLightTree;
// Diffuse-only scenes keep the diffuse kernels' direct lobe calls, guided too.
extern const uint32_t kGuidedKernels[4] = {kG | kE, kG | kE | kT, kG | kN | kE, kG | kN | kE | kT};

TraceFn guided_kernel(uint32_t f) {
  switch (f) {
    case kG | kE: return &trace_path_t<kG | kE>;
    case kG | kE | kT: return &trace_path_t<kG | kE | kT>;
    case kG | kN | kE: return &trace_path_t<kG | kN | kE>;
    case kG | kN | kE | kT: return &trace_path_t<kG | kN | kE | kT>;
    default: return &trace_path_t<kKernelAll>;
  }
}

}  // namespace pl
