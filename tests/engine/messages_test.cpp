// Issue 22 (messages): nearest-name suggestions, empty and .nan values named as such,
// --version, COMMAND --help, golden without --update, a folder given as the workflow.
#include <doctest/doctest.h>

#include "test_kinds.hpp"

using namespace mftest;

namespace {
const char* kOne = R"(meshflow: 1
name: one
stages:
  source: {kind: t_source, with: {text: "ab", repeat: 3}}
)";
}  // namespace

TEST_CASE("a misspelled parameter suggests the nearest known one, and the --set hint uses it") {
  WorkflowFixture f("meshflow: 1\nname: one\nstages:\n  source: {kind: t_source, with: {repeet: 3}}\n");
  auto r = f.run();
  CHECK(r.code == 2);
  CHECK(r.err.find("did you mean 'repeat'?") != std::string::npos);
  CHECK(r.err.find("--set source.repeat=VALUE") != std::string::npos);
  WorkflowFixture far("meshflow: 1\nname: one\nstages:\n  source: {kind: t_source, with: {zzzzzzzz: 3}}\n");
  CHECK(far.run().err.find("did you mean") == std::string::npos);  // nothing close: no guess
}

TEST_CASE("a misspelled kind, --set stage or need suggests the nearest name") {
  WorkflowFixture k("meshflow: 1\nname: one\nstages:\n  source: {kind: t_sourse}\n");
  auto r = k.run();
  CHECK(r.code == 2);
  CHECK(r.err.find("unknown kind 't_sourse'; did you mean 't_source'?") != std::string::npos);
  WorkflowFixture f(kOne);
  auto s = f.run({"--set", "sourse.repeat=2"});
  CHECK(s.code == 2);
  CHECK(s.err.find("no stage 'sourse'; did you mean 'source'?") != std::string::npos);
  WorkflowFixture n(std::string(kOne) + "  cat: {kind: t_cat, needs: [sourc]}\n");
  CHECK(n.run().err.find("needs 'sourc', which is not a stage of this workflow; did you mean 'source'?") != std::string::npos);
}

TEST_CASE("--set a.b= and .nan are named as such") {
  WorkflowFixture f(kOne);
  auto e = f.run({"--set", "source.repeat="});
  CHECK(e.code == 2);
  CHECK(e.err.find("the value is empty") != std::string::npos);
  auto n = f.run({"--set", "source.repeat=.nan"});
  CHECK(n.code == 2);
  CHECK(n.err.find(".nan is not a number") != std::string::npos);
  WorkflowFixture y("meshflow: 1\nname: one\nstages:\n  source: {kind: t_source, with: {repeat: .NaN}}\n");
  auto yr = y.run();
  CHECK(yr.code == 2);
  CHECK(yr.err.find("is .NaN (not a number)") != std::string::npos);
}

TEST_CASE("--version, convert --help, quality --help, golden --help and golden without --update") {
  auto v = cli({"--version"});
  CHECK(v.code == 0);
  CHECK(v.out.find("meshflow 0.") == 0);
  for (std::string c : {"convert", "quality"}) {
    CAPTURE(c);
    auto h = cli({c, "--help"});
    CHECK(h.code == 0);
    CHECK(h.out.find("usage: meshflow " + c) != std::string::npos);
  }
  auto g = cli({"golden", "--help"});
  CHECK(g.code == 0);
  CHECK(g.out.find("--update") != std::string::npos);
  CHECK(g.out.find("--update REQUIRED") == std::string::npos);
  CHECK(g.err.find("required") == std::string::npos);
  WorkflowFixture f(kOne);
  auto u = f.run({}, "golden");
  CHECK(u.code == 2);
  CHECK(u.err.find("--update") != std::string::npos);
}

TEST_CASE("a folder given as the workflow file says so") {
  WorkflowFixture f(kOne);
  auto r = cli({"dag", f.dir.string()});
  CHECK(r.code == 2);
  CHECK(r.err.find("is a folder, not a workflow file") != std::string::npos);
}

TEST_CASE("a folder given where a file parameter wants a file says so") {
  WorkflowFixture f("meshflow: 1\nname: files\nstages:\n  c: {kind: t_file, with: {path: data}}\n");
  fs::create_directories(f.dir / "data");
  auto r = f.run();
  CHECK(r.code == 2);  // bad input, as --help says (found when the stage's key is made)
  CHECK(r.err.find("it is a folder: give the path of a file in it") != std::string::npos);
}
