#include "stages/model/element.hpp"

#include <algorithm>
#include <map>
#include <stdexcept>

namespace meshflow::model {

namespace {

// ---- Gmsh topology tables (as defined in Gmsh's MElement classes) ----
const std::vector<std::array<int, 2>> kEdgesLine = {{0, 1}};
const std::vector<std::array<int, 2>> kEdgesTri = {{0, 1}, {1, 2}, {2, 0}};
const std::vector<std::array<int, 2>> kEdgesQuad = {{0, 1}, {1, 2}, {2, 3}, {3, 0}};
const std::vector<std::array<int, 2>> kEdgesTet = {{0, 1}, {1, 2}, {2, 0}, {3, 0}, {3, 2}, {3, 1}};
const std::vector<std::array<int, 2>> kEdgesHex = {{0, 1}, {0, 3}, {0, 4}, {1, 2}, {1, 5}, {2, 3},
                                                   {2, 6}, {3, 7}, {4, 5}, {4, 7}, {5, 6}, {6, 7}};
const std::vector<std::array<int, 2>> kEdgesPrism = {{0, 1}, {0, 2}, {0, 3}, {1, 2}, {1, 4},
                                                     {2, 5}, {3, 4}, {3, 5}, {4, 5}};
const std::vector<std::array<int, 2>> kEdgesPyr = {{0, 1}, {0, 3}, {0, 4}, {1, 2},
                                                   {1, 4}, {2, 3}, {2, 4}, {3, 4}};
const std::vector<std::vector<int>> kFacesNone = {};
const std::vector<std::vector<int>> kFacesTri = {{0, 1, 2}};
const std::vector<std::vector<int>> kFacesQuad = {{0, 1, 2, 3}};
const std::vector<std::vector<int>> kFacesTet = {{0, 2, 1}, {0, 1, 3}, {0, 3, 2}, {3, 1, 2}};
const std::vector<std::vector<int>> kFacesHex = {{0, 3, 2, 1}, {0, 1, 5, 4}, {0, 4, 7, 3},
                                                 {1, 2, 6, 5}, {2, 3, 7, 6}, {4, 5, 6, 7}};
const std::vector<std::vector<int>> kFacesPrism = {{0, 2, 1}, {3, 4, 5}, {0, 1, 4, 3}, {0, 3, 5, 2}, {1, 2, 5, 4}};
const std::vector<std::vector<int>> kFacesPyr = {{0, 1, 4}, {3, 0, 4}, {1, 2, 4}, {2, 3, 4}, {0, 3, 2, 1}};

// ---- Gmsh node layouts, generated the way Gmsh generates its Lagrange points: vertices,
// then each edge from its first to its second vertex, then each face as a lower-order face
// element spanned from the face's first vertex, then the interior as a lower-order element.
using L = Lattice;
L add(L a, L b) { return {a[0] + b[0], a[1] + b[1], a[2] + b[2]}; }
L mul(L a, int s) { return {a[0] * s, a[1] * s, a[2] * s}; }
L step(L a, L b, int p) { return {(b[0] - a[0]) / p, (b[1] - a[1]) / p, (b[2] - a[2]) / p}; }

std::vector<L> gen(Shape s, int p);

void gen_edges(std::vector<L>& m, const std::vector<std::array<int, 2>>& edges, int p) {
  if (p < 2) return;
  std::vector<L> v(m.begin(), m.end());
  for (auto [a, b] : edges) {
    L u = step(v[a], v[b], p);
    for (int i = 1; i < p; ++i) m.push_back(add(v[a], mul(u, i)));
  }
}

// faces with i0 = f[0], u towards f[1], v towards f[3] (quad) or f[2] (triangle)
void gen_faces(std::vector<L>& m, const std::vector<std::vector<int>>& faces, int nv, int p) {
  std::vector<L> v(m.begin(), m.begin() + nv);
  for (auto& f : faces) {
    bool quad = f.size() == 4;
    if (quad ? p < 2 : p < 3) continue;
    std::vector<L> sub = quad ? gen(Shape::Quad, p - 2) : gen(Shape::Tri, p - 3);
    L u = step(v[f[0]], v[f[1]], p), w = step(v[f[0]], v[quad ? f[3] : f[2]], p);
    for (auto& q : sub) m.push_back(add(v[f[0]], add(mul(u, q[0] + 1), mul(w, q[1] + 1))));
  }
}

std::vector<L> gen(Shape s, int p) {
  std::vector<L> m;
  if (p == 0 || s == Shape::Point) return {{0, 0, 0}};
  switch (s) {
    case Shape::Line:
      m = {{0, 0, 0}, {p, 0, 0}};
      for (int i = 1; i < p; ++i) m.push_back({i, 0, 0});
      return m;
    case Shape::Tri:
      m = {{0, 0, 0}, {p, 0, 0}, {0, p, 0}};
      gen_edges(m, kEdgesTri, p);
      if (p >= 3)
        for (auto q : gen(Shape::Tri, p - 3)) m.push_back(add(q, {1, 1, 0}));
      return m;
    case Shape::Quad:
      m = {{0, 0, 0}, {p, 0, 0}, {p, p, 0}, {0, p, 0}};
      gen_edges(m, kEdgesQuad, p);
      if (p >= 2)
        for (auto q : gen(Shape::Quad, p - 2)) m.push_back(add(q, {1, 1, 0}));
      return m;
    case Shape::Tet:
      m = {{0, 0, 0}, {p, 0, 0}, {0, p, 0}, {0, 0, p}};
      gen_edges(m, kEdgesTet, p);
      gen_faces(m, kFacesTet, 4, p);
      if (p >= 4)
        for (auto q : gen(Shape::Tet, p - 4)) m.push_back(add(q, {1, 1, 1}));
      return m;
    case Shape::Hex:
      m = {{0, 0, 0}, {p, 0, 0}, {p, p, 0}, {0, p, 0}, {0, 0, p}, {p, 0, p}, {p, p, p}, {0, p, p}};
      gen_edges(m, kEdgesHex, p);
      gen_faces(m, kFacesHex, 8, p);
      if (p >= 2)
        for (auto q : gen(Shape::Hex, p - 2)) m.push_back(add(q, {1, 1, 1}));
      return m;
    case Shape::Prism:
      m = {{0, 0, 0}, {p, 0, 0}, {0, p, 0}, {0, 0, p}, {p, 0, p}, {0, p, p}};
      gen_edges(m, kEdgesPrism, p);
      gen_faces(m, kFacesPrism, 6, p);
      if (p >= 3)
        for (auto t : gen(Shape::Tri, p - 3))
          for (auto l : gen(Shape::Line, p - 2)) m.push_back({1 + t[0], 1 + t[1], 1 + l[0]});
      return m;
    case Shape::Pyramid:
      m = {{0, 0, p}, {p, 0, p}, {p, p, p}, {0, p, p}, {0, 0, 0}};
      gen_edges(m, kEdgesPyr, p);
      gen_faces(m, kFacesPyr, 5, p);
      if (p >= 3)
        for (auto q : gen(Shape::Pyramid, p - 3)) m.push_back(add(q, {1, 1, 2}));
      return m;
    default: break;
  }
  return m;
}

// ---- VTK layouts (vtkLagrange* / linear cells) as lattice points in VTK order ----
std::vector<L> vtk_tri_recursive(int p) {  // vtkLagrangeTriangle: vertices, edges, recursive interior
  if (p == 0) return {{0, 0, 0}};
  std::vector<L> m = {{0, 0, 0}, {p, 0, 0}, {0, p, 0}};
  for (int i = 1; i < p; ++i) m.push_back({i, 0, 0});
  for (int i = 1; i < p; ++i) m.push_back({p - i, i, 0});
  for (int i = 1; i < p; ++i) m.push_back({0, p - i, 0});
  if (p >= 3)
    for (auto q : vtk_tri_recursive(p - 3)) m.push_back(add(q, {1, 1, 0}));
  return m;
}
std::vector<L> vtk_tet(int p) {
  if (p == 0) return {{0, 0, 0}};
  std::vector<L> V = {{0, 0, 0}, {p, 0, 0}, {0, p, 0}, {0, 0, p}};
  std::vector<L> m = V;
  const int E[6][2] = {{0, 1}, {1, 2}, {2, 0}, {0, 3}, {1, 3}, {2, 3}};
  for (auto& e : E) {
    L u = step(V[e[0]], V[e[1]], p);
    for (int i = 1; i < p; ++i) m.push_back(add(V[e[0]], mul(u, i)));
  }
  const int F[4][3] = {{0, 1, 3}, {2, 3, 1}, {0, 3, 2}, {0, 2, 1}};
  if (p >= 3)
    for (auto& f : F)
      for (auto q : vtk_tri_recursive(p - 3)) {
        int a = p - 3 - q[0] - q[1] + 1, b = q[0] + 1, c = q[1] + 1;
        L r = add(add(mul(V[f[0]], a), mul(V[f[1]], b)), mul(V[f[2]], c));
        m.push_back({r[0] / p, r[1] / p, r[2] / p});
      }
  if (p >= 4)
    for (auto q : vtk_tet(p - 4)) m.push_back(add(q, {1, 1, 1}));
  return m;
}
std::vector<L> vtk_layout(Shape s, int p) {
  std::vector<L> m;
  switch (s) {
    case Shape::Point: return {{0, 0, 0}};
    case Shape::Line:
      m = {{0, 0, 0}, {p, 0, 0}};
      for (int i = 1; i < p; ++i) m.push_back({i, 0, 0});
      return m;
    case Shape::Tri: return vtk_tri_recursive(p);
    case Shape::Quad:
      m = {{0, 0, 0}, {p, 0, 0}, {p, p, 0}, {0, p, 0}};
      for (int i = 1; i < p; ++i) m.push_back({i, 0, 0});
      for (int i = 1; i < p; ++i) m.push_back({p, i, 0});
      for (int i = 1; i < p; ++i) m.push_back({i, p, 0});
      for (int i = 1; i < p; ++i) m.push_back({0, i, 0});
      for (int j = 1; j < p; ++j)
        for (int i = 1; i < p; ++i) m.push_back({i, j, 0});
      return m;
    case Shape::Tet: return vtk_tet(p);
    case Shape::Hex: {
      m = {{0, 0, 0}, {p, 0, 0}, {p, p, 0}, {0, p, 0}, {0, 0, p}, {p, 0, p}, {p, p, p}, {0, p, p}};
      for (int z : {0, p}) {
        for (int i = 1; i < p; ++i) m.push_back({i, 0, z});
        for (int i = 1; i < p; ++i) m.push_back({p, i, z});
        for (int i = 1; i < p; ++i) m.push_back({i, p, z});
        for (int i = 1; i < p; ++i) m.push_back({0, i, z});
      }
      for (L c : std::vector<L>{{0, 0, 0}, {p, 0, 0}, {p, p, 0}, {0, p, 0}})
        for (int k = 1; k < p; ++k) m.push_back({c[0], c[1], k});
      for (int x : {0, p})
        for (int k = 1; k < p; ++k)
          for (int j = 1; j < p; ++j) m.push_back({x, j, k});
      for (int y : {0, p})
        for (int k = 1; k < p; ++k)
          for (int i = 1; i < p; ++i) m.push_back({i, y, k});
      for (int z : {0, p})
        for (int j = 1; j < p; ++j)
          for (int i = 1; i < p; ++i) m.push_back({i, j, z});
      for (int k = 1; k < p; ++k)
        for (int j = 1; j < p; ++j)
          for (int i = 1; i < p; ++i) m.push_back({i, j, k});
      return m;
    }
    case Shape::Prism: {
      // VTK_WEDGE (order 1) turns its first triangle the other way round: its (0,1,2) faces
      // away from (3,4,5) (vtkWedge's docs; Gmsh's faces into the prism), so VTK gives a Gmsh-
      // ordered wedge a negative volume. meshio writes Gmsh's [0,2,1,3,5,4] as well.
      // VTK_LAGRANGE_WEDGE keeps Gmsh's orientation, at every order.
      if (p == 1) return {{0, 0, 0}, {0, 1, 0}, {1, 0, 0}, {0, 0, 1}, {0, 1, 1}, {1, 0, 1}};
      m = {{0, 0, 0}, {p, 0, 0}, {0, p, 0}, {0, 0, p}, {p, 0, p}, {0, p, p}};
      for (int z : {0, p}) {
        for (int i = 1; i < p; ++i) m.push_back({i, 0, z});
        for (int i = 1; i < p; ++i) m.push_back({p - i, i, z});
        for (int i = 1; i < p; ++i) m.push_back({0, p - i, z});
      }
      for (L c : std::vector<L>{{0, 0, 0}, {p, 0, 0}, {0, p, 0}})
        for (int k = 1; k < p; ++k) m.push_back({c[0], c[1], k});
      for (int z : {0, p})
        for (int j = 1; j < p; ++j)
          for (int i = 1; i + j < p; ++i) m.push_back({i, j, z});
      for (int k = 1; k < p; ++k)
        for (int i = 1; i < p; ++i) m.push_back({i, 0, k});
      for (int k = 1; k < p; ++k)
        for (int i = 1; i < p; ++i) m.push_back({p - i, i, k});
      for (int k = 1; k < p; ++k)
        for (int i = 1; i < p; ++i) m.push_back({0, p - i, k});
      for (int k = 1; k < p; ++k)
        for (int j = 1; j < p; ++j)
          for (int i = 1; i + j < p; ++i) m.push_back({i, j, k});
      return m;
    }
    case Shape::Pyramid: {  // VTK_PYRAMID / VTK_QUADRATIC_PYRAMID (13 nodes, no base centre)
      m = {{0, 0, p}, {p, 0, p}, {p, p, p}, {0, p, p}, {0, 0, 0}};
      if (p == 2) {
        std::vector<L> v = m;
        const int E[8][2] = {{0, 1}, {1, 2}, {2, 3}, {3, 0}, {0, 4}, {1, 4}, {2, 4}, {3, 4}};
        for (auto& e : E) m.push_back(add(v[e[0]], step(v[e[0]], v[e[1]], 2)));
      }
      return m;
    }
  }
  return m;
}

struct Tables {
  std::vector<L> lat[kNumShapes][kMaxOrder + 1];
  std::vector<Vec3> ref[kNumShapes][kMaxOrder + 1];
  std::vector<std::vector<int>> enodes[kNumShapes][kMaxOrder + 1];
  std::vector<std::vector<int>> fnodes[kNumShapes][kMaxOrder + 1];
  std::vector<int> vtk[kNumShapes][kMaxOrder + 1];
  Tables() {
    for (int si = 0; si < kNumShapes; ++si) {
      Shape s = static_cast<Shape>(si);
      for (int p = 1; p <= kMaxOrder; ++p) {
        lat[si][p] = gen(s, p);
        if ((int)lat[si][p].size() != num_nodes(s, p)) throw std::logic_error("node layout size");
        std::map<L, int> index;
        for (int i = 0; i < (int)lat[si][p].size(); ++i) {
          index[lat[si][p][i]] = i;
          ref[si][p].push_back(lattice_to_reference(s, p, lat[si][p][i]));
        }
        const auto& V = lat[si][p];
        for (auto [a, b] : edge_vertices(s)) {
          std::vector<int> e;
          for (auto q : gen(Shape::Line, p)) e.push_back(index.at(add(V[a], mul(step(V[a], V[b], p), q[0]))));
          enodes[si][p].push_back(e);
        }
        if (dimension(s) == 3)
          for (auto& f : face_vertices(s)) {
            bool quad = f.size() == 4;
            L u = step(V[f[0]], V[f[1]], p), w = step(V[f[0]], V[quad ? f[3] : f[2]], p);
            std::vector<int> fn;
            for (auto q : gen(quad ? Shape::Quad : Shape::Tri, p))
              fn.push_back(index.at(add(V[f[0]], add(mul(u, q[0]), mul(w, q[1])))));
            fnodes[si][p].push_back(fn);
          }
        if (vtk_cell_type(s, p) != 0) {
          for (auto& q : vtk_layout(s, p)) vtk[si][p].push_back(index.at(q));
        }
      }
    }
  }
};
const Tables& tables() {
  static const Tables t;
  return t;
}
void check_order(Shape, int order) {
  if (order < 1 || order > kMaxOrder)
    throw std::out_of_range("element order " + std::to_string(order) + " outside 1.." +
                            std::to_string(kMaxOrder));
}

}  // namespace

int dimension(Shape s) {
  switch (s) {
    case Shape::Point: return 0;
    case Shape::Line: return 1;
    case Shape::Tri:
    case Shape::Quad: return 2;
    default: return 3;
  }
}
int num_vertices(Shape s) {
  static const int n[] = {1, 2, 3, 4, 4, 6, 5, 8};
  return n[static_cast<int>(s)];
}
int num_nodes(Shape s, int p) {
  switch (s) {
    case Shape::Point: return 1;
    case Shape::Line: return p + 1;
    case Shape::Tri: return (p + 1) * (p + 2) / 2;
    case Shape::Quad: return (p + 1) * (p + 1);
    case Shape::Tet: return (p + 1) * (p + 2) * (p + 3) / 6;
    case Shape::Prism: return (p + 1) * (p + 1) * (p + 2) / 2;
    case Shape::Pyramid: return (p + 1) * (p + 2) * (2 * p + 3) / 6;
    case Shape::Hex: return (p + 1) * (p + 1) * (p + 1);
  }
  return 0;
}
const char* shape_name(Shape s) {
  static const char* n[] = {"point", "line", "tri", "quad", "tet", "prism", "pyramid", "hex"};
  return n[static_cast<int>(s)];
}
bool shape_from_name(const std::string& name, Shape& out) {
  for (int i = 0; i < kNumShapes; ++i)
    if (name == shape_name(static_cast<Shape>(i))) {
      out = static_cast<Shape>(i);
      return true;
    }
  return false;
}

// Gmsh's element type numbers of complete Lagrange elements, orders 1..6 (GmshDefines.h).
static const int kGmshTypes[kNumShapes][7] = {
    {15, 15, 0, 0, 0, 0, 0},        // point (order-independent)
    {0, 1, 8, 26, 27, 28, 62},      // line
    {0, 2, 9, 21, 23, 25, 42},      // triangle
    {0, 3, 10, 36, 37, 38, 47},     // quadrangle
    {0, 4, 11, 29, 30, 31, 71},     // tetrahedron
    {0, 6, 13, 90, 91, 106, 107},   // prism
    {0, 7, 14, 118, 119, 120, 121}, // pyramid
    {0, 5, 12, 92, 93, 94, 95},     // hexahedron
};
int gmsh_type(Shape s, int order) {
  if (s == Shape::Point) return 15;
  if (order < 1 || order > 6) return 0;
  return kGmshTypes[static_cast<int>(s)][order];
}
bool from_gmsh_type(int type, Shape& s, int& order) {
  if (type == 15) {
    s = Shape::Point;
    order = 1;
    return true;
  }
  for (int si = 1; si < kNumShapes; ++si)
    for (int p = 1; p <= 6; ++p)
      if (kGmshTypes[si][p] == type) {
        s = static_cast<Shape>(si);
        order = p;
        return true;
      }
  return false;
}

Vec3 lattice_to_reference(Shape s, int p, const Lattice& l) {
  const double P = p;
  switch (s) {
    case Shape::Point: return {0, 0, 0};
    case Shape::Line: return {-1 + 2 * l[0] / P, 0, 0};
    case Shape::Tri:
    case Shape::Tet: return {l[0] / P, l[1] / P, l[2] / P};
    case Shape::Quad: return {-1 + 2 * l[0] / P, -1 + 2 * l[1] / P, 0};
    case Shape::Hex: return {-1 + 2 * l[0] / P, -1 + 2 * l[1] / P, -1 + 2 * l[2] / P};
    case Shape::Prism: return {l[0] / P, l[1] / P, -1 + 2 * l[2] / P};
    case Shape::Pyramid: {
      double z = 1 - l[2] / P;
      return {-(1 - z) + 2 * l[0] / P, -(1 - z) + 2 * l[1] / P, z};
    }
  }
  return {0, 0, 0};
}

const std::vector<Lattice>& lattice(Shape s, int order) {
  check_order(s, order);
  return tables().lat[static_cast<int>(s)][order];
}
const std::vector<Vec3>& reference_nodes(Shape s, int order) {
  check_order(s, order);
  return tables().ref[static_cast<int>(s)][order];
}
const std::vector<std::array<int, 2>>& edge_vertices(Shape s) {
  static const std::vector<std::array<int, 2>> none;
  switch (s) {
    case Shape::Line: return kEdgesLine;
    case Shape::Tri: return kEdgesTri;
    case Shape::Quad: return kEdgesQuad;
    case Shape::Tet: return kEdgesTet;
    case Shape::Prism: return kEdgesPrism;
    case Shape::Pyramid: return kEdgesPyr;
    case Shape::Hex: return kEdgesHex;
    default: return none;
  }
}
const std::vector<std::vector<int>>& face_vertices(Shape s) {
  switch (s) {
    case Shape::Tri: return kFacesTri;
    case Shape::Quad: return kFacesQuad;
    case Shape::Tet: return kFacesTet;
    case Shape::Prism: return kFacesPrism;
    case Shape::Pyramid: return kFacesPyr;
    case Shape::Hex: return kFacesHex;
    default: return kFacesNone;
  }
}
const std::vector<std::vector<int>>& edge_nodes(Shape s, int order) {
  check_order(s, order);
  return tables().enodes[static_cast<int>(s)][order];
}
const std::vector<std::vector<int>>& face_nodes(Shape s, int order) {
  check_order(s, order);
  return tables().fnodes[static_cast<int>(s)][order];
}

int vtk_cell_type(Shape s, int order) {
  if (order == 1 || s == Shape::Point) {
    static const int lin[] = {1, 3, 5, 9, 10, 13, 14, 12};
    return lin[static_cast<int>(s)];
  }
  switch (s) {
    case Shape::Line: return 68;
    case Shape::Tri: return 69;
    case Shape::Quad: return 70;
    case Shape::Tet: return 71;
    case Shape::Hex: return 72;
    case Shape::Prism: return 73;
    case Shape::Pyramid: return order == 2 ? 27 : 0;  // VTK 9.1 has no Lagrange pyramid
    default: return 0;
  }
}
const std::vector<int>& vtk_to_gmsh(Shape s, int order) {
  check_order(s, order);
  return tables().vtk[static_cast<int>(s)][order];
}
bool from_vtk_cell_type(int t, int n, Shape& s, int& order) {
  static const std::pair<int, Shape> lin[] = {{1, Shape::Point}, {3, Shape::Line}, {5, Shape::Tri},
                                              {9, Shape::Quad},  {10, Shape::Tet}, {13, Shape::Prism},
                                              {14, Shape::Pyramid}, {12, Shape::Hex}};
  for (auto [vt, sh] : lin)
    if (vt == t) {
      s = sh;
      order = 1;
      return n == num_nodes(sh, 1);
    }
  if (t == 27) {
    s = Shape::Pyramid;
    order = 2;
    return n == 13;
  }
  static const std::pair<int, Shape> lag[] = {{68, Shape::Line}, {69, Shape::Tri}, {70, Shape::Quad},
                                              {71, Shape::Tet},  {72, Shape::Hex}, {73, Shape::Prism}};
  for (auto [vt, sh] : lag)
    if (vt == t) {
      for (int p = 1; p <= kMaxOrder; ++p)
        if (num_nodes(sh, p) == n) {
          s = sh;
          order = p;
          return true;
        }
      return false;
    }
  return false;
}

}  // namespace meshflow::model
