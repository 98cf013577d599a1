// workflows/wing_body_parametric.yaml end to end through sweep and tet (meshflow run, as a user
// runs it): the CRM-like wing-body half model gives a valid, conforming linear hybrid mesh with
// junction hexes along the wing-body junction (body = face A, wing surface and blunt
// trailing-edge face = the partners B sharing the trailing-edge edges at the junction ends).
#include <doctest/doctest.h>

#include "stages/io/mesh_io.hpp"
#include "stages/model/quality.hpp"
#include "support.hpp"

#include <nlohmann/json.hpp>

#include <filesystem>
#include <string>

namespace {
namespace fs = std::filesystem;
using meshflow::model::Shape;
std::size_t count_of(const meshflow::model::Mesh& m, Shape s) {
  std::size_t n = 0;
  for (auto& b : m.blocks)
    if (b.shape == s && b.entity_dim == 3) n += b.size();
  return n;
}
}  // namespace

TEST_CASE("wing_body_parametric.yaml through sweep and tet: valid, conforming, prisms, junction hexes and tets") {
  fs::path dir = mftest::temp_dir("sweep-wing-body");
  std::string wf = std::string(MESHFLOW_SOURCE_DIR) + "/workflows/wing_body_parametric.yaml";
  auto r = mftest::sh("cd " + dir.string() + " && " + std::string(MESHFLOW_EXE) + " run " + wf + " --cache " +
                      (dir / "cache").string() + " --out " + (dir / "out").string() + " 2>&1");
  INFO(r.out);
  REQUIRE(r.code == 0);
  auto rep = nlohmann::json::parse(mftest::read_text(dir / "out/report.json"));
  for (auto& s : rep["stages"]) {
    if (!s.contains("stats") || !s["stats"].contains("mesh")) continue;
    INFO(s["name"].get<std::string>());
    CHECK(s["stats"]["mesh"]["invalid"] == 0);
    CHECK(s["stats"]["mesh"]["nonconforming_faces"] == 0);
  }
  // our own reading of the written file, independent of the stage's report
  auto mesh = meshflow::io::read_mesh(dir / "out/linear.msh");
  auto st = meshflow::model::mesh_stats(mesh);
  CHECK(st.at("invalid").get<int>() == 0);
  CHECK(st.at("nonconforming_faces").get<int>() == 0);
  CHECK(count_of(mesh, Shape::Prism) > 1000);
  CHECK(count_of(mesh, Shape::Hex) > 10);  // the wing-body junction (root loop + trailing-edge face)
  CHECK(count_of(mesh, Shape::Tet) > 1000);
  MESSAGE("wing-body linear mesh: " << count_of(mesh, Shape::Prism) << " prisms, " << count_of(mesh, Shape::Hex)
                                    << " hexes, " << count_of(mesh, Shape::Tet) << " tets, " << count_of(mesh, Shape::Pyramid)
                                    << " pyramids, min scaled Jacobian " << st.at("min_scaled_jacobian"));
}

// At balance.max_size 0.04 the nose's parameter plane (a pole at v = 0) gave one triangle pair
// folded onto itself around the pole (the same three nodes twice), which tet refused as a
// boundary face given twice; sweep now removes such pairs.
TEST_CASE("wing_body_parametric.yaml with coarser walls (max_size 0.04): the nose pole has no folded triangle pair") {
  fs::path dir = mftest::temp_dir("sweep-wing-body-coarse");
  std::string wf = std::string(MESHFLOW_SOURCE_DIR) + "/workflows/wing_body_parametric.yaml";
  auto r = mftest::sh("cd " + dir.string() + " && " + std::string(MESHFLOW_EXE) + " run " + wf +
                      " --set balance.max_size=0.04 -v --cache " + (dir / "cache").string() + " --out " + (dir / "out").string() +
                      " 2>&1");
  INFO(r.out);
  REQUIRE(r.code == 0);
  CHECK(r.out.find("folded triangle pair(s) at a pole removed") != std::string::npos);
  auto mesh = meshflow::io::read_mesh(dir / "out/linear.msh");
  auto st = meshflow::model::mesh_stats(mesh);
  CHECK(st.at("invalid").get<int>() == 0);
  CHECK(st.at("nonconforming_faces").get<int>() == 0);
  CHECK(count_of(mesh, Shape::Hex) > 0);
}
