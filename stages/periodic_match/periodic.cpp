// periodic_match: the transform between the periodic sides and the pairing of their entities
// (see periodic.hpp for the method). Eigen for the rigid fits (Kabsch: SVD of the 3x3
// cross-covariance) and the axis point (least squares); the CAD through stages/cad/cad.hpp.
#include "stages/periodic_match/periodic.hpp"

#include "engine/stage.hpp"
#include "stages/cad/cad.hpp"

#include <Eigen/Dense>
#include <Eigen/Geometry>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <map>
#include <set>
#include <sstream>
#include <stdexcept>

namespace meshflow::periodic {

using P3 = std::array<double, 3>;

namespace {

P3 p3(const cad::Vec3& v) { return {v.x, v.y, v.z}; }
cad::Vec3 v3(const P3& p) { return {p[0], p[1], p[2]}; }
P3 sub(const P3& a, const P3& b) { return {a[0] - b[0], a[1] - b[1], a[2] - b[2]}; }
double dot(const P3& a, const P3& b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }
double norm(const P3& a) { return std::sqrt(dot(a, a)); }
double dist(const P3& a, const P3& b) { return norm(sub(a, b)); }

std::string fmt(double x) {
  char b[64];
  std::snprintf(b, sizeof b, "%.6g", x);
  return b;
}
std::string fmt(const P3& p) { return "(" + fmt(p[0]) + ", " + fmt(p[1]) + ", " + fmt(p[2]) + ")"; }
std::string list(const std::vector<int>& v) {
  std::string s;
  for (std::size_t i = 0; i < v.size(); ++i) s += (i ? ", " : "") + std::to_string(v[i]);
  return s;
}

// Rotation matrix (row-major) about unit axis a by angle th (Rodrigues).
std::array<double, 9> rodrigues(const P3& a, double th) {
  double c = std::cos(th), s = std::sin(th), C = 1 - c;
  double x = a[0], y = a[1], z = a[2];
  return {c + x * x * C,     x * y * C - z * s, x * z * C + y * s,
          y * x * C + z * s, c + y * y * C,     y * z * C - x * s,
          z * x * C - y * s, z * y * C + x * s, c + z * z * C};
}

// A rigid motion as fitted: y = R x + t.
struct Rigid {
  Eigen::Matrix3d R = Eigen::Matrix3d::Identity();
  Eigen::Vector3d t = Eigen::Vector3d::Zero();
};

Eigen::Vector3d ev(const P3& p) { return {p[0], p[1], p[2]}; }

// Least-squares proper rigid motion carrying P[i] onto Q[i] (Kabsch). Why own code: Eigen's
// umeyama() does the same but allows no reflection check of our own and needs matrices; this is
// the textbook 3x3 SVD form, a dozen lines.
Rigid kabsch(const std::vector<P3>& P, const std::vector<P3>& Q) {
  Eigen::Vector3d pc = Eigen::Vector3d::Zero(), qc = Eigen::Vector3d::Zero();
  for (std::size_t i = 0; i < P.size(); ++i) pc += ev(P[i]), qc += ev(Q[i]);
  pc /= double(P.size()), qc /= double(Q.size());
  Eigen::Matrix3d H = Eigen::Matrix3d::Zero();
  for (std::size_t i = 0; i < P.size(); ++i) H += (ev(P[i]) - pc) * (ev(Q[i]) - qc).transpose();
  Eigen::JacobiSVD<Eigen::Matrix3d> svd(H, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d V = svd.matrixV(), U = svd.matrixU();
  double d = (V * U.transpose()).determinant() < 0 ? -1 : 1;
  Eigen::Matrix3d D = Eigen::Matrix3d::Identity();
  D(2, 2) = d;
  Rigid r;
  r.R = V * D * U.transpose();
  r.t = qc - r.R * pc;
  return r;
}

// A feature of one side: a vertex or the arc-length midpoint of an edge.
struct Feature {
  int kind = 0;  // 0 vertex, 1 edge midpoint
  int id = -1;
  P3 p{};
  std::vector<double> sig;  // sorted distances to the other features of the side
};

struct Side {
  std::vector<int> faces, edges, vertices;  // sorted; edges: non-degenerate only
  std::vector<Feature> features;
};

P3 arc_midpoint(const cad::Shape& s, int e) {
  cad::Range r = s.edge_range(e);
  double L = s.edge_length(e), half = 0.5 * L;
  // Newton on s(t) = L/2 (s' = |C'|), safeguarded by bisection.
  double a = r.lo, b = r.hi, t = 0.5 * (a + b);
  for (int it = 0; it < 60; ++it) {
    double f = s.edge_length(e, r.lo, t) - half;
    if (std::abs(f) <= 1e-14 * L) break;
    if (f > 0) b = t; else a = t;
    cad::CurveDeriv d = s.edge_eval(e, t);
    double sp = std::sqrt(d.d1.x * d.d1.x + d.d1.y * d.d1.y + d.d1.z * d.d1.z);
    double tn = sp > 0 ? t - f / sp : 0.5 * (a + b);
    t = (tn > a && tn < b) ? tn : 0.5 * (a + b);
  }
  return p3(s.edge_point(e, t));
}

Side side(const cad::Shape& s, cad::Tag tag) {
  Side S;
  S.faces = s.faces_with_tag(tag);
  std::set<int> E, V;
  for (int f : S.faces)
    for (int e : s.face_edges(f)) {
      auto vv = s.edge_vertices(e);
      V.insert(vv[0]), V.insert(vv[1]);
      if (!s.edge_degenerate(e)) E.insert(e);
    }
  S.edges.assign(E.begin(), E.end());
  S.vertices.assign(V.begin(), V.end());
  for (int v : S.vertices) S.features.push_back({0, v, p3(s.vertex_point(v)), {}});
  for (int e : S.edges) S.features.push_back({1, e, arc_midpoint(s, e), {}});
  for (auto& f : S.features) {
    for (auto& g : S.features)
      if (&f != &g) f.sig.push_back(dist(f.p, g.p));
    std::sort(f.sig.begin(), f.sig.end());
  }
  return S;
}

bool same_signature(const Feature& a, const Feature& b, double tol) {
  if (a.kind != b.kind || a.sig.size() != b.sig.size()) return false;
  for (std::size_t i = 0; i < a.sig.size(); ++i)
    if (std::abs(a.sig[i] - b.sig[i]) > 2 * tol) return false;
  return true;
}

// ── Pairing ─────────────────────────────────────────────────────────────────────────────
struct FaceSample {
  double u, v;
  P3 x, n;
};

std::vector<FaceSample> face_samples(const cad::Shape& s, int f) {
  cad::UVBounds b = s.face_uv_bounds(f);
  std::vector<FaceSample> out;
  for (int K : {8, 24, 64}) {
    out.clear();
    for (int i = 0; i < K; ++i)
      for (int j = 0; j < K; ++j) {
        // serpentine order: consecutive samples are neighbours (good projection hints)
        int jj = i % 2 ? K - 1 - j : j;
        double u = b.u0 + (b.u1 - b.u0) * (i + 0.5) / K, v = b.v0 + (b.v1 - b.v0) * (jj + 0.5) / K;
        if (!s.face_contains_uv(f, u, v)) continue;
        out.push_back({u, v, p3(s.face_point(f, u, v)), p3(s.face_normal(f, u, v))});
      }
    if (out.size() >= 12) break;
  }
  return out;
}

struct Check {
  bool ok = true;
  double worst = 0;  // largest projection distance seen (before failing, if it failed)
  P3 where{};        // the sample with the largest distance / where it failed
  std::string why;   // "off the surface", "outside the trimmed face", "same orientation"
};

// Do the samples of face a, carried by map M (R n for normals), lie on face b (within tol,
// inside its trimmed domain, with opposite normals)? all = false: stop at the first failure.
template <class Map, class VMap>
Check face_on_face(const cad::Shape& s, const std::vector<FaceSample>& S, int b, const Map& M, const VMap& VM, double tol,
                   bool all) {
  Check c;
  std::optional<cad::Vec2> hint;
  for (const FaceSample& fs : S) {
    P3 y = M(fs.x);
    cad::SurfaceProjection pr = s.project_to_face(b, v3(y), hint);
    if (hint && pr.distance > tol) pr = s.project_to_face(b, v3(y));  // a far hint may mislead Newton
    hint = cad::Vec2{pr.u, pr.v};
    std::string why;
    if (pr.distance > tol) why = "off the surface";
    else if (!s.face_contains_uv(b, pr.u, pr.v, tol)) why = "outside the trimmed face";
    else if (dot(VM(fs.n), p3(s.face_normal(b, pr.u, pr.v))) > -0.5) why = "with the same orientation (the fluid on the same side)";
    if (pr.distance >= c.worst) c.worst = pr.distance, c.where = y;
    if (!why.empty()) {
      if (c.ok) c.why = why, c.where = y;
      c.ok = false;
      if (!all) return c;
    }
  }
  return c;
}

std::vector<double> edge_params(const cad::Shape& s, int e, int M) {
  cad::Range r = s.edge_range(e);
  std::vector<double> t;
  for (int k = 0; k < M; ++k) t.push_back(r.lo + (r.hi - r.lo) * (k + 0.5) / M);
  return t;
}

// Do the sampled points of edge a carried by M lie on edge b? Returns the check; `reversed`
// from the tangents.
template <class Map, class VMap>
Check edge_on_edge(const cad::Shape& s, int a, int b, const Map& M, const VMap& VM, double tol, bool all, bool* reversed, int samples) {
  Check c;
  std::optional<double> hint;
  int along = 0, against = 0;
  for (double t : edge_params(s, a, samples)) {
    cad::CurveDeriv d = s.edge_eval(a, t);
    P3 y = M(p3(d.p));
    cad::CurveProjection pr = s.project_to_edge(b, v3(y), hint);
    if (hint && pr.distance > tol) pr = s.project_to_edge(b, v3(y));
    hint = pr.t;
    if (pr.distance >= c.worst) c.worst = pr.distance, c.where = y;
    if (pr.distance > tol) {
      if (c.ok) c.why = "off the edge", c.where = y;
      c.ok = false;
      if (!all) return c;
      continue;
    }
    double w = dot(VM(p3(d.d1)), p3(s.edge_eval(b, pr.t).d1));
    (w < 0 ? against : along)++;
  }
  if (c.ok && along && against) c.ok = false, c.why = "with a tangent turning back";
  if (reversed) *reversed = against > 0;
  return c;
}

bool boxes_overlap(const cad::Box& a, const cad::Box& b, double tol) {
  for (int i = 0; i < 3; ++i)
    if (a.lo[i] > b.hi[i] + tol || b.lo[i] > a.hi[i] + tol) return false;
  return true;
}
template <class Map>
cad::Box mapped_box(const cad::Box& b, const Map& M) {
  cad::Box o{{1e300, 1e300, 1e300}, {-1e300, -1e300, -1e300}};
  for (int k = 0; k < 8; ++k) {
    P3 c = M(P3{k & 1 ? b.hi.x : b.lo.x, k & 2 ? b.hi.y : b.lo.y, k & 4 ? b.hi.z : b.lo.z});
    o.lo = {std::min(o.lo.x, c[0]), std::min(o.lo.y, c[1]), std::min(o.lo.z, c[2])};
    o.hi = {std::max(o.hi.x, c[0]), std::max(o.hi.y, c[1]), std::max(o.hi.z, c[2])};
  }
  return o;
}

struct Pairing {
  bool ok = false;
  std::string error;  // why not, naming the entities
  std::vector<Pair> faces, edges, vertices;
  double face_mis = 0, edge_mis = 0, vertex_mis = 0;
};

// Pairs every entity of lo with one of hi under T (both ways). quick: stop at the first problem
// (used to discard candidate transforms).
Pairing pair_entities(const cad::Shape& s, const Side& lo, const Side& hi, const Transform& T, double tol, double size,
                      const std::map<int, std::vector<FaceSample>>& samples, bool quick) {
  Pairing P;
  auto fwd = [&](const P3& p) { return T.apply(p); };
  auto inv = [&](const P3& p) { return T.apply_inverse(p); };
  auto vf = [&](const P3& v) { return T.apply_vector(v); };
  auto vi = [&](const P3& v) {  // R^T v
    const auto& A = T.affine;
    return P3{A[0] * v[0] + A[4] * v[1] + A[8] * v[2], A[1] * v[0] + A[5] * v[1] + A[9] * v[2], A[2] * v[0] + A[6] * v[1] + A[10] * v[2]};
  };
  auto rel = [&](double d) { return fmt(d) + " (" + fmt(d / size) + " of the model size)"; };
  std::string what = T.kind == "translation" ? "the translation by " + fmt(T.translation)
                                             : "the rotation by " + fmt(T.angle * 180 / M_PI) + " deg about the axis through " +
                                                   fmt(T.axis_point) + " along " + fmt(T.axis_dir);
  // faces, lo -> hi
  std::map<int, int> hi_of;
  for (int f : lo.faces) {
    cad::Box fb = mapped_box(s.face_box(f), fwd);
    std::vector<int> found;
    double mis = 0;
    for (int h : hi.faces) {
      if (!boxes_overlap(fb, s.face_box(h), tol)) continue;
      Check c = face_on_face(s, samples.at(f), h, fwd, vf, tol, false);
      if (c.ok) found.push_back(h), mis = std::max(mis, c.worst);
    }
    if (found.size() == 1) {
      hi_of[f] = found[0];
      P.face_mis = std::max(P.face_mis, mis);
      continue;
    }
    if (found.size() > 1) {
      P.error = "periodic_lo face " + std::to_string(f) + " is carried by " + what + " onto several periodic_hi faces (" + list(found) +
                "): overlapping periodic_hi faces? check the geometry";
      return P;
    }
    if (quick) {
      P.error = "periodic_lo face " + std::to_string(f) + " has no partner";
      return P;
    }
    // the nearest hi face, for the message
    Check best;
    int bh = -1;
    for (int h : hi.faces) {
      Check c = face_on_face(s, samples.at(f), h, fwd, vf, tol, true);
      if (bh < 0 || c.worst < best.worst) best = c, bh = h;
    }
    P.error = "periodic_lo face " + std::to_string(f) + " has no periodic_hi partner under " + what + ": its image is " +
              (bh < 0 ? std::string("not near any periodic_hi face")
                      : "up to " + rel(best.worst) + " from the nearest periodic_hi face " + std::to_string(bh) + ", first " + best.why +
                            " near " + fmt(best.where)) +
              " (tolerance " + rel(tol) + "); the periodic sides do not match: check the geometry or its periodic tags";
    return P;
  }
  // every hi face used once, and covered: its samples carried back lie on the lo partner
  std::map<int, int> lo_of;
  for (auto [f, h] : hi_of) {
    if (lo_of.count(h)) {
      P.error = "periodic_hi face " + std::to_string(h) + " is the image of two periodic_lo faces (" + std::to_string(lo_of[h]) + ", " +
                std::to_string(f) + ") under " + what + "; check the geometry";
      return P;
    }
    lo_of[h] = f;
  }
  for (int h : hi.faces) {
    if (!lo_of.count(h)) {
      P.error = "periodic_hi face " + std::to_string(h) + " is the image of no periodic_lo face under " + what +
                " (periodic_lo faces " + list(lo.faces) + "); the periodic sides do not match: check the geometry or its periodic tags";
      return P;
    }
    Check c = face_on_face(s, samples.at(h), lo_of[h], inv, vi, tol, !quick);
    if (!c.ok) {
      P.error = "periodic_hi face " + std::to_string(h) + " is larger than the image of periodic_lo face " + std::to_string(lo_of[h]) +
                " under " + what + ": carried back, its points are up to " + rel(c.worst) + " " + c.why + " of face " +
                std::to_string(lo_of[h]) + " (first near " + fmt(c.where) + ", tolerance " + rel(tol) + "); the periodic sides do not match";
      return P;
    }
    P.face_mis = std::max(P.face_mis, c.worst);
    P.faces.push_back({lo_of[h], h, false});
  }
  std::sort(P.faces.begin(), P.faces.end(), [](const Pair& a, const Pair& b) { return a.lo < b.lo; });

  // edges: 9 samples to discard candidates, 500 for the final check (the intersection curves of
  // Rotor 67 deviate locally, over ~0.3% of their length)
  const int ne = quick ? 9 : 500;
  std::map<int, int> ehi_of;
  for (int a : lo.edges) {
    cad::Box eb = mapped_box(s.edge_box(a), fwd);
    std::vector<int> found;
    std::vector<bool> rev;
    double mis = 0;
    for (int b : hi.edges) {
      if (!boxes_overlap(eb, s.edge_box(b), tol)) continue;
      bool r = false;
      Check c = edge_on_edge(s, a, b, fwd, vf, tol, false, &r, ne);
      if (!c.ok) continue;
      // both ways: b's samples carried back lie on a
      Check back = edge_on_edge(s, b, a, inv, vi, tol, false, nullptr, ne);
      if (!back.ok) continue;
      found.push_back(b), rev.push_back(r), mis = std::max({mis, c.worst, back.worst});
    }
    if (found.size() != 1) {
      if (found.empty()) {
        double best = 1e300;
        int bb = -1;
        for (int b : hi.edges) {
          Check c = edge_on_edge(s, a, b, fwd, vf, tol, true, nullptr, ne);
          if (c.worst < best) best = c.worst, bb = b;
        }
        P.error = "periodic edge " + std::to_string(a) + " (of periodic_lo faces) has no partner among the edges of the periodic_hi faces under " +
                  what + (bb < 0 ? std::string() : ": the nearest, edge " + std::to_string(bb) + ", is up to " + rel(best) + " away") +
                  " (tolerance " + rel(tol) + "); the periodic sides do not match (their boundaries differ)";
      } else {
        P.error = "periodic edge " + std::to_string(a) + " is carried onto several edges of the periodic_hi faces (" + list(found) + ")";
      }
      return P;
    }
    ehi_of[a] = found[0];
    P.edges.push_back({a, found[0], bool(rev[0])});
    P.edge_mis = std::max(P.edge_mis, mis);
  }
  {
    std::map<int, int> used;
    for (auto [a, b] : ehi_of) {
      if (used.count(b)) {
        P.error = "edge " + std::to_string(b) + " of the periodic_hi faces is the image of two edges (" + std::to_string(used[b]) + ", " +
                  std::to_string(a) + ")";
        return P;
      }
      used[b] = a;
    }
    for (int b : hi.edges)
      if (!used.count(b)) {
        P.error = "edge " + std::to_string(b) + " of the periodic_hi faces is the image of no edge of the periodic_lo faces under " + what +
                  "; the periodic sides do not match (their boundaries differ)";
        return P;
      }
  }
  // vertices
  std::map<int, int> vused;
  for (int a : lo.vertices) {
    P3 y = fwd(p3(s.vertex_point(a)));
    int found = -1;
    double d = 1e300;
    for (int b : hi.vertices) {
      double db = dist(y, p3(s.vertex_point(b)));
      if (db < d) d = db, found = b;
    }
    if (found < 0 || d > tol) {
      P.error = "vertex " + std::to_string(a) + " of the periodic_lo faces at " + fmt(p3(s.vertex_point(a))) +
                " has no partner on the periodic_hi faces under " + what + " (nearest " + rel(d) + " away, tolerance " + rel(tol) + ")";
      return P;
    }
    if (vused.count(found)) {
      P.error = "vertex " + std::to_string(found) + " of the periodic_hi faces is the image of two vertices (" + std::to_string(vused[found]) +
                ", " + std::to_string(a) + ")";
      return P;
    }
    vused[found] = a;
    P.vertices.push_back({a, found, false});
    P.vertex_mis = std::max(P.vertex_mis, d);
  }
  for (int b : hi.vertices)
    if (!vused.count(b)) {
      P.error = "vertex " + std::to_string(b) + " of the periodic_hi faces at " + fmt(p3(s.vertex_point(b))) +
                " is the image of no vertex of the periodic_lo faces under " + what;
      return P;
    }
  P.ok = true;
  return P;
}

// Classifies a fitted rigid motion: translation, rotation (axis point nearest the origin) or a
// screw motion (refused by the caller: returns kind "screw").
Transform classify(const Rigid& g, double tol) {
  Eigen::AngleAxisd aa(g.R);
  double th = aa.angle();
  if (th < 1e-9) {
    return Transform::translation_by({g.t(0), g.t(1), g.t(2)});
  }
  Eigen::Vector3d a = aa.axis().normalized();
  // axis point c: (I - R) c = t - s a, c . a = 0  (least squares over the 4x3 system)
  Eigen::Matrix<double, 4, 3> A;
  A.topRows<3>() = Eigen::Matrix3d::Identity() - g.R;
  A.row(3) = a.transpose();
  Eigen::Vector4d b;
  double screw = g.t.dot(a);
  b.head<3>() = g.t - screw * a;
  b(3) = 0;
  Eigen::Vector3d c = A.colPivHouseholderQr().solve(b);
  Transform T = Transform::rotation({c(0), c(1), c(2)}, {a(0), a(1), a(2)}, th);
  if (std::abs(screw) > tol) {
    T.kind = "screw";
    T.translation = {screw * a(0), screw * a(1), screw * a(2)};
  }
  return T;
}

// Exact values close to the fitted ones (see periodic.hpp); returns false if nothing snaps.
bool snap(const Transform& T, double tol, Transform& out) {
  if (T.kind == "translation") {
    P3 t = T.translation;
    bool any = false;
    for (double& x : t)
      if (x != 0 && std::abs(x) <= tol) x = 0, any = true;
    if (!any) return false;
    out = Transform::translation_by(t);
    return true;
  }
  P3 a = T.axis_dir, c = T.axis_point;
  double th = T.angle;
  bool any = false;
  int ax = -1;
  for (int i = 0; i < 3; ++i)
    if (std::hypot(a[(i + 1) % 3], a[(i + 2) % 3]) < 1e-6) ax = i;  // within 1e-6 rad of coordinate axis i
  if (ax >= 0) {
    if (a[ax] < 0) th = -th;
    P3 e{0, 0, 0};
    e[ax] = 1;
    any |= e != a;
    a = e;
    c[ax] = 0;
  }
  for (int i = 0; i < 3; ++i)
    if (i != ax && c[i] != 0 && std::abs(c[i]) <= tol) c[i] = 0, any = true;
  double N = std::round(2 * M_PI / std::abs(th));
  if (N >= 1 && N <= 10000) {
    double exact = std::copysign(2 * M_PI / N, th);
    if (std::abs(th - exact) < 1e-6 && exact != th) th = exact, any = true;
  }
  if (!any) return false;
  out = Transform::rotation(c, a, th);
  return true;
}

// Refines a rigid map on the paired faces (point-to-plane Gauss-Newton): the images of the lo
// face samples should lie on the hi partner's surface. The features (vertices, edge midpoints:
// intersection curves, accurate to ~1e-7) enter with a small weight, only to hold the motions the
// surfaces leave free (sliding along a plane). Why own code: a 6-unknown linear least-squares
// step (Eigen QR) repeated a few times; no library offers point-to-CAD-surface registration.
Rigid refine(const cad::Shape& s, const Transform& T, const std::vector<Pair>& faces, const std::map<int, std::vector<FaceSample>>& samples,
             const std::vector<P3>& P, const std::vector<P3>& Q, double size) {
  Rigid g;
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) g.R(i, j) = T.affine[4 * i + j];
    g.t(i) = T.affine[4 * i + 3];
  }
  const double w = 1e-3;
  for (int it = 0; it < 6; ++it) {
    std::vector<Eigen::Matrix<double, 1, 6>> rows;
    std::vector<double> rhs;
    for (const Pair& fp : faces) {
      std::optional<cad::Vec2> hint;
      for (const FaceSample& fs : samples.at(fp.lo)) {
        Eigen::Vector3d y = g.R * ev(fs.x) + g.t;
        cad::SurfaceProjection pr = s.project_to_face(fp.hi, {y(0), y(1), y(2)}, hint);
        hint = cad::Vec2{pr.u, pr.v};
        Eigen::Vector3d n = ev(p3(s.face_normal(fp.hi, pr.u, pr.v)));
        if (n.norm() < 0.5) continue;
        Eigen::Matrix<double, 1, 6> J;
        J << y.cross(n).transpose(), n.transpose();  // d(n.(y + w x y + v)) / d(w, v)
        rows.push_back(J);
        rhs.push_back(-n.dot(y - ev(p3(pr.point))));
      }
    }
    for (std::size_t i = 0; i < P.size(); ++i) {
      Eigen::Vector3d y = g.R * ev(P[i]) + g.t, r = y - ev(Q[i]);
      for (int k = 0; k < 3; ++k) {
        Eigen::Matrix<double, 1, 6> J = Eigen::Matrix<double, 1, 6>::Zero();
        Eigen::Vector3d ek = Eigen::Vector3d::Unit(k);
        J.head<3>() = w * y.cross(ek).transpose();  // e_k . (w x y) = w . (y x e_k)
        J(3 + k) = w;
        rows.push_back(J);
        rhs.push_back(-w * r(k));
      }
    }
    Eigen::MatrixXd A(rows.size(), 6);
    Eigen::VectorXd b(rows.size());
    for (std::size_t i = 0; i < rows.size(); ++i) A.row(i) = rows[i], b(i) = rhs[i];
    Eigen::Matrix<double, 6, 1> x = A.colPivHouseholderQr().solve(b);
    Eigen::Vector3d om = x.head<3>(), v = x.tail<3>();
    Eigen::Matrix3d Rw = om.norm() > 0 ? Eigen::AngleAxisd(om.norm(), om.normalized()).toRotationMatrix() : Eigen::Matrix3d::Identity();
    g.R = Rw * g.R;
    g.t = Rw * g.t + v;
    if (om.norm() * size + v.norm() < 1e-15 * size) break;
  }
  return g;
}

}  // namespace

// ── Transform ───────────────────────────────────────────────────────────────────────────
P3 Transform::apply(const P3& p) const {
  const auto& A = affine;
  return {A[0] * p[0] + A[1] * p[1] + A[2] * p[2] + A[3], A[4] * p[0] + A[5] * p[1] + A[6] * p[2] + A[7],
          A[8] * p[0] + A[9] * p[1] + A[10] * p[2] + A[11]};
}
P3 Transform::apply_vector(const P3& v) const {
  const auto& A = affine;
  return {A[0] * v[0] + A[1] * v[1] + A[2] * v[2], A[4] * v[0] + A[5] * v[1] + A[6] * v[2], A[8] * v[0] + A[9] * v[1] + A[10] * v[2]};
}
P3 Transform::apply_inverse(const P3& p) const {
  const auto& A = affine;
  P3 q{p[0] - A[3], p[1] - A[7], p[2] - A[11]};  // R^T (p - t)
  return {A[0] * q[0] + A[4] * q[1] + A[8] * q[2], A[1] * q[0] + A[5] * q[1] + A[9] * q[2], A[2] * q[0] + A[6] * q[1] + A[10] * q[2]};
}
Transform Transform::rotation(const P3& c, const P3& dir, double angle) {
  Transform T;
  T.kind = "rotation";
  double n = norm(dir);
  T.axis_dir = {dir[0] / n, dir[1] / n, dir[2] / n};
  T.axis_point = c;
  T.angle = angle;
  auto R = rodrigues(T.axis_dir, angle);
  for (int i = 0; i < 3; ++i) {
    double Rc = R[3 * i] * c[0] + R[3 * i + 1] * c[1] + R[3 * i + 2] * c[2];
    for (int j = 0; j < 3; ++j) T.affine[4 * i + j] = R[3 * i + j];
    T.affine[4 * i + 3] = c[i] - Rc;  // t = c - R c
  }
  T.affine[15] = 1;
  return T;
}
Transform Transform::translation_by(const P3& t) {
  Transform T;
  T.kind = "translation";
  T.translation = t;
  T.affine = {1, 0, 0, t[0], 0, 1, 0, t[1], 0, 0, 1, t[2], 0, 0, 0, 1};
  return T;
}

const Pair* Match::partner(int dim, int lo) const {
  const std::vector<Pair>& v = dim == 0 ? vertices : dim == 1 ? edges : faces;
  auto it = std::lower_bound(v.begin(), v.end(), lo, [](const Pair& p, int x) { return p.lo < x; });
  return it != v.end() && it->lo == lo ? &*it : nullptr;
}

// ── find ────────────────────────────────────────────────────────────────────────────────
Match find(const cad::Shape& shape, double rel_tol) { return find(shape, rel_tol, {}); }

Match find(const cad::Shape& s, double rel_tol, const std::function<void(const std::string&)>& log) {
  auto say = [&](const std::string& l) {
    if (log) log(l);
  };
  if (!(rel_tol > 0)) throw StageError("periodic_match: the tolerance must be positive");
  Side lo = side(s, cad::Tag::periodic_lo), hi = side(s, cad::Tag::periodic_hi);
  if (lo.faces.empty() && hi.faces.empty())
    throw StageError("periodic_match: the shape has no face tagged periodic_lo or periodic_hi, so there is nothing to match; tag the two "
                     "periodic sides in the geometry stage (e.g. `tag_overrides: [{tag: periodic_lo, plane: ...}, {tag: periodic_hi, "
                     "plane: ...}]`) or remove the periodic_match stage");
  if (lo.faces.empty() || hi.faces.empty())
    throw StageError(std::string("periodic_match: faces ") + list(lo.faces.empty() ? hi.faces : lo.faces) + " are tagged " +
                     (lo.faces.empty() ? "periodic_hi" : "periodic_lo") + " but no face is tagged " +
                     (lo.faces.empty() ? "periodic_lo" : "periodic_hi") + "; tag the other periodic side too");
  Match m;
  m.units = s.units();
  cad::Box box = s.box();
  m.model_size = dist(p3(box.hi), p3(box.lo));
  const double tol = rel_tol * m.model_size;
  const std::string names = "periodic_lo faces " + list(lo.faces) + " and periodic_hi faces " + list(hi.faces);

  std::map<int, std::vector<FaceSample>> samples;
  for (const Side* S : {&lo, &hi})
    for (int f : S->faces) {
      samples[f] = face_samples(s, f);
      if (samples[f].empty())
        throw StageError("periodic_match: periodic face " + std::to_string(f) + " has no sample point inside it (a sliver?); heal the shape");
    }

  // ── candidate transforms from the features ──
  const auto& FL = lo.features;
  const auto& FH = hi.features;
  std::vector<std::vector<int>> cand(FL.size());
  for (std::size_t i = 0; i < FL.size(); ++i)
    for (std::size_t j = 0; j < FH.size(); ++j)
      if (same_signature(FL[i], FH[j], tol)) cand[i].push_back(int(j));
  int a = -1;
  for (std::size_t i = 0; i < FL.size(); ++i)
    if (!cand[i].empty() && (a < 0 || cand[i].size() < cand[a].size())) a = int(i);
  auto unmatched_features = [&]() {
    std::string u;
    int k = 0;
    for (std::size_t i = 0; i < FL.size(); ++i)
      if (cand[i].empty() && k++ < 6)
        u += std::string(k > 1 ? "; " : "") + (FL[i].kind ? "edge " : "vertex ") + std::to_string(FL[i].id) + " at " + fmt(FL[i].p);
    return u;
  };
  if (FL.size() != FH.size() || a < 0)
    throw StageError("periodic_match: the periodic sides do not have the same shape: " + names + " have " + std::to_string(lo.vertices.size()) +
                     " and " + std::to_string(hi.vertices.size()) + " vertices, " + std::to_string(lo.edges.size()) + " and " +
                     std::to_string(hi.edges.size()) + " edges" +
                     (unmatched_features().empty() ? std::string() : "; periodic_lo features without a congruent partner: " + unmatched_features()) +
                     "; check the geometry or its periodic tags");
  int b = -1, c = -1;
  double best = -1;
  for (std::size_t i = 0; i < FL.size(); ++i)
    if (!cand[i].empty() && dist(FL[i].p, FL[a].p) > best) best = dist(FL[i].p, FL[a].p), b = int(i);
  best = -1;
  if (b >= 0) {
    P3 ab = sub(FL[b].p, FL[a].p);
    double L = norm(ab);
    for (std::size_t i = 0; i < FL.size(); ++i) {
      if (cand[i].empty()) continue;
      P3 ap = sub(FL[i].p, FL[a].p);
      P3 cr{ab[1] * ap[2] - ab[2] * ap[1], ab[2] * ap[0] - ab[0] * ap[2], ab[0] * ap[1] - ab[1] * ap[0]};
      double h = norm(cr) / L;
      if (h > best) best = h, c = int(i);
    }
  }
  if (b < 0 || c < 0 || best <= 10 * tol)
    throw StageError("periodic_match: the vertices and edges of " + names +
                     " are collinear (or too few): they do not fix a transformation; split the periodic faces or add a vertex");

  struct Candidate {
    Rigid g;
    std::vector<int> corr;  // hi feature of each lo feature
  };
  std::vector<Candidate> full;
  std::set<std::vector<int>> seen;
  std::size_t best_count = 0;
  std::string best_missing;
  long tried = 0;
  const long max_tries = 200000;  // symmetric sides with many congruent features: bounded work
  for (int ja : cand[a])
    for (int jb : cand[b]) {
      if (tried > max_tries) break;
      if (jb == ja || std::abs(dist(FH[ja].p, FH[jb].p) - dist(FL[a].p, FL[b].p)) > 2 * tol) continue;
      for (int jc : cand[c]) {
        if (jc == ja || jc == jb || std::abs(dist(FH[ja].p, FH[jc].p) - dist(FL[a].p, FL[c].p)) > 2 * tol ||
            std::abs(dist(FH[jb].p, FH[jc].p) - dist(FL[b].p, FL[c].p)) > 2 * tol)
          continue;
        if (++tried > max_tries) break;
        Rigid g = kabsch({FL[a].p, FL[b].p, FL[c].p}, {FH[ja].p, FH[jb].p, FH[jc].p});
        std::vector<int> corr(FL.size(), -1);
        std::set<int> used;
        std::size_t count = 0;
        std::string missing;
        for (std::size_t i = 0; i < FL.size(); ++i) {
          Eigen::Vector3d y = g.R * ev(FL[i].p) + g.t;
          int jbest = -1;
          double d = 1e300;
          for (std::size_t j = 0; j < FH.size(); ++j) {
            if (FH[j].kind != FL[i].kind) continue;
            double dj = (y - ev(FH[j].p)).norm();
            if (dj < d) d = dj, jbest = int(j);
          }
          if (jbest >= 0 && d <= 10 * tol && !used.count(jbest)) {
            corr[i] = jbest, used.insert(jbest), ++count;
          } else if (missing.size() < 300) {
            missing += std::string(missing.empty() ? "" : "; ") + (FL[i].kind ? "edge " : "vertex ") + std::to_string(FL[i].id) + " at " +
                       fmt(FL[i].p) + " (nearest image " + fmt(d) + " away)";
          }
        }
        if (count > best_count) best_count = count, best_missing = missing;
        if (count == FL.size() && seen.insert(corr).second) full.push_back({g, corr});
      }
    }
  say("periodic_match: " + std::to_string(FL.size()) + " features per side, " + std::to_string(tried) + " candidate correspondences, " +
      std::to_string(full.size()) + " carry every feature");
  if (full.empty())
    throw StageError("periodic_match: no rotation or translation carries the vertices and edges of the periodic_lo faces " + list(lo.faces) +
                     " onto those of the periodic_hi faces " + list(hi.faces) + " (the best carries " + std::to_string(best_count) + " of " +
                     std::to_string(FL.size()) + "; without partner: " + best_missing + "); the periodic sides do not have the same shape");

  // ── refit each on all its features, classify, check on the faces ──
  struct Good {
    Transform T;
    Pairing P;
    std::vector<P3> P_feat, Q_feat;  // the feature pairs it was fitted on
  };
  std::vector<Good> good;
  std::string last_error;
  for (const Candidate& cd : full) {
    std::vector<P3> P, Q;
    for (std::size_t i = 0; i < FL.size(); ++i) P.push_back(FL[i].p), Q.push_back(FH[cd.corr[i]].p);
    Rigid g = kabsch(P, Q);
    Transform T = classify(g, tol);
    if (T.kind == "screw") {
      last_error = "the only rigid motions carrying the features are screw motions (rotation by " + fmt(T.angle * 180 / M_PI) +
                   " deg about " + fmt(T.axis_dir) + " with a shift " + fmt(T.translation) + " along it), neither a rotation nor a translation";
      continue;
    }
    Pairing pr = pair_entities(s, lo, hi, T, tol, m.model_size, samples, true);
    if (!pr.ok) {
      last_error = pr.error;
      continue;
    }
    good.push_back({T, pr, P, Q});
  }
  auto describe = [](const Transform& T) {
    return T.kind == "translation" ? "translation by " + fmt(T.translation)
                                   : "rotation by " + fmt(T.angle * 180 / M_PI) + " deg about " + fmt(T.axis_dir) + " through " + fmt(T.axis_point);
  };
  if (good.size() > 1) {
    std::string l;
    for (auto& g : good) l += (l.empty() ? "" : "; ") + describe(g.T);
    throw StageError("periodic_match: several candidate transforms map " + names + " onto each other (" + l +
                     "); the periodic sides are symmetric: split them or tag fewer faces so that one map is singled out");
  }
  if (good.empty()) {
    // Report the face-level failure of the best candidate in full.
    std::vector<P3> P, Q;
    for (std::size_t i = 0; i < FL.size(); ++i) P.push_back(FL[i].p), Q.push_back(FH[full[0].corr[i]].p);
    Transform T = classify(kabsch(P, Q), tol);
    if (T.kind != "screw") {
      Pairing pr = pair_entities(s, lo, hi, T, tol, m.model_size, samples, false);
      if (!pr.ok) throw StageError("periodic_match: " + pr.error);
    }
    throw StageError("periodic_match: " + names + " do not match: " + last_error);
  }

  // ── refine on the surfaces, then snap to exact values, each when it fits at least as well ──
  Good g = std::move(good[0]);
  Pairing full_pr = pair_entities(s, lo, hi, g.T, tol, m.model_size, samples, false);
  if (!full_pr.ok) throw StageError("periodic_match: " + full_pr.error);
  {
    Transform R = classify(refine(s, g.T, full_pr.faces, samples, g.P_feat, g.Q_feat, m.model_size), tol);
    if (R.kind != "screw") {
      Pairing rp = pair_entities(s, lo, hi, R, tol, m.model_size, samples, false);
      bool take = rp.ok && rp.face_mis < full_pr.face_mis;
      say("periodic_match: fitted on the features " + describe(g.T) + " (face mismatch " + fmt(full_pr.face_mis) +
          "); refined on the surfaces " + describe(R) + " (face mismatch " + (rp.ok ? fmt(rp.face_mis) : "-") + "): " +
          (take ? "refined" : "kept the fit"));
      if (take) g.T = R, full_pr = std::move(rp);
    }
  }
  Transform snapped;
  if (snap(g.T, tol, snapped)) {
    Pairing sp = pair_entities(s, lo, hi, snapped, tol, m.model_size, samples, false);
    bool take = sp.ok && sp.face_mis <= full_pr.face_mis + 1e-13 * m.model_size;
    say("periodic_match: " + describe(g.T) + " (face mismatch " + fmt(full_pr.face_mis) + "); exact candidate " + describe(snapped) +
        " (face mismatch " + (sp.ok ? fmt(sp.face_mis) : "-") + "): " + (take ? "snapped" : "kept the fit"));
    if (take) {
      g.T = snapped;
      g.T.snapped = true;
      full_pr = std::move(sp);
    }
  }
  m.transform = g.T;
  m.faces = full_pr.faces, m.edges = full_pr.edges, m.vertices = full_pr.vertices;
  m.face_mismatch = full_pr.face_mis, m.edge_mismatch = full_pr.edge_mis, m.vertex_mismatch = full_pr.vertex_mis;
  m.max_mismatch = std::max({m.face_mismatch, m.edge_mismatch, m.vertex_mismatch});
  return m;
}

// ── image ───────────────────────────────────────────────────────────────────────────────
Image image(const cad::Shape& s, const Match& m, int dim, int lo, const P3& x, std::optional<std::array<double, 2>> hint) {
  const Pair* p = m.partner(dim, lo);
  if (!p) throw std::out_of_range("periodic: entity (" + std::to_string(dim) + ", " + std::to_string(lo) + ") has no periodic partner");
  P3 y = m.transform.apply(x);
  Image im;
  if (dim == 0) {
    im.point = p3(s.vertex_point(p->hi));
  } else if (dim == 1) {
    cad::CurveProjection pr = s.project_to_edge(p->hi, v3(y), hint ? std::optional<double>((*hint)[0]) : std::nullopt);
    im.point = p3(pr.point), im.t = pr.t;
  } else {
    cad::SurfaceProjection pr =
        s.project_to_face(p->hi, v3(y), hint ? std::optional<cad::Vec2>(cad::Vec2{(*hint)[0], (*hint)[1]}) : std::nullopt);
    im.point = p3(pr.point), im.u = pr.u, im.v = pr.v;
  }
  im.distance = dist(im.point, y);
  return im;
}

}  // namespace meshflow::periodic
