// meshflow curve — the bottom-up placement of high-order nodes (see curve.hpp).
#include "stages/curve/curve.hpp"

#include "engine/stage.hpp"
#include "stages/cad/cad.hpp"
#include "stages/model/basis.hpp"
#include "stages/model/element.hpp"
#include "stages/model/quality.hpp"

#include <Eigen/Dense>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <map>
#include <memory>
#include <optional>
#include <sstream>
#include <unordered_map>

namespace meshflow::curve {
namespace {

using model::Lattice;
using model::Mesh;
using model::Shape;
using V3 = std::array<double, 3>;
using UV = std::array<double, 2>;
using Clock = std::chrono::steady_clock;

double secs(Clock::time_point a) { return std::chrono::duration<double>(Clock::now() - a).count(); }
double dist2(const UV& a, const UV& b) { return (a[0] - b[0]) * (a[0] - b[0]) + (a[1] - b[1]) * (a[1] - b[1]); }
double norm3(const cad::Vec3& a) { return std::sqrt(a.x * a.x + a.y * a.y + a.z * a.z); }

// ── Per (shape, order) tables: reference nodes, vertex weights, boundary/interior, stencils ──
struct Tables {
  Shape s = Shape::Tet;
  int P = 1, n = 0, nv = 0, dim = 0;
  std::vector<model::Vec3> ref;
  std::vector<Lattice> lat;
  std::map<Lattice, int> at_lat;                    // lattice point -> local node
  std::map<std::array<long, 3>, int> at_ref;        // round(ref * P) -> local node
  std::vector<double> w;                            // n x nv order-1 weights (rounded to k/P^3 when exact)
  std::vector<long> wi;                             // n x nv integer weights (w * P^3), -1 when not integral
  std::vector<char> boundary;                       // node on an edge (2D) / face (3D) / vertex (1D)
  std::vector<int> interior, bnd;
  Eigen::MatrixXd H;                                // interior x bnd: discrete harmonic extension
  std::vector<std::vector<int>> edge_line;          // 2D: per edge, local nodes k = 0..P along it
  int local(const model::Vec3& r) const {
    auto it = at_ref.find({std::lround(r[0] * P), std::lround(r[1] * P), std::lround(r[2] * P)});
    return it == at_ref.end() ? -1 : it->second;
  }
};

std::vector<Lattice> stencil(Shape s) {
  switch (s) {
    case Shape::Line: return {{1, 0, 0}, {-1, 0, 0}};
    case Shape::Tri: return {{1, 0, 0}, {-1, 0, 0}, {0, 1, 0}, {0, -1, 0}, {1, -1, 0}, {-1, 1, 0}};
    case Shape::Quad: return {{1, 0, 0}, {-1, 0, 0}, {0, 1, 0}, {0, -1, 0}};
    case Shape::Hex: return {{1, 0, 0}, {-1, 0, 0}, {0, 1, 0}, {0, -1, 0}, {0, 0, 1}, {0, 0, -1}};
    case Shape::Tet: {
      std::vector<Lattice> o;
      for (int a = 0; a < 3; ++a) {
        Lattice e{0, 0, 0};
        e[a] = 1;
        o.push_back(e);
        e[a] = -1;
        o.push_back(e);
        for (int b = a + 1; b < 3; ++b) {
          Lattice d{0, 0, 0};
          d[a] = 1, d[b] = -1;
          o.push_back(d);
          d[a] = -1, d[b] = 1;
          o.push_back(d);
        }
      }
      return o;
    }
    case Shape::Prism:
      return {{1, 0, 0}, {-1, 0, 0}, {0, 1, 0}, {0, -1, 0}, {1, -1, 0}, {-1, 1, 0}, {0, 0, 1}, {0, 0, -1}};
    case Shape::Pyramid:  // k = layer from the apex, 0 <= i, j <= k: a body-centred stencil
      return {{1, 0, 0}, {-1, 0, 0}, {0, 1, 0},  {0, -1, 0},  {0, 0, 1},   {1, 0, 1},
              {0, 1, 1}, {1, 1, 1},  {0, 0, -1}, {-1, 0, -1}, {0, -1, -1}, {-1, -1, -1}};
    default: return {};
  }
}

Tables make_tables(Shape s, int P) {
  Tables T;
  T.s = s, T.P = P, T.dim = model::dimension(s), T.nv = model::num_vertices(s);
  T.ref = model::reference_nodes(s, P);
  T.lat = model::lattice(s, P);
  T.n = int(T.ref.size());
  for (int i = 0; i < T.n; ++i) {
    T.at_lat[T.lat[i]] = i;
    T.at_ref[{std::lround(T.ref[i][0] * P), std::lround(T.ref[i][1] * P), std::lround(T.ref[i][2] * P)}] = i;
  }
  const auto& b1 = model::LagrangeBasis::get(s, 1);
  const double P3 = double(P) * P * P;
  T.w.assign(std::size_t(T.n) * T.nv, 0.0);
  T.wi.assign(std::size_t(T.n) * T.nv, -1);
  std::vector<double> N(T.nv);
  for (int i = 0; i < T.n; ++i) {
    if (i < T.nv) {
      for (int v = 0; v < T.nv; ++v) T.w[i * T.nv + v] = v == i, T.wi[i * T.nv + v] = v == i ? long(P3) : 0;
      continue;
    }
    b1.eval(T.ref[i], N.data());
    for (int v = 0; v < T.nv; ++v) {
      double k = N[v] * P3;
      long r = std::lround(k);
      if (std::abs(k - double(r)) < 1e-7) {
        T.w[i * T.nv + v] = double(r) / P3;
        T.wi[i * T.nv + v] = r;
      } else {
        T.w[i * T.nv + v] = N[v];
      }
    }
  }
  T.boundary.assign(T.n, 0);
  if (T.dim == 3) {
    for (auto& f : model::face_nodes(s, P))
      for (int i : f) T.boundary[i] = 1;
  } else if (T.dim == 2) {
    for (auto& e : model::edge_nodes(s, P))
      for (int i : e) T.boundary[i] = 1;
    for (auto [a, b] : model::edge_vertices(s)) {
      std::vector<int> line;
      for (int k = 0; k <= P; ++k) {
        Lattice l;
        for (int c = 0; c < 3; ++c) l[c] = (T.lat[a][c] * (P - k) + T.lat[b][c] * k) / P;
        line.push_back(T.at_lat.at(l));
      }
      T.edge_line.push_back(line);
    }
  } else {
    for (int v = 0; v < T.nv; ++v) T.boundary[v] = 1;
  }
  for (int i = 0; i < T.n; ++i) (T.boundary[i] ? T.bnd : T.interior).push_back(i);
  // Discrete harmonic extension: each interior node is the mean of its stencil neighbours.
  const int ni = int(T.interior.size()), nb = int(T.bnd.size());
  if (ni > 0) {
    std::vector<int> pos_i(T.n, -1), pos_b(T.n, -1);
    for (int a = 0; a < ni; ++a) pos_i[T.interior[a]] = a;
    for (int a = 0; a < nb; ++a) pos_b[T.bnd[a]] = a;
    Eigen::MatrixXd A = Eigen::MatrixXd::Identity(ni, ni), B = Eigen::MatrixXd::Zero(ni, nb);
    auto st = stencil(s);
    for (int a = 0; a < ni; ++a) {
      const Lattice& l = T.lat[T.interior[a]];
      std::vector<int> nb_nodes;
      for (auto& o : st) {
        auto it = T.at_lat.find({l[0] + o[0], l[1] + o[1], l[2] + o[2]});
        if (it == T.at_lat.end())
          throw std::logic_error(std::string("curve: stencil of ") + model::shape_name(s) + " leaves the lattice");
        nb_nodes.push_back(it->second);
      }
      for (int j : nb_nodes) {
        double c = 1.0 / double(nb_nodes.size());
        if (pos_i[j] >= 0) A(a, pos_i[j]) -= c;
        else B(a, pos_b[j]) += c;
      }
    }
    T.H = A.partialPivLu().solve(B);
  }
  return T;
}

// Lagrange interpolation on P+1 equispaced nodes of [0,1].
void lagrange1d(int P, double s, double* L) {
  for (int k = 0; k <= P; ++k) {
    double v = 1, xk = double(k) / P;
    for (int j = 0; j <= P; ++j)
      if (j != k) v *= (s - double(j) / P) / (xk - double(j) / P);
    L[k] = v;
  }
}

// Fills D at the interior nodes of a triangle/quad of tables T from D at its boundary nodes
// (D at the vertices must be zero): Coons on quads, edge blending on triangles. C components.
template <int C>
void tfi2d(const Tables& T, std::vector<std::array<double, C>>& D) {
  const int P = T.P;
  std::vector<double> L(P + 1);
  for (int i : T.interior) {
    std::array<double, C> r{};
    const Lattice& l = T.lat[i];
    if (T.s == Shape::Quad) {
      double s = double(l[0]) / P, t = double(l[1]) / P;
      int b = T.at_lat.at({l[0], 0, 0}), tp = T.at_lat.at({l[0], P, 0});
      int lf = T.at_lat.at({0, l[1], 0}), rt = T.at_lat.at({P, l[1], 0});
      for (int c = 0; c < C; ++c) r[c] = (1 - t) * D[b][c] + t * D[tp][c] + (1 - s) * D[lf][c] + s * D[rt][c];
    } else {
      double lam[3] = {1.0 - double(l[0] + l[1]) / P, double(l[0]) / P, double(l[1]) / P};
      const auto& ev = model::edge_vertices(Shape::Tri);
      for (std::size_t e = 0; e < ev.size(); ++e) {
        double la = lam[ev[e][0]], lb = lam[ev[e][1]], ws = la + lb;
        if (ws < 1e-14) continue;
        lagrange1d(P, lb / ws, L.data());
        for (int k = 0; k <= P; ++k)
          for (int c = 0; c < C; ++c) r[c] += ws * L[k] * D[T.edge_line[e][k]][c];
      }
    }
    D[i] = r;
  }
}

// τ_k (k = 1..P-1) in (0,1) with arc(0, τ_k) = k/P arc(0, 1) for a path of speed |dx/dτ|.
// Gauss-Legendre (3 points) on 2P sub-intervals, then Newton inside the sub-interval.
template <class Speed>
std::vector<double> equal_arc(int P, const Speed& speed) {
  static const double gx[3] = {-0.7745966692414834, 0.0, 0.7745966692414834};
  static const double gw[3] = {5.0 / 9.0, 8.0 / 9.0, 5.0 / 9.0};
  auto integ = [&](double a, double b) {
    double s = 0, h = 0.5 * (b - a), m = 0.5 * (a + b);
    for (int q = 0; q < 3; ++q) s += gw[q] * speed(m + h * gx[q]);
    return s * h;
  };
  const int M = 2 * P;
  std::vector<double> cum(M + 1, 0.0);
  for (int m = 0; m < M; ++m) cum[m + 1] = cum[m] + integ(double(m) / M, double(m + 1) / M);
  std::vector<double> tau(P - 1);
  for (int k = 1; k < P; ++k) tau[k - 1] = double(k) / P;
  if (!(cum[M] > 1e-300) || !std::isfinite(cum[M])) return tau;
  for (int k = 1; k < P; ++k) {
    double target = cum[M] * k / P;
    int m = 0;
    while (m < M - 1 && cum[m + 1] < target) ++m;
    double a = double(m) / M, b = double(m + 1) / M;
    double seg = cum[m + 1] - cum[m];
    double t = seg > 0 ? a + (target - cum[m]) / seg * (b - a) : 0.5 * (a + b);
    for (int it = 0; it < 5; ++it) {
      double f = cum[m] + integ(a, t) - target, sp = speed(t);
      if (!(sp > 1e-300)) break;
      double tn = std::clamp(t - f / sp, a, b);
      if (std::abs(tn - t) < 1e-15) {
        t = tn;
        break;
      }
      t = tn;
    }
    tau[k - 1] = t;
  }
  return tau;
}

// ── keys ────────────────────────────────────────────────────────────────────────────────
using NodeKey = std::array<std::uint64_t, 4>;  // sorted (vertex << 16 | weight), padding ~0
struct KeyHash {
  std::size_t operator()(const NodeKey& k) const {
    std::uint64_t h = 1469598103934665603ull;
    for (auto v : k) h = (h ^ v) * 1099511628211ull;
    return std::size_t(h);
  }
};
using EdgeKey = std::array<std::uint32_t, 2>;
using FaceKey = std::array<std::uint32_t, 4>;
FaceKey face_key(const std::uint32_t* v, int n) {
  FaceKey k{UINT32_MAX, UINT32_MAX, UINT32_MAX, UINT32_MAX};
  n = std::clamp(n, 0, 4);
  for (int i = 0; i < n; ++i) k[i] = v[i];
  std::sort(k.begin(), k.end());  // the padding sorts last
  return k;
}

enum Src : std::uint8_t { kVertex = 0, kCurve, kSurface, kNear, kStraight, kBlend, kInterior };

struct EdgeEnt {
  std::uint32_t a = 0, b = 0;          // vertex nodes, a < b
  std::vector<std::uint32_t> nodes;    // P-1 nodes from a to b
  int cad_edge = -1;                   // rule 1
  int face = -1, el_block = -1;        // first 2D element on a CAD face containing it
  std::size_t el = 0;
  bool wall = false, near = false;
  int rule = kStraight;
};
struct FaceEnt {
  Shape s = Shape::Tri;
  std::vector<std::uint32_t> nodes;    // face-local Gmsh order
  int face = -1, el_block = -1;        // its 2D element on a CAD face, if any
  std::size_t el = 0;
  bool wall = false, near = false;
  int rule = kBlend;
};
struct Chart {
  std::array<UV, 4> uv{};
  std::array<char, 4> pole{};
  std::array<std::array<UV, 2>, 4> pole_seg{};
};
struct NearEl {
  std::uint32_t block = 0;
  std::size_t el = 0;
  std::vector<std::pair<int, double>> walls;  // (reference axis, value) per wall face
};

struct FaceInfo {
  std::vector<int> edges;
  std::vector<UV> periods;
};
struct EdgeInfo {
  std::array<int, 2> verts{};
  cad::Range range;
  bool degenerate = false;
  std::vector<int> faces;
};

class Curver {
 public:
  Curver(const Mesh& in, const cad::Shape& S, const Options& o, Report& R, const std::function<void(const std::string&)>& log)
      : in_(in), S_(S), O_(o), R_(R), log_(log),
        clones_([&S] { return std::shared_ptr<cad::Shape>(new cad::Shape(S.clone())); }) {}

  Mesh run();

 private:
  const Mesh& in_;
  const cad::Shape& S_;
  Options O_;
  Report& R_;
  const std::function<void(const std::string&)>& log_;
  tbb::enumerable_thread_specific<std::shared_ptr<cad::Shape>> clones_;
  int P_ = 4;
  Mesh m_;
  std::vector<double> Xs_;  // straight positions, 3 per node
  std::vector<std::uint8_t> src_;
  std::map<std::pair<Shape, int>, Tables> tables_;
  std::vector<EdgeEnt> edges_;
  std::vector<FaceEnt> faces_;
  std::map<EdgeKey, std::size_t> edge_of_;
  std::map<FaceKey, std::size_t> face_of_;
  std::vector<std::vector<Chart>> charts_;  // per block (2D blocks on CAD faces), per element
  std::vector<std::vector<int>> near_of_;   // per block, per element: index in near_, -1 (far field) or kNearNoFollow
  static constexpr int kNearNoFollow = -2;  // a near-field element while follow_wall is off
  std::vector<NearEl> near_;
  std::vector<FaceInfo> finfo_;
  std::vector<EdgeInfo> einfo_;
  std::vector<char> wall_entity_;           // by CAD face id
  std::atomic<std::size_t> fallback_{0}, seam_{0}, pole_{0};

  void log(const std::string& s) {
    if (log_) log_(s);
  }
  cad::Shape& shape() { return *clones_.local(); }
  const Tables& tab(Shape s, int P) {
    auto k = std::make_pair(s, P);
    auto it = tables_.find(k);
    if (it == tables_.end()) it = tables_.emplace(k, make_tables(s, P)).first;
    return it->second;
  }
  const Tables& ctab(Shape s) const { return tables_.at({s, P_}); }
  V3 X(std::uint32_t n) const { return {m_.x[n], m_.y[n], m_.z[n]}; }
  void setX(std::uint32_t n, const V3& p) { m_.x[n] = p[0], m_.y[n] = p[1], m_.z[n] = p[2]; }
  V3 D(std::uint32_t n) const { return {m_.x[n] - Xs_[3 * n], m_.y[n] - Xs_[3 * n + 1], m_.z[n] - Xs_[3 * n + 2]}; }
  void classify(std::uint32_t n, int dim, int tag, double u, double v) {
    m_.node_entity_dim[n] = dim, m_.node_entity_tag[n] = tag, m_.node_u[n] = u, m_.node_v[n] = v;
  }

  void validate();
  void create_nodes();
  void build_entities();
  void build_cad_info();
  std::vector<UV> candidates(std::uint32_t n, int f, bool& pole, std::array<UV, 2>& seg, const UV* hint);
  UV nearest(const std::vector<UV>& c, int f, const UV& target) const;
  void make_charts();
  double end_t(std::uint32_t n, int e, std::optional<double> other);
  void rule1_edge(EdgeEnt& E);
  void rule2_edge(EdgeEnt& E);
  void rule2_face(FaceEnt& F);
  void near_field();
  void blend_face(FaceEnt& F);
  void interior(std::uint32_t b, std::size_t e);
  void report_distances();
  void check_quality(const Mesh& out);
  template <class F>
  void pfor(std::size_t n, const F& f) {
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 16), [&](const tbb::blocked_range<std::size_t>& r) {
      for (std::size_t i = r.begin(); i != r.end(); ++i) f(i);
    });
  }
};

void Curver::validate() {
  if (O_.order < 2 || O_.order > 6)
    throw StageError("curve: order " + std::to_string(O_.order) +
                     " is outside 2..6 (the Gmsh node orderings and the Bezier validity proof cover P <= 6); set with.order to 2..6");
  const std::size_t N = in_.num_nodes();
  if (in_.node_entity_dim.size() != N || in_.node_entity_tag.size() != N || in_.node_u.size() != N || in_.node_v.size() != N)
    throw StageError(
        "curve: the input mesh has no CAD classification of its nodes (entity and parametric coordinates of each node); "
        "curve needs the linear mesh of the sweep/tet contract (stages/sweep/sweep.hpp): give it the `mesh` of a tet stage");
  bool any_cad = false;
  for (auto& b : in_.blocks) {
    if (b.order != 1)
      throw StageError(std::string("curve: the input mesh is already of order ") + std::to_string(b.order) + " (" +
                       model::shape_name(b.shape) + " block on entity (" + std::to_string(b.entity_dim) + ", " +
                       std::to_string(b.entity_tag) + ")); curve needs the linear mesh of tet");
    if (b.shape == Shape::Point) continue;
    if (b.entity_dim == 2 && b.size() > 0) {
      if (b.entity_tag < 1 || b.entity_tag > S_.num_faces())
        throw StageError("curve: 2D elements on entity (2, " + std::to_string(b.entity_tag) + ") but the shape has " +
                         std::to_string(S_.num_faces()) + " faces: the mesh was not made from this shape (check needs:)");
      any_cad = true;
    }
    if (b.entity_dim == 1 && b.size() > 0 && (b.entity_tag < 1 || b.entity_tag > S_.num_edges()))
      throw StageError("curve: lines on entity (1, " + std::to_string(b.entity_tag) + ") but the shape has " +
                       std::to_string(S_.num_edges()) + " edges: the mesh was not made from this shape");
  }
  if (!any_cad)
    throw StageError("curve: the input mesh has no boundary faces on CAD faces (2D elements on entities (2, f+1)); "
                     "nothing can be curved: give it the `mesh` of a tet stage");
  std::size_t classified = 0;
  for (std::size_t i = 0; i < N; ++i) {
    int d = in_.node_entity_dim[i], t = in_.node_entity_tag[i];
    if (d == 0 && (t < 1 || t > S_.num_vertices()))
      throw StageError("curve: node " + std::to_string(in_.node_tag(i)) + " is classified on vertex " + std::to_string(t - 1) +
                       " which the shape does not have: the mesh was not made from this shape");
    if (d == 1 && (t < 1 || t > S_.num_edges()))
      throw StageError("curve: node " + std::to_string(in_.node_tag(i)) + " is classified on edge " + std::to_string(t - 1) +
                       " which the shape does not have: the mesh was not made from this shape");
    if (d == 2 && (t < 1 || t > S_.num_faces()))
      throw StageError("curve: node " + std::to_string(in_.node_tag(i)) + " is classified on face " + std::to_string(t - 1) +
                       " which the shape does not have: the mesh was not made from this shape");
    if (d == 1 && std::isfinite(in_.node_u[i])) {
      cad::Range r = S_.edge_range(t - 1);
      double tol = 1e-7 * std::max(1.0, r.hi - r.lo);
      if (in_.node_u[i] < r.lo - tol || in_.node_u[i] > r.hi + tol)
        throw StageError("curve: node " + std::to_string(in_.node_tag(i)) + " is classified on edge " + std::to_string(t - 1) +
                         " with parameter " + std::to_string(in_.node_u[i]) + " outside the edge's range [" + std::to_string(r.lo) +
                         ", " + std::to_string(r.hi) + "]: the mesh does not follow the contract (node_u must be the edge's own parameter)");
    }
    if ((d == 1 && std::isfinite(in_.node_u[i])) || (d == 2 && std::isfinite(in_.node_u[i]) && std::isfinite(in_.node_v[i])) || d == 0)
      ++classified;
  }
  if (classified == 0)
    throw StageError("curve: no node of the input mesh lies on the CAD with parameters (all are classified on volumes or "
                     "unclassified); curve needs the linear mesh of the sweep/tet contract");
}

void Curver::create_nodes() {
  const std::size_t N = in_.num_nodes();
  m_.x = in_.x, m_.y = in_.y, m_.z = in_.z;
  m_.node_entity_dim = in_.node_entity_dim, m_.node_entity_tag = in_.node_entity_tag;
  m_.node_u = in_.node_u, m_.node_v = in_.node_v;
  m_.node_tags = in_.node_tags;
  m_.entities = in_.entities, m_.physicals = in_.physicals, m_.periodic = in_.periodic;
  Xs_.resize(3 * N);
  for (std::size_t i = 0; i < N; ++i) Xs_[3 * i] = in_.x[i], Xs_[3 * i + 1] = in_.y[i], Xs_[3 * i + 2] = in_.z[i];
  src_.assign(N, kVertex);
  std::uint64_t next_tag = 0;
  for (auto t : in_.node_tags) next_tag = std::max(next_tag, t);
  std::unordered_map<NodeKey, std::uint32_t, KeyHash> keyed;
  auto new_node = [&](const V3& xs, int dim, int tag) {
    std::uint32_t i = std::uint32_t(m_.x.size());
    m_.x.push_back(xs[0]), m_.y.push_back(xs[1]), m_.z.push_back(xs[2]);
    m_.node_entity_dim.push_back(dim), m_.node_entity_tag.push_back(tag);
    m_.node_u.push_back(NAN), m_.node_v.push_back(NAN);
    if (!m_.node_tags.empty()) m_.node_tags.push_back(++next_tag);
    Xs_.insert(Xs_.end(), xs.begin(), xs.end());
    src_.push_back(kStraight);
    return i;
  };
  for (auto& ib : in_.blocks) {
    model::ElementBlock ob;
    ob.shape = ib.shape, ob.entity_dim = ib.entity_dim, ob.entity_tag = ib.entity_tag, ob.tags = ib.tags;
    ob.order = ib.shape == Shape::Point ? 1 : P_;
    if (ib.shape == Shape::Point) {
      ob.nodes = ib.nodes;
      m_.blocks.push_back(std::move(ob));
      continue;
    }
    const Tables& T = tab(ib.shape, P_);
    const int nv = T.nv;
    ob.nodes.resize(ib.size() * std::size_t(T.n));
    for (std::size_t e = 0; e < ib.size(); ++e) {
      const std::uint32_t* v = ib.element(e);
      std::uint32_t* o = ob.nodes.data() + e * std::size_t(T.n);
      for (int i = 0; i < nv; ++i) o[i] = v[i];
      for (int i = nv; i < T.n; ++i) {
        V3 xs{0, 0, 0};
        for (int a = 0; a < nv; ++a) {
          double w = T.w[i * nv + a];
          if (w == 0) continue;
          xs[0] += w * in_.x[v[a]], xs[1] += w * in_.y[v[a]], xs[2] += w * in_.z[v[a]];
        }
        if (T.dim == 3 && !T.boundary[i]) {
          o[i] = new_node(xs, ib.entity_dim, ib.entity_tag);
          src_[o[i]] = kInterior;
          continue;
        }
        std::vector<std::pair<std::uint32_t, long>> kv;
        for (int a = 0; a < nv; ++a) {
          long wi = T.wi[i * nv + a];
          if (wi < 0)
            throw std::logic_error(std::string("curve: non-integral weight on a boundary node of a ") + model::shape_name(ib.shape));
          if (wi > 0) kv.push_back({v[a], wi});
        }
        if (kv.size() < 2 || kv.size() > 4) throw std::logic_error("curve: boundary node with " + std::to_string(kv.size()) + " vertex weights");
        std::sort(kv.begin(), kv.end());
        NodeKey k{~0ull, ~0ull, ~0ull, ~0ull};
        for (std::size_t a = 0; a < kv.size(); ++a) k[a] = (std::uint64_t(kv[a].first) << 16) | std::uint64_t(kv[a].second);
        auto it = keyed.find(k);
        if (it != keyed.end()) {
          o[i] = it->second;
        } else {
          o[i] = new_node(xs, ib.entity_dim, ib.entity_tag);
          keyed.emplace(k, o[i]);
        }
      }
    }
    m_.blocks.push_back(std::move(ob));
  }
  // tables of the faces of 3D elements
  tab(Shape::Tri, P_), tab(Shape::Quad, P_), tab(Shape::Line, P_);
}

void Curver::build_cad_info() {
  const int nf = S_.num_faces(), ne = S_.num_edges();
  finfo_.resize(nf);
  einfo_.resize(ne);
  wall_entity_.assign(nf, 0);
  for (int e = 0; e < ne; ++e) {
    auto& I = einfo_[e];
    I.degenerate = S_.edge_degenerate(e);
    I.verts = S_.edge_vertices(e);
    I.range = S_.edge_range(e);
    I.faces = S_.edge_faces(e);
  }
  for (int f = 0; f < nf; ++f) {
    auto& I = finfo_[f];
    I.edges = S_.face_edges(f);
    // a period of the face's (u,v), unless one of the same size is known already
    auto add_period = [&I](const UV& d) {
      bool dup = false;
      for (auto& p : I.periods) dup = dup || (std::abs(std::abs(p[0]) - std::abs(d[0])) < 1e-9 && std::abs(std::abs(p[1]) - std::abs(d[1])) < 1e-9);
      if (!dup) I.periods.push_back(d);
    };
    for (int e : I.edges) {
      if (einfo_[e].degenerate || !S_.edge_is_seam(e, f)) continue;
      double t = 0.5 * (einfo_[e].range.lo + einfo_[e].range.hi);
      cad::Vec2 a = S_.edge_uv(e, f, t, false), b = S_.edge_uv(e, f, t, true);
      UV d{b.u - a.u, b.v - a.v};
      if (std::hypot(d[0], d[1]) < 1e-12) continue;
      add_period(d);
    }
    // The surface's own periods, for a face without a seam edge whose parameter box still
    // straddles the surface's seam (Rotor 67's hub and casing: a 2 pi / 22 sector of a surface
    // of revolution whose seam runs through the passage). Its nodes' parameters then come in
    // two representations, u near 0 and u near 2 pi, and interpolating between them goes the
    // long way round the hub: the high-order nodes of those elements landed on the far side of
    // the hub, on the CAD (distance 0) but 0.6 ft away.
    // Only where the face spans less than half a period in that direction: then two of its
    // points are always less than half a period apart and the nearest representation is the
    // right one. A wider face (the demo's round tip, a surface of revolution over more than pi)
    // has elements round its poles whose corners legitimately lie more than half a period apart.
    const auto fp = S_.face_periods(f);
    const auto fb = S_.face_uv_bounds(f);
    const double width[2] = {fb.u1 - fb.u0, fb.v1 - fb.v0};
    for (int k = 0; k < 2; ++k) {
      if (!(fp[k] > 0) || !(width[k] < 0.5 * fp[k]) || I.periods.size() >= 2) continue;
      add_period(UV{k == 0 ? fp[0] : 0.0, k == 1 ? fp[1] : 0.0});
    }
  }
  for (auto& ent : in_.entities)
    if (ent.dim == 2 && ent.tag >= 1 && ent.tag <= nf) {
      if (in_.group_name(2, ent.tag) == O_.wall_group) wall_entity_[ent.tag - 1] = 1;
      for (int p : ent.physicals)
        for (auto& g : in_.physicals)
          if (g.dim == 2 && g.tag == p && g.name == O_.wall_group) wall_entity_[ent.tag - 1] = 1;
    }
}

void Curver::build_entities() {
  const std::size_t nb = m_.blocks.size();
  charts_.assign(nb, {});
  near_of_.assign(nb, {});
  // faces of 2D elements on CAD faces first (their element is the face's owner)
  auto add_face = [&](const FaceKey& k, Shape s, std::vector<std::uint32_t> nodes) -> std::size_t {
    auto it = face_of_.find(k);
    if (it != face_of_.end()) return it->second;
    FaceEnt F;
    F.s = s, F.nodes = std::move(nodes);
    faces_.push_back(std::move(F));
    face_of_.emplace(k, faces_.size() - 1);
    return faces_.size() - 1;
  };
  auto add_edge = [&](std::uint32_t a, std::uint32_t b, const std::vector<std::uint32_t>& inner) -> std::size_t {
    EdgeKey k{std::min(a, b), std::max(a, b)};
    auto it = edge_of_.find(k);
    if (it != edge_of_.end()) return it->second;
    EdgeEnt E;
    E.a = k[0], E.b = k[1];
    E.nodes = inner;
    if (a > b) std::reverse(E.nodes.begin(), E.nodes.end());
    edges_.push_back(std::move(E));
    edge_of_.emplace(k, edges_.size() - 1);
    return edges_.size() - 1;
  };
  auto element_edges = [&](const model::ElementBlock& b, std::size_t e, const std::function<void(std::size_t)>& each) {
    const std::uint32_t* o = b.element(e);
    for (auto& en : model::edge_nodes(b.shape, P_)) {
      std::vector<std::uint32_t> inner;
      for (std::size_t k = 2; k < en.size(); ++k) inner.push_back(o[en[k]]);
      each(add_edge(o[en[0]], o[en[1]], inner));
    }
  };
  for (std::size_t bi = 0; bi < nb; ++bi) {
    auto& b = m_.blocks[bi];
    if (b.entity_dim != 2 || model::dimension(b.shape) != 2) continue;
    const int f = b.entity_tag - 1;
    const int nv = model::num_vertices(b.shape);
    charts_[bi].resize(b.size());
    for (std::size_t e = 0; e < b.size(); ++e) {
      const std::uint32_t* o = b.element(e);
      std::size_t fi = add_face(face_key(o, nv), b.shape, std::vector<std::uint32_t>(o, o + b.nodes_per_element()));
      FaceEnt& F = faces_[fi];
      if (F.el_block < 0) F.face = f, F.el_block = int(bi), F.el = e;
      if (wall_entity_[f]) F.wall = true;
      element_edges(b, e, [&](std::size_t ei) {
        EdgeEnt& E = edges_[ei];
        if (E.el_block < 0) E.face = f, E.el_block = int(bi), E.el = e;
        if (wall_entity_[f]) E.wall = true;
      });
    }
  }
  for (std::size_t bi = 0; bi < nb; ++bi) {
    auto& b = m_.blocks[bi];
    if (b.entity_dim != 1 || b.shape != Shape::Line) continue;
    for (std::size_t e = 0; e < b.size(); ++e) element_edges(b, e, [&](std::size_t ei) {
        if (edges_[ei].cad_edge < 0) edges_[ei].cad_edge = b.entity_tag - 1;
      });
  }
  for (std::size_t bi = 0; bi < nb; ++bi) {
    auto& b = m_.blocks[bi];
    if (model::dimension(b.shape) != 3) continue;
    near_of_[bi].assign(b.size(), -1);
    const auto& fv = model::face_vertices(b.shape);
    const auto& fnodes = model::face_nodes(b.shape, P_);
    const auto& r1 = model::reference_nodes(b.shape, 1);
    for (std::size_t e = 0; e < b.size(); ++e) {
      const std::uint32_t* o = b.element(e);
      std::vector<std::size_t> fidx;
      NearEl ne;
      for (std::size_t lf = 0; lf < fv.size(); ++lf) {
        std::uint32_t vv[4];
        for (std::size_t a = 0; a < fv[lf].size(); ++a) vv[a] = o[fv[lf][a]];
        std::vector<std::uint32_t> nodes;
        for (int i : fnodes[lf]) nodes.push_back(o[i]);
        std::size_t fi = add_face(face_key(vv, int(fv[lf].size())), fv[lf].size() == 3 ? Shape::Tri : Shape::Quad, nodes);
        fidx.push_back(fi);
        if (!faces_[fi].wall) continue;
        if (b.shape != Shape::Prism && b.shape != Shape::Hex) continue;
        if (b.shape == Shape::Prism && fv[lf].size() != 3) continue;
        // the reference axis on which the face is a constant
        for (int d = 0; d < 3; ++d) {
          bool same = true;
          for (int a : fv[lf]) same = same && std::abs(r1[a][d] - r1[fv[lf][0]][d]) < 1e-12;
          if (!same) continue;
          bool dup = false;
          for (auto& w : ne.walls) dup = dup || w.first == d;
          if (!dup) ne.walls.push_back({d, r1[fv[lf][0]][d]});
          break;
        }
      }
      std::vector<std::size_t> eidx;
      element_edges(b, e, [&](std::size_t ei) { eidx.push_back(ei); });
      if (!ne.walls.empty()) near_of_[bi][e] = O_.follow_wall ? int(near_.size()) : kNearNoFollow;
      if (!ne.walls.empty() && O_.follow_wall) {
        ne.block = std::uint32_t(bi), ne.el = e;
        if (b.shape == Shape::Prism) ++R_.near_field_prisms;
        else if (ne.walls.size() > 1) ++R_.junction_hexes;
        else ++R_.near_field_hexes;
        near_.push_back(std::move(ne));
        for (auto fi : fidx) faces_[fi].near = true;
        for (auto ei : eidx) edges_[ei].near = true;
      }
    }
  }
  // rules and node sources
  for (auto& E : edges_) {
    if (E.cad_edge >= 0) E.rule = kCurve;
    else if (E.face >= 0 && (E.wall || !E.near)) E.rule = kSurface;
    else if (E.near) E.rule = kNear;
    else E.rule = kStraight;
    for (auto n : E.nodes) src_[n] = std::uint8_t(E.rule);
  }
  for (auto& F : faces_) {
    if (F.face >= 0 && (F.wall || !F.near)) F.rule = kSurface;
    else if (F.near) F.rule = kNear;
    else F.rule = kBlend;
    const Tables& T = ctab(F.s);
    for (int i : T.interior) src_[F.nodes[i]] = std::uint8_t(F.rule);
  }
  for (auto& ne : near_) {
    auto& b = m_.blocks[ne.block];
    const Tables& T = ctab(b.shape);
    for (int i : T.interior) src_[b.element(ne.el)[i]] = kNear;
  }
}

// Candidate (u,v) of node n on face f (several on seams and at vertices); pole: n is at a
// degenerate edge of f, whose p-curve segment is seg.
std::vector<UV> Curver::candidates(std::uint32_t n, int f, bool& pole, std::array<UV, 2>& seg, const UV* hint) {
  pole = false;
  std::vector<UV> c;
  int d = m_.node_entity_dim[n], t = m_.node_entity_tag[n];
  const auto& FI = finfo_[f];
  if (d == 2 && t == f + 1 && std::isfinite(m_.node_u[n]) && std::isfinite(m_.node_v[n])) {
    c.push_back({m_.node_u[n], m_.node_v[n]});
    return c;
  }
  if (d == 1 && std::isfinite(m_.node_u[n]) && std::find(FI.edges.begin(), FI.edges.end(), t - 1) != FI.edges.end()) {
    int e = t - 1;
    cad::Vec2 a = S_.edge_uv(e, f, m_.node_u[n], false);
    c.push_back({a.u, a.v});
    if (S_.edge_is_seam(e, f)) {
      cad::Vec2 b = S_.edge_uv(e, f, m_.node_u[n], true);
      c.push_back({b.u, b.v});
    }
    return c;
  }
  if (d == 0) {
    int V = t - 1;
    for (int e : FI.edges) {
      const auto& EI = einfo_[e];
      if (EI.verts[0] != V && EI.verts[1] != V) continue;
      if (EI.degenerate) {
        pole = true;
        cad::Vec2 a = S_.edge_uv(e, f, EI.range.lo, false), b = S_.edge_uv(e, f, EI.range.hi, false);
        seg = {UV{a.u, a.v}, UV{b.u, b.v}};
        continue;
      }
      bool seam = S_.edge_is_seam(e, f);
      for (int end = 0; end < 2; ++end) {
        if (EI.verts[end] != V) continue;
        double tt = end == 0 ? EI.range.lo : EI.range.hi;
        for (int rev = 0; rev < (seam ? 2 : 1); ++rev) {
          cad::Vec2 a = S_.edge_uv(e, f, tt, rev == 1);
          c.push_back({a.u, a.v});
        }
      }
    }
    if (!c.empty() || pole) return c;
  }
  // not classified on f's closure: project (a contract violation, counted)
  ++fallback_;
  cad::Vec3 p{m_.x[n], m_.y[n], m_.z[n]};
  auto pr = hint ? shape().project_to_face(f, p, cad::Vec2{(*hint)[0], (*hint)[1]}) : shape().project_to_face(f, p);
  c.push_back({pr.u, pr.v});
  return c;
}

UV Curver::nearest(const std::vector<UV>& c, int f, const UV& target) const {
  const auto& per = finfo_[f].periods;
  UV best = c.front();
  double bd = INFINITY;
  for (const UV& a : c) {
    for (int k1 = -1; k1 <= 1; ++k1)
      for (int k2 = -1; k2 <= 1; ++k2) {
        if ((k1 != 0 && per.size() < 1) || (k2 != 0 && per.size() < 2)) continue;
        UV b = a;
        if (k1) b[0] += k1 * per[0][0], b[1] += k1 * per[0][1];
        if (k2) b[0] += k2 * per[1][0], b[1] += k2 * per[1][1];
        double dd = dist2(b, target);
        if (dd < bd - 1e-14) bd = dd, best = b;
      }
  }
  return best;
}

UV project_on_segment(const std::array<UV, 2>& s, const UV& p) {
  UV d{s[1][0] - s[0][0], s[1][1] - s[0][1]};
  double l2 = d[0] * d[0] + d[1] * d[1];
  if (l2 < 1e-30) return s[0];
  double t = std::clamp(((p[0] - s[0][0]) * d[0] + (p[1] - s[0][1]) * d[1]) / l2, 0.0, 1.0);
  return {s[0][0] + t * d[0], s[0][1] + t * d[1]};
}

void Curver::make_charts() {
  for (std::size_t bi = 0; bi < m_.blocks.size(); ++bi) {
    auto& b = m_.blocks[bi];
    if (charts_[bi].empty()) continue;
    const int f = b.entity_tag - 1, nv = model::num_vertices(b.shape);
    pfor(b.size(), [&](std::size_t e) {
      const std::uint32_t* o = b.element(e);
      Chart& C = charts_[bi][e];
      std::vector<std::vector<UV>> cand(nv);
      std::array<char, 4> placed{};
      int ref = -1;
      for (int a = 0; a < nv; ++a) {
        bool pole = false;
        cand[a] = candidates(o[a], f, pole, C.pole_seg[a], nullptr);
        C.pole[a] = pole;
        if (pole) ++pole_;
        if (!pole && cand[a].size() == 1 && ref < 0) ref = a;
      }
      for (int a = 0; a < nv && ref < 0; ++a)
        if (!C.pole[a] && !cand[a].empty()) ref = a;
      if (ref < 0) {  // all poles (cannot happen on a valid face): any point of the first segment
        for (int a = 0; a < nv; ++a) C.uv[a] = C.pole_seg[a][0];
        return;
      }
      C.uv[ref] = cand[ref].front();
      placed[ref] = 1;
      for (int a = 0; a < nv; ++a) {
        if (placed[a] || C.pole[a]) continue;
        UV mean{0, 0};
        int k = 0;
        for (int q = 0; q < nv; ++q)
          if (placed[q]) mean[0] += C.uv[q][0], mean[1] += C.uv[q][1], ++k;
        mean[0] /= k, mean[1] /= k;
        if (cand[a].size() > 1) ++seam_;
        C.uv[a] = nearest(cand[a], f, mean);
        placed[a] = 1;
      }
      UV mean{0, 0};
      int k = 0;
      for (int q = 0; q < nv; ++q)
        if (placed[q]) mean[0] += C.uv[q][0], mean[1] += C.uv[q][1], ++k;
      mean[0] /= k, mean[1] /= k;
      for (int a = 0; a < nv; ++a)
        if (C.pole[a]) C.uv[a] = project_on_segment(C.pole_seg[a], mean);
    });
  }
}

double Curver::end_t(std::uint32_t n, int e, std::optional<double> other) {
  int d = m_.node_entity_dim[n], t = m_.node_entity_tag[n];
  const auto& EI = einfo_[e];
  if (d == 1 && t == e + 1 && std::isfinite(m_.node_u[n])) return m_.node_u[n];
  if (d == 0) {
    int V = t - 1;
    bool lo = EI.verts[0] == V, hi = EI.verts[1] == V;
    if (lo && hi) return other && std::abs(*other - EI.range.hi) < std::abs(*other - EI.range.lo) ? EI.range.hi : EI.range.lo;
    if (lo) return EI.range.lo;
    if (hi) return EI.range.hi;
  }
  ++fallback_;
  return shape().project_to_edge(e, cad::Vec3{m_.x[n], m_.y[n], m_.z[n]}, other).t;
}

void Curver::rule1_edge(EdgeEnt& E) {
  const int e = E.cad_edge;
  bool a_vertex = m_.node_entity_dim[E.a] == 0, b_vertex = m_.node_entity_dim[E.b] == 0;
  double ta, tb;
  if (a_vertex && !b_vertex) {
    tb = end_t(E.b, e, std::nullopt);
    ta = end_t(E.a, e, tb);
  } else {
    ta = end_t(E.a, e, std::nullopt);
    tb = end_t(E.b, e, ta);
  }
  auto speed = [&](double tau) {
    cad::CurveDeriv d = S_.edge_eval(e, ta + tau * (tb - ta));
    return norm3(d.d1) * std::abs(tb - ta);
  };
  std::vector<double> tau = equal_arc(P_, speed);
  for (int k = 1; k < P_; ++k) {
    double t = ta + tau[k - 1] * (tb - ta);
    cad::Vec3 p = S_.edge_point(e, t);
    std::uint32_t n = E.nodes[k - 1];
    setX(n, {p.x, p.y, p.z});
    classify(n, 1, e + 1, t, NAN);
  }
}

void Curver::rule2_edge(EdgeEnt& E) {
  const auto& b = m_.blocks[E.el_block];
  const Chart& C = charts_[E.el_block][E.el];
  const std::uint32_t* o = b.element(E.el);
  const int nv = model::num_vertices(b.shape), f = E.face;
  int la = -1, lb = -1;
  for (int a = 0; a < nv; ++a) {
    if (o[a] == E.a) la = a;
    if (o[a] == E.b) lb = a;
  }
  UV ua = C.uv[la], ub = C.uv[lb];
  if (C.pole[la] && !C.pole[lb]) ua = project_on_segment(C.pole_seg[la], ub);
  if (C.pole[lb] && !C.pole[la]) ub = project_on_segment(C.pole_seg[lb], ua);
  UV du{ub[0] - ua[0], ub[1] - ua[1]};
  std::vector<double> tau(P_ - 1);
  for (int k = 1; k < P_; ++k) tau[k - 1] = double(k) / P_;
  if (O_.equalise_arc_length) {
    auto speed = [&](double s) {
      cad::SurfDeriv d = S_.face_eval(f, ua[0] + s * du[0], ua[1] + s * du[1]);
      cad::Vec3 v{d.du.x * du[0] + d.dv.x * du[1], d.du.y * du[0] + d.dv.y * du[1], d.du.z * du[0] + d.dv.z * du[1]};
      return norm3(v);
    };
    tau = equal_arc(P_, speed);
  }
  for (int k = 1; k < P_; ++k) {
    UV uv{ua[0] + tau[k - 1] * du[0], ua[1] + tau[k - 1] * du[1]};
    cad::Vec3 p = S_.face_point(f, uv[0], uv[1]);
    std::uint32_t n = E.nodes[k - 1];
    setX(n, {p.x, p.y, p.z});
    classify(n, 2, f + 1, uv[0], uv[1]);
  }
}

void Curver::rule2_face(FaceEnt& F) {
  const Tables& T = ctab(F.s);
  if (T.interior.empty()) return;
  const Chart& C = charts_[F.el_block][F.el];
  const int f = F.face, nv = T.nv;
  // the 2D element's nodes in its own order: F.nodes (owner = the 2D element)
  std::vector<UV> lin(T.n);
  for (int i = 0; i < T.n; ++i) {
    UV u{0, 0};
    for (int a = 0; a < nv; ++a) u[0] += T.w[i * nv + a] * C.uv[a][0], u[1] += T.w[i * nv + a] * C.uv[a][1];
    lin[i] = u;
  }
  std::vector<std::array<double, 2>> Duv(T.n, {0.0, 0.0});
  for (int i : T.bnd) {
    if (i < nv) continue;
    bool pole = false;
    std::array<UV, 2> seg;
    auto c = candidates(F.nodes[i], f, pole, seg, &lin[i]);
    UV uv = pole ? project_on_segment(seg, lin[i]) : nearest(c, f, lin[i]);
    Duv[i] = {uv[0] - lin[i][0], uv[1] - lin[i][1]};
  }
  int npole = 0, q = -1;
  for (int a = 0; a < nv; ++a)
    if (C.pole[a]) ++npole, q = a;
  if (F.s == Shape::Tri && npole == 1) {
    // A triangle at a pole Q: its (u,v) image is a quad whose side at Q is the pole segment
    // (u undefined there). Coons on that collapsed quad: s along A -> B, h towards Q, the
    // sides A -> Q and B -> Q being the edges (meridians), the top the pole segment.
    const int a = (q + 1) % 3, b = (q + 2) % 3;
    auto edge_of = [&](int x, int y) {  // local nodes from vertex x to vertex y, k = 0..P
      std::vector<int> line;
      for (int k = 0; k <= P_; ++k) {
        Lattice l;
        for (int c = 0; c < 3; ++c) l[c] = (T.lat[x][c] * (P_ - k) + T.lat[y][c] * k) / P_;
        line.push_back(T.at_lat.at(l));
      }
      return line;
    };
    auto AB = edge_of(a, b), AQ = edge_of(a, q), BQ = edge_of(b, q);
    auto uv_at = [&](int i) { return UV{lin[i][0] + Duv[i][0], lin[i][1] + Duv[i][1]}; };
    // the pole's u as seen from each meridian: that of the meridian's node next to the pole
    UV QA = project_on_segment(C.pole_seg[q], UV{uv_at(AQ[P_ - 1])[0], C.uv[q][1]});
    UV QB = project_on_segment(C.pole_seg[q], UV{uv_at(BQ[P_ - 1])[0], C.uv[q][1]});
    std::vector<double> L(P_ + 1);
    auto curve_at = [&](const std::vector<int>& line, double s, const UV& end) {
      lagrange1d(P_, s, L.data());
      UV r{0, 0};
      for (int k = 0; k <= P_; ++k) {
        UV p = k == P_ ? end : uv_at(line[k]);
        r[0] += L[k] * p[0], r[1] += L[k] * p[1];
      }
      return r;
    };
    for (int i : T.interior) {
      double lam[3] = {1.0 - double(T.lat[i][0] + T.lat[i][1]) / P_, double(T.lat[i][0]) / P_, double(T.lat[i][1]) / P_};
      double h = lam[q], s = lam[b] / (lam[a] + lam[b]);
      UV bot = curve_at(AB, s, uv_at(AB[P_])), lft = curve_at(AQ, h, QA), rgt = curve_at(BQ, h, QB);
      UV top{(1 - s) * QA[0] + s * QB[0], (1 - s) * QA[1] + s * QB[1]};
      UV A = uv_at(a), B = uv_at(b);
      UV r;
      for (int c = 0; c < 2; ++c)
        r[c] = (1 - h) * bot[c] + h * top[c] + (1 - s) * lft[c] + s * rgt[c] -
               ((1 - s) * (1 - h) * A[c] + s * (1 - h) * B[c] + (1 - s) * h * QA[c] + s * h * QB[c]);
      Duv[i] = {r[0] - lin[i][0], r[1] - lin[i][1]};
    }
  } else {
    tfi2d<2>(T, Duv);
  }
  for (int i : T.interior) {
    UV uv{lin[i][0] + Duv[i][0], lin[i][1] + Duv[i][1]};
    cad::Vec3 p = S_.face_point(f, uv[0], uv[1]);
    setX(F.nodes[i], {p.x, p.y, p.z});
    classify(F.nodes[i], 2, f + 1, uv[0], uv[1]);
  }
}

void Curver::near_field() {
  // predictions, summed in mesh order (deterministic), then averaged
  std::vector<std::uint32_t> touched;
  std::unordered_map<std::uint32_t, std::pair<V3, int>> acc;
  for (auto& ne : near_) {
    const auto& b = m_.blocks[ne.block];
    const Tables& T = ctab(b.shape);
    const std::uint32_t* o = b.element(ne.el);
    const int nw = int(ne.walls.size());
    for (int i = T.nv; i < T.n; ++i) {
      std::uint32_t n = o[i];
      if (src_[n] != kNear) continue;
      V3 d{0, 0, 0};
      for (int mask = 1; mask < (1 << nw); ++mask) {
        model::Vec3 r = T.ref[i];
        int bits = 0;
        for (int w = 0; w < nw; ++w)
          if (mask & (1 << w)) r[ne.walls[w].first] = ne.walls[w].second, ++bits;
        int j = T.local(r);
        if (j < 0) throw std::logic_error("curve: wall projection outside the lattice");
        V3 dj = D(o[j]);
        double sgn = (bits % 2) ? 1.0 : -1.0;
        for (int c = 0; c < 3; ++c) d[c] += sgn * dj[c];
      }
      auto [it, fresh] = acc.try_emplace(n, V3{0, 0, 0}, 0);
      if (fresh) touched.push_back(n);
      for (int c = 0; c < 3; ++c) it->second.first[c] += d[c];
      it->second.second += 1;
    }
  }
  for (auto n : touched) {
    auto& [d, k] = acc[n];
    setX(n, {Xs_[3 * n] + d[0] / k, Xs_[3 * n + 1] + d[1] / k, Xs_[3 * n + 2] + d[2] / k});
  }
  R_.nodes_near_field = touched.size();
  // near-field entities on non-wall CAD faces: project their nodes onto the face
  struct Job {
    std::uint32_t n;
    int f;
    UV hint;
  };
  std::vector<Job> jobs;
  for (auto& E : edges_) {
    if (E.rule != kNear || E.face < 0) continue;
    const auto& b = m_.blocks[E.el_block];
    const Chart& C = charts_[E.el_block][E.el];
    const std::uint32_t* o = b.element(E.el);
    int la = 0, lb = 0;
    for (int a = 0; a < model::num_vertices(b.shape); ++a) {
      if (o[a] == E.a) la = a;
      if (o[a] == E.b) lb = a;
    }
    for (int k = 1; k < P_; ++k) {
      double s = double(k) / P_;
      jobs.push_back({E.nodes[k - 1], E.face, {C.uv[la][0] + s * (C.uv[lb][0] - C.uv[la][0]), C.uv[la][1] + s * (C.uv[lb][1] - C.uv[la][1])}});
    }
  }
  for (auto& F : faces_) {
    if (F.rule != kNear || F.face < 0) continue;
    const Tables& T = ctab(F.s);
    const Chart& C = charts_[F.el_block][F.el];
    for (int i : T.interior) {
      UV u{0, 0};
      for (int a = 0; a < T.nv; ++a) u[0] += T.w[i * T.nv + a] * C.uv[a][0], u[1] += T.w[i * T.nv + a] * C.uv[a][1];
      jobs.push_back({F.nodes[i], F.face, u});
    }
  }
  pfor(jobs.size(), [&](std::size_t j) {
    const Job& J = jobs[j];
    auto pr = shape().project_to_face(J.f, cad::Vec3{m_.x[J.n], m_.y[J.n], m_.z[J.n]}, cad::Vec2{J.hint[0], J.hint[1]});
    setX(J.n, {pr.point.x, pr.point.y, pr.point.z});
    classify(J.n, 2, J.f + 1, pr.u, pr.v);
  });
  R_.nodes_projected = jobs.size();
}

void Curver::blend_face(FaceEnt& F) {
  const Tables& T = ctab(F.s);
  if (T.interior.empty()) return;
  std::vector<std::array<double, 3>> d(T.n, {0.0, 0.0, 0.0});
  for (int i : T.bnd) d[i] = D(F.nodes[i]);
  for (int a = 0; a < T.nv; ++a) d[a] = {0, 0, 0};
  tfi2d<3>(T, d);
  for (int i : T.interior) {
    std::uint32_t n = F.nodes[i];
    setX(n, {Xs_[3 * n] + d[i][0], Xs_[3 * n + 1] + d[i][1], Xs_[3 * n + 2] + d[i][2]});
  }
}

void Curver::interior(std::uint32_t bi, std::size_t e) {
  const auto& b = m_.blocks[bi];
  const Tables& T = ctab(b.shape);
  if (T.interior.empty()) return;
  const std::uint32_t* o = b.element(e);
  Eigen::MatrixXd Db(T.bnd.size(), 3);
  bool zero = true;
  for (std::size_t a = 0; a < T.bnd.size(); ++a) {
    V3 d = D(o[T.bnd[a]]);
    for (int c = 0; c < 3; ++c) Db(a, c) = d[c], zero = zero && d[c] == 0;
  }
  if (zero) return;  // exactly the straight element
  Eigen::MatrixXd Di = T.H * Db;
  for (std::size_t a = 0; a < T.interior.size(); ++a) {
    std::uint32_t n = o[T.interior[a]];
    setX(n, {Xs_[3 * n] + Di(a, 0), Xs_[3 * n + 1] + Di(a, 1), Xs_[3 * n + 2] + Di(a, 2)});
  }
}

void Curver::report_distances() {
  const std::size_t N0 = in_.num_nodes(), N = m_.num_nodes();
  std::vector<double> dc(N - N0, 0.0), ds(N - N0, 0.0);
  pfor(N - N0, [&](std::size_t k) {
    std::uint32_t n = std::uint32_t(N0 + k);
    cad::Vec3 p{m_.x[n], m_.y[n], m_.z[n]};
    int d = m_.node_entity_dim[n], t = m_.node_entity_tag[n];
    if (d == 1) dc[k] = shape().project_to_edge(t - 1, p, m_.node_u[n]).distance;
    if (d == 2) ds[k] = shape().project_to_face(t - 1, p, cad::Vec2{m_.node_u[n], m_.node_v[n]}).distance;
  });
  for (std::size_t k = 0; k < dc.size(); ++k) {
    int d = m_.node_entity_dim[N0 + k];
    if (d == 1) ++R_.nodes_on_curves;
    if (d == 2) ++R_.nodes_on_surfaces;
    R_.max_distance_curve = std::max(R_.max_distance_curve, dc[k]);
    R_.max_distance_surface = std::max(R_.max_distance_surface, ds[k]);
    std::uint8_t s = src_[N0 + k];
    if (s == kStraight) ++R_.nodes_straight;
    if (s == kBlend || s == kInterior) ++R_.nodes_blended;
  }
}

void Curver::check_quality(const Mesh& out) {
  auto qin = model::mesh_quality(in_, O_.threads);
  for (auto& b : qin)
    for (auto& q : b) R_.invalid_linear += !q.valid;
  R_.quality = model::mesh_quality(out, O_.threads);
  const auto& q = R_.quality;
  for (std::size_t bi = 0; bi < q.size(); ++bi) {
    const auto& b = out.blocks[bi];
    for (std::size_t e = 0; e < q[bi].size(); ++e) {
      ++R_.elements;
      R_.min_scaled_jacobian = std::min(R_.min_scaled_jacobian, q[bi][e].scaled_jacobian);
      if (q[bi][e].valid) continue;
      ++R_.invalid;
      bool nf = !near_of_[bi].empty() && near_of_[bi][e] != -1;
      R_.invalid_near_field += nf;
      if (R_.invalid_elements.size() < 100) {
        InvalidElement ie;
        ie.tag = b.tags.empty() ? 0 : b.tags[e];
        if (b.tags.empty()) {  // implicit tags: running count over blocks
          std::uint64_t before = 0;
          for (std::size_t k = 0; k < bi; ++k) before += out.blocks[k].size();
          ie.tag = before + e + 1;
        }
        ie.type = std::string(model::shape_name(b.shape)) + std::to_string(b.order);
        const std::uint32_t* o = b.element(e);
        int nv = model::num_vertices(b.shape);
        for (int a = 0; a < nv; ++a) ie.centroid[0] += out.x[o[a]] / nv, ie.centroid[1] += out.y[o[a]] / nv, ie.centroid[2] += out.z[o[a]] / nv;
        ie.min_det = q[bi][e].min_det;
        ie.near_field = nf;
        R_.invalid_elements.push_back(ie);
      }
    }
  }
}

Mesh Curver::run() {
  auto t0 = Clock::now();
  P_ = O_.order;
  validate();
  R_.order = P_;
  R_.nodes_in = in_.num_nodes();
  build_cad_info();
  create_nodes();
  build_entities();
  make_charts();
  // rule 1, rule 2 edges, wall faces, near field, other CAD faces, straight edges, blends
  std::vector<std::size_t> r1, r2, fw, fo, fb;
  for (std::size_t i = 0; i < edges_.size(); ++i) {
    if (edges_[i].rule == kCurve) r1.push_back(i);
    if (edges_[i].rule == kSurface) r2.push_back(i);
  }
  for (std::size_t i = 0; i < faces_.size(); ++i) {
    if (faces_[i].rule == kSurface) (faces_[i].wall ? fw : fo).push_back(i);
    if (faces_[i].rule == kBlend) fb.push_back(i);
  }
  pfor(r1.size(), [&](std::size_t k) { rule1_edge(edges_[r1[k]]); });
  pfor(r2.size(), [&](std::size_t k) { rule2_edge(edges_[r2[k]]); });
  pfor(fw.size(), [&](std::size_t k) { rule2_face(faces_[fw[k]]); });
  near_field();
  pfor(fo.size(), [&](std::size_t k) { rule2_face(faces_[fo[k]]); });
  pfor(fb.size(), [&](std::size_t k) { blend_face(faces_[fb[k]]); });
  std::vector<std::pair<std::uint32_t, std::size_t>> els;
  for (std::size_t bi = 0; bi < m_.blocks.size(); ++bi)
    if (model::dimension(m_.blocks[bi].shape) == 3)
      for (std::size_t e = 0; e < m_.blocks[bi].size(); ++e)
        if (near_of_[bi][e] < 0) els.push_back({std::uint32_t(bi), e});  // near field: placed by rule 3
  pfor(els.size(), [&](std::size_t k) { interior(els[k].first, els[k].second); });
  R_.nodes_out = m_.num_nodes();
  R_.fallback_projections = fallback_;
  R_.seam_choices = seam_;
  R_.pole_ends = pole_;
  report_distances();
  R_.seconds_place = secs(t0);
  if (O_.check) {
    auto t1 = Clock::now();
    check_quality(m_);
    R_.seconds_check = secs(t1);
  }
  R_.seconds_total = secs(t0);
  return std::move(m_);
}

}  // namespace

nlohmann::json Report::to_json() const {
  nlohmann::json inv = nlohmann::json::array();
  for (auto& e : invalid_elements)
    inv.push_back({{"tag", e.tag}, {"type", e.type}, {"centroid", e.centroid}, {"min_det", e.min_det}, {"near_field", e.near_field}});
  return {{"order", order},
          {"nodes", {{"in", nodes_in}, {"out", nodes_out}}},
          {"high_order_nodes",
           {{"on_curves", nodes_on_curves},
            {"on_surfaces", nodes_on_surfaces},
            {"near_field", nodes_near_field},
            {"near_field_projected", nodes_projected},
            {"straight", nodes_straight},
            {"blended", nodes_blended}}},
          {"near_field", {{"prisms", near_field_prisms}, {"hexes", near_field_hexes}, {"junction_hexes", junction_hexes}}},
          {"max_distance_to_cad", {{"curve", max_distance_curve}, {"surface", max_distance_surface}}},
          {"seam_choices", seam_choices},
          {"pole_vertices", pole_ends},
          {"fallback_projections", fallback_projections},
          {"validity",
           {{"elements", elements},
            {"invalid_linear_input", invalid_linear},
            {"invalid", invalid},
            {"invalid_near_field", invalid_near_field},
            {"min_scaled_jacobian", min_scaled_jacobian},
            {"invalid_elements", inv}}},
          {"seconds", {{"place", seconds_place}, {"check", seconds_check}, {"total", seconds_total}}}};
}

model::Mesh curve_mesh(const model::Mesh& linear, const cad::Shape& shape, const Options& opt, Report& report,
                       const std::function<void(const std::string&)>& log) {
  report = Report{};
  std::unique_ptr<tbb::task_arena> arena = opt.threads > 0 ? std::make_unique<tbb::task_arena>(opt.threads) : std::make_unique<tbb::task_arena>();
  Mesh out;
  arena->execute([&] {
    Curver c(linear, shape, opt, report, log);
    out = c.run();
  });
  std::ostringstream s;
  s << "curve: order " << report.order << ", " << report.nodes_in << " -> " << report.nodes_out << " nodes; "
    << report.nodes_on_curves << " high-order nodes on CAD curves, " << report.nodes_on_surfaces << " on CAD surfaces (max distance "
    << report.max_distance_curve << " / " << report.max_distance_surface << "); near field: " << report.near_field_prisms << " prisms, "
    << report.near_field_hexes + report.junction_hexes << " hexes (" << report.junction_hexes << " junction), "
    << report.nodes_near_field << " nodes follow the wall";
  if (log) log(s.str());
  if (opt.check && log) {
    std::ostringstream v;
    v << "curve: validity (Bezier bounds over each whole element): " << report.invalid << " of " << report.elements
      << " elements invalid after curving (" << report.invalid_near_field << " in the near field; linear input: "
      << report.invalid_linear << " invalid); min scaled Jacobian " << report.min_scaled_jacobian
      << (report.invalid ? " — left for optimise" : "");
    log(v.str());
    for (auto& e : report.invalid_elements) {
      std::ostringstream l;
      l << "curve:   invalid " << e.type << " element " << e.tag << (e.near_field ? " (near field)" : "") << " at (" << e.centroid[0]
        << ", " << e.centroid[1] << ", " << e.centroid[2] << "), min det J " << e.min_det;
      log(l.str());
    }
  }
  return out;
}

}  // namespace meshflow::curve
