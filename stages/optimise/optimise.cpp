// meshflow optimise — the algorithm of optimise.hpp (units, L-BFGS-B, blending, validity guard).
// Libraries: LBFGSpp (bounded L-BFGS-B), Eigen (small dense solves), TBB (parallel units). CAD
// only through stages/cad/cad.hpp.
#include "stages/optimise/optimise.hpp"

#include "engine/stage.hpp"
#include "stages/cad/cad.hpp"
#include "stages/model/element.hpp"
#include "stages/model/quality.hpp"

#include <Eigen/Dense>
#include <LBFGSB.h>
#include <nlohmann/json.hpp>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <map>
#include <mutex>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

namespace meshflow::optimise {

using model::Mesh;
using model::Shape;

nlohmann::json Report::to_json() const {
  return {{"order", order},
          {"units", {{"curve_edges", curve_edges}, {"surface_edges", surface_edges}, {"faces", faces}}},
          {"skipped", {{"inconsistent_parameters", skipped_inconsistent}, {"seam", skipped_seam}}},
          {"unwrapped_seam", unwrapped_seam},
          {"energy", {{"before", energy_before}, {"after", energy_after}}},
          {"max_cad_distance", max_cad_distance},
          {"nodes_moved", nodes_moved},
          {"nodes_blended", nodes_blended},
          {"elements_checked", elements_checked},
          {"invalid", {{"before", invalid_before}, {"after", invalid_after}}},
          {"guard", {{"backtracked_units", backtracked_units}, {"reverted_units", reverted_units}, {"rounds", guard_rounds},
                     {"quality_backtracked_units", quality_backtracked_units}}},
          {"min_scaled_jacobian", {{"before", elements_checked ? min_sj_before : 1.0}, {"after", elements_checked ? min_sj_after : 1.0}}},
          {"iterations", {{"total", iterations}, {"max_per_unit", max_unit_iterations}}},
          {"time", {{"total", seconds}, {"optimise", optimise_seconds}, {"guard", guard_seconds}}}};
}

namespace {

using Clock = std::chrono::steady_clock;
double since(Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); }

struct V3 {
  double x = 0, y = 0, z = 0;
};
inline V3 operator-(V3 a, V3 b) { return {a.x - b.x, a.y - b.y, a.z - b.z}; }
inline V3 operator+(V3 a, V3 b) { return {a.x + b.x, a.y + b.y, a.z + b.z}; }
inline V3 operator*(double s, V3 a) { return {s * a.x, s * a.y, s * a.z}; }
inline double dot(V3 a, V3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
inline double norm(V3 a) { return std::sqrt(dot(a, a)); }
inline V3 v3(const cad::Vec3& p) { return {p.x, p.y, p.z}; }

enum class Kind : std::uint8_t { curve_edge, surface_edge, face };

// One spring system (optimise.hpp, "Units").
struct Unit {
  Kind kind = Kind::curve_edge;
  int entity = -1;                            // CAD edge id or face id (0-based)
  std::vector<std::uint32_t> free, fixed;     // global node indices
  std::vector<std::array<int, 2>> springs;    // >= 0: free local index; < 0: fixed -1-k
  std::vector<double> p0, popt, lb, ub;       // parameters of the free nodes (dim per node)
  std::vector<double> home0, home1;           // natural range to wrap back into (per param dim)
  bool unwrapped = false;
  bool moved = false;   // popt differs from p0
  double alpha = 1;     // backtracking factor
  int iterations = 0;
  int dim() const { return kind == Kind::curve_edge ? 1 : 2; }
};

// Position and parameter derivatives of a free node.
struct Eval {
  V3 x, d[2];
};
inline Eval eval(const cad::Shape& s, const Unit& u, const double* p) {
  Eval r;
  if (u.kind == Kind::curve_edge) {
    auto d = s.edge_eval(u.entity, p[0]);
    r.x = v3(d.p);
    r.d[0] = v3(d.d1);
  } else {
    auto d = s.face_eval(u.entity, p[0], p[1]);
    r.x = v3(d.p);
    r.d[0] = v3(d.du);
    r.d[1] = v3(d.dv);
  }
  return r;
}
inline V3 point(const cad::Shape& s, const Unit& u, const double* p) {
  if (u.kind == Kind::curve_edge) return v3(s.edge_point(u.entity, p[0]));
  return v3(s.face_point(u.entity, p[0], p[1]));
}

inline V3 node(const Mesh& m, std::uint32_t n) { return {m.x[n], m.y[n], m.z[n]}; }
inline V3 node(const std::vector<double>& X, std::uint32_t n) { return {X[3 * n], X[3 * n + 1], X[3 * n + 2]}; }

// Spring energy of a unit with every node at its position in X (xyz interleaved).
double unit_energy(const Unit& u, const std::vector<double>& X) {
  double E = 0;
  for (auto [a, b] : u.springs) {
    V3 xa = node(X, a >= 0 ? u.free[a] : u.fixed[-1 - a]);
    V3 xb = node(X, b >= 0 ? u.free[b] : u.fixed[-1 - b]);
    V3 d = xa - xb;
    E += dot(d, d);
  }
  return E;
}

// The objective of one unit for LBFGSpp: variables y, parameters p = p0 + s * y; energy divided
// by its initial value. Remembers the best point it was evaluated at (a line search that fails
// near convergence throws, and x is then a trial point, not the best).
struct Objective {
  const cad::Shape& shape;
  const Unit& u;
  const std::vector<V3>& fixed_x;
  std::vector<double> scale;
  double E0 = 1;
  std::vector<Eval> ev;
  std::vector<double> p;
  double best = INFINITY;
  Eigen::VectorXd best_y;

  Objective(const cad::Shape& s, const Unit& unit, const std::vector<V3>& fx) : shape(s), u(unit), fixed_x(fx) {}

  double operator()(const Eigen::VectorXd& y, Eigen::VectorXd& g) {
    const int dim = u.dim();
    const std::size_t nf = u.free.size();
    ev.resize(nf);
    p.resize(nf * dim);
    for (std::size_t i = 0; i < nf * dim; ++i) p[i] = u.p0[i] + scale[i] * y[i];
    for (std::size_t i = 0; i < nf; ++i) ev[i] = eval(shape, u, &p[i * dim]);
    double E = 0;
    g.setZero(y.size());
    for (auto [a, b] : u.springs) {
      V3 xa = a >= 0 ? ev[a].x : fixed_x[-1 - a];
      V3 xb = b >= 0 ? ev[b].x : fixed_x[-1 - b];
      V3 d = xa - xb;
      E += dot(d, d);
      if (a >= 0)
        for (int c = 0; c < dim; ++c) g[a * dim + c] += 2 * dot(d, ev[a].d[c]);
      if (b >= 0)
        for (int c = 0; c < dim; ++c) g[b * dim + c] -= 2 * dot(d, ev[b].d[c]);
    }
    for (Eigen::Index i = 0; i < y.size(); ++i) g[i] *= scale[i] / E0;
    double f = E / E0;
    if (f < best) best = f, best_y = y;
    return f;
  }
};

// Optimises one unit: fills popt, iterations, moved.
void optimise_unit(const cad::Shape& shape, const Mesh& m, Unit& u, const Options& opt) {
  const int dim = u.dim();
  const std::size_t nf = u.free.size(), nv = nf * dim;
  std::vector<V3> fixed_x(u.fixed.size());
  for (std::size_t k = 0; k < u.fixed.size(); ++k) fixed_x[k] = node(m, u.fixed[k]);
  Objective obj(shape, u, fixed_x);
  // energy at the start, spring length scale, variable scales
  obj.scale.assign(nv, 1.0);
  Eigen::VectorXd y = Eigen::VectorXd::Zero(nv), g(nv);
  double E0 = obj(y, g);  // with E0 = 1: the raw energy
  if (!(E0 > 0) || !std::isfinite(E0)) {
    u.popt = u.p0;
    return;
  }
  const double h = std::sqrt(E0 / double(u.springs.size()));
  for (std::size_t i = 0; i < nf; ++i)
    for (int c = 0; c < dim; ++c) {
      double J = norm(obj.ev[i].d[c]), range = u.ub[i * dim + c] - u.lb[i * dim + c];
      double s = J > 0 ? h / J : range;
      obj.scale[i * dim + c] = std::min(s, range > 0 ? range : s);
    }
  obj.E0 = E0;
  obj.best = INFINITY;
  Eigen::VectorXd lb(nv), ub(nv);
  for (std::size_t i = 0; i < nv; ++i) {
    lb[i] = (u.lb[i] - u.p0[i]) / obj.scale[i];
    ub[i] = (u.ub[i] - u.p0[i]) / obj.scale[i];
    lb[i] = std::min(lb[i], 0.0);  // a start on the bound stays feasible
    ub[i] = std::max(ub[i], 0.0);
  }
  LBFGSpp::LBFGSBParam<double> param;
  param.m = 6;
  param.epsilon = opt.tolerance;
  param.epsilon_rel = 0;
  param.past = 1;
  param.delta = 1e-14;
  param.max_iterations = opt.max_iterations;
  param.max_linesearch = 40;
  LBFGSpp::LBFGSBSolver<double> solver(param);
  double fx = 0;
  y.setZero();
  try {
    u.iterations = solver.minimize(obj, y, fx, lb, ub);
  } catch (const std::exception&) {
    // line search failure near the minimum (rounding): keep the best point seen
    u.iterations = param.max_iterations;
  }
  u.popt = u.p0;
  if (obj.best < 1 && obj.best_y.size() == Eigen::Index(nv)) {
    for (std::size_t i = 0; i < nv; ++i)
      u.popt[i] = std::clamp(u.p0[i] + obj.scale[i] * obj.best_y[i], std::min(u.lb[i], u.p0[i]), std::max(u.ub[i], u.p0[i]));
    u.moved = u.popt != u.p0;
  }
}

// ── harmonic extension on an element's node lattice ────────────────────────────────────
struct Extension {
  std::vector<int> interior, boundary;  // local node indices
  Eigen::MatrixXd W;                    // interior displacement = W * boundary displacement
};

std::vector<model::Lattice> lattice_steps(Shape s) {
  using L = model::Lattice;
  switch (s) {
    case Shape::Line: return {L{1, 0, 0}};
    case Shape::Tri: return {L{1, 0, 0}, L{0, 1, 0}, L{1, -1, 0}};
    case Shape::Quad: return {L{1, 0, 0}, L{0, 1, 0}};
    case Shape::Tet: return {L{1, 0, 0}, L{0, 1, 0}, L{0, 0, 1}, L{1, -1, 0}, L{1, 0, -1}, L{0, 1, -1}};
    case Shape::Hex: return {L{1, 0, 0}, L{0, 1, 0}, L{0, 0, 1}};
    case Shape::Prism: return {L{1, 0, 0}, L{0, 1, 0}, L{1, -1, 0}, L{0, 0, 1}};
    case Shape::Pyramid: return {L{1, 0, 0}, L{0, 1, 0}, L{0, 0, 1}, L{1, 0, 1}, L{0, 1, 1}, L{1, 1, 1}};
    default: return {};
  }
}

Extension make_extension(Shape s, int P) {
  Extension ex;
  const auto& lat = model::lattice(s, P);
  const int n = int(lat.size());
  std::vector<char> bnd(n, 0);
  const int d = model::dimension(s);
  if (d == 3) {
    for (const auto& f : model::face_nodes(s, P))
      for (int i : f) bnd[i] = 1;
  } else if (d == 2) {
    for (const auto& e : model::edge_nodes(s, P))
      for (int i : e) bnd[i] = 1;
  } else {
    bnd[0] = bnd[1] = 1;
  }
  std::vector<int> idx(n, -1);
  for (int i = 0; i < n; ++i) {
    if (bnd[i]) idx[i] = int(ex.boundary.size()), ex.boundary.push_back(i);
    else idx[i] = int(ex.interior.size()), ex.interior.push_back(i);
  }
  const int ni = int(ex.interior.size()), nb = int(ex.boundary.size());
  if (ni == 0) return ex;
  std::map<model::Lattice, int> at;
  for (int i = 0; i < n; ++i) at[lat[i]] = i;
  Eigen::MatrixXd LII = Eigen::MatrixXd::Zero(ni, ni), AIB = Eigen::MatrixXd::Zero(ni, nb);
  auto steps = lattice_steps(s);
  for (int a = 0; a < ni; ++a) {
    const auto& l = lat[ex.interior[a]];
    for (const auto& st : steps)
      for (int sg : {1, -1}) {
        model::Lattice q{l[0] + sg * st[0], l[1] + sg * st[1], l[2] + sg * st[2]};
        auto it = at.find(q);
        if (it == at.end()) continue;
        LII(a, a) += 1;
        if (bnd[it->second]) AIB(a, idx[it->second]) += 1;
        else LII(a, idx[it->second]) -= 1;
      }
  }
  ex.W = LII.partialPivLu().solve(AIB);
  return ex;
}

const Extension& extension(Shape s, int P) {
  static std::mutex mu;
  static std::map<std::pair<int, int>, Extension> cache;
  std::lock_guard<std::mutex> lk(mu);
  auto key = std::make_pair(int(s), P);
  auto it = cache.find(key);
  if (it == cache.end()) it = cache.emplace(key, make_extension(s, P)).first;
  return it->second;
}

// A set of nodes that follow by blending: `nodes` are the element's or face's nodes in its
// local order (shape/order of `ext`), targets are ext.interior.
struct Blend {
  const Extension* ext = nullptr;
  std::vector<std::uint32_t> nodes;
};

struct Elem {
  std::uint32_t block = 0, index = 0;
};

}  // namespace

Report optimise_mesh(Mesh& m, const cad::Shape& shape, const Options& opt, int threads) {
  auto t_start = Clock::now();
  Report rep;
  // ── input checks ──
  const int dim = m.dimension();
  const int P = m.order();
  rep.order = P;
  if (dim < 2) throw StageError("optimise: the mesh has no 2D or 3D elements; give it the order-P mesh of the curve stage");
  if (P < 2)
    throw StageError("optimise: the mesh is linear (order 1); there are no high-order nodes to optimise. Run the curve "
                     "stage before optimise (needs: [heal, curve])");
  const std::size_t nn = m.num_nodes();
  if (m.node_entity_dim.size() != nn || !m.has_parametric() || m.node_u.size() != nn || m.node_v.size() != nn)
    throw StageError("optimise: the mesh's nodes carry no CAD classification and parameters (the linear mesh contract "
                     "of stages/sweep/sweep.hpp); give it the mesh of the curve stage, which keeps them");
  for (std::size_t i = 0; i < nn; ++i) {
    int d = m.node_entity_dim[i], t = m.node_entity_tag[i];
    if (d == 1 || d == 2) {
      int count = d == 1 ? shape.num_edges() : shape.num_faces();
      if (t < 1 || t > count)
        throw StageError("optimise: node " + std::to_string(m.node_tag(i)) + " is classified on CAD " +
                         (d == 1 ? "edge " : "face ") + std::to_string(t) + " but the shape has " + std::to_string(count) +
                         (d == 1 ? " edges" : " faces") + "; mesh and shape do not belong together (needs: [heal, curve])");
      if (!std::isfinite(m.node_u[i]) || (d == 2 && !std::isfinite(m.node_v[i])))
        throw StageError("optimise: node " + std::to_string(m.node_tag(i)) + " lies on CAD " + (d == 1 ? "edge " : "face ") +
                         std::to_string(t) + " but has no parameter" + (d == 2 ? "s (u,v)" : " t") +
                         "; the curve stage must store them (linear mesh contract, stages/sweep/sweep.hpp)");
    }
  }
  for (const auto& b : m.blocks)
    if (model::dimension(b.shape) == dim && b.order != P)
      throw StageError("optimise: mixed orders among the " + std::to_string(dim) + "D elements (" + std::to_string(b.order) +
                       " and " + std::to_string(P) + "); optimise expects one order P from the curve stage");

  auto bb = shape.box(threads > 0 ? threads : tbb::this_task_arena::max_concurrency());  // the faces' boxes in parallel
  double diag = norm(v3(bb.hi) - v3(bb.lo));
  {
    double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (std::size_t i = 0; i < nn; ++i) {
      double p[3] = {m.x[i], m.y[i], m.z[i]};
      for (int c = 0; c < 3; ++c) lo[c] = std::min(lo[c], p[c]), hi[c] = std::max(hi[c], p[c]);
    }
    if (nn) diag = std::hypot(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]);
  }
  const double pos_tol = opt.position_tolerance * (diag > 0 ? diag : 1);

  auto on_cad = [&](std::uint32_t n) {
    int d = m.node_entity_dim[n];
    return d == 0 || d == 1 || d == 2;
  };

  // ── units ──
  std::vector<Unit> units;
  std::vector<char> is_vertex(nn, 0);
  for (const auto& b : m.blocks)
    for (std::size_t e = 0; e < b.size(); ++e)
      for (int k = 0; k < model::num_vertices(b.shape); ++k) is_vertex[b.element(e)[k]] = 1;

  // edges: key (lower vertex, upper vertex) -> interior nodes from the lower vertex
  struct EdgeCand {
    std::uint32_t a, b;
    std::vector<std::uint32_t> inner;
  };
  std::vector<EdgeCand> cands;
  auto add_edges = [&](const model::ElementBlock& b) {
    const auto& en = model::edge_nodes(b.shape, b.order);
    for (std::size_t e = 0; e < b.size(); ++e) {
      const std::uint32_t* el = b.element(e);
      for (const auto& ed : en) {
        if (ed.size() < 3) continue;
        EdgeCand c{el[ed[0]], el[ed[1]], {}};
        for (std::size_t k = 2; k < ed.size(); ++k) c.inner.push_back(el[ed[k]]);
        if (c.a > c.b) std::swap(c.a, c.b), std::reverse(c.inner.begin(), c.inner.end());
        cands.push_back(std::move(c));
      }
    }
  };
  for (const auto& b : m.blocks)
    if (b.order >= 2 && (b.shape == Shape::Line || b.shape == Shape::Tri || b.shape == Shape::Quad)) add_edges(b);
  std::sort(cands.begin(), cands.end(), [](const EdgeCand& x, const EdgeCand& y) {
    return std::tie(x.a, x.b, x.inner) < std::tie(y.a, y.b, y.inner);
  });
  cands.erase(std::unique(cands.begin(), cands.end(),
                          [](const EdgeCand& x, const EdgeCand& y) { return x.a == y.a && x.b == y.b && x.inner == y.inner; }),
              cands.end());

  // (t of an end node on curve e): its own t, or the curve's end at its CAD vertex (a closed
  // curve: the end nearer to the neighbouring interior node); NaN when unknown.
  auto end_t = [&](std::uint32_t n, int e, double t_near) -> double {
    int d = m.node_entity_dim[n], tag = m.node_entity_tag[n];
    if (d == 1 && tag - 1 == e) return m.node_u[n];
    auto r = shape.edge_range(e);
    if (d == 0) {
      auto vs = shape.edge_vertices(e);
      bool lo = vs[0] == tag - 1, hi = vs[1] == tag - 1;
      if (lo && hi) return std::abs(t_near - r.lo) <= std::abs(t_near - r.hi) ? r.lo : r.hi;
      if (lo) return r.lo;
      if (hi) return r.hi;
    }
    // elsewhere (should not happen by the contract): project
    auto pr = shape.project_to_edge(e, {m.x[n], m.y[n], m.z[n]}, t_near);
    return pr.distance <= pos_tol ? pr.t : NAN;
  };

  // Fills bounds and checks a unit; false = skip (counted).
  auto finish_unit = [&](Unit& u) -> bool {
    const int d = u.dim();
    const std::size_t nf = u.free.size();
    // parameters reproduce the positions
    for (std::size_t i = 0; i < nf; ++i)
      if (norm(point(shape, u, &u.p0[i * d]) - node(m, u.free[i])) > pos_tol) {
        ++rep.skipped_inconsistent;
        return false;
      }
    if (u.kind != Kind::curve_edge) {
      auto fb = shape.face_uv_bounds(u.entity);
      const double per[2] = {fb.u1 - fb.u0, fb.v1 - fb.v0};
      u.home0 = {fb.u0, fb.v0};
      u.home1 = {fb.u1, fb.v1};
      // a unit given in a chart shifted by whole periods (the first free node outside the
      // face's bounds, e.g. u in [-2pi, 0] on a cylinder): shift all of it back when the
      // shifted parameters give the same point
      for (int c = 0; c < 2; ++c) {
        if (per[c] <= 0) continue;
        double q[2] = {u.p0[0], u.p0[1]};
        double k = std::floor((q[c] - u.home0[c]) / per[c]);
        if (k == 0 || std::abs(k) > 2) continue;
        q[c] -= k * per[c];
        if (norm(point(shape, u, q) - node(m, u.free[0])) > pos_tol) continue;
        for (std::size_t i = 0; i < nf; ++i) u.p0[i * 2 + c] -= k * per[c];
        u.unwrapped = true;
      }
      // unwrap parameters across a periodic seam (relative to the first free node)
      for (std::size_t i = 1; i < nf; ++i)
        for (int c = 0; c < 2; ++c) {
          double diff = u.p0[i * 2 + c] - u.p0[c];
          if (std::abs(diff) <= 0.5 * per[c] || per[c] <= 0) continue;
          double q[2] = {u.p0[i * 2], u.p0[i * 2 + 1]};
          q[c] -= diff > 0 ? per[c] : -per[c];
          if (norm(point(shape, u, q) - node(m, u.free[i])) <= pos_tol) {
            u.p0[i * 2 + c] = q[c];
            u.unwrapped = true;
          }
        }
      u.lb.resize(nf * 2);
      u.ub.resize(nf * 2);
      for (std::size_t i = 0; i < nf; ++i) {
        u.lb[2 * i] = fb.u0, u.ub[2 * i] = fb.u1, u.lb[2 * i + 1] = fb.v0, u.ub[2 * i + 1] = fb.v1;
        if (u.unwrapped)  // a periodic chart: any parameter is valid, keep within one period around
          for (int c = 0; c < 2; ++c)
            u.lb[2 * i + c] = u.home0[c] - 0.5 * per[c], u.ub[2 * i + c] = u.home1[c] + 0.5 * per[c];
      }
    }
    // no spring between two free nodes may jump across the parameter domain
    for (auto [a, b] : u.springs) {
      if (a < 0 || b < 0) continue;
      double mid[2];
      for (int c = 0; c < d; ++c) mid[c] = 0.5 * (u.p0[a * d + c] + u.p0[b * d + c]);
      V3 xa = node(m, u.free[a]), xb = node(m, u.free[b]);
      if (norm(point(shape, u, mid) - 0.5 * (xa + xb)) > 0.5 * norm(xa - xb) + pos_tol) {
        ++rep.skipped_seam;
        return false;
      }
    }
    if (u.unwrapped) ++rep.unwrapped_seam;
    return true;
  };

  for (int pass = 0; pass < 2; ++pass)  // curve edges first, then surface edges (stable order)
    for (const auto& c : cands) {
      int d0 = m.node_entity_dim[c.inner[0]], t0 = m.node_entity_tag[c.inner[0]];
      bool same = true;
      for (auto n : c.inner) same = same && m.node_entity_dim[n] == d0 && m.node_entity_tag[n] == t0;
      if (!same || d0 != (pass == 0 ? 1 : 2)) continue;
      if (pass == 0 ? !opt.curve_edges : !opt.surface_edges) continue;
      Unit u;
      u.kind = pass == 0 ? Kind::curve_edge : Kind::surface_edge;
      u.entity = t0 - 1;
      u.free = c.inner;
      u.fixed = {c.a, c.b};
      const int k = int(c.inner.size());
      u.springs.push_back({-1, 0});
      for (int i = 0; i + 1 < k; ++i) u.springs.push_back({i, i + 1});
      u.springs.push_back({k - 1, -2});
      for (auto n : c.inner) {
        u.p0.push_back(m.node_u[n]);
        if (pass == 1) u.p0.push_back(m.node_v[n]);
      }
      if (pass == 0) {
        double ta = end_t(c.a, u.entity, u.p0.front()), tb = end_t(c.b, u.entity, u.p0.back());
        if (!std::isfinite(ta) || !std::isfinite(tb)) {
          ++rep.skipped_inconsistent;
          continue;
        }
        double lo = std::min(ta, tb), hi = std::max(ta, tb);
        u.lb.assign(k, lo);
        u.ub.assign(k, hi);
      }
      if (!finish_unit(u)) continue;
      units.push_back(std::move(u));
      ++(pass == 0 ? rep.curve_edges : rep.surface_edges);
    }

  // faces: interior nodes of 2D elements on a CAD face
  if (opt.faces)
    for (const auto& b : m.blocks) {
      if (!(b.shape == Shape::Tri || b.shape == Shape::Quad) || b.order < 2 || b.entity_dim != 2) continue;
      const Extension& ex = extension(b.shape, b.order);
      if (ex.interior.empty()) continue;
      const auto& lat = model::lattice(b.shape, b.order);
      std::map<model::Lattice, int> at;
      for (int i = 0; i < int(lat.size()); ++i) at[lat[i]] = i;
      auto steps = lattice_steps(b.shape);
      std::vector<int> local(lat.size(), 0);  // >= 0 free, < 0 fixed
      for (std::size_t e = 0; e < b.size(); ++e) {
        const std::uint32_t* el = b.element(e);
        int face_tag = m.node_entity_tag[el[ex.interior[0]]];
        bool ok = true;
        for (int i : ex.interior) ok = ok && m.node_entity_dim[el[i]] == 2 && m.node_entity_tag[el[i]] == face_tag;
        if (!ok) continue;
        Unit u;
        u.kind = Kind::face;
        u.entity = face_tag - 1;
        for (int i : ex.interior) {
          local[i] = int(u.free.size());
          u.free.push_back(el[i]);
          u.p0.push_back(m.node_u[el[i]]);
          u.p0.push_back(m.node_v[el[i]]);
        }
        for (int i : ex.boundary) {
          local[i] = -1 - int(u.fixed.size());
          u.fixed.push_back(el[i]);
        }
        for (int i : ex.interior)
          for (const auto& st : steps)
            for (int sg : {1, -1}) {
              model::Lattice q{lat[i][0] + sg * st[0], lat[i][1] + sg * st[1], lat[i][2] + sg * st[2]};
              auto it = at.find(q);
              if (it == at.end()) continue;
              int j = it->second;
              if (local[j] >= 0 && j < i) continue;  // free-free spring once
              u.springs.push_back({local[i], local[j]});
            }
        if (!finish_unit(u)) continue;
        units.push_back(std::move(u));
        ++rep.faces;
      }
    }

  // ── optimise: edges (parallel), then faces (parallel, with the optimised edge nodes) ──
  const int nthreads = threads > 0 ? threads : tbb::this_task_arena::max_concurrency();
  tbb::task_arena arena(nthreads);
  std::vector<double> X0(3 * nn), X(3 * nn);
  for (std::size_t i = 0; i < nn; ++i) X0[3 * i] = m.x[i], X0[3 * i + 1] = m.y[i], X0[3 * i + 2] = m.z[i];
  const std::vector<double> U0 = m.node_u, V0 = m.node_v;

  std::vector<int> unit_of(nn, -1);
  for (std::size_t k = 0; k < units.size(); ++k)
    for (auto n : units[k].free) unit_of[n] = int(k);

  // Places the free nodes of unit k at its current alpha (writes m.x/y/z and parameters).
  auto apply = [&](std::size_t k) {
    Unit& u = units[k];
    const int d = u.dim();
    for (std::size_t i = 0; i < u.free.size(); ++i) {
      std::uint32_t n = u.free[i];
      if (u.alpha == 0 || !u.moved) {
        m.x[n] = X0[3 * n], m.y[n] = X0[3 * n + 1], m.z[n] = X0[3 * n + 2];
        m.node_u[n] = U0[n], m.node_v[n] = V0[n];
        continue;
      }
      double p[2];
      for (int c = 0; c < d; ++c) p[c] = u.p0[i * d + c] + u.alpha * (u.popt[i * d + c] - u.p0[i * d + c]);
      V3 x = point(shape, u, p);
      m.x[n] = x.x, m.y[n] = x.y, m.z[n] = x.z;
      if (u.unwrapped)
        for (int c = 0; c < 2; ++c) {
          double per = u.home1[c] - u.home0[c];
          if (p[c] < u.home0[c]) p[c] += per;
          else if (p[c] > u.home1[c]) p[c] -= per;
        }
      m.node_u[n] = p[0];
      if (d == 2) m.node_v[n] = p[1];
    }
  };

  auto t_opt = Clock::now();
  auto run_units = [&](Kind lo, Kind hi) {
    std::vector<std::size_t> idx;
    for (std::size_t k = 0; k < units.size(); ++k)
      if (units[k].kind >= lo && units[k].kind <= hi) idx.push_back(k);
    arena.execute([&] {
      tbb::parallel_for(tbb::blocked_range<std::size_t>(0, idx.size(), 4), [&](const tbb::blocked_range<std::size_t>& r) {
        for (std::size_t j = r.begin(); j != r.end(); ++j) optimise_unit(shape, m, units[idx[j]], opt);
      });
      tbb::parallel_for(tbb::blocked_range<std::size_t>(0, idx.size(), 16), [&](const tbb::blocked_range<std::size_t>& r) {
        for (std::size_t j = r.begin(); j != r.end(); ++j) apply(idx[j]);
      });
    });
  };
  run_units(Kind::curve_edge, Kind::surface_edge);
  run_units(Kind::face, Kind::face);
  rep.optimise_seconds = since(t_opt);
  for (const auto& u : units) {
    rep.iterations += std::size_t(u.iterations);
    rep.max_unit_iterations = std::max(rep.max_unit_iterations, u.iterations);
  }

  // ── blending (VolumeMethod::blend) ──
  auto t_guard = Clock::now();
  std::vector<Elem> elems;
  for (std::uint32_t bi = 0; bi < m.blocks.size(); ++bi)
    if (model::dimension(m.blocks[bi].shape) == dim)
      for (std::uint32_t e = 0; e < m.blocks[bi].size(); ++e) elems.push_back({bi, e});
  std::vector<char> moves(nn, 0);  // may move: in a unit, or blended from one that may
  for (std::size_t n = 0; n < nn; ++n) moves[n] = unit_of[n] >= 0 && units[unit_of[n]].moved;
  std::vector<Blend> face_blends, elem_blends;
  std::vector<char> blended(nn, 0);
  auto follower = [&](std::uint32_t n) { return !on_cad(n) && !is_vertex[n]; };
  auto add_blend = [&](std::vector<Blend>& out, Shape s, const std::vector<std::uint32_t>& nodes) {
    const Extension& ex = extension(s, P);
    if (ex.interior.empty()) return;
    bool any_src = false, any_dst = false;
    for (int i : ex.boundary) any_src = any_src || moves[nodes[i]];
    for (int i : ex.interior) any_dst = any_dst || (follower(nodes[i]) && !blended[nodes[i]]);
    if (!any_src || !any_dst) return;
    for (int i : ex.interior) blended[nodes[i]] = 1;
    out.push_back({&ex, nodes});
  };
  if (opt.volume == VolumeMethod::blend) {
    if (dim == 3) {
      for (const auto& el : elems) {  // faces first, each once (a face's interior nodes are its own)
        const auto& b = m.blocks[el.block];
        const std::uint32_t* en = b.element(el.index);
        const auto& fv = model::face_vertices(b.shape);
        const auto& fn = model::face_nodes(b.shape, b.order);
        for (std::size_t f = 0; f < fn.size(); ++f) {
          std::vector<std::uint32_t> nodes;
          for (int i : fn[f]) nodes.push_back(en[i]);
          add_blend(face_blends, fv[f].size() == 3 ? Shape::Tri : Shape::Quad, nodes);
        }
      }
      for (std::size_t n = 0; n < nn; ++n) moves[n] = moves[n] || blended[n];
    }
    for (const auto& el : elems) {
      const auto& b = m.blocks[el.block];
      const std::uint32_t* en = b.element(el.index);
      add_blend(elem_blends, b.shape, std::vector<std::uint32_t>(en, en + b.nodes_per_element()));
    }
    for (std::size_t n = 0; n < nn; ++n) moves[n] = moves[n] || blended[n];
  }
  for (std::size_t n = 0; n < nn; ++n) rep.nodes_blended += blended[n] && follower(std::uint32_t(n));
  auto reblend = [&] {
    arena.execute([&] {
      for (auto* list : {&face_blends, &elem_blends})
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, list->size(), 16), [&](const tbb::blocked_range<std::size_t>& r) {
          for (std::size_t j = r.begin(); j != r.end(); ++j) {
            const Blend& bl = (*list)[j];
            const auto& ex = *bl.ext;
            const int nb = int(ex.boundary.size());
            Eigen::MatrixXd D(nb, 3);
            for (int q = 0; q < nb; ++q) {
              std::uint32_t n = bl.nodes[ex.boundary[q]];
              D(q, 0) = m.x[n] - X0[3 * n], D(q, 1) = m.y[n] - X0[3 * n + 1], D(q, 2) = m.z[n] - X0[3 * n + 2];
            }
            Eigen::MatrixXd I = ex.W * D;
            for (int a = 0; a < int(ex.interior.size()); ++a) {
              std::uint32_t n = bl.nodes[ex.interior[a]];
              if (!follower(n)) continue;
              m.x[n] = X0[3 * n] + I(a, 0), m.y[n] = X0[3 * n + 1] + I(a, 1), m.z[n] = X0[3 * n + 2] + I(a, 2);
            }
          }
        });
    });
  };
  reblend();

  // ── validity guard ──
  std::vector<std::size_t> touched;
  for (std::size_t k = 0; k < elems.size(); ++k) {
    const auto& b = m.blocks[elems[k].block];
    const std::uint32_t* en = b.element(elems[k].index);
    for (int i = 0; i < b.nodes_per_element(); ++i)
      if (moves[en[i]]) {
        touched.push_back(k);
        break;
      }
  }
  rep.elements_checked = touched.size();
  // Bezier validity of the listed elements at `coords` (null: the mesh's current nodes), through
  // model::mesh_quality on a mesh of just those elements (its batched evaluation is several
  // times faster than element_quality one by one; results are per element, so deterministic).
  auto check = [&](const std::vector<std::size_t>& list, const std::vector<double>* coords, std::vector<char>& valid,
                   std::vector<double>& sj) {
    valid.assign(list.size(), 1);
    sj.assign(list.size(), 1.0);
    if (list.empty()) return;
    Mesh sub;
    if (coords) {
      sub.x.resize(nn), sub.y.resize(nn), sub.z.resize(nn);
      for (std::size_t n = 0; n < nn; ++n) sub.x[n] = (*coords)[3 * n], sub.y[n] = (*coords)[3 * n + 1], sub.z[n] = (*coords)[3 * n + 2];
    } else {
      sub.x = m.x, sub.y = m.y, sub.z = m.z;
    }
    std::map<std::uint32_t, std::size_t> block_of;  // mesh block -> sub block
    std::vector<std::pair<std::size_t, std::size_t>> where(list.size());
    for (std::size_t j = 0; j < list.size(); ++j) {
      const auto& b = m.blocks[elems[list[j]].block];
      auto it = block_of.find(elems[list[j]].block);
      if (it == block_of.end()) {
        it = block_of.emplace(elems[list[j]].block, sub.blocks.size()).first;
        model::ElementBlock nb;
        nb.shape = b.shape, nb.order = b.order, nb.entity_dim = b.entity_dim, nb.entity_tag = b.entity_tag;
        sub.blocks.push_back(std::move(nb));
      }
      auto& sb = sub.blocks[it->second];
      where[j] = {it->second, sb.size()};
      sb.add(b.element(elems[list[j]].index));
    }
    auto q = arena.execute([&] { return model::mesh_quality(sub, nthreads); });
    for (std::size_t j = 0; j < list.size(); ++j) {
      const auto& e = q[where[j].first][where[j].second];
      valid[j] = e.valid;
      sj[j] = e.scaled_jacobian;
    }
  };
  std::vector<char> valid_before, valid_now;
  std::vector<double> sj_before, sj_now;
  check(touched, &X0, valid_before, sj_before);
  for (char v : valid_before) rep.invalid_before += !v;
  std::vector<std::size_t> pos_in_touched(elems.size(), SIZE_MAX);
  for (std::size_t j = 0; j < touched.size(); ++j) pos_in_touched[touched[j]] = j;
  std::vector<std::vector<std::size_t>> node_elems(nn);  // node -> touched elements (positions)
  for (std::size_t j = 0; j < touched.size(); ++j) {
    const auto& b = m.blocks[elems[touched[j]].block];
    const std::uint32_t* en = b.element(elems[touched[j]].index);
    for (int i = 0; i < b.nodes_per_element(); ++i)
      if (moves[en[i]]) node_elems[en[i]].push_back(j);
  }
  valid_now = valid_before;
  sj_now = sj_before;
  // the patch of a unit: the checked elements with one of its nodes; worst_before[k] = the lowest
  // scaled Jacobian of unit k's patch before optimisation (the quality guard's floor)
  std::vector<double> worst_before(units.size(), INFINITY);
  for (std::size_t j = 0; j < touched.size(); ++j) {
    const auto& b = m.blocks[elems[touched[j]].block];
    const std::uint32_t* en = b.element(elems[touched[j]].index);
    for (int i = 0; i < b.nodes_per_element(); ++i)
      if (unit_of[en[i]] >= 0) worst_before[unit_of[en[i]]] = std::min(worst_before[unit_of[en[i]]], sj_before[j]);
  }
  std::vector<std::size_t> recheck(touched.size());
  for (std::size_t j = 0; j < touched.size(); ++j) recheck[j] = j;
  std::vector<char> backtracked(units.size(), 0), worsened(units.size(), 0);
  while (true) {
    std::vector<std::size_t> list;
    for (auto j : recheck) list.push_back(touched[j]);
    std::vector<char> v;
    std::vector<double> q;
    check(list, nullptr, v, q);
    for (std::size_t i = 0; i < recheck.size(); ++i) valid_now[recheck[i]] = v[i], sj_now[recheck[i]] = q[i];
    if (!opt.keep_valid && !opt.keep_quality) break;
    std::vector<char> mark(units.size(), 0);
    bool bad = false;
    for (auto j : recheck) {
      const auto& b = m.blocks[elems[touched[j]].block];
      const std::uint32_t* en = b.element(elems[touched[j]].index);
      // validity: a valid element became invalid -> every unit with a node in it backs off
      const bool inverted = opt.keep_valid && valid_before[j] && !valid_now[j];
      // quality: the element is now below the worst before of the patches of all the units
      // that move it (any of them may have done it) -> every unit with a node in it backs off
      double floor = INFINITY;
      for (int i = 0; i < b.nodes_per_element(); ++i)
        if (unit_of[en[i]] >= 0) floor = std::min(floor, worst_before[unit_of[en[i]]]);
      const bool worse = opt.keep_quality && sj_now[j] < floor;
      bool movable = false;  // an inverted element has a unit that can still back off
      for (int i = 0; i < b.nodes_per_element(); ++i) {
        const int k = unit_of[en[i]];
        if (k < 0 || units[k].alpha == 0) continue;
        movable = true;
        if (mark[k] || !(inverted || worse)) continue;
        mark[k] = 1, bad = true;
        if (!inverted) worsened[k] = 1;
      }
      if (inverted && !movable)  // cannot happen: an element whose units are all at alpha 0 is exactly as before
        throw std::logic_error("optimise: validity guard found no unit to backtrack");
    }
    if (!bad) break;
    ++rep.guard_rounds;
    std::vector<double> before(3 * nn);
    for (std::size_t n = 0; n < nn; ++n) before[3 * n] = m.x[n], before[3 * n + 1] = m.y[n], before[3 * n + 2] = m.z[n];
    for (std::size_t k = 0; k < units.size(); ++k)
      if (mark[k]) {
        backtracked[k] = 1;
        units[k].alpha = units[k].alpha > 0.125 ? units[k].alpha * 0.5 : 0.0;
        apply(k);
      }
    reblend();
    std::vector<char> flag(touched.size(), 0);
    recheck.clear();
    for (std::size_t n = 0; n < nn; ++n)
      if (m.x[n] != before[3 * n] || m.y[n] != before[3 * n + 1] || m.z[n] != before[3 * n + 2])
        for (auto j : node_elems[n])
          if (!flag[j]) flag[j] = 1, recheck.push_back(j);
    std::sort(recheck.begin(), recheck.end());
  }
  for (char v : valid_now) rep.invalid_after += !v;
  for (double q : sj_before) rep.min_sj_before = std::min(rep.min_sj_before, q);
  for (double q : sj_now) rep.min_sj_after = std::min(rep.min_sj_after, q);
  for (char w : worsened) rep.quality_backtracked_units += w;
  for (std::size_t k = 0; k < units.size(); ++k) {
    rep.backtracked_units += backtracked[k];
    rep.reverted_units += backtracked[k] && units[k].alpha == 0;
  }
  rep.guard_seconds = since(t_guard);

  // ── report: energies, moved nodes, distance to the CAD (independent projection) ──
  for (std::size_t n = 0; n < nn; ++n) X[3 * n] = m.x[n], X[3 * n + 1] = m.y[n], X[3 * n + 2] = m.z[n];
  for (const auto& u : units) {
    rep.energy_before += unit_energy(u, X0);
    rep.energy_after += unit_energy(u, X);
    if (!u.moved || u.alpha == 0) continue;
    for (auto n : u.free) {
      if (X[3 * n] == X0[3 * n] && X[3 * n + 1] == X0[3 * n + 1] && X[3 * n + 2] == X0[3 * n + 2]) continue;
      ++rep.nodes_moved;
      cad::Vec3 p{m.x[n], m.y[n], m.z[n]};
      double dist = u.kind == Kind::curve_edge ? shape.project_to_edge(u.entity, p, m.node_u[n]).distance
                                               : shape.project_to_face(u.entity, p, cad::Vec2{m.node_u[n], m.node_v[n]}).distance;
      rep.max_cad_distance = std::max(rep.max_cad_distance, dist);
    }
  }
  rep.seconds = since(t_start);
  return rep;
}

}  // namespace meshflow::optimise
