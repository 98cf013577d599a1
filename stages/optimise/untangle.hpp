// meshflow optimise — untangling of the elements that curving left invalid (a local volume
// optimiser of the high-order nodes off the CAD; the place the optimise issue reserved for it).
//
// Why: curving moves boundary nodes onto the CAD; an element whose straight-sided version is
// valid can then be inverted between its nodes (a thin prism whose wall triangle is a sliver of
// a blunt trailing edge; a flat tet lying on a convex curved face). Surface optimisation keeps
// the CAD nodes where the geometry wants them, so the volume nodes must make room.
//
// How (after Gmsh's high-order mesh optimiser, Toulorge et al. 2013, and Persson & Peraire 2009,
// reduced to what a validity repair needs): for each invalid element, in mesh order,
//   patch   the elements within `ring` node-adjacency rings of it (ring = 1, 2, .. max_rings
//           until it is repaired);
//   free    the high-order nodes of patch elements that are off the CAD (classified on a volume
//           entity, or unclassified and on no 1D/2D element), are no element's vertex, belong
//           to no pyramid, and all of whose elements are in the patch (so nothing outside the
//           patch changes);
//   energy  for each patch element with a free node, at sample points (its equispaced reference
//           lattice of order P + 2), r = det J / det J_straight (det J of the element made of its
//           vertices only, at its centroid: positive, since the linear mesh is valid) and the
//           penalty (target - r)^2 where r < target (optionally a spring lambda |x - x0|^2 / h^2,
//           h the invalid element's mean edge length; off by default, so nodes move only while a
//           sample is below target). Gradient exact: d det J / d x_a = cof(J) grad N_a.
//           Minimised by L-BFGS (LBFGSpp), variables (x - x0) / h. When the result is not valid,
//           a second attempt from the same start uses 2.5 x target on the denser lattice of
//           order 3(P-1) (the degree of det J on a tet): samples can be positive while det J dips
//           below zero between them. When the first attempt ends with an energy of at least
//           target^2 (what one sample at r <= 0 costs alone) the patch is stuck far from valid
//           and the harder attempts are skipped (counted: stuck). The second and third attempts
//           stop early (counted: early_exits) at the first point, tested every 10th energy
//           evaluation, where the patch passes "accept" below with each element that must be valid
//           at a scaled Jacobian of at least 0.05 (or its own before, if lower): they often ran all
//           their iterations on a patch long acceptable (DLR-F6: 82 of 91 s of untangling).
//   slide   with the shape (the stage passes it), when moving the off-CAD nodes of a patch does
//           not repair it, the same patch is tried again with the high-order nodes inside CAD
//           faces free as well, sliding on their faces: variables (u, v), x = S(u, v) (never
//           element vertices, nodes on CAD curves, pyramid nodes or nodes in periodic pairs;
//           (u, v) stay in the face's parameter box unless the surface is periodic there). A
//           wall triangle folded on the CAD (a thin triangle across a strongly curved region,
//           whose optimised edges cross) is repaired this way; the nodes stay on the CAD and the
//           node parameters are updated. Off-CAD first, so a repair that needs no surface move
//           makes none.
//   lift    before the L-BFGS attempts of an off-CAD patch, its free tet nodes are lifted: the
//           displacement from the straight element (x - x_straight) that is discrete-harmonic
//           over the patch's straight tets, held at its current value on every other node (the
//           curved CAD faces, the patch's rim, and the boundary layer's prism and hex nodes,
//           which curving's rule 3 placed to carry the wall's displacement through the layer).
//           Curving places far-field nodes element by element (a tet on the curved shell takes
//           the whole bulge alone, its other edges straight); the lift spreads the boundary's
//           displacement over the patch, the start Persson & Peraire 2009 and Gmsh's optimiser
//           take from an elastic analogy. When the lifted patch passes the early exit's test
//           below (the element valid at a scaled Jacobian of 0.05, no valid element below its
//           own quality or 0.05), it is kept with no L-BFGS at all (counted: lift.repaired);
//           else the attempts start from it when its penalty is lower than the patch's now
//           (counted: lift.started_from). Its cost, one Jacobian evaluation per quadrature point
//           of each patch tet and two penalty evaluations, is charged to the budget.
//   fold    except for an element with a face on the CAD that is folded: its curved normal turns
//           against its straight face's normal at a sample (order P + 2). There det J = n . x_w
//           (x_w the derivative into the element) can be made positive by off-CAD moves only by
//           turning x_w out through the wall, an element that overlaps the solid; only sliding
//           undoes the fold. Such an element tries sliding first at every ring, then off-CAD
//           (counted: folded_wall_faces). On DLR-F6 two such prisms spent 141 s, 46% of the
//           untangling, in off-CAD attempts that failed before sliding repaired them in 1.6 and 16 s.
//   accept when every patch element that was valid stays valid, the element is valid by the
//           Bezier bounds of stages/model/quality.hpp (the proof, not the samples), and no patch
//           element ends below the lowest scaled Jacobian of the patch before (never worse: another
//           invalid element of the patch may not get more inverted); otherwise the patch is
//           restored exactly and the next ring is tried.
//   floor   an accepted result whose elements that must be valid are not all at the early exit's
//           floor (each at a scaled Jacobian of 0.05, or its own before if lower) is kept aside
//           while the patch's next attempt is tried (counted: below_floor_retries): the first
//           attempt's penalty acts on samples only and could end an element barely valid between
//           them (DLR-F6: 0.0008). The first attempt that passes the floor is kept; when none
//           does, the first accepted result is.
// An invalid element inside the largest patch of one that could not be repaired is not tried
// again (its patches are nearly the same; it is counted as skipped and stays invalid).
//   budget  the untangler gives up instead of grinding. Its work is counted in Jacobian
//           evaluations at sample points (one per sample of a patch element per energy
//           evaluation; about 1 microsecond each on one core at P=4): an invalid element whose
//           patches (all rings, modes and attempts) have used `element_budget` of them is given
//           up (reason "budget"), and once `stage_budget` has been used since the last repair
//           (no progress; checked before each element, so the stage stops within one element
//           budget of it) the remaining invalid elements are not tried (reason "no progress").
//           A stage that repairs nothing stops there. Once it has repaired an element, the limit
//           is one element_budget more than the larger of stage_budget and the work its repairs
//           so far took: one element given up does not stop a stage that repairs, and a run of
//           failures may cost as much as the repairs did. Both counts are deterministic (independent of
//           the thread count and the machine), so they decide the output reproducibly.
//           `time_limit` (seconds, 0 = none) is only an outer safety net against a machine far
//           slower than expected: when it fires the result depends on the machine's speed, and the
//           report says so (time_limit_fired).
//   report  every element still invalid at the end gets a reason: budget, stuck (the coarse try
//           stayed far from valid at the largest ring), not repaired (every ring and mode
//           tried), degenerate (a patch element's straight version has no or a negligible volume: nothing to
//           aim at), no free nodes (every node of the patch is fixed: vertices, CAD, pyramids),
//           in a failed patch (inside the largest patch of one that could not be repaired: not
//           tried), no progress / time limit (not tried). The first `max_listed` of them are
//           listed with their tag and centroid, with counts per reason and advice.
// Element vertices never move, nodes on the CAD move only on it (sliding), the mesh stays conforming (shared
// nodes are single nodes). Sequential in mesh order, so the result is deterministic; the cost is
// proportional to the number of invalid elements, not to the mesh.
#pragma once

#include "stages/model/mesh.hpp"
#include "stages/model/quality.hpp"

#include <nlohmann/json_fwd.hpp>

#include <cstddef>
#include <cstdint>
#include <functional>
#include <map>
#include <string>
#include <vector>

namespace meshflow::cad { class Shape; }

namespace meshflow::optimise {

struct UntangleOptions {
  int max_rings = 3;          // patch growth: 1..max_rings node-adjacency rings
  double target = 0.2;        // penalised below this det J / det J_straight at the samples
  double spring = 0;          // lambda, weight of a displacement spring (0: nodes move only while a sample is below target)
  int max_iterations = 400;   // L-BFGS iterations per patch attempt
  bool surface = true;        // with a shape: try sliding the nodes inside CAD faces when off-CAD moves fail
  bool lift = true;           // off-CAD patches start from the harmonic lift ("lift" above)
  // Budgets ("budget" above), in Jacobian evaluations at sample points; <= 0 = unlimited.
  double element_budget = 200e6;  // per invalid element, all its patch attempts (DLR-F6 needs 124e6 for one)
  double stage_budget = 40e6;     // since the last repair (no progress; after a repair at least one element budget and the repairs' work), checked between elements
  double time_limit = 0;          // seconds, safety net only (non-deterministic when it fires); 0 = none
  int max_listed = 20;           // unrepaired elements listed in the report
  // What is known of the mesh's quality at the start (model::mesh_quality's `known` and `moved`:
  // e.g. the input's stored quality and the nodes moved since): the first pass computes the rest.
  const model::MeshQuality* known_quality = nullptr;
  const std::vector<char>* moved_since_known = nullptr;
};

// An element left invalid, with where it is and why (reasons: "budget" above).
struct Unrepaired {
  std::uint64_t tag = 0;
  double centroid[3] = {0, 0, 0};  // mean of its vertices
  std::string reason;
};

// What the untangler is doing, for progress messages: elements visited / invalid at the start,
// repaired so far, seconds since it started.
struct UntangleProgress {
  std::size_t visited = 0, total = 0, repaired = 0;
  double seconds = 0;
};

struct UntangleReport {
  std::size_t invalid_before = 0, invalid_after = 0;  // invalid 3D elements of the whole mesh
  std::size_t attempts = 0, repaired = 0, nodes_moved = 0;
  std::size_t surface_nodes_moved = 0, repaired_sliding = 0;  // nodes slid on CAD faces; patches that needed it
  std::size_t folded_wall = 0;  // tried elements with a wall face folded on the CAD (sliding tried first)
  std::size_t lifts = 0, repaired_by_lift = 0, lift_starts = 0;  // lifts computed; repairs by one alone; attempts started from one
  std::size_t skipped = 0;  // invalid elements inside the largest patch of one that could not be repaired: not tried
  std::size_t early_exits = 0;  // second/third attempts stopped at the first tested point that was acceptable
  std::size_t below_floor = 0;  // attempts whose valid result was below the floors, so the next attempt was tried
  std::size_t stuck = 0;    // patch attempts whose coarse try stayed >= target^2: the harder tries were skipped
  std::vector<int> repaired_at_ring;                   // [ring-1] = elements repaired with that ring
  std::vector<Unrepaired> unrepaired;                  // the first max_listed elements still invalid
  std::map<std::string, std::size_t> unrepaired_by_reason;  // all of them, counted per reason
  std::size_t budget_exhausted = 0;                     // elements given up on their element budget
  double work = 0;                                      // Jacobian evaluations at sample points, all patches
  double max_element_work = 0;                          // the most any one invalid element used
  double repair_work = 0;                               // of it, on the elements it repaired
  bool stage_budget_exhausted = false, time_limit_fired = false;  // stopped for no progress / on the time limit
  double max_move = 0;                                  // largest node displacement / h of its patch
  double seconds = 0;
  std::string advice() const;                           // what the user can change ("" when all repaired)
  nlohmann::json to_json() const;
};

// Repairs the invalid 3D elements of `m` in place (see above). Never makes a valid element
// invalid. `threads` is used only for the whole-mesh validity check.
// `log`, when set, gets one line per patch attempt (a diagnostic: energies, sizes, outcome).
// With `shape` (the one the mesh's node classification refers to), nodes inside CAD faces may
// slide on them ("slide" above); without it they never move. `progress`, when set, is called
// before each invalid element and about every second during a long patch optimisation.
UntangleReport untangle(model::Mesh& m, const UntangleOptions& opt, int threads = 0,
                        const std::function<void(const std::string&)>& log = {}, const cad::Shape* shape = nullptr,
                        const std::function<void(const UntangleProgress&)>& progress = {});

}  // namespace meshflow::optimise
