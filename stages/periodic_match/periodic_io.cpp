// The "periodic" artifact: one line of JSON (see periodic.hpp), its reader, its summary and the
// artifact type.
#include "stages/periodic_match/periodic.hpp"

#include "engine/artifact_type.hpp"
#include "engine/stage.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <sstream>

namespace meshflow::periodic {
namespace {

nlohmann::json pairs_json(const std::vector<Pair>& v) {
  nlohmann::json a = nlohmann::json::array();
  for (const Pair& p : v) a.push_back({p.lo, p.hi, p.reversed});
  return a;
}
std::vector<Pair> pairs_from(const nlohmann::json& a, const char* what) {
  std::vector<Pair> v;
  for (auto& p : a) {
    if (!p.is_array() || p.size() != 3) throw std::runtime_error(std::string(what) + ": a pair is not [lo, hi, reversed]");
    v.push_back({p[0].get<int>(), p[1].get<int>(), p[2].get<bool>()});
    if (v.back().lo < 0 || v.back().hi < 0) throw std::runtime_error(std::string(what) + ": negative id");
    if (v.size() > 1 && !(v[v.size() - 2].lo < v.back().lo)) throw std::runtime_error(std::string(what) + ": not sorted by lo");
  }
  return v;
}

}  // namespace

nlohmann::json Match::summary() const {
  const Transform& T = transform;
  nlohmann::json s = {{"kind", T.kind},
                      {"faces", faces.size()},
                      {"edges", edges.size()},
                      {"vertices", vertices.size()},
                      {"model_size", model_size},
                      {"max_mismatch_rel", model_size > 0 ? max_mismatch / model_size : 0.0},
                      {"snapped", T.snapped}};
  if (T.kind == "rotation") {
    s["axis_point"] = T.axis_point;
    s["axis_dir"] = T.axis_dir;
    s["angle_deg"] = T.angle * 180 / M_PI;
    s["sectors"] = T.angle != 0 ? 2 * M_PI / std::abs(T.angle) : 0.0;
  } else {
    s["translation"] = T.translation;
  }
  nlohmann::json F = nlohmann::json::array();
  for (const Pair& p : faces) F.push_back({p.lo, p.hi});
  s["face_pairs"] = F;
  return s;
}

void write(const Match& m, const std::filesystem::path& file) {
  const Transform& T = m.transform;
  nlohmann::json h;
  h["format"] = "meshflow-periodic 1";
  h["units"] = m.units;
  h["transform"] = {{"kind", T.kind},       {"axis_point", T.axis_point},   {"axis_dir", T.axis_dir}, {"angle", T.angle},
                    {"translation", T.translation}, {"affine", T.affine}, {"snapped", T.snapped}};
  h["faces"] = pairs_json(m.faces);
  h["edges"] = pairs_json(m.edges);
  h["vertices"] = pairs_json(m.vertices);
  h["model_size"] = m.model_size;
  h["max_mismatch"] = m.max_mismatch;
  h["face_mismatch"] = m.face_mismatch;
  h["edge_mismatch"] = m.edge_mismatch;
  h["vertex_mismatch"] = m.vertex_mismatch;
  std::ofstream out(file, std::ios::binary);
  out << h.dump() << "\n";
  out.close();
  if (!out) throw StageError("periodic_match: could not write the periodic artifact " + file.string() + " (disk full?)");
}

Match read(const std::filesystem::path& file) {
  std::ifstream in(file, std::ios::binary);
  if (!in) throw StageError("periodic: cannot open " + file.string() + "; re-run the periodic_match stage");
  std::stringstream ss;
  ss << in.rdbuf();
  nlohmann::json h;
  try {
    h = nlohmann::json::parse(ss.str());
  } catch (const std::exception& e) {
    throw StageError("periodic: " + file.string() + " is not valid JSON (" + e.what() + "); re-run the periodic_match stage");
  }
  if (!h.is_object() || h.value("format", "") != "meshflow-periodic 1")
    throw StageError("periodic: " + file.string() + " is not a periodic artifact (format 'meshflow-periodic 1' expected)");
  Match m;
  try {
    m.units = h.at("units").get<std::string>();
    const auto& t = h.at("transform");
    Transform& T = m.transform;
    T.kind = t.at("kind").get<std::string>();
    if (T.kind != "rotation" && T.kind != "translation") throw std::runtime_error("unknown transform kind '" + T.kind + "'");
    T.axis_point = t.at("axis_point").get<std::array<double, 3>>();
    T.axis_dir = t.at("axis_dir").get<std::array<double, 3>>();
    T.angle = t.at("angle").get<double>();
    T.translation = t.at("translation").get<std::array<double, 3>>();
    T.affine = t.at("affine").get<std::array<double, 16>>();
    T.snapped = t.at("snapped").get<bool>();
    m.faces = pairs_from(h.at("faces"), "faces");
    m.edges = pairs_from(h.at("edges"), "edges");
    m.vertices = pairs_from(h.at("vertices"), "vertices");
    m.model_size = h.at("model_size").get<double>();
    m.max_mismatch = h.at("max_mismatch").get<double>();
    m.face_mismatch = h.at("face_mismatch").get<double>();
    m.edge_mismatch = h.at("edge_mismatch").get<double>();
    m.vertex_mismatch = h.at("vertex_mismatch").get<double>();
  } catch (const std::exception& e) {
    throw StageError("periodic: " + file.string() + " is inconsistent (" + e.what() + "); re-run the periodic_match stage");
  }
  return m;
}

namespace {
ArtifactTypeRegistrar reg({
    .type = "periodic",
    .extension = ".mfper",
    .summary = "periodic match: the rotation/translation periodic_lo -> periodic_hi and the paired faces, edges and vertices (JSON, meshflow-periodic 1)",
    .formats = {},
    .summarize = [](const std::filesystem::path& p) { return read(p).summary(); },
});
}  // namespace

}  // namespace meshflow::periodic
