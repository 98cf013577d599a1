// The parameter-domain mesher of sweep (see uv_mesher.hpp). CGAL only; no OCCT.
#include "stages/sweep/uv_mesher.hpp"

#include <CGAL/Constrained_Delaunay_triangulation_2.h>
#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#include <CGAL/Triangulation_face_base_with_info_2.h>
#include <CGAL/Triangulation_vertex_base_with_info_2.h>

#include <algorithm>
#include <cstdio>
#include <cmath>
#include <list>
#include <map>
#include <set>
#include <stdexcept>
#include <string>

namespace meshflow::sweep::detail {
namespace {

using K = CGAL::Exact_predicates_inexact_constructions_kernel;
struct FaceInfo {
  int nesting = -1;
  bool touched = false;
  bool in_domain() const { return nesting % 2 == 1; }
};
using Vb = CGAL::Triangulation_vertex_base_with_info_2<int, K>;
using Fbi = CGAL::Triangulation_face_base_with_info_2<FaceInfo, K>;
using Fb = CGAL::Constrained_triangulation_face_base_2<K, Fbi>;
using Tds = CGAL::Triangulation_data_structure_2<Vb, Fb>;
using CDT = CGAL::Constrained_Delaunay_triangulation_2<K, Tds, CGAL::Exact_predicates_tag>;
using Point = K::Point_2;

// Nesting level of every face (CGAL's polygon-with-holes example): odd levels are inside.
void mark_domains(CDT& cdt) {
  for (auto f = cdt.all_faces_begin(); f != cdt.all_faces_end(); ++f) f->info().nesting = -1;
  std::list<CDT::Edge> border;
  auto flood = [&](CDT::Face_handle start, int index) {
    if (start->info().nesting != -1) return;
    std::list<CDT::Face_handle> queue{start};
    while (!queue.empty()) {
      auto fh = queue.front();
      queue.pop_front();
      if (fh->info().nesting != -1) continue;
      fh->info().nesting = index;
      for (int i = 0; i < 3; ++i) {
        CDT::Edge e(fh, i);
        auto n = fh->neighbor(i);
        if (n->info().nesting == -1) {
          if (cdt.is_constrained(e))
            border.push_back(e);
          else
            queue.push_back(n);
        }
      }
    }
  };
  flood(cdt.infinite_face(), 0);
  while (!border.empty()) {
    auto e = border.front();
    border.pop_front();
    auto n = e.first->neighbor(e.second);
    if (n->info().nesting == -1) flood(n, e.first->info().nesting + 1);
  }
}

double dist3(const std::array<double, 3>& a, const std::array<double, 3>& b) {
  return std::sqrt((a[0] - b[0]) * (a[0] - b[0]) + (a[1] - b[1]) * (a[1] - b[1]) + (a[2] - b[2]) * (a[2] - b[2]));
}

double seg_dist(const Point& p, const Point& a, const Point& b) {
  double dx = b.x() - a.x(), dy = b.y() - a.y();
  double l2 = dx * dx + dy * dy;
  double t = l2 > 0 ? std::clamp(((p.x() - a.x()) * dx + (p.y() - a.y()) * dy) / l2, 0.0, 1.0) : 0.0;
  double qx = a.x() + t * dx - p.x(), qy = a.y() + t * dy - p.y();
  return std::sqrt(qx * qx + qy * qy);
}

double tri_quality(const std::array<double, 3>& a, const std::array<double, 3>& b, const std::array<double, 3>& c) {
  double e1[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]}, e2[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
  double cx = e1[1] * e2[2] - e1[2] * e2[1], cy = e1[2] * e2[0] - e1[0] * e2[2], cz = e1[0] * e2[1] - e1[1] * e2[0];
  double area = 0.5 * std::sqrt(cx * cx + cy * cy + cz * cz);
  double l = dist3(a, b) * dist3(a, b) + dist3(b, c) * dist3(b, c) + dist3(c, a) * dist3(c, a);
  return l > 0 ? 4 * std::sqrt(3.0) * area / l : 0.0;
}

double orient(const std::array<double, 2>& a, const std::array<double, 2>& b, const std::array<double, 2>& c) {
  return (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]);
}

// Per boundary point: its pole (the ends of pole segments, joined), or -1. The two ends of a
// degenerate edge's segment are evaluated at parameters mapped back from Reparam's plane, not
// exactly the pole's: on the corpus capsule and rounded box they were not one point to 1e-12,
// and the segment's triangle, a point in 3D, was taken for a folded one (in.pole marks them).
std::vector<int> pole_groups(const UVMeshInput& in, const std::vector<std::array<double, 3>>& p3) {
  std::vector<int> g(in.uv.size(), -1);
  double scale = 0;
  for (auto& s : in.segments) scale = std::max(scale, dist3(p3[s[0]], p3[s[1]]));
  auto root = [&](int a) {
    while (g[a] >= 0 && g[a] != a) a = g[a];
    return a;
  };
  for (auto& s : in.segments) {
    bool marked = s[0] < static_cast<int>(in.pole.size()) && in.pole[s[0]];
    if (s[0] == s[1] || !(marked || dist3(p3[s[0]], p3[s[1]]) <= 1e-12 * scale)) continue;
    for (int v : {s[0], s[1]})
      if (g[v] < 0) g[v] = v;
    int a = root(s[0]), b = root(s[1]);
    if (a != b) g[std::max(a, b)] = std::min(a, b);
  }
  for (std::size_t v = 0; v < g.size(); ++v)
    if (g[v] >= 0) g[v] = root(static_cast<int>(v));
  return g;
}

// The mesher of one face's parameter plane: mesh_uv's steps (see uv_mesher.hpp).
class UVMesher {
 public:
  explicit UVMesher(const UVMeshInput& input) : in(input) {}
  UVMeshOutput run() {
    setup();
    insert_boundary();
    refine();
    collect_triangles();
    nb = static_cast<int>(in.uv.size());
    np = static_cast<int>(out.uv.size());
    vt.assign(np, {}), nbr.assign(np, {});
    p3.resize(np);
    swaps();
    rebuild_adjacency();  // (after the swaps: the smoothing needs the final connectivity)
    smooth();
    swaps();
    if (!in.smooth.empty()) smooth_corners();
    unfold();
    finish();
    return std::move(out);
  }

 private:
  struct Cand {
    double score;
    Point p;
    CDT::Face_handle f;
    double r;  // h/4 (3D): the spacing to the vertices around it, see insert_pass
  };
  const UVMeshInput& in;
  UVMeshOutput out;
  std::vector<std::array<double, 3>> p3, n3;  // surface points and normals of out.uv
  std::vector<int> pole;                      // per boundary point: its pole or -1 (pole_groups)
  std::set<std::pair<int, int>> segments;     // the boundary segments, (lower, higher) point
  CDT cdt;
  int nb = 0, np = 0;  // boundary points, all points (after refinement)
  std::vector<std::vector<int>> vt, nbr;  // triangles and neighbours of each point
  bool fold_check_ = true;                // tq counts a folded triangle as 0 (see swaps)

  void setup() {
    out.uv = in.uv;
    for (auto& sg : in.segments) segments.insert({std::min(sg[0], sg[1]), std::max(sg[0], sg[1])});
    p3.reserve(in.uv.size());
    for (auto& q : in.uv) p3.push_back(in.point(q[0], q[1]));
    if (in.normal)
      for (auto& q : in.uv) n3.push_back(in.normal(q[0], q[1]));
    pole = pole_groups(in, p3);
  }
  double turn(int a, int b) const {
    const auto &x = n3[a], &y = n3[b];
    double nx = std::sqrt(x[0] * x[0] + x[1] * x[1] + x[2] * x[2]), ny = std::sqrt(y[0] * y[0] + y[1] * y[1] + y[2] * y[2]);
    if (!(nx > 0) || !(ny > 0)) return 0.0;  // undefined at a pole
    return std::acos(std::clamp((x[0] * y[0] + x[1] * y[1] + x[2] * y[2]) / (nx * ny), -1.0, 1.0));
  }
  // Poles: boundary points at one 3D point (the two ends of a degenerate edge's segment: a
  // sphere's pole, a cone's apex). A triangle with two of them is the pole segment's own
  // triangle, a point in 3D: it is not refined for its shape (its quality is 0 whatever is
  // inserted), it counts as perfect in the swaps and the smoothing (nothing improves it), and
  // mesh_face drops it.
  int pole_of(int v) const { return v < static_cast<int>(pole.size()) ? pole[v] : -1; }
  bool collapsed(int a, int b, int c) const {
    return (pole_of(a) >= 0 && (pole_of(a) == pole_of(b) || pole_of(a) == pole_of(c))) ||
           (pole_of(b) >= 0 && pole_of(b) == pole_of(c));
  }
  // Folded: the 3D triangle's normal opposes the surface's at its centroid. Round a pole the
  // plane's triangles fan over more than half a turn and fold over one another: the corpus
  // sphere's face got 3,020 points in 30 passes and 17% too much area (3.684 for 3.1416) before
  // folded triangles were kept out of the swaps and the smoothing. (Refining them, by their
  // centroid, made the corpus cone's apex fan worse: 30 untangling passes, 5 crossings left.) (Vertex normals would not do: a coarse triangle across the NACA demo's revolved
  // tip has two vertices on its upper and one on its lower side, normals opposite.)
  bool folded(int a, int b, int c) const {
    if (in.orientation == 0 || !in.normal || collapsed(a, b, c)) return false;
    double e1[3], e2[3];
    for (int k = 0; k < 3; ++k) e1[k] = p3[b][k] - p3[a][k], e2[k] = p3[c][k] - p3[a][k];
    auto nn = in.normal((out.uv[a][0] + out.uv[b][0] + out.uv[c][0]) / 3, (out.uv[a][1] + out.uv[b][1] + out.uv[c][1]) / 3);
    double cx = e1[1] * e2[2] - e1[2] * e2[1], cy = e1[2] * e2[0] - e1[0] * e2[2], cz = e1[0] * e2[1] - e1[1] * e2[0];
    return in.orientation * (cx * nn[0] + cy * nn[1] + cz * nn[2]) < 0;
  }
  // (a pole's own triangle, a point in 3D, counts as perfect: nothing improves it; a folded one as 0)
  double tq(int a, int b, int c) const {
    if (collapsed(a, b, c)) return 1.0;
    if (fold_check_ && folded(a, b, c)) {
      return 0.0;
    }
    return tri_quality(p3[a], p3[b], p3[c]);
  }
  double q3(int t) const {
    auto& tr = out.tris[t];
    return tq(tr[0], tr[1], tr[2]);
  }

  // ", first between boundary points i-j and k-l at (x, y, z)": the first pair of boundary
  // segments (in input order) that cross in the parameter plane, for the message.
  std::string first_crossing() const {
    auto orient = [&](int a, int b, int c) {
      const auto &A = in.uv[a], &B = in.uv[b], &C = in.uv[c];
      double d = (B[0] - A[0]) * (C[1] - A[1]) - (B[1] - A[1]) * (C[0] - A[0]);
      return (d > 0) - (d < 0);
    };
    const auto& S = in.segments;
    for (std::size_t i = 0; i < S.size(); ++i)
      for (std::size_t j = i + 1; j < S.size(); ++j) {
        int a = S[i][0], b = S[i][1], c = S[j][0], d = S[j][1];
        auto same = [&](int x, int y) { return in.uv[x][0] == in.uv[y][0] && in.uv[x][1] == in.uv[y][1]; };
        if (same(a, c) || same(a, d) || same(b, c) || same(b, d)) continue;
        if (orient(a, b, c) * orient(a, b, d) < 0 && orient(c, d, a) * orient(c, d, b) < 0) {
          char buf[200];
          std::snprintf(buf, sizeof buf, ", first between boundary points %d-%d and %d-%d near (%.6g, %.6g, %.6g)", a, b, c, d,
                        p3[a][0], p3[a][1], p3[a][2]);
          return buf;
        }
      }
    return "";
  }

  void insert_boundary() {
    std::vector<CDT::Vertex_handle> vh(in.uv.size());
    for (std::size_t i = 0; i < in.uv.size(); ++i) {
      vh[i] = cdt.insert(Point(in.uv[i][0], in.uv[i][1]));
      vh[i]->info() = -1;
    }
    for (std::size_t i = 0; i < in.uv.size(); ++i)
      if (vh[i]->info() < 0) vh[i]->info() = static_cast<int>(i);
    try {
      for (auto& s : in.segments)
        if (vh[s[0]] != vh[s[1]]) cdt.insert_constraint(vh[s[0]], vh[s[1]]);
    } catch (const std::exception& e) {
      throw std::runtime_error(std::string("the boundary loops cross in the parameter plane (") + e.what() + ")");
    }
    {
      long nv = static_cast<long>(cdt.number_of_vertices()), ni = static_cast<long>(in.uv.size());
      if (nv < ni)
        throw std::runtime_error("the boundary has " + std::to_string(ni - nv) + " coincident points in the parameter plane");
      if (nv > ni)
        throw std::runtime_error("the boundary loops cross themselves or each other in the parameter plane (" +
                                 std::to_string(nv - ni) + " crossings" + first_crossing() +
                                 "; e.g. a junction strip wider than the face allows)");
    }
  }

  // A point inside the diametral sphere of a constrained segment (in 3D, so that a pole's
  // segment, of length 0, has none) whose sphere is still empty is not inserted. Our segments
  // are never split, so a triangle on one longer than the local size stays "big" whatever is
  // inserted, and its centroid lies a third of the way down to the segment: inserted pass after
  // pass, the apex ended ever closer to the segment, a sliver whose prism the layer's
  // directions turn over (Rotor 67: the blade beside its tip strip, where a 0.06-long segment
  // follows the trailing edge's 0.002 ones, got triangles of quality 0.012 and 0.02 there; with
  // the shell's crossing thinning on, one such prism stayed inverted after untangling). This is
  // Ruppert's encroachment rule without the split: a segment whose sphere is empty keeps it
  // empty. Next to a segment whose own triangle's apex is inside the sphere already (a face
  // narrower than its segments) refinement goes on as before (keeping DLR-F6's narrow
  // trailing-edge and pylon faces, and the end caps of junctions there, as they were). Circumcentres
  // and centroids alike; the constrained edges looked at are those of the triangle the point
  // falls in and of its three neighbours.
  bool encroaches(const std::array<double, 3>& x, CDT::Face_handle a) const {
    if (cdt.is_infinite(a)) return false;
    // true when y is inside the diametral sphere of s0-s1 (sees it under more than 90 degrees)
    auto wide = [&](const std::array<double, 3>& y, const std::array<double, 3>& s0, const std::array<double, 3>& s1) {
      double d = 0;  // (s0 - y).(s1 - y)
      for (int k = 0; k < 3; ++k) d += (s0[k] - y[k]) * (s1[k] - y[k]);
      return d < 0;
    };
    for (CDT::Face_handle fh : {a, a->neighbor(0), a->neighbor(1), a->neighbor(2)}) {
      if (cdt.is_infinite(fh) || !fh->info().in_domain()) continue;
      for (int i = 0; i < 3; ++i) {
        if (!cdt.is_constrained(CDT::Edge(fh, i))) continue;
        const auto& s0 = p3[fh->vertex(cdt.cw(i))->info()];
        const auto& s1 = p3[fh->vertex(cdt.ccw(i))->info()];
        if (wide(p3[fh->vertex(i)->info()], s0, s1)) continue;  // encroached already (a narrow face)
        if (wide(x, s0, s1)) return true;
      }
    }
    return false;
  }

  // Whether triangle f needs a point (too big for the size, turning too fast, or skinny), and which (the circumcentre when it is inside the domain and clear of the
  // constraints, else the centroid)
  bool candidate(CDT::Face_handle f, Cand& out_c) {
    int a = f->vertex(0)->info(), b = f->vertex(1)->info(), c = f->vertex(2)->info();
    double L = std::max({dist3(p3[a], p3[b]), dist3(p3[b], p3[c]), dist3(p3[c], p3[a])});
    Point g = CGAL::centroid(f->vertex(0)->point(), f->vertex(1)->point(), f->vertex(2)->point());
    double h = in.size(g.x(), g.y());
    double q = tri_quality(p3[a], p3[b], p3[c]);
    bool big = L > in.refine_ratio * h;
    // the turn-angle rule away from the boundary only: a boundary segment cannot be split, so
    // a triangle on a coarse boundary edge over a curved region would be refined for ever
    if (!big && in.normal && L > in.min_length && !cdt.is_constrained(CDT::Edge(f, 0)) && !cdt.is_constrained(CDT::Edge(f, 1)) &&
        !cdt.is_constrained(CDT::Edge(f, 2)) && std::max({turn(a, b), turn(b, c), turn(c, a)}) > in.max_turn)
      big = true;
    const bool pole_tri = collapsed(a, b, c);
    bool skinny = !big && !pole_tri && q < in.min_quality && L > 0.5 * h;
    if (!big && !skinny) return false;
    // the circumcentre when it is inside the domain and clear of the constraints, else the centroid
    Point cc = CGAL::circumcenter(f->vertex(0)->point(), f->vertex(1)->point(), f->vertex(2)->point());
    Point p = g;
    auto lf = cdt.locate(cc, f);
    if (!cdt.is_infinite(lf) && lf->info().in_domain()) {
      bool clear = !encroaches(in.point(cc.x(), cc.y()), lf);
      for (int i = 0; i < 3 && clear; ++i) {
        if (!cdt.is_constrained(CDT::Edge(lf, i))) continue;
        const Point& s0 = lf->vertex(cdt.cw(i))->point();
        const Point& s1 = lf->vertex(cdt.ccw(i))->point();
        double len = std::sqrt(CGAL::squared_distance(s0, s1));
        if (seg_dist(cc, s0, s1) < 0.5 * len) clear = false;
      }
      if (clear)
        p = cc;
      else if (skinny || q < 0.1)
        return false;  // a needle at the boundary (a thin face): a centroid would make it worse
    } else if (skinny || q < 0.1) {
      return false;
    }
    if (p == g && encroaches(in.point(g.x(), g.y()), f)) return false;  // (g is inside f)
    {
      double lmin = std::min({std::sqrt(CGAL::squared_distance(f->vertex(0)->point(), f->vertex(1)->point())),
                              std::sqrt(CGAL::squared_distance(f->vertex(1)->point(), f->vertex(2)->point())),
                              std::sqrt(CGAL::squared_distance(f->vertex(2)->point(), f->vertex(0)->point()))});
      bool near = false;
      for (int i = 0; i < 3; ++i) near |= std::sqrt(CGAL::squared_distance(p, f->vertex(i)->point())) < 1e-3 * lmin;
      if (near) return false;
      // nor a point closer than h/4 (in 3D) to a vertex of the triangle it falls in or of the
      // bad triangle: it would only make a tiny edge
      auto x = in.point(p.x(), p.y());
      auto lf2 = cdt.locate(p, f);
      for (CDT::Face_handle fh : std::array<CDT::Face_handle, 2>{f, lf2}) {
        if (cdt.is_infinite(fh)) continue;
        for (int i = 0; i < 3; ++i) {
          auto vv = fh->vertex(i);
          if (cdt.is_infinite(vv)) continue;
          near |= dist3(x, p3[vv->info()]) < 0.25 * std::min(h, L);
        }
      }
      if (near) return false;
    }
    out_c = {big ? L / h : 1 - q, p, f, 0.25 * std::min(h, L)};
    return true;
  }

  void refine() {
    for (int pass = 0; pass < in.max_passes; ++pass) {
      mark_domains(cdt);
      for (auto f = cdt.all_faces_begin(); f != cdt.all_faces_end(); ++f) f->info().touched = false;
      std::vector<Cand> cand;
      for (auto f = cdt.finite_faces_begin(); f != cdt.finite_faces_end(); ++f) {
        Cand c;
        if (f->info().in_domain() && candidate(f, c)) cand.push_back(c);
      }
      if (cand.empty()) break;
      insert_pass(cand);
      out.passes = pass + 1;
      if (out.uv.size() > in.max_points)
        throw std::runtime_error("more than " + std::to_string(in.max_points) +
                                 " points in one face: the sizes are too small for this face (raise min_size)");
    }
  }

  // One pass's candidates, best first, at most one per triangle and its neighbours.
  void insert_pass(std::vector<Cand>& cand) {
    std::stable_sort(cand.begin(), cand.end(), [](const Cand& x, const Cand& y) { return x.score > y.score; });
    std::vector<const Cand*> accept;
    for (auto& c : cand) {
      if (c.f->info().touched) continue;
      c.f->info().touched = true;
      for (int i = 0; i < 3; ++i) c.f->neighbor(i)->info().touched = true;
      accept.push_back(&c);
    }
    // The candidates were chosen against the triangulation as it was before this pass, so two
    // of them may be one point: triangles whose corners lie on one circle share their
    // circumcentre, and the `touched` rule keeps apart only neighbouring triangles. A face
    // bounded by one closed circular edge (the end discs of a cylinder: a regular polygon of
    // boundary points) has every triangle of its first pass centred on the disc's centre, up
    // to rounding: 12 points landed within 1e-15 of one another there, coincident nodes, zero-area
    // wall triangles and prisms of aspect ratio 3e14 (issue 20, corpus cylinder_in_box). A
    // point is not inserted where a point inserted before it in this pass (a vertex of the
    // triangle it falls in or of that triangle's neighbours) lies within 1e-3 of the h/4
    // spacing above (3D): the same point, up to rounding. (Points of one pass further apart are
    // kept as before: the full h/4 spacing would also drop 27 points of the NACA demo's faces,
    // 0.05 to 1 times h/4 from another, and change its mesh.)
    const int pass_first = static_cast<int>(out.uv.size());
    CDT::Face_handle hint;
    for (const Cand* c : accept) {
      const Point& p = c->p;
      {
        auto x = in.point(p.x(), p.y());
        auto lf = hint == CDT::Face_handle() ? cdt.locate(p) : cdt.locate(p, hint);
        bool near = false;
        for (CDT::Face_handle fh : {lf, lf->neighbor(0), lf->neighbor(1), lf->neighbor(2)})
          for (int i = 0; i < 3 && !near; ++i) {
            auto vv = fh->vertex(i);
            if (cdt.is_infinite(vv) || vv->info() < pass_first) continue;
            near = dist3(x, p3[vv->info()]) < 1e-3 * c->r;
          }
        if (near) continue;
      }
      auto before = cdt.number_of_vertices();
      auto v = cdt.insert(p);
      if (cdt.number_of_vertices() == before) continue;  // an existing point
      hint = v->face();
      v->info() = static_cast<int>(out.uv.size());
      out.uv.push_back({p.x(), p.y()});
      p3.push_back(in.point(p.x(), p.y()));
      if (in.normal) n3.push_back(in.normal(p.x(), p.y()));
    }
  }

  void collect_triangles() {
    mark_domains(cdt);
    for (auto f = cdt.finite_faces_begin(); f != cdt.finite_faces_end(); ++f)
      if (f->info().in_domain()) out.tris.push_back({f->vertex(0)->info(), f->vertex(1)->info(), f->vertex(2)->info()});
    std::sort(out.tris.begin(), out.tris.end());
  }

  // 3D edge swaps: an edge shared by two triangles is flipped when the flip is valid in (u,v)
  // and raises the worse 3D quality of the pair (Delaunay in the parameter plane is not
  // Delaunay on the surface where the parameterisation is anisotropic, e.g. a revolved tip
  // near its small end)
  // edge (sorted node pair) -> the triangles that have it
  std::map<std::pair<int, int>, std::vector<int>> edge_triangles() const {
    std::map<std::pair<int, int>, std::vector<int>> et;
    for (int t = 0; t < static_cast<int>(out.tris.size()); ++t)
      for (int k = 0; k < 3; ++k) {
        int a = out.tris[t][k], b = out.tris[t][(k + 1) % 3];
        et[{std::min(a, b), std::max(a, b)}].push_back(t);
      }
    return et;
  }
  int swap_passes() {
    int total = 0;
    for (int pass = 0; pass < 20; ++pass) {
      auto et = edge_triangles();
      int flips = 0;
      std::vector<char> done(out.tris.size(), 0);
      for (auto& [e, ts] : et) {
        if (ts.size() != 2 || done[ts[0]] || done[ts[1]]) continue;
        auto &T0 = out.tris[ts[0]], &T1 = out.tris[ts[1]];
        int c = -1, d = -1;
        for (int k = 0; k < 3; ++k) {
          if (T0[k] != e.first && T0[k] != e.second) c = T0[k];
          if (T1[k] != e.first && T1[k] != e.second) d = T1[k];
        }
        if (c < 0 || d < 0 || c == d) continue;
        // T0 = (a, b, c) counter-clockwise for some order of a, b
        int a = e.first, b = e.second;
        if (orient(out.uv[a], out.uv[b], out.uv[c]) < 0) std::swap(a, b);
        std::array<int, 3> N0{a, d, c}, N1{d, b, c};
        if (!(orient(out.uv[N0[0]], out.uv[N0[1]], out.uv[N0[2]]) > 0) ||
            !(orient(out.uv[N1[0]], out.uv[N1[1]], out.uv[N1[2]]) > 0))
          continue;
        double before = std::min(tq(T0[0], T0[1], T0[2]), tq(T1[0], T1[1], T1[2]));
        double after = std::min(tq(N0[0], N0[1], N0[2]), tq(N1[0], N1[1], N1[2]));
        if (after > before * 1.01 + 1e-12) {
          T0 = N0, T1 = N1;
          done[ts[0]] = done[ts[1]] = 1;
          ++flips;
        }
      }
      total += flips;
      if (flips == 0) break;
    }
    return total;
  }
  // The swaps judge by the unsigned 3D quality (as always); where that leaves a triangle folded
  // in 3D, they are redone from the same start refusing folds (folded triangles count as
  // quality 0). Where Reparam's plane is strongly sheared (a full turn of a sphere or a torus)
  // a flip valid in the plane folds a thin triangle over: the plain swaps left 191 folded on the
  // corpus sphere and 112 on the torus, and a second, fold-aware round after them still 104 and
  // 44. (Refusing folds always would change the NACA demo's tip, where a fold is taken and undone
  // within the swaps: the same triangles, their vertices in another order.)
  int swaps() {
    const auto start = out.tris;
    fold_check_ = false;
    int n = swap_passes();
    fold_check_ = true;
    if (!any_folded()) return n;
    out.tris = start;
    return swap_passes();
  }
  bool any_folded() const {
    for (auto& t : out.tris)
      if (folded(t[0], t[1], t[2])) return true;
    return false;
  }
  void rebuild_adjacency() {
    for (auto& v : vt) v.clear();
    for (auto& v : nbr) v.clear();
    for (int t = 0; t < static_cast<int>(out.tris.size()); ++t)
      for (int k = 0; k < 3; ++k) {
        int a = out.tris[t][k];
        vt[a].push_back(t);
        for (int j = 1; j < 3; ++j) nbr[a].push_back(out.tris[t][(k + j) % 3]);
      }
    for (auto& n : nbr) {
      std::sort(n.begin(), n.end());
      n.erase(std::unique(n.begin(), n.end()), n.end());
    }
  }

  // Smoothing of the new points: Laplacian in (u, v), a move kept only when every incident
  // triangle stays counter-clockwise and the worst 3D quality does not drop (a folded triangle
  // counting as 0)
  void smooth() {
    for (int pass = 0; pass < in.smooth_passes; ++pass)
      for (int i = nb; i < np; ++i) {
        if (nbr[i].empty()) continue;
        std::array<double, 2> m{0, 0};
        for (int j : nbr[i]) m[0] += out.uv[j][0], m[1] += out.uv[j][1];
        m[0] /= nbr[i].size(), m[1] /= nbr[i].size();
        double before = 1;
        for (int t : vt[i]) before = std::min(before, q3(t));
        auto old = out.uv[i];
        auto oldp = p3[i];
        out.uv[i] = m;
        p3[i] = in.point(m[0], m[1]);
        bool ok = true;
        double after = 1;
        for (int t : vt[i]) {
          auto& tr = out.tris[t];
          if (!(orient(out.uv[tr[0]], out.uv[tr[1]], out.uv[tr[2]]) > 0)) {
            ok = false;
            break;
          }
          after = std::min(after, q3(t));
        }
        if (!ok || after < before) out.uv[i] = old, p3[i] = oldp;
      }
  }

  // ── no two boundary segments of one triangle meeting at a smooth boundary point ──
  void smooth_corners() {
    auto smooth_corner = [&](int v, int a, int b) {
      return v < nb && v < static_cast<int>(in.smooth.size()) && in.smooth[v] && is_segment(a, v) && is_segment(v, b);
    };
    // The split point of triangle tr at its smooth corner k: off the middle of the shorter of the
    // two boundary segments at the smooth point, inwards by half its length, so that the corners
    // at both of its ends open to about 90 degrees (a centroid would leave the sliver's corner at
    // the smooth point nearly flat, and the curved segment's end tangent would fold it); false
    // when that point is not inside the triangle.
    auto split_point = [&](const std::array<int, 3>& tr, int k, std::array<double, 2>& q) {
      int v = tr[k], a = tr[(k + 2) % 3], b = tr[(k + 1) % 3];
      auto len = [&](int i, int j) { return std::hypot(out.uv[i][0] - out.uv[j][0], out.uv[i][1] - out.uv[j][1]); };
      int o = len(a, v) <= len(v, b) ? a : b;  // the shorter segment is (v, o)
      int far = o == a ? b : a;
      std::array<double, 2> mid{0.5 * (out.uv[v][0] + out.uv[o][0]), 0.5 * (out.uv[v][1] + out.uv[o][1])};
      std::array<double, 2> nrm{-(out.uv[o][1] - out.uv[v][1]), out.uv[o][0] - out.uv[v][0]};  // |nrm| = segment length
      double side = nrm[0] * (out.uv[far][0] - mid[0]) + nrm[1] * (out.uv[far][1] - mid[1]);
      if (side < 0) nrm = {-nrm[0], -nrm[1]};
      q = {mid[0] + 0.5 * nrm[0], mid[1] + 0.5 * nrm[1]};
      return orient(out.uv[tr[0]], out.uv[tr[1]], q) > 0 && orient(out.uv[tr[1]], out.uv[tr[2]], q) > 0 &&
             orient(out.uv[tr[2]], out.uv[tr[0]], q) > 0;
    };
    // Where that point is not inside the triangle (a flat triangle: on a sliver face, DLR-F6's
    // 1.6 mm wide, 400 mm long strips along the outer wing, the triangle of a short edge's two
    // divisions; its centroid lands 0.007 mm from the smooth point and the prisms on the
    // slivers fold into the tip's layer), the triangle's third edge (a, b) is flipped instead
    // when the quad with the triangle across it is convex in (u,v).
    {
      auto et = edge_triangles();
      std::vector<char> done(out.tris.size(), 0);
      for (int t = 0; t < static_cast<int>(out.tris.size()); ++t) {
        if (done[t]) continue;
        auto tr = out.tris[t];
        for (int k = 0; k < 3; ++k) {
          int v = tr[k], b = tr[(k + 1) % 3], a = tr[(k + 2) % 3];  // (v, b, a) counter-clockwise
          if (!smooth_corner(v, a, b)) continue;
          std::array<double, 2> q;
          if (split_point(tr, k, q) || is_segment(a, b)) break;
          auto& ts = et[{std::min(a, b), std::max(a, b)}];
          if (ts.size() != 2) break;
          int u = ts[0] == t ? ts[1] : ts[0];
          if (done[u]) break;
          int x = -1;
          for (int j = 0; j < 3; ++j)
            if (out.tris[u][j] != a && out.tris[u][j] != b) x = out.tris[u][j];
          std::array<int, 3> N0{v, b, x}, N1{v, x, a};
          if (x < 0 || !(orient(out.uv[N0[0]], out.uv[N0[1]], out.uv[N0[2]]) > 0) ||
              !(orient(out.uv[N1[0]], out.uv[N1[1]], out.uv[N1[2]]) > 0))
            break;
          out.tris[t] = N0, out.tris[u] = N1;
          done[t] = done[u] = 1;
          ++out.smooth_corner_flips;
          break;
        }
      }
    }
    const std::size_t nt = out.tris.size();
    for (std::size_t t = 0; t < nt; ++t) {
      auto tr = out.tris[t];
      int k = 0;
      while (k < 3 && !smooth_corner(tr[k], tr[(k + 2) % 3], tr[(k + 1) % 3])) ++k;
      if (k == 3) continue;
      // the split point, or the centroid when it is not inside the triangle
      std::array<double, 2> c;
      if (!split_point(tr, k, c))
        c = {(out.uv[tr[0]][0] + out.uv[tr[1]][0] + out.uv[tr[2]][0]) / 3,
             (out.uv[tr[0]][1] + out.uv[tr[1]][1] + out.uv[tr[2]][1]) / 3};
      int ci = static_cast<int>(out.uv.size());
      out.uv.push_back(c);
      p3.push_back(in.point(c[0], c[1]));
      out.tris[t] = {tr[0], tr[1], ci};
      out.tris.push_back({tr[1], tr[2], ci});
      out.tris.push_back({tr[2], tr[0], ci});
      ++out.smooth_corner_splits;
    }
  }

  // ── the triangles still folded in 3D, repaired where they are ──
  // A point inserted next to a curved boundary segment, nearly on its chord in the plane, lies
  // off it in 3D by the segment's sag: the sliver between them has a normal of either sign
  // (bottle's torus fillet: a point 0.2 of the way between two boundary points, its triangle
  // folded). For each folded triangle, in turn: flip one of its edges that is no boundary
  // segment, when both new triangles are counter-clockwise and unfolded; else move one of its
  // new points to the best of a few positions round it (Laplacian, halfway to it, a ring at a
  // third of its distance to its neighbours) at which its triangles are counter-clockwise and
  // none folded; else collapse such a point into a neighbour (the link condition kept, every
  // new triangle counter-clockwise and unfolded). Only a mesh with folds changes; points a
  // collapse left unused are dropped.
  void unfold() {
    if (!any_folded()) return;
    vt.assign(out.uv.size(), {}), nbr.assign(out.uv.size(), {});  // smooth_corners may have added points
    for (int pass = 0; pass < 8 && any_folded(); ++pass)
      for (int t = 0; t < static_cast<int>(out.tris.size()); ++t) {
        if (out.tris[t][0] < 0 || !folded(out.tris[t][0], out.tris[t][1], out.tris[t][2])) continue;
        rebuild_adjacency();
        if (flip_folded(t)) {
          ++out.unfold_repairs;
          continue;
        }
        const auto tr = out.tris[t];
        for (int v : tr)
          if (v >= nb && (relocate(v) || collapse(v))) {
            ++out.unfold_repairs;
            break;
          }
      }
    drop_unused();
  }
  bool ccw(const std::array<int, 3>& t) const { return orient(out.uv[t[0]], out.uv[t[1]], out.uv[t[2]]) > 0; }
  // counter-clockwise, unfolded, and not a pole's own triangle (a point in 3D, dropped later: a repair must not make one)
  bool sound(const std::array<int, 3>& t) const { return ccw(t) && !folded(t[0], t[1], t[2]) && !collapsed(t[0], t[1], t[2]); }
  bool is_segment(int a, int b) const { return segments.count({std::min(a, b), std::max(a, b)}) > 0; }
  bool flip_folded(int t) {
    for (int k = 0; k < 3; ++k) {
      const int a = out.tris[t][k], b = out.tris[t][(k + 1) % 3], c = out.tris[t][(k + 2) % 3];
      if (is_segment(a, b)) continue;
      for (int u : vt[a]) {
        if (u == t || out.tris[u][0] < 0) continue;
        int d = -1;
        bool has_b = false;
        for (int j = 0; j < 3; ++j) {
          has_b |= out.tris[u][j] == b;
          if (out.tris[u][j] != a && out.tris[u][j] != b) d = out.tris[u][j];
        }
        if (!has_b || d < 0) continue;
        const std::array<int, 3> N0{a, d, c}, N1{d, b, c};  // (a, b, c) counter-clockwise, d across (a, b)
        if (!sound(N0) || !sound(N1)) continue;
        out.tris[t] = N0, out.tris[u] = N1;
        return true;
      }
    }
    return false;
  }
  bool relocate(int v) {
    if (nbr[v].empty()) return false;
    std::array<double, 2> m{0, 0};
    double reach = 0;
    for (int j : nbr[v]) {
      m[0] += out.uv[j][0], m[1] += out.uv[j][1];
      reach += std::hypot(out.uv[j][0] - out.uv[v][0], out.uv[j][1] - out.uv[v][1]);
    }
    m[0] /= nbr[v].size(), m[1] /= nbr[v].size(), reach /= 3 * nbr[v].size();
    const auto old = out.uv[v];
    const auto oldp = p3[v];
    std::vector<std::array<double, 2>> cand{m, {0.5 * (old[0] + m[0]), 0.5 * (old[1] + m[1])}};
    for (int k = 0; k < 8; ++k) cand.push_back({old[0] + reach * std::cos(k * M_PI / 4), old[1] + reach * std::sin(k * M_PI / 4)});
    double best = 0;
    std::array<double, 2> at = old;
    for (const auto& c : cand) {
      out.uv[v] = c, p3[v] = in.point(c[0], c[1]);
      double worst = 1;
      for (int t : vt[v]) worst = ccw(out.tris[t]) ? std::min(worst, q3(t)) : 0.0;  // a folded one counts 0
      if (worst > best) best = worst, at = c;
    }
    out.uv[v] = at, p3[v] = best > 0 ? in.point(at[0], at[1]) : oldp;
    return best > 0;
  }
  bool collapse(int v) {
    for (int w : nbr[v]) {
      // link condition: the common neighbours of v and w are the apexes of their shared triangles
      std::vector<int> apex, common;
      for (int t : vt[v])
        for (int j = 0; j < 3; ++j)
          if (out.tris[t][j] == w)
            for (int x : out.tris[t])
              if (x != v && x != w) apex.push_back(x);
      std::set_intersection(nbr[v].begin(), nbr[v].end(), nbr[w].begin(), nbr[w].end(), std::back_inserter(common));
      std::sort(apex.begin(), apex.end());
      if (apex != common) continue;
      bool ok = true;
      std::vector<std::pair<int, std::array<int, 3>>> moved;
      for (int t : vt[v]) {
        auto n = out.tris[t];
        if (std::find(n.begin(), n.end(), w) != n.end()) continue;  // dropped
        for (int& x : n)
          if (x == v) x = w;
        if (!sound(n)) {
          ok = false;
          break;
        }
        moved.push_back({t, n});
      }
      if (!ok) continue;
      for (int t : vt[v]) out.tris[t] = {-1, -1, -1};
      for (auto& [t, n] : moved) out.tris[t] = n;
      out.tris.erase(std::remove(out.tris.begin(), out.tris.end(), std::array<int, 3>{-1, -1, -1}), out.tris.end());
      return true;
    }
    return false;
  }
  void drop_unused() {
    std::vector<int> id(out.uv.size(), -1);
    for (int i = 0; i < nb; ++i) id[i] = i;
    for (auto& t : out.tris)
      for (int v : t)
        if (v >= nb) id[v] = 0;
    int next = nb;
    for (std::size_t i = nb; i < id.size(); ++i)
      if (id[i] >= 0) {
        id[i] = next;
        out.uv[next] = out.uv[i], p3[next] = p3[i];
        if (i < n3.size()) n3[next] = n3[i];
        ++next;
      }
    if (next == static_cast<int>(out.uv.size())) return;
    out.uv.resize(next), p3.resize(next);
    if (n3.size() > out.uv.size()) n3.resize(next);
    for (auto& t : out.tris)
      for (int& v : t) v = id[v];
  }

  void finish() {
    std::sort(out.tris.begin(), out.tris.end());
    out.min_quality = 1;
    for (int t = 0; t < static_cast<int>(out.tris.size()); ++t) {
      out.min_quality = std::min(out.min_quality, q3(t));
      const auto& tr = out.tris[t];
      if (!folded(tr[0], tr[1], tr[2])) continue;
      bool on_segment = false;
      for (int k = 0; k < 3; ++k) on_segment |= is_segment(tr[k], tr[(k + 1) % 3]);
      // where it is: the first folded triangle, or the first on a boundary segment if any is
      if (out.folded++ == 0 || (on_segment && !out.folded_on_segment)) {
        out.folded_at = {0, 0, 0};
        for (int k = 0; k < 3; ++k)
          for (int c = 0; c < 3; ++c) out.folded_at[c] += p3[tr[k]][c] / 3;
        out.folded_on_segment = on_segment;
      }
    }
  }
};

}  // namespace

UVMeshOutput mesh_uv(const UVMeshInput& in) { return UVMesher(in).run(); }

}  // namespace meshflow::sweep::detail
