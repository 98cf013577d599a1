#include "engine/schema.hpp"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <regex>
#include <set>
#include <stdexcept>

using nlohmann::json;

namespace meshflow {
namespace {

std::string type_name(const json& v) {
  switch (v.type()) {
    case json::value_t::null: return "null";
    case json::value_t::boolean: return "boolean";
    case json::value_t::number_integer:
    case json::value_t::number_unsigned: return "integer";
    case json::value_t::number_float: return "number";
    case json::value_t::string: return "string";
    case json::value_t::array: return "array";
    case json::value_t::object: return "object";
    default: return "value";
  }
}

std::string show(const json& v) {
  std::string s = v.dump(-1, ' ', false, json::error_handler_t::replace);
  return s.size() > 60 ? s.substr(0, 57) + "..." : s;
}

// Does `v` match type `t`? May convert v (integral float -> integer).
bool matches_type(json& v, const std::string& t) {
  if (t == "object") return v.is_object();
  if (t == "array") return v.is_array();
  if (t == "string") return v.is_string();
  if (t == "boolean") return v.is_boolean();
  if (t == "null") return v.is_null();
  if (t == "number") return v.is_number();
  if (t == "integer") {
    if (v.is_number_integer()) return true;
    if (v.is_number_float() && std::isfinite(v.get<double>()) && std::floor(v.get<double>()) == v.get<double>() &&
        std::fabs(v.get<double>()) < 9e15) {
      v = static_cast<long long>(v.get<double>());
      return true;
    }
    return false;
  }
  return false;
}

std::string escape_token(const std::string& k) {
  std::string s;
  for (char c : k) {
    if (c == '~') s += "~0";
    else if (c == '/') s += "~1";
    else s += c;
  }
  return s;
}

}  // namespace

void check_schema_keywords(const json& schema, const std::string& where) {
  static const std::set<std::string> known = {
      "type", "properties", "required", "additionalProperties", "enum", "const", "minimum", "maximum",
      "exclusiveMinimum", "exclusiveMaximum", "items", "minItems", "maxItems", "pattern", "default", "oneOf",
      "description", "title", "$schema", "$id", "examples", "x-meshflow-file"};
  if (!schema.is_object()) throw std::logic_error(where + ": a schema must be an object");
  for (auto& [k, v] : schema.items()) {
    if (!known.count(k)) throw std::logic_error(where + ": schema keyword '" + k + "' is not supported by meshflow's validator");
    if (k == "properties")
      for (auto& [pk, pv] : v.items()) check_schema_keywords(pv, where + "/properties/" + pk);
    if ((k == "items" || k == "additionalProperties") && v.is_object()) check_schema_keywords(v, where + "/" + k);
    if (k == "oneOf")
      for (size_t i = 0; i < v.size(); ++i) check_schema_keywords(v[i], where + "/oneOf/" + std::to_string(i));
  }
}

std::vector<SchemaIssue> validate_schema(json& v, const json& s, const std::map<std::string, std::string>* raw,
                                         const std::string& ptr) {
  std::vector<SchemaIssue> out;
  std::string desc = s.value("description", "");
  auto fail = [&](std::string msg) { out.push_back({ptr, std::move(msg), desc}); };

  // Plain YAML scalars where a string is expected become the text as written.
  if (raw && !v.is_string() && !v.is_object() && !v.is_array() && s.contains("type")) {
    bool wants_string = s["type"] == "string" ||
                        (s["type"].is_array() && std::find(s["type"].begin(), s["type"].end(), "string") != s["type"].end() &&
                         std::find(s["type"].begin(), s["type"].end(), type_name(v)) == s["type"].end());
    auto it = raw->find(ptr);
    if (wants_string && it != raw->end()) v = it->second;
  }

  if (s.contains("oneOf")) {
    std::vector<json> passing;
    std::vector<std::vector<SchemaIssue>> fails;
    for (auto& branch : s["oneOf"]) {
      json copy = v;
      auto issues = validate_schema(copy, branch, raw, ptr);
      if (issues.empty()) passing.push_back(std::move(copy));
      else fails.push_back(std::move(issues));
    }
    if (passing.size() == 1) v = std::move(passing[0]);
    else if (passing.empty()) {
      std::string why;
      for (auto& f : fails)
        if (!f.empty()) why += (why.empty() ? "" : "; or ") + f.front().message;
      fail("matches none of the allowed forms (" + why + ")");
      return out;
    } else {
      fail("is ambiguous: it matches " + std::to_string(passing.size()) + " of the allowed forms");
      return out;
    }
  }

  if (s.contains("type")) {
    bool ok = false;
    std::string expected;
    if (s["type"].is_array()) {
      for (auto& t : s["type"]) {
        expected += (expected.empty() ? "" : " or ") + t.get<std::string>();
        if (!ok) ok = matches_type(v, t);
      }
    } else {
      expected = s["type"].get<std::string>();
      ok = matches_type(v, expected);
    }
    if (!ok) {
      fail("must be " + (expected == "integer" ? std::string("an integer") : (expected == "object" || expected == "array") ? "an " + expected : "a " + expected) +
           ", got " + type_name(v) + " " + show(v));
      return out;
    }
  }
  if (s.contains("const") && v != s["const"]) fail("must be " + show(s["const"]) + ", got " + show(v));
  if (s.contains("enum")) {
    bool found = false;
    for (auto& e : s["enum"]) found = found || e == v;
    if (!found) {
      std::string list;
      for (auto& e : s["enum"]) list += (list.empty() ? "" : ", ") + e.dump();
      fail("is " + show(v) + ", not one of " + list);
    }
  }
  if (v.is_number()) {
    double x = v.get<double>();
    if (!std::isfinite(x)) fail("must be a finite number");
    if (s.contains("minimum") && x < s["minimum"].get<double>()) fail("is " + show(v) + ", below the minimum " + show(s["minimum"]));
    if (s.contains("maximum") && x > s["maximum"].get<double>()) fail("is " + show(v) + ", above the maximum " + show(s["maximum"]));
    if (s.contains("exclusiveMinimum") && x <= s["exclusiveMinimum"].get<double>())
      fail("is " + show(v) + ", must be greater than " + show(s["exclusiveMinimum"]));
    if (s.contains("exclusiveMaximum") && x >= s["exclusiveMaximum"].get<double>())
      fail("is " + show(v) + ", must be less than " + show(s["exclusiveMaximum"]));
  }
  if (v.is_string() && s.contains("pattern")) {
    std::regex re(s["pattern"].get<std::string>(), std::regex::ECMAScript);
    if (!std::regex_search(v.get<std::string>(), re))
      fail("is " + show(v) + ", which does not match the pattern " + s["pattern"].get<std::string>());
  }
  if (v.is_array()) {
    if (s.contains("minItems") && v.size() < s["minItems"].get<size_t>())
      fail("has " + std::to_string(v.size()) + " items, needs at least " + show(s["minItems"]));
    if (s.contains("maxItems") && v.size() > s["maxItems"].get<size_t>())
      fail("has " + std::to_string(v.size()) + " items, allows at most " + show(s["maxItems"]));
    if (s.contains("items") && s["items"].is_object())
      for (size_t i = 0; i < v.size(); ++i) {
        auto sub = validate_schema(v[i], s["items"], raw, ptr + "/" + std::to_string(i));
        out.insert(out.end(), sub.begin(), sub.end());
      }
  }
  if (v.is_object()) {
    const json empty = json::object();
    const json& props = s.contains("properties") ? s["properties"] : empty;
    if (s.contains("required"))
      for (auto& r : s["required"])
        if (!v.contains(r.get<std::string>())) {
          std::string rd = props.contains(r) ? props[r.get<std::string>()].value("description", "") : "";
          out.push_back({ptr + "/" + escape_token(r.get<std::string>()), "is required but missing", rd});
        }
    for (auto& [k, sub] : props.items())
      if (!v.contains(k) && sub.contains("default")) v[k] = sub["default"];
    for (auto& [k, val] : v.items()) {
      std::string p = ptr + "/" + escape_token(k);
      if (props.contains(k)) {
        auto sub = validate_schema(val, props[k], raw, p);
        out.insert(out.end(), sub.begin(), sub.end());
      } else if (s.contains("additionalProperties")) {
        const json& ap = s["additionalProperties"];
        if (ap.is_boolean() && !ap.get<bool>()) {
          std::string known;
          std::vector<std::string> names;
          for (auto& [pk, pv] : props.items()) {
            known += (known.empty() ? "" : ", ") + pk;
            names.push_back(pk);
          }
          std::string near = nearest_name(k, names);
          std::string msg = "is not a known parameter";
          if (!near.empty()) msg += "; did you mean '" + near + "'?";
          if (!known.empty()) msg += " (known: " + known + ")";
          out.push_back({p, msg, "", near});
        } else if (ap.is_object()) {
          auto sub = validate_schema(val, ap, raw, p);
          out.insert(out.end(), sub.begin(), sub.end());
        }
      }
    }
  }
  return out;
}

std::string nearest_name(const std::string& word, const std::vector<std::string>& known) {
  auto lower = [](std::string t) {
    for (auto& c : t) c = char(std::tolower(static_cast<unsigned char>(c)));
    return t;
  };
  const std::string w = lower(word);
  std::string best;
  size_t best_d = std::max<size_t>(2, w.size() / 3) + 1;
  for (auto& k : known) {
    const std::string c = lower(k);
    // Levenshtein distance, one row at a time.
    std::vector<size_t> row(c.size() + 1);
    for (size_t j = 0; j <= c.size(); ++j) row[j] = j;
    for (size_t i = 1; i <= w.size(); ++i) {
      size_t diag = row[0];
      row[0] = i;
      for (size_t j = 1; j <= c.size(); ++j) {
        size_t up = row[j];
        row[j] = std::min({row[j] + 1, row[j - 1] + 1, diag + (w[i - 1] == c[j - 1] ? 0 : 1)});
        diag = up;
      }
    }
    if (row[c.size()] < best_d) {
      best_d = row[c.size()];
      best = k;
    }
  }
  return best;
}

std::vector<std::string> file_parameters(const json& v, const json& s, const std::string& ptr) {
  std::vector<std::string> out;
  if (s.value("x-meshflow-file", false) && v.is_string()) out.push_back(ptr);
  if (v.is_object() && s.contains("properties"))
    for (auto& [k, sub] : s["properties"].items())
      if (v.contains(k)) {
        auto r = file_parameters(v[k], sub, ptr + "/" + escape_token(k));
        out.insert(out.end(), r.begin(), r.end());
      }
  if (v.is_array() && s.contains("items") && s["items"].is_object())
    for (size_t i = 0; i < v.size(); ++i) {
      auto r = file_parameters(v[i], s["items"], ptr + "/" + std::to_string(i));
      out.insert(out.end(), r.begin(), r.end());
    }
  if (s.contains("oneOf"))
    for (auto& b : s["oneOf"]) {
      json copy = v;
      if (validate_schema(copy, b).empty()) {
        auto r = file_parameters(v, b, ptr);
        out.insert(out.end(), r.begin(), r.end());
      }
    }
  return out;
}

}  // namespace meshflow
