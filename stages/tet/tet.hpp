// meshflow stage `tet` (paper §III.D): fills the far field of a linear near-field mesh with
// tetrahedra (TetGen), conforming exactly to the shell surface.
//
// Input contract (the "mesh" artifact of sweep):
//   - linear volume elements of the near field (prisms; hexes in junction blocks; tets and
//     pyramids are accepted too), all valid;
//   - linear boundary faces (2D blocks, triangles/quads) on entities whose physical group
//     names the boundary: wall, farfield, symmetry, periodic_lo, periodic_hi (any name works).
//     Faces may be given in either orientation.
// The far-field region is bounded by
//   - the shell: faces of exactly one near-field element that are not boundary faces (the
//     outer side of the boundary layer), and
//   - the boundary faces that are not faces of a near-field element (far field, symmetry,
//     periodic, or walls left without a boundary layer).
// Together they must form a closed manifold surface: each edge used by exactly two faces (an odd
// count is an open surface, more than two a pinch or pocket of the shell, e.g. where a junction
// ends on a third wall face: stages/sweep/sweep.hpp, KNOWN LIMITATION; both are refused before
// TetGen, which would report intersecting facets or crash on them).
// Quad faces of the shell get a pyramid each (apex on the outward normal of the quad at
// `pyramid_height` times its mean edge length; its four triangles go into the PLC). Quad
// boundary faces not covered by the near field are split into two triangles along the
// shorter diagonal (the 2D boundary block then holds triangles: a documented alternative to
// pyramids on the boundary). Each connected component of the near field gives TetGen one hole
// point (the centroid of its first element) so that the region inside the shell is not meshed.
// TetGen runs with -pYM (PLC, no Steiner points on the boundary, no facet merging: the shell
// triangles are kept exactly, checked on the result), -q<radius_edge>/<min_dihedral>,
// -a<max_volume> and -m with a size field h(x) = min(h_own, min_s h_s + growth |x - s|) over
// the shell points s (h = mean incident edge length).
//
// Output: the input mesh unchanged (nodes, blocks, entities, groups) + new nodes (pyramid
// apexes, then TetGen's Steiner points) + pyramids and tets in one new volume entity (tag =
// max volume tag + 1, same physical groups as the first volume entity) + the split quads.
// Every element valid (model::element_quality), every interior face conforming, every face of
// a single element a classified boundary face — or StageError naming where and what to do.
#pragma once

#include "stages/model/mesh.hpp"

#include <nlohmann/json.hpp>

#include <cstddef>
#include <functional>
#include <string>

namespace meshflow::tet {

struct Options {
  double radius_edge = 1.5;    // -q maximum radius-edge ratio
  double min_dihedral = 10;    // -q/.. minimum dihedral angle (degrees), 0: none
  double max_volume = 0;       // -a, 0: no bound
  double size_growth = 0.3;    // size field growth per unit distance from the shell, 0: off
  double pyramid_height = 0.5; // apex height / mean edge length of the quad
  int max_steiner = -1;        // -S, -1: unbounded
  int optimisation = 2;        // -O level 0..10
  long max_elements = 5000000; // the stage stops past this many tetrahedra, 0: no bound
  int threads = 1;             // for the quality check
};

struct Report {
  std::size_t near_elements = 0, near_components = 0;
  std::size_t shell_triangles = 0, shell_quads = 0, pyramids = 0;
  std::size_t boundary_triangles = 0, boundary_quads_split = 0;
  std::size_t plc_points = 0, plc_facets = 0;
  std::size_t tets = 0, steiner_points = 0;
  double tetgen_seconds = 0, check_seconds = 0, total_seconds = 0;  // check: mesh_stats
  std::string switches;
  std::string switches_retry;       // non-empty: TetGen crashed with `switches` and ran with these
  std::size_t pyramids_lowered = 0;  // pyramids whose apex was lowered to clear a crossing
  nlohmann::json mesh_stats;  // model::mesh_stats of the result
  nlohmann::json to_json() const;
};

// Fills the far field; throws meshflow::StageError on bad input or a failure (never returns
// an invalid or non-conforming mesh). `log` receives TetGen's messages, one line each.
model::Mesh fill_far_field(const model::Mesh& near, const Options& opt, Report& report,
                           const std::function<void(const std::string&)>& log = {});

// Writes the PLC that fill_far_field would give TetGen as TetGen files: <stem>.poly (points,
// facets with markers, holes) and, with a size field, <stem>.mtr; returns the switches (without
// the leading '-'), so that `tetgen -<switches> <stem>.poly` reproduces the stage's TetGen run
// (used by the benchmark and for reporting TetGen problems upstream).
std::string write_tetgen_input(const model::Mesh& near, const Options& opt, const std::string& stem);

}  // namespace meshflow::tet
