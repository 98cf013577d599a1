// OCCT-made bodies for the junction-width tests (see ledge_shapes.hpp); the only OCCT translation
// unit of these tests.
#include "ledge_shapes.hpp"

#include "stages/cad/occt.hpp"

#include <BRepAlgoAPI_Fuse.hxx>
#include <BRepPrimAPI_MakeBox.hxx>
#include <ShapeUpgrade_UnifySameDomain.hxx>
#include <gp_Pnt.hxx>

#include <stdexcept>

namespace sweeptest {

void write_ledge_body(const std::filesystem::path& file, double w, bool open_u) {
  TopoDS_Shape lower = BRepPrimAPI_MakeBox(gp_Pnt(0, 0, 0), gp_Pnt(4, 4, 1)).Shape();
  TopoDS_Shape upper = BRepPrimAPI_MakeBox(gp_Pnt(w, w, 1), gp_Pnt(4 - w, open_u ? 4 : 4 - w, 2)).Shape();
  BRepAlgoAPI_Fuse fuse(lower, upper);
  if (!fuse.IsDone()) throw std::runtime_error("write_ledge_body: the fuse failed");
  ShapeUpgrade_UnifySameDomain unify(fuse.Shape());
  unify.Build();
  meshflow::cad::occt::make_shape(unify.Shape(), "m").export_brep(file);
}

}  // namespace sweeptest
