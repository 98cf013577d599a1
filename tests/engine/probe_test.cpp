// The faults a probe of bad inputs and cache damage found (issue 44), each run as a user meets
// it: a symbolic-link loop or a folder where the cache keeps an object, negative -j and
// --threads, a `file:` parameter naming nothing or a folder, YAML nested thousands deep, a
// sampling spacing of 1e-300.
#include <doctest/doctest.h>

#include "test_kinds.hpp"

#include <nlohmann/json.hpp>

#include <chrono>
#include <string>

using namespace mftest;
using nlohmann::json;

namespace {
const char* kTwo = R"(meshflow: 1
name: probe
stages:
  a: {kind: t_source, with: {text: "ab", repeat: 3}}
  b: {kind: t_cat, needs: [a], with: {suffix: "-b"}}
outputs:
  b: {from: b}
)";

// The object stage `a` stored (its output's digest from report.json) and its path in the cache.
fs::path object_of(const WorkflowFixture& f, const std::string& stage) {
  const json s = f.stage(stage);
  REQUIRE(s.is_object());
  REQUIRE(!s["outputs"].empty());
  const std::string d = s["outputs"][0]["digest"];
  return f.cache / "objects" / d.substr(0, 2) / d;
}
// Replaces the object at `p` (read-only, as the store leaves it) by what `make` puts there.
template <class Make>
void replace_object(const fs::path& p, Make make) {
  fs::permissions(p, fs::perms::owner_write, fs::perm_options::add);
  fs::remove(p);
  make(p);
}
}  // namespace

TEST_CASE("cache: a symbolic-link loop at an object's path is a corrupt object: runs recompute it, gc --verify reports it, --repair removes it") {
  WorkflowFixture f(kTwo);
  REQUIRE(f.run().code == 0);
  const fs::path obj = object_of(f, "a");
  replace_object(obj, [](const fs::path& p) { fs::create_symlink(p.filename(), p); });  // a link to itself
  REQUIRE(fs::is_symlink(obj));
  // a run: the object is set aside and `a` runs again (before: "Too many levels of symbolic links")
  f.reset_calls();
  auto r = f.run();
  INFO(r.out, r.err);
  CHECK(r.code == 0);
  CHECK(f.calls().size() >= 1);
  CHECK(read_text(f.out / "b.txt") == "ababab-b");
  CHECK(fs::is_regular_file(fs::symlink_status(obj)));
  // the same loop again, found by gc --verify, and removed by --repair
  replace_object(obj, [](const fs::path& p) { fs::create_symlink(p.filename(), p); });
  auto v = cli({"gc", f.wf.string(), "--cache", f.cache.string(), "--verify"});
  INFO(v.out, v.err);
  CHECK(v.code == 1);
  CHECK(v.out.find("is a symbolic link, not a file") != std::string::npos);
  CHECK(cli({"gc", f.wf.string(), "--cache", f.cache.string(), "--verify", "--repair"}).code == 0);
  CHECK(!fs::exists(fs::symlink_status(obj)));
  CHECK(cli({"gc", f.wf.string(), "--cache", f.cache.string(), "--verify"}).code == 0);
  CHECK(cli({"gc", f.wf.string(), "--cache", f.cache.string(), "--grace", "0"}).code == 0);  // plain gc too
  CHECK(f.run().code == 0);
}

TEST_CASE("cache: a folder in place of an object fails gc --verify, and --repair and a run recover") {
  WorkflowFixture f(kTwo);
  REQUIRE(f.run().code == 0);
  const fs::path obj = object_of(f, "b");
  replace_object(obj, [](const fs::path& p) { fs::create_directories(p / "inside"); });
  auto v = cli({"gc", f.wf.string(), "--cache", f.cache.string(), "--verify"});
  INFO(v.out, v.err);
  CHECK(v.code == 1);
  CHECK(v.out.find("is a folder, not a file") != std::string::npos);
  CHECK(v.out.find("action ") != std::string::npos);  // b's entry names it: suspect too
  CHECK(cli({"gc", f.wf.string(), "--cache", f.cache.string(), "--verify", "--repair"}).code == 0);
  CHECK(!fs::exists(obj));
  auto r = f.run();
  INFO(r.out, r.err);
  CHECK(r.code == 0);
  CHECK(read_text(f.out / "b.txt") == "ababab-b");
  // and a folder met by a run (not by gc) is set aside the same way
  replace_object(obj, [](const fs::path& p) { fs::create_directories(p); });
  f.reset_calls();
  CHECK(f.run().code == 0);
  CHECK(f.calls().size() == 1);
  CHECK(fs::is_regular_file(fs::symlink_status(obj)));
}

TEST_CASE("-j and --threads below 0 are refused: exit 2 naming the option") {
  WorkflowFixture f(kTwo);
  for (auto args : {std::vector<std::string>{"-j", "-1"}, {"--jobs", "-3"}, {"--threads", "-5"}}) {
    auto r = f.run(args);
    INFO(args[0], " ", args[1], ": ", r.err);
    CHECK(r.code == 2);
    CHECK(r.err.find(args[0] == "--threads" ? "--threads" : "--jobs") != std::string::npos);
    CHECK(action_count(f.cache) == 0);
  }
  CHECK(cli({"export", "snakemake", f.wf.string(), "--threads", "-2", "-o", "-"}).code == 2);
  CHECK(f.run({"-j", "0", "--threads", "0"}).code == 0);  // 0: the default (the cores)
}

TEST_CASE("a file: parameter naming a missing file or a folder is bad input: exit 2 with the file, line and parameter") {
  WorkflowFixture f("meshflow: 1\nname: files\nstages:\n  c: {kind: t_file, with: {path: data/in.txt}}\n");
  auto missing = f.run();
  INFO(missing.err);
  CHECK(missing.code == 2);
  CHECK(missing.err.find(f.wf.filename().string() + ":4: stage 'c', parameter 'path': cannot read") != std::string::npos);
  CHECK(missing.err.find("no such file") != std::string::npos);
  fs::create_directories(f.dir / "data/in.txt");
  auto folder = f.run();
  INFO(folder.err);
  CHECK(folder.code == 2);
  CHECK(folder.err.find("it is a folder") != std::string::npos);
  CHECK(action_count(f.cache) == 0);
}

TEST_CASE("YAML nested 10,000 deep: the file, the place and that it is nested too deep, exit 2") {
  std::string deep = "meshflow: 1\nname: deep\nstages:\n  a: {kind: t_source, with: {text: ";
  deep += std::string(10000, '[') + std::string(10000, ']') + "}}\n";
  WorkflowFixture f(deep);
  for (const char* cmd : {"run", "dag"}) {
    auto r = f.run({}, cmd);
    INFO(cmd, ": ", r.err.substr(0, 400));
    CHECK(r.code == 2);
    CHECK(r.err.find(f.wf.filename().string() + ":4:") != std::string::npos);
    CHECK(r.err.find("nested too deep") != std::string::npos);
    CHECK(r.err.find("bad file") == std::string::npos);
  }
  auto s = f.run({"--set", "a.text=" + std::string(5000, '[') + std::string(5000, ']')}, "dag");
  CHECK(s.code == 2);  // the deep file is refused first; a deep --set alone:
  WorkflowFixture g(kTwo);
  auto o = g.run({"--set", "a.text=" + std::string(5000, '[') + std::string(5000, ']')}, "dag");
  INFO(o.err.substr(0, 300));
  CHECK(o.code == 2);
  CHECK(o.err.find("--set a.text=") != std::string::npos);
  CHECK(o.err.find("nested too deep") != std::string::npos);
}

TEST_CASE("a sampling spacing of 1e-300 is refused at once, naming the parameter and its bound (it sampled for 117 s before)") {
  // the real meshflow on the demo workflow: `dag` validates the workflow and runs nothing
  for (const std::string set : {"medial.spacing=1e-300", "medial.farfield_spacing=1e-300", "medial.min_spacing=1e-300"}) {
    const auto t0 = std::chrono::steady_clock::now();
    auto r = sh(std::string(MESHFLOW_EXE) + " dag " + MESHFLOW_SOURCE_DIR + "/workflows/naca_wingtip.yaml --set " + set);
    const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    INFO(set, ": ", r.out);
    CHECK(r.code == 2);
    CHECK(r.out.find("parameter '" + set.substr(7, set.find('=') - 7) + "'") != std::string::npos);
    CHECK(r.out.find("minimum") != std::string::npos);
    CHECK(s < 10);
  }
}
