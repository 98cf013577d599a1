// The engine's side of the mesh contract: a stage that lists problems in stats.problems makes
// the run fail with its own exit code (3) unless the problem is repairable and not delivered;
// outputs are still written and marked; --allow-invalid accepts; check never does; a cached
// invalid result stays invalid.
#include <doctest/doctest.h>

#include "test_kinds.hpp"

#include <nlohmann/json.hpp>

#include <cstdlib>
#include <string>

using namespace mftest;
using nlohmann::json;

namespace {

// a -> m (t_cat reporting a problem, blocking or not) -> z; outputs from z, and from m as well
// when `deliver_m`.
struct Flawed : WorkflowFixture {
  Flawed(bool blocking, bool deliver_m)
      : WorkflowFixture(std::string("meshflow: 1\nname: flawed\nstages:\n") +
                            "  a: {kind: t_source, with: {text: \"x\"}}\n"
                            "  m: {kind: t_cat, needs: [a], with: {suffix: \"-m\", problem: " +
                            (blocking ? "blocking" : "repairable") +
                            "}}\n"
                            "  z: {kind: t_cat, needs: [m], with: {suffix: \"-z\"}}\n"
                            "outputs:\n  final: {from: z}\n" +
                            (deliver_m ? "  middle: {from: m}\n" : "") + "golden: golden\n",
                        "contract") {}
};

}  // namespace

TEST_CASE("a repairable problem of an intermediate result is passed on: the run succeeds") {
  Flawed f(/*blocking=*/false, /*deliver_m=*/false);
  auto r = f.run();
  INFO(r.out, r.err);
  CHECK(r.code == 0);
  CHECK(f.report()["ok"] == true);
  CHECK(f.report()["invalid"] == false);
  CHECK(f.stage("m")["status"] == "ran");
  CHECK(f.stage("z")["status"] == "ran");
  CHECK(r.out.find("note    m: validity: 2 element(s)") != std::string::npos);
  CHECK(r.out.find("INVALID") == std::string::npos);
}

TEST_CASE("a blocking problem stops what needs it, exits 3 and says where first") {
  Flawed f(/*blocking=*/true, /*deliver_m=*/false);
  auto r = f.run();
  INFO(r.out, r.err);
  CHECK(r.code == 3);
  json rep = f.report();
  CHECK(rep["ok"] == false);
  CHECK(rep["invalid"] == true);
  CHECK(f.stage("m")["status"] == "invalid");
  CHECK(f.stage("z")["status"] == "skipped");
  REQUIRE(rep["problems"].size() == 1);
  CHECK(rep["problems"][0]["stage"] == "m");
  CHECK(rep["problems"][0]["count"] == 2);
  CHECK(rep["problems"][0]["where"][0]["element"] == 17);
  // the summary opens with the verdict and the place
  auto pos = r.out.find("\nINVALID: the mesh breaks the contract");
  REQUIRE(pos != std::string::npos);
  auto where = r.out.find("m: validity: 2 element(s) with det J <= 0 somewhere; first listed: element 17 (tet4) at (", pos);
  CHECK(where != std::string::npos);
  CHECK(where < r.out.find("stage ", pos));  // before the stage table
  CHECK(r.out.find("INVALID in ") != std::string::npos);

  // cached: still invalid, same exit code, nothing recomputed
  fs::remove(f.calls_file);
  auto r2 = f.run();
  CHECK(r2.code == 3);
  CHECK(f.stage("m")["status"] == "invalid");
  CHECK(calls(f.calls_file).empty());
}

TEST_CASE("a delivered result with a repairable problem fails the run, its output is written and marked") {
  Flawed f(/*blocking=*/false, /*deliver_m=*/true);
  auto r = f.run();
  INFO(r.out, r.err);
  CHECK(r.code == 3);
  json rep = f.report();
  CHECK(f.stage("m")["status"] == "invalid");
  CHECK(f.stage("z")["status"] == "ran");  // not blocking: later stages still run
  CHECK(fs::exists(f.out / "middle.txt"));
  CHECK(rep["outputs"]["middle"]["invalid"] == true);
  CHECK_FALSE(rep["outputs"]["final"].contains("invalid"));
  CHECK(r.out.find("outputs (INVALID mesh, written for inspection)") != std::string::npos);
}

TEST_CASE("--allow-invalid accepts a broken result for debugging, check never does") {
  Flawed f(/*blocking=*/true, /*deliver_m=*/false);
  auto r = f.run({"--allow-invalid"});
  INFO(r.out, r.err);
  CHECK(r.code == 0);
  json rep = f.report();
  CHECK(rep["ok"] == true);
  CHECK(rep["invalid"] == true);
  CHECK(rep["invalid_accepted"] == true);
  CHECK(f.stage("z")["status"] == "ran");
  CHECK(r.out.find("INVALID (accepted by --allow-invalid)") != std::string::npos);
  CHECK(r.out.find("ok (INVALID mesh accepted) in ") != std::string::npos);

  write_text(f.dir / "golden" / "summary.json", "{}");
  auto c = f.run({}, "check");
  CHECK(c.code == 3);
  auto g = f.run({"--update"}, "golden");
  CHECK(g.code == (std::getenv("CI") && std::string(std::getenv("CI")) == "true" ? 2 : 3));  // CI refuses --update first
  CHECK(read_text(f.dir / "golden" / "summary.json") == "{}");
  // the flag belongs to `run` alone
  auto bad = f.run({"--allow-invalid"}, "check");
  CHECK(bad.code == 2);
}

TEST_CASE("--help documents the exit codes") {
  auto r = cli({"--help"});
  CHECK(r.out.find("3 a mesh breaks the contract") != std::string::npos);
}
