// CGNS node orderings, generated from the rules of CGNS/SIDS 3.3 (the element figures and
// tables of the SIDS, checked by hand for TRI_15, QUAD_25, TETRA_35, PYRA_55, PENTA_75,
// HEXA_64 and HEXA_125):
//   - vertices as Gmsh's (the linear types agree);
//   - edge nodes edge by edge, each edge from its first to its second vertex, the edges in the
//     SIDS edge tables' order (these differ from Gmsh's, e.g. the tetrahedron's E4..E6);
//   - face nodes face by face in the order below; a triangle face's interior is the CGNS
//     triangle of order p-3 spanned from the listed corners (TETRA_35: N23 nearest N1, N24
//     nearest N2, N25 nearest N3); a quadrilateral face's interior is a spiral: from the node
//     nearest the first corner towards the second, round the ring, then the centre (QUAD_25:
//     N17 nearest N1, N18 between N17 and N19, N19 nearest N2, ..., N25 the centre). Gmsh
//     orders a quad interior recursively (4 corners, then 4 edge nodes) instead;
//   - interior nodes: the tetrahedron's and pyramid's as an inner element of order p-4 resp.
//     p-3 (PYRA_55: N51..N54 in the plane of N18, N21, N24, N27, N55 above them), the prism's
//     and hexahedron's as the slices between bottom and top, each ordered like a face.
// The SIDS gives the interior points of the pyramid's PYRA_55 as intersections of lines that
// do not fall on the equispaced lattice (N51 on N5-N30 at z = 1/4 is (-3/8, -3/8), N55 on the
// axis at the level of N20, z = 3/4), contradicting its own figure, which draws them on the
// lattice (N55 at the level of N19). We keep the lattice: Gmsh's CGNS reader and the
// equispaced Lagrange bases solvers use assume it, and the ordering is unaffected.
// Written here because libcgns stores connectivity only: it has no ordering tables.
#include "stages/io/cgns_layout.hpp"

#include <array>
#include <cmath>
#include <mutex>
#include <stdexcept>
#include <string>

namespace meshflow::io::detail {

using model::Shape;
using model::Vec3;

namespace {

Vec3 lerp(const Vec3& a, const Vec3& b, double t) {
  return {a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1]), a[2] + t * (b[2] - a[2])};
}
// a + u (b - a) + v (c - a)
Vec3 span(const Vec3& a, const Vec3& b, const Vec3& c, double u, double v) {
  return {a[0] + u * (b[0] - a[0]) + v * (c[0] - a[0]), a[1] + u * (b[1] - a[1]) + v * (c[1] - a[1]),
          a[2] + u * (b[2] - a[2]) + v * (c[2] - a[2])};
}

using Pts = std::vector<Vec3>;

void edge(Pts& out, const Vec3& a, const Vec3& b, int p) {
  for (int i = 1; i < p; ++i) out.push_back(lerp(a, b, double(i) / p));
}

// The CGNS triangle of order q on the unit triangle (u, v): vertices, edges, interior.
std::vector<std::array<double, 2>> unit_tri(int q) {
  if (q == 0) return {{1.0 / 3, 1.0 / 3}};
  std::vector<std::array<double, 2>> t = {{0, 0}, {1, 0}, {0, 1}};
  for (int e = 0; e < 3; ++e)
    for (int i = 1; i < q; ++i) {
      const auto &a = t[e], &b = t[(e + 1) % 3];
      const double s = double(i) / q;
      t.push_back({a[0] + s * (b[0] - a[0]), a[1] + s * (b[1] - a[1])});
    }
  if (q >= 3)
    for (auto [u, v] : unit_tri(q - 3)) t.push_back({(1 + u * (q - 3)) / q, (1 + v * (q - 3)) / q});
  return t;
}

// Interior nodes of a triangle face a, b, c of an order-p element.
void tri_interior(Pts& out, const Vec3& a, const Vec3& b, const Vec3& c, int p) {
  if (p < 3) return;
  for (auto [u, v] : unit_tri(p - 3)) out.push_back(span(a, b, c, (1 + u * (p - 3)) / p, (1 + v * (p - 3)) / p));
}

// Interior nodes of a quadrilateral face c0..c3 (a parallelogram on every reference element):
// the spiral over the lattice indices lo..hi, from (lo, lo) along c0 -> c1.
void quad_ring(Pts& out, const Vec3& c0, const Vec3& c1, const Vec3& c3, int p, int lo, int hi) {
  auto at = [&](int i, int j) { out.push_back(span(c0, c1, c3, double(i) / p, double(j) / p)); };
  if (lo > hi) return;
  if (lo == hi) return at(lo, lo);
  for (int i = lo; i <= hi; ++i) at(i, lo);
  for (int j = lo + 1; j <= hi; ++j) at(hi, j);
  for (int i = hi - 1; i >= lo; --i) at(i, hi);
  for (int j = hi - 1; j > lo; --j) at(lo, j);
  quad_ring(out, c0, c1, c3, p, lo + 1, hi - 1);
}
void quad_interior(Pts& out, const Vec3& c0, const Vec3& c1, const Vec3& c3, int p) { quad_ring(out, c0, c1, c3, p, 1, p - 1); }

Pts points(Shape s, int p);

// The interior of a tetrahedron (p >= 4) or pyramid (p >= 3): the CGNS element of order q
// shrunk into it.
void inner_element(Pts& out, Shape s, int p) {
  const int q = s == Shape::Tet ? p - 4 : p - 3;
  if (q < 0) return;
  Pts in;
  if (q == 0) in = {s == Shape::Tet ? Vec3{0.25, 0.25, 0.25} : Vec3{0, 0, 0}};
  else in = points(s, q);
  const double k = double(q) / p, o = 1.0 / p;
  for (auto& x : in)
    out.push_back(s == Shape::Tet ? Vec3{o + k * x[0], o + k * x[1], o + k * x[2]} : Vec3{k * x[0], k * x[1], o + k * x[2]});
}

Pts points(Shape s, int p) {
  const Pts& v0 = model::reference_nodes(s, 1);  // the vertices, in Gmsh's (= CGNS's) order
  Pts out(v0.begin(), v0.end());
  const auto& v = v0;
  if (s == Shape::Point) return out;
  auto edges = [&](std::initializer_list<std::array<int, 2>> es) {
    for (auto [a, b] : es) edge(out, v[a], v[b], p);
  };
  switch (s) {
    case Shape::Line: edges({{0, 1}}); break;
    case Shape::Tri:
      edges({{0, 1}, {1, 2}, {2, 0}});
      tri_interior(out, v[0], v[1], v[2], p);
      break;
    case Shape::Quad:
      edges({{0, 1}, {1, 2}, {2, 3}, {3, 0}});
      quad_interior(out, v[0], v[1], v[3], p);
      break;
    case Shape::Tet:
      edges({{0, 1}, {1, 2}, {2, 0}, {0, 3}, {1, 3}, {2, 3}});
      tri_interior(out, v[0], v[1], v[2], p);
      tri_interior(out, v[0], v[1], v[3], p);
      tri_interior(out, v[1], v[2], v[3], p);
      tri_interior(out, v[2], v[0], v[3], p);
      inner_element(out, s, p);
      break;
    case Shape::Pyramid:
      edges({{0, 1}, {1, 2}, {2, 3}, {3, 0}, {0, 4}, {1, 4}, {2, 4}, {3, 4}});
      quad_interior(out, v[0], v[1], v[3], p);
      for (int f = 0; f < 4; ++f) tri_interior(out, v[f], v[(f + 1) % 4], v[4], p);
      inner_element(out, s, p);
      break;
    case Shape::Prism:
      edges({{0, 1}, {1, 2}, {2, 0}, {0, 3}, {1, 4}, {2, 5}, {3, 4}, {4, 5}, {5, 3}});
      tri_interior(out, v[0], v[1], v[2], p);
      for (int f = 0; f < 3; ++f) quad_interior(out, v[f], v[(f + 1) % 3], v[f + 3], p);
      tri_interior(out, v[3], v[4], v[5], p);
      for (int k = 1; k < p; ++k) {
        const double t = double(k) / p;
        tri_interior(out, lerp(v[0], v[3], t), lerp(v[1], v[4], t), lerp(v[2], v[5], t), p);
      }
      break;
    case Shape::Hex:
      edges({{0, 1}, {1, 2}, {2, 3}, {3, 0}, {0, 4}, {1, 5}, {2, 6}, {3, 7}, {4, 5}, {5, 6}, {6, 7}, {7, 4}});
      quad_interior(out, v[0], v[1], v[3], p);
      for (int f = 0; f < 4; ++f) quad_interior(out, v[f], v[(f + 1) % 4], v[f + 4], p);
      quad_interior(out, v[4], v[5], v[7], p);
      for (int k = 1; k < p; ++k) {
        const double t = double(k) / p;
        quad_interior(out, lerp(v[0], v[4], t), lerp(v[1], v[5], t), lerp(v[3], v[7], t), p);
      }
      break;
    default: break;
  }
  return out;
}

void check(Shape s, int order) {
  if (order < 1 || order > kCgnsMaxOrder)
    throw std::out_of_range(std::string("CGNS has no complete ") + model::shape_name(s) + " of order " + std::to_string(order) +
                            " (orders 1 to 4 only)");
}

}  // namespace

std::vector<Vec3> cgns_reference_points(Shape s, int order) {
  check(s, order);
  return points(s, order);
}

const std::vector<int>& cgns_to_gmsh(Shape s, int order) {
  check(s, order);
  static std::once_flag once;
  static std::vector<int> table[model::kNumShapes][kCgnsMaxOrder + 1];
  std::call_once(once, [] {
    for (int si = 0; si < model::kNumShapes; ++si)
      for (int p = 1; p <= kCgnsMaxOrder; ++p) {
        const Shape sh = static_cast<Shape>(si);
        const Pts c = points(sh, p);
        const Pts& g = model::reference_nodes(sh, p);
        if (c.size() != g.size()) throw std::logic_error(std::string("CGNS layout size of ") + model::shape_name(sh));
        std::vector<int> perm(c.size(), -1);
        std::vector<bool> used(g.size(), false);
        for (size_t i = 0; i < c.size(); ++i)
          for (size_t j = 0; j < g.size(); ++j)
            if (!used[j] && std::abs(c[i][0] - g[j][0]) + std::abs(c[i][1] - g[j][1]) + std::abs(c[i][2] - g[j][2]) < 1e-9) {
              perm[i] = static_cast<int>(j), used[j] = true;
              break;
            }
        for (int x : perm)
          if (x < 0) throw std::logic_error(std::string("CGNS layout of ") + model::shape_name(sh) + " is not Gmsh's point set");
        table[si][p] = std::move(perm);
      }
  });
  return table[static_cast<int>(s)][order];
}

}  // namespace meshflow::io::detail
