// meshflow geometry kind `naca_wing`: a NACA 4-digit wing with a rounded (revolved) or flat tip,
// root on the wall of a box far field — the paper's wing-tip case, the default demo geometry.
//
// Frame: x along the chord (flow direction), y normal to the chord plane, z along the span;
// the leading edge of the root section is at the origin, the root wall is the plane z = 0, and
// the incidence rotates the wing about the z axis (nose up).
//
// Symmetric profiles (00tt) are represented EXACTLY: with x = c s^2 the half-thickness
//   y_t = 5 t c (0.2969 s - 0.1260 s^2 - 0.3516 s^4 + 0.2843 s^6 - 0.1015 s^8)
// is a polynomial of degree 8 in s, so the profile (s in [-1,1], lower surface s < 0) is a
// degree-8 B-spline made of two Bezier pieces joined C1 at the leading edge. Cambered profiles
// (mptt) are interpolated (401 points, error reported in stats as profile_max_error).
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
#include <BRepPrimAPI_MakeBox.hxx>
#include <BRepPrimAPI_MakePrism.hxx>
#include <BRepPrimAPI_MakeRevol.hxx>
#include <GeomAPI_Interpolate.hxx>
#include <GeomAPI_ProjectPointOnCurve.hxx>
#include <Geom_BSplineCurve.hxx>
#include <Geom_TrimmedCurve.hxx>
#include <ShapeUpgrade_UnifySameDomain.hxx>
#include <Standard_Failure.hxx>
#include <Standard_Version.hxx>
#include <TColStd_Array1OfInteger.hxx>
#include <TColStd_Array1OfReal.hxx>
#include <TColStd_HArray1OfReal.hxx>
#include <TColgp_Array1OfPnt.hxx>
#include <TColgp_HArray1OfPnt.hxx>
#include <TopExp_Explorer.hxx>
#include <TopoDS.hxx>
#include <gp_Ax1.hxx>
#include <gp_Trsf.hxx>

#include <array>
#include <cmath>
#include <string>
#include <vector>

namespace meshflow::geometry {
namespace {

using naca::Naca4;

TopoDS_Shape moved(const TopoDS_Shape& s, const gp_Trsf& t) { return BRepBuilderAPI_Transform(s, t, Standard_True).Shape(); }

void run(StageContext& ctx) {
  const auto& P = ctx.params();
  std::string prof = P.at("profile").get<std::string>();
  double c = P.at("chord").get<double>();
  double span = P.at("span").get<double>();
  double inc = P.at("incidence_deg").get<double>() * M_PI / 180.0;
  bool sharp = P.at("trailing_edge").get<std::string>() == "sharp";
  bool round = P.at("tip").get<std::string>() == "round";
  double ff = P.at("farfield_chords").get<double>(), wake = P.at("wake_chords").get<double>();
  std::string units = P.at("units").get<std::string>();

  Naca4 n = naca::parse(prof, sharp, "naca_wing");
  if (round && n.m > 0)
    throw StageError("naca_wing: a round tip is the profile revolved about its chord line, which closes only a "
                     "symmetric profile; profile \"" + prof + "\" is cambered: use tip: flat or a 00xx profile");

  cad::occt::Log log([&](const std::string& s) { ctx.log(s); });
  ctx.progress(0.05, "profile");
  double max_err = 0;
  Handle(Geom_BSplineCurve) C = n.m == 0 ? naca::symmetric_profile(n, c) : naca::interpolated_profile(n, c, max_err, "naca_wing");
  double ymax = 0;  // largest half thickness (radius of the round tip), chord units
  for (int i = 0; i <= 200000; ++i) ymax = std::max(ymax, n.yt(i / 200000.0));
  double tip_ext = round ? ymax * c : 0.0;
  double zs = span - tip_ext;  // end of the straight part
  if (zs <= 0.05 * c)
    throw StageError("naca_wing: span " + std::to_string(span) + " is too short for the round tip (which adds " +
                     std::to_string(tip_ext) + "): make the span larger than " + std::to_string(tip_ext + 0.05 * c));
  const double z0 = -0.1 * c;  // the wing starts below the wall, so the cut is not coplanar

  TopoDS_Shape fluid;
  try {
    gp_Pnt te_lo = C->Value(-1), te_up = C->Value(1);
    BRepBuilderAPI_MakeWire mw;
    for (auto& piece : naca::profile_pieces(C, sharp)) mw.Add(BRepBuilderAPI_MakeEdge(piece));
    if (!sharp) mw.Add(BRepBuilderAPI_MakeEdge(te_up, te_lo));
    TopoDS_Face section = BRepBuilderAPI_MakeFace(mw.Wire(), Standard_True);
    gp_Trsf down;
    down.SetTranslation(gp_Vec(0, 0, z0));
    TopoDS_Shape wing = BRepPrimAPI_MakePrism(moved(section, down), gp_Vec(0, 0, zs - z0)).Shape();
    ctx.progress(0.2, "tip");
    if (round) {
      Handle(Geom_BSplineCurve) U = Handle(Geom_BSplineCurve)::DownCast(C->Copy());
      U->Segment(0, 1);
      BRepBuilderAPI_MakeWire hw;
      gp_Pnt le(0, 0, 0), te_mid(C->Value(1).X(), 0, 0);
      hw.Add(BRepBuilderAPI_MakeEdge(U));
      if (!sharp) hw.Add(BRepBuilderAPI_MakeEdge(te_up, te_mid));
      hw.Add(BRepBuilderAPI_MakeEdge(te_mid, le));
      TopoDS_Face half = BRepBuilderAPI_MakeFace(hw.Wire(), Standard_True);
      gp_Trsf up;
      up.SetTranslation(gp_Vec(0, 0, zs));
      TopoDS_Shape tip =
          BRepPrimAPI_MakeRevol(moved(half, up), gp_Ax1(gp_Pnt(0, 0, zs), gp_Dir(1, 0, 0)), M_PI).Shape();
      BRepAlgoAPI_Fuse fu(wing, tip);
      if (!fu.IsDone() || fu.HasErrors()) throw StageError("naca_wing: fusing the round tip to the wing failed");
      ShapeUpgrade_UnifySameDomain un(fu.Shape(), Standard_True, Standard_True, Standard_False);
      un.Build();
      wing = un.Shape();
    }
    gp_Trsf rot;
    rot.SetRotation(gp_Ax1(gp_Pnt(0, 0, 0), gp_Dir(0, 0, 1)), -inc);
    wing = moved(wing, rot);
    ctx.progress(0.5, "far field");
    gp_Pnt lo(-ff * c, -ff * c, 0), hi(c + wake * c, ff * c, span + ff * c);
    TopoDS_Shape box = BRepPrimAPI_MakeBox(lo, hi).Shape();
    BRepAlgoAPI_Cut cut(box, wing);
    if (!cut.IsDone() || cut.HasErrors()) throw StageError("naca_wing: cutting the wing from the far-field box failed");
    ShapeUpgrade_UnifySameDomain un(cut.Shape(), Standard_True, Standard_True, Standard_False);
    un.Build();
    fluid = un.Shape();
    TopExp_Explorer ex(fluid, TopAbs_SOLID);
    if (!ex.More()) throw StageError("naca_wing: the far-field cut produced no solid");
    fluid = ex.Current();
    ex.Next();
    if (ex.More()) throw StageError("naca_wing: the far-field cut produced more than one solid");
  } catch (const Standard_Failure& e) {
    throw StageError(std::string("naca_wing: OpenCASCADE failed building the wing (") + e.GetMessageString() +
                     "); check chord, span and far-field sizes");
  }
  ctx.progress(0.8, "checking");
  BRepCheck_Analyzer chk(fluid);
  if (!chk.IsValid())
    throw StageError("naca_wing: the generated fluid solid is not valid for profile \"" + prof +
                     "\"; try other span/far-field parameters (and report it: this is a bug)");
  auto tags = cad::occt::tags_by_box(fluid, 1e-6 * c);
  cad::Shape shape = cad::occt::make_shape(fluid, units, tags);
  cad::apply_tag_rules(shape, P.at("tag_overrides"), "naca_wing stage '" + ctx.stage_name() + "'");
  auto& st = ctx.stats();
  st = cad::occt::summarize(shape);
  st["profile_exact"] = n.m == 0;
  st["profile_max_error"] = max_err;
  st["tip_radius"] = tip_ext;
  shape.save(ctx.output("shape", "shape"));
  ctx.progress(1.0, "done");
}

StageRegistrar reg({.kind = "naca_wing",
                    .version = 2,  // 2: a sharp trailing edge is an edge between lower and upper faces
                    .summary = "NACA 4-digit wing with round tip, root on the wall of a box far field",
                    .libraries = {"OCCT " OCC_VERSION_COMPLETE},
                    .produces = {{"shape", "shape"}},
                    .run = run});
}  // namespace
}  // namespace meshflow::geometry
