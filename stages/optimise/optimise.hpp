// meshflow optimise — paper §IV.A (Marcon et al. 2018): surface node optimisation of an order-P
// curved mesh on its CAD, keeping every valid element valid.
//
// Input: an order-P mesh (P >= 2) classified by the linear mesh contract (stages/sweep/
// sweep.hpp), with its high-order nodes placed on the CAD by the curve stage: nodes inside
// CAD curves classified (1, e+1) with node_u = curve parameter t, nodes inside CAD faces
// (2, f+1) with (node_u, node_v); and the shape those ids refer to.
//
// ── Units ──────────────────────────────────────────────────────────────────────────────
// The optimisation works on independent units, each a spring system whose free nodes move in
// CAD parameter space and whose ends/boundary nodes stay where they are:
//   curve edge    a high-order mesh edge (of a 2D element on a CAD face or a 1D element)
//                 whose interior nodes all lie on CAD curve e: springs between consecutive
//                 nodes, variables t_1..t_{P-1}, bounded by the end nodes' parameters.
//   surface edge  a mesh edge whose interior nodes all lie on CAD face f: the same chain with
//                 variables (u_i, v_i), bounded by the face's (u,v) bounds (face_uv_bounds).
//                 The minimiser approaches the geodesic between the ends, equally spaced.
//   face          the interior nodes of a 2D element (tri/quad) on CAD face f: springs between
//                 lattice neighbours (triangle lattice: steps (1,0), (0,1), (1,-1); quad
//                 lattice: (1,0), (0,1)) where at least one end is interior; variables (u,v)
//                 of the interior nodes, bounded by face_uv_bounds. Optimised after the edges,
//                 with the optimised edge nodes fixed.
// Energy of a unit: E = sum over springs |x_a - x_b|^2 (rest length 0: the minimiser of a
// chain with fixed ends has nearly equal chords; of a lattice, the discrete harmonic net on
// the surface). A fixed node enters by its position x (its parameters are not needed);
// a free node by x = C(t) or S(u,v), gradient by the chain rule with the CAD derivatives
// (edge_eval / face_eval). Minimised by bounded L-BFGS-B (LBFGSpp) in variables scaled so
// that a unit step moves a node by about the mean spring length, energy divided by its
// initial value. Units are optimised in parallel (TBB, each unit writes only its own slots;
// no CAD projection runs in parallel, so results do not depend on the thread count).
// Vertices of the mesh elements never move.
//
// Units that cannot be optimised are left untouched and counted: nodes whose stored
// parameters do not reproduce their position (> position_tolerance), and units whose
// parameters jump across a periodic seam between two free nodes (detected by comparing the
// surface point at the (u,v) midpoint of a spring with the chord midpoint) when the jump
// cannot be unwrapped by one parameter period.
//
// ── Following in the volume ────────────────────────────────────────────────────────────
// VolumeMethod::blend (the only method so far): nodes that are neither optimised nor element
// vertices follow the moved boundary by a discrete harmonic extension of the displacement
// (uniform weights on the lattice steps of the element's node lattice; W = -L_II^{-1} L_IB,
// precomputed per shape and order): first the interior nodes of element faces that are not on
// CAD (from the face's edge nodes; each face once, so neighbours stay conforming), then the
// element-interior nodes (from all the element's face nodes). Being linear, blending the
// displacement keeps the rule of the curve stage, "interior node = straight position +
// blended boundary displacement", up to the choice of blending. A variational volume
// optimiser of the whole mesh (Turner et al. 2016) is the planned second VolumeMethod; it is not
// there yet. What curving inverted is repaired locally afterwards by untangle.hpp (the stage
// runs it after optimise_mesh, option `untangle`): patches around each invalid element only.
//
// ── Validity guard ─────────────────────────────────────────────────────────────────────
// Every element of the mesh's highest dimension that has a moved node is checked with the
// Bezier validity of stages/model/quality.hpp before and after. Where an element valid before
// is invalid after, every unit with a node in it backtracks: its nodes go to
// param_old + a (param_opt - param_old) with a halved (1, 1/2, ... 1/8, then 0 = exactly the
// old positions and parameters), the volume nodes are re-blended, and the changed elements
// are checked again until none valid before is invalid. So no valid element becomes invalid.
// Quality guard: the patch of a unit is the checked elements with one of its nodes; where an
// element ends below the lowest scaled Jacobian (model::element_quality) before optimisation of
// the patches of all units that move it (any of them may have done it), those units backtrack
// the same way. So no element ends below the worst of the patches of the moves that changed it,
// and the mesh's min scaled Jacobian never drops. (Without it, a spring system pulling
// edge nodes to the geodesic / equal spacing could squeeze a neighbouring thin or strongly
// curved element, measured 0.348 -> 0.018 on a dome, while keeping it valid.)
//
// ── Report ─────────────────────────────────────────────────────────────────────────────
// Energies before/after (sum over units, mesh units squared), the largest distance of a moved
// node to its CAD entity (an independent projection: project_to_edge / project_to_face), the
// number of invalid elements among the checked ones before/after, nodes moved, units by kind,
// L-BFGS-B iterations, backtracked units, time.
#pragma once

#include "stages/model/mesh.hpp"

#include <nlohmann/json_fwd.hpp>

#include <cmath>
#include <cstddef>

namespace meshflow::cad { class Shape; }

namespace meshflow::optimise {

// How nodes that are not on the CAD follow the optimised surface nodes. A variational volume
// optimiser will be a second enumerator here (and a second value of the schema's "volume").
enum class VolumeMethod { blend };

struct Options {
  bool curve_edges = true;    // optimise edges on CAD curves
  bool surface_edges = true;  // optimise edges on CAD faces
  bool faces = true;          // optimise face-interior nodes of 2D elements
  VolumeMethod volume = VolumeMethod::blend;
  int max_iterations = 200;   // L-BFGS-B iterations per unit
  double tolerance = 1e-9;    // projected-gradient norm of the normalised energy to stop at
  // Stored parameters must reproduce a node's position to within this fraction of the mesh's
  // bounding-box diagonal, else its unit is skipped.
  double position_tolerance = 1e-6;
  // The validity guard (section above). Only tests and diagnostics turn it off, to show what it
  // prevents; the stage always keeps it on.
  bool keep_valid = true;
  // The quality guard (same section): no unit may leave an element of its patch with a scaled
  // Jacobian below the lowest of that patch before. Off only in tests, to show what it prevents.
  bool keep_quality = true;
};

struct Report {
  int order = 0;
  std::size_t curve_edges = 0, surface_edges = 0, faces = 0;  // units optimised
  std::size_t skipped_inconsistent = 0, skipped_seam = 0, unwrapped_seam = 0;
  std::size_t nodes_moved = 0, nodes_blended = 0, elements_checked = 0;
  std::size_t invalid_before = 0, invalid_after = 0;  // among the checked elements
  std::size_t backtracked_units = 0, reverted_units = 0, guard_rounds = 0;
  std::size_t quality_backtracked_units = 0;  // backtracked for quality alone (not for an inverted element)
  double min_sj_before = INFINITY, min_sj_after = INFINITY;  // lowest scaled Jacobian among the checked elements
  double energy_before = 0, energy_after = 0;
  double max_cad_distance = 0;  // of the moved nodes, by projection
  std::size_t iterations = 0;   // L-BFGS-B iterations, all units
  int max_unit_iterations = 0;
  double seconds = 0, optimise_seconds = 0, guard_seconds = 0;
  nlohmann::json to_json() const;
};

// Optimises `m` in place. Throws meshflow::StageError for a linear mesh, a mesh without CAD
// parameters, nodes on CAD curves/faces without parameters, or ids not in `shape`.
Report optimise_mesh(model::Mesh& m, const cad::Shape& shape, const Options& opt, int threads = 0);

}  // namespace meshflow::optimise
