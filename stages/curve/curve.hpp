// meshflow curve — paper §IV (after Sherwin & Peiró 2002): the linear hybrid mesh becomes an
// order-P mesh whose boundary nodes lie on the CAD, built bottom-up.
//
// Input: the linear mesh of the contract in stages/sweep/sweep.hpp (after tet: near-field
// prisms (wall triangle first) and junction hexes, far-field tets and pyramids, boundary
// triangles/quads on every CAD face, lines on every CAD edge, nodes classified with their CAD
// parameters) and the healed shape it was made from.
// Output: the same mesh with every element of order P (Gmsh node ordering, equispaced reference
// nodes as stages/model defines them). Vertex nodes keep their index, coordinates and CAD
// parameters; new nodes follow, numbered in mesh order (blocks, elements, local Gmsh order), a
// node shared by several elements created once: keyed by the global vertex nodes of its edge
// (face) and its integer weights on them, independently of floating point and thread count.
//
// ── Placement, bottom-up (each node belongs to exactly one entity: an edge, a face or an
//    element interior; its position is decided by the first rule that applies) ──────────────
//  1. Edges of a line element on CAD edge e (entity (1, e+1)): nodes at equal arc length on
//     the curve between the end parameters (a vertex end takes the edge's lo/hi parameter; on a
//     closed edge the one nearer the other end), classified (1, e+1) with u = t.
//  2. Edges and faces of 2D elements on CAD face f (entity (2, f+1)) — on walls always, on other
//     faces unless they are near-field entities (rule 3): in a per-element (u,v) chart, nodes at
//     equispaced (u,v) on the segment between the ends, re-spaced to equal 3D arc length along
//     it, evaluated on the surface; face-interior nodes by transfinite interpolation in (u,v)
//     (Coons on quads, edge blending on triangles: uv = uv_lin + sum over edges ab of
//     (la+lb) d_ab(lb/(la+lb)), d the edge's deviation from its straight uv segment).
//     Charts: a node on a seam edge has two (u,v) (the edge's two p-curves), a vertex one per
//     incident edge use; each is also shifted by the face's periods (the differences of the
//     seams' p-curves); the element takes, starting from an unambiguous vertex, the candidate
//     nearest to what it has placed. A vertex at a pole (a degenerate edge of the face) has no u:
//     an edge takes the other end's u (a meridian), a face the mean of its other vertices'.
//  3. Near field (the boundary layer, option follow_wall): prisms with a wall triangle and hexes
//     with 1..3 wall faces (walls: 2D elements in the physical group `wall_group`, as split
//     finds them) are one thin layer whose wall face is now curved. Every node of such an
//     element not placed by 1-2 gets the wall's displacement carried along the layer direction:
//     X = X_straight + sum over non-empty subsets S of the wall faces (-1)^(|S|+1) D(proj_S xi),
//     D = (curved - straight) of the wall node at the reference point projected onto the walls
//     of S (one wall: the shell face = the wall face's mapping + the layer vector interpolated
//     linearly; layer edges stay straight; two walls (C junction): the Boolean sum of both). A
//     node shared by several near-field elements takes the mean of their values (they differ
//     only where a junction meets prisms). Nodes of such entities lying on a non-wall CAD face
//     (prism side quads sliding on a symmetry plane) are then projected onto that face.
//  4. Remaining edges stay straight; remaining faces (far-field faces touching curved ones)
//     get their edges' displacement by the same transfinite blending (in 3D); element
//     interiors (tets, pyramids, far-field elements) get the discrete harmonic extension of
//     the displacement of their boundary nodes over the reference lattice (a symmetric nearest-
//     neighbour stencil, so a zero boundary displacement gives exactly the straight element).
// Validity is checked afterwards with model::mesh_quality (Bezier bounds over the whole
// element); invalid elements are not an error here (optimise comes next): they are counted
// and each is reported with its location.
//
// Parallel (TBB) over entities, each thread with its own cad::Shape clone for projections;
// results are written into preallocated slots, so the output is byte-identical at any thread
// count.
#pragma once

#include "stages/model/mesh.hpp"
#include "stages/model/quality.hpp"

#include <nlohmann/json.hpp>

#include <array>
#include <cstddef>
#include <functional>
#include <string>
#include <vector>

namespace meshflow::cad { class Shape; }

namespace meshflow::curve {

struct Options {
  int order = 4;                     // 2..6
  bool follow_wall = true;           // rule 3 (false: near-field elements like any other)
  bool equalise_arc_length = true;   // re-space edge nodes on surfaces to equal 3D arc length
  std::string wall_group = "wall";
  int threads = 0;                   // <= 0: TBB's default
  bool check = true;                 // compute validity (quality) before and after
};

struct InvalidElement {
  std::uint64_t tag = 0;
  std::string type;  // "prism4", ...
  std::array<double, 3> centroid{};
  double min_det = 0;
  bool near_field = false;
};

struct Report {
  int order = 0;
  std::size_t nodes_in = 0, nodes_out = 0;
  std::size_t nodes_on_curves = 0, nodes_on_surfaces = 0;  // new high-order nodes placed on CAD
  std::size_t nodes_near_field = 0, nodes_projected = 0;   // rule 3; of those re-projected on a face
  std::size_t nodes_straight = 0, nodes_blended = 0;       // rule 4: straight edges; faces + interiors
  std::size_t near_field_prisms = 0, near_field_hexes = 0, junction_hexes = 0;
  std::size_t fallback_projections = 0;  // end nodes whose parameters had to be found by projection
  std::size_t seam_choices = 0, pole_ends = 0;
  double max_distance_curve = 0, max_distance_surface = 0;  // high-order nodes to their CAD entity
  std::size_t invalid_linear = 0, invalid = 0, invalid_near_field = 0, elements = 0;
  double min_scaled_jacobian = 1;
  std::vector<InvalidElement> invalid_elements;  // at most 100, in mesh order
  double seconds_place = 0, seconds_check = 0, seconds_total = 0;
  // The curved mesh's per-element quality (when checked): the contract takes it, not a second pass.
  model::MeshQuality quality;
  nlohmann::json to_json() const;
};

// Curves `linear` on `shape`. Throws meshflow::StageError on bad input: order outside 2..6,
// elements that are not linear, nodes without CAD classification/parameters, entities that
// do not exist in the shape.
model::Mesh curve_mesh(const model::Mesh& linear, const cad::Shape& shape, const Options& opt, Report& report,
                       const std::function<void(const std::string&)>& log = {});

}  // namespace meshflow::curve
