// meshflow mesh model — topology: unique edges and faces of the top-dimensional elements,
// face-to-element adjacency, conformity.
//
// "Faces" are the (d-1)-dimensional sides of the d-dimensional elements (faces of volume
// elements, edges of a 2D mesh). Faces are identified by their vertex nodes. Ordering is
// deterministic: faces and edges are sorted by their sorted vertex node indices.
// Conformity: a face of two elements must be a face of exactly two elements and both must
// have the same high-order face nodes (the same node indices); a face of three or more
// elements, or of two elements whose face nodes differ, is non-conforming.
#pragma once

#include "stages/model/mesh.hpp"

#include <array>
#include <cstdint>
#include <vector>

namespace meshflow::model {

struct ElementRef {
  std::uint32_t block = 0;
  std::uint32_t element = 0;  // index within the block
  std::uint32_t local = 0;    // local face (edge) number in the element's Gmsh table
};

struct TopoFace {
  std::array<std::uint32_t, 4> vertices{};  // sorted vertex node indices (unused: UINT32_MAX)
  int num_vertices = 0;
  std::vector<ElementRef> elements;  // 1 = boundary face, 2 = interior face
  bool conforming = true;
};

struct Topology {
  int dim = 0;  // dimension of the elements the faces belong to
  std::vector<std::array<std::uint32_t, 2>> edges;  // unique edges (sorted vertex pairs)
  std::vector<TopoFace> faces;
  std::size_t boundary_faces = 0;
  std::size_t nonconforming_faces = 0;
};

// Topology of the elements of the mesh's highest dimension (2 or 3).
Topology build_topology(const Mesh& m);

}  // namespace meshflow::model
