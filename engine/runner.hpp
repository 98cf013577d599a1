// meshflow engine — runs a workflow: stale stages only, independent ones in parallel, each in
// a child process; progress while running, a summary table and report.json at the end.
#pragma once

#include "engine/cache.hpp"
#include "engine/remote_cache.hpp"
#include "engine/stage.hpp"
#include "engine/workflow.hpp"

#include <nlohmann/json.hpp>

#include <filesystem>
#include <iosfwd>
#include <optional>
#include <string>
#include <vector>

namespace meshflow {

constexpr int kEngineFormat = 2;  // bump when the key preimage or the store layout changes (2: the preimage names meshflow's version)
constexpr double kDefaultMemoryShare = 0.8;  // RunOptions::memory_budget_gb's default: this share of the machine

// The memory budget in bytes that `gb` (RunOptions::memory_budget_gb) means on this machine;
// 0: none (also in sanitizer builds, whose shadow memory needs terabytes of address space).
unsigned long long memory_budget_bytes(double gb);

struct RunOptions {
  std::filesystem::path cache_dir;  // empty: --cache > $MESHFLOW_CACHE > .meshflow/ beside the workflow
  std::filesystem::path out_dir;    // empty: out/<workflow name>/ under the current directory
  int jobs = 0;                     // stages at once; 0 = number of cores
  int threads = 0;                  // total thread budget; 0 = number of cores
  // Address space each stage process may take, in GB (RLIMIT_AS): a stage past it fails with a
  // message naming the budget instead of being killed by the kernel's OOM killer (or taking the
  // machine down). Negative: kDefaultMemoryShare of the machine's memory; 0: no limit.
  double memory_budget_gb = -1;
  bool materialise = true;          // write outputs and report.json
  bool verbose = false;             // stage log lines as they come
  // Accept results that break their contract (stats.problems): downstream stages run on them
  // and the run counts as ok, marked "invalid_accepted". For debugging; never the default.
  bool allow_invalid = false;
  // Whether the last stages' results are delivered (their non-blocking contract problems fail
  // the run). False for `run --only STAGE`: a Snakemake rule computes one stage for later ones,
  // and the rule that writes the outputs judges what is delivered.
  bool deliver = true;
  RemoteCacheOptions remote;        // url empty: no remote cache (see resolve_remote_cache)
  std::ostream* out = nullptr;      // progress and summary (default std::cout)
  std::ostream* err = nullptr;      // error paragraphs (default std::cerr)
};

struct StageResult {
  std::string name, kind;
  std::string status = "skipped";  // ran | cached | invalid | failed | skipped
  std::string computed;            // an invalid result: how it was obtained (ran | cached)
  bool remote = false;             // cached: served by the remote cache (downloaded in this run)
  std::string key, error;
  double seconds = 0, peak_rss_mb = 0;
  nlohmann::json stats = nlohmann::json::object();
  std::vector<Artifact> outputs;
};

struct RunResult {
  bool ok = false;
  // Some stage's result breaks its contract (status "invalid"): the run is not ok unless
  // allow_invalid accepted it. Exit code 3 (cli's kInvalid), distinct from a failed stage.
  bool invalid = false;
  bool failed = false;  // a stage failed, or the outputs or report.json could not be written
  // A stage's input is bad (a `file:` parameter names a missing file or a folder): exit 2
  // (cli's kBadInput), as for any bad input, rather than 1.
  bool bad_input = false;
  std::vector<StageResult> stages;  // in topological order
  nlohmann::json report;
  std::filesystem::path out_dir;
};

std::filesystem::path resolve_cache_dir(const Workflow& wf, const std::filesystem::path& option);

RunResult run_workflow(const Workflow& wf, const RunOptions& options);

// Status without running: fresh (cached), stale (with the reason), never run, or waiting on
// a stale upstream stage.
struct StageStatus {
  std::string name, state, reason, key;
};
std::vector<StageStatus> workflow_status(const Workflow& wf, Cache& cache);

// Field-by-field difference of two JSON values: "params.layers: 10 -> 12".
std::vector<std::string> json_diff(const nlohmann::json& before, const nlohmann::json& after, const std::string& path = "");

// `meshflow explain`: why STAGE is stale, as lines.
std::vector<std::string> explain_stage(const Workflow& wf, Cache& cache, const std::string& stage);

}  // namespace meshflow
