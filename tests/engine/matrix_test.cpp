// A workflow's `matrix:`: variants named and ordered, shared stages computed once, outputs and
// the table per variant, bad matrices refused at load (exit 2) before anything runs.
#include <doctest/doctest.h>

#include "engine/matrix.hpp"
#include "test_kinds.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>

using namespace mftest;
using nlohmann::json;

TEST_CASE("matrix: six variants, named by their values, the shared stages run once") {
  WorkflowFixture f(kStudy, "matrix");
  auto wf = meshflow::load_workflow(f.wf);
  auto vs = meshflow::matrix_variants(wf);
  REQUIRE(vs.size() == 6);
  CHECK(vs[0].name == "b.suffix--x_c.suffix--1");  // both keys end in 'suffix': the whole key
  CHECK(vs[0].overrides == std::vector<std::string>{"b.suffix=\"-x\"", "c.suffix=\"-1\""});
  CHECK(vs[5].overrides == std::vector<std::string>{"b.suffix=\"-y\"", "c.suffix=\"-3\""});
  auto r = f.run();
  INFO(r.out, r.err);
  REQUIRE(r.code == 0);
  auto calls = f.calls();
  CHECK(std::count(calls.begin(), calls.end(), "a") == 1);
  CHECK(std::count(calls.begin(), calls.end(), "b") == 2);
  CHECK(std::count(calls.begin(), calls.end(), "c") == 6);
  for (auto& v : vs) {
    INFO(v.name);
    CHECK(fs::exists(f.out / v.name / "report.json"));
  }
  CHECK(read_text(f.out / vs[0].name / "final.txt") == "abab-x-1");
  CHECK(read_text(f.out / vs[5].name / "final.txt") == "abab-y-3");
  json m = json::parse(read_text(f.out / "matrix.json"));
  REQUIRE(m["variants"].size() == 6);
  CHECK(m["variants"][0]["ran"] == 3);
  CHECK(m["variants"][1]["ran"] == 1);  // only c: a and b served from the cache
  CHECK(m["variants"][1]["cached"] == 2);
  CHECK(m["variants"][3]["ran"] == 2);  // the second b, and c
  for (auto& v : m["variants"]) CHECK(v["status"] == "ok");
  CHECK(r.out.find("matrix: 6 variants") != std::string::npos);
  // a second run: everything cached
  f.reset_calls();
  REQUIRE(f.run().code == 0);
  CHECK(f.calls().empty());
  // one variant by name: its outputs in out/<variant>/ as well; other commands need one
  auto one = f.run({"--variant", vs[2].name});
  CHECK(one.code == 0);
  auto st = f.run({}, "status");
  CHECK(st.code == 2);
  CHECK(st.err.find("add --variant NAME") != std::string::npos);
  CHECK(f.run({"--variant", vs[2].name}, "status").code == 0);
  auto bad = f.run({"--variant", "nope"});
  CHECK(bad.code == 2);
  CHECK(bad.err.find("the variants are: " + vs[0].name) != std::string::npos);
  auto clash = f.run({"--set", "c.suffix=-9"});
  CHECK(clash.code == 2);
  CHECK(clash.err.find("the workflow's matrix varies c.suffix") != std::string::npos);
  auto dag = f.run({}, "dag");
  CHECK(dag.out.find("matrix: 6 variants: " + vs[0].name) != std::string::npos);
}

TEST_CASE("matrix: distinct last components name variants short, and bad matrices are exit 2 before anything runs") {
  {
    WorkflowFixture f(std::string(kStudy).substr(0, std::string(kStudy).find("matrix:")) +
                          "matrix:\n  a.repeat: [1, 2]\n  c.suffix: [\"-p q\"]\n",
                      "matrix_names");
    auto vs = meshflow::matrix_variants(meshflow::load_workflow(f.wf));
    REQUIRE(vs.size() == 2);
    CHECK(vs[0].name == "repeat-1_suffix--p_q");
    CHECK(vs[1].name == "repeat-2_suffix--p_q");
  }
  const std::string head = std::string(kStudy).substr(0, std::string(kStudy).find("matrix:"));
  struct Bad {
    const char* matrix;
    const char* says;
  };
  for (Bad b : {Bad{"matrix:\n  z.suffix: [\"-1\"]\n", "names no stage of this workflow"},
                Bad{"matrix:\n  csuffix: [\"-1\"]\n", "is not STAGE.PARAM"},
                Bad{"matrix:\n  c.suffix: []\n", "matrix"},
                Bad{"matrix:\n  a.repeat: [2, \"many\"]\n", "matrix variant repeat-many"},
                Bad{"matrix:\n  c.nosuch: [1]\n", "matrix variant nosuch-1"}}) {
    INFO(b.matrix);
    WorkflowFixture f(head + b.matrix, "matrix_bad");
    auto r = f.run();
    CHECK(r.code == 2);
    CHECK(r.err.find(b.says) != std::string::npos);
    CHECK(f.calls().empty());
    CHECK_FALSE(fs::exists(f.out / "matrix.json"));
  }
}
