// sweep with a periodic match, end to end (meshflow run): the parametric NACA wing in a box whose
// sides y = -2 / y = 2 are tagged periodic_lo / periodic_hi (a translation by 4 in y), through
// balance -> periodic_match -> sweep -> tet. Asserts that the hi side's surface mesh is the image
// of the lo side's (every hi triangle is the image of a lo triangle), that every node on a hi
// entity has its $Periodic pair and the pairs coincide after the transform to 1e-12 of the model
// size, that tet keeps the links, and that Gmsh loads the mesh (periodic section included) and
// finds nothing inverted. Then workflows/rotor67.yaml (a rotation by 2 pi / 22) through sweep:
// the same checks on its near field, pairs matched to 1e-12 of the casing radius.
#include <doctest/doctest.h>

#include "stages/io/mesh_io.hpp"
#include "stages/model/quality.hpp"
#include "stages/periodic_match/periodic.hpp"
#include "support.hpp"

#include <nlohmann/json.hpp>

#include <cmath>
#include <map>
#include <set>
#include <sstream>

namespace {
namespace fs = std::filesystem;
using meshflow::model::Mesh;
using meshflow::model::Shape;

const char* kPeriodicWorkflow = R"(meshflow: 1
name: sweep-periodic
stages:
  geometry:
    kind: naca_wing
    with:
      farfield_chords: 2
      wake_chords: 3
      tag_overrides:
        - {tag: periodic_lo, plane: {point: [0, -2, 0], normal: [0, 1, 0]}}
        - {tag: periodic_hi, plane: {point: [0, 2, 0], normal: [0, 1, 0]}}
  heal: {kind: heal, needs: [geometry]}
  medial: {kind: medial, needs: [heal]}
  shell: {kind: shell, needs: [heal, medial]}
  balance: {kind: balance, needs: [heal, shell], with: {max_size: 0.15}}
  periodic_match: {kind: periodic_match, needs: [heal, balance]}
  sweep: {kind: sweep, needs: [heal, shell, balance, periodic_match]}
  tet: {kind: tet, needs: [sweep]}
outputs:
  periodic: {from: periodic_match}
  near: {from: sweep}
  mesh: {from: tet}
)";

// The faces of `m` classified on (2, tag), as sorted node triples (so a triangle matches its
// image whatever its orientation and first node).
std::set<std::array<std::uint32_t, 3>> face_tris(const Mesh& m, int tag) {
  std::set<std::array<std::uint32_t, 3>> s;
  for (auto& b : m.blocks)
    if (b.shape == Shape::Tri && b.entity_dim == 2 && b.entity_tag == tag)
      for (std::size_t e = 0; e < b.size(); ++e) {
        std::array<std::uint32_t, 3> t{b.nodes[3 * e], b.nodes[3 * e + 1], b.nodes[3 * e + 2]};
        std::sort(t.begin(), t.end());
        s.insert(t);
      }
  return s;
}

// The checks of the periodic contract (sweep.hpp "periodic") on one mesh; returns the max mismatch.
double check_periodic(const Mesh& m, const meshflow::periodic::Match& pm) {
  REQUIRE(!m.periodic.empty());
  std::map<std::pair<int, int>, int> master;  // (dim, hi tag) -> lo tag
  for (auto& p : pm.faces) master[{2, p.hi + 1}] = p.lo + 1;
  for (auto& p : pm.edges) master[{1, p.hi + 1}] = p.lo + 1;
  for (auto& p : pm.vertices) master[{0, p.hi + 1}] = p.lo + 1;
  double worst = 0;
  std::map<std::uint32_t, std::uint32_t> hi_to_lo;
  for (auto& L : m.periodic) {
    INFO("link (" << L.dim << "," << L.tag << ") <- " << L.master_tag);
    REQUIRE(master.count({L.dim, L.tag}));
    CHECK(master[{L.dim, L.tag}] == L.master_tag);
    REQUIRE(L.affine.size() == 16);
    for (int i = 0; i < 16; ++i) CHECK(L.affine[i] == pm.transform.affine[i]);
    CHECK(!L.nodes.empty());
    for (auto [h, l] : L.nodes) {
      REQUIRE(h < m.num_nodes());
      REQUIRE(l < m.num_nodes());
      CHECK(m.node_entity_dim[h] == L.dim);
      CHECK(m.node_entity_tag[h] == L.tag);
      CHECK(m.node_entity_dim[l] == L.dim);
      CHECK(m.node_entity_tag[l] == L.master_tag);
      auto y = pm.transform.apply({m.x[l], m.y[l], m.z[l]});
      worst = std::max(worst, std::hypot(y[0] - m.x[h], y[1] - m.y[h], y[2] - m.z[h]));
      CHECK(hi_to_lo.emplace(h, l).second);  // each hi node paired once
    }
  }
  // every node classified on a hi entity has its pair
  for (std::size_t i = 0; i < m.num_nodes(); ++i) {
    auto it = master.find({m.node_entity_dim[i], m.node_entity_tag[i]});
    if (it != master.end() && it->second != it->first.second) CHECK(hi_to_lo.count(static_cast<std::uint32_t>(i)));
  }
  // the hi face mesh is the image of the lo face mesh
  for (auto& p : pm.faces) {
    auto lo = face_tris(m, p.lo + 1), hi = face_tris(m, p.hi + 1);
    CHECK(lo.size() > 100);
    CHECK(lo.size() == hi.size());
    std::map<std::uint32_t, std::uint32_t> lo_to_hi;
    for (auto [h, l] : hi_to_lo) lo_to_hi[l] = h;
    std::size_t imaged = 0;
    for (auto t : lo) {
      std::array<std::uint32_t, 3> g{};
      bool ok = true;
      for (int i = 0; i < 3; ++i) {
        auto it = lo_to_hi.find(t[i]);
        if (it == lo_to_hi.end()) ok = false;
        else g[i] = it->second;
      }
      std::sort(g.begin(), g.end());
      if (ok && hi.count(g)) ++imaged;
    }
    CHECK(imaged == lo.size());
  }
  return worst;
}

// Gmsh loads `file` (its $Periodic section included), finds as many periodic node pairs as `m`
// holds and no element with a non-positive Jacobian.
void gmsh_check(const fs::path& dir, const fs::path& file, const Mesh& m) {
  std::string py =
      "import gmsh,sys\n"
      "gmsh.initialize(); gmsh.option.setNumber('General.Terminal',0)\n"
      "gmsh.open(sys.argv[1])\n"
      "n=0\n"
      "for d in (0,1,2):\n"
      "  for (dd,t) in gmsh.model.getEntities(d):\n"
      "    m,_,_,_=gmsh.model.mesh.getPeriodicNodes(dd,t)\n"
      "    if m!=t: n+=len(gmsh.model.mesh.getPeriodicNodes(dd,t)[1])\n"
      "gmsh.plugin.setNumber('AnalyseMeshQuality','JacobianDeterminant',1)\n"
      "gmsh.plugin.setNumber('AnalyseMeshQuality','CreateView',1)\n"
      "gmsh.plugin.run('AnalyseMeshQuality')\n"
      "d=gmsh.view.getModelData(gmsh.view.getTags()[-1],0)\n"
      "print(n, len(d[1]), sum(1 for v in d[2] if v[0]<=0))\n";
  mftest::write_text(dir / "check.py", py);
  auto g = mftest::sh(std::string(MESHFLOW_PYTHON) + " " + (dir / "check.py").string() + " " + file.string());
  INFO(g.out);
  REQUIRE(g.code == 0);
  std::istringstream in(g.out);
  long pairs = -1, checked = -1, bad = -1;
  in >> pairs >> checked >> bad;
  std::size_t ours = 0;
  for (auto& L : m.periodic) ours += L.nodes.size();
  CHECK(pairs == static_cast<long>(ours));
  CHECK(checked > 0);
  CHECK(bad == 0);
}

}  // namespace

TEST_CASE("sweep with periodic_match: the periodic_hi side is the image of periodic_lo, $Periodic pairs coincide to 1e-12") {
  fs::path dir = mftest::temp_dir("sweep-periodic");
  mftest::write_text(dir / "w.yaml", kPeriodicWorkflow);
  auto r = mftest::sh("cd " + dir.string() + " && " + std::string(MESHFLOW_EXE) + " run --threads 2 " + (dir / "w.yaml").string() + " 2>&1");
  INFO(r.out);
  REQUIRE(r.code == 0);
  fs::path out = dir / "out/sweep-periodic";
  auto pm = meshflow::periodic::read(out / "periodic.mfper");
  REQUIRE(pm.transform.kind == "translation");
  auto near = meshflow::io::read_mesh(out / "near.msh");
  auto mesh = meshflow::io::read_mesh(out / "mesh.msh");

  double w_near = check_periodic(near, pm), w_mesh = check_periodic(mesh, pm);
  MESSAGE("periodic max mismatch: near " << w_near << ", whole mesh " << w_mesh << " (model size " << pm.model_size << ")");
  CHECK(w_near <= 1e-12 * pm.model_size);
  CHECK(w_mesh <= 1e-12 * pm.model_size);

  nlohmann::json st = mftest::stage_stats(out, "sweep");
  INFO(st.dump());
  CHECK(st.at("sweep").at("periodic_faces_copied") == 1);
  CHECK(st.at("sweep").at("periodic_pairs").get<std::size_t>() > 100);
  CHECK(st.at("sweep").at("periodic_max_mismatch_rel").get<double>() <= 1e-12);
  auto ms = meshflow::model::mesh_stats(mesh);
  CHECK(ms.at("invalid").get<int>() == 0);
  CHECK(ms.at("nonconforming_faces").get<int>() == 0);

  gmsh_check(dir, out / "mesh.msh", mesh);
}

TEST_CASE("workflows/rotor67.yaml through tet: valid conforming linear hybrid mesh, outer-surface crossings cleared, periodic_hi the rotated image of periodic_lo to 1e-12 R") {
  REQUIRE(fs::exists(fs::path(MESHFLOW_DATA_DIR) / "rotor67/rotor67geometry.dat"));
  fs::path dir = mftest::temp_dir("sweep-rotor67");
  // the workflow up to tet (the high-order stages and their output removed)
  std::string wf = mftest::workflow_without(fs::path(MESHFLOW_SOURCE_DIR) / "workflows/rotor67.yaml", dir / "rotor67_linear.yaml",
                                            {"curve", "optimise", "split", "mesh"});
  auto r = mftest::sh(std::string(MESHFLOW_EXE) + " run " + wf +
                      " --threads 2 --cache " + (dir / "cache").string() + " --out " + (dir / "out").string() + " 2>&1");
  INFO(r.out);
  REQUIRE(r.code == 0);
  fs::path out = dir / "out";
  auto pm = meshflow::periodic::read(out / "periodic.mfper");
  REQUIRE(pm.transform.kind == "rotation");
  auto near = meshflow::io::read_mesh(out / "near.msh");
  // the radius of the passage (casing) about the rotation axis x
  double R = 0;
  for (std::size_t i = 0; i < near.num_nodes(); ++i) R = std::max(R, std::hypot(near.y[i], near.z[i]));
  double w = check_periodic(near, pm);
  std::size_t prisms = 0, hexes = 0, wall_tris = 0;
  for (auto& b : near.blocks) {
    if (b.shape == Shape::Prism) prisms += b.size();
    if (b.shape == Shape::Hex) hexes += b.size();
    if (b.shape == Shape::Tri && near.group_name(2, b.entity_tag) == "wall") wall_tris += b.size();
  }
  auto ms = meshflow::model::mesh_stats(near, 2);
  MESSAGE("rotor67 near field: " << prisms << " prisms, " << hexes << " hexes, invalid " << ms.at("invalid") << ", min scaled Jacobian "
                                 << ms.at("min_scaled_jacobian") << ", periodic max mismatch " << w << " (R " << R << ")");
  CHECK(w <= 1e-12 * R);
  CHECK(prisms > 10000);
  CHECK(prisms == wall_tris);
  CHECK(hexes > 0);
  CHECK(ms.at("invalid").get<int>() == 0);
  CHECK(ms.at("nonconforming_faces").get<int>() == 0);
  // the shell: junction blocks at the blade's hub and casing roots, every wall face sampled with
  // its junction strips (the blade's wrapped wire is unwrapped and rebuilt, as sweep does), and no
  // crossing pair left in the sampled surface (1069 before the unwrapping, 38 at the
  // junctions round the blade's leading edge and on the blade after it; 2 on the field grid since
  // the face fields are evaluated as sweep does and the strips round the seam follow the p-curve,
  // 14 on the finer lattice the curved blade is sampled on), none after the shell's thinning
  // (one round; sweep's face mesher used to leave slivers on the blade beside the tip strip,
  // one of whose prisms then stayed inverted)
  nlohmann::json sh = mftest::stage_stats(out, "shell");
  INFO(sh.dump());
  CHECK(sh.at("counts").at("hex_junction_blocks").get<int>() == 2);
  CHECK(sh.at("faces_unsampled").get<int>() == 0);
  CHECK(sh.at("junction_strip_fallback_faces").empty());
  CHECK(sh.at("self_intersections").get<long>() == 0);
  CHECK(sh.at("not_honoured").at("thinned_for_crossings").at("crossings_before").get<long>() > 0);
  // the blade's layer fans into the hub's and casing's around its leading and trailing edges:
  // sweep found crossings of the outer surface and cleared every one by thinning (without it
  // TetGen aborts on this surface)
  nlohmann::json sw = mftest::stage_stats(out, "sweep").at("sweep");
  INFO(sw.dump());
  CHECK(sw.at("outer_crossings_before").get<long>() > 0);
  CHECK(sw.at("outer_crossings").get<long>() == 0);
  CHECK(sw.at("crossing_nodes_thinned").get<long>() > 0);
  CHECK(sw.at("crossing_min_scale").get<double>() >= 0.25);

  // the whole linear hybrid mesh: tets fill the passage, conforming, valid, periodic pairs kept
  auto lin = meshflow::io::read_mesh(out / "linear.msh");
  std::size_t tets = 0, lprisms = 0, lhexes = 0;
  for (auto& b : lin.blocks) {
    if (b.shape == Shape::Tet) tets += b.size();
    if (b.shape == Shape::Prism) lprisms += b.size();
    if (b.shape == Shape::Hex) lhexes += b.size();
  }
  auto ls = meshflow::model::mesh_stats(lin, 2);
  MESSAGE("rotor67 linear mesh: " << lprisms << " prisms, " << lhexes << " hexes, " << tets << " tets, invalid " << ls.at("invalid")
                                  << ", min scaled Jacobian " << ls.at("min_scaled_jacobian"));
  CHECK(lprisms == prisms);
  CHECK(lhexes == hexes);
  CHECK(tets > 100000);
  CHECK(ls.at("invalid").get<int>() == 0);
  CHECK(ls.at("nonconforming_faces").get<int>() == 0);
  CHECK(check_periodic(lin, pm) <= 1e-12 * R);
  gmsh_check(dir, out / "linear.msh", lin);
  fs::remove_all(dir);
}
