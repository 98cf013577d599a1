// Stage kinds that exist only in the engine tests, and helpers to write workflows and run
// the CLI (in-process, or as a child process via `test_engine --as-meshflow`).
#pragma once

#include "support.hpp"

#include <nlohmann/json.hpp>

#include <filesystem>
#include <string>
#include <vector>

namespace mftest {

struct CliResult {
  int code;
  std::string out, err;
};
// Runs `meshflow ARGS` in-process (stage kinds of this test binary available).
CliResult cli(const std::vector<std::string>& args);
// Starts `meshflow ARGS` as a child process (this test binary with --as-meshflow); returns pid.
int spawn_meshflow(const std::vector<std::string>& args, const fs::path& log);

// Lines appended by every test-stage run (stage name), via $MESHFLOW_TEST_CALLS.
std::vector<std::string> calls(const fs::path& file);

// A workflow file in a fresh folder beside its cache, outputs and the stages' call log; runs
// the CLI on it (run, check and golden write to `out`).
struct WorkflowFixture {
  fs::path dir, wf, cache, calls_file, out;
  explicit WorkflowFixture(const std::string& yaml, const std::string& tag = "run");
  CliResult run(std::vector<std::string> extra = {}, const std::string& cmd = "run") const;
  std::vector<std::string> calls() const { return mftest::calls(calls_file); }
  void reset_calls() const { fs::remove(calls_file); }
  nlohmann::json report() const;                         // out/report.json
  nlohmann::json stage(const std::string& name) const;  // that stage's entry of it (null if none)
};
// A study a -> b -> c whose matrix varies b (2 values) and c (3 values): a is shared by all 6
// variants, each b by 3 (matrix and Snakemake export tests).
extern const char* const kStudy;
// Number of action entries in a cache.
int action_count(const fs::path& cache);
// Files left in the cache's tmp/.
int tmp_count(const fs::path& cache);

}  // namespace mftest
