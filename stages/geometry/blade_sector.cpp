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

#include <nlohmann/json.hpp>

#include <BOPAlgo_MakerVolume.hxx>
#include <BRepBuilderAPI_MakeFace.hxx>
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

void run(StageContext& ctx) {
  const auto& P = ctx.params();
  std::string name = P.at("file").get<std::string>();
  auto path = ctx.file(name);
  std::string format = P.at("format").get<std::string>();
  double scale = P.at("scale").get<double>();
  double up = P.at("upstream").get<double>(), down = P.at("downstream").get<double>();
  std::string units = P.at("units").get<std::string>();

  ctx.progress(0.0, "reading sections");
  std::string text = slurp(path);
  BladeSections bs = format == "csv"
                         ? parse_blade_csv(text, path.string(), P.at("hub_radius").get<double>() , P.at("casing_radius").get<double>())
                         : parse_rotor67(text, path.string());
  if (units.empty()) units = format == "csv" ? "m" : "ft";
  int N = P.at("blades").get<int>();
  if (N == 0) N = bs.blades;
  if (N <= 0)
    throw StageError("blade_sector: the number of blades is not in the file '" + path.string() + "': set `blades:`");
  const double pitch = 2 * M_PI / N;
  for (auto* set : {&bs.loops, &bs.mean})
    for (auto& l : *set)
      for (auto& p : l) p.x *= scale, p.r *= scale;
  for (auto* m : {&bs.hub, &bs.casing})
    for (auto& p : *m) p.x *= scale, p.r *= scale;

  double xle = 1e300, xte = -1e300, rmax = 0;
  for (auto& l : bs.loops)
    for (auto& p : l) xle = std::min(xle, p.x), xte = std::max(xte, p.x), rmax = std::max(rmax, p.r);
  for (auto& p : bs.casing) rmax = std::max(rmax, p.r);
  const double cax = xte - xle;
  const double x_in = xle - up * cax, x_out = xte + down * cax;
  const double margin = 0.05 * cax;
  double height = 0;  // blade height at the leading edge: casing minus hub radius
  {
    auto at = [](const std::vector<Cyl>& m, double x) {
      for (size_t j = 0; j + 1 < m.size(); ++j)
        if (x >= m[j].x && x <= m[j + 1].x) return m[j].r + (x - m[j].x) / (m[j + 1].x - m[j].x) * (m[j + 1].r - m[j].r);
      return x < m[0].x ? m[0].r : m.back().r;
    };
    height = at(bs.casing, xle) - at(bs.hub, xle);
  }
  if (!(height > 0)) throw StageError("blade_sector: the casing is not above the hub at the leading edge");
  const double tol = 1e-12 * rmax;

  // blade loops with one section beyond hub and casing
  std::vector<std::vector<Cyl>> loops = bs.loops;
  const size_t ns = loops.size();
  double f_lo = 0.5, f_hi = 0.5;
  if (bs.format == "csv") {  // cylinders: make sure the extension crosses them by 5% of the height
    double rh = bs.hub[0].r, rc = bs.casing[0].r, g0 = 1e300, g1 = 1e300, need0 = 0, need1 = 0;
    for (size_t i = 0; i < loops[0].size(); ++i) {
      g0 = std::min(g0, loops[1][i].r - loops[0][i].r);
      g1 = std::min(g1, loops[ns - 1][i].r - loops[ns - 2][i].r);
      need0 = std::max(need0, loops[0][i].r - rh + 0.05 * height);
      need1 = std::max(need1, rc - loops[ns - 1][i].r + 0.05 * height);
    }
    if (!(g0 > 0) || !(g1 > 0))
      throw StageError("blade_sector: the CSV sections must go from hub to tip with every point's radius increasing from one section to the next");
    f_lo = std::max(0.5, need0 / g0);
    f_hi = std::max(0.5, need1 / g1);
  }
  loops.insert(loops.begin(), extrapolate(loops[0], loops[1], f_lo));
  loops.push_back(extrapolate(loops[ns], loops[ns - 1], f_hi));

  // mean lines: to the inflow/outflow planes, decimated, beyond hub and casing, at -pitch/2
  std::vector<std::vector<Cyl>> mean = bs.mean;
  fit_axially(mean, x_in - margin, x_out + margin);
  auto keep = decimate(mean, 0.01);
  for (auto& l : mean) {
    std::vector<Cyl> d;
    for (size_t j : keep) d.push_back(l[j]);
    l = d;
  }
  mean.insert(mean.begin(), extrapolate(mean[0], mean[1], f_lo));
  mean.push_back(extrapolate(mean[ns], mean[ns - 1], f_hi));
  for (auto& l : mean)
    for (auto& p : l) p.t -= 0.5 * pitch;
  std::vector<std::vector<Cyl>> hubm = {bs.hub}, casm = {bs.casing};
  fit_axially(hubm, x_in - margin, x_out + margin);
  fit_axially(casm, x_in - margin, x_out + margin);

  double tmin = 1e300, tmax = -1e300;
  for (auto& l : mean)
    for (auto& p : l) tmin = std::min(tmin, p.t), tmax = std::max(tmax, p.t + pitch);
  for (auto& l : loops)
    for (auto& p : l) tmin = std::min(tmin, p.t), tmax = std::max(tmax, p.t);
  const double ta = tmin - 0.2, tb = tmax + 0.2;
  if (tb - ta >= 2 * M_PI - 1e-3)
    throw StageError("blade_sector: the passage (mean lines plus one pitch) turns by more than a full revolution about the axis; "
                     "check `blades` and the file's angles");

  cad::occt::Log log([&](const std::string& s) { ctx.log(s); });
  ctx.progress(0.1, "blade surface");
  TopoDS_Shape fluid;
  std::vector<Tag> tags;
  double section_err = 0;
  int nfaces_by_source[7] = {0, 0, 0, 0, 0, 0, 0};
  try {
    std::vector<std::vector<gp_Pnt>> rows;
    for (auto& l : loops) {
      rows.emplace_back();
      for (auto& p : l) rows.back().push_back(cart(p));
    }
    std::vector<double> bu, bv, pu, pv;
    Handle(Geom_BSplineSurface) blade = skin(rows, true, tol, bu, bv);
    for (size_t k = 1; k + 1 < rows.size(); ++k)
      for (size_t i = 0; i < rows[k].size(); ++i)
        section_err = std::max(section_err, blade->Value(bu[i], bv[k]).Distance(rows[k][i]));
    rows.clear();
    for (auto& l : mean) {
      rows.emplace_back();
      for (auto& p : l) rows.back().push_back(cart(p));
    }
    ctx.progress(0.25, "periodic surfaces");
    Handle(Geom_BSplineSurface) plo = skin(rows, false, tol, pu, pv);
    gp_Trsf rot;
    rot.SetRotation(gp_Ax1(gp_Pnt(0, 0, 0), gp_Dir(1, 0, 0)), pitch);
    Handle(Geom_BSplineSurface) phi = Handle(Geom_BSplineSurface)::DownCast(plo->Transformed(rot));

    auto meridian = [&](const std::vector<Cyl>& m) {
      std::vector<gp_Pnt> p;
      for (auto& c : m) p.push_back(gp_Pnt(c.x, c.r, 0));
      return interp(p, chord_params({p}, false), false, tol);
    };
    Handle(Geom_SurfaceOfRevolution) hub = new Geom_SurfaceOfRevolution(meridian(hubm[0]), gp_Ax1(gp_Pnt(0, 0, 0), gp_Dir(1, 0, 0)));
    Handle(Geom_SurfaceOfRevolution) cas = new Geom_SurfaceOfRevolution(meridian(casm[0]), gp_Ax1(gp_Pnt(0, 0, 0), gp_Dir(1, 0, 0)));
    const double R = 1.5 * rmax;
    std::vector<TopoDS_Face> src(7);
    src[0] = BRepBuilderAPI_MakeFace(hub, ta, tb, 0, 1, tol);
    src[1] = BRepBuilderAPI_MakeFace(cas, ta, tb, 0, 1, tol);
    src[2] = BRepBuilderAPI_MakeFace(gp_Pln(gp_Pnt(x_in, 0, 0), gp_Dir(1, 0, 0)), -R, R, -R, R);
    src[3] = BRepBuilderAPI_MakeFace(gp_Pln(gp_Pnt(x_out, 0, 0), gp_Dir(1, 0, 0)), -R, R, -R, R);
    src[4] = BRepBuilderAPI_MakeFace(plo, Precision::Confusion());
    src[5] = BRepBuilderAPI_MakeFace(phi, Precision::Confusion());
    src[6] = BRepBuilderAPI_MakeFace(blade, Precision::Confusion());
    const Tag src_tag[7] = {Tag::wall, Tag::wall, Tag::farfield, Tag::farfield, Tag::periodic_lo, Tag::periodic_hi, Tag::wall};

    ctx.progress(0.35, "sector (boolean)");
    BOPAlgo_MakerVolume mv;
    TopTools_ListOfShape args;
    for (auto& f : src) args.Append(f);
    mv.SetArguments(args);
    mv.SetRunParallel(false);
    mv.SetIntersect(true);
    mv.Perform();
    if (mv.HasErrors())
      throw StageError("blade_sector: building the sector from hub, casing, planes, periodic and blade surfaces failed "
                       "(OCCT BOPAlgo_MakerVolume); check upstream/downstream and the section file");
    // the fluid: the solid bounded by the periodic faces
    Handle(BRepTools_History) hist = mv.History();
    auto source_of = [&](const TopoDS_Shape& f) {
      for (int s = 0; s < 7; ++s) {
        if (f.IsSame(src[s])) return s;
        for (TopTools_ListIteratorOfListOfShape it(hist->Modified(src[s])); it.More(); it.Next())
          if (it.Value().IsSame(f)) return s;
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
        if (chosen >= 0) throw StageError("blade_sector: more than one passage volume (internal error)");
        chosen = (int)i;
      }
    }
    if (chosen < 0)
      throw StageError("blade_sector: the periodic, hub, casing and inflow/outflow surfaces do not close a passage volume (" +
                       std::to_string(solids.size()) + " volume(s) found); check upstream/downstream and the section file");
    fluid = solids[chosen];
    for (size_t i = 0; i < solids.size(); ++i) {
      std::string d = "blade_sector: volume " + std::to_string(i) + " faces from:";
      for (TopExp_Explorer ex(solids[i], TopAbs_FACE); ex.More(); ex.Next()) d += " " + std::to_string(source_of(ex.Current()));
      ctx.log(d);
    }
    TopTools_IndexedMapOfShape faces;
    TopExp::MapShapes(fluid, TopAbs_FACE, faces);
    for (int i = 1; i <= faces.Extent(); ++i) {
      int s = source_of(faces(i));
      if (s < 0) throw StageError("blade_sector: a face of the passage has no known origin (internal error)");
      tags.push_back(src_tag[s]);
      nfaces_by_source[s]++;
    }
  } catch (const Standard_Failure& e) {
    throw StageError(std::string("blade_sector: OpenCASCADE failed building the sector (") + e.GetMessageString() +
                     "); check the section file and the parameters");
  }
  static const char* src_name[7] = {"hub", "casing", "inflow", "outflow", "periodic_lo", "periodic_hi", "blade"};
  for (int s = 0; s < 7; ++s)
    if (nfaces_by_source[s] == 0)
      throw StageError(std::string("blade_sector: the passage has no ") + src_name[s] + " face (faces per surface hub, casing, inflow, outflow, periodic_lo, periodic_hi, blade: " + std::to_string(nfaces_by_source[0]) + std::to_string(nfaces_by_source[1]) + std::to_string(nfaces_by_source[2]) + std::to_string(nfaces_by_source[3]) + std::to_string(nfaces_by_source[4]) + std::to_string(nfaces_by_source[5]) + std::to_string(nfaces_by_source[6]) + ")" +
                       " face: the surfaces do not bound the passage as expected; check upstream/downstream");
  ctx.progress(0.85, "checking");
  if (!BRepCheck_Analyzer(fluid).IsValid())
    throw StageError("blade_sector: the passage solid is not valid (BRepCheck); report it with the section file");
  cad::Shape shape = cad::occt::make_shape(fluid, units, tags);
  if (!shape.free_edges().empty() || !shape.multiple_edges().empty())
    throw StageError("blade_sector: the passage solid is not watertight; report it with the section file");
  cad::apply_tag_rules(shape, P.at("tag_overrides"), "blade_sector stage '" + ctx.stage_name() + "'");
  auto& st = ctx.stats();
  st = cad::occt::summarize(shape);
  st["format"] = bs.format;
  st["blades"] = N;
  st["sections"] = (int)ns;
  st["points_per_section"] = (int)bs.loops[0].size();
  st["blade_height"] = height;
  st["axial_chord"] = cax;
  st["inflow_x"] = x_in;
  st["outflow_x"] = x_out;
  st["section_points_max_error"] = section_err;
  nlohmann::json by = nlohmann::json::object();
  for (int s = 0; s < 7; ++s) by[src_name[s]] = nfaces_by_source[s];
  st["faces_by_surface"] = by;
  shape.save(ctx.output("shape", "shape"));
  ctx.progress(1.0, "done");
}

StageRegistrar reg({.kind = "blade_sector",
                    .version = 1,
                    .summary = "blade lofted through file sections (Rotor 67, CSV) on a hub in a 2pi/N periodic sector",
                    .libraries = {"OCCT " OCC_VERSION_COMPLETE},
                    .run = run});
}  // namespace
}  // namespace meshflow::geometry
