// meshflow stage kind `medial` (paper §III.B): samples the healed fluid solid through the CAD
// interface, computes the medial object (medial.hpp), refines the radii by projecting the
// medial points on their contact faces, writes the "medial" artifact. No CGAL and no
// OpenCASCADE header here: the CAD is reached through stages/cad/cad.hpp only.
#include "engine/stage.hpp"
#include "stages/cad/cad.hpp"
#include "stages/cad/shape_clones.hpp"
#include "stages/medial/medial.hpp"

#include <CGAL/version_macros.h>  // version string only (no CGAL code)
#include <nlohmann/json.hpp>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <set>

namespace meshflow::medial {
namespace {

Vec3 v3(const cad::Vec3& v) { return {v.x, v.y, v.z}; }

Vec3 unit(Vec3 a) {
  double l = std::sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]);
  if (!(l > 1e-12)) return {0, 0, 0};
  return {a[0] / l, a[1] / l, a[2] / l};
}

// The CAD shape seen as a BoundaryModel. Immutable after construction; its const queries may run
// concurrently (the sampling's parallel loops): the classifier's caches live in per-thread clones.
class CadModel : public BoundaryModel {
 public:
  CadModel(const cad::Shape& s, const std::set<cad::Tag>& refine) : s_(s), clones_(s) {
    refined_.resize(s.num_faces());
    planar_.resize(s.num_faces());
    for (int f = 0; f < s.num_faces(); ++f) planar_[f] = s.face_surface_type(f) == "plane";
    bool any = false;
    for (int f = 0; f < s.num_faces(); ++f) any |= (refined_[f] = refine.count(s.face_tag(f)) > 0);
    if (!any) std::fill(refined_.begin(), refined_.end(), true);
    all_refined_fallback_ = !any;
    vfaces_.resize(s.num_vertices());
    vedges_.resize(s.num_vertices());
    for (int e = 0; e < s.num_edges(); ++e) {
      auto ends = s.edge_vertices(e);
      auto fs = s.edge_faces(e);
      for (int k = 0; k < 2; ++k) {
        if (ends[k] < 0) continue;
        vedges_[ends[k]].push_back({e, k});
        vfaces_[ends[k]].insert(vfaces_[ends[k]].end(), fs.begin(), fs.end());
      }
    }
    polys_.resize(s.num_faces());
    for (int f = 0; f < s.num_faces(); ++f) build_poly(f);
    for (auto& v : vfaces_) {
      std::sort(v.begin(), v.end());
      v.erase(std::unique(v.begin(), v.end()), v.end());
    }
  }
  bool all_refined_fallback() const { return all_refined_fallback_; }
  // faces whose seam p-curves were chosen by continuity / classified by OCCT alone (build_poly)
  std::pair<long, long> polygon_fixes() const { return {seam_polygons_by_continuity_, polygons_refused_}; }

  int num_faces() const override { return s_.num_faces(); }
  std::array<double, 4> face_bounds(int f) const override {
    auto b = s_.face_uv_bounds(f);
    return {b.u0, b.u1, b.v0, b.v1};
  }
  Vec3 face_point(int f, double u, double v) const override { return v3(s_.face_point(f, u, v)); }
  Vec3 face_normal(int f, double u, double v) const override { return v3(s_.face_normal(f, u, v)); }
  double face_curvature(int f, double u, double v) const override {
    if (planar_[f]) return 0;
    auto c = s_.face_curvature(f, u, v);
    if (!c.defined) return 0;
    double k = std::max(std::abs(c.k1), std::abs(c.k2));
    return std::isfinite(k) ? k : 0;
  }
  // Even-odd test against the face's wires as uv polygons (64 points per edge use); points
  // within `band` of a polygon (4x the largest measured chord deviation) go to the exact
  // OCCT classifier, as do faces whose polygons could not be built or disagree with it (build_poly).
  bool face_contains(int f, double u, double v) const override {
    const FacePoly& fp = polys_[f];
    if (!fp.ok) return clones_.local().face_contains_uv(f, u, v, 1e-9);
    return polygon_contains(f, fp, u, v);
  }
  bool face_refined(int f) const override { return refined_[f]; }
  int num_edges() const override { return s_.num_edges(); }
  bool edge_degenerate(int e) const override { return s_.edge_degenerate(e); }
  std::array<double, 2> edge_range(int e) const override {
    auto r = s_.edge_range(e);
    return {r.lo, r.hi};
  }
  Vec3 edge_point(int e, double t) const override { return v3(s_.edge_point(e, t)); }
  Vec3 edge_normal(int e, double t) const override {
    Vec3 n{0, 0, 0};
    for (int f : s_.edge_faces(e)) {
      auto uv = s_.edge_uv(e, f, t);
      Vec3 nf = v3(s_.face_normal(f, uv.u, uv.v));
      for (int k = 0; k < 3; ++k) n[k] += nf[k];
    }
    return unit(n);
  }
  std::vector<int> edge_faces(int e) const override { return s_.edge_faces(e); }
  int num_vertices() const override { return s_.num_vertices(); }
  Vec3 vertex_point(int v) const override { return v3(s_.vertex_point(v)); }
  Vec3 vertex_normal(int v) const override {
    Vec3 n{0, 0, 0};
    for (auto [e, end] : vedges_[v]) {
      if (s_.edge_degenerate(e)) continue;
      auto r = s_.edge_range(e);
      Vec3 ne = edge_normal(e, end == 0 ? r.lo : r.hi);
      for (int k = 0; k < 3; ++k) n[k] += ne[k];
    }
    return unit(n);
  }
  std::vector<int> vertex_faces(int v) const override { return vfaces_[v]; }

 private:
  const cad::Shape& s_;
  cad::ShapeClones clones_;
  std::vector<char> refined_, planar_;
  struct FacePoly {
    bool ok = false;
    double band = 0;
    std::vector<std::vector<std::pair<double, double>>> loops;
  };
  std::vector<FacePoly> polys_;
  // One edge use as N + 1 uv points (its end included) and the largest chord sag; `pcurve`
  // selects the seam's p-curve.
  using UVLoop = std::vector<std::pair<double, double>>;
  UVLoop use_points(int f, const cad::EdgeUse& eu, bool pcurve, double& sag) const {
    const int N = 64;
    auto r = s_.edge_range(eu.edge);
    UVLoop pts;
    for (int k = 0; k < N; ++k) {
      double a = eu.reversed ? 1.0 - double(k) / N : double(k) / N;
      double an = eu.reversed ? 1.0 - double(k + 1) / N : double(k + 1) / N;
      double t = r.lo + a * (r.hi - r.lo), tn = r.lo + an * (r.hi - r.lo);
      auto p0 = s_.edge_uv(eu.edge, f, t, pcurve), p1 = s_.edge_uv(eu.edge, f, tn, pcurve);
      auto pm = s_.edge_uv(eu.edge, f, 0.5 * (t + tn), pcurve);
      sag = std::max(sag, std::hypot(pm.u - 0.5 * (p0.u + p1.u), pm.v - 0.5 * (p0.v + p1.v)));
      pts.push_back({p0.u, p0.v});
      if (k == N - 1) pts.push_back({p1.u, p1.v});  // the end, which the next use starts from
    }
    return pts;
  }
  bool polygon_contains(int f, const FacePoly& fp, double u, double v) const {
    bool in = false;
    double d2min = INFINITY;  // squared: a square root per segment (std::hypot) was 11% of the wing's medial stage
    for (auto& loop : fp.loops) {
      const std::size_t n = loop.size();
      for (std::size_t i = 0, j = n - 1; i < n; j = i++) {
        auto [ui, vi] = loop[i];
        auto [uj, vj] = loop[j];
        if ((vi > v) != (vj > v) && u < (uj - ui) * (v - vi) / (vj - vi) + ui) in = !in;
        double du = uj - ui, dv = vj - vi, l2 = du * du + dv * dv;
        double t = l2 > 0 ? std::clamp(((u - ui) * du + (v - vi) * dv) / l2, 0.0, 1.0) : 0.0;
        const double eu = u - ui - t * du, ev = v - vi - t * dv;
        d2min = std::min(d2min, eu * eu + ev * ev);
      }
    }
    if (std::sqrt(d2min) <= fp.band) return clones_.local().face_contains_uv(f, u, v, 1e-9);
    return in;
  }
  // A wire as a uv polygon, each use on the p-curve its orientation names, or (by_continuity) a
  // seam's uses after the first on whichever of its two p-curves starts where the previous use
  // ended.
  UVLoop wire_loop(int f, const std::vector<cad::EdgeUse>& wire, bool by_continuity, double& sag) const {
    UVLoop loop;
    std::pair<double, double> end{};
    for (auto& eu : wire) {
      UVLoop pts = use_points(f, eu, eu.reversed, sag);
      if (by_continuity && !loop.empty() && s_.edge_is_seam(eu.edge, f)) {
        UVLoop other = use_points(f, eu, !eu.reversed, sag);
        auto gap = [&](const UVLoop& c) { return std::hypot(c.front().first - end.first, c.front().second - end.second); };
        if (gap(other) < gap(pts)) pts = std::move(other);
      }
      end = pts.back();
      loop.insert(loop.end(), pts.begin(), pts.end() - 1);
    }
    return loop;
  }
  FacePoly face_poly(int f, bool by_continuity) const {
    FacePoly fp;
    auto b = s_.face_uv_bounds(f);
    double sag = 0;
    for (auto& wire : s_.face_wires(f)) {
      UVLoop loop = wire_loop(f, wire, by_continuity, sag);
      if (loop.size() >= 3) fp.loops.push_back(std::move(loop));
    }
    double ext = std::max(b.u1 - b.u0, b.v1 - b.v0);
    fp.band = std::max(4 * sag, 1e-6 * ext);
    fp.ok = !fp.loops.empty() && std::isfinite(fp.band);
    for (auto& l : fp.loops)
      for (auto& [u, v] : l) fp.ok = fp.ok && std::isfinite(u) && std::isfinite(v);
    return fp;
  }
  // The polygon classifies like OCCT on both sides of its own boundary: points 8 bands (at least
  // 1e-4 of the uv extent) either side of every 8th chord's middle.
  bool agrees_with_occt(int f, const FacePoly& fp) const {
    auto b = s_.face_uv_bounds(f);
    const double d = std::max(8 * fp.band, 1e-4 * std::max(b.u1 - b.u0, b.v1 - b.v0));
    for (auto& loop : fp.loops)
      for (std::size_t i = 0; i < loop.size(); i += 8) {
        auto [ua, va] = loop[i];
        auto [ub, vb] = loop[(i + 1) % loop.size()];
        const double l = std::hypot(ub - ua, vb - va);
        if (!(l > 0)) continue;
        for (double side : {-1.0, 1.0}) {
          double u = 0.5 * (ua + ub) - side * d * (vb - va) / l, v = 0.5 * (va + vb) + side * d * (ub - ua) / l;
          if (polygon_contains(f, fp, u, v) != clones_.local().face_contains_uv(f, u, v, 1e-9)) return false;
        }
      }
    return true;
  }
  bool has_seam(int f) const {
    for (int e : s_.face_edges(f))
      if (s_.edge_is_seam(e, f)) return true;
    return false;
  }
  // A face with a seam: the polygon on the p-curves the orientations name unless it classifies
  // unlike OCCT, then the seam's p-curves chosen by continuity (NekMesh's cylinder after heal's
  // unify: the names gave the u = 0 p-curve right after the top circle ended at u = 2 pi, a
  // bow-tie that classified a band beside each junction circle, half way round, as outside: no
  // face sample within 9e-3 of the circle there, and Delaunay balls across the gap that the shell
  // took for narrow passages; Rotor 67's blade, whose closed edges run the same way round, needs
  // the names), else none (OCCT's classifier everywhere).
  void build_poly(int f) {
    FacePoly fp;
    try {
      fp = face_poly(f, false);
      if (fp.ok && has_seam(f) && !agrees_with_occt(f, fp)) {
        fp = face_poly(f, true);
        fp.ok = fp.ok && agrees_with_occt(f, fp);
        ++(fp.ok ? seam_polygons_by_continuity_ : polygons_refused_);
      }
    } catch (...) {
      fp.ok = false;
    }
    polys_[f] = std::move(fp);
  }
  long seam_polygons_by_continuity_ = 0, polygons_refused_ = 0;
  bool all_refined_fallback_ = false;
  std::vector<std::vector<int>> vfaces_;
  std::vector<std::vector<std::pair<int, int>>> vedges_;
};

struct Foot {
  double u = 0, v = 0, distance = INFINITY;
  Vec3 p{};
};
// Nearest point of face f to c near (u,v): damped Newton on |S(u,v) - c|^2 with the second
// derivatives (Gauss-Newton where the Hessian is not positive definite), inside the uv bounds.
// A local search from the contact sample's parameters: far cheaper than a global projection.
Foot newton_foot(const cad::Shape& s, int f, const Vec3& c, double u, double v, const cad::UVBounds& b) {
  auto d3 = [](const cad::Vec3& a, const cad::Vec3& q) { return a.x * q.x + a.y * q.y + a.z * q.z; };
  auto dist = [&](double uu, double vv) {
    auto q = s.face_point(f, uu, vv);
    return std::hypot(q.x - c[0], q.y - c[1], q.z - c[2]);
  };
  const double tol = 1e-12 * std::max(b.u1 - b.u0, b.v1 - b.v0);
  double cur = dist(u, v);
  for (int it = 0; it < 30; ++it) {
    cad::SurfDeriv d = s.face_eval(f, u, v);
    cad::Vec3 r{d.p.x - c[0], d.p.y - c[1], d.p.z - c[2]};
    double gu = d3(r, d.du), gv = d3(r, d.dv);
    double a = d3(d.du, d.du) + d3(r, d.duu), bb = d3(d.du, d.dv) + d3(r, d.duv), cc = d3(d.dv, d.dv) + d3(r, d.dvv);
    double det = a * cc - bb * bb;
    if (!(a > 0 && det > 0)) {
      a = d3(d.du, d.du), bb = d3(d.du, d.dv), cc = d3(d.dv, d.dv);
      det = a * cc - bb * bb;
    }
    if (!(det > 0)) break;
    double su = -(cc * gu - bb * gv) / det, sv = -(-bb * gu + a * gv) / det;
    double step = 1, best = cur, nu = u, nv = v;
    for (int k = 0; k < 8; ++k, step *= 0.5) {
      double tu = std::clamp(u + step * su, b.u0, b.u1), tv = std::clamp(v + step * sv, b.v0, b.v1);
      double dn = dist(tu, tv);
      if (dn < best) {
        best = dn, nu = tu, nv = tv;
        break;
      }
    }
    bool moved = std::abs(nu - u) + std::abs(nv - v) > tol;
    u = nu, v = nv, cur = best;
    if (!moved) break;  // converged, or no descent along the Newton direction
  }
  Foot ft;
  ft.u = u, ft.v = v, ft.distance = cur;
  ft.p = v3(s.face_point(f, u, v));
  return ft;
}

// Radius = distance to the boundary: the minimum over the contact faces of the distance to the
// face (projection inside the trimmed face), never above the empty-ball radius. Planar faces
// need no projection (the distance to the plane of a contact sample is exact). A foot point within
// two spacings of a contact sample on that face is inside it; farther ones are classified.
struct FaceTables {
  std::vector<char> planar;
  std::vector<cad::UVBounds> bounds;
};
// One medial point (`mine`: this thread's clone); returns the number of projections accepted.
int refine_point(const cad::Shape& mine, const FaceTables& ft, const std::vector<Sample>& S, MedialPoint& p) {
  std::vector<int> done;
  double r = p.ball_radius;
  bool any = false;
  int projected = 0;
  for (auto q : p.contacts) {
    const Sample& s = S[q];
    if (s.kind != 0 || std::find(done.begin(), done.end(), s.id) != done.end()) continue;
    done.push_back(s.id);
    if (ft.planar[s.id]) {
      double d = std::abs((p.c[0] - s.p[0]) * s.n[0] + (p.c[1] - s.p[1]) * s.n[1] + (p.c[2] - s.p[2]) * s.n[2]);
      r = std::min(r, d);
      any = true;
      continue;
    }
    Foot f = newton_foot(mine, s.id, p.c, s.u, s.v, ft.bounds[s.id]);
    if (!std::isfinite(f.distance)) continue;
    double dq = std::hypot(f.p[0] - s.p[0], f.p[1] - s.p[1], f.p[2] - s.p[2]);
    if (dq > 2 * s.h && !mine.face_contains_uv(s.id, f.u, f.v, 1e-7)) continue;
    r = std::min(r, f.distance);
    any = true;
    ++projected;
  }
  if (any) p.radius = r;
  return projected;
}

// Parallel over medial points (in the caller's task arena) with one Shape clone per thread: each
// point is independent and writes only itself, so the result does not depend on the thread count.
long refine_radii(const cad::Shape& shape, MedialObject& M) {
  const int nf = shape.num_faces();
  FaceTables ft;
  ft.planar.resize(nf);
  ft.bounds.resize(nf);
  for (int f = 0; f < nf; ++f) {
    ft.planar[f] = shape.face_surface_type(f) == "plane";
    ft.bounds[f] = shape.face_uv_bounds(f);
  }
  const std::size_t np = M.points.size();
  std::vector<int> counts(np, 0);
  cad::ShapeClones clones(shape);
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, np, 64), [&](const tbb::blocked_range<std::size_t>& rg) {
    const cad::Shape& mine = clones.local();
    for (std::size_t i = rg.begin(); i != rg.end(); ++i) counts[i] = refine_point(mine, ft, M.samples, M.points[i]);
  });
  for (std::size_t i = 0; i < M.info.size(); ++i) {
    auto& si = M.info[i];
    if (si.pole_in >= 0) si.r_in = M.points[si.pole_in].radius;
    if (si.pole_out >= 0) si.r_out = M.points[si.pole_out].radius;
  }
  long total = 0;
  for (int c : counts) total += c;
  return total;
}

double now() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

cad::Shape load_closed_solid(StageContext& ctx) {
  cad::Shape shape = cad::Shape::load(ctx.input("shape").path);
  if (shape.num_solids() < 1)
    throw StageError("medial: the input shape has no solid; the medial object needs the closed fluid solid: put a `heal` stage "
                     "(or a geometry kind that builds the fluid solid) in `needs`");
  if (auto fe = shape.free_edges(); !fe.empty())
    throw StageError("medial: the input shape is not closed (" + std::to_string(fe.size()) + " free edges, e.g. edge " +
                     std::to_string(fe[0]) + "); heal it first (stage kind `heal`)");
  return shape;
}

void write_stats(StageContext& ctx, const MedialObject& M, const RunReport& rep, long projected, std::pair<long, long> fixes,
                 double t_projection, double t_total) {
  auto& st = ctx.stats();
  nlohmann::json sum = M.summary();
  st["samples"] = M.samples.size();
  st["samples_per_pass"] = rep.samples_per_pass;
  st["medial_points"] = sum["medial_points"];
  st["halos"] = M.halos.size();
  st["halo_samples"] = sum["halo_samples"];
  st["radius_fluid"] = sum["radius_fluid"];
  st["radius_body"] = sum["radius_body"];
  st["lfs_walls"] = sum["lfs_walls"];
  st["projections"] = projected;
  if (fixes.first + fixes.second > 0)  // only when it acts: other medial stats keep their bytes
    st["uv_polygons"] = {{"seam_by_continuity", fixes.first}, {"occt_only", fixes.second}};
  st["time"] = {{"sampling", rep.t_sampling}, {"delaunay", rep.t_delaunay}, {"poles", rep.t_poles},
                {"lfs", rep.t_lfs},           {"projection", t_projection}, {"total", t_total}};
}

// Everything parallel (sampling, core, projections) runs in a task arena of the stage's thread
// budget; every parallel loop writes per-index slots, so the bytes do not depend on it.
void run(StageContext& ctx) {
  const auto& P = ctx.params();
  double t0 = now();
  cad::Shape shape = load_closed_solid(ctx);
  std::set<cad::Tag> refine;
  for (auto& t : P.at("refine_tags")) refine.insert(cad::tag_from_name(t.get<std::string>()));
  CadModel model(shape, refine);
  if (model.all_refined_fallback())
    ctx.log("medial: no face carries one of refine_tags; all faces are refined");
  const auto [by_continuity, refused] = model.polygon_fixes();
  if (by_continuity + refused > 0)
    ctx.log("medial: " + std::to_string(by_continuity) + " face(s) with a seam classified with its p-curves chosen by continuity, " +
            std::to_string(refused) + " by OCCT's classifier alone (their uv polygon as the wire names it disagreed with OCCT)");
  Params prm = Params::from_json(P);
  RunReport rep;
  MedialObject M;
  long projected = 0;
  double t1 = 0, t2 = 0;
  tbb::task_arena arena(std::max(1, ctx.threads()));
  arena.execute([&] {
    M = compute(model, prm, &rep, [&](double f, const std::string& w) { ctx.progress(f, w); });
    t1 = now();
    if (P.at("refine_radius").get<bool>()) {
      ctx.progress(0.95, "projecting medial points");
      projected = refine_radii(shape, M);
    }
    t2 = now();
  });
  nlohmann::json h = nlohmann::json::parse(M.header);
  h["units"] = shape.units();
  h["params"]["refine_radius"] = P.at("refine_radius");
  h["params"]["refine_tags"] = P.at("refine_tags");
  M.header = h.dump();
  write(M, ctx.output("medial", "medial"));
  write_stats(ctx, M, rep, projected, {by_continuity, refused}, t2 - t1, now() - t0);
  ctx.progress(1.0, "done");
}

StageRegistrar reg({.kind = "medial",
                    .version = 1,
                    .summary = "medial object of the fluid solid (CGAL Delaunay poles): medial points with radius, wall LFS, halos",
                    .libraries = {"CGAL " CGAL_VERSION_STR},
                    .needs = {"shape"},
                    .produces = {{"medial", "medial"}},
                    .run = run});

}  // namespace
}  // namespace meshflow::medial
