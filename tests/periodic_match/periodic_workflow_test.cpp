// periodic_match end to end through `meshflow run`, as a user runs it: the parametric wing with
// its box sides y = -2 / y = 2 tagged periodic (translation, divisions from balance checked), and
// workflows/rotor67.yaml (rotation by 2π/22).
#include <doctest/doctest.h>

#include "support.hpp"

#include "stages/periodic_match/periodic.hpp"

#include <nlohmann/json.hpp>

#include <cmath>
#include <cstdlib>

namespace per = meshflow::periodic;
namespace fs = std::filesystem;

namespace {
int run(const fs::path& wf, const fs::path& dir) {
  std::string cmd = std::string(MESHFLOW_EXE) + " run " + wf.string() + " --threads 2 --cache " + (dir / "cache").string() + " --out " +
                    (dir / "out").string() + " > " + (dir / "log").string() + " 2>&1";
  int rc = std::system(cmd.c_str());
  if (rc != 0) MESSAGE(mftest::read_text(dir / "log"));
  return rc;
}
}  // namespace

TEST_CASE("meshflow run: naca_wing with periodic box sides -> balance -> periodic_match (translation, equal divisions)") {
  fs::path dir = mftest::temp_dir("periodic-e2e");
  mftest::write_text(dir / "wf.yaml",
                     "meshflow: 1\nname: periodic-e2e\nstages:\n"
                     "  geometry:\n    kind: naca_wing\n    with:\n      farfield_chords: 2\n      wake_chords: 3\n"
                     "      tag_overrides:\n"
                     "        - {tag: periodic_lo, plane: {point: [0, -2, 0], normal: [0, 1, 0]}}\n"
                     "        - {tag: periodic_hi, plane: {point: [0, 2, 0], normal: [0, 1, 0]}}\n"
                     "  heal: {kind: heal, needs: [geometry]}\n"
                     "  medial: {kind: medial, needs: [heal]}\n"
                     "  shell: {kind: shell, needs: [heal, medial]}\n"
                     "  balance: {kind: balance, needs: [heal, shell]}\n"
                     "  periodic_match: {kind: periodic_match, needs: [heal, balance]}\n"
                     "outputs:\n  periodic: {from: periodic_match}\n");
  REQUIRE(run(dir / "wf.yaml", dir) == 0);
  per::Match m = per::read(dir / "out" / "periodic.mfper");
  CHECK(m.transform.kind == "translation");
  CHECK(std::abs(m.transform.translation[1] - 4) < 1e-12);
  CHECK(std::abs(m.transform.translation[0]) + std::abs(m.transform.translation[2]) < 1e-12);
  CHECK(m.faces.size() == 1);
  CHECK(m.edges.size() == 4);
  CHECK(m.max_mismatch < 1e-9 * m.model_size);
  nlohmann::json st = mftest::stage_stats(dir / "out", "periodic_match");
  MESSAGE("periodic_match stats: " << st.dump());
  if (!st.empty()) {
    CHECK(st["divisions"]["checked"] == true);
    CHECK(st["divisions"]["edge_pairs"] == 4);
  }
  // cached on a second run
  REQUIRE(run(dir / "wf.yaml", dir) == 0);
  CHECK(mftest::read_text(dir / "log").find("cached") != std::string::npos);
  fs::remove_all(dir);
}

TEST_CASE("meshflow run: workflows/rotor67.yaml matches the periodic sides by the rotation 2 pi / 22 about x") {
  REQUIRE(fs::exists(fs::path(MESHFLOW_DATA_DIR) / "rotor67/rotor67geometry.dat"));
  fs::path dir = mftest::temp_dir("periodic-rotor67");
  // the workflow up to periodic_match (the stages after it and their outputs removed)
  std::string wf = mftest::workflow_without(fs::path(MESHFLOW_SOURCE_DIR) / "workflows/rotor67.yaml", dir / "rotor67_periodic.yaml",
                                            {"sweep", "tet", "curve", "optimise", "split", "near", "linear", "mesh"});
  REQUIRE(run(wf, dir) == 0);
  per::Match m = per::read(dir / "out" / "periodic.mfper");
  CHECK(m.transform.kind == "rotation");
  CHECK(m.transform.axis_dir == std::array<double, 3>{1, 0, 0});
  CHECK(std::abs(m.transform.angle - 2 * M_PI / 22) < 1e-15);
  CHECK(m.faces.size() == 1);
  CHECK(m.face_mismatch < 1e-12 * m.model_size);
  auto st = mftest::stage_stats(dir / "out", "periodic_match");
  MESSAGE("rotor67 periodic_match stats: " << st.dump());
  CHECK(st["divisions"]["checked"] == true);  // the workflow runs balance: paired edges have equal divisions
  fs::remove_all(dir);
}
