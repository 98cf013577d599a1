// meshflow mesh model — element shapes, Gmsh element types, node layouts.
//
// Internal node layout: the element's nodes are equispaced (the layout of Gmsh's complete
// Lagrange elements) and ordered exactly as Gmsh orders them (vertices, edge nodes edge by
// edge, face nodes face by face, interior nodes recursively), on Gmsh's reference elements:
//   line [-1,1]; triangle/tet: unit simplex; quad/hex [-1,1]^d; prism: unit triangle x [-1,1];
//   pyramid: base [-1,1]^2 at z=0, apex (0,0,1).
// Keeping Gmsh's layout internally makes MSH IO a copy; other formats permute (vtk_permutation).
//
// Each node is identified by an integer lattice point (i,j,k) of the element of order P; the
// lattice is the "monomial" index Gmsh uses to generate its points (for the pyramid k counts
// layers from the apex: k=P is the base).
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <vector>

namespace meshflow::model {

enum class Shape : std::uint8_t { Point = 0, Line, Tri, Quad, Tet, Prism, Pyramid, Hex };
inline constexpr int kNumShapes = 8;
inline constexpr int kMaxOrder = 10;  // model limit (Gmsh types are known for orders 1..6)

using Lattice = std::array<int, 3>;
using Vec3 = std::array<double, 3>;

int dimension(Shape s);
int num_vertices(Shape s);
int num_nodes(Shape s, int order);
const char* shape_name(Shape s);  // "tet", "prism", ...
bool shape_from_name(const std::string& name, Shape& out);

// Gmsh element type number of a complete Lagrange element (0 if Gmsh has none).
int gmsh_type(Shape s, int order);
// Inverse of gmsh_type; false for unknown or unsupported (serendipity, polygons, ...) types.
bool from_gmsh_type(int type, Shape& s, int& order);

// Node layout in Gmsh order (cached, thread-safe after first use).
const std::vector<Lattice>& lattice(Shape s, int order);
const std::vector<Vec3>& reference_nodes(Shape s, int order);
Vec3 lattice_to_reference(Shape s, int order, const Lattice& l);

// Gmsh topology tables: local vertices of edges and faces (faces outward oriented).
const std::vector<std::array<int, 2>>& edge_vertices(Shape s);
const std::vector<std::vector<int>>& face_vertices(Shape s);  // 3 or 4 entries each
// Local node indices of edge e (in Gmsh line order: v0, v1, interior) and of face f (in
// Gmsh triangle/quad order of the face seen from its vertices face_vertices(s)[f]).
const std::vector<std::vector<int>>& edge_nodes(Shape s, int order);
const std::vector<std::vector<int>>& face_nodes(Shape s, int order);

// VTK: cell type (linear types at order 1, Lagrange types above; 0 if VTK 9.1 cannot hold
// it) and vtk_to_gmsh[i] = Gmsh local index of VTK point i.
int vtk_cell_type(Shape s, int order);
const std::vector<int>& vtk_to_gmsh(Shape s, int order);
bool from_vtk_cell_type(int vtk_type, int num_points, Shape& s, int& order);

}  // namespace meshflow::model
