#include "stages/model/quality.hpp"

#include "stages/model/basis.hpp"
#include "stages/model/topology.hpp"

#include <Eigen/Dense>
#include <nlohmann/json.hpp>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <cstring>
#include <atomic>
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

std::atomic<bool> g_tet_perturbation_proof{true};  // set_tet_perturbation_proof

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
// Chebyshev-Gauss-Lobatto abscissa q of degree d on [-1,1] (tensor directions: the 1D
// Bernstein interpolation there is ~100x better conditioned than on equispaced points)
double cheb_point(int q, int d) { return q == 0 ? -1.0 : q == d ? 1.0 : -std::cos(M_PI * q / d); }

// ---- Sum-factorised Jacobians of tensor shapes (quad, hex: Q_P; prism: P_P(tri) x P_P(line)) ----
// J at the (d+1)^dim (prism: triangle lattice x (d2+1)) sample points of a box (prism: triangle x
// interval) of the reference element, by one 1D (triangle) contraction per direction instead of a
// dense (3 npts) x nodes matrix: for a P=4 hex ~120k multiply-adds instead of 1.9M, for a P=4
// prism ~110k instead of 535k (the dense product was what made split boundary layers slow: 15k
// P=4 hexes cost ~10 s). Own code: the contraction order is fixed (no BLAS), so the results do not
// depend on batching or threads. The 1D and triangle basis tables come from the exact product
// formulas above (long double, rounded once).
struct TensorEval {
  Shape shape = Shape::Hex;
  int P = 0, p1 = 0, m[3] = {1, 1, 1};
  std::vector<double> L[3], D[3];  // per axis: m[ax] x p1, 1D Lagrange values / derivatives at the points
  std::vector<double> LT[3], DT[3];  // the same transposed (p1 x m[ax])
  int nt = 0, ns = 0;              // prism: triangle nodes, triangle sample points
  std::vector<double> N, Gx, Gy;   // prism: ns x nt triangle basis values / gradients
  std::vector<int> pos;            // Gmsh node -> position in the tensor layout
  double lambda[3] = {0, 0, 0};    // max over points of sum_i |dN_i/dxi_c| (rounding of J's column c)
  int npts() const { return shape == Shape::Prism ? ns * m[2] : m[0] * m[1] * m[2]; }
};

// max over rows of sum |A[row][k]| (A row-major with `cols` columns)
double abs_rowsum(const std::vector<double>& A, int cols) {
  double m = 0;
  for (std::size_t r = 0; r + cols <= A.size(); r += cols) {
    double s = 0;
    for (int k = 0; k < cols; ++k) s += std::abs(A[r + k]);
    m = std::max(m, s);
  }
  return m;
}

// The evaluator for the sample points of the domain `dom` (vertex list in the parent's reference
// coordinates: a box for quads/hexes, triangle x interval for prisms), degrees d1 (d2: prism axis).
TensorEval make_tensor_eval(Shape s, int P, int d1, int d2, const std::vector<Vec3>& dom) {
  TensorEval te;
  te.shape = s, te.P = P, te.p1 = P + 1;
  auto axis = [&](int ax, double lo, double hi, int d) {
    te.m[ax] = d + 1;
    te.L[ax].resize((d + 1) * te.p1), te.D[ax].resize((d + 1) * te.p1);
    for (int q = 0; q <= d; ++q) {
      const double c = cheb_point(q, d);
      const double t = lo == -1 && hi == 1 ? c : lo + (c + 1) / 2 * (hi - lo);
      for (int i = 0; i <= P; ++i) {
        LD Lv, dL;
        lagrange1(P, i, t, Lv, dL);
        te.L[ax][q * te.p1 + i] = (double)Lv, te.D[ax][q * te.p1 + i] = (double)dL;
      }
    }
    te.LT[ax].resize((d + 1) * te.p1), te.DT[ax].resize((d + 1) * te.p1);
    for (int q = 0; q <= d; ++q)
      for (int i = 0; i <= P; ++i)
        te.LT[ax][i * (d + 1) + q] = te.L[ax][q * te.p1 + i], te.DT[ax][i * (d + 1) + q] = te.D[ax][q * te.p1 + i];
  };
  const auto& lat = lattice(s, P);
  if (s == Shape::Quad || s == Shape::Hex) {
    const int dim = s == Shape::Hex ? 3 : 2;
    for (int ax = 0; ax < 3; ++ax) {
      if (ax >= dim) {  // quads: a dummy third axis of one point, value 1 (unused)
        te.m[ax] = 1;
        continue;
      }
      double lo = dom[0][ax], hi = dom[0][ax];
      for (auto& v : dom) lo = std::min(lo, v[ax]), hi = std::max(hi, v[ax]);
      axis(ax, lo, hi, d1);
    }
    for (auto& a : lat) te.pos.push_back(dim == 3 ? (a[0] * te.p1 + a[1]) * te.p1 + a[2] : a[0] * te.p1 + a[1]);
    double sl[3] = {1, 1, 1}, sd[3] = {1, 1, 1};
    for (int ax = 0; ax < dim; ++ax) sl[ax] = abs_rowsum(te.L[ax], te.p1), sd[ax] = abs_rowsum(te.D[ax], te.p1);
    te.lambda[0] = sd[0] * sl[1] * sl[2];
    te.lambda[1] = sl[0] * sd[1] * sl[2];
    te.lambda[2] = dim == 3 ? sl[0] * sl[1] * sd[2] : 0;
  } else {  // prism
    te.m[0] = te.m[1] = 1;
    axis(2, dom[0][2], dom[3][2], d2);
    std::vector<Lattice> tri;  // distinct triangle lattice points of the nodes, first-seen order
    for (auto& a : lat) {
      Lattice t{a[0], a[1], 0};
      int k = int(std::find(tri.begin(), tri.end(), t) - tri.begin());
      if (k == (int)tri.size()) tri.push_back(t);
      te.pos.push_back(k * te.p1 + a[2]);
    }
    te.nt = (int)tri.size();
    const std::vector<Vec3> tv = {dom[0], dom[1], dom[2]};
    for (int i = 0; i <= d1; ++i)
      for (int j = 0; i + j <= d1; ++j) {
        const Vec3 z = d1 ? Vec3{i / double(d1), j / double(d1), 0} : Vec3{1 / 3., 1 / 3., 0};
        const bool canonical = dom[0][0] == 0 && dom[0][1] == 0 && dom[1][0] == 1 && dom[1][1] == 0 && dom[2][0] == 0 &&
                               dom[2][1] == 1;
        const Vec3 x = canonical ? z : map_linear(Shape::Tri, tv, z);
        for (auto& a : tri) {
          LD R0, d0, R1, dd1, R2, dd2;
          silvester(P, P - a[0] - a[1], 1 - (LD)x[0] - (LD)x[1], R0, d0);
          silvester(P, a[0], x[0], R1, dd1);
          silvester(P, a[1], x[1], R2, dd2);
          te.N.push_back((double)(R0 * R1 * R2));
          te.Gx.push_back((double)(-d0 * R1 * R2 + R0 * dd1 * R2));
          te.Gy.push_back((double)(-d0 * R1 * R2 + R0 * R1 * dd2));
        }
        ++te.ns;
      }
    const double sl = abs_rowsum(te.L[2], te.p1), sd = abs_rowsum(te.D[2], te.p1);
    te.lambda[0] = abs_rowsum(te.Gx, te.nt) * sl;
    te.lambda[1] = abs_rowsum(te.Gy, te.nt) * sl;
    te.lambda[2] = abs_rowsum(te.N, te.nt) * sd;
  }
  return te;
}

// J at the sample points, planar: Jp[(3r+c)*np + p] = dx_r/dxi_c at point p (unused columns 0).
// Column c is computed from node differences along reference direction c (x - x at the start of
// the node line in that direction; on prisms the triangle columns from x - x at the triangle's
// first vertex), which the derivative annihilates exactly: so the rounding of column c is
// relative to the element's extent along c (Rc[3c+r] = largest |difference| of coordinate r), not
// to its largest size. A 1000:1 boundary-layer element keeps a thin column accurate to ~1e-14 of
// its own length. X: 3n node coordinates (Gmsh order).
// Compiled twice (target_clones), for AVX2 and for the baseline x86-64, the loader picking the
// one the CPU runs: the innermost loops (over a line's sample points) then take 4 doubles at a
// time instead of 2. Neither clone may contract a multiply and an add (AVX2 is not FMA) and each
// sum is still formed in the same order, so both give the same bits (Rotor 67's split and curve
// artifacts byte-identical); the stages whose contract computes the quality of every element got
// faster by as much (Rotor 67: split 28.1 -> 24.9 s, curve 24.1 -> 22.2 s).
__attribute__((target_clones("avx2", "default"))) void tensor_jacobians(const TensorEval& te, const double* X, double* Jp, double* Rc) {
  const int p1 = te.p1, np = te.npts();
  std::fill(Jp, Jp + 9 * np, 0.0);
  std::fill(Rc, Rc + 9, 0.0);
  thread_local std::vector<double> Xt, Xa, Xb, Xc, Y, Yd, Y2, Z0, Z1, Z2;
  const int nn = (int)te.pos.size();
  const int nslots = te.shape == Shape::Prism ? te.nt * p1 : te.shape == Shape::Hex ? p1 * p1 * p1 : p1 * p1;
  Xt.assign(nslots, 0.0), Xa.assign(nslots, 0.0), Xb.assign(nslots, 0.0), Xc.assign(nslots, 0.0);
  auto amax = [](const std::vector<double>& v) {
    double m = 0;
    for (double x : v) m = std::max(m, std::abs(x));
    return m;
  };
  for (int r = 0; r < 3; ++r) {
    for (int i = 0; i < nn; ++i) Xt[te.pos[i]] = X[3 * i + r];
    double* J0 = Jp + (3 * r + 0) * np;
    double* J1 = Jp + (3 * r + 1) * np;
    double* J2 = Jp + (3 * r + 2) * np;
    if (te.shape == Shape::Hex) {
      const int m0 = te.m[0], m1 = te.m[1], m2 = te.m[2];
      for (int i = 0; i < p1; ++i)
        for (int j = 0; j < p1; ++j)
          for (int k = 0; k < p1; ++k) {
            const int at = (i * p1 + j) * p1 + k;
            Xa[at] = Xt[at] - Xt[(0 * p1 + j) * p1 + k];
            Xb[at] = Xt[at] - Xt[(i * p1 + 0) * p1 + k];
            Xc[at] = Xt[at] - Xt[(i * p1 + j) * p1 + 0];
          }
      Rc[0 + r] = amax(Xa), Rc[3 + r] = amax(Xb), Rc[6 + r] = amax(Xc);
      // stage k: Y = L2 Xa, Y2 = L2 Xb, Yd = D2 Xc; layout (i p1 + j) m2 + c
      Y.assign(p1 * p1 * m2, 0.0), Y2.assign(p1 * p1 * m2, 0.0), Yd.assign(p1 * p1 * m2, 0.0);
      for (int ij = 0; ij < p1 * p1; ++ij)
        for (int k = 0; k < p1; ++k) {
          const double xa = Xa[ij * p1 + k], xb = Xb[ij * p1 + k], xc = Xc[ij * p1 + k];
          const double* l = &te.LT[2][k * m2];
          const double* d = &te.DT[2][k * m2];
          double* y = &Y[ij * m2];
          double* y2 = &Y2[ij * m2];
          double* yd = &Yd[ij * m2];
          for (int c = 0; c < m2; ++c) y[c] += l[c] * xa, y2[c] += l[c] * xb, yd[c] += d[c] * xc;
        }
      // stage j: Z0 = L1 Y, Z1 = D1 Y2, Z2 = L1 Yd, layout (i m1 + b) m2 + c
      Z0.assign(p1 * m1 * m2, 0.0), Z1.assign(p1 * m1 * m2, 0.0), Z2.assign(p1 * m1 * m2, 0.0);
      for (int i = 0; i < p1; ++i)
        for (int b = 0; b < m1; ++b)
          for (int j = 0; j < p1; ++j) {
            const double wl = te.L[1][b * p1 + j], wd = te.D[1][b * p1 + j];
            const double* y = &Y[(i * p1 + j) * m2];
            const double* y2 = &Y2[(i * p1 + j) * m2];
            const double* yd = &Yd[(i * p1 + j) * m2];
            double* z0 = &Z0[(i * m1 + b) * m2];
            double* z1 = &Z1[(i * m1 + b) * m2];
            double* z2 = &Z2[(i * m1 + b) * m2];
            for (int c = 0; c < m2; ++c) z0[c] += wl * y[c], z1[c] += wd * y2[c], z2[c] += wl * yd[c];
          }
      // stage i
      const int q = m1 * m2;
      for (int a = 0; a < m0; ++a)
        for (int i = 0; i < p1; ++i) {
          const double wl = te.L[0][a * p1 + i], wd = te.D[0][a * p1 + i];
          const double* z0 = &Z0[i * q];
          const double* z1 = &Z1[i * q];
          const double* z2 = &Z2[i * q];
          double* j0 = J0 + a * q;
          double* j1 = J1 + a * q;
          double* j2 = J2 + a * q;
          for (int t = 0; t < q; ++t) j0[t] += wd * z0[t], j1[t] += wl * z1[t], j2[t] += wl * z2[t];
        }
    } else if (te.shape == Shape::Quad) {
      const int m0 = te.m[0], m1 = te.m[1];
      for (int i = 0; i < p1; ++i)
        for (int j = 0; j < p1; ++j) Xa[i * p1 + j] = Xt[i * p1 + j] - Xt[j], Xb[i * p1 + j] = Xt[i * p1 + j] - Xt[i * p1];
      Rc[0 + r] = amax(Xa), Rc[3 + r] = amax(Xb);
      Y.assign(p1 * m1, 0.0), Yd.assign(p1 * m1, 0.0);
      for (int i = 0; i < p1; ++i)
        for (int j = 0; j < p1; ++j) {
          const double xa = Xa[i * p1 + j], xb = Xb[i * p1 + j];
          for (int b = 0; b < m1; ++b) Y[i * m1 + b] += te.LT[1][j * m1 + b] * xa, Yd[i * m1 + b] += te.DT[1][j * m1 + b] * xb;
        }
      for (int a = 0; a < m0; ++a)
        for (int i = 0; i < p1; ++i) {
          const double wl = te.L[0][a * p1 + i], wd = te.D[0][a * p1 + i];
          for (int b = 0; b < m1; ++b) J0[a * m1 + b] += wd * Y[i * m1 + b], J1[a * m1 + b] += wl * Yd[i * m1 + b];
        }
    } else {  // prism: triangle node 0 is the element's vertex 0
      const int m = te.m[2], nt = te.nt;
      for (int t = 0; t < nt; ++t)
        for (int k = 0; k < p1; ++k) Xa[t * p1 + k] = Xt[t * p1 + k] - Xt[k], Xc[t * p1 + k] = Xt[t * p1 + k] - Xt[t * p1];
      Rc[0 + r] = Rc[3 + r] = amax(Xa), Rc[6 + r] = amax(Xc);
      Y.assign(nt * m, 0.0), Yd.assign(nt * m, 0.0);
      for (int t = 0; t < nt; ++t)
        for (int k = 0; k < p1; ++k) {
          const double xa = Xa[t * p1 + k], xc = Xc[t * p1 + k];
          for (int c = 0; c < m; ++c) Y[t * m + c] += te.LT[2][k * m + c] * xa, Yd[t * m + c] += te.DT[2][k * m + c] * xc;
        }
      for (int s = 0; s < te.ns; ++s)
        for (int t = 0; t < nt; ++t) {
          const double gx = te.Gx[s * nt + t], gy = te.Gy[s * nt + t], n = te.N[s * nt + t];
          const double* y = &Y[t * m];
          const double* yd = &Yd[t * m];
          double* j0 = J0 + s * m;
          double* j1 = J1 + s * m;
          double* j2 = J2 + s * m;
          for (int c = 0; c < m; ++c) j0[c] += gx * y[c], j1[c] += gy * y[c], j2[c] += n * yd[c];
        }
    }
  }
}


// Bernstein basis of the det J space of one shape; `lat` = multi-indices (also the lattice
// points of the interpolation: point = index / degree).

struct JacobianSpace {
  Shape shape;
  int order, dim;
  int d1 = 0, d2 = 0;               // degrees (d2: tensor/prism axis)
  std::vector<Lattice> lat;
  std::vector<Vec3> pts;             // canonical sample points (reference coordinates)
  Eigen::MatrixXd G;                 // (3*npts) x nnodes: dN_i/dxi_c at point p in row 3p+c
  // Simplices of order >= 2: G = E Hs through the derivatives' own space (degree P-1, m nodes):
  // Hs (3m x nnodes, row c m + j) = dN_i/dxi_c at node j of the order P-1 lattice, E (npts x m)
  // = that lattice's Lagrange basis at the samples (both from product formulas in long double);
  // for a P=4 tet 46k instead of 69k multiply-adds per element.
  Eigen::MatrixXd Hs, E;
  bool factored = false;
  // Tets of order >= 2, the perturbation proof (see tet_perturbation_proof): Bm (m x m) = the
  // Lagrange -> Bernstein transform of degree P-1 on the tet (long double, rounded once), its
  // infinity norm, and lamH[c] = max_j sum_i |Hs(c m + j, i)|.
  Eigen::MatrixXd Bm;
  double normBm = 0, lamH[3] = {0, 0, 0};
  bool perturb = false;
  int jterms = 0;                    // rounded terms per J entry (the guard's n)
  Eigen::MatrixXd T;                 // lagrange values -> bezier coefficients (simplices)
  Eigen::MatrixXd Ta, Tb;            // factors: 1D (quad/hex: every axis) or triangle x line (prism)
  std::vector<double> TaR, TaT;      // Ta row-major and transposed (quad/hex)
  bool bezier = false;               // false: sampling only (pyramids, ill-conditioned degrees)
  double lambda[3] = {0, 0, 0};      // dense G: max over points of sum_i |G(3p+c, i)|
  int rterms = 0;                    // terms per coefficient in the values -> Bezier transform
  bool tensor = false;               // quad, hex, prism: J by sum factorisation (te), G unused
  TensorEval te;
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
    // quad/hex: Ta along every axis (sum factorisation), r ascending in every sum
    const int n1 = d1 + 1;
    thread_local std::vector<double> a, b;
    a.assign(v, v + np), b.resize(np);
    for (int ax = 0; ax < dim; ++ax) {  // axis ax has stride n1^(dim-1-ax)
      int st = 1;
      for (int k = ax + 1; k < dim; ++k) st *= n1;
      const int outer = np / (n1 * st);
      std::fill(b.begin(), b.end(), 0.0);
      for (int o = 0; o < outer; ++o)
        if (st == 1) {  // last axis: vectorise over q (TaT = Ta transposed)
          double* out = &b[o * n1];
          const double* in = &a[o * n1];
          for (int r = 0; r < n1; ++r) {
            const double x = in[r];
            const double* w = &TaT[r * n1];
            for (int q = 0; q < n1; ++q) out[q] += w[q] * x;
          }
        } else {
          for (int q = 0; q < n1; ++q) {
            double* out = &b[(o * n1 + q) * st];
            for (int r = 0; r < n1; ++r) {
              const double w = TaR[q * n1 + r];
              const double* in = &a[(o * n1 + r) * st];
              for (int t = 0; t < st; ++t) out[t] += w * in[t];
            }
          }
        }
      std::swap(a, b);
    }
    std::copy(a.begin(), a.end(), c);
  }
  std::vector<std::vector<Vec3>> children;  // canonical subdivision (vertex lists)
  double ref_volume = 1;

  static double cheb(int q, int d) { return cheb_point(q, d); }
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
    tensor = s == Shape::Quad || s == Shape::Hex || s == Shape::Prism;
    if (tensor) te = make_tensor_eval(s, p, d1, d2, reference_nodes(s, 1));
    G.resize(tensor ? 0 : 3 * np, n);
    std::vector<double> dN(3 * n);
    std::vector<LD> dNl(3 * n);
    for (int q = 0; q < (tensor ? 0 : np); ++q) {
      if (exact_grad_supported(s)) {
        exact_grad(s, p, pts[q], dNl.data());
        for (int k = 0; k < 3 * n; ++k) dN[k] = (double)dNl[k];
      } else {
        b.grad(pts[q], dN.data());
      }
      for (int c = 0; c < 3; ++c)
        for (int i = 0; i < n; ++i) G(3 * q + c, i) = dN[3 * i + c];
    }
    for (int q = 0; q < (tensor ? 0 : np); ++q)
      for (int c = 0; c < 3; ++c) {
        double a = 0;
        for (int i = 0; i < n; ++i) a += std::abs(G(3 * q + c, i));
        lambda[c] = std::max(lambda[c], a);
      }
    if (tensor) std::copy(te.lambda, te.lambda + 3, lambda);
    jterms = n;
    if ((s == Shape::Tri || s == Shape::Tet) && p >= 2) {
      const int dd = p - 1;
      const auto& dl = lattice(s, dd);
      const auto& dp = reference_nodes(s, dd);
      const int m = (int)dl.size();
      Hs.resize(3 * m, n);
      for (int j = 0; j < m; ++j) {
        exact_grad(s, p, dp[j], dNl.data());
        for (int c = 0; c < 3; ++c)
          for (int i = 0; i < n; ++i) Hs(c * m + j, i) = (double)dNl[3 * i + c];
      }
      E.resize(np, m);
      const bool tet = s == Shape::Tet;
      for (int q = 0; q < np; ++q) {
        const LD x = (LD)lat[q][0] / d1, y = (LD)lat[q][1] / d1, z = tet ? (LD)lat[q][2] / d1 : 0;
        for (int j = 0; j < m; ++j) {
          const Lattice& a = dl[j];
          LD R0, R1, R2, R3 = 1, dummy;
          silvester(dd, dd - a[0] - a[1] - (tet ? a[2] : 0), 1 - x - y - z, R0, dummy);
          silvester(dd, a[0], x, R1, dummy);
          silvester(dd, a[1], y, R2, dummy);
          if (tet) silvester(dd, a[2], z, R3, dummy);
          E(q, j) = (double)(R0 * R1 * R2 * R3);
        }
      }
      factored = true;
      if (tet) {  // the perturbation proof's tables
        using MatL = Eigen::Matrix<LD, Eigen::Dynamic, Eigen::Dynamic>;
        MatL M(m, m);
        std::vector<std::array<int, 3>> ex(m);  // Bernstein exponents of x, y, z (rounded lattice)
        for (int a = 0; a < m; ++a)
          for (int c = 0; c < 3; ++c) ex[a][c] = (int)std::lround(dp[a][c] * dd);
        for (int q = 0; q < m; ++q)
          for (int a = 0; a < m; ++a) {
            const LD x = (LD)dp[q][0], y = (LD)dp[q][1], z = (LD)dp[q][2];
            const int a0 = dd - ex[a][0] - ex[a][1] - ex[a][2];
            LD c = 1;
            for (int k = 1; k <= dd; ++k) c *= k;
            for (int e : {a0, ex[a][0], ex[a][1], ex[a][2]})
              for (int k = 2; k <= e; ++k) c /= k;
            M(q, a) = c * std::pow(1 - x - y - z, (LD)a0) * std::pow(x, (LD)ex[a][0]) * std::pow(y, (LD)ex[a][1]) *
                      std::pow(z, (LD)ex[a][2]);
          }
        Bm = MatL(M.fullPivLu().inverse()).cast<double>();
        normBm = Bm.cwiseAbs().rowwise().sum().maxCoeff();
        for (int c = 0; c < 3; ++c) lamH[c] = Hs.middleRows(c * m, m).cwiseAbs().rowwise().sum().maxCoeff();
        perturb = true;
      }
      jterms = n + m;
      for (int c = 0; c < 3; ++c) {  // abs sums of the two-stage computation
        lambda[c] = 0;
        for (int q = 0; q < np; ++q) {
          double a = 0;
          for (int j = 0; j < m; ++j) a += std::abs(E(q, j)) * Hs.block(c * m + j, 0, 1, n).cwiseAbs().sum();
          lambda[c] = std::max(lambda[c], a);
        }
      }
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
        for (int q = 0; q <= d1; ++q)
          for (int r = 0; r <= d1; ++r) TaR.push_back(Ta(q, r));
        for (int r = 0; r <= d1; ++r)
          for (int q = 0; q <= d1; ++q) TaT.push_back(Ta(q, r));
      }
      // Values -> Bernstein is ill-conditioned at high degree: the amplification is the
      // infinity norm of the transform (a product of the factors' norms on tensor shapes).
      // A coefficient is trusted positive only above the rounding bound of coefficient_guard
      // (amplification x the rounding of the samples, scaled per element and per direction);
      // where that bound would exceed 14% of det J's scale the transform cannot certify
      // anything useful: hexahedra of order >= 5, proven by Bernstein arithmetic instead
      // (hex_det_bezier), prisms of order >= 6 (sampled); pyramids by Bernstein arithmetic in collapsed
      // coordinates (pyramid_det_bezier): their det J is not a polynomial in (x, y, z).
      auto rowsum = [](const Eigen::MatrixXd& A) { return A.cwiseAbs().rowwise().sum().maxCoeff(); };
      amplification = T.size() ? rowsum(T)
                      : s == Shape::Prism ? rowsum(Ta) * rowsum(Tb)
                                          : std::pow(rowsum(Ta), dim);
      rterms = T.size() ? np : s == Shape::Prism ? (int)Ta.cols() + d2 + 1 : dim * (d1 + 1);
      // Feasible when the guard of coefficient_guard stays below 14% of det J's scale for an
      // element whose extents are ~2x its Jacobian columns (R_c ~ 2 N_c, any aspect ratio).
      constexpr double u = std::numeric_limits<double>::epsilon() / 2;
      const double lmax = std::max({lambda[0], lambda[1], lambda[2]});
      bezier = amplification * ((rterms + 34) * u + 1.01 * (jterms + 6) * u * lmax * 2) < 0.14;
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

// det J (jacobian_determinant's formulas, same rounding) and the largest squared Hadamard bound
// at np points from planar J: Jp[(3r+c)*np + p]. Loops over points vectorise.
void planar_det(int dim, const double* Jp, int np, const double* normal, double* V, double& h2max, double cmax2[3]) {
  auto J = [&](int k) { return Jp + k * np; };
  const double *j0 = J(0), *j1 = J(1), *j2 = J(2), *j3 = J(3), *j4 = J(4), *j5 = J(5), *j6 = J(6), *j7 = J(7), *j8 = J(8);
  double hm = 0, c0 = 0, c1 = 0, c2 = 0;
  if (dim == 3) {
    for (int p = 0; p < np; ++p) {
      V[p] = j0[p] * (j4[p] * j8[p] - j5[p] * j7[p]) - j1[p] * (j3[p] * j8[p] - j5[p] * j6[p]) +
             j2[p] * (j3[p] * j7[p] - j4[p] * j6[p]);
      const double a = j0[p] * j0[p] + j3[p] * j3[p] + j6[p] * j6[p], b = j1[p] * j1[p] + j4[p] * j4[p] + j7[p] * j7[p],
                   c = j2[p] * j2[p] + j5[p] * j5[p] + j8[p] * j8[p], h = a * b * c;
      hm = h > hm ? h : hm;
      c0 = a > c0 ? a : c0, c1 = b > c1 ? b : c1, c2 = c > c2 ? c : c2;
    }
  } else {
    const double n0 = normal[0], n1 = normal[1], n2 = normal[2];
    for (int p = 0; p < np; ++p) {
      const double cx = j3[p] * j7[p] - j6[p] * j4[p], cy = j6[p] * j1[p] - j0[p] * j7[p], cz = j0[p] * j4[p] - j3[p] * j1[p];
      V[p] = cx * n0 + cy * n1 + cz * n2;
      const double a = j0[p] * j0[p] + j3[p] * j3[p] + j6[p] * j6[p], b = j1[p] * j1[p] + j4[p] * j4[p] + j7[p] * j7[p],
                   h = a * b;
      hm = h > hm ? h : hm;
      c0 = a > c0 ? a : c0, c1 = b > c1 ? b : c1;
    }
  }
  h2max = std::max(h2max, hm);
  cmax2[0] = std::max(cmax2[0], c0), cmax2[1] = std::max(cmax2[1], c1), cmax2[2] = std::max(cmax2[2], c2);
}

// Rounding bound of the Bezier coefficients of det J on one (sub-)domain, scaled per element:
//   amplification * ( (rterms + 2) u max|v|      the values -> Bezier transform (and its entries)
//                   + 32 u href                    det J's formula (<= 5 roundings of a sum bounded by
//                                                  the permanent of |J| <= 3^1.5 x Hadamard bound href)
//                   + prod_c (N_c + e_c) - prod_c N_c )   J's own rounding
// with N_c the largest length of J's column c over the samples and e_c = (n + 6) u lambda_c R_c
// the rounding of column c (sums of <= n + 4 rounded products of node differences bounded by
// R_c, with basis derivative weights whose absolute sum is <= lambda_c; u = eps/2). On tensor
// shapes R_c is the element's extent along reference direction c (see tensor_jacobians), on
// simplices the largest offset from node 0. The guard used before (128 eps x Hadamard bound)
// assumed column roundings relative to their own lengths: false for thin elements, whose thin
// column is a difference of coordinates of the element's long size unless computed from
// differences along that direction.
double coefficient_guard(const JacobianSpace& sp, int nnodes, double vmax, double h2max, const double cmax2[3],
                         const double lambda[3], const double Rc[9]) {
  constexpr double u = std::numeric_limits<double>::epsilon() / 2;  // unit roundoff
  double with = 1, without = 1;
  for (int c = 0; c < sp.dim; ++c) {
    const double R = std::sqrt(Rc[3 * c] * Rc[3 * c] + Rc[3 * c + 1] * Rc[3 * c + 1] + Rc[3 * c + 2] * Rc[3 * c + 2]);
    const double N = std::sqrt(cmax2[c]) * (1 + 4 * u), e = 1.01 * (nnodes + 6) * u * lambda[c] * R;
    with *= N + e, without *= N;
  }
  const double g = 1.01 * (sp.rterms + 2) * u * vmax + 32 * u * std::sqrt(h2max) + (with - without) * (1 + 8 * u);
  return sp.amplification * g * (1 + 8 * u);
}
// Offsets of the nodes from node 0 (the rounding scale of a dense J: every column gets it).
void dense_offsets(int nnodes, const double* X, double Rc[9]) {
  for (int r = 0; r < 3; ++r) {
    double m = 0;
    for (int i = 0; i < nnodes; ++i) m = std::max(m, std::abs(X[3 * i + r] - X[r]));
    Rc[r] = Rc[3 + r] = Rc[6 + r] = m * (1 + 1e-15);
  }
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

// Subdivision limits of the Bezier proof. The subdomain budget bounds the cost of one element
// (each subdomain is one det J interpolation or de Casteljau split); the depth only limits
// refinement towards a point, where det J is small but positive: a near-degenerate corner (the
// junction hexes where a sharp trailing edge meets a casing, scaled Jacobian 0.004) is decided
// along one path of 8 subdomains per level, at depth 7 to 12 (at 6 they stayed undecided).
constexpr int kMaxSubdivisionDepth = 12, kMaxSubdomains = 600;

// Slow path: subdivide the reference domain until the Bezier bounds decide.
void refine(const JacobianSpace& sp, const double* X, const double* normal, ElementQuality& q) {
  const LagrangeBasis& b = LagrangeBasis::get(sp.shape, sp.order);
  const int np = (int)sp.pts.size(), n = b.size();
  std::vector<double> dN(3 * n);
  std::vector<LD> dNl(3 * n);
  const bool exact = exact_grad_supported(sp.shape);
  std::deque<std::pair<std::vector<Vec3>, int>> todo;
  for (auto& c : sp.children) todo.push_back({c, 1});
  int visited = 0;
  Eigen::VectorXd v(np);
  std::vector<double> Jp;
  while (!todo.empty()) {
    auto [dom, depth] = std::move(todo.front());
    todo.pop_front();
    double lam[3] = {0, 0, 0}, Rc[9];
    if (++visited > kMaxSubdomains) {
      q.inconclusive = true;
      return;
    }
    Jp.resize(9 * np);
    if (sp.tensor) {  // sum factorisation on the sub-domain (a box, or triangle x interval)
      const TensorEval te = make_tensor_eval(sp.shape, sp.order, sp.d1, sp.d2, dom);
      tensor_jacobians(te, X, Jp.data(), Rc);
      std::copy(te.lambda, te.lambda + 3, lam);
    } else {
      dense_offsets(n, X, Rc);
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
            for (int c = 0; c < 3; ++c) J[3 * r + c] += (X[3 * i + r] - X[r]) * dN[3 * i + c];
        for (int k = 0; k < 9; ++k) Jp[k * np + p] = J[k];
        for (int c = 0; c < 3; ++c) {
          double a = 0;
          for (int i = 0; i < n; ++i) a += std::abs(dN[3 * i + c]);
          lam[c] = std::max(lam[c], a);
        }
      }
    }
    double h2 = 0, cm[3] = {0, 0, 0};
    planar_det(sp.dim, Jp.data(), np, normal, v.data(), h2, cm);
    const double guard = coefficient_guard(sp, n, v.cwiseAbs().maxCoeff(), h2, cm, lam, Rc);
    q.min_det = std::min(q.min_det, v.minCoeff());
    q.max_det = std::max(q.max_det, v.maxCoeff());
    if (v.minCoeff() <= 0) {
      q.valid = false;
      return;
    }
    Eigen::VectorXd c(np);
    sp.to_bezier(v.data(), c.data());
    if (c.minCoeff() > guard) continue;
    if (depth >= kMaxSubdivisionDepth) {
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
// det J's Bernstein coefficients (and a bound of their rounding) from the scaled Bernstein
// coefficients D[r][c] of dx_r/dxi_c and their bounds DE = |D| + rounding (hexes, pyramids);
// every D[.][c] has the same degrees for a given c, each degree <= P.
void det_from_columns(int P, const Tensor D[3][3], const Tensor DE[3][3], Tensor& det, double& err) {
  constexpr double u = std::numeric_limits<double>::epsilon() / 2;
  // det = x_xi (y_eta z_zeta - y_zeta z_eta) + x_eta (y_zeta z_xi - y_xi z_zeta) + x_zeta (y_xi z_eta - y_eta z_xi)
  det = Tensor(D[0][0].n[0] + D[1][1].n[0] + D[2][2].n[0], D[0][0].n[1] + D[1][1].n[1] + D[2][2].n[1],
               D[0][0].n[2] + D[1][1].n[2] + D[2][2].n[2]);
  Tensor bound = det, bounde = det;
  const int perm[3][3] = {{0, 1, 2}, {1, 2, 0}, {2, 0, 1}};  // (c0 ; c1, c2) of each term
  for (auto& pc : perm) {
    const int c0 = pc[0], c1 = pc[1], c2 = pc[2];
    Tensor cof = convolve(D[1][c1], D[2][c2]);
    axpy(cof, -1, convolve(D[1][c2], D[2][c1]));
    Tensor cofa = convolve(absval(D[1][c1]), absval(D[2][c2]));
    axpy(cofa, 1, convolve(absval(D[1][c2]), absval(D[2][c1])));
    Tensor cofe = convolve(DE[1][c1], DE[2][c2]);
    axpy(cofe, 1, convolve(DE[1][c2], DE[2][c1]));
    axpy(det, 1, convolve(D[0][c0], cof));
    axpy(bound, 1, convolve(absval(D[0][c0]), cofa));
    axpy(bounde, 1, convolve(DE[0][c0], cofe));
  }
  scale_binomial(det, true);
  scale_binomial(bound, true);
  scale_binomial(bounde, true);
  double bmax = 0, emax = 0;
  for (std::size_t i = 0; i < bound.c.size(); ++i)
    bmax = std::max(bmax, bounde.c[i]), emax = std::max(emax, bounde.c[i] - bound.c[i]);
  // Rounding of the products and sums (each det coefficient: <= 6 (P+1)^6 rounded terms in
  // <= 2 (P+1)^3 + 8 sequential operations, binomial scalings; `bound` is the same computation on
  // absolute values, `bounde` on |D| + its rounding bound) plus the propagated rounding of the
  // derivative coefficients: products of scaled coefficients have positive weights, so a
  // coefficient of det moves by at most bounde - bound (multilinearity); de Casteljau splits
  // (<= 3 x 6 levels of 3P-1 averaging steps) add their own rounding.
  const double K = 2.0 * std::pow(P + 1, 3) + 16 + 18.0 * (3 * P - 1);
  err = (1.01 * K * u * bmax + emax) * (1 + 8 * u);
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
  // Control points of node differences along each direction c (x - x at the start of the node
  // line along c: d/dxi_c annihilates it exactly), so the rounding of column c of J is relative
  // to the element's extent along c (thin boundary-layer hexes), not to its largest size or its
  // distance from the origin.
  const auto& lat = lattice(Shape::Hex, P);
  double l2b_norm = 0;  // infinity norm of the 1D transform
  for (int a = 0; a <= P; ++a) {
    double sa = 0;
    for (int q = 0; q <= P; ++q) sa += std::abs(L2B[a * (P + 1) + q]);
    l2b_norm = std::max(l2b_norm, sa);
  }
  constexpr double u = std::numeric_limits<double>::epsilon() / 2;
  Tensor D[3][3], DE[3][3];  // D[r][c] = d x_r / d xi_c; DE: |D| + its rounding bound
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) {
      Tensor V(P, P, P);
      for (std::size_t i = 0; i < lat.size(); ++i) V.at(lat[i][0], lat[i][1], lat[i][2]) = X[3 * i + r];
      Tensor Vd(P, P, P);
      double R = 0;
      for (int i = 0; i <= P; ++i)
        for (int j = 0; j <= P; ++j)
          for (int k = 0; k <= P; ++k) {
            Vd.at(i, j, k) = V.at(i, j, k) - V.at(c == 0 ? 0 : i, c == 1 ? 0 : j, c == 2 ? 0 : k);
            R = std::max(R, std::abs(Vd.at(i, j, k)));
          }
      Tensor Va = absval(Vd);
      for (int ax = 0; ax < 3; ++ax) {  // apply L2B along each axis (and |L2B| to |Vd|: rounding bound)
        Tensor W(P, P, P), Wa(P, P, P);
        for (int i = 0; i <= P; ++i)
          for (int j = 0; j <= P; ++j)
            for (int k = 0; k <= P; ++k) {
              double sum = 0, suma = 0;
              for (int q = 0; q <= P; ++q) {
                const int a[3] = {ax == 0 ? q : i, ax == 1 ? q : j, ax == 2 ? q : k};
                const double w = L2B[(ax == 0 ? i : ax == 1 ? j : k) * (P + 1) + q];
                sum += w * Vd.at(a[0], a[1], a[2]);
                suma += std::abs(w) * Va.at(a[0], a[1], a[2]);
              }
              W.at(i, j, k) = sum, Wa.at(i, j, k) = suma;
            }
        Vd = W, Va = Wa;
      }
      // control point rounding <= gamma_{3(P+2)+3} (|L2B| x |differences|) (the transform's
      // entries rounded once from long double included); a derivative coefficient is P/2 times
      // a difference of two
      const double g = 1.01 * (3 * (P + 2) + 3) * u;
      Tensor T(c == 0 ? P - 1 : P, c == 1 ? P - 1 : P, c == 2 ? P - 1 : P), TE = T;
      for (int i = 0; i <= T.n[0]; ++i)
        for (int j = 0; j <= T.n[1]; ++j)
          for (int k = 0; k <= T.n[2]; ++k) {
            const int i1 = i + (c == 0), j1 = j + (c == 1), k1 = k + (c == 2);
            T.at(i, j, k) = 0.5 * P * (Vd.at(i1, j1, k1) - Vd.at(i, j, k));
            const double e = 0.5 * P * g * (Va.at(i1, j1, k1) + Va.at(i, j, k)) * (1 + 4 * u) + 2 * u * std::abs(T.at(i, j, k));
            TE.at(i, j, k) = std::abs(T.at(i, j, k)) + e;
          }
      scale_binomial(T, false);
      scale_binomial(TE, false);
      D[r][c] = T;
      DE[r][c] = TE;
    }
  det_from_columns(P, D, DE, det, err);
}
// Decides det > 0 on the box from its tensor Bernstein coefficients `det` (rounding bound err),
// subdividing (de Casteljau) within the limits above (hexes, pyramids in collapsed coordinates).
void tensor_bezier_validity(Tensor det, double err, ElementQuality& q) {
  std::deque<std::pair<Tensor, int>> todo;
  todo.push_back({std::move(det), 0});
  int visited = 0;
  while (!todo.empty()) {
    auto [T, depth] = std::move(todo.front());
    todo.pop_front();
    if (++visited > kMaxSubdomains) {
      q.inconclusive = true;
      return;
    }
    // corner coefficients are values of det J: one <= 0 (beyond rounding) proves invalidity
    for (int i : {0, T.n[0]})
      for (int j : {0, T.n[1]})
        for (int k : {0, T.n[2]})
          if (T.at(i, j, k) < -err) {
            q.valid = false;
            return;
          }
    const double mn = *std::min_element(T.c.begin(), T.c.end());
    if (mn > err) continue;
    if (depth >= kMaxSubdivisionDepth) {
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

// ---- Pyramids: det J in Bernstein form in collapsed coordinates ----
// The pyramid (base [-1,1]^2 at z = 0, apex (0,0,1)) is the image of the cube (a, b, c) in
// [-1,1]^2 x [0,1] under the collapse x = (1-c) a, y = (1-c) b, z = c. Bergot's space (basis.hpp)
// spanned by x'^i y'^j (1-z)^max(i,j) z^k, x' = x/(1-z) = a, becomes a^i b^j (1-c)^max(i,j) c^k:
// polynomials of degree <= P in each of a, b, c. So the mapping composed with the collapse, Q(a,b,c),
// has tensor Bernstein control points C = T X (T: nodes -> control points, fixed per order). With
// Q_a = (1-c) x_x, Q_b = (1-c) x_y and Q_c = x_z - a x_x - b x_y (chain rule),
//   det J(x, y, z) = det[Q_a / (1-c), Q_b / (1-c), Q_c],
// where Q_a and Q_b are divisible by (1-c) exactly (every term with i >= 1 or j >= 1 carries it;
// their top control layer c = 1 is the apex, constant in a and b): dividing a degree-n Bernstein
// polynomial by (1-c) is g_r = n f_r / (n - r), exact up to one rounding. det J is then a
// polynomial of degrees (3P-1, 3P-1, 3P-3) on the cube, its Bernstein coefficients formed by
// Bernstein arithmetic as for hexes (det_from_columns) and decided by the same subdivision. The
// whole closed pyramid is covered (the face c = 1 holds the limits of det J at the apex, which
// depend on the direction: Bergot's space is rational there). This is the proof Gmsh's pyramids
// lacked in our earlier sampling.
struct PyramidControl {
  std::vector<double> T;  // ((P+1)^3) x nodes, row (i*(P+1)+j)*(P+1)+k, row-major
  std::vector<double> Tabs_rowsum;  // sum_n |T(row, n)| (rounding of applying T)
  double rho = 0;         // bound of T's own error, relative to max |X_n - X_0| (see below)
  int apex = -1;
};

const PyramidControl& pyramid_control(int P) {
  static std::mutex mu;
  static std::unique_ptr<PyramidControl> cache[kMaxOrder + 1];
  std::lock_guard<std::mutex> lock(mu);
  auto& slot = cache[P];
  if (slot) return *slot;
  auto pc = std::make_unique<PyramidControl>();
  using MatL = Eigen::Matrix<LD, Eigen::Dynamic, Eigen::Dynamic>;
  const auto& lat = lattice(Shape::Pyramid, P);
  const int n = (int)lat.size(), m1 = P + 1, nc = m1 * m1 * m1;
  // the space's exponents (i, j, k): k + max(i, j) <= P, as in basis.cpp
  std::vector<std::array<int, 3>> ex;
  for (int i = 0; i <= P; ++i)
    for (int j = 0; j <= P; ++j)
      for (int k = 0; k + std::max(i, j) <= P; ++k) ex.push_back({i, j, k});
  // nodes in collapsed coordinates, exactly from their lattice indices (l2 = layer from the apex)
  std::vector<std::array<LD, 3>> abc(n);
  for (int q = 0; q < n; ++q) {
    const auto& l = lat[q];
    if (l[2] == 0) pc->apex = q;
    abc[q] = {l[2] ? -1 + 2 * (LD)l[0] / l[2] : 0, l[2] ? -1 + 2 * (LD)l[1] / l[2] : 0, 1 - (LD)l[2] / P};
  }
  auto phi = [&](const std::array<int, 3>& e, const std::array<LD, 3>& x) {
    const int mx = std::max(e[0], e[1]);
    return std::pow(x[0], (LD)e[0]) * std::pow(x[1], (LD)e[1]) * std::pow(1 - x[2], (LD)mx) * std::pow(x[2], (LD)e[2]);
  };
  MatL V(n, (int)ex.size());
  for (int q = 0; q < n; ++q)
    for (int e = 0; e < (int)ex.size(); ++e) V(q, e) = q == pc->apex ? (std::max(ex[e][0], ex[e][1]) == 0 ? 1 : 0) : phi(ex[e], abc[q]);
  MatL Vi = V.fullPivLu().inverse();  // N_q = sum_e phi_e Vi(e, q)
  // degree-P Bernstein coefficients of a^i on [-1,1] (s = (a+1)/2: a^i = sum_l C(i,l) 2^l s^l (-1)^(i-l);
  // s^l = sum_{r >= l} C(r,l)/C(P,l) B_r) and of (1-c)^mx c^k on [0,1] (C(P-mx-k, r-k) / C(P, r))
  auto bin = [](int a, int b) -> LD { return b < 0 || b > a ? 0 : (LD)binom(a, b); };
  auto mono_a = [&](int i, int r) {
    LD s = 0;
    for (int l = 0; l <= std::min(i, r); ++l) s += bin(i, l) * std::pow((LD)2, (LD)l) * ((i - l) % 2 ? -1 : 1) * bin(r, l) / bin(P, l);
    return s;
  };
  auto mono_c = [&](int mx, int k, int r) { return r < k || r > P - mx ? (LD)0 : bin(P - mx - k, r - k) / bin(P, r); };
  MatL Tl = MatL::Zero(nc, n);
  for (int e = 0; e < (int)ex.size(); ++e) {
    const int mx = std::max(ex[e][0], ex[e][1]);
    for (int i = 0; i <= P; ++i) {
      const LD fa = mono_a(ex[e][0], i);
      if (fa == 0) continue;
      for (int j = 0; j <= P; ++j) {
        const LD fb = mono_a(ex[e][1], j);
        if (fb == 0) continue;
        for (int k = 0; k <= P; ++k) {
          const LD fc = mono_c(mx, ex[e][2], k);
          if (fc == 0) continue;
          Tl.row((i * m1 + j) * m1 + k) += fa * fb * fc * Vi.row(e);
        }
      }
    }
  }
  // the top layer c = 1 is the apex value, exactly
  for (int i = 0; i <= P; ++i)
    for (int j = 0; j <= P; ++j)
      for (int q = 0; q < n; ++q) Tl((i * m1 + j) * m1 + P, q) = q == pc->apex ? 1 : 0;
  // T's own error (long double inverse of the Vandermonde matrix): the computed polynomials
  // interpolate the nodes up to residuals R = (values at the nodes) - I; as the error lies in the
  // space, it is T R, so a control point of T X is off by at most ||T R|| max |X_q - X_0| (the
  // constant is reproduced: sum_q T(row, q) = 1, so differences from X_0 can be used).
  auto bern = [&](int d, int r, LD t) { return bin(d, r) * std::pow(t, (LD)r) * std::pow(1 - t, (LD)(d - r)); };
  MatL B(n, nc);  // the tensor Bernstein basis at the nodes
  for (int q = 0; q < n; ++q) {
    const LD s = q == pc->apex ? 0.5 : (abc[q][0] + 1) / 2, t = q == pc->apex ? 0.5 : (abc[q][1] + 1) / 2, w = abc[q][2];
    for (int i = 0; i <= P; ++i)
      for (int j = 0; j <= P; ++j)
        for (int k = 0; k <= P; ++k) B(q, (i * m1 + j) * m1 + k) = bern(P, i, s) * bern(P, j, t) * bern(P, k, w);
  }
  MatL R = B * Tl - MatL::Identity(n, n);
  MatL TR = Tl * R;
  LD rho = 0;
  for (int row = 0; row < nc; ++row) rho = std::max(rho, TR.row(row).cwiseAbs().sum());
  // (plus the rounding of R's and T R's own long double sums: <= (nc + n) eps_ld ||T||_inf each)
  LD normT = 0;
  for (int row = 0; row < nc; ++row) normT = std::max(normT, Tl.row(row).cwiseAbs().sum());
  pc->rho = (double)(1.01L * rho + 4 * (nc + n) * std::numeric_limits<LD>::epsilon() * normT * (1 + normT));
  pc->T.resize(std::size_t(nc) * n);
  pc->Tabs_rowsum.assign(nc, 0);
  for (int row = 0; row < nc; ++row)
    for (int q = 0; q < n; ++q) {
      pc->T[std::size_t(row) * n + q] = (double)Tl(row, q);
      pc->Tabs_rowsum[row] += std::abs((double)Tl(row, q));
    }
  slot = std::move(pc);
  return *slot;
}

// Bernstein coefficients of det J (and a bound of their rounding) of a pyramid of order P, on the
// cube of collapsed coordinates (s, t, c) = ((a+1)/2, (b+1)/2, c) in [0,1]^3.
void pyramid_det_bezier(int P, const double* X, Tensor& det, double& err) {
  const PyramidControl& pc = pyramid_control(P);
  const int n = num_nodes(Shape::Pyramid, P), m1 = P + 1;
  constexpr double u = std::numeric_limits<double>::epsilon() / 2;
  Tensor D[3][3], DE[3][3];
  for (int r = 0; r < 3; ++r) {
    // control points of x_r - x_r(node 0) and a bound of their error
    std::vector<double> Xd(n);
    double xmax = 0;
    for (int q = 0; q < n; ++q) Xd[q] = X[3 * q + r] - X[r], xmax = std::max(xmax, std::abs(Xd[q]));
    Tensor C(P, P, P), CE(P, P, P);
    for (int row = 0; row < m1 * m1 * m1; ++row) {
      const double* t = &pc.T[std::size_t(row) * n];
      double sum = 0, suma = 0;
      for (int q = 0; q < n; ++q) sum += t[q] * Xd[q], suma += std::abs(t[q] * Xd[q]);
      C.c[row] = sum;
      // rounding of the differences (one each) and of the sum of n products, plus T's own error
      CE.c[row] = 1.01 * (n + 2) * u * (suma + pc.Tabs_rowsum[row] * xmax) + pc.rho * xmax;
    }
    for (int c = 0; c < 3; ++c) {
      // derivative along axis c (d/da = P/2 differences on [-1,1]; d/dc = P differences on [0,1]),
      // then for c = 0, 1 division by (1 - c): degree P-1 in the collapsed axis, P-1 along the axis
      Tensor T(c == 0 ? P - 1 : P, c == 1 ? P - 1 : P, P - 1), TE = T;
      const double f = c < 2 ? 0.5 * P : (double)P;
      for (int i = 0; i <= T.n[0]; ++i)
        for (int j = 0; j <= T.n[1]; ++j)
          for (int k = 0; k <= T.n[2]; ++k) {
            const int i1 = i + (c == 0), j1 = j + (c == 1), k1 = k + (c == 2);
            double v = f * (C.at(i1, j1, k1) - C.at(i, j, k));
            double e = f * (CE.at(i1, j1, k1) + CE.at(i, j, k)) * (1 + 4 * u) + 2 * u * std::abs(v);
            if (c < 2) {  // g_k = P f_k / (P - k); the dropped top layer f_P is 0 exactly (the apex)
              const double w = double(P) / (P - k);
              v *= w;
              e = e * w * (1 + 2 * u) + u * std::abs(v);
            }
            T.at(i, j, k) = v;
            TE.at(i, j, k) = std::abs(v) + e;
          }
      scale_binomial(T, false);
      scale_binomial(TE, false);
      D[r][c] = std::move(T);
      DE[r][c] = std::move(TE);
    }
  }
  det_from_columns(P, D, DE, det, err);
}

// ---- Tets: the perturbation proof (the fast path of the validity check) ----
// J(xi) of an order-P tet is a matrix of polynomials of degree P-1; their Bernstein
// coefficients B_a (m per entry) come from J at the nodes of the order P-1 lattice (Hs X, which
// the sampling computes anyway) by one small transform Bm (9 m^2 multiply-adds: 3.6k for P=4).
// Let K be (the computed inverse of) the mean of the coefficients, M(xi) = K J(xi) - I. If
// det K > 0 and ||M(xi)|| < 1 for every xi, every eigenvalue of K J(xi) = I + M(xi) lies in the
// disc |lambda - 1| < 1, so det(K J(xi)) > 0 and det J(xi) = det(K J(xi)) / det K > 0 on the
// whole closed element: a proof of validity. ||M(xi)|| is bounded by the infinity (row sum) and
// the one (column sum) norms of the entrywise bounds max_a |M_a| (Bernstein polynomials are a
// non-negative partition of unity), each coefficient enlarged by its rounding bound. Elements
// proven this way skip the values -> Bezier transform of det J (T V: 48k multiply-adds per P=4
// tet) and its subdivision; the others (strongly curved or invalid) take the Bezier path
// unchanged. The test is sufficient, never necessary, so it cannot call an invalid element valid.
bool tet_perturbation_proof(const JacobianSpace& sp, const Eigen::MatrixXd& HX, int e, const double Rc[9]) {
  constexpr double u = std::numeric_limits<double>::epsilon() / 2;
  const int m = (int)sp.Bm.rows(), n = (int)sp.Hs.cols();
  thread_local std::vector<double> B;
  B.resize(9 * static_cast<std::size_t>(m));
  double A[9];
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) {
      const double* v = HX.col(3 * e + r).data() + c * m;
      double* b = &B[(3 * r + c) * m];
      double sum = 0;
      for (int a = 0; a < m; ++a) {
        double t = 0;
        for (int j = 0; j < m; ++j) t += sp.Bm(a, j) * v[j];
        b[a] = t;
        sum += t;
      }
      A[3 * r + c] = sum / m;
    }
  const double c0 = A[4] * A[8] - A[5] * A[7], c1 = A[5] * A[6] - A[3] * A[8], c2 = A[3] * A[7] - A[4] * A[6];
  const double detA = A[0] * c0 + A[1] * c1 + A[2] * c2;
  if (!(detA > 0) || !std::isfinite(detA)) return false;
  const double K[9] = {c0 / detA, (A[2] * A[7] - A[1] * A[8]) / detA, (A[1] * A[5] - A[2] * A[4]) / detA,
                       c1 / detA, (A[0] * A[8] - A[2] * A[6]) / detA, (A[2] * A[3] - A[0] * A[5]) / detA,
                       c2 / detA, (A[1] * A[6] - A[0] * A[7]) / detA, (A[0] * A[4] - A[1] * A[3]) / detA};
  // det K > 0 beyond its rounding (6 triple products, 5 sums: < 8u of the sum of their moduli)
  const double t[6] = {K[0] * K[4] * K[8], -K[0] * K[5] * K[7], -K[1] * K[3] * K[8],
                       K[1] * K[5] * K[6],  K[2] * K[3] * K[7], -K[2] * K[4] * K[6]};
  double detK = 0, detKabs = 0;
  for (double x : t) detK += x, detKabs += std::abs(x);
  if (!(detK > 1.01 * 8 * u * detKabs)) return false;
  // rounding of B(s, c, a) (Hs X: n products of node offsets bounded by R_s, then Bm: m terms;
  // the tables' entries rounded once from long double; the offsets rounded once)
  double errB[9];
  for (int s = 0; s < 3; ++s)
    for (int c = 0; c < 3; ++c) errB[3 * s + c] = 1.01 * (n + m + 6) * u * sp.normBm * sp.lamH[c] * Rc[s];
  double S[9];
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) {
      const double k0 = K[3 * r], k1 = K[3 * r + 1], k2 = K[3 * r + 2];
      const double a0 = std::abs(k0), a1 = std::abs(k1), a2 = std::abs(k2), d = r == c ? 1.0 : 0.0;
      const double* b0 = &B[(0 + c) * m];
      const double* b1 = &B[(3 + c) * m];
      const double* b2 = &B[(6 + c) * m];
      double mx = 0;
      for (int a = 0; a < m; ++a) {
        const double v = k0 * b0[a] + k1 * b1[a] + k2 * b2[a] - d;
        const double w = std::abs(v) + 5.05 * u * (a0 * std::abs(b0[a]) + a1 * std::abs(b1[a]) + a2 * std::abs(b2[a]) + d);
        mx = w > mx ? w : mx;
      }
      S[3 * r + c] = (mx + a0 * errB[c] + a1 * errB[3 + c] + a2 * errB[6 + c]) * (1 + 8 * u);
    }
  double ninf = 0, n1 = 0;
  for (int r = 0; r < 3; ++r) ninf = std::max(ninf, S[3 * r] + S[3 * r + 1] + S[3 * r + 2]);
  for (int c = 0; c < 3; ++c) n1 = std::max(n1, S[c] + S[3 + c] + S[6 + c]);
  return std::min(ninf, n1) * (1 + 4 * u) < 1;
}

void classify(const JacobianSpace& sp, const double* X, const double* normal, const double* vals,
              const double* coef, double guard, ElementQuality& q, bool proven = false) {
  const int np = (int)sp.pts.size();
  q.min_det = *std::min_element(vals, vals + np);
  q.max_det = *std::max_element(vals, vals + np);
  q.aspect_ratio = aspect(sp.shape, X);
  if (proven) {  // tet_perturbation_proof (a sample <= 0 would contradict it: only by rounding)
    q.valid = q.min_det > 0;
  } else if (!sp.bezier && (sp.shape == Shape::Hex || sp.shape == Shape::Pyramid)) {
    if (q.min_det <= 0) {
      q.valid = false;  // a sample with det J <= 0
    } else {  // proof by Bernstein arithmetic (pyramids in collapsed coordinates), see above
      Tensor det;
      double err = 0;
      (sp.shape == Shape::Hex ? hex_det_bezier : pyramid_det_bezier)(sp.order, X, det, err);
      tensor_bezier_validity(std::move(det), err, q);
    }
  } else if (!sp.bezier) {
    q.sampled = true;
    q.valid = q.min_det > 0;
  } else if (q.min_det <= 0) {
    q.valid = false;
  } else if (*std::min_element(coef, coef + np) > guard) {
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
  Eigen::MatrixXd V(np, count);
  thread_local std::vector<double> H;
  H.resize(count);
  thread_local std::vector<double> Jp;
  Jp.resize(9 * np);
  Eigen::MatrixXd GX, GXc[3], HX;
  thread_local std::vector<char> proven;
  proven.assign(count, 0);
  if (sp.factored) {
    const int m = (int)sp.E.cols();
    HX.noalias() = sp.Hs * X;  // (3m) x (3count)
    for (int c = 0; c < sp.dim; ++c) GXc[c].noalias() = sp.E * HX.middleRows(c * m, m);  // np x (3count)
  } else if (!sp.tensor) {
    GX.noalias() = sp.G * X;  // (3np) x (3count)
  }
  for (int e = 0; e < count; ++e) {
    double Rc[9];
    if (sp.tensor) {
      tensor_jacobians(sp.te, xyz[e], Jp.data(), Rc);
    } else {
      dense_offsets(num_nodes(sp.shape, sp.order), xyz[e], Rc);
      if (sp.perturb && sp.factored && sp.dim == 3 && g_tet_perturbation_proof.load(std::memory_order_relaxed) &&
          (proven[e] = tet_perturbation_proof(sp, HX, e, Rc))) {
        // proven valid: det J at the samples (min/max for the scaled Jacobian) straight from the
        // product's columns, the same formula as planar_det; no copy, no rounding guard
        const double *j0 = GXc[0].col(3 * e).data(), *j1 = GXc[1].col(3 * e).data(), *j2 = GXc[2].col(3 * e).data();
        const double *j3 = GXc[0].col(3 * e + 1).data(), *j4 = GXc[1].col(3 * e + 1).data(), *j5 = GXc[2].col(3 * e + 1).data();
        const double *j6 = GXc[0].col(3 * e + 2).data(), *j7 = GXc[1].col(3 * e + 2).data(), *j8 = GXc[2].col(3 * e + 2).data();
        double* v = V.col(e).data();
        for (int p = 0; p < np; ++p)
          v[p] = j0[p] * (j4[p] * j8[p] - j5[p] * j7[p]) - j1[p] * (j3[p] * j8[p] - j5[p] * j6[p]) +
                 j2[p] * (j3[p] * j7[p] - j4[p] * j6[p]);
        H[e] = 0;
        continue;
      }
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) {
          double* jp = &Jp[(3 * r + c) * np];
          if (sp.factored) {
            if (c < sp.dim) std::copy(GXc[c].col(3 * e + r).data(), GXc[c].col(3 * e + r).data() + np, jp);
            else std::fill(jp, jp + np, 0.0);
          } else {
            for (int p = 0; p < np; ++p) jp[p] = GX(3 * p + c, 3 * e + r);
          }
        }
    }
    double h2 = 0, cm[3] = {0, 0, 0};
    planar_det(sp.dim, Jp.data(), np, normals + 3 * e, V.col(e).data(), h2, cm);
    const double vmax = V.col(e).cwiseAbs().maxCoeff();
    H[e] = coefficient_guard(sp, sp.jterms, vmax, h2, cm, sp.lambda, Rc);
  }
  // Bezier coefficients of det J for the elements the perturbation proof did not decide
  thread_local std::vector<int> rest;
  rest.clear();
  for (int e = 0; e < count; ++e)
    if (!proven[e]) rest.push_back(e);
  Eigen::MatrixXd C(np, (Eigen::Index)rest.size());
  if (sp.T.size() && !rest.empty()) {
    if ((int)rest.size() == count) {
      C.noalias() = sp.T * V;
    } else {
      Eigen::MatrixXd Vr(np, (Eigen::Index)rest.size());
      for (std::size_t k = 0; k < rest.size(); ++k) Vr.col(k) = V.col(rest[k]);
      C.noalias() = sp.T * Vr;
    }
  } else if (sp.bezier) {
    for (std::size_t k = 0; k < rest.size(); ++k) sp.to_bezier(V.col(rest[k]).data(), C.col(k).data());
  }
  for (std::size_t k = 0; k < rest.size(); ++k) {
    const int e = rest[k];
    classify(sp, xyz[e], normals + 3 * e, V.col(e).data(), sp.bezier ? C.col(k).data() : nullptr, H[e], out[e]);
  }
  for (int e = 0; e < count; ++e)
    if (proven[e]) classify(sp, xyz[e], normals + 3 * e, V.col(e).data(), nullptr, H[e], out[e], true);
}

}  // namespace

void set_tet_perturbation_proof(bool on) { g_tet_perturbation_proof = on; }

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
    for (int r = 0; r < 3; ++r) M(i, r) = X[3 * i + r] - X[r];
  std::vector<const double*> xyz = {X};
  evaluate_chunk(sp, M, 1, nrm, xyz, &q);
  return q;
}

namespace {
std::atomic<std::uint64_t> quality_calls{0};
}
std::uint64_t mesh_quality_calls() { return quality_calls.load(); }

namespace {
// The quality of `count` elements of block b, element(k) the k-th, into out[0..count), in
// chunks evaluated together (the per-element results do not depend on the chunk's others).
template <class ElementOf>
void evaluate_elements(const Mesh& m, const ElementBlock& b, int dim, bool planar, std::size_t count, ElementOf element_of,
                       ElementQuality* out) {
  const JacobianSpace& sp = space(b.shape, b.order);
  const int n = b.nodes_per_element();
  constexpr int kChunk = 32;  // dense shapes: G X and T V of a chunk stay in L2 (64 and more: 2.5x slower)
  const size_t nchunks = (count + kChunk - 1) / kChunk;
  tbb::parallel_for(tbb::blocked_range<size_t>(0, nchunks), [&](const tbb::blocked_range<size_t>& r) {
    Eigen::MatrixXd X(n, 3 * kChunk);
    std::vector<double> coords(static_cast<size_t>(kChunk) * n * 3);
    std::vector<double> normals(3 * kChunk);
    std::vector<const double*> xyz(kChunk);
    for (size_t c = r.begin(); c != r.end(); ++c) {
      const size_t e0 = c * kChunk;
      const int cnt = (int)std::min<size_t>(kChunk, count - e0);
      if (cnt < kChunk) X.setZero();
      for (int e = 0; e < cnt; ++e) {
        const std::uint32_t* nodes = b.element(element_of(e0 + e));
        double* P = coords.data() + static_cast<size_t>(e) * n * 3;
        for (int i = 0; i < n; ++i) {
          P[3 * i] = m.x[nodes[i]];
          P[3 * i + 1] = m.y[nodes[i]];
          P[3 * i + 2] = m.z[nodes[i]];
          for (int rr = 0; rr < 3; ++rr) X(i, 3 * e + rr) = P[3 * i + rr] - P[rr];
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
      evaluate_chunk(sp, X, cnt, normals.data(), xyz, out + e0);
    }
  });
}
}  // namespace

std::vector<std::vector<ElementQuality>> mesh_quality(const Mesh& m, int threads, const MeshQuality* known,
                                                      const std::vector<char>* moved) {
  ++quality_calls;
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
      if (known && bi < known->size() && !(*known)[bi].empty() && (*known)[bi].size() == b.size()) {
        res[bi] = (*known)[bi];
        if (!moved) continue;
        // the elements with a moved node, computed and put in their places
        std::vector<std::uint32_t> redo;
        const int n = b.nodes_per_element();
        for (std::uint32_t e = 0; e < b.size(); ++e) {
          const std::uint32_t* nodes = b.element(e);
          for (int i = 0; i < n; ++i)
            if (nodes[i] >= moved->size() || (*moved)[nodes[i]]) {
              redo.push_back(e);
              break;
            }
        }
        std::vector<ElementQuality> q(redo.size());
        evaluate_elements(m, b, dim, planar, redo.size(), [&](size_t k) { return redo[k]; }, q.data());
        for (std::size_t k = 0; k < redo.size(); ++k) res[bi][redo[k]] = q[k];
        continue;
      }
      res[bi].resize(b.size());
      evaluate_elements(m, b, dim, planar, b.size(), [](size_t k) { return k; }, res[bi].data());
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

std::vector<char> moved_nodes(const Mesh& m, const std::vector<double>& x0, const std::vector<double>& y0,
                              const std::vector<double>& z0) {
  std::vector<char> moved(m.num_nodes(), 1);
  const std::size_t n = std::min({m.num_nodes(), x0.size(), y0.size(), z0.size()});
  for (std::size_t i = 0; i < n; ++i)  // bitwise: -0.0 and 0.0 differ, NaN equals itself
    moved[i] = std::memcmp(&m.x[i], &x0[i], sizeof(double)) || std::memcmp(&m.y[i], &y0[i], sizeof(double)) ||
               std::memcmp(&m.z[i], &z0[i], sizeof(double));
  return moved;
}

namespace {
// How validity was established, in words a reader trusts: "proven for every element" only when it
// was (an element the Bezier refinement could not decide is inconclusive: the contract refuses it).
std::string validity_method_text(std::size_t total, std::size_t sampled, std::size_t inconclusive,
                                 const std::string& sampled_shapes) {
  if (!sampled && !inconclusive) return "bezier (proven for every element)";
  const std::size_t proven = total - sampled - std::min(inconclusive, total - sampled);
  std::string s = "bezier (proven) for " + std::to_string(proven) + " elements";
  if (inconclusive)
    s += "; inconclusive (neither proven valid nor shown invalid, the contract refuses them) for " +
         std::to_string(inconclusive) + " elements";
  if (sampled) s += "; sampling (not proven) for " + std::to_string(sampled) + " elements: " + sampled_shapes;
  return s;
}
}  // namespace

nlohmann::json mesh_stats(const Mesh& m, int threads) { return mesh_stats(m, mesh_quality(m, threads), build_topology(m)); }

nlohmann::json mesh_stats(const Mesh& m, const std::vector<std::vector<ElementQuality>>& q, const Topology& topo) {
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
  j["nonconforming_faces"] = topo.nonconforming_faces;
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
  // proven (Bezier bounds) for every element but those sampled (prisms of order >= 6), by shape
  std::map<std::string, std::size_t> sampled_by;
  for (size_t bi = 0; bi < m.blocks.size(); ++bi)
    for (const auto& eq : q[bi])
      if (eq.sampled) ++sampled_by[shape_name(m.blocks[bi].shape)];
  std::string which;
  for (auto& [name, count] : sampled_by) which += (which.empty() ? "" : ", ") + std::to_string(count) + " " + name + "s";
  j["validity_method"] = validity_method_text(total, sampled, inconclusive, which);
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
