// meshflow engine — the workflow file: YAML -> validated model with a deterministic DAG.
//
// A workflow (format version 1):
//   meshflow: 1
//   name: naca-wingtip
//   stages:
//     NAME: {kind: KIND, needs: [NAME...], with: {PARAM: VALUE...}}
//   outputs:
//     NAME: {from: STAGE, artifact: ARTIFACT (default: the stage's first), formats: [FMT...]}
//   golden: DIR | {path: DIR, tolerance: {rel, abs}, fields: {"a.b.c": {rel, abs}}}
//   matrix: {STAGE.PARAM: [VALUE...], ...}   (variants: engine/matrix.hpp)
//   report: false                            (no out/<name>/report.html; engine/run_report.hpp)
// schemas/workflow.schema.json is the truth for the top level; schemas/<kind>.schema.json
// for each stage's `with`. Relative paths are relative to the workflow file's folder.
#pragma once

#include <nlohmann/json.hpp>

#include <cstddef>
#include <filesystem>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

namespace meshflow {

// Bounds on what a workflow file may hold, checked while loading (a workflow is a few kB and
// a few hundred YAML nodes; these leave ample room and stop a hostile file early):
constexpr std::size_t kMaxWorkflowBytes = 1 << 20;  // the file (1 MiB)
constexpr std::size_t kMaxYamlNodes = 100000;       // nodes after alias expansion (`*a` copies `&a`)
constexpr std::size_t kMaxNameLength = 100;         // workflow and stage names (they name files)
constexpr std::size_t kMaxVariants = 256;           // variants a `matrix:` may make

// Every problem with a workflow is reported as one paragraph: where, what, what to do.
struct WorkflowError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

struct FileParam {
  std::string pointer;          // "/file" within the stage's params
  std::filesystem::path path;   // resolved against the workflow folder
};

struct StageDecl {
  std::string name, kind;
  std::vector<std::string> needs;
  nlohmann::json params;        // validated, defaults filled
  std::vector<FileParam> files; // parameters naming input files
  int line = 0;                 // where the stage is declared (1-based; 0 unknown)
};

struct OutputDecl {
  std::string name, from, artifact;
  std::vector<std::string> formats;
};

struct GoldenDecl {
  std::filesystem::path dir;
  double rel = 1e-9, abs = 1e-12;  // default tolerance of numeric fields
  nlohmann::json fields = nlohmann::json::object();  // "mesh.min_scaled_jacobian": {rel, abs}
};

struct Workflow {
  std::filesystem::path file;  // as given
  std::filesystem::path dir;   // its folder (absolute)
  std::string name;
  std::vector<StageDecl> stages;  // in deterministic topological order (file order for ties)
  std::vector<OutputDecl> outputs;
  std::optional<GoldenDecl> golden;
  bool report = true;  // write out/<name>/report.html after a run
  // `matrix:` in file order: "STAGE.PARAM" and its values (each as JSON text, which is YAML and
  // goes through the same path as --set). Empty without a matrix. engine/matrix.hpp expands it.
  std::vector<std::pair<std::string, std::vector<std::string>>> matrix;

  const StageDecl* find(const std::string& stage) const;
  // The stage and everything downstream of it.
  std::vector<std::string> descendants(const std::string& stage) const;
  // The workflow reduced to `stage` and what it needs, directly or not, with no outputs
  // (`meshflow run --only STAGE`: one stage of a Snakemake rule). Throws WorkflowError for an
  // unknown stage.
  Workflow upstream_of(const std::string& stage) const;
};

// Loads and validates the workflow; `overrides` are "STAGE.PARAM=VALUE" (--set), the value
// parsed as YAML and typed by the schema. Throws WorkflowError.
Workflow load_workflow(const std::filesystem::path& file, const std::vector<std::string>& overrides = {});
// The same from the file's text (`file` names it in messages and anchors relative paths).
Workflow load_workflow_text(const std::string& text, const std::filesystem::path& file,
                            const std::vector<std::string>& overrides = {});

}  // namespace meshflow
