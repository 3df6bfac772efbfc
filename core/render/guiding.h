// Path guiding: a spatio-directional tree of incident radiance learnt during the render
// (Müller, Gross and Novák 2017, "Practical Path Guiding": a binary tree over the scene's
// bounds whose cells each hold a quadtree over the sphere's equal-area square), sampled in
// one-sample MIS with the BSDF. Our own implementation; Open PGL, which Cycles uses, is no
// package here.
//
// Deterministic and independent of the thread count: training iterations end at fixed sample
// counts, and records go into integer (fixed-point) sums, whose atomic additions give the same
// totals in any order.
#pragma once
#include <atomic>
#include <cstdint>
#include <memory>
#include <mutex>
#include <unordered_map>
#include <vector>

#include "geometry/aabb.h"
#include "util/math.h"
#include "util/sampling.h"

namespace pl {

class GuidingField {
 public:
  static constexpr int kMaxQuadDepth = 20;
  static constexpr int kMaxSpatialDepth = 24;
  static constexpr size_t kMaxCells = 1 << 15;  // spatial cells: bounds the field's memory
  static constexpr float kSubdivide = 0.01f;  // a quadrant with more than this share of the energy splits

  GuidingField();
  ~GuidingField();
  GuidingField(const GuidingField&) = delete;
  GuidingField& operator=(const GuidingField&) = delete;

  // Starts over for a scene inside `bounds`; `split_threshold`: records per cell (times the
  // square root of an iteration's samples) above which a cell splits.
  void reset(const Aabb& bounds, float split_threshold);
  // A distribution has been learnt (after the first iteration): sample() and pdf() are valid.
  bool ready() const { return iterations_ > 0; }
  int iterations() const { return iterations_; }
  size_t cells() const { return cells_.size() / kNormalClasses; }  // spatial cells

  // Each spatial cell keeps one quadtree per class of surface orientation (the axis and sign
  // of the normal's largest component), so that a coarse cell over a floor and a wall does not
  // blend the light the floor sees with the wall's, and send floor samples into the floor.
  static constexpr uint32_t kNormalClasses = 6;
  // The quadtree for point p on a surface facing n (what the calls below take, found once per
  // vertex).
  uint32_t cell_of(Vec3 p, Vec3 n) const;
  // A direction from the cell's learnt distribution, and its solid-angle pdf. u in [0, 1)^2.
  Vec3 sample(uint32_t cell, Vec2 u, float& pdf) const;
  float pdf(uint32_t cell, Vec3 w) const;
  Vec3 sample(Vec3 p, Vec3 n, Vec2 u, float& pdf) const { return sample(cell_of(p, n), u, pdf); }
  float pdf(Vec3 p, Vec3 n, Vec3 w) const { return pdf(cell_of(p, n), w); }

  // Training (any thread, during a pass): radiance `value` (a scalar estimate of the radiance
  // arriving in the cell from unit direction w, divided by the pdf that sampled w).
  void record(uint32_t cell, Vec3 w, float value);
  void record(Vec3 p, Vec3 n, Vec3 w, float value) {
    if (is_finite(p)) record(cell_of(p, n), w, value);
  }
  // Ends a training iteration of `samples` samples per pixel: the recorded sums become the
  // sampling distribution, the quadtrees refine, crowded cells split. Not thread-safe: call
  // between passes.
  void end_iteration(int samples);

  // A guide probability learnt per cell, in place of one for all (Müller 2019 learns it by
  // gradient descent on the KL divergence, in the order records arrive; here, deterministically,
  // once per iteration): each training record also adds, for every candidate probability a_k,
  // the second moment its vertex's estimate would have had with it (est^2 q / q_k: est, the
  // vertex's BSDF-side estimate over the pdf q it was drawn with; q_k = a_k guide + (1 - a_k)
  // BSDF pdf), in fixed point, and end_iteration gives each cell with enough records the
  // candidate of least sum, at most `initial`, the cells' probability until then.
  static constexpr int kProbabilities = 10;  // 0, 0.1, ..., 0.9
  static constexpr uint64_t kMinMomentRecords = 256;
  void set_learn_probability(bool on, float initial);
  bool learns_probability() const { return learn_probability_; }
  float probability(uint32_t cell) const;
  // The cells' probabilities weighted by the records of the last iteration (a statistic).
  float mean_probability() const { return mean_probability_; }
  // est: the vertex's estimate over q (luminance); q: the pdf it was drawn with; pb, pg: the
  // BSDF's and the guide's pdfs of its direction.
  void record_moment(uint32_t cell, float est, float q, float pb, float pg);
  // Müller et al.'s directional filter: a record (camera or photon) is spread over a square of
  // the size of the quadtree leaf it falls in, centred on it, by area (phi wraps round).
  void set_directional_filter(bool on) { filter_ = on; }

  // Photon training (Jensen 1995; Vorba et al. 2014): flux that light paths bring to a cell
  // from direction w, in units of the mean emitted photon (about 1). Summed apart from the
  // camera records; end_iteration normalises each per cell and mixes them, `photon_share` of
  // the photons' (where a cell has both), so their scales never meet.
  void record_photon(uint32_t cell, Vec3 w, float value);
  void set_photon_share(float share) { photon_share_ = share; }
  // What a photon record counts for towards a cell's split, against a camera record's 1.
  void set_photon_split_weight(float w) { photon_split_weight_ = w; }
  float photon_share() const { return photon_share_; }
  uint64_t photon_records() const { return photon_records_; }  // all iterations so far

  // Kept photon records (caustic photons, guide_photons.h): where and from where flux arrived.
  // Unlike record_photon's, they are kept over the iterations: every end_iteration sums all of
  // them into the cells of the field as it is then (a photon is an estimate of the same
  // incident light whichever iteration traced it), so late guides learn from all photons.
  struct PhotonRecord {
    Vec3 p;
    Vec2 s;  // the arrival direction on the unit square (to_square)
    float value;
    uint8_t normal_class;
  };
  static constexpr size_t kMaxKeptPhotons = size_t(1) << 22;  // ~100 MB: later ones only count once
  // Any thread, during photon tracing; the records' order does not matter (fixed-point sums).
  void keep_photons(std::vector<PhotonRecord>& records);
  static uint8_t normal_class(Vec3 n);

  // Caustic lobes (photon-map guiding at a point, after Jensen 1995): the kept caustic photons
  // binned into small cubes of the scene (and the 6 orientation classes), each cube's photons
  // merged by arrival direction into at most kMaxLobes lobes, a lobe a cone of half-angle
  // `cone` about where its photons came from. The SD-tree's cells are too coarse for a metal
  // bowl's caustic on a wall (the bowl a few thousandths of a steradian, its highlight less);
  // these aim at the highlight seen from about the vertex. Rebuilt by end_iteration from all
  // kept photons; `cube`: the cubes' edge over the scene's diagonal (0: no lobes).
  static constexpr int kMaxLobes = 32;
  void set_caustic_lobes(float cube, float cone);
  // The cube of p on a surface facing n, or -1 where no caustic photon arrived.
  int32_t caustic_cell(Vec3 p, Vec3 n) const;
  Vec3 caustic_sample(int32_t cell, float u_lobe, Vec2 u, float& pdf) const;
  float caustic_pdf(int32_t cell, Vec3 w) const;
  size_t caustic_cells() const { return caustic_cells_.size(); }

  // The unit square's equal-area map of the sphere (z = cos theta, phi around z).
  static Vec2 to_square(Vec3 w);
  static Vec3 from_square(Vec2 s);

  struct Cell;

 private:
  struct SpatialNode {
    uint32_t child = 0;  // the first of two children (the second follows); 0: a leaf
    uint32_t cell = 0;  // a leaf's first quadtree (kNormalClasses follow)
    uint8_t axis = 0;  // the split's axis (x, y, z in turn by depth)
    uint8_t depth = 0;
  };
  Aabb bounds_;
  Vec3 inv_extent_{1.0f};
  float split_threshold_ = 0.0f;
  double scale_ = 65536.0;  // fixed-point units per unit of recorded value
  float photon_share_ = 0.5f;
  bool learn_probability_ = false, filter_ = false;
  float initial_probability_ = 0.5f, mean_probability_ = 0.0f;
  float photon_split_weight_ = 1.0f;
  uint64_t photon_records_ = 0;
  int iterations_ = 0;
  std::vector<SpatialNode> nodes_;
  std::vector<std::unique_ptr<Cell>> cells_;
  std::mutex photon_mutex_;
  std::vector<PhotonRecord> photon_map_;  // all kept photons (the first kMaxKeptPhotons)
  size_t photon_map_new_ = 0;  // where this iteration's kept photons start
  uint32_t leaf_of(Vec3 p) const;  // the spatial leaf's first quadtree
  struct CausticLobe {
    Vec3 dir;
    float cdf;  // the lobes' running share of the cube's flux, the last 1
  };
  struct CausticCube {
    uint32_t first = 0, count = 0;
  };
  float caustic_cube_ = 0.0f, cos_cone_ = 1.0f, cone_pdf_ = 0.0f;
  float caustic_inv_h_ = 0.0f;
  std::unordered_map<uint64_t, uint32_t> caustic_index_;  // cube key -> caustic_cells_
  std::vector<CausticCube> caustic_cells_;
  std::vector<CausticLobe> caustic_lobes_;
  uint64_t caustic_key(Vec3 p, uint32_t normal_class) const;
  void build_caustic_lobes();
};

// A guided vertex's one-sample MIS mixture pdf towards w: the BSDF's (bsdf_pdf), the guide's in
// `cell` with probability gp (sd_pdf where already known, else negative: looked up), and the
// caustic lobes of caustic_cell with probability pc (none where caustic_cell < 0). The camera
// path (trace_path.inl) and the caustic light paths' weight at its rough vertex
// (integrator_caustics.cpp) both take it from here, so the two sides compute the same number.
inline float guided_mixture_pdf(const GuidingField& g, float bsdf_pdf, Vec3 w, float gp, uint32_t cell, float sd_pdf,
                                int32_t caustic_cell, float pc) {
  // (a cell that learnt 0 never samples its guide: no quadtree descent, the same value)
  float p = bsdf_pdf;
  if (gp > 0.0f) p = (1.0f - gp) * bsdf_pdf + gp * (sd_pdf >= 0.0f ? sd_pdf : g.pdf(cell, w));
  if (caustic_cell >= 0) p = (1.0f - pc) * p + pc * g.caustic_pdf(caustic_cell, w);
  return p;
}

}  // namespace pl
