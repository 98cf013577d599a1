#include "engine/registry.hpp"

#include <nlohmann/json.hpp>

#include <cstdio>
#include <cstdlib>
#include <iostream>
#include <memory>

namespace meshflow {
namespace {
// Function-local statics: registration runs from static initialisers of other translation
// units, whose order is unspecified.
std::map<std::string, StageKind>& stage_table() {
  static std::map<std::string, StageKind> t;
  return t;
}
std::map<std::string, ArtifactType>& type_table() {
  static std::map<std::string, ArtifactType> t;
  return t;
}
}  // namespace

void register_stage(StageKind kind) {
  auto& t = stage_table();
  if (t.count(kind.kind)) {
    std::fprintf(stderr, "meshflow: internal error: stage kind '%s' registered twice\n", kind.kind.c_str());
    std::abort();
  }
  std::string k = kind.kind;
  t.emplace(k, std::move(kind));
}

const StageKind* find_stage_kind(const std::string& kind) {
  auto& t = stage_table();
  auto it = t.find(kind);
  return it == t.end() ? nullptr : &it->second;
}

std::vector<const StageKind*> all_stage_kinds() {
  std::vector<const StageKind*> v;
  for (auto& [k, s] : stage_table()) v.push_back(&s);
  return v;
}

void register_artifact_type(ArtifactType type) {
  auto& t = type_table();
  if (t.count(type.type)) {
    std::fprintf(stderr, "meshflow: internal error: artifact type '%s' registered twice\n", type.type.c_str());
    std::abort();
  }
  std::string k = type.type;
  t.emplace(k, std::move(type));
}

const ArtifactType* find_artifact_type(const std::string& type) {
  auto& t = type_table();
  auto it = t.find(type);
  return it == t.end() ? nullptr : &it->second;
}

std::vector<const ArtifactType*> all_artifact_types() {
  std::vector<const ArtifactType*> v;
  for (auto& [k, s] : type_table()) v.push_back(&s);
  return v;
}

const nlohmann::json* schema_for(const std::string& name) {
  static std::map<std::string, std::unique_ptr<nlohmann::json>> parsed = [] {
    std::map<std::string, std::unique_ptr<nlohmann::json>> m;
    for (auto& [k, text] : embedded_schemas()) {
      try {
        m[k] = std::make_unique<nlohmann::json>(nlohmann::json::parse(text));
      } catch (const std::exception& e) {
        std::fprintf(stderr, "meshflow: internal error: schemas/%s.schema.json is not valid JSON: %s\n", k.c_str(), e.what());
        std::abort();
      }
    }
    return m;
  }();
  auto it = parsed.find(name);
  return it == parsed.end() ? nullptr : it->second.get();
}

namespace {
std::map<std::string, std::string>& code_table() {
  static std::map<std::string, std::string> t;
  return t;
}
}  // namespace

void register_module_code(const std::string& module, const std::string& digest) { code_table()[module] = digest; }

const std::string& module_code(const std::string& module) {
  static const std::string none;
  auto it = code_table().find(module);
  return it == code_table().end() ? none : it->second;
}

const nlohmann::json* kind_schema(const StageKind& kind) {
  if (kind.schema.empty()) return schema_for(kind.kind);
  static std::map<std::string, std::unique_ptr<nlohmann::json>> inline_schemas;  // parsed once
  auto& slot = inline_schemas[kind.kind];
  if (!slot) slot = std::make_unique<nlohmann::json>(nlohmann::json::parse(kind.schema));
  return slot.get();
}

const Artifact& StageContext::input(const std::string& type) const {
  for (auto& a : inputs())
    if (a.type == type) return a;
  throw StageError("stage '" + stage_name() + "' needs an input artifact of type '" + type +
                   "', but none of the stages in its `needs` produces one: add such a stage to `needs`");
}

std::vector<const Artifact*> StageContext::inputs_of(const std::string& type) const {
  std::vector<const Artifact*> v;
  for (auto& a : inputs())
    if (a.type == type) v.push_back(&a);
  return v;
}

}  // namespace meshflow

#include "engine/command.hpp"
namespace meshflow {
namespace {
std::map<std::string, Command>& command_table() {
  static std::map<std::string, Command> t;
  return t;
}
}  // namespace
void register_command(Command command) {
  auto& t = command_table();
  if (t.count(command.name)) {
    std::fprintf(stderr, "meshflow: internal error: command '%s' registered twice\n", command.name.c_str());
    std::abort();
  }
  std::string k = command.name;
  t.emplace(k, std::move(command));
}
bool parse_file_command(const std::string& name, const std::vector<std::string>& args, FileCommandArgs& out) {
  const std::string usage = "usage: meshflow " + name + " FILE [--json] [--threads N]\n";
  for (std::size_t i = 0; i < args.size(); ++i) {
    if (args[i] == "--json") out.json = true;
    else if (args[i] == "--threads" && i + 1 < args.size()) out.threads = std::atoi(args[++i].c_str());
    else if (!args[i].empty() && args[i][0] == '-') {
      std::cerr << "meshflow " << name << ": unknown option " << args[i] << "\n" << usage;
      return false;
    } else if (out.file.empty()) out.file = args[i];
    else {
      std::cerr << "meshflow " << name << ": one FILE expected\n" << usage;
      return false;
    }
  }
  if (out.file.empty()) std::cerr << usage;
  return !out.file.empty();
}
const Command* find_command(const std::string& name) {
  auto& t = command_table();
  auto it = t.find(name);
  return it == t.end() ? nullptr : &it->second;
}
std::vector<const Command*> all_commands() {
  std::vector<const Command*> v;
  for (auto& [k, c] : command_table()) v.push_back(&c);
  return v;
}
}  // namespace meshflow
