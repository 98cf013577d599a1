// VTU pyramids of order >= 3: VTK (9.1 here) has no Lagrange pyramid cell, so they are written
// as linear 5-node pyramids and the file says so in its FieldData (meshflow_linearised_cells =
// 74, VTK_LAGRANGE_PYRAMID). Checked with VTK's own reader and with meshio.
#include <doctest/doctest.h>

#include "stages/io/mesh_io.hpp"
#include "stages/model/basis.hpp"

#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <sstream>

using namespace meshflow;
using namespace meshflow::model;
namespace fs = std::filesystem;

namespace {
// one curved pyramid of order p (its vertices at known places) and, beside it, nothing else
Mesh curved_pyramid(int p) {
  Mesh m;
  std::vector<std::uint32_t> n;
  for (auto& r : reference_nodes(Shape::Pyramid, p))
    n.push_back(m.add_node(r[0] + 0.03 * std::sin(3 * r[1]), r[1] + 0.02 * r[0] * r[0], r[2] + 0.01 * r[0]));
  m.add_physical(3, 7, "fluid");
  m.add_entity(3, 1, {7});
  m.block(Shape::Pyramid, p, 3, 1).add(n.data());
  return m;
}
std::string run_python(const std::string& script, const std::string& args) {
  auto dir = fs::temp_directory_path() / ("mf_vtu_pyr_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  auto py = dir / "s.py", out = dir / "o.txt";
  std::ofstream(py) << script;
  const int rc = std::system((std::string(MESHFLOW_PYTHON) + " " + py.string() + " " + args + " > " + out.string() + " 2>&1").c_str());
  std::ifstream in(out);
  std::stringstream ss;
  ss << in.rdbuf();
  REQUIRE_MESSAGE(rc == 0, ss.str());
  return ss.str();
}
}  // namespace

TEST_CASE("VTU: order-4 pyramids are linear cells named in FieldData, VTK and meshio read them") {
  auto dir = fs::temp_directory_path() / ("mf_vtu_pyr_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  Mesh m4 = curved_pyramid(4), m2 = curved_pyramid(2);
  auto f4 = dir / "p4.vtu", f2 = dir / "p2.vtu";
  io::write_vtu(m4, f4);
  io::write_vtu(m2, f2);
  // expected: the pyramid's 5 vertices (Gmsh's and VTK's linear pyramid share the vertex order)
  std::ostringstream want;
  want.precision(17);
  for (int v = 0; v < 5; ++v) {
    const auto id = m4.blocks[0].nodes[v];
    want << (v ? "," : "") << "(" << m4.x[id] << "," << m4.y[id] << "," << m4.z[id] << ")";
  }
  const std::string script = R"(import sys, vtk, meshio
def read(f):
    r = vtk.vtkXMLUnstructuredGridReader(); r.SetFileName(f); r.Update(); return r.GetOutput()
g = read(sys.argv[1])
a = g.GetFieldData().GetArray('meshflow_linearised_cells')
print('field', [int(a.GetValue(i)) for i in range(a.GetNumberOfTuples())])
c = g.GetCell(0)
print('cell', g.GetCellType(0), c.GetNumberOfPoints())
want = [)" + want.str() + R"(]
got = [g.GetPoint(c.GetPointId(i)) for i in range(c.GetNumberOfPoints())]
print('points', all(max(abs(p - q) for p, q in zip(a_, b_)) < 1e-12 for a_, b_ in zip(got, want)) and len(got) == len(want))
# VTK evaluates the cell: its parametric base centre is the mean of the base vertices, and the
# vertices' mean lies inside it
sub = vtk.reference(0); x = [0.0] * 3; w = [0.0] * 5
c.EvaluateLocation(sub, [0.5, 0.5, 0.0], x, w)
base = [sum(p[k] for p in want[:4]) / 4 for k in range(3)]
mid = [sum(p[k] for p in want) / 5 for k in range(3)]
cp = [0.0] * 3; pc = [0.0] * 3; d2 = vtk.reference(0.0)
inside = c.EvaluatePosition(mid, cp, sub, pc, d2, w)
print('evaluate', max(abs(x[k] - base[k]) for k in range(3)) < 1e-12 and inside == 1)
mm = meshio.read(sys.argv[1])
print('meshio', [c.type for c in mm.cells], [int(x) for x in mm.field_data['meshflow_linearised_cells']])
g2 = read(sys.argv[2])
print('order2', g2.GetCellType(0), g2.GetFieldData().GetArray('meshflow_linearised_cells') is None)
# VTK's own limit, the reason for the fallback: a cell of type 74 is kept but cannot be made
ug = vtk.vtkUnstructuredGrid(); pts = vtk.vtkPoints()
for i in range(14): pts.InsertNextPoint(i, i % 3, i % 5)
ug.SetPoints(pts); ids = vtk.vtkIdList()
for i in range(14): ids.InsertNextId(i)
ug.InsertNextCell(74, ids)
print('vtk74', ug.GetCell(0) is None)
)";
  std::istringstream out(run_python(script, f4.string() + " " + f2.string()));
  std::vector<std::string> lines;
  for (std::string l; std::getline(out, l);) lines.push_back(l);
  REQUIRE(lines.size() == 7);
  CHECK(lines[0] == "field [74]");
  CHECK(lines[1] == "cell 14 5");
  CHECK(lines[2] == "points True");
  CHECK(lines[3] == "evaluate True");
  CHECK(lines[4] == "meshio ['pyramid'] [74]");
  CHECK(lines[5] == "order2 27 True");  // order 2: VTK's quadratic pyramid, no fallback named
  CHECK(lines[6] == "vtk74 True");       // when VTK gains a Lagrange pyramid, write it instead
  // our own reader still reads the file with the fallback
  Mesh back = io::read_mesh(f4);
  CHECK(back.num_elements() == 1);
}
