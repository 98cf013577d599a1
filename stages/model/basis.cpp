#include "stages/model/basis.hpp"

#include <Eigen/Dense>

#include <cmath>
#include <mutex>
#include <stdexcept>

namespace meshflow::model {

namespace {

std::vector<Lattice> exponents(Shape s, int p) {
  std::vector<Lattice> e;
  switch (s) {
    case Shape::Point: e.push_back({0, 0, 0}); break;
    case Shape::Line:
      for (int i = 0; i <= p; ++i) e.push_back({i, 0, 0});
      break;
    case Shape::Tri:
      for (int i = 0; i <= p; ++i)
        for (int j = 0; i + j <= p; ++j) e.push_back({i, j, 0});
      break;
    case Shape::Quad:
      for (int i = 0; i <= p; ++i)
        for (int j = 0; j <= p; ++j) e.push_back({i, j, 0});
      break;
    case Shape::Tet:
      for (int i = 0; i <= p; ++i)
        for (int j = 0; i + j <= p; ++j)
          for (int k = 0; i + j + k <= p; ++k) e.push_back({i, j, k});
      break;
    case Shape::Hex:
      for (int i = 0; i <= p; ++i)
        for (int j = 0; j <= p; ++j)
          for (int k = 0; k <= p; ++k) e.push_back({i, j, k});
      break;
    case Shape::Prism:
      for (int i = 0; i <= p; ++i)
        for (int j = 0; i + j <= p; ++j)
          for (int k = 0; k <= p; ++k) e.push_back({i, j, k});
      break;
    case Shape::Pyramid:
      for (int i = 0; i <= p; ++i)
        for (int j = 0; j <= p; ++j)
          for (int k = 0; k + std::max(i, j) <= p; ++k) e.push_back({i, j, k});
      break;
  }
  return e;
}

double ipow(double x, int n) {
  double r = 1;
  for (int i = 0; i < n; ++i) r *= x;
  return r;
}

}  // namespace

const LagrangeBasis& LagrangeBasis::get(Shape s, int order) {
  static std::mutex mu;
  static std::unique_ptr<LagrangeBasis> cache[kNumShapes][kMaxOrder + 1];
  if (order < 1 || order > kMaxOrder) throw std::out_of_range("basis order out of range");
  std::lock_guard<std::mutex> lock(mu);
  auto& slot = cache[static_cast<int>(s)][order];
  if (!slot) slot = std::make_unique<LagrangeBasis>(s, order, reference_nodes(s, order));
  return *slot;
}

LagrangeBasis::LagrangeBasis(Shape s, int order, const std::vector<Vec3>& nodes)
    : shape_(s), order_(order), exps_(exponents(s, order)), nodes_(nodes) {
  n_ = static_cast<int>(exps_.size());
  if (static_cast<int>(nodes.size()) != n_)
    throw std::invalid_argument("LagrangeBasis: " + std::to_string(nodes.size()) + " nodes for a " +
                                shape_name(s) + " of order " + std::to_string(order) + " (needs " +
                                std::to_string(n_) + ")");
  Eigen::MatrixXd V(n_, n_);
  std::vector<double> phi(n_);
  for (int i = 0; i < n_; ++i) {
    monomials(nodes[i], phi.data(), nullptr);
    for (int m = 0; m < n_; ++m) V(i, m) = phi[m];
  }
  Eigen::FullPivLU<Eigen::MatrixXd> lu(V);
  if (!lu.isInvertible()) throw std::invalid_argument("LagrangeBasis: nodes are not unisolvent");
  Eigen::MatrixXd inv = lu.inverse();  // N = phi^T inv  => N_i = sum_m phi_m inv(m, i)
  inv_.resize(static_cast<size_t>(n_) * n_);
  for (int m = 0; m < n_; ++m)
    for (int i = 0; i < n_; ++i) inv_[static_cast<size_t>(m) * n_ + i] = inv(m, i);
}

void LagrangeBasis::monomials(const Vec3& xi, double* phi, double* dphi) const {
  const double x = xi[0], y = xi[1], z = xi[2];
  for (int m = 0; m < n_; ++m) {
    const int i = exps_[m][0], j = exps_[m][1], k = exps_[m][2];
    if (shape_ != Shape::Pyramid) {
      phi[m] = ipow(x, i) * ipow(y, j) * ipow(z, k);
      if (dphi) {
        dphi[3 * m + 0] = i ? i * ipow(x, i - 1) * ipow(y, j) * ipow(z, k) : 0.0;
        dphi[3 * m + 1] = j ? j * ipow(x, i) * ipow(y, j - 1) * ipow(z, k) : 0.0;
        dphi[3 * m + 2] = k ? k * ipow(x, i) * ipow(y, j) * ipow(z, k - 1) : 0.0;
      }
      continue;
    }
    // Bergot's pyramidal space; the apex (z = 1) is the limit from inside.
    const int mx = std::max(i, j);
    double w = 1 - z;
    if (w < 1e-14) {
      phi[m] = mx == 0 ? ipow(z, k) : 0.0;
      if (dphi) {  // gradients at the apex are direction-dependent; evaluate just below it
        Vec3 below = {x, y, 1 - 1e-9};
        std::vector<double> tmp(n_), dtmp(3 * static_cast<size_t>(n_));
        monomials(below, tmp.data(), dtmp.data());
        for (int c = 0; c < 3; ++c) dphi[3 * m + c] = dtmp[3 * m + c];
      }
      continue;
    }
    const double xh = x / w, yh = y / w;
    const double base = ipow(xh, i) * ipow(yh, j);
    phi[m] = base * ipow(w, mx) * ipow(z, k);
    if (dphi) {
      const double wm1 = mx >= 1 ? ipow(w, mx - 1) : 1.0 / w;
      dphi[3 * m + 0] = i ? i * ipow(xh, i - 1) * ipow(yh, j) * wm1 * ipow(z, k) : 0.0;
      dphi[3 * m + 1] = j ? j * ipow(xh, i) * ipow(yh, j - 1) * wm1 * ipow(z, k) : 0.0;
      double dz = (i + j - mx) * base * wm1 * ipow(z, k);
      if (k) dz += k * base * ipow(w, mx) * ipow(z, k - 1);
      dphi[3 * m + 2] = dz;
    }
  }
}

void LagrangeBasis::eval(const Vec3& xi, double* N) const {
  std::vector<double> phi(n_);
  monomials(xi, phi.data(), nullptr);
  for (int i = 0; i < n_; ++i) N[i] = 0;
  for (int m = 0; m < n_; ++m) {
    const double pm = phi[m];
    if (pm == 0) continue;
    const double* row = &inv_[static_cast<size_t>(m) * n_];
    for (int i = 0; i < n_; ++i) N[i] += pm * row[i];
  }
}

void LagrangeBasis::grad(const Vec3& xi, double* dN) const {
  std::vector<double> phi(n_), dphi(3 * static_cast<size_t>(n_));
  monomials(xi, phi.data(), dphi.data());
  for (int i = 0; i < 3 * n_; ++i) dN[i] = 0;
  for (int m = 0; m < n_; ++m) {
    const double* row = &inv_[static_cast<size_t>(m) * n_];
    for (int c = 0; c < 3; ++c) {
      const double d = dphi[3 * m + c];
      if (d == 0) continue;
      for (int i = 0; i < n_; ++i) dN[3 * i + c] += d * row[i];
    }
  }
}

Vec3 map_point(const LagrangeBasis& b, const double* X, const Vec3& xi) {
  std::vector<double> N(b.size());
  b.eval(xi, N.data());
  Vec3 x = {0, 0, 0};
  for (int i = 0; i < b.size(); ++i)
    for (int r = 0; r < 3; ++r) x[r] += N[i] * X[3 * i + r];
  return x;
}

void jacobian(const LagrangeBasis& b, const double* X, const Vec3& xi, double J[9]) {
  std::vector<double> dN(3 * static_cast<size_t>(b.size()));
  b.grad(xi, dN.data());
  jacobian(X, dN.data(), b.size(), J);
}
void jacobian(const double* X, const double* dN, int n, double J[9]) {
  for (int i = 0; i < 9; ++i) J[i] = 0;
  for (int i = 0; i < n; ++i)
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) J[3 * r + c] += X[3 * i + r] * dN[3 * i + c];
}

double jacobian_determinant(int dim, const double J[9], const double normal[3]) {
  if (dim == 3)
    return J[0] * (J[4] * J[8] - J[5] * J[7]) - J[1] * (J[3] * J[8] - J[5] * J[6]) +
           J[2] * (J[3] * J[7] - J[4] * J[6]);
  if (dim == 2) {
    const double cx = J[3] * J[7] - J[6] * J[4];  // (col0 x col1)
    const double cy = J[6] * J[1] - J[0] * J[7];
    const double cz = J[0] * J[4] - J[3] * J[1];
    return cx * normal[0] + cy * normal[1] + cz * normal[2];
  }
  if (dim == 1) return std::sqrt(J[0] * J[0] + J[3] * J[3] + J[6] * J[6]);
  return 1.0;
}

Vec3 map_linear(Shape s, const std::vector<Vec3>& vertices, const Vec3& zeta) {
  const LagrangeBasis& b1 = LagrangeBasis::get(s, 1);
  double N[8];
  b1.eval(zeta, N);
  Vec3 x = {0, 0, 0};
  for (int v = 0; v < b1.size(); ++v)
    for (int r = 0; r < 3; ++r) x[r] += N[v] * vertices[v][r];
  return x;
}

std::vector<double> map_sub_element(Shape parent, int parent_order, const double* X, Shape sub,
                                    int sub_order, const std::vector<Vec3>& sub_vertices) {
  if (static_cast<int>(sub_vertices.size()) != num_vertices(sub))
    throw std::invalid_argument("map_sub_element: wrong number of sub-element vertices");
  const LagrangeBasis& pb = LagrangeBasis::get(parent, parent_order);
  const auto& zeta = reference_nodes(sub, sub_order);
  std::vector<double> out(3 * zeta.size());
  for (size_t i = 0; i < zeta.size(); ++i) {
    Vec3 x = map_point(pb, X, map_linear(sub, sub_vertices, zeta[i]));
    for (int r = 0; r < 3; ++r) out[3 * i + r] = x[r];
  }
  return out;
}

}  // namespace meshflow::model
