// The interval-assignment integer program with lp_solve 5.5. The ONLY translation unit of the
// project that includes lp_lib.h (it defines REAL, TRUE, FALSE): no OCCT/CGAL/TetGen here,
// and no lp_solve type leaves this file.
#include "balance.hpp"

#include <lpsolve/lp_lib.h>

#include <chrono>
#include <cmath>
#include <map>
#include <memory>
#include <sstream>
#include <stdexcept>

namespace meshflow::balance {
namespace {

using Log = std::function<void(const std::string&)>;

void lp_log(lprec*, void* handle, char* buf) {
  auto* log = static_cast<const Log*>(handle);
  if (log && *log && buf) {
    std::string s(buf);
    while (!s.empty() && (s.back() == '\n' || s.back() == '\r')) s.pop_back();
    if (!s.empty()) (*log)("lp_solve: " + s);
  }
}

struct LpDeleter {
  void operator()(lprec* lp) const { delete_lp(lp); }
};
using LpPtr = std::unique_ptr<lprec, LpDeleter>;

struct Result {
  int status = NOTRUN;
  std::vector<int> n;  // per edge (filled when feasible)
  long bb_nodes = 0;
  long rows = 0, columns = 0;
  int failed_component = -1;  // infeasible: a component (index into comp_groups) that is
  std::vector<std::vector<int>> comp_groups;  // active groups per component
};

int find(std::vector<int>& u, int a) {
  while (u[a] != a) a = u[a] = u[u[a]];
  return a;
}
void unite(std::vector<int>& u, int a, int b) {
  a = find(u, a), b = find(u, b);
  if (a != b) u[std::max(a, b)] = std::min(a, b);  // smallest index is the root: deterministic
}

// Solves the program with the groups `active`. Equal and periodic groups are substituted
// (one integer column per class of edges they join), and the problem splits into
// independent components (classes joined by parity loops), each solved by lp_solve on its own:
// one big branch and bound over independent parts prunes badly (the gap of each part adds
// up), small exact ones do not. feasibility_only: zero objective (infeasibility diagnosis).
Result solve_active(const IPProblem& p, const std::vector<char>& active, bool feasibility_only, const Log& log) {
  const int E = static_cast<int>(p.edges.size());
  const int G = static_cast<int>(p.groups.size());
  std::vector<int> cls(E);
  for (int e = 0; e < E; ++e) cls[e] = e;
  for (int g = 0; g < G; ++g)
    if (active[g] && (p.groups[g].kind == "equal" || p.groups[g].kind == "periodic"))
      for (int e : p.groups[g].edges) unite(cls, e, p.groups[g].edges[0]);
  std::vector<int> comp(E);
  for (int e = 0; e < E; ++e) comp[e] = find(cls, e);
  // A parity row in which every class appears an even number of times (the loop of a
  // structured quad face: 2a + 2b) holds for any n: it is left out (it would only couple parts).
  std::vector<char> use(active.begin(), active.end());
  for (int g = 0; g < G; ++g)
    if (use[g] && p.groups[g].kind == "even") {
      std::map<int, int> mult;
      for (int e : p.groups[g].edges) ++mult[find(cls, e)];
      bool odd = false;
      for (auto& [c, m] : mult) odd |= (m % 2) != 0;
      if (!odd) use[g] = 0;
    }
  for (int g = 0; g < G; ++g)
    if (use[g] && !p.groups[g].edges.empty())
      for (int e : p.groups[g].edges) unite(comp, find(comp, e), find(comp, p.groups[g].edges[0]));
  // components in order of their smallest edge; edges and groups per component
  std::map<int, int> comp_index;
  std::vector<std::vector<int>> comp_edges;
  Result r;
  for (int e = 0; e < E; ++e) {
    int c = find(comp, e);
    auto [it, fresh] = comp_index.emplace(c, static_cast<int>(comp_edges.size()));
    if (fresh) comp_edges.emplace_back(), r.comp_groups.emplace_back();
    comp_edges[it->second].push_back(e);
  }
  for (int g = 0; g < G; ++g)
    if (use[g] && !p.groups[g].edges.empty()) r.comp_groups[comp_index.at(find(comp, p.groups[g].edges[0]))].push_back(g);
  r.n.assign(E, 0);
  for (std::size_t c = 0; c < comp_edges.size(); ++c) {
    const std::vector<int>& edges = comp_edges[c];
    // columns: one n per class, then p_e, m_e per edge, then k per even group
    std::map<int, int> col;  // class root -> column
    for (int e : edges) col.emplace(find(cls, e), 0);
    int ncol = 0;
    for (auto& [root, cc] : col) cc = ++ncol;
    std::map<int, int> pcol;
    for (int e : edges) pcol[e] = ncol + 1, ncol += 2;
    std::map<int, int> kcol;
    for (int g : r.comp_groups[c])
      if (p.groups[g].kind == "even") kcol[g] = ++ncol;
    LpPtr lp(make_lp(0, ncol));
    if (!lp) throw std::runtime_error("balance: lp_solve could not allocate the problem (make_lp failed)");
    lprec* L = lp.get();
    set_verbose(L, NEUTRAL);
    put_logfunc(L, lp_log, const_cast<Log*>(&log));
    set_add_rowmode(L, TRUE);
    long rows = 0;
    for (int e : edges) {  // n_class(e) - p_e + m_e = t_e
      REAL v[3] = {1, -1, 1};
      int cc[3] = {col.at(find(cls, e)), pcol.at(e), pcol.at(e) + 1};
      add_constraintex(L, 3, v, cc, EQ, p.edges[e].target), ++rows;
    }
    for (int g : r.comp_groups[c]) {
      const IPGroup& Gr = p.groups[g];
      if (Gr.kind == "even") {
        std::map<int, REAL> coef;
        for (int e : Gr.edges) coef[col.at(find(cls, e))] += 1;
        std::vector<REAL> v;
        std::vector<int> cc;
        for (auto& [k, x] : coef) cc.push_back(k), v.push_back(x);
        cc.push_back(kcol.at(g)), v.push_back(-2);
        add_constraintex(L, static_cast<int>(v.size()), v.data(), cc.data(), EQ, 0), ++rows;
      } else if (Gr.value) {
        for (int e : Gr.edges) {
          REAL v[1] = {1};
          int cc[1] = {col.at(find(cls, e))};
          add_constraintex(L, 1, v, cc, EQ, *Gr.value), ++rows;
        }
      }
    }
    set_add_rowmode(L, FALSE);
    std::vector<REAL> obj(ncol + 1, 0.0);
    if (!feasibility_only)
      for (int e : edges) obj[pcol.at(e)] = obj[pcol.at(e) + 1] = p.edges[e].weight / p.edges[e].target;
    set_obj_fn(L, obj.data());
    set_minim(L);
    std::map<int, int> lowbo;  // class root -> the largest min_n of its edges
    for (int e : edges) lowbo[find(cls, e)] = std::max(lowbo[find(cls, e)], std::max(1, p.edges[e].min_n));
    for (auto& [root, cc] : col) set_int(L, cc, TRUE), set_lowbo(L, cc, lowbo.at(root));
    for (auto& [g, cc] : kcol) set_int(L, cc, TRUE);
    set_timeout(L, static_cast<long>(std::ceil(p.timeout_s)));
    int st = solve(L);
    r.bb_nodes += static_cast<long>(get_total_nodes(L));
    r.rows += rows, r.columns += ncol;
    if (st != OPTIMAL && st != SUBOPTIMAL && st != PRESOLVED) {
      r.status = st;
      r.failed_component = static_cast<int>(c);
      return r;
    }
    if (st == SUBOPTIMAL) r.status = SUBOPTIMAL;
    std::vector<REAL> x(ncol, 0.0);
    get_variables(L, x.data());
    for (int e : edges) r.n[e] = static_cast<int>(std::lround(x[col.at(find(cls, e)) - 1]));
  }
  if (r.status == NOTRUN) r.status = OPTIMAL;
  return r;
}

std::string edge_list(const IPProblem& p, const IPGroup& g) {
  std::string s;
  for (std::size_t i = 0; i < g.edges.size(); ++i) {
    if (i) s += ", ";
    s += p.edges[g.edges[i]].name;
  }
  return s;
}

}  // namespace

IPSolution solve_intervals(const IPProblem& p, const Log& log) {
  auto t0 = std::chrono::steady_clock::now();
  const int E = static_cast<int>(p.edges.size());
  for (const IPEdge& e : p.edges)
    if (!(e.target > 0) || !std::isfinite(e.target) || !(e.weight >= 0))
      throw std::invalid_argument("balance: edge '" + e.name + "' has target " + std::to_string(e.target) +
                                  " and weight " + std::to_string(e.weight) + " (target must be > 0, weight >= 0)");
  for (const IPGroup& g : p.groups) {
    for (int e : g.edges)
      if (e < 0 || e >= E) throw std::invalid_argument("balance: constraint '" + g.name + "' names edge index " + std::to_string(e) + " out of range");
    if (g.kind != "equal" && g.kind != "layer" && g.kind != "periodic" && g.kind != "even")
      throw std::invalid_argument("balance: constraint '" + g.name + "' has unknown kind '" + g.kind + "'");
  }
  IPSolution out;
  if (E == 0) return out;
  std::vector<char> all(p.groups.size(), 1);
  Result r = solve_active(p, all, false, log);
  if (r.status == INFEASIBLE) {
    // Deletion filter over the groups of the infeasible component (groups of other components
    // share no edge with it): drop each in turn; keep it dropped if still infeasible. What
    // remains is an irreducible infeasible set (every remaining group is needed).
    std::vector<char> act(p.groups.size(), 0);
    for (int g : r.comp_groups.at(r.failed_component)) act[g] = 1;
    for (int g : r.comp_groups.at(r.failed_component)) {
      act[g] = 0;
      Result q = solve_active(p, act, true, log);
      if (q.status != INFEASIBLE) act[g] = 1;
    }
    std::vector<std::string> names;
    std::ostringstream m;
    m << "balance: the interval assignment has no integer solution. A minimal set of conflicting constraints"
      << " (every edge also has n >= 1):";
    for (std::size_t g = 0; g < p.groups.size(); ++g)
      if (act[g]) {
        const IPGroup& G = p.groups[g];
        names.push_back(G.name);
        m << "\n  - " << G.kind << " '" << G.name << "'";
        if (G.value) m << " (= " << *G.value << ")";
        if (G.kind == "even") m << " (sum even)";
        m << ": edges " << edge_list(p, G);
      }
    m << "\nRelax one of them: change the block structure (shell parameters) or the constraint that is wrong.";
    throw InfeasibleError(m.str(), names);
  }
  if (r.status != OPTIMAL && r.status != SUBOPTIMAL) {
    static const char* why[] = {"optimal", "suboptimal", "infeasible", "unbounded", "degenerate", "numerical failure",
                                "user abort", "timeout", "", "presolved"};
    std::string s = (r.status >= 0 && r.status <= 9) ? why[r.status] : "status " + std::to_string(r.status);
    throw StageError("balance: lp_solve found no integer solution (" + s + ") for " + std::to_string(E) +
                     " edges within timeout_s = " + std::to_string(p.timeout_s) + " s; raise timeout_s or report the workflow");
  }
  out.optimal = r.status == OPTIMAL;
  out.bb_nodes = r.bb_nodes;
  out.columns = r.columns;
  out.rows = r.rows;
  out.components = static_cast<long>(r.comp_groups.size());
  out.n = r.n;
  for (int e = 0; e < E; ++e) {
    double dev = std::abs(out.n[e] - p.edges[e].target) / p.edges[e].target;
    out.total_deviation += dev;
    out.objective += p.edges[e].weight * dev;
    out.max_rel_deviation = std::max(out.max_rel_deviation, dev);
  }
  // Verify what we return (lp_solve's integrality tolerance is 1e-7): every constraint holds exactly.
  for (const IPGroup& G : p.groups) {
    long sum = 0;
    for (int e : G.edges) {
      sum += out.n[e];
      if (G.value && out.n[e] != *G.value) throw std::logic_error("balance: lp_solve solution violates '" + G.name + "'");
      if ((G.kind == "equal" || G.kind == "periodic") && out.n[e] != out.n[G.edges[0]])
        throw std::logic_error("balance: lp_solve solution violates '" + G.name + "'");
    }
    if (G.kind == "even" && sum % 2) throw std::logic_error("balance: lp_solve solution violates '" + G.name + "'");
  }
  for (int e = 0; e < E; ++e)
    if (out.n[e] < 1) throw std::logic_error("balance: lp_solve solution has n < 1 on " + p.edges[e].name);
  out.solve_time = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  if (log)
    log("balance: lp_solve " + std::to_string(MAJORVERSION) + "." + std::to_string(MINORVERSION) + "." +
        std::to_string(RELEASE) + "." + std::to_string(BUILD) + ": " + std::to_string(E) + " edges, " +
        std::to_string(p.groups.size()) + " constraint groups, " + std::to_string(out.components) + " independent parts, " +
        std::to_string(out.bb_nodes) + " B&B nodes, " +
        (out.optimal ? "optimal" : "best found before timeout"));
  return out;
}

std::string lp_solve_version() {
  return "lp_solve " + std::to_string(MAJORVERSION) + "." + std::to_string(MINORVERSION) + "." + std::to_string(RELEASE) +
         "." + std::to_string(BUILD);
}

}  // namespace meshflow::balance
