// The shell stage on the two real workflows that have a junction between walls of separate
// bodies, DLR-F6 (workflows/wing_body.yaml: wing-fuselage, pylon, nacelle) and Rotor 67
// (workflows/rotor67.yaml: the blade on the hub and under the casing), each run up to its shell
// stage with `meshflow run` as a user runs it:
//   - topology C (the workflows' own) puts hexahedral junction blocks at those junctions, and
//     topology O (--set shell.topology=O) puts none;
//   - the shell artifact is identical, byte for byte, at 2 threads and again at 1;
//   - on Rotor 67 the medial radius of the narrow blade passage limits the thickness somewhere
//     (stats.not_honoured.limited_by_medial).
// The crossing pairs of these shells are ratcheted by tests/shell/dlr_f6_test.cpp and
// tests/sweep/periodic_test.cpp, which go on to sweep.
#include <doctest/doctest.h>

#include "support.hpp"

#include <nlohmann/json.hpp>

#include <filesystem>
#include <string>
#include <vector>

namespace {
namespace fs = std::filesystem;

struct Shelled {
  int code = 0;
  std::string log;
  nlohmann::json stats;
  std::string key;
};

Shelled run_to_shell(const fs::path& wf, const fs::path& dir, const std::string& cache, const std::string& extra) {
  auto r = mftest::sh(std::string(MESHFLOW_EXE) + " run " + wf.string() + " " + extra + " --cache " + (dir / cache).string() +
                      " --out " + (dir / ("out-" + cache)).string() + " 2>&1");
  Shelled s{r.code, r.out, {}, {}};
  if (r.code != 0) return s;
  auto rep = nlohmann::json::parse(mftest::read_text(dir / ("out-" + cache) / "report.json"));
  for (auto& st : rep["stages"])
    if (st["name"] == "shell") s.stats = st["stats"], s.key = st["key"];
  return s;
}

void check_real_shell(const std::string& workflow, const std::vector<std::string>& drop, bool passage) {
  fs::path dir = mftest::temp_dir("shell-real");
  std::string wf = mftest::workflow_without(fs::path(MESHFLOW_SOURCE_DIR) / "workflows" / workflow, dir / workflow, drop);
  // the shell artifact as an output of the copy (Rotor 67's workflow does not write it)
  std::string text = mftest::read_text(wf);
  if (text.find("  shell: {from: shell}") == std::string::npos) {
    auto at = text.find("\noutputs:\n");
    REQUIRE(at != std::string::npos);
    text.insert(at + 10, "  shell: {from: shell}\n");
    mftest::write_text(wf, text);
  }
  // the workflow's shell (topology C) from an empty cache at 2 threads
  Shelled a = run_to_shell(wf, dir, "a", "--threads 2");
  INFO(a.log);
  REQUIRE(a.code == 0);
  REQUIRE(a.stats.is_object());
  // the shell again at 1 thread on the same inputs: a copy of the cache without the shell's
  // action entry (cache/actions/<key>.json), so that only the shell re-runs
  fs::copy(dir / "a", dir / "b", fs::copy_options::recursive);
  REQUIRE(fs::remove(dir / "b/actions" / (a.key + ".json")));
  Shelled b = run_to_shell(wf, dir, "b", "--threads 1");
  INFO(b.log);
  REQUIRE(b.code == 0);
  CHECK(b.log.find("ran     shell") != std::string::npos);
  CHECK(b.log.find("ran     medial") == std::string::npos);
  const std::string bytes_a = mftest::read_text(dir / "out-a/shell.mfshell"), bytes_b = mftest::read_text(dir / "out-b/shell.mfshell");
  CHECK(!bytes_a.empty());
  CHECK(bytes_a == bytes_b);
  const long blocks_c = a.stats.at("counts").at("hex_junction_blocks").get<long>();
  MESSAGE(workflow << " shell (C): " << blocks_c << " junction blocks, " << a.stats.at("self_intersections") << " crossing pairs, not honoured "
                   << a.stats.at("not_honoured").dump());
  CHECK(blocks_c > 0);
  if (passage) CHECK(a.stats.at("not_honoured").at("limited_by_medial").get<long>() > 0);
  // topology O on the same inputs (only shell re-runs): no junction block anywhere
  Shelled o = run_to_shell(wf, dir, "a", "--set shell.topology=O");
  INFO(o.log);
  REQUIRE(o.code == 0);
  MESSAGE(workflow << " shell (O): " << o.stats.at("counts").dump());
  CHECK(o.stats.at("counts").at("hex_junction_blocks").get<long>() == 0);
  fs::remove_all(dir);
}

}  // namespace

TEST_CASE("shell on DLR-F6 (wing_body.yaml): junction blocks with topology C, none with O, same bytes at 1 and 2 threads") {
  REQUIRE(fs::exists(fs::path(MESHFLOW_DATA_DIR) / "dlr_f6/dlr_f6.brep"));
  check_real_shell("wing_body.yaml", {"balance", "sweep", "tet", "curve", "optimise", "split", "divisions", "linear", "mesh"}, false);
}

TEST_CASE("shell on Rotor 67 (rotor67.yaml): junction blocks at hub and casing with C, none with O, passage limits the thickness, same bytes") {
  REQUIRE(fs::exists(fs::path(MESHFLOW_DATA_DIR) / "rotor67/rotor67geometry.dat"));
  check_real_shell("rotor67.yaml",
                   {"balance", "periodic_match", "sweep", "tet", "curve", "optimise", "split", "periodic", "near", "linear", "mesh"}, true);
}
