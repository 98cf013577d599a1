// meshflow medial — adaptive boundary sampling over a BoundaryModel and the multi-pass driver
// (sampling → core → feature-size refinement → sampling ...). Plain C++: no CGAL, no OCCT.
#include "stages/medial/medial.hpp"

#include "engine/stage.hpp"

#include <nlohmann/json.hpp>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <string>

namespace meshflow::medial {
namespace {

double now() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}
double dist(const Vec3& a, const Vec3& b) {
  return std::sqrt((a[0] - b[0]) * (a[0] - b[0]) + (a[1] - b[1]) * (a[1] - b[1]) + (a[2] - b[2]) * (a[2] - b[2]));
}
std::uint64_t mix(std::uint64_t x) {  // splitmix64
  x += 0x9e3779b97f4a7c15ULL;
  x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ULL;
  x = (x ^ (x >> 27)) * 0x94d049bb133111ebULL;
  return x ^ (x >> 31);
}
// Deterministic jitter in [-a, a] from a key.
double jitter(std::uint64_t key, double a) {
  return a * (2.0 * static_cast<double>(mix(key) >> 11) / static_cast<double>(1ULL << 53) - 1.0);
}

struct BoxAcc {
  Vec3 lo{1e300, 1e300, 1e300}, hi{-1e300, -1e300, -1e300};
  void add(const Vec3& p) {
    for (int k = 0; k < 3; ++k) lo[k] = std::min(lo[k], p[k]), hi[k] = std::max(hi[k], p[k]);
  }
  bool empty() const { return lo[0] > hi[0]; }
  double diag() const { return empty() ? 0 : dist(lo, hi); }
};

struct Field {
  double h_ref = 0, h_far = 0, h_min = 0, turn = 0, grading = 0;
  const NearestIndex* idx = nullptr;
  const std::vector<double>* src_h = nullptr;
  double operator()(bool refined, const Vec3& p, double kappa) const {
    double h = refined ? h_ref : h_far;
    if (kappa > 0) h = std::min(h, turn / kappa);
    if (idx)
      for (auto& [j, d] : idx->nearest(p, 4)) h = std::min(h, (*src_h)[j] + grading * d);
    return std::max(h, h_min);
  }
};

std::array<std::int32_t, 3> face_set(std::vector<int> f) {
  std::sort(f.begin(), f.end());
  f.erase(std::unique(f.begin(), f.end()), f.end());
  std::array<std::int32_t, 3> a{-1, -1, -1};
  for (std::size_t k = 0; k < f.size() && k < 3; ++k) a[k] = f[k];
  return a;
}

[[noreturn]] void too_many_samples(const Params& prm) {
  throw StageError("medial: more than max_samples = " + std::to_string(prm.max_samples) +
                   " boundary samples would be needed; increase `spacing`/`min_spacing` or `max_samples`");
}

void append(std::vector<Sample>& out, const std::vector<Sample>& more) { out.insert(out.end(), more.begin(), more.end()); }

// A cell of a face's kd-split in (u,v), with its corner points when its parent evaluated them
// (corner[i][j] at (u_i, v_j): the same parameters, so the same points).
struct Cell {
  int f;
  double u0, u1, v0, v1;
  std::uint64_t key;
  int depth;
  bool has_corners = false;
  Vec3 corner[2][2]{};
};

// The sampling of faces, edges and vertices. Its const methods may run concurrently (they need a
// model whose const queries may): the parallel loops below give every face subtree, edge and
// vertex its own output vector and concatenate them in the serial order (faces by id, each in
// depth-first order of its cells, then edges, then vertices), whatever the thread count.
class Sampler {
 public:
  Sampler(const BoundaryModel& m, const Params& prm, const Field& fld) : m_(m), prm_(prm), f_(fld) {}

  std::vector<Sample> faces(const std::vector<int>& ids) const {
    std::vector<Item> items;
    for (int f : ids) {
      auto [u0, u1, v0, v1] = m_.face_bounds(f);
      if (!(u1 > u0) || !(v1 > v0)) continue;
      items.push_back({Cell{f, u0, u1, v0, v1, mix(0x5eedULL + static_cast<std::uint64_t>(f)), 0}, true, {}});
    }
    // The top of the trees level by level (in parallel), until there are enough open subtrees to
    // share out; then each open subtree depth first on its own.
    for (int round = 0; round < 8 && open_count(items) > 0 && open_count(items) < 256; ++round) items = expand(items);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, items.size(), 1), [&](const tbb::blocked_range<std::size_t>& r) {
      for (std::size_t i = r.begin(); i != r.end(); ++i)
        if (items[i].open) subtree(items[i].c, items[i].out);
    });
    std::vector<Sample> out;
    for (auto& it : items) append(out, it.out);
    return out;
  }

  std::vector<Sample> edges(const std::vector<int>& ids) const {
    return per_id(ids, 1, [this](int e, std::vector<Sample>& o) { edge(e, o); });
  }
  std::vector<Sample> vertices(const std::vector<int>& ids) const {
    return per_id(ids, 16, [this](int v, std::vector<Sample>& o) { vertex(v, o); });
  }

 private:
  // sample(id, out) for every id in parallel, each into its own vector, joined in the order of ids
  template <class SampleOne>
  static std::vector<Sample> per_id(const std::vector<int>& ids, std::size_t grain, SampleOne sample) {
    std::vector<std::vector<Sample>> per(ids.size());
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, ids.size(), grain), [&](const tbb::blocked_range<std::size_t>& r) {
      for (std::size_t i = r.begin(); i != r.end(); ++i) sample(ids[i], per[i]);
    });
    std::vector<Sample> out;
    for (auto& p : per) append(out, p);
    return out;
  }
  // A cell still to visit (open) or the samples that took its place.
  struct Item {
    Cell c;
    bool open;
    std::vector<Sample> out;
  };
  static std::size_t open_count(const std::vector<Item>& items) {
    return std::count_if(items.begin(), items.end(), [](const Item& it) { return it.open; });
  }
  // Visits every open cell (in parallel); each is replaced, in place, by its children or its sample.
  std::vector<Item> expand(std::vector<Item>& items) const {
    std::vector<std::vector<Cell>> kids(items.size());
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, items.size(), 1), [&](const tbb::blocked_range<std::size_t>& r) {
      for (std::size_t i = r.begin(); i != r.end(); ++i)
        if (items[i].open) visit(items[i].c, kids[i], items[i].out);
    });
    std::vector<Item> next;
    for (std::size_t i = 0; i < items.size(); ++i) {
      if (!items[i].open || !items[i].out.empty()) next.push_back({items[i].c, false, std::move(items[i].out)});
      for (const Cell& k : kids[i]) next.push_back({k, true, {}});
    }
    return next;
  }
  // A cell and everything below it, depth first (children in the order visit gives them).
  void subtree(const Cell& root, std::vector<Sample>& out) const {
    std::vector<Cell> stack{root}, kids;
    while (!stack.empty()) {
      Cell c = stack.back();
      stack.pop_back();
      kids.clear();
      visit(c, kids, out);
      stack.insert(stack.end(), kids.rbegin(), kids.rend());
    }
  }
  // One cell: split it (its children into `kids`, in sampling order) while its 3D extent along u
  // or v exceeds the spacing there, else one sample near its centre if inside the trimmed face.
  void visit(const Cell& c, std::vector<Cell>& kids, std::vector<Sample>& out) const {
    const int f = c.f;
    const bool refined = m_.face_refined(f);
    double us[3] = {c.u0, 0.5 * (c.u0 + c.u1), c.u1}, vs[3] = {c.v0, 0.5 * (c.v0 + c.v1), c.v1};
    Vec3 P[3][3];
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j)
        P[i][j] = c.has_corners && i != 1 && j != 1 ? c.corner[i / 2][j / 2] : m_.face_point(f, us[i], vs[j]);
    double eu = 0, ev = 0;
    for (int k = 0; k < 3; ++k) {
      eu = std::max(eu, dist(P[0][k], P[1][k]) + dist(P[1][k], P[2][k]));
      ev = std::max(ev, dist(P[k][0], P[k][1]) + dist(P[k][1], P[k][2]));
    }
    double h = f_(refined, P[1][1], m_.face_curvature(f, us[1], vs[1]));
    bool su = c.depth < 2 || (eu > h && c.depth < 64), sv = c.depth < 2 || (ev > h && c.depth < 64);
    if (su || sv) {
      int nu = su ? 2 : 1, nv = sv ? 2 : 1;
      for (int a = 0; a < nu; ++a)
        for (int b = 0; b < nv; ++b) {
          const int i0 = su ? a : 0, i1 = su ? a + 1 : 2, j0 = sv ? b : 0, j1 = sv ? b + 1 : 2;  // in the 3x3 grid
          Cell k{f, us[i0], us[i1], vs[j0], vs[j1], mix(c.key * 5 + static_cast<std::uint64_t>(a * 2 + b + 1)), c.depth + 1};
          k.has_corners = true;
          k.corner[0][0] = P[i0][j0], k.corner[0][1] = P[i0][j1], k.corner[1][0] = P[i1][j0], k.corner[1][1] = P[i1][j1];
          kids.push_back(k);
        }
      return;
    }
    double u = us[1] + jitter(c.key, 0.2) * (c.u1 - c.u0), v = vs[1] + jitter(c.key ^ 0xabcdefULL, 0.2) * (c.v1 - c.v0);
    if (!m_.face_contains(f, u, v)) return;
    Vec3 n = m_.face_normal(f, u, v);
    if (n[0] * n[0] + n[1] * n[1] + n[2] * n[2] < 0.25) return;  // singular point
    Sample s;
    s.p = m_.face_point(f, u, v);
    s.n = n;
    s.u = u;
    s.v = v;
    s.h = std::max(eu, ev);
    s.kind = 0;
    s.id = f;
    s.faces = {f, -1, -1};
    s.refined = refined;
    push(out, s);
  }

  void edge(int e, std::vector<Sample>& out) const {
    if (m_.edge_degenerate(e)) return;
    auto fs = m_.edge_faces(e);
    bool refined = false;
    for (int f : fs) refined |= m_.face_refined(f);
    auto set = face_set(fs);
    auto [t0, t1] = m_.edge_range(e);
    if (!(t1 > t0)) return;
    struct Iv {
      double a, b;
      std::uint64_t key;
      int depth;
    };
    std::vector<Iv> stack{{t0, t1, mix(0xed9eULL + static_cast<std::uint64_t>(e)), 0}};
    const double cos_turn = std::cos(f_.turn);
    while (!stack.empty()) {
      Iv iv = stack.back();
      stack.pop_back();
      double tm = 0.5 * (iv.a + iv.b);
      Vec3 pa = m_.edge_point(e, iv.a), pm = m_.edge_point(e, tm), pb = m_.edge_point(e, iv.b);
      double len = dist(pa, pm) + dist(pm, pb);
      double h = f_(refined, pm, 0);
      Vec3 d1{pm[0] - pa[0], pm[1] - pa[1], pm[2] - pa[2]}, d2{pb[0] - pm[0], pb[1] - pm[1], pb[2] - pm[2]};
      double l1 = dist(pa, pm), l2 = dist(pm, pb);
      bool bends = l1 > 0 && l2 > 0 && (d1[0] * d2[0] + d1[1] * d2[1] + d1[2] * d2[2]) < cos_turn * l1 * l2 && len > f_.h_min;
      if (iv.depth < 2 || ((len > h || bends) && iv.depth < 60)) {
        stack.push_back({tm, iv.b, mix(iv.key * 3 + 2), iv.depth + 1});
        stack.push_back({iv.a, tm, mix(iv.key * 3 + 1), iv.depth + 1});
        continue;
      }
      double t = tm + jitter(iv.key, 0.2) * (iv.b - iv.a);
      Sample s;
      s.p = m_.edge_point(e, t);
      s.n = m_.edge_normal(e, t);
      if (s.n[0] * s.n[0] + s.n[1] * s.n[1] + s.n[2] * s.n[2] < 0.25) s.n = {0, 0, 0};
      s.u = t;
      s.h = len;
      s.kind = 1;
      s.id = e;
      s.faces = set;
      s.refined = refined;
      push(out, s);
    }
  }

  void vertex(int v, std::vector<Sample>& out) const {
    auto fs = m_.vertex_faces(v);
    if (fs.empty()) return;
    Sample s;
    s.p = m_.vertex_point(v);
    s.n = m_.vertex_normal(v);
    if (s.n[0] * s.n[0] + s.n[1] * s.n[1] + s.n[2] * s.n[2] < 0.25) s.n = {0, 0, 0};
    s.kind = 2;
    s.id = v;
    s.faces = face_set(fs);
    for (int f : fs) s.refined |= m_.face_refined(f);
    s.h = f_(s.refined, s.p, 0);
    push(out, s);
  }

  void push(std::vector<Sample>& out, const Sample& s) const {
    if (static_cast<long>(out.size()) >= prm_.max_samples) too_many_samples(prm_);
    out.push_back(s);
  }
  const BoundaryModel& m_;
  const Params& prm_;
  const Field& f_;
};

struct Scales {
  double ref_diag = 0, all_diag = 0;
  std::vector<char> edge_refined, vertex_refined;
};

Scales scales(const BoundaryModel& m) {
  BoxAcc all, ref;
  Scales sc;
  bool any_ref = false;
  for (int f = 0; f < m.num_faces(); ++f) {
    auto [u0, u1, v0, v1] = m.face_bounds(f);
    bool r = m.face_refined(f);
    any_ref |= r;
    for (int i = 0; i <= 8; ++i)
      for (int j = 0; j <= 8; ++j) {
        double u = u0 + (u1 - u0) * i / 8.0, v = v0 + (v1 - v0) * j / 8.0;
        if (!m.face_contains(f, u, v)) continue;
        Vec3 p = m.face_point(f, u, v);
        all.add(p);
        if (r) ref.add(p);
      }
  }
  sc.edge_refined.assign(m.num_edges(), 0);
  for (int e = 0; e < m.num_edges(); ++e) {
    if (m.edge_degenerate(e)) continue;
    bool r = false;
    for (int f : m.edge_faces(e)) r |= m.face_refined(f);
    sc.edge_refined[e] = r;
    auto [t0, t1] = m.edge_range(e);
    for (int i = 0; i <= 16; ++i) {
      Vec3 p = m.edge_point(e, t0 + (t1 - t0) * i / 16.0);
      all.add(p);
      if (r) ref.add(p);
    }
  }
  sc.vertex_refined.assign(m.num_vertices(), 0);
  for (int v = 0; v < m.num_vertices(); ++v) {
    bool r = false;
    for (int f : m.vertex_faces(v)) r |= m.face_refined(f);
    sc.vertex_refined[v] = r;
    all.add(m.vertex_point(v));
    if (r) ref.add(m.vertex_point(v));
  }
  if (all.empty() || !(all.diag() > 0)) throw StageError("medial: the boundary is empty or has zero size");
  sc.all_diag = all.diag();
  sc.ref_diag = any_ref && ref.diag() > 0 ? ref.diag() : sc.all_diag;
  return sc;
}

Field base_field(const Params& prm, const Scales& sc) {
  Field f;
  f.h_ref = prm.spacing * sc.ref_diag;
  f.h_far = std::max(f.h_ref, prm.farfield_spacing * sc.all_diag);
  f.h_min = std::min(prm.min_spacing * sc.ref_diag, f.h_ref);
  f.turn = prm.max_turn_deg * M_PI / 180.0;
  f.grading = prm.grading;
  return f;
}

// Samples everything (or only what touches refined faces).
std::vector<Sample> sample_with(const BoundaryModel& m, const Params& prm, const Field& fld, const Scales& sc,
                                bool refined_only) {
  std::vector<int> fs, es, vs;
  for (int f = 0; f < m.num_faces(); ++f)
    if (!refined_only || m.face_refined(f)) fs.push_back(f);
  for (int e = 0; e < m.num_edges(); ++e)
    if (!refined_only || sc.edge_refined[e]) es.push_back(e);
  for (int v = 0; v < m.num_vertices(); ++v)
    if (!refined_only || sc.vertex_refined[v]) vs.push_back(v);
  Sampler s(m, prm, fld);
  std::vector<Sample> out = s.faces(fs);
  append(out, s.edges(es));
  append(out, s.vertices(vs));
  if (static_cast<long>(out.size()) > prm.max_samples) too_many_samples(prm);
  return out;
}

}  // namespace

Params Params::from_json(const nlohmann::json& j) {
  Params p;
  p.spacing = j.value("spacing", p.spacing);
  p.farfield_spacing = j.value("farfield_spacing", p.farfield_spacing);
  p.min_spacing = j.value("min_spacing", p.min_spacing);
  p.max_turn_deg = j.value("max_turn_deg", p.max_turn_deg);
  p.lfs_fraction = j.value("lfs_fraction", p.lfs_fraction);
  p.grading = j.value("grading", p.grading);
  p.passes = j.value("passes", p.passes);
  p.min_object_angle_deg = j.value("min_object_angle_deg", p.min_object_angle_deg);
  p.max_samples = j.value("max_samples", p.max_samples);
  return p;
}

nlohmann::json Params::to_json() const {
  return {{"spacing", spacing},           {"farfield_spacing", farfield_spacing},
          {"min_spacing", min_spacing},   {"max_turn_deg", max_turn_deg},
          {"lfs_fraction", lfs_fraction}, {"grading", grading},
          {"passes", passes},             {"min_object_angle_deg", min_object_angle_deg},
          {"max_samples", max_samples}};
}

std::vector<Sample> sample_boundary(const BoundaryModel& model, const Params& prm, const std::vector<Vec3>& source_p,
                                    const std::vector<double>& source_h) {
  Scales sc = scales(model);
  Field fld = base_field(prm, sc);
  std::unique_ptr<NearestIndex> idx;
  if (!source_p.empty()) {
    idx = std::make_unique<NearestIndex>(source_p);
    fld.idx = idx.get();
    fld.src_h = &source_h;
  }
  return sample_with(model, prm, fld, sc, false);
}

MedialObject compute(const BoundaryModel& model, const Params& prm, RunReport* report,
                     const std::function<void(double, const std::string&)>& progress) {
  auto say = [&](double f, const std::string& w) {
    if (progress) progress(f, w);
  };
  RunReport rep;
  double t = now();
  Scales sc = scales(model);
  Field base = base_field(prm, sc);
  const int passes = std::max(1, prm.passes);

  // Pass 1: the walls alone, then everything graded away from them.
  say(0.0, "sampling walls");
  std::vector<Sample> S = sample_with(model, prm, base, sc, true);
  std::vector<Vec3> src_p;
  std::vector<double> src_h;
  for (auto& s : S) src_p.push_back(s.p), src_h.push_back(s.h);
  MedialObject M;
  CoreOptions copt{.min_object_angle_deg = prm.min_object_angle_deg};
  CoreTimes ct;
  for (int pass = 1; pass <= passes; ++pass) {
    say(0.9 * (pass - 1) / passes, "sampling, pass " + std::to_string(pass));
    {
      Field fld = base;
      std::unique_ptr<NearestIndex> idx;
      if (!src_p.empty()) {
        idx = std::make_unique<NearestIndex>(src_p);
        fld.idx = idx.get();
        fld.src_h = &src_h;
      }
      double ts = now();
      S = sample_with(model, prm, fld, sc, false);
      rep.t_sampling += now() - ts;
    }
    rep.samples_per_pass.push_back(static_cast<long>(S.size()));
    say(0.9 * (pass - 0.5) / passes, "medial, pass " + std::to_string(pass) + " (" + std::to_string(S.size()) + " samples)");
    M = medial_from_samples(S, copt, &ct);
    if (pass == passes) break;
    // Feature-size refinement near the walls.
    std::vector<Vec3> rel;
    for (auto& p : M.points) {
      bool touches = false;
      for (auto q : p.contacts) touches |= M.samples[q].refined;
      if (touches) rel.push_back(p.c);
    }
    std::unique_ptr<NearestIndex> idx;
    if (!rel.empty()) idx = std::make_unique<NearestIndex>(rel);
    const std::size_t ns = M.samples.size();
    src_p.resize(ns);
    src_h.resize(ns);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, ns, 256), [&](const tbb::blocked_range<std::size_t>& r) {
      for (std::size_t i = r.begin(); i != r.end(); ++i) {
        const Sample& s = M.samples[i];
        double target = s.h;
        if (idx) target = std::min(target, std::max(base.h_min, prm.lfs_fraction * idx->nearest(s.p, 1)[0].second));
        src_p[i] = s.p;
        src_h[i] = target;
      }
    });
  }
  rep.t_delaunay = ct.delaunay;
  rep.t_poles = ct.poles;
  rep.t_lfs = ct.lfs;
  nlohmann::json h;
  h["params"] = prm.to_json();
  h["counts"] = {{"samples", M.samples.size()}, {"medial_points", M.points.size()}, {"halos", M.halos.size()}};
  h["faces"] = model.num_faces();
  std::vector<int> rf;
  for (int f = 0; f < model.num_faces(); ++f)
    if (model.face_refined(f)) rf.push_back(f);
  h["refined_faces"] = rf;
  h["scales"] = {{"refined_diagonal", sc.ref_diag}, {"diagonal", sc.all_diag}};
  M.header = h.dump();
  (void)t;
  if (report) *report = rep;
  say(0.95, "medial done");
  return M;
}

}  // namespace meshflow::medial
