// meshflow engine — `meshflow export snakemake WORKFLOW`: the workflow (every variant of its
// matrix) as a Snakefile, so that Snakemake runs its stages on the cores of one machine
// (`snakemake --cores N`) or on a cluster (`snakemake --slurm`, or `--cluster sbatch`), the
// cache (shared folder, or a remote cache) being where the stages meet.
//
// One rule per distinct stage: a stage of several variants with the same kind, parameters and
// upstream stages (the matrix varies only later stages) is one rule, run once. A rule runs
// `meshflow run WORKFLOW [--variant V] --only STAGE` (the stage, its upstream served from the
// cache) and touches a stamp file; a rule per variant writes its outputs (`meshflow run
// --variant V --out OUT/V`) once all its stages have run; `rule all` asks for those. `threads:`
// is the stage's thread budget (`--threads`, default 2) and `resources: mem_mb=` twice the peak
// memory of the stage's last run found in the cache (1024 when none is known).
#pragma once

#include "engine/workflow.hpp"

#include <filesystem>
#include <string>
#include <vector>

namespace meshflow {

struct SnakemakeExport {
  std::string exe;                  // the meshflow command the rules run (default: this executable)
  std::filesystem::path cache_dir;  // the cache the rules share (absolute in the Snakefile)
  std::filesystem::path out_dir;    // outputs: OUT/ (no matrix) or OUT/<variant>/
  std::filesystem::path stamps = "meshflow-stamps";  // stamp files, relative to Snakemake's working folder
  int threads = 2;
  std::vector<std::string> sets;    // --set overrides, passed to every rule
  std::vector<std::string> extra;   // further options for every meshflow command (e.g. --remote-cache URL)
};

// The Snakefile's text. Throws WorkflowError (a variant that does not load).
std::string snakefile(const Workflow& base, const SnakemakeExport& options);

}  // namespace meshflow
