// The balance stage: builds the interval-assignment problem from the shell's block structure
// and the CAD (targets from the turn-angle sizing), solves it (ip_solve.cpp, lp_solve) and
// writes the "divisions" artifact. No foreign library here: the CAD through cad.hpp.
#include "balance.hpp"

#include "engine/stage.hpp"
#include "stages/cad/cad.hpp"
#include "stages/cad/vec3.hpp"
#include "stages/shell/shell.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <optional>
#include <array>
#include <chrono>
#include <cmath>
#include <iterator>
#include <map>
#include <set>
#include <sstream>

namespace meshflow::balance {
namespace {

using namespace cad::vec;  // V3, v3, add, sub, mul, dot, cross, norm
double now() { return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count(); }

constexpr int kSamples = 256;  // sub-intervals per CAD edge (Simpson) and per sampled curve

struct Sizing {
  double theta = 0, hmin = 0, hmax = 0;
  double h(double kappa) const {
    double rho_h = kappa > 0 ? theta / kappa : hmax;
    return std::clamp(rho_h, hmin, hmax);
  }
};

// A CAD edge tabulated for targets and sizing-graded node placement.
struct CadEdgeTable {
  std::vector<double> t, s;  // parameters and cumulative arc length at kSamples+1 points
  std::vector<double> c;     // cumulative target (integral of ds / h) at the same points
  double length = 0, target = 0;
  double width = INFINITY;  // of the faces across the edge (width_across), when finite
  int min_n = 1;            // divisions the width asks for at least (balance.hpp, "Targets")
  bool width_capped = false;  // the width asked for more than kWidthCap x the target
};

// The least distance from edge e to the other edges of its faces that share no vertex with it,
// below `limit` (edge boxes farther apart are skipped), else INFINITY. Sampled at 17 points of e.
double width_across(const cad::Shape& shape, int e, double limit) {
  if (shape.edge_degenerate(e)) return INFINITY;
  auto ve = shape.edge_vertices(e);
  auto be = shape.edge_box(e);
  cad::Range r = shape.edge_range(e);
  double w = INFINITY;
  for (int f : shape.edge_faces(e))
    for (int e2 : shape.face_edges(f)) {
      if (e2 == e || shape.edge_degenerate(e2) || shape.edge_is_seam(e2, f)) continue;
      auto v2 = shape.edge_vertices(e2);
      bool share = false;
      for (int a : ve)
        for (int b : v2) share |= a >= 0 && a == b;
      if (share) continue;
      auto b2 = shape.edge_box(e2);
      double gap2 = 0;
      for (int k = 0; k < 3; ++k) {
        double g = std::max({0.0, b2.lo[k] - be.hi[k], be.lo[k] - b2.hi[k]});
        gap2 += g * g;
      }
      if (std::sqrt(gap2) >= std::min(limit, w)) continue;
      std::optional<double> hint;
      for (int i = 0; i <= 16; ++i) {
        auto pr = shape.project_to_edge(e2, shape.edge_point(e, r.lo + (r.hi - r.lo) * i / 16), hint);
        hint = pr.t;
        w = std::min(w, pr.distance);
      }
    }
  return w < limit ? w : INFINITY;
}
constexpr double kWidthSag = 0.25;  // chord sag allowed, x the width of the faces across an edge
constexpr double kWidthCap = 32;    // the width's minimum divisions, at most this x the edge's target
constexpr double kWidthCapLeast = 256;  // ... or this many, the larger (a pipe coupling's chamfer asks 126 for 13)

CadEdgeTable tabulate(const cad::Shape& shape, int e, const Sizing& S) {
  CadEdgeTable T;
  cad::Range r = shape.edge_range(e);
  // A seam of a wall face (Rotor 67's blade: its seam runs up the leading edge) is nearly
  // straight, but the surface turns sharply across it: the triangles beside it are only as good
  // as its divisions, so the surface's largest principal curvature there counts too.
  int seam_face = -1;
  for (int f : shape.edge_faces(e))
    if (shape.face_tag(f) == cad::Tag::wall && shape.edge_is_seam(e, f)) seam_face = f;
  auto speed_kappa = [&](double t, double& sp) {
    cad::CurveDeriv d = shape.edge_eval(e, t);
    V3 d1 = v3(d.d1), d2 = v3(d.d2);
    sp = norm(d1);
    double k = sp > 0 ? norm(cross(d1, d2)) / (sp * sp * sp) : 0.0;
    if (seam_face >= 0) {
      auto uv = shape.edge_uv(e, seam_face, t, false);
      auto c = shape.face_curvature(seam_face, uv.u, uv.v);
      if (c.defined) k = std::max({k, std::abs(c.k1), std::abs(c.k2)});
    }
    return k;
  };
  T.width = width_across(shape, e, 4 * S.hmax);
  double nw = 0;  // integral of ds sqrt(k / (8 kWidthSag W))
  auto wrate = [&](double k) { return std::isfinite(T.width) && k > 0 ? std::sqrt(k / (8 * kWidthSag * T.width)) : 0.0; };
  double dt = (r.hi - r.lo) / kSamples, s = 0, n = 0;
  T.t.push_back(r.lo), T.s.push_back(0), T.c.push_back(0);
  double sp0, k0 = speed_kappa(r.lo, sp0);
  auto tangent = [&](double t) { return v3(shape.edge_eval(e, t).d1); };
  for (int i = 0; i < kSamples; ++i) {
    double a0 = r.lo + i * dt, b0 = i + 1 == kSamples ? r.hi : a0 + dt;
    // A sub-interval over which the curve turns by more than 20 degrees is split in 32: a
    // leading edge much smaller than the edge (Rotor 67's blade root: radius ~1e-3 of a 0.66
    // long closed curve, the nose inside 2 of 256 uniform sub-intervals) would otherwise be
    // missed by Simpson's rule and get far too few divisions.
    V3 ta = tangent(a0), tb = tangent(b0);
    int sub = 1;
    if (norm(ta) > 0 && norm(tb) > 0 && dot(ta, tb) < std::cos(20 * M_PI / 180) * norm(ta) * norm(tb)) sub = 32;
    for (int q = 0; q < sub; ++q) {
      double a = a0 + (b0 - a0) * q / sub, b = q + 1 == sub ? b0 : a0 + (b0 - a0) * (q + 1) / sub;
      double spm, km = speed_kappa(0.5 * (a + b), spm), sp1, k1 = speed_kappa(b, sp1);
      s += (b - a) / 6 * (sp0 + 4 * spm + sp1);
      n += (b - a) / 6 * (sp0 / S.h(k0) + 4 * spm / S.h(km) + sp1 / S.h(k1));
      nw += (b - a) / 6 * (sp0 * wrate(k0) + 4 * spm * wrate(km) + sp1 * wrate(k1));
      T.t.push_back(b), T.s.push_back(s), T.c.push_back(n);
      sp0 = sp1, k0 = k1;
    }
  }
  T.length = s, T.target = n;
  // A width that all but vanishes (two edges of a face touching at a point: a machined part's
  // tangent fillet meets its neighbour's rim) would ask for millions of divisions (the angled
  // base clamp: 1.5e7 on one edge, 195 M in all, 11 GB before sweep); the bound holds where the
  // face is narrow along the edge (the DLR-F6 nacelle ring asks for a few times its target, a
  // pipe coupling's 0.01 wide chamfer 126 for a target of 13), so it is capped at kWidthCap
  // times the target or kWidthCapLeast, the larger.
  const double cap = std::max(kWidthCapLeast, kWidthCap * std::max(1.0, std::ceil(n)));
  T.width_capped = nw > cap;
  T.min_n = std::max(1, static_cast<int>(std::ceil(std::min(nw, cap) - 1e-9)));
  return T;
}

// Parameters of n+1 nodes at equal increments of the target integral (ds / h): nodes are
// graded by the sizing (dense where the curvature rule asks, e.g. around a leading edge), as
// the integer program's targets assume; equal arc length where h is constant.
std::vector<double> arc_nodes(const CadEdgeTable& T, int n) {
  std::vector<double> out;
  std::size_t j = 0;
  const std::vector<double>& C = T.c.back() > 0 ? T.c : T.s;
  for (int k = 0; k <= n; ++k) {
    if (k == 0) { out.push_back(T.t.front()); continue; }
    if (k == n) { out.push_back(T.t.back()); continue; }
    double s = C.back() * k / n;
    while (j + 2 < C.size() && C[j + 1] < s) ++j;
    double f = C[j + 1] > C[j] ? (s - C[j]) / (C[j + 1] - C[j]) : 0;
    out.push_back(T.t[j] + f * (T.t[j + 1] - T.t[j]));
  }
  return out;
}

// Length and target of a sampled 3D curve (discrete curvature: turning angle per length).
std::pair<double, double> polyline_target(const std::vector<V3>& P, const Sizing& S) {
  std::size_t m = P.size();
  if (m < 2) return {0, 0};
  std::vector<double> l(m - 1), kap(m, 0.0);
  for (std::size_t i = 0; i + 1 < m; ++i) l[i] = norm(sub(P[i + 1], P[i]));
  for (std::size_t i = 1; i + 1 < m; ++i) {
    V3 a = sub(P[i], P[i - 1]), b = sub(P[i + 1], P[i]);
    double na = norm(a), nb = norm(b);
    if (na <= 0 || nb <= 0) continue;
    double ang = std::atan2(norm(cross(a, b)), dot(a, b));
    kap[i] = ang / (0.5 * (na + nb));
  }
  double L = 0, n = 0;
  for (std::size_t i = 0; i + 1 < m; ++i) {
    L += l[i];
    n += l[i] / S.h(0.5 * (kap[i] + kap[i + 1]));
  }
  return {L, n};
}

struct Named {
  std::string kind;  // wall shell junction cross periodic
  int cad = -1;
};

Named classify(const std::string& name) {
  auto num = [&](std::size_t from) {
    std::size_t end = from;
    while (end < name.size() && std::isdigit(static_cast<unsigned char>(name[end]))) ++end;
    if (end == from) throw StageError("balance: the shell names an edge '" + name + "' this version does not understand; re-run shell or update balance");
    return std::stoi(name.substr(from, end - from));
  };
  if (name.empty()) throw StageError("balance: the shell has an empty edge name");
  switch (name[0]) {
    case 'w': return {"wall", num(1)};
    case 's': return {"shell", num(1)};
    case 'j': return {"junction", num(1)};
    case 'x': return {"cross", num(1)};
    case 'e': return {"periodic", num(1)};
  }
  throw StageError("balance: the shell names an edge '" + name + "' this version does not understand; re-run shell or update balance");
}

class Stage {
 public:
  explicit Stage(StageContext& c) : ctx(c) {}

  void run() {
    double t0 = now();
    const nlohmann::json& P = ctx.params();
    shape = cad::Shape::load(ctx.input("shape").path);
    shell::ShellData sd = shell::read(ctx.input("shell").path);
    nlohmann::json H = nlohmann::json::parse(sd.header);
    const nlohmann::json& blocks = H.at("blocks");

    // sizing, relative to the walls' bounding box unless lengths are asked for
    double Lref = 1;
    if (P.at("sizes_relative_to") == "wall_box") {
      V3 lo{INFINITY, INFINITY, INFINITY}, hi{-INFINITY, -INFINITY, -INFINITY};
      for (int f : shape.faces_with_tag(cad::Tag::wall)) {
        auto b = shape.face_box(f);
        for (int k = 0; k < 3; ++k) lo[k] = std::min(lo[k], b.lo[k]), hi[k] = std::max(hi[k], b.hi[k]);
      }
      if (!(hi[0] >= lo[0])) throw StageError("balance: the shape has no wall face; sizes_relative_to: wall_box needs walls (use sizes_relative_to: length)");
      Lref = std::max({hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]});
    }
    S.theta = P.at("turn_angle_deg").get<double>() * M_PI / 180;
    S.hmin = P.at("min_size").get<double>() * Lref;
    S.hmax = P.at("max_size").get<double>() * Lref;
    if (S.hmin > S.hmax)
      throw StageError("balance: min_size (" + std::to_string(P.at("min_size").get<double>()) + ") is larger than max_size (" +
                       std::to_string(P.at("max_size").get<double>()) + "); make min_size <= max_size");

    // ── unknowns and constraints from the blocks ──
    auto add_group = [&](std::string name, std::string kind, const std::vector<std::string>& names, std::optional<int> value = {}) {
      IPGroup g;
      g.name = std::move(name), g.kind = std::move(kind), g.value = value;
      for (auto& n : names) g.edges.push_back(var(n));
      prob.groups.push_back(std::move(g));
    };
    for (const auto& b : blocks) {
      std::string kind = b.at("kind");
      if (kind == "prism_sweep") {
        std::string bn = "prism_sweep face " + std::to_string(b.at("face").get<int>());
        for (auto& n : b.at("edges")) var(n.get<std::string>());
        for (auto& g : b.at("equal")) add_group(bn + ": equal " + g.dump(), "equal", g.get<std::vector<std::string>>());
      } else if (kind == "hex_junction") {
        int e = b.at("edge");
        std::string s = std::to_string(e), bn = "hex_junction edge " + s;
        for (auto& g : b.at("equal")) add_group(bn + ": equal " + g.dump(), "equal", g.get<std::vector<std::string>>());
        junctions[e] = &b;
        bool partner_wall = b.value("partner_tag", "") == "wall";
        for (int end : {0, 1}) {
          std::string x = "x" + s + "." + std::to_string(end) + ".";
          add_group(bn + ": layer " + x + "ac (one-layer sweep of face A)", "layer", {x + "ac"}, 1);
          if (partner_wall) add_group(bn + ": layer " + x + "bc (one-layer sweep of wall partner B)", "layer", {x + "bc"}, 1);
          add_group(bn + ": even end cap " + std::to_string(end), "even", {x + "0a", x + "ac", x + "bc", x + "0b"});
        }
        std::string x0 = "x" + s + ".0.", x1 = "x" + s + ".1.";
        add_group(bn + ": even strip on A", "even", {"w" + s, x0 + "0a", "j" + s + "a", x1 + "0a"});
        add_group(bn + ": even strip on B", "even", {"w" + s, x0 + "0b", "j" + s + "b", x1 + "0b"});
        add_group(bn + ": even outer strip A", "even", {"j" + s + "a", x0 + "ac", "j" + s + "c", x1 + "ac"});
        add_group(bn + ": even outer strip B", "even", {"j" + s + "b", x0 + "bc", "j" + s + "c", x1 + "bc"});
      } else {
        throw StageError("balance: the shell has a block of kind '" + kind + "' this version does not know; update balance or re-run shell");
      }
    }
    periodic_pairs(add_group);
    if (prob.edges.empty()) throw StageError("balance: the shell defines no block edge (no wall face?); nothing to balance");
    prob.timeout_s = P.at("timeout_s").get<double>();

    // ── targets ──
    ctx.progress(0.1, "targets");
    std::vector<double> length(prob.edges.size(), 0);
    for (std::size_t i = 0; i < prob.edges.size(); ++i) {
      auto [L, t] = measure(prob.edges[i].name, sd);
      length[i] = L;
      prob.edges[i].target = std::max(t, 1.0);  // every edge needs one division: a shorter one is not 'off target'
      Named nm = classify(prob.edges[i].name);
      if (nm.kind == "wall") prob.edges[i].min_n = table(nm.cad).min_n;
    }

    // ── solve ──
    ctx.progress(0.4, "integer program");
    IPSolution sol = solve_intervals(prob, [&](const std::string& s) { ctx.log(s); });

    // ── nodes and artifact ──
    ctx.progress(0.8, "nodes");
    Divisions D;
    D.units = shape.units();
    D.params_json = P.dump();
    nlohmann::json C = nlohmann::json::array();
    std::map<std::string, long> nkind;
    for (const IPGroup& g : prob.groups) {
      nlohmann::json names = nlohmann::json::array();
      for (int e : g.edges) names.push_back(prob.edges[e].name);
      nlohmann::json c = {{"name", g.name}, {"kind", g.kind}, {"edges", names}};
      if (g.value) c["value"] = *g.value;
      C.push_back(c);
      ++nkind[g.kind];
    }
    D.constraints_json = C.dump();
    std::vector<int> order(prob.edges.size());
    for (std::size_t i = 0; i < order.size(); ++i) order[i] = static_cast<int>(i);
    std::sort(order.begin(), order.end(), [&](int a, int b) { return prob.edges[a].name < prob.edges[b].name; });
    long total = 0;
    std::string worst;
    double worst_dev = -1;
    for (int i : order) {
      EdgeDivision d;
      d.name = prob.edges[i].name;
      Named nm = classify(d.name);
      d.kind = nm.kind, d.cad_edge = nm.cad, d.n = sol.n[i], d.target = prob.edges[i].target, d.length = length[i];
      if (nm.kind == "cross") {
        d.param = "fraction";
        for (int k = 0; k <= d.n; ++k) d.nodes.push_back(static_cast<double>(k) / d.n);
      } else {
        d.param = "cad";
        d.nodes = arc_nodes(table(nm.cad), d.n);
      }
      total += d.n;
      double dev = std::abs(d.n - d.target) / d.target;
      if (dev > worst_dev) worst_dev = dev, worst = d.name;
      D.edges.push_back(std::move(d));
    }
    nlohmann::json cst = nlohmann::json::object();
    for (auto& [k, v] : nkind) cst[k] = v;
    cst["total"] = prob.groups.size();
    nlohmann::json wl = nlohmann::json::array();  // wall edges the width of their faces gave a minimum
    for (auto& [e, T] : tables)
      if (T.min_n > 1)
        wl.push_back({{"edge", e}, {"width", T.width}, {"min_divisions", T.min_n}, {"capped", T.width_capped}});
    nlohmann::json st = {{"edges", prob.edges.size()},
                         {"constraints", cst},
                         {"total_divisions", total},
                         {"total_deviation", sol.total_deviation},
                         {"max_rel_deviation", sol.max_rel_deviation},
                         {"max_rel_deviation_edge", worst},
                         {"objective", sol.objective},
                         {"optimal", sol.optimal},
                         {"rows", sol.rows},
                         {"columns", sol.columns},
                         {"size_min", S.hmin},
                         {"size_max", S.hmax},
                         {"width_limited_edges", wl},
                         {"node_placement", "equal increments of the sizing integral (least-squares skew reduction not done)"}};
    D.stats_json = st.dump();  // deterministic part only: no times in the artifact
    write(D, ctx.output("divisions", "divisions"));

    auto& out = ctx.stats();
    for (auto& [k, v] : st.items()) out[k] = v;
    out["bb_nodes"] = sol.bb_nodes;
    out["solve_time"] = sol.solve_time;
    out["time"] = now() - t0;
    ctx.log("balance: " + std::to_string(prob.edges.size()) + " edges, " + std::to_string(total) + " divisions, total deviation " +
            std::to_string(sol.total_deviation) + ", max relative deviation " + std::to_string(sol.max_rel_deviation) + " (" + worst + ")");
    ctx.progress(1.0, "done");
  }

 private:
  StageContext& ctx;
  cad::Shape shape;
  Sizing S;
  IPProblem prob;
  std::map<std::string, int> index;
  std::map<int, const nlohmann::json*> junctions;
  std::map<int, CadEdgeTable> tables;

  int var(const std::string& name) {
    auto it = index.find(name);
    if (it != index.end()) return it->second;
    classify(name);
    int i = static_cast<int>(prob.edges.size());
    prob.edges.push_back({name, 1.0, 1.0});
    index.emplace(name, i);
    return i;
  }

  const CadEdgeTable& table(int e) {
    auto it = tables.find(e);
    if (it == tables.end()) it = tables.emplace(e, tabulate(shape, e, S)).first;
    return it->second;
  }

  const nlohmann::json& junction(int e, const std::string& name) {
    auto it = junctions.find(e);
    if (it == junctions.end())
      throw StageError("balance: the shell names '" + name + "' but has no hex_junction block for edge " + std::to_string(e) + "; re-run shell");
    return *it->second;
  }

  // {length, target} of a named edge.
  std::pair<double, double> measure(const std::string& name, const shell::ShellData& sd) {
    Named nm = classify(name);
    if (nm.kind == "wall" || nm.kind == "periodic") {
      const CadEdgeTable& T = table(nm.cad);
      return {T.length, T.target};
    }
    if (nm.kind == "shell") {
      const CadEdgeTable& T = table(nm.cad);
      std::vector<V3> pts;
      for (double t : T.t) {
        auto [th, d] = sd.edge_field(nm.cad, t);
        pts.push_back(add(v3(shape.edge_point(nm.cad, t)), mul(V3{d[0], d[1], d[2]}, th)));
      }
      auto lt = polyline_target(pts, S);
      // the shell image of a wall seam is swept from the seam's nodes: it needs the seam's
      // resolution (across the surface, see tabulate), which its own polyline does not see
      for (int f : shape.edge_faces(nm.cad))
        if (shape.face_tag(f) == cad::Tag::wall && shape.edge_is_seam(nm.cad, f)) lt.second = std::max(lt.second, T.target);
      return lt;
    }
    const nlohmann::json& st = junction(nm.cad, name).at("stations");
    if (st.size() < 2) throw StageError("balance: hex_junction block of edge " + std::to_string(nm.cad) + " has fewer than 2 stations; re-run shell");
    auto pt = [&](const nlohmann::json& s, const char* key) {
      auto a = s.at(key).get<std::vector<double>>();
      return V3{a.at(0), a.at(1), a.at(2)};
    };
    if (nm.kind == "junction") {
      const char* key = name.back() == 'a' ? "PA" : name.back() == 'b' ? "PB" : "PC";
      std::vector<V3> pts;
      for (auto& s : st) pts.push_back(pt(s, key));
      return polyline_target(pts, S);
    }
    // cross-section "x<e>.<end>.<side>": a straight segment at the first/last station
    auto dot1 = name.find('.');
    if (dot1 == std::string::npos || name.size() < dot1 + 5) throw StageError("balance: malformed cross-section edge name '" + name + "'");
    const nlohmann::json& s = name[dot1 + 1] == '0' ? st.front() : st.back();
    std::string side = name.substr(dot1 + 3);
    static const std::map<std::string, std::pair<const char*, const char*>> ends = {
        {"0a", {"P0", "PA"}}, {"0b", {"P0", "PB"}}, {"ac", {"PA", "PC"}}, {"bc", {"PB", "PC"}}};
    auto it = ends.find(side);
    if (it == ends.end()) throw StageError("balance: malformed cross-section edge name '" + name + "'");
    double L = norm(sub(pt(s, it->second.second), pt(s, it->second.first)));
    return {L, L / S.hmax};
  }

  // Periodic partners: every CAD edge of a periodic_lo face paired with the periodic_hi edge it
  // maps onto under one rigid map (a translation, or a rotation about the x, y or z axis).
  template <class AddGroup>
  void periodic_pairs(AddGroup& add_group) {
    std::set<int> lo, hi;
    for (int f : shape.faces_with_tag(cad::Tag::periodic_lo))
      for (int e : shape.face_edges(f))
        if (!shape.edge_degenerate(e)) lo.insert(e);
    for (int f : shape.faces_with_tag(cad::Tag::periodic_hi))
      for (int e : shape.face_edges(f))
        if (!shape.edge_degenerate(e)) hi.insert(e);
    std::vector<int> both;  // an edge on both sides (e.g. on the axis of a sector) is its own partner
    std::set_intersection(lo.begin(), lo.end(), hi.begin(), hi.end(), std::back_inserter(both));
    for (int e : both) lo.erase(e), hi.erase(e);
    if (lo.empty() && hi.empty()) return;
    if (lo.size() != hi.size())
      throw StageError("balance: " + std::to_string(lo.size()) + " edges on periodic_lo faces but " + std::to_string(hi.size()) +
                       " on periodic_hi faces; the periodic sides must have the same edges (check the geometry's tags)");
    auto ends = [&](int e) {
      auto v = shape.edge_vertices(e);
      return std::array<V3, 2>{v3(shape.vertex_point(v[0])), v3(shape.vertex_point(v[1]))};
    };
    V3 clo{0, 0, 0}, chi{0, 0, 0};
    for (int e : lo) for (auto& p : ends(e)) clo = add(clo, mul(p, 0.5 / lo.size()));
    for (int e : hi) for (auto& p : ends(e)) chi = add(chi, mul(p, 0.5 / hi.size()));
    auto box = shape.box(ctx.threads());  // the faces' boxes in parallel
    double tol = 1e-6 * norm(sub(v3(box.hi), v3(box.lo)));
    std::vector<std::pair<std::string, std::function<V3(V3)>>> maps;
    V3 T = sub(chi, clo);
    maps.push_back({"translation", [T](V3 p) { return add(p, T); }});
    for (int ax = 0; ax < 3; ++ax) {
      int i = (ax + 1) % 3, j = (ax + 2) % 3;
      double phi = std::atan2(chi[j], chi[i]) - std::atan2(clo[j], clo[i]);
      double c = std::cos(phi), s = std::sin(phi);
      maps.push_back({std::string("rotation about ") + "xyz"[ax], [=](V3 p) {
                        V3 q = p;
                        q[i] = c * p[i] - s * p[j];
                        q[j] = s * p[i] + c * p[j];
                        return q;
                      }});
    }
    for (auto& [what, F] : maps) {
      std::vector<std::pair<int, int>> pairs;
      std::set<int> used;
      for (int a : lo) {
        auto pa = ends(a);
        V3 m0 = F(pa[0]), m1 = F(pa[1]);
        int found = -1;
        for (int b : hi) {
          if (used.count(b)) continue;
          auto pb = ends(b);
          bool same = (norm(sub(m0, pb[0])) < tol && norm(sub(m1, pb[1])) < tol) ||
                      (norm(sub(m0, pb[1])) < tol && norm(sub(m1, pb[0])) < tol);
          if (same && std::abs(shape.edge_length(a) - shape.edge_length(b)) < tol * 10) { found = b; break; }
        }
        if (found < 0) break;
        used.insert(found);
        pairs.push_back({a, found});
      }
      if (pairs.size() != lo.size()) continue;
      ctx.log("balance: periodic sides related by a " + what + " (" + std::to_string(pairs.size()) + " edge pairs)");
      auto name_of = [&](int e) {
        std::string num = std::to_string(e), w = std::string("w").append(num);
        return index.count(w) ? w : std::string("e").append(num);
      };
      for (auto [a, b] : pairs)
        add_group("periodic " + name_of(a) + " ~ " + name_of(b), "periodic", {name_of(a), name_of(b)});
      return;
    }
    throw StageError("balance: no translation or rotation about a coordinate axis maps the edges of the periodic_lo faces onto those of "
                     "the periodic_hi faces (tolerance " + std::to_string(tol) + "); check the periodic tags of the geometry");
  }
};

void run(StageContext& ctx) {
  Stage s(ctx);
  s.run();
}

StageRegistrar reg({.kind = "balance",
                    .version = 3,  // 3: the width minimum capped at max(256, 32 x the target) (width_limited_edges[].capped)
                    .summary = "interval assignment (integer program, lp_solve): divisions per block edge from the turn-angle sizing, equal/periodic/parity constraints",
                    .libraries = {lp_solve_version()},
                    .needs = {"shape", "shell"},
                    .produces = {{"divisions", "divisions"}},
                    .run = run});

}  // namespace
}  // namespace meshflow::balance
