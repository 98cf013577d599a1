// report.html (engine/run_report + stages/mesh_report) from a small run: a test kind writes an
// order-2 hex box, optionally with one element inverted (its interior node pushed out). The page
// is self-contained, names the invalid elements' ids (found here independently from the mesh
// written), renders in headless Chromium to a picture that is not blank, is rebuilt identically
// by `meshflow report`, and `report: false` writes none.
#include <doctest/doctest.h>

#include "support.hpp"

#include "engine/stage.hpp"
#include "stages/contract/contract.hpp"
#include "stages/io/mesh_io.hpp"
#include "stages/model/quality.hpp"

#include <nlohmann/json.hpp>

#include <cmath>
#include <map>
#include <set>
#include <string>

namespace {

namespace fs = std::filesystem;
using meshflow::model::Shape;

// n x n x n hexes of order 2 on the unit cube; with `invert`, element 1's interior node moved
// 1.3 cells along x (det J < 0 inside it).
meshflow::model::Mesh box(int n, bool invert) {
  meshflow::model::Mesh m;
  m.add_physical(3, 1, "fluid");
  m.add_entity(3, 1, {1});
  auto& blk = m.block(Shape::Hex, 2, 3, 1);
  std::map<std::array<long, 3>, std::uint32_t> at;
  const auto& ref = meshflow::model::reference_nodes(Shape::Hex, 2);
  const double h = 1.0 / n;
  for (int k = 0; k < n; ++k)
    for (int j = 0; j < n; ++j)
      for (int i = 0; i < n; ++i) {
        std::vector<std::uint32_t> el;
        for (std::size_t r = 0; r < ref.size(); ++r) {
          std::array<long, 3> key{long(2 * i + ref[r][0] + 1), long(2 * j + ref[r][1] + 1), long(2 * k + ref[r][2] + 1)};
          const bool interior = r + 1 == ref.size();
          auto it = at.find(key);
          if (it == at.end() || interior) {
            double x = key[0] * h / 2, y = key[1] * h / 2, z = key[2] * h / 2;
            if (interior && invert && i == 0 && j == 0 && k == 0) x += 1.3 * h;
            std::uint32_t id = m.add_node(x, y, z);
            if (!interior) at[key] = id;
            el.push_back(id);
          } else {
            el.push_back(it->second);
          }
        }
        blk.add(el.data());
      }
  return m;
}

meshflow::StageRegistrar box_reg({
    .kind = "report_test_box",
    .version = 1,
    .summary = "test only: an order-2 hex box, optionally with an inverted element",
    .run =
        [](meshflow::StageContext& ctx) {
          auto m = box(ctx.params().value("cells", 4), ctx.params().value("invert", false));
          meshflow::io::write_mesh(m, ctx.output("mesh", "mesh"), meshflow::io::MeshFormat::MshBinary);
          auto q = meshflow::contract::record(ctx, m, meshflow::contract::Extent::NearField, nullptr);
          const std::string stored = ctx.params().value("quality", "none");
          if (stored == "halved")  // not the mesh's: shows whether the page reads the stored one
            for (auto& b : q)
              for (auto& e : b) e.scaled_jacobian *= 0.5;
          if (stored != "none") meshflow::io::write_quality(m, q, ctx.output("quality", "mesh_quality"));
        },
    .schema = R"({"type": "object", "additionalProperties": false, "properties": {
        "cells": {"type": "integer", "minimum": 1, "maximum": 10, "default": 4, "description": "cells per side"},
        "invert": {"type": "boolean", "default": false, "description": "invert element 1"},
        "quality": {"enum": ["none", "stored", "halved"], "default": "none",
                    "description": "store the contract quality beside the mesh; halved: its scaled Jacobians halved"}}})"});

struct Run {
  fs::path dir, out;
  mftest::Cli cli;
};

Run run_box(bool invert, bool report = true, const std::string& quality = "none") {
  Run r;
  r.dir = mftest::temp_dir("mesh-report");
  r.out = r.dir / "out";
  mftest::write_text(r.dir / "wf.yaml", std::string("meshflow: 1\nname: box\n") + (report ? "" : "report: false\n") +
                                            "stages:\n  box: {kind: report_test_box, with: {invert: " +
                                            (invert ? "true" : "false") + ", quality: " + quality +
                                            "}}\noutputs:\n  mesh: {from: box}\n");
  r.cli = mftest::run_cli({"run", (r.dir / "wf.yaml").string(), "--cache", (r.dir / "cache").string(), "--out",
                           r.out.string(), "--threads", "2"});
  return r;
}

// Element tags with det J <= 0 somewhere, from the mesh file (mesh_stats' tag rule: implicit
// tags count the elements of every block).
std::set<std::uint64_t> invalid_tags(const fs::path& msh) {
  auto m = meshflow::io::read_mesh(msh);
  auto q = meshflow::model::mesh_quality(m, 1);
  std::set<std::uint64_t> out;
  std::uint64_t running = 0;
  for (std::size_t b = 0; b < m.blocks.size(); ++b) {
    for (std::size_t e = 0; e < q[b].size(); ++e)
      if (!q[b][e].valid) out.insert(m.blocks[b].tags.empty() ? running + e + 1 : m.blocks[b].tags[e]);
    running += m.blocks[b].size();
  }
  return out;
}

void check_self_contained(const std::string& page) {
  CHECK(page.rfind("<!DOCTYPE html>", 0) == 0);
  CHECK(page.find("http:") == std::string::npos);
  CHECK(page.find("https:") == std::string::npos);
  CHECK(page.find("<script") == std::string::npos);
  CHECK(page.find("<link") == std::string::npos);
  CHECK(page.find("@import") == std::string::npos);
  CHECK(page.find("url(") == std::string::npos);
  CHECK(page.find("</html>") != std::string::npos);
}

}  // namespace

TEST_CASE("a small run writes a self-contained report.html with the stage table, histograms and pictures") {
  Run r = run_box(false);
  INFO(r.cli.out, r.cli.err);
  REQUIRE(r.cli.code == 0);
  const std::string page = mftest::read_text(r.out / "report.html");
  REQUIRE(!page.empty());
  check_self_contained(page);
  CHECK(page.find("<h2>Stages</h2>") != std::string::npos);
  CHECK(page.find("report_test_box") != std::string::npos);
  CHECK(page.find("scaled Jacobian histogram") != std::string::npos);
  CHECK(page.find("aspect ratio histogram") != std::string::npos);
  CHECK(page.find("<title>surface from +x +y +z</title>") != std::string::npos);
  CHECK(page.find("<title>cut z = 0.5</title>") != std::string::npos);
  CHECK(r.cli.out.find("report: ") != std::string::npos);
  // `meshflow report OUT_DIR` rebuilds the same page from report.json and the cache
  fs::path first = r.dir / "first.html";
  fs::rename(r.out / "report.html", first);
  auto again = mftest::run_cli({"report", r.out.string(), "--threads", "1"});
  INFO(again.err);
  CHECK(again.code == 0);
  CHECK(mftest::read_text(r.out / "report.html") == mftest::read_text(first));
  // and from the outputs alone when the cache is gone (the stored mesh is out/mesh.msh)
  fs::remove_all(r.dir / "cache");
  fs::remove(r.out / "report.html");
  CHECK(mftest::run_cli({"report", r.out.string()}).code == 0);
  CHECK(mftest::read_text(r.out / "report.html") == mftest::read_text(first));
  // a folder without report.json: exit 2
  CHECK(mftest::run_cli({"report", r.dir.string()}).code == 2);
}

TEST_CASE("the page draws the quality its stage stored beside the mesh, not a second computation") {
  // stored: the contract's own numbers, so the page is the one computed without them (the cache gone)
  Run r = run_box(false, true, "stored");
  INFO(r.cli.out, r.cli.err);
  REQUIRE(r.cli.code == 0);
  const std::string stored = mftest::read_text(r.out / "report.html");
  fs::remove_all(r.dir / "cache");
  fs::remove(r.out / "report.html");
  REQUIRE(mftest::run_cli({"report", r.out.string()}).code == 0);
  const std::string computed = mftest::read_text(r.out / "report.html");
  CHECK(stored == computed);
  // halved: the stored numbers are what the pictures show
  Run h = run_box(false, true, "halved");
  REQUIRE(h.cli.code == 0);
  const std::string halved = mftest::read_text(h.out / "report.html");
  // the same run's page rebuilt without the cache (computed quality) is not the one drawn from
  // the halved numbers (the page is otherwise a function of report.json and the mesh)
  fs::remove_all(h.dir / "cache");
  fs::remove(h.out / "report.html");
  REQUIRE(mftest::run_cli({"report", h.out.string()}).code == 0);
  CHECK(mftest::read_text(h.out / "report.html") != halved);
}

TEST_CASE("an invalid mesh's page lists and marks its invalid elements by id") {
  Run r = run_box(true);
  INFO(r.cli.out, r.cli.err);
  REQUIRE(r.cli.code == 3);
  const std::string page = mftest::read_text(r.out / "report.html");
  check_self_contained(page);
  auto bad = invalid_tags(r.out / "mesh.msh");
  REQUIRE(!bad.empty());
  CHECK(page.find("INVALID") != std::string::npos);
  CHECK(page.find("Where the listed elements are") != std::string::npos);
  for (auto t : bad) {
    CAPTURE(t);
    CHECK(page.find("<tr><td>" + std::to_string(t) + "</td>") != std::string::npos);  // the table
    CHECK(page.find(">" + std::to_string(t) + "</text>") != std::string::npos);       // the mark
  }
  // elements that are valid are not listed
  for (std::uint64_t t = 1; t <= 64; ++t)
    if (!bad.count(t)) CHECK(page.find("<tr><td>" + std::to_string(t) + "</td><td>hex2") == std::string::npos);
}

TEST_CASE("report: false writes no page and removes an older one") {
  Run r = run_box(false);
  REQUIRE(r.cli.code == 0);
  REQUIRE(fs::exists(r.out / "report.html"));
  mftest::write_text(r.dir / "wf.yaml", "meshflow: 1\nname: box\nreport: false\nstages:\n"
                                        "  box: {kind: report_test_box}\noutputs:\n  mesh: {from: box}\n");
  auto again = mftest::run_cli({"run", (r.dir / "wf.yaml").string(), "--cache", (r.dir / "cache").string(), "--out", r.out.string()});
  CHECK(again.code == 0);
  CHECK(!fs::exists(r.out / "report.html"));
  CHECK(fs::exists(r.out / "report.json"));
}

TEST_CASE("the page renders in headless Chromium to a picture that is not blank") {
  Run r = run_box(true);
  REQUIRE(r.cli.code == 3);
  const fs::path png = r.dir / "page.png";
  auto shot = mftest::sh("timeout 120 chromium --headless --no-sandbox --disable-gpu --hide-scrollbars --window-size=1280,3000 --screenshot=" +
                         png.string() + " file://" + (r.out / "report.html").string() + " 2>&1");
  INFO(shot.out);
  REQUIRE(fs::exists(png));
  // several distinct colours (quality colours, purple marks, text), and not nearly all white
  auto stats = mftest::sh(std::string(MESHFLOW_PYTHON) +
                          " -c \"from PIL import Image; im = Image.open('" + png.string() +
                          "').convert('RGB'); c = im.getcolors(1 << 24); n = sum(k for k, _ in c); "
                          "w = sum(k for k, v in c if min(v) > 245); print(len(c), round(1 - w / n, 4))\"");
  INFO(stats.out);
  REQUIRE(stats.code == 0);
  int colours = 0;
  double inked = 0;
  REQUIRE(std::sscanf(stats.out.c_str(), "%d %lf", &colours, &inked) == 2);
  CHECK(colours >= 50);
  CHECK(inked > 0.05);
}
