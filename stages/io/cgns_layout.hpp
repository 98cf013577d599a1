// Internal: CGNS node orderings of the complete Lagrange elements (CGNS/SIDS section 3.3,
// "Unstructured Grid Element Numbering Conventions", orders 1-4: BAR_2..5, TRI_3/6/10/15,
// QUAD_4/9/16/25, TETRA_4/10/20/35, PYRA_5/14/30/55, PENTA_6/18/40/75, HEXA_8/27/64/125).
// No libcgns here: the permutations are pure geometry, tested on their own (tests/io).
#pragma once

#include "stages/model/element.hpp"

#include <vector>

namespace meshflow::io::detail {

inline constexpr int kCgnsMaxOrder = 4;  // CGNS 3.4 has no complete Lagrange type above quartic

// cgns_to_gmsh(s, p)[i] = the Gmsh (model) local index of CGNS node i (0-based) of the element
// of shape s and order p (1..4); throws std::out_of_range outside that.
const std::vector<int>& cgns_to_gmsh(model::Shape s, int order);

// The CGNS element's nodes as points of Gmsh's reference element (model::reference_nodes), in
// CGNS order, generated from the SIDS rules (see cgns_layout.cpp).
std::vector<model::Vec3> cgns_reference_points(model::Shape s, int order);

}  // namespace meshflow::io::detail
