// The mesh contract (stages/contract): each clause on a mesh built to break exactly that clause,
// and the unbroken mesh at orders 1 and 4 passing every clause with its volume and face areas
// integrated exactly.
#include <doctest/doctest.h>

#include "engine/stage.hpp"
#include "stages/contract/contract.hpp"
#include "stages/model/element.hpp"
#include "stages/model/topology.hpp"
#include "support.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <map>
#include <tuple>

using namespace meshflow;
using model::Mesh;
using model::Shape;
using nlohmann::json;
namespace fs = std::filesystem;

namespace {

// The unit cube [0,1]^3 as 6 tetrahedra of order P (Kuhn's subdivision, conforming), with the
// boundary triangles on six entities 1..6 (x=0, x=1, y=0, y=1, z=0, z=1), all tagged "wall".
struct Cube {
  Mesh m;
  std::map<std::tuple<long, long, long>, std::uint32_t> at;
  std::uint32_t node(double x, double y, double z) {
    auto k = std::make_tuple(std::lround(x * 1e6), std::lround(y * 1e6), std::lround(z * 1e6));
    auto it = at.find(k);
    if (it != at.end()) return it->second;
    return at[k] = m.add_node(x, y, z);
  }
  explicit Cube(int P, bool boundary = true) {
    m.add_physical(3, 1, "fluid");
    m.add_entity(3, 1, {1});
    m.add_physical(2, 1, "wall");
    for (int f = 1; f <= 6; ++f) m.add_entity(2, f, {1});
    const double V[8][3] = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {1, 1, 0}, {0, 0, 1}, {1, 0, 1}, {0, 1, 1}, {1, 1, 1}};
    // Kuhn: paths 0 -> 7 along the axes in every order
    const int tets[6][4] = {{0, 1, 3, 7}, {0, 1, 5, 7}, {0, 2, 3, 7}, {0, 2, 6, 7}, {0, 4, 5, 7}, {0, 4, 6, 7}};
    auto& blk = m.block(Shape::Tet, P, 3, 1);
    const auto& ref = model::reference_nodes(Shape::Tet, P);
    for (auto& t : tets) {
      double a[4][3];
      for (int v = 0; v < 4; ++v)
        for (int k = 0; k < 3; ++k) a[v][k] = V[t[v]][k];
      // positive orientation
      double d1[3], d2[3], d3[3];
      for (int k = 0; k < 3; ++k) d1[k] = a[1][k] - a[0][k], d2[k] = a[2][k] - a[0][k], d3[k] = a[3][k] - a[0][k];
      double det = d1[0] * (d2[1] * d3[2] - d2[2] * d3[1]) - d1[1] * (d2[0] * d3[2] - d2[2] * d3[0]) +
                   d1[2] * (d2[0] * d3[1] - d2[1] * d3[0]);
      if (det < 0)
        for (int k = 0; k < 3; ++k) std::swap(a[1][k], a[2][k]);
      std::vector<std::uint32_t> nodes;
      for (auto& r : ref) {
        double p[3];
        for (int k = 0; k < 3; ++k) p[k] = a[0][k] + r[0] * (a[1][k] - a[0][k]) + r[1] * (a[2][k] - a[0][k]) + r[2] * (a[3][k] - a[0][k]);
        nodes.push_back(node(p[0], p[1], p[2]));
      }
      blk.add(nodes.data());
    }
    if (boundary) add_boundary(P);
  }
  void add_boundary(int P) {
    auto topo = model::build_topology(m);
    for (auto& f : topo.faces) {
      if (f.elements.size() != 1) continue;
      const auto& b = m.blocks[f.elements[0].block];
      const auto& fn = model::face_nodes(b.shape, b.order)[f.elements[0].local];
      const std::uint32_t* n = b.element(f.elements[0].element);
      double c[3] = {0, 0, 0};
      for (int k = 0; k < 3; ++k) {
        auto v = f.vertices[size_t(k)];
        c[0] += m.x[v] / 3, c[1] += m.y[v] / 3, c[2] += m.z[v] / 3;
      }
      int ent = 0;
      for (int ax = 0; ax < 3; ++ax)
        for (int side = 0; side < 2; ++side) {
          bool on = true;
          for (int k = 0; k < 3; ++k) {
            auto v = f.vertices[size_t(k)];
            double x = ax == 0 ? m.x[v] : ax == 1 ? m.y[v] : m.z[v];
            if (std::abs(x - side) > 1e-12) on = false;
          }
          if (on) ent = 1 + 2 * ax + side;
        }
      REQUIRE(ent > 0);
      std::vector<std::uint32_t> nodes;
      for (int ln : fn) nodes.push_back(n[ln]);
      m.block(Shape::Tri, P, 2, ent).add(nodes.data());
    }
  }
};

contract::CadReference cube_cad() {
  contract::CadReference c;
  c.volume = 1;
  for (int f = 1; f <= 6; ++f) c.faces.push_back({f, 1.0, "wall"});
  return c;
}

std::vector<std::string> clauses(const contract::Result& r) {
  std::vector<std::string> out;
  for (auto& p : r.problems) out.push_back(p["clause"].get<std::string>());
  return out;
}

// The "degenerate" problem of a mesh's check (fails the test when there is none).
json degenerate_problem(const Mesh& m) {
  auto r = contract::check(m, contract::Extent::NearField, nullptr, 1);
  INFO(r.problems.dump());
  for (auto& p : r.problems)
    if (p["clause"] == "degenerate") return p;
  FAIL("no degenerate problem");
  return {};
}

}  // namespace

TEST_CASE("contract: the unit cube passes every clause at orders 1 and 4 with exact volume and areas") {
  for (int P : {1, 4}) {
    CAPTURE(P);
    Cube c(P);
    auto cad = cube_cad();
    auto r = contract::check(c.m, contract::Extent::Domain, &cad, 1);
    INFO(r.problems.dump());
    CHECK(r.ok());
    CHECK(r.contract["volume"].get<double>() == doctest::Approx(1.0).epsilon(1e-12));
    CHECK(r.contract["face_area_worst_rel_error"].get<double>() < 1e-12);
    CHECK(r.contract["untagged_faces"] == 0);
    CHECK(r.contract["degenerate"] == 0);
    CHECK(r.mesh["elements"]["tet"] == 6);
  }
}

TEST_CASE("contract: a reference volume given as figures (split's input mesh) is compared like the CAD's") {
  Cube c(2);
  CHECK(contract::enclosed_volume(c.m) == doctest::Approx(1.0).epsilon(1e-12));
  contract::CadReference input;
  input.volume = 1.2;  // an input that filled more: this mesh lost part of the domain
  input.source = "the input mesh";
  auto r = contract::check(c.m, contract::Extent::Domain, &input, 1);
  REQUIRE(clauses(r) == std::vector<std::string>{"volume"});
  CHECK(r.problems[0]["what"].get<std::string>().find("the input mesh 1.2") != std::string::npos);
  CHECK(r.contract["reference"] == "the input mesh");
  input.volume = contract::enclosed_volume(c.m);
  CHECK(contract::check(c.m, contract::Extent::Domain, &input, 1).ok());
}

TEST_CASE("contract: a curved boundary's enclosed volume is integrated exactly at order 2") {
  // Move the mid-edge node of one boundary edge on the face z=1 outwards: the volume grows by
  // the integral of the quadratic bump, computed independently here.
  Cube c(2);
  // the P=2 tet nodes: mid-edge nodes of face z=1 lie at z=1; take the one at (0.5, 0.5, 1)
  std::uint32_t mid = UINT32_MAX;
  for (std::uint32_t i = 0; i < c.m.num_nodes(); ++i)
    if (std::abs(c.m.x[i] - 0.5) < 1e-12 && std::abs(c.m.y[i] - 0.5) < 1e-12 && std::abs(c.m.z[i] - 1) < 1e-12) mid = i;
  REQUIRE(mid != UINT32_MAX);
  const double h = 0.1;
  c.m.z[mid] += h;
  auto r = contract::check(c.m, contract::Extent::Domain, nullptr, 1);
  INFO(r.problems.dump());
  // The node is the midpoint of the diagonal shared by the two triangles of face z=1; on each
  // triangle the height is h * 4 l0 l1 (l0, l1 the barycentrics of the diagonal's ends), whose
  // integral over a triangle of area A is h * 4 * A / 12 = h A / 3; the two triangles (A = 1/2
  // each) add h / 3.
  CHECK(r.contract["volume"].get<double>() == doctest::Approx(1.0 + h / 3).epsilon(1e-12));
}

TEST_CASE("contract: an inverted element breaks validity (repairable: not blocking)") {
  Cube c(1);
  auto& b = c.m.blocks[0];
  std::swap(b.nodes[1], b.nodes[2]);  // first tet turned inside out
  auto r = contract::check(c.m, contract::Extent::Domain, nullptr, 1);
  REQUIRE(clauses(r) == std::vector<std::string>{"validity"});
  CHECK(r.problems[0]["count"] == 1);
  CHECK(r.problems[0]["blocking"] == false);
  CHECK(r.problems[0]["where"][0]["element"] == 1);
  CHECK(r.problems[0]["where"][0]["scaled_jacobian"].get<double>() < 0);
  CHECK(r.problems[0]["where"][0]["at"].size() == 3);
}

TEST_CASE("contract: area and volume off beside inverted elements are repairable (not blocking), off on a valid mesh they block") {
  // the mid-edge node at (0.5, 0.5, 1) of the P=2 cube's top face, pushed out a little (the
  // mesh stays valid) or deep into the cube (its tets fold, their top faces with them)
  for (double h : {0.2, -1.5}) {
    CAPTURE(h);
    Cube c(2);
    std::uint32_t mid = UINT32_MAX;
    for (std::uint32_t i = 0; i < c.m.num_nodes(); ++i)
      if (std::abs(c.m.x[i] - 0.5) < 1e-12 && std::abs(c.m.y[i] - 0.5) < 1e-12 && std::abs(c.m.z[i] - 1) < 1e-12) mid = i;
    REQUIRE(mid != UINT32_MAX);
    c.m.z[mid] += h;
    auto cad = cube_cad();
    auto r = contract::check(c.m, contract::Extent::Domain, &cad, 1);
    INFO(r.problems.dump());
    const auto cl = clauses(r);
    const bool inverted = std::count(cl.begin(), cl.end(), "validity") > 0;
    CHECK(inverted == (h < 0));
    int measured = 0;
    for (auto& p : r.problems) {
      if (p["clause"] != "volume" && p["clause"] != "coverage") continue;
      ++measured;
      CHECK(p["blocking"] == !inverted);
      CHECK((p["what"].get<std::string>().find("inverted elements") != std::string::npos) == inverted);
    }
    CHECK(measured >= 1);
  }
}

TEST_CASE("contract: degenerate elements: coincident nodes, a flat element") {
  SUBCASE("a prism with two coincident nodes, as a collapsed wall triangle gives") {
    Mesh m;
    m.add_entity(3, 1);
    // bottom (0,0,0) (1,0,0) (0,1,0); top: the same raised by 0.1, but nodes 4 and 5 coincide
    // in space though they are distinct nodes
    for (auto p : std::vector<std::array<double, 3>>{{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, 0.1}, {0.5, 0.5, 0.1}, {0.5, 0.5, 0.1}})
      m.add_node(p[0], p[1], p[2]);
    m.block(Shape::Prism, 1, 3, 1).add({0, 1, 2, 3, 4, 5});
    json p = degenerate_problem(m);
    CHECK(p["blocking"] == true);
    CHECK(p["where"][0]["why"] == "zero-length edge");
  }
  SUBCASE("a flat tetrahedron (all edges of fair length)") {
    Mesh m;
    m.add_entity(3, 1);
    for (auto p : std::vector<std::array<double, 3>>{{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0.3, 0.3, 0}}) m.add_node(p[0], p[1], p[2]);
    m.block(Shape::Tet, 1, 3, 1).add({0, 1, 2, 3});
    CHECK(degenerate_problem(m)["where"][0]["why"] == "zero volume");
  }
}

TEST_CASE("contract: a face shared by three elements breaks conformity") {
  Cube c(1, /*boundary=*/false);
  auto& b = c.m.blocks[0];
  std::vector<std::uint32_t> first(b.nodes.begin(), b.nodes.begin() + 4);
  b.add(first.data());  // the first tet twice: its faces are shared by 2 or 3 elements
  auto r = contract::check(c.m, contract::Extent::NearField, nullptr, 1);
  INFO(r.problems.dump());
  auto cl = clauses(r);
  CHECK(std::find(cl.begin(), cl.end(), "conformity") != cl.end());
}

TEST_CASE("contract: a boundary face without a tagged boundary element breaks the tags clause") {
  SUBCASE("an untagged entity") {
    Cube c(1);
    // move one boundary triangle to an entity with no physical group
    c.m.add_entity(2, 99);
    auto& from = c.m.blocks[1];
    std::vector<std::uint32_t> tri(from.nodes.end() - 3, from.nodes.end());
    from.nodes.resize(from.nodes.size() - 3);
    c.m.block(Shape::Tri, 1, 2, 99).add(tri.data());
    auto r = contract::check(c.m, contract::Extent::Domain, nullptr, 1);
    INFO(r.problems.dump());
    REQUIRE(clauses(r) == std::vector<std::string>{"tags"});
    CHECK(r.problems[0]["count"] == 1);
    CHECK(r.problems[0]["blocking"] == true);
  }
  SUBCASE("a hole in the wall: the boundary element is missing, the CAD face not covered") {
    Cube c(1);
    auto& from = c.m.blocks[1];
    from.nodes.resize(from.nodes.size() - 3);
    auto cad = cube_cad();
    auto r = contract::check(c.m, contract::Extent::Domain, &cad, 1);
    INFO(r.problems.dump());
    REQUIRE(clauses(r) == std::vector<std::string>{"tags", "coverage"});
    // the rim of the hole: the missing triangle's three edges are used by one boundary element
    CHECK(r.problems[1]["what"].get<std::string>().find("do not close") != std::string::npos);
    CHECK(r.problems[1]["count"] == 3);
    CHECK(r.contract["boundary_rim_edges"] == 3);
  }
  SUBCASE("a whole CAD face without boundary elements is not covered") {
    Cube c(1);
    auto cad = cube_cad();
    cad.faces.push_back({7, 0.25, "wall"});  // a face the mesh has no element on
    auto r = contract::check(c.m, contract::Extent::Domain, &cad, 1);
    INFO(r.problems.dump());
    REQUIRE(clauses(r) == std::vector<std::string>{"coverage"});
    CHECK(r.problems[0]["where"][0]["cad_face"] == 6);
    CHECK(r.problems[0]["where"][0]["mesh_area"] == 0.0);
  }
  SUBCASE("the near field's open outer surface is not a tags problem") {
    Cube c(1, /*boundary=*/false);
    auto r = contract::check(c.m, contract::Extent::NearField, nullptr, 1);
    CHECK(r.ok());
  }
}

TEST_CASE("contract: a body not cut out: its CAD face is not covered and the volume differs") {
  Cube c(4);
  // the CAD: the cube minus a body of volume 0.2 whose face (entity 7, a wall) has area 1.7
  auto cad = cube_cad();
  cad.volume = 0.8;
  cad.faces.push_back({7, 1.7, "wall"});
  auto r = contract::check(c.m, contract::Extent::Domain, &cad, 1);
  INFO(r.problems.dump());
  REQUIRE(clauses(r) == std::vector<std::string>{"volume", "coverage", "coverage"});
  CHECK(r.problems[1]["where"][0]["cad_face"] == 6);
  CHECK(r.problems[1]["where"][0]["mesh_area"] == 0.0);
  CHECK(r.problems[2]["where"][0]["group"] == "wall");  // the wall group's area: 6 of 7.7
  CHECK(r.contract["group_areas"]["wall"]["rel_error"].get<double>() == doctest::Approx(1.7 / 7.7));
  CHECK(r.contract["volume_rel_error"].get<double>() == doctest::Approx(0.25));
}

TEST_CASE("contract: the corpus sphere healed without sewing is cut out and covered: sweep's coverage figures, exit 0") {
  // Once sweep gave this sphere's face no triangle and the contract stopped the run (exit 3,
  // "1 face(s) of the healed CAD without any boundary element"); the face mesher now meshes
  // poles and seams, so the same run keeps every clause and says how much of the face it covers.
  const fs::path data = MESHFLOW_DATA_DIR;
  REQUIRE(fs::exists(data / "corpus/sphere.step"));
  fs::path d = mftest::temp_dir("contract-sphere");
  mftest::write_text(d / "w.yaml", "meshflow: 1\nname: sphere-nosew\nstages:\n"
                                   "  geometry: {kind: step, with: {file: " + (data / "corpus/sphere.step").string() + "}}\n"
                                   "  heal: {kind: heal, needs: [geometry], with: {fluid: box, sew: false}}\n"
                                   "  medial: {kind: medial, needs: [heal]}\n"
                                   "  shell: {kind: shell, needs: [heal, medial], with: {thickness: 0.05}}\n"
                                   "  balance: {kind: balance, needs: [heal, shell]}\n"
                                   "  sweep: {kind: sweep, needs: [heal, shell, balance]}\n"
                                   "  tet: {kind: tet, needs: [sweep]}\n"
                                   "outputs:\n  linear: {from: tet, formats: [msh]}\n");
  auto r = mftest::sh(std::string(MESHFLOW_EXE) + " run " + (d / "w.yaml").string() + " --cache " + (d / "c").string() +
                      " --out " + (d / "out").string() + " 2>&1");
  INFO(r.out);
  CHECK(r.code == 0);
  json sweep = mftest::stage_stats(d / "out", "sweep");
  CHECK(sweep["problems"].empty());
  CHECK(sweep["contract"]["faces_checked"] == 7);  // the sphere and the box's six faces
  CHECK(sweep["contract"]["group_areas"]["wall"]["rel_error"].get<double>() < 0.01);  // 3.1310 of pi
  fs::remove_all(d);
}

TEST_CASE("contract: meshflow contract FILE checks a mesh another tool wrote (Gmsh, Nektar++) and exits 3 when it breaks a clause") {
  const fs::path data = fs::path(MESHFLOW_DATA_DIR) / "highorder";
  REQUIRE(fs::exists(data / "v4.1_cube_all.msh"));
  const std::string exe = MESHFLOW_EXE;
  // Gmsh's mixed linear cube (hex, tet, prism, pyramid) keeps every clause that needs no CAD
  auto ok = mftest::sh(exe + " contract " + (data / "v4.1_cube_all.msh").string() + " 2>&1");
  INFO(ok.out);
  CHECK(ok.code == 0);
  CHECK(ok.out.find("keeps the mesh contract") != std::string::npos);
  // Nektar++'s test mesh with one invalid curved quad: the validity clause names element 9
  auto bad = mftest::sh(exe + " contract " + (data / "linearise_invalid_quad.xml").string() + " --json 2>&1");
  INFO(bad.out);
  CHECK(bad.code == 3);
  json r = json::parse(bad.out);
  CHECK(r["ok"] == false);
  // only that: the quads are the domain of a 2D mesh, not boundary elements with a rim
  REQUIRE(r["problems"].size() == 1);
  CHECK(r["problems"][0]["clause"] == "validity");
  CHECK(r["problems"][0]["where"][0]["element"] == 9);
  // a file it cannot read is bad input
  auto none = mftest::sh(exe + " contract /nonexistent.msh 2>&1");
  CHECK(none.code == 2);
}

TEST_CASE("contract: the CAD reference artifact reads back bit for bit, and an unreadable one is an error naming the file") {
  contract::CadReference ref;
  ref.volume = 1.0 / 3.0;
  ref.volume_reliable = false;
  ref.source = "the healed fluid solid";
  ref.faces.push_back({1, std::nextafter(0.1, 1.0), "wall", true});
  ref.faces.push_back({2, 2.0e-300, "", false});
  ref.faces.push_back({7, 12345.678901234567, "farfield", true});
  const auto dir = mftest::temp_dir("cad-reference");
  contract::write_cad_reference(ref, dir / "r.json");
  const contract::CadReference back = contract::read_cad_reference(dir / "r.json");
  CHECK(back.volume == ref.volume);
  CHECK(back.volume_reliable == ref.volume_reliable);
  CHECK(back.source == ref.source);
  REQUIRE(back.faces.size() == ref.faces.size());
  for (std::size_t i = 0; i < ref.faces.size(); ++i) {
    CHECK(back.faces[i].entity == ref.faces[i].entity);
    CHECK(back.faces[i].area == ref.faces[i].area);
    CHECK(back.faces[i].group == ref.faces[i].group);
    CHECK(back.faces[i].reliable == ref.faces[i].reliable);
  }
  mftest::write_text(dir / "bad.json", "{\"format\": \"meshflow cad_reference 1\", \"volume\": 1}");
  try {
    contract::read_cad_reference(dir / "bad.json");
    FAIL("no error");
  } catch (const meshflow::StageError& e) {
    CHECK(std::string(e.what()).find("bad.json") != std::string::npos);
  }
}
