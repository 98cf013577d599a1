// libFuzzer target: the workflow loader (YAML parse, schema validation with defaults and
// coercion, --set overrides, DAG checks). Anything but a WorkflowError or success is a bug.
// Built by `make fuzz` (clang, -fsanitize=fuzzer,address,undefined).
#include "engine/stage.hpp"
#include "engine/workflow.hpp"

#include <cstdint>
#include <string>

namespace {
// Kinds whose schemas exercise every keyword the validator supports.
meshflow::StageRegistrar a({.kind = "fz_a", .version = 1, .summary = "fuzz", .run = [](meshflow::StageContext&) {},
                            .schema = R"({"type":"object","additionalProperties":false,"required":["n"],"properties":{
  "n":{"type":"integer","minimum":1,"maximum":100,"default":3,"description":"n"},
  "x":{"type":"number","exclusiveMinimum":0,"exclusiveMaximum":1,"default":0.5,"description":"x"},
  "s":{"type":"string","pattern":"^[0-9]{4}$","default":"0012","description":"s"},
  "e":{"type":"string","enum":["a","b"],"default":"a","description":"e"},
  "c":{"const":1,"description":"c"},
  "f":{"type":"string","x-meshflow-file":true,"description":"f"},
  "l":{"type":"array","items":{"type":"number"},"minItems":1,"maxItems":3,"default":[1],"description":"l"},
  "o":{"oneOf":[{"type":"number"},{"type":"object","additionalProperties":false,"properties":{"v":{"type":"number","default":1}}}],"description":"o"},
  "m":{"type":["object","null"],"additionalProperties":{"type":"integer"},"description":"m"}}})"});
meshflow::StageRegistrar b({.kind = "fz_b", .version = 1, .summary = "fuzz", .run = [](meshflow::StageContext&) {},
                            .schema = R"({"type":"object","additionalProperties":false,"properties":{}})"});
}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  std::string text(reinterpret_cast<const char*>(data), size);
  // The first line, if it starts with "#set ", is a --set override: fuzz those too.
  std::vector<std::string> sets;
  if (text.rfind("#set ", 0) == 0) {
    auto nl = text.find('\n');
    sets.push_back(text.substr(5, nl == std::string::npos ? std::string::npos : nl - 5));
  }
  try {
    meshflow::load_workflow_text(text, "/tmp/fuzz/w.yaml", sets);
  } catch (const meshflow::WorkflowError&) {
  }
  return 0;
}
