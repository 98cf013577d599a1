// Internal: the parts of a Nektar++ XML file meshflow reads, as read from either form of its
// sections (plain text or B64Z-compressed, stages/io/nektar_b64z.hpp): the XML tree (expat),
// then VERTEX, EDGE, FACE, ELEMENT and CURVED as ids, coordinates and point sets (Geo).
// read_nektar (nektar_read.cpp) builds the mesh from a Geo.
#pragma once

#include "stages/model/mesh.hpp"

#include <map>
#include <memory>
#include <string>
#include <vector>

namespace meshflow::io::nektar {

struct Node {
  std::string name;
  std::map<std::string, std::string> attr;
  std::string text;
  long line = 0;
  std::vector<std::unique_ptr<Node>> kids;
  const Node* child(const std::string& n) const {
    for (auto& k : kids)
      if (k->name == n) return k.get();
    return nullptr;
  }
};

std::unique_ptr<Node> parse_xml(const std::string& path, const std::string& data);
[[noreturn]] void fail(const std::string& path, const Node* n, const std::string& what);
std::vector<double> numbers(const std::string& path, const Node* n);
long id_of(const std::string& path, const Node* n);

struct Geo {
  std::map<long, model::Vec3> V;
  std::map<long, std::array<long, 2>> E;
  std::map<long, std::vector<long>> F;  // edges
  struct Curve {
    std::string type;  // Nektar++'s point set name (PolyEvenlySpaced, ...)
    int n = 0;
    std::vector<double> xyz;
    const Node* node = nullptr;  // where it was read (for messages)
  };
  std::map<long, Curve> CE, CF;
  struct Element {
    long id = 0;
    std::string letter;       // T, Q (2D); A, P, R, H (3D)
    std::vector<long> sides;  // edge (2D) or face (3D) ids
    const Node* node = nullptr;
  };
  std::vector<Element> elements;  // in file order
  int order = 1;                  // from the CURVED edges' point counts
};

// Reads VERTEX, EDGE, FACE (3D), CURVED and ELEMENT of <GEOMETRY>, plain or compressed (each
// section by its own COMPRESSED attribute), checking that every id referred to is defined.
Geo read_sections(const std::string& path, const Node* geometry, int dim);

}  // namespace meshflow::io::nektar
