// Linear meshes for the curve tests, following the contract of stages/sweep/sweep.hpp, built
// from a structured (a, b, r) grid around a wall: the wall (r = r1) parameterised by (a, b),
// one thin layer of prisms (wall triangle first, then its image at r1 + thickness), then
// far-field layers of prisms split into 3 tets each (diagonals by the minimum vertex index, so
// neighbours conform) out to r2. Nodes are classified by projecting them on the shape (vertex,
// edge with t, face with (u,v), or volume); boundary faces (faces of one element) become 2D
// elements of the CAD face containing all their vertices, mesh edges with both ends on one CAD
// edge become its lines.
#pragma once

#include "shapes.hpp"
#include "stages/model/mesh.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <functional>
#include <map>
#include <set>
#include <stdexcept>
#include <vector>

namespace curvetest {

using meshflow::model::Mesh;
using meshflow::model::Shape;
inline const double kPi = 3.14159265358979323846;

struct Grid {
  int na = 16, nb = 8;               // wall divisions: a periodic, b from 0 to nb
  bool poles = false;                // rows b = 0 and b = nb collapse (sphere)
  std::vector<double> radii;         // r_0 = r1 (wall), r_1 = r1 + thickness (shell), ..., r2
  std::function<std::array<double, 3>(double a, double b, double r)> point;  // a in [0, 2pi), b in [0, 1]
};

struct Built {
  Mesh mesh;
  std::size_t prisms = 0, tets = 0, wall_tris = 0;
};

inline std::array<double, 3> sub3(const std::array<double, 3>& a, const std::array<double, 3>& b) {
  return {a[0] - b[0], a[1] - b[1], a[2] - b[2]};
}
inline double det3(const std::array<double, 3>& a, const std::array<double, 3>& b, const std::array<double, 3>& c) {
  return a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0]) + a[2] * (b[0] * c[1] - b[1] * c[0]);
}

// Whether p lies on CAD edge e (distance < tol), and its parameter t there: project_to_edge may
// answer on the whole periodic curve, outside the edge's range, so its answer is moved into the
// range by a period.
inline bool on_edge(const meshflow::cad::Shape& S, int e, const meshflow::cad::Vec3& p, double tol, double& t) {
  auto pr = S.project_to_edge(e, p);
  auto rr = S.edge_range(e);
  for (double sh : {0.0, 2 * kPi, -2 * kPi})
    if (pr.t + sh >= rr.lo - 1e-9 && pr.t + sh <= rr.hi + 1e-9) {
      pr.t += sh;
      break;
    }
  if (pr.t < rr.lo - 1e-9 || pr.t > rr.hi + 1e-9 || !(pr.distance < tol)) return false;
  t = pr.t;
  return true;
}

inline Built build(const meshflow::cad::Shape& S, const Grid& g, double tol = 1e-7) {
  Built out;
  Mesh& m = out.mesh;
  const int K = int(g.radii.size()) - 1;
  // nodes
  std::map<std::array<int, 3>, std::uint32_t> id;
  auto key = [&](int i, int j, int k) -> std::array<int, 3> {
    i = ((i % g.na) + g.na) % g.na;
    if (g.poles && (j == 0 || j == g.nb)) i = 0;
    return {i, j, k};
  };
  auto node = [&](int i, int j, int k) { return id.at(key(i, j, k)); };
  std::vector<std::array<double, 3>> P;
  for (int k = 0; k <= K; ++k)
    for (int j = 0; j <= g.nb; ++j)
      for (int i = 0; i < g.na; ++i) {
        auto kk = key(i, j, k);
        if (id.count(kk)) continue;
        id[kk] = std::uint32_t(P.size());
        P.push_back(g.point(2 * kPi * i / g.na, double(j) / g.nb, g.radii[k]));
      }
  for (auto& p : P) m.add_node(p[0], p[1], p[2]);
  const std::size_t N = P.size();
  m.node_entity_dim.assign(N, 3), m.node_entity_tag.assign(N, 2), m.node_u.assign(N, NAN), m.node_v.assign(N, NAN);
  // classification by projection
  std::vector<std::set<int>> faces_of(N), edges_of(N);
  const double scale = 1.0;
  for (std::size_t n = 0; n < N; ++n) {
    meshflow::cad::Vec3 p{P[n][0], P[n][1], P[n][2]};
    bool done = false;
    for (int v = 0; v < S.num_vertices() && !done; ++v) {
      auto q = S.vertex_point(v);
      if (std::hypot(q.x - p.x, q.y - p.y, q.z - p.z) < tol * scale) {
        m.node_entity_dim[n] = 0, m.node_entity_tag[n] = v + 1, done = true;
        for (int e = 0; e < S.num_edges(); ++e) {
          auto ev = S.edge_vertices(e);
          if (ev[0] == v || ev[1] == v) {
            edges_of[n].insert(e);
            for (int f : S.edge_faces(e)) faces_of[n].insert(f);
          }
        }
      }
    }
    for (int e = 0; e < S.num_edges() && !done; ++e) {
      if (S.edge_degenerate(e)) continue;
      double t = 0;
      if (on_edge(S, e, p, tol * scale, t)) {
        m.node_entity_dim[n] = 1, m.node_entity_tag[n] = e + 1, m.node_u[n] = t, done = true;
        edges_of[n].insert(e);
        for (int f : S.edge_faces(e)) faces_of[n].insert(f);
      }
    }
    for (int f = 0; f < S.num_faces() && !done; ++f) {
      auto pr = S.project_to_face(f, p);
      if (pr.distance < tol * scale && S.face_contains_uv(f, pr.u, pr.v, 1e-7)) {
        m.node_entity_dim[n] = 2, m.node_entity_tag[n] = f + 1, m.node_u[n] = pr.u, m.node_v[n] = pr.v, done = true;
        faces_of[n].insert(f);
      }
    }
  }
  // groups and entities
  m.add_physical(2, 1, "wall");
  m.add_physical(2, 2, "farfield");
  m.add_physical(2, 3, "symmetry");
  m.add_physical(3, 10, "fluid");
  for (int v = 0; v < S.num_vertices(); ++v) m.add_entity(0, v + 1);
  for (int e = 0; e < S.num_edges(); ++e) m.add_entity(1, e + 1);
  for (int f = 0; f < S.num_faces(); ++f) {
    auto t = S.face_tag(f);
    int grp = t == meshflow::cad::Tag::wall ? 1 : t == meshflow::cad::Tag::farfield ? 2 : 3;
    m.add_entity(2, f + 1, {grp});
  }
  m.add_entity(3, 1, {10});
  m.add_entity(3, 2, {10});
  // wall triangles, outward (normal towards increasing r)
  std::vector<std::array<int, 6>> tris;  // (i, j) of the 3 corners
  for (int j = 0; j < g.nb; ++j)
    for (int i = 0; i < g.na; ++i) {
      std::array<int, 2> c00{i, j}, c10{i + 1, j}, c11{i + 1, j + 1}, c01{i, j + 1};
      bool south = g.poles && j == 0, north = g.poles && j == g.nb - 1;
      auto add = [&](std::array<int, 2> a, std::array<int, 2> b, std::array<int, 2> c) {
        tris.push_back({a[0], a[1], b[0], b[1], c[0], c[1]});
      };
      if (south) add(c00, c11, c01);
      else if (north) add(c00, c10, c11);
      else if ((i + j) % 2 == 0) add(c00, c10, c11), add(c00, c11, c01);
      else add(c00, c10, c01), add(c10, c11, c01);
    }
  m.block(Shape::Prism, 1, 3, 1);
  m.block(Shape::Tet, 1, 3, 2);
  auto& prisms = m.blocks[0];  // references stay valid until the 2D blocks are added
  auto& tets = m.blocks[1];
  auto X = [&](std::uint32_t n) { return P[n]; };
  for (auto& t : tris) {
    for (int k = 0; k < K; ++k) {
      std::array<std::uint32_t, 3> lo{node(t[0], t[1], k), node(t[2], t[3], k), node(t[4], t[5], k)};
      std::array<std::uint32_t, 3> hi{node(t[0], t[1], k + 1), node(t[2], t[3], k + 1), node(t[4], t[5], k + 1)};
      // orientation: (b - a) x (c - a) . (top - bottom) > 0
      auto vol = det3(sub3(X(lo[1]), X(lo[0])), sub3(X(lo[2]), X(lo[0])), sub3(X(hi[0]), X(lo[0])));
      if (vol < 0) std::swap(lo[1], lo[2]), std::swap(hi[1], hi[2]);
      if (k == 0) {
        prisms.add({lo[0], lo[1], lo[2], hi[0], hi[1], hi[2]});
        ++out.prisms;
        continue;
      }
      // split into 3 tets, diagonals through the minimum index (Dompierre et al. 1999)
      std::array<std::uint32_t, 6> V{lo[0], lo[1], lo[2], hi[0], hi[1], hi[2]};
      int mn = int(std::min_element(V.begin(), V.end()) - V.begin());
      std::array<int, 6> perm;
      if (mn < 3) perm = {mn, (mn + 1) % 3, (mn + 2) % 3, 3 + mn, 3 + (mn + 1) % 3, 3 + (mn + 2) % 3};
      else {
        int b = mn - 3;
        perm = {3 + b, 3 + (b + 2) % 3, 3 + (b + 1) % 3, b, (b + 2) % 3, (b + 1) % 3};
      }
      std::array<std::uint32_t, 6> W;
      for (int q = 0; q < 6; ++q) W[q] = V[perm[q]];
      std::vector<std::array<std::uint32_t, 4>> T;
      if (std::min(W[1], W[5]) < std::min(W[2], W[4])) T = {{W[0], W[1], W[2], W[5]}, {W[0], W[1], W[5], W[4]}, {W[0], W[4], W[5], W[3]}};
      else T = {{W[0], W[1], W[2], W[4]}, {W[0], W[4], W[2], W[5]}, {W[0], W[4], W[5], W[3]}};
      for (auto tt : T) {
        if (det3(sub3(X(tt[1]), X(tt[0])), sub3(X(tt[2]), X(tt[0])), sub3(X(tt[3]), X(tt[0]))) < 0) std::swap(tt[1], tt[2]);
        tets.add({tt[0], tt[1], tt[2], tt[3]});
        ++out.tets;
      }
    }
  }
  // volume classification of the shell (layer 1) nodes: near field (3, 1)
  for (int j = 0; j <= g.nb; ++j)
    for (int i = 0; i < g.na; ++i) {
      auto n = node(i, j, 1);
      if (m.node_entity_dim[n] == 3) m.node_entity_tag[n] = 1;
    }
  // boundary faces
  std::map<std::vector<std::uint32_t>, std::pair<std::vector<std::uint32_t>, int>> faces;  // sorted -> (oriented, count)
  auto face = [&](std::vector<std::uint32_t> f) {
    auto s = f;
    std::sort(s.begin(), s.end());
    auto& e = faces[s];
    if (e.second == 0) e.first = f;
    ++e.second;
  };
  for (std::size_t e = 0; e < prisms.size(); ++e) {
    auto v = prisms.element(e);
    face({v[0], v[2], v[1]}), face({v[3], v[4], v[5]}), face({v[0], v[1], v[4], v[3]}), face({v[0], v[3], v[5], v[2]}),
        face({v[1], v[2], v[5], v[4]});
  }
  for (std::size_t e = 0; e < tets.size(); ++e) {
    auto v = tets.element(e);
    face({v[0], v[2], v[1]}), face({v[0], v[1], v[3]}), face({v[0], v[3], v[2]}), face({v[3], v[1], v[2]});
  }
  std::vector<std::pair<int, std::vector<std::uint32_t>>> bfaces;
  for (auto& [s, fc] : faces) {
    if (fc.second != 1) continue;
    std::set<int> common = faces_of[s[0]];
    for (auto n : s) {
      std::set<int> r;
      std::set_intersection(common.begin(), common.end(), faces_of[n].begin(), faces_of[n].end(), std::inserter(r, r.begin()));
      common = r;
    }
    if (common.size() != 1) throw std::runtime_error("builder: boundary face on " + std::to_string(common.size()) + " CAD faces");
    int f = *common.begin();
    bfaces.push_back({f, fc.first});
    if (S.face_tag(f) == meshflow::cad::Tag::wall) ++out.wall_tris;
  }
  std::sort(bfaces.begin(), bfaces.end());
  for (auto& [f, v] : bfaces) m.block(v.size() == 3 ? Shape::Tri : Shape::Quad, 1, 2, f + 1).add(v.data());
  // lines: boundary-face edges with both ends on one CAD edge
  std::set<std::pair<std::uint32_t, std::uint32_t>> seen;
  std::vector<std::pair<int, std::array<std::uint32_t, 2>>> lines;
  for (auto& b : m.blocks) {
    if (b.entity_dim != 2) continue;
    int nv = b.shape == Shape::Tri ? 3 : 4;
    for (std::size_t e = 0; e < b.size(); ++e)
      for (int a = 0; a < nv; ++a) {
        std::uint32_t p = b.element(e)[a], q = b.element(e)[(a + 1) % nv];
        auto k = std::minmax(p, q);
        if (!seen.insert(k).second) continue;
        std::set<int> r;
        std::set_intersection(edges_of[p].begin(), edges_of[p].end(), edges_of[q].begin(), edges_of[q].end(), std::inserter(r, r.begin()));
        for (int ce : r) {
          if (S.edge_degenerate(ce)) continue;
          lines.push_back({ce, {p, q}});
        }
      }
  }
  std::sort(lines.begin(), lines.end());
  for (auto& [ce, pq] : lines) m.block(Shape::Line, 1, 1, ce + 1).add({pq[0], pq[1]});
  m.check();
  return out;
}

// Fluid between spheres: (a, b) = (longitude, latitude from -pi/2 to pi/2).
inline Grid sphere_grid(int na, int nb, double r1, double thickness, double r2, int far_layers) {
  Grid g;
  g.na = na, g.nb = nb, g.poles = true;
  g.radii = {r1, r1 + thickness};
  for (int k = 1; k <= far_layers; ++k) g.radii.push_back(r1 + thickness + (r2 - r1 - thickness) * std::pow(double(k) / far_layers, 1.5));
  g.point = [](double a, double b, double r) -> std::array<double, 3> {
    double lat = -kPi / 2 + kPi * b;
    return {r * std::cos(lat) * std::cos(a), r * std::cos(lat) * std::sin(a), r * std::sin(lat)};
  };
  return g;
}
// Fluid between cylinders: (a, b) = (angle, z / h).
inline Grid cylinder_grid(int na, int nb, double r1, double thickness, double r2, double h, int far_layers) {
  Grid g;
  g.na = na, g.nb = nb, g.poles = false;
  g.radii = {r1, r1 + thickness};
  for (int k = 1; k <= far_layers; ++k) g.radii.push_back(r1 + thickness + (r2 - r1 - thickness) * std::pow(double(k) / far_layers, 1.5));
  g.point = [h](double a, double b, double r) -> std::array<double, 3> { return {r * std::cos(a), r * std::sin(a), h * b}; };
  return g;
}

}  // namespace curvetest
