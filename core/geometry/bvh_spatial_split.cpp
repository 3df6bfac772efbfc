// Spatial splits (SBVH, Stich, Friedrich & Dietrich 2009): binned planes that cut the
// triangles themselves, tried where an object split's children overlap; a cut triangle is
// referenced by both children, each with the box of its part (clip_triangle).
#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <memory>
#include <utility>
#include <vector>

#include "geometry/bvh_build.h"
#include "util/parallel.h"

namespace pl {
namespace {

inline float round_down(double d) {
  const float f = static_cast<float>(d);
  return std::nextafter(static_cast<double>(f) > d ? std::nextafter(f, -kInf) : f, -kInf);
}
inline float round_up(double d) {
  const float f = static_cast<float>(d);
  return std::nextafter(static_cast<double>(f) < d ? std::nextafter(f, kInf) : f, kInf);
}

// The box of the part of the triangle with plo <= x[axis] <= phi, intersected with `box` (the
// reference's box). The real triangle is clipped (in double, then rounded outwards one ulp
// more than needed), so the box always contains that part of it: a hit in it is never culled
// by the slab tests. Empty (lo > hi) when nothing of the triangle is left.
Aabb clip_triangle(const TriangleVerts& t, int axis, float plo, float phi, const Aabb& box) {
  const Vec3* v[3] = {&t.v0, &t.v1, &t.v2};
  double lo[3] = {kInf, kInf, kInf}, hi[3] = {-kInf, -kInf, -kInf};
  const auto grow = [&](const double p[3]) {
    for (int k = 0; k < 3; ++k) {
      lo[k] = std::min(lo[k], p[k]);
      hi[k] = std::max(hi[k], p[k]);
    }
  };
  for (int i = 0; i < 3; ++i) {
    const Vec3& a = *v[i];
    const Vec3& b = *v[i == 2 ? 0 : i + 1];
    const double pa[3] = {a.x, a.y, a.z}, pb[3] = {b.x, b.y, b.z};
    if (pa[axis] >= plo && pa[axis] <= phi) grow(pa);
    for (const float q : {plo, phi}) {
      if (!std::isfinite(q)) continue;
      const double da = pa[axis] - q, db = pb[axis] - q;
      if (!((da < 0 && db > 0) || (da > 0 && db < 0))) continue;  // the edge does not cross the plane
      const double s = da / (da - db);
      double p[3];
      for (int k = 0; k < 3; ++k) p[k] = pa[k] + s * (pb[k] - pa[k]);
      p[axis] = q;
      grow(p);
    }
  }
  Aabb r;
  if (!(lo[0] <= hi[0] && lo[1] <= hi[1] && lo[2] <= hi[2])) return r;  // empty (or NaN)
  r.lo = vmax(Vec3(round_down(lo[0]), round_down(lo[1]), round_down(lo[2])), box.lo);
  r.hi = vmin(Vec3(round_up(hi[0]), round_up(hi[1]), round_up(hi[2])), box.hi);
  if (std::isfinite(plo)) r.lo[axis] = std::max(r.lo[axis], plo);
  if (std::isfinite(phi)) r.hi[axis] = std::min(r.hi[axis], phi);
  if (r.lo.x > r.hi.x || r.lo.y > r.hi.y || r.lo.z > r.hi.z) return Aabb();
  return r;
}

}  // namespace

namespace bvh_detail {

// The bins of a spatial split (Stich et al. 2009) on all three axes: each bin's box holds the
// parts of the triangles inside its slab; entry / exit count the references starting / ending
// in it.
struct SpatialBinSet {
  V4 lo[3][kMaxBins], hi[3][kMaxBins];
  uint32_t entry[3][kMaxBins], exit[3][kMaxBins];
  void reset(int bins) {
    for (int a = 0; a < 3; ++a)
      for (int b = 0; b < bins; ++b) {
        lo[a][b] = V4::set1(kInf);
        hi[a][b] = V4::set1(-kInf);
        entry[a][b] = exit[a][b] = 0;
      }
  }
  void merge(const SpatialBinSet& o, int bins) {
    for (int a = 0; a < 3; ++a)
      for (int b = 0; b < bins; ++b) {
        lo[a][b] = vmin(lo[a][b], o.lo[a][b]);
        hi[a][b] = vmax(hi[a][b], o.hi[a][b]);
        entry[a][b] += o.entry[a][b];
        exit[a][b] += o.exit[a][b];
      }
  }
};

// First and last spatial bin of a reference on `axis`. References with a non-finite box are
// never cut (clipping them means nothing): they stay whole in their first bin.
void Builder::span(const PrimRef& r, int axis, float lo, float scale, int& first, int& last) const {
  const int B = opt_.bins;
  first = bin_of(r.lo[axis], lo, scale, B);
  last = is_finite(r.lo) && is_finite(r.hi) ? std::max(first, bin_of(r.hi[axis], lo, scale, B)) : first;
}

// Spatial bins of refs_[begin, end) on every axis with scale > 0: each reference's triangle
// clipped to every bin slab it spans.
void Builder::spatial_bin_range(uint32_t begin, uint32_t end, const float lo[3], const float scale[3],
                                const float step[3], SpatialBinSet& sb) const {
  V4 plo[kMaxBins], phi[kMaxBins];  // the triangle's part in each bin it spans
  for (uint32_t i = begin; i < end; ++i) {
    if ((i & 4095) == 0 && cancelled()) return;  // a big node's clipping takes a while: stay cancellable
    const PrimRef& r = refs_[i];
    const V4 box_lo = r.vlo(), box_hi = r.vhi();
    const bool finite = is_finite(r.lo) && is_finite(r.hi);
    const TriangleVerts& t = tris_[r.id];
    const Vec3* v[3] = {&t.v0, &t.v1, &t.v2};
    V4 vv[3];
    bool loaded = false;
    for (int a = 0; a < 3; ++a) {
      if (!(scale[a] > 0.0f)) continue;
      const int f = bin_of(r.lo[a], lo[a], scale[a], opt_.bins);
      const int l = finite ? std::max(f, bin_of(r.hi[a], lo[a], scale[a], opt_.bins)) : f;  // as span()
      sb.entry[a][f]++;
      sb.exit[a][l]++;
      if (f == l) {
        sb.lo[a][f] = vmin(sb.lo[a][f], box_lo);
        sb.hi[a][f] = vmax(sb.hi[a][f], box_hi);
        continue;
      }
      // The triangle's part in each slab: its vertices there and its edges' crossings of the
      // slab's planes, one walk along each edge (float: the bins only estimate costs; the
      // partition clips exactly).
      if (!loaded) {
        for (int k = 0; k < 3; ++k) vv[k] = V4::set(v[k]->x, v[k]->y, v[k]->z);
        loaded = true;
      }
      for (int b = f; b <= l; ++b) {
        plo[b] = V4::set1(kInf);
        phi[b] = V4::set1(-kInf);
      }
      int vb[3];
      for (int k = 0; k < 3; ++k) {
        vb[k] = std::clamp(bin_of((*v[k])[a], lo[a], scale[a], opt_.bins), f, l);
        plo[vb[k]] = vmin(plo[vb[k]], vv[k]);
        phi[vb[k]] = vmax(phi[vb[k]], vv[k]);
      }
      for (int e = 0; e < 3; ++e) {
        int k0 = e, k1 = e == 2 ? 0 : e + 1;
        if (vb[k0] == vb[k1]) continue;
        if (vb[k0] > vb[k1]) std::swap(k0, k1);
        const float a0 = (*v[k0])[a], da = (*v[k1])[a] - a0;
        const float inv = da > 0.0f ? 1.0f / da : 0.0f;
        const V4 d = vv[k1] - vv[k0];
        for (int j = vb[k0] + 1; j <= vb[k1]; ++j) {  // plane j: between bins j - 1 and j
          const float q = lo[a] + float(j) * step[a];
          const V4 x = vv[k0] + d * V4::set1(std::clamp((q - a0) * inv, 0.0f, 1.0f));
          plo[j - 1] = vmin(plo[j - 1], x);
          phi[j - 1] = vmax(phi[j - 1], x);
          plo[j] = vmin(plo[j], x);
          phi[j] = vmax(phi[j], x);
        }
      }
      for (int b = f; b <= l; ++b) {
        const V4 cl = vmax(plo[b], box_lo), ch = vmin(phi[b], box_hi);
        if (V4::any_gt_xyz(cl, ch)) continue;
        sb.lo[a][b] = vmin(sb.lo[a][b], cl);
        sb.hi[a][b] = vmax(sb.hi[a][b], ch);
      }
    }
  }
}

// Looks for a spatial split of refs_[begin, end) (Stich et al. 2009) cheaper than `to_beat`
// (the SAH cost of the object split or leaf the node would otherwise get, in the same units)
// whose duplicates fit in the node's spare slots. On success the children's references are
// written in place (left from begin, right after the left's share of the spare slots), `sp`
// is filled and placed, and it returns true; else refs_ is untouched.
bool Builder::spatial_split(const Aabb& bounds, uint32_t begin, uint32_t end, uint32_t cap_end, int depth,
                            float to_beat, Split& sp) {
  const uint32_t n = end - begin, room = cap_end - begin;
  const int B = opt_.bins;
  const Vec3 ext = bounds.extent();
  float lo[3], scale[3], step[3];
  for (int a = 0; a < 3; ++a) {
    lo[a] = bounds.lo[a];
    const bool ok = ext[a] > 0.0f && std::isfinite(ext[a]);
    scale[a] = ok ? B / ext[a] : 0.0f;
    step[a] = ok ? ext[a] / B : 0.0f;
  }
  // One bin set per thread, reused: a node's attempt must not cost an allocation.
  thread_local std::unique_ptr<SpatialBinSet> bin_store;
  if (!bin_store) bin_store = std::make_unique<SpatialBinSet>();
  SpatialBinSet* sb = bin_store.get();
  const int chunks = chunk_count(n, depth);
  if (chunks == 1) {
    sb->reset(B);
    spatial_bin_range(begin, end, lo, scale, step, *sb);
  } else {  // merged in a fixed order (min, max and sums: the same bins in any order anyway)
    std::vector<std::unique_ptr<SpatialBinSet>> part(chunks);
    run_chunks(chunks, [&](int c) {
      part[c] = std::make_unique<SpatialBinSet>();
      part[c]->reset(B);
      spatial_bin_range(begin + chunk_start(n, c, chunks), begin + chunk_start(n, c + 1, chunks),
                        lo, scale, step, *part[c]);
    });
    sb->reset(B);
    for (const auto& p : part) sb->merge(*p, B);
  }
  if (cancelled()) return false;
  float best_cost = kInf;
  int best_axis = -1, best_plane = 0;
  for (int a = 0; a < 3; ++a) {
    if (!(scale[a] > 0.0f)) continue;
    float right_cost[kMaxBins];
    uint32_t right_n[kMaxBins];
    BoxAcc acc;
    uint32_t cnt = 0;
    for (int j = B - 1; j > 0; --j) {
      acc.grow(sb->lo[a][j], sb->hi[a][j]);
      cnt += sb->exit[a][j];
      right_cost[j] = half_area(acc.lo, acc.hi) * tests(cnt);  // +inf for an empty box: never chosen
      right_n[j] = cnt;
    }
    acc = BoxAcc();
    cnt = 0;
    for (int j = 1; j < B; ++j) {  // the plane between bins j - 1 and j
      acc.grow(sb->lo[a][j - 1], sb->hi[a][j - 1]);
      cnt += sb->entry[a][j - 1];
      if (cnt == 0 || right_n[j] == 0 || uint64_t(cnt) + right_n[j] > room) continue;
      const float cost = half_area(acc.lo, acc.hi) * tests(cnt) + right_cost[j];
      if (cost < best_cost) {
        best_cost = cost;
        best_axis = a;
        best_plane = j;
      }
    }
  }
  const float parent_area = bounds.half_area();
  const float cost = opt_.traversal_cost + (parent_area > 0 ? best_cost / parent_area : 0.0f);
  if (best_axis < 0) return false;
  if (!(cost < to_beat)) return false;

  // Partition, with reference unsplitting (Stich et al. section 4.4): a triangle the plane
  // cuts goes whole to one side when that costs less than referencing it on both.
  const int a = best_axis;
  const float plane = lo[a] + float(best_plane) * step[a];
  Aabb lbox, rbox;
  uint32_t nl = 0, nr = 0;
  for (int b = 0; b < B; ++b) {
    const Aabb c = BoxAcc{sb->lo[a][b], sb->hi[a][b]}.aabb();
    if (b < best_plane) {
      if (!c.empty()) lbox.grow(c);
      nl += sb->entry[a][b];
    } else {
      if (!c.empty()) rbox.grow(c);
      nr += sb->exit[a][b];
    }
  }
  std::vector<PrimRef> left, right;
  left.reserve(nl);
  right.reserve(nr);
  for (uint32_t i = begin; i < end; ++i) {
    const PrimRef& r = refs_[i];
    int f, l;
    span(r, a, lo[a], scale[a], f, l);
    if (l < best_plane) {
      left.push_back(r);
    } else if (f >= best_plane) {
      right.push_back(r);
    } else {
      const Aabb whole{r.lo, r.hi};
      Aabb l1 = lbox, r1 = rbox;
      l1.grow(whole);
      r1.grow(whole);
      const float c_split = lbox.half_area() * tests(nl) + rbox.half_area() * tests(nr);
      const float c_left = l1.half_area() * tests(nl) + rbox.half_area() * tests(nr - 1);
      const float c_right = lbox.half_area() * tests(nl - 1) + r1.half_area() * tests(nr);
      if (c_left < c_split && c_left <= c_right) {
        left.push_back(r);
        lbox = l1;
        --nr;
      } else if (c_right < c_split) {
        right.push_back(r);
        rbox = r1;
        --nl;
      } else {
        const TriangleVerts& t = tris_[r.id];
        const Aabb cl = clip_triangle(t, a, -kInf, plane, whole), cr = clip_triangle(t, a, plane, kInf, whole);
        PrimRef x = r;
        if (!cl.empty()) {
          x.lo = cl.lo;
          x.hi = cl.hi;
          left.push_back(x);
        }
        if (!cr.empty()) {
          x.lo = cr.lo;
          x.hi = cr.hi;
          right.push_back(x);
        }
        if (cl.empty() && cr.empty()) left.push_back(r);  // cannot happen for a finite triangle; kept whole
      }
    }
  }
  if (left.empty() || right.empty() || left.size() + right.size() > room) return false;
  const uint32_t ln = uint32_t(left.size()), rn = uint32_t(right.size());
  const uint32_t spare = room - ln - rn;
  const uint32_t sl = uint32_t(uint64_t(spare) * ln / (uint64_t(ln) + rn));
  std::copy(left.begin(), left.end(), &refs_[begin]);
  std::copy(right.begin(), right.end(), &refs_[begin + ln + sl]);
  sp.lbegin = begin;
  sp.lend = begin + ln;
  sp.lcap = sp.rbegin = begin + ln + sl;
  sp.rend = sp.rbegin + rn;
  sp.rcap = cap_end;
  sp.placed = true;
  sp.mid = sp.lend;
  sp.lt = ln;  // spatial splits are never clustered: weights of 1
  sp.rt = rn;
  range_bounds(sp.lbegin, sp.lend, sp.lb, sp.lcb);
  range_bounds(sp.rbegin, sp.rend, sp.rb, sp.rcb);
  spatial_splits_.fetch_add(1, std::memory_order_relaxed);
  return true;
}

}  // namespace bvh_detail
}  // namespace pl
