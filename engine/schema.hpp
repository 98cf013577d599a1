// meshflow engine — a validator for the subset of JSON Schema (draft 2020-12) our schemas use.
//
// Why our own: no C++ JSON Schema validator is packaged in Debian 12, and we need two things a
// generic validator does not give: defaults filled into the instance (the cache key is over
// parameters *after* defaults) and plain YAML scalars coerced to strings where the schema says
// "string" (so `profile: 0012` stays "0012"). Keywords supported: type, properties, required,
// additionalProperties, enum, const, minimum, maximum, exclusiveMinimum, exclusiveMaximum,
// items, minItems, maxItems, pattern, default, oneOf; annotations description, title,
// $schema, $id, examples and "x-meshflow-file" (a string parameter naming an input file whose
// content digest goes into the cache key). Any other keyword in a schema is an internal error,
// so a schema can never silently promise more than is checked.
#pragma once

#include <nlohmann/json.hpp>

#include <map>
#include <string>
#include <vector>

namespace meshflow {

struct SchemaIssue {
  std::string pointer;  // JSON pointer into the instance, e.g. "/layers"
  std::string message;  // "is 0, below the minimum 1"
  std::string description;  // the schema's description of that value, if any
  std::string suggestion;   // for an unknown name: the nearest known one ("" if none is close)
};

// The known name nearest to `word` ("did you mean ...?"): smallest edit distance (ignoring
// case), within a third of the word's length (at least 2); "" when none is that close.
std::string nearest_name(const std::string& word, const std::vector<std::string>& known);

// Validates `instance` in place (defaults filled, plain scalars coerced). `raw_plain` maps
// JSON pointers of values that were plain (unquoted) YAML scalars to their source text.
std::vector<SchemaIssue> validate_schema(nlohmann::json& instance, const nlohmann::json& schema,
                                         const std::map<std::string, std::string>* raw_plain = nullptr,
                                         const std::string& pointer = "");

// Throws std::logic_error naming the keyword if `schema` uses one the validator does not know.
void check_schema_keywords(const nlohmann::json& schema, const std::string& where);

// JSON pointers (relative to the instance) of string values marked "x-meshflow-file".
std::vector<std::string> file_parameters(const nlohmann::json& instance, const nlohmann::json& schema,
                                         const std::string& pointer = "");

}  // namespace meshflow
