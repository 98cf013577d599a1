// Variants of a workflow's `matrix:` (matrix.hpp).
#include "engine/matrix.hpp"

#include "engine/fsutil.hpp"

#include <algorithm>
#include <cctype>
#include <chrono>
#include <cstdio>
#include <iomanip>
#include <iostream>
#include <set>
#include <sstream>

namespace meshflow {

namespace fs = std::filesystem;
using json = nlohmann::json;

namespace {

// A value as it appears in a folder name: strings without their quotes, every character but
// letters, digits, '.', '+' and '-' as '_'.
std::string value_label(const std::string& json_text) {
  std::string v = json_text;
  if (v.size() >= 2 && v.front() == '"' && v.back() == '"') v = v.substr(1, v.size() - 2);
  for (char& c : v)
    if (!std::isalnum(static_cast<unsigned char>(c)) && c != '.' && c != '+' && c != '-') c = '_';
  return v.empty() ? "_" : v;
}

// The label of each key: its last component ("order" of curve.order) unless two keys share it.
std::vector<std::string> key_labels(const Workflow& wf) {
  std::vector<std::string> last;
  for (auto& [key, values] : wf.matrix) last.push_back(key.substr(key.rfind('.') + 1));
  std::vector<std::string> out;
  for (std::size_t i = 0; i < last.size(); ++i)
    out.push_back(std::count(last.begin(), last.end(), last[i]) > 1 ? wf.matrix[i].first : last[i]);
  return out;
}

// The figures of a variant's delivered mesh: the last stage (in run order) with mesh stats.
json mesh_figures(const RunResult& rr) {
  for (auto it = rr.stages.rbegin(); it != rr.stages.rend(); ++it) {
    if (!it->stats.contains("mesh") || !it->stats["mesh"].is_object()) continue;
    const json& m = it->stats["mesh"];
    json f = {{"stage", it->name}};
    long elements = 0;
    if (m.contains("elements") && m["elements"].is_object())
      for (auto& [type, n] : m["elements"].items())
        if (n.is_number()) elements += n.get<long>();
    f["elements"] = elements;
    for (const char* k : {"order", "nodes", "invalid", "min_scaled_jacobian", "max_aspect_ratio"})
      if (m.contains(k) && m[k].is_number()) f[k] = m[k];
    return f;
  }
  return json::object();
}

void print_table(std::ostream& out, const json& table) {
  out << "\nmatrix: " << table.size() << " variants\n"
      << std::left << std::setw(28) << "variant" << std::setw(9) << "status" << std::right << std::setw(5) << "ran"
      << std::setw(8) << "cached" << std::setw(9) << "seconds" << std::setw(11) << "elements" << std::setw(9) << "invalid"
      << std::setw(10) << "min SJ" << std::setw(10) << "max AR" << "\n";
  for (auto& v : table) {
    const json& m = v["mesh"];
    char sj[32] = "-", ar[32] = "-";
    if (m.contains("min_scaled_jacobian")) std::snprintf(sj, sizeof sj, "%.3g", m["min_scaled_jacobian"].get<double>());
    if (m.contains("max_aspect_ratio")) std::snprintf(ar, sizeof ar, "%.3g", m["max_aspect_ratio"].get<double>());
    out << std::left << std::setw(28) << v["variant"].get<std::string>() << std::setw(9) << v["status"].get<std::string>()
        << std::right << std::setw(5) << v["ran"].get<int>() << std::setw(8) << v["cached"].get<int>() << std::setw(9)
        << std::fixed << std::setprecision(1) << v["seconds"].get<double>() << std::setw(11)
        << (m.contains("elements") ? std::to_string(m["elements"].get<long>()) : "-") << std::setw(9)
        << (m.contains("invalid") ? std::to_string(m["invalid"].get<long>()) : "-") << std::setw(10) << sj << std::setw(10) << ar
        << "\n";
    out.unsetf(std::ios::fixed);
  }
}

}  // namespace

std::vector<Variant> matrix_variants(const Workflow& wf) {
  std::vector<Variant> out;
  if (wf.matrix.empty()) return out;
  const auto labels = key_labels(wf);
  std::vector<std::size_t> at(wf.matrix.size(), 0);  // odometer over the values, last key fastest
  std::set<std::string> names;
  while (true) {
    Variant v;
    for (std::size_t k = 0; k < wf.matrix.size(); ++k) {
      const auto& [key, values] = wf.matrix[k];
      v.overrides.push_back(key + "=" + values[at[k]]);
      v.name += (k ? "_" : "") + labels[k] + "-" + value_label(values[at[k]]);
    }
    // two values alike once made names ("a b" and "a_b"): numbered, still deterministic
    if (!names.insert(v.name).second) v.name += "." + std::to_string(out.size());
    names.insert(v.name);
    out.push_back(std::move(v));
    std::size_t k = wf.matrix.size();
    while (k > 0 && ++at[k - 1] == wf.matrix[k - 1].second.size()) at[--k] = 0;
    if (k == 0) break;
  }
  return out;
}

const Variant& find_variant(const std::vector<Variant>& variants, const std::string& name, const Workflow& wf) {
  std::string names;
  for (auto& v : variants) {
    if (v.name == name) return v;
    names += (names.empty() ? "" : ", ") + v.name;
  }
  throw WorkflowError(wf.file.string() + ": " +
                      (variants.empty() ? "the workflow has no `matrix:`, so no variant '" + name + "'. Drop --variant."
                                        : "no variant '" + name + "' in its matrix; the variants are: " + names + "."));
}

MatrixResult run_matrix(const Workflow& base, const std::vector<std::string>& sets, const RunOptions& options,
                        const std::string& only) {
  const auto variants = matrix_variants(base);
  for (auto& s : sets)
    for (auto& [key, values] : base.matrix)
      if (s.rfind(key + "=", 0) == 0)
        throw WorkflowError("--set " + s + ": the workflow's matrix varies " + key +
                            "; change its values in the matrix, or pick one variant with --variant.");
  // every variant loaded first: a value its parameter's schema refuses stops the study before
  // anything runs
  std::vector<std::pair<const Variant*, Workflow>> todo;
  for (auto& v : variants) {
    if (!only.empty() && v.name != only) continue;
    std::vector<std::string> o = sets;
    o.insert(o.end(), v.overrides.begin(), v.overrides.end());
    try {
      todo.emplace_back(&v, load_workflow(base.file, o));
    } catch (const WorkflowError& e) {
      throw WorkflowError("matrix variant " + v.name + ": " + e.what());
    }
  }
  if (todo.empty()) find_variant(variants, only, base);  // throws with the list
  std::ostream& out = options.out ? *options.out : std::cout;
  const fs::path root = options.out_dir.empty() ? fs::current_path() / "out" / base.name : options.out_dir;
  MatrixResult res;
  for (std::size_t i = 0; i < todo.size(); ++i) {
    auto& [v, wf] = todo[i];
    out << "\n== variant " << (i + 1) << "/" << todo.size() << ": " << v->name << "\n" << std::flush;
    RunOptions ro = options;
    ro.out_dir = root / v->name;
    const auto t0 = std::chrono::steady_clock::now();
    RunResult rr = run_workflow(wf, ro);
    const double secs = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    int ran = 0, cached = 0;
    for (auto& s : rr.stages) {
      ran += s.status == "ran" || (s.status == "invalid" && s.computed == "ran");
      cached += s.status == "cached" || (s.status == "invalid" && s.computed == "cached");
    }
    res.ok = res.ok && rr.ok;
    res.invalid = res.invalid || rr.invalid;
    res.failed = res.failed || rr.failed;
    res.bad_input = res.bad_input || rr.bad_input;
    res.table.push_back({{"variant", v->name},
                         {"overrides", v->overrides},
                         {"status", rr.ok ? "ok" : rr.failed ? "failed" : "invalid"},
                         {"out", (root / v->name).string()},
                         {"ran", ran},
                         {"cached", cached},
                         {"seconds", secs},
                         {"mesh", mesh_figures(rr)}});
  }
  print_table(out, res.table);
  if (options.materialise) {
    json doc = {{"workflow", base.file.string()}, {"name", base.name}, {"variants", res.table}};
    fs::create_directories(root);
    atomic_write(root / "matrix.json", doc.dump(2) + "\n");
    out << "matrix: " << (root / "matrix.json").string() << "\n";
  }
  return res;
}

}  // namespace meshflow
