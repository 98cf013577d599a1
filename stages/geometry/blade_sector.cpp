// meshflow geometry kind `blade_sector`: one blade passage of a turbomachine row — a blade lofted
// through stacked sections read from a file (NASA Rotor 67 export or CSV, blade_sections.hpp),
// fused to a hub and a casing (no tip clearance), in a 2π/N annular sector whose two periodic
// sides are exact rotations of each other.
//
// Construction (all OCCT):
//   blade     tensor-product cubic B-spline interpolation of the section loops: every section is
//             interpolated by a periodic cubic through its points with common (averaged chord-
//             length) parameters, so all share one knot vector, then the pole columns are
//             interpolated spanwise. The surface passes EXACTLY through every file point (the
//             residual at the points is reported in stats.section_points_max_error). One extra
//             section is extrapolated below the hub and above the casing so that the blade
//             crosses both.
//   periodic  the same skinning through the sections' mean (camber) lines — for Rotor 67 the
//             whole streamsurface, its extensions upstream and downstream included — shifted by
//             -π/N: periodic_lo runs through the middle of the passage (the blade is staggered
//             more than one pitch, so planar sides would cut it); periodic_hi is the same
//             Geom surface rotated by 2π/N about the axis (poles rotated: exact to rounding).
//   hub/casing surfaces of revolution of the first/last streamsurface's meridian (x, r);
//             CSV: cylinders.
//   inflow/outflow  planes x = const, `upstream`/`downstream` blade axial chords from the blade.
//   sector    BOPAlgo_MakerVolume over these seven faces: the closed volumes they bound are the
//             passage and the blade's inside; the passage (the one bounded by the periodic
//             faces) is the fluid. Faces are tagged by their origin (BOP history).
#include "engine/stage.hpp"
#include "stages/cad/cad.hpp"
#include "stages/cad/occt.hpp"
#include "stages/cad/tag_rules.hpp"
#include "stages/geometry/blade_sections.hpp"
#include "stages/geometry/passage_check.hpp"
#include "stages/geometry/section_util.hpp"

#include <nlohmann/json.hpp>

#include <BOPAlgo_MakerVolume.hxx>
#include <BRepBuilderAPI_MakeFace.hxx>
#include <BRepBuilderAPI_Sewing.hxx>
#include <BRepCheck_Analyzer.hxx>
#include <BRepGProp.hxx>
#include <BRepTools_History.hxx>
#include <BRep_Tool.hxx>
#include <GProp_GProps.hxx>
#include <GeomAPI_Interpolate.hxx>
#include <Geom_BSplineCurve.hxx>
#include <Geom_BSplineSurface.hxx>
#include <Geom_Plane.hxx>
#include <Geom_SurfaceOfRevolution.hxx>
#include <Precision.hxx>
#include <Standard_Failure.hxx>
#include <Standard_Version.hxx>
#include <TColStd_Array1OfInteger.hxx>
#include <TColStd_Array1OfReal.hxx>
#include <TColStd_HArray1OfReal.hxx>
#include <TColgp_Array2OfPnt.hxx>
#include <TColgp_HArray1OfPnt.hxx>
#include <TopExp.hxx>
#include <TopExp_Explorer.hxx>
#include <TopTools_IndexedMapOfShape.hxx>
#include <TopTools_ListOfShape.hxx>
#include <TopoDS.hxx>
#include <gp_Ax1.hxx>
#include <gp_Pln.hxx>
#include <gp_Trsf.hxx>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

namespace meshflow::geometry {
namespace {
using cad::Tag;

gp_Pnt cart(const Cyl& c) { return gp_Pnt(c.x, c.r * std::cos(c.t), c.r * std::sin(c.t)); }

Handle(TColStd_HArray1OfReal) harr(const std::vector<double>& v) {
  Handle(TColStd_HArray1OfReal) a = new TColStd_HArray1OfReal(1, (int)v.size());
  for (size_t i = 0; i < v.size(); ++i) a->SetValue((int)i + 1, v[i]);
  return a;
}

Handle(Geom_BSplineCurve) interp(const std::vector<gp_Pnt>& p, const std::vector<double>& par, bool periodic, double tol) {
  Handle(TColgp_HArray1OfPnt) pts = new TColgp_HArray1OfPnt(1, (int)p.size());
  for (size_t i = 0; i < p.size(); ++i) pts->SetValue((int)i + 1, p[i]);
  GeomAPI_Interpolate ip(pts, harr(par), periodic, tol);
  ip.Perform();
  if (!ip.IsDone()) throw StageError("blade_sector: B-spline interpolation of the sections failed");
  return ip.Curve();
}

// Averaged normalised chord-length parameters of the rows (closed: one more, the junction).
std::vector<double> chord_params(const std::vector<std::vector<gp_Pnt>>& rows, bool closed) {
  size_t n = rows[0].size(), np = closed ? n + 1 : n;
  std::vector<double> avg(np, 0.0);
  for (auto& r : rows) {
    std::vector<double> s(np, 0.0);
    for (size_t i = 1; i < np; ++i) s[i] = s[i - 1] + r[i - 1].Distance(r[i % n]);
    for (size_t i = 0; i < np; ++i) avg[i] += s[i] / s[np - 1] / rows.size();
  }
  avg[0] = 0, avg[np - 1] = 1;
  return avg;
}

// Tensor-product cubic interpolation: rows (v direction, e.g. sections) of points (u direction).
// S(u_i, v_k) = rows[k][i] exactly; u-periodic when `uper` (rows are closed loops).
Handle(Geom_BSplineSurface) skin(const std::vector<std::vector<gp_Pnt>>& rows, bool uper, double tol,
                                 std::vector<double>& upar, std::vector<double>& vpar) {
  upar = chord_params(rows, uper);
  // v parameters: averaged chord length across the sections, over the point columns
  std::vector<std::vector<gp_Pnt>> cols(rows[0].size());
  for (size_t i = 0; i < rows[0].size(); ++i)
    for (auto& r : rows) cols[i].push_back(r[i]);
  vpar = chord_params(cols, false);
  std::vector<Handle(Geom_BSplineCurve)> sec;
  for (auto& r : rows) sec.push_back(interp(r, upar, uper, tol));
  auto same_knots = [](const Handle(Geom_BSplineCurve)& a, const Handle(Geom_BSplineCurve)& b) {
    if (a->NbKnots() != b->NbKnots() || a->NbPoles() != b->NbPoles() || a->Degree() != b->Degree()) return false;
    for (int i = 1; i <= a->NbKnots(); ++i)
      if (a->Knot(i) != b->Knot(i) || a->Multiplicity(i) != b->Multiplicity(i)) return false;
    return true;
  };
  for (auto& c : sec)
    if (!same_knots(c, sec[0])) throw StageError("blade_sector: section curves are not compatible (internal error)");
  const int np = sec[0]->NbPoles();
  std::vector<Handle(Geom_BSplineCurve)> colc;
  for (int i = 1; i <= np; ++i) {
    std::vector<gp_Pnt> q;
    for (auto& c : sec) q.push_back(c->Pole(i));
    colc.push_back(interp(q, vpar, false, 0.0));
  }
  for (auto& c : colc)
    if (!same_knots(c, colc[0])) throw StageError("blade_sector: pole columns are not compatible (internal error)");
  const int mp = colc[0]->NbPoles();
  TColgp_Array2OfPnt poles(1, np, 1, mp);
  for (int i = 1; i <= np; ++i)
    for (int j = 1; j <= mp; ++j) poles(i, j) = colc[i - 1]->Pole(j);
  TColStd_Array1OfReal uk(1, sec[0]->NbKnots()), vk(1, colc[0]->NbKnots());
  TColStd_Array1OfInteger um(1, sec[0]->NbKnots()), vm(1, colc[0]->NbKnots());
  sec[0]->Knots(uk);
  sec[0]->Multiplicities(um);
  colc[0]->Knots(vk);
  colc[0]->Multiplicities(vm);
  return new Geom_BSplineSurface(poles, uk, vk, um, vm, 3, 3, uper, false);
}

// Linear extrapolation of section `a` away from section `b`: a + f (a - b), pointwise in (x, r, θ).
std::vector<Cyl> extrapolate(const std::vector<Cyl>& a, const std::vector<Cyl>& b, double f) {
  std::vector<Cyl> out(a.size());
  for (size_t i = 0; i < a.size(); ++i)
    out[i] = {a[i].x + f * (a[i].x - b[i].x), a[i].r + f * (a[i].r - b[i].r), a[i].t + f * (a[i].t - b[i].t)};
  return out;
}

// Restricts polylines with common indices to [x0, x1] (keeping one point beyond each end) and
// extends them straight (in x, r, θ) where they do not reach.
void fit_axially(std::vector<std::vector<Cyl>>& lines, double x0, double x1) {
  size_t n = lines[0].size();
  size_t j0 = 0, j1 = n - 1;
  for (size_t j = 0; j < n; ++j) {
    bool all = true;
    for (auto& l : lines) all &= l[j].x <= x0;
    if (all) j0 = j;
  }
  for (size_t j = n; j-- > 0;) {
    bool all = true;
    for (auto& l : lines) all &= l[j].x >= x1;
    if (all) j1 = j;
  }
  if (j1 <= j0 + 1) j0 = 0, j1 = n - 1;
  for (auto& l : lines) {
    l = std::vector<Cyl>(l.begin() + j0, l.begin() + j1 + 1);
    // straight extensions along the secant over the first/last tenth of the line, in 6 steps
    const size_t m = std::max<size_t>(1, (l.size() - 1) / 10);
    if (l.front().x > x0) {
      const Cyl a = l[0], b = l[m];
      double f = (a.x - (x0 - 0.01 * std::abs(x1 - x0))) / std::max(b.x - a.x, 1e-300);
      for (int k = 1; k <= 6; ++k) {
        double g = f * k / 6;
        l.insert(l.begin(), Cyl{a.x - g * (b.x - a.x), a.r - g * (b.r - a.r), a.t - g * (b.t - a.t)});
      }
    }
    if (l.back().x < x1) {
      const Cyl a = l[l.size() - 1], b = l[l.size() - 1 - m];
      double f = ((x1 + 0.01 * std::abs(x1 - x0)) - a.x) / std::max(a.x - b.x, 1e-300);
      for (int k = 1; k <= 6; ++k) {
        double g = f * k / 6;
        l.push_back(Cyl{a.x + g * (a.x - b.x), a.r + g * (a.r - b.r), a.t + g * (a.t - b.t)});
      }
    }
  }
}

// Common indices keeping the mean lines' points at least `frac` of their (averaged) length apart.
std::vector<size_t> decimate(const std::vector<std::vector<Cyl>>& lines, double frac) {
  size_t n = lines[0].size();
  std::vector<double> s(n, 0.0);
  for (size_t j = 1; j < n; ++j) {
    double d = 0;
    for (auto& l : lines) d += cart(l[j]).Distance(cart(l[j - 1]));
    s[j] = s[j - 1] + d / lines.size();
  }
  std::vector<size_t> keep = {0};
  for (size_t j = 1; j + 1 < n; ++j)
    if (s[j] - s[keep.back()] >= frac * s[n - 1] && s[n - 1] - s[j] >= frac * s[n - 1]) keep.push_back(j);
  keep.push_back(n - 1);
  return keep;
}

std::string slurp(const std::filesystem::path& p) {
  std::ifstream in(p, std::ios::binary);
  if (!in) throw StageError("blade_sector: cannot open '" + p.string() + "': check the path (relative to the workflow file)");
  std::ostringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

BladeSections read_sections(const std::filesystem::path& path, const nlohmann::json& P) {
  const std::string format = P.at("format").get<std::string>();
  std::string text = slurp(path);
  if (format == "rotor67") return parse_rotor67(text, path.string());
  TableOptions o;
  o.layout = format == "zrt" ? TableLayout::zrt : TableLayout::xyz;
  o.angle_unit = P.at("angle_unit").get<std::string>();
  o.hub_radius = P.at("hub_radius").get<double>();
  o.casing_radius = P.at("casing_radius").get<double>();
  return parse_blade_table(text, path.string(), o);
}

// The result's unit label and the factor from the file's lengths to it: `scale`, times the
// conversion from the unit the file declares to `units` when both are given and differ.
std::pair<std::string, double> result_units(const BladeSections& bs, const nlohmann::json& P) {
  std::string units = P.at("units").get<std::string>();
  double f = P.at("scale").get<double>();
  if (units.empty()) units = !bs.units.empty() ? bs.units : bs.format == "rotor67" ? "ft" : "m";
  else if (!bs.units.empty() && units != bs.units) f *= length_unit_in_m(bs.units) / length_unit_in_m(units);
  return {units, f};
}

void scale_sections(BladeSections& bs, double f) {
  for (auto* set : {&bs.loops, &bs.mean})
    for (auto& l : *set)
      for (auto& p : l) p.x *= f, p.r *= f;
  for (auto* m : {&bs.hub, &bs.casing})
    for (auto& p : *m) p.x *= f, p.r *= f;
}

// Radius of a meridian polyline at axial position x (held constant beyond its ends).
double radius_at(const std::vector<Cyl>& m, double x) {
  for (size_t j = 0; j + 1 < m.size(); ++j)
    if (x >= m[j].x && x <= m[j + 1].x) return m[j].r + (x - m[j].x) / (m[j + 1].x - m[j].x) * (m[j + 1].r - m[j].r);
  return x < m[0].x ? m[0].r : m.back().r;
}

// Axial frame of the passage: the blade's leading and trailing edges, the planes, the height.
struct Frame {
  double xle = 1e300, xte = -1e300, rmax = 0, cax = 0, x_in = 0, x_out = 0, margin = 0, height = 0;
};
Frame frame_of(const BladeSections& bs, double up, double down) {
  Frame F;
  for (auto& l : bs.loops)
    for (auto& p : l) F.xle = std::min(F.xle, p.x), F.xte = std::max(F.xte, p.x), F.rmax = std::max(F.rmax, p.r);
  for (auto& p : bs.casing) F.rmax = std::max(F.rmax, p.r);
  F.cax = F.xte - F.xle;
  F.x_in = F.xle - up * F.cax, F.x_out = F.xte + down * F.cax;
  F.margin = 0.05 * F.cax;
  F.height = radius_at(bs.casing, F.xle) - radius_at(bs.hub, F.xle);  // blade height at the leading edge
  if (!(F.height > 0)) throw StageError("blade_sector: the casing is not above the hub at the leading edge");
  return F;
}

// The point sets the surfaces interpolate: blade loops and mean lines with one section beyond
// hub and casing (mean lines to the planes, at -pitch/2), hub and casing meridians to the planes.
struct PassageLines {
  std::vector<std::vector<Cyl>> loops, mean;
  std::vector<Cyl> hub, casing;
  double ta = 0, tb = 0;           // angular range of the hub and casing faces
  double f_lo = 0.5, f_hi = 0.5;   // extrapolation factors below the first and above the last section
};

// How far the blade is extrapolated below the hub and above the casing, in section spacings:
// half a spacing (streamsurfaces: rotor67), or enough to cross the cylinders by 5% of the height.
void extension_factors(const BladeSections& bs, const Frame& F, PassageLines& L) {
  if (bs.format == "rotor67") return;
  const auto& loops = bs.loops;
  const size_t ns = loops.size();
  double rh = bs.hub[0].r, rc = bs.casing[0].r, g0 = 1e300, g1 = 1e300, need0 = 0, need1 = 0;
  for (size_t i = 0; i < loops[0].size(); ++i) {
    g0 = std::min(g0, loops[1][i].r - loops[0][i].r);
    g1 = std::min(g1, loops[ns - 1][i].r - loops[ns - 2][i].r);
    need0 = std::max(need0, loops[0][i].r - rh + 0.05 * F.height);
    need1 = std::max(need1, rc - loops[ns - 1][i].r + 0.05 * F.height);
  }
  if (!(g0 > 0) || !(g1 > 0))
    throw StageError("blade_sector: the sections must go from hub to tip with every point's radius increasing from one "
                     "section to the next (at the first or last pair of sections a point's radius does not increase)");
  L.f_lo = std::max(0.5, need0 / g0);
  L.f_hi = std::max(0.5, need1 / g1);
}

PassageLines passage_lines(const BladeSections& bs, const Frame& F, double pitch) {
  PassageLines L;
  extension_factors(bs, F, L);
  const size_t ns = bs.loops.size();
  L.loops = bs.loops;
  L.loops.insert(L.loops.begin(), extrapolate(L.loops[0], L.loops[1], L.f_lo));
  L.loops.push_back(extrapolate(L.loops[ns], L.loops[ns - 1], L.f_hi));
  L.mean = bs.mean;
  fit_axially(L.mean, F.x_in - F.margin, F.x_out + F.margin);
  auto keep = decimate(L.mean, 0.01);
  for (auto& l : L.mean) {
    std::vector<Cyl> d;
    for (size_t j : keep) d.push_back(l[j]);
    l = d;
  }
  L.mean.insert(L.mean.begin(), extrapolate(L.mean[0], L.mean[1], L.f_lo));
  L.mean.push_back(extrapolate(L.mean[ns], L.mean[ns - 1], L.f_hi));
  for (auto& l : L.mean)
    for (auto& p : l) p.t -= 0.5 * pitch;
  std::vector<std::vector<Cyl>> hubm = {bs.hub}, casm = {bs.casing};
  fit_axially(hubm, F.x_in - F.margin, F.x_out + F.margin);
  fit_axially(casm, F.x_in - F.margin, F.x_out + F.margin);
  L.hub = hubm[0], L.casing = casm[0];
  double tmin = 1e300, tmax = -1e300;
  for (auto& l : L.mean)
    for (auto& p : l) tmin = std::min(tmin, p.t), tmax = std::max(tmax, p.t + pitch);
  for (auto& l : L.loops)
    for (auto& p : l) tmin = std::min(tmin, p.t), tmax = std::max(tmax, p.t);
  L.ta = tmin - 0.2, L.tb = tmax + 0.2;
  if (L.tb - L.ta >= 2 * M_PI - 1e-3)
    throw StageError("blade_sector: the passage (mean lines plus one pitch) turns by more than a full revolution about the axis; "
                     "check `blades` and the file's angles (format: zrt reads theta in degrees unless the header or "
                     "angle_unit says rad)");
  return L;
}

// A sharp corner of the sections (a sharp trailing edge): the point index where every file
// section's loop turns by more than 60 degrees and by more than three times as much as at either
// neighbouring point (unrolled on its mean radius: x, r θ), or -1. Smooth sections turn by 25
// degrees at most per point (Rotor 67's round edges), a coarsely sampled elliptic nose by large
// but similar angles at three points in a row; a cambered NACA section with a closed trailing
// edge turns by 166 degrees there and by a few at its neighbours.
int sharp_corner(const std::vector<std::vector<Cyl>>& loops) {
  int corner = -2;
  for (auto& l : loops) {
    double rm = 0;
    for (auto& p : l) rm += p.r / l.size();
    const size_t n = l.size();
    std::vector<double> turn(n);
    for (size_t i = 0; i < n; ++i) {
      const Cyl &a = l[(i + n - 1) % n], &b = l[i], &c = l[(i + 1) % n];
      double d1x = b.x - a.x, d1y = rm * (b.t - a.t), d2x = c.x - b.x, d2y = rm * (c.t - b.t);
      turn[i] = std::abs(std::atan2(d1x * d2y - d1y * d2x, d1x * d2x + d1y * d2y)) * 180 / M_PI;
    }
    int best = -1;
    for (size_t i = 0; i < n; ++i)
      if (turn[i] > 60 && turn[i] > 3 * std::max(turn[(i + n - 1) % n], turn[(i + 1) % n]) && (best < 0 || turn[i] > turn[best]))
        best = (int)i;
    if (best < 0) return -1;
    if (corner == -2) corner = best;
    else if (corner != best) return -1;
  }
  return corner < 0 ? -1 : corner;
}

// The Geom surfaces of the seven sides.
struct Surfaces {
  Handle(Geom_BSplineSurface) blade, plo, phi;
  Handle(Geom_SurfaceOfRevolution) hub, cas;
  std::vector<double> bu, bv;   // blade parameters of the loops' points and sections
  double section_err = 0;       // largest distance of a file point to the blade surface
  // A sharp trailing edge (sections' point `corner`): the blade is one non-periodic surface from
  // the corner round to the corner (C0 there, C2 elsewhere), made two faces split at the leading
  // edge's parameter `u_le` (tangent-continuous there: one surface). Else one periodic surface.
  int corner = -1;
  double u_le = 0;
};

Surfaces build_surfaces(const PassageLines& L, int corner, double pitch, double tol) {
  Surfaces S;
  S.corner = corner;
  std::vector<std::vector<gp_Pnt>> rows;
  for (auto& l : L.loops) {
    rows.emplace_back();
    const size_t n = l.size();
    if (corner < 0)
      for (auto& p : l) rows.back().push_back(cart(p));
    else
      for (size_t i = 0; i <= n; ++i) rows.back().push_back(cart(l[(corner + i) % n]));
  }
  S.blade = skin(rows, corner < 0, tol, S.bu, S.bv);
  if (corner >= 0) S.u_le = S.bu[(L.loops[0].size() - corner) % L.loops[0].size()];
  for (size_t k = 1; k + 1 < rows.size(); ++k)
    for (size_t i = 0; i < rows[k].size(); ++i)
      S.section_err = std::max(S.section_err, S.blade->Value(S.bu[i], S.bv[k]).Distance(rows[k][i]));
  rows.clear();
  for (auto& l : L.mean) {
    rows.emplace_back();
    for (auto& p : l) rows.back().push_back(cart(p));
  }
  std::vector<double> pu, pv;
  S.plo = skin(rows, false, tol, pu, pv);
  gp_Trsf rot;
  rot.SetRotation(gp_Ax1(gp_Pnt(0, 0, 0), gp_Dir(1, 0, 0)), pitch);
  S.phi = Handle(Geom_BSplineSurface)::DownCast(S.plo->Transformed(rot));
  auto meridian = [&](const std::vector<Cyl>& m) {
    std::vector<gp_Pnt> p;
    for (auto& c : m) p.push_back(gp_Pnt(c.x, c.r, 0));
    return interp(p, chord_params({p}, false), false, tol);
  };
  S.hub = new Geom_SurfaceOfRevolution(meridian(L.hub), gp_Ax1(gp_Pnt(0, 0, 0), gp_Dir(1, 0, 0)));
  S.cas = new Geom_SurfaceOfRevolution(meridian(L.casing), gp_Ax1(gp_Pnt(0, 0, 0), gp_Dir(1, 0, 0)));
  return S;
}

constexpr int kSources = 7;
const char* const kSourceName[kSources] = {"hub", "casing", "inflow", "outflow", "periodic_lo", "periodic_hi", "blade"};
const Tag kSourceTag[kSources] = {Tag::wall, Tag::wall, Tag::farfield, Tag::farfield, Tag::periodic_lo, Tag::periodic_hi, Tag::wall};

// The boolean's arguments and the surface (0..kSources-1) each comes from.
struct Faces {
  std::vector<TopoDS_Face> f;
  std::vector<int> source;
};

Faces make_faces(const Surfaces& S, const PassageLines& L, const Frame& F, double tol) {
  const double R = 1.5 * F.rmax;
  Faces out;
  auto add = [&](const TopoDS_Face& f, int s) { out.f.push_back(f), out.source.push_back(s); };
  add(BRepBuilderAPI_MakeFace(S.hub, L.ta, L.tb, 0, 1, tol), 0);
  add(BRepBuilderAPI_MakeFace(S.cas, L.ta, L.tb, 0, 1, tol), 1);
  add(BRepBuilderAPI_MakeFace(gp_Pln(gp_Pnt(F.x_in, 0, 0), gp_Dir(1, 0, 0)), -R, R, -R, R), 2);
  add(BRepBuilderAPI_MakeFace(gp_Pln(gp_Pnt(F.x_out, 0, 0), gp_Dir(1, 0, 0)), -R, R, -R, R), 3);
  add(BRepBuilderAPI_MakeFace(S.plo, Precision::Confusion()), 4);
  add(BRepBuilderAPI_MakeFace(S.phi, Precision::Confusion()), 5);
  if (S.corner < 0) {
    add(BRepBuilderAPI_MakeFace(S.blade, Precision::Confusion()), 6);
  } else {
    double u0, u1, v0, v1;
    S.blade->Bounds(u0, u1, v0, v1);
    // sewn first, so that the two faces share their leading- and trailing-edge edges (the
    // boolean alone keeps them apart: the blade would not close)
    // Each face its own segment of the surface: two faces on one surface are merged by heal's
    // unify into one face whose seam is the crease, which fails OCCT's validity check.
    BRepBuilderAPI_Sewing sew(Precision::Confusion());
    for (auto [a, b] : {std::pair{u0, S.u_le}, std::pair{S.u_le, u1}}) {
      Handle(Geom_BSplineSurface) part = Handle(Geom_BSplineSurface)::DownCast(S.blade->Copy());
      part->Segment(a, b, v0, v1);
      sew.Add(BRepBuilderAPI_MakeFace(part, Precision::Confusion()));
    }
    sew.Perform();
    for (TopExp_Explorer ex(sew.SewedShape(), TopAbs_FACE); ex.More(); ex.Next()) add(TopoDS::Face(ex.Current()), 6);
  }
  return out;
}

Cyl cyl_of(const gp_Pnt& p) { return {p.X(), std::hypot(p.Y(), p.Z()), std::atan2(p.Z(), p.Y())}; }

// Points of a surface along u (v fixed) or along v (u fixed), n + 1 of them, angles unwrapped
// from `t0` (the angle the surface's data starts near).
std::vector<Cyl> iso(const Handle(Geom_Surface)& s, bool along_u, double fixed, int n, double t0) {
  double u0, u1, v0, v1;
  s->Bounds(u0, u1, v0, v1);
  std::vector<Cyl> out;
  double last = t0;
  for (int i = 0; i <= n; ++i) {
    double w = (double)i / n;
    gp_Pnt p = along_u ? s->Value(u0 + w * (u1 - u0), fixed) : s->Value(fixed, v0 + w * (v1 - v0));
    Cyl c = cyl_of(p);
    c.t += 2 * M_PI * std::round((last - c.t) / (2 * M_PI));
    last = c.t;
    out.push_back(c);
  }
  return out;
}

// The samples passage_check needs: meridians, the blade's and periodic_lo's boundary curves, the
// file's sections and periodic_lo's rows through them.
PassageSamples sample_passage(const Surfaces& S, const PassageLines& L, const BladeSections& bs, const Frame& F,
                              double pitch, const std::string& units) {
  PassageSamples ps;
  ps.units = units, ps.pitch = pitch, ps.x_in = F.x_in, ps.x_out = F.x_out, ps.height = F.height;
  ps.ta = L.ta, ps.tb = L.tb;
  double u0, u1, v0, v1;
  S.hub->Bounds(u0, u1, v0, v1);
  ps.hub = iso(S.hub, false, 0.0, 1000, 0);
  ps.casing = iso(S.cas, false, 0.0, 1000, 0);
  for (auto* m : {&ps.hub, &ps.casing})
    for (auto& p : *m) p.t = 0;
  S.blade->Bounds(u0, u1, v0, v1);
  ps.blade_root = iso(S.blade, true, v0, 800, L.loops.front()[0].t);
  ps.blade_tip = iso(S.blade, true, v1, 800, L.loops.back()[0].t);
  S.plo->Bounds(u0, u1, v0, v1);
  ps.periodic_root = iso(S.plo, true, v0, 800, L.mean.front()[0].t);
  ps.periodic_tip = iso(S.plo, true, v1, 800, L.mean.back()[0].t);
  ps.periodic_in = iso(S.plo, false, u0, 400, L.mean.front()[0].t);
  ps.periodic_out = iso(S.plo, false, u1, 400, L.mean.front().back().t);
  ps.sections = bs.loops;
  ps.periodic_rows.assign(L.mean.begin() + 1, L.mean.end() - 1);
  return ps;
}

[[noreturn]] void refuse(const std::vector<Finding>& found, const std::string& path) {
  std::string m = "blade_sector: the passage cannot close with the surfaces from '" + path + "': ";
  int n = 0;
  for (auto& f : found)
    if (f.fatal) m += (n++ ? "; also " : "") + f.text;
  throw StageError(m);
}

// What the surface checks found, for a message when the boolean fails anyway.
std::string findings_text(const std::vector<Finding>& found, const PassageSamples& ps) {
  std::string t;
  for (auto& f : found) t += " " + f.text + ".";
  return t + " " + passage_margins(ps);
}

// The fluid: the solid of the boolean bounded by both periodic faces, with each face's tag.
struct Sector {
  TopoDS_Shape fluid;
  std::vector<Tag> tags;
  int faces_by_source[kSources] = {0, 0, 0, 0, 0, 0, 0};
};

Sector make_sector(StageContext& ctx, const Faces& src, const std::string& diag) {
  BOPAlgo_MakerVolume mv;
  TopTools_ListOfShape args;
  for (auto& f : src.f) args.Append(f);
  mv.SetArguments(args);
  mv.SetRunParallel(false);
  mv.SetIntersect(true);
  mv.Perform();
  if (mv.HasErrors())
    throw StageError("blade_sector: building the sector from hub, casing, planes, periodic and blade surfaces failed "
                     "(OCCT BOPAlgo_MakerVolume); check upstream/downstream and the section file." + diag);
  Handle(BRepTools_History) hist = mv.History();
  auto source_of = [&](const TopoDS_Shape& f) {
    for (size_t i = 0; i < src.f.size(); ++i) {
      if (f.IsSame(src.f[i])) return src.source[i];
      for (TopTools_ListIteratorOfListOfShape it(hist->Modified(src.f[i])); it.More(); it.Next())
        if (it.Value().IsSame(f)) return src.source[i];
    }
    return -1;
  };
  std::vector<TopoDS_Shape> solids;
  for (TopExp_Explorer ex(mv.Shape(), TopAbs_SOLID); ex.More(); ex.Next()) solids.push_back(ex.Current());
  int chosen = -1;
  for (size_t i = 0; i < solids.size(); ++i) {
    bool has_lo = false, has_hi = false;
    for (TopExp_Explorer ex(solids[i], TopAbs_FACE); ex.More(); ex.Next()) {
      int s = source_of(ex.Current());
      has_lo |= s == 4, has_hi |= s == 5;
    }
    if (has_lo && has_hi) {
      if (chosen >= 0) throw StageError("blade_sector: more than one passage volume (internal error)." + diag);
      chosen = (int)i;
    }
  }
  if (chosen < 0)
    throw StageError("blade_sector: the periodic, hub, casing and inflow/outflow surfaces do not close a passage volume (" +
                     std::to_string(solids.size()) + " volume(s) found)." + diag);
  for (size_t i = 0; i < solids.size(); ++i) {
    std::string d = "blade_sector: volume " + std::to_string(i) + " faces from:";
    for (TopExp_Explorer ex(solids[i], TopAbs_FACE); ex.More(); ex.Next()) d += " " + std::to_string(source_of(ex.Current()));
    ctx.log(d);
  }
  Sector out;
  out.fluid = solids[chosen];
  TopTools_IndexedMapOfShape faces;
  TopExp::MapShapes(out.fluid, TopAbs_FACE, faces);
  for (int i = 1; i <= faces.Extent(); ++i) {
    int s = source_of(faces(i));
    if (s < 0) throw StageError("blade_sector: a face of the passage has no known origin (internal error)");
    out.tags.push_back(kSourceTag[s]);
    out.faces_by_source[s]++;
  }
  std::string counts;
  for (int s = 0; s < kSources; ++s) counts += std::string(s ? ", " : "") + kSourceName[s] + " " + std::to_string(out.faces_by_source[s]);
  for (int s = 0; s < kSources; ++s)
    if (out.faces_by_source[s] == 0)
      throw StageError(std::string("blade_sector: the passage has no ") + kSourceName[s] + " face (faces per surface: " + counts +
                       "): the surfaces do not bound the passage as expected; check upstream/downstream." + diag);
  return out;
}

void run(StageContext& ctx) {
  const auto& P = ctx.params();
  auto path = ctx.file(P.at("file").get<std::string>());
  double up = P.at("upstream").get<double>(), down = P.at("downstream").get<double>();

  ctx.progress(0.0, "reading sections");
  BladeSections bs = read_sections(path, P);
  for (auto& n : bs.notes) ctx.log("blade_sector: " + n);
  auto [units, factor] = result_units(bs, P);
  int N = P.at("blades").get<int>();
  if (N == 0) N = bs.blades;
  if (N <= 0)
    throw StageError("blade_sector: the number of blades is not in the file '" + path.string() + "': set `blades:`");
  const double pitch = 2 * M_PI / N;
  scale_sections(bs, factor);
  const Frame F = frame_of(bs, up, down);
  const double tol = 1e-12 * F.rmax;
  const PassageLines L = passage_lines(bs, F, pitch);

  cad::occt::Log log([&](const std::string& s) { ctx.log(s); });
  ctx.progress(0.1, "blade surface");
  Sector sector;
  double section_err = 0;
  int sharp = -1;
  std::vector<Finding> found;
  try {
    const int corner = sharp_corner(bs.loops);
    if (corner >= 0)
      ctx.log("blade_sector: the sections have a sharp corner at point " + std::to_string(corner + 1) +
              " (a sharp trailing edge): the blade is two faces meeting there, split at the leading edge");
    Surfaces S = build_surfaces(L, corner, pitch, tol);
    sharp = corner;
    section_err = S.section_err;
    ctx.progress(0.3, "surface checks");
    PassageSamples ps = sample_passage(S, L, bs, F, pitch, units);
    found = check_passage(ps);
    for (auto& f : found) ctx.log(std::string("blade_sector: ") + (f.fatal ? "fails: " : "note: ") + f.surface + ": " + f.text);
    ctx.log("blade_sector: " + passage_margins(ps));
    if (!found.empty() && found.front().fatal) refuse(found, path.string());
    ctx.progress(0.35, "sector (boolean)");
    sector = make_sector(ctx, make_faces(S, L, F, tol), findings_text(found, ps));
  } catch (const Standard_Failure& e) {
    throw StageError(std::string("blade_sector: OpenCASCADE failed building the sector (") + e.GetMessageString() +
                     "); check the section file and the parameters");
  }
  ctx.progress(0.85, "checking");
  if (!BRepCheck_Analyzer(sector.fluid).IsValid())
    throw StageError("blade_sector: the passage solid is not valid (BRepCheck); report it with the section file");
  cad::Shape shape = cad::occt::make_shape(sector.fluid, units, sector.tags);
  if (!shape.free_edges().empty() || !shape.multiple_edges().empty())
    throw StageError("blade_sector: the passage solid is not watertight (" + std::to_string(shape.free_edges().size()) +
                     " free and " + std::to_string(shape.multiple_edges().size()) +
                     " multiple edges); report it with the section file");
  cad::apply_tag_rules(shape, P.at("tag_overrides"), "blade_sector stage '" + ctx.stage_name() + "'");
  auto& st = ctx.stats();
  st = cad::occt::summarize(shape);
  st["format"] = bs.format;
  st["blades"] = N;
  st["sections"] = (int)bs.loops.size();
  st["points_per_section"] = (int)bs.loops[0].size();
  st["blade_height"] = F.height;
  st["axial_chord"] = F.cax;
  st["inflow_x"] = F.x_in;
  st["outflow_x"] = F.x_out;
  st["section_points_max_error"] = section_err;
  nlohmann::json by = nlohmann::json::object();
  for (int s = 0; s < kSources; ++s) by[kSourceName[s]] = sector.faces_by_source[s];
  st["faces_by_surface"] = by;
  if (bs.resampled_from > 0) st["sections_resampled_from"] = bs.resampled_from;
  if (sharp >= 0) st["sharp_trailing_edge_point"] = sharp + 1;
  if (!found.empty()) {
    nlohmann::json notes = nlohmann::json::array();
    for (auto& f : found) notes.push_back(f.text);
    st["surface_notes"] = notes;
  }
  shape.save(ctx.output("shape", "shape"));
  ctx.progress(1.0, "done");
}

StageRegistrar reg({.kind = "blade_sector",
                    .version = 1,
                    .summary = "blade lofted through file sections (Rotor 67, CSV, Z/R/theta) on a hub in a 2pi/N periodic sector",
                    .libraries = {"OCCT " OCC_VERSION_COMPLETE},
                    .produces = {{"shape", "shape"}},
                    .run = run});
}  // namespace
}  // namespace meshflow::geometry
