// CGNS output and input (stages/io/cgns.cpp): node orderings against facts stated by the
// CGNS/SIDS, round trips of Gmsh-made meshes of every 3D type at orders 1-4, cgnscheck (the
// CGNS project's own checker) on what we write, independent element counts (VTK's CGNS
// reader), byte-identical files, bad input.
#include <doctest/doctest.h>

#include "engine/artifact_type.hpp"
#include "engine/command.hpp"
#include "stages/io/cgns_layout.hpp"
#include "stages/io/mesh_io.hpp"
#include "stages/model/quality.hpp"

#include <cgnslib.h>
#include <nlohmann/json.hpp>

#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <regex>
#include <sstream>

using namespace meshflow;
using namespace meshflow::model;
namespace fs = std::filesystem;

namespace {

const std::string kData = std::string(MESHFLOW_DATA_DIR) + "/highorder/";

fs::path tmpdir() {
  static fs::path d = [] {
    auto p = fs::temp_directory_path() / ("mf_cgns_test_" + std::to_string(::getpid()));
    fs::create_directories(p);
    return p;
  }();
  return d;
}

// Runs a shell command; returns its exit code and fills `out` with stdout + stderr.
int shell(const std::string& cmd, std::string& out) {
  static int k = 0;
  auto o = tmpdir() / ("sh" + std::to_string(k++) + ".txt");
  int rc = std::system((cmd + " > " + o.string() + " 2>&1").c_str());
  std::ifstream in(o);
  std::stringstream ss;
  ss << in.rdbuf();
  out = ss.str();
  return WIFEXITED(rc) ? WEXITSTATUS(rc) : -1;
}

std::string slurp(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

// A curved, invertible map of the reference element: x = phi(xi).
Vec3 phi(const Vec3& r) { return {r[0] + 0.1 * r[1] * r[1], r[1] + 0.05 * r[2] * r[2], r[2]}; }
Vec3 phi_inverse(const Vec3& x) {
  const double z = x[2], y = x[1] - 0.05 * z * z;
  return {x[0] - 0.1 * y * y, y, z};
}

// Mesh of one element of shape s, order p: nodes at phi(Gmsh reference nodes), in Gmsh order.
Mesh curved_element(Shape s, int p) {
  Mesh m;
  std::vector<std::uint32_t> n;
  for (auto& r : reference_nodes(s, p)) {
    auto x = phi(r);
    n.push_back(m.add_node(x[0], x[1], x[2]));
  }
  m.add_physical(3, 1, "fluid");
  m.add_entity(3, 1, {1});
  m.block(s, p, 3, 1).add(n.data());
  return m;
}

// The element's nodes as written in the file, read with libcgns directly (not read_cgns), in
// CGNS order, mapped back to reference coordinates.
std::vector<Vec3> cgns_nodes_in_file(const fs::path& f) {
  int fn = 0;
  REQUIRE(cg_open(f.c_str(), CG_MODE_READ, &fn) == CG_OK);
  char name[33];
  cgsize_t size[3];
  REQUIRE(cg_zone_read(fn, 1, 1, name, size) == CG_OK);
  std::vector<double> X[3];
  const char* cn[3] = {"CoordinateX", "CoordinateY", "CoordinateZ"};
  for (int c = 0; c < 3; ++c) {
    X[c].resize(size[0]);
    cgsize_t lo = 1, hi = size[0];
    REQUIRE(cg_coord_read(fn, 1, 1, cn[c], CGNS_ENUMV(RealDouble), &lo, &hi, X[c].data()) == CG_OK);
  }
  cgsize_t n = 0;
  REQUIRE(cg_ElementDataSize(fn, 1, 1, 1, &n) == CG_OK);
  std::vector<cgsize_t> conn(n);
  REQUIRE(cg_elements_read(fn, 1, 1, 1, conn.data(), nullptr) == CG_OK);
  cg_close(fn);
  std::vector<Vec3> out;
  for (auto v : conn) out.push_back(phi_inverse({X[0][v - 1], X[1][v - 1], X[2][v - 1]}));
  return out;
}

struct Fact {  // CGNS node `node` (1-based, as the SIDS numbers it) = sum of w * N_k
  int node;
  std::vector<std::pair<int, double>> terms;
  bool nearest = false;  // only: of the nodes among[0]..among[1], `node` is the nearest to that point
  std::array<int, 2> among = {0, 0};
};
// The SIDS notes of the quartic types place face nodes at centroids of corner sub-triangles
// (TETRA_35: N23 at the centroid of N1-N12-N6, i.e. (1/6, 1/6) on the face), which are not the
// equispaced points (1/4, 1/4) the figures draw and Gmsh's and others' Lagrange bases use; what
// the notes fix is which node is which: of the face's (or slice's) nodes, which the SIDS tables
// list, the one nearest that centroid.
Fact sub_centroid(int n, std::vector<int> of, std::array<int, 2> among) {
  Fact f{n, {}, true, among};
  for (int k : of) f.terms.push_back({k, 1.0 / of.size()});
  return f;
}
Fact centroid(int n, std::vector<int> of) {
  Fact f{n, {}};
  for (int k : of) f.terms.push_back({k, 1.0 / of.size()});
  return f;
}
Fact para(int n, int a, int b, int c) { return {n, {{a, 1}, {b, 1}, {c, -1}}}; }  // a + b - c

struct TypeFacts {
  Shape shape;
  int order;
  std::vector<std::array<int, 2>> edges;  // the SIDS edge table (1-based vertices)
  std::vector<Fact> facts;                // face and interior nodes the SIDS locates
};

// Transcribed from CGNS/SIDS 3.3 (figures, edge tables and the notes locating face and
// interior nodes), independently of the generator in stages/io/cgns_layout.cpp.
std::vector<TypeFacts> sids_facts() {
  const std::vector<std::array<int, 2>> tet = {{1, 2}, {2, 3}, {3, 1}, {1, 4}, {2, 4}, {3, 4}};
  const std::vector<std::array<int, 2>> pyr = {{1, 2}, {2, 3}, {3, 4}, {4, 1}, {1, 5}, {2, 5}, {3, 5}, {4, 5}};
  const std::vector<std::array<int, 2>> pri = {{1, 2}, {2, 3}, {3, 1}, {1, 4}, {2, 5}, {3, 6}, {4, 5}, {5, 6}, {6, 4}};
  const std::vector<std::array<int, 2>> hex = {{1, 2}, {2, 3}, {3, 4}, {4, 1}, {1, 5}, {2, 6},
                                               {3, 7}, {4, 8}, {5, 6}, {6, 7}, {7, 8}, {8, 5}};
  std::vector<TypeFacts> t;
  for (int p = 1; p <= 4; ++p) {
    t.push_back({Shape::Tet, p, tet, {}});
    t.push_back({Shape::Pyramid, p, pyr, {}});
    t.push_back({Shape::Prism, p, pri, {}});
    t.push_back({Shape::Hex, p, hex, {}});
  }
  auto at = [&](Shape s, int p) -> std::vector<Fact>& {
    for (auto& x : t)
      if (x.shape == s && x.order == p) return x.facts;
    throw std::logic_error("no such type");
  };
  // quadratic: face centres in face order, volume centre
  at(Shape::Pyramid, 2) = {centroid(14, {1, 2, 3, 4})};
  at(Shape::Prism, 2) = {centroid(16, {1, 2, 5, 4}), centroid(17, {2, 3, 6, 5}), centroid(18, {3, 1, 4, 6})};
  at(Shape::Hex, 2) = {centroid(21, {1, 2, 3, 4}), centroid(22, {1, 2, 6, 5}), centroid(23, {2, 3, 7, 6}),
                       centroid(24, {3, 4, 8, 7}), centroid(25, {1, 5, 8, 4}), centroid(26, {5, 6, 7, 8}),
                       centroid(27, {1, 2, 3, 4, 5, 6, 7, 8})};
  // cubic
  at(Shape::Tet, 3) = {centroid(17, {1, 2, 3}), centroid(18, {1, 2, 4}), centroid(19, {2, 3, 4}), centroid(20, {3, 1, 4})};
  at(Shape::Pyramid, 3) = {para(22, 6, 13, 1), para(23, 7, 8, 2), para(24, 9, 10, 3), para(25, 11, 12, 4),
                           centroid(26, {1, 2, 5}), centroid(27, {2, 3, 5}), centroid(28, {3, 4, 5}), centroid(29, {4, 1, 5}),
                           {30, {{1, 1.0 / 6}, {2, 1.0 / 6}, {3, 1.0 / 6}, {4, 1.0 / 6}, {5, 1.0 / 3}}}};
  at(Shape::Prism, 3) = {centroid(25, {1, 2, 3}), para(26, 7, 13, 1), para(27, 8, 15, 2), para(28, 8, 16, 2),
                         para(29, 7, 14, 1),       para(30, 9, 15, 2),  para(34, 11, 17, 3), centroid(38, {4, 5, 6}),
                         centroid(39, {13, 17, 15}), centroid(40, {14, 18, 16})};
  at(Shape::Hex, 3) = {para(33, 9, 16, 1),  para(34, 10, 11, 2), para(37, 9, 17, 1),  para(38, 10, 19, 2),
                       para(49, 15, 23, 4), para(50, 16, 23, 4), para(51, 16, 24, 4), para(53, 25, 32, 5),
                       para(57, 33, 17, 1), para(61, 33, 18, 1), para(64, 36, 18, 1)};
  // quartic
  at(Shape::Tet, 4) = {sub_centroid(23, {1, 12, 6}, {23, 25}),  sub_centroid(24, {2, 6, 9}, {23, 25}),   sub_centroid(25, {3, 9, 12}, {23, 25}),
                       sub_centroid(26, {1, 6, 15}, {26, 28}),  sub_centroid(27, {2, 18, 6}, {26, 28}),  sub_centroid(28, {4, 15, 18}, {26, 28}),
                       sub_centroid(29, {2, 9, 18}, {29, 31}),  sub_centroid(30, {3, 21, 9}, {29, 31}),  sub_centroid(31, {4, 18, 21}, {29, 31}),
                       sub_centroid(32, {3, 12, 21}, {32, 34}), sub_centroid(33, {1, 15, 12}, {32, 34}), sub_centroid(34, {4, 21, 15}, {32, 34}),
                       centroid(35, {1, 2, 3, 4})};
  at(Shape::Pyramid, 4) = {para(30, 6, 17, 1),        para(31, 7, 17, 1),        para(32, 8, 9, 2),
                           para(34, 11, 12, 3),       para(36, 14, 15, 4),       centroid(38, {1, 2, 3, 4}),
                           sub_centroid(39, {1, 7, 19}, {39, 41}),  sub_centroid(40, {2, 22, 7}, {39, 41}),  sub_centroid(41, {5, 19, 22}, {39, 41}),
                           sub_centroid(42, {2, 10, 22}, {42, 44}), sub_centroid(43, {3, 25, 10}, {42, 44}), sub_centroid(44, {5, 22, 25}, {42, 44}),
                           sub_centroid(45, {3, 13, 25}, {45, 47}), sub_centroid(46, {4, 28, 13}, {45, 47}), sub_centroid(47, {5, 25, 28}, {45, 47}),
                           sub_centroid(48, {4, 16, 28}, {48, 50}), sub_centroid(49, {1, 19, 16}, {48, 50}), sub_centroid(50, {5, 28, 19}, {48, 50}),
                           // N51..N54 in the plane of N18, N21, N24, N27, each above its base node
                           // N30, N32, N34, N36 (the figure; on the lattice, see cgns_layout.cpp)
                           para(51, 18, 30, 1),       para(52, 21, 32, 2),       para(53, 24, 34, 3),
                           para(54, 27, 36, 4),       centroid(55, {19, 22, 25, 28})};
  at(Shape::Prism, 4) = {sub_centroid(34, {1, 14, 8}, {34, 36}),   sub_centroid(35, {2, 8, 11}, {34, 36}),   sub_centroid(36, {3, 11, 14}, {34, 36}),
                         para(37, 7, 16, 1),         para(38, 8, 16, 1),         para(39, 9, 19, 2),
                         centroid(45, {1, 2, 5, 4}), para(46, 10, 19, 2),        para(55, 13, 22, 3),
                         para(57, 15, 16, 1),        sub_centroid(64, {4, 26, 32}, {64, 66}),  sub_centroid(65, {5, 29, 26}, {64, 66}),
                         sub_centroid(66, {6, 32, 29}, {64, 66}),  sub_centroid(67, {16, 38, 56}, {67, 69}), sub_centroid(68, {19, 47, 38}, {67, 69}),
                         sub_centroid(69, {22, 56, 47}, {67, 69}), sub_centroid(70, {17, 45, 63}, {70, 72}), sub_centroid(71, {20, 54, 45}, {70, 72}),
                         sub_centroid(72, {23, 63, 54}, {70, 72}), sub_centroid(73, {18, 42, 60}, {73, 75}), sub_centroid(74, {21, 51, 42}, {73, 75}),
                         sub_centroid(75, {24, 60, 51}, {73, 75})};
  at(Shape::Hex, 4) = {para(45, 9, 20, 1),   para(46, 10, 20, 1),  para(47, 11, 12, 2),  centroid(53, {1, 2, 3, 4}),
                       para(54, 9, 21, 1),   para(56, 11, 24, 2),  para(63, 12, 24, 2),  para(72, 15, 27, 3),
                       para(81, 18, 30, 4),  para(82, 19, 30, 4),  para(83, 20, 30, 4),  para(84, 20, 31, 4),
                       para(90, 33, 44, 5),  para(99, 45, 21, 1),  para(100, 46, 21, 1), para(107, 53, 21, 1),
                       para(108, 45, 22, 1), centroid(116, {1, 2, 3, 4, 5, 6, 7, 8}), para(125, 53, 23, 1)};
  return t;
}

Mesh gmsh_made(const fs::path& msh) { return io::read_mesh(msh); }

// Gmsh-made meshes of every 3D type (the linear mixed cube of data/highorder, its orders raised
// by Gmsh's setOrder to 2, 3, 4), its unnamed groups replaced by wall, farfield, symmetry
// (every third surface each) and fluid.
const std::vector<fs::path>& gmsh_cubes() {
  static std::vector<fs::path> files = [] {
    auto py = tmpdir() / "cubes.py";
    std::ofstream(py) << "import gmsh, sys\n"
                         "for p in (1, 2, 3, 4):\n"
                         "    gmsh.initialize(); gmsh.option.setNumber('General.Terminal', 0)\n"
                         "    gmsh.open(sys.argv[1]); gmsh.model.removePhysicalGroups()\n"
                         "    surf = [t for d, t in gmsh.model.getEntities(2)]\n"
                         "    for g, name in ((1, 'wall'), (2, 'farfield'), (3, 'symmetry')):\n"
                         "        gmsh.model.setPhysicalName(2, gmsh.model.addPhysicalGroup(2, surf[g - 1::3], g), name)\n"
                         "    vol = [t for d, t in gmsh.model.getEntities(3)]\n"
                         "    gmsh.model.setPhysicalName(3, gmsh.model.addPhysicalGroup(3, vol, 10), 'fluid')\n"
                         "    if p > 1: gmsh.model.mesh.setOrder(p)\n"
                         "    gmsh.option.setNumber('Mesh.SaveAll', 0)\n"
                         "    gmsh.write(sys.argv[2] + '/cube_p%d.msh' % p)\n"
                         "    gmsh.finalize()\n";
    std::string out;
    REQUIRE_MESSAGE(shell(std::string(MESHFLOW_PYTHON) + " " + py.string() + " " + kData + "v4.1_cube_all.msh " +
                              tmpdir().string(), out) == 0, out);
    std::vector<fs::path> f;
    for (int p = 1; p <= 4; ++p) f.push_back(tmpdir() / ("cube_p" + std::to_string(p) + ".msh"));
    return f;
  }();
  return files;
}

// Concatenated node lists per (dimension, group name, shape, order), in block order.
std::map<std::tuple<int, std::string, int, int>, std::vector<std::uint32_t>> connectivity(const Mesh& m) {
  std::map<std::tuple<int, std::string, int, int>, std::vector<std::uint32_t>> c;
  const int dim = m.dimension();
  for (auto& b : m.blocks) {
    const int d = dimension(b.shape);
    if (d < dim - 1) continue;
    auto& v = c[{d, d == dim ? "" : m.group_name(b.entity_dim, b.entity_tag), static_cast<int>(b.shape), b.order}];
    v.insert(v.end(), b.nodes.begin(), b.nodes.end());
  }
  return c;
}

int run_cmd(const std::string& name, std::vector<std::string> args) {
  const Command* c = find_command(name);
  REQUIRE(c != nullptr);
  return c->run(args);
}

}  // namespace

TEST_CASE("CGNS node orderings: every type of orders 1-4 puts its nodes where the CGNS/SIDS says") {
  int checked = 0;
  for (auto& t : sids_facts()) {
    INFO(shape_name(t.shape) << " order " << t.order);
    const int p = t.order, nv = num_vertices(t.shape);
    // a bijection onto Gmsh's nodes
    auto perm = io::detail::cgns_to_gmsh(t.shape, p);
    std::sort(perm.begin(), perm.end());
    for (int i = 0; i < (int)perm.size(); ++i) REQUIRE(perm[i] == i);
    // through a file: written by write_cgns, read with libcgns, positions mapped back by phi^-1
    auto f = tmpdir() / "one.cgns";
    io::write_cgns(curved_element(t.shape, p), f);
    const auto N = cgns_nodes_in_file(f);
    REQUIRE((int)N.size() == num_nodes(t.shape, p));
    auto near = [](const Vec3& a, const Vec3& b) { return std::abs(a[0] - b[0]) + std::abs(a[1] - b[1]) + std::abs(a[2] - b[2]) < 1e-12; };
    const auto& V = reference_nodes(t.shape, 1);
    for (int k = 0; k < nv; ++k) CHECK(near(N[k], V[k]));
    for (size_t e = 0; e < t.edges.size(); ++e)
      for (int j = 1; j < p; ++j) {
        const Vec3 &a = V[t.edges[e][0] - 1], &b = V[t.edges[e][1] - 1];
        const double s = double(j) / p;
        INFO("edge E" << e + 1 << " node " << j);
        CHECK(near(N[nv + e * (p - 1) + j - 1], Vec3{a[0] + s * (b[0] - a[0]), a[1] + s * (b[1] - a[1]), a[2] + s * (b[2] - a[2])}));
        ++checked;
      }
    for (auto& fact : t.facts) {
      Vec3 x{0, 0, 0};
      for (auto [k, w] : fact.terms)
        for (int c = 0; c < 3; ++c) x[c] += w * N[k - 1][c];
      INFO("N" << fact.node);
      if (fact.nearest) {
        auto d = [&](const Vec3& a) { return std::hypot(a[0] - x[0], a[1] - x[1], a[2] - x[2]); };
        int best = fact.among[0] - 1;
        for (int k = fact.among[0] - 1; k < fact.among[1]; ++k)
          if (d(N[k]) < d(N[best])) best = k;
        CHECK(best + 1 == fact.node);
      } else {
        CHECK(near(N[fact.node - 1], x));
      }
      ++checked;
    }
  }
  CHECK(checked > 300);
}

TEST_CASE("CGNS round trip of Gmsh-made meshes of every 3D type at orders 1-4: counts, nodes, connectivity, groups") {
  for (auto& f : gmsh_cubes()) {
    INFO(f);
    Mesh m = gmsh_made(f);
    auto c = tmpdir() / "cube.cgns";
    io::write_cgns(m, c);
    Mesh r = io::read_mesh(c);  // by extension
    auto a = mesh_stats(m), b = mesh_stats(r);
    CHECK(a["order"] == b["order"]);
    CHECK(a["elements"] == b["elements"]);
    CHECK(a["boundary"] == b["boundary"]);
    CHECK(a["by_type"] != nullptr);
    CHECK(b["groups"]["wall"] == a["groups"]["wall"]);
    CHECK(b["groups"]["farfield"] == a["groups"]["farfield"]);
    CHECK(b["groups"]["symmetry"] == a["groups"]["symmetry"]);
    CHECK(b["groups"]["fluid"] == a["groups"]["fluid"]);
    CHECK(b["invalid"] == 0);
    CHECK(b["nonconforming_faces"] == 0);
    REQUIRE(r.num_nodes() == m.num_nodes());
    CHECK(r.x == m.x);
    CHECK(r.y == m.y);
    CHECK(r.z == m.z);
    CHECK(connectivity(r) == connectivity(m));
  }
  // every type present at order 4
  auto s = mesh_stats(gmsh_made(gmsh_cubes().back()));
  for (auto t : {"tet4", "pyramid4", "prism4", "hex4", "tri4", "quad4"}) CHECK(s["by_type"].value(t, 0) > 0);
}

TEST_CASE("CGNS: cgnscheck accepts what we write, VTK's CGNS reader counts the same elements, bytes are deterministic") {
  for (auto& f : gmsh_cubes()) {
    INFO(f);
    Mesh m = gmsh_made(f);
    auto c = tmpdir() / "check.cgns";
    io::write_cgns(m, c);
    std::string out;
    const int rc = shell("cgnscheck " + c.string(), out);
    INFO(out);
    CHECK(rc == 0);
    // cgnscheck reports "ERROR:" and "WARNING:" lines; none of either is expected
    CHECK(out.find("ERROR") == std::string::npos);
    CHECK(out.find("WARNING") == std::string::npos);
    // same mesh, same bytes
    auto c2 = tmpdir() / "check2.cgns";
    io::write_cgns(m, c2);
    CHECK(slurp(c) == slurp(c2));
    // element counts seen by an independent reader: VTK 9.1's CGNS reader loads the zone's
    // cells (its boundary patches only for BCWall-like types and orders <= 2)
    auto s = mesh_stats(m);
    std::size_t cells = 0;
    for (auto& [k, v] : s["elements"].items()) cells += v.get<std::size_t>();
    auto py = tmpdir() / "vtkcount.py";
    std::ofstream(py) << "import sys, vtk\n"
                         "vtk.vtkObject.GlobalWarningDisplayOff()\n"
                         "r = vtk.vtkCGNSReader(); r.SetFileName(sys.argv[1]); r.UpdateInformation()\n"
                         "r.EnableAllBases(); r.Update()\n"
                         "it = r.GetOutput().NewIterator(); it.InitTraversal(); n = 0\n"
                         "while not it.IsDoneWithTraversal():\n"
                         "    n += it.GetCurrentDataObject().GetNumberOfCells(); it.GoToNextItem()\n"
                         "print('cells', n)\n";
    REQUIRE(shell(std::string(MESHFLOW_PYTHON) + " " + py.string() + " " + c.string(), out) == 0);
    INFO(out);
    CHECK(out.find("cells " + std::to_string(cells) + "\n") != std::string::npos);
  }
}

TEST_CASE("CGNS order 2: VTK's CGNS reader puts every node of every cell where our VTU has it") {
  // VTK 9.1 maps TETRA_10, PYRA_14, PENTA_18 and HEXA_27 to its quadratic cells with its own
  // CGNS permutations: an ordering check independent of ours (VTK reads higher orders as
  // quadratic cells, so it is no check there). Cells are matched by their vertex count and
  // vertices' centroid; VTK keeps the pyramid's base centre (14 points) where our VTU has 13: each of
  // our VTU cell's points is compared.
  Mesh m = gmsh_made(gmsh_cubes()[1]);
  auto c = tmpdir() / "q.cgns", v = tmpdir() / "q.vtu";
  io::write_cgns(m, c);
  io::write_vtu(m, v);
  auto py = tmpdir() / "vtkorder.py";
  std::ofstream(py) << "import sys, vtk\n"
                       "vtk.vtkObject.GlobalWarningDisplayOff()\n"
                       "r = vtk.vtkCGNSReader(); r.SetFileName(sys.argv[1]); r.UpdateInformation(); r.EnableAllBases(); r.Update()\n"
                       "it = r.GetOutput().NewIterator(); it.InitTraversal(); cg = it.GetCurrentDataObject()\n"
                       "x = vtk.vtkXMLUnstructuredGridReader(); x.SetFileName(sys.argv[2]); x.Update(); ug = x.GetOutput()\n"
                       "def cells(g, dim):\n"
                       "    out = {}\n"
                       "    for i in range(g.GetNumberOfCells()):\n"
                       "        c = g.GetCell(i)\n"
                       "        if c.GetCellDimension() != dim: continue\n"
                       "        pts = [tuple(round(v, 12) for v in c.GetPoints().GetPoint(k)) for k in range(c.GetNumberOfPoints())]\n"
                       "        nv = {24: 4, 71: 4, 27: 5, 32: 6, 73: 6, 29: 8, 72: 8}[c.GetCellType()]\n"
                       "        key = (nv,) + tuple(round(sum(p[d] for p in pts[:nv]) / nv, 9) for d in range(3))\n"
                       "        out[key] = (c.GetCellType(), pts)\n"
                       "    return out\n"
                       "a, b = cells(cg, 3), cells(ug, 3)\n"
                       "same = sum(1 for k in a if k in b and len(a[k][1]) >= len(b[k][1]) and a[k][1][:len(b[k][1])] == b[k][1])\n"
                       "print('cells', len(a), len(b), 'same', same, 'types', sorted(set(t for t, p in a.values())))\n";
  std::string out;
  REQUIRE(shell(std::string(MESHFLOW_PYTHON) + " " + py.string() + " " + c.string() + " " + v.string(), out) == 0);
  INFO(out);
  auto s = mesh_stats(m);
  std::size_t cells = 0;
  for (auto& [k, n] : s["elements"].items()) cells += n.get<std::size_t>();
  const std::string n = std::to_string(cells);
  CHECK(out.find("cells " + n + " " + n + " same " + n + " ") != std::string::npos);
}

TEST_CASE("CGNS bad input: missing file, not CGNS, truncated, order 5-6 meshes, convert exits 2 and leaves no file") {
  auto expect_error = [](const fs::path& p, const std::string& msg) {
    INFO(p);
    try {
      io::read_mesh(p);
      FAIL("no error");
    } catch (const io::MeshIOError& e) {
      CHECK(std::string(e.what()).find(p.string()) != std::string::npos);
      CHECK_MESSAGE(std::string(e.what()).find(msg) != std::string::npos, e.what());
    }
  };
  expect_error(tmpdir() / "missing.cgns", "no such file");
  auto text = tmpdir() / "text.cgns";
  std::ofstream(text) << "this is not a CGNS file\n";
  expect_error(text, "not a CGNS file");
  auto good = tmpdir() / "good.cgns";
  io::write_cgns(gmsh_made(gmsh_cubes()[1]), good);
  auto trunc = tmpdir() / "trunc.cgns";
  {
    std::string b = slurp(good);
    std::ofstream(trunc, std::ios::binary) << b.substr(0, b.size() / 2);
  }
  expect_error(trunc, "CGNS");
  // orders CGNS has no type for: Gmsh's order-6 tets and order-5 hexes
  for (std::string f : {"v4.1_cube_tet.msh", "v4.1_cube_hex.msh"}) {
    auto out = tmpdir() / (f + ".cgns");
    try {
      io::write_cgns(io::read_mesh(kData + f), out);
      FAIL("no error");
    } catch (const io::MeshIOError& e) {
      CHECK_MESSAGE(std::string(e.what()).find("quartic") != std::string::npos, e.what());
    }
    CHECK(!fs::exists(out));
    CHECK(run_cmd("convert", {kData + f, out.string()}) == 2);
    CHECK(!fs::exists(out));
  }
  CHECK(run_cmd("convert", {text.string(), (tmpdir() / "x.msh").string()}) == 2);
  for (auto& e : fs::directory_iterator(tmpdir())) CHECK(e.path().string().find(".tmp") == std::string::npos);
}

TEST_CASE("CGNS: convert x.msh y.cgns and back, and the 'cgns' format of the mesh artifact") {
  auto msh = gmsh_cubes()[3];
  auto c = tmpdir() / "conv.cgns", back = tmpdir() / "back.msh";
  CHECK(run_cmd("convert", {msh.string(), c.string()}) == 0);
  CHECK(run_cmd("convert", {c.string(), back.string()}) == 0);
  auto a = mesh_stats(io::read_mesh(msh)), b = mesh_stats(io::read_mesh(back));
  CHECK(a["elements"] == b["elements"]);
  CHECK(a["boundary"] == b["boundary"]);
  CHECK(a["by_type"] == b["by_type"]);
  const ArtifactType* t = find_artifact_type("mesh");
  REQUIRE(t != nullptr);
  bool has = false;
  for (auto& [name, f] : t->formats) has = has || (name == "cgns" && f.extension == ".cgns");
  CHECK(has);
}
