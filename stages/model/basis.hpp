// meshflow mesh model — nodal Lagrange bases on the reference elements, element mappings.
//
// A basis is the Lagrange basis of the element's polynomial space interpolating at a node
// set; by default the equispaced Gmsh node set of element.hpp (so basis functions are
// numbered like the element's nodes). Spaces: P_P on simplices, Q_P on quads/hexes,
// P_P(triangle) x P_P(line) on prisms, and on pyramids the rational space of Bergot, Cohen
// and Duruflé (2010) that Gmsh also uses, spanned by x'^i y'^j (1-z)^max(i,j) z^k with
// x' = x/(1-z), y' = y/(1-z), 0 <= i,j <= P, 0 <= k <= P - max(i,j). The nodal basis is the
// monomial basis times the inverse Vandermonde matrix (exact enough up to P = 10 on these
// small reference domains; no library offers these spaces with Gmsh's node numbering).
#pragma once

#include "stages/model/element.hpp"

#include <memory>
#include <vector>

namespace meshflow::model {

class LagrangeBasis {
 public:
  // The basis on the element's own (Gmsh, equispaced) nodes; cached, thread-safe.
  static const LagrangeBasis& get(Shape s, int order);
  // A basis of the same space interpolating at other nodes (e.g. Gauss-Lobatto-Legendre or
  // electrostatic points read from Nektar++ files). Throws if the nodes are unisolvent-bad.
  LagrangeBasis(Shape s, int order, const std::vector<Vec3>& nodes);

  Shape shape() const { return shape_; }
  int order() const { return order_; }
  int size() const { return n_; }
  const std::vector<Vec3>& nodes() const { return nodes_; }

  // N[i] = value of basis function i at xi.
  void eval(const Vec3& xi, double* N) const;
  // dN[3*i+c] = d N_i / d xi_c (c < dimension; the other entries are 0).
  void grad(const Vec3& xi, double* dN) const;

 private:
  void monomials(const Vec3& xi, double* phi, double* dphi) const;
  Shape shape_;
  int order_, n_;
  std::vector<Lattice> exps_;
  std::vector<Vec3> nodes_;
  std::vector<double> inv_;  // inverse Vandermonde, n x n row-major: N_i = sum_m phi_m inv_[m*n+i]
};

// Element mapping x(xi) = sum_i X_i N_i(xi); X is node coordinates xyz-interleaved (3*n).
Vec3 map_point(const LagrangeBasis& b, const double* X, const Vec3& xi);
// J[3*r+c] = d x_r / d xi_c (3x3; for 2D elements column 2 is 0, for lines columns 1-2).
void jacobian(const LagrangeBasis& b, const double* X, const Vec3& xi, double J[9]);
// The same from the n basis gradients at xi (dN[3*i+c] = dN_i/dxi_c, as LagrangeBasis::grad
// writes them), for callers that evaluate one point set for many elements.
void jacobian(const double* X, const double* dN, int n, double J[9]);
// Determinant used for validity: 3D: det J; 2D: (J_0 x J_1) . normal; 1D: |J_0|.
double jacobian_determinant(int dim, const double J[9], const double normal[3]);

// Sub-element mapping: the nodes of a sub-element of `sub` shape and `sub_order` whose
// vertices are `sub_vertices` (reference coordinates of the parent, in the sub-element's
// Gmsh vertex order), mapped through the parent's mapping: x = x_parent(chi(zeta)), chi the
// linear (multilinear) map of the sub-element in the parent's reference space. Returns
// 3*num_nodes(sub, sub_order) coordinates in Gmsh node order. Used by the split stage.
std::vector<double> map_sub_element(Shape parent, int parent_order, const double* X, Shape sub,
                                    int sub_order, const std::vector<Vec3>& sub_vertices);

// Linear (order-1) map of a reference domain with the given vertices, at zeta.
Vec3 map_linear(Shape s, const std::vector<Vec3>& vertices, const Vec3& zeta);

}  // namespace meshflow::model
