// The tet stage's algorithm (see tet.hpp): shell extraction, pyramids, the PLC, TetGen (through
// tetgen_call.hpp), assembly and the checks. No foreign library header here.
#include "stages/tet/tet.hpp"

#include "engine/stage.hpp"
#include "stages/model/quality.hpp"
#include "stages/model/topology.hpp"
#include "stages/shell/shell.hpp"
#include "stages/tet/tetgen_call.hpp"

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <limits>
#include <map>
#include <numeric>
#include <regex>
#include <set>
#include <sstream>

namespace meshflow::tet {
namespace {

using model::Mesh;
using model::Shape;
using Key = std::array<std::uint32_t, 4>;
constexpr std::uint32_t kNone = std::numeric_limits<std::uint32_t>::max();

Key make_key(const std::uint32_t* v, int n) {
  Key k{kNone, kNone, kNone, kNone};
  for (int i = 0; i < n; ++i) k[i] = v[i];
  std::sort(k.begin(), k.begin() + n);
  return k;
}

std::string fmt(double v) {
  char b[64];
  std::snprintf(b, sizeof b, "%.6g", v);
  return b;
}

struct P3 {
  double x, y, z;
};
P3 operator-(P3 a, P3 b) { return {a.x - b.x, a.y - b.y, a.z - b.z}; }
P3 operator+(P3 a, P3 b) { return {a.x + b.x, a.y + b.y, a.z + b.z}; }
P3 operator*(double s, P3 a) { return {s * a.x, s * a.y, s * a.z}; }
P3 cross(P3 a, P3 b) { return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x}; }
double dot(P3 a, P3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
double norm(P3 a) { return std::sqrt(dot(a, a)); }

std::string where(P3 p) {
  std::ostringstream s;
  s.precision(6);
  s << "(" << p.x << ", " << p.y << ", " << p.z << ")";
  return s.str();
}

// A face of a near-field volume element (outward oriented, Gmsh's face tables).
struct VFace {
  Key key;
  std::array<std::uint32_t, 4> v;
  int nv;
  std::uint32_t block, elem;
};
// A boundary face (2D element).
struct BFace {
  Key key;
  std::array<std::uint32_t, 4> v;
  int nv;
  std::uint32_t block, elem;
  bool covered = false;
};
// A facet of the PLC and where it comes from (for messages).
struct Facet {
  std::array<std::uint32_t, 3> v;  // node indices of the output mesh
  enum Kind { Shell, PyramidSide, Boundary, SplitQuad } kind;
  std::uint32_t block, elem;  // the near-field element (Shell, PyramidSide) or 2D element
};

class Builder {
 public:
  Builder(const Mesh& near, const Options& opt, Report& rep, const std::function<void(const std::string&)>& log)
      : in_(near), out_(near), opt_(opt), rep_(rep), log_(log) {}

  void prepare() {
    check_input();
    collect_faces();
    match_faces();
    make_pyramids();
    boundary_facets();
    lower_crossing_pyramids();
    check_closed();
    holes();
    build_plc();
    rep_.switches = switches();
  }

  std::string write_poly(const std::string& stem) {
    prepare();
    std::FILE* f = std::fopen((stem + ".poly").c_str(), "w");
    if (!f) throw StageError("tet: cannot write " + stem + ".poly");
    std::size_t np = plc_.points.size() / 3, nf = plc_.triangles.size() / 3, nh = plc_.holes.size() / 3;
    std::fprintf(f, "%zu 3 0 0\n", np);
    for (std::size_t i = 0; i < np; ++i)
      std::fprintf(f, "%zu %.17g %.17g %.17g\n", i, plc_.points[3 * i], plc_.points[3 * i + 1], plc_.points[3 * i + 2]);
    std::fprintf(f, "%zu 1\n", nf);
    for (std::size_t i = 0; i < nf; ++i)
      std::fprintf(f, "1 0 %d\n3 %u %u %u\n", plc_.markers[i], plc_.triangles[3 * i], plc_.triangles[3 * i + 1], plc_.triangles[3 * i + 2]);
    std::fprintf(f, "%zu\n", nh);
    for (std::size_t i = 0; i < nh; ++i)
      std::fprintf(f, "%zu %.17g %.17g %.17g\n", i, plc_.holes[3 * i], plc_.holes[3 * i + 1], plc_.holes[3 * i + 2]);
    std::fprintf(f, "0\n");
    bool ok = std::fclose(f) == 0;
    if (!plc_.point_size.empty()) {
      std::FILE* g = std::fopen((stem + ".mtr").c_str(), "w");
      if (!g) throw StageError("tet: cannot write " + stem + ".mtr");
      std::fprintf(g, "%zu 1\n", np);
      for (double h : plc_.point_size) std::fprintf(g, "%.17g\n", h);
      ok = std::fclose(g) == 0 && ok;
    }
    if (!ok) throw StageError("tet: cannot write " + stem + ".poly/.mtr (disk full?)");
    return rep_.switches;
  }

  Mesh run() {
    auto t0 = std::chrono::steady_clock::now();
    prepare();
    call_tetgen();
    assemble();
    verify();
    rep_.total_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    return std::move(out_);
  }

 private:
  P3 node(std::uint32_t i) const { return {out_.x[i], out_.y[i], out_.z[i]}; }
  P3 centroid(const std::uint32_t* v, int n) const {
    P3 c{0, 0, 0};
    for (int i = 0; i < n; ++i) c = c + node(v[i]);
    return (1.0 / n) * c;
  }
  std::string elem_name(std::uint32_t b, std::uint32_t e) const {
    const auto& B = in_.blocks[b];
    std::string s = std::string(model::shape_name(B.shape)) + " ";
    s += std::to_string(B.tags.empty() ? e + 1 : B.tags[e]);
    s += " of block " + std::to_string(b) + " (entity " + std::to_string(B.entity_dim) + ":" +
         std::to_string(B.entity_tag);
    std::string g = in_.group_name(B.entity_dim, B.entity_tag);
    if (!g.empty()) s += ", group '" + g + "'";
    s += ") at " + where(centroid(B.element(e), model::num_vertices(B.shape)));
    return s;
  }

  std::uint32_t new_node(P3 p, std::uint64_t& next_tag) {
    out_.x.push_back(p.x);
    out_.y.push_back(p.y);
    out_.z.push_back(p.z);
    if (!out_.node_entity_dim.empty()) {
      out_.node_entity_dim.push_back(3);
      out_.node_entity_tag.push_back(vol_tag_);
    }
    if (!out_.node_u.empty()) {
      out_.node_u.push_back(NAN);
      out_.node_v.push_back(NAN);
    }
    if (!out_.node_tags.empty()) out_.node_tags.push_back(next_tag++);
    return static_cast<std::uint32_t>(out_.x.size() - 1);
  }

  void check_input() {
    try {
      in_.check();
    } catch (const std::exception& e) {
      throw StageError(std::string("tet: the input mesh is inconsistent: ") + e.what() +
                       ". Re-run the stage that produced it (sweep) or check the file it read.");
    }
    int max3 = 0;
    for (std::uint32_t b = 0; b < in_.blocks.size(); ++b) {
      const auto& B = in_.blocks[b];
      int d = model::dimension(B.shape);
      if ((d == 2 || d == 3) && B.order != 1 && B.size())
        throw StageError("tet: the input mesh has " + std::string(model::shape_name(B.shape)) + " elements of order " +
                         std::to_string(B.order) + " (block " + std::to_string(b) +
                         "); tet works on the linear near-field mesh: run it before curve");
      if (d == 3) {
        max3 = std::max(max3, B.entity_tag);
        vol_blocks_.push_back(b);
      }
    }
    for (auto& e : in_.entities)
      if (e.dim == 3) max3 = std::max(max3, e.tag);
    vol_tag_ = max3 + 1;
    // the near field must be valid before anything is built on it
    for (std::uint32_t b : vol_blocks_) {
      const auto& B = in_.blocks[b];
      int nn = B.nodes_per_element();
      std::vector<double> X(3 * nn);
      for (std::uint32_t e = 0; e < B.size(); ++e) {
        const std::uint32_t* v = B.element(e);
        for (int i = 0; i < nn; ++i) X[3 * i] = in_.x[v[i]], X[3 * i + 1] = in_.y[v[i]], X[3 * i + 2] = in_.z[v[i]];
        auto q = model::element_quality(B.shape, 1, X.data());
        if (!q.valid)
          throw StageError("tet: the near-field input has an inverted or degenerate element: " + elem_name(b, e) +
                           " (min det J " + fmt(q.min_det) +
                           "). The far field cannot be built on it: fix the near-field mesh (sweep: shell thickness, "
                           "layer height at that place).");
        ++rep_.near_elements;
      }
    }
  }

  void collect_faces() {
    for (std::uint32_t b : vol_blocks_) {
      const auto& B = in_.blocks[b];
      const auto& faces = model::face_vertices(B.shape);
      for (std::uint32_t e = 0; e < B.size(); ++e) {
        const std::uint32_t* v = B.element(e);
        for (auto& f : faces) {
          VFace F;
          F.nv = static_cast<int>(f.size());
          F.v = {kNone, kNone, kNone, kNone};
          for (int i = 0; i < F.nv; ++i) F.v[i] = v[f[i]];
          F.key = make_key(F.v.data(), F.nv);
          F.block = b;
          F.elem = e;
          vfaces_.push_back(F);
        }
      }
    }
    auto less = [](const auto& a, const auto& b) {
      return std::tie(a.key, a.block, a.elem) < std::tie(b.key, b.block, b.elem);
    };
    std::sort(vfaces_.begin(), vfaces_.end(), less);
    for (std::uint32_t b = 0; b < in_.blocks.size(); ++b) {
      const auto& B = in_.blocks[b];
      if (model::dimension(B.shape) != 2) continue;
      int n = model::num_vertices(B.shape);
      for (std::uint32_t e = 0; e < B.size(); ++e) {
        BFace F;
        F.nv = n;
        F.v = {kNone, kNone, kNone, kNone};
        for (int i = 0; i < n; ++i) F.v[i] = B.element(e)[i];
        F.key = make_key(F.v.data(), n);
        F.block = b;
        F.elem = e;
        bfaces_.push_back(F);
      }
    }
    std::sort(bfaces_.begin(), bfaces_.end(), less);
    for (std::size_t i = 1; i < bfaces_.size(); ++i)
      if (bfaces_[i].key == bfaces_[i - 1].key)
        throw StageError("tet: the boundary face " + elem_name(bfaces_[i].block, bfaces_[i].elem) +
                         " is given twice (also " + elem_name(bfaces_[i - 1].block, bfaces_[i - 1].elem) +
                         "). Each boundary face must appear once, in one group: fix the upstream mesh.");
  }

  BFace* find_bface(const Key& k) {
    auto it = std::lower_bound(bfaces_.begin(), bfaces_.end(), k, [](const BFace& f, const Key& key) { return f.key < key; });
    return it != bfaces_.end() && it->key == k ? &*it : nullptr;
  }

  void match_faces() {
    // components of the near field (union-find over shared faces)
    std::vector<std::size_t> offset;
    std::size_t total = 0;
    for (std::uint32_t b : vol_blocks_) offset.push_back(total), total += in_.blocks[b].size();
    auto gid = [&](const VFace& f) {
      std::size_t k = std::find(vol_blocks_.begin(), vol_blocks_.end(), f.block) - vol_blocks_.begin();
      return offset[k] + f.elem;
    };
    parent_.resize(total);
    std::iota(parent_.begin(), parent_.end(), std::size_t{0});
    for (std::size_t i = 0; i < vfaces_.size();) {
      std::size_t j = i + 1;
      while (j < vfaces_.size() && vfaces_[j].key == vfaces_[i].key) ++j;
      BFace* bf = find_bface(vfaces_[i].key);
      if (j - i > 2)
        throw StageError("tet: the near-field face at " + where(centroid(vfaces_[i].v.data(), vfaces_[i].nv)) +
                         " is shared by " + std::to_string(j - i) + " elements (" + elem_name(vfaces_[i].block, vfaces_[i].elem) +
                         ", ...): the near-field mesh is not a manifold; fix it upstream (sweep).");
      if (j - i == 2) {
        std::size_t a = find(gid(vfaces_[i])), b = find(gid(vfaces_[i + 1]));
        if (a != b) parent_[std::max(a, b)] = std::min(a, b);
        if (bf) bf->covered = true;  // an interior face tagged as boundary: not part of the far field
      } else if (bf) {
        bf->covered = true;  // a wall / symmetry / periodic face of the near field
      } else {
        shell_.push_back(vfaces_[i]);
      }
      i = j;
    }
    // one hole point per component: the centroid of its first element
    std::vector<bool> seen(total, false);
    for (std::size_t k = 0; k < vol_blocks_.size(); ++k) {
      const auto& B = in_.blocks[vol_blocks_[k]];
      for (std::uint32_t e = 0; e < B.size(); ++e) {
        std::size_t r = find(offset[k] + e);
        if (seen[r]) continue;
        seen[r] = true;
        hole_points_.push_back(centroid(B.element(e), model::num_vertices(B.shape)));
      }
    }
    rep_.near_components = hole_points_.size();
  }
  std::size_t find(std::size_t a) {
    while (parent_[a] != a) a = parent_[a] = parent_[parent_[a]];
    return a;
  }

  void make_pyramids() {
    if (!in_.node_tags.empty()) next_node_tag_ = *std::max_element(in_.node_tags.begin(), in_.node_tags.end()) + 1;
    for (const auto& F : shell_) {
      if (F.nv == 3) {
        facets_.push_back({{F.v[0], F.v[1], F.v[2]}, Facet::Shell, F.block, F.elem});
        ++rep_.shell_triangles;
        continue;
      }
      ++rep_.shell_quads;
      P3 p[4];
      for (int i = 0; i < 4; ++i) p[i] = node(F.v[i]);
      P3 c = 0.25 * (p[0] + p[1] + p[2] + p[3]);
      P3 n = cross(p[2] - p[0], p[3] - p[1]);  // outward (face tables are outward oriented)
      double len = 0;
      for (int i = 0; i < 4; ++i) len += norm(p[(i + 1) % 4] - p[i]);
      len /= 4;
      double nn = norm(n);
      if (!(nn > 0))
        throw StageError("tet: the quad face of " + elem_name(F.block, F.elem) +
                         " facing the far field is degenerate; fix the near-field mesh upstream (sweep).");
      P3 apex = c + (opt_.pyramid_height * len / nn) * n;
      std::uint32_t a = new_node(apex, next_node_tag_);
      // Gmsh pyramid: base counter-clockwise seen from the apex = the outward face order
      pyramids_.push_back({F.v[0], F.v[1], F.v[2], F.v[3], a});
      double X[15];
      for (int i = 0; i < 5; ++i) {
        P3 q = node(pyramids_.back()[i]);
        X[3 * i] = q.x, X[3 * i + 1] = q.y, X[3 * i + 2] = q.z;
      }
      auto q = model::element_quality(Shape::Pyramid, 1, X);
      if (!q.valid)
        throw StageError("tet: the pyramid on the quad face of " + elem_name(F.block, F.elem) + " (apex " + where(apex) +
                         ") is inverted: the quad is too warped for pyramid_height " + fmt(opt_.pyramid_height) +
                         "; raise pyramid_height or flatten the quad upstream (sweep).");
      for (int i = 0; i < 4; ++i)
        facets_.push_back({{F.v[i], F.v[(i + 1) % 4], a}, Facet::PyramidSide, F.block, F.elem});
    }
    rep_.pyramids = pyramids_.size();
  }

  // Pairs of facets that cross (sharing no vertex), in the output mesh's nodes.
  shell::IntersectionReport facet_crossings() const {
    std::vector<std::int32_t> idx(out_.x.size(), -1);
    std::vector<shell::Vec3> pts;
    std::vector<std::array<std::int32_t, 3>> tris(facets_.size());
    for (std::size_t f = 0; f < facets_.size(); ++f)
      for (int k = 0; k < 3; ++k) {
        std::uint32_t v = facets_[f].v[k];
        if (idx[v] < 0) idx[v] = static_cast<std::int32_t>(pts.size()), pts.push_back({out_.x[v], out_.y[v], out_.z[v]});
        tris[f][k] = idx[v];
      }
    return shell::self_intersections(pts, tris, opt_.threads);
  }

  // A pyramid whose sides cross another facet (a junction hex's quad next to a symmetry plane:
  // its apex pokes through the plane; two junctions' pyramids meeting at a concave corner) has
  // its apex lowered halfway to its base, up to 5 times (pyramid_height / 32), each round
  // checked again: TetGen is never handed a surface that crosses itself on their account
  // (TetGen 1.5 dies with signal 11 on some). A pyramid lowering would invert is left.
  void lower_crossing_pyramids() {
    if (pyramids_.empty()) return;
    std::map<std::uint32_t, std::size_t> by_apex;
    for (std::size_t i = 0; i < pyramids_.size(); ++i) by_apex[pyramids_[i][4]] = i;
    std::set<std::size_t> lowered;
    for (int round = 0; round < 5; ++round) {
      auto rep = facet_crossings();
      if (rep.pairs == 0) {
        surface_checked_clean_ = true;  // call_tetgen need not check the same facets again
        break;
      }
      std::set<std::size_t> hit;
      for (auto& pr : rep.all)
        for (int f : pr)
          if (facets_[f].kind == Facet::PyramidSide) hit.insert(by_apex.at(facets_[f].v[2]));
      int moved = 0;
      for (std::size_t i : hit) {
        const auto& py = pyramids_[i];
        P3 c = 0.25 * (node(py[0]) + node(py[1]) + node(py[2]) + node(py[3])), a = node(py[4]);
        P3 lower = c + 0.5 * (a - c);
        double X[15];
        for (int k = 0; k < 4; ++k) {
          P3 q = node(py[k]);
          X[3 * k] = q.x, X[3 * k + 1] = q.y, X[3 * k + 2] = q.z;
        }
        X[12] = lower.x, X[13] = lower.y, X[14] = lower.z;
        if (!model::element_quality(Shape::Pyramid, 1, X).valid) continue;
        out_.x[py[4]] = lower.x, out_.y[py[4]] = lower.y, out_.z[py[4]] = lower.z;
        lowered.insert(i);
        ++moved;
      }
      if (moved == 0) break;  // no pyramid can change what crosses: the same facets would be checked again
    }
    rep_.pyramids_lowered = lowered.size();
    if (!lowered.empty() && log_)
      log_("tet: " + std::to_string(lowered.size()) + " pyramid(s) crossing other facets had their apex lowered");
  }

  void boundary_facets() {
    for (auto& F : bfaces_) {
      if (F.covered) continue;
      if (F.nv == 3) {
        facets_.push_back({{F.v[0], F.v[1], F.v[2]}, Facet::Boundary, F.block, F.elem});
        ++rep_.boundary_triangles;
        continue;
      }
      // split along the shorter diagonal (ties: the diagonal through the first vertex)
      P3 p[4];
      for (int i = 0; i < 4; ++i) p[i] = node(F.v[i]);
      bool d02 = norm(p[2] - p[0]) <= norm(p[3] - p[1]);
      std::array<std::uint32_t, 3> t1, t2;
      if (d02)
        t1 = {F.v[0], F.v[1], F.v[2]}, t2 = {F.v[0], F.v[2], F.v[3]};
      else
        t1 = {F.v[0], F.v[1], F.v[3]}, t2 = {F.v[1], F.v[2], F.v[3]};
      facets_.push_back({t1, Facet::SplitQuad, F.block, F.elem});
      facets_.push_back({t2, Facet::SplitQuad, F.block, F.elem});
      split_.push_back({&F, t1, t2});
      ++rep_.boundary_quads_split;
    }
  }

  std::string facet_name(std::size_t f) const {
    const Facet& F = facets_[f];
    P3 c = centroid(F.v.data(), 3);
    switch (F.kind) {
      case Facet::Shell: return "the shell triangle at " + where(c) + " (outer face of " + elem_name(F.block, F.elem) + ")";
      case Facet::PyramidSide:
        return "a side of the pyramid at " + where(c) + " (on the quad face of " + elem_name(F.block, F.elem) + ")";
      case Facet::Boundary: return "the boundary triangle " + elem_name(F.block, F.elem);
      case Facet::SplitQuad: return "a half of the boundary quad " + elem_name(F.block, F.elem);
    }
    return {};
  }

  void check_closed() {
    if (facets_.empty())
      throw StageError("tet: there is no far field to mesh: the input has no shell faces (faces of one near-field element "
                       "that are not boundary faces) and no uncovered boundary faces. Give tet the near-field mesh with "
                       "its farfield/symmetry boundary faces.");
    std::vector<std::pair<std::array<std::uint32_t, 2>, std::uint32_t>> edges;
    edges.reserve(3 * facets_.size());
    for (std::uint32_t f = 0; f < facets_.size(); ++f)
      for (int i = 0; i < 3; ++i) {
        std::uint32_t a = facets_[f].v[i], b = facets_[f].v[(i + 1) % 3];
        if (a == b)
          throw StageError("tet: " + facet_name(f) + " has a repeated vertex; fix the input mesh upstream.");
        edges.push_back({{std::min(a, b), std::max(a, b)}, f});
      }
    std::sort(edges.begin(), edges.end());
    std::size_t open = 0;
    std::string first;
    for (std::size_t i = 0; i < edges.size();) {
      std::size_t j = i + 1;
      while (j < edges.size() && edges[j].first == edges[i].first) ++j;
      if ((j - i) % 2 == 1) {
        if (!open++)
          first = "the edge " + where(node(edges[i].first[0])) + " - " + where(node(edges[i].first[1])) + " is used by " +
                  std::to_string(j - i) + " face(s) of the far-field boundary (e.g. " + facet_name(edges[i].second) + ")";
      }
      i = j;
    }
    if (open)
      throw StageError("tet: the far-field boundary is not closed: " + std::to_string(open) + " edge(s) have an odd number of faces; " +
                       first + ". The shell (outer faces of the near field) and the farfield/symmetry/periodic boundary "
                       "faces must close the far-field region: check that every boundary face is present and that they share "
                       "the nodes of the shell (no duplicate nodes).");
    // a closed surface TetGen can fill is also a manifold: an edge of more than two faces is a
    // pinch of the far-field region (e.g. a thin pocket of the shell between three quads that
    // share an edge pairwise: a junction ending on a third wall face, sweep.hpp KNOWN
    // LIMITATION), on which TetGen finds intersecting facets or crashes
    std::size_t pinched = 0;
    std::string pfirst;
    for (std::size_t i = 0; i < edges.size();) {
      std::size_t j = i + 1;
      while (j < edges.size() && edges[j].first == edges[i].first) ++j;
      if (j - i > 2 && !pinched++) {
        std::string fs;
        for (std::size_t k = i; k < j && k < i + 4; ++k) fs += (k > i ? "; " : "") + facet_name(edges[k].second);
        pfirst = "the edge " + where(node(edges[i].first[0])) + " - " + where(node(edges[i].first[1])) + " is used by " +
                 std::to_string(j - i) + " faces (" + fs + ")";
      }
      i = j;
    }
    if (pinched)
      throw StageError("tet: the far-field boundary is not a manifold: " + std::to_string(pinched) +
                       " edge(s) are used by more than two of its faces; " + pfirst +
                       ". The near field's outer surface touches itself there (a pocket or a pinch), which TetGen cannot mesh. "
                       "Where a junction ends on a wall face that is not one of its faces (stages/sweep/sweep.hpp, KNOWN "
                       "LIMITATION) make that face's edges junctions too (shell.junction_angle_deg, shell.junction_with) or use "
                       "shell.topology O; otherwise fix the near field upstream (sweep).");
  }

  void holes() {
    for (auto& h : hole_points_) plc_.holes.insert(plc_.holes.end(), {h.x, h.y, h.z});
  }

  void build_plc() {
    plc_of_node_.assign(out_.num_nodes(), kNone);
    for (auto& F : facets_)
      for (auto v : F.v) plc_of_node_[v] = 0;
    for (std::uint32_t i = 0; i < out_.num_nodes(); ++i)
      if (plc_of_node_[i] != kNone) {
        plc_of_node_[i] = static_cast<std::uint32_t>(node_of_plc_.size());
        node_of_plc_.push_back(i);
        plc_.points.insert(plc_.points.end(), {out_.x[i], out_.y[i], out_.z[i]});
      }
    for (std::uint32_t f = 0; f < facets_.size(); ++f) {
      for (auto v : facets_[f].v) plc_.triangles.push_back(plc_of_node_[v]);
      plc_.markers.push_back(static_cast<int>(f + 1));
    }
    rep_.plc_points = node_of_plc_.size();
    rep_.plc_facets = facets_.size();
    size_field();
  }

  // h(p) = min(own(p), min over shell points s of own(s) + growth |p - s|)
  void size_field() {
    if (!(opt_.size_growth > 0)) return;
    std::size_t n = node_of_plc_.size();
    std::vector<double> sum(n, 0);
    std::vector<int> cnt(n, 0);
    std::vector<std::array<std::uint32_t, 2>> edges;
    for (std::size_t t = 0; t < plc_.triangles.size(); t += 3)
      for (int i = 0; i < 3; ++i) {
        std::uint32_t a = plc_.triangles[t + i], b = plc_.triangles[t + (i + 1) % 3];
        edges.push_back({std::min(a, b), std::max(a, b)});
      }
    std::sort(edges.begin(), edges.end());
    edges.erase(std::unique(edges.begin(), edges.end()), edges.end());
    auto P = [&](std::uint32_t i) { return P3{plc_.points[3 * i], plc_.points[3 * i + 1], plc_.points[3 * i + 2]}; };
    for (auto& e : edges) {
      double l = norm(P(e[0]) - P(e[1]));
      sum[e[0]] += l, sum[e[1]] += l, ++cnt[e[0]], ++cnt[e[1]];
    }
    std::vector<double> own(n);
    for (std::size_t i = 0; i < n; ++i) own[i] = sum[i] / std::max(cnt[i], 1);
    std::vector<std::uint32_t> src;
    std::vector<bool> is_src(n, false);
    for (auto& F : facets_)
      if (F.kind == Facet::Shell || F.kind == Facet::PyramidSide)
        for (auto v : F.v) is_src[plc_of_node_[v]] = true;
    for (std::uint32_t i = 0; i < n; ++i)
      if (is_src[i]) src.push_back(i);
    if (src.empty()) return;
    std::sort(src.begin(), src.end(), [&](std::uint32_t a, std::uint32_t b) {
      return std::make_pair(plc_.points[3 * a], a) < std::make_pair(plc_.points[3 * b], b);
    });
    std::vector<double> sx(src.size());
    double hmin = std::numeric_limits<double>::infinity();
    for (std::size_t k = 0; k < src.size(); ++k) sx[k] = plc_.points[3 * src[k]], hmin = std::min(hmin, own[src[k]]);
    double g = opt_.size_growth;
    plc_.point_size.resize(n);
    for (std::uint32_t i = 0; i < n; ++i) {
      P3 p = P(i);
      double best = own[i];
      std::size_t mid = std::lower_bound(sx.begin(), sx.end(), p.x) - sx.begin();
      for (std::size_t k = mid; k < src.size() && hmin + g * (sx[k] - p.x) < best; ++k)
        best = std::min(best, own[src[k]] + g * norm(p - P(src[k])));
      for (std::size_t k = mid; k-- > 0 && hmin + g * (p.x - sx[k]) < best;)
        best = std::min(best, own[src[k]] + g * norm(p - P(src[k])));
      plc_.point_size[i] = best;
    }
  }

  std::string switches() const {
    std::string sw = "pYMzQ";
    sw += "q" + fmt(opt_.radius_edge) + "/" + fmt(opt_.min_dihedral);
    if (opt_.max_volume > 0) sw += "a" + fmt(opt_.max_volume);
    if (!plc_.point_size.empty()) sw += "m";
    sw += "O" + std::to_string(opt_.optimisation);
    if (opt_.max_steiner >= 0) sw += "S" + std::to_string(opt_.max_steiner);
    return sw;
  }

  // TetGen on the PLC: refused before the call when its facets cross (TetGen cannot mesh that
  // and 1.5 crashes on some); an internal error (a crash) on a surface that does not cross is
  // retried once with the quality bounds relaxed and no optimisation, the switches that differ
  // reported (stats.switches_retry); other failures stop the stage, naming what TetGen named.
  void call_tetgen() {
    const std::string& sw = rep_.switches;
    auto t0 = std::chrono::steady_clock::now();
    if (std::string c = surface_checked_clean_ ? std::string() : crossings(false); !c.empty())
      throw StageError("tet: the surface TetGen would fill crosses itself, so TetGen is not run (it cannot mesh "
                       "that, and crashes on some)." + c);
    try {
      res_ = detail::run_tetgen(plc_, sw);
    } catch (const detail::TetgenFailure& f) {
      emit(f.output);
      if (f.code != 2) throw StageError(failure_message(f));
      rep_.switches_retry = relaxed_switches();
      if (log_) log_("tet: TetGen failed (" + std::string(f.what()) + "); retried with -" + rep_.switches_retry);
      try {
        res_ = detail::run_tetgen(plc_, rep_.switches_retry);
      } catch (const detail::TetgenFailure& g) {
        emit(g.output);
        throw StageError(failure_message(f) + " Retried with -" + rep_.switches_retry + ": " + g.what() + ".");
      }
    }
    rep_.tetgen_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    emit(res_.output);
    check_budget();
  }

  // The element budget: a far field sized wrongly for its body (a far field many body lengths
  // away meshed with near-body sizes) gives millions of tetrahedra that curve, at order 4, cannot
  // hold in memory (about 2.6 kB per element: 81 MB for the corpus capsule's 31 k). Stop here,
  // saying what to change, rather than many minutes later out of memory.
  void check_budget() const {
    std::size_t n = res_.tets.size() / 4;
    if (opt_.max_elements <= 0 || n <= (std::size_t)opt_.max_elements) return;
    throw StageError("tet: TetGen made " + std::to_string(n) + " tetrahedra, more than max_elements " +
                     std::to_string(opt_.max_elements) + " (about " + fmt(2.6e-6 * n) +
                     " GB at order 4 in curve). The far field is probably meshed finer than it needs: raise "
                     "sweep.farfield_size (the far-field boundary's element size) or tet.size_growth (how fast "
                     "elements grow away from the body), or raise tet.max_elements if this many is intended.");
  }

  // The switches of the retry: quality bounds relaxed (radius-edge 2, no dihedral bound), no
  // mesh optimisation; sizes and limits as asked.
  std::string relaxed_switches() const {
    std::string sw = "pYMzQq2/0";
    if (opt_.max_volume > 0) sw += "a" + fmt(opt_.max_volume);
    if (!plc_.point_size.empty()) sw += "m";
    sw += "O0";
    if (opt_.max_steiner >= 0) sw += "S" + std::to_string(opt_.max_steiner);
    return sw;
  }

  void emit(const std::string& text) {
    if (!log_) return;
    std::istringstream s(text);
    std::string line;
    while (std::getline(s, line))
      if (!line.empty()) log_("tetgen: " + line);
  }

  // Only after TetGen failed (no cost on success): which facets of the far-field boundary cross
  // each other (CGAL's AABB tree, exact predicates; pairs sharing a vertex are not tested), as
  // TetGen's own words name at most two facets and often none (it crashes on some of them). The
  // run log lists up to 20 pairs; the message counts them by the near-field blocks involved.
  std::string crossings(bool after_failure = true) const {
    std::vector<shell::Vec3> pts(node_of_plc_.size());
    for (std::size_t i = 0; i < pts.size(); ++i) pts[i] = {plc_.points[3 * i], plc_.points[3 * i + 1], plc_.points[3 * i + 2]};
    std::vector<std::array<std::int32_t, 3>> tris(facets_.size());
    for (std::size_t f = 0; f < facets_.size(); ++f)
      for (int k = 0; k < 3; ++k) tris[f][k] = static_cast<std::int32_t>(plc_.triangles[3 * f + k]);
    auto rep = shell::self_intersections(pts, tris, opt_.threads);
    if (rep.pairs == 0)
      return after_failure ? " Checked after the failure: no two facets of the far-field boundary without a common vertex cross." : "";
    // what a facet belongs to: a boundary face's CAD face, or for the near field the CAD entity
    // of its element's first node (a prism's wall node: its wall face; a junction hex's: its edge)
    auto origin = [&](std::size_t f) {
      const Facet& F = facets_[f];
      const auto& B = in_.blocks[F.block];
      if (F.kind == Facet::Boundary || F.kind == Facet::SplitQuad) {
        std::string n = in_.group_name(B.entity_dim, B.entity_tag);
        return "boundary face " + std::to_string(B.entity_tag) + (n.empty() ? "" : " (" + n + ")");
      }
      std::uint32_t n0 = B.nodes[static_cast<std::size_t>(F.elem) * B.nodes_per_element()];
      if (in_.node_entity_dim.empty() || in_.node_entity_dim[n0] > 2) return std::string("the near field");
      return std::string(in_.node_entity_dim[n0] == 2 ? "the layer on face " : "the junction on edge ") +
             std::to_string(in_.node_entity_tag[n0]);
    };
    std::map<std::string, long> by;
    for (std::size_t i = 0; i < rep.all.size(); ++i) {
      auto a = origin(rep.all[i][0]), b = origin(rep.all[i][1]);
      ++by[a < b ? a + " x " + b : b + " x " + a];
      if (log_ && i < 20) log_("crossing facets: " + facet_name(rep.all[i][0]) + " and " + facet_name(rep.all[i][1]));
    }
    std::string s = std::string(after_failure ? " Checked after the failure: " : " ") + std::to_string(rep.pairs) +
                    " pair(s) of facets of the far-field boundary cross (first: " + facet_name(rep.all[0][0]) + " and " + facet_name(rep.all[0][1]) +
                    "); by where they come from:";
    int k = 0;
    for (auto& [what, n] : by)
      if (k++ < 6) s += (k > 1 ? ";" : "") + std::string(" ") + what + " " + std::to_string(n);
    return s + ". The near field's outer faces must not cross each other or the outer boundary; sweep thins the layer "
               "where they do (its stats outer_crossings: what it could not clear), the shell stage's stats "
               "self_intersection_* say where its own surface crosses.";
  }

  std::string failure_message(const detail::TetgenFailure& f) const {
    std::string msg = "tet: " + std::string(f.what()) + " (TetGen code " + std::to_string(f.code) + ", switches -" +
                      rep_.switches + ")";
    // TetGen names what it could not handle: "1st: [a, b, c] #m" (a facet: its points and our
    // marker = facet index + 1) or "1st: [a,b] m." (a segment: its end points)
    std::regex item(R"((1st|2nd): \[([0-9, ]+)\]( #([0-9]+))?)");
    std::vector<std::string> named;
    std::size_t np = node_of_plc_.size();
    for (std::sregex_iterator it(f.output.begin(), f.output.end(), item), end; it != end && named.size() < 4; ++it) {
      std::vector<std::size_t> ids;
      std::istringstream is(std::regex_replace((*it)[2].str(), std::regex(","), " "));
      std::size_t v;
      while (is >> v) ids.push_back(v);
      bool ok = !ids.empty();
      for (auto i : ids) ok = ok && i < np;
      if (!ok) continue;
      std::string d;
      if ((*it)[4].matched) {
        std::size_t m = std::stoul((*it)[4].str());
        if (m >= 1 && m <= facets_.size()) d = facet_name(m - 1);
      }
      if (d.empty() && ids.size() == 2)
        d = "the edge " + where(node(node_of_plc_[ids[0]])) + " - " + where(node(node_of_plc_[ids[1]]));
      if (d.empty()) {
        P3 c{0, 0, 0};
        for (auto i : ids) c = c + node(node_of_plc_[i]);
        d = "the face at " + where((1.0 / ids.size()) * c);
      }
      if (std::find(named.begin(), named.end(), d) == named.end()) named.push_back(d);
    }
    if (!named.empty()) {
      msg += ": ";
      for (std::size_t i = 0; i < named.size(); ++i) msg += (i ? " and " : "") + named[i];
    }
    std::string said;
    {
      std::istringstream s(f.output);
      std::string line;
      while (std::getline(s, line)) {
        // the C library's own words when TetGen 1.5.0 crashes after reporting (double free)
        if (line.empty() || line.find("invalid pointer") != std::string::npos || line.find("free()") != std::string::npos ||
            line.find("corrupted") != std::string::npos)
          continue;
        while (!line.empty() && line[0] == ' ') line.erase(0, 1);
        said += (said.empty() ? "" : " ") + line;
      }
    }
    if (said.size() > 400) said = "..." + said.substr(said.size() - 400);
    if (!said.empty()) msg += ". TetGen said: \"" + said + "\"";
    switch (f.code) {
      case 3:
        msg += ". The far-field boundary intersects itself: the shell crosses a farfield/symmetry face or another part of "
               "the shell (shell too thick for the domain, or pyramids colliding: lower pyramid_height).";
        break;
      case 4:
      case 5:
        msg += ". Two input faces or points are nearly coincident: check for duplicate nodes and for shell faces touching "
               "the outer boundary.";
        break;
      case 1: msg += ". Lower the refinement (raise max_volume or radius_edge) or give the stage more memory."; break;
      default: msg += ". Check the input surface (closed, not self-intersecting) and the quality parameters."; break;
    }
    return msg;
  }

  void assemble() {
    std::size_t n_in = node_of_plc_.size(), n_out = res_.points.size() / 3;
    if (n_out < n_in)
      throw StageError("tet: TetGen returned fewer points (" + std::to_string(n_out) + ") than it was given (" +
                       std::to_string(n_in) + "): coincident input points were merged; check the input for duplicate nodes.");
    for (std::size_t i = 0; i < 3 * n_in; ++i)
      if (res_.points[i] != plc_.points[i])
        throw StageError("tet: TetGen moved input point " + std::to_string(i / 3) + " at " +
                         where(node(node_of_plc_[i / 3])) + "; this should not happen with -Y: report it with the input mesh.");
    rep_.steiner_points = n_out - n_in;
    std::vector<std::uint32_t> mesh_of(n_out);
    for (std::size_t i = 0; i < n_in; ++i) mesh_of[i] = node_of_plc_[i];
    for (std::size_t i = n_in; i < n_out; ++i)
      mesh_of[i] = new_node({res_.points[3 * i], res_.points[3 * i + 1], res_.points[3 * i + 2]}, next_node_tag_);

    // the boundary of the result must be exactly the PLC (no Steiner point, no flip on it)
    std::vector<Key> want, got;
    for (std::size_t t = 0; t < plc_.triangles.size(); t += 3) want.push_back(make_key(&plc_.triangles[t], 3));
    for (std::size_t t = 0; t < res_.faces.size(); t += 3) got.push_back(make_key(&res_.faces[t], 3));
    std::sort(want.begin(), want.end());
    std::sort(got.begin(), got.end());
    if (want != got) {
      std::vector<Key> missing;
      std::set_difference(want.begin(), want.end(), got.begin(), got.end(), std::back_inserter(missing));
      std::string w = missing.empty() ? std::string("extra boundary faces")
                                      : "the input face at " + where(centroid(std::array<std::uint32_t, 3>{node_of_plc_[missing[0][0]], node_of_plc_[missing[0][1]], node_of_plc_[missing[0][2]]}.data(), 3));
      throw StageError("tet: TetGen did not keep the shell/boundary triangles exactly (" + std::to_string(missing.size()) +
                       " input faces missing, " + std::to_string(got.size()) + " boundary faces for " +
                       std::to_string(want.size()) + " given; first: " + w +
                       "). The region is probably not closed where expected (a hole point in the far field?).");
    }

    // far-field elements in one new volume entity with the groups of the first volume entity
    std::vector<int> phys;
    for (auto& e : in_.entities)
      if (e.dim == 3) {
        phys = e.physicals;
        break;
      }
    out_.add_entity(3, vol_tag_, phys);
    std::uint64_t next_elem_tag = 1;
    bool tagged = false;
    for (auto& B : out_.blocks) {
      if (!B.tags.empty()) tagged = true, next_elem_tag = std::max(next_elem_tag, *std::max_element(B.tags.begin(), B.tags.end()) + 1);
      else if (B.size()) next_elem_tag = std::max<std::uint64_t>(next_elem_tag, 1);
    }
    if (tagged) {
      // implicit tags of untagged blocks are index + 1: stay above every explicit and implicit tag
      for (auto& B : out_.blocks) next_elem_tag = std::max<std::uint64_t>(next_elem_tag, B.size() + 1);
    }
    if (!pyramids_.empty()) {
      auto& PB = out_.block(Shape::Pyramid, 1, 3, vol_tag_);
      for (auto& p : pyramids_) {
        PB.add(p.data());
        if (tagged) PB.tags.push_back(next_elem_tag++);
      }
    }
    auto& TB = out_.block(Shape::Tet, 1, 3, vol_tag_);
    std::size_t nt = res_.tets.size() / 4;
    TB.nodes.reserve(4 * nt);
    for (std::size_t t = 0; t < nt; ++t) {
      std::uint32_t v[4];
      for (int k = 0; k < 4; ++k) v[k] = mesh_of[res_.tets[4 * t + k]];
      if (dot(cross(node(v[1]) - node(v[0]), node(v[2]) - node(v[0])), node(v[3]) - node(v[0])) < 0) std::swap(v[1], v[2]);
      TB.add(v);
      if (tagged) TB.tags.push_back(next_elem_tag++);
    }
    rep_.tets = nt;

    // boundary quads that were split: replace them by their two triangles
    if (!split_.empty()) {
      std::vector<std::vector<bool>> drop(out_.blocks.size());
      for (auto& s : split_) {
        auto& d = drop[s.face->block];
        d.resize(out_.blocks[s.face->block].size(), false);
        d[s.face->elem] = true;
      }
      for (auto& s : split_) {
        const auto& Q = in_.blocks[s.face->block];
        auto& T = out_.block(Shape::Tri, 1, Q.entity_dim, Q.entity_tag);
        T.add(s.t1.data());
        T.add(s.t2.data());
        if (tagged) T.tags.push_back(next_elem_tag++), T.tags.push_back(next_elem_tag++);
      }
      for (std::size_t b = 0; b < drop.size(); ++b) {
        if (drop[b].empty()) continue;
        auto& B = out_.blocks[b];
        int nn = B.nodes_per_element();
        std::vector<std::uint32_t> keep;
        std::vector<std::uint64_t> keep_tags;
        for (std::size_t e = 0; e < B.size(); ++e)
          if (!drop[b][e]) {
            keep.insert(keep.end(), B.element(e), B.element(e) + nn);
            if (!B.tags.empty()) keep_tags.push_back(B.tags[e]);
          }
        B.nodes = std::move(keep);
        B.tags = std::move(keep_tags);
      }
      std::vector<model::ElementBlock> kept;
      for (auto& B : out_.blocks)
        if (B.size() || model::dimension(B.shape) != 2) kept.push_back(std::move(B));
      out_.blocks = std::move(kept);
    }
  }

  // The model's own statistics are the final gate (validity of every element, conformity of
  // every face); the leak check (every face of one element is a boundary face) follows from
  // TetGen's boundary being exactly the PLC, checked in assemble(). Only when the gate fails
  // are the elements and faces searched for a location to report.
  void verify() {
    auto t0 = std::chrono::steady_clock::now();
    rep_.mesh_stats = model::mesh_stats(out_, opt_.threads);
    rep_.check_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    if (rep_.mesh_stats.value("invalid", 0) != 0 || rep_.mesh_stats.value("nonconforming_faces", 0) != 0) locate_problem();
  }

  void locate_problem() {
    // every new element valid (the near field was checked on input)
    for (std::uint32_t b = 0; b < out_.blocks.size(); ++b) {
      const auto& B = out_.blocks[b];
      if (model::dimension(B.shape) != 3 || B.entity_tag != vol_tag_) continue;
      int nn = B.nodes_per_element();
      std::vector<double> X(3 * nn);
      for (std::size_t e = 0; e < B.size(); ++e) {
        const std::uint32_t* v = B.element(e);
        for (int i = 0; i < nn; ++i) X[3 * i] = out_.x[v[i]], X[3 * i + 1] = out_.y[v[i]], X[3 * i + 2] = out_.z[v[i]];
        auto q = model::element_quality(B.shape, 1, X.data());
        if (!q.valid)
          throw StageError("tet: the far-field " + std::string(model::shape_name(B.shape)) + " " + std::to_string(e + 1) +
                           " at " + where(centroid(v, nn)) + " is inverted or degenerate (min det J " + fmt(q.min_det) +
                           "); no mesh is written. Check the input surface there (nearly coincident faces) or change "
                           "pyramid_height/radius_edge.");
      }
    }
    // conformity, and every face of a single element must be a boundary face of the output
    model::Topology topo = model::build_topology(out_);
    std::vector<Key> bkeys;
    for (auto& B : out_.blocks)
      if (model::dimension(B.shape) == 2)
        for (std::size_t e = 0; e < B.size(); ++e) bkeys.push_back(make_key(B.element(e), model::num_vertices(B.shape)));
    std::sort(bkeys.begin(), bkeys.end());
    for (auto& f : topo.faces) {
      P3 c = centroid(f.vertices.data(), f.num_vertices);
      if (!f.conforming)
        throw StageError("tet: the face at " + where(c) + " is not conforming (" + std::to_string(f.elements.size()) +
                         " elements); no mesh is written. Report this with the input mesh.");
      if (f.elements.size() == 1) {
        Key k{kNone, kNone, kNone, kNone};
        for (int i = 0; i < f.num_vertices; ++i) k[i] = f.vertices[i];
        if (!std::binary_search(bkeys.begin(), bkeys.end(), k))
          throw StageError("tet: the face at " + where(c) + " bounds the mesh but is no boundary face of any group: "
                           "the far field leaks there (a gap between the shell and the boundary faces, or a missing "
                           "boundary face). Check the input surface.");
      }
    }
    throw StageError("tet: the assembled mesh has " + rep_.mesh_stats["invalid"].dump() + " invalid elements and " +
                       rep_.mesh_stats["nonconforming_faces"].dump() + " non-conforming faces; no mesh is written.");
  }

  struct Split {
    BFace* face;
    std::array<std::uint32_t, 3> t1, t2;
  };

  const Mesh& in_;
  Mesh out_;
  const Options& opt_;
  Report& rep_;
  std::function<void(const std::string&)> log_;
  int vol_tag_ = 1;
  std::uint64_t next_node_tag_ = 1;
  std::vector<std::uint32_t> vol_blocks_;
  std::vector<VFace> vfaces_, shell_;
  std::vector<BFace> bfaces_;
  std::vector<std::size_t> parent_;
  std::vector<P3> hole_points_;
  std::vector<std::array<std::uint32_t, 5>> pyramids_;
  bool surface_checked_clean_ = false;  // lower_crossing_pyramids found no crossing facets
  std::vector<Facet> facets_;
  std::vector<Split> split_;
  detail::Plc plc_;
  std::vector<std::uint32_t> plc_of_node_, node_of_plc_;
  detail::TetgenResult res_;
};

}  // namespace

nlohmann::json Report::to_json() const {
  nlohmann::json j = {{"near_elements", near_elements},
          {"near_components", near_components},
          {"shell_triangles", shell_triangles},
          {"shell_quads", shell_quads},
          {"pyramids", pyramids},
          {"boundary_triangles", boundary_triangles},
          {"boundary_quads_split", boundary_quads_split},
          {"plc_points", plc_points},
          {"plc_facets", plc_facets},
          {"tets", tets},
          {"steiner_points", steiner_points},
          {"steiner_points_on_boundary", 0},
          {"tetgen_seconds", tetgen_seconds},
          {"check_seconds", check_seconds},
          {"total_seconds", total_seconds},
          {"switches", "-" + switches},
          {"pyramids_lowered", pyramids_lowered},
          {"tetgen_version", detail::tetgen_version()}};
  if (!switches_retry.empty()) j["switches_retry"] = "-" + switches_retry;
  return j;
}

std::string write_tetgen_input(const model::Mesh& near, const Options& opt, const std::string& stem) {
  Report rep;
  Builder b(near, opt, rep, {});
  return b.write_poly(stem);
}

model::Mesh fill_far_field(const model::Mesh& near, const Options& opt, Report& report,
                           const std::function<void(const std::string&)>& log) {
  report = Report{};
  Builder b(near, opt, report, log);
  return b.run();
}

}  // namespace meshflow::tet
