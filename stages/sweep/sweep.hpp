// meshflow sweep — paper §III.D: the surface mesh of every CAD face, and the one-layer
// near-field mesh swept from the walls to the shell.
//
// Inputs: the healed shape (cad), the shell (fields + block structure) and the divisions
// (balance); optionally a periodic match (periodic_match), whose lo faces are meshed and
// copied onto the hi faces by its transformation.
//
// ── Surface mesh ───────────────────────────────────────────────────────────────────────
// Edges: wall edges and junction curves get exactly the nodes of the divisions artifact; every
// other CAD edge (far-field box, symmetry, periodic) is divided by the same sizing rule as
// balance (30° turn angle, min/max size) computed here. Faces: constrained Delaunay
// triangulation (CGAL 2D) of the face's (u,v) domain, conforming to the edge nodes, refined by
// inserting points where a triangle's 3D edges are longer than the local size (curvature rule,
// graded from the boundary), then smoothed; junction strips are quadrilaterals.
//
// ── The linear mesh contract (sweep → tet → curve → optimise → split) ──────────────────
//   entities   CAD vertex k → (0, k+1), CAD edge e → (1, e+1), CAD face f → (2, f+1);
//              near-field volume (3, 1); tet adds the far field as (3, 2).
//   physicals  dim 2: one group per face tag, fixed tags: wall 1, farfield 2, symmetry 3,
//              periodic_lo 4, periodic_hi 5 (faces tagged none get none); dim 3: "fluid" 10.
//   nodes      classified on the lowest-dimensional CAD entity they lie on: a CAD vertex
//              (0, k+1); a CAD edge (1, e+1) with node_u = the edge's curve parameter; a CAD
//              face (2, f+1) with (node_u, node_v) on that face's surface; otherwise the volume
//              (3, 1 or 2) with NaN parameters. Nodes on a seam edge are classified on the
//              edge (their two (u,v) come from cad::Shape::edge_uv with either p-curve).
//   elements   1D lines on every CAD edge (entity (1, e+1)), oriented along the curve;
//              2D triangles/quads on every CAD face, covering it exactly (walls: the wall
//              triangles and the junction strip quads on A; other faces: far-field
//              triangles, junction strip quads on B, side quads of prisms sliding on them);
//              3D prisms (wall triangle first, then its shell image, Gmsh order) and hexes in
//              the near field. All linear (order 1), every element valid.
//   periodic   one PeriodicLink per periodic_hi face, edge and vertex (slave = hi, master =
//              lo, affine = the 4x4 transformation lo → hi), with node pairs.
#pragma once

#include "stages/model/mesh.hpp"

namespace meshflow::sweep {

// Physical group tags of the contract above.
enum PhysicalTag : int { wall = 1, farfield = 2, symmetry = 3, periodic_lo = 4, periodic_hi = 5, fluid = 10 };

}  // namespace meshflow::sweep
