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
//           and the harder attempts are skipped (counted: stuck).
//   slide   with the shape (the stage passes it), when moving the off-CAD nodes of a patch does
//           not repair it, the same patch is tried again with the high-order nodes inside CAD
//           faces free as well, sliding on their faces: variables (u, v), x = S(u, v) (never
//           element vertices, nodes on CAD curves, pyramid nodes or nodes in periodic pairs;
//           (u, v) stay in the face's parameter box unless the surface is periodic there). A
//           wall triangle folded on the CAD (a thin triangle across a strongly curved region,
//           whose optimised edges cross) is repaired this way; the nodes stay on the CAD and the
//           node parameters are updated. Off-CAD first, so a repair that needs no surface move
//           makes none.
//   accept when every patch element that was valid stays valid and the element is valid by the
//           Bezier bounds of stages/model/quality.hpp (the proof, not the samples); otherwise the
//           patch is restored exactly and the next ring is tried.
// An invalid element inside the largest patch of one that could not be repaired is not tried
// again (its patches are nearly the same; it is counted as skipped and stays invalid).
// Element vertices never move, nodes on the CAD move only on it (sliding), the mesh stays conforming (shared
// nodes are single nodes). Sequential in mesh order, so the result is deterministic; the cost is
// proportional to the number of invalid elements, not to the mesh.
#pragma once

#include "stages/model/mesh.hpp"

#include <nlohmann/json_fwd.hpp>

#include <cstddef>
#include <cstdint>
#include <functional>
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
};

struct UntangleReport {
  std::size_t invalid_before = 0, invalid_after = 0;  // invalid 3D elements of the whole mesh
  std::size_t attempts = 0, repaired = 0, nodes_moved = 0;
  std::size_t surface_nodes_moved = 0, repaired_sliding = 0;  // nodes slid on CAD faces; patches that needed it
  std::size_t skipped = 0;  // invalid elements inside the largest patch of one that could not be repaired: not tried
  std::size_t stuck = 0;    // patch attempts whose coarse try stayed >= target^2: the harder tries were skipped
  std::vector<int> repaired_at_ring;                   // [ring-1] = elements repaired with that ring
  std::vector<std::uint64_t> unresolved;               // element tags still invalid (at most 100)
  double max_move = 0;                                  // largest node displacement / h of its patch
  double seconds = 0;
  nlohmann::json to_json() const;
};

// Repairs the invalid 3D elements of `m` in place (see above). Never makes a valid element
// invalid. `threads` is used only for the whole-mesh validity check.
// `log`, when set, gets one line per patch attempt (a diagnostic: energies, sizes, outcome).
// With `shape` (the one the mesh's node classification refers to), nodes inside CAD faces may
// slide on them ("slide" above); without it they never move. `progress`, when set, is called
// before each invalid element with (elements visited, invalid elements).
UntangleReport untangle(model::Mesh& m, const UntangleOptions& opt, int threads = 0,
                        const std::function<void(const std::string&)>& log = {}, const cad::Shape* shape = nullptr,
                        const std::function<void(std::size_t, std::size_t)>& progress = {});

}  // namespace meshflow::optimise
