// Loading workflows: defaults, overrides, DAG order, and every kind of bad input with a
// message that names the place and what to do.
#include <doctest/doctest.h>

#include "engine/workflow.hpp"
#include "test_kinds.hpp"

using namespace mftest;
using meshflow::load_workflow;
using meshflow::WorkflowError;

namespace {
// The error message of loading `yaml`, or "" when it loads.
std::string load_error(const std::string& yaml, const std::vector<std::string>& sets = {}) {
  fs::path d = temp_dir("wf");
  write_text(d / "w.yaml", yaml);
  try {
    load_workflow(d / "w.yaml", sets);
  } catch (const WorkflowError& e) {
    return e.what();
  }
  return "";
}
const char* kGood = R"(meshflow: 1
name: demo
stages:
  b: {kind: t_cat, needs: [a], with: {suffix: "!"}}
  a: {kind: t_source, with: {text: hi, repeat: 3}}
  c: {kind: t_cat, needs: [a, b]}
outputs:
  out: {from: c}
)";
}  // namespace

TEST_CASE("a good workflow loads with defaults filled and a deterministic topological order") {
  fs::path d = temp_dir("wf");
  write_text(d / "w.yaml", kGood);
  auto wf = load_workflow(d / "w.yaml");
  CHECK(wf.name == "demo");
  REQUIRE(wf.stages.size() == 3);
  CHECK(wf.stages[0].name == "a");
  CHECK(wf.stages[1].name == "b");
  CHECK(wf.stages[2].name == "c");
  CHECK(wf.stages[0].params["mode"] == "a");  // default filled
  CHECK(wf.stages[2].params["suffix"] == "");
  CHECK(wf.descendants("b") == std::vector<std::string>{"b", "c"});
  auto wf2 = load_workflow(d / "w.yaml", {"a.repeat=7", "b.suffix=12"});
  CHECK(wf2.find("a")->params["repeat"] == 7);
  CHECK(wf2.find("b")->params["suffix"] == "12");  // typed by the schema: a string
}

TEST_CASE("plain scalars become strings where the schema wants a string") {
  fs::path d = temp_dir("wf");
  write_text(d / "w.yaml", "meshflow: 1\nname: x\nstages:\n  a: {kind: t_source, with: {text: 0012}}\n");
  auto wf = load_workflow(d / "w.yaml");
  CHECK(wf.stages[0].params["text"] == "0012");
}

TEST_CASE("bad input: every kind gives file, line and what to do") {
  SUBCASE("YAML syntax error") {
    auto e = load_error("meshflow: 1\nname: x\nstages:\n  a: {kind: t_source\n");
    CHECK(e.find("w.yaml:") != std::string::npos);
    CHECK(e.find("YAML syntax error") != std::string::npos);
  }
  SUBCASE("missing meshflow version") {
    auto e = load_error("name: x\nstages:\n  a: {kind: t_source}\n");
    CHECK(e.find("'meshflow' is required") != std::string::npos);
    CHECK(e.find("meshflow: 1") != std::string::npos);
  }
  SUBCASE("wrong format version") {
    auto e = load_error("meshflow: 2\nname: x\nstages:\n  a: {kind: t_source}\n");
    CHECK(e.find("w.yaml:1:") != std::string::npos);
    CHECK(e.find("meshflow") != std::string::npos);
  }
  SUBCASE("missing name") {
    auto e = load_error("meshflow: 1\nstages:\n  a: {kind: t_source}\n");
    CHECK(e.find("'name' is required") != std::string::npos);
  }
  SUBCASE("unknown top-level key") {
    auto e = load_error("meshflow: 1\nname: x\nstagse: {}\nstages:\n  a: {kind: t_source}\n");
    CHECK(e.find("w.yaml:3:") != std::string::npos);
    CHECK(e.find("'stagse' is not a known parameter") != std::string::npos);
  }
  SUBCASE("unknown kind") {
    auto e = load_error("meshflow: 1\nname: x\nstages:\n  a: {kind: nope}\n");
    CHECK(e.find("w.yaml:4:") != std::string::npos);
    CHECK(e.find("unknown kind 'nope'") != std::string::npos);
    CHECK(e.find("t_source") != std::string::npos);  // lists the known kinds
  }
  SUBCASE("unknown parameter") {
    auto e = load_error("meshflow: 1\nname: x\nstages:\n  a:\n    kind: t_source\n    with:\n      txet: hi\n");
    CHECK(e.find("w.yaml:7:") != std::string::npos);
    CHECK(e.find("'txet'") != std::string::npos);
    CHECK(e.find("known: mode, repeat, text") != std::string::npos);
  }
  SUBCASE("wrong type") {
    auto e = load_error("meshflow: 1\nname: x\nstages:\n  a:\n    kind: t_source\n    with:\n      repeat: many\n");
    CHECK(e.find("w.yaml:7:") != std::string::npos);
    CHECK(e.find("must be an integer") != std::string::npos);
    CHECK(e.find("--set a.repeat=") != std::string::npos);
  }
  SUBCASE("out of range") {
    auto e = load_error("meshflow: 1\nname: x\nstages:\n  a: {kind: t_source, with: {repeat: 0}}\n");
    CHECK(e.find("below the minimum 1") != std::string::npos);
    CHECK(e.find("how often") != std::string::npos);  // the parameter's description
  }
  SUBCASE("not in enum") {
    auto e = load_error("meshflow: 1\nname: x\nstages:\n  a: {kind: t_source, with: {mode: c}}\n");
    CHECK(e.find("not one of \"a\", \"b\"") != std::string::npos);
  }
  SUBCASE("missing required parameter") {
    auto e = load_error("meshflow: 1\nname: x\nstages:\n  a: {kind: t_fail}\n");
    CHECK(e.find("'message'") != std::string::npos);
    CHECK(e.find("required") != std::string::npos);
  }
  SUBCASE("duplicate stage") {
    auto e = load_error("meshflow: 1\nname: x\nstages:\n  a: {kind: t_source}\n  a: {kind: t_source}\n");
    CHECK(e.find("w.yaml:5:") != std::string::npos);
    CHECK(e.find("duplicate key 'a'") != std::string::npos);
  }
  SUBCASE("unknown need") {
    auto e = load_error("meshflow: 1\nname: x\nstages:\n  a: {kind: t_cat, needs: [zz]}\n");
    CHECK(e.find("needs 'zz'") != std::string::npos);
    CHECK(e.find("w.yaml:4:") != std::string::npos);
  }
  SUBCASE("cycle") {
    auto e = load_error(
        "meshflow: 1\nname: x\nstages:\n  a: {kind: t_cat, needs: [c]}\n  b: {kind: t_cat, needs: [a]}\n  c: {kind: t_cat, needs: [b]}\n");
    CHECK(e.find("cycle: a -> c -> b -> a") != std::string::npos);
  }
  SUBCASE("unreadable workflow file") {
    CHECK_THROWS_WITH_AS(load_workflow("/nonexistent/w.yaml"), doctest::Contains("no such file"), WorkflowError);
  }
  SUBCASE("bad --set") {
    CHECK(load_error(kGood, {"zz.repeat=3"}).find("no stage 'zz'") != std::string::npos);
    CHECK(load_error(kGood, {"a.repeat"}).find("STAGE.PARAM=VALUE") != std::string::npos);
    auto e = load_error(kGood, {"a.repeat=-1"});
    CHECK(e.find("(--set)") != std::string::npos);
    CHECK(e.find("below the minimum") != std::string::npos);
  }
  SUBCASE("not UTF-8 (found by fuzzing)") {
    auto e = load_error("meshflow: 1\nname: x\xef\nstages:\n  a: {kind: t_source}\n");
    CHECK(e.find("w.yaml:2: the file is not valid UTF-8") != std::string::npos);
  }
  SUBCASE("an output from an unknown stage") {
    auto e = load_error("meshflow: 1\nname: x\nstages:\n  a: {kind: t_source}\noutputs:\n  o: {from: b}\n");
    CHECK(e.find("w.yaml:6:") != std::string::npos);
  }
}

// What a stage's kind reads must come from its `needs`, and an output's formats must be formats
// of its artifact's type: both are refused at load (exit 2), before any stage runs.
TEST_CASE("a needs list that cannot supply a kind's inputs, or an unknown format, is exit 2 at load") {
  const std::string head = "meshflow: 1\nname: flow\nstages:\n  geometry: {kind: naca_wing}\n  heal: {kind: heal, needs: [geometry]}\n";
  // tet reads a mesh; heal gives a shape
  std::string e = load_error(head + "  tet: {kind: tet, needs: [heal]}\n");
  CHECK(e.find("w.yaml:6:") != std::string::npos);
  CHECK(e.find("stage 'tet' (kind tet) reads an artifact of type 'mesh'") != std::string::npos);
  CHECK(e.find("heal (heal) gives shape") != std::string::npos);
  CHECK(e.find("kinds: curve, optimise, split, sweep, tet") != std::string::npos);
  // a kind that needs two types, given one
  e = load_error(head + "  medial: {kind: medial, needs: [heal]}\n  shell: {kind: shell, needs: [medial]}\n");
  CHECK(e.find("stage 'shell' (kind shell) reads an artifact of type 'shape'") != std::string::npos);
  // no needs at all
  e = load_error(head + "  medial: {kind: medial}\n");
  CHECK(e.find("it lists none") != std::string::npos);
  // an optional input is not required (periodic_match reads divisions when given)
  CHECK(load_error(head + "  pm: {kind: periodic_match, needs: [heal]}\n") == "");
  // formats: unknown, with a suggestion; an artifact the kind does not write
  e = load_error(head + "outputs:\n  shape: {from: heal, formats: [brep, stp]}\n");
  CHECK(e.find("w.yaml:7:") != std::string::npos);
  CHECK(e.find("output 'shape': a shape has no format 'stp'; did you mean 'step'?") != std::string::npos);
  e = load_error(head + "outputs:\n  shape: {from: heal, artifact: mesh}\n");
  CHECK(e.find("writes no artifact 'mesh' (it writes: shape, cad_reference)") != std::string::npos);
  CHECK(load_error(head + "outputs:\n  shape: {from: heal, formats: [brep, step]}\n") == "");
  // the CLI: exit 2, nothing run, nothing cached
  WorkflowFixture f(head + "  tet: {kind: tet, needs: [heal]}\n", "flow");
  auto r = f.run();
  CHECK(r.code == 2);
  CHECK(action_count(f.cache) == 0);
  CHECK(f.run({}, "dag").code == 2);
}

TEST_CASE("meshflow kinds KIND says what the kind needs, reads and produces") {
  auto r = cli({"kinds", "shell"});
  REQUIRE(r.code == 0);
  CHECK(r.out.find("needs:    shape, medial") != std::string::npos);
  CHECK(r.out.find("produces: shell (type shell") != std::string::npos);
  r = cli({"kinds", "sweep"});
  CHECK(r.out.find("reads:    periodic") != std::string::npos);
  CHECK(r.out.find("produces: mesh (type mesh; output formats cgns, msh,") != std::string::npos);
  CHECK(cli({"kinds", "naca_wing"}).out.find("needs:    nothing") != std::string::npos);
  CHECK(cli({"kinds", "--check"}).code == 0);
}
