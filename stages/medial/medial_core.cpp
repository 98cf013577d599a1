// meshflow medial — the CGAL part: Delaunay of the samples, poles, filter, LFS, halos, and the
// kd-tree behind NearestIndex. The only translation unit of the project that includes CGAL
// for the medial stage (no OpenCASCADE here). Method: see medial.hpp.
#include "stages/medial/medial.hpp"

#include "engine/stage.hpp"

#include <CGAL/Delaunay_triangulation_3.h>
#include <CGAL/Delaunay_triangulation_cell_base_3.h>
#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#include <CGAL/Orthogonal_k_neighbor_search.h>
#include <CGAL/Search_traits_3.h>
#include <CGAL/Search_traits_adapter.h>
#include <CGAL/Triangulation_cell_base_with_info_3.h>
#include <CGAL/Triangulation_vertex_base_with_info_3.h>
#include <CGAL/property_map.h>
#include <boost/iterator/counting_iterator.hpp>
#include <tbb/parallel_for.h>
#include <tbb/parallel_sort.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <numeric>
#include <string>

namespace meshflow::medial {
namespace {

using K = CGAL::Exact_predicates_inexact_constructions_kernel;
using Vb = CGAL::Triangulation_vertex_base_with_info_3<std::int32_t, K>;
using Cb = CGAL::Triangulation_cell_base_with_info_3<std::int32_t, K, CGAL::Delaunay_triangulation_cell_base_3<K>>;
using Tds = CGAL::Triangulation_data_structure_3<Vb, Cb>;
using DT = CGAL::Delaunay_triangulation_3<K, Tds>;

double now() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}
Vec3 sub(const Vec3& a, const Vec3& b) { return {a[0] - b[0], a[1] - b[1], a[2] - b[2]}; }
double dot(const Vec3& a, const Vec3& b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }
Vec3 cross(const Vec3& a, const Vec3& b) {
  return {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
}
double norm(const Vec3& a) { return std::sqrt(dot(a, a)); }

struct CellRec {
  std::array<std::int32_t, 4> ids{};  // sample ids, ascending
  Vec3 c{};
  double r = 0;
  bool valid = false;
};

// Circumcentre from the vertices in ascending id order (independent of CGAL's vertex order).
void circumcentre(const std::vector<Sample>& S, CellRec& rec) {
  const Vec3& a = S[rec.ids[0]].p;
  Vec3 b = sub(S[rec.ids[1]].p, a), c = sub(S[rec.ids[2]].p, a), d = sub(S[rec.ids[3]].p, a);
  Vec3 cd = cross(c, d), db = cross(d, b), bc = cross(b, c);
  double det = dot(b, cd);
  double L = std::max({norm(b), norm(c), norm(d), norm(sub(c, b)), norm(sub(d, b)), norm(sub(d, c))});
  if (!(std::abs(det) > 1e-12 * L * L * L)) return;  // flat: the centre is undefined
  double bb = dot(b, b), cc = dot(c, c), dd = dot(d, d);
  Vec3 x{(bb * cd[0] + cc * db[0] + dd * bc[0]) / (2 * det), (bb * cd[1] + cc * db[1] + dd * bc[1]) / (2 * det),
         (bb * cd[2] + cc * db[2] + dd * bc[2]) / (2 * det)};
  double r = norm(x);
  // consistency: the centre must be equidistant from the four vertices
  for (const Vec3* q : {&b, &c, &d})
    if (!(std::abs(norm(sub(x, *q)) - r) <= 1e-7 * std::max(r, L))) return;
  rec.c = {a[0] + x[0], a[1] + x[1], a[2] + x[2]};
  rec.r = r;
  rec.valid = std::isfinite(r);
}

bool share_face(const Sample& a, const Sample& b) {
  for (int fa : a.faces)
    for (int fb : b.faces)
      if (fa >= 0 && fa == fb) return true;
  return false;
}

double angle_deg(const Vec3& a, const Vec3& b) {
  double na = norm(a), nb = norm(b);
  if (na == 0 || nb == 0) return 0;
  double c = std::clamp(dot(a, b) / (na * nb), -1.0, 1.0);
  return std::acos(c) * 180.0 / M_PI;
}

}  // namespace

// ── NearestIndex ──────────────────────────────────────────────────────────────────────────
namespace {
using Pmap = CGAL::Pointer_property_map<K::Point_3>::type;
using KTraits = CGAL::Search_traits_adapter<std::size_t, Pmap, CGAL::Search_traits_3<K>>;
using KSearch = CGAL::Orthogonal_k_neighbor_search<KTraits>;
}  // namespace

struct NearestIndex::Impl {
  std::vector<K::Point_3> pts;
  std::unique_ptr<KSearch::Tree> tree;
};

NearestIndex::NearestIndex(const std::vector<Vec3>& points) : impl_(std::make_unique<Impl>()) {
  impl_->pts.reserve(points.size());
  for (auto& p : points) impl_->pts.emplace_back(p[0], p[1], p[2]);
  Pmap pm = CGAL::make_property_map(impl_->pts);
  impl_->tree = std::make_unique<KSearch::Tree>(boost::counting_iterator<std::size_t>(0),
                                                boost::counting_iterator<std::size_t>(points.size()),
                                                KSearch::Tree::Splitter(), KTraits(pm));
  impl_->tree->build();  // built once here: const queries may then run concurrently
}
NearestIndex::~NearestIndex() = default;
NearestIndex::NearestIndex(NearestIndex&&) noexcept = default;
NearestIndex& NearestIndex::operator=(NearestIndex&&) noexcept = default;
std::size_t NearestIndex::size() const { return impl_->pts.size(); }

std::vector<std::pair<std::int32_t, double>> NearestIndex::nearest(const Vec3& q, int k) const {
  std::vector<std::pair<std::int32_t, double>> out;
  if (impl_->pts.empty() || k <= 0) return out;
  Pmap pm = CGAL::make_property_map(impl_->pts);
  KSearch search(*impl_->tree, K::Point_3(q[0], q[1], q[2]), static_cast<unsigned>(k), 0, true,
                 KSearch::Distance(pm));
  for (auto it = search.begin(); it != search.end(); ++it)
    out.emplace_back(static_cast<std::int32_t>(it->first), std::sqrt(it->second));
  std::sort(out.begin(), out.end(), [](auto& a, auto& b) { return a.second != b.second ? a.second < b.second : a.first < b.first; });
  return out;
}

// ── the core ──────────────────────────────────────────────────────────────────────────────
// Every parallel loop below runs in the caller's task arena and writes per-index slots; what is
// reduced is reduced serially in index order or by a total order (ties by sample ids), so the
// result does not depend on the thread count nor on CGAL's cell and vertex order.
namespace {

// Distinct points (a vertex sampled twice is inserted once): rep[i] is the first sample at S[i].p.
std::vector<std::pair<K::Point_3, std::int32_t>> distinct_points(const std::vector<Sample>& S, std::vector<std::int32_t>& rep) {
  const std::int32_t n = static_cast<std::int32_t>(S.size());
  std::vector<std::int32_t> order(n);
  rep.assign(n, -1);
  std::iota(order.begin(), order.end(), 0);
  // a total order (ties by index): the parallel sort gives the one sorted sequence
  tbb::parallel_sort(order.begin(), order.end(), [&](std::int32_t a, std::int32_t b) { return S[a].p != S[b].p ? S[a].p < S[b].p : a < b; });
  std::vector<std::pair<K::Point_3, std::int32_t>> pts;
  for (std::size_t k = 0; k < order.size(); ++k) {
    std::int32_t i = order[k];
    for (double x : S[i].p)
      if (!std::isfinite(x)) throw StageError("medial: a boundary sample has a non-finite coordinate (sample " + std::to_string(i) + "); check the input shape");
    if (k > 0 && S[order[k - 1]].p == S[i].p) {
      rep[i] = rep[order[k - 1]];
      continue;
    }
    rep[i] = i;
    pts.emplace_back(K::Point_3(S[i].p[0], S[i].p[1], S[i].p[2]), i);
  }
  if (pts.size() < 8)
    throw StageError("medial: only " + std::to_string(pts.size()) + " distinct boundary samples; at least 8 are needed (decrease `spacing`)");
  return pts;
}

// The finite cells (sorted vertex ids, circumcentres: in parallel, each cell its own slot); each
// cell's info is its index here, -1 for infinite cells.
std::vector<CellRec> cell_records(DT& dt, const std::vector<Sample>& S) {
  std::vector<DT::Cell_handle> finite;
  finite.reserve(dt.number_of_finite_cells());
  for (auto ch : dt.all_cell_handles()) {
    ch->info() = -1;
    if (!dt.is_infinite(ch)) finite.push_back(ch);
  }
  std::vector<CellRec> cells(finite.size());
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, cells.size(), 1024), [&](const tbb::blocked_range<std::size_t>& r) {
    for (std::size_t c = r.begin(); c != r.end(); ++c) {
      CellRec& rec = cells[c];
      for (int j = 0; j < 4; ++j) rec.ids[j] = finite[c]->vertex(j)->info();
      std::sort(rec.ids.begin(), rec.ids.end());
      finite[c]->info() = static_cast<std::int32_t>(c);
      circumcentre(S, rec);
    }
  });
  return cells;
}

// Poles: per sample the farthest Voronoi vertex of its cell on each side (ties by ids: a total
// order, so the cells may come in any order). One pass over the cells, each telling its vertices.
void find_poles(const DT& dt, const std::vector<CellRec>& cells, const std::vector<Sample>& S, const std::vector<std::int32_t>& rep,
                std::vector<std::int32_t>& pole_in, std::vector<std::int32_t>& pole_out) {
  const std::size_t n = S.size();
  pole_in.assign(n, -1);
  pole_out.assign(n, -1);
  std::vector<char> hull(n, 0);
  auto better = [&](std::int32_t a, std::int32_t b) {  // a farther than b (ties by ids)
    if (b < 0) return true;
    return cells[a].r != cells[b].r ? cells[a].r > cells[b].r : cells[a].ids < cells[b].ids;
  };
  for (auto ch : dt.all_cell_handles()) {
    const std::int32_t ci = ch->info();
    for (int j = 0; j < 4; ++j) {
      auto v = ch->vertex(j);
      if (dt.is_infinite(v)) continue;
      const std::int32_t i = v->info();
      const Vec3& nrm = S[i].n;
      if (rep[i] != i || dot(nrm, nrm) < 0.25) continue;  // no normal (a singular point): no poles
      if (ci < 0) {
        hull[i] = 1;
        continue;
      }
      if (!cells[ci].valid) continue;
      double s = dot(sub(cells[ci].c, S[i].p), nrm);
      if (s < 0 && better(ci, pole_in[i])) pole_in[i] = ci;
      if (s > 0 && better(ci, pole_out[i])) pole_out[i] = ci;
    }
  }
  for (std::size_t i = 0; i < n; ++i)
    if (hull[i]) pole_out[i] = -1;  // unbounded cell: the body-side pole is at infinity
}

struct Cand {
  int side;
  std::int32_t cell;
};
// Candidate medial balls: (side, cell) of every pole, sorted by (side, contacts), once each.
std::vector<Cand> candidates(const std::vector<CellRec>& cells, const std::vector<std::int32_t>& pole_in,
                             const std::vector<std::int32_t>& pole_out) {
  std::vector<Cand> cand;
  for (std::size_t i = 0; i < pole_in.size(); ++i) {
    if (pole_in[i] >= 0) cand.push_back({0, pole_in[i]});
    if (pole_out[i] >= 0) cand.push_back({1, pole_out[i]});
  }
  // distinct cells have distinct ids: candidates that compare equal are equal, any sort gives one sequence
  tbb::parallel_sort(cand.begin(), cand.end(), [&](const Cand& a, const Cand& b) {
    return a.side != b.side ? a.side < b.side : cells[a.cell].ids < cells[b.cell].ids;
  });
  cand.erase(std::unique(cand.begin(), cand.end(), [](const Cand& a, const Cand& b) { return a.side == b.side && a.cell == b.cell; }),
             cand.end());
  return cand;
}

// One candidate through the filter (method, step 4): the medial point, or nothing.
struct Judged {
  bool kept = false, halo = false;
  MedialPoint mp;
  Halo h;
};
Judged judge(const Cand& cd, const CellRec& cr, const std::vector<Sample>& S, const CoreOptions& opt) {
  Judged out;
  const double sigma = cd.side == 0 ? -1.0 : 1.0, R = cr.r;
  for (std::int32_t q : cr.ids) {
    const Sample& s = S[q];
    if (s.kind == 0 && sigma * dot(sub(cr.c, s.p), s.n) < -0.05 * R) return out;
  }
  double amax = 0;
  for (int a = 0; a < 4; ++a)
    for (int b = a + 1; b < 4; ++b)
      amax = std::max(amax, angle_deg(sub(S[cr.ids[a]].p, cr.c), sub(S[cr.ids[b]].p, cr.c)));
  if (amax < opt.min_object_angle_deg) return out;
  out.kept = true;
  MedialPoint& mp = out.mp;
  mp.c = cr.c;
  mp.ball_radius = R;
  mp.contacts = cr.ids;
  mp.side = cd.side == 0 ? Side::fluid : Side::body;
  mp.object_angle_deg = static_cast<std::uint8_t>(std::lround(amax));
  const double cos_tangent = std::cos(25.0 * M_PI / 180.0);
  double r = R;
  for (std::int32_t q : cr.ids) {
    const Sample& s = S[q];
    if (s.kind != 0 || R <= 0) continue;
    Vec3 w = sub(s.p, cr.c);
    double along = -sigma * dot(w, s.n);  // distance to the tangent plane at the contact
    if (along >= cos_tangent * R) r = std::min(r, along);
  }
  mp.radius = std::max(r, 0.5 * R);
  if (cd.side != 0) return out;
  // halo: two contacts on faces with nothing in common; the pair of largest angle
  double best = -1;
  Halo& h = out.h;
  for (int a = 0; a < 4; ++a)
    for (int b = a + 1; b < 4; ++b) {
      const Sample &sa = S[cr.ids[a]], &sb = S[cr.ids[b]];
      if (sa.faces[0] < 0 || sb.faces[0] < 0 || share_face(sa, sb)) continue;
      double ang = angle_deg(sub(sa.p, cr.c), sub(sb.p, cr.c));
      if (ang > best) {
        best = ang;
        h.sample_a = cr.ids[a];
        h.sample_b = cr.ids[b];
        h.face_a = sa.faces[0];
        h.face_b = sb.faces[0];
      }
    }
  if (best >= 0) {
    out.halo = mp.halo = true;
    if (h.face_a > h.face_b) {
      std::swap(h.face_a, h.face_b);
      std::swap(h.sample_a, h.sample_b);
    }
  }
  return out;
}

// The kept candidates in candidate order (judged in parallel); kept_in/out map a cell to its point.
void keep_medial_points(const std::vector<Cand>& cand, const std::vector<CellRec>& cells, const std::vector<Sample>& S,
                        const CoreOptions& opt, MedialObject& M, std::vector<std::int32_t>& kept_in,
                        std::vector<std::int32_t>& kept_out) {
  std::vector<Judged> judged(cand.size());
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, cand.size(), 512), [&](const tbb::blocked_range<std::size_t>& r) {
    for (std::size_t k = r.begin(); k != r.end(); ++k) judged[k] = judge(cand[k], cells[cand[k].cell], S, opt);
  });
  kept_in.assign(cells.size(), -1);
  kept_out.assign(cells.size(), -1);
  for (std::size_t k = 0; k < cand.size(); ++k) {
    if (!judged[k].kept) continue;
    const std::int32_t idx = static_cast<std::int32_t>(M.points.size());
    if (judged[k].halo) {
      judged[k].h.medial = idx;
      M.halos.push_back(judged[k].h);
    }
    (cand[k].side == 0 ? kept_in : kept_out)[cand[k].cell] = idx;
    M.points.push_back(judged[k].mp);
  }
  std::sort(M.halos.begin(), M.halos.end(), [](const Halo& a, const Halo& b) {
    return std::tie(a.face_a, a.face_b, a.medial) < std::tie(b.face_a, b.face_b, b.medial);
  });
}

// Per-sample results (method, steps 5-6), in parallel: each sample writes its own slot.
void sample_info(const std::vector<Sample>& S, const std::vector<std::int32_t>& rep, const std::vector<std::int32_t>& pole_in,
                 const std::vector<std::int32_t>& pole_out, const std::vector<std::int32_t>& kept_in,
                 const std::vector<std::int32_t>& kept_out, MedialObject& M) {
  M.info.assign(S.size(), SampleInfo{});
  std::vector<Vec3> centres;
  centres.reserve(M.points.size());
  for (auto& p : M.points) centres.push_back(p.c);
  const NearestIndex idx(centres);  // built by its constructor: concurrent queries are safe
  auto one = [&](std::size_t i) {
    std::int32_t r = rep[i];
    SampleInfo& si = M.info[i];
    if (pole_in[r] >= 0 && kept_in[pole_in[r]] >= 0) {
      si.pole_in = kept_in[pole_in[r]];
      const MedialPoint& mp = M.points[si.pole_in];
      si.r_in = mp.radius;
      if (mp.halo) {
        double best = -1;
        for (std::int32_t q : mp.contacts) {
          if (S[q].faces[0] < 0 || share_face(S[q], S[i])) continue;
          double ang = angle_deg(sub(S[q].p, mp.c), sub(S[i].p, mp.c));
          if (ang > best) {
            best = ang;
            si.halo_face = S[q].faces[0];
          }
        }
      }
    }
    if (pole_out[r] >= 0 && kept_out[pole_out[r]] >= 0) {
      si.pole_out = kept_out[pole_out[r]];
      si.r_out = M.points[si.pole_out].radius;
    }
    if (idx.size()) si.lfs = idx.nearest(S[i].p, 1)[0].second;
  };
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, S.size(), 256), [&](const tbb::blocked_range<std::size_t>& r) {
    for (std::size_t i = r.begin(); i != r.end(); ++i) one(i);
  });
}

}  // namespace

MedialObject medial_from_samples(std::vector<Sample> S, const CoreOptions& opt, CoreTimes* times) {
  double t0 = now();
  std::vector<std::int32_t> rep;
  auto pts = distinct_points(S, rep);
  DT dt;
  dt.insert(pts.begin(), pts.end());
  if (dt.dimension() < 3)
    throw StageError("medial: the boundary samples are coplanar (the solid is flat or empty); a medial object needs a 3D solid");
  std::vector<CellRec> cells = cell_records(dt, S);
  double t1 = now();
  std::vector<std::int32_t> pole_in, pole_out;  // cell indices
  find_poles(dt, cells, S, rep, pole_in, pole_out);
  dt.clear();
  MedialObject M;
  std::vector<std::int32_t> kept_in, kept_out;
  keep_medial_points(candidates(cells, pole_in, pole_out), cells, S, opt, M, kept_in, kept_out);
  double t2 = now();
  sample_info(S, rep, pole_in, pole_out, kept_in, kept_out, M);
  M.samples = std::move(S);
  double t3 = now();
  if (times) {
    times->delaunay += t1 - t0;
    times->poles += t2 - t1;
    times->lfs += t3 - t2;
  }
  return M;
}

}  // namespace meshflow::medial
