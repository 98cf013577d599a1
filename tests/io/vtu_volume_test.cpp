// VTU cells as VTK measures them: a box of prisms and hexahedra at orders 1, 2 and 4, written
// with write_vtu, has every cell's volume positive in VTK (vtkCellSizeFilter, through
// tests/io/vtk_volumes.hpp) and VTK's total equal to ours, and reads back through
// read_vtu as the same elements. VTK_WEDGE (order 1) orders its first triangle the other way
// round from Gmsh's prism; a writer that forgets it gives VTK negative wedges.
#include <doctest/doctest.h>

#include "stages/io/mesh_io.hpp"
#include "vtk_volumes.hpp"
#include "stages/model/basis.hpp"

#include <unistd.h>

#include <array>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>

using namespace meshflow;
using namespace meshflow::model;
namespace fs = std::filesystem;

namespace {
fs::path tmpdir() {
  static fs::path d = [] {
    auto p = fs::temp_directory_path() / ("mf_vtu_volume_" + std::to_string(::getpid()));
    fs::create_directories(p);
    return p;
  }();
  return d;
}

// The straight-sided box [0,2]x[0,1]x[0,1.5] cut into n^3 cells: its lower half into prisms
// (two per cell, triangles counter-clockwise seen from +z), its upper half into hexahedra,
// every element of order p with its own nodes at the straight (affine) places.
Mesh box_of_prisms_and_hexes(int p, int n = 2) {
  Mesh m;
  m.add_physical(3, 1, "fluid");
  m.add_entity(3, 1, {1});
  const double L[3] = {2, 1, 1.5};
  const double h[3] = {L[0] / n, L[1] / n, L[2] / n};
  auto add = [&](Shape s, const std::array<double, 3>& o) {
    std::vector<std::uint32_t> nodes;
    for (const auto& r : reference_nodes(s, p)) {
      // reference -> cell: hex [-1,1]^3; prism: (u, v) in the unit triangle, w in [-1,1]
      double x, y, z = o[2] + (r[2] + 1) / 2 * h[2];
      if (s == Shape::Hex) x = o[0] + (r[0] + 1) / 2 * h[0], y = o[1] + (r[1] + 1) / 2 * h[1];
      else x = o[0], y = o[1];
      nodes.push_back(m.add_node(x, y, z));
    }
    return nodes;
  };
  for (int k = 0; k < n; ++k)
    for (int j = 0; j < n; ++j)
      for (int i = 0; i < n; ++i) {
        const std::array<double, 3> o = {i * h[0], j * h[1], k * h[2]};
        if (2 * k >= n) {
          auto nd = add(Shape::Hex, o);
          m.block(Shape::Hex, p, 3, 1).add(nd.data());
          continue;
        }
        // two prisms: triangles (a, b, c) and (a, c, d) of the cell's xy square
        for (int t = 0; t < 2; ++t) {
          std::vector<std::uint32_t> nd;
          const double ax = o[0], ay = o[1];
          const double bx = t == 0 ? o[0] + h[0] : o[0] + h[0], by = t == 0 ? o[1] : o[1] + h[1];
          const double cx = t == 0 ? o[0] + h[0] : o[0], cy = o[1] + h[1];
          for (const auto& r : reference_nodes(Shape::Prism, p)) {
            const double x = ax + r[0] * (bx - ax) + r[1] * (cx - ax), y = ay + r[0] * (by - ay) + r[1] * (cy - ay);
            nd.push_back(m.add_node(x, y, o[2] + (r[2] + 1) / 2 * h[2]));
          }
          m.block(Shape::Prism, p, 3, 1).add(nd.data());
        }
      }
  return m;
}

// Our volume of a block: det J at the reference centroid times the reference volume (exact
// for the affine elements above); the sign is ours: negative for an inverted element.
double our_volume(const ElementBlock& b, const Mesh& m) {
  const LagrangeBasis& basis = LagrangeBasis::get(b.shape, b.order);
  const bool hex = b.shape == Shape::Hex;
  const Vec3 centroid = hex ? Vec3{0, 0, 0} : Vec3{1.0 / 3, 1.0 / 3, 0};
  const double ref_volume = hex ? 8 : 1;
  double total = 0;
  for (size_t e = 0; e < b.size(); ++e) {
    std::vector<double> X;
    for (int k = 0; k < b.nodes_per_element(); ++k) {
      const auto id = b.element(e)[k];
      X.insert(X.end(), {m.x[id], m.y[id], m.z[id]});
    }
    double J[9];
    jacobian(basis, X.data(), centroid, J);
    total += jacobian_determinant(3, J, nullptr) * ref_volume;
  }
  return total;
}
}  // namespace

TEST_CASE("VTU prisms and hexahedra of orders 1, 2, 4: every cell's volume positive in VTK, VTK's total equal to ours, read back unchanged") {
  for (int p : {1, 2, 4}) {
    INFO("order " << p);
    const Mesh m = box_of_prisms_and_hexes(p);
    double ours = 0;
    for (const auto& b : m.blocks) ours += our_volume(b, m);
    REQUIRE(std::abs(ours - 3.0) < 1e-12);  // the box, and none of our elements inverted
    const auto file = tmpdir() / ("box" + std::to_string(p) + ".vtu");
    io::write_vtu(m, file);
    const auto by = mfvtk::measure(file).by_class;
    const std::string wedge = p == 1 ? "vtkWedge" : "vtkLagrangeWedge", hex = p == 1 ? "vtkHexahedron" : "vtkLagrangeHexahedron";
    REQUIRE(by.count(wedge));
    REQUIRE(by.count(hex));
    CHECK(by.at(wedge).cells == 8);
    CHECK(by.at(hex).cells == 4);
    CHECK(by.at(wedge).nonpositive == 0);
    CHECK(by.at(hex).nonpositive == 0);
    const double theirs = by.at(wedge).total + by.at(hex).total;
    CHECK(std::abs(theirs - ours) <= 1e-9 * ours);
    CHECK(std::abs(by.at(wedge).total - 1.5) <= 1e-9);
    // our reader undoes the writer's permutation: the same elements, node for node
    const Mesh back = io::read_vtu(file);
    REQUIRE(back.blocks.size() == m.blocks.size());
    for (size_t i = 0; i < m.blocks.size(); ++i) {
      CHECK(back.blocks[i].shape == m.blocks[i].shape);
      CHECK(back.blocks[i].nodes == m.blocks[i].nodes);
    }
  }
}
