// meshflow mesh model — validity and quality of high-order elements.
//
// Validity (method "bezier"): det J > 0 over the whole element. det J of an order-P element
// is a polynomial: degree 3(P-1) on a tet, 2(P-1) on a triangle, 3P-1 per direction on a hex
// (Q_P: d/dxi lowers one direction only), 2P-1 per direction on a quad, and on a prism
// (P_P(tri) x P_P(line)) degree 3P-2 in the triangle variables times 3P-1 in the prism axis.
// We interpolate det J at a lattice of that degree (equispaced on simplices, Chebyshev-Lobatto
// along tensor directions, where the 1D Bernstein interpolation is far better conditioned),
// with J from exact product formulas (on quads, hexes and prisms by sum factorisation: one 1D or
// triangle contraction per direction, ~15x fewer operations than a dense product for a P=4
// hex), and convert the values to Bernstein (Bezier) coefficients with transforms computed in
// long double. All coefficients above a rigorous rounding bound prove validity (the polynomial
// is a convex combination of them); a sampled value <= 0 proves invalidity; otherwise the domain
// is subdivided (simplices into 4/8, boxes into 4/8, prisms into 8) and each part is checked
// again (at most 600 sub-domains per element, to depth 12 along any path; still undecided then:
// "inconclusive", which the mesh contract does not count as valid). This is
// the method of Johnen, Remacle and Geuzaine (2013) that Gmsh uses.
// Rounding bound, per element and per direction: amplification of the transform (its infinity
// norm) x (the transform's own rounding + det J's formula + the rounding of J's columns). Column
// c of J is computed from node differences along reference direction c (tensor shapes), so its
// rounding is relative to the element's extent along c: thin boundary-layer elements (aspect
// ratio 1000 and more) keep a bound relative to their thickness. (A bound relative to the
// Hadamard bound alone, as used before, is not a bound for such elements.)
// Tets first try a cheaper proof (the perturbation proof): J's Bernstein coefficients (m per
// entry, m = 20 at P=4) come from J at the degree-(P-1) lattice by one small transform; with K
// the inverse of their mean, if ||K J(xi) - I|| < 1 everywhere (bounded entrywise by the
// coefficients of K J - I, which Bernstein polynomials combine convexly, plus rounding bounds)
// every eigenvalue of K J lies in the disc |lambda - 1| < 1, so det(K J) > 0 and det J > 0 on
// the whole element. Sufficient, never necessary: the elements it does not prove (strongly
// curved or invalid) take the Bezier path below unchanged. A proven element skips det J's
// Bezier transform and the subdivision (P=4: ~48k of ~95k multiply-adds), so its scaled
// Jacobian is over the lattice points only. set_tet_perturbation_proof(false) turns it off
// (tests compare both paths).
// Proven this way: triangles, quads, tets up to P=6, prisms up to P=5, hexahedra up to P=4.
// Hexahedra of order >= 5 (transform amplification >= 1.6e12: no useful rigorous bound) get
// det J's Bernstein coefficients by Bernstein arithmetic instead: control points of the mapping
// (of node differences along each direction; a well-conditioned degree-P transform), derivatives
// in Bernstein form, products by convolution of scaled coefficients (positive weights), rounding
// bounded by the same computation on absolute values plus the propagated rounding of the
// control points; subdivision by de Casteljau. Prisms of order >= 6 (amplification 2e11) are
// sampled (reported in "sampled", not proven). Pyramids: see below.
// Pyramids (proven, Bernstein arithmetic in collapsed coordinates): Gmsh's pyramidal space
// (Bergot) is rational, so det J is not a polynomial in (x, y, z); but in the collapsed
// coordinates a = x/(1-z), b = y/(1-z), c = z the pyramid is the cube [-1,1]^2 x [0,1], the
// mapping is a polynomial of degree P in each of a, b, c, and det J = det[Q_a/(1-c), Q_b/(1-c), Q_c]
// is a polynomial of degrees (3P-1, 3P-1, 3P-3) whose tensor Bernstein coefficients come from the
// mapping's control points as for high-order hexes, with the same rounding bounds and de Casteljau
// subdivision. The face c = 1 holds det J's limits at the apex (direction-dependent), so the
// whole closed pyramid is decided. Their scaled Jacobian is over the samples of the pyramid
// lattice of order 3P+2 (apex excluded).
// Scaled Jacobian: min det J / max det J over the samples (the Bezier lattice points and
// those of the subdivisions, when the element needed subdividing). <= 0 for invalid elements.
// Aspect ratio: longest / shortest straight vertex-to-vertex edge of the element (for a thin
// boundary-layer prism: tangential size / layer thickness, the paper's "aspect ratio").
// 2D elements are measured with det = (dx/dxi x dx/deta) . n, n = +z for a mesh in a plane
// z = const, else the normal of the element's straight (vertex) geometry.
#pragma once

#include "stages/model/mesh.hpp"
#include "stages/model/topology.hpp"

#include <nlohmann/json_fwd.hpp>

#include <cstdint>
#include <vector>

namespace meshflow::model {

struct ElementQuality {
  double min_det = 0, max_det = 0;
  double scaled_jacobian = 1;
  double aspect_ratio = 1;
  bool valid = true;
  bool inconclusive = false;  // Bezier bounds inconclusive at the maximum depth
  bool sampled = false;       // method "sampling" (not proven: prisms of order >= 6)
};

// Quality of one element; X = 3*num_nodes(s, order) coordinates (Gmsh node order).
// `normal` is used for 2D elements (may be null: the straight-geometry normal).
ElementQuality element_quality(Shape s, int order, const double* X, const double* normal = nullptr);

// Tests and diagnostics: whether tets try the perturbation proof first (default true). Off, every
// tet takes the Bezier path; validity verdicts are the same either way (the proof is sound).
void set_tet_perturbation_proof(bool on);

// Quality of every element of the mesh's highest dimension: result[b][e] for block b
// (empty for the lower-dimensional blocks). Deterministic for any thread count.
// `known`: blocks whose quality is known already (known[b] has one entry per element of block b,
// e.g. elements a stage passed through unchanged, with the quality its input stored): copied,
// not computed (an element's quality is a function of its node coordinates alone). With
// `moved` (per node), known holds for the coordinates before those nodes moved: the elements
// with a moved node are computed, the others copied.
using MeshQuality = std::vector<std::vector<ElementQuality>>;
MeshQuality mesh_quality(const Mesh& m, int threads = 0, const MeshQuality* known = nullptr,
                         const std::vector<char>* moved = nullptr);
// Per node: whether its coordinates differ from (x0, y0, z0) (bitwise; nodes beyond them: moved).
std::vector<char> moved_nodes(const Mesh& m, const std::vector<double>& x0, const std::vector<double>& y0,
                              const std::vector<double>& z0);
// Number of mesh_quality calls in this process (tests: a writer given the stored quality must
// not compute it again).
std::uint64_t mesh_quality_calls();

// The statistics of the whole mesh as stored in stats.mesh and printed by
// `meshflow quality --json`:
//   {"order", "nodes", "elements": {tet, prism, hex, pyramid, tri, quad, line},
//    "boundary": {tri, quad, line}, "by_type": {"tet4": n, ...}, "groups": {name: faces},
//    "invalid", "invalid_elements": [tags, at most 100], "inconclusive", "nonconforming_faces",
//    "min_scaled_jacobian", "median_scaled_jacobian", "max_aspect_ratio",
//    "histograms": {"scaled_jacobian": {edges, counts}, "aspect_ratio": {...}},
//    "validity_method", "bbox", "fingerprint"}
nlohmann::json mesh_stats(const Mesh& m, int threads = 0);
// The same from the quality and topology already computed (the mesh contract needs both).
nlohmann::json mesh_stats(const Mesh& m, const std::vector<std::vector<ElementQuality>>& q, const Topology& topo);

}  // namespace meshflow::model
