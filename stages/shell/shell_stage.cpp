// meshflow stage kind `shell` (paper §III.C): thickness and sweep-direction fields on the walls
// bounded by the medial object, the near-field block structure (prism sweep per wall face,
// hex junction blocks at concave edges for topology C) and a sampled shell surface with its
// checks. Method and artifact: stages/shell/shell.hpp. No CGAL, no OCCT header here.
#include "engine/stage.hpp"
#include "stages/cad/cad.hpp"
#include "stages/cad/shape_clones.hpp"
#include "stages/cad/vec3.hpp"
#include "stages/medial/medial.hpp"
#include "stages/shell/shell.hpp"

#include <CGAL/version_macros.h>  // version string only (no CGAL code)
#include <nlohmann/json.hpp>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <array>
#include <cstdio>
#include <cstdlib>
#include <chrono>
#include <cmath>
#include <map>
#include <numeric>
#include <optional>
#include <queue>
#include <set>
#include <sstream>
#include <tuple>

namespace meshflow::shell {
namespace {

// ── small vector helpers ──
using namespace cad::vec;  // v3, cv, add, sub, mul, dot, cross, norm
Vec3 unit(Vec3 a) {
  double l = norm(a);
  return l > 1e-300 ? mul(a, 1 / l) : Vec3{0, 0, 0};
}
double smoothstep(double x) {
  x = std::clamp(x, 0.0, 1.0);
  return x * x * (3 - 2 * x);
}
std::string fmt(Vec3 p) {
  std::ostringstream o;
  o.precision(6);
  o << "(" << p[0] << ", " << p[1] << ", " << p[2] << ")";
  return o.str();
}
double now() { return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count(); }

// body(mine, i) for every i in [0, n) on `threads` threads, each working on its own clone of
// `shape` (its projections fill lazy caches, see cad.hpp). The body writes per-index slots only
// and the caller reduces them in index order, so the result does not depend on the thread count.
template <class Body>
void for_each_index(const cad::Shape& shape, int threads, std::size_t n, Body&& body) {
  if (threads <= 1 || n < 256) {
    cad::Shape mine = shape.clone();
    for (std::size_t i = 0; i < n; ++i) body(mine, i);
    return;
  }
  cad::ShapeClones clones(shape);
  tbb::task_arena arena(threads);
  arena.execute([&] {
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 64), [&](const tbb::blocked_range<std::size_t>& r) {
      cad::Shape& mine = clones.local();
      for (std::size_t i = r.begin(); i != r.end(); ++i) body(mine, i);
    });
  });
}

enum class EdgeKind { none, seam, wall_wall, wall_other };

struct EdgeInfo {
  EdgeKind kind = EdgeKind::none;
  int a = -1, b = -1;        // wall face A; B (wall or other); seam: a only
  double fluid_angle = 180;  // degrees, through the fluid
  bool concave = false, junction = false;
  double sign_a = 1, sign_b = 1;  // m_X = sign_X * unit(T x n_X) points into face X
  // stations
  std::vector<double> t;           // parameters
  std::vector<Vec3> p;             // points
  std::vector<double> arc;         // cumulative length
  std::vector<std::map<int, cad::Vec2>> uv;  // per station, per face
  std::vector<std::map<int, Vec3>> nu;       // fluid normals per face
  std::vector<Vec3> ma, mb;                  // in-face directions
  std::vector<double> th;                    // thickness
  std::vector<int> sides;                    // faces with a field (ascending)
  std::map<int, std::vector<Vec3>> dir;      // per side
  int v0 = -1, v1 = -1;
};

struct Stage {
  StageContext& ctx;
  const nlohmann::json& P;
  cad::Shape shape;
  medial::MedialObject M;
  int nf = 0, ne = 0, nv = 0;
  std::vector<char> wall;
  std::set<cad::Tag> junction_with;
  bool topo_c = true;
  double T = 0, alpha = 0.5, grad = 0.3, h = 0, blend = 2, junction_angle = 150, Lref = 0;
  int max_grid = 200;
  std::vector<EdgeInfo> E;
  std::vector<std::vector<int>> treated_nbrs;  // faces joined to f by a concave treated edge
  // wall samples
  std::vector<int> ws;              // indices into M.samples
  std::vector<double> ws_a, ws_t;   // allowed, smoothed thickness
  std::unique_ptr<medial::NearestIndex> ws_index;
  // vertices
  std::vector<char> v_has;
  std::vector<double> v_t;
  std::vector<Vec3> v_d;
  // face grids
  std::map<int, FaceGrid> grids;

  Stage(StageContext& c) : ctx(c), P(c.params()) {}

  Vec3 fluid_normal(int f, double u, double v) const {
    Vec3 n = v3(shape.face_normal(f, u, v));
    if (norm(n) < 0.5) {  // singular point: step towards the middle of the bounds
      auto b = shape.face_uv_bounds(f);
      double uc = 0.5 * (b.u0 + b.u1), vc = 0.5 * (b.v0 + b.v1);
      for (double s = 1e-6; s < 0.2 && norm(n) < 0.5; s *= 4) n = v3(shape.face_normal(f, u + s * (uc - u), v + s * (vc - v)));
    }
    return mul(n, -1.0);
  }

  // ── 1. edges: classification and stations ──
  void classify_edges() {
    E.resize(ne);
    for (int e = 0; e < ne; ++e) {
      EdgeInfo& I = E[e];
      if (shape.edge_degenerate(e)) continue;
      auto fs = shape.edge_faces(e);
      std::vector<int> wf;
      for (int f : fs)
        if (wall[f]) wf.push_back(f);
      if (wf.empty()) continue;
      if (fs.size() == 1) {
        if (!shape.edge_is_seam(e, fs[0])) continue;
        I.kind = EdgeKind::seam, I.a = fs[0];
      } else if (fs.size() == 2) {
        if (wf.size() == 2) I.kind = EdgeKind::wall_wall, I.a = fs[0], I.b = fs[1];
        else I.kind = EdgeKind::wall_other, I.a = wf[0], I.b = fs[0] == wf[0] ? fs[1] : fs[0];
      } else {
        continue;  // non-manifold: heal refuses these; nothing to do here
      }
      auto r = shape.edge_range(e);
      double len = shape.edge_length(e);
      int n = std::clamp(static_cast<int>(std::ceil(len / h)) + 1, 9, 4001);
      {
        // Stations are uniform in t, and dense enough that interpolating between them is
        // faithful: junction corners (PA, PB, PC) are interpolated linearly and directions by
        // normalised lerp. Around a leading edge whose radius is below the spacing (the root of
        // a wing on a body: radius 0.16, spacing 0.7) a chord between two stations cuts through
        // the wing and the interpolated corner folds the junction hexes. Refined (doubled) while
        // the tangent turns by more than 90 degrees between two stations or a chord deviates
        // from the curve (at the middle parameter) by more than 10% of the requested thickness.
        auto too_coarse = [&](int m) {
          double dt = (r.hi - r.lo) / (m - 1);
          Vec3 pa = v3(shape.edge_point(e, r.lo)), ta = unit(v3(shape.edge_eval(e, r.lo).d1));
          for (int i = 1; i < m; ++i) {
            double tb = r.lo + i * dt;
            Vec3 pb = v3(shape.edge_point(e, tb)), tgb = unit(v3(shape.edge_eval(e, tb).d1));
            Vec3 pm = v3(shape.edge_point(e, tb - 0.5 * dt));
            if (norm(sub(pm, mul(add(pa, pb), 0.5))) > 0.1 * T) return true;
            if (norm(ta) > 0.5 && norm(tgb) > 0.5 && dot(ta, tgb) < 0) return true;
            pa = pb, ta = tgb;
          }
          return false;
        };
        while (n < 4001 && too_coarse(n)) n = std::min(4001, 2 * n - 1);
      }
      auto ends = shape.edge_vertices(e);
      I.v0 = ends[0], I.v1 = ends[1];
      std::vector<int> faces = {I.a};
      if (I.b >= 0) faces.push_back(I.b);
      for (int k = 0; k < n; ++k) {
        double t = r.lo + (r.hi - r.lo) * k / (n - 1);
        I.t.push_back(t);
        I.p.push_back(v3(shape.edge_point(e, t)));
        I.arc.push_back(k == 0 ? 0 : I.arc.back() + norm(sub(I.p[k], I.p[k - 1])));
        std::map<int, cad::Vec2> uv;
        std::map<int, Vec3> nn;
        for (int f : faces) {
          uv[f] = shape.edge_uv(e, f, t);
          nn[f] = fluid_normal(f, uv[f].u, uv[f].v);
        }
        I.uv.push_back(uv);
        I.nu.push_back(nn);
      }
      if (I.kind == EdgeKind::seam) continue;
      // In-face directions perpendicular to the edge, their signs, and whether the edge is concave
      // are decided at one station: the middle one, unless it disagrees with the majority of nine
      // stations spread along the edge; then the station nearest the middle that agrees. A single
      // station can sit on a crease of a face (a blade's sharp trailing edge, where a loop edge
      // round the blade's tip meets the casing: the normals there are the crease's, and the edge
      // read as convex lost its junction blocks).
      auto tangent = [&](int k) { return unit(v3(shape.edge_eval(e, I.t[k]).d1)); };
      auto side_sign = [&](int f, int k) {
        Vec3 c = unit(cross(tangent(k), I.nu[k][f]));
        auto d = shape.face_eval(f, I.uv[k][f].u, I.uv[k][f].v);
        Vec3 su = v3(d.du), sv = v3(d.dv);
        double a11 = dot(su, su), a12 = dot(su, sv), a22 = dot(sv, sv), b1 = dot(su, c), b2 = dot(sv, c);
        double det = a11 * a22 - a12 * a12;
        double step = std::min(1e-3 * len, 0.25 * h);
        if (std::abs(det) > 0) {
          double du = (a22 * b1 - a12 * b2) / det, dv = (a11 * b2 - a12 * b1) / det;
          bool plus = shape.face_contains_uv(f, I.uv[k][f].u + step * du, I.uv[k][f].v + step * dv, 1e-12);
          bool minus = shape.face_contains_uv(f, I.uv[k][f].u - step * du, I.uv[k][f].v - step * dv, 1e-12);
          if (plus != minus) return plus ? 1.0 : -1.0;
        }
        auto bx = shape.face_box(f);
        Vec3 mid = mul(add(v3(bx.lo), v3(bx.hi)), 0.5);
        return dot(sub(mid, I.p[k]), c) >= 0 ? 1.0 : -1.0;
      };
      // a station's reading: the two signs and concavity
      auto reading = [&](int k) {
        double sa = side_sign(I.a, k), sb = side_sign(I.b, k);
        Vec3 mb = mul(unit(cross(tangent(k), I.nu[k][I.b])), sb);
        return std::array<int, 3>{sa > 0, sb > 0, dot(I.nu[k][I.a], mb) > 1e-9};
      };
      std::array<int, 3> votes{0, 0, 0};
      for (int i = 1; i <= 9; ++i) {
        auto r9 = reading(i * (n - 1) / 10);
        for (int j = 0; j < 3; ++j) votes[j] += r9[j];
      }
      const std::array<int, 3> major{votes[0] >= 5, votes[1] >= 5, votes[2] >= 5};
      int k = n / 2;
      for (int d = 0; d <= n / 2; ++d) {
        if (k - d >= 0 && reading(k - d) == major) {
          k -= d;
          break;
        }
        if (k + d < n && reading(k + d) == major) {
          k += d;
          break;
        }
      }
      I.sign_a = side_sign(I.a, k);
      I.sign_b = side_sign(I.b, k);
      for (int j = 0; j < n; ++j) {
        Vec3 T = tangent(j);
        I.ma.push_back(mul(unit(cross(T, I.nu[j][I.a])), I.sign_a));
        I.mb.push_back(mul(unit(cross(T, I.nu[j][I.b])), I.sign_b));
      }
      double c = std::clamp(dot(I.ma[k], I.mb[k]), -1.0, 1.0);
      double a0 = std::acos(c) * 180 / M_PI;
      I.concave = dot(I.nu[k][I.a], I.mb[k]) > 1e-9;
      I.fluid_angle = I.concave ? a0 : 360 - a0;
      I.junction = topo_c && I.concave && I.fluid_angle < junction_angle && junction_with.count(shape.face_tag(I.b));
      if (I.concave) {
        treated_nbrs[I.a].push_back(I.b);
        treated_nbrs[I.b].push_back(I.a);
      }
    }
    for (auto& v : treated_nbrs) {
      std::sort(v.begin(), v.end());
      v.erase(std::unique(v.begin(), v.end()), v.end());
    }
  }

  // ── 1a. junction chains that end on a third face ──
  // A junction edge ending at a vertex V where a wall face meets that is neither face of any
  // junction ending at V (DLR-F6: the pylon's junctions with the wing end on the pylon's blunt
  // trailing-edge face, the pylon-nacelle junction on the pylon's leading-edge face) leaves a
  // pocket between the hex's end face and the third face's prisms that no layered element fills
  // (stages/sweep/sweep.hpp, "Junction ends on a third face"). With third_face_ends = averaged
  // every junction edge connected to such an end (through vertices shared by junction edges:
  // the whole chain, so that no block ends in the middle of a wall|wall curve) gets no block; it
  // is treated like a concave edge above junction_angle_deg (normals averaged), so every element
  // there is a layered prism. With `cap` the blocks stay and sweep caps their ends (tets and
  // pyramids, which split cannot layer). Recorded in stats.junction_chains_averaged.
  nlohmann::json averaged_chains = nlohmann::json::array();
  void average_third_face_chains() {
    std::vector<std::set<int>> vfaces(std::max(nv, 0));
    std::vector<std::vector<int>> vjunctions(std::max(nv, 0));
    for (int e = 0; e < ne; ++e) {
      if (shape.edge_degenerate(e)) continue;
      auto vs = shape.edge_vertices(e);
      for (int f : shape.edge_faces(e))
        if (wall[f])
          for (int v : vs)
            if (v >= 0 && v < nv) vfaces[v].insert(f);
      if (E[e].junction)
        for (int k = 0; k < 2; ++k)
          if (vs[k] >= 0 && vs[k] < nv && (k == 0 || vs[1] != vs[0])) vjunctions[vs[k]].push_back(e);
    }
    // chains: junction edges connected through shared vertices (union-find on edge ids)
    std::vector<int> parent(ne);
    for (int e = 0; e < ne; ++e) parent[e] = e;
    auto find = [&](int a) {
      while (parent[a] != a) a = parent[a] = parent[parent[a]];
      return a;
    };
    for (int v = 0; v < nv; ++v)
      for (std::size_t k = 1; k < vjunctions[v].size(); ++k) {
        int a = find(vjunctions[v][0]), b = find(vjunctions[v][k]);
        if (a != b) parent[std::max(a, b)] = std::min(a, b);
      }
    std::map<int, std::pair<int, int>> ends;  // chain root -> (vertex, third face) of its first such end
    for (int v = 0; v < nv; ++v) {
      if (vjunctions[v].empty()) continue;
      std::set<int> roles;
      for (int e : vjunctions[v]) roles.insert(E[e].a), roles.insert(E[e].b);
      for (int f : vfaces[v])
        if (!roles.count(f)) {
          ends.emplace(find(vjunctions[v][0]), std::make_pair(v, f));
          break;
        }
    }
    for (auto& [root, vf] : ends) {
      std::vector<int> chain;
      for (int e = 0; e < ne; ++e)
        if (E[e].junction && find(e) == root) chain.push_back(e), E[e].junction = false;
      auto x = shape.vertex_point(vf.first);
      averaged_chains.push_back({{"edges", chain}, {"vertex", vf.first}, {"third_face", vf.second}, {"at", {x.x, x.y, x.z}}});
      std::string l = "shell: the junction chain along edge";
      for (int e : chain) l += " " + std::to_string(e);
      ctx.log(l + " ends at vertex " + std::to_string(vf.first) + " on face " + std::to_string(vf.second) +
              ", not one of its faces: no junction blocks along it, normals averaged (third_face_ends: averaged)");
    }
  }

  std::vector<std::vector<int>> face_edges_cache;
  static double dist_to_polyline(const std::vector<Vec3>& p, const Vec3& x) {
    double best = INFINITY;
    for (std::size_t k = 0; k + 1 < p.size(); ++k) {
      Vec3 ab = sub(p[k + 1], p[k]);
      double l2 = dot(ab, ab);
      double s = l2 > 0 ? std::clamp(dot(sub(x, p[k]), ab) / l2, 0.0, 1.0) : 0.0;
      best = std::min(best, norm(sub(x, add(p[k], mul(ab, s)))));
    }
    return best;
  }
  // ── 1b. junction strips limited by the width of their faces ──
  // A junction block's cross-section is square: the strip on A is as wide as B's layer is thick
  // and the strip on B as wide as A's layer (PA = P0 + th m_A, PB = P0 + th m_B, PC = PA's shell
  // image ~ P0 + th (m_A + m_B)), all the edge thickness th. Where a face is narrower than that
  // across the junction edge (DLR-F6: the nacelle's blunt base, a plane ring 0.7 mm wide, meets
  // the pylon along 8 mm of its outer circle; th 2.4 mm) the strip reaches past the face's far
  // side, its boundary crosses the face's other loop in (u,v), and sweep cannot triangulate the
  // face. The strip alone cannot be made narrower (B's layer would then be thinner than B's field
  // next to it: a step), so the thickness itself is limited there: at each station of a junction
  // edge, W_X = how far the ray P0 + s m_X (projected on X) stays inside face X (X = A, B), and
  // th <= kStripFraction x W_X. Each limit is a point constraint t(x) <= a + g |x - P0|, applied by
  // thickness_at to every wall point (3D distance, like the medial bound it joins): the field
  // stays g-Lipschitz and continuous across faces, a dimple of radius (T - a) / g around the
  // narrow place. Exits through an edge that shares a vertex with the junction edge (the face's
  // side edge at an acute corner, where sweep puts the block's end cross-section) or through a
  // seam (not a boundary in 3D) do not count. Faces at least T / kStripFraction wide across their
  // junction edges (every case before DLR-F6) are not affected: their shells are unchanged.
  static constexpr double kStripFraction = 0.5;
  struct WidthLimit {
    Vec3 p;
    double a;
  };
  std::vector<WidthLimit> width_limits;
  long width_limited_stations = 0;
  double width_limit_min = INFINITY;
  Vec3 width_limit_at{};
  // how far the ray from station k of edge e along dir stays inside face X (INFINITY: beyond smax,
  // or it leaves through an edge that does not count, see above)
  double face_width(int e, int k, int X, const Vec3& dir, double smax) const {
    const EdgeInfo& I = E[e];
    cad::Vec2 hint = I.uv[k].at(X);
    auto inside = [&](double s, cad::Vec2& hnt) {
      auto pr = shape.project_to_face(X, cv(add(I.p[k], mul(dir, s))), hnt);
      hnt = cad::Vec2{pr.u, pr.v};
      return shape.face_contains_uv(X, pr.u, pr.v);
    };
    const int N = 8;
    double lo = 0, hi = -1;
    for (int i = 1; i <= N; ++i) {
      double s = smax * i / N;
      if (!inside(s, hint)) {
        hi = s;
        break;
      }
      lo = s;
    }
    if (hi < 0) return INFINITY;
    cad::Vec2 h2 = hint;
    for (int it = 0; it < 10; ++it) {
      double mid = 0.5 * (lo + hi);
      cad::Vec2 hh = I.uv[k].at(X);
      if (inside(mid, hh)) lo = mid;
      else hi = mid, h2 = hh;
    }
    // the edge it leaves through
    auto q = shape.face_point(X, h2.u, h2.v);
    int best = -1;
    double bd = INFINITY;
    for (int f2e : face_edges_cache[X]) {
      if (shape.edge_degenerate(f2e)) continue;
      double d = shape.project_to_edge(f2e, q).distance;
      if (d < bd) bd = d, best = f2e;
    }
    if (best < 0 || best == e || shape.edge_is_seam(best, X)) return INFINITY;
    auto vs = shape.edge_vertices(best);
    for (int v : vs)
      if (v >= 0 && (v == I.v0 || v == I.v1)) return INFINITY;
    return lo;
  }
  void junction_width_limits() {
    const double smax = T / kStripFraction;
    for (int e = 0; e < ne; ++e) {
      const EdgeInfo& I = E[e];
      if (!I.junction || I.t.empty()) continue;
      for (std::size_t k = 0; k < I.t.size(); ++k) {
        double w = std::min(face_width(e, static_cast<int>(k), I.a, I.ma[k], smax),
                            face_width(e, static_cast<int>(k), I.b, I.mb[k], smax));
        if (!std::isfinite(w)) continue;
        double a = kStripFraction * w;
        if (!(a < T)) continue;
        width_limits.push_back({I.p[k], a});
        ++width_limited_stations;
        if (a < width_limit_min) width_limit_min = a, width_limit_at = I.p[k];
      }
    }
  }

  // ── 2. thickness on the wall samples ──
  // The limit is local: every wall sample gets its own bound a_i (alpha x fluid-side medial
  // radius, lfs bound), spread g-Lipschitz along the walls; small balls thin the layer where they
  // are, not everywhere. A refusal is left for a thickness the domain cannot hold over a large
  // part of the wall (thinning_verdict).
  long corner_balls = 0, limited_samples = 0, limited_by_lfs = 0;
  double lfs_factor = 0, thin_fraction = 0.5, max_thinned_area = 0.5;
  double lim_min = INFINITY;
  Vec3 lim_at{};
  std::vector<double> ws_free;  // the smoothed bound without the cap T (INFINITY: no bound)
  std::vector<std::vector<std::pair<int, double>>> ws_adj;  // kNN graph of wall samples sharing a face
  nlohmann::json thinning;      // stats.local_thinning

  void collect_wall_samples() {
    for (std::size_t i = 0; i < M.samples.size(); ++i) {
      auto& s = M.samples[i];
      bool onwall = false;
      for (int f : s.faces)
        if (f >= 0 && f < nf && wall[f]) onwall = true;
      if (onwall) ws.push_back(static_cast<int>(i));
    }
    if (ws.empty())
      throw StageError("shell: the medial object has no sample on a wall face; was it computed from the same shape "
                       "(needs: [heal, medial] with medial after heal)?");
    std::vector<medial::Vec3> pts;
    for (int i : ws) pts.push_back(M.samples[i].p);
    ws_index = std::make_unique<medial::NearestIndex>(pts);
  }

  // A corner ball: its centre lies in the corner region of a treated concave edge of the sample's
  // face (within 2 r / sin(angle/2) of the edge: the bisector distance of a ball of radius r tangent
  // to both faces, doubled); its radius goes to 0 at the edge by construction and the topology
  // (junction, slide, averaged normals) handles it. r is the ball's refined radius (see shell.hpp
  // for why not its empty-ball radius).
  bool near_treated_concave_edge(const medial::Sample& s, const Vec3& c, double r) const {
    for (int f : s.faces) {
      if (f < 0) continue;
      for (int e : face_edges_cache[f]) {
        const EdgeInfo& I = E[e];
        if (!I.concave || I.fluid_angle > 170 || I.p.size() < 2) continue;
        if (dist_to_polyline(I.p, c) <= 2 * r / std::sin(I.fluid_angle * M_PI / 360) + 0.5 * h) return true;
      }
    }
    return false;
  }
  bool corner_ball(const medial::Sample& s, const medial::MedialPoint& mp) const {
    return near_treated_concave_edge(s, mp.c, mp.radius);
  }

  // a_i: the bound of wall sample k (INFINITY: none)
  double sample_bound(std::size_t k) {
    const auto& si = M.info[ws[k]];
    double a = INFINITY;
    if (si.r_in >= 0 && si.pole_in >= 0) {
      if (corner_ball(M.samples[ws[k]], M.points[si.pole_in])) {
        ++corner_balls;
      } else {
        a = alpha * si.r_in;
      }
    }
    if (lfs_factor > 0 && si.lfs > 0 && lfs_factor * si.lfs < std::min(a, T)) {
      a = lfs_factor * si.lfs;
      ++limited_by_lfs;
    }
    return a;
  }

  void build_sample_graph() {
    const int K = 10;
    ws_adj.assign(ws.size(), {});
    for (std::size_t k = 0; k < ws.size(); ++k) {
      auto nb = ws_index->nearest(M.samples[ws[k]].p, K + 1);
      for (auto [j, d] : nb) {
        if (j == static_cast<int>(k)) continue;
        bool share = false;
        for (int f : M.samples[ws[k]].faces)
          for (int g : M.samples[ws[j]].faces) share |= f >= 0 && f == g;
        if (!share) continue;
        ws_adj[k].push_back({j, d});
        ws_adj[j].push_back({static_cast<int>(k), d});
      }
    }
  }

  // Lipschitz smoothing on the kNN graph (Dijkstra): t_i = min_j (a_j + g path(i, j))
  std::vector<double> smooth(std::vector<double> t) const {
    using Q = std::pair<double, int>;
    std::priority_queue<Q, std::vector<Q>, std::greater<Q>> q;
    for (std::size_t k = 0; k < ws.size(); ++k)
      if (std::isfinite(t[k])) q.push({t[k], static_cast<int>(k)});
    while (!q.empty()) {
      auto [tk, k] = q.top();
      q.pop();
      if (tk > t[k]) continue;
      for (auto [j, d] : ws_adj[k])
        if (tk + grad * d < t[j]) {
          t[j] = tk + grad * d;
          q.push({t[j], j});
        }
    }
    return t;
  }

  void sample_thickness() {
    collect_wall_samples();
    std::vector<double> bound(ws.size());
    ws_a.assign(ws.size(), T);
    for (std::size_t k = 0; k < ws.size(); ++k) {
      bound[k] = sample_bound(k);
      ws_a[k] = std::min(T, bound[k]);
      if (ws_a[k] < T * (1 - 1e-12)) {
        ++limited_samples;
        if (ws_a[k] < lim_min) lim_min = ws_a[k], lim_at = M.samples[ws[k]].p;
      }
    }
    build_sample_graph();
    ws_t = smooth(ws_a);
    ws_free = smooth(bound);
    thinning_verdict();
  }

  // The wall area a sample stands for: its sampling cell (h^2) for face samples; edge and vertex
  // samples stand for none (their faces' samples cover the area)
  double sample_area(std::size_t k) const {
    const auto& s = M.samples[ws[k]];
    return s.kind == 0 ? s.h * s.h : 0.0;
  }
  std::string place(std::size_t k) const {
    const auto& s = M.samples[ws[k]];
    int f = s.faces[0];
    for (int g : s.faces)
      if (g >= 0 && g < nf && wall[g]) { f = g; break; }
    return fmt(s.p) + " on face " + std::to_string(f) + " (" + cad::tag_name(shape.face_tag(f)) + ")";
  }

  // How much of the wall is thinned, logged and kept in stats.local_thinning; a refusal only when
  // more than max_thinned_area of the wall area would be thinner than thin_fraction x T, naming
  // the thinnest place and the largest thickness that keeps that part small enough.
  void thinning_verdict() {
    double area = 0, area_thinned = 0, area_below = 0;
    long thinned = 0;
    std::size_t kmin = 0;
    for (std::size_t k = 0; k < ws.size(); ++k) {
      const double w = sample_area(k);
      area += w;
      if (ws_t[k] < T * (1 - 1e-9)) ++thinned, area_thinned += w;
      if (ws_t[k] < thin_fraction * T) area_below += w;
      if (ws_t[k] < ws_t[kmin]) kmin = k;
    }
    const double frac_thinned = area > 0 ? area_thinned / area : 0, frac_below = area > 0 ? area_below / area : 0;
    thinning = {{"samples", thinned},
                {"of", ws.size()},
                {"area_fraction", frac_thinned},
                {"area_fraction_below", frac_below},
                {"thin_fraction", thin_fraction},
                {"min", ws_t[kmin]},
                {"at", M.samples[ws[kmin]].p},
                {"where", place(kmin)}};
    if (frac_below > max_thinned_area) refuse(frac_below, kmin);
    if (thinned > 0) {
      std::ostringstream o;
      o.precision(4);
      o << "shell: thinned locally where the fluid domain is narrow: " << thinned << " of " << ws.size()
        << " wall samples (" << 100 * frac_thinned << "% of the wall area) below the requested " << T << ", "
        << 100 * frac_below << "% below " << thin_fraction << " x; thinnest " << ws_t[kmin] << " at " << place(kmin);
      ctx.log(o.str());
    }
  }

  // the largest thickness T' for which at most max_thinned_area of the wall is below
  // thin_fraction x T': the smoothed bound commutes with the cap (t(T') = min(T', ws_free)), so
  // T' = (the max_thinned_area quantile by area of ws_free) / thin_fraction
  double workable_thickness() const {
    std::vector<std::pair<double, double>> v;
    double area = 0;
    for (std::size_t k = 0; k < ws.size(); ++k)
      if (sample_area(k) > 0) v.push_back({ws_free[k], sample_area(k)}), area += sample_area(k);
    std::sort(v.begin(), v.end());
    double acc = 0;
    for (auto [t, w] : v) {
      if (acc + w > max_thinned_area * area) return t / thin_fraction;
      acc += w;
    }
    return T;
  }

  [[noreturn]] void refuse(double frac_below, std::size_t kmin) const {
    // rounded down to 3 significant digits, so that the figure printed still fits
    const double Tw0 = std::min(T, workable_thickness()), q = std::pow(10.0, std::floor(std::log10(Tw0)) - 2);
    const double Tw = Tw0 > 0 ? std::floor(Tw0 / q) * q : Tw0;
    const bool rel = P.at("thickness_relative_to") == "wall_box";
    std::ostringstream o;
    o.precision(4);
    o << "shell: the requested thickness " << T;
    if (rel) o << " (thickness " << T / Lref << " x the wall box's largest side " << Lref << ")";
    o << " is more than the fluid domain can hold over most of the wall: on " << 100 * frac_below
      << "% of the wall area (more than max_thinned_area = " << 100 * max_thinned_area << "%) alpha x medial radius allows less than "
      << thin_fraction << " x " << T << " (alpha = " << alpha << "); the narrowest place is " << place(kmin)
      << ", where the layer could be " << ws_t[kmin] << " thick. Use a thickness of at most " << Tw;
    if (rel) o << " (thickness: " << Tw / Lref << " with thickness_relative_to: wall_box)";
    o << ", or increase alpha (at most 1)";
    throw StageError(o.str());
  }

  // thickness at a wall point on one of `faces`: min_j (t_j + g |x - x_j|) over nearby samples
  // (then the junction width limits, in thickness_at below)
  double medial_thickness_at(const Vec3& x, const std::vector<int>& faces) const {
    for (int k : {24, 96, 400}) {
      auto nb = ws_index->nearest(x, k);
      double t = INFINITY;
      for (auto [j, d] : nb) {
        bool ok = false;
        for (int f : M.samples[ws[j]].faces)
          for (int g : faces) ok |= f >= 0 && f == g;
        if (ok) t = std::min(t, ws_t[j] + grad * d);
      }
      if (std::isfinite(t)) return std::min(t, T);
    }
    auto nb = ws_index->nearest(x, 1);
    return std::min(T, ws_t[nb[0].first] + grad * nb[0].second);
  }
  double thickness_at(const Vec3& x, const std::vector<int>& faces, bool with_crossing_limits = true) const {
    double t = medial_thickness_at(x, faces);
    for (auto& L : width_limits) t = std::min(t, L.a + grad * norm(sub(x, L.p)));
    if (with_crossing_limits)
      for (auto& L : crossing_limits) t = std::min(t, L.a + kCrossingGradient * grad * norm(sub(x, L.p)));
    return t;
  }

  // ── 2b. thinning where the sampled shell crosses itself (crossing_rounds > 0) ──
  // The medial bound keeps offsets of facing walls apart, but the shell can still fold where the
  // fields turn faster than the layer is thick: round a leading or trailing edge far thinner than
  // the layer next to a junction (Rotor 67's blade root), at the corners of junction strips, at
  // convex edges whose averaged directions converge on a neighbour. Where the sampled surface
  // crosses, every point of the two triangles gets a point constraint t(x) <= kCrossingScale x
  // t(S) + kCrossingGradient g |x - S|, S the wall point whose thickness sets the point's offset
  // (for a strip corner PC: its junction station P0, whose thickness is the strip's width): a
  // Lipschitz dimple a few thicknesses wide, no step. The fields and the sampled surface are
  // then built again, up to crossing_rounds times (default 8), never below kCrossingFloor x the
  // thickness without these constraints; the round with the fewest crossings is kept, and a
  // round that brings the shell nearer to a wall than kCrossingClearance x the unthinned
  // walls_over_thickness is not (a dimple beside a junction corner can turn a strip's corner
  // onto the other face: DLR-F6's wing-pylon corner). It changes the fields, so the near-field
  // mesh, wherever it acts. Pairs that survive are reported (self_intersections).
  // (Rotor 67: 38 pairs at first while the corners PC on the hub's negative-angle side were
  // evaluated in the wrong period and the blade's strips folded round the seam, see grid_at and
  // closed_round_seam; 2 since, cleared by one round: chord triangles where the blade's and the
  // hub's shells leave the root's corner curve at a narrow angle (fluid angle ~65 degrees, x ~0.03)
  // and one at the tip's leading edge, where the casing's field beside the strip is thicker than
  // the edge's thickness at the vertex.)
  static constexpr double kCrossingScale = 0.75, kCrossingFloor = 0.2;
  int max_crossing_rounds = 0;  // parameter crossing_rounds (0: off)
  static constexpr double kCrossingClearance = 0.5;  // x the unthinned walls_over_thickness
  static constexpr double kCrossingGradient = 0.25;  // x max_gradient: dimples about 3 thicknesses wide
  std::vector<WidthLimit> crossing_limits;
  long crossing_points = 0;
  double crossing_min_scale = 1;
  Vec3 crossing_min_at{};
  // adds the constraints of one round; false when no point could be thinned further
  bool add_crossing_limits(const IntersectionReport& inter) {
    std::set<int> pts;
    for (auto [i, j] : inter.all)
      for (int t : {i, j})
        for (int c = 0; c < 3; ++c) pts.insert(out.shell_tris[t][c]);
    bool added = false;
    std::vector<int> faces;
    for (int f = 0; f < nf; ++f) faces.push_back(f);  // any wall face: the bound near W
    for (int q : pts) {
      const Vec3& W = point_source[q];
      double t = thickness_at(W, faces);
      double base = thickness_at(W, faces, false);
      if (!(base > 0)) continue;
      double a = std::max(kCrossingScale * t, kCrossingFloor * base);
      if (!(a < t * (1 - 1e-6))) continue;
      crossing_limits.push_back({W, a});
      added = true;
    }
    return added;
  }
  // forget the fields and the sampled surface (edge_fields .. sample_surface append to them)
  void reset_fields() {
    for (auto& I : E) I.dir.clear(), I.sides.clear(), I.th.clear();
    grids.clear();
    strip_memo.clear();
    out = ShellData{};
    point_faces.clear();
    point_source.clear();
    welded_points = 0;
    strip_fallback.clear();
    refined_faces.clear();
    resampled_points = 0;
    faces_unsampled = 0;
    unsampled_why.clear();
  }

  static double min_dot(const Vec3& d, const std::vector<Vec3>& n) {
    double q = INFINITY;
    for (auto& x : n) q = std::min(q, dot(d, x));
    return q;
  }
  // The unit d maximising min_i d.n_i over unit normals n_i (q: that minimum). The optimum is
  // fixed by at most three active normals (a spherical minimax), so the candidates are each
  // normal, each pair's bisector and each triple's equiangular direction (N d = 1): at most
  // C(k,3) for the k faces at a vertex (k <= 8 in practice; capped at 12 normals).
  static Vec3 maximin_direction(std::vector<Vec3> n, double& q) {
    std::vector<Vec3> u;  // distinct normals
    for (auto& x : n) {
      bool dup = false;
      for (auto& y : u) dup = dup || dot(x, y) > 1 - 1e-9;
      if (!dup && u.size() < 12) u.push_back(x);
    }
    Vec3 best = u.front();
    q = -INFINITY;
    auto consider = [&](Vec3 d) {
      double l = norm(d);
      if (!(l > 1e-12)) return;
      d = mul(d, 1 / l);
      if (double qd = min_dot(d, u); qd > q + 1e-12) q = qd, best = d;
    };
    const std::size_t k = u.size();
    for (std::size_t a = 0; a < k; ++a) {
      consider(u[a]);
      for (std::size_t b = a + 1; b < k; ++b) {
        consider(add(u[a], u[b]));
        for (std::size_t c = b + 1; c < k; ++c) {
          // d = N^-1 (1,1,1) with rows u[a], u[b], u[c] (Cramer: the cross products)
          Vec3 bc = cross(u[b], u[c]), ca = cross(u[c], u[a]), ab = cross(u[a], u[b]);
          double det = dot(u[a], bc);
          if (std::abs(det) < 1e-9) continue;
          consider(mul(add(add(bc, ca), ab), 1 / det));
        }
      }
    }
    return best;
  }
  long maximin_vertices = 0;  // vertices given the maximin direction (edge_fields)

  // ── 3. edge fields ──
  void edge_fields() {
    for (int e = 0; e < ne; ++e) {
      EdgeInfo& I = E[e];
      if (I.kind == EdgeKind::none) continue;
      std::vector<int> wf = {I.a};
      if (I.kind == EdgeKind::wall_wall) wf.push_back(I.b);
      std::sort(wf.begin(), wf.end());
      const std::size_t n = I.t.size();
      I.th.resize(n);
      for (std::size_t k = 0; k < n; ++k) I.th[k] = thickness_at(I.p[k], wf);
      if (I.kind == EdgeKind::seam) {
        I.sides = {I.a};
        for (std::size_t k = 0; k < n; ++k) I.dir[I.a].push_back(I.nu[k][I.a]);
      } else if (I.kind == EdgeKind::wall_other) {
        I.sides = {I.a};
        for (std::size_t k = 0; k < n; ++k) {
          Vec3 na = I.nu[k][I.a];
          Vec3 pr = mul(I.mb[k], dot(na, I.mb[k]));  // the fluid normal projected on B's tangent plane
          I.dir[I.a].push_back(norm(pr) > 0.2 ? unit(pr) : na);
        }
      } else if (I.junction) {
        I.sides = wf;
        for (std::size_t k = 0; k < n; ++k) {
          I.dir[I.a].push_back(I.mb[k]);
          I.dir[I.b].push_back(I.ma[k]);
        }
      } else {
        I.sides = {wf[0]};
        for (std::size_t k = 0; k < n; ++k) I.dir[wf[0]].push_back(unit(add(I.nu[k][I.a], I.nu[k][I.b])));
      }
    }
    // vertices: mean of the edges' end values, projected on the non-wall faces there
    v_has.assign(nv, 0);
    v_t.assign(nv, INFINITY);
    v_d.assign(nv, Vec3{0, 0, 0});
    std::vector<std::vector<Vec3>> other_normals(nv), wall_normals(nv);
    std::vector<char> averaged_concave(nv, 0);  // a concave wall|wall edge without a block ends here
    maximin_vertices = 0;
    for (int e = 0; e < ne; ++e) {
      EdgeInfo& I = E[e];
      if (I.kind == EdgeKind::none) continue;
      for (int end = 0; end < 2; ++end) {
        int v = end ? I.v1 : I.v0;
        if (v < 0) continue;
        std::size_t k = end ? I.t.size() - 1 : 0;
        v_has[v] = 1;
        v_t[v] = std::min(v_t[v], I.th[k]);
        for (auto& [f, d] : I.dir) v_d[v] = add(v_d[v], d[k]);
        if (I.kind == EdgeKind::wall_other) other_normals[v].push_back(I.nu[k][I.b]);
        for (auto& [f, n] : I.nu[k])
          if (wall[f]) wall_normals[v].push_back(n);
        if (I.kind == EdgeKind::wall_wall && I.concave && !I.junction) averaged_concave[v] = 1;
      }
    }
    for (int v = 0; v < nv; ++v) {
      if (!v_has[v]) continue;
      Vec3 d = unit(v_d[v]);
      // A vertex of an acute concave corner without junction blocks (DLR-F6: where the pylon's
      // averaged chain meets the wing's spanwise panels, fluid angle 51 degrees): the mean of
      // the edge values leans towards the side with more edges there (two wing faces, one pylon
      // face) and is almost tangent to the pylon (0.06 of the way out), so the pylon's prisms
      // at the vertex fold whatever their height. There the direction that is furthest from
      // every wall face's tangent plane (max over d of min_f d.n_f) is used instead, when the
      // mean is less than half as far out as it. Only where a concave wall|wall edge without a
      // block ends (elsewhere the mean has served every shell so far).
      if (double qm = 0; averaged_concave[v] && !wall_normals[v].empty()) {
        auto best = maximin_direction(wall_normals[v], qm);
        if (qm > 0 && min_dot(d, wall_normals[v]) < 0.5 * qm) d = best, ++maximin_vertices;
      }
      for (int it = 0; it < 3; ++it)
        for (auto& n : other_normals[v]) d = unit(sub(d, mul(n, dot(d, n))));
      v_d[v] = d;
    }
    // A vertex that is no corner: where a closed edge passes through its own vertex (both ends
    // there, each side's direction the same at both ends) and the only other edges there are
    // seams — Rotor 67's blade root and tip, whose vertex sits where the blade's seam runs up its
    // leading edge. The mean of the end values is no direction of the wall there (it mixes the
    // junction's two sides), and blending the edges towards it over blend_length thicknesses
    // turns the directions round a nose far thinner than the layer, so the prisms there cross.
    // So the closed edge is not blended there, and a seam ending there is blended towards the
    // closed edge's value on the seam's face.
    std::vector<int> through(nv, -1);  // vertex -> the closed edge passing through it
    {
      std::vector<std::vector<int>> at(nv);
      for (int e = 0; e < ne; ++e)
        if (E[e].kind != EdgeKind::none && E[e].kind != EdgeKind::seam)
          for (int v : {E[e].v0, E[e].v1})
            if (v >= 0 && (at[v].empty() || at[v].back() != e)) at[v].push_back(e);
      for (int v = 0; v < nv; ++v) {
        if (at[v].size() != 1) continue;
        const EdgeInfo& I = E[at[v][0]];
        if (I.v0 != v || I.v1 != v) continue;
        bool same = true;
        for (auto& [f, d] : I.dir) same = same && dot(d.front(), d.back()) > std::cos(10 * M_PI / 180);
        if (same) through[v] = at[v][0];
      }
    }
    // blend the edge fields into the vertex values near their ends
    for (int e = 0; e < ne; ++e) {
      EdgeInfo& I = E[e];
      if (I.kind == EdgeKind::none) continue;
      const std::size_t n = I.t.size();
      double L = I.arc.back();
      for (int end = 0; end < 2; ++end) {
        int v = end ? I.v1 : I.v0;
        if (v < 0 || !v_has[v]) continue;
        if (through[v] == e) continue;
        Vec3 target = v_d[v];
        if (through[v] >= 0 && I.kind == EdgeKind::seam) {
          const EdgeInfo& C = E[through[v]];
          auto it = C.dir.find(I.a);
          if (it != C.dir.end()) {
            // the closed edge's value at the station nearest the seam's end
            Vec3 q = end ? I.p.back() : I.p.front();
            std::size_t kb = 0;
            for (std::size_t k = 1; k < C.p.size(); ++k)
              if (norm(sub(C.p[k], q)) < norm(sub(C.p[kb], q))) kb = k;
            target = it->second[kb];
          }
        }
        // within at most 30% of the edge from each end: on a short edge (the 0.004-long
        // trailing-edge arc of a rounded tip) the middle keeps its own averaged normal
        double R = std::min(blend * v_t[v], 0.3 * L);
        for (std::size_t k = 0; k < n; ++k) {
          double a = end ? L - I.arc[k] : I.arc[k];
          double beta = R > 0 ? smoothstep(1 - a / R) : (a == 0 ? 1.0 : 0.0);
          if (a == 0) beta = 1;
          if (beta <= 0) continue;
          for (auto& [f, d] : I.dir) d[k] = unit(add(mul(d[k], 1 - beta), mul(target, beta)));
          if (a == 0) I.th[k] = v_t[v];
        }
      }
    }
  }

  // ── 4. face grids ──
  // the face's edges with their side values (for the blended direction of node_direction)
  struct Near {
    const EdgeInfo* I;
    const std::vector<Vec3>* d;
  };
  std::vector<Near> near_edges(int f) const {
    std::vector<Near> edges;
    for (int e : shape.face_edges(f)) {
      const EdgeInfo& I = E[e];
      if (I.kind == EdgeKind::none || I.kind == EdgeKind::seam) continue;
      auto it = I.dir.find(f);
      if (it == I.dir.end()) it = I.dir.begin();
      edges.push_back({&I, &it->second});
    }
    return edges;
  }
  // the shell direction at (u,v) (at x) of face f, as a grid node of face_grids has it
  Vec3 node_direction(int f, double u, double v, const Vec3& x, const std::vector<Near>& edges) const {
    Vec3 nrm = fluid_normal(f, u, v);
    // d = R(n): the node's own normal turned by the blended rotation of the nearby edges.
    // Edge e contributes the rotation vector r_e that turns the face's own normal n_e at the
    // foot point into the edge value d_e, weighted by beta_e w_e / sum w (inverse-distance
    // weights, so that at an edge its own rotation wins and d = d_e there). A rotation,
    // not a direction, is blended: a tangent-continuous edge (d_e = n_e) adds nothing,
    // and where two edges' directions nearly cancel (near the pole of a round tip) the
    // node keeps its own normal instead of an arbitrary mean.
    Vec3 de{0, 0, 0};
    double wsum = 0;
    for (auto& ne_ : edges) {
      const EdgeInfo& I = *ne_.I;
      // nearest point of the station polyline
      double best = INFINITY;
      std::size_t bk = 0;
      double bs = 0;
      for (std::size_t k = 0; k + 1 < I.p.size(); ++k) {
        Vec3 a = I.p[k], ab = sub(I.p[k + 1], a);
        double l2 = dot(ab, ab);
        double s = l2 > 0 ? std::clamp(dot(sub(x, a), ab) / l2, 0.0, 1.0) : 0.0;
        double dd = norm(sub(x, add(a, mul(ab, s))));
        if (dd < best) best = dd, bk = k, bs = s;
      }
      double te = (1 - bs) * I.th[bk] + bs * I.th[bk + 1];
      double R = blend * std::max(te, 1e-300);
      if ((I.junction ? std::max(0.0, best - te) : best) >= R) continue;
      // The distance along the face, not through space: the length of the straight (u,v)
      // path to the foot point. Across a thin feature (the upper and lower surfaces of a
      // trailing edge in one face) the 3D distance is small but the path is long, and
      // blending the far side's edge direction would turn the shell sideways.
      const auto& uva = I.uv[bk].at(f);
      const auto& uvb = I.uv[bk + 1].at(f);
      double path = surface_path(f, u, v, (1 - bs) * uva.u + bs * uvb.u, (1 - bs) * uva.v + bs * uvb.v, x);
      best = std::max(best, path);
      Vec3 dk = unit(add(mul((*ne_.d)[bk], 1 - bs), mul((*ne_.d)[bk + 1], bs)));
      double dist = I.junction ? std::max(0.0, best - te) : best;
      double beta = smoothstep(1 - dist / R);
      if (beta <= 0) continue;
      Vec3 nk = unit(add(mul(I.nu[bk].at(f), 1 - bs), mul(I.nu[bk + 1].at(f), bs)));
      Vec3 ax = cross(nk, dk);
      double sn = norm(ax), ang = std::atan2(sn, dot(nk, dk));
      double b2 = best * best + 1e-12 * h * h, w = 1 / (b2 * b2);
      if (sn > 1e-12) de = add(de, mul(ax, beta * w * ang / sn));
      wsum += w;
    }
    Vec3 d = nrm;
    if (wsum > 0) {
      Vec3 rv = mul(de, 1 / wsum);
      double th = norm(rv);
      if (th > 1e-12) {  // Rodrigues
        Vec3 k = mul(rv, 1 / th);
        d = unit(add(add(mul(nrm, std::cos(th)), mul(cross(k, nrm), std::sin(th))), mul(k, dot(k, nrm) * (1 - std::cos(th)))));
      }
    }
    return d;
  }

  void face_grids() {
    int done = 0, nw = 0;
    for (int f = 0; f < nf; ++f) nw += wall[f];
    for (int f = 0; f < nf; ++f) {
      if (!wall[f]) continue;
      ctx.progress(0.3 + 0.4 * done++ / std::max(nw, 1), "field grid of face " + std::to_string(f));
      auto b = shape.face_uv_bounds(f);
      // 3D extents along u and v
      double Lu = 0, Lv = 0;
      for (int s = 0; s < 3; ++s) {
        double vv = b.v0 + (b.v1 - b.v0) * (s + 0.5) / 3, uu = b.u0 + (b.u1 - b.u0) * (s + 0.5) / 3, lu = 0, lv = 0;
        Vec3 pu = v3(shape.face_point(f, b.u0, vv)), pv = v3(shape.face_point(f, uu, b.v0));
        for (int k = 1; k <= 32; ++k) {
          Vec3 qu = v3(shape.face_point(f, b.u0 + (b.u1 - b.u0) * k / 32, vv));
          Vec3 qv = v3(shape.face_point(f, uu, b.v0 + (b.v1 - b.v0) * k / 32));
          lu += norm(sub(qu, pu)), lv += norm(sub(qv, pv));
          pu = qu, pv = qv;
        }
        Lu = std::max(Lu, lu), Lv = std::max(Lv, lv);
      }
      FaceGrid G;
      G.face = f, G.u0 = b.u0, G.u1 = b.u1, G.v0 = b.v0, G.v1 = b.v1;
      G.nu = std::clamp(static_cast<int>(std::ceil(Lu / h)) + 1, std::min(9, max_grid), max_grid);
      G.nv = std::clamp(static_cast<int>(std::ceil(Lv / h)) + 1, std::min(9, max_grid), max_grid);
      G.data.resize(std::size_t(G.nu) * G.nv * 4);
      const auto edges = near_edges(f);
      for (int j = 0; j < G.nv; ++j)
        for (int i = 0; i < G.nu; ++i) {
          double u = G.u0 + (G.u1 - G.u0) * i / (G.nu - 1), v = G.v0 + (G.v1 - G.v0) * j / (G.nv - 1);
          Vec3 x = v3(shape.face_point(f, u, v));
          double t = thickness_at(x, {f});
          Vec3 d = node_direction(f, u, v, x, edges);
          double* q = &G.data[(std::size_t(j) * G.nu + i) * 4];
          q[0] = t, q[1] = d[0], q[2] = d[1], q[3] = d[2];
        }
      lipschitz_grid(f, G);
      grids[f] = std::move(G);
    }
  }

  // 3D length of the straight (u,v) segment from (u0,v0) (at x0) to (u1,v1) on face f, 8 chords
  double surface_path(int f, double u0, double v0, double u1, double v1, const Vec3& x0) const {
    double len = 0;
    Vec3 prev = x0;
    for (int k = 1; k <= 8; ++k) {
      double s = k / 8.0;
      Vec3 q = v3(shape.face_point(f, u0 + s * (u1 - u0), v0 + s * (v1 - v0)));
      len += norm(sub(q, prev));
      prev = q;
    }
    return len;
  }

  // t_i <= t_j + g |x_i - x_j| between 8-neighbours of the grid (forward/backward sweeps):
  // the thickness evaluated from a finite set of nearby samples is not exactly Lipschitz
  // where the candidate set changes; this makes the tabulated field so
  void lipschitz_grid(int f, FaceGrid& G) const {
    std::vector<Vec3> X(std::size_t(G.nu) * G.nv);
    for (int j = 0; j < G.nv; ++j)
      for (int i = 0; i < G.nu; ++i)
        X[std::size_t(j) * G.nu + i] = v3(shape.face_point(f, G.u0 + (G.u1 - G.u0) * i / (G.nu - 1), G.v0 + (G.v1 - G.v0) * j / (G.nv - 1)));
    auto relax = [&](int i, int j, int di, int dj) {
      int a = i + di, b = j + dj;
      if (a < 0 || b < 0 || a >= G.nu || b >= G.nv) return false;
      std::size_t p = std::size_t(j) * G.nu + i, q = std::size_t(b) * G.nu + a;
      double lim = G.data[q * 4] + grad * norm(sub(X[p], X[q]));
      if (lim < G.data[p * 4] * (1 - 1e-14)) {
        G.data[p * 4] = lim;
        return true;
      }
      return false;
    };
    for (int it = 0; it < 20; ++it) {
      bool ch = false;
      for (int j = 0; j < G.nv; ++j)
        for (int i = 0; i < G.nu; ++i)
          for (auto [di, dj] : {std::pair{-1, 0}, {0, -1}, {-1, -1}, {1, -1}}) ch |= relax(i, j, di, dj);
      for (int j = G.nv - 1; j >= 0; --j)
        for (int i = G.nu - 1; i >= 0; --i)
          for (auto [di, dj] : {std::pair{1, 0}, {0, 1}, {1, 1}, {-1, 1}}) ch |= relax(i, j, di, dj);
      if (!ch) break;
    }
  }

  // The face field at (u,v) as sweep evaluates it (shell::grid_field_on), so that the sampled
  // surface and the junction corners PC are the shell sweep builds (Rotor 67: with the plain
  // bilinear field, (u,v) on the hub outside the grid's period got the grid's last column and
  // the root strip's corners PC on the blade's negative-angle side, 0.01 off their place, folded
  // into the hub's and blade's shells: the junction crossings at the hub).
  std::pair<double, Vec3> grid_at(int f, double u, double v) const { return grid_field_on(grids.at(f), shape, u, v); }

  // A junction block's cross-section at station k of edge e: PA on A and PB on B at the
  // edge's thickness w along m_A / m_B (projected on the faces), the outer corner PC = PA's
  // shell image by A's field. Memoised: blocks() and the sampled surface use the same points.
  struct StripStation {
    Vec3 PA, PB, PC;
    std::array<double, 2> uvA, uvB;
  };
  std::map<std::pair<int, int>, StripStation> strip_memo;
  // A closed junction edge round a wrapped face X (both ends at one vertex on a seam of X:
  // Rotor 67's blade root and tip, the blade's seam up its leading edge). The leading and
  // trailing edges are far thinner than a strip width and the blade leans: the stations near the
  // nose, offset in 3D along m_X and projected, land on either side of the seam in scrambled
  // order (the root's PB: u 0.0006, 0.0011, 0.0002, 0.9984 for the first four stations), the
  // strip boundary folds in (u,v), the face's loop is trimmed there and the sampled shell
  // leaves the nose's corner points out (the crossings round the root's leading edge), and the
  // corner PC of the tip (PA on the blade) is the field at a folded PA. As sweep does
  // (sweep.cpp, build_junction_curves: "Strip boundaries next to a seam", L infinite), the strip
  // boundary on X is then the edge's p-curve offset across itself by the station's own offset
  // (the projection's (u,v) offset without its component along the p-curve), monotone along the
  // edge like the edge itself.
  bool closed_round_seam(int e, int X) const {
    const EdgeInfo& I = E[e];
    if (I.v0 < 0 || I.v0 != I.v1) return false;
    for (int s : face_edges_cache[X])
      if (shape.edge_is_seam(s, X)) {
        auto vs = shape.edge_vertices(s);
        if (vs[0] == I.v0 || vs[1] == I.v0) return true;
      }
    return false;
  }
  // A station of a seam of X closer to the vertex than the end of a closed junction's strip
  // boundary there (see closed_round_seam): that end lies on the seam, one strip width up it, and
  // the seam's stations below it are inside the strip, whose image is the junction hex, not
  // shell (as sweep cuts the seam at the end's corner). Kept in the loop they made a spike down
  // the seam and back whose triangles crossed the hub's shell round the nose (Rotor 67's root).
  bool in_seam_strip(int X, int seam, const Vec3& p) {
    if (!shape.edge_is_seam(seam, X)) return false;
    auto vs = shape.edge_vertices(seam);
    for (int je : face_edges_cache[X]) {
      const EdgeInfo& J = E[je];
      if (!(J.junction && J.kind == EdgeKind::wall_wall) || J.t.empty() || !closed_round_seam(je, X)) continue;
      if (vs[0] != J.v0 && vs[1] != J.v0) continue;
      StripStation q = strip_station(je, 0);
      const Vec3& Q = X == J.a ? q.PA : q.PB;
      if (norm(sub(p, J.p.front())) < norm(sub(Q, J.p.front()))) return true;
    }
    return false;
  }
  std::array<double, 2> across_pcurve(int e, int X, double t, std::array<double, 2> uv) const {
    auto eu = shape.edge_uv(e, X, t, false);
    auto per = shape.face_periods(X);
    const double target[2] = {eu.u, eu.v};
    for (int c = 0; c < 2; ++c)
      if (per[c] > 0) uv[c] += per[c] * std::round((target[c] - uv[c]) / per[c]);
    auto r = shape.edge_range(e);
    double dt = 1e-4 * (r.hi - r.lo);
    auto e1 = shape.edge_uv(e, X, t + dt, false), e0 = shape.edge_uv(e, X, t - dt, false);
    double tu = e1.u - e0.u, tv = e1.v - e0.v, tl = std::hypot(tu, tv);
    if (!(tl > 0)) return uv;
    double nu = -tv / tl, nv = tu / tl;
    double off = (uv[0] - eu.u) * nu + (uv[1] - eu.v) * nv;
    return {eu.u + off * nu, eu.v + off * nv};
  }
  StripStation strip_station(int e, int k) {
    auto key = std::make_pair(e, k);
    auto it = strip_memo.find(key);
    if (it != strip_memo.end()) return it->second;
    const EdgeInfo& I = E[e];
    double w = I.th[k];
    Vec3 P0 = I.p[k];
    auto pa = shape.project_to_face(I.a, cv(add(P0, mul(I.ma[k], w))), I.uv[k].at(I.a));
    auto pb = shape.project_to_face(I.b, cv(add(P0, mul(I.mb[k], w))), I.uv[k].at(I.b));
    for (auto [X, pr] : {std::pair{I.a, &pa}, std::pair{I.b, &pb}})
      if (closed_round_seam(e, X)) {
        auto uv = across_pcurve(e, X, I.t[k], {pr->u, pr->v});
        pr->u = uv[0], pr->v = uv[1];
        pr->point = shape.face_point(X, uv[0], uv[1]);
      }
    auto [ta, da] = grid_at(I.a, pa.u, pa.v);
    StripStation q;
    q.PA = v3(pa.point), q.PB = v3(pb.point);
    q.PC = add(q.PA, mul(da, ta));
    q.uvA = {pa.u, pa.v}, q.uvB = {pb.u, pb.v};
    strip_memo[key] = q;
    return q;
  }

  // true when no two segments of the loops touch except consecutive ones at their shared end
  // (orientation predicates in doubles; O(n^2), loops have at most a few thousand points)
  static bool simple_loops(const std::vector<std::array<double, 2>>& p, const std::vector<std::array<std::int32_t, 2>>& seg,
                           int* bad_i = nullptr, int* bad_j = nullptr) {
    auto fail = [&](std::size_t i, std::size_t j) {
      if (bad_i) *bad_i = static_cast<int>(i), *bad_j = static_cast<int>(j);
      return false;
    };
    auto orient = [&](int a, int b, int c) {
      double d = (p[b][0] - p[a][0]) * (p[c][1] - p[a][1]) - (p[b][1] - p[a][1]) * (p[c][0] - p[a][0]);
      return (d > 0) - (d < 0);
    };
    auto on = [&](int a, int b, int c) {  // c on the closed segment ab, given collinear
      return std::min(p[a][0], p[b][0]) <= p[c][0] && p[c][0] <= std::max(p[a][0], p[b][0]) &&
             std::min(p[a][1], p[b][1]) <= p[c][1] && p[c][1] <= std::max(p[a][1], p[b][1]);
    };
    for (std::size_t i = 0; i < seg.size(); ++i) {
      auto [a, b] = seg[i];
      if (p[a] == p[b]) return fail(i, i);
      for (std::size_t j = i + 1; j < seg.size(); ++j) {
        auto [c, d] = seg[j];
        bool adj = a == c || a == d || b == c || b == d;
        if (adj) {
          // consecutive segments: only a fold back onto the previous one is a defect
          int s = (b == c) ? a : (a == d) ? b : -1, t = (b == c) ? d : (a == d) ? c : -1, m = (b == c) ? b : (a == d) ? a : -1;
          if (s >= 0 && orient(s, m, t) == 0) {
            double dx1 = p[m][0] - p[s][0], dy1 = p[m][1] - p[s][1], dx2 = p[t][0] - p[m][0], dy2 = p[t][1] - p[m][1];
            if (dx1 * dx2 + dy1 * dy2 < 0) return fail(i, j);
          }
          continue;
        }
        int o1 = orient(a, b, c), o2 = orient(a, b, d), o3 = orient(c, d, a), o4 = orient(c, d, b);
        if (o1 != o2 && o3 != o4) return fail(i, j);
        if ((o1 == 0 && on(a, b, c)) || (o2 == 0 && on(a, b, d)) || (o3 == 0 && on(c, d, a)) || (o4 == 0 && on(c, d, b)))
          return fail(i, j);
      }
    }
    return true;
  }

  // Trims the local loops of a boundary loop (points [first, end) of uv/gid) in (u,v): where the
  // strip curves of two junction edges meeting at a corner of the face (or a strip curve and the
  // next edge) cross, like the offsets of two sides of a polygon, the part between the two
  // crossing segments (at most 64 segments or half the loop) is cut off and the crossing point
  // (gid -1: its shell image comes from the face grid) takes its place.
  static void trim_loop(std::vector<std::array<double, 2>>& uv, std::vector<int>& gid, std::size_t first) {
    std::vector<std::array<double, 2>> P(uv.begin() + static_cast<long>(first), uv.end());
    std::vector<int> G(gid.begin() + static_cast<long>(first), gid.end());
    auto cross2 = [](std::array<double, 2> a, std::array<double, 2> b, std::array<double, 2> c) {
      return (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]);
    };
    for (int guard = 0; guard < 10000 && P.size() > 4; ++guard) {
      const std::size_t m = P.size(), W = std::min<std::size_t>(m / 2, 64);
      bool changed = false;
      for (std::size_t i = 0; i < m && !changed; ++i) {
        const auto &a = P[i], &b = P[(i + 1) % m];
        for (std::size_t d = 2; d <= W && !changed; ++d) {
          std::size_t j = (i + d) % m;
          if ((j + 1) % m == i) continue;
          const auto &c = P[j], &e = P[(j + 1) % m];
          double d1 = cross2(a, b, c), d2 = cross2(a, b, e), d3 = cross2(c, e, a), d4 = cross2(c, e, b);
          // crossing or touching (an end on the other segment), not collinear
          if (d1 * d2 > 0 || d3 * d4 > 0 || d1 == d2 || d3 == d4) continue;
          double t = std::clamp(d3 / (d3 - d4), 0.0, 1.0);  // along a -> b
          std::array<double, 2> X{a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])};
          std::vector<std::array<double, 2>> Q;
          std::vector<int> H;
          for (std::size_t k = (j + 1) % m;; k = (k + 1) % m) {  // j+1 .. i, then X
            Q.push_back(P[k]), H.push_back(G[k]);
            if (k == i) break;
          }
          Q.push_back(X), H.push_back(-1);
          P.swap(Q), G.swap(H);
          changed = true;
        }
      }
      if (!changed) break;
    }
    uv.resize(first), gid.resize(first);
    uv.insert(uv.end(), P.begin(), P.end());
    gid.insert(gid.end(), G.begin(), G.end());
  }

  // ── 5. sampled shell surface ──
  ShellData out;
  long faces_unsampled = 0;
  std::vector<std::string> unsampled_why;
  std::vector<std::vector<int>> point_faces;  // non-wall faces each shell point slides on
  std::vector<Vec3> point_source;             // the wall point whose thickness sets each offset
  std::vector<int> strip_fallback;            // faces sampled over their junction strips (loop not simple)
  static constexpr double kSag = 0.1;         // sampled-surface chord sag, x the face's least thickness
  static constexpr int kMaxRefine = 8;
  std::vector<std::array<int, 3>> refined_faces;  // (face, ru, rv) sampled finer than their grid
  static constexpr int kSagRounds = 6;
  static constexpr int kResamplePasses = 3;
  std::vector<char> lattice_bare;  // per face: no lattice point inside, no junction strip (sample_surface)
  std::set<int> resample_faces;    // bare faces sampled from the field at the points (see run)
  long resampled_points = 0;
  void sample_surface() {
    // ids: vertex -> id, (edge, station, side) -> id
    std::map<int, int> vid;
    std::map<std::tuple<int, int, int>, int> eid;
    // src: the wall point whose thickness sets this point's offset (a strip point PC: the edge
    // station P0, whose thickness is the strip's width), for the thinning of crossings
    auto add_point = [&](Vec3 wallp, Vec3 shellp, std::vector<int> slide, const Vec3* src = nullptr) {
      out.shell_wall.push_back(wallp);
      out.shell_points.push_back(shellp);
      point_faces.push_back(std::move(slide));
      point_source.push_back(src ? *src : wallp);
      return static_cast<int>(out.shell_points.size() - 1);
    };
    auto vertex_id = [&](int v) {
      auto it = vid.find(v);
      if (it != vid.end()) return it->second;
      Vec3 x = v3(shape.vertex_point(v));
      std::vector<int> slide;
      for (int e = 0; e < ne; ++e)
        if (E[e].kind == EdgeKind::wall_other && (E[e].v0 == v || E[e].v1 == v)) slide.push_back(E[e].b);
      int id = add_point(x, add(x, mul(v_d[v], v_t[v])), slide);
      vid[v] = id;
      return id;
    };
    auto station_id = [&](int e, int k, int f) {
      const EdgeInfo& I = E[e];
      int n = static_cast<int>(I.t.size());
      if (k == 0 && I.v0 >= 0 && v_has[I.v0]) return vertex_id(I.v0);
      if (k == n - 1 && I.v1 >= 0 && v_has[I.v1]) return vertex_id(I.v1);
      int side = I.dir.count(f) ? f : I.dir.begin()->first;
      auto key = std::make_tuple(e, k, side);
      auto it = eid.find(key);
      if (it != eid.end()) return it->second;
      std::vector<int> slide;
      if (I.kind == EdgeKind::wall_other) slide.push_back(I.b);
      int id = add_point(I.p[k], add(I.p[k], mul(I.dir.at(side)[k], I.th[k])), slide);
      eid[key] = id;
      return id;
    };
    // the strip boundary of a wall|wall junction: one shell point PC per station, shared by A and B
    std::map<std::pair<int, int>, int> sid;
    // Ends: every wall|wall junction ending at a vertex shares one corner point there, the mean
    // of their PC (and PA) at that end, as sweep shares one cross-section per vertex: the strips
    // of consecutive junction edges (a pylon's faces along a wing) and the faces B between them
    // then close at one point instead of overlapping around it.
    std::map<int, std::pair<Vec3, Vec3>> end_sum;  // vertex -> (sum PA, sum PC)
    std::map<int, int> end_count, end_id;
    for (int e = 0; e < ne; ++e) {
      const EdgeInfo& I = E[e];
      if (!(I.junction && I.kind == EdgeKind::wall_wall) || I.t.empty()) continue;
      for (int end = 0; end < 2; ++end) {
        int v = end ? I.v1 : I.v0;
        if (v < 0) continue;
        StripStation q = strip_station(e, end ? static_cast<int>(I.t.size()) - 1 : 0);
        auto& sum = end_sum[v];
        sum.first = add(sum.first, q.PA), sum.second = add(sum.second, q.PC);
        ++end_count[v];
      }
    }
    auto strip_id = [&](int e, int k) {
      const EdgeInfo& I = E[e];
      int n = static_cast<int>(I.t.size());
      int v = k == 0 ? I.v0 : k == n - 1 ? I.v1 : -1;
      if (v >= 0 && end_count.count(v)) {
        auto it = end_id.find(v);
        if (it != end_id.end()) return it->second;
        double c = 1.0 / end_count[v];
        const Vec3 src = k == 0 ? I.p.front() : I.p.back();
        int id = add_point(mul(end_sum[v].first, c), mul(end_sum[v].second, c), {}, &src);
        end_id[v] = id;
        return id;
      }
      auto key = std::make_pair(e, k);
      auto it = sid.find(key);
      if (it != sid.end()) return it->second;
      StripStation q = strip_station(e, k);
      int id = add_point(q.PA, q.PC, {}, &I.p[k]);
      sid[key] = id;
      return id;
    };
    std::vector<char> strips_used(nf, 0);
    lattice_bare.assign(nf, 0);
    for (int f = 0; f < nf; ++f) {
      if (!wall[f]) continue;
      const FaceGrid& G = grids.at(f);
      std::vector<std::array<double, 2>> uv;
      std::vector<int> gid;  // global point id of each uv point (-1: not yet)
      std::vector<std::array<std::int32_t, 2>> seg;
      std::vector<std::vector<std::array<double, 2>>> loops;
      std::vector<Vec3> bpts;
      bool ok = true;
      // Wall|wall junctions (topology C): the face is sampled outside its junction strip, whose
      // boundary (PA on A, PB on B) maps to the block's outer corner PC; the strip's image is
      // the junction hex's face, inside the near field, not shell. (Sampling the strip too put
      // the hex's two inner faces into the shell twice, once from each side, and they cross.)
      // Where that boundary loop is not simple in (u,v) (a partner face narrower than the strip:
      // a blunt trailing edge) the face falls back to its own edges and the crack is closed below.
      bool use_strips = false;
      for (int e : face_edges_cache[f])
        if (E[e].junction && E[e].kind == EdgeKind::wall_wall) use_strips = true;
    for (;;) {  // at most twice: with strips, then (not simple) without
      uv.clear(), gid.clear(), seg.clear(), loops.clear(), bpts.clear();
      ok = true;
      for (auto& wire : shape.face_wires(f)) {
        std::vector<std::array<double, 2>> loop;
        int first = static_cast<int>(uv.size());
        const std::size_t gid0 = gid.size(), bp0 = bpts.size();
        const auto perw = shape.face_periods(f);
        bool after_strip = false, after_pole = false;
        // A wrapped face whose two closed edges run the same way round (Rotor 67's blade: hub
        // and casing both u 1 -> 0, the seam up at u = 1 and down at u = 0) gives a chain that
        // ends two periods from its start; as sweep does (sweep.cpp, "A wire closes in the
        // plane"), the wire is then built again with its first closed edge the other way round
        for (int flip_at = -1; flip_at < static_cast<int>(wire.size()); ++flip_at) {
        if (flip_at >= 0) {
          int e = wire[flip_at].edge;
          auto vs = shape.edge_vertices(e);
          if (shape.edge_degenerate(e) || shape.edge_is_seam(e, f) || vs[0] != vs[1]) continue;
          uv.resize(first), gid.resize(gid0), bpts.resize(bp0), loop.clear();
          after_strip = false, after_pole = false;
          ok = true;
        }
        // On a periodic face (a blade lofted round its section: u periodic, one seam) the (u,v)
        // of consecutive pieces of the loop may sit a period apart: a closed edge's p-curve can
        // start at u = 1 where the seam's p-curve before it ends at u = 0 (Rotor 67's blade, whose
        // loop then crossed the whole face and its triangulation failed), and strip stations are
        // projections. Each piece (an edge's stations, a strip, a pole) is therefore unwrapped:
        // its points nearest to each other, the piece nearest to the loop's last point; the
        // whole loop is then moved by whole periods so that its mean lies in the face's box.
        const auto per = shape.face_periods(f);
        // (only jumps beyond 3/4 of a period, cad::Shape::unwrap_towards as in sweep; nothing is
        // moved after a pole, whose p-curve may span half a period)
        auto near_to = [&](std::array<double, 2> x, std::array<double, 2> ref) {
          for (int c = 0; c < 2; ++c) x[c] = cad::Shape::unwrap_towards(x[c], ref[c], per[c]);
          return x;
        };
        auto append = [&](std::vector<std::array<double, 2>>& piece, bool pole = false) {
          for (std::size_t i = 1; i < piece.size(); ++i) piece[i] = near_to(piece[i], piece[i - 1]);
          const bool shift = !after_pole;
          after_pole = pole;
          if (shift && !piece.empty() && !loop.empty()) {
            auto x = near_to(piece.front(), loop.back());
            double du = x[0] - piece.front()[0], dv = x[1] - piece.front()[1];
            for (auto& q : piece) q[0] += du, q[1] += dv;
          }
          for (auto& q : piece) uv.push_back(q), loop.push_back(q);
        };
        std::vector<std::array<double, 2>> piece;
        for (auto& eu0 : wire) {
          const bool flipped = flip_at >= 0 && &eu0 == &wire[flip_at];
          const cad::EdgeUse eu{eu0.edge, flipped ? !eu0.reversed : eu0.reversed};
          int e = eu.edge;
          piece.clear();
          if (use_strips && E[e].junction && E[e].kind == EdgeKind::wall_wall) {
            const EdgeInfo& I = E[e];
            int n = static_cast<int>(I.t.size());
            for (int s = 0; s < n; ++s) {
              int k = eu.reversed ? n - 1 - s : s;
              StripStation q = strip_station(e, k);
              bool onA = f == I.a;
              piece.push_back(onA ? q.uvA : q.uvB);
              gid.push_back(strip_id(e, k));
              bpts.push_back(onA ? q.PA : q.PB);
            }
            append(piece);
            after_strip = true;
            continue;
          }
          bool skip_first = after_strip;  // the vertex between a strip's end and this edge
          after_strip = false;
          if (shape.edge_degenerate(e)) {
            // a pole: the p-curve's end points, both the vertex
            auto r = shape.edge_range(e);
            auto vs = shape.edge_vertices(e);
            cad::Vec2 q = shape.edge_uv(e, f, eu.reversed ? r.hi : r.lo, eu.reversed);
            if (vs[0] < 0 || !v_has[vs[0]]) { ok = false; break; }
            piece.push_back({q.u, q.v});
            gid.push_back(vertex_id(vs[0]));
            append(piece, true);
            continue;
          }
          const EdgeInfo& I = E[e];
          if (I.kind == EdgeKind::none) { ok = false; break; }
          int n = static_cast<int>(I.t.size());
          for (int s = skip_first ? 1 : 0; s < n - 1; ++s) {
            int k = eu.reversed ? n - 1 - s : s;
            if (use_strips && in_seam_strip(f, e, I.p[k])) continue;
            cad::Vec2 q = shape.edge_uv(e, f, I.t[k], eu.reversed);
            piece.push_back({q.u, q.v});
            gid.push_back(station_id(e, k, f));
            bpts.push_back(I.p[k]);
          }
          append(piece);
        }
        bool closes = true;
        if (ok && loop.size() >= 3)
          for (int c = 0; c < 2; ++c)
            if (cad::Shape::period_jump(loop.front()[c], loop.back()[c], per[c])) closes = false;
        if (closes || !ok) break;
        }
        if (ok && (perw[0] > 0 || perw[1] > 0) && !loop.empty()) {
          const auto bnd = shape.face_uv_bounds(f);
          double mu = 0, mv = 0;
          for (auto& q : loop) mu += q[0], mv += q[1];
          mu /= double(loop.size()), mv /= double(loop.size());
          double du = perw[0] > 0 ? -perw[0] * std::floor((mu - bnd.u0) / perw[0]) : 0;
          double dv = perw[1] > 0 ? -perw[1] * std::floor((mv - bnd.v0) / perw[1]) : 0;
          for (std::size_t i = static_cast<std::size_t>(first); i < uv.size(); ++i) uv[i][0] += du, uv[i][1] += dv;
          for (auto& q : loop) q[0] += du, q[1] += dv;
        }
        if (!ok) break;
        // a loop that starts right after a strip: its first edge's vertex is dropped too
        if (after_strip && use_strips && !loop.empty()) {
          auto& eu0 = wire.front();
          const EdgeInfo& I0 = E[eu0.edge];
          if (!shape.edge_degenerate(eu0.edge) && !(I0.junction && I0.kind == EdgeKind::wall_wall)) {
            loop.erase(loop.begin());
            uv.erase(uv.begin() + first), gid.erase(gid.begin() + first);
          }
        }
        if (use_strips) {
          trim_loop(uv, gid, first);
          loop.assign(uv.begin() + first, uv.end());
        }
        int last = static_cast<int>(uv.size());
        for (int i = first; i < last; ++i) seg.push_back({i, i + 1 < last ? i + 1 : first});
        loops.push_back(std::move(loop));
      }
      if (ok && use_strips && std::getenv("MESHFLOW_SHELL_DEBUG")) {
        int a = -1, b = -1;
        simple_loops(uv, seg, &a, &b);
        if (a >= 0)
          ctx.log("shell: face " + std::to_string(f) + " loop of " + std::to_string(uv.size()) + " points not simple: segments " +
                  std::to_string(a) + " (" + std::to_string(seg[a][0]) + "->" + std::to_string(seg[a][1]) + ", gid " +
                  std::to_string(gid[seg[a][0]]) + ") and " + std::to_string(b) + " (" + std::to_string(seg[b][0]) + "->" +
                  std::to_string(seg[b][1]) + ", gid " + std::to_string(gid[seg[b][0]]) + ") at " + fmt(out.shell_wall[gid[seg[a][0]]]));
      }
      if (ok && use_strips && !simple_loops(uv, seg)) {
        use_strips = false;
        strip_fallback.push_back(f);
        continue;
      }
      break;
    }
      strips_used[f] = use_strips;
      if (!ok || loops.empty()) {
        ++faces_unsampled;
        unsampled_why.push_back("face " + std::to_string(f) + ": an edge without a field");
        continue;
      }
      auto inside = [&](double u, double v) {
        bool in = false;
        for (auto& l : loops)
          for (std::size_t i = 0, j = l.size() - 1; i < l.size(); j = i++) {
            auto [ui, vi] = l[i];
            auto [uj, vj] = l[j];
            if ((vi > v) != (vj > v) && u < (uj - ui) * (v - vi) / (vj - vi) + ui) in = !in;
          }
        return in;
      };
      // interior grid nodes inside the face, at least h/2 from the boundary stations
      std::vector<medial::Vec3> bp(bpts.begin(), bpts.end());
      std::unique_ptr<medial::NearestIndex> bidx;
      if (!bp.empty()) bidx = std::make_unique<medial::NearestIndex>(bp);
      const std::size_t nb = uv.size();
      // The sampled surface must follow the shell, not cut through it: a chord of length c on
      // a wall of curvature k sags c^2 k / 8, and where that is a good part of the thickness
      // (DLR-F6's nacelle: 18 mm chords, r = 45 mm, a 0.5 mm layer) triangles of one face's
      // shell pass through each other. So the interior lattice is the field grid refined by
      // (ru, rv) until the sag of a lattice step is at most kSag x the face's least thickness
      // (the field is the grid's bilinear interpolant, so the finer points sample exactly what
      // sweep evaluates). Curvature: the turn of the fluid normal between neighbouring grid
      // nodes inside the face over their distance. Faces with a gentle enough curvature keep
      // the grid itself (ru = rv = 1: their shells keep their bytes).
      int ru = 1, rv = 1;
      {
        std::vector<Vec3> X(std::size_t(G.nu) * G.nv), N(X.size());
        std::vector<char> in(X.size(), 0);
        double tmin = INFINITY;
        for (int j = 0; j < G.nv; ++j)
          for (int i = 0; i < G.nu; ++i) {
            double u = G.u0 + (G.u1 - G.u0) * i / (G.nu - 1), v = G.v0 + (G.v1 - G.v0) * j / (G.nv - 1);
            std::size_t q = std::size_t(j) * G.nu + i;
            if (!(in[q] = inside(u, v))) continue;
            X[q] = v3(shape.face_point(f, u, v)), N[q] = fluid_normal(f, u, v);
            tmin = std::min(tmin, G.data[q * 4]);
          }
        double su = 0, sv = 0;  // largest sag of one grid step along u / v
        for (int j = 0; j < G.nv; ++j)
          for (int i = 0; i < G.nu; ++i) {
            std::size_t q = std::size_t(j) * G.nu + i;
            if (!in[q]) continue;
            for (int dir = 0; dir < 2; ++dir) {
              int a = i + (dir == 0), b = j + (dir == 1);
              if (a >= G.nu || b >= G.nv) continue;
              std::size_t q2 = std::size_t(b) * G.nu + a;
              if (!in[q2]) continue;
              double c = norm(sub(X[q2], X[q]));
              double ang = std::acos(std::clamp(dot(N[q], N[q2]), -1.0, 1.0));
              double sag = c * ang / 8;  // c^2 k / 8 with k = ang / c
              (dir == 0 ? su : sv) = std::max(dir == 0 ? su : sv, sag);
            }
          }
        if (std::isfinite(tmin) && tmin > 0) {
          // refining a step by r divides its sag by r^2
          auto factor = [&](double sag) {
            return std::clamp(static_cast<int>(std::ceil(std::sqrt(sag / (kSag * tmin)) - 1e-9)), 1, kMaxRefine);
          };
          ru = factor(su), rv = factor(sv);
        }
      }
      if (ru > 1 || rv > 1) refined_faces.push_back({f, ru, rv});
      const int Nu = (G.nu - 1) * ru + 1, Nv = (G.nv - 1) * rv + 1;
      const double hmin = std::min(h, std::min((G.u1 - G.u0), (G.v1 - G.v0)) > 0 ? h / std::max(ru, rv) : h);
      for (int j = 1; j + 1 < Nv; ++j)
        for (int i = 1; i + 1 < Nu; ++i) {
          double u = G.u0 + (G.u1 - G.u0) * i / (Nu - 1), v = G.v0 + (G.v1 - G.v0) * j / (Nv - 1);
          if (!inside(u, v)) continue;
          Vec3 x = v3(shape.face_point(f, u, v));
          if (bidx && bidx->nearest(x, 1)[0].second < 0.5 * hmin) continue;
          uv.push_back({u, v});
          gid.push_back(-1);
        }
      std::vector<std::array<std::int32_t, 3>> tris;
      std::vector<int> depth;
      try {
        tris = cdt2(uv, seg, &depth);
      } catch (const std::exception& ex) {
        ++faces_unsampled;
        unsampled_why.push_back("face " + std::to_string(f) + ": " + ex.what());
        continue;
      }
      // Faces the lattice does not reach. The lattice and its refinement above see a face only
      // through its field grid's nodes: a face narrower than a grid cell (DLR-F6's face 80, a
      // sliver along the outer wing to its tip: 0.4 mm wide, 330 mm long, 13 mm cells) has no
      // node inside, every lattice point falls within h/2 of its boundary and is dropped, and
      // the face is triangulated from its boundary stations alone (there the triangulation
      // fanned from one station of a long edge to the short end edge's stations 13 mm away,
      // and that fan's shell cut the tip face's shell at the convex edge between them, at the
      // thinning's floor). On such a face the grid's bilinear interpolant is not the field
      // either: all its nodes lie off the face, and points sampled from it fold against the
      // boundary stations' edge directions (tried: 10 crossings on face 80 instead of 1). So a
      // face in resample_faces (bare, with a crossing the thinning left, see run) is sampled
      // from the field as a grid node has it, at the point itself (thickness_at,
      // node_direction: at an edge its own direction wins, so the points continue the
      // boundary's): every triangle whose shell at its (u,v) centroid sags from the mean of its
      // corners' shell by more than kSag x the least thickness there gets its centroid (inside
      // the triangle, so inside the face), and the face is triangulated again, at most
      // kSagRounds times. Faces sampled outside a junction strip are left out: the strip's
      // boundary maps to the junction block's corner PC, which the face's own field near it
      // does not continue (resampling those too put 50 crossings along DLR-F6's strips).
      const bool bare = uv.size() == nb && !use_strips;
      lattice_bare[f] = bare;
      const bool resample = bare && resample_faces.count(f);
      const auto nedges = near_edges(f);
      // the field at (u,v) as a grid node has it: thickness, direction, and the wall point x
      auto exact_at = [&](double u, double v) {
        Vec3 x = v3(shape.face_point(f, u, v));
        return std::tuple<double, Vec3, Vec3>{thickness_at(x, {f}), node_direction(f, u, v, x, nedges), x};
      };
      if (resample) {
        std::vector<Vec3> S;
        std::vector<double> Th;
        auto shell_at = [&](double u, double v, double* th) {
          auto [t, d, x] = exact_at(u, v);
          *th = t;
          return add(x, mul(d, t));
        };
        for (int round = 0; round < kSagRounds; ++round) {
          while (S.size() < uv.size()) {
            double t = 0;
            S.push_back(shell_at(uv[S.size()][0], uv[S.size()][1], &t));
            Th.push_back(t);
          }
          std::vector<std::array<double, 2>> more;
          for (std::size_t ti = 0; ti < tris.size(); ++ti) {
            if (depth[ti] % 2 == 0) continue;
            const auto& t = tris[ti];
            const double uc = (uv[t[0]][0] + uv[t[1]][0] + uv[t[2]][0]) / 3;
            const double vc = (uv[t[0]][1] + uv[t[1]][1] + uv[t[2]][1]) / 3;
            double tc = 0;
            Vec3 sc = shell_at(uc, vc, &tc);
            Vec3 m = mul(add(add(S[t[0]], S[t[1]]), S[t[2]]), 1.0 / 3);
            double tl = std::min({Th[t[0]], Th[t[1]], Th[t[2]], tc});
            if (tl > 0 && norm(sub(sc, m)) > kSag * tl) more.push_back({uc, vc});
          }
          if (more.empty()) break;
          for (auto& q : more) uv.push_back(q), gid.push_back(-1);
          resampled_points += static_cast<long>(more.size());
          try {
            tris = cdt2(uv, seg, &depth);
          } catch (const std::exception& ex) {
            tris.clear();
            ++faces_unsampled;
            unsampled_why.push_back("face " + std::to_string(f) + ": " + ex.what());
            break;
          }
        }
      }
      for (std::size_t ti = 0; ti < tris.size(); ++ti) {
        const auto& t = tris[ti];
        // Inside the face: odd nesting depth in the CDT (outside the loops or in a hole: even).
        // Not by the centroid in the loops: along an edge whose p-curve is an iso-line (the round
        // tip's edges at u = pi, the blunt trailing edge's root edge) the stations wobble by 1e-8
        // in (u,v), the hull then holds zero-area triangles of three stations of one edge
        // outside the loop, whose centroid lies on the boundary and was taken for inside half
        // the time; in 3D they are real triangles along the edge, lying across the shell's own
        // triangles there (the paper's wing: crossings at the root of the trailing-edge face and
        // at the tip's trailing edge; the demo: 4 such triangles along the root, no crossing)
        if (depth[ti] % 2 == 0) continue;
        std::array<std::int32_t, 3> g{};
        for (int c = 0; c < 3; ++c) {
          int li = t[c];
          if (gid[li] < 0) {
            double th = 0;
            Vec3 d, x;
            if (resample) {
              std::tie(th, d, x) = exact_at(uv[li][0], uv[li][1]);
            } else {
              std::tie(th, d) = grid_at(f, uv[li][0], uv[li][1]);
              x = v3(shape.face_point(f, uv[li][0], uv[li][1]));
            }
            gid[li] = add_point(x, add(x, mul(d, th)), {});
          }
          g[c] = gid[li];
        }
        if (g[0] == g[1] || g[1] == g[2] || g[0] == g[2]) continue;
        out.shell_tris.push_back(g);
        out.shell_tri_face.push_back(f);
      }
    }
    // wall|wall junctions: close the crack between the two sides' shells through the block's
    // outer corner curve PC = P0 + t (m_A + m_B)
    for (int e = 0; e < ne; ++e) {
      const EdgeInfo& I = E[e];
      if (!(I.junction && I.kind == EdgeKind::wall_wall)) continue;
      if (strips_used[I.a] && strips_used[I.b]) continue;  // both sides end at the strip curve PC
      int n = static_cast<int>(I.t.size());
      std::vector<int> c(n);
      bool to_strip = strips_used[I.a] || strips_used[I.b];  // one side ends at PC: close the other to it
      for (int k = 0; k < n; ++k) {
        if (to_strip) {
          c[k] = strip_id(e, k);
          continue;
        }
        if ((k == 0 && I.v0 >= 0 && v_has[I.v0]) || (k == n - 1 && I.v1 >= 0 && v_has[I.v1])) {
          c[k] = station_id(e, k, I.a);
          continue;
        }
        c[k] = add_point(I.p[k], add(I.p[k], mul(add(I.ma[k], I.mb[k]), I.th[k])), {});
      }
      for (int side : {I.a, I.b})
        for (int k = 0; k + 1 < n; ++k) {
          if (strips_used[side]) break;
          int s0 = station_id(e, k, side), s1 = station_id(e, k + 1, side);
          std::array<std::int32_t, 3> t1{s0, s1, c[k + 1]}, t2{s0, c[k + 1], c[k]};
          for (auto t : {t1, t2})
            if (t[0] != t[1] && t[1] != t[2] && t[0] != t[2]) {
              out.shell_tris.push_back(t);
              out.shell_tri_face.push_back(side);
            }
        }
    }
    weld_duplicates();
  }

  // Points made twice with the same wall and shell position (a junction's strip corner reached
  // from two edges' stations at a vertex: DLR-F6's fuselage-wing fillet corner) are one point:
  // triangles are renumbered to the first of them, so that neighbours sharing the position also
  // share the index (the crossing check skips pairs sharing a vertex; touching at a duplicated
  // vertex would count as a crossing). Triangles that become degenerate are dropped.
  long welded_points = 0;
  void weld_duplicates() {
    // the same position up to rounding (two evaluations of one strip corner differ by ~1e-11)
    const double tol = 1e-9 * Lref;
    std::vector<int> to(out.shell_points.size());
    if (to.empty()) return;
    std::vector<medial::Vec3> wp(out.shell_wall.begin(), out.shell_wall.end());
    medial::NearestIndex idx(wp);
    for (std::size_t i = 0; i < to.size(); ++i) {
      to[i] = static_cast<int>(i);
      for (auto [j, d] : idx.nearest(out.shell_wall[i], 8)) {
        if (d > tol) break;
        if (j < static_cast<int>(i) && norm(sub(out.shell_points[j], out.shell_points[i])) <= tol) {
          to[i] = to[j];
          ++welded_points;
          break;
        }
      }
    }
    if (welded_points == 0) return;
    std::vector<std::array<std::int32_t, 3>> tris;
    std::vector<std::int32_t> tf;
    for (std::size_t t = 0; t < out.shell_tris.size(); ++t) {
      auto g = out.shell_tris[t];
      for (auto& x : g) x = to[x];
      if (g[0] == g[1] || g[1] == g[2] || g[0] == g[2]) continue;
      tris.push_back(g), tf.push_back(out.shell_tri_face[t]);
    }
    out.shell_tris.swap(tris), out.shell_tri_face.swap(tf);
  }

  // ── 5b. clearance of the sampled shell to the walls (nearest wall sample, refined by
  // projection on its face; rel_wall: over the point's own offset) and to the far field ──
  struct Clearance {
    double wall = INFINITY, far = INFINITY, rel_wall = INFINITY;
    Vec3 at_wall{}, at_far{};
  };
  std::unique_ptr<medial::NearestIndex> clear_widx, clear_fidx;
  std::vector<int> clear_wi;
  Clearance clearance() {
    Clearance c;
    if (!clear_widx) {
      std::vector<medial::Vec3> wp, fp;
      for (std::size_t i = 0; i < M.samples.size(); ++i) {
        auto& s = M.samples[i];
        bool w = false, far = false;
        for (int f : s.faces)
          if (f >= 0) w |= wall[f] > 0, far |= shape.face_tag(f) == cad::Tag::farfield;
        if (w) wp.push_back(s.p), clear_wi.push_back(static_cast<int>(i));
        if (far) fp.push_back(s.p);
      }
      clear_widx = std::make_unique<medial::NearestIndex>(wp);
      if (!fp.empty()) clear_fidx = std::make_unique<medial::NearestIndex>(fp);
    }
    // per point: distance to the walls and to the far field (in parallel), then reduced in
    // point order (the first nearest point wins on ties, at any thread count)
    const std::size_t n = out.shell_points.size();
    std::vector<double> dw(n), df(n, INFINITY);
    for_each_index(shape, ctx.threads(), n, [&](cad::Shape& mine, std::size_t q) {
      const Vec3& x = out.shell_points[q];
      auto [j, d] = clear_widx->nearest(x, 1)[0];
      const auto& s = M.samples[clear_wi[j]];
      if (s.kind == 0) {  // refine by projection on the sample's face, from the sample: a local search
        auto pr = mine.project_to_face_near(s.id, cv(x), cad::Vec2{s.u, s.v});
        if (pr.distance < d && mine.face_contains_uv(s.id, pr.u, pr.v, 1e-7)) d = pr.distance;
      }
      dw[q] = d;
      if (clear_fidx) df[q] = clear_fidx->nearest(x, 1)[0].second;
    });
    for (std::size_t q = 0; q < n; ++q) {
      const Vec3& x = out.shell_points[q];
      if (dw[q] < c.wall) c.wall = dw[q], c.at_wall = x;
      double tq = norm(sub(x, out.shell_wall[q]));
      if (tq > 0) c.rel_wall = std::min(c.rel_wall, dw[q] / tq);
      if (df[q] < c.far) c.far = df[q], c.at_far = x;
    }
    return c;
  }

  // ── 6. blocks ──
  nlohmann::json blocks() {
    nlohmann::json B = nlohmann::json::array();
    for (int f = 0; f < nf; ++f) {
      if (!wall[f]) continue;
      nlohmann::json edges = nlohmann::json::array(), equal = nlohmann::json::array();
      for (int e : shape.face_edges(f)) {
        if (shape.edge_degenerate(e)) continue;
        const EdgeInfo& I = E[e];
        std::string base = I.junction ? "j" + std::to_string(e) + (I.a == f ? "a" : "b") : "w" + std::to_string(e);
        edges.push_back(base);
        equal.push_back({base, I.junction ? "j" + std::to_string(e) + "c" : "s" + std::to_string(e)});
      }
      B.push_back({{"kind", "prism_sweep"}, {"face", f}, {"tag", cad::tag_name(shape.face_tag(f))}, {"edges", edges}, {"equal", equal}});
    }
    for (int e = 0; e < ne; ++e) {
      const EdgeInfo& I = E[e];
      if (!I.junction) continue;
      std::string s = std::to_string(e);
      nlohmann::json st = nlohmann::json::array();
      int n = static_cast<int>(I.t.size());
      for (int k = 0; k < n; ++k) {
        StripStation q = strip_station(e, k);
        st.push_back({{"t", I.t[k]}, {"P0", I.p[k]}, {"PA", q.PA}, {"uvA", q.uvA}, {"PB", q.PB}, {"uvB", q.uvB}, {"PC", q.PC}});
      }
      nlohmann::json equal = nlohmann::json::array();
      equal.push_back({"w" + s, "j" + s + "a", "j" + s + "b", "j" + s + "c"});
      equal.push_back({"x" + s + ".0.0a", "x" + s + ".0.bc", "x" + s + ".1.0a", "x" + s + ".1.bc"});
      equal.push_back({"x" + s + ".0.0b", "x" + s + ".0.ac", "x" + s + ".1.0b", "x" + s + ".1.ac"});
      B.push_back({{"kind", "hex_junction"},
                   {"edge", e},
                   {"face", I.a},
                   {"partner", I.b},
                   {"partner_tag", cad::tag_name(shape.face_tag(I.b))},
                   {"fluid_angle_deg", I.fluid_angle},
                   {"vertices", {I.v0, I.v1}},
                   {"equal", equal},
                   {"stations", st}});
    }
    return B;
  }

  void run() {
    double t0 = now();
    shape = cad::Shape::load(ctx.input("shape").path);
    M = medial::read(ctx.input("medial").path);
    nf = shape.num_faces(), ne = shape.num_edges(), nv = shape.num_vertices();
    if (static_cast<int>(M.info.size()) != static_cast<int>(M.samples.size()))
      throw StageError("shell: the medial artifact is inconsistent (samples vs per-sample info); re-run medial");
    wall.assign(nf, 0);
    for (int f : shape.faces_with_tag(cad::Tag::wall)) wall[f] = 1;
    auto walls = shape.faces_with_tag(cad::Tag::wall);
    if (walls.empty())
      throw StageError("shell: the shape has no face tagged `wall`; the shell offsets the walls (tag the body faces as wall in the geometry/heal stage)");
    for (auto& s : M.samples)
      for (int f : s.faces)
        if (f >= nf)
          throw StageError("shell: the medial object refers to face " + std::to_string(f) + " but the shape has " +
                           std::to_string(nf) + " faces; medial and shell must read the same shape (needs: [heal, medial])");
    topo_c = P.at("topology").get<std::string>() == "C";
    for (auto& t : P.at("junction_with")) junction_with.insert(cad::tag_from_name(t.get<std::string>()));
    lfs_factor = P.at("lfs_factor");
    thin_fraction = P.at("thin_fraction"), max_thinned_area = P.at("max_thinned_area");
    alpha = P.at("alpha"), grad = P.at("max_gradient"), blend = P.at("blend_length");
    junction_angle = P.at("junction_angle_deg"), max_grid = P.at("max_grid");
    max_crossing_rounds = P.at("crossing_rounds");
    Vec3 lo{INFINITY, INFINITY, INFINITY}, hi{-INFINITY, -INFINITY, -INFINITY};
    for (int f : walls) {
      auto b = shape.face_box(f);
      for (int k = 0; k < 3; ++k) lo[k] = std::min(lo[k], b.lo[k]), hi[k] = std::max(hi[k], b.hi[k]);
    }
    Lref = std::max({hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]});
    double diag = norm(sub(hi, lo));
    T = P.at("thickness").get<double>();
    if (P.at("thickness_relative_to") == "wall_box") T *= Lref;
    h = P.at("spacing").get<double>() * diag;
    treated_nbrs.assign(nf, {});
    ctx.progress(0.02, "edges");
    classify_edges();
    if (topo_c && P.at("third_face_ends") == "averaged") average_third_face_chains();
    face_edges_cache.resize(nf);
    for (int f = 0; f < nf; ++f) face_edges_cache[f] = shape.face_edges(f);
    junction_width_limits();
    ctx.progress(0.15, "thickness on the wall samples");
    sample_thickness();
    IntersectionReport inter;
    long crossings_first = -1;
    int crossing_rounds = 0;
    // the round with the fewest crossings (the constraints it had): kept when later rounds,
    // whose dimples move the sampled surface elsewhere, end with more
    long best_pairs = -1;
    double rel_first = 0;
    std::size_t best_limits = 0;
    int best_round = 0;
    std::optional<Clearance> cl_last;  // of the surface built last, when the loop measured it
    // the fields, the sampled surface and its crossings, from the current constraints (after
    // reset_fields); progress reported when a label is given
    auto build_surface = [&](const std::string& label) {
      if (!label.empty()) ctx.progress(0.25, label);
      edge_fields();
      face_grids();
      if (!label.empty()) ctx.progress(0.7, "sampled shell surface");
      sample_surface();
      if (!label.empty()) ctx.progress(0.85, "checks");
      inter = self_intersections(out.shell_points, out.shell_tris, ctx.threads());
      cl_last.reset();
    };
    for (bool final = false;;) {
      build_surface(crossing_rounds ? "edge fields (thinning round " + std::to_string(crossing_rounds) + ")" : "edge fields");
      if (final) break;
      // a round must not bring the shell much nearer to a wall than the unthinned one was (a
      // dimple next to a junction corner can turn a strip's corner point onto the other face)
      if (inter.pairs > 0 || crossing_rounds > 0) cl_last = clearance();
      const double rel = cl_last ? cl_last->rel_wall : 0;
      if (crossings_first < 0) crossings_first = inter.pairs, rel_first = rel;
      const bool admissible = crossing_rounds == 0 || rel >= kCrossingClearance * rel_first;
      if (admissible && (best_pairs < 0 || inter.pairs < best_pairs))
        best_pairs = inter.pairs, best_limits = crossing_limits.size(), best_round = crossing_rounds;
      bool more = admissible && inter.pairs > 0 && crossing_rounds < max_crossing_rounds;
      if (more) {
        ctx.log(std::to_string(inter.pairs) + " crossing pairs in the sampled shell; thinning there (round " +
                std::to_string(crossing_rounds + 1) + ")");
        more = add_crossing_limits(inter);
      }
      if (more) {
        ++crossing_rounds;
        reset_fields();
        continue;
      }
      if (admissible && inter.pairs <= best_pairs) break;
      // a later round ended worse: build the best round's shell again
      ctx.log("keeping thinning round " + std::to_string(best_round) + " (" + std::to_string(best_pairs) + " crossing pairs)");
      crossing_limits.resize(best_limits);
      crossing_rounds = best_round;
      reset_fields();
      final = true;
    }
    // Crossings the thinning left (DLR-F6: 1, at the floor) may be the sampling's, not the
    // shell's: a face the lattice does not reach is triangulated from its boundary alone (see
    // sample_surface). The bare faces of the crossing triangles are sampled from the field at
    // the points and the surface built again, with the same thinning, as long as that clears
    // crossings (a pass that does not is undone). Only where crossings are treated at all
    // (crossing_rounds > 0) and left: other shells keep their bytes.
    for (int pass = 0; max_crossing_rounds > 0 && inter.pairs > 0 && pass < kResamplePasses; ++pass) {
      std::set<int> more;
      for (auto [i, j] : inter.all)
        for (int t : {i, j}) {
          const int f = out.shell_tri_face[t];
          if (lattice_bare[f] && !resample_faces.count(f)) more.insert(f);
        }
      if (more.empty()) break;
      const auto keep = resample_faces;
      const long before = inter.pairs;
      resample_faces.insert(more.begin(), more.end());
      auto rebuild = [&] {
        reset_fields();
        build_surface("");
      };
      ctx.log(std::to_string(before) + " crossing pairs left; sampling " + std::to_string(more.size()) +
              " face(s) the lattice does not reach from the field");
      rebuild();
      if (inter.pairs >= before) {
        resample_faces = keep;
        rebuild();
        break;
      }
    }
    if (crossing_rounds > 0) {  // what the kept constraints do
      crossing_points = static_cast<long>(crossing_limits.size());
      crossing_min_scale = 1;
      std::vector<int> all(nf);
      std::iota(all.begin(), all.end(), 0);
      for (auto& L : crossing_limits) {
        double base = thickness_at(L.p, all, false);
        if (base > 0 && L.a / base < crossing_min_scale) crossing_min_scale = L.a / base, crossing_min_at = L.p;
      }
    }

    // clearance of the shell points to the walls and to the far field
    const Clearance cl = cl_last ? *cl_last : clearance();
    const double clear_wall = cl.wall, clear_far = cl.far, rel_wall = cl.rel_wall;
    const Vec3 at_wall = cl.at_wall, at_far = cl.at_far;
    // honoured thickness
    double tmin = INFINITY, tmax = 0;
    Vec3 worst{};
    for (std::size_t k = 0; k < ws.size(); ++k) {
      if (ws_t[k] < tmin) tmin = ws_t[k], worst = M.samples[ws[k]].p;
      tmax = std::max(tmax, ws_t[k]);
    }
    long reduced = 0;
    for (double t : ws_t) reduced += t < T * (1 - 1e-9);
    double gmin = INFINITY, gmax = 0;
    for (auto& [f, G] : grids)
      for (std::size_t i = 0; i < G.data.size(); i += 4) gmin = std::min(gmin, G.data[i]), gmax = std::max(gmax, G.data[i]);

    nlohmann::json stats;
    stats["thickness_requested"] = T;
    stats["reference_length"] = Lref;
    stats["thickness"] = {{"min", tmin}, {"max", tmax}, {"grid_min", gmin}, {"grid_max", gmax}};
    stats["not_honoured"] = {{"samples", reduced},
                             {"of", ws.size()},
                             {"limited_by_medial", limited_samples},
                             {"limited_by_lfs", limited_by_lfs},
                             {"medial_limit_min", std::isfinite(lim_min) ? nlohmann::json(lim_min) : nlohmann::json(nullptr)},
                             {"medial_limit_at", lim_at},
                             {"min_thickness", tmin},
                             {"worst_location", worst}};
    if (width_limited_stations > 0)  // only when it acts: shells of wide enough faces keep their bytes
      stats["not_honoured"]["limited_by_face_width"] = {
          {"stations", width_limited_stations}, {"min", width_limit_min}, {"at", width_limit_at}};
    stats["corner_balls_ignored"] = corner_balls;
    // only when it acts (a sample thinned, or a gap ball taken for a corner): other shells, and
    // the goldens that hold their stats, keep their bytes
    if (thinning.at("samples").get<long>() > 0) stats["local_thinning"] = thinning;
    stats["self_intersections"] = inter.pairs;
    if (crossing_rounds > 0)  // only when it acts: shells that never crossed keep their bytes
      stats["not_honoured"]["thinned_for_crossings"] = {{"rounds", crossing_rounds},
                                                        {"crossings_before", crossings_first},
                                                        {"points", crossing_points},
                                                        {"min_scale", crossing_min_scale},
                                                        {"at", crossing_min_at}};
    nlohmann::json rundiag;  // diagnostics of this run: in the stage's report (stats), not in the artifact
    if (inter.pairs > 0) stats["self_intersection_at"] = inter.first;
    {
      // where the crossings are: per pair of wall faces the crossing triangles were swept from
      // ("a-b", a <= b; "a-a": two triangles of one face's shell)
      std::map<std::pair<int, int>, long> by;
      for (auto [i, j] : inter.all) {
        int a = out.shell_tri_face[i], b = out.shell_tri_face[j];
        ++by[{std::min(a, b), std::max(a, b)}];
      }
      nlohmann::json jf = nlohmann::json::object();
      for (auto& [k, c] : by) jf[std::to_string(k.first) + "-" + std::to_string(k.second)] = c;
      rundiag["self_intersection_faces"] = jf;
      // and by what joins the two faces: one face (its own shell folds), an edge (by its
      // kind: junction, other concave, convex, sharp convex above 300 degrees through the fluid
      // such as a trailing edge), a vertex only, or nothing (facing walls across a gap)
      std::map<std::pair<int, int>, std::string> joined;
      for (int e = 0; e < ne; ++e) {
        const EdgeInfo& I = E[e];
        if (I.kind != EdgeKind::wall_wall) continue;
        std::string k = I.junction ? "junction_edge"
                        : I.concave ? "concave_edge"
                        : I.fluid_angle > 300 ? "sharp_convex_edge"
                                              : "convex_edge";
        joined.emplace(std::make_pair(std::min(I.a, I.b), std::max(I.a, I.b)), k);
      }
      std::vector<std::set<int>> fverts(nf);
      for (int f = 0; f < nf; ++f)
        if (wall[f])
          for (int e : face_edges_cache[f])
            for (int v : shape.edge_vertices(e)) fverts[f].insert(v);
      std::map<std::string, long> kinds;
      std::map<std::string, nlohmann::json> where;
      for (auto& [key, c] : by) {
        auto [a, b] = key;
        std::string k;
        if (a == b) k = "same_face";
        else if (auto it = joined.find(key); it != joined.end()) k = it->second;
        else {
          bool v = false;
          for (int x : fverts[a]) v |= fverts[b].count(x) > 0;
          k = v ? "shared_vertex" : "separate_faces";
        }
        kinds[k] += c;
        if (where[k].size() < 12) where[k].push_back(std::to_string(a) + "-" + std::to_string(b));
      }
      nlohmann::json jk = nlohmann::json::object();
      for (auto& [k, c] : kinds) jk[k] = {{"pairs", c}, {"faces", where[k]}};
      rundiag["self_intersection_kinds"] = jk;
      if (const char* dbg = std::getenv("MESHFLOW_SHELL_DEBUG")) {  // every crossing pair, for analysis
        std::FILE* fp = std::fopen(dbg, "w");
        if (fp) {
          for (auto [i, j] : inter.all) std::fprintf(fp, "%d %d\n", i, j);
          std::fclose(fp);
        }
      }
    }
    stats["min_clearance"] = {{"walls", clear_wall},
                              {"walls_over_thickness", rel_wall},
                              {"farfield", std::isfinite(clear_far) ? nlohmann::json(clear_far) : nlohmann::json(nullptr)},
                              {"walls_at", at_wall}};
    if (std::isfinite(clear_far)) stats["min_clearance"]["farfield_at"] = at_far;
    stats["faces_unsampled"] = faces_unsampled;
    rundiag["junction_strip_fallback_faces"] = strip_fallback;
    rundiag["welded_points"] = welded_points;
    {
      nlohmann::json rf = nlohmann::json::array();
      for (auto [f, a, b] : refined_faces) rf.push_back({f, a, b});
      rundiag["sampling_refined_faces"] = rf;  // (face, ru, rv): interior lattice finer than the field grid
    }
    if (!resample_faces.empty())  // faces sampled from the field at the points (see run)
      rundiag["resampled_faces"] = {{"faces", std::vector<int>(resample_faces.begin(), resample_faces.end())},
                                    {"points", resampled_points}};
    if (!unsampled_why.empty()) stats["unsampled"] = unsampled_why;
    if (!averaged_chains.empty()) stats["junction_chains_averaged"] = averaged_chains;
    if (maximin_vertices) stats["maximin_vertices"] = maximin_vertices;
    long nj = 0, nwall_other = 0, nww = 0;
    nlohmann::json jlist = nlohmann::json::array();
    for (int e = 0; e < ne; ++e) {
      nj += E[e].junction;
      nwall_other += E[e].kind == EdgeKind::wall_other;
      nww += E[e].kind == EdgeKind::wall_wall;
    }
    ctx.progress(0.9, "blocks");
    nlohmann::json B = blocks();
    nlohmann::json h;
    nlohmann::json params = P;
    h["params"] = params;
    h["units"] = shape.units();
    h["counts"] = {{"wall_faces", walls.size()},
                   {"wall_wall_edges", nww},
                   {"wall_other_edges", nwall_other},
                   {"junction_edges", nj},
                   {"prism_blocks", walls.size()},
                   {"hex_junction_blocks", nj}};
    h["blocks"] = B;
    h["stats"] = stats;
    for (auto& [f, G] : grids) out.faces.push_back(G);
    for (int e = 0; e < ne; ++e) {
      const EdgeInfo& I = E[e];
      if (I.kind == EdgeKind::none) continue;
      EdgeField F;
      F.edge = e, F.t0 = I.t.front(), F.t1 = I.t.back(), F.sides = I.sides;
      for (int s : I.sides) {
        std::vector<double> d;
        for (std::size_t k = 0; k < I.t.size(); ++k) {
          auto& dk = I.dir.at(s)[k];
          d.insert(d.end(), {I.th[k], dk[0], dk[1], dk[2]});
        }
        F.data.push_back(std::move(d));
      }
      out.edges.push_back(std::move(F));
    }
    for (int v = 0; v < nv; ++v)
      if (v_has[v]) out.vertices.push_back({v, v_t[v], v_d[v]});
    out.header = h.dump();
    write(out, ctx.output("shell", "shell"));

    auto& st = ctx.stats();
    for (auto& [k, v] : stats.items()) st[k] = v;
    for (auto& [k, v] : rundiag.items()) st[k] = v;  // the run's report only, not the artifact header
    st["counts"] = h["counts"];
    st["shell_points"] = out.shell_points.size();
    st["shell_triangles"] = out.shell_tris.size();
    st["time"] = now() - t0;
    ctx.progress(1.0, "done");
  }
};

void run(StageContext& ctx) {
  Stage s(ctx);
  s.run();
}

StageRegistrar reg({.kind = "shell",
                    .version = 5,
                    .summary = "near-field shell bounded by the medial object: thickness/direction fields, prism and C-type hex junction blocks",
                    .libraries = {"CGAL " CGAL_VERSION_STR},
                    .needs = {"shape", "medial"},
                    .produces = {{"shell", "shell"}},
                    .run = run});

}  // namespace
}  // namespace meshflow::shell
