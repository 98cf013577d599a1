// Issue 9 robustness on a small real workflow (parametric NACA wing geometry), run through the
// real `meshflow` binary: SIGKILL at random moments, concurrent runs on one cache.
#include <doctest/doctest.h>

#include "support.hpp"

#include <nlohmann/json.hpp>

#include <chrono>
#include <csignal>
#include <fcntl.h>
#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>
#include <sys/wait.h>
#include <thread>
#include <unistd.h>

namespace fs = std::filesystem;
using nlohmann::json;

namespace {
std::string slurp(const fs::path& p) { return mftest::read_text(p); }
int spawn(std::vector<std::string> args, const fs::path& log) {
  args.insert(args.begin(), MESHFLOW_EXE);
  return mftest::spawn(args, log);
}
using mftest::temp_dir;
using mftest::wait_exit;
int count_entries(const fs::path& d) {
  int n = 0;
  if (fs::exists(d))
    for ([[maybe_unused]] auto& e : fs::directory_iterator(d)) ++n;
  return n;
}
// A small real workflow: the parametric wing and what follows it that exists in this build.
std::string small_workflow(const std::string& name, double span) {
  std::ostringstream y;
  y << "meshflow: 1\nname: " << name << "\nstages:\n"
    << "  geometry: {kind: naca_wing, with: {span: " << span << "}}\n"
    << "outputs:\n  shape: {from: geometry, formats: [brep]}\n";
  return y.str();
}
}  // namespace

TEST_CASE("SIGKILL at 30 random moments: the next run completes with byte-identical outputs and no debris") {
  fs::path d = temp_dir("kill");
  std::ofstream(d / "w.yaml") << small_workflow("killed", 1.0);
  std::string wf = (d / "w.yaml").string();
  // The reference: a clean run, timed.
  auto t0 = std::chrono::steady_clock::now();
  REQUIRE(wait_exit(spawn({"run", wf, "--cache", (d / "ref-cache").string(), "--out", (d / "ref").string()}, d / "ref.log")) == 0);
  double cold = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  std::string reference = slurp(d / "ref/shape.brep");
  REQUIRE(!reference.empty());

  std::mt19937 rng(12345);
  std::uniform_real_distribution<double> when(0.0, cold * 1.2);
  fs::path cache = d / "cache";
  int killed_mid_run = 0;
  for (int i = 0; i < 30; ++i) {
    fs::remove_all(cache / "actions");  // force recomputation, keep objects (as after a gc)
    int pid = spawn({"run", wf, "--cache", cache.string(), "--out", (d / "out").string()}, d / "kill.log");
    std::this_thread::sleep_for(std::chrono::duration<double>(when(rng)));
    kill(pid, SIGKILL);
    int code = wait_exit(pid);
    killed_mid_run += code == 128 + SIGKILL;
    std::this_thread::sleep_for(std::chrono::milliseconds(50));  // stage processes die with it
    auto r = wait_exit(spawn({"run", wf, "--cache", cache.string(), "--out", (d / "out").string()}, d / "after.log"));
    INFO("iteration ", i, ": ", slurp(d / "after.log"));
    REQUIRE(r == 0);
    CHECK(slurp(d / "out/shape.brep") == reference);
    CHECK(count_entries(cache / "tmp") == 0);
  }
  MESSAGE(killed_mid_run, " of 30 kills hit a running meshflow (cold run ", cold, " s)");
  CHECK(killed_mid_run >= 10);
  CHECK(wait_exit(spawn({"gc", wf, "--cache", cache.string(), "--verify"}, d / "gc.log")) == 0);
  fs::remove_all(d);
}

TEST_CASE("4 processes on one workflow and 2 on another, one cache: all succeed, identical outputs, consistent cache") {
  fs::path d = temp_dir("conc");
  std::ofstream(d / "a.yaml") << small_workflow("wa", 1.0);
  std::ofstream(d / "b.yaml") << small_workflow("wb", 1.5);
  fs::path cache = d / "cache";
  std::vector<int> pids;
  for (int i = 0; i < 4; ++i)
    pids.push_back(spawn({"run", (d / "a.yaml").string(), "--cache", cache.string(), "--out", (d / ("a" + std::to_string(i))).string()},
                         d / ("a" + std::to_string(i) + ".log")));
  for (int i = 0; i < 2; ++i)
    pids.push_back(spawn({"run", (d / "b.yaml").string(), "--cache", cache.string(), "--out", (d / ("b" + std::to_string(i))).string()},
                         d / ("b" + std::to_string(i) + ".log")));
  for (size_t i = 0; i < pids.size(); ++i) {
    int code = wait_exit(pids[i]);
    INFO("process ", i, ": ", slurp(d / ((i < 4 ? "a" : "b") + std::to_string(i < 4 ? i : i - 4) + ".log")));
    CHECK(code == 0);
  }
  for (int i = 1; i < 4; ++i) CHECK(slurp(d / ("a" + std::to_string(i)) / "shape.brep") == slurp(d / "a0/shape.brep"));
  CHECK(slurp(d / "b1/shape.brep") == slurp(d / "b0/shape.brep"));
  CHECK(slurp(d / "a0/shape.brep") != slurp(d / "b0/shape.brep"));
  CHECK(wait_exit(spawn({"gc", (d / "a.yaml").string(), "--cache", cache.string(), "--verify"}, d / "gc.log")) == 0);
  CHECK(slurp(d / "gc.log").find("consistent") != std::string::npos);
  CHECK(count_entries(cache / "tmp") == 0);
  CHECK(count_entries(cache / "locks") == 0);
  fs::remove_all(d);
}

// A stage past the memory budget fails with a message naming it, not killed by the kernel; the
// stages before it are kept, it leaves no entry, and the same run with room ends ok.
TEST_CASE("a stage past --memory-budget fails with a message naming the budget, leaves no entry, and runs with room") {
  fs::path d = temp_dir("budget");
  std::ofstream(d / "w.yaml") << "meshflow: 1\nname: budget\nstages:\n"
                              << "  geometry: {kind: naca_wing, with: {span: 1.0}}\n"
                              << "  heal: {kind: heal, needs: [geometry]}\n"
                              << "  medial: {kind: medial, needs: [heal]}\n";
  std::string wf = (d / "w.yaml").string(), cache = (d / "cache").string();
  // 0.12 GB of address space: the medial stage's Delaunay needs more
  int code = wait_exit(spawn({"run", wf, "--cache", cache, "--out", (d / "out").string(), "--memory-budget", "0.12"}, d / "low.log"));
  std::string log = slurp(d / "low.log");
  INFO(log);
  CHECK(code == 1);
  CHECK(log.find("stage 'medial' (kind medial) failed: the stage needed more memory than its budget of 0.12 GB") != std::string::npos);
  CHECK(log.find("--memory-budget") != std::string::npos);
  CHECK(count_entries(d / "cache/actions") == 2);  // geometry and heal
  CHECK(wait_exit(spawn({"run", wf, "--cache", cache, "--out", (d / "out").string()}, d / "ok.log")) == 0);
  CHECK(count_entries(d / "cache/actions") == 3);
  // a negative budget is a usage error
  CHECK(wait_exit(spawn({"run", wf, "--cache", cache, "--memory-budget", "-2"}, d / "bad.log")) != 0);
  fs::remove_all(d);
}
