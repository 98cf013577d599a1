// What solvers' MSH importers need of a mesh (mesh_io.hpp: make_solver_ready, apply_pyfr_names).
#include "stages/io/mesh_io.hpp"

#include <algorithm>
#include <map>
#include <set>

namespace meshflow::io {

using model::Mesh;

namespace {

// The tag of the physical group `name` of dimension `dim`, made (with a tag no group of any
// dimension uses) when absent.
int group_tag(Mesh& m, int dim, const std::string& name) {
  int top = 0;
  for (auto& p : m.physicals) {
    if (p.dim == dim && p.name == name) return p.tag;
    top = std::max(top, p.tag);
  }
  m.add_physical(dim, top + 1, name);
  return top + 1;
}

}  // namespace

void make_solver_ready(Mesh& m, bool keep_parametric) {
  if (!keep_parametric) m.node_u.clear(), m.node_v.clear();
  std::set<std::pair<int, int>> grouped;  // (dim, tag) of entities in a physical group
  for (auto& e : m.entities)
    if (!e.physicals.empty()) grouped.insert({e.dim, e.tag});
  if (m.physicals.empty() && grouped.empty()) return;  // no groups at all: every element stays
  int top = 0;  // the dimension of the volume elements
  for (auto& b : m.blocks)
    if (b.size()) top = std::max(top, b.entity_dim);
  std::set<int> ungrouped_volumes;
  for (auto& b : m.blocks)
    if (b.size() && b.entity_dim == top && !grouped.count({b.entity_dim, b.entity_tag})) ungrouped_volumes.insert(b.entity_tag);
  if (!ungrouped_volumes.empty()) {
    const int g = group_tag(m, top, "fluid");
    for (int t : ungrouped_volumes) {
      bool found = false;
      for (auto& e : m.entities)
        if (e.dim == top && e.tag == t) e.physicals.push_back(g), found = true;
      if (!found) m.add_entity(top, t, {g});
      grouped.insert({top, t});
    }
  }
  std::erase_if(m.blocks, [&](const model::ElementBlock& b) { return !grouped.count({b.entity_dim, b.entity_tag}); });
}

void apply_pyfr_names(Mesh& m) {
  // unique tags across dimensions: a tag seen before (in (dim, tag) order) gets a fresh one
  std::sort(m.physicals.begin(), m.physicals.end(),
            [](auto& a, auto& b) { return std::tie(a.dim, a.tag) < std::tie(b.dim, b.tag); });
  int top = 0;
  for (auto& p : m.physicals) top = std::max(top, p.tag);
  std::set<int> seen;
  std::map<std::pair<int, int>, int> renamed;  // (dim, old tag) -> new tag
  for (auto& p : m.physicals) {
    if (seen.insert(p.tag).second) continue;
    renamed[{p.dim, p.tag}] = ++top;
    p.tag = top;
    seen.insert(top);
  }
  for (auto& e : m.entities)
    for (int& t : e.physicals)
      if (auto it = renamed.find({e.dim, t}); it != renamed.end()) t = it->second;
  for (auto& p : m.physicals) {
    if (p.name == "periodic_lo") p.name = "periodic_0_l";
    else if (p.name == "periodic_hi") p.name = "periodic_0_r";
  }
}

}  // namespace meshflow::io
