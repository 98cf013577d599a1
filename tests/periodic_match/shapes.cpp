// OCCT-made shapes for the periodic_match tests (see shapes.hpp).
#include "shapes.hpp"

#include "stages/cad/occt.hpp"

#include <BRepAlgoAPI_Cut.hxx>
#include <BRepBuilderAPI_Copy.hxx>
#include <BRepBuilderAPI_MakeFace.hxx>
#include <BRepBuilderAPI_MakePolygon.hxx>
#include <BRepBuilderAPI_Transform.hxx>
#include <BRepPrimAPI_MakeBox.hxx>
#include <BRepPrimAPI_MakeCylinder.hxx>
#include <BRepPrimAPI_MakeRevol.hxx>
#include <BRep_Builder.hxx>
#include <BRep_Tool.hxx>
#include <Geom_BSplineSurface.hxx>
#include <Geom_RectangularTrimmedSurface.hxx>
#include <TopoDS_Compound.hxx>
#include <TopoDS_Iterator.hxx>
#include <gp_Ax1.hxx>
#include <gp_Ax2.hxx>
#include <Standard_Failure.hxx>
#include <gp_Trsf.hxx>

#include <cmath>
#include <stdexcept>

namespace pmtest {
namespace occt = meshflow::cad::occt;
using meshflow::cad::Tag;

namespace {
std::vector<Tag> tags_of(const Shape& s) {
  std::vector<Tag> t;
  for (int f = 0; f < s.num_faces(); ++f) t.push_back(s.face_tag(f));
  return t;
}
}  // namespace

Shape box_with_hole(double L, bool through) {
  TopoDS_Shape box = BRepPrimAPI_MakeBox(L, 1.0, 1.0).Shape();
  double len = through ? L + 1.0 : L / 2 + 0.5;
  TopoDS_Shape cyl = BRepPrimAPI_MakeCylinder(gp_Ax2(gp_Pnt(-0.5, 0.5, 0.5), gp::DX()), 0.2, len).Shape();
  BRepAlgoAPI_Cut cut(box, cyl);
  if (!cut.IsDone()) throw std::runtime_error("box_with_hole: the cut failed");
  return occt::make_shape(cut.Shape(), "m");
}

Shape annulus_sectors(double x0, double x1, double r0, double r1, const std::vector<std::array<double, 2>>& ta) {
  TopoDS_Compound c;
  BRep_Builder b;
  b.MakeCompound(c);
  for (auto [t0, alpha] : ta) {
    auto P = [&](double x, double r) { return gp_Pnt(x, r * std::cos(t0), r * std::sin(t0)); };
    BRepBuilderAPI_MakePolygon poly(P(x0, r0), P(x1, r0), P(x1, r1), P(x0, r1), Standard_True);
    TopoDS_Face f = BRepBuilderAPI_MakeFace(poly.Wire(), Standard_True).Face();
    b.Add(c, BRepPrimAPI_MakeRevol(f, gp::OX(), alpha, Standard_True).Shape());
  }
  if (ta.size() == 1) {
    TopoDS_Iterator it(c);
    return occt::make_shape(it.Value(), "m");
  }
  return occt::make_shape(c, "m");
}

Shape moved(const Shape& s, std::array<double, 3> p, std::array<double, 3> d, double angle, std::array<double, 3> shift) {
  gp_Trsf r, t;
  r.SetRotation(gp_Ax1(gp_Pnt(p[0], p[1], p[2]), gp_Dir(d[0], d[1], d[2])), angle);
  t.SetTranslation(gp_Vec(shift[0], shift[1], shift[2]));
  TopoDS_Shape m = BRepBuilderAPI_Transform(occt::shape(s), t * r, Standard_True).Shape();
  return occt::make_shape(m, s.units(), tags_of(s));
}

Shape bulged(const Shape& s, int face, std::array<double, 3> delta) {
  // a deep copy (geometry included), so that `s` keeps its surface; the pole is then moved in
  // place: the edges' p-curves stay attached to the same surface object
  TopoDS_Shape copy = BRepBuilderAPI_Copy(occt::shape(s), Standard_True).Shape();
  Shape c = occt::make_shape(copy, s.units(), tags_of(s));
  const TopoDS_Face& F = c.impl().face(face);
  TopLoc_Location loc;
  Handle(Geom_Surface) g = BRep_Tool::Surface(F, loc);
  Handle(Geom_BSplineSurface) bs = Handle(Geom_BSplineSurface)::DownCast(g);
  if (bs.IsNull()) {
    auto tr = Handle(Geom_RectangularTrimmedSurface)::DownCast(g);
    if (!tr.IsNull()) bs = Handle(Geom_BSplineSurface)::DownCast(tr->BasisSurface());
  }
  if (bs.IsNull()) throw std::runtime_error("bulged: face " + std::to_string(face) + " is not a B-spline");
  int i = (bs->NbUPoles() + 1) / 2, j = (bs->NbVPoles() + 1) / 2;
  gp_Pnt p = bs->Pole(i, j);
  bs->SetPole(i, j, gp_Pnt(p.X() + delta[0], p.Y() + delta[1], p.Z() + delta[2]));
  try {
    Shape out = occt::make_shape(copy, s.units(), tags_of(s));
    out.box();
    return out;
  } catch (const Standard_Failure& e) {
    throw std::runtime_error(std::string("bulged: ") + e.DynamicType()->Name() + ": " + e.GetMessageString());
  }
}

}  // namespace pmtest
