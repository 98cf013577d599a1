// meshflow engine — golden regression: summaries of a run's outputs compared with
// golden/<workflow>/summary.json through the comparators artifact types register.
#pragma once

#include "engine/runner.hpp"
#include "engine/workflow.hpp"

#include <nlohmann/json.hpp>

#include <string>
#include <vector>

namespace meshflow {

// {"outputs": {NAME: summary}}: the artifact type's summarize(), or {"digest"} without one.
nlohmann::json golden_summary(const Workflow& wf, const RunResult& run);

// Numeric leaves within |a-b| <= abs + rel*|b| (per-field tolerances by dotted-path prefix);
// everything else exactly. Returns the differing fields, empty when they agree.
std::vector<std::string> golden_compare(const nlohmann::json& golden, const nlohmann::json& obtained, const GoldenDecl& tol);

}  // namespace meshflow
