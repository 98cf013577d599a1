// The sweep stage end to end (meshflow run, as a user runs it): a small NACA wing with a flat
// tip on a symmetry wall -> heal -> medial -> shell -> balance -> sweep -> tet. Asserts the
// linear mesh contract of stages/sweep/sweep.hpp, validity and conformity by our checks and
// by Gmsh, prisms = wall triangles, one hex per junction division, deterministic bytes, and
// a refusal naming the stage when the shell is too thick to sweep.
#include <doctest/doctest.h>

#include "engine/stage.hpp"
#include "stages/balance/balance.hpp"
#include "stages/cad/cad.hpp"
#include "stages/io/mesh_io.hpp"
#include "stages/shell/shell.hpp"
#include "stages/sweep/sweep.hpp"
#include "stages/model/quality.hpp"
#include "support.hpp"

#include <nlohmann/json.hpp>

#include <cmath>
#include <map>

namespace {
namespace fs = std::filesystem;
using meshflow::model::Shape;

const char* kWorkflow = R"(meshflow: 1
name: sweep-test
stages:
  geometry:
    kind: naca_wing
    with: {profile: "0012", chord: 1.0, span: 1.0, incidence_deg: 10, tip: flat, trailing_edge: blunt, farfield_chords: 3}
  heal: {kind: heal, needs: [geometry]}
  medial: {kind: medial, needs: [heal]}
  shell: {kind: shell, needs: [heal, medial], with: {thickness: THICK, topology: C}}
  balance: {kind: balance, needs: [heal, shell], with: {turn_angle_deg: 30, max_size: 0.15, min_size: 0.015}}
  sweep: {kind: sweep, needs: [heal, shell, balance]}
  tet: {kind: tet, needs: [sweep]}
outputs:
  near: {from: sweep}
  mesh: {from: tet}
)";

fs::path write_workflow(const fs::path& dir, const std::string& thickness) {
  std::string w = kWorkflow;
  w.replace(w.find("THICK"), 5, thickness);
  fs::create_directories(dir);
  mftest::write_text(dir / "w.yaml", w);
  return dir / "w.yaml";
}

std::size_t count(const meshflow::model::Mesh& m, Shape s, int dim) {
  std::size_t n = 0;
  for (auto& b : m.blocks)
    if (b.shape == s && b.entity_dim == dim) n += b.size();
  return n;
}

}  // namespace

TEST_CASE("sweep and tet on a small NACA wing: the linear hybrid mesh is valid, conforming and classified") {
  fs::path dir = mftest::temp_dir("sweep");
  fs::path w = write_workflow(dir, "0.05");
  auto r = mftest::sh("cd " + dir.string() + " && " + std::string(MESHFLOW_EXE) + " run " + w.string() + " 2>&1");
  INFO(r.out);
  REQUIRE(r.code == 0);
  auto near = meshflow::io::read_mesh(dir / "out/sweep-test/near.msh");
  auto mesh = meshflow::io::read_mesh(dir / "out/sweep-test/mesh.msh");

  // near field: one prism per wall triangle, junction hexes, classified nodes
  std::size_t prisms = count(near, Shape::Prism, 3), hexes = count(near, Shape::Hex, 3);
  std::size_t wall_tris = 0;
  for (auto& b : near.blocks)
    if (b.shape == Shape::Tri && near.group_name(2, b.entity_tag) == "wall") wall_tris += b.size();
  CHECK(prisms > 100);
  CHECK(prisms == wall_tris);
  CHECK(hexes > 0);
  REQUIRE(near.node_entity_dim.size() == near.num_nodes());
  for (std::size_t i = 0; i < near.num_nodes(); ++i) {
    int d = near.node_entity_dim[i];
    CHECK((d >= 0 && d <= 3));
    if (d == 1) CHECK(std::isfinite(near.node_u[i]));
    if (d == 2) CHECK((std::isfinite(near.node_u[i]) && std::isfinite(near.node_v[i])));
  }
  // the hexes are the junction divisions: w<e> counts of the junction edges
  std::map<std::string, int> groups;
  for (auto& g : near.physicals) groups[g.name] = g.tag;
  CHECK(groups.count("wall"));
  CHECK(groups.count("symmetry"));
  CHECK(groups.count("farfield"));

  // whole mesh: valid (Bezier), conforming, tets and pyramids added, the near field kept
  auto st = meshflow::model::mesh_stats(mesh);
  CHECK(st.at("invalid").get<int>() == 0);
  CHECK(st.at("nonconforming_faces").get<int>() == 0);
  CHECK(count(mesh, Shape::Prism, 3) == prisms);
  CHECK(count(mesh, Shape::Hex, 3) == hexes);
  CHECK(count(mesh, Shape::Tet, 3) > 1000);
  CHECK(count(mesh, Shape::Pyramid, 3) > 0);

  // Gmsh loads it and finds nothing inverted
  std::string py =
      "import gmsh,sys\n"
      "gmsh.initialize(); gmsh.option.setNumber('General.Terminal',0)\n"
      "gmsh.option.setNumber('General.AbortOnError',0)\n"
      "gmsh.open(sys.argv[1])\n"
      "gmsh.plugin.setNumber('AnalyseMeshQuality','JacobianDeterminant',1)\n"
      "gmsh.plugin.setNumber('AnalyseMeshQuality','CreateView',1)\n"
      "gmsh.plugin.run('AnalyseMeshQuality')\n"
      "d=gmsh.view.getModelData(gmsh.view.getTags()[-1],0)\n"
      "print(len(d[1]), sum(1 for v in d[2] if v[0]<=0))\n";
  mftest::write_text(dir / "check.py", py);
  auto g = mftest::sh(std::string(MESHFLOW_PYTHON) + " " + (dir / "check.py").string() + " " +
                              (dir / "out/sweep-test/mesh.msh").string());
  INFO(g.out);
  REQUIRE(g.code == 0);
  std::istringstream in(g.out);
  long n = 0, bad = -1;
  in >> n >> bad;
  CHECK(n == static_cast<long>(mesh.num_elements() - count(mesh, Shape::Tri, 2) - count(mesh, Shape::Quad, 2) -
                               count(mesh, Shape::Line, 1)));
  CHECK(bad == 0);

  // deterministic: a second run from a clean cache writes the same bytes
  auto first = mftest::read_text(dir / "out/sweep-test/mesh.msh");
  fs::remove_all(dir / ".meshflow");
  fs::remove_all(dir / "out");
  auto r2 = mftest::sh("cd " + dir.string() + " && " + std::string(MESHFLOW_EXE) + " run -j 2 " + w.string() + " 2>&1");
  REQUIRE(r2.code == 0);
  CHECK(mftest::read_text(dir / "out/sweep-test/mesh.msh") == first);
}

TEST_CASE("sweep refuses divisions that do not belong to the shell, naming the edge and what to do") {
  // the pipeline up to balance, then sweep called on its artifacts with the junction edge's
  // divisions removed (what a balance artifact from another shell would look like)
  fs::path dir = mftest::temp_dir("sweep-bad");
  std::string w = kWorkflow;
  w.replace(w.find("THICK"), 5, "0.05");
  w = w.substr(0, w.find("  sweep:")) + "outputs:\n  shape: {from: heal}\n  shell: {from: shell}\n  divisions: {from: balance}\n";
  mftest::write_text(dir / "w.yaml", w);
  auto r = mftest::sh("cd " + dir.string() + " && " + std::string(MESHFLOW_EXE) + " run w.yaml 2>&1");
  INFO(r.out);
  REQUIRE(r.code == 0);
  auto shape = meshflow::cad::Shape::load(dir / "out/sweep-test/shape.mfshape");
  auto shell = meshflow::shell::read(dir / "out/sweep-test/shell.mfshell");
  auto div = meshflow::balance::read(dir / "out/sweep-test/divisions.mfdiv");
  meshflow::sweep::Options o;
  meshflow::sweep::Report rep;
  // as read, it sweeps
  auto m = meshflow::sweep::sweep_mesh(shape, shell, div, o, rep);
  CHECK(rep.prisms > 0);
  // without the junction edge's wall divisions it refuses, naming the entry and the remedy
  auto H = nlohmann::json::parse(shell.header);
  std::string missing;
  for (auto& b : H.at("blocks"))
    if (b.at("kind") == "hex_junction") missing = "w" + std::to_string(b.at("edge").get<int>());
  REQUIRE(!missing.empty());
  std::erase_if(div.edges, [&](const meshflow::balance::EdgeDivision& e) { return e.name == missing; });
  meshflow::sweep::Report rep2;
  try {
    meshflow::sweep::sweep_mesh(shape, shell, div, o, rep2);
    FAIL("sweep accepted divisions without " << missing);
  } catch (const meshflow::StageError& e) {
    std::string what = e.what();
    CHECK(what.find(missing) != std::string::npos);
    CHECK(what.find("re-run balance") != std::string::npos);
  }
}

TEST_CASE("sweep and tet on the paper's wing (STEP, rounded tip, tunnel wall): valid and conforming") {
  fs::path stp = fs::path(MESHFLOW_DATA_DIR) / "wingtip/3d_bl_wing.stp";
  REQUIRE(fs::exists(stp));
  fs::path dir = mftest::temp_dir("sweep-step");
  mftest::write_text(dir / "w.yaml", "meshflow: 1\nname: sweep-step\nstages:\n"
                                     "  geometry: {kind: step, with: {file: " + stp.string() + "}}\n"
                                     "  heal: {kind: heal, needs: [geometry]}\n"
                                     "  medial: {kind: medial, needs: [heal]}\n"
                                     "  shell: {kind: shell, needs: [heal, medial], with: {thickness: 0.05, topology: C}}\n"
                                     "  balance: {kind: balance, needs: [heal, shell]}\n"
                                     "  sweep: {kind: sweep, needs: [heal, shell, balance]}\n"
                                     "  tet: {kind: tet, needs: [sweep]}\n"
                                     "outputs:\n  mesh: {from: tet}\n");
  auto r = mftest::sh("cd " + dir.string() + " && " + std::string(MESHFLOW_EXE) + " run w.yaml 2>&1");
  INFO(r.out);
  REQUIRE(r.code == 0);
  auto mesh = meshflow::io::read_mesh(dir / "out/sweep-step/mesh.msh");
  auto st = meshflow::model::mesh_stats(mesh);
  CHECK(st.at("invalid").get<int>() == 0);
  CHECK(st.at("nonconforming_faces").get<int>() == 0);
  CHECK(count(mesh, Shape::Prism, 3) > 1000);
  CHECK(count(mesh, Shape::Hex, 3) > 10);  // the root junction on the tunnel wall
  CHECK(count(mesh, Shape::Tet, 3) > 1000);
}
