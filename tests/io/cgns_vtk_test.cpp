// CGNS files as ParaView sees them (VTK 9.1's vtkCGNSReader, through tests/io/vtk_volumes.hpp):
// every boundary group of a Gmsh-made mixed cube (wall, farfield, symmetry) loads as a patch,
// at orders 1 and 2, and the cells' volumes are what VTK gives the same cells from our VTU,
// except where VTK itself is at fault (README, "CGNS in ParaView"):
//   - PENTA_6: VTK's CGNS reader hands the SIDS node order to VTK_WEDGE unchanged, while
//     VTK_WEDGE turns its first triangle the other way round (its own reference wedge has
//     volume -0.5): every linear prism comes out with exactly the negative of its volume.
//   - VTK_BIQUADRATIC_QUADRATIC_WEDGE and VTK_TRIQUADRATIC_HEXAHEDRON (PENTA_18, HEXA_27):
//     VTK 9.1 integrates its own reference cells of these types to 1/12 and 0 instead of 1/2
//     and 1, so no file can give ParaView their volume; only their count is compared.
// The node orders themselves are checked against the SIDS in cgns_test.cpp.
#include <doctest/doctest.h>

#include "stages/io/mesh_io.hpp"
#include "vtk_volumes.hpp"

#include <unistd.h>

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <set>
#include <string>

using namespace meshflow;
namespace fs = std::filesystem;

namespace {
fs::path tmpdir() {
  static fs::path d = [] {
    auto p = fs::temp_directory_path() / ("mf_cgns_vtk_" + std::to_string(::getpid()));
    fs::create_directories(p);
    return p;
  }();
  return d;
}

// data/highorder's mixed cube (tets, pyramids, prisms, hexes: volume 1) at order p (Gmsh's
// setOrder), its surfaces in three groups wall, farfield, symmetry and its volume in fluid.
fs::path gmsh_cube(int p) {
  const auto py = tmpdir() / "cube.py", out = tmpdir() / ("cube_p" + std::to_string(p) + ".msh");
  std::ofstream(py) << "import gmsh, sys\n"
                       "gmsh.initialize(); gmsh.option.setNumber('General.Terminal', 0)\n"
                       "gmsh.open(sys.argv[1]); gmsh.model.removePhysicalGroups()\n"
                       "surf = [t for d, t in gmsh.model.getEntities(2)]\n"
                       "for g, name in ((1, 'wall'), (2, 'farfield'), (3, 'symmetry')):\n"
                       "    gmsh.model.setPhysicalName(2, gmsh.model.addPhysicalGroup(2, surf[g - 1::3], g), name)\n"
                       "vol = [t for d, t in gmsh.model.getEntities(3)]\n"
                       "gmsh.model.setPhysicalName(3, gmsh.model.addPhysicalGroup(3, vol, 10), 'fluid')\n"
                       "p = int(sys.argv[3])\n"
                       "if p > 1: gmsh.model.mesh.setOrder(p)\n"
                       "gmsh.option.setNumber('Mesh.SaveAll', 0)\n"
                       "gmsh.write(sys.argv[2])\n";
  const std::string cmd = std::string(MESHFLOW_PYTHON) + " " + py.string() + " " + MESHFLOW_DATA_DIR +
                          "/highorder/v4.1_cube_all.msh " + out.string() + " " + std::to_string(p);
  REQUIRE(std::system(cmd.c_str()) == 0);
  return out;
}
}  // namespace

TEST_CASE("CGNS in ParaView (VTK's CGNS reader), orders 1 and 2: every boundary group loads, and volumes as VTK gives them from our VTU, but for VTK's own wedge faults") {
  for (int p : {1, 2}) {
    INFO("order " << p);
    const model::Mesh m = io::read_mesh(gmsh_cube(p));
    const auto cgns = tmpdir() / ("cube" + std::to_string(p) + ".cgns"), vtu = tmpdir() / ("cube" + std::to_string(p) + ".vtu");
    io::write_cgns(m, cgns);
    io::write_vtu(m, vtu);
    const auto theirs = mfvtk::measure(cgns), ref = mfvtk::measure(vtu);
    // every boundary group, with every one of its faces
    std::set<std::string> groups;
    for (const auto& [name, n] : theirs.patches) groups.insert(name);
    CHECK(groups == std::set<std::string>{"farfield", "symmetry", "wall"});
    long faces = 0, written = 0;
    for (const auto& [name, n] : theirs.patches) faces += n;
    for (const auto& b : m.blocks)
      if (model::dimension(b.shape) == 2) written += static_cast<long>(b.size());
    CHECK(faces == written);
    // the volume: VTU (VTK's Lagrange cells, checked against ours in vtu_volume_test) as the
    // reference; CGNS cells map to VTK's linear/quadratic classes by their vertex count
    auto vtu_class = [&](const std::string& c) -> std::string {
      if (p == 1) return c;
      if (c.find("Tetra") != std::string::npos) return "vtkLagrangeTetra";
      if (c.find("Wedge") != std::string::npos) return "vtkLagrangeWedge";
      if (c.find("Hexahedron") != std::string::npos) return "vtkLagrangeHexahedron";
      return c;  // vtkQuadraticPyramid both ways
    };
    double total = 0;
    for (const auto& [cls, v] : theirs.by_class) {
      INFO(cls);
      REQUIRE(ref.by_class.count(vtu_class(cls)));
      const auto& r = ref.by_class.at(vtu_class(cls));
      CHECK(v.cells == r.cells);
      CHECK(r.nonpositive == 0);
      if (cls == "vtkWedge") {  // VTK's reader: SIDS order into VTK_WEDGE unchanged
        CHECK(v.nonpositive == v.cells);
        CHECK(std::abs(v.total + r.total) <= 1e-9 * r.total);
      } else if (cls == "vtkBiQuadraticQuadraticWedge" || cls == "vtkTriQuadraticHexahedron") {
        // VTK 9.1 cannot integrate these cells (see the file's head); nothing to compare
      } else {
        CHECK(v.nonpositive == 0);
        CHECK(std::abs(v.total - r.total) <= 1e-9 * r.total);
      }
      total += r.total;
    }
    CHECK(std::abs(total - 1.0) < 1e-9);  // the unit cube, all of it
  }
}

TEST_CASE("VTK 9.1's own reference wedges and triquadratic hexahedron: the volumes the CGNS test's exceptions rest on") {
  // VTK's cells with their points at VTK's own parametric coordinates: a right-handed wedge
  // of volume 1/2 and a unit cube, whatever any file says. If VTK fixes these, the exceptions
  // in the test above are to be removed.
  const auto py = tmpdir() / "ref.py", out = tmpdir() / "ref.txt";
  std::ofstream(py) << "import vtk\nvtk.vtkObject.GlobalWarningDisplayOff()\n"
                       "for cls, t in ((vtk.vtkWedge, 13), (vtk.vtkBiQuadraticQuadraticWedge, 32), (vtk.vtkTriQuadraticHexahedron, 29),\n"
                       "               (vtk.vtkLagrangeWedge, 73)):\n"
                       "    c = cls()\n"
                       "    if t == 73: c.GetPointIds().SetNumberOfIds(6); c.GetPoints().SetNumberOfPoints(6); c.Initialize()\n"
                       "    pc = c.GetParametricCoords(); n = c.GetNumberOfPoints()\n"
                       "    g = vtk.vtkUnstructuredGrid(); P = vtk.vtkPoints()\n"
                       "    for i in range(n): P.InsertNextPoint(pc[3 * i], pc[3 * i + 1], pc[3 * i + 2])\n"
                       "    g.SetPoints(P); l = vtk.vtkIdList()\n"
                       "    for i in range(n): l.InsertNextId(i)\n"
                       "    g.InsertNextCell(t, l)\n"
                       "    ia = vtk.vtkIntegrateAttributes(); ia.SetInputData(g); ia.Update()\n"
                       "    print(t, '%.12g' % ia.GetOutput().GetCellData().GetArray('Volume').GetValue(0))\n";
  REQUIRE(std::system((std::string(MESHFLOW_PYTHON) + " " + py.string() + " > " + out.string() + " 2>&1").c_str()) == 0);
  std::ifstream in(out);
  std::map<int, double> vol;
  int t;
  double v;
  while (in >> t >> v) vol[t] = v;
  CHECK(vol[13] == doctest::Approx(-0.5));      // VTK_WEDGE: left-handed parametric space
  CHECK(vol[73] == doctest::Approx(0.5));       // VTK_LAGRANGE_WEDGE: right-handed, as Gmsh and CGNS
  CHECK(vol[32] == doctest::Approx(1.0 / 12));  // VTK_BIQUADRATIC_QUADRATIC_WEDGE: neither
  CHECK(vol[29] == doctest::Approx(0.0));       // VTK_TRIQUADRATIC_HEXAHEDRON: nothing
}
