// meshflow optimise — the last resort for curved elements the untangler could not repair (or
// whose validity the Bezier bounds could not decide, which the mesh contract refuses too):
// take back part or all of their curvature (NekMesh's `linearise:invalid` module, made
// conforming and minimal).
//
// Why: the linear mesh is valid (the contract of sweep and tet), so every element made of its
// vertices alone is valid; curving and the untangler can leave elements inverted where the CAD
// bends more than the element is thick (a sliver on a strongly curved fillet, a junction's
// concave corner). A refusal there costs the user the whole mesh for a few elements; an element
// whose boundary face lies a little inside the CAD's curve costs a little geometric accuracy at
// one place, which the report states.
//
// How, for each element still invalid, in mesh order (deterministic, sequential):
//   region   R = {the element}; its moved nodes N = the high-order nodes (never a vertex) of
//            R's elements; each node's straight position x_s comes from the linear (vertex) map
//            of one element of R at the node's reference coordinates (the same from every
//            element sharing the node's edge or face, so the mesh stays conforming);
//   blend    for t = 0.9, 3/4, 1/2, 1/4, 0: x = x_s + t (x_0 - x_s), x_0 the node's position
//            before; the elements with a node in N are checked by the Bezier bounds of
//            stages/model/quality.hpp; t is accepted when every one of them is valid. Of the
//            accepted t, the largest whose worst element is at a scaled Jacobian of at least
//            `floor`, or of half the best any accepted t reaches when that is lower (the
//            elements may be poor in the linear mesh already), is kept: the most of the CAD's
//            curvature that still gives a usable element;
//   grow     when no t is accepted, the elements still invalid at t = 0 (neighbours bent by
//            R's straightened faces, or other invalid elements) join R, the moved nodes go
//            back to x_0 and the blend is tried again; at most `max_rounds` times and
//            `max_elements` elements, else the nodes are restored and the element stays
//            invalid (reason "region too large");
//   refuse   an element whose straight version is itself invalid (a linear mesh that broke its
//            contract) or that has a node in a periodic pair (its partner would not follow) is
//            left as it is, with its reason.
// Nodes of boundary faces that move are no longer on the CAD: their parameters are cleared (NaN)
// and the report gives their number and the largest distance they moved (a bound on their
// distance to the CAD, since they were on it). Vertices never move.
#pragma once

#include "stages/model/mesh.hpp"
#include "stages/model/quality.hpp"

#include <nlohmann/json_fwd.hpp>

#include <cstddef>
#include <map>
#include <string>
#include <vector>

namespace meshflow::optimise {

struct LineariseOptions {
  double floor = 0.1;     // scaled Jacobian a blend should reach to be preferred (Gmsh's HighOrderThresholdMin)
  int max_rounds = 12;    // region growths per invalid element
  std::size_t max_elements = 5000;  // elements in one region at most
  // What is known of the mesh's quality at the start (as UntangleOptions): the rest is computed.
  const model::MeshQuality* known_quality = nullptr;
  const std::vector<char>* moved_since_known = nullptr;
};

struct LineariseReport {
  std::size_t invalid_before = 0, invalid_after = 0;  // invalid 3D elements of the whole mesh
  std::size_t regions = 0;            // regions accepted
  std::size_t elements = 0;           // elements of accepted regions (the invalid ones and the neighbours they took)
  std::size_t straight_elements = 0;  // of them, in regions made fully straight (t = 0)
  std::size_t nodes_moved = 0, cad_nodes_moved = 0;  // all moved nodes; those of boundary faces (now off the CAD)
  double max_cad_move = 0;            // largest move of a node that was on the CAD (a bound on its distance to it)
  double max_cad_move_relative = 0;   // the same divided by the mean edge length of its region's first element
  double min_scaled_jacobian = 1;     // lowest over the elements of accepted regions, after
  std::map<std::string, std::size_t> unrepaired_by_reason;
  double seconds = 0;
  nlohmann::json to_json() const;
};

// Linearises, in place, as little as it can of each invalid element of `m`'s highest dimension.
// `moved` (optional) gets one flag per node: 1 where the node moved.
LineariseReport linearise_invalid(model::Mesh& m, const LineariseOptions& opt, int threads = 0,
                                  std::vector<char>* moved = nullptr);

}  // namespace meshflow::optimise
