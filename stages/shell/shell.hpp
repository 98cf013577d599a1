// meshflow shell — paper §III.C: the offset "shell" of the walls, whose thickness is bounded by
// the medial object, and the near-field block structure (one swept prism block per wall face,
// hexahedral C-type junction blocks along concave wall edges) that `balance`, `sweep` and `tet`
// build on. No CGAL and no OpenCASCADE here: the CAD through stages/cad/cad.hpp, the medial
// object through stages/medial/medial.hpp; CGAL (AABB tree) in shell_check.cpp only.
//
// ── Representation (why fields, not offset surfaces) ────────────────────────────────────
// The shell point of a wall point x is  x + t(x) d(x)  with a thickness field t and a unit
// sweep-direction field d. Sweep needs exactly this map (one layer from each wall node to the
// shell), it is cheap to evaluate, exact on the wall (no fitting error), and it needs no OCCT
// (offset B-splines would have to be built in stages/cad and would still have to be matched at
// shared edges). The fields are tabulated on the wall's own topology so that the map is
// single-valued on shared entities:
//   - per wall face: a regular nu × nv grid over the face's (u,v) bounds (face_uv_bounds),
//     nodes outside the trimmed face included (the surface is evaluated on its natural
//     extension); values t and d at the nodes; interpolation: bilinear in (u,v) for t and for
//     the three components of d, then d normalised (ShellData::face_field). Sweep corrects
//     this for the grid's resolution (sweep.cpp, Builder::face_field: (u,v) of a periodic face
//     taken in the grid's period; where the fluid normal turns by more than 30 degrees within a
//     cell, the deviation of d from the exact normal interpolated instead of d), and the shell
//     stage evaluates its grids the same way for the junction corners PC and the sampled
//     surface, so that both are the shell sweep builds;
//   - per wall edge: n stations uniform in the edge parameter over edge_range; linear
//     interpolation in t (the parameter), d normalised;
//   - per wall vertex: one value.
// RULE FOR SWEEP: a wall node on a CAD vertex uses the vertex value, a node on a CAD edge the
// edge field (whatever face it is seen from), a node inside a face the face grid. Shared nodes
// therefore have one shell point and neighbouring prisms stay conforming. The face grids are
// built to agree with the edge fields near the edges (the direction is blended from the edge
// value into the face normal over `blend_length` thicknesses), so the map is continuous up to
// the grid's interpolation error. Blending: a grid node's own normal n is turned by the
// weighted mean of the edges' rotation vectors (each turning the face normal at the edge's
// foot point into the edge value), weights smoothstep(1 − dist/R) / dist⁴, dist measured along
// the face (3D length of the straight (u,v) path to the foot point), not through space, so that
// the far side of a thin feature (upper/lower surface at a trailing edge in one face) does not
// count, and opposite deflections (the two sides of a round tip near its pole) cancel instead of
// averaging two opposite directions.
//
// ── Thickness ───────────────────────────────────────────────────────────────────────────
// Requested T = `thickness` (a length, or × the largest side of the walls' bounding box when
// `thickness_relative_to: wall_box`). At every wall sample i of the medial object the allowed
// thickness is a_i = min(T, alpha × r_in_i), r_in the radius of the sample's fluid-side medial
// ball, ignoring "corner balls": balls in the corner region of a concave edge that the shell
// treats (junction or slide), whose radius goes to 0 at the edge by construction and is handled
// by the topology (the layer is swept along both walls), not by thinning. (A ball is a corner
// ball when its centre is within 2 r / sin(θ/2) + h/2 of a concave edge of the sample's face with
// fluid angle θ < 170°, r its refined radius. NekMesh's cylinder once had 36 balls of radius
// down to 6e-6 beside its junction circles: gaps in medial's sampling of its seamed face, fixed
// in medial; counting such balls as corners by their empty-ball radius left Rotor 67's blade
// roots unthinned and 168 elements tangled after optimise.)
// The limit is local: each sample keeps its own bound, spread along the walls as below, so small
// balls thin the layer where they are. The stage refuses T only when more than
// `max_thinned_area` (0.5) of the wall area (face samples weighted by h²) would be thinner than
// `thin_fraction` (0.5) × T; the message names the narrowest place (coordinates, CAD face) and
// the largest thickness that fits (the smoothed bound commutes with the cap T, so it is the
// area quantile of the uncapped bound / thin_fraction). Where it thins, the log and
// stats.local_thinning {samples, of, area_fraction, area_fraction_below, min, at, where} say how much and where (only when it acts). Optionally (`lfs_factor` > 0) also a_i <=
// lfs_factor × lfs_i, the local feature size (distance to the medial object on either side):
// the fluid-side radius of a convex body such as a wing is large everywhere (it only sees the
// far field and the root wall), so a thin trailing edge or leading edge thins the shell only
// through this bound (it makes the near-field prisms around sharp convex edges less
// distorted). Then
// t_i = min_j (a_j + g · path length i→j) over the k-nearest-neighbour graph of wall samples
// that share a face (Dijkstra), g = `max_gradient`: the thickness is g-Lipschitz along the
// walls (no steps). At any wall point x (grid node, edge station) t(x) = min_j (t_j + g|x−x_j|)
// over the nearest samples on the face (edge: on its wall faces).
// Junction strips limited by the width of their faces: a junction block's cross-section is
// square (the strip on A is as wide as B's layer is thick, and vice versa: both the edge
// thickness), so where a face is narrower across a junction edge than twice the thickness (the
// DLR-F6 nacelle's 0.7 mm base ring, joined to the pylon along 8 mm of its rim) the thickness
// itself is limited: at each station of a junction edge, W = how far the ray from the edge along
// m_A (m_B) stays inside face A (B), and t <= 0.5 W there, as a point constraint
// t(x) <= 0.5 W + g |x - P0| on every wall point (so the field stays g-Lipschitz and continuous
// across faces). Exits through a seam, or through an edge sharing a vertex with the junction edge
// (an acute corner of the face, where sweep puts the block's end cross-section), do not count.
// stats.not_honoured.limited_by_face_width {stations, min, at} reports it when it acts.
// Optionally (`crossing_rounds` > 0, off by default) the shell is thinned where its sampled
// surface crosses itself: point constraints like the face-width ones at the crossing triangles'
// points, the fields rebuilt, round by round (shell_stage.cpp "2b"); it changes the fields
// wherever it acts: stats.not_honoured.thinned_for_crossings {rounds, crossings_before, points,
// min_scale, at}.
//
// ── Directions ──────────────────────────────────────────────────────────────────────────
// Face interior: the unit normal into the fluid. Edges (per side when they differ):
//   - wall|wall, convex, or concave above `junction_angle_deg`, or topology O: the mean of the
//     two fluid normals (both sides equal: "averaged normals");
//   - wall|other (symmetry, farfield, periodic; not a junction): the shell slides on the other
//     face: d = the in-face direction m_B of B perpendicular to the edge (the fluid normal of
//     the wall projected on B's tangent plane);
//   - junction (topology C, partner tag in `junction_with`, fluid dihedral below
//     `junction_angle_deg`): side A uses m_B, side B uses m_A, so that the wall's layer meets
//     the junction block's outer corner.
// Vertices: the normalised mean of their edges' end values, projected on the tangent planes
// of non-wall faces at the vertex. Edge fields are blended towards the vertex value within
// `blend_length` thicknesses of their ends.
//
// ── Blocks (for balance and sweep) ─────────────────────────────────────────────────────
// Edge names: "w<e>" wall edge e; "s<e>" its image on the shell; "v<k>" the layer edge from
// wall vertex k to its shell point (1 division in the one-layer sweep); for a junction at
// edge e between wall face A and partner face B: "j<e>a" the strip boundary on A (at distance
// w = the edge thickness from the edge), "j<e>b" the strip boundary on B, "j<e>c" the
// block's outer corner curve, "x<e>.<end>.<side>" the four cross-section edges at each end
// (end 0/1 = first/last vertex of the edge; side: "0a" P0→PA, "0b" P0→PB, "ac" PA→PC,
// "bc" PB→PC).
//   prism_sweep: {"kind","face","edges":[base edges of the face's wires, "j<e>a" replacing a
//     junction edge], "equal":[[base, shell image] ...]}
//   hex_junction: {"kind","edge","face" (A),"partner" (B),"partner_tag","fluid_angle_deg",
//     "equal":[["w<e>","j<e>a","j<e>b","j<e>c"], [x..0a, x..bc, x1..0a, x1..bc], [x..0b, x..ac, ...]],
//     "stations": {edge parameter, P0, PA (+uv on A), PB (+uv on B), PC} per station}
//   The division constraints for the IP are the "equal" groups of all blocks.
// A junction ending at a vertex whose other wall faces include a third face (neither A nor B of a
// block there) gets no block of its own at that end: sweep replaces the third face's prisms at
// the vertex by an end cap of tets and pyramids closing onto the hex's end face (sweep.hpp,
// "Junction ends on a third face"), from these fields as they are.
// Strip boundary on a wrapped face round which a junction edge closes through its own vertex,
// on the face's seam (Rotor 67's blade root and tip): the edge's p-curve offset across itself
// by each station's (u,v) offset (its component along the p-curve dropped), as sweep builds it
// (sweep.cpp, "Strip boundaries next to a seam"), not the plain projection, which folds round a
// nose thinner than the strip; the seam's stations inside the strip are not sampled.
// Sweep of a junction face strip: wall nodes on "j<e>a" map to the corner curve PC
// (interpolated linearly in the edge parameter between stations), not to the face field.
//
// ── The "shell" artifact (extension ".mfshell") ────────────────────────────────────────
//   char[8] "MFSHELL1", u32 header length L, L bytes of JSON (keys sorted, see write()),
//   then the f64/i32 arrays the header's "arrays" list names, in that order, little-endian:
//     face_grid_<f>   f64 [nv][nu][4]  (t, dx, dy, dz) — node (i,j) at u0+i·du, v0+j·dv
//     edge_field_<e>  f64 [n][4]       (t, dx, dy, dz) per side when the sides differ
//     shell_points    f64 [n][3]       sampled shell surface (conforming triangulation; interior
//                                      points on the field grid, refined per face until a chord's
//                                      sag is at most 0.1 x the face's least thickness: stats
//                                      sampling_refined_faces)
//     shell_wall      f64 [n][3]       the wall point each shell point was swept from
//     shell_tris      i32 [m][3]
//     shell_tri_face  i32 [m]          the wall face of each triangle
//   Deterministic: same inputs ⇒ same bytes.
#pragma once

#include <array>
#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include <nlohmann/json_fwd.hpp>

namespace meshflow::cad {
class Shape;
}

namespace meshflow::shell {

using Vec3 = std::array<double, 3>;

struct FaceGrid {
  int face = -1;
  int nu = 0, nv = 0;
  double u0 = 0, u1 = 0, v0 = 0, v1 = 0;
  std::vector<double> data;  // [nv][nu][4]: t, dx, dy, dz
};

struct EdgeField {
  int edge = -1;
  double t0 = 0, t1 = 0;                         // edge_range
  std::vector<int> sides;                        // faces, ascending (one entry: unified)
  std::vector<std::vector<double>> data;         // per side [n][4]
};

struct VertexValue {
  int vertex = -1;
  double t = 0;
  Vec3 d{};
};

struct ShellData {
  std::string header = "{}";  // JSON text: params, counts, blocks, stats, arrays
  std::vector<FaceGrid> faces;
  std::vector<EdgeField> edges;
  std::vector<VertexValue> vertices;
  std::vector<Vec3> shell_points, shell_wall;
  std::vector<std::array<std::int32_t, 3>> shell_tris;
  std::vector<std::int32_t> shell_tri_face;

  // Thickness and direction at (u,v) of a wall face (bilinear, d normalised). Throws
  // std::out_of_range for a face without a grid.
  std::pair<double, Vec3> face_field(int face, double u, double v) const;
  // At parameter t of a wall edge, as seen from `face` (-1: the first side).
  std::pair<double, Vec3> edge_field(int edge, double t, int face = -1) const;
  nlohmann::json summary() const;
};

// One face grid at (u,v): bilinear in t and d, d normalised ((u,v) clamped to the grid's box).
std::pair<double, Vec3> grid_field(const FaceGrid& g, double u, double v);
// The same field as sweep builds the shell from it (and the shell stage samples it): (u,v) of a
// periodic face first taken in the grid's period (a projection onto a hub returns an angle in
// [0, 2 pi) where the grid may span [-0.14, 0.37]); and where the exact fluid normal
// (-face_normal) turns by more than 30 degrees between the cell's corners and (u,v) (a leading or
// trailing edge far thinner than a grid cell: Rotor 67's blade, radius ~1e-3 ft inside one cell
// of its grid) the deviation of d from the normal is interpolated, not d itself:
// d = normalise(n(x) + sum_c w_c (d_c - n_c)); bilinear d would be a mean of the normals on both
// sides of the nose, nearly tangent to the wall. Elsewhere, at poles and where the deviation
// undoes the normal: grid_field's direction. The thickness is always grid_field's.
std::pair<double, Vec3> grid_field_on(const FaceGrid& g, const cad::Shape& shape, double u, double v);

void write(const ShellData& s, const std::filesystem::path& file);
// Throws meshflow::StageError naming the file when missing, truncated or not a shell artifact.
ShellData read(const std::filesystem::path& file);

// ── checks (CGAL AABB tree, shell_check.cpp) ───────────────────────────────────────────
struct IntersectionReport {
  long pairs = 0;             // intersecting triangle pairs not sharing a vertex
  Vec3 first{};               // a point of the first pair (centroid of its first triangle)
  std::vector<std::array<int, 2>> examples;  // up to 10 pairs
  std::vector<std::array<int, 2>> all;       // every pair (triangle indices), in report order
};
// `threads` > 1: the triangles are tested in parallel, the report is the same at any count.
IntersectionReport self_intersections(const std::vector<Vec3>& points,
                                      const std::vector<std::array<std::int32_t, 3>>& tris, int threads = 1);

// Constrained Delaunay triangulation (CGAL, 2D) of points with constrained segments (index
// pairs): all triangles of the convex hull as index triples, counter-clockwise, sorted. With
// `depth`, each triangle's nesting depth: the number of constrained segments crossed on the way
// from the unbounded face (flood fill over the triangulation: the triangles inside closed loops
// of segments, holes excluded, are those of odd depth, decided combinatorially, with no
// point-in-polygon test that a sliver along a nearly straight boundary could fool). Throws
// std::runtime_error when CGAL fails or when two segments cross (CGAL would insert their
// intersection point, which has no input index).
std::vector<std::array<std::int32_t, 3>> cdt2(const std::vector<std::array<double, 2>>& points,
                                              const std::vector<std::array<std::int32_t, 2>>& segments,
                                              std::vector<int>* depth = nullptr);

}  // namespace meshflow::shell
