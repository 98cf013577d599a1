// meshflow balance — paper §III.D: interval assignment. Every edge of the near-field block
// structure gets an integer number of divisions, as close as possible to its sizing target,
// subject to the constraints that make the blocks meshable (Tam & Armstrong 1993), solved as an
// integer program with lp_solve 5.5 (in ip_solve.cpp only: lp_lib.h defines REAL/TRUE/FALSE;
// this header includes no foreign library).
//
// ── The unknowns (which edges) ─────────────────────────────────────────────────────────
// One integer n_e >= 1 per *named edge* (names from stages/shell/shell.hpp):
//   - every name in the "edges" and "equal" lists of every shell block: "w<e>" wall CAD edge
//     e, "s<e>" its shell image, "j<e>a|b|c" junction strip boundaries / outer corner curve,
//     "x<e>.<end>.<side>" junction cross-section edges;
//   - "e<e>": CAD edge e of a periodic_lo/periodic_hi face that is not a wall edge (so that
//     periodic partners can be made equal even where the walls do not reach).
// The layer edges "v<k>" (wall vertex -> shell point) are not unknowns: the near field is
// swept in exactly one layer, so they have 1 division by definition.
//
// ── Constraints (each one named; the names appear in infeasibility messages) ───────────
//   equal     every "equal" group of every shell block (prism_sweep: base edge = its shell
//             image; hex_junction: w = ja = jb = jc, and the two cross-section directions),
//             name "<block>: equal [a, b, ...]" with <block> = "prism_sweep face F" or
//             "hex_junction edge E";
//   layer     n = 1 for the junction cross-section edges that are one-layer sweep edges of a
//             neighbouring prism block: "x<e>.<end>.ac" (PA -> PC: the sweep of the strip
//             boundary on face A) always, "x<e>.<end>.bc" too when the partner face is a wall;
//   periodic  n_a = n_b for a CAD edge of a periodic_lo face and its image on periodic_hi (the
//             image is found geometrically: a translation or a rotation about a coordinate
//             axis mapping every periodic_lo edge onto a periodic_hi edge);
//   even      sum of n over a loop of a face meshed with quadrilaterals is even (one integer
//             helper k per loop: sum = 2k). The shell's quad-meshed faces are the six faces
//             of each hex_junction block (strip on A, strip on B, two outer strips, two end
//             caps); they are structured, so their loops are even already by the equal
//             groups — the rows are kept as a cross-check and for non-structured quad faces
//             a later shell may declare. The shell declares no other quad-meshed loops.
//
// ── Objective ──────────────────────────────────────────────────────────────────────────
//   minimise  sum_e w_e (p_e + m_e) / t_e   with  n_e - t_e = p_e - m_e,  p_e, m_e >= 0
// i.e. the weighted relative deviation |n_e - t_e| / t_e, linearised with two slacks per
// edge. n_e and the parity helpers are integer (set_int); lp_solve's branch and bound.
// Equal and periodic groups are substituted (one integer column per class of edges they join)
// and the program splits into independent parts (classes coupled by parity loops), each solved
// exactly by its own lp_solve run: one branch and bound over many independent parts prunes
// badly (measured: 300 chained quad blocks hit a 60 s timeout as one program).
//
// ── Targets ────────────────────────────────────────────────────────────────────────────
// t_e = integral over the edge of ds / h(s), h(s) = clamp(turn_angle × rho(s), min_size,
// max_size), rho = 1/curvature (|C' x C''| / |C'|^3 from cad::Shape::edge_eval on CAD edges;
// the discrete turning angle per length on the sampled shell/junction curves). For constant h
// this is length / h. Cross-section edges are straight (t = length / max_size). Targets below 1
// are raised to 1 (an edge shorter than the local size needs one division and is not counted as
// a deviation; otherwise a 0.0025-long blunt trailing edge would dominate the objective).
//
// A wall edge along a narrow face gets a hard lower bound instead (IPEdge::min_n): its chords
// sag c^2 k / 8 towards the face, and where that reaches the face's width across the edge (the
// DLR-F6 nacelle's base ring: r = 25 mm circles 0.7 mm apart, 30-degree chords sag 0.88 mm)
// the face's boundary loops cross in its parameter plane and sweep cannot mesh it. So
// n_e >= ceil(integral of ds sqrt(k / (8 beta W))), beta = 0.25 (sag at most a quarter of the
// width W: the least distance from the edge to the other edges of its faces that share no
// vertex with it). It is not a target: an equal group with a coarser shell image would
// otherwise pull the count back under it. stats.width_limited_edges lists where it acts.
//
// ── Infeasible problems ────────────────────────────────────────────────────────────────
// solve_intervals throws InfeasibleError (a StageError) whose message names a minimal set of
// conflicting constraint groups and their edges: a deletion filter drops the groups one at a
// time (in order) and keeps a group only if the problem becomes feasible without it.
//
// ── The "divisions" artifact (extension ".mfdiv") ───────────────────────────────────────
// One line of JSON (keys sorted, numbers with 17 significant digits: deterministic bytes):
//   {"format":"meshflow-divisions 1", "units":"mm", "params":{...},
//    "edges":[{"name":"w3", "cad_edge":3, "kind":"wall"|"shell"|"junction"|"cross"|"periodic",
//              "n":5, "target":4.73, "length":0.81,
//              "param":"cad"|"fraction", "nodes":[t_0, ..., t_n]} ...],   sorted by name
//    "constraints":[{"name":..., "kind":"equal"|"layer"|"periodic"|"even", "edges":[...]}],
//    "stats":{...}}
// nodes are the n+1 parameters of the edge's nodes, ends included, increasing:
//   param "cad": parameters of CAD edge `cad_edge` (its curve's direction) — for "w", "s",
//     "j" and "e" names; "s<e>"/"j<e>*" nodes are those of "w<e>" (the wall nodes they are
//     swept/offset from, so junction blocks stay structured), graded on the wall edge by the
//     sizing (equal increments of the integral of ds / h(s), equal arc length where h is constant);
//   param "fraction": fractions in [0,1] of a straight cross-section edge, from its first
//     point to its second as named ("0a": P0 -> PA).
// Node placement follows the sizing (see above). The paper's second step (§III.D: node positions
// on the edges of a junction block moved by least squares to reduce the block's skew) is not
// done: there the junction edge and its strip boundaries / outer corner curve are separate
// curves whose nodes are placed independently, so the cross-sections through corresponding
// nodes lean; here the strip boundaries and the corner curve carry no nodes of their own — the
// nodes of "j<e>*" are the wall nodes of "w<e>" and sweep builds each cross-section of the block
// from one wall node (stages/sweep/sweep.hpp, "Junction blocks"), so corresponding nodes lie in
// one cross-section by construction and there is no skew for a least-squares step to remove.
#pragma once

#include <filesystem>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json_fwd.hpp>

#include "engine/stage.hpp"

namespace meshflow::balance {

// ── The integer program (ip_solve.cpp) ──────────────────────────────────────────────────
struct IPEdge {
  std::string name;
  double target = 1;  // > 0
  double weight = 1;  // >= 0
  int min_n = 1;      // a hard lower bound (the width of the faces across a wall edge), >= 1
};
struct IPGroup {
  std::string name;               // shown in messages
  std::string kind;               // "equal" | "layer" | "periodic" | "even"
  std::vector<int> edges;         // indices into IPProblem::edges
  std::optional<int> value;       // layer/fixed: every member = value
};
struct IPProblem {
  std::vector<IPEdge> edges;
  std::vector<IPGroup> groups;
  double timeout_s = 60;  // lp_solve set_timeout; an interrupted solve keeps its best integer solution
};
struct IPSolution {
  std::vector<int> n;           // per edge
  double objective = 0;         // sum w |n - t| / t
  double total_deviation = 0;   // sum |n - t| / t
  double max_rel_deviation = 0;
  double solve_time = 0;        // seconds, including infeasibility diagnosis
  long rows = 0, columns = 0;
  long bb_nodes = 0;            // branch-and-bound nodes (sum over the parts)
  long components = 0;          // independent parts solved separately
  bool optimal = true;          // false: timeout, best integer solution found
};

struct InfeasibleError : StageError {
  std::vector<std::string> conflict;  // names of a minimal set of conflicting groups
  InfeasibleError(const std::string& what, std::vector<std::string> groups)
      : StageError(what), conflict(std::move(groups)) {}
};

// Solves the interval assignment. Throws InfeasibleError naming a minimal conflicting set of
// groups, std::invalid_argument for a malformed problem (target <= 0, index out of range).
// `log` receives lp_solve's messages and a summary line (may be empty).
IPSolution solve_intervals(const IPProblem& p, const std::function<void(const std::string&)>& log = {});
// "lp_solve 5.5.2.5" (the version compiled in; part of the stage's cache key).
std::string lp_solve_version();

// ── The "divisions" artifact (divisions_io.cpp) ─────────────────────────────────────────
struct EdgeDivision {
  std::string name;
  int cad_edge = -1;          // CAD edge id the name derives from (for "x": the junction edge)
  std::string kind;           // wall | shell | junction | cross | periodic
  int n = 1;
  double target = 1, length = 0;
  std::string param;          // "cad" | "fraction"
  std::vector<double> nodes;  // n + 1 parameters
};
struct Divisions {
  std::string units;
  std::vector<EdgeDivision> edges;  // sorted by name
  // JSON text of the header's "params", "constraints" and "stats" (kept verbatim)
  std::string params_json = "{}", constraints_json = "[]", stats_json = "{}";

  // The entry of a name, or nullptr.
  const EdgeDivision* find(const std::string& name) const;
  // Division count of a name; throws std::out_of_range naming it when absent.
  int count(const std::string& name) const;
  nlohmann::json summary() const;  // golden regression: counts, totals, per-name n
};

void write(const Divisions& d, const std::filesystem::path& file);
// Throws StageError naming the file when missing, not a divisions artifact or inconsistent.
Divisions read(const std::filesystem::path& file);

}  // namespace meshflow::balance
