// The split stage through the engine: a test-only source kind writes the junction mesh as a
// "mesh" artifact; `meshflow run` splits it; outputs, stats, re-run on --set, determinism
// across thread budgets, and a refused input.
#include <doctest/doctest.h>

#include "support.hpp"

#include "builders.hpp"
#include "engine/cli.hpp"
#include "engine/stage.hpp"
#include "stages/io/mesh_io.hpp"
#include "stages/model/quality.hpp"
#include "stages/model/topology.hpp"

#include <nlohmann/json.hpp>

#include <fstream>
#include <iostream>
#include <sstream>
#include <unistd.h>

namespace {

namespace fs = std::filesystem;

// Source kind: the cylinder-on-plate junction mesh of order `order` (optionally without wall
// groups, to exercise a refusal).
meshflow::StageRegistrar source_reg({
    .kind = "split_test_junction",
    .version = 1,
    .summary = "test only: the split tests' cylinder-on-plate junction mesh",
    .run =
        [](meshflow::StageContext& ctx) {
          int P = ctx.params().value("order", 2);
          auto J = splittest::junction_mesh(P, ctx.params().value("segments", 8));
          if (!ctx.params().value("walls", true))
            for (auto& g : J.mesh.physicals)
              if (g.name == "wall") g.name = "body";
          const auto mesh_path = ctx.output("mesh", "mesh");
          meshflow::io::write_mesh(J.mesh, mesh_path, meshflow::io::MeshFormat::MshBinary);
          const std::string stored = ctx.params().value("quality", "none");
          if (stored != "none") {  // as a mesh stage stores it beside its mesh; halved: not this mesh's numbers
            auto m = meshflow::io::read_mesh(mesh_path);
            auto q = meshflow::model::mesh_quality(m, 1);
            if (stored == "halved")
              for (auto& b : q)
                for (auto& e : b) e.scaled_jacobian *= 0.5;
            meshflow::io::write_quality(m, q, ctx.output("quality", "mesh_quality"));
          }
        },
    .schema = R"({"type": "object", "additionalProperties": false, "properties": {
        "order": {"type": "integer", "minimum": 1, "maximum": 6, "default": 2, "description": "order"},
        "segments": {"type": "integer", "minimum": 4, "maximum": 64, "default": 8, "description": "segments around"},
        "walls": {"type": "boolean", "default": true, "description": "keep the wall group"},
        "quality": {"enum": ["none", "stored", "halved"], "default": "none", "description": "store the quality beside the mesh"}}})"});

using mftest::Cli;
Cli run(std::vector<std::string> args) { return mftest::run_cli(std::move(args)); }

std::string slurp(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

fs::path tmpdir() {
  static int n = 0;
  auto d = fs::temp_directory_path() / ("meshflow-split-wf-" + std::to_string(getpid()) + "-" + std::to_string(n++));
  fs::remove_all(d);
  fs::create_directories(d);
  return d;
}

const char* kWorkflow = R"(meshflow: 1
name: split-test
stages:
  source: {kind: split_test_junction, with: {order: 3, segments: 8}}
  split:  {kind: split, needs: [source], with: {layers: 4, ratio: 1.5}}
outputs: {mesh: {from: split}}
)";

nlohmann::json stage_stats(const fs::path& out, const std::string& name) {
  auto rep = nlohmann::json::parse(slurp(out / "report.json"));
  for (auto& s : rep["stages"])
    if (s["name"] == name) return s;
  return {};
}

}  // namespace

TEST_CASE("split through meshflow run: artifact, stats, --set re-runs only split, same bytes at 1 and 2 threads") {
  fs::path d = tmpdir();
  std::ofstream(d / "w.yaml") << kWorkflow;
  // The test source is a patch of a domain, not a whole one: its open boundary breaks the mesh
  // contract's tags (and, with the CAD, coverage and volume) clauses, accepted here on purpose.
  auto r1 = run({"run", "--allow-invalid", (d / "w.yaml").string(), "--cache", (d / "cache1").string(), "--out", (d / "out1").string(), "--threads", "1"});
  INFO(r1.out << r1.err);
  REQUIRE(r1.code == 0);
  auto m = meshflow::io::read_mesh(d / "out1" / "mesh.msh");
  auto J = splittest::junction_mesh(3, 8);
  std::size_t np = 0, nh = 0;
  for (auto& b : m.blocks) {
    if (b.shape == splittest::Shape::Prism) np += b.size();
    if (b.shape == splittest::Shape::Hex) nh += b.size();
  }
  CHECK(np == 4 * (J.prisms_a + J.prisms_c));
  CHECK(nh == 16 * J.hexes);
  CHECK(meshflow::model::build_topology(m).nonconforming_faces == 0);
  auto st = stage_stats(d / "out1", "split");
  REQUIRE(st.is_object());
  CHECK(st["status"] == "invalid");  // accepted (see above); it ran
  CHECK(st["computed"] == "ran");
  CHECK(st["stats"]["mesh"]["invalid"] == 0);
  CHECK(st["stats"]["mesh"]["nonconforming_faces"] == 0);
  CHECK(st["stats"]["split"]["sub"]["prism"] == np);
  CHECK(st["stats"]["split"]["macro"]["hex_2wall"] == J.hexes);
  CHECK(st["stats"]["mesh"]["max_aspect_ratio"].get<double>() > 10);

  // another cache, two threads: identical bytes
  auto r2 = run({"run", "--allow-invalid", (d / "w.yaml").string(), "--cache", (d / "cache2").string(), "--out", (d / "out2").string(), "--threads", "2"});
  REQUIRE(r2.code == 0);
  CHECK(slurp(d / "out1" / "mesh.msh") == slurp(d / "out2" / "mesh.msh"));

  // --set split.layers=5 re-runs split only
  auto r3 = run({"run", "--allow-invalid", (d / "w.yaml").string(), "--cache", (d / "cache1").string(), "--out", (d / "out3").string(), "--set",
                 "split.layers=5"});
  INFO(r3.out << r3.err);
  REQUIRE(r3.code == 0);
  CHECK(stage_stats(d / "out3", "source")["status"] == "cached");
  CHECK(stage_stats(d / "out3", "split")["computed"] == "ran");
  CHECK(stage_stats(d / "out3", "split")["stats"]["split"]["sub"]["hex"] == 25 * J.hexes);

  // schema: out-of-range parameters are refused before anything runs
  auto r4 = run({"run", "--allow-invalid", (d / "w.yaml").string(), "--cache", (d / "cache1").string(), "--out", (d / "out4").string(), "--set",
                 "split.ratio=0.5"});
  CHECK(r4.code != 0);
  fs::remove_all(d);
}

TEST_CASE("split through meshflow run: a mesh without walls is refused with the stage's message") {
  fs::path d = tmpdir();
  std::string wf = kWorkflow;
  wf.replace(wf.find("segments: 8}"), 12, "segments: 8, walls: false}");
  std::ofstream(d / "w.yaml") << wf;
  auto r = run({"run", "--allow-invalid", (d / "w.yaml").string(), "--cache", (d / "cache").string(), "--out", (d / "out").string()});
  CHECK(r.code != 0);
  CHECK((r.out + r.err).find("no wall faces") != std::string::npos);
  fs::remove_all(d);
}

// The far field split passes through unchanged keeps the quality its input's stage stored: the
// contract takes it, computes the split blocks only, and stores the same bytes as without it.
TEST_CASE("split takes the passed-through elements' quality from its input's stored quality") {
  fs::path d = tmpdir();
  auto quality_of = [&](const std::string& stored, const std::string& tag) {
    std::ofstream(d / (tag + ".yaml")) << "meshflow: 1\nname: split-q\nstages:\n"
                                          "  source: {kind: split_test_junction, with: {order: 3, segments: 8, quality: " +
                                              stored + "}}\n"
                                          "  split:  {kind: split, needs: [source], with: {layers: 4, ratio: 1.5}}\n"
                                          "outputs: {mesh: {from: split}}\n";
    auto r = run({"run", "--allow-invalid", (d / (tag + ".yaml")).string(), "--cache", (d / "cache").string(), "--out",
                  (d / tag).string(), "--threads", "2"});
    INFO(r.out << r.err);
    REQUIRE(r.code == 0);
    std::string digest;
    const auto st = stage_stats(d / tag, "split");
    for (auto& o : st["outputs"])
      if (o["name"] == "quality") digest = o["digest"];
    REQUIRE(digest.size() == 64);
    const fs::path obj = d / "cache" / "objects" / digest.substr(0, 2) / digest;
    REQUIRE(fs::exists(obj));
    auto m = meshflow::io::read_mesh(d / tag / "mesh.msh");
    return std::make_pair(digest, meshflow::io::read_quality(obj, m));
  };
  auto [none_digest, computed] = quality_of("none", "none");
  auto [stored_digest, stored] = quality_of("stored", "stored");
  auto [halved_digest, halved] = quality_of("halved", "halved");
  CHECK(stored_digest == none_digest);  // the stored numbers are the computed ones
  CHECK(halved_digest != none_digest);  // taken, not computed again
  REQUIRE(halved.size() == computed.size());
  std::size_t tets = 0, subs = 0;
  auto m = meshflow::io::read_mesh(d / "none" / "mesh.msh");
  for (std::size_t b = 0; b < m.blocks.size(); ++b) {
    REQUIRE(halved[b].size() == computed[b].size());
    for (std::size_t e = 0; e < computed[b].size(); ++e) {
      if (m.blocks[b].shape == meshflow::model::Shape::Tet) {  // passed through: the source's (halved) numbers
        CHECK(halved[b][e].scaled_jacobian == computed[b][e].scaled_jacobian * 0.5);
        ++tets;
      } else {  // split: computed
        CHECK(halved[b][e].scaled_jacobian == computed[b][e].scaled_jacobian);
        ++subs;
      }
    }
  }
  CHECK(tets > 0);
  CHECK(subs > 0);
  fs::remove_all(d);
}
