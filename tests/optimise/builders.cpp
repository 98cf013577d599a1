// Test meshes of builders.hpp (no OCCT here: the CAD through cad::Shape).
#include "builders.hpp"

#include "stages/model/element.hpp"

#include <array>
#include <cmath>
#include <functional>
#include <map>
#include <stdexcept>
#include <vector>

namespace opttest {

using meshflow::cad::Shape;
using meshflow::model::Mesh;
namespace model = meshflow::model;

namespace {

struct UV {
  double u, v;
};

// Classifies node n (add_node appends to the classification arrays only once they exist).
std::uint32_t set(Mesh& m, std::uint32_t n, int dim, int tag, double u, double v) {
  m.node_entity_dim.resize(m.num_nodes(), -1);
  m.node_entity_tag.resize(m.num_nodes(), -1);
  m.node_u.resize(m.num_nodes(), NAN);
  m.node_v.resize(m.num_nodes(), NAN);
  m.node_entity_dim[n] = dim, m.node_entity_tag[n] = tag, m.node_u[n] = u, m.node_v[n] = v;
  return n;
}

// Classification of a node: CAD vertex / edge (id) / face (id); -1 = none.
struct Cls {
  int dim = 2, id = 0;
};

// A structured (u,v) grid of cells on one face, meshed into order-P triangles or quads.
struct GridMesher {
  const Shape& s;
  int face, P;
  Distortion d;
  int nu, nv;
  bool periodic_u;
  std::function<UV(int, int)> uv_of;                 // grid point (i, j) in the cell's chart
  std::function<Cls(int, int)> vertex_cls;           // classification of grid vertex
  std::function<int(int, int, int, int)> curve_of;   // CAD edge of the grid edge (i,j)-(k,l), or -1
  Mesh m;
  int elements = 0;  // built so far
  std::map<long, std::uint32_t> vnodes;
  std::map<std::pair<long, long>, std::vector<std::uint32_t>> enodes;

  GridMesher(const Shape& sh, int f, int p, Distortion dd, int nu_, int nv_, bool per)
      : s(sh), face(f), P(p), d(dd), nu(nu_), nv(nv_), periodic_u(per) {}

  long key(int i, int j) const { return long(periodic_u ? i % nu : i) * (nv + 1) + j; }

  std::uint32_t add(const meshflow::cad::Vec3& x, int dim, int tag, double u, double v) {
    return set(m, m.add_node(x.x, x.y, x.z), dim, tag, u, v);
  }
  std::uint32_t on_face(UV uv) { return add(s.face_point(face, uv.u, uv.v), 2, face + 1, uv.u, uv.v); }
  std::uint32_t at_point(const meshflow::cad::Vec3& x, Cls c, UV uv) {
    if (c.dim == 0) return add(x, 0, c.id + 1, NAN, NAN);
    if (c.dim == 1) return add(x, 1, c.id + 1, s.project_to_edge(c.id, x).t, NAN);
    return add(x, 2, face + 1, uv.u, uv.v);
  }

  std::uint32_t vertex(int i, int j) {
    auto it = vnodes.find(key(i, j));
    if (it != vnodes.end()) return it->second;
    UV uv = uv_of(i, j);
    auto x = s.face_point(face, uv.u, uv.v);
    return vnodes[key(i, j)] = at_point(x, vertex_cls(i, j), uv);
  }
  // Interior nodes of the grid edge (i,j) -> (k,l), in that direction.
  std::vector<std::uint32_t> edge(int i, int j, int k, int l) {
    long a = key(i, j), b = key(k, l);
    bool flip = a > b;
    if (flip) std::swap(i, k), std::swap(j, l), std::swap(a, b);
    auto it = enodes.find({a, b});
    if (it == enodes.end()) {
      UV A = uv_of(i, j), B = uv_of(k, l);
      int curve = curve_of(i, j, k, l);
      std::vector<std::uint32_t> nodes;
      for (int q = 1; q < P; ++q) {
        double xi = double(q) / P, t = xi - d.bunch * xi * (1 - xi), w = curve < 0 ? d.bump * xi * (1 - xi) : 0;
        UV uv{A.u + t * (B.u - A.u) - w * (B.v - A.v), A.v + t * (B.v - A.v) + w * (B.u - A.u)};
        auto x = s.face_point(face, uv.u, uv.v);
        nodes.push_back(curve >= 0 ? at_point(x, {1, curve}, uv) : on_face(uv));
      }
      it = enodes.emplace(std::make_pair(a, b), nodes).first;
    }
    std::vector<std::uint32_t> r = it->second;
    if (flip) std::reverse(r.begin(), r.end());
    return r;
  }
  // An order-P element with grid vertices gv (3 or 4, Gmsh vertex order) and interior nodes at
  // `interior_uv(a, b)` (lattice indices).
  std::vector<std::uint32_t> element(model::Shape shape, const std::vector<std::array<int, 2>>& gv) {
    const auto& lat = model::lattice(shape, P);
    std::vector<std::uint32_t> el(lat.size(), UINT32_MAX);
    for (std::size_t k = 0; k < gv.size(); ++k) el[k] = vertex(gv[k][0], gv[k][1]);
    for (const auto& ed : model::edge_nodes(shape, P)) {
      auto nodes = edge(gv[ed[0]][0], gv[ed[0]][1], gv[ed[1]][0], gv[ed[1]][1]);
      for (std::size_t q = 2; q < ed.size(); ++q) el[ed[q]] = nodes[q - 2];
    }
    std::vector<UV> c;
    for (auto& g : gv) c.push_back(uv_of(g[0], g[1]));
    double size = std::hypot(c[1].u - c[0].u, c[1].v - c[0].v);
    const bool shift = d.interior_only < 0 || d.interior_only == elements;
    const double su = shift ? d.interior_u * size : 0, sv = shift ? d.interior_v * size : 0;
    ++elements;
    for (std::size_t k = 0; k < lat.size(); ++k) {
      if (el[k] != UINT32_MAX) continue;
      double a = double(lat[k][0]) / P, b = double(lat[k][1]) / P;
      UV uv;
      if (shape == model::Shape::Tri) {
        double l0 = 1 - a - b;
        uv = {l0 * c[0].u + a * c[1].u + b * c[2].u, l0 * c[0].v + a * c[1].v + b * c[2].v};
        double bub = 27 * l0 * a * b;  // 1 at the centroid
        uv.u += su * bub, uv.v += sv * bub;
      } else {
        double w[4] = {(1 - a) * (1 - b), a * (1 - b), a * b, (1 - a) * b};
        uv = {0, 0};
        for (int q = 0; q < 4; ++q) uv.u += w[q] * c[q].u, uv.v += w[q] * c[q].v;
        double bub = 16 * a * (1 - a) * b * (1 - b);
        uv.u += su * bub, uv.v += sv * bub;
      }
      el[k] = on_face(uv);
    }
    return el;
  }
};

}  // namespace

Mesh sphere_patch(const Shape& s, int P, const Patch& pa, const Distortion& d, double thickness) {
  int face = 0;
  while (face < s.num_faces() && s.face_surface_type(face) != "sphere") ++face;
  if (face == s.num_faces()) throw std::runtime_error("sphere_patch: no spherical face");
  GridMesher g(s, face, P, d, pa.nu, pa.nv, false);
  g.uv_of = [&](int i, int j) { return UV{pa.u0 + (pa.u1 - pa.u0) * i / pa.nu, pa.v0 + (pa.v1 - pa.v0) * j / pa.nv}; };
  g.vertex_cls = [](int, int) { return Cls{2, 0}; };
  g.curve_of = [](int, int, int, int) { return -1; };
  g.m.add_physical(2, 1, "wall");
  g.m.add_entity(2, face + 1, {1});
  std::vector<std::vector<std::uint32_t>> tris;
  for (int i = 0; i < pa.nu; ++i)
    for (int j = 0; j < pa.nv; ++j) {
      tris.push_back(g.element(model::Shape::Tri, {{{i, j}}, {{i + 1, j}}, {{i + 1, j + 1}}}));
      tris.push_back(g.element(model::Shape::Tri, {{{i, j}}, {{i + 1, j + 1}}, {{i, j + 1}}}));
    }
  auto& tb = g.m.block(model::Shape::Tri, P, 2, face + 1);
  for (auto& t : tris) tb.add(t.data());
  if (thickness > 0) {
    Mesh& m = g.m;
    m.add_physical(3, 10, "fluid");
    m.add_entity(3, 1, {10});
    std::map<std::pair<std::uint32_t, int>, std::uint32_t> lifted;
    auto lift = [&](std::uint32_t w, int k) {
      if (k == 0) return w;
      auto it = lifted.find({w, k});
      if (it != lifted.end()) return it->second;
      double r = std::sqrt(m.x[w] * m.x[w] + m.y[w] * m.y[w] + m.z[w] * m.z[w]);
      double f = 1 + thickness * k / (P * r);
      return lifted[{w, k}] = set(m, m.add_node(m.x[w] * f, m.y[w] * f, m.z[w] * f), 3, 1, NAN, NAN);
    };
    const auto& tlat = model::lattice(model::Shape::Tri, P);
    std::map<model::Lattice, int> tri_at;
    for (int i = 0; i < int(tlat.size()); ++i) tri_at[tlat[i]] = i;
    const auto& plat = model::lattice(model::Shape::Prism, P);
    std::vector<std::vector<std::uint32_t>> prisms;
    for (auto& t : tris) {
      std::vector<std::uint32_t> el(plat.size());
      for (std::size_t k = 0; k < plat.size(); ++k) el[k] = lift(t[tri_at.at({plat[k][0], plat[k][1], 0})], plat[k][2]);
      prisms.push_back(el);
    }
    auto& pb = m.block(model::Shape::Prism, P, 3, 1);
    for (auto& p : prisms) pb.add(p.data());
  }
  g.m.check();
  return std::move(g.m);
}

Mesh cylinder_quads(const Shape& s, int P, int nu, int nv, const Distortion& d) {
  int face = 0;
  while (face < s.num_faces() && s.face_surface_type(face) != "cylinder") ++face;
  if (face == s.num_faces()) throw std::runtime_error("cylinder_quads: no cylindrical face");
  auto b = s.face_uv_bounds(face);
  int seam = -1, bottom = -1, top = -1, vbot = -1, vtop = -1;
  for (int e : s.face_edges(face)) {
    if (s.edge_degenerate(e)) continue;
    if (s.edge_is_seam(e, face)) {
      seam = e;
      continue;
    }
    auto r = s.edge_range(e);
    auto p = s.edge_point(e, 0.5 * (r.lo + r.hi));
    (std::abs(p.z - s.face_point(face, b.u0, b.v0).z) < 1e-9 ? bottom : top) = e;
  }
  for (int k = 0; k < s.num_vertices(); ++k)
    (std::abs(s.vertex_point(k).z - s.face_point(face, b.u0, b.v0).z) < 1e-9 ? vbot : vtop) = k;
  if (seam < 0 || bottom < 0 || top < 0) throw std::runtime_error("cylinder_quads: edges not found");
  GridMesher g(s, face, P, d, nu, nv, true);
  g.uv_of = [&](int i, int j) { return UV{b.u0 + (b.u1 - b.u0) * i / nu, b.v0 + (b.v1 - b.v0) * j / nv}; };
  g.vertex_cls = [&](int i, int j) {
    bool rim = j == 0 || j == nv, sm = i % nu == 0;
    if (rim && sm) return Cls{0, j == 0 ? vbot : vtop};
    if (rim) return Cls{1, j == 0 ? bottom : top};
    if (sm) return Cls{1, seam};
    return Cls{2, face};
  };
  g.curve_of = [&](int i, int j, int k, int l) {
    if (j == l && (j == 0 || j == nv)) return j == 0 ? bottom : top;
    if (i == k && i % nu == 0) return seam;
    return -1;
  };
  Mesh& m = g.m;
  m.add_physical(2, 1, "wall");
  m.add_entity(2, face + 1, {1});
  for (int e : {seam, bottom, top}) m.add_entity(1, e + 1);
  std::vector<std::vector<std::uint32_t>> quads;
  for (int i = 0; i < nu; ++i)
    for (int j = 0; j < nv; ++j) quads.push_back(g.element(model::Shape::Quad, {{{i, j}}, {{i + 1, j}}, {{i + 1, j + 1}}, {{i, j + 1}}}));
  auto& qb = m.block(model::Shape::Quad, P, 2, face + 1);
  for (auto& q : quads) qb.add(q.data());
  // lines on the CAD edges, oriented along the curves
  auto line = [&](int e, int i, int j, int k, int l) {
    std::vector<std::uint32_t> n = {g.vertex(i, j), g.vertex(k, l)};
    for (auto x : g.edge(i, j, k, l)) n.push_back(x);
    m.block(model::Shape::Line, P, 1, e + 1).add(n.data());
  };
  for (int i = 0; i < nu; ++i) line(bottom, i, 0, i + 1, 0), line(top, i, nv, i + 1, nv);
  for (int j = 0; j < nv; ++j) line(seam, 0, j, 0, j + 1);
  m.check();
  return std::move(g.m);
}

double max_param_error(const Mesh& m, const Shape& s) {
  double e = 0;
  for (std::size_t i = 0; i < m.num_nodes(); ++i) {
    meshflow::cad::Vec3 p;
    if (m.node_entity_dim[i] == 1) p = s.edge_point(m.node_entity_tag[i] - 1, m.node_u[i]);
    else if (m.node_entity_dim[i] == 2) p = s.face_point(m.node_entity_tag[i] - 1, m.node_u[i], m.node_v[i]);
    else continue;
    e = std::max(e, std::hypot(p.x - m.x[i], p.y - m.y[i], p.z - m.z[i]));
  }
  return e;
}

}  // namespace opttest
