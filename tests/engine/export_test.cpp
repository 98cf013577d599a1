// `meshflow export snakemake` and `meshflow run --only STAGE`: the Snakefile has one rule per
// distinct stage of the matrix (shared stages once), and Snakemake running it locally gives the
// outputs `meshflow run` gives, each stage computed once.
#include <doctest/doctest.h>

#include "test_kinds.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <regex>

using namespace mftest;
using nlohmann::json;

namespace {

int count(const std::string& text, const std::string& what) {
  int n = 0;
  for (auto p = text.find(what); p != std::string::npos; p = text.find(what, p + 1)) ++n;
  return n;
}
}  // namespace

TEST_CASE("run --only: the stage and what it needs, no outputs, and an unknown stage is exit 2") {
  WorkflowFixture f(std::string(kStudy).substr(0, std::string(kStudy).find("matrix:")), "only");
  auto r = f.run({"--only", "b"});
  INFO(r.out, r.err);
  REQUIRE(r.code == 0);
  CHECK(f.calls() == std::vector<std::string>{"a", "b"});
  CHECK_FALSE(fs::exists(f.out / "final.txt"));
  f.reset_calls();
  REQUIRE(f.run().code == 0);  // the full run: only c is left
  CHECK(f.calls() == std::vector<std::string>{"c"});
  CHECK(read_text(f.out / "final.txt") == "abab-b-c");
  auto bad = f.run({"--only", "zz"});
  CHECK(bad.code == 2);
  CHECK(bad.err.find("no stage 'zz'") != std::string::npos);
}

TEST_CASE("export snakemake: a rule per distinct stage, commands that name the variant") {
  WorkflowFixture f(kStudy, "export");
  auto r = cli({"export", "snakemake", f.wf.string(), "--cache", f.cache.string(), "--out", f.out.string(), "-o", "-",
                "--threads", "3", "--exe", "/opt/mf"});
  INFO(r.out, r.err);
  REQUIRE(r.code == 0);
  const std::string& s = r.out;
  CHECK(count(s, "\nrule a_") == 1);
  CHECK(count(s, "\nrule b_") == 2);
  CHECK(count(s, "\nrule c_") == 6);
  CHECK(count(s, "\nrule outputs_") == 6);
  CHECK(count(s, "threads: 3") == 9 + 6);
  CHECK(s.find("MESHFLOW = \"/opt/mf\"") != std::string::npos);
  CHECK(s.find("--variant 'b.suffix--y_c.suffix--3' --only 'c'") != std::string::npos);
  CHECK(s.find("--out '" + (f.out / "b.suffix--x_c.suffix--1").string() + "'") != std::string::npos);
  CHECK(f.calls().empty());  // exporting runs nothing
  // nothing measured yet: the default memory; after a run, twice the measured peak (>= 256)
  CHECK(count(s, "mem_mb=1024") == 9);
  REQUIRE(f.run().code == 0);
  auto again = cli({"export", "snakemake", f.wf.string(), "--cache", f.cache.string(), "-o", "-"});
  CHECK(count(again.out, "mem_mb=1024") == 0);
  CHECK(count(again.out, "mem_mb=") == 9);
  // -o into a folder that does not exist yet: made; under a file: exit 2 naming the folder
  const fs::path nested = f.dir / "new" / "deeper" / "Snakefile";
  auto made = cli({"export", "snakemake", f.wf.string(), "--cache", f.cache.string(), "-o", nested.string()});
  INFO(made.err);
  CHECK(made.code == 0);
  CHECK(read_text(nested) == again.out);
  write_text(f.dir / "plain", "a file");
  auto under_file = cli({"export", "snakemake", f.wf.string(), "-o", (f.dir / "plain" / "Snakefile").string()});
  CHECK(under_file.code == 2);
  CHECK(under_file.err.find("cannot make the folder " + (f.dir / "plain").string()) != std::string::npos);
  // bad: an unknown target, a workflow that does not load
  CHECK(cli({"export", "make", f.wf.string()}).code == 2);
  write_text(f.dir / "bad.yaml", "meshflow: 1\nname: x\nstages: {a: {kind: nope}}\n");
  CHECK(cli({"export", "snakemake", (f.dir / "bad.yaml").string(), "-o", "-"}).code == 2);
}

TEST_CASE("export snakemake: Snakemake runs the study locally with meshflow run's outputs, each stage once") {
  if (!fs::exists("/usr/bin/snakemake")) {
    MESSAGE("skipped: /usr/bin/snakemake is not installed (scripts/install-deps installs it)");
    return;
  }
  WorkflowFixture f(kStudy, "export_smk");
  const fs::path snakefile = f.dir / "Snakefile", work = f.dir / "smk";
  const std::string exe = fs::read_symlink("/proc/self/exe").string() + " --as-meshflow";
  auto r = cli({"export", "snakemake", f.wf.string(), "--cache", f.cache.string(), "--out", (f.dir / "smk_out").string(),
                "-o", snakefile.string(), "--exe", exe, "--threads", "1"});
  INFO(r.out, r.err);
  REQUIRE(r.code == 0);
  auto sm = sh("cd " + f.dir.string() + " && /usr/bin/snakemake -s " + snakefile.string() + " --cores 2 -d " +
               work.string() + " --quiet 2>&1");
  INFO(sm.out);
  REQUIRE(sm.code == 0);
  auto calls = f.calls();
  CHECK(std::count(calls.begin(), calls.end(), "a") == 1);
  CHECK(std::count(calls.begin(), calls.end(), "b") == 2);
  CHECK(std::count(calls.begin(), calls.end(), "c") == 6);
  // meshflow run of the same study: every stage from the cache, the same outputs
  f.reset_calls();
  REQUIRE(f.run().code == 0);
  CHECK(f.calls().empty());
  int compared = 0;
  for (auto& e : fs::directory_iterator(f.out)) {
    if (!e.is_directory()) continue;
    const fs::path mine = f.dir / "smk_out" / e.path().filename() / "final.txt";
    INFO(mine);
    REQUIRE(fs::exists(mine));
    CHECK(read_text(mine) == read_text(e.path() / "final.txt"));
    ++compared;
  }
  CHECK(compared == 6);
  // a second Snakemake run has nothing to do
  auto again = sh("/usr/bin/snakemake -s " + snakefile.string() + " --cores 2 -d " + work.string() + " -n 2>&1");
  CHECK(again.out.find("Nothing to be done") != std::string::npos);
}
