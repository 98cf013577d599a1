// meshflow engine — parameter studies: a workflow's `matrix:` expanded into variants.
//
//   matrix: {curve.order: [2, 3, 4], split.layers: [5, 10]}
//
// makes 6 variants, the Cartesian product in file order (the first key varies slowest). Each
// variant is the workflow with its values applied as --set overrides, named by them
// ("order-2_layers-5"; the whole key where two keys end alike). `meshflow run` runs them one
// after another against the one cache, so the stages they share (here everything upstream of
// curve) are computed once and served from the cache after; each variant runs its own stages in
// parallel (-j) as any run does. Outputs go to out/<name>/<variant>/, each with its report.json;
// out/<name>/matrix.json and the printed table hold every variant's status and mesh figures.
#pragma once

#include "engine/runner.hpp"
#include "engine/workflow.hpp"

#include <iosfwd>
#include <string>
#include <vector>

namespace meshflow {

struct Variant {
  std::string name;
  std::vector<std::string> overrides;  // "STAGE.PARAM=VALUE", as --set takes them
};

// The variants of wf's matrix, in order; empty when it has none.
std::vector<Variant> matrix_variants(const Workflow& wf);

// The variant called `name`; throws WorkflowError listing the names when there is none.
const Variant& find_variant(const std::vector<Variant>& variants, const std::string& name, const Workflow& wf);

// Loads every variant (a bad value is a WorkflowError before anything runs; `sets` may not
// name a key the matrix varies), runs each into <out>/<variant>/, prints the table and writes
// <out>/matrix.json. `only` (non-empty) runs that variant alone.
struct MatrixResult {
  bool ok = true, invalid = false, failed = false, bad_input = false;  // see RunResult
  nlohmann::json table = nlohmann::json::array();
};
MatrixResult run_matrix(const Workflow& base, const std::vector<std::string>& sets, const RunOptions& options,
                        const std::string& only = {});

}  // namespace meshflow
