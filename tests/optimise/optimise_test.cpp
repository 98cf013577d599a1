// The optimise algorithm (stages/optimise/optimise.hpp) on curved meshes built here on an
// OCCT sphere and cylinder with badly placed high-order nodes.
#include <doctest/doctest.h>

#include "builders.hpp"
#include "engine/stage.hpp"
#include "stages/io/mesh_io.hpp"
#include "stages/model/element.hpp"
#include "stages/model/quality.hpp"
#include "stages/model/topology.hpp"
#include "stages/optimise/optimise.hpp"

#include <nlohmann/json.hpp>

#include <atomic>
#include <cmath>
#include <fstream>
#include <sstream>
#include <unistd.h>

using meshflow::cad::Shape;
using meshflow::model::Mesh;
namespace model = meshflow::model;
namespace opt = meshflow::optimise;
namespace fs = std::filesystem;

namespace {

fs::path scratch() {
  static std::atomic<int> n{0};
  auto d = fs::temp_directory_path() / ("meshflow-opt-" + std::to_string(getpid()) + "-" + std::to_string(n++));
  fs::create_directories(d);
  return d;
}

struct Shapes {
  fs::path dir = scratch();
  Shape sphere, cylinder;
  Shapes() {
    opttest::save_sphere(dir / "sphere.mfshape");
    opttest::save_cylinder(dir / "cyl.mfshape");
    sphere = Shape::load(dir / "sphere.mfshape");
    cylinder = Shape::load(dir / "cyl.mfshape");
  }
  ~Shapes() { fs::remove_all(dir); }
};
Shapes& shapes() {
  static Shapes s;
  return s;
}

struct P3 {
  double x, y, z;
};
P3 at(const Mesh& m, std::uint32_t n) { return {m.x[n], m.y[n], m.z[n]}; }
double dist(P3 a, P3 b) { return std::hypot(a.x - b.x, a.y - b.y, a.z - b.z); }

// For every high-order edge of the 2D elements: ratio longest/shortest chord between
// consecutive nodes (worst over edges).
double worst_chord_ratio(const Mesh& m) {
  double worst = 1;
  for (const auto& b : m.blocks) {
    if (model::dimension(b.shape) != 2) continue;
    for (std::size_t e = 0; e < b.size(); ++e)
      for (const auto& ed : model::edge_nodes(b.shape, b.order)) {
        std::vector<std::uint32_t> chain = {b.element(e)[ed[0]]};
        for (std::size_t q = 2; q < ed.size(); ++q) chain.push_back(b.element(e)[ed[q]]);
        chain.push_back(b.element(e)[ed[1]]);
        double lo = 1e300, hi = 0;
        for (std::size_t q = 0; q + 1 < chain.size(); ++q) {
          double L = dist(at(m, chain[q]), at(m, chain[q + 1]));
          lo = std::min(lo, L), hi = std::max(hi, L);
        }
        worst = std::max(worst, hi / lo);
      }
  }
  return worst;
}

std::size_t invalid_count(const Mesh& m) {
  std::size_t n = 0;
  for (auto& b : model::mesh_quality(m, 1))
    for (auto& q : b) n += !q.valid;
  return n;
}

}  // namespace

TEST_CASE("sphere patch P=4: energy drops, nodes stay on the sphere within bounds, edges become equally spaced geodesics") {
  const Shape& s = shapes().sphere;
  opttest::Distortion d;
  d.bunch = 0.35, d.bump = 0.1, d.interior_u = 0.05, d.interior_v = 0.03;
  Mesh m = opttest::sphere_patch(s, 4, {}, d);
  REQUIRE(invalid_count(m) == 0);
  const double ratio_before = worst_chord_ratio(m);
  CHECK(ratio_before > 1.5);  // the test mesh is really bad
  opt::Report r = opt::optimise_mesh(m, s, {}, 1);
  MESSAGE("energy " << r.energy_before << " -> " << r.energy_after << ", chord ratio " << ratio_before << " -> "
                    << worst_chord_ratio(m) << ", iterations " << r.iterations << " max " << r.max_unit_iterations
                    << ", moved " << r.nodes_moved << ", dist " << r.max_cad_distance);
  CHECK(r.surface_edges > 0);
  CHECK(r.faces == 24);
  CHECK(r.energy_after < 0.9 * r.energy_before);
  CHECK(r.max_cad_distance < 1e-7);
  CHECK(opttest::max_param_error(m, s) < 1e-7);
  CHECK(r.invalid_before == 0);
  CHECK(r.invalid_after == 0);
  CHECK(invalid_count(m) == 0);
  CHECK(worst_chord_ratio(m) < 1.01);
  auto fb = s.face_uv_bounds(0);
  double plane = 0;
  for (std::size_t i = 0; i < m.num_nodes(); ++i) {
    CHECK(std::abs(std::hypot(m.x[i], m.y[i], m.z[i]) - 1.0) < 1e-9);
    CHECK((m.node_u[i] >= fb.u0 && m.node_u[i] <= fb.u1 && m.node_v[i] >= fb.v0 && m.node_v[i] <= fb.v1));
  }
  // every edge's nodes lie on the great circle through its ends (the geodesic)
  for (const auto& b : m.blocks)
    for (std::size_t e = 0; e < b.size(); ++e)
      for (const auto& ed : model::edge_nodes(b.shape, b.order)) {
        P3 a = at(m, b.element(e)[ed[0]]), c = at(m, b.element(e)[ed[1]]);
        P3 n{a.y * c.z - a.z * c.y, a.z * c.x - a.x * c.z, a.x * c.y - a.y * c.x};
        double L = std::hypot(n.x, n.y, n.z);
        for (std::size_t q = 2; q < ed.size(); ++q) {
          P3 p = at(m, b.element(e)[ed[q]]);
          plane = std::max(plane, std::abs(p.x * n.x + p.y * n.y + p.z * n.z) / L);
        }
      }
  MESSAGE("distance to the great circles " << plane);
  CHECK(plane < 1e-6);
}
