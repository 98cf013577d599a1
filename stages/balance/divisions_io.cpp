// The "divisions" artifact: one line of JSON (see balance.hpp), its reader and the artifact type.
#include "balance.hpp"

#include "engine/artifact_type.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <fstream>
#include <sstream>
#include <stdexcept>

namespace meshflow::balance {

const EdgeDivision* Divisions::find(const std::string& name) const {
  auto it = std::lower_bound(edges.begin(), edges.end(), name, [](const EdgeDivision& d, const std::string& n) { return d.name < n; });
  return it != edges.end() && it->name == name ? &*it : nullptr;
}

int Divisions::count(const std::string& name) const {
  if (const EdgeDivision* d = find(name)) return d->n;
  throw std::out_of_range("divisions: no edge named '" + name + "'");
}

nlohmann::json Divisions::summary() const {
  long total = 0;
  nlohmann::json per = nlohmann::json::object(), kinds = nlohmann::json::object();
  for (const EdgeDivision& d : edges) {
    total += d.n;
    per[d.name] = d.n;
    kinds[d.kind] = kinds.value(d.kind, 0L) + 1;
  }
  nlohmann::json s = {{"edges", edges.size()}, {"total_divisions", total}, {"edges_by_kind", kinds}, {"divisions", per}};
  nlohmann::json st = nlohmann::json::parse(stats_json);
  for (const char* k : {"total_deviation", "max_rel_deviation", "constraints"})
    if (st.contains(k)) s[k] = st[k];
  return s;
}

void write(const Divisions& d, const std::filesystem::path& file) {
  nlohmann::json h;
  h["format"] = "meshflow-divisions 1";
  h["units"] = d.units;
  h["params"] = nlohmann::json::parse(d.params_json);
  h["constraints"] = nlohmann::json::parse(d.constraints_json);
  h["stats"] = nlohmann::json::parse(d.stats_json);
  nlohmann::json E = nlohmann::json::array();
  for (const EdgeDivision& e : d.edges)
    E.push_back({{"name", e.name}, {"cad_edge", e.cad_edge}, {"kind", e.kind}, {"n", e.n}, {"target", e.target},
                 {"length", e.length}, {"param", e.param}, {"nodes", e.nodes}});
  h["edges"] = E;
  std::ofstream out(file, std::ios::binary);
  out << h.dump() << "\n";
  out.close();
  if (!out) throw StageError("balance: could not write the divisions artifact " + file.string() + " (disk full?)");
}

Divisions read(const std::filesystem::path& file) {
  std::ifstream in(file, std::ios::binary);
  if (!in) throw StageError("divisions: cannot open " + file.string() + "; re-run the balance stage");
  std::stringstream ss;
  ss << in.rdbuf();
  nlohmann::json h;
  try {
    h = nlohmann::json::parse(ss.str());
  } catch (const std::exception& e) {
    throw StageError("divisions: " + file.string() + " is not valid JSON (" + e.what() + "); re-run the balance stage");
  }
  if (!h.is_object() || h.value("format", "") != "meshflow-divisions 1")
    throw StageError("divisions: " + file.string() + " is not a divisions artifact (format 'meshflow-divisions 1' expected)");
  Divisions d;
  try {
    d.units = h.at("units").get<std::string>();
    d.params_json = h.at("params").dump();
    d.constraints_json = h.at("constraints").dump();
    d.stats_json = h.at("stats").dump();
    for (auto& e : h.at("edges")) {
      EdgeDivision x;
      x.name = e.at("name"), x.cad_edge = e.at("cad_edge"), x.kind = e.at("kind"), x.n = e.at("n");
      x.target = e.at("target"), x.length = e.at("length"), x.param = e.at("param");
      x.nodes = e.at("nodes").get<std::vector<double>>();
      if (x.n < 1 || x.nodes.size() != static_cast<std::size_t>(x.n) + 1)
        throw std::runtime_error("edge '" + x.name + "' has n = " + std::to_string(x.n) + " but " +
                                 std::to_string(x.nodes.size()) + " nodes");
      if (!d.edges.empty() && !(d.edges.back().name < x.name)) throw std::runtime_error("edges not sorted by name at '" + x.name + "'");
      d.edges.push_back(std::move(x));
    }
  } catch (const std::exception& e) {
    throw StageError("divisions: " + file.string() + " is inconsistent (" + e.what() + "); re-run the balance stage");
  }
  return d;
}

namespace {
ArtifactTypeRegistrar reg({
    .type = "divisions",
    .extension = ".mfdiv",
    .summary = "interval assignment: division count and node parameters per named block edge (JSON, meshflow-divisions 1)",
    .formats = {},
    .summarize = [](const std::filesystem::path& p) { return read(p).summary(); },
});
}  // namespace

}  // namespace meshflow::balance
