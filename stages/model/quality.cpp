#include "stages/model/quality.hpp"

#include "stages/model/basis.hpp"
#include "stages/model/topology.hpp"

#include <Eigen/Dense>
#include <nlohmann/json.hpp>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <cmath>
#include <deque>
#include <limits>
#include <map>
#include <memory>
#include <mutex>

namespace meshflow::model {

namespace {

using LD = long double;

// Gradients of the nodal Lagrange basis on the element's equispaced (Gmsh) nodes, by product
// formulas accurate to rounding (not through an inverse Vandermonde matrix): simplices by
// Silvester's formula N = prod_m R_{a_m}(lambda_m), R_a(l) = prod_{s<a} (P l - s)/(s+1);
// quads/hexes as products of 1D Lagrange polynomials; prisms as triangle x line.
// dN[3*i+c] for node i (Gmsh order), direction c.
void silvester(int P, int a, LD l, LD& R, LD& dR) {  // R_a(l) and dR/dl
  R = 1, dR = 0;
  for (int s = 0; s < a; ++s) {
    const LD f = (P * l - s) / (s + 1), df = LD(P) / (s + 1);
    dR = dR * f + R * df;
    R *= f;
  }
}
void lagrange1(int P, int i, LD x, LD& L, LD& dL) {  // 1D Lagrange on -1 + 2s/P, s = 0..P
  L = 1, dL = 0;
  const LD xi = -1 + 2 * LD(i) / P;
  for (int s = 0; s <= P; ++s) {
    if (s == i) continue;
    const LD xs = -1 + 2 * LD(s) / P, den = xi - xs;
    dL = dL * (x - xs) / den + L / den;
    L *= (x - xs) / den;
  }
}
bool exact_grad_supported(Shape s) {
  return s == Shape::Tri || s == Shape::Quad || s == Shape::Tet || s == Shape::Prism || s == Shape::Hex;
}
void exact_grad(Shape s, int P, const Vec3& xi, LD* dN) {
  const auto& lat = lattice(s, P);
  const int n = (int)lat.size();
  for (int i = 0; i < n; ++i) {
    const Lattice& a = lat[i];
    LD g[3] = {0, 0, 0};
    if (s == Shape::Tri || s == Shape::Tet || s == Shape::Prism) {
      const bool tet = s == Shape::Tet;
      const LD x = xi[0], y = xi[1], z = tet ? LD(xi[2]) : 0;
      const int a0 = P - a[0] - a[1] - (tet ? a[2] : 0);
      LD R0, d0, R1, d1, R2, d2, R3 = 1, d3 = 0;
      silvester(P, a0, 1 - x - y - z, R0, d0);
      silvester(P, a[0], x, R1, d1);
      silvester(P, a[1], y, R2, d2);
      if (tet) silvester(P, a[2], z, R3, d3);
      LD L = 1, dL = 0;
      if (s == Shape::Prism) lagrange1(P, a[2], xi[2], L, dL);
      g[0] = (-d0 * R1 * R2 * R3 + R0 * d1 * R2 * R3) * L;
      g[1] = (-d0 * R1 * R2 * R3 + R0 * R1 * d2 * R3) * L;
      if (tet) g[2] = -d0 * R1 * R2 * R3 + R0 * R1 * R2 * d3;
      if (s == Shape::Prism) g[2] = R0 * R1 * R2 * dL;
    } else {  // quad, hex
      const int d = s == Shape::Hex ? 3 : 2;
      LD L[3] = {1, 1, 1}, dL[3] = {0, 0, 0};
      for (int c = 0; c < d; ++c) lagrange1(P, a[c], xi[c], L[c], dL[c]);
      g[0] = dL[0] * L[1] * L[2];
      g[1] = L[0] * dL[1] * L[2];
      if (d == 3) g[2] = L[0] * L[1] * dL[2];
    }
    for (int c = 0; c < 3; ++c) dN[3 * i + c] = g[c];
  }
}

double binom(int n, int k) {
  double r = 1;
  for (int i = 1; i <= k; ++i) r = r * (n - k + i) / i;
  return r;
}
double bern1(int d, int a, double t) { return binom(d, a) * std::pow(t, a) * std::pow(1 - t, d - a); }

// Bernstein basis of the det J space of one shape; `lat` = multi-indices (also the lattice
// points of the interpolation: point = index / degree).
// Relative rounding allowance of the Bernstein coefficients: the per-direction (<= 18 term)
// sums in up to 3 stages, the transform rounded from long double, the det J of the samples.
constexpr double kKappa = 128 * std::numeric_limits<double>::epsilon();

struct JacobianSpace {
  Shape shape;
  int order, dim;
  int d1 = 0, d2 = 0;               // degrees (d2: tensor/prism axis)
  std::vector<Lattice> lat;
  std::vector<Vec3> pts;             // canonical sample points (reference coordinates)
  Eigen::MatrixXd G;                 // (3*npts) x nnodes: dN_i/dxi_c at point p in row 3p+c
  Eigen::MatrixXd T;                 // lagrange values -> bezier coefficients (simplices)
  Eigen::MatrixXd Ta, Tb;            // factors: 1D (quad/hex: every axis) or triangle x line (prism)
  bool bezier = false;               // false: sampling only (pyramids, ill-conditioned degrees)
  double amplification = 0;

  // Bernstein coefficients of the det J values v at pts (lattice order: last index fastest).
  void to_bezier(const double* v, double* c) const {
    const int np = (int)pts.size();
    if (T.size()) {
      Eigen::Map<Eigen::VectorXd>(c, np) = T * Eigen::Map<const Eigen::VectorXd>(v, np);
      return;
    }
    if (shape == Shape::Prism) {  // V is (ntri x nline) row-major: C = Ta V Tb^T
      const int nl = d2 + 1, nt = np / nl;
      Eigen::Map<const Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>> V(v, nt, nl);
      Eigen::Map<Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>> C(c, nt, nl);
      C = Ta * V * Tb.transpose();
      return;
    }
    const int n1 = d1 + 1;
    std::vector<double> a(v, v + np), b(np);
    const int naxes = dim;
    for (int ax = 0; ax < naxes; ++ax) {  // apply Ta along axis ax (stride = n1^(naxes-1-ax))
      int stride = 1;
      for (int k = ax + 1; k < naxes; ++k) stride *= n1;
      for (int base = 0; base < np; ++base) {
        if ((base / stride) % n1 != 0) continue;
        for (int q = 0; q < n1; ++q) {
          double sum = 0;
          for (int r = 0; r < n1; ++r) sum += Ta(q, r) * a[base + r * stride];
          b[base + q * stride] = sum;
        }
      }
      std::swap(a, b);
    }
    std::copy(a.begin(), a.end(), c);
  }
  std::vector<std::vector<Vec3>> children;  // canonical subdivision (vertex lists)
  double ref_volume = 1;

  // Chebyshev-Gauss-Lobatto abscissa q of degree d on [-1,1] (tensor directions: the 1D
  // Bernstein interpolation there is ~100x better conditioned than on equispaced points)
  static double cheb(int q, int d) { return q == 0 ? -1.0 : q == d ? 1.0 : -std::cos(M_PI * q / d); }
  Vec3 point(const Lattice& a) const {
    switch (shape) {
      case Shape::Tri: return d1 ? Vec3{a[0] / double(d1), a[1] / double(d1), 0} : Vec3{1 / 3., 1 / 3., 0};
      case Shape::Tet: return d1 ? Vec3{a[0] / double(d1), a[1] / double(d1), a[2] / double(d1)} : Vec3{.25, .25, .25};
      case Shape::Quad: return {cheb(a[0], d1), cheb(a[1], d1), 0};
      case Shape::Hex: return {cheb(a[0], d1), cheb(a[1], d1), cheb(a[2], d1)};
      case Shape::Prism:
        return {d1 ? a[0] / double(d1) : 1 / 3., d1 ? a[1] / double(d1) : 1 / 3., cheb(a[2], d2)};
      default: return {0, 0, 0};
    }
  }
  double bernstein(const Lattice& a, const Vec3& x) const {
    switch (shape) {
      case Shape::Tri:
      case Shape::Tet: {
        const int d = d1;
        double l0 = 1 - x[0] - x[1] - (shape == Shape::Tet ? x[2] : 0);
        int a0 = d - a[0] - a[1] - a[2];
        double c = std::tgamma(d + 1) / (std::tgamma(a0 + 1) * std::tgamma(a[0] + 1) * std::tgamma(a[1] + 1) *
                                         std::tgamma(a[2] + 1));
        return c * std::pow(l0, a0) * std::pow(x[0], a[0]) * std::pow(x[1], a[1]) *
               (shape == Shape::Tet ? std::pow(x[2], a[2]) : 1.0);
      }
      case Shape::Quad: return bern1(d1, a[0], (x[0] + 1) / 2) * bern1(d1, a[1], (x[1] + 1) / 2);
      case Shape::Hex:
        return bern1(d1, a[0], (x[0] + 1) / 2) * bern1(d1, a[1], (x[1] + 1) / 2) * bern1(d1, a[2], (x[2] + 1) / 2);
      case Shape::Prism: {
        double l0 = 1 - x[0] - x[1];
        int a0 = d1 - a[0] - a[1];
        double c = std::tgamma(d1 + 1) / (std::tgamma(a0 + 1) * std::tgamma(a[0] + 1) * std::tgamma(a[1] + 1));
        return c * std::pow(l0, a0) * std::pow(x[0], a[0]) * std::pow(x[1], a[1]) * bern1(d2, a[2], (x[2] + 1) / 2);
      }
      default: return 0;
    }
  }

  JacobianSpace(Shape s, int p) : shape(s), order(p), dim(dimension(s)) {
    switch (s) {
      case Shape::Tri:
        d1 = 2 * (p - 1);
        for (int i = 0; i <= d1; ++i)
          for (int j = 0; i + j <= d1; ++j) lat.push_back({i, j, 0});
        ref_volume = 0.5;
        break;
      case Shape::Tet:
        d1 = 3 * (p - 1);
        for (int i = 0; i <= d1; ++i)
          for (int j = 0; i + j <= d1; ++j)
            for (int k = 0; i + j + k <= d1; ++k) lat.push_back({i, j, k});
        ref_volume = 1 / 6.;
        break;
      case Shape::Quad:
        d1 = 2 * p - 1;
        for (int i = 0; i <= d1; ++i)
          for (int j = 0; j <= d1; ++j) lat.push_back({i, j, 0});
        ref_volume = 4;
        break;
      case Shape::Hex:
        d1 = 3 * p - 1;
        for (int i = 0; i <= d1; ++i)
          for (int j = 0; j <= d1; ++j)
            for (int k = 0; k <= d1; ++k) lat.push_back({i, j, k});
        ref_volume = 8;
        break;
      case Shape::Prism:
        d1 = 3 * p - 2;
        d2 = 3 * p - 1;
        for (int i = 0; i <= d1; ++i)
          for (int j = 0; i + j <= d1; ++j)
            for (int k = 0; k <= d2; ++k) lat.push_back({i, j, k});
        ref_volume = 1;
        break;
      case Shape::Pyramid: {  // sampling: pyramid lattice of order 3P+2 without the apex
        const int q = 3 * p + 2;
        for (int k = 1; k <= q; ++k)  // layer k from the apex has (k+1)^2 points
          for (int i = 0; i <= k; ++i)
            for (int j = 0; j <= k; ++j) pts.push_back(lattice_to_reference(Shape::Pyramid, q, {i, j, k}));
        ref_volume = 4. / 3.;
        break;
      }
      default: break;
    }
    for (auto& a : lat) pts.push_back(point(a));
    const LagrangeBasis& b = LagrangeBasis::get(s, p);
    const int n = b.size(), np = (int)pts.size();
    G.resize(3 * np, n);
    std::vector<double> dN(3 * n);
    std::vector<LD> dNl(3 * n);
    for (int q = 0; q < np; ++q) {
      if (exact_grad_supported(s)) {
        exact_grad(s, p, pts[q], dNl.data());
        for (int k = 0; k < 3 * n; ++k) dN[k] = (double)dNl[k];
      } else {
        b.grad(pts[q], dN.data());
      }
      for (int c = 0; c < 3; ++c)
        for (int i = 0; i < n; ++i) G(3 * q + c, i) = dN[3 * i + c];
    }
    if (!lat.empty()) {
      // Lagrange -> Bernstein: dense on simplices, factorised (Kronecker) on tensor shapes.
      // (the transforms are computed in long double and rounded once to double)
      using MatL = Eigen::Matrix<LD, Eigen::Dynamic, Eigen::Dynamic>;
      auto inv1 = [](int d) {
        MatL M(d + 1, d + 1);
        for (int q = 0; q <= d; ++q) {
          const LD t = (1 + (LD)cheb(q, d)) / 2;
          for (int a = 0; a <= d; ++a) M(q, a) = (LD)binom(d, a) * std::pow(t, (LD)a) * std::pow(1 - t, (LD)(d - a));
        }
        return Eigen::MatrixXd(MatL(M.fullPivLu().inverse()).cast<double>());
      };
      if (s == Shape::Tri || s == Shape::Tet) {
        MatL M(np, np);
        for (int q = 0; q < np; ++q)
          for (int a = 0; a < np; ++a) {
            const LD x = (LD)lat[q][0] / d1, y = (LD)lat[q][1] / d1, z = (LD)lat[q][2] / d1;
            const int a0 = d1 - lat[a][0] - lat[a][1] - lat[a][2];
            LD c = 1;  // multinomial d1! / (a0! a1! a2! a3!)
            for (int k = 1; k <= d1; ++k) c *= k;
            for (int e : {a0, lat[a][0], lat[a][1], lat[a][2]})
              for (int k = 2; k <= e; ++k) c /= k;
            M(q, a) = c * std::pow(1 - x - y - z, (LD)a0) * std::pow(x, (LD)lat[a][0]) * std::pow(y, (LD)lat[a][1]) *
                      std::pow(z, (LD)lat[a][2]);
          }
        T = MatL(M.partialPivLu().inverse()).cast<double>();
      } else if (s == Shape::Prism) {
        std::vector<Lattice> tl;
        for (int i = 0; i <= d1; ++i)
          for (int j = 0; i + j <= d1; ++j) tl.push_back({i, j, 0});
        const int nt = (int)tl.size();
        MatL M(nt, nt);
        for (int q = 0; q < nt; ++q)
          for (int a = 0; a < nt; ++a) {
            const LD x = d1 ? (LD)tl[q][0] / d1 : LD(1) / 3, y = d1 ? (LD)tl[q][1] / d1 : LD(1) / 3;
            const int a0 = d1 - tl[a][0] - tl[a][1];
            LD c = 1;
            for (int k = 1; k <= d1; ++k) c *= k;
            for (int e : {a0, tl[a][0], tl[a][1]})
              for (int k = 2; k <= e; ++k) c /= k;
            M(q, a) = c * std::pow(1 - x - y, (LD)a0) * std::pow(x, (LD)tl[a][0]) * std::pow(y, (LD)tl[a][1]);
          }
        Ta = MatL(M.fullPivLu().inverse()).cast<double>();
        Tb = inv1(d2);
      } else {
        Ta = inv1(d1);
      }
      // Values -> Bernstein is ill-conditioned at high degree: the amplification is the
      // infinity norm of the transform (a product of the factors' norms on tensor shapes).
      // A coefficient is trusted positive only above the rounding bound
      // kKappa * amplification * (max over samples of the Hadamard bound of det J), see
      // classify(); where that bound would exceed 14% of det J's scale the transform cannot
      // certify anything useful: hexahedra of order >= 6, proven by Bernstein arithmetic
      // instead (hex_bezier_validity); pyramids are always sampled.
      auto rowsum = [](const Eigen::MatrixXd& A) { return A.cwiseAbs().rowwise().sum().maxCoeff(); };
      amplification = T.size() ? rowsum(T)
                      : s == Shape::Prism ? rowsum(Ta) * rowsum(Tb)
                                          : std::pow(rowsum(Ta), dim);
      bezier = amplification * kKappa < 0.14;
    }
    // canonical children as vertex lists in reference coordinates
    auto mid = [](Vec3 a, Vec3 b) { return Vec3{(a[0] + b[0]) / 2, (a[1] + b[1]) / 2, (a[2] + b[2]) / 2}; };
    if (s == Shape::Tri || s == Shape::Prism) {
      Vec3 v0{0, 0, 0}, v1{1, 0, 0}, v2{0, 1, 0};
      Vec3 m01 = mid(v0, v1), m12 = mid(v1, v2), m20 = mid(v2, v0);
      std::vector<std::array<Vec3, 3>> tris = {{v0, m01, m20}, {m01, v1, m12}, {m20, m12, v2}, {m12, m20, m01}};
      if (s == Shape::Tri)
        for (auto& t : tris) children.push_back({t[0], t[1], t[2]});
      else
        for (auto& t : tris)
          for (double z0 : {-1.0, 0.0}) {
            std::vector<Vec3> c;
            for (double z : {z0, z0 + 1})
              for (auto v : t) c.push_back({v[0], v[1], z});
            children.push_back(c);
          }
    } else if (s == Shape::Tet) {
      Vec3 v[4] = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
      Vec3 m01 = mid(v[0], v[1]), m02 = mid(v[0], v[2]), m03 = mid(v[0], v[3]), m12 = mid(v[1], v[2]),
           m13 = mid(v[1], v[3]), m23 = mid(v[2], v[3]);
      children = {{v[0], m01, m02, m03}, {m01, v[1], m12, m13}, {m02, m12, v[2], m23}, {m03, m13, m23, v[3]},
                  {m01, m02, m03, m13},  {m01, m02, m12, m13},  {m02, m03, m13, m23},  {m02, m12, m13, m23}};
    } else if (s == Shape::Quad || s == Shape::Hex) {
      const auto& rv = reference_nodes(s, 1);
      int nz = s == Shape::Hex ? 2 : 1;
      for (int cz = 0; cz < nz; ++cz)
        for (int cy = 0; cy < 2; ++cy)
          for (int cx = 0; cx < 2; ++cx) {
            std::vector<Vec3> c;
            for (auto r : rv) {
              Vec3 q{cx - 1 + (r[0] + 1) / 2, cy - 1 + (r[1] + 1) / 2, s == Shape::Hex ? cz - 1 + (r[2] + 1) / 2 : 0};
              c.push_back(q);
            }
            children.push_back(c);
          }
    }
  }
};

const JacobianSpace& space(Shape s, int p) {
  static std::mutex mu;
  static std::unique_ptr<JacobianSpace> cache[kNumShapes][kMaxOrder + 1];
  std::lock_guard<std::mutex> lock(mu);
  auto& slot = cache[static_cast<int>(s)][p];
  if (!slot) slot = std::make_unique<JacobianSpace>(s, p);
  return *slot;
}

double det_at(int dim, const double J[9], const double* normal) { return jacobian_determinant(dim, J, normal); }
// Hadamard bound of |det J| (product of the column lengths): the scale of det J's rounding.
double hadamard(int dim, const double J[9]) {
  double h = 1;
  for (int c = 0; c < dim; ++c) h *= std::sqrt(J[c] * J[c] + J[3 + c] * J[3 + c] + J[6 + c] * J[6 + c]);
  return h;
}

void straight_normal(Shape s, const double* X, double n[3]) {
  auto P = [&](int i, int r) { return X[3 * i + r]; };
  double a[3], b[3];
  if (s == Shape::Tri)
    for (int r = 0; r < 3; ++r) a[r] = P(1, r) - P(0, r), b[r] = P(2, r) - P(0, r);
  else
    for (int r = 0; r < 3; ++r) a[r] = P(2, r) - P(0, r), b[r] = P(3, r) - P(1, r);
  n[0] = a[1] * b[2] - a[2] * b[1];
  n[1] = a[2] * b[0] - a[0] * b[2];
  n[2] = a[0] * b[1] - a[1] * b[0];
  double l = std::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
  if (l > 0)
    for (int r = 0; r < 3; ++r) n[r] /= l;
}

double aspect(Shape s, const double* X) {
  double lo = std::numeric_limits<double>::infinity(), hi = 0;
  for (auto [a, b] : edge_vertices(s)) {
    double d2 = 0;
    for (int r = 0; r < 3; ++r) d2 += (X[3 * a + r] - X[3 * b + r]) * (X[3 * a + r] - X[3 * b + r]);
    lo = std::min(lo, d2);
    hi = std::max(hi, d2);
  }
  if (hi == 0) return 1;
  if (lo == 0) return std::numeric_limits<double>::max();
  return std::sqrt(hi / lo);
}

// Slow path: subdivide the reference domain until the Bezier bounds decide.
void refine(const JacobianSpace& sp, const double* X, const double* normal, ElementQuality& q) {
  const LagrangeBasis& b = LagrangeBasis::get(sp.shape, sp.order);
  const int np = (int)sp.pts.size(), n = b.size();
  std::vector<double> dN(3 * n);
  std::vector<LD> dNl(3 * n);
  const bool exact = exact_grad_supported(sp.shape);
  std::deque<std::pair<std::vector<Vec3>, int>> todo;
  for (auto& c : sp.children) todo.push_back({c, 1});
  const int max_depth = 6, max_domains = 600;
  int visited = 0;
  Eigen::VectorXd v(np);
  while (!todo.empty()) {
    auto [dom, depth] = std::move(todo.front());
    todo.pop_front();
    double href = 0;
    if (++visited > max_domains) {
      q.inconclusive = true;
      return;
    }
    for (int p = 0; p < np; ++p) {
      Vec3 xi = map_linear(sp.shape, dom, sp.pts[p]);
      if (exact) {
        exact_grad(sp.shape, sp.order, xi, dNl.data());
        for (int k = 0; k < 3 * n; ++k) dN[k] = (double)dNl[k];
      } else {
        b.grad(xi, dN.data());
      }
      double J[9] = {0, 0, 0, 0, 0, 0, 0, 0, 0};
      for (int i = 0; i < n; ++i)
        for (int r = 0; r < 3; ++r)
          for (int c = 0; c < 3; ++c) J[3 * r + c] += X[3 * i + r] * dN[3 * i + c];
      v[p] = det_at(sp.dim, J, normal);
      href = std::max(href, hadamard(sp.dim, J));
      q.min_det = std::min(q.min_det, v[p]);
      q.max_det = std::max(q.max_det, v[p]);
    }
    if (v.minCoeff() <= 0) {
      q.valid = false;
      return;
    }
    Eigen::VectorXd c(np);
    sp.to_bezier(v.data(), c.data());
    if (c.minCoeff() > kKappa * sp.amplification * href) continue;
    if (depth >= max_depth) {
      q.inconclusive = true;
      continue;
    }
    for (auto& ch : sp.children) {
      std::vector<Vec3> sub;
      for (auto& cv : ch) sub.push_back(map_linear(sp.shape, dom, cv));
      todo.push_back({sub, depth + 1});
    }
  }
}

// Classifies element e of a chunk given its det values and coefficients.
// ---- Hexahedra of high order: det J in Bernstein form by Bernstein arithmetic ----
// The interpolation transform of det J (degree 3P-1 per direction) is too ill-conditioned at
// P >= 6; instead the mapping's nodes are converted to Bernstein control points (degree P, a
// well-conditioned 1D transform per direction), differentiated in Bernstein form, and det J's
// coefficients formed exactly as sums of products ("scaled" Bernstein coefficients b*C(n,i)
// multiply by plain convolution), with positive weights only. Every operation is also done on
// absolute values, which bounds the rounding. Subdivision: de Casteljau at t = 1/2 per axis.
struct Tensor {  // coefficients on (n0+1)(n1+1)(n2+1), index (i*(n1+1)+j)*(n2+1)+k
  int n[3] = {0, 0, 0};
  std::vector<double> c;
  Tensor() = default;
  Tensor(int a, int b, int d) : n{a, b, d}, c(std::size_t(a + 1) * (b + 1) * (d + 1), 0.0) {}
  double& at(int i, int j, int k) { return c[(std::size_t(i) * (n[1] + 1) + j) * (n[2] + 1) + k]; }
  double at(int i, int j, int k) const { return c[(std::size_t(i) * (n[1] + 1) + j) * (n[2] + 1) + k]; }
};
// plain 3D convolution of scaled coefficients (A, B scaled: product is scaled)
Tensor convolve(const Tensor& A, const Tensor& B) {
  Tensor C(A.n[0] + B.n[0], A.n[1] + B.n[1], A.n[2] + B.n[2]);
  for (int i = 0; i <= A.n[0]; ++i)
    for (int j = 0; j <= A.n[1]; ++j)
      for (int k = 0; k <= A.n[2]; ++k) {
        const double a = A.at(i, j, k);
        if (a == 0) continue;
        for (int p = 0; p <= B.n[0]; ++p)
          for (int q = 0; q <= B.n[1]; ++q) {
            const double* b = &B.c[(std::size_t(p) * (B.n[1] + 1) + q) * (B.n[2] + 1)];
            double* c = &C.at(i + p, j + q, k);
            for (int r = 0; r <= B.n[2]; ++r) c[r] += a * b[r];
          }
      }
  return C;
}
void axpy(Tensor& Y, double s, const Tensor& X) {
  for (std::size_t i = 0; i < Y.c.size(); ++i) Y.c[i] += s * X.c[i];
}
Tensor absval(const Tensor& A) {
  Tensor B = A;
  for (auto& v : B.c) v = std::abs(v);
  return B;
}
void scale_binomial(Tensor& T, bool divide) {  // multiply (or divide) by C(n0,i)C(n1,j)C(n2,k)
  for (int i = 0; i <= T.n[0]; ++i)
    for (int j = 0; j <= T.n[1]; ++j)
      for (int k = 0; k <= T.n[2]; ++k) {
        const double w = binom(T.n[0], i) * binom(T.n[1], j) * binom(T.n[2], k);
        T.at(i, j, k) = divide ? T.at(i, j, k) / w : T.at(i, j, k) * w;
      }
}
// de Casteljau split along axis `ax` at t = 1/2: lower (half 0) or upper (half 1) part
Tensor split(const Tensor& T, int ax, int half) {
  Tensor R = T;
  const int n = T.n[ax];
  int idx[3];
  const int m0 = ax == 0 ? 0 : T.n[0], m1 = ax == 1 ? 0 : T.n[1], m2 = ax == 2 ? 0 : T.n[2];
  std::vector<double> b(n + 1), out(n + 1);
  for (idx[0] = 0; idx[0] <= m0; ++idx[0])
    for (idx[1] = 0; idx[1] <= m1; ++idx[1])
      for (idx[2] = 0; idx[2] <= m2; ++idx[2]) {
        int w[3] = {idx[0], idx[1], idx[2]};
        for (int i = 0; i <= n; ++i) w[ax] = i, b[i] = T.at(w[0], w[1], w[2]);
        for (int r = 0; r <= n; ++r) {  // after r steps b[0] is the lower part's r-th coefficient
          if (half == 0) out[r] = b[0];
          else out[n - r] = b[n - r];
          for (int i = 0; i < n - r; ++i) b[i] = 0.5 * (b[i] + b[i + 1]);
        }
        for (int i = 0; i <= n; ++i) w[ax] = i, R.at(w[0], w[1], w[2]) = out[i];
      }
  return R;
}
// Bernstein coefficients of det J (and a bound of their rounding) of a hex of order P.
void hex_det_bezier(int P, const double* X, Tensor& det, double& err) {
  // 1D equispaced Lagrange -> Bernstein of degree P (long double, rounded once)
  static std::mutex mu;
  static std::vector<double> cache[kMaxOrder + 1];
  std::vector<double> L2B;
  {
    std::lock_guard<std::mutex> lock(mu);
    if (cache[P].empty()) {
      Eigen::Matrix<LD, Eigen::Dynamic, Eigen::Dynamic> M(P + 1, P + 1);
      for (int q = 0; q <= P; ++q)
        for (int a = 0; a <= P; ++a) M(q, a) = (LD)binom(P, a) * std::pow((LD)q / P, (LD)a) * std::pow(1 - (LD)q / P, (LD)(P - a));
      Eigen::Matrix<LD, Eigen::Dynamic, Eigen::Dynamic> Mi = M.fullPivLu().inverse();
      cache[P].resize((P + 1) * (P + 1));
      for (int a = 0; a <= P; ++a)
        for (int q = 0; q <= P; ++q) cache[P][a * (P + 1) + q] = (double)Mi(a, q);
    }
    L2B = cache[P];
  }
  const auto& lat = lattice(Shape::Hex, P);
  Tensor B[3];
  for (int r = 0; r < 3; ++r) {
    Tensor V(P, P, P);
    for (std::size_t i = 0; i < lat.size(); ++i) V.at(lat[i][0], lat[i][1], lat[i][2]) = X[3 * i + r];
    for (int ax = 0; ax < 3; ++ax) {  // apply L2B along each axis
      Tensor W(P, P, P);
      for (int i = 0; i <= P; ++i)
        for (int j = 0; j <= P; ++j)
          for (int k = 0; k <= P; ++k) {
            double s = 0;
            for (int q = 0; q <= P; ++q) {
              const int a[3] = {ax == 0 ? q : i, ax == 1 ? q : j, ax == 2 ? q : k};
              s += L2B[(ax == 0 ? i : ax == 1 ? j : k) * (P + 1) + q] * V.at(a[0], a[1], a[2]);
            }
            W.at(i, j, k) = s;
          }
      V = W;
    }
    B[r] = V;
  }
  // derivatives (d/dxi = P/2 * forward differences), in scaled form
  Tensor D[3][3];  // D[r][c] = d x_r / d xi_c
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) {
      Tensor T(c == 0 ? P - 1 : P, c == 1 ? P - 1 : P, c == 2 ? P - 1 : P);
      for (int i = 0; i <= T.n[0]; ++i)
        for (int j = 0; j <= T.n[1]; ++j)
          for (int k = 0; k <= T.n[2]; ++k)
            T.at(i, j, k) = 0.5 * P * (B[r].at(i + (c == 0), j + (c == 1), k + (c == 2)) - B[r].at(i, j, k));
      scale_binomial(T, false);
      D[r][c] = T;
    }
  // det = x_xi (y_eta z_zeta - y_zeta z_eta) + x_eta (y_zeta z_xi - y_xi z_zeta) + x_zeta (y_xi z_eta - y_eta z_xi)
  det = Tensor(3 * P - 1, 3 * P - 1, 3 * P - 1);
  Tensor bound = det;
  const int perm[3][3] = {{0, 1, 2}, {1, 2, 0}, {2, 0, 1}};  // (c0 ; c1, c2) of each term
  for (auto& pc : perm) {
    const int c0 = pc[0], c1 = pc[1], c2 = pc[2];
    Tensor cof = convolve(D[1][c1], D[2][c2]);
    axpy(cof, -1, convolve(D[1][c2], D[2][c1]));
    Tensor cofa = convolve(absval(D[1][c1]), absval(D[2][c2]));
    axpy(cofa, 1, convolve(absval(D[1][c2]), absval(D[2][c1])));
    axpy(det, 1, convolve(D[0][c0], cof));
    axpy(bound, 1, convolve(absval(D[0][c0]), cofa));
  }
  scale_binomial(det, true);
  scale_binomial(bound, true);
  double bmax = 0;
  for (double b : bound.c) bmax = std::max(bmax, b);
  // products/sums of <= (P+1)^3 terms per coefficient, the control points' own rounding
  err = bmax * 1e-11;
}
// Proves validity of a hex by its det J coefficients, subdividing (de Casteljau) up to depth 6.
void hex_bezier_validity(int P, const double* X, ElementQuality& q) {
  Tensor det;
  double err = 0;
  hex_det_bezier(P, X, det, err);
  std::deque<std::pair<Tensor, int>> todo;
  todo.push_back({std::move(det), 0});
  int visited = 0;
  const int n = 3 * P - 1;
  while (!todo.empty()) {
    auto [T, depth] = std::move(todo.front());
    todo.pop_front();
    if (++visited > 600) {
      q.inconclusive = true;
      return;
    }
    // corner coefficients are values of det J: one <= 0 (beyond rounding) proves invalidity
    for (int i : {0, n})
      for (int j : {0, n})
        for (int k : {0, n})
          if (T.at(i, j, k) < -err) {
            q.valid = false;
            return;
          }
    const double mn = *std::min_element(T.c.begin(), T.c.end());
    if (mn > err) continue;
    if (depth >= 6) {
      q.inconclusive = true;
      continue;
    }
    for (int a = 0; a < 2; ++a) {
      Tensor Ta = split(T, 0, a);
      for (int b = 0; b < 2; ++b) {
        Tensor Tb = split(Ta, 1, b);
        for (int c = 0; c < 2; ++c) todo.push_back({split(Tb, 2, c), depth + 1});
      }
    }
  }
}

void classify(const JacobianSpace& sp, const double* X, const double* normal, const double* vals,
              const double* coef, double href, ElementQuality& q) {
  const int np = (int)sp.pts.size();
  q.min_det = *std::min_element(vals, vals + np);
  q.max_det = *std::max_element(vals, vals + np);
  q.aspect_ratio = aspect(sp.shape, X);
  if (!sp.bezier && sp.shape == Shape::Hex && q.min_det > 0) {
    hex_bezier_validity(sp.order, X, q);  // Bernstein arithmetic (proof), see above
  } else if (!sp.bezier && sp.shape == Shape::Hex) {
    q.valid = false;  // a sample with det J <= 0
  } else if (!sp.bezier) {
    q.sampled = true;
    q.valid = q.min_det > 0;
  } else if (q.min_det <= 0) {
    q.valid = false;
  } else if (*std::min_element(coef, coef + np) > kKappa * sp.amplification * href) {
    q.valid = true;
  } else {
    refine(sp, X, normal, q);
  }
  q.scaled_jacobian = q.max_det > 0 ? q.min_det / q.max_det : (q.min_det < 0 ? -1.0 : 0.0);
  if (q.max_det <= 0) q.scaled_jacobian = q.min_det < 0 ? -1.0 : 0.0;
}

// Evaluates `count` elements whose coordinates are in X (n x 3count, column 3e+r).
void evaluate_chunk(const JacobianSpace& sp, const Eigen::MatrixXd& X, int count, const double* normals,
                    const std::vector<const double*>& xyz, ElementQuality* out) {
  const int np = (int)sp.pts.size();
  Eigen::MatrixXd GX = sp.G * X;  // (3np) x (3count)
  Eigen::MatrixXd V(np, count);
  double H[64];
  for (int e = 0; e < count; ++e) {
    double h = 0;
    for (int p = 0; p < np; ++p) {
      double J[9];
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) J[3 * r + c] = GX(3 * p + c, 3 * e + r);
      V(p, e) = det_at(sp.dim, J, normals + 3 * e);
      h = std::max(h, hadamard(sp.dim, J));
    }
    H[e] = h;
  }
  Eigen::MatrixXd C(np, count);
  if (sp.T.size())
    C.noalias() = sp.T * V;
  else if (sp.bezier)
    for (int e = 0; e < count; ++e) sp.to_bezier(V.col(e).data(), C.col(e).data());
  for (int e = 0; e < count; ++e)
    classify(sp, xyz[e], normals + 3 * e, V.col(e).data(), sp.bezier ? C.col(e).data() : nullptr, H[e], out[e]);
}

}  // namespace

ElementQuality element_quality(Shape s, int order, const double* X, const double* normal) {
  ElementQuality q;
  const int d = dimension(s);
  if (d < 2) {
    q.aspect_ratio = d == 1 ? 1 : 1;
    return q;
  }
  const JacobianSpace& sp = space(s, order);
  const int n = num_nodes(s, order);
  double nrm[3] = {0, 0, 1};
  if (d == 2) {
    if (normal)
      std::copy(normal, normal + 3, nrm);
    else
      straight_normal(s, X, nrm);
  }
  Eigen::MatrixXd M(n, 3);
  for (int i = 0; i < n; ++i)
    for (int r = 0; r < 3; ++r) M(i, r) = X[3 * i + r];
  std::vector<const double*> xyz = {X};
  evaluate_chunk(sp, M, 1, nrm, xyz, &q);
  return q;
}

std::vector<std::vector<ElementQuality>> mesh_quality(const Mesh& m, int threads) {
  std::vector<std::vector<ElementQuality>> res(m.blocks.size());
  const int dim = m.dimension();
  if (dim < 2) return res;
  bool planar = true;
  if (dim == 2)
    for (size_t i = 1; i < m.num_nodes() && planar; ++i) planar = m.z[i] == m.z[0];
  auto run = [&] {
    for (size_t bi = 0; bi < m.blocks.size(); ++bi) {
      const auto& b = m.blocks[bi];
      if (dimension(b.shape) != dim) continue;
      res[bi].resize(b.size());
      const JacobianSpace& sp = space(b.shape, b.order);
      const int n = b.nodes_per_element();
      constexpr int kChunk = 32;
      const size_t nchunks = (b.size() + kChunk - 1) / kChunk;
      tbb::parallel_for(tbb::blocked_range<size_t>(0, nchunks), [&](const tbb::blocked_range<size_t>& r) {
        Eigen::MatrixXd X(n, 3 * kChunk);
        std::vector<double> coords(static_cast<size_t>(kChunk) * n * 3);
        std::vector<double> normals(3 * kChunk);
        std::vector<const double*> xyz(kChunk);
        for (size_t c = r.begin(); c != r.end(); ++c) {
          const size_t e0 = c * kChunk;
          const int cnt = (int)std::min<size_t>(kChunk, b.size() - e0);
          if (cnt < kChunk) X.setZero();
          for (int e = 0; e < cnt; ++e) {
            const std::uint32_t* nodes = b.element(e0 + e);
            double* P = coords.data() + static_cast<size_t>(e) * n * 3;
            for (int i = 0; i < n; ++i) {
              P[3 * i] = m.x[nodes[i]];
              P[3 * i + 1] = m.y[nodes[i]];
              P[3 * i + 2] = m.z[nodes[i]];
              for (int rr = 0; rr < 3; ++rr) X(i, 3 * e + rr) = P[3 * i + rr];
            }
            xyz[e] = P;
            if (dim == 2) {
              if (planar) {
                normals[3 * e] = 0, normals[3 * e + 1] = 0, normals[3 * e + 2] = 1;
              } else {
                straight_normal(b.shape, P, &normals[3 * e]);
              }
            }
          }
          evaluate_chunk(sp, X, cnt, normals.data(), xyz, res[bi].data() + e0);
        }
      });
    }
  };
  if (threads > 0) {
    tbb::task_arena arena(threads);
    arena.execute(run);
  } else {
    run();
  }
  return res;
}

nlohmann::json mesh_stats(const Mesh& m, int threads) {
  using nlohmann::json;
  json j;
  const int dim = m.dimension();
  j["order"] = m.order();
  j["nodes"] = m.num_nodes();
  json el = {{"tet", 0}, {"prism", 0}, {"hex", 0}, {"pyramid", 0}};
  json bd = json::object();
  std::map<std::string, std::size_t> by_type;
  std::map<std::string, std::size_t> groups;
  for (auto& b : m.blocks) {
    const int d = dimension(b.shape);
    std::string sn = shape_name(b.shape);
    if (d == dim) el[sn] = el.value(sn, 0) + b.size();
    if (d == dim - 1) bd[sn] = bd.value(sn, 0) + b.size();
    by_type[sn + std::to_string(b.order)] += b.size();
    const Entity* ent = m.find_entity(b.entity_dim, b.entity_tag);
    if (ent)
      for (int pt : ent->physicals) {
        std::string name;
        for (auto& p : m.physicals)
          if (p.dim == b.entity_dim && p.tag == pt) name = p.name;
        if (name.empty()) name = std::to_string(b.entity_dim) + ":" + std::to_string(pt);
        groups[name] += b.size();
      }
  }
  j["elements"] = el;
  j["boundary"] = bd;
  j["by_type"] = by_type;
  j["groups"] = groups;

  auto q = mesh_quality(m, threads);
  std::size_t invalid = 0, inconclusive = 0, sampled = 0, total = 0;
  std::vector<double> sj;
  double max_ar = 0, volume = 0;
  json invalid_tags = json::array();
  std::uint64_t running = 0;
  std::vector<double> sj_edges = {-1, 0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0000001};
  std::vector<double> ar_edges = {1, 2, 5, 10, 20, 50, 100, 200, 500, 1000, 1e300};
  std::vector<std::size_t> sj_counts(sj_edges.size() - 1), ar_counts(ar_edges.size() - 1);
  auto bin = [](const std::vector<double>& edges, double v) {
    for (size_t i = 0; i + 1 < edges.size(); ++i)
      if (v < edges[i + 1]) return i;
    return edges.size() - 2;
  };
  for (size_t bi = 0; bi < m.blocks.size(); ++bi) {
    const auto& b = m.blocks[bi];
    for (size_t e = 0; e < q[bi].size(); ++e) {
      const auto& eq = q[bi][e];
      ++total;
      if (!eq.valid) {
        ++invalid;
        if (invalid_tags.size() < 100) invalid_tags.push_back(b.tags.empty() ? running + e + 1 : b.tags[e]);
      }
      if (eq.inconclusive) ++inconclusive;
      if (eq.sampled) ++sampled;
      sj.push_back(eq.scaled_jacobian);
      max_ar = std::max(max_ar, eq.aspect_ratio);
      sj_counts[bin(sj_edges, eq.scaled_jacobian)]++;
      ar_counts[bin(ar_edges, eq.aspect_ratio)]++;
    }
    running += b.size();
  }
  (void)volume;
  j["invalid"] = invalid;
  j["invalid_elements"] = invalid_tags;
  j["inconclusive"] = inconclusive;
  j["nonconforming_faces"] = build_topology(m).nonconforming_faces;
  double mn = 1, med = 1;
  if (!sj.empty()) {
    mn = *std::min_element(sj.begin(), sj.end());
    std::vector<double> s = sj;
    std::nth_element(s.begin(), s.begin() + s.size() / 2, s.end());
    med = s[s.size() / 2];
  }
  j["min_scaled_jacobian"] = mn;
  j["median_scaled_jacobian"] = med;
  j["max_aspect_ratio"] = total ? max_ar : 1.0;
  std::size_t sampled_pyr = 0;
  for (size_t bi = 0; bi < m.blocks.size(); ++bi)
    if (m.blocks[bi].shape == Shape::Pyramid) sampled_pyr += q[bi].size();
  // proven (Bezier bounds): every shape but the pyramid; sampled: pyramids
  j["validity_method"] =
      sampled ? "bezier (proven) for " + std::to_string(total - sampled) + " elements; sampling (not proven) for " +
                    std::to_string(sampled) + " elements: " + std::to_string(sampled_pyr) + " pyramids (rational space)" +
                    (sampled > sampled_pyr ? ", " + std::to_string(sampled - sampled_pyr) + " others" : std::string())
              : std::string("bezier (proven for every element)");
  j["sampled"] = sampled;
  sj_edges.back() = 1.0;
  ar_edges.back() = 1e300;
  j["histograms"] = {{"scaled_jacobian", {{"edges", sj_edges}, {"counts", sj_counts}}},
                     {"aspect_ratio", {{"edges", std::vector<double>(ar_edges.begin(), ar_edges.end() - 1)},
                                       {"counts", ar_counts}}}};
  // bounding box and a geometric fingerprint (moments of the node coordinates)
  double bb[6] = {0, 0, 0, 0, 0, 0};
  double m1[3] = {0, 0, 0}, m2[6] = {0, 0, 0, 0, 0, 0};
  if (m.num_nodes()) {
    bb[0] = bb[3] = m.x[0];
    bb[1] = bb[4] = m.y[0];
    bb[2] = bb[5] = m.z[0];
  }
  for (size_t i = 0; i < m.num_nodes(); ++i) {
    const double p[3] = {m.x[i], m.y[i], m.z[i]};
    for (int r = 0; r < 3; ++r) {
      bb[r] = std::min(bb[r], p[r]);
      bb[3 + r] = std::max(bb[3 + r], p[r]);
      m1[r] += p[r];
    }
    m2[0] += p[0] * p[0], m2[1] += p[1] * p[1], m2[2] += p[2] * p[2];
    m2[3] += p[0] * p[1], m2[4] += p[1] * p[2], m2[5] += p[0] * p[2];
  }
  const double nn = m.num_nodes() ? double(m.num_nodes()) : 1.0;
  j["bbox"] = {bb[0], bb[1], bb[2], bb[3], bb[4], bb[5]};
  j["fingerprint"] = {{"centroid", {m1[0] / nn, m1[1] / nn, m1[2] / nn}},
                      {"second_moments", {m2[0] / nn, m2[1] / nn, m2[2] / nn, m2[3] / nn, m2[4] / nn, m2[5] / nn}}};
  return j;
}

}  // namespace meshflow::model
