// meshflow geometry kind `wing_body`: a half model of a transport aircraft — a body of
// revolution with a swept, tapered NACA 4-digit wing meeting it in a real junction curve — cut
// by the symmetry plane and placed in a box far field. The defaults resemble the NASA Common
// Research Model (CRM) wing-body: the paper's CRM case (Marcon et al. 2018, §V.B).
//
// Frame: x along the body axis (flow direction), the nose tip at the origin; y spanwise, the
// half model is y >= 0 and the symmetry plane is y = 0; z up. The body axis is the x axis.
//
// Body (a half solid of revolution: the meridian in the plane y = 0, z <= 0, revolved by π about
// x through y > 0, so that its meridian edges on the symmetry plane are the exact profile curves):
//   nose     x in [0, Ln]: ellipsoid r = R sqrt(1 - ((Ln-x)/Ln)^2) (a rational quadratic
//            Bezier, exact) or tangent ogive (circular arc of radius (R^2+Ln^2)/(2R));
//   cylinder x in [Ln, Ln+Lc]: r = R;
//   tail     x in [xt, L], xt = Ln+Lc, L = xt+Lt: r = R - (R-rt)(3ξ^2 - 2ξ^3), ξ = (x-xt)/Lt
//            (a cubic Bezier with x linear in its parameter, so this formula is exact): the
//            tail joins the cylinder and ends with zero slope;
//   base     the flat disc x = L, r <= rt.
// Wing: streamwise sections (planes y = const) of the NACA profile, scaled by the local chord
// c(y) = c0 (1 - (1-λ) y / yt), rotated nose up by the incidence about the spanwise axis through
// the section's leading edge, and placed with its leading edge at
//   x_le(y) = wing_x + y tan(Λ) + 0.25 cos(α) (c0 - c(y))   (Λ: sweep of the quarter-chord line)
//   z_le(y) = wing_z + y tan(Γ)                             (Γ: dihedral)
// c0 is the chord at the symmetry plane y = 0 (the "theoretical root" inside the body), yt the
// span station of the tip section. Since x_le, z_le and c are linear in y and the incidence is
// constant (no twist), the wing surface is EXACTLY the ruled surface between the root (y = 0)
// and tip sections (BRepOffsetAPI_ThruSections, ruled): every streamwise section is the
// transformed 4-digit profile (exact for 00tt profiles, see naca4.hpp; a sharp trailing edge
// is an edge between the lower and upper faces, a blunt one a planar face). The tip is flat (the
// tip section) or round (the upper half of the tip section revolved about its chord line into
// y > yt, symmetric profiles only); `semispan` is the distance from the symmetry plane to the
// tip extremity, round tip included.
// Because the root section at y = 0 lies inside the body (checked), the wing pierces the body
// and BRepAlgoAPI_Fuse gives one closed junction curve on the body (checked after the fuse:
// the edges shared by a wing face and a body face form exactly one closed loop).
// Far field: the box x in [-f L, L + w L], y in [0, f L], z in [-f L, f L] (f =
// farfield_lengths, w = wake_lengths); the result is the FLUID solid box − (body ∪ wing).
// Tags: body and wing faces `wall`, the box face y = 0 `symmetry` (it touches the body), the
// other box faces `farfield` (cad::occt::tags_by_box), then the workflow's tag_overrides.
// Refused with a StageError: a cambered profile with a round tip, a tail radius not smaller
// than the body radius, a root section (y = 0) not inside the body (the wing would not meet the
// body in one closed curve), a tip section not outside the body (the wing does not reach out of
// it), any part of the model closer than 0.1 L to the box (span, height or length too large for
// the far field), and a junction that is not one closed loop.
#include "engine/stage.hpp"
#include "stages/cad/cad.hpp"
#include "stages/cad/occt.hpp"
#include "stages/cad/tag_rules.hpp"
#include "stages/geometry/naca4.hpp"

#include <nlohmann/json.hpp>

#include <BRepAlgoAPI_Cut.hxx>
#include <BRepAlgoAPI_Fuse.hxx>
#include <BRepBuilderAPI_MakeEdge.hxx>
#include <BRepBuilderAPI_MakeFace.hxx>
#include <BRepBuilderAPI_MakeWire.hxx>
#include <BRepBuilderAPI_Transform.hxx>
#include <BRepCheck_Analyzer.hxx>
#include <BRepGProp.hxx>
#include <GProp_GProps.hxx>
#include <BRepOffsetAPI_ThruSections.hxx>
#include <BRepPrimAPI_MakeBox.hxx>
#include <BRepPrimAPI_MakeRevol.hxx>
#include <GC_MakeArcOfCircle.hxx>
#include <Geom_BSplineCurve.hxx>
#include <Geom_BezierCurve.hxx>
#include <ShapeUpgrade_UnifySameDomain.hxx>
#include <Standard_Failure.hxx>
#include <Standard_Version.hxx>
#include <TColStd_Array1OfReal.hxx>
#include <TColgp_Array1OfPnt.hxx>
#include <TopExp_Explorer.hxx>
#include <TopoDS.hxx>
#include <gp_Ax1.hxx>
#include <gp_Trsf.hxx>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <map>
#include <string>
#include <vector>

namespace meshflow::geometry {
namespace {

using naca::Naca4;

std::string num(double v) {
  char b[32];
  std::snprintf(b, sizeof b, "%.6g", v);
  return b;
}

struct Body {
  bool ogive = false;
  double R = 3, Ln = 10, Lc = 30, Lt = 22, rt = 0.5;
  double xt() const { return Ln + Lc; }
  double L() const { return Ln + Lc + Lt; }
  // Radius of the body at station x (0 outside [0, L]).
  double r(double x) const {
    if (x < 0 || x > L()) return 0;
    if (x < Ln) {
      double d = Ln - x;
      if (!ogive) return R * std::sqrt(std::max(0.0, 1 - (d / Ln) * (d / Ln)));
      double rho = (R * R + Ln * Ln) / (2 * R);
      return std::sqrt(std::max(0.0, rho * rho - d * d)) + R - rho;
    }
    if (x <= xt()) return R;
    double s = (x - xt()) / Lt;
    return R - (R - rt) * (3 * s * s - 2 * s * s * s);
  }
  // Distance-like measure of p from the body surface (exact on the surface: 0).
  double off_surface(const gp_Pnt& p) const {
    double rr = std::hypot(p.Y(), p.Z());
    double side = (p.X() >= -1e-12 && p.X() <= L() + 1e-12) ? std::abs(rr - r(std::clamp(p.X(), 0.0, L()))) : 1e300;
    double base = rr <= rt * (1 + 1e-9) ? std::abs(p.X() - L()) : 1e300;
    return std::min(side, base);
  }
};

// The wing planform: a section at span station y (0 <= y <= yt).
struct Wing {
  double c0 = 10, lambda = 0.3, yt = 29, sweep = 0, dihedral = 0, alpha = 0, x0 = 20, z0 = 0;
  double chord(double y) const { return c0 * (1 - (1 - lambda) * y / yt); }
  double x_le(double y) const { return x0 + y * std::tan(sweep) + 0.25 * std::cos(alpha) * (c0 - chord(y)); }
  double z_le(double y) const { return z0 + y * std::tan(dihedral); }
  // Profile plane (x chord, y thickness, chord 1) -> the section at y: a similarity.
  gp_Trsf section(double y) const {
    double c = chord(y), ca = std::cos(alpha), sa = std::sin(alpha);
    gp_Trsf t;
    t.SetValues(c * ca, c * sa, 0, x_le(y),  //
                0, 0, -c, y,                 //
                -c * sa, c * ca, 0, z_le(y));
    return t;
  }
  // Point of the section at y of profile point (px, py) (chord-1 profile coordinates).
  gp_Pnt at(double y, double px, double py) const { return gp_Pnt(px, py, 0).Transformed(section(y)); }
};

TopoDS_Shape moved(const TopoDS_Shape& s, const gp_Trsf& t) { return BRepBuilderAPI_Transform(s, t, Standard_True).Shape(); }

TopoDS_Shape unified(const TopoDS_Shape& s) {
  ShapeUpgrade_UnifySameDomain un(s, Standard_True, Standard_True, Standard_False);
  un.Build();
  return un.Shape();
}

TopoDS_Shape single_solid(const TopoDS_Shape& s, const std::string& what) {
  TopExp_Explorer ex(s, TopAbs_SOLID);
  if (!ex.More()) throw StageError("wing_body: " + what + " produced no solid");
  TopoDS_Shape so = ex.Current();
  ex.Next();
  if (ex.More()) throw StageError("wing_body: " + what + " produced more than one solid");
  return so;
}

// The half body of revolution (y >= 0): the meridian in the plane y = 0 at z <= 0 revolved by π
// about +x (through y > 0 to z >= 0). Its meridian edges on the symmetry plane are the exact
// profile curves and their p-curves exact iso-lines (u = 0, π) of the revolution surfaces;
// the two flat meridian faces (y = 0) are merged into one.
TopoDS_Shape make_body(const Body& b) {
  const double R = b.R, Ln = b.Ln, xt = b.xt(), L = b.L(), rt = b.rt;
  BRepBuilderAPI_MakeWire w;
  // meridian from the nose tip to the base centre, r = -z
  if (!b.ogive) {
    TColgp_Array1OfPnt p(1, 3);
    p(1) = gp_Pnt(0, 0, 0);
    p(2) = gp_Pnt(0, 0, -R);
    p(3) = gp_Pnt(Ln, 0, -R);
    TColStd_Array1OfReal wt(1, 3);
    wt(1) = 1;
    wt(2) = std::sqrt(0.5);
    wt(3) = 1;
    w.Add(BRepBuilderAPI_MakeEdge(Handle(Geom_BezierCurve)(new Geom_BezierCurve(p, wt))).Edge());
  } else {
    GC_MakeArcOfCircle arc(gp_Pnt(Ln, 0, -R), gp_Vec(-1, 0, 0), gp_Pnt(0, 0, 0));
    if (!arc.IsDone()) throw StageError("wing_body: building the ogive nose arc failed");
    w.Add(BRepBuilderAPI_MakeEdge(arc.Value()).Edge());
  }
  w.Add(BRepBuilderAPI_MakeEdge(gp_Pnt(Ln, 0, -R), gp_Pnt(xt, 0, -R)).Edge());
  {
    TColgp_Array1OfPnt p(1, 4);
    p(1) = gp_Pnt(xt, 0, -R);
    p(2) = gp_Pnt(xt + b.Lt / 3, 0, -R);
    p(3) = gp_Pnt(xt + 2 * b.Lt / 3, 0, -rt);
    p(4) = gp_Pnt(L, 0, -rt);
    w.Add(BRepBuilderAPI_MakeEdge(Handle(Geom_BezierCurve)(new Geom_BezierCurve(p))).Edge());
  }
  w.Add(BRepBuilderAPI_MakeEdge(gp_Pnt(L, 0, -rt), gp_Pnt(L, 0, 0)).Edge());
  w.Add(BRepBuilderAPI_MakeEdge(gp_Pnt(L, 0, 0), gp_Pnt(0, 0, 0)).Edge());
  if (!w.IsDone()) throw StageError("wing_body: the body meridian does not close");
  TopoDS_Face f = BRepBuilderAPI_MakeFace(w.Wire(), Standard_True);
  BRepPrimAPI_MakeRevol rv(f, gp_Ax1(gp_Pnt(0, 0, 0), gp_Dir(1, 0, 0)), M_PI);
  if (!rv.IsDone()) throw StageError("wing_body: revolving the body meridian failed");
  return single_solid(unified(rv.Shape()), "revolving the body meridian");
}

// Volume by adaptive integration (the default fixed-order rule is ~0.5% off on the wing).
double volume(const TopoDS_Shape& s) {
  GProp_GProps g;
  BRepGProp::VolumeProperties(s, g, 1e-9);
  return g.Mass();
}

TopoDS_Wire section_wire(const Handle(Geom_BSplineCurve)& C, bool sharp, const gp_Trsf& t) {
  Handle(Geom_BSplineCurve) c = Handle(Geom_BSplineCurve)::DownCast(C->Transformed(t));
  BRepBuilderAPI_MakeWire mw;
  for (auto& piece : naca::profile_pieces(c, sharp)) mw.Add(BRepBuilderAPI_MakeEdge(piece).Edge());
  if (!sharp) mw.Add(BRepBuilderAPI_MakeEdge(c->Value(c->LastParameter()), c->Value(c->FirstParameter())).Edge());
  return mw.Wire();
}

// The wing solid from y = 0 (inside the body) to the tip.
TopoDS_Shape make_wing(const Wing& w, const Handle(Geom_BSplineCurve)& C, bool sharp, bool round) {
  BRepOffsetAPI_ThruSections ts(Standard_True, Standard_True, 1e-7 * w.c0);
  ts.CheckCompatibility(Standard_False);
  ts.AddWire(section_wire(C, sharp, w.section(0)));
  ts.AddWire(section_wire(C, sharp, w.section(w.yt)));
  ts.Build();
  if (!ts.IsDone()) throw StageError("wing_body: lofting the wing between its root and tip sections failed");
  TopoDS_Shape wing = single_solid(ts.Shape(), "lofting the wing");
  if (!round) return wing;
  // round tip: the upper half of the tip section revolved about its chord line into y > yt
  Handle(Geom_BSplineCurve) U = Handle(Geom_BSplineCurve)::DownCast(C->Copy());
  U->Segment(0, 1);
  gp_Pnt le(0, 0, 0), te_up = C->Value(1), te_mid(C->Value(1).X(), 0, 0);
  BRepBuilderAPI_MakeWire hw;
  hw.Add(BRepBuilderAPI_MakeEdge(U).Edge());
  if (!sharp) hw.Add(BRepBuilderAPI_MakeEdge(te_up, te_mid).Edge());
  hw.Add(BRepBuilderAPI_MakeEdge(te_mid, le).Edge());
  TopoDS_Face half = BRepBuilderAPI_MakeFace(hw.Wire(), Standard_True);
  gp_Trsf t = w.section(w.yt);
  gp_Pnt a = le.Transformed(t);
  gp_Dir d = gp_Vec(a, gp_Pnt(1, 0, 0).Transformed(t));  // along the chord
  // rotating the upper side (+z) about -d turns it towards +y (outboard)
  TopoDS_Shape tip = BRepPrimAPI_MakeRevol(moved(half, t), gp_Ax1(a, d.Reversed()), M_PI).Shape();
  BRepAlgoAPI_Fuse fu(wing, tip);
  if (!fu.IsDone() || fu.HasErrors()) throw StageError("wing_body: fusing the round tip to the wing failed");
  return single_solid(unified(fu.Shape()), "fusing the round tip");
}

void run(StageContext& ctx) {
  const auto& P = ctx.params();
  const std::string who = "wing_body stage '" + ctx.stage_name() + "'";
  std::string prof = P.at("profile").get<std::string>();
  bool sharp = P.at("trailing_edge").get<std::string>() == "sharp";
  bool round = P.at("tip").get<std::string>() == "round";
  Body b;
  b.ogive = P.at("nose").get<std::string>() == "ogive";
  b.R = P.at("body_radius").get<double>();
  b.Ln = P.at("nose_length").get<double>();
  b.Lc = P.at("cylinder_length").get<double>();
  b.Lt = P.at("tail_length").get<double>();
  b.rt = P.at("tail_radius").get<double>();
  const double L = b.L();
  Wing w;
  w.c0 = P.at("root_chord").get<double>();
  w.lambda = P.at("taper_ratio").get<double>();
  const double semispan = P.at("semispan").get<double>();
  w.sweep = P.at("sweep_deg").get<double>() * M_PI / 180;
  w.dihedral = P.at("dihedral_deg").get<double>() * M_PI / 180;
  w.alpha = P.at("incidence_deg").get<double>() * M_PI / 180;
  w.x0 = P.at("wing_x").get<double>();
  w.z0 = P.at("wing_z").get<double>();
  const double ff = P.at("farfield_lengths").get<double>(), wake = P.at("wake_lengths").get<double>();
  const std::string units = P.at("units").get<std::string>();

  Naca4 n = naca::parse(prof, sharp, who);
  if (round && n.m > 0)
    throw StageError(who + ": a round tip is the profile revolved about its chord line, which closes only a "
                     "symmetric profile; profile \"" + prof + "\" is cambered: use tip: flat or a 00xx profile");
  if (b.rt >= b.R)
    throw StageError(who + ": tail_radius " + num(b.rt) + " must be smaller than body_radius " + num(b.R) +
                     " (the tail tapers the body down to its base)");
  double ymax = 0;  // largest half thickness, chord 1 (the round tip's radius / tip chord)
  for (int i = 0; i <= 200000; ++i) ymax = std::max(ymax, n.yt(i / 200000.0));
  // the round tip reaches ymax * c_tip beyond the tip section, c_tip = lambda c0
  double tip_ext = round ? ymax * w.lambda * w.c0 : 0.0;
  w.yt = semispan - tip_ext;
  if (w.yt <= 0.05 * semispan)
    throw StageError(who + ": semispan " + num(semispan) + " is too short for the round tip (which adds " +
                     num(tip_ext) + ")");

  // Sample points of a section (chord-1 profile coordinates), to check placement.
  std::vector<std::array<double, 2>> prof_pts;
  for (int i = 0; i <= 400; ++i) prof_pts.push_back(n.point(-1 + 2.0 * i / 400));
  // 1. the root section (y = 0) inside the body, with a margin
  for (auto& q : prof_pts) {
    gp_Pnt p = w.at(0, q[0], q[1]);
    double r = b.r(p.X());
    if (std::abs(p.Z()) > r - 1e-3 * b.R)
      throw StageError(who + ": the wing does not reach into the body: its root section at the symmetry plane y = 0 "
                       "must lie inside the body (so that the wing meets the body in one closed junction curve), but "
                       "its point (x " + num(p.X()) + ", z " + num(p.Z()) + ") is outside (body radius there " +
                       num(r) + "). Move wing_z towards the axis, wing_x onto the body, or reduce root_chord or "
                       "incidence_deg");
  }
  // 2. the tip section outside the body
  for (auto& q : prof_pts) {
    gp_Pnt p = w.at(w.yt, q[0], q[1]);
    double r = b.r(p.X());
    if (std::hypot(p.Y(), p.Z()) < r + 1e-3 * b.R)
      throw StageError(who + ": the wing does not reach out of the body: its tip section at y = " + num(w.yt) +
                       " has the point (x " + num(p.X()) + ", z " + num(p.Z()) + ") inside or on the body (radius " +
                       num(r) + " there). Make semispan larger than body_radius (" + num(b.R) + ") with a margin");
  }
  // 3. the far field box and the clearance of the model to it
  const gp_Pnt lo(-ff * L, 0, -ff * L), hi(L + wake * L, ff * L, ff * L);
  {
    double wx0 = 0, wx1 = L, wy1 = b.R, wz0 = -b.R, wz1 = b.R;  // body
    for (double y : {0.0, w.yt})
      for (auto& q : prof_pts) {
        gp_Pnt p = w.at(y, q[0], q[1]);
        wx0 = std::min(wx0, p.X());
        wx1 = std::max(wx1, p.X());
        wz0 = std::min(wz0, p.Z() - (y > 0 ? tip_ext : 0));
        wz1 = std::max(wz1, p.Z() + (y > 0 ? tip_ext : 0));
      }
    wy1 = std::max(wy1, semispan);
    const double gap = 0.1 * L;
    if (wy1 + gap > hi.Y())
      throw StageError(who + ": semispan " + num(semispan) + " is too long for the far-field box, which reaches y = " +
                       num(hi.Y()) + " (farfield_lengths " + num(ff) + " x body length " + num(L) +
                       "); the tip must stay 0.1 body lengths inside: raise farfield_lengths to at least " +
                       num((wy1 + gap) / L) + " or shorten the span");
    if (wz0 - gap < lo.Z() || wz1 + gap > hi.Z())
      throw StageError(who + ": the wing reaches z = " + num(wz0 < -wz1 ? wz0 : wz1) +
                       " (dihedral and span), closer than 0.1 body lengths to the far-field box at z = +-" + num(hi.Z()) +
                       ": raise farfield_lengths or reduce dihedral_deg");
    if (wx0 - gap < lo.X() || wx1 + gap > hi.X())
      throw StageError(who + ": the wing reaches x from " + num(wx0) + " to " + num(wx1) +
                       ", closer than 0.1 body lengths to the far-field box (x from " + num(lo.X()) + " to " +
                       num(hi.X()) + "): raise farfield_lengths/wake_lengths or reduce the sweep");
  }

  cad::occt::Log log([&](const std::string& s) { ctx.log(s); });
  ctx.progress(0.05, "profile");
  double max_err = 0;
  Handle(Geom_BSplineCurve) C = n.m == 0 ? naca::symmetric_profile(n, 1.0) : naca::interpolated_profile(n, 1.0, max_err, who);

  TopoDS_Shape fluid;
  double body_volume = 0, wing_volume = 0;
  try {
    ctx.progress(0.1, "body");
    TopoDS_Shape body = make_body(b);
    ctx.progress(0.2, "wing");
    TopoDS_Shape wing = make_wing(w, C, sharp, round);
    body_volume = volume(body);
    wing_volume = volume(wing);
    ctx.progress(0.35, "wing-body junction");
    BRepAlgoAPI_Fuse fu(body, wing);
    if (!fu.IsDone() || fu.HasErrors()) throw StageError(who + ": fusing the wing with the body failed");
    TopoDS_Shape aircraft = single_solid(unified(fu.Shape()), "fusing the wing with the body");
    ctx.progress(0.55, "far field");
    TopoDS_Shape box = BRepPrimAPI_MakeBox(lo, hi).Shape();
    BRepAlgoAPI_Cut cut(box, aircraft);
    if (!cut.IsDone() || cut.HasErrors()) throw StageError(who + ": cutting the aircraft from the far-field box failed");
    fluid = single_solid(unified(cut.Shape()), "the far-field cut");
  } catch (const Standard_Failure& e) {
    throw StageError(who + ": OpenCASCADE failed building the wing-body (" + e.GetMessageString() +
                     "); check the body, wing and far-field parameters");
  }
  ctx.progress(0.8, "checking");
  BRepCheck_Analyzer chk(fluid);
  if (!chk.IsValid())
    throw StageError(who + ": the generated fluid solid is not valid (BRepCheck) for these parameters; try other "
                     "wing or body parameters (and report it: this is a bug)");
  auto tags = cad::occt::tags_by_box(fluid, 1e-6 * L);
  cad::Shape shape = cad::occt::make_shape(fluid, units, tags);

  // wall faces: body or wing (by the body formula at an interior point), and the junction
  std::vector<char> on_body(shape.num_faces(), 0);
  int nbody = 0, nwing = 0;
  for (int f = 0; f < shape.num_faces(); ++f) {
    if (shape.face_tag(f) != cad::Tag::wall) continue;
    gp_Pnt p = cad::occt::interior_point(shape.impl().face(f));
    on_body[f] = b.off_surface(p) < 1e-7 * L;
    (on_body[f] ? nbody : nwing)++;
  }
  std::vector<int> junction;
  double junction_length = 0;
  std::map<int, int> degree;
  for (int e = 0; e < shape.num_edges(); ++e) {
    auto fs = shape.edge_faces(e);
    if (fs.size() != 2 || shape.face_tag(fs[0]) != cad::Tag::wall || shape.face_tag(fs[1]) != cad::Tag::wall) continue;
    if (on_body[fs[0]] == on_body[fs[1]]) continue;
    junction.push_back(e);
    junction_length += shape.edge_length(e);
    for (int v : shape.edge_vertices(e)) degree[v] += 1;
  }
  // one closed loop: every vertex used twice, and the edges connected
  bool closed = !junction.empty();
  for (auto& [v, d] : degree) closed &= d == 2;
  if (closed) {
    std::vector<char> seen(junction.size(), 0);
    std::vector<int> stack = {0};
    seen[0] = 1;
    while (!stack.empty()) {
      int i = stack.back();
      stack.pop_back();
      auto vi = shape.edge_vertices(junction[i]);
      for (size_t j = 0; j < junction.size(); ++j) {
        if (seen[j]) continue;
        auto vj = shape.edge_vertices(junction[j]);
        if (vi[0] == vj[0] || vi[0] == vj[1] || vi[1] == vj[0] || vi[1] == vj[1]) seen[j] = 1, stack.push_back((int)j);
      }
    }
    closed = std::count(seen.begin(), seen.end(), 1) == (long)junction.size();
  }
  if (!closed)
    throw StageError(who + ": the wing meets the body in " + std::to_string(junction.size()) +
                     " edge(s) that do not form one closed junction curve (the wing re-enters the body or crosses its "
                     "nose or tail); move the wing (wing_x, wing_z) onto the cylindrical part or reduce dihedral_deg");
  cad::apply_tag_rules(shape, P.at("tag_overrides"), who);

  auto& st = ctx.stats();
  st = cad::occt::summarize(shape);
  st["profile_exact"] = n.m == 0;
  st["profile_max_error"] = max_err;
  st["tip_radius"] = tip_ext;
  st["body_length"] = L;
  st["body_volume"] = body_volume;  // the half body
  st["wing_volume"] = wing_volume;  // the whole lofted wing, its part inside the body included
  st["tip_chord"] = w.chord(w.yt);
  st["tip_section_y"] = w.yt;
  st["body_faces"] = nbody;
  st["wing_faces"] = nwing;
  st["junction"] = {{"edges", junction.size()}, {"length", junction_length}, {"loops", 1}};
  shape.save(ctx.output("shape", "shape"));
  ctx.progress(1.0, "done");
}

StageRegistrar reg({.kind = "wing_body",
                    .version = 1,
                    .summary = "half wing-body (body of revolution + swept tapered NACA wing) in a box far field",
                    .libraries = {"OCCT " OCC_VERSION_COMPLETE},
                    .produces = {{"shape", "shape"}},
                    .run = run});
}  // namespace
}  // namespace meshflow::geometry
