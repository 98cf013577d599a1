// The medial stage end to end on the naca_wing geometry (through the CAD interface).
#include <doctest/doctest.h>

#include "support.hpp"

#include "../cad/test_context.hpp"
#include "engine/stage.hpp"
#include "stages/cad/cad.hpp"
#include "stages/medial/medial.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <sstream>

using meshflow::StageError;
using meshflow::testing::TestContext;
using namespace meshflow::medial;

namespace {
// NACA 00tt half thickness (blunt trailing edge), chord 1.
double yt(double t, double x) {
  return 5 * t * (0.2969 * std::sqrt(x) - 0.1260 * x - 0.3516 * x * x + 0.2843 * x * x * x - 0.1015 * x * x * x * x);
}
}  // namespace

TEST_CASE("medial stage on naca_wing: body radius = half thickness at mid-chord, tiny at the trailing edge, root halos, deterministic") {
  TestContext geo("naca_wing", {{"incidence_deg", 0.0}});
  geo.run();
  meshflow::Artifact shape = geo.artifact("shape");
  TestContext a("medial", {}, {shape}), b("medial", {}, {shape});
  a.run();
  b.run();
  auto pa = a.artifact("medial").path;
  CHECK(mftest::read_text(pa) == mftest::read_text(b.artifact("medial").path));
  MESSAGE("naca_wing stats: " << a.stats_.dump());
  MedialObject M = read(pa);
  auto cadshape = meshflow::cad::Shape::load(shape.path);
  auto walls = cadshape.faces_with_tag(meshflow::cad::Tag::wall);
  auto syms = cadshape.faces_with_tag(meshflow::cad::Tag::symmetry);
  REQUIRE(syms.size() == 1);
  auto is_wall = [&](int f) { return std::find(walls.begin(), walls.end(), f) != walls.end(); };

  // body side, straight part of the span: the camber line (y = 0), radius ~ half thickness
  double worst_mid = 0, max_te = 0;
  long n_mid = 0, n_te = 0;
  for (auto& p : M.points) {
    if (p.side != Side::body || p.c[2] < 0.2 || p.c[2] > 0.7) continue;
    double x = p.c[0];
    if (x > 0.3 && x < 0.6) {
      // the medial ball at x touches the surface near x, where the thickness varies slowly:
      // its radius is within the half-thickness range over x ± r
      double r = p.radius, lo = 1e9, hi = 0;
      for (double s = x - 2 * r; s <= x + 2 * r; s += r / 20) lo = std::min(lo, yt(0.12, s)), hi = std::max(hi, yt(0.12, s));
      double e = r < lo ? lo - r : r > hi ? r - hi : 0;
      worst_mid = std::max(worst_mid, e / yt(0.12, x));
      CHECK(std::abs(p.c[1]) < 0.02 * 0.12);
      ++n_mid;
    }
    if (x > 0.98) {
      max_te = std::max(max_te, p.radius);
      ++n_te;
    }
  }
  MESSAGE("naca_wing: mid-chord body points " << n_mid << " radius error / half-thickness " << worst_mid
                                               << "; trailing-edge (x > 0.98) points " << n_te << " max radius " << max_te);
  CHECK(n_mid > 50);
  CHECK(worst_mid < 0.02);
  CHECK(n_te > 5);
  CHECK(max_te < 0.1 * yt(0.12, 0.3));
  // the wing-root junction: fluid-side halos between the wing and the root wall
  long root_halos = 0;
  for (auto& h : M.halos)
    if ((h.face_a == syms[0] && is_wall(h.face_b)) || (h.face_b == syms[0] && is_wall(h.face_a))) {
      if (M.points[h.medial].c[2] < 0.05) ++root_halos;
    }
  CHECK(root_halos > 50);
  // every wall sample has a feature size, small at the trailing edge
  long wall_samples = 0;
  for (std::size_t i = 0; i < M.samples.size(); ++i)
    if (M.samples[i].refined) {
      ++wall_samples;
      CHECK(M.info[i].lfs > 0);
    }
  CHECK(wall_samples > 1000);
  CHECK(a.progress_ok_);
  CHECK(a.stats_["medial_points"]["body"].get<long>() > 0);
}

TEST_CASE("medial stage on naca_wing: the same bytes with a budget of 1 and of 2 threads") {
  TestContext geo("naca_wing", {{"incidence_deg", 0.0}});
  geo.run();
  meshflow::Artifact shape = geo.artifact("shape");
  TestContext a("medial", {}, {shape}), b("medial", {}, {shape});
  b.threads_ = 2;
  a.run();
  b.run();
  std::string one = mftest::read_text(a.artifact("medial").path), two = mftest::read_text(b.artifact("medial").path);
  CHECK(one.size() > 1000);
  CHECK(one == two);
  CHECK(a.stats_["projections"] == b.stats_["projections"]);
}

TEST_CASE("medial stage: refuses a shape that is not a closed solid") {
  TestContext bogus("medial", {}, {meshflow::Artifact{.name = "shape", .type = "shape", .path = "/nonexistent/x.mfshape"}});
  CHECK_THROWS_AS(bogus.run(), StageError);
  TestContext none("medial", {}, {});
  CHECK_THROWS_AS(none.run(), StageError);
}

TEST_CASE("meshflow run: geometry -> heal -> medial, identical bytes with 1 and 2 threads") {
  namespace fs = std::filesystem;
  fs::path dir = meshflow::testing::scratch_dir("medial-e2e");
  {
    std::ofstream w(dir / "wf.yaml");
    w << "meshflow: 1\nname: medial-e2e\nstages:\n"
         "  geometry: {kind: naca_wing}\n"
         "  heal: {kind: heal, needs: [geometry]}\n"
         "  medial: {kind: medial, needs: [heal], with: {passes: 2}}\n"
         "outputs:\n  medial: {from: medial}\n";
  }
  auto run = [&](int threads, const std::string& tag) {  // -j 1: the stage gets all of --threads (threads / jobs)
    std::string cmd = std::string(MESHFLOW_EXE) + " run " + (dir / "wf.yaml").string() + " -j 1 --threads " + std::to_string(threads) +
                      " --cache " + (dir / ("cache" + tag)).string() + " --out " + (dir / ("out" + tag)).string() + " > " +
                      (dir / ("log" + tag)).string() + " 2>&1";
    return std::system(cmd.c_str());
  };
  REQUIRE(run(1, "1") == 0);
  REQUIRE(run(2, "2") == 0);
  std::string a = mftest::read_text(dir / "out1" / "medial.mfmedial"), b = mftest::read_text(dir / "out2" / "medial.mfmedial");
  CHECK(a.size() > 1000);
  CHECK(a == b);
  MedialObject M = read(dir / "out1" / "medial.mfmedial");
  CHECK(M.points.size() > 1000);
  CHECK(nlohmann::json::parse(M.header).at("units") == "m");
  std::filesystem::remove_all(dir);
}
