// The path tracer's kernels for scenes that use the light tree (kKernelLightTree): a unit of
// their own, so that adding them left the other kernels' code as it was (in one unit, GCC's
// unit-growth limits stopped inlining helpers into every kernel: +3 % instructions).
#include "render/integrator.h"
#include "render/guiding.h"
#include "render/subsurface.h"
#include "scene/phase.h"

namespace pl {
namespace {
#include "render/trace_path.inl"
}  // namespace

TraceFn light_tree_kernel(uint32_t f) {
  constexpr uint32_t kT = kKernelLightTree, kE = kKernelEnvironment, kN = kKernelNonDiffuse;
  switch (f) {
    case kT: return &trace_path_t<kT>;
    case kT | kE: return &trace_path_t<kT | kE>;
    case kT | kN: return &trace_path_t<kT | kN>;
    case kT | kN | kE: return &trace_path_t<kT | kN | kE>;
    default: return &trace_path_t<kKernelAll>;
  }
}

}  // namespace pl
