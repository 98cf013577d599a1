#include "stages/model/mesh.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace meshflow::model {

std::size_t Mesh::num_elements() const {
  std::size_t n = 0;
  for (auto& b : blocks) n += b.size();
  return n;
}

int Mesh::dimension() const {
  int d = 0;
  for (auto& b : blocks)
    if (b.size()) d = std::max(d, model::dimension(b.shape));
  return d;
}

int Mesh::order() const {
  int d = dimension(), p = 0;
  for (auto& b : blocks)
    if (b.size() && model::dimension(b.shape) == d) p = std::max(p, b.order);
  return p;
}

std::uint32_t Mesh::add_node(double px, double py, double pz) {
  x.push_back(px);
  y.push_back(py);
  z.push_back(pz);
  if (!node_entity_dim.empty()) {
    node_entity_dim.push_back(-1);
    node_entity_tag.push_back(-1);
  }
  if (!node_u.empty()) {
    node_u.push_back(NAN);
    node_v.push_back(NAN);
  }
  if (!node_tags.empty()) node_tags.push_back(node_tags.empty() ? 1 : *std::max_element(node_tags.begin(), node_tags.end()) + 1);
  return static_cast<std::uint32_t>(x.size() - 1);
}

ElementBlock& Mesh::block(Shape s, int order, int entity_dim, int entity_tag) {
  for (auto& b : blocks)
    if (b.shape == s && b.order == order && b.entity_dim == entity_dim && b.entity_tag == entity_tag)
      return b;
  ElementBlock b;
  b.shape = s;
  b.order = order;
  b.entity_dim = entity_dim;
  b.entity_tag = entity_tag;
  blocks.push_back(std::move(b));
  return blocks.back();
}

Entity& Mesh::add_entity(int dim, int tag, std::vector<int> phys) {
  for (auto& e : entities)
    if (e.dim == dim && e.tag == tag) {
      for (int p : phys)
        if (std::find(e.physicals.begin(), e.physicals.end(), p) == e.physicals.end()) e.physicals.push_back(p);
      return e;
    }
  Entity e;
  e.dim = dim;
  e.tag = tag;
  e.physicals = std::move(phys);
  entities.push_back(std::move(e));
  return entities.back();
}

void Mesh::add_physical(int dim, int tag, std::string name) {
  for (auto& p : physicals)
    if (p.dim == dim && p.tag == tag) {
      p.name = std::move(name);
      return;
    }
  physicals.push_back({dim, tag, std::move(name)});
}

const Entity* Mesh::find_entity(int dim, int tag) const {
  for (auto& e : entities)
    if (e.dim == dim && e.tag == tag) return &e;
  return nullptr;
}

std::string Mesh::group_name(int entity_dim, int entity_tag) const {
  const Entity* e = find_entity(entity_dim, entity_tag);
  if (!e) return {};
  for (int pt : e->physicals)
    for (auto& p : physicals)
      if (p.dim == entity_dim && p.tag == pt) return p.name;
  return {};
}

void Mesh::check() const {
  const std::size_t n = x.size();
  if (y.size() != n || z.size() != n) throw std::invalid_argument("mesh: coordinate arrays differ in size");
  if (!node_entity_dim.empty() && (node_entity_dim.size() != n || node_entity_tag.size() != n))
    throw std::invalid_argument("mesh: node classification arrays differ in size from the node count");
  if (!node_u.empty() && (node_u.size() != n || node_v.size() != n))
    throw std::invalid_argument("mesh: parametric coordinate arrays differ in size from the node count");
  if (!node_tags.empty() && node_tags.size() != n)
    throw std::invalid_argument("mesh: node tag array differs in size from the node count");
  for (std::size_t i = 0; i < n; ++i)
    if (!std::isfinite(x[i]) || !std::isfinite(y[i]) || !std::isfinite(z[i]))
      throw std::invalid_argument("mesh: node " + std::to_string(node_tag(i)) + " has a non-finite coordinate");
  for (std::size_t bi = 0; bi < blocks.size(); ++bi) {
    const auto& b = blocks[bi];
    if (b.order < 1 || b.order > kMaxOrder) throw std::invalid_argument("mesh: block " + std::to_string(bi) + " has order " + std::to_string(b.order));
    if (b.nodes.size() % b.nodes_per_element())
      throw std::invalid_argument("mesh: block " + std::to_string(bi) + " connectivity is not a multiple of " +
                                  std::to_string(b.nodes_per_element()));
    if (!b.tags.empty() && b.tags.size() != b.size())
      throw std::invalid_argument("mesh: block " + std::to_string(bi) + " tag count differs from its element count");
    for (std::size_t k = 0; k < b.nodes.size(); ++k)
      if (b.nodes[k] >= n)
        throw std::invalid_argument("mesh: block " + std::to_string(bi) + " element " +
                                    std::to_string(k / b.nodes_per_element()) + " refers to node index " +
                                    std::to_string(b.nodes[k]) + " but the mesh has " + std::to_string(n) + " nodes");
  }
  for (auto& l : periodic)
    for (auto [s, m] : l.nodes)
      if (s >= n || m >= n) throw std::invalid_argument("mesh: periodic link refers to a node out of range");
}

}  // namespace meshflow::model
