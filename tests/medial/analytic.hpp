// Analytic boundary models for the medial tests: shapes whose medial object is known, built
// directly as BoundaryModels (faces with (u,v) maps, edges, vertices), no CAD needed.
#pragma once

#include "stages/medial/medial.hpp"

#include <cmath>
#include <functional>
#include <vector>

namespace mftest {

using meshflow::medial::Vec3;

inline Vec3 add(Vec3 a, Vec3 b) { return {a[0] + b[0], a[1] + b[1], a[2] + b[2]}; }
inline Vec3 mul(double s, Vec3 a) { return {s * a[0], s * a[1], s * a[2]}; }
inline double norm(Vec3 a) { return std::sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]); }
inline Vec3 unit(Vec3 a) {
  double l = norm(a);
  return l > 0 ? mul(1 / l, a) : Vec3{0, 0, 0};
}

class AnalyticModel : public meshflow::medial::BoundaryModel {
 public:
  struct Face {
    std::array<double, 4> b;
    std::function<Vec3(double, double)> P, N;  // point, normal out of the domain
    double kappa = 0;
    std::function<bool(double, double)> in = [](double, double) { return true; };
    bool refined = true;
  };
  struct Edge {
    std::array<double, 2> r;
    std::function<Vec3(double)> P;
    std::vector<int> faces;
    std::function<Vec3(double)> N;
  };
  struct Vertex {
    Vec3 p, n;
    std::vector<int> faces;
  };
  std::vector<Face> F;
  std::vector<Edge> E;
  std::vector<Vertex> V;

  int num_faces() const override { return (int)F.size(); }
  std::array<double, 4> face_bounds(int f) const override { return F[f].b; }
  Vec3 face_point(int f, double u, double v) const override { return F[f].P(u, v); }
  Vec3 face_normal(int f, double u, double v) const override { return F[f].N(u, v); }
  double face_curvature(int f, double, double) const override { return F[f].kappa; }
  bool face_contains(int f, double u, double v) const override { return F[f].in(u, v); }
  bool face_refined(int f) const override { return F[f].refined; }
  int num_edges() const override { return (int)E.size(); }
  bool edge_degenerate(int) const override { return false; }
  std::array<double, 2> edge_range(int e) const override { return E[e].r; }
  Vec3 edge_point(int e, double t) const override { return E[e].P(t); }
  Vec3 edge_normal(int e, double t) const override { return E[e].N(t); }
  std::vector<int> edge_faces(int e) const override { return E[e].faces; }
  int num_vertices() const override { return (int)V.size(); }
  Vec3 vertex_point(int v) const override { return V[v].p; }
  Vec3 vertex_normal(int v) const override { return V[v].n; }
  std::vector<int> vertex_faces(int v) const override { return V[v].faces; }

  // An axis-aligned box [lo,hi]. inside = true: the domain is the inside of the box (normals
  // outward); false: the box is a body (normals point into it). Faces are numbered from
  // F.size(): -x, +x, -y, +y, -z, +z. `skip_face` (0..5) leaves a face out (with its edges and
  // vertices kept, attached to the remaining faces) — used for a block standing on a floor.
  void box(Vec3 lo, Vec3 hi, bool inside, bool refined, int skip_face = -1,
           std::function<bool(int, double, double)> face_in = {}) {
    const int base = (int)F.size();
    const double sg = inside ? 1 : -1;
    std::vector<int> id(6, -1);
    for (int k = 0; k < 6; ++k) {
      if (k == skip_face) continue;
      int ax = k / 2, a1 = (ax + 1) % 3, a2 = (ax + 2) % 3;
      double x = (k % 2) ? hi[ax] : lo[ax];
      Vec3 n{0, 0, 0};
      n[ax] = sg * ((k % 2) ? 1 : -1);
      Face f;
      f.b = {lo[a1], hi[a1], lo[a2], hi[a2]};
      f.P = [=](double u, double v) {
        Vec3 p;
        p[ax] = x, p[a1] = u, p[a2] = v;
        return p;
      };
      f.N = [=](double, double) { return n; };
      if (face_in) f.in = [=](double u, double v) { return face_in(k, u, v); };
      f.refined = refined;
      id[k] = base + (int)(F.size() - base);
      F.push_back(f);
    }
    // edges: along axis ax at the corner (a1 side s1, a2 side s2)
    for (int ax = 0; ax < 3; ++ax) {
      int a1 = (ax + 1) % 3, a2 = (ax + 2) % 3;
      for (int s1 = 0; s1 < 2; ++s1)
        for (int s2 = 0; s2 < 2; ++s2) {
          int f1 = id[2 * a1 + s1], f2 = id[2 * a2 + s2];
          std::vector<int> fs;
          if (f1 >= 0) fs.push_back(f1);
          if (f2 >= 0) fs.push_back(f2);
          Vec3 n{0, 0, 0};
          n[a1] = sg * (s1 ? 1 : -1), n[a2] = sg * (s2 ? 1 : -1);
          if (f1 < 0) n[a1] = 0;
          if (f2 < 0) n[a2] = 0;
          n = unit(n);
          Vec3 c;
          c[a1] = s1 ? hi[a1] : lo[a1], c[a2] = s2 ? hi[a2] : lo[a2];
          Edge e;
          e.r = {lo[ax], hi[ax]};
          e.P = [=](double t) {
            Vec3 p = c;
            p[ax] = t;
            return p;
          };
          e.N = [=](double) { return n; };
          e.faces = fs;
          E.push_back(e);
        }
    }
    for (int s = 0; s < 8; ++s) {
      Vertex v;
      Vec3 n;
      for (int ax = 0; ax < 3; ++ax) {
        int side = (s >> ax) & 1;
        v.p[ax] = side ? hi[ax] : lo[ax];
        n[ax] = sg * (side ? 1 : -1);
        if (id[2 * ax + side] >= 0) v.faces.push_back(id[2 * ax + side]);
        else n[ax] = 0;
      }
      v.n = unit(n);
      V.push_back(v);
    }
  }

  // A sphere: the domain outside (body) when `body`, normals into it.
  void sphere(Vec3 c, double R, bool body, bool refined) {
    Face f;
    f.b = {0, 2 * M_PI, -M_PI / 2, M_PI / 2};
    f.P = [=](double u, double v) { return add(c, Vec3{R * std::cos(v) * std::cos(u), R * std::cos(v) * std::sin(u), R * std::sin(v)}); };
    double sg = body ? -1 : 1;
    f.N = [=](double u, double v) { return Vec3{sg * std::cos(v) * std::cos(u), sg * std::cos(v) * std::sin(u), sg * std::sin(v)}; };
    f.kappa = 1 / R;
    f.refined = refined;
    F.push_back(f);
  }
};

// Fluid inside a capped cylinder of radius R, axis z, z in [0, L].
inline AnalyticModel cylinder(double R, double L) {
  AnalyticModel m;
  AnalyticModel::Face lat;
  lat.b = {0, 2 * M_PI, 0, L};
  lat.P = [=](double u, double v) { return Vec3{R * std::cos(u), R * std::sin(u), v}; };
  lat.N = [=](double u, double) { return Vec3{std::cos(u), std::sin(u), 0}; };
  lat.kappa = 1 / R;
  m.F.push_back(lat);
  for (int k = 0; k < 2; ++k) {
    AnalyticModel::Face cap;
    double z = k ? L : 0, nz = k ? 1 : -1;
    cap.b = {-R, R, -R, R};
    cap.P = [=](double u, double v) { return Vec3{u, v, z}; };
    cap.N = [=](double, double) { return Vec3{0, 0, nz}; };
    cap.in = [=](double u, double v) { return u * u + v * v < R * R; };
    m.F.push_back(cap);
    AnalyticModel::Edge circle;
    circle.r = {0, 2 * M_PI};
    circle.P = [=](double t) { return Vec3{R * std::cos(t), R * std::sin(t), z}; };
    circle.N = [=](double t) { return unit(Vec3{std::cos(t), std::sin(t), nz}); };
    circle.faces = {0, 1 + k};
    m.E.push_back(circle);
    m.V.push_back({Vec3{R, 0, z}, unit(Vec3{1, 0, nz}), {0, 1 + k}});
  }
  AnalyticModel::Edge seam;
  seam.r = {0, L};
  seam.P = [=](double t) { return Vec3{R, 0, t}; };
  seam.N = [=](double) { return Vec3{1, 0, 0}; };
  seam.faces = {0};
  m.E.push_back(seam);
  return m;
}

}  // namespace mftest
