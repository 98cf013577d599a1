// The curve stage on small meshes built in the tests (builders.hpp) on OCCT shapes
// (shapes.cpp): a sphere (poles, seam) and a cylinder (seam, circles, planes) in a shell of
// fluid, each with one thin layer of prisms on the wall and tets outside.
#include <doctest/doctest.h>

#include "builders.hpp"
#include "engine/stage.hpp"
#include "stages/curve/curve.hpp"
#include "stages/io/mesh_io.hpp"
#include "stages/model/basis.hpp"
#include "stages/model/quality.hpp"
#include "stages/model/topology.hpp"

#include <nlohmann/json.hpp>

#include <cmath>
#include <fstream>
#include <iostream>
#include <sstream>

using namespace curvetest;
namespace mc = meshflow::curve;
namespace model = meshflow::model;

namespace {

struct Case {
  meshflow::cad::Shape shape;
  Built built;
};
Case sphere_case(int na = 16, int nb = 8, double thickness = 0.05) {
  Case c{sphere_shell(1.0, 3.0), {}};
  c.built = build(c.shape, sphere_grid(na, nb, 1.0, thickness, 3.0, 3));
  return c;
}
Case cylinder_case(int na = 16, int nb = 3, double thickness = 0.05) {
  Case c{cylinder_shell(1.0, 3.0, 1.0), {}};
  c.built = build(c.shape, cylinder_grid(na, nb, 1.0, thickness, 3.0, 1.0, 3));
  return c;
}

model::Mesh curve(const Case& c, int P, mc::Report& r, bool follow = true, int threads = 1) {
  mc::Options o;
  o.order = P;
  o.follow_wall = follow;
  o.threads = threads;
  return mc::curve_mesh(c.built.mesh, c.shape, o, r);
}

}  // namespace

TEST_CASE("curve: sphere and cylinder, P = 2..6: nodes on the CAD, every element valid, conforming") {
  for (int which = 0; which < 2; ++which) {
    Case c = which == 0 ? sphere_case() : cylinder_case();
    for (int P = 2; P <= 6; ++P) {
      INFO(std::string(which == 0 ? "sphere" : "cylinder") << " P=" << P);
      mc::Report r;
      auto m = curve(c, P, r);
      CHECK(m.order() == P);
      CHECK(r.invalid_linear == 0);
      CHECK(r.invalid == 0);
      CHECK(r.max_distance_curve < 1e-7);
      CHECK(r.max_distance_surface < 1e-7);
      CHECK(r.fallback_projections == 0);
      CHECK(r.nodes_on_surfaces > 0);
      CHECK(model::build_topology(m).nonconforming_faces == 0);
      if (which == 1) CHECK(r.nodes_on_curves > 0);
      if (which == 0) CHECK(r.pole_ends > 0);
      CHECK(r.seam_choices > 0);
      MESSAGE(r.to_json().dump());
    }
  }
}
