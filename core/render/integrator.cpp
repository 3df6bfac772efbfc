#include "render/integrator.h"
#include "render/guiding.h"
#include "render/subsurface.h"
#include "scene/phase.h"

namespace pl {
namespace {
#include "render/trace_path.inl"
}  // namespace

bool denoising_features(const ClosureList& cl, Vec3 wo, bool flip, Vec3& normal, Vec3& diffuse_albedo,
                        Vec3& specular_albedo) {
  normal = diffuse_albedo = specular_albedo = Vec3(0.0f);
  float sum = 0.0f, sum_rough = 0.0f;
  for (int i = 0; i < cl.n; ++i) {
    const Closure& c = cl.c[size_t(i)];
    const float w = std::fabs(average(c.weight));
    normal += c.frame.n * w;
    sum += w;
    const Vec3 a = closure_albedo(c, wo);
    if (closure_is_rough(c)) {
      diffuse_albedo += a;
      sum_rough += w;
    } else {
      specular_albedo += a;
    }
  }
  // Mostly (75 % or more) specular: the features come from what is seen through it.
  if (sum > 0.0f && !(sum_rough * 4.0f > sum)) return false;
  if (sum > 0.0f) normal = normal / sum;
  if (flip) normal = -normal;
  return true;
}

namespace {

// The instantiated kernels, fastest first: a render runs the first that covers its features.
struct KernelEntry {
  uint32_t features;
  TraceFn fn;
};
constexpr KernelEntry kKernels[] = {
    {0u, &trace_path_t<0u>},
    {kKernelEnvironment, &trace_path_t<kKernelEnvironment>},
    {kKernelNonDiffuse, &trace_path_t<kKernelNonDiffuse>},
    {kKernelNonDiffuse | kKernelEnvironment, &trace_path_t<kKernelNonDiffuse | kKernelEnvironment>},
    // Media (volumes, absorbing glass) without the environment, the light tree, subsurface or
    // passes: the fog box of build.py bench was on the general kernel.
    {kKernelMedia | kKernelNonDiffuse, &trace_path_t<kKernelMedia | kKernelNonDiffuse>},
};
// The light tree's kernels, in the same order (integrator_tree.cpp).
constexpr uint32_t kTreeKernels[] = {kKernelLightTree, kKernelLightTree | kKernelEnvironment,
                                     kKernelLightTree | kKernelNonDiffuse,
                                     kKernelLightTree | kKernelNonDiffuse | kKernelEnvironment};

}  // namespace

// The caustic light tracing kernels (integrator_caustics.cpp).
TraceFn caustic_kernel(uint32_t needed, bool force_general, uint32_t& chosen);
// The light tree kernel with exactly the features f (one of kTreeKernels).
TraceFn light_tree_kernel(uint32_t f);
// The guided kernels (integrator_guided.cpp), fastest first.
extern const uint32_t kGuidedKernels[4];
TraceFn guided_kernel(uint32_t f);

Vec3 trace_path(const Scene& scene, Ray ray, Sampler& sampler, const IntegratorSettings& s, PathCounters& c,
                PathAovs* aov) {
  return trace_path_t<kKernelAll>(scene, ray, sampler, s, c, aov);
}

uint32_t kernel_features(const SceneFeatures& f, bool aovs, bool guiding, bool caustics, bool tricks,
                         bool fast_gi) {
  uint32_t k = 0;
  // (a light's Max Bounces is one of Cycles' tricks: only those kernels read it)
  if (tricks || f.light_bounce_limits) k |= kKernelTricks;
  if (fast_gi) k |= kKernelFastGI;
  if (caustics) k |= kKernelCaustics;
  if (guiding) k |= kKernelGuiding;
  if (f.media) k |= kKernelMedia;
  if (aovs) k |= kKernelAovs;
  if (!f.diffuse_only()) k |= kKernelNonDiffuse;
  if (f.environment) k |= kKernelEnvironment;
  if (f.light_tree) k |= kKernelLightTree;
  if (f.subsurface) k |= kKernelSubsurface;
  if (f.light_links) k |= kKernelLightLinks;
  // (also the one kernel that steps camera rays past objects they do not see: Indirect Only)
  if ((f.shadow_catcher && aovs) || f.camera_invisible) k |= kKernelShadowCatcher;
  return k;
}

TraceFn select_kernel(uint32_t needed, bool force_general, uint32_t& chosen) {
  if (needed & kKernelCaustics) {  // (the session turns them off with catchers and guiding)
    return caustic_kernel(needed, force_general, chosen);
  }
  if (needed & kKernelShadowCatcher) {  // (the one kernel that splits paths at catchers)
    chosen = kKernelCatcher;
    return &trace_path_t<kKernelCatcher>;
  }
  if (!force_general) {
    for (const KernelEntry& e : kKernels)
      if ((needed & ~e.features) == 0) {
        chosen = e.features;
        return e.fn;
      }
    for (const uint32_t f : kTreeKernels)
      if ((needed & ~f) == 0) {
        chosen = f;
        return light_tree_kernel(f);
      }
    for (const uint32_t f : kGuidedKernels)
      if ((needed & ~f) == 0) {
        chosen = f;
        return guided_kernel(f);
      }
  }
  chosen = kKernelAll;
  return &trace_path_t<kKernelAll>;
}

std::string kernel_name(uint32_t features) {
  if (features == kKernelAll) return "general";
  if (features == (kKernelAll | kKernelCaustics)) return "general+caustics";
  if (features == kKernelCatcher) return "general+catcher";
  std::string n = (features & kKernelNonDiffuse) ? "surfaces" : "diffuse";
  if (features & kKernelEnvironment) n += "+env";
  if (features & kKernelLightTree) n += "+tree";
  if (features & kKernelMedia) n += "+media";
  if (features & kKernelAovs) n += "+passes";
  if (features & kKernelSubsurface) n += "+subsurface";
  if (features & kKernelGuiding) n += "+guiding";
  if (features & kKernelLightLinks) n += "+links";
  if (features & kKernelCaustics) n += "+caustics";
  return n;
}

}  // namespace pl
