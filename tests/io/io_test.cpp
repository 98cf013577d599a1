// Tests of the mesh formats against external truth: the files in data/highorder,
// Gmsh and meshio loading what we write, Gmsh's own Jacobian analysis, VTK's Lagrange cells.
#include <doctest/doctest.h>

#include "engine/artifact_type.hpp"
#include "engine/command.hpp"
#include "stages/io/mesh_io.hpp"
#include "stages/io/reader.hpp"
#include "stages/model/basis.hpp"
#include "stages/model/quality.hpp"

#include <nlohmann/json.hpp>

#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <limits>
#include <set>
#include <sstream>

using namespace meshflow;
using namespace meshflow::model;
namespace fs = std::filesystem;

namespace {
const std::string kData = std::string(MESHFLOW_DATA_DIR) + "/highorder/";

fs::path tmpdir() {
  static fs::path d = [] {
    auto p = fs::temp_directory_path() / ("mf_io_test_" + std::to_string(::getpid()));
    fs::create_directories(p);
    return p;
  }();
  return d;
}

std::string python(const std::string& script) {
  static int k = 0;
  auto py = tmpdir() / ("s" + std::to_string(k) + ".py"), out = tmpdir() / ("o" + std::to_string(k++) + ".txt");
  std::ofstream(py) << script;
  std::string cmd = std::string(MESHFLOW_PYTHON) + " " + py.string() + " > " + out.string() + " 2>&1";
  int rc = std::system(cmd.c_str());
  std::ifstream in(out);
  std::stringstream ss;
  ss << in.rdbuf();
  REQUIRE_MESSAGE(rc == 0, "python failed: " << ss.str());
  return ss.str();
}

// One curved element of each shape and order (plus its boundary faces as 2D blocks) in a mesh.
Mesh one_element(Shape s, int p) {
  Mesh m;
  const auto& ref = reference_nodes(s, p);
  std::vector<std::uint32_t> n;
  for (auto& r : ref) {
    double x = r[0] + 0.03 * std::sin(3 * r[1]), y = r[1] + 0.02 * r[0] * r[0], z = r[2] + 0.01 * r[0];
    n.push_back(m.add_node(x, y, z));
  }
  const int d = dimension(s);
  m.add_physical(d, 7, "fluid");
  m.add_entity(d, 1, {7});
  m.block(s, p, d, 1).add(n.data());
  if (d == 3) {
    m.add_physical(2, 3, "wall");
    m.add_entity(2, 5, {3});
    for (size_t f = 0; f < face_vertices(s).size(); ++f) {
      std::vector<std::uint32_t> fn;
      for (int ln : face_nodes(s, p)[f]) fn.push_back(n[ln]);
      m.block(face_vertices(s)[f].size() == 4 ? Shape::Quad : Shape::Tri, p, 2, 5).add(fn.data());
    }
  }
  return m;
}

void same_mesh(const Mesh& a, const Mesh& b, bool exact = true) {
  REQUIRE(a.num_nodes() == b.num_nodes());
  for (size_t i = 0; i < a.num_nodes(); ++i) {
    if (exact) {
      CHECK(a.x[i] == b.x[i]);
      CHECK(a.y[i] == b.y[i]);
      CHECK(a.z[i] == b.z[i]);
    }
  }
  REQUIRE(a.blocks.size() == b.blocks.size());
  for (size_t k = 0; k < a.blocks.size(); ++k) {
    CHECK(a.blocks[k].shape == b.blocks[k].shape);
    CHECK(a.blocks[k].order == b.blocks[k].order);
    CHECK(a.blocks[k].nodes == b.blocks[k].nodes);
    CHECK(a.blocks[k].entity_tag == b.blocks[k].entity_tag);
  }
}

int run_cmd(const std::string& name, std::vector<std::string> args) {
  const Command* c = find_command(name);
  REQUIRE(c != nullptr);
  return c->run(args);
}
}  // namespace

TEST_CASE("every file in data/highorder reads with the counts the file states") {
  struct Expect {
    const char* file;
    size_t nodes;
    size_t elements;  // all elements of all dimensions
  };
  // counts as stated in the files' own headers ($Nodes/$Elements; Nektar: V/E/F/element lists)
  auto header = [](const std::string& f, const std::string& sec, int field) {
    std::ifstream in(kData + f);
    std::string line;
    while (std::getline(in, line))
      if (line == sec) {
        std::getline(in, line);
        std::istringstream is(line);
        size_t v = 0;
        for (int i = 0; i <= field; ++i) is >> v;
        return v;
      }
    return size_t(0);
  };
  for (std::string f : {"v2.2_varopti_cube_sphere.msh", "v2.2_varopti_naca.msh"}) {
    auto m = io::read_mesh(kData + f);
    CHECK(m.num_nodes() == header(f, "$Nodes", 0));
    CHECK(m.num_elements() == header(f, "$Elements", 0));
  }
  for (std::string f : {"v4.1_cube_all.msh", "v4.1_cube_hex.msh", "v4.1_cube_prism.msh", "v4.1_cube_tet.msh"}) {
    auto m = io::read_mesh(kData + f);
    INFO(f);
    CHECK(m.num_nodes() == header(f, "$Nodes", 1));
    CHECK(m.num_elements() == header(f, "$Elements", 1));
    CHECK(mesh_stats(m)["invalid"] == 0);
    CHECK(mesh_stats(m)["nonconforming_faces"] == 0);
  }
  auto q = io::read_mesh(kData + "linearise_invalid_quad.xml");
  CHECK(q.order() == 3);
  CHECK(q.blocks[0].size() == 9);
  auto t = io::read_mesh(kData + "extract_curved_face.xml");
  CHECK(t.order() == 4);
  size_t tets = 0, tris = 0;
  for (auto& b : t.blocks) (b.shape == Shape::Tet ? tets : tris) += b.size();
  CHECK(tets == 433);
  auto s = mesh_stats(t);
  CHECK(s["nonconforming_faces"] == 0);
  CHECK(s["invalid"] == 0);
  // 127 vertices in the file; every curved face point set must agree with its curved edges
  CHECK(s["groups"].size() == 8);  // 7 boundary composites + the domain
}

TEST_CASE("linearise_invalid_quad.xml: exactly one invalid element, the one whose edge node was pushed across") {
  auto m = io::read_mesh(kData + "linearise_invalid_quad.xml");
  auto s = mesh_stats(m);
  CHECK(s["invalid"] == 1);
  // Nektar element 8 (tag 9) owns edge 15 from the right; its CURVED point x=0.9667 lies
  // beyond the element's far side x=0.5
  CHECK(s["invalid_elements"] == nlohmann::json::array({9}));
}

TEST_CASE("round trips msh binary / msh ascii / vtu preserve every type and order 1-6") {
  for (Shape s : {Shape::Line, Shape::Tri, Shape::Quad, Shape::Tet, Shape::Prism, Shape::Pyramid, Shape::Hex})
    for (int p = 1; p <= 6; ++p) {
      INFO(std::string(shape_name(s)) << " order " << p);
      Mesh m = one_element(s, p);
      auto f1 = tmpdir() / "a.msh", f2 = tmpdir() / "b.msh", f3 = tmpdir() / "c.vtu";
      io::write_msh(m, f1, true);
      io::write_msh(m, f2, false);
      Mesh a = io::read_mesh(f1), b = io::read_mesh(f2);
      same_mesh(m, a);
      same_mesh(m, b);
      CHECK(a.group_name(dimension(s), 1) == "fluid");
      // byte-identical rewrite
      io::write_msh(a, f2, true);
      std::ifstream i1(f1, std::ios::binary), i2(f2, std::ios::binary);
      std::string s1((std::istreambuf_iterator<char>(i1)), {}), s2((std::istreambuf_iterator<char>(i2)), {});
      CHECK(s1 == s2);
      if (s != Shape::Pyramid || p <= 1) {
        io::write_vtu(m, f3);
        Mesh c = io::read_mesh(f3);
        same_mesh(m, c);
      }
    }
}

TEST_CASE("Nektar++ round trip for triangles, quads (2D) and tets, prisms, pyramids, hexes (3D), orders 1-6") {
  for (Shape s : {Shape::Tri, Shape::Quad, Shape::Tet, Shape::Prism, Shape::Pyramid, Shape::Hex})
    for (int p = 1; p <= 6; ++p) {
      INFO(std::string(shape_name(s)) << " order " << p);
      Mesh m = one_element(s, p);
      auto f = tmpdir() / "n.xml";
      io::write_nektar(m, f);
      Mesh r = io::read_mesh(f);
      // same element, same node positions for every node the format stores (vertices, edge
      // and face nodes, as VERTEX and CURVED data); element interiors are rebuilt (Nektar++
      // stores none)
      const auto& bm = m.blocks[0];
      const ElementBlock* br = nullptr;
      size_t boundary = 0;
      for (auto& b : r.blocks) {
        if (b.shape == s) br = &b;
        if (dimension(b.shape) == dimension(s) - 1) boundary += b.size();
      }
      REQUIRE(br);
      REQUIRE(br->size() == 1);
      CHECK(br->order == p);
      if (dimension(s) == 3) CHECK(boundary == face_vertices(s).size());  // the wall composite
      std::set<int> stored;
      for (int v = 0; v < num_vertices(s); ++v) stored.insert(v);
      for (auto& side : dimension(s) == 3 ? face_nodes(s, p) : edge_nodes(s, p)) stored.insert(side.begin(), side.end());
      int compared = 0;
      // the reader may number the element's vertices differently: compare positions
      for (int i : stored) {
        auto a = bm.nodes[i];
        double best = 1e300;
        for (auto b : br->nodes)
          best = std::min(best, std::hypot(r.x[b] - m.x[a], r.y[b] - m.y[a], r.z[b] - m.z[a]));
        CHECK(best < 1e-12);
        ++compared;
      }
      CHECK(compared == (int)stored.size());
      CHECK(mesh_stats(r)["invalid"] == 0);
      // and the element reads back with positive orientation in our vertex order
      CHECK(mesh_stats(r)["min_scaled_jacobian"].get<double>() > 0.5);
    }
}

TEST_CASE("Gmsh and meshio load every MSH/VTU we write with the same counts") {
  std::string script = "import gmsh, meshio, sys\ngmsh.initialize()\ngmsh.option.setNumber('General.Terminal',0)\n"
                       "gmsh.option.setNumber('General.AbortOnError',0)\n";
  std::vector<std::string> expect;
  int k = 0;
  for (Shape s : {Shape::Tri, Shape::Quad, Shape::Tet, Shape::Prism, Shape::Pyramid, Shape::Hex})
    for (int p = 1; p <= 6; ++p) {
      Mesh m = one_element(s, p);
      auto f = tmpdir() / ("g" + std::to_string(k) + ".msh");
      auto v = tmpdir() / ("g" + std::to_string(k++) + ".vtu");
      io::write_msh(m, f, (k % 2) == 0);
      script += "gmsh.clear()\ngmsh.open('" + f.string() +
                "')\nt,tags,nodes=gmsh.model.mesh.getElements()\nnt,_,_=gmsh.model.mesh.getNodes()\n"
                "try:\n  mm=meshio.read('" + f.string() + "')\n  mc=(len(mm.points), sum(len(c.data) for c in mm.cells))\n"
                "except KeyError:\n  mc=('meshio-unknown-type',)\n"
                "print(len(nt), sum(len(x) for x in tags), *mc)\n";
      // meshio 5.0 has no Gmsh types for pyramids of order >= 3
      std::string line = std::to_string(m.num_nodes()) + " " + std::to_string(m.num_elements()) + " " +
                         (s == Shape::Pyramid && p >= 3 ? std::string("meshio-unknown-type")
                                                        : std::to_string(m.num_nodes()) + " " + std::to_string(m.num_elements()));
      expect.push_back(line);
      if (s != Shape::Pyramid || p == 1) {
        io::write_vtu(m, v);
        script += "mv=meshio.read('" + v.string() + "')\nprint('vtu', len(mv.points), sum(len(c.data) for c in mv.cells))\n";
        expect.push_back("vtu " + std::to_string(m.num_nodes()) + " " + std::to_string(m.num_elements()));
      }
    }
  std::istringstream out(python(script));
  std::string line;
  size_t i = 0;
  while (std::getline(out, line)) {
    if (line.empty() || !std::isdigit((unsigned char)line[0]) && line.rfind("vtu", 0) != 0) continue;
    REQUIRE(i < expect.size());
    CHECK(line == expect[i]);
    ++i;
  }
  CHECK(i == expect.size());
}

TEST_CASE("on Gmsh-made curved tet meshes our invalid set equals Gmsh's AnalyseMeshQuality set (non-empty)") {
  for (int order : {2, 4}) {
    auto f = tmpdir() / ("sphere" + std::to_string(order) + ".msh");
    auto res = tmpdir() / ("gmshbad" + std::to_string(order) + ".txt");
    std::string script =
        "import gmsh\ngmsh.initialize()\ngmsh.option.setNumber('General.Terminal',0)\n"
        "gmsh.option.setNumber('General.AbortOnError',0)\n"
        "gmsh.model.occ.addBox(-1,-1,-1,2,2,2)\ngmsh.model.occ.addSphere(0,0,0,0.2)\n"
        "gmsh.model.occ.cut([(3,1)],[(3,2)])\ngmsh.model.occ.synchronize()\n"
        "gmsh.option.setNumber('Mesh.MeshSizeMax',0.8)\ngmsh.option.setNumber('Mesh.MeshSizeFromCurvature',0)\n"
        "gmsh.option.setNumber('Mesh.HighOrderOptimize',0)\n"
        "gmsh.model.mesh.generate(3)\ngmsh.model.mesh.setOrder(" + std::to_string(order) + ")\n"
        "gmsh.write('" + f.string() + "')\n"
        "gmsh.plugin.setNumber('AnalyseMeshQuality','JacobianDeterminant',1)\n"
        "gmsh.plugin.setNumber('AnalyseMeshQuality','CreateView',1)\n"
        "gmsh.plugin.setNumber('AnalyseMeshQuality','DimensionOfElements',3)\n"
        "v=gmsh.plugin.run('AnalyseMeshQuality')\n"
        "tags=gmsh.view.getTags()\n"
        "bad=set()\n"
        "for t in tags:\n"
        "  name=gmsh.option.getString('View[%d].Name'%gmsh.view.getIndex(t))\n"
        "  if 'min J/max J' in name or 'minJ/maxJ' in name:\n"
        "    typ,els,data,time,nc=gmsh.view.getModelData(t,0)\n"
        "    bad={int(e) for e,d in zip(els,data) if d[0]<=0}\n"
        "open('" + res.string() + "','w').write(' '.join(map(str,sorted(bad))))\n"
        "print(len(bad))\n";
    python(script);
    Mesh m = io::read_mesh(f);
    auto q = mesh_quality(m);
    std::set<std::uint64_t> ours, theirs;
    std::uint64_t running = 0;  // element tags are implicit (running index + 1) when the file's are
    for (size_t b = 0; b < m.blocks.size(); ++b) {
      for (size_t e = 0; e < q[b].size(); ++e)
        if (!q[b][e].valid) ours.insert(m.blocks[b].tags.empty() ? running + e + 1 : m.blocks[b].tags[e]);
      running += m.blocks[b].size();
    }
    std::ifstream in(res);
    std::uint64_t t;
    while (in >> t) theirs.insert(t);
    INFO("order " << order << ": ours " << ours.size() << ", Gmsh " << theirs.size());
    // a small sphere (radius 0.2) in tets sized for the box (up to 0.8): the curved boundary
    // edges and faces push through the thin tets around the sphere; Gmsh 4.8 leaves 3 (P=2)
    // and 13 (P=4) of ~1200 tets inverted
    CHECK(!theirs.empty());
    CHECK(ours == theirs);
  }
}

// VTK 9.1 facts this test relies on (both found while debugging this cross-check):
// - vtkLagrangeHexahedron::InterpolateDerivs returns the derivatives interleaved per point
//   (derivs[3*i+c]), while vtkLagrangeWedge/Tetra return them blocked per direction
//   (derivs[c*n+i]); we also compare positions (InterpolateFunctions), which have no such
//   ambiguity, so a node-ordering error cannot hide behind the derivative layout.
// - VTK XML files of version < 2.2 are read with the legacy Lagrange-hexahedron order (the
//   vertical edges of vertices 2 and 3 swapped). We write version 1.0 (meshio 5 rejects 2.2)
//   with hexahedra in that legacy order, so VTK >= 9.1 converts them to its current order.
TEST_CASE("order-4 prisms and hexes: det J signs agree with VTK 9.1's own Lagrange cells") {
  for (Shape s : {Shape::Prism, Shape::Hex, Shape::Tet}) {
    for (int variant = 0; variant < 2; ++variant) {
      Mesh m = one_element(s, 4);
      if (variant == 1) {  // push the middle node of edge 0 far across the element
        const auto& en = edge_nodes(s, 4)[0];
        auto id = m.blocks[0].nodes[en[3]];
        m.y[id] += s == Shape::Hex ? 3.0 : 1.5;
      }
      auto v = tmpdir() / "vtkcheck.vtu";
      io::write_vtu(m, v);
      // our det J at sample points (reference coordinates of Gmsh), then VTK's at the same
      // points (VTK's parametric coordinates: [0,1] for hex and the prism axis)
      const LagrangeBasis& b = LagrangeBasis::get(s, 4);
      std::vector<double> X;
      for (auto id : m.blocks[0].nodes) X.insert(X.end(), {m.x[id], m.y[id], m.z[id]});
      std::vector<Vec3> pts;
      for (int i = 0; i <= 6; ++i)
        for (int j = 0; j <= 6; ++j)
          for (int k = 0; k <= 6; ++k) {
            Vec3 r{i / 6.0, j / 6.0, k / 6.0};
            if (s != Shape::Hex && r[0] + r[1] > 1) continue;
            if (s == Shape::Tet && r[0] + r[1] + r[2] > 1) continue;
            pts.push_back(r);
          }
      std::string script = "import vtk\nr=vtk.vtkXMLUnstructuredGridReader()\nr.SetFileName('" + v.string() +
                           "')\nr.Update()\ng=r.GetOutput()\nc=g.GetCell(0)\nimport numpy as np\n"
                           "n=c.GetNumberOfPoints()\nP=np.array([g.GetPoint(c.GetPointId(i)) for i in range(n)])\n"
                           "inter=c.GetClassName()=='vtkLagrangeHexahedron'\n"
                           "for p in [";
      {
        std::ostringstream ps;
        ps.precision(17);
        for (auto& r : pts) ps << "(" << r[0] << "," << r[1] << "," << r[2] << "),";
        script += ps.str();
      }
      script += "]:\n  d=[0.0]*(3*n)\n  c.InterpolateDerivs(p,d)\n"
                "  D=np.array(d).reshape(n,3).T if inter else np.array(d).reshape(3,n)\n"
                "  w=[0.0]*n\n  c.InterpolateFunctions(p,w)\n  x=np.array(w)@P\n"
                "  J=D@P\n  print('%.17g %.17g %.17g %.17g'%(np.linalg.det(J),x[0],x[1],x[2]))\n";
      std::istringstream out(python(script));
      int agree = 0, total = 0;
      double max_dx = 0;
      for (auto& r : pts) {
        double theirs, tx[3];
        REQUIRE(static_cast<bool>(out >> theirs >> tx[0] >> tx[1] >> tx[2]));
        Vec3 xi = r;
        if (s == Shape::Hex) xi = {2 * r[0] - 1, 2 * r[1] - 1, 2 * r[2] - 1};
        if (s == Shape::Prism) xi = {r[0], r[1], 2 * r[2] - 1};
        double J[9];
        jacobian(b, X.data(), xi, J);
        double ours = jacobian_determinant(3, J, nullptr);
        Vec3 ox = map_point(b, X.data(), xi);
        for (int c = 0; c < 3; ++c) max_dx = std::max(max_dx, std::abs(ox[c] - tx[c]));
        if (std::abs(ours) < 1e-9 && std::abs(theirs) < 1e-9) continue;
        ++total;
        agree += (ours > 0) == (theirs > 0);
      }
      INFO(std::string(shape_name(s)) << " variant " << variant);
      CHECK(max_dx < 1e-12);
      CHECK(total > 50);
      CHECK(agree == total);
      auto q = element_quality(s, 4, X.data());
      CHECK(q.valid == (variant == 0));
    }
  }
}

TEST_CASE("VTK node orderings: VTK 9.1 interpolates our VTU cells exactly like our mapping, every type, orders 1-6") {
  // A wrong node permutation changes the interpolant: comparing positions at interior
  // sample points checks the whole vtk_to_gmsh table (edges, faces, interiors).
  const std::vector<Vec3> samples = {{0.11, 0.23, 0.31}, {0.52, 0.17, 0.08}, {0.07, 0.61, 0.2}, {0.3, 0.3, 0.33}};
  std::string script = "import vtk\n";
  std::vector<std::pair<Mesh, Shape>> cases;
  int k = 0;
  for (Shape s : {Shape::Line, Shape::Tri, Shape::Quad, Shape::Tet, Shape::Prism, Shape::Hex})
    for (int p = 1; p <= 6; ++p) {
      Mesh m = one_element(s, p);
      auto v = tmpdir() / ("ord" + std::to_string(k++) + ".vtu");
      io::write_vtu(m, v);
      script += "r=vtk.vtkXMLUnstructuredGridReader()\nr.SetFileName('" + v.string() +
                "')\nr.Update()\ng=r.GetOutput()\nc=g.GetCell(0)\nn=c.GetNumberOfPoints()\n"
                "for p in [(0.11,0.23,0.31),(0.52,0.17,0.08),(0.07,0.61,0.2),(0.3,0.3,0.33)]:\n"
                "  w=[0.0]*n\n  c.InterpolateFunctions(p,w)\n"
                "  x=[sum(w[i]*g.GetPoint(c.GetPointId(i))[a] for i in range(n)) for a in range(3)]\n"
                "  print('%.17g %.17g %.17g'%tuple(x))\n";
      cases.push_back({std::move(m), s});
    }
  std::istringstream out(python(script));
  for (auto& [m, s] : cases) {
    const int p = m.blocks[0].order;
    const LagrangeBasis& b = LagrangeBasis::get(s, p);
    std::vector<double> X;
    for (auto id : m.blocks[0].nodes) X.insert(X.end(), {m.x[id], m.y[id], m.z[id]});
    double err = 0;
    for (auto r : samples) {
      double t[3];
      REQUIRE(static_cast<bool>(out >> t[0] >> t[1] >> t[2]));
      Vec3 xi = r;  // VTK parametric -> Gmsh reference
      if (s == Shape::Line) xi = {2 * r[0] - 1, 0, 0};
      if (s == Shape::Tri) xi = {r[0], r[1], 0};
      if (s == Shape::Quad) xi = {2 * r[0] - 1, 2 * r[1] - 1, 0};
      if (s == Shape::Hex) xi = {2 * r[0] - 1, 2 * r[1] - 1, 2 * r[2] - 1};
      if (s == Shape::Prism) xi = {r[0], r[1], 2 * r[2] - 1};
      // VTK_WEDGE's first triangle runs the other way round (vertices 1 and 2 swapped)
      if (s == Shape::Prism && p == 1) xi = {r[1], r[0], 2 * r[2] - 1};
      Vec3 o = map_point(b, X.data(), xi);
      for (int c = 0; c < 3; ++c) err = std::max(err, std::abs(o[c] - t[c]));
    }
    INFO(std::string(shape_name(s)) << " order " << p);
    CHECK(err < 1e-10);
  }
}

TEST_CASE("VTU files: version 2.2 hexahedra (current VTK order) and 1.0 (legacy order) read as VTK 9.1 reads them") {
  for (int p : {2, 3, 4}) {
    Mesh m = one_element(Shape::Hex, p);
    auto v = tmpdir() / "legacy.vtu";
    io::write_vtu(m, v);
    std::string d;
    {
      std::ifstream in(v, std::ios::binary);
      d.assign(std::istreambuf_iterator<char>(in), {});
    }
    const std::string from = "type=\"UnstructuredGrid\" version=\"1.0\"";
    REQUIRE(d.find(from) != std::string::npos);
    for (const char* ver : {"1.0", "2.2"}) {
      d.replace(d.find("type=\"UnstructuredGrid\" version=\""), from.size(), std::string("type=\"UnstructuredGrid\" version=\"") + ver + "\"");
      std::ofstream(v, std::ios::binary) << d;
      // VTK's points of the hexahedron (in VTK order) vs ours mapped through vtk_to_gmsh
      std::istringstream out(python("import vtk\nr=vtk.vtkXMLUnstructuredGridReader()\nr.SetFileName('" + v.string() +
                                    "')\nr.Update()\ng=r.GetOutput()\n"
                                    "for ci in range(g.GetNumberOfCells()):\n  c=g.GetCell(ci)\n"
                                    "  if c.GetCellDimension()==3:\n"
                                    "    for i in range(c.GetNumberOfPoints()): print('%.17g %.17g %.17g'%g.GetPoint(c.GetPointId(i)))\n"));
      Mesh r = io::read_vtu(v);
      const ElementBlock* hb = nullptr;
      for (auto& b : r.blocks)
        if (b.shape == Shape::Hex) hb = &b;
      REQUIRE(hb);
      const auto& perm = vtk_to_gmsh(Shape::Hex, p);
      double err = 0;
      int n = 0;
      for (size_t k = 0; k < perm.size(); ++k) {
        double x, y, z;
        REQUIRE(static_cast<bool>(out >> x >> y >> z));
        auto id = hb->nodes[perm[k]];
        err = std::max({err, std::abs(r.x[id] - x), std::abs(r.y[id] - y), std::abs(r.z[id] - z)});
        ++n;
      }
      INFO("order " << p << " version " << ver);
      CHECK(n == num_nodes(Shape::Hex, p));
      CHECK(err == 0);
      // the file we wrote (1.0) reads back as the element we wrote; the same bytes as 2.2
      // are a different (permuted) element for VTK and for us
      if (std::string(ver) == "1.0") CHECK(hb->nodes == m.blocks[0].nodes);
      else CHECK(hb->nodes != m.blocks[0].nodes);
    }
  }
}

TEST_CASE("a swapped element and a pushed P=4 edge node are invalid for us, for Gmsh and for VTK") {
  Mesh m = one_element(Shape::Tet, 4);
  Mesh m2 = m;
  std::swap(m.blocks[0].nodes[1], m.blocks[0].nodes[2]);  // swapped vertices (and so inverted)
  m2.y[m2.blocks[0].nodes[5]] += 0.15;                      // valid at nodes, invalid between
  {
    const LagrangeBasis& b = LagrangeBasis::get(Shape::Tet, 4);
    std::vector<double> X;
    for (auto id : m2.blocks[0].nodes) X.insert(X.end(), {m2.x[id], m2.y[id], m2.z[id]});
    double at_nodes = 1e300, between = 1e300, J[9];
    for (auto& xi : b.nodes()) {
      jacobian(b, X.data(), xi, J);
      at_nodes = std::min(at_nodes, jacobian_determinant(3, J, nullptr));
    }
    const int F = 40;
    for (int i = 0; i <= F; ++i)
      for (int j = 0; i + j <= F; ++j)
        for (int k = 0; i + j + k <= F; ++k) {
          jacobian(b, X.data(), {i / double(F), j / double(F), k / double(F)}, J);
          between = std::min(between, jacobian_determinant(3, J, nullptr));
        }
    INFO("pushed element: min det J at nodes " << at_nodes << ", on a fine lattice " << between);
    REQUIRE(at_nodes > 0.05);
    REQUIRE(between < -0.05);
  }
  int k = 0;
  for (Mesh* mm : {&m, &m2}) {
    INFO((k == 0 ? "swapped vertices" : "pushed edge node"));
    auto f = tmpdir() / ("bad" + std::to_string(k) + ".msh");
    auto v = tmpdir() / ("bad" + std::to_string(k++) + ".vtu");
    io::write_msh(*mm, f);
    io::write_vtu(*mm, v);
    CHECK(mesh_stats(*mm)["invalid"] == 1);
    std::string out = python(
        "import gmsh\ngmsh.initialize()\ngmsh.option.setNumber('General.Terminal',0)\n"
        "gmsh.option.setNumber('General.AbortOnError',0)\ngmsh.open('" + f.string() + "')\n"
        "gmsh.plugin.setNumber('AnalyseMeshQuality','JacobianDeterminant',1)\n"
        "gmsh.plugin.setNumber('AnalyseMeshQuality','DimensionOfElements',3)\n"
        "gmsh.plugin.setNumber('AnalyseMeshQuality','CreateView',1)\ngmsh.plugin.run('AnalyseMeshQuality')\n"
        "for t in gmsh.view.getTags():\n"
        "  name=gmsh.option.getString('View[%d].Name'%gmsh.view.getIndex(t))\n"
        "  if 'min J/max J' in name or 'minJ/maxJ' in name:\n"
        "    typ,els,data,time,nc=gmsh.view.getModelData(t,0)\n"
        "    print('GMSH', len(els), sum(1 for d in data if d[0]<=0))\n"
        "import vtk\nr=vtk.vtkXMLUnstructuredGridReader()\nr.SetFileName('" + v.string() + "')\nr.Update()\n"
        "g=r.GetOutput()\nc=g.GetCell(0)\nimport numpy as np\nn=c.GetNumberOfPoints()\n"
        "P=np.array([g.GetPoint(c.GetPointId(i)) for i in range(n)])\nneg=0\nF=20\n"
        "for i in range(F+1):\n for j in range(F+1-i):\n  for l in range(F+1-i-j):\n"
        "   d=[0.0]*(3*n)\n   c.InterpolateDerivs((i/F,j/F,l/F),d)\n"
        "   neg+=np.linalg.det(np.array(d).reshape(3,n)@P)<0\n"
        "print('VTK', c.GetClassName(), neg>0)\n");
    INFO(out);
    CHECK(out.find("GMSH 1 1") != std::string::npos);
    CHECK(out.find("VTK vtkLagrangeTetra True") != std::string::npos);
  }
}

TEST_CASE("bad input: clear errors naming the file and line/offset, commands exit 2") {
  auto write = [](const std::string& name, const std::string& text) {
    auto p = tmpdir() / name;
    std::ofstream(p, std::ios::binary) << text;
    return p;
  };
  const std::string head = "$MeshFormat\n4.1 0 8\n$EndMeshFormat\n";
  const std::string nodes = "$Nodes\n1 2 1 2\n3 1 0 2\n1\n2\n0 0 0\n1 0 0\n$EndNodes\n";
  struct Case {
    const char* name;
    std::string text;
    const char* msg;
  } cases[] = {
      {"trunc.msh", head + "$Nodes\n1 2 1 2\n3 1 0 2\n1\n2\n0 0 0\n", "end of file"},
      {"version.msh", "$MeshFormat\n3.0 0 8\n$EndMeshFormat\n", "unsupported MSH version 3.0"},
      {"magic.msh", "hello\n", "not a Gmsh MSH file"},
      {"type.msh", head + nodes + "$Elements\n1 1 1 1\n3 1 17 1\n1 1 2 1 2 1 2 1 2 1 2 1 2 1 2 1 2 1 2 1 2\n$EndElements\n", "unknown or unsupported element type 17"},
      {"range.msh", head + nodes + "$Elements\n1 1 1 1\n1 1 1 1\n1 1 9\n$EndElements\n", "node 9"},
      {"nan.msh", head + "$Nodes\n1 2 1 2\n3 1 0 2\n1\n2\n0 nan 0\n1 0 0\n$EndNodes\n", "non-finite"},
      {"counts.msh", head + "$Nodes\n1 3 1 3\n3 1 0 2\n1\n2\n0 0 0\n1 0 0\n$EndNodes\n", "inconsistent counts"},
      {"xml.xml", "<NEKTAR><GEOMETRY DIM=\"2\"><VERTEX><V ID=\"0\">0 0", "XML error"},
      {"vtu.vtu", "<VTKFile type=\"UnstructuredGrid\">", "appended"},
  };
  for (auto& c : cases) {
    auto p = write(c.name, c.text);
    INFO(c.name);
    try {
      io::read_mesh(p);
      FAIL("no exception for " << c.name);
    } catch (const io::MeshIOError& e) {
      std::string w = e.what();
      CHECK(w.find(p.string()) != std::string::npos);
      CHECK(w.find(c.msg) != std::string::npos);
      CHECK((w.find(":line ") != std::string::npos || w.find(":byte offset ") != std::string::npos));
    }
    CHECK(run_cmd("quality", {p.string()}) == 2);
    CHECK(run_cmd("convert", {p.string(), (tmpdir() / "x.vtu").string()}) == 2);
  }
  // binary truncation names a byte offset
  Mesh m = one_element(Shape::Tet, 3);
  auto f = tmpdir() / "bin.msh";
  io::write_msh(m, f, true);
  std::string full;
  {
    std::ifstream in(f, std::ios::binary);
    full.assign(std::istreambuf_iterator<char>(in), {});
  }
  auto cut = write("bincut.msh", full.substr(0, full.size() * 2 / 3));
  CHECK_THROWS_WITH_AS(io::read_mesh(cut), doctest::Contains("byte offset"), io::MeshIOError);
  // binary blocks are read in bulk: a NaN coordinate and an element node tag that is not in
  // $Nodes still name the exact byte offset of the bad value
  {
    Mesh lin;
    std::uint32_t v[4];
    const double xs[4][3] = {{12345.678, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
    for (int i = 0; i < 4; ++i) v[i] = lin.add_node(xs[i][0], xs[i][1], xs[i][2]);
    lin.add_physical(3, 7, "fluid");
    lin.add_entity(3, 1, {7});
    lin.block(Shape::Tet, 1, 3, 1).add(v);
    auto g = tmpdir() / "binlin.msh";
    io::write_msh(lin, g, true);
    std::string bytes;
    {
      std::ifstream in(g, std::ios::binary);
      bytes.assign(std::istreambuf_iterator<char>(in), {});
    }
    auto pack = [](auto value) { return std::string(reinterpret_cast<const char*>(&value), sizeof value); };
    const std::size_t at_x = bytes.find(pack(12345.678), bytes.find("$Nodes"));  // (not the entity box)
    REQUIRE(at_x != std::string::npos);
    std::string nan_bytes = bytes;
    nan_bytes.replace(at_x, 8, pack(std::numeric_limits<double>::quiet_NaN()));
    auto fn = write("binnan.msh", nan_bytes);
    CHECK_THROWS_WITH_AS(io::read_mesh(fn), doctest::Contains("non-finite coordinate"), io::MeshIOError);
    const std::string off_x = "byte offset " + std::to_string(at_x) + ":";
    CHECK_THROWS_WITH_AS(io::read_mesh(fn), doctest::Contains(off_x.c_str()), io::MeshIOError);
    const std::string rec = pack(std::uint64_t(1)) + pack(std::uint64_t(1)) + pack(std::uint64_t(2)) +
                            pack(std::uint64_t(3)) + pack(std::uint64_t(4));
    const std::size_t at_e = bytes.find(rec, bytes.find("$Elements"));
    REQUIRE(at_e != std::string::npos);
    std::string range_bytes = bytes;
    range_bytes.replace(at_e + 16, 8, pack(std::uint64_t(999)));
    auto fr = write("binrange.msh", range_bytes);
    CHECK_THROWS_WITH_AS(io::read_mesh(fr), doctest::Contains("refers to node 999"), io::MeshIOError);
    const std::string off_e = "byte offset " + std::to_string(at_e + 16) + ":";
    CHECK_THROWS_WITH_AS(io::read_mesh(fr), doctest::Contains(off_e.c_str()), io::MeshIOError);
  }
  CHECK(run_cmd("quality", {}) == 2);
}

TEST_CASE("quality --json and convert commands, artifact type 'mesh' is registered") {
  auto out = tmpdir() / "conv.vtu";
  CHECK(run_cmd("convert", {kData + "v4.1_cube_prism.msh", out.string()}) == 0);
  CHECK(fs::file_size(out) > 1000);
  auto xml = tmpdir() / "conv.xml";
  CHECK(run_cmd("convert", {kData + "v2.2_varopti_cube_sphere.msh", xml.string()}) == 0);
  auto back = io::read_mesh(xml);
  size_t tets = 0;
  for (auto& b : back.blocks) tets += b.shape == Shape::Tet ? b.size() : 0;
  CHECK(tets == 276);
  CHECK(run_cmd("quality", {kData + "v4.1_cube_all.msh", "--json"}) == 0);
  auto s = mesh_stats(io::read_mesh(kData + "v4.1_cube_all.msh"));
  for (const char* k : {"order", "nodes", "elements", "invalid", "nonconforming_faces", "min_scaled_jacobian", "max_aspect_ratio"})
    CHECK(s.contains(k));
  for (const char* k : {"tet", "prism", "hex", "pyramid"}) CHECK(s["elements"].contains(k));
  const ArtifactType* t = find_artifact_type("mesh");
  REQUIRE(t);
  CHECK(t->extension == ".msh");
  CHECK(t->formats.count("vtu") == 1);
  auto stored = tmpdir() / "stored.msh";
  io::write_msh(io::read_mesh(kData + "v4.1_cube_tet.msh"), stored);
  CHECK(t->summarize(stored)["elements"]["tet"] == 48);
  auto exported = tmpdir() / "exported.xml";
  t->formats.at("nektar").write(stored, exported);
  CHECK(fs::file_size(exported) > 1000);
}

TEST_CASE("Gmsh-made meshes of every 3D type (data/highorder) survive msh -> Nektar++ xml -> model") {
  for (std::string f : {"v4.1_cube_all.msh", "v4.1_cube_hex.msh", "v4.1_cube_prism.msh", "v4.1_cube_tet.msh"}) {
    INFO(f);
    Mesh m = io::read_mesh(kData + f);
    auto x = tmpdir() / "cube.xml";
    io::write_nektar(m, x);
    Mesh r = io::read_mesh(x);
    auto a = mesh_stats(m), b = mesh_stats(r);
    CHECK(a["order"] == b["order"]);
    CHECK(a["elements"] == b["elements"]);
    CHECK(a["boundary"] == b["boundary"]);
    CHECK(b["invalid"] == 0);
    CHECK(b["nonconforming_faces"] == 0);
    for (int k = 0; k < 6; ++k)  // edge points pass through Nektar++'s interpolation: rounding only
      CHECK(b["bbox"][k].get<double>() == doctest::Approx(a["bbox"][k].get<double>()).epsilon(1e-11));
    CHECK(b["min_scaled_jacobian"].get<double>() == doctest::Approx(a["min_scaled_jacobian"].get<double>()).epsilon(1e-9));
  }
}

TEST_CASE("MSH with parametric node coordinates: Gmsh reads ours, meshio 5 reads the msh-plain export and convert --no-parametric") {
  // A Gmsh-made order-2 mesh of a sphere in a box with Mesh.SaveParametric: nodes on the sphere
  // and on the box's curves carry (u, v) / u. We keep them through read and write (Gmsh reads our
  // file back with the same counts and parameters); meshio 5 refuses parametric node blocks
  // ("parametric nodes not implemented"), so the artifact type has the msh-plain format and
  // convert has --no-parametric, and meshio reads those with the same counts.
  auto src = tmpdir() / "param_src.msh";
  python("import gmsh\ngmsh.initialize()\ngmsh.option.setNumber('General.Terminal',0)\n"
         "gmsh.model.occ.addBox(-1,-1,-1,2,2,2,1)\ngmsh.model.occ.addSphere(0,0,0,0.5,2)\n"
         "gmsh.model.occ.cut([(3,1)],[(3,2)])\ngmsh.model.occ.synchronize()\n"
         "gmsh.option.setNumber('Mesh.MeshSizeMax',0.4)\ngmsh.model.mesh.generate(3)\ngmsh.model.mesh.setOrder(2)\n"
         "gmsh.option.setNumber('Mesh.SaveParametric',1)\ngmsh.option.setNumber('Mesh.Binary',1)\n"
         "gmsh.write('" + src.string() + "')\n");
  Mesh m = io::read_mesh(src);
  REQUIRE(m.has_parametric());
  std::size_t with_uv = 0;
  double uv_sum = 0;  // what Gmsh must read back from our file: sum of |u| + |v| over surface nodes
  for (std::size_t i = 0; i < m.num_nodes(); ++i)
    if (!m.node_entity_dim.empty() && m.node_entity_dim[i] == 2 && std::isfinite(m.node_v[i]))
      ++with_uv, uv_sum += std::abs(m.node_u[i]) + std::abs(m.node_v[i]);
  CHECK(with_uv > 50);
  char uv_text[64];
  std::snprintf(uv_text, sizeof uv_text, "%.9g", uv_sum);
  auto ours = tmpdir() / "param_ours.msh";
  io::write_msh(m, ours);
  const ArtifactType* t = find_artifact_type("mesh");
  REQUIRE(t);
  REQUIRE(t->formats.count("msh-plain") == 1);
  auto plain = tmpdir() / "param_plain.msh";
  t->formats.at("msh-plain").write(ours, plain);
  auto conv = tmpdir() / "param_conv.msh";
  CHECK(run_cmd("convert", {ours.string(), conv.string(), "--no-parametric"}) == 0);
  CHECK_FALSE(io::read_mesh(plain).has_parametric());
  std::string script = "import gmsh, meshio\ngmsh.initialize()\ngmsh.option.setNumber('General.Terminal',0)\n";
  for (auto& f : {ours, plain, conv})
    script += "gmsh.clear()\ngmsh.open('" + f.string() + "')\nnt,_,p=gmsh.model.mesh.getNodes(2,-1,False,True)\n"
              "_,tags,_=gmsh.model.mesh.getElements()\nnall,_,_=gmsh.model.mesh.getNodes()\n"
              "print('gmsh', len(nall), sum(len(x) for x in tags), '%.9g' % sum(abs(x) for x in p))\n"
              "try:\n  mm=meshio.gmsh.read('" + f.string() + "')\n  print('meshio', len(mm.points), sum(len(c.data) for c in mm.cells))\n"
              "except meshio.ReadError as e:\n  print('meshio-refused', 'parametric' in str(e))\n";
  std::istringstream out(python(script));
  std::vector<std::string> lines;
  for (std::string line; std::getline(out, line);)
    if (line.rfind("gmsh ", 0) == 0 || line.rfind("meshio", 0) == 0) lines.push_back(line);
  const std::string counts = std::to_string(m.num_nodes()) + " " + std::to_string(m.num_elements());
  REQUIRE(lines.size() == 6);
  CHECK(lines[0] == "gmsh " + counts + " " + uv_text);  // ours: Gmsh reads the surface nodes' (u, v)
  CHECK(lines[1] == "meshio-refused True");              // meshio 5's own limit
  CHECK(lines[2] == "gmsh " + counts + " 0");            // plain: no parameters
  CHECK(lines[3] == "meshio " + counts);
  CHECK(lines[4] == "gmsh " + counts + " 0");
  CHECK(lines[5] == "meshio " + counts);
}

TEST_CASE("solver-ready MSH: every element in a physical group, meshio and Gmsh agree, PyFR's importer rules hold") {
  // A Gmsh-made order-4 tet mesh of a box (no pyramids: meshio 5 has every order-4 type but the
  // pyramid) written with Mesh.SaveAll, so that the box's curves and corners carry elements in no
  // physical group, as our stages' meshes do. Case A names the faces periodic_lo / periodic_hi /
  // wall and the volume 'fluid' with tag 1, the tag of a face group too (PyFR refuses both); case
  // B has no volume group (make_solver_ready makes 'fluid').
  const std::string rules = std::string(MESHFLOW_SOURCE_DIR) + "/tests/io/pyfr_rules.py";
  for (bool volume_group : {true, false}) {
    INFO("volume group: " << volume_group);
    auto src = tmpdir() / "sr_src.msh";
    python(std::string("import gmsh\ngmsh.initialize()\ngmsh.option.setNumber('General.Terminal',0)\n"
                       "gmsh.model.occ.addBox(0,0,0,1,1,1,1)\ngmsh.model.occ.synchronize()\n"
                       "gmsh.model.addPhysicalGroup(2,[1],1)\ngmsh.model.setPhysicalName(2,1,'periodic_lo')\n"
                       "gmsh.model.addPhysicalGroup(2,[2],2)\ngmsh.model.setPhysicalName(2,2,'periodic_hi')\n"
                       "gmsh.model.addPhysicalGroup(2,[3,4,5,6],3)\ngmsh.model.setPhysicalName(2,3,'wall')\n") +
           (volume_group ? "gmsh.model.addPhysicalGroup(3,[1],1)\ngmsh.model.setPhysicalName(3,1,'fluid')\n" : "") +
           "gmsh.option.setNumber('Mesh.MeshSizeMax',0.5)\ngmsh.model.mesh.generate(3)\ngmsh.model.mesh.setOrder(4)\n"
           "gmsh.option.setNumber('Mesh.SaveAll',1)\ngmsh.option.setNumber('Mesh.Binary',1)\n"
           "gmsh.write('" + src.string() + "')\n");
    Mesh m = io::read_mesh(src);
    std::size_t vol = 0, tagged_faces = 0, loose = 0;
    for (auto& b : m.blocks) {
      if (b.entity_dim == 3) vol += b.size();
      else if (b.entity_dim == 2) tagged_faces += b.size();
      else loose += b.size();
    }
    REQUIRE(loose > 0);  // curve and point elements in no physical group: what readers choke on
    auto stored = tmpdir() / "sr_stored.msh";
    io::write_msh(m, stored);
    const ArtifactType* t = find_artifact_type("mesh");
    REQUIRE(t);
    auto plain = tmpdir() / "sr.plain.msh", pyfr = tmpdir() / "sr.pyfr.msh", ascii = tmpdir() / "sr.ascii.msh";
    t->formats.at("msh-plain").write(stored, plain);
    t->formats.at("pyfr").write(stored, pyfr);
    t->formats.at("msh-ascii").write(stored, ascii);
    auto conv = tmpdir() / "sr_conv.msh";
    CHECK(run_cmd("convert", {stored.string(), conv.string()}) == 0);  // convert's default is solver-ready too

    Mesh r = io::read_mesh(plain);
    CHECK_FALSE(r.has_parametric());
    std::size_t r_vol = 0, r_faces = 0, r_loose = 0;
    for (auto& b : r.blocks) (b.entity_dim == 3 ? r_vol : b.entity_dim == 2 ? r_faces : r_loose) += b.size();
    CHECK(r_vol == vol);  // no volume element is ever dropped
    CHECK(r_faces == tagged_faces);
    CHECK(r_loose == 0);
    std::set<std::string> names;
    for (auto& p : r.physicals) names.insert(std::to_string(p.dim) + ":" + p.name);
    CHECK(names == std::set<std::string>{"2:periodic_lo", "2:periodic_hi", "2:wall", "3:fluid"});

    // meshio and Gmsh read the solver-ready files with the same counts; meshio refuses the stored file
    const std::string counts = std::to_string(r.num_elements());
    std::string script = "import gmsh, meshio\ngmsh.initialize()\ngmsh.option.setNumber('General.Terminal',0)\n";
    for (auto& f : {plain, conv, ascii})
      script += "gmsh.clear()\ngmsh.open('" + f.string() + "')\n_,tags,_=gmsh.model.mesh.getElements()\n"
                "mm=meshio.read('" + f.string() + "')\nprint('both', sum(len(x) for x in tags), sum(len(c.data) for c in mm.cells),"
                " len(mm.cell_data['gmsh:physical']) == len(mm.cells))\n";
    script += "try:\n  meshio.read('" + stored.string() + "')\n  print('stored-read')\nexcept Exception as e:\n  print('stored-refused')\n";
    std::istringstream out(python(script));
    std::vector<std::string> lines;
    for (std::string line; std::getline(out, line);)
      if (line.rfind("both", 0) == 0 || line.rfind("stored", 0) == 0) lines.push_back(line);
    REQUIRE(lines.size() == 4);
    for (int k = 0; k < 3; ++k) CHECK(lines[k] == "both " + counts + " " + counts + " True");
    CHECK(lines[3] == "stored-refused");

    // PyFR's rules: the pyfr format passes with one volume group, two boundary groups and one
    // periodic pair; the others are refused for the reason PyFR would give
    auto rule = [&](const fs::path& f) {
      std::string o = python("import subprocess, sys\nr=subprocess.run([sys.executable,'" + rules + "','" + f.string() +
                             "'],capture_output=True,text=True)\nprint(r.stdout.strip())\n");
      return o.substr(0, o.find('\n'));
    };
    CHECK(rule(pyfr) == "ok " + std::to_string(r.num_nodes()) + " " + counts + " 1 1 1");
    CHECK(rule(stored).find("refused: not an ASCII file") == 0);
    const std::string a = rule(ascii);
    CHECK(a.find("refused: ") == 0);
    if (volume_group) CHECK(a.find("duplicate physical tag 1") != std::string::npos);
    else CHECK(a.find("periodic name 'periodic_lo'") != std::string::npos);
  }
}

namespace {
std::string file_bytes(const fs::path& p) {
  std::ifstream f(p, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(f), {});
}
}  // namespace

TEST_CASE("mesh_quality artifact: the VTU writer given the stage's stored quality does not recompute it, same bytes") {
  // A stage stores the quality its contract computed (io::write_quality) beside its mesh; the
  // runner loads the mesh once with that companion (ArtifactType::load) and the vtu format
  // writes from it (write_loaded). Fails if the writer computes the quality again (counter,
  // and a deliberately altered stored quality that must reach the file) or if the bytes
  // differ from a VTU whose quality is computed.
  const ArtifactType* t = find_artifact_type("mesh");
  REQUIRE(t);
  REQUIRE(t->load);
  REQUIRE(t->formats.at("vtu").write_loaded);
  REQUIRE(find_artifact_type("mesh_quality"));
  for (std::string f : {"v4.1_cube_all.msh", "v4.1_cube_prism.msh"}) {
    INFO(f);
    Mesh m = io::read_mesh(kData + f);
    m.block(Shape::Tet, 4, 3, 99);  // an empty block: not written to the MSH, skipped by the quality file too
    const auto stored = tmpdir() / "q_stored.msh", qfile = tmpdir() / "q_stored.quality";
    io::write_msh(m, stored);
    const MeshQuality q = mesh_quality(m, 2);
    io::write_quality(m, q, qfile);

    // round trip: every field of every element, aligned with the mesh as read back
    const Mesh back = io::read_msh(stored);
    const MeshQuality rq = io::read_quality(qfile, back);
    REQUIRE(rq.size() == back.blocks.size());
    std::size_t bi = 0, measured = 0;
    for (std::size_t b = 0; b < m.blocks.size(); ++b) {
      if (!m.blocks[b].size()) continue;
      REQUIRE(rq[bi].size() == q[b].size());
      for (std::size_t e = 0; e < q[b].size(); ++e) {
        CHECK(rq[bi][e].scaled_jacobian == q[b][e].scaled_jacobian);
        CHECK(rq[bi][e].aspect_ratio == q[b][e].aspect_ratio);
        CHECK(rq[bi][e].min_det == q[b][e].min_det);
        CHECK(rq[bi][e].max_det == q[b][e].max_det);
        CHECK(rq[bi][e].valid == q[b][e].valid);
        CHECK(rq[bi][e].inconclusive == q[b][e].inconclusive);
      }
      measured += q[b].size();
      ++bi;
    }
    CHECK(measured > 0);

    // the vtu format: with the stored quality, no mesh_quality call and the bytes of a computed one
    const auto computed_vtu = tmpdir() / "q_computed.vtu", stored_vtu = tmpdir() / "q_stored.vtu";
    t->formats.at("vtu").write(stored, computed_vtu);
    const Artifact companion{"quality", "mesh_quality", "", "stage", qfile};
    auto loaded = t->load(stored, {companion});
    const auto calls = mesh_quality_calls();
    t->formats.at("vtu").write_loaded(loaded.get(), stored_vtu);
    CHECK(mesh_quality_calls() == calls);
    CHECK(file_bytes(stored_vtu) == file_bytes(computed_vtu));
    // the other formats from the loaded mesh: the bytes of their standalone writers
    for (std::string fmt : {"nektar", "msh-plain"}) {
      INFO(fmt);
      const auto a = tmpdir() / ("q_a_" + fmt), b = tmpdir() / ("q_b_" + fmt);
      t->formats.at(fmt).write(stored, a);
      t->formats.at(fmt).write_loaded(loaded.get(), b);
      CHECK(file_bytes(a) == file_bytes(b));
    }

    // what the stored quality says is what the file says (not recomputed): altered values show
    MeshQuality altered = q;
    for (auto& blk : altered)
      for (auto& e : blk) e.scaled_jacobian = 0.123;
    const auto qalt = tmpdir() / "q_altered.quality", alt_vtu = tmpdir() / "q_altered.vtu";
    io::write_quality(m, altered, qalt);
    auto loaded_alt = t->load(stored, {Artifact{"quality", "mesh_quality", "", "stage", qalt}});
    t->formats.at("vtu").write_loaded(loaded_alt.get(), alt_vtu);
    CHECK(mesh_quality_calls() == calls);
    const std::string alt = file_bytes(alt_vtu);
    CHECK(alt != file_bytes(computed_vtu));
    const double v = 0.123;
    CHECK(alt.find(std::string(reinterpret_cast<const char*>(&v), sizeof v)) != std::string::npos);

    // without a companion (or one not of this mesh) the cell fields are computed: same bytes
    auto loaded_none = t->load(stored, {});
    const auto none_vtu = tmpdir() / "q_none.vtu";
    t->formats.at("vtu").write_loaded(loaded_none.get(), none_vtu);
    CHECK(mesh_quality_calls() == calls + 1);
    CHECK(file_bytes(none_vtu) == file_bytes(computed_vtu));
  }
  // a quality file that is not the mesh's, or is cut short, is refused by read_quality
  Mesh a = io::read_mesh(kData + "v4.1_cube_tet.msh"), b = io::read_mesh(kData + "v4.1_cube_hex.msh");
  const auto qa = tmpdir() / "q_a.quality";
  io::write_quality(a, mesh_quality(a), qa);
  CHECK_THROWS_AS(io::read_quality(qa, b), io::MeshIOError);
  std::string bytes = file_bytes(qa);
  {
    std::ofstream o(qa, std::ios::binary | std::ios::trunc);
    o.write(bytes.data(), (std::streamsize)bytes.size() - 3);
  }
  CHECK_THROWS_AS(io::read_quality(qa, a), io::MeshIOError);
}

namespace {
// resident set size of this process, in bytes (/proc/self/statm: pages)
std::size_t rss_bytes() {
  std::ifstream f("/proc/self/statm");
  std::size_t size = 0, resident = 0;
  f >> size >> resident;
  return resident * static_cast<std::size_t>(::sysconf(_SC_PAGESIZE));
}
}  // namespace

TEST_CASE("reading: a mapped file's parsed pages leave memory (release_before), the bytes read the same after") {
  const fs::path p = fs::temp_directory_path() / ("meshflow_release_" + std::to_string(::getpid()) + ".bin");
  const std::size_t n = 64u << 20;
  {
    std::ofstream o(p, std::ios::binary);
    std::string block(1u << 20, '\0');
    for (std::size_t b = 0; b < n / block.size(); ++b) {
      for (std::size_t i = 0; i < block.size(); ++i) block[i] = char((b * 131 + i * 7) & 0xff);
      o.write(block.data(), std::streamsize(block.size()));
    }
  }
  auto sum = [](std::string_view v) {
    std::uint64_t s = 0;
    for (std::size_t i = 0; i < v.size(); i += 4093) s = s * 31 + static_cast<unsigned char>(v[i]);
    return s;
  };
  {
    const io::detail::FileBytes data(p);
    const std::uint64_t before = sum(data.view());
    const std::size_t mapped = rss_bytes();
    data.release_before(n / 2);
    const std::size_t half = rss_bytes();
    data.release_before(n);
    const std::size_t none = rss_bytes();
    MESSAGE("RSS mapped " << mapped / 1048576 << " MB, half released " << half / 1048576 << " MB, all " << none / 1048576 << " MB");
    CHECK(mapped - half >= n / 2 - (1u << 20));  // the first half's pages left the process
    CHECK(mapped - none >= n - (1u << 20));
    CHECK(sum(data.view()) == before);  // read again: the same bytes, faulted in from the file
  }
  // the Cursor's hook: a reader calls done_before_here() where it has parsed everything before
  {
    const io::detail::FileBytes data(p);
    io::detail::Cursor c(p.string(), data.view());
    std::size_t asked = 0;
    c.on_done([&](std::size_t pos) { asked = pos, data.release_before(pos); });
    c.seek(n / 4);
    c.done_before_here();
    CHECK(asked == n / 4);
  }
  fs::remove(p);
}
