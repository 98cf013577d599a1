// meshflow geometry — PRIVATE header (stages/geometry .cpp files only): the NACA 4-digit
// profile shared by the `naca_wing` and `wing_body` kinds.
//
// Symmetric profiles (00tt) are represented EXACTLY: with x = c s^2 the half-thickness
//   y_t = 5 t c (0.2969 s - 0.1260 s^2 - 0.3516 s^4 + 0.2843 s^6 - 0.1015 s^8)
// is a polynomial of degree 8 in s, so the profile (s in [-1,1], lower surface s < 0) is a
// degree-8 B-spline made of two Bezier pieces joined C1 at the leading edge. Cambered profiles
// (mptt) are interpolated (401 points; the largest deviation is returned in max_err).
// The curve lies in the plane z = 0: x along the chord (leading edge at the origin), y normal to it.
#pragma once

#include "engine/stage.hpp"

#include <GeomAPI_Interpolate.hxx>
#include <GeomAPI_ProjectPointOnCurve.hxx>
#include <Geom_BSplineCurve.hxx>
#include <TColStd_Array1OfInteger.hxx>
#include <TColStd_Array1OfReal.hxx>
#include <TColStd_HArray1OfReal.hxx>
#include <TColgp_Array1OfPnt.hxx>
#include <TColgp_HArray1OfPnt.hxx>

#include <algorithm>
#include <array>
#include <cmath>
#include <string>
#include <vector>

namespace meshflow::geometry::naca {

struct Naca4 {
  double m = 0, p = 0, t = 0.12;
  bool sharp = false;
  double a4() const { return sharp ? -0.1036 : -0.1015; }
  // half thickness at x (chord 1)
  double yt(double x) const {
    double s = std::sqrt(std::max(x, 0.0));
    return 5 * t * (0.2969 * s - 0.1260 * x - 0.3516 * x * x + 0.2843 * x * x * x + a4() * x * x * x * x);
  }
  double yc(double x) const {
    if (m == 0) return 0;
    return x < p ? m / (p * p) * (2 * p * x - x * x) : m / ((1 - p) * (1 - p)) * (1 - 2 * p + 2 * p * x - x * x);
  }
  double dyc(double x) const {
    if (m == 0) return 0;
    return x < p ? 2 * m / (p * p) * (p - x) : 2 * m / ((1 - p) * (1 - p)) * (p - x);
  }
  // Point of the profile at s in [-1,1] (x = s^2; s > 0 upper surface), chord 1.
  std::array<double, 2> point(double s) const {
    double x = s * s, y = (s >= 0 ? 1 : -1) * yt(x);
    double th = std::atan(dyc(x));
    return {x - y * std::sin(th), yc(x) + y * std::cos(th)};
  }
};

inline double binom(int n, int k) {
  double r = 1;
  for (int i = 1; i <= k; ++i) r = r * (n - k + i) / i;
  return r;
}

// Bernstein (Bezier) coefficients on s in [a,b] of the polynomial sum c[i] s^i (degree n).
inline std::vector<double> bezier_coeffs(const std::vector<double>& c, double a, double b, int n) {
  double h = b - a;
  std::vector<double> d(n + 1, 0.0);  // monomial coefficients in tau
  for (int i = 0; i < (int)c.size(); ++i)
    for (int j = 0; j <= i; ++j) d[j] += c[i] * binom(i, j) * std::pow(a, i - j) * std::pow(h, j);
  std::vector<double> bz(n + 1, 0.0);
  for (int k = 0; k <= n; ++k)
    for (int j = 0; j <= k; ++j) bz[k] += binom(k, j) / binom(n, j) * d[j];
  return bz;
}

// Exact degree-8 B-spline of a symmetric profile, chord c, in the plane z = 0.
inline Handle(Geom_BSplineCurve) symmetric_profile(const Naca4& n, double c) {
  const int deg = 8;
  double k = 5 * n.t;
  std::vector<double> xs = {0, 0, 1};  // x = s^2
  std::vector<double> yu = {0, k * 0.2969, k * -0.1260, 0, k * -0.3516, 0, k * 0.2843, 0, k * n.a4()};
  std::vector<double> yl = yu;
  for (int i = 2; i <= 8; ++i) yl[i] = -yu[i];
  auto xl = bezier_coeffs(xs, -1, 0, deg), ylb = bezier_coeffs(yl, -1, 0, deg);
  auto xu = bezier_coeffs(xs, 0, 1, deg), yub = bezier_coeffs(yu, 0, 1, deg);
  TColgp_Array1OfPnt poles(1, 17);
  for (int i = 0; i <= 8; ++i) poles(i + 1) = gp_Pnt(c * xl[i], c * ylb[i], 0);
  for (int i = 1; i <= 8; ++i) poles(9 + i) = gp_Pnt(c * xu[i], c * yub[i], 0);
  TColStd_Array1OfReal knots(1, 3);
  knots(1) = -1; knots(2) = 0; knots(3) = 1;
  TColStd_Array1OfInteger mults(1, 3);
  mults(1) = 9; mults(2) = 8; mults(3) = 9;
  Handle(Geom_BSplineCurve) bs = new Geom_BSplineCurve(poles, knots, mults, deg);
  bs->RemoveKnot(2, 7, 1e-12 * c);  // the pieces join C1 at the leading edge
  return bs;
}

inline Handle(Geom_BSplineCurve) interpolated_profile(const Naca4& n, double c, double& max_err, const std::string& who) {
  const int N = 401;
  Handle(TColgp_HArray1OfPnt) pts = new TColgp_HArray1OfPnt(1, N);
  Handle(TColStd_HArray1OfReal) par = new TColStd_HArray1OfReal(1, N);
  for (int i = 0; i < N; ++i) {
    double s = -1 + 2.0 * i / (N - 1);
    auto q = n.point(s);
    pts->SetValue(i + 1, gp_Pnt(c * q[0], c * q[1], 0));
    par->SetValue(i + 1, s);
  }
  GeomAPI_Interpolate ip(pts, par, Standard_False, 1e-12);
  ip.Perform();
  if (!ip.IsDone()) throw StageError(who + ": interpolating the cambered profile failed");
  Handle(Geom_BSplineCurve) bs = ip.Curve();
  max_err = 0;
  for (int i = 0; i < 4 * (N - 1); ++i) {
    double s = -1 + 2.0 * (i + 0.5) / (4 * (N - 1));
    auto q = n.point(s);
    GeomAPI_ProjectPointOnCurve pr(gp_Pnt(c * q[0], c * q[1], 0), bs);
    if (pr.NbPoints() > 0) max_err = std::max(max_err, pr.LowerDistance() / c);
  }
  return bs;
}

// The edges of a section wire: a sharp trailing edge closes the profile, which is then split at
// the leading edge (s = 0) into the lower and upper surfaces, so that the trailing edge is a
// real edge between two faces (one closed face would touch itself along its seam there, which
// OpenCASCADE's self-intersection check reports and meshing cannot use as a feature edge); a
// blunt profile is one curve (the trailing-edge segment is added by the caller).
inline std::vector<Handle(Geom_BSplineCurve)> profile_pieces(const Handle(Geom_BSplineCurve)& C, bool sharp) {
  if (!sharp) return {C};
  Handle(Geom_BSplineCurve) lo = Handle(Geom_BSplineCurve)::DownCast(C->Copy());
  Handle(Geom_BSplineCurve) up = Handle(Geom_BSplineCurve)::DownCast(C->Copy());
  lo->Segment(C->FirstParameter(), 0);
  up->Segment(0, C->LastParameter());
  return {lo, up};
}

// Parses "mptt"; throws StageError (prefixed by `who`) for a zero thickness or a camber
// without a camber position (or the reverse).
inline Naca4 parse(const std::string& prof, bool sharp, const std::string& who) {
  Naca4 n;
  n.m = (prof[0] - '0') / 100.0;
  n.p = (prof[1] - '0') / 10.0;
  n.t = std::stoi(prof.substr(2)) / 100.0;
  n.sharp = sharp;
  if (n.t <= 0) throw StageError(who + ": profile \"" + prof + "\" has zero thickness; use e.g. \"0012\"");
  if ((n.m > 0) != (n.p > 0))
    throw StageError(who + ": profile \"" + prof +
                     "\" gives a camber without a camber position (or the reverse): the first two digits must "
                     "both be 0 (symmetric) or both non-zero");
  return n;
}

}  // namespace meshflow::geometry::naca
