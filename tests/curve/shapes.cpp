// OCCT-made shapes for the curve tests (the only test translation unit that includes OCCT):
// the fluid between two concentric spheres (poles and a seam on both) and between two coaxial
// cylinders cut by two planes (seams, circles, planar annuli).
#include "shapes.hpp"

#include "stages/cad/occt.hpp"

#include <BRepBuilderAPI_MakeFace.hxx>
#include <BRepAlgoAPI_Cut.hxx>
#include <Geom_CylindricalSurface.hxx>
#include <gp.hxx>
#include <gp_Ax3.hxx>
#include <BRepPrimAPI_MakeCylinder.hxx>
#include <BRepPrimAPI_MakeSphere.hxx>

namespace curvetest {

namespace {
// inner surface (extent ~ 2 r1) -> wall, planes -> symmetry, the rest -> farfield
meshflow::cad::Shape tagged(const TopoDS_Shape& s, double r1) {
  auto S = meshflow::cad::occt::make_shape(s, "m");
  for (int f = 0; f < S.num_faces(); ++f) {
    auto b = S.face_box(f);
    double ext = std::max(b.hi.x - b.lo.x, b.hi.y - b.lo.y);
    if (S.face_surface_type(f) == "plane") S.set_face_tag(f, meshflow::cad::Tag::symmetry);
    else if (ext < 2.0 * r1 * 1.01) S.set_face_tag(f, meshflow::cad::Tag::wall);
    else S.set_face_tag(f, meshflow::cad::Tag::farfield);
  }
  return S;
}
}  // namespace

meshflow::cad::Shape sphere_shell(double r1, double r2) {
  TopoDS_Shape outer = BRepPrimAPI_MakeSphere(r2).Shape();
  TopoDS_Shape inner = BRepPrimAPI_MakeSphere(r1).Shape();
  return tagged(BRepAlgoAPI_Cut(outer, inner).Shape(), r1);
}

meshflow::cad::Shape cylinder_shell(double r1, double r2, double h) {
  TopoDS_Shape outer = BRepPrimAPI_MakeCylinder(r2, h).Shape();
  TopoDS_Shape inner = BRepPrimAPI_MakeCylinder(r1, h).Shape();
  return tagged(BRepAlgoAPI_Cut(outer, inner).Shape(), r1);
}

meshflow::cad::Shape cylinder_sector_face(double r, double h, double a) {
  Handle(Geom_CylindricalSurface) cyl = new Geom_CylindricalSurface(gp_Ax3(gp::XOY()), r);
  TopoDS_Shape face = BRepBuilderAPI_MakeFace(cyl, -a, a, 0.0, h, 1e-9).Shape();
  auto S = meshflow::cad::occt::make_shape(face, "m");
  S.set_face_tag(0, meshflow::cad::Tag::wall);
  return S;
}

}  // namespace curvetest
