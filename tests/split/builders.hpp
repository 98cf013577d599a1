// Test meshes for the split stage: random curved macro elements, and a cylinder standing on
// a plate (C-type junction) with a one-layer near field of prisms and junction hexes capped
// by tets, all of order P, conforming by construction.
#pragma once

#include "stages/model/basis.hpp"
#include "stages/model/mesh.hpp"
#include "stages/model/quality.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <map>
#include <random>
#include <stdexcept>
#include <vector>

namespace splittest {

using meshflow::model::Mesh;
using meshflow::model::Shape;
using meshflow::model::Vec3;

inline const double kPi = 3.14159265358979323846;

// Physical groups / entities used by the builders.
enum : int { kVol = 1, kWall = 10, kWall2 = 11, kSym = 12, kFar = 13, kLine = 20 };

inline void add_groups(Mesh& m) {
  m.add_physical(3, 1, "fluid");
  m.add_physical(2, 1, "wall");
  m.add_physical(2, 2, "symmetry");
  m.add_physical(2, 3, "farfield");
  m.add_physical(1, 4, "axis");
  m.add_entity(3, kVol, {1});
  m.add_entity(2, kWall, {1});
  m.add_entity(2, kWall2, {1});
  m.add_entity(2, kSym, {2});
  m.add_entity(2, kFar, {3});
  m.add_entity(1, kLine, {4});
}

// One random curved macro element of order P (prism or hex) with its wall face(s) as 2D
// boundary elements: a smooth random map of the reference element (thin in the wall-normal
// directions, like a boundary-layer element) plus random perturbations of the high-order
// nodes, shrunk until the element is valid by the Bezier check. `walls` lists the local
// faces on the wall (prism: 0 or 1; hex: faces on distinct axes).
inline Mesh random_macro(Shape s, int P, const std::vector<int>& walls, std::mt19937_64& rng, double amp = 0.15) {
  std::uniform_real_distribution<double> U(-1, 1);
  const auto& ref = meshflow::model::reference_nodes(s, P);
  const int n = int(ref.size());
  // random smooth map: x = A xi + quadratic terms, thin in the wall-normal direction(s)
  double A[3][3], Q[3][6];
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) A[r][c] = (r == c ? 1.0 : 0.0) + 0.3 * U(rng);
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 6; ++c) Q[r][c] = 0.25 * U(rng);
  double scale[3] = {1, 1, 1};
  if (s == Shape::Prism) scale[2] = 0.05 + 0.2 * (U(rng) + 1);
  else
    for (int f : walls) {
      const auto& fv = meshflow::model::face_vertices(Shape::Hex)[f];
      const auto& r1 = meshflow::model::reference_nodes(Shape::Hex, 1);
      for (int d = 0; d < 3; ++d) {
        bool same = true;
        for (int v : fv) same = same && r1[v][d] == r1[fv[0]][d];
        if (same) scale[d] = 0.05 + 0.2 * (U(rng) + 1);
      }
    }
  std::vector<Vec3> base(n);
  for (int i = 0; i < n; ++i) {
    Vec3 xi = ref[i];
    double q[6] = {xi[0] * xi[0], xi[1] * xi[1], xi[2] * xi[2], xi[0] * xi[1], xi[1] * xi[2], xi[0] * xi[2]};
    for (int r = 0; r < 3; ++r) {
      double v = 0;
      for (int c = 0; c < 3; ++c) v += A[r][c] * xi[c] * scale[c];
      for (int c = 0; c < 6; ++c) v += Q[r][c] * q[c] * 2.0 * (scale[0] * scale[1] * scale[2] / std::max({scale[0], scale[1], scale[2]}));
      base[i][r] = v;
    }
  }
  // affine part orientation: make det A' > 0 by flipping x if needed (checked below anyway)
  std::vector<Vec3> pert(n);
  double h = std::min({scale[0], scale[1], scale[2]}) / P;
  for (int i = meshflow::model::num_vertices(s); i < n; ++i)
    for (int r = 0; r < 3; ++r) pert[i][r] = U(rng) * h;
  for (int attempt = 0; attempt < 60; ++attempt) {
    std::vector<double> X(3 * n);
    for (int i = 0; i < n; ++i)
      for (int r = 0; r < 3; ++r) X[3 * i + r] = base[i][r] + amp * pert[i][r];
    auto q = meshflow::model::element_quality(s, P, X.data());
    if (!q.valid && attempt == 0) {  // mirror the map to fix the orientation
      for (auto& b : base) b[0] = -b[0];
      for (auto& p : pert) p[0] = -p[0];
      continue;
    }
    if (q.valid) {
      Mesh m;
      add_groups(m);
      std::vector<std::uint32_t> ids(n);
      for (int i = 0; i < n; ++i) ids[i] = m.add_node(X[3 * i], X[3 * i + 1], X[3 * i + 2]);
      m.block(s, P, 3, kVol).add(ids.data());
      for (int f : walls) {
        const auto& fn = meshflow::model::face_nodes(s, P)[f];
        Shape fs = meshflow::model::face_vertices(s)[f].size() == 3 ? Shape::Tri : Shape::Quad;
        std::vector<std::uint32_t> fnid;
        for (int k : fn) fnid.push_back(ids[k]);
        m.block(fs, P, 2, kWall).add(fnid.data());
      }
      return m;
    }
    amp *= 0.7;
  }
  throw std::runtime_error("random_macro: could not make a valid element");
}

// The cylinder-on-plate junction mesh. Parametric space (theta, z, r) mapped by
// x = r cos(theta), y = r sin(theta), z. Near field (one layer, thickness d):
//   A: cylinder boundary layer, r in [R, R+d], z in [d, H]: prisms, wall r = R (2 tris per cell)
//   B: junction, r in [R, R+d], z in [0, d]: hexes with walls r = R and z = 0
//   C: plate boundary layer, r in [R+d, R2], z in [0, d]: prisms, wall z = 0
// with tets capping every outer prism face (their apexes above the face). Boundary faces:
// walls (cylinder and plate), symmetry at z = H (A's quads), farfield at r = R2 (C's quads).
// Nodes of the symmetry plane z = H carry (u, v) = (x, y) on entity kSym; a CAD line (1D
// elements) runs along theta = 0, z = H, r in [R, R+d] (a split edge of the symmetry plane).
struct Junction {
  Mesh mesh;
  std::size_t prisms_a = 0, prisms_c = 0, hexes = 0, tets = 0;
};

inline Junction junction_mesh(int P, int ntheta = 12, bool tets = true) {
  const double R = 1, d = 0.1, R2 = 1.5, H = 1.0;
  const std::vector<double> zl = {0, d, 0.4, 0.7, H}, rl = {R, R + d, R2};
  Junction J;
  Mesh& m = J.mesh;
  add_groups(m);
  const long NT = long(ntheta) * P;
  std::map<std::array<long, 3>, std::uint32_t> at;  // (theta, z, r) fine integer coordinates
  auto param = [&](double ti, double zi, double ri) {
    auto lv = [&](const std::vector<double>& L, double k) {
      long c = std::min(long(k) / P, long(L.size()) - 2);
      double f = (k - double(c) * P) / P;
      return L[c] + (L[c + 1] - L[c]) * f;
    };
    return Vec3{2 * kPi * ti / double(NT), lv(zl, zi), lv(rl, ri)};
  };
  auto xyz = [&](const Vec3& p) { return Vec3{p[2] * std::cos(p[0]), p[2] * std::sin(p[0]), p[1]}; };
  auto node = [&](long t, long z, long r) {
    t = ((t % NT) + NT) % NT;
    auto it = at.find({t, z, r});
    if (it != at.end()) return it->second;
    Vec3 x = xyz(param(double(t), double(z), double(r)));
    std::uint32_t id = m.add_node(x[0], x[1], x[2]);
    at[{t, z, r}] = id;
    return id;
  };
  const auto& plat = meshflow::model::lattice(Shape::Prism, P);
  const auto& hlat = meshflow::model::lattice(Shape::Hex, P);
  auto valid = [&](Shape s, const std::vector<std::uint32_t>& ids) {
    std::vector<double> X;
    for (auto i : ids) X.insert(X.end(), {m.x[i], m.y[i], m.z[i]});
    return meshflow::model::element_quality(s, P, X.data()).valid;
  };
  // a prism: triangle corners c[3] in the tangential fine coords (a, b), normal axis from n0
  // to n0 + P; `axes` maps (tangential a, tangential b, normal) to (theta, z, r) indices
  // a prism: triangle corners c[3] in the tangential fine coords (a, b), normal axis from n0
  // to n0 + P; `axes` maps (tangential a, tangential b, normal) to (theta, z, r) indices.
  // Returns its nodes and the fine (theta, z, r) coordinates of its outer vertices 3, 4, 5.
  using Outer = std::array<std::array<double, 3>, 3>;
  auto prism = [&](std::array<std::array<long, 2>, 3> c, std::array<int, 3> axes, long n0, int wall_ent) {
    for (int flip = 0; flip < 2; ++flip) {
      std::vector<std::uint32_t> ids;
      for (auto& l : plat) {
        long a = c[0][0] + ((c[1][0] - c[0][0]) * l[0] + (c[2][0] - c[0][0]) * l[1]) / P;
        long b = c[0][1] + ((c[1][1] - c[0][1]) * l[0] + (c[2][1] - c[0][1]) * l[1]) / P;
        long q[3];
        q[axes[0]] = a, q[axes[1]] = b, q[axes[2]] = n0 + l[2];
        ids.push_back(node(q[0], q[1], q[2]));
      }
      if (valid(Shape::Prism, ids)) {
        m.block(Shape::Prism, P, 3, kVol).add(ids.data());
        std::vector<std::uint32_t> w;
        for (int k : meshflow::model::face_nodes(Shape::Prism, P)[0]) w.push_back(ids[k]);
        m.block(Shape::Tri, P, 2, wall_ent).add(w.data());
        Outer o;
        for (int k = 0; k < 3; ++k) {
          o[k][axes[0]] = double(c[k][0]), o[k][axes[1]] = double(c[k][1]), o[k][axes[2]] = double(n0 + P);
        }
        return std::make_pair(ids, o);
      }
      std::swap(c[1], c[2]);
    }
    throw std::runtime_error("junction_mesh: invalid prism");
  };
  // a tet on the prism's outer face (face 1: vertices 3, 4, 5), straight in the parameter
  // space (theta, z, r) with its apex half a level beyond the face, mapped like the rest
  auto tet_cap = [&](const std::vector<std::uint32_t>& pr, const Outer& o, int normal_axis) {
    const auto& tl = meshflow::model::lattice(Shape::Tet, P);
    std::array<double, 3> apex{0, 0, 0};
    for (int k = 0; k < 3; ++k)
      for (int r = 0; r < 3; ++r) apex[r] += o[k][r] / 3;
    apex[normal_axis] += 0.5 * P;
    const auto& fn = meshflow::model::face_nodes(Shape::Prism, P)[1];
    const auto& tril = meshflow::model::lattice(Shape::Tri, P);
    std::map<std::pair<int, int>, std::uint32_t> face;  // face 1 lattice: (0,0)->3, (P,0)->4, (0,P)->5
    for (std::size_t k = 0; k < fn.size(); ++k) face[{tril[k][0], tril[k][1]}] = pr[fn[k]];
    const std::size_t before = m.num_nodes();
    for (int flip = 0; flip < 2; ++flip) {
      std::vector<std::uint32_t> ids;
      std::array<std::array<double, 3>, 4> V = {o[0], flip ? o[2] : o[1], flip ? o[1] : o[2], apex};
      for (auto& l : tl) {
        int i = flip ? l[1] : l[0], j = flip ? l[0] : l[1];
        if (l[2] == 0) {
          ids.push_back(face.at({i, j}));
          continue;
        }
        double pq[3];
        for (int r = 0; r < 3; ++r)
          pq[r] = V[0][r] + (V[1][r] - V[0][r]) * l[0] / P + (V[2][r] - V[0][r]) * l[1] / P + (V[3][r] - V[0][r]) * l[2] / P;
        Vec3 x = xyz(param(pq[0], pq[1], pq[2]));
        ids.push_back(m.add_node(x[0], x[1], x[2]));
      }
      if (valid(Shape::Tet, ids)) {
        m.block(Shape::Tet, P, 3, kVol).add(ids.data());
        ++J.tets;
        return;
      }
      m.x.resize(before), m.y.resize(before), m.z.resize(before);
    }
    throw std::runtime_error("junction_mesh: invalid tet");
  };
  const long ZL = long(zl.size() - 1) * P;
  // A: cells (theta i, z level j >= 1); tangential (theta, z), normal r from 0
  for (int i = 0; i < ntheta; ++i)
    for (std::size_t j = 1; j + 1 < zl.size(); ++j) {
      long t0 = long(i) * P, t1 = t0 + P, z0 = long(j) * P, z1 = z0 + P;
      for (auto tri : {std::array<std::array<long, 2>, 3>{{{t0, z0}, {t1, z0}, {t1, z1}}},
                       std::array<std::array<long, 2>, 3>{{{t0, z0}, {t1, z1}, {t0, z1}}}}) {
        auto [pr, outer] = prism(tri, {0, 1, 2}, 0, kWall);
        ++J.prisms_a;
        if (tets) tet_cap(pr, outer, 2);
      }
      if (z1 == ZL) {  // symmetry quad (r x theta) at z = H: faces of A's prisms
        std::vector<std::uint32_t> q;
        for (auto& l : meshflow::model::lattice(Shape::Quad, P)) q.push_back(node(t0 + l[1], z1, l[0]));
        m.block(Shape::Quad, P, 2, kSym).add(q.data());
      }
    }
  // B: junction hexes, xi -> r, eta -> theta, zeta -> z (orientation checked)
  for (int i = 0; i < ntheta; ++i) {
    for (int flip = 0; flip < 2; ++flip) {
      std::vector<std::uint32_t> ids;
      for (auto& l : hlat) ids.push_back(node(long(i) * P + (flip ? P - l[1] : l[1]), l[2], l[0]));
      if (!valid(Shape::Hex, ids)) {
        if (flip) throw std::runtime_error("junction_mesh: invalid hex");
        continue;
      }
      m.block(Shape::Hex, P, 3, kVol).add(ids.data());
      ++J.hexes;
      // wall faces: the hex faces at r = R (xi = -1: face 2) and z = 0 (zeta = -1: face 0)
      for (int f : {2, 0}) {
        std::vector<std::uint32_t> w;
        for (int k : meshflow::model::face_nodes(Shape::Hex, P)[f]) w.push_back(ids[k]);
        m.block(Shape::Quad, P, 2, f == 2 ? kWall : kWall2).add(w.data());
      }
      break;
    }
  }
  // C: cells (theta i, r level 1); tangential (theta, r), normal z from 0
  for (int i = 0; i < ntheta; ++i) {
    long t0 = long(i) * P, t1 = t0 + P, r0 = P, r1 = 2 * P;
    for (auto tri : {std::array<std::array<long, 2>, 3>{{{t0, r0}, {t1, r0}, {t1, r1}}},
                     std::array<std::array<long, 2>, 3>{{{t0, r0}, {t1, r1}, {t0, r1}}}}) {
      auto [pr, outer] = prism(tri, {0, 2, 1}, 0, kWall2);
      ++J.prisms_c;
      if (tets) tet_cap(pr, outer, 1);
    }
    std::vector<std::uint32_t> q;  // farfield quad at r = R2 (theta x z)
    for (auto& l : meshflow::model::lattice(Shape::Quad, P)) q.push_back(node(t0 + l[0], l[1], r1));
    m.block(Shape::Quad, P, 2, kFar).add(q.data());
  }
  // a CAD line along r at theta = 0, z = H, r in [R, R+d] (a split edge of the symmetry plane)
  {
    std::vector<std::uint32_t> l = {node(0, ZL, 0), node(0, ZL, P)};
    for (int k = 1; k < P; ++k) l.push_back(node(0, ZL, k));
    m.block(Shape::Line, P, 1, kLine).add(l.data());
  }
  // classification: nodes of the symmetry plane z = H on (2, kSym) with (u, v) = (x, y); the
  // others on the volume
  m.node_entity_dim.assign(m.num_nodes(), 3);
  m.node_entity_tag.assign(m.num_nodes(), kVol);
  m.node_u.assign(m.num_nodes(), NAN);
  m.node_v.assign(m.num_nodes(), NAN);
  for (auto& [k, id] : at)
    if (k[1] == ZL && k[2] <= P) {
      m.node_entity_dim[id] = 2, m.node_entity_tag[id] = kSym;
      m.node_u[id] = m.x[id], m.node_v[id] = m.y[id];
    }
  m.check();
  return J;
}

}  // namespace splittest
