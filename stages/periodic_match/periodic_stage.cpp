// meshflow stage kind `periodic_match` (paper §III.E): the transform between the periodic sides of
// the healed shape and the pairing of their entities (periodic.hpp), checked against the edge
// divisions of balance when they are given: paired edges must have equal division counts.
#include "engine/stage.hpp"
#include "stages/balance/balance.hpp"
#include "stages/cad/cad.hpp"
#include "stages/periodic_match/periodic.hpp"

#include <nlohmann/json.hpp>

#include <chrono>
#include <cmath>

namespace meshflow::periodic {
namespace {

// The divisions entry of a CAD edge of a periodic face: "w<e>" when it is a wall edge, else "e<e>".
const balance::EdgeDivision* division_of(const balance::Divisions& d, int e) {
  if (const auto* w = d.find("w" + std::to_string(e))) return w;
  return d.find("e" + std::to_string(e));
}

nlohmann::json check_divisions(StageContext& ctx, const cad::Shape& shape, const Match& m, const balance::Divisions& d) {
  std::vector<std::string> bad, missing;
  double worst = 0;
  long checked = 0;
  for (const Pair& p : m.edges) {
    if (p.lo == p.hi) continue;  // an edge on both sides is its own partner
    const balance::EdgeDivision* a = division_of(d, p.lo);
    const balance::EdgeDivision* b = division_of(d, p.hi);
    if (!a || !b) {
      missing.push_back(std::to_string(a ? p.hi : p.lo));
      continue;
    }
    ++checked;
    if (a->n != b->n) {
      bad.push_back(a->name + " (" + std::to_string(a->n) + ") ~ " + b->name + " (" + std::to_string(b->n) + ")");
      continue;
    }
    // where the nodes land: lo's nodes carried by the transform against hi's (in hi's order)
    if (a->param != "cad" || b->param != "cad") continue;
    for (int k = 0; k <= a->n; ++k) {
      cad::Vec3 x = shape.edge_point(p.lo, a->nodes[k]);
      auto y = m.transform.apply({x.x, x.y, x.z});
      cad::Vec3 z = shape.edge_point(p.hi, b->nodes[p.reversed ? b->n - k : k]);
      worst = std::max(worst, std::hypot(y[0] - z.x, y[1] - z.y, y[2] - z.z));
    }
  }
  if (!missing.empty())
    throw StageError("periodic_match: the divisions artifact has no entry (w<e> or e<e>) for the periodic edge(s) " +
                     [&] { std::string s; for (auto& x : missing) s += (s.empty() ? "" : ", ") + x; return s; }() +
                     "; it was made for another shape or by an older balance: re-run balance on the same heal output");
  if (!bad.empty()) {
    std::string s;
    for (auto& x : bad) s += (s.empty() ? "" : "; ") + x;
    throw StageError("periodic_match: paired periodic edges have different division counts in the balance artifact: " + s +
                     "; balance must constrain them equal (its periodic constraints) — re-run balance on the same heal output");
  }
  ctx.log("periodic_match: " + std::to_string(checked) + " paired edges have equal divisions");
  return {{"checked", true},
          {"edge_pairs", checked},
          {"nodes_max_mismatch_rel", m.model_size > 0 ? worst / m.model_size : 0.0}};
}

void run(StageContext& ctx) {
  const double tol = ctx.params().at("tolerance").get<double>();
  ctx.progress(0, "loading the shape");
  cad::Shape shape = cad::Shape::load(ctx.input("shape").path);
  ctx.progress(0.1, "matching the periodic sides");
  auto t0 = std::chrono::steady_clock::now();
  Match m = find(shape, tol, [&](const std::string& l) { ctx.log(l); });
  double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  ctx.progress(0.8, "checking the divisions");
  nlohmann::json& st = ctx.stats();
  auto divs = ctx.inputs_of("divisions");
  if (!divs.empty()) {
    st["divisions"] = check_divisions(ctx, shape, m, balance::read(divs[0]->path));
  } else {
    ctx.log("periodic_match: no divisions input (no balance in needs): division counts not checked");
    st["divisions"] = {{"checked", false}};
  }
  nlohmann::json s = m.summary();
  for (auto& [k, v] : s.items())
    if (k != "face_pairs") st[k] = v;
  st["pairs"] = {{"faces", m.faces.size()}, {"edges", m.edges.size()}, {"vertices", m.vertices.size()}};
  st["face_mismatch_rel"] = m.face_mismatch / m.model_size;
  st["edge_mismatch_rel"] = m.edge_mismatch / m.model_size;
  st["vertex_mismatch_rel"] = m.vertex_mismatch / m.model_size;
  st["tolerance"] = tol;
  st["find_seconds"] = seconds;
  ctx.log("periodic_match: " + m.transform.kind + ", " + std::to_string(m.faces.size()) + " face, " + std::to_string(m.edges.size()) +
          " edge, " + std::to_string(m.vertices.size()) + " vertex pairs, max mismatch " + std::to_string(m.max_mismatch / m.model_size) +
          " of the model size");
  write(m, ctx.output("periodic", "periodic"));
  ctx.progress(1, "done");
}

StageRegistrar reg({.kind = "periodic_match",
                    .version = 1,
                    .summary = "find the rotation/translation mapping periodic_lo onto periodic_hi, pair their faces, edges and vertices, check equal divisions",
                    .libraries = {},
                    .needs = {"shape"},
                    .reads = {"divisions"},
                    .produces = {{"periodic", "periodic"}},
                    .run = run});

}  // namespace
}  // namespace meshflow::periodic
