// meshflow engine — lookup of registered stage kinds and embedded schemas (engine-internal).
#pragma once

#include "engine/artifact_type.hpp"
#include "engine/stage.hpp"

#include <map>
#include <string>
#include <vector>

namespace meshflow {

const StageKind* find_stage_kind(const std::string& kind);
std::vector<const StageKind*> all_stage_kinds();  // sorted by kind
std::vector<const ArtifactType*> all_artifact_types();

// schemas/<name>.schema.json as embedded at build time ("workflow", "<kind>", ...).
const std::map<std::string, std::string>& embedded_schemas();
// The parsed schema, or nullptr when there is none.
const nlohmann::json* schema_for(const std::string& name);
// The parameter schema of a kind: its inline schema, else schemas/<kind>.schema.json.
const nlohmann::json* kind_schema(const StageKind& kind);

}  // namespace meshflow
