#include "engine/golden.hpp"

#include "engine/artifact_type.hpp"

#include <cmath>
#include <set>

using nlohmann::json;

namespace meshflow {

json golden_summary(const Workflow& wf, const RunResult& run) {
  json outs = json::object();
  for (auto& od : wf.outputs) {
    for (auto& s : run.stages) {
      if (s.name != od.from || s.outputs.empty()) continue;
      const Artifact* a = &s.outputs.front();
      for (auto& o : s.outputs)
        if (o.name == od.artifact) a = &o;
      const ArtifactType* t = find_artifact_type(a->type);
      outs[od.name] = t && t->summarize ? t->summarize(a->path) : json{{"digest", a->digest}};
    }
  }
  return {{"outputs", outs}};
}

namespace {
void compare(const json& g, const json& o, const std::string& path, const GoldenDecl& tol, std::vector<std::string>& out) {
  if (g.is_object() && o.is_object()) {
    std::set<std::string> keys;
    for (auto& [k, v] : g.items()) keys.insert(k);
    for (auto& [k, v] : o.items()) keys.insert(k);
    for (auto& k : keys) {
      std::string p = path.empty() ? k : path + "." + k;
      if (!g.contains(k)) out.push_back(p + ": not in the golden, obtained " + o[k].dump());
      else if (!o.contains(k)) out.push_back(p + ": golden " + g[k].dump() + ", missing from the obtained summary");
      else compare(g[k], o[k], p, tol, out);
    }
    return;
  }
  if (g.is_array() && o.is_array() && g.size() == o.size()) {
    for (size_t i = 0; i < g.size(); ++i) compare(g[i], o[i], path + "[" + std::to_string(i) + "]", tol, out);
    return;
  }
  if (g.is_number() && o.is_number()) {
    double rel = tol.rel, abs = tol.abs;
    size_t best = 0;
    for (auto& [k, v] : tol.fields.items())
      if ((path == k || path.rfind(k + ".", 0) == 0 || path.rfind(k + "[", 0) == 0) && k.size() >= best) {
        best = k.size();
        rel = v.value("rel", rel);
        abs = v.value("abs", abs);
      }
    double a = g.get<double>(), b = o.get<double>();
    if (std::isnan(a) && std::isnan(b)) return;
    if (!(std::fabs(a - b) <= abs + rel * std::fabs(a)))
      out.push_back(path + ": golden " + g.dump() + ", obtained " + o.dump() + " (tolerance rel " + json(rel).dump() +
                    ", abs " + json(abs).dump() + ")");
    return;
  }
  if (g != o) out.push_back(path + ": golden " + g.dump() + ", obtained " + o.dump());
}
}  // namespace

std::vector<std::string> golden_compare(const json& golden, const json& obtained, const GoldenDecl& tol) {
  std::vector<std::string> out;
  compare(golden, obtained, "", tol, out);
  return out;
}

}  // namespace meshflow
