// periodic_match: find() on the Rotor 67 sector (rotation about the machine axis by 2π/22) and
// on shapes made in tests/periodic_match/shapes.cpp (OCCT): a box with translational sides,
// perturbed and untagged sides; the stage with divisions; the artifact round trip.
#include <doctest/doctest.h>

#include "../cad/test_context.hpp"
#include "shapes.hpp"
#include "stages/cad/cad.hpp"
#include "stages/periodic_match/periodic.hpp"

#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <sstream>

using meshflow::StageError;
using meshflow::cad::Shape;
using meshflow::cad::Tag;
using meshflow::testing::TestContext;
namespace fs = std::filesystem;
namespace per = meshflow::periodic;

namespace {
const fs::path kRotor = fs::path(MESHFLOW_DATA_DIR) / "rotor67/rotor67geometry.dat";

std::string slurp(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

// The Rotor 67 sector through blade_sector and heal, made once per test process.
struct Rotor {
  std::unique_ptr<TestContext> geo, heal;
  meshflow::Artifact shape;
};
Rotor& rotor() {
  static Rotor r = [] {
    Rotor x;
    x.geo = std::make_unique<TestContext>("blade_sector", nlohmann::json{{"file", kRotor.string()}});
    x.geo->run();
    x.heal = std::make_unique<TestContext>("heal", nlohmann::json::object(), std::vector<meshflow::Artifact>{x.geo->artifact("shape")});
    x.heal->run();
    x.shape = x.heal->artifact("shape");
    return x;
  }();
  return r;
}
}  // namespace

TEST_CASE("Rotor 67: rotation about the machine axis by 2 pi / 22, every periodic entity paired") {
  if (!fs::exists(kRotor)) return;
  Shape s = Shape::load(rotor().shape.path);
  std::vector<std::string> log;
  auto t0 = std::chrono::steady_clock::now();
  per::Match m = per::find(s, 1e-6, [&](const std::string& l) { log.push_back(l); });
  double sec = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  for (auto& l : log) MESSAGE(l);
  MESSAGE("Rotor 67 find(): " << sec << " s; " << m.faces.size() << " face, " << m.edges.size() << " edge, " << m.vertices.size()
                              << " vertex pairs; mismatch faces " << m.face_mismatch << ", edges " << m.edge_mismatch << ", vertices "
                              << m.vertex_mismatch << " " << m.units << " (model size " << m.model_size << ")");
  CHECK(m.transform.kind == "rotation");
  CHECK(std::abs(std::abs(m.transform.axis_dir[0]) - 1) < 1e-12);
  CHECK(std::abs(std::abs(m.transform.angle) - 2 * M_PI / 22) < 1e-12);
}
