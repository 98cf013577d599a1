// The curve stage through the engine: test-only source kinds write the shape (OCCT sphere or
// cylinder shell) and the linear mesh built on it; `meshflow run` curves it; stats, --set
// re-runs curve only, same bytes at 1 and 2 threads, a refused order.
#include <doctest/doctest.h>

#include "support.hpp"

#include "builders.hpp"
#include "engine/cli.hpp"
#include "engine/stage.hpp"
#include "stages/io/mesh_io.hpp"
#include "stages/model/topology.hpp"

#include <nlohmann/json.hpp>

#include <fstream>
#include <iostream>
#include <sstream>
#include <unistd.h>

namespace {

namespace fs = std::filesystem;

meshflow::StageRegistrar shape_reg({
    .kind = "curve_test_shape",
    .version = 1,
    .summary = "test only: the curve tests' sphere or cylinder shell",
    .run =
        [](meshflow::StageContext& ctx) {
          bool sphere = ctx.params().value("body", std::string("sphere")) == "sphere";
          auto S = sphere ? curvetest::sphere_shell(1.0, 3.0) : curvetest::cylinder_shell(1.0, 3.0, 1.0);
          S.save(ctx.output("shape", "shape"));
        },
    .schema = R"({"type": "object", "additionalProperties": false, "properties": {
        "body": {"enum": ["sphere", "cylinder"], "default": "sphere", "description": "which shell"}}})"});

meshflow::StageRegistrar mesh_reg({
    .kind = "curve_test_linear",
    .version = 1,
    .summary = "test only: the curve tests' linear mesh on the input shape",
    .run =
        [](meshflow::StageContext& ctx) {
          auto S = meshflow::cad::Shape::load(ctx.input("shape").path);
          bool sphere = S.face_surface_type(0) == "sphere";
          int na = ctx.params().value("divisions", 16);
          auto g = sphere ? curvetest::sphere_grid(na, na / 2, 1.0, 0.05, 3.0, 3) : curvetest::cylinder_grid(na, 3, 1.0, 0.05, 3.0, 1.0, 3);
          auto B = curvetest::build(S, g);
          meshflow::io::write_mesh(B.mesh, ctx.output("mesh", "mesh"), meshflow::io::MeshFormat::MshBinary);
        },
    .schema = R"({"type": "object", "additionalProperties": false, "properties": {
        "divisions": {"type": "integer", "minimum": 6, "maximum": 64, "default": 16, "description": "divisions around"}}})"});

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
  auto d = fs::temp_directory_path() / ("meshflow-curve-wf-" + std::to_string(getpid()) + "-" + std::to_string(n++));
  fs::remove_all(d);
  fs::create_directories(d);
  return d;
}

nlohmann::json stage_report(const fs::path& out, const std::string& name) {
  auto rep = nlohmann::json::parse(slurp(out / "report.json"));
  for (auto& s : rep["stages"])
    if (s["name"] == name) return s;
  return {};
}

const char* kWorkflow = R"(meshflow: 1
name: curve-test
stages:
  shape:  {kind: curve_test_shape, with: {body: BODY}}
  linear: {kind: curve_test_linear, needs: [shape]}
  curve:  {kind: curve, needs: [shape, linear], with: {order: 3}}
outputs: {mesh: {from: curve}}
)";

}  // namespace

TEST_CASE("curve through meshflow run: artifact, stats, --set re-runs only curve, same bytes at 1 and 2 threads") {
  for (std::string body : {"sphere", "cylinder"}) {
    INFO(body);
    fs::path d = tmpdir();
    std::string wf = kWorkflow;
    wf.replace(wf.find("BODY"), 4, body);
    std::ofstream(d / "w.yaml") << wf;
    auto r1 = run({"run", (d / "w.yaml").string(), "--cache", (d / "cache1").string(), "--out", (d / "out1").string(), "--threads", "1"});
    INFO(r1.out << r1.err);
    REQUIRE(r1.code == 0);
    auto m = meshflow::io::read_mesh(d / "out1" / "mesh.msh");
    CHECK(m.order() == 3);
    CHECK(meshflow::model::build_topology(m).nonconforming_faces == 0);
    auto st = stage_report(d / "out1", "curve");
    REQUIRE(st.is_object());
    CHECK(st["status"] == "ran");
    CHECK(st["stats"]["mesh"]["invalid"] == 0);
    CHECK(st["stats"]["mesh"]["order"] == 3);
    CHECK(st["stats"]["curve"]["validity"]["invalid"] == 0);
    CHECK(st["stats"]["curve"]["max_distance_to_cad"]["surface"].get<double>() < 1e-7);
    CHECK(st["stats"]["curve"]["high_order_nodes"]["on_surfaces"].get<int>() > 0);

    auto r2 = run({"run", (d / "w.yaml").string(), "--cache", (d / "cache2").string(), "--out", (d / "out2").string(), "--threads", "2"});
    REQUIRE(r2.code == 0);
    CHECK(slurp(d / "out1" / "mesh.msh") == slurp(d / "out2" / "mesh.msh"));

    auto r3 = run({"run", (d / "w.yaml").string(), "--cache", (d / "cache1").string(), "--out", (d / "out3").string(), "--set",
                   "curve.order=4"});
    INFO(r3.out << r3.err);
    REQUIRE(r3.code == 0);
    CHECK(stage_report(d / "out3", "shape")["status"] == "cached");
    CHECK(stage_report(d / "out3", "linear")["status"] == "cached");
    CHECK(stage_report(d / "out3", "curve")["status"] == "ran");
    CHECK(meshflow::io::read_mesh(d / "out3" / "mesh.msh").order() == 4);

    auto r4 = run({"run", (d / "w.yaml").string(), "--cache", (d / "cache1").string(), "--out", (d / "out4").string(), "--set",
                   "curve.order=7"});
    CHECK(r4.code != 0);
    fs::remove_all(d);
  }
}
