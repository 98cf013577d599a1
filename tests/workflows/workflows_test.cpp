// End-to-end: the real `meshflow` binary on the real workflows of workflows/, as a user runs it.
#include <doctest/doctest.h>

#include <nlohmann/json.hpp>

#include <array>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <memory>
#include <random>
#include <sstream>
#include <string>
#include <sys/wait.h>
#include <unistd.h>

namespace fs = std::filesystem;
using nlohmann::json;

namespace {
struct Result {
  int code;
  std::string out;
};
Result sh(const std::string& cmd) {
  std::string full = cmd + " 2>&1";
  std::unique_ptr<FILE, int (*)(FILE*)> p(popen(full.c_str(), "r"), &pclose);
  std::string out;
  std::array<char, 4096> buf;
  size_t n;
  while ((n = fread(buf.data(), 1, buf.size(), p.get())) > 0) out.append(buf.data(), n);
  int st = pclose(p.release());
  return {WIFEXITED(st) ? WEXITSTATUS(st) : 128, out};
}
std::string meshflow() { return std::string(MESHFLOW_EXE); }
fs::path temp_dir() {
  fs::path p = fs::temp_directory_path() / ("meshflow-e2e-" + std::to_string(getpid()) + "-" + std::to_string(std::random_device{}() % 100000));
  fs::create_directories(p);
  return p;
}
std::string slurp(const fs::path& p) {
  std::ifstream in(p);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}
}  // namespace

TEST_CASE("every registered kind has a schema the validator enforces") {
  auto r = sh(meshflow() + " kinds --check");
  INFO(r.out);
  CHECK(r.code == 0);
}

TEST_CASE("every workflow in workflows/ is valid") {
  int n = 0;
  for (auto& e : fs::directory_iterator(fs::path(MESHFLOW_SOURCE_DIR) / "workflows")) {
    if (e.path().extension() != ".yaml") continue;
    ++n;
    auto r = sh(meshflow() + " dag " + e.path().string());
    INFO(e.path().string(), r.out);
    CHECK(r.code == 0);
    // the first line tells editors where the schema is
    CHECK(slurp(e.path()).rfind("# yaml-language-server: $schema=../schemas/workflow.schema.json", 0) == 0);
  }
  CHECK(n >= 1);
}

TEST_CASE("naca_wingtip: runs, matches its golden, re-runs from cache, --set re-runs the stage") {
  fs::path d = temp_dir();
  std::string wf = std::string(MESHFLOW_SOURCE_DIR) + "/workflows/naca_wingtip.yaml";
  std::string common = " --cache " + (d / "cache").string() + " --out " + (d / "out").string();
  auto r = sh("cd " + d.string() + " && " + meshflow() + " check " + wf + common);
  INFO(r.out);
  REQUIRE(r.code == 0);
  CHECK(r.out.find("outputs agree") != std::string::npos);
  json rep = json::parse(slurp(d / "out/report.json"));
  CHECK(rep["ok"] == true);
  for (auto& s : rep["stages"]) CHECK(s["status"] == "ran");
  auto r2 = sh(meshflow() + " run " + wf + common);
  json rep2 = json::parse(slurp(d / "out/report.json"));
  for (auto& s : rep2["stages"]) CHECK(s["status"] == "cached");
  auto r3 = sh(meshflow() + " run " + wf + common + " --set geometry.span=2");
  json rep3 = json::parse(slurp(d / "out/report.json"));
  CHECK(rep3["stages"][0]["status"] == "ran");
  fs::remove_all(d);
}
