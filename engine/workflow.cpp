#include "engine/workflow.hpp"

#include "engine/artifact_type.hpp"
#include "engine/registry.hpp"
#include "engine/schema.hpp"

#include <yaml-cpp/depthguard.h>
#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cstdlib>
#include <fstream>
#include <functional>
#include <map>
#include <optional>
#include <regex>
#include <set>
#include <sstream>

namespace fs = std::filesystem;
using nlohmann::json;

namespace meshflow {

namespace {

struct Mark {
  int line = 0, column = 0;  // 1-based; line -1 = from --set
};

struct Source {
  std::string file;
  std::size_t nodes = 0;  // YAML nodes converted so far (aliases count each time they are used)
  std::map<std::string, Mark> marks;       // JSON pointer -> where it was written
  std::map<std::string, std::string> raw;  // pointer -> text of plain scalars

  [[noreturn]] void fail(const std::string& pointer, const std::string& what) const {
    // The nearest enclosing pointer that has a mark.
    std::string p = pointer;
    Mark m;
    while (true) {
      auto it = marks.find(p);
      if (it != marks.end()) {
        m = it->second;
        break;
      }
      if (p.empty()) break;
      p = p.substr(0, p.rfind('/'));
    }
    std::string where = file;
    if (m.line > 0) where += ":" + std::to_string(m.line) + ":" + std::to_string(m.column);
    if (m.line < 0) where += " (--set)";
    throw WorkflowError(where + ": " + what);
  }
};

std::string escape_token(const std::string& k) {
  std::string s;
  for (char c : k) s += c == '~' ? std::string("~0") : c == '/' ? std::string("~1") : std::string(1, c);
  return s;
}

std::string dotted(const std::string& pointer) {
  std::string s;
  std::stringstream in(pointer);
  std::string tok;
  std::getline(in, tok, '/');
  while (std::getline(in, tok, '/')) s += (s.empty() ? "" : ".") + tok;
  return s;
}

json scalar_to_json(const YAML::Node& n, bool* plain) {
  const std::string& t = n.Scalar();
  *plain = n.Tag() != "!";
  if (!*plain) return t;
  static const std::regex int_re("[-+]?[0-9]+");
  static const std::regex float_re("[-+]?(\\.[0-9]+|[0-9]+(\\.[0-9]*)?)([eE][-+]?[0-9]+)?");
  if (t == "~" || t == "null" || t == "Null" || t == "NULL" || t.empty()) return nullptr;
  if (t == "true" || t == "True" || t == "TRUE") return true;
  if (t == "false" || t == "False" || t == "FALSE") return false;
  if (std::regex_match(t, int_re)) {
    try {
      return std::stoll(t);
    } catch (...) {
    }
  }
  // strtod, not stod: 1e999 is +inf (rejected later as not finite), not an exception (fuzzing).
  if (std::regex_match(t, float_re)) return std::strtod(t.c_str(), nullptr);
  if (t == ".inf" || t == "+.inf") return std::numeric_limits<double>::infinity();
  if (t == "-.inf") return -std::numeric_limits<double>::infinity();
  return t;
}

// YAML's spellings of not-a-number (a plain scalar).
bool is_nan_text(const std::string& t) { return t == ".nan" || t == ".NaN" || t == ".NAN"; }

json yaml_to_json(const YAML::Node& n, const std::string& ptr, Source& src) {
  if (++src.nodes > kMaxYamlNodes)
    throw WorkflowError(src.file + ":" + std::to_string(n.Mark().line + 1) + ": the workflow expands to more than " +
                        std::to_string(kMaxYamlNodes) +
                        " YAML nodes (each alias `*name` copies its anchor `&name`, so nested aliases multiply). A "
                        "workflow needs a few hundred: remove the nested aliases.");
  src.marks[ptr] = {n.Mark().line + 1, n.Mark().column + 1};
  switch (n.Type()) {
    case YAML::NodeType::Null: return nullptr;
    case YAML::NodeType::Scalar: {
      if (n.Tag() != "!" && is_nan_text(n.Scalar()))
        src.fail(ptr, "'" + dotted(ptr) + "' is " + n.Scalar() + " (not a number): give a finite number.");
      bool plain = false;
      json v = scalar_to_json(n, &plain);
      if (plain) src.raw[ptr] = n.Scalar();
      return v;
    }
    case YAML::NodeType::Sequence: {
      json a = json::array();
      size_t i = 0;
      for (auto it = n.begin(); it != n.end(); ++it, ++i) a.push_back(yaml_to_json(*it, ptr + "/" + std::to_string(i), src));
      return a;
    }
    case YAML::NodeType::Map: {
      json o = json::object();
      for (auto it = n.begin(); it != n.end(); ++it) {
        if (!it->first.IsScalar()) src.fail(ptr, "a key must be a plain name");
        std::string k = it->first.Scalar();
        std::string p = ptr + "/" + escape_token(k);
        if (o.contains(k)) {
          src.marks[p] = {it->first.Mark().line + 1, it->first.Mark().column + 1};
          src.fail(p, "duplicate key '" + k + "'" + (dotted(ptr) == "stages" ? " (a stage of that name is already declared)" : "") +
                          ": each key may appear once; rename or remove one of them.");
        }
        o[k] = yaml_to_json(it->second, p, src);
        src.marks[p] = {it->first.Mark().line + 1, it->first.Mark().column + 1};
      }
      return o;
    }
    default: return nullptr;
  }
}

std::string issue_text(const SchemaIssue& is, const std::string& prefix) {
  std::string name = dotted(is.pointer);
  std::string s = prefix + (name.empty() ? std::string("the value") : "'" + name + "'") + " " + is.message + ".";
  if (!is.description.empty()) s += " (" + name + ": " + is.description + ")";
  return s;
}

}  // namespace

const StageDecl* Workflow::find(const std::string& stage) const {
  for (auto& s : stages)
    if (s.name == stage) return &s;
  return nullptr;
}

std::vector<std::string> Workflow::descendants(const std::string& stage) const {
  std::set<std::string> set{stage};
  for (auto& s : stages)  // topological order: one pass suffices
    for (auto& n : s.needs)
      if (set.count(n)) set.insert(s.name);
  std::vector<std::string> out;
  for (auto& s : stages)
    if (set.count(s.name)) out.push_back(s.name);
  return out;
}

Workflow Workflow::upstream_of(const std::string& stage) const {
  if (!find(stage)) throw WorkflowError(file.string() + ": --only " + stage + ": the workflow has no stage '" + stage + "'.");
  std::set<std::string> keep{stage};
  for (auto it = stages.rbegin(); it != stages.rend(); ++it)  // reverse topological order: one pass
    if (keep.count(it->name)) keep.insert(it->needs.begin(), it->needs.end());
  Workflow w = *this;
  w.stages.clear();
  for (auto& s : stages)
    if (keep.count(s.name)) w.stages.push_back(s);
  w.outputs.clear();
  return w;
}

namespace {
// The artifact types a stage's `needs` supply; nullopt when one of them is a kind that declares
// nothing (a test kind): then nothing can be said.
std::optional<std::set<std::string>> supplied_types(const StageDecl& d, const std::vector<StageDecl>& decls,
                                                    const std::map<std::string, size_t>& index) {
  std::set<std::string> types;
  for (auto& n : d.needs) {
    const StageKind* k = find_stage_kind(decls[index.at(n)].kind);
    if (k->produces.empty()) return std::nullopt;
    for (auto& a : k->produces) types.insert(a.type);
  }
  return types;
}

// The kinds that produce `type`, for a message ("sweep, split, ...").
std::string producers_of(const std::string& type) {
  std::string s;
  for (auto* k : all_stage_kinds())
    for (auto& a : k->produces)
      if (a.type == type && k->schema.empty()) {
        s += (s.empty() ? "" : ", ") + k->kind;
        break;
      }
  return s.empty() ? "none" : s;
}

// A stage whose `needs` cannot supply an artifact type its kind reads is refused at load:
// the run would otherwise fail when that stage starts, after everything before it ran.
void check_inputs_supplied(const Source& src, const StageDecl& d, const std::vector<StageDecl>& decls,
                           const std::map<std::string, size_t>& index) {
  const StageKind* kind = find_stage_kind(d.kind);
  auto types = supplied_types(d, decls, index);
  if (!types) return;
  for (auto& t : kind->needs) {
    if (types->count(t)) continue;
    std::string have;
    for (auto& n : d.needs) {
      have += (have.empty() ? "" : "; ") + n + " (" + decls[index.at(n)].kind + ") gives";
      for (auto& a : find_stage_kind(decls[index.at(n)].kind)->produces) have += " " + a.type;
    }
    std::string needed;
    for (auto& x : kind->needs) needed += (needed.empty() ? "" : ", ") + x;
    src.fail("/stages/" + escape_token(d.name) + "/needs",
             "stage '" + d.name + "' (kind " + d.kind + ") reads an artifact of type '" + t + "', which none of its `needs` " +
                 (d.needs.empty() ? "supplies: it lists none" : "produces (" + have + ")") + ". A " + d.kind +
                 " stage needs " + needed + ". Add a stage that produces " + t + " (kinds: " + producers_of(t) +
                 ") to its `needs`; `meshflow kinds " + d.kind + "` says what it needs.");
  }
}

// An output names an artifact its stage's kind writes, in formats of that artifact's type.
void check_output_formats(const Source& src, const OutputDecl& od, const StageKind& kind) {
  if (kind.produces.empty()) return;
  const std::string at = "/outputs/" + escape_token(od.name);
  const ArtifactDecl* art = &kind.produces.front();
  if (!od.artifact.empty()) {
    art = nullptr;
    std::string names;
    for (auto& a : kind.produces) {
      if (a.name == od.artifact) art = &a;
      names += (names.empty() ? "" : ", ") + a.name;
    }
    if (!art)
      src.fail(at + "/artifact", "output '" + od.name + "': stage '" + od.from + "' (kind " + kind.kind +
                                     ") writes no artifact '" + od.artifact + "' (it writes: " + names + ").");
  }
  const ArtifactType* type = find_artifact_type(art->type);
  if (!type) return;
  for (size_t i = 0; i < od.formats.size(); ++i) {
    if (type->formats.count(od.formats[i])) continue;
    std::string known;
    std::vector<std::string> names;
    for (auto& [n, f] : type->formats) {
      known += (known.empty() ? "" : ", ") + n;
      names.push_back(n);
    }
    std::string near = nearest_name(od.formats[i], names);
    src.fail(at + "/formats/" + std::to_string(i),
             "output '" + od.name + "': a " + art->type + " has no format '" + od.formats[i] + "'" +
                 (near.empty() ? "" : "; did you mean '" + near + "'?") + " (formats: " + (known.empty() ? "none" : known) +
                 "; `meshflow kinds` describes them).");
  }
}
}  // namespace

namespace {
std::string too_large(const fs::path& file, std::uintmax_t bytes) {
  return file.string() + ": the workflow file is " + std::to_string(bytes) + " bytes; at most " +
         std::to_string(kMaxWorkflowBytes) +
         " are read (a workflow is a few kB; put large data in files that stages read, e.g. `file:`).";
}
}  // namespace

Workflow load_workflow(const fs::path& file, const std::vector<std::string>& overrides) {
  std::error_code ec;
  if (fs::is_directory(file, ec))
    throw WorkflowError(file.string() + ": is a folder, not a workflow file. Give the path of a .yaml file.");
  std::ifstream in(file, std::ios::binary);
  if (!in)
    throw WorkflowError(file.string() + ": cannot read the workflow file (" +
                        (fs::exists(file) ? "permission denied" : "no such file") + "). Check the path.");
  // Read at most one byte more than the limit: a huge (or endless, /dev/zero) file is refused
  // without being read whole.
  std::string text(kMaxWorkflowBytes + 1, '\0');
  in.read(text.data(), std::streamsize(text.size()));
  text.resize(std::size_t(in.gcount()));
  if (text.size() > kMaxWorkflowBytes) {
    auto size = fs::file_size(file, ec);
    throw WorkflowError(too_large(file, ec ? text.size() : size));
  }
  return load_workflow_text(text, file, overrides);
}

namespace {
// Byte offset of the first invalid UTF-8 sequence, or npos. (JSON, hence keys and reports,
// hold only UTF-8; found by fuzzing.)
size_t invalid_utf8(const std::string& s) {
  size_t i = 0, n = s.size();
  while (i < n) {
    unsigned char c = static_cast<unsigned char>(s[i]);
    size_t len = c < 0x80 ? 1 : (c >> 5) == 6 ? 2 : (c >> 4) == 14 ? 3 : (c >> 3) == 30 ? 4 : 0;
    if (len == 0 || i + len > n) return i;
    if (len == 2 && c < 0xC2) return i;  // overlong
    for (size_t k = 1; k < len; ++k)
      if ((static_cast<unsigned char>(s[i + k]) >> 6) != 2) return i;
    if (len == 3) {
      unsigned char c1 = static_cast<unsigned char>(s[i + 1]);
      if ((c == 0xE0 && c1 < 0xA0) || (c == 0xED && c1 >= 0xA0)) return i;  // overlong, surrogates
    }
    if (len == 4) {
      unsigned char c1 = static_cast<unsigned char>(s[i + 1]);
      if ((c == 0xF0 && c1 < 0x90) || c > 0xF4 || (c == 0xF4 && c1 >= 0x90)) return i;
    }
    i += len;
  }
  return std::string::npos;
}
}  // namespace

Workflow load_workflow_text(const std::string& text, const fs::path& file, const std::vector<std::string>& overrides) {
  Source src;
  src.file = file.string();
  if (text.size() > kMaxWorkflowBytes) throw WorkflowError(too_large(file, text.size()));
  if (size_t bad = invalid_utf8(text); bad != std::string::npos) {
    int line = 1 + int(std::count(text.begin(), text.begin() + long(bad), '\n'));
    throw WorkflowError(file.string() + ":" + std::to_string(line) + ": the file is not valid UTF-8 (byte offset " +
                        std::to_string(bad) + "). Save it as UTF-8.");
  }
  for (auto& o : overrides)
    if (invalid_utf8(o) != std::string::npos) throw WorkflowError("--set " + std::string(o.size() > 40 ? o.substr(0, 40) : o) + "...: not valid UTF-8.");
  YAML::Node root;
  try {
    root = YAML::Load(text);
  } catch (const YAML::DeepRecursion& e) {  // yaml-cpp's message is only "bad file"
    throw WorkflowError(file.string() + ":" + std::to_string(e.mark.line + 1) + ":" + std::to_string(e.mark.column + 1) +
                        ": the YAML is nested too deep: lists or mappings " + std::to_string(e.depth()) +
                        " levels deep, the most the YAML reader takes (a workflow needs a handful). Look for runaway "
                        "brackets or indentation there.");
  } catch (const YAML::Exception& e) {
    throw WorkflowError(file.string() + ":" + std::to_string(e.mark.line + 1) + ":" + std::to_string(e.mark.column + 1) +
                        ": YAML syntax error: " + e.msg + ". Fix the YAML (indentation, quotes, colons) at that place.");
  }
  if (!root.IsMap())
    throw WorkflowError(file.string() + ": a workflow must be a YAML mapping with `meshflow: 1`, `name` and `stages`.");
  json doc = yaml_to_json(root, "", src);

  // --set STAGE.PARAM=VALUE
  for (auto& o : overrides) {
    auto eq = o.find('=');
    auto dot = o.find('.');
    if (eq == std::string::npos || dot == std::string::npos || dot > eq)
      throw WorkflowError("--set " + o + ": expected STAGE.PARAM=VALUE, e.g. --set split.layers=12");
    std::string stage = o.substr(0, dot), path = o.substr(dot + 1, eq - dot - 1), value = o.substr(eq + 1);
    if (value.empty())
      throw WorkflowError("--set " + o + ": the value is empty. Give one, e.g. --set " + stage + "." + path +
                          "=VALUE (an empty string is --set '" + stage + "." + path + "=\"\"').");
    if (is_nan_text(value))
      throw WorkflowError("--set " + o + ": " + value + " is not a number. Give a finite number.");
    if (!doc.contains("stages") || !doc["stages"].is_object() || !doc["stages"].contains(stage)) {
      std::vector<std::string> names;
      if (doc.contains("stages") && doc["stages"].is_object())
        for (auto& [n, v] : doc["stages"].items()) names.push_back(n);
      std::string near = nearest_name(stage, names);
      throw WorkflowError("--set " + o + ": the workflow " + file.string() + " has no stage '" + stage + "'" +
                          (near.empty() ? "." : "; did you mean '" + near + "'?"));
    }
    json& st = doc["stages"][stage];
    if (!st.is_object()) break;  // reported by validation below
    std::string ptr = "/stages/" + escape_token(stage) + "/with";
    json* target = &st["with"];
    if (target->is_null()) *target = json::object();
    std::stringstream ps(path);
    std::string tok;
    std::vector<std::string> toks;
    while (std::getline(ps, tok, '.')) toks.push_back(tok);
    for (size_t i = 0; i < toks.size(); ++i) {
      if (!target->is_object())
        throw WorkflowError("--set " + o + ": '" + stage + "." + path + "' does not name a parameter of an object.");
      ptr += '/';
      ptr += escape_token(toks[i]);
      target = &(*target)[toks[i]];
    }
    YAML::Node v;
    try {
      v = YAML::Load(value);
    } catch (const YAML::DeepRecursion& e) {
      throw WorkflowError("--set " + o.substr(0, 60) + "...: the value is nested too deep: lists or mappings " +
                          std::to_string(e.depth()) + " levels deep, the most the YAML reader takes.");
    } catch (const YAML::Exception& e) {
      throw WorkflowError("--set " + o + ": the value is not valid YAML: " + e.msg);
    }
    Source tmp;
    *target = v.IsNull() && !value.empty() ? json(value) : yaml_to_json(v, ptr, tmp);
    for (auto& [p, r] : tmp.raw) src.raw[p] = r;
    for (auto& [p, m] : tmp.marks) src.marks[p] = {-1, 0};
  }

  // Top level against schemas/workflow.schema.json.
  const json* wschema = schema_for("workflow");
  if (!wschema) throw std::logic_error("schemas/workflow.schema.json is not embedded");
  auto issues = validate_schema(doc, *wschema, &src.raw);
  if (!issues.empty()) {
    auto& is = issues.front();
    std::string what = issue_text(is, "");
    if (is.pointer == "/meshflow") what += " This meshflow reads workflow format 1: put `meshflow: 1` at the top.";
    if (is.pointer == "/name") what += " Give the workflow a `name:` (letters, digits, '-', '_', '.').";
    src.fail(is.pointer, what);
  }

  Workflow wf;
  wf.file = file;
  wf.dir = fs::absolute(file).parent_path();
  wf.name = doc["name"];
  if (wf.name.size() > kMaxNameLength)
    src.fail("/name", "the workflow name is " + std::to_string(wf.name.size()) + " characters long; at most " +
                          std::to_string(kMaxNameLength) + " are allowed (it names the folders out/<name>/ and the cache's "
                          "records). Give it a shorter `name:`.");

  // Stages in file order (yaml-cpp keeps document order; nlohmann sorts, so walk the YAML).
  std::vector<StageDecl> decls;
  static const std::regex name_re("[A-Za-z_][A-Za-z0-9_-]*");
  for (auto it = root["stages"].begin(); it != root["stages"].end(); ++it) {
    std::string name = it->first.Scalar();
    std::string base = "/stages/" + escape_token(name);
    if (!std::regex_match(name, name_re))
      src.fail(base, "stage name '" + name + "' must start with a letter or '_' and contain only letters, digits, '_' and '-'.");
    if (name.size() > kMaxNameLength)
      src.fail(base, "a stage name is " + std::to_string(name.size()) + " characters long; at most " +
                         std::to_string(kMaxNameLength) + " are allowed (it names the cache's record of the stage). Shorten it.");
    json& st = doc["stages"][name];
    StageDecl d;
    d.name = name;
    d.kind = st["kind"];
    d.line = src.marks[base].line;
    for (auto& n : st.value("needs", json::array())) d.needs.push_back(n);
    const StageKind* kind = find_stage_kind(d.kind);
    if (!kind) {
      std::string known;
      std::vector<std::string> names;
      for (auto* k : all_stage_kinds()) {
        known += (known.empty() ? "" : ", ") + k->kind;
        names.push_back(k->kind);
      }
      std::string near = nearest_name(d.kind, names);
      src.fail(base + "/kind", "stage '" + name + "': unknown kind '" + d.kind + "'" +
                                   (near.empty() ? "." : "; did you mean '" + near + "'?") + " Known kinds: " + known +
                                   " (`meshflow kinds` describes them).");
    }
    const json* schema = kind_schema(*kind);
    if (!schema) throw std::logic_error("stage kind '" + d.kind + "' has no schemas/" + d.kind + ".schema.json");
    d.params = st.contains("with") && !st["with"].is_null() ? st["with"] : json::object();
    auto pis = validate_schema(d.params, *schema, &src.raw, base + "/with");
    if (!pis.empty()) {
      auto& is = pis.front();
      std::string param = dotted(is.pointer.substr(base.size() + 5));
      std::string what = "stage '" + name + "' (kind " + d.kind + "), parameter '" + param + "' " + is.message + ".";
      if (!is.description.empty()) what += " " + param + ": " + is.description;
      std::string settable = param;
      if (!is.suggestion.empty()) {
        auto dot = settable.rfind('.');
        settable = (dot == std::string::npos ? "" : settable.substr(0, dot + 1)) + is.suggestion;
      }
      what += " Fix it in the workflow or with --set " + name + "." + settable + "=VALUE.";
      src.fail(is.pointer, what);
    }
    for (auto& p : file_parameters(d.params, *schema)) {
      fs::path given = d.params.at(json::json_pointer(p)).get<std::string>();
      fs::path resolved = given.is_absolute() ? given : wf.dir / given;
      d.files.push_back({p, resolved.lexically_normal()});
    }
    decls.push_back(std::move(d));
  }

  // Needs: known, not self, then a cycle check that names the cycle.
  std::map<std::string, size_t> index;
  for (size_t i = 0; i < decls.size(); ++i) index[decls[i].name] = i;
  for (auto& d : decls)
    for (size_t j = 0; j < d.needs.size(); ++j) {
      std::string p = "/stages/" + escape_token(d.name) + "/needs/" + std::to_string(j);
      if (!index.count(d.needs[j])) {
        std::string known;
        std::vector<std::string> names;
        for (auto& e : decls) {
          known += (known.empty() ? "" : ", ") + e.name;
          names.push_back(e.name);
        }
        std::string near = nearest_name(d.needs[j], names);
        src.fail(p, "stage '" + d.name + "' needs '" + d.needs[j] + "', which is not a stage of this workflow" +
                        (near.empty() ? "" : "; did you mean '" + near + "'?") + " (stages: " + known +
                        "). Fix the name or declare that stage.");
      }
      if (std::count(d.needs.begin(), d.needs.end(), d.needs[j]) > 1)
        src.fail(p, "stage '" + d.name + "' lists '" + d.needs[j] + "' twice in `needs`: list each stage once.");
    }
  std::vector<int> color(decls.size(), 0);
  std::vector<size_t> stack;
  std::function<void(size_t)> dfs = [&](size_t i) {
    color[i] = 1;
    stack.push_back(i);
    for (auto& n : decls[i].needs) {
      size_t j = index[n];
      if (color[j] == 1) {
        std::string cyc;
        auto from = std::find(stack.begin(), stack.end(), j);
        for (auto k = from; k != stack.end(); ++k) cyc += decls[*k].name + " -> ";
        cyc += decls[j].name;
        src.fail("/stages/" + escape_token(decls[i].name) + "/needs",
                 "the stages form a cycle: " + cyc + " (each needs the next). A workflow must be acyclic: remove one of these needs.");
      }
      if (color[j] == 0) dfs(j);
    }
    stack.pop_back();
    color[i] = 2;
  };
  for (size_t i = 0; i < decls.size(); ++i)
    if (color[i] == 0) dfs(i);

  for (auto& d : decls) check_inputs_supplied(src, d, decls, index);

  // Kahn's algorithm, ties broken by file order: a deterministic topological order.
  std::vector<int> indeg(decls.size(), 0);
  for (auto& d : decls) indeg[index[d.name]] = int(d.needs.size());
  std::vector<bool> done(decls.size(), false);
  while (wf.stages.size() < decls.size()) {
    for (size_t i = 0; i < decls.size(); ++i) {
      if (done[i] || indeg[i] != 0) continue;
      done[i] = true;
      for (auto& e : decls)
        if (std::count(e.needs.begin(), e.needs.end(), decls[i].name)) --indeg[index[e.name]];
      wf.stages.push_back(decls[i]);
      break;
    }
  }

  // Outputs.
  if (doc.contains("outputs"))
    for (auto& [oname, o] : doc["outputs"].items()) {
      OutputDecl od{oname, o["from"], o.value("artifact", ""), {}};
      for (auto& f : o.value("formats", json::array())) od.formats.push_back(f);
      if (!wf.find(od.from))
        src.fail("/outputs/" + escape_token(oname) + "/from",
                 "output '" + oname + "' comes from stage '" + od.from + "', which is not a stage of this workflow.");
      check_output_formats(src, od, *find_stage_kind(wf.find(od.from)->kind));
      wf.outputs.push_back(std::move(od));
    }

  wf.report = doc.value("report", true);

  if (doc.contains("golden")) {
    GoldenDecl g;
    const json& gj = doc["golden"];
    fs::path p = gj.is_string() ? gj.get<std::string>() : gj["path"].get<std::string>();
    g.dir = (p.is_absolute() ? p : wf.dir / p).lexically_normal();
    if (gj.is_object()) {
      if (gj.contains("tolerance")) {
        g.rel = gj["tolerance"].value("rel", g.rel);
        g.abs = gj["tolerance"].value("abs", g.abs);
      }
      if (gj.contains("fields")) g.fields = gj["fields"];
    }
    wf.golden = g;
  }

  // Matrix: keys name stages of this workflow (the parameter itself is checked when each variant
  // is loaded with the key as an override), in file order (walk the YAML: nlohmann sorts).
  if (root["matrix"]) {
    std::size_t variants = 1;
    for (auto it = root["matrix"].begin(); it != root["matrix"].end(); ++it) {
      const std::string key = it->first.Scalar();
      const std::string ptr = "/matrix/" + escape_token(key);
      const auto dot = key.find('.');
      if (dot == std::string::npos || dot == 0 || dot + 1 == key.size())
        src.fail(ptr, "matrix key '" + key + "' is not STAGE.PARAM (as for --set, e.g. curve.order).");
      const std::string stage = key.substr(0, dot);
      if (!wf.find(stage)) {
        std::vector<std::string> names;
        for (auto& s : wf.stages) names.push_back(s.name);
        const std::string near = nearest_name(stage, names);
        src.fail(ptr, "matrix key '" + key + "' names no stage of this workflow" +
                          (near.empty() ? "." : "; did you mean '" + near + key.substr(dot) + "'?"));
      }
      std::vector<std::string> values;
      for (auto& v : doc["matrix"][key]) values.push_back(v.dump());
      variants *= values.size();
      wf.matrix.emplace_back(key, std::move(values));
    }
    if (variants > kMaxVariants)
      src.fail("/matrix", "the matrix makes " + std::to_string(variants) + " variants; at most " + std::to_string(kMaxVariants) +
                              " are allowed. Split the study into several workflows or fewer values.");
  }
  return wf;
}

}  // namespace meshflow
