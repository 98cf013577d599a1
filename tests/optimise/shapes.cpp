// Test shapes for the optimise tests, made with OpenCASCADE (this translation unit is the only
// one of tests/optimise that includes OCCT): a sphere and a cylinder saved as "shape" artifacts.
#include "builders.hpp"

#include "stages/cad/occt.hpp"

#include <BRepPrimAPI_MakeCylinder.hxx>
#include <BRepPrimAPI_MakeSphere.hxx>

namespace opttest {

void save_sphere(const std::filesystem::path& file, double R) {
  meshflow::cad::occt::make_shape(BRepPrimAPI_MakeSphere(R).Shape(), "m").save(file);
}

void save_cylinder(const std::filesystem::path& file, double R, double H) {
  meshflow::cad::occt::make_shape(BRepPrimAPI_MakeCylinder(R, H).Shape(), "m").save(file);
}

}  // namespace opttest
