// meshflow mesh model — the Mesh every meshing stage reads and writes.
//
// Nodes are a structure of arrays. Elements are grouped in blocks of one shape and order on
// one geometric entity (Gmsh's model: an entity is a CAD point/curve/surface/volume by
// dimension and tag). Boundary faces are the 2D blocks: their entity tag is the CAD face id,
// and the entity's physical groups give the boundary name ("wall", "farfield", ...).
// Node tags and element tags are implicit (index + 1) unless the optional tag arrays are
// filled (readers keep the file's tags so that messages and cross-checks can name them).
//
// Building a mesh (e.g. in a stage):
//   Mesh m;
//   uint32_t a = m.add_node(0, 0, 0), ...;
//   m.add_physical(3, 1, "fluid"); m.add_entity(3, 1, {1});
//   ElementBlock& tets = m.block(Shape::Tet, 4, 3, 1);   // shape, order, entity dim, tag
//   tets.add({a, b, c, ...});                             // 35 node indices, Gmsh order
#pragma once

#include "stages/model/element.hpp"

#include <cmath>
#include <cstdint>
#include <initializer_list>
#include <limits>
#include <string>
#include <vector>

namespace meshflow::model {

struct ElementBlock {
  Shape shape = Shape::Tet;
  int order = 1;
  int entity_dim = 3;
  int entity_tag = 1;
  std::vector<std::uint32_t> nodes;  // 0-based node indices, nodes_per_element() per element
  std::vector<std::uint64_t> tags;   // optional element tags (empty: implicit)

  int nodes_per_element() const { return num_nodes(shape, order); }
  std::size_t size() const { return nodes.size() / static_cast<std::size_t>(nodes_per_element()); }
  const std::uint32_t* element(std::size_t e) const { return nodes.data() + e * nodes_per_element(); }
  void add(std::initializer_list<std::uint32_t> n) { nodes.insert(nodes.end(), n); }
  void add(const std::uint32_t* n) { nodes.insert(nodes.end(), n, n + nodes_per_element()); }
};

struct PhysicalGroup {
  int dim = 0;
  int tag = 0;
  std::string name;
};

struct Entity {
  int dim = 0;
  int tag = 0;
  std::vector<int> physicals;  // physical group tags (of the same dimension)
  std::vector<int> boundary;   // signed tags of bounding entities (dim - 1), as in MSH 4.1
  double bbox[6] = {NAN, NAN, NAN, NAN, NAN, NAN};  // min xyz, max xyz (a point: xyz twice)
};

struct PeriodicLink {
  int dim = 0;
  int tag = 0;         // slave entity
  int master_tag = 0;  // master entity
  std::vector<double> affine;  // 16 entries (row-major 4x4) or empty
  std::vector<std::pair<std::uint32_t, std::uint32_t>> nodes;  // (slave, master) node indices
};

struct Mesh {
  // --- nodes (structure of arrays) ---
  std::vector<double> x, y, z;
  // CAD classification of each node (empty: unclassified) and parametric coordinates on it
  // (empty: none; NaN where a node has none; v is NaN for nodes on curves).
  std::vector<int> node_entity_dim, node_entity_tag;
  std::vector<double> node_u, node_v;
  std::vector<std::uint64_t> node_tags;  // optional

  std::vector<ElementBlock> blocks;
  std::vector<Entity> entities;
  std::vector<PhysicalGroup> physicals;
  std::vector<PeriodicLink> periodic;

  std::size_t num_nodes() const { return x.size(); }
  std::size_t num_elements() const;
  // Highest dimension of any element (0 for an empty mesh).
  int dimension() const;
  // Highest order of the elements of the highest dimension.
  int order() const;
  std::uint64_t node_tag(std::size_t i) const { return node_tags.empty() ? i + 1 : node_tags[i]; }

  std::uint32_t add_node(double px, double py, double pz);
  // The block of (shape, order, entity) — created at the end if absent.
  ElementBlock& block(Shape s, int order, int entity_dim, int entity_tag);
  Entity& add_entity(int dim, int tag, std::vector<int> physicals = {});
  void add_physical(int dim, int tag, std::string name);
  const Entity* find_entity(int dim, int tag) const;
  // Name of the first physical group of the entity ("" if none).
  std::string group_name(int entity_dim, int entity_tag) const;
  bool has_parametric() const { return !node_u.empty(); }

  // Throws std::invalid_argument naming the first inconsistency: node index out of range,
  // non-finite coordinate, array sizes, entity/physical references, duplicate tags.
  void check() const;
};

}  // namespace meshflow::model
