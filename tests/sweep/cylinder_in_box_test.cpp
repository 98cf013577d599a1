// workflows/cylinder_in_box.yaml up to tet (issue 20, clause 5): a short cylinder cut out of a
// box, whose end discs are planar faces bounded by one closed circular edge each. Their face mesh
// had up to 12 points of one refinement pass at the disc's centre (the common circumcentre of a
// regular polygon's triangles), coincident nodes: zero-area wall triangles and prisms of aspect
// ratio 3e14 that tet and curve inherited (327 elements inverted by curving there). The linear
// mesh has no coincident nodes, no element with an edge shorter than 1e-9 of its longest, and a
// finite, moderate max aspect ratio.
#include <doctest/doctest.h>

#include "stages/io/mesh_io.hpp"
#include "stages/model/quality.hpp"
#include "support.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <array>
#include <cmath>
#include <filesystem>
#include <string>
#include <vector>

namespace {
namespace fs = std::filesystem;
using meshflow::model::Shape;
}  // namespace

TEST_CASE("cylinder_in_box.yaml through tet: no coincident nodes at the end-disc centres, no element with a zero-length edge, max aspect ratio moderate") {
  fs::path step = fs::path(MESHFLOW_DATA_DIR) / "corpus/cylinder_in_box.step";
  REQUIRE(fs::exists(step));
  fs::path dir = mftest::temp_dir("sweep-cylinder-in-box");
  std::string wf = mftest::workflow_without(std::string(MESHFLOW_SOURCE_DIR) + "/workflows/cylinder_in_box.yaml",
                                            dir / "cylinder_in_box_linear.yaml", {"curve", "optimise", "split", "shape", "mesh"});
  auto r = mftest::sh("cd " + dir.string() + " && " + std::string(MESHFLOW_EXE) + " run " + wf + " --cache " +
                      (dir / "cache").string() + " --out " + (dir / "out").string() + " 2>&1");
  INFO(r.out);
  REQUIRE(r.code == 0);
  for (std::string stage : {"sweep", "tet"}) {
    auto st = mftest::stage_stats(dir / "out", stage);
    INFO(stage);
    REQUIRE(st.contains("mesh"));
    double ar = st["mesh"]["max_aspect_ratio"].get<double>();
    MESSAGE(stage << ": max aspect ratio " << ar << ", min scaled Jacobian " << st["mesh"]["min_scaled_jacobian"]);
    CHECK(std::isfinite(ar));
    CHECK(ar < 1e4);
    CHECK(st["mesh"]["invalid"] == 0);
  }
  // our own reading of the written linear mesh
  auto mesh = meshflow::io::read_mesh(dir / "out/linear.msh");
  auto X = [&](std::uint32_t i) { return std::array<double, 3>{mesh.x[i], mesh.y[i], mesh.z[i]}; };
  auto dist = [&](std::uint32_t a, std::uint32_t b) {
    auto p = X(a), q = X(b);
    return std::sqrt((p[0] - q[0]) * (p[0] - q[0]) + (p[1] - q[1]) * (p[1] - q[1]) + (p[2] - q[2]) * (p[2] - q[2]));
  };
  // no two nodes within 1e-9 of the box's size (10) of one another: sorted by x, neighbours in x
  {
    std::vector<std::uint32_t> ord(mesh.num_nodes());
    for (std::uint32_t i = 0; i < ord.size(); ++i) ord[i] = i;
    std::sort(ord.begin(), ord.end(), [&](auto a, auto b) { return mesh.x[a] < mesh.x[b]; });
    std::size_t close = 0;
    for (std::size_t i = 0; i < ord.size(); ++i)
      for (std::size_t j = i + 1; j < ord.size() && mesh.x[ord[j]] - mesh.x[ord[i]] < 1e-8; ++j)
        if (dist(ord[i], ord[j]) < 1e-8) ++close;
    CHECK(close == 0);
  }
  double worst = INFINITY;
  std::size_t short_edged = 0, prisms = 0, wall_tris = 0;
  std::array<double, 3> where{};
  for (auto& b : mesh.blocks) {
    if (b.order != 1 || b.entity_dim < 2) continue;
    if (b.shape == Shape::Prism) prisms += b.size();
    if (b.shape == Shape::Tri) wall_tris += b.size();
    const auto& ev = meshflow::model::edge_vertices(b.shape);
    for (std::size_t e = 0; e < b.size(); ++e) {
      const std::uint32_t* n = b.element(e);
      double lo = INFINITY, hi = 0;
      for (auto& ab : ev) {
        double l = dist(n[ab[0]], n[ab[1]]);
        lo = std::min(lo, l), hi = std::max(hi, l);
      }
      double ratio = hi > 0 ? lo / hi : 0;
      if (ratio < 1e-9) ++short_edged;
      if (ratio < worst) worst = ratio, where = X(n[0]);
    }
  }
  MESSAGE("linear mesh: " << prisms << " prisms, " << wall_tris << " boundary triangles; smallest min/max edge ratio of an element "
                          << worst << " at (" << where[0] << ", " << where[1] << ", " << where[2] << ")");
  CHECK(prisms > 500);
  CHECK(short_edged == 0);
  CHECK(worst > 1e-3);
}
