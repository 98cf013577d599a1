// meshflow split stage — isoparametric boundary-layer splitting (Moxey et al. 2015, CMAME;
// Marcon et al. 2018, section IV.B-C).
//
// A near-field macro element is a prism with one triangular face on a wall or a hex with one,
// two (C-type junction) or three faces on walls, on distinct axes (walls = boundary faces
// whose entity is in the physical group `wall_group`). Its reference element is cut along each
// wall-normal parametric direction at t_0 = 0 < t_1 < ... < t_L = 1 (distance from the wall,
// heights in geometric progression `ratio`), and every node of every sub-element is the macro
// element's own order-P mapping f evaluated at the sub-element's straight reference nodes:
// the sub-element is f o chi with chi affine (multilinear), so it is valid whenever f is.
// The evaluation is batched (tensor-product sum factorisation: Q_P on hexes, P_P(tri) x P_P
// (line) on prisms), which is model::map_sub_element's mapping for all sub-elements at once.
//
// Shared-node identity: every sub-node is a point of the macro element's "fine lattice"
// (integer coordinates: original lattice index in unsplit directions, layer * P + node in
// split ones). A point whose split coordinates are all at 0 or at the end is an original node
// of the macro element and reuses it (wall faces, outer faces, unsplit edges: the far field
// and the walls keep their node indices, coordinates and CAD parameters). A point inside a
// macro edge or face gets a key made only of integers and global node indices: the edge's
// vertex nodes (sorted), the wall end, the number of fine intervals and the offset from the
// lower-numbered vertex (for a face: its sorted vertex nodes and the two edge keys of the
// point's projections on the face edges through the face's lowest-numbered vertex). Two
// macro elements sharing a face produce the same key for the same point, independently of
// floating point; the node is created once, by the first element in mesh order, with that
// element's coordinates. Keys never depend on the thread count; new nodes are numbered in
// mesh order; coordinates are computed in parallel into preallocated slots.
//
// Boundary faces (2D elements) on a split macro face are replaced by the sub-elements' faces
// (same orientation, entity and physical groups); CAD lines (1D elements) on a split macro
// edge by sub-lines. New nodes inside macro elements are classified on the volume; new nodes
// on a boundary face on its entity, on a macro edge on the entity of the edge's original
// interior nodes. Parametric coordinates of new boundary nodes are interpolated in the parent
// face's (edge's) order-P parametrisation when every node of that face (edge) has parameters
// on that same entity, else NaN (counted in Stats::nodes_without_params; re-projection is
// left to a later stage). Wall faces are never subdivided, so wall nodes keep their exact
// parameters. Periodic links are extended to the new nodes of split periodic faces by the
// same keys with the slave vertices replaced by their masters.
#pragma once

#include "stages/model/mesh.hpp"

#include <cstddef>
#include <string>
#include <vector>

namespace meshflow::split {

struct Options {
  int layers = 10;
  double ratio = 1.5;
  double first_height = 0;  // > 0: solve the ratio from it (see schemas/split.schema.json)
  std::string wall_group = "wall";
  bool check_conformity = true;  // refuse a result with more non-conforming faces than the input
};

struct Stats {
  int layers = 0;
  double ratio = 1;
  bool ratio_from_first_height = false;
  int order = 0;
  // Thickness of the stacks and height of their first layer: length of the mapped
  // wall-normal parametric line through the wall face's centroid (Gauss-Legendre, 8 points),
  // over each split direction of each macro element.
  double thickness_min = 0, thickness_max = 0, first_height_min = 0, first_height_max = 0;
  std::size_t macro_prisms = 0, macro_hexes_1wall = 0, macro_hexes_2wall = 0, macro_hexes_3wall = 0;
  std::size_t sub_prisms = 0, sub_hexes = 0, passthrough_elements = 0;
  std::size_t nodes_in = 0, nodes_out = 0, new_nodes = 0, dropped_nodes = 0;
  std::size_t boundary_faces_split = 0, boundary_subfaces = 0, lines_split = 0;
  std::size_t nodes_without_params = 0, periodic_pairs_added = 0;
};

struct Result {
  model::Mesh mesh;  // its blocks are the input's, in order (split blocks: their sub-elements)
  Stats stats;
  // per block: 1 when its elements are the input block's, unchanged (same nodes, same order)
  std::vector<char> passed_through;
};

// Cut positions t_0 = 0 < ... < t_L = 1 (distance from the wall, fraction of the thickness):
// layer k has height ratio^k / sum_j ratio^j.
std::vector<double> layer_cuts(int layers, double ratio);
// The ratio r in [1, 10] whose first-layer fraction (r-1)/(r^L-1) equals `fraction`;
// throws StageError when none is (fraction > 1/L or below the r = 10 value).
double ratio_for_first_fraction(int layers, double fraction);

// Splits every macro element of `in`; throws meshflow::StageError on bad input (no 3D
// elements, no wall faces, mixed orders, a prism/hex without an identifiable wall face, a
// split that would break conformity). `threads` <= 0: TBB's default.
Result split_mesh(const model::Mesh& in, const Options& opt, int threads = 0);
// The same, consuming the input: its node arrays are released once the new nodes' coordinates
// are computed and its pass-through blocks' connectivity is moved into the result, so the input's
// nodes are never held beside the whole output (Rotor 67: the stage's peak). `in` is left with
// its element blocks but no nodes; only its destruction or assignment is meaningful.
Result split_mesh(model::Mesh&& in, const Options& opt, int threads = 0);

}  // namespace meshflow::split
