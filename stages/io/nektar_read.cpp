// Nektar++ XML geometry: read (both forms of the sections: nektar_sections.cpp gives a Geo).
// Supported: 2D meshes of triangles and quadrilaterals and 3D meshes of tetrahedra (A),
// prisms (R), pyramids (P) and hexahedra (H), with T and Q faces, CURVED edges
// (PolyEvenlySpaced, GaussLobattoLegendre) and faces (triangles: NodalTriEvenlySpaced,
// NodalTriElec; quadrilaterals: PolyEvenlySpaced, GaussLobattoLegendre as a tensor of 1D
// points, index i + n j in the face's own frame), COMPOSITE and DOMAIN. XML is parsed with
// expat. Conventions as in Nektar++'s SpatialDomains (HexGeom/PrismGeom/PyrGeom/QuadGeom):
// an element lists its faces in Nektar++'s order (hex: bottom, y=-1, x=+1, y=+1, x=-1, top;
// prism: base quad, tri, quad, tri, quad; pyramid: base quad, then the triangles), its vertex
// i is the vertex common to the faces VertexFaceConnectivity[i]; a face's vertex 0 is the
// common vertex of its last and first edge. Prism vertices 0..5 of Nektar++ are our (Gmsh)
// 0,1,4,3,2,5 (Nektar++'s triangles are its faces 1 and 3). Elements left-handed in a file
// are mirrored to our positive orientation.
//
// Nektar++ stores no element-interior points (it rebuilds them from its expansion). On
// reading, quadrilateral interiors follow Nektar++'s own rule (edge deviations blended
// linearly towards the opposite edge, i.e. zero interior modes of the modified basis);
// other missing nodes (tet interiors, interiors of faces without CURVED data) are placed by
// a discrete harmonic extension of the displacement from the straight (vertex) element over
// the node lattice: exact for straight elements, smooth otherwise, but not Nektar++'s rule. Curved points of other point sets are interpolated to our equispaced
// nodes with the Lagrange basis of their own point set. Electrostatic triangle points:
// Hesthaven (1998), as tabulated by Nektar++ (NodalTriElecData.h), orders 1-6.
#include "stages/io/mesh_io.hpp"
#include "stages/io/nektar_xml.hpp"
#include "stages/io/reader.hpp"
#include "stages/model/basis.hpp"
#include "stages/model/topology.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <map>
#include <set>
#include <sstream>
#include <stdexcept>
#include <tuple>

namespace meshflow::io {

using namespace model;
using nektar::fail;
using nektar::Geo;
using nektar::Node;

namespace {

// 1D point sets on [0,1] (Nektar's [-1,1] mapped)
std::vector<double> points1d(const std::string& type, int n, const std::string& path, const Node* at) {
  std::vector<double> t(n);
  if (n < 2) fail(path, at, "NUMPOINTS must be at least 2");
  if (type == "PolyEvenlySpaced") {
    for (int i = 0; i < n; ++i) t[i] = double(i) / (n - 1);
  } else if (type == "GaussLobattoLegendre") {  // roots of (1-x^2) P'_{n-1}(x), Newton on Chebyshev guesses
    const int N = n - 1;
    for (int i = 0; i < n; ++i) {
      double x = -std::cos(M_PI * i / N);
      if (i > 0 && i < N)
        for (int it = 0; it < 100; ++it) {
          double p0 = 1, p1 = x;  // Legendre recurrence
          for (int k = 2; k <= N; ++k) {
            double p2 = ((2 * k - 1) * x * p1 - (k - 1) * p0) / k;
            p0 = p1, p1 = p2;
          }
          // P_N = p1, P_{N-1} = p0; q = P_N' ; q' from Legendre ODE
          double dp = N * (x * p1 - p0) / (x * x - 1);
          double ddp = (2 * x * dp - N * (N + 1) * p1) / (1 - x * x);
          double dx = dp / ddp;
          x -= dx;
          if (std::abs(dx) < 1e-16) break;
        }
      t[i] = (x + 1) / 2;
    }
  } else {
    fail(path, at, "unsupported edge point type '" + type + "' (supported: PolyEvenlySpaced, GaussLobattoLegendre)");
  }
  return t;
}

double lagrange1d(const std::vector<double>& t, const std::vector<double>& f, double x) {
  double s = 0;
  for (size_t i = 0; i < t.size(); ++i) {
    double l = 1;
    for (size_t j = 0; j < t.size(); ++j)
      if (j != i) l *= (x - t[j]) / (t[i] - t[j]);
    s += l * f[i];
  }
  return s;
}

// Electrostatic points (Hesthaven 1998) as tabulated in Nektar++: rows {n1, n3, n6, l1, l2, l3}.
const double kElec[][6] = {
    {0, 2, 0, 1.0, 0.0, 0.0},                                                                    // order 1
    {0, 2, 0, 1.0, 0.0, 0.0}, {0, 1, 0, 0.5, 0.5, 0.0},                                         // 2
    {0, 2, 0, 1.0, 0.0, 0.0}, {0, 0, 1, 0.7236067977, 0.2763932023, 0.0}, {1, 0, 0, 1 / 3., 1 / 3., 1 / 3.},  // 3
    {0, 2, 0, 1.0, 0.0, 0.0}, {0, 1, 0, 0.5, 0.5, 0.0}, {0, 0, 1, 0.8273268354, 0.1726731646, 0.0},
    {0, 1, 0, 0.2371200168, 0.2371200168, 0.5257599664},  // 4
    {0, 2, 0, 1.0, 0.0, 0.0}, {0, 0, 1, 0.6426157582, 0.3573842418, 0.0}, {0, 0, 1, 0.8825276620, 0.1174723380, 0.0},
    {0, 1, 0, 0.4105151510, 0.4105151510, 0.1789696980}, {0, 1, 0, 0.1575181512, 0.1575181512, 0.6849636976},  // 5
    {0, 2, 0, 1.0, 0.0, 0.0}, {0, 1, 0, 0.5, 0.5, 0.0}, {0, 0, 1, 0.7344243967, 0.2655756033, 0.0},
    {0, 0, 1, 0.9151119481, 0.0848880519, 0.0}, {1, 0, 0, 1 / 3., 1 / 3., 1 / 3.},
    {0, 1, 0, 0.1061169285, 0.1061169285, 0.7877661430}, {0, 0, 1, 0.3097982151, 0.5569099204, 0.1332918645}};  // 6
const int kElecRows[] = {1, 2, 3, 4, 5, 7};

// Nektar triangle point set of order P in (x,y) on the unit triangle, in Nektar's order:
// vertices, edge 0 (y=0) by x, edge 1 (hypotenuse) by y, edge 2 (x=0) by decreasing y,
// interior sorted by y then, in rows of P-2, P-3, ... points, by x.
std::vector<Vec3> tri_points(const std::string& type, int P, const std::string& path, const Node* at) {
  std::vector<std::pair<double, double>> pts;  // Nektar's (x, y) in [-1,1]
  if (type == "NodalTriElec") {
    if (P < 1 || P > 6) fail(path, at, "NodalTriElec supported for orders 1-6");
    int row = 0;
    for (int o = 1; o < P; ++o) row += kElecRows[o - 1];
    const int A3[3][3] = {{0, 1, 2}, {2, 0, 1}, {0, 2, 1}}, B3[3][3] = {{0, 1, 2}, {1, 0, 2}, {1, 2, 0}};
    const int S6[6][3] = {{0, 1, 2}, {1, 0, 2}, {2, 0, 1}, {2, 1, 0}, {0, 2, 1}, {1, 2, 0}};
    for (int r = 0; r < kElecRows[P - 1]; ++r) {
      const double* d = kElec[row + r];
      const double* l = d + 3;
      if (d[0]) pts.push_back({2 * l[1] - 1, 2 * l[2] - 1});
      else if (d[1] == 1)
        for (auto& q : A3) pts.push_back({2 * l[q[1]] - 1, 2 * l[q[2]] - 1});
      else if (d[1] == 2)
        for (auto& q : B3) pts.push_back({2 * l[q[1]] - 1, 2 * l[q[2]] - 1});
      else
        for (auto& q : S6) pts.push_back({2 * l[q[1]] - 1, 2 * l[q[2]] - 1});
    }
  } else if (type == "NodalTriEvenlySpaced") {
    pts = {{-1, -1}, {1, -1}, {-1, 1}};
    for (int j = 0; j <= P; ++j)
      for (int i = 0; i + j <= P; ++i) {
        if ((i == 0 && j == 0) || (i == P && j == 0) || (i == 0 && j == P)) continue;
        pts.push_back({-1 + 2.0 * i / P, -1 + 2.0 * j / P});
      }
  } else {
    fail(path, at, "unsupported face point type '" + type + "' (supported: NodalTriEvenlySpaced, NodalTriElec)");
  }
  const int ne = P - 1, nb = 3 * ne + 3;
  const double tol = 1e-8;
  auto group = [&](int start, auto on, auto less) {
    int cnt = start;
    for (int i = start; i < (int)pts.size(); ++i)
      if (on(pts[i])) std::swap(pts[cnt++], pts[i]);
    std::stable_sort(pts.begin() + start, pts.begin() + start + ne, less);
  };
  if (ne > 0 && (int)pts.size() >= nb) {
    group(3, [&](auto p) { return std::abs(p.second + 1) < tol; }, [](auto a, auto b) { return a.first < b.first; });
    group(3 + ne, [&](auto p) { return std::abs(p.first + p.second) < tol; }, [](auto a, auto b) { return a.second < b.second; });
    group(3 + 2 * ne, [&](auto p) { return std::abs(p.first + 1) < tol; }, [](auto a, auto b) { return a.second > b.second; });
    std::stable_sort(pts.begin() + nb, pts.end(), [](auto a, auto b) { return a.second < b.second; });
    int off = nb;
    for (int npl = P - 2; npl > 1; --npl) {
      std::stable_sort(pts.begin() + off, pts.begin() + off + npl, [](auto a, auto b) { return a.first < b.first; });
      off += npl;
    }
  }
  std::vector<Vec3> out;
  for (auto [x, y] : pts) out.push_back({(x + 1) / 2, (y + 1) / 2, 0});
  return out;
}


long common_vertex(const Geo& g, long e1, long e2, const std::string& path, const Node* at) {
  auto a = g.E.at(e1), b = g.E.at(e2);
  for (long x : a)
    for (long y : b)
      if (x == y) return x;
  fail(path, at, "edges " + std::to_string(e1) + " and " + std::to_string(e2) + " share no vertex");
}

}  // namespace

// The sides (faces in 3D, edges in 2D) of the volume elements by their sorted vertex nodes, so
// that a boundary composite's side is found in one lookup: a scan over every element per side
// made reading the demo's mesh quadratic (70 s of 74 s in std::set inserts, perf).
class SideIndex {
 public:
  struct Hit {
    std::size_t block, element;
    int side;
  };
  SideIndex(const Mesh& m, int dim) {
    for (std::size_t bi = 0; bi < m.blocks.size(); ++bi) {
      const ElementBlock& bb = m.blocks[bi];
      if (dimension(bb.shape) != dim) continue;
      const std::size_t sides = dim == 3 ? face_vertices(bb.shape).size() : edge_vertices(bb.shape).size();
      for (std::size_t e = 0; e < bb.size(); ++e)
        for (std::size_t sd = 0; sd < sides; ++sd)
          index_.emplace(key(side_vertices(bb, e, int(sd), dim)), Hit{bi, e, int(sd)});  // the first one found is kept
    }
  }
  const Hit* find(std::vector<std::uint32_t> vertices) const {
    auto it = index_.find(key(std::move(vertices)));
    return it == index_.end() ? nullptr : &it->second;
  }

 private:
  using Key = std::array<std::uint32_t, 4>;
  static std::vector<std::uint32_t> side_vertices(const ElementBlock& bb, std::size_t e, int sd, int dim) {
    const std::uint32_t* nd = bb.element(e);
    std::vector<std::uint32_t> v;
    if (dim == 3)
      for (int k : face_vertices(bb.shape)[std::size_t(sd)]) v.push_back(nd[k]);
    else
      v = {nd[edge_vertices(bb.shape)[std::size_t(sd)][0]], nd[edge_vertices(bb.shape)[std::size_t(sd)][1]]};
    return v;
  }
  static Key key(std::vector<std::uint32_t> v) {  // sorted, without repeats (a set), padded
    std::sort(v.begin(), v.end());
    v.erase(std::unique(v.begin(), v.end()), v.end());
    Key k;
    k.fill(UINT32_MAX);
    std::copy_n(v.begin(), std::min<std::size_t>(v.size(), 4), k.begin());
    return k;
  }
  std::map<Key, Hit> index_;
};

// COMPOSITE: the domain's composites become the volume's physical groups; boundary composites of
// faces (3D) or edges (2D) become boundary elements of order P, their nodes taken from the
// element side with the same vertices.
void read_composites(const Node* comp, const Geo& g, const std::map<long, std::uint32_t>& vnode, const std::set<long>& domain,
                     int dim, int P, const std::string& path, Mesh& m) {
  const SideIndex sides(m, dim);
  for (auto& c : comp->kids) {
    long cid = nektar::id_of(path, c.get());
    std::string t = c->text;
    size_t lb = t.find('['), rb = t.find(']');
    if (lb == std::string::npos || rb == std::string::npos) fail(path, c.get(), "composite without [list]");
    char kind = 0;
    for (size_t q = 0; q < lb; ++q)
      if (std::isalpha((unsigned char)t[q])) kind = t[q];
    std::vector<long> ids;
    std::istringstream ls(t.substr(lb + 1, rb - lb - 1));
    std::string item;
    while (std::getline(ls, item, ',')) {
      auto dash = item.find('-');
      if (dash == std::string::npos) ids.push_back(std::atol(item.c_str()));
      else
        for (long k = std::atol(item.substr(0, dash).c_str()); k <= std::atol(item.substr(dash + 1).c_str()); ++k) ids.push_back(k);
    }
    std::string name = c->attr.count("NAME") ? c->attr.at("NAME") : "C" + std::to_string(cid);
    if (domain.count(cid)) {
      m.add_physical(dim, (int)cid, name);
      m.add_entity(dim, 1, {(int)cid});
      continue;
    }
    const bool faces = kind == 'F';
    if (!(faces && dim == 3) && !(kind == 'E' && dim == 2)) continue;
    m.add_physical(dim - 1, (int)cid, name);
    m.add_entity(dim - 1, (int)cid, {(int)cid});
    for (long sid : ids) {
      std::vector<std::uint32_t> want;
      if (faces) {
        if (!g.F.count(sid)) fail(path, c.get(), "composite refers to face " + std::to_string(sid) + " which is not defined");
        for (long ed : g.F.at(sid))
          for (long v : g.E.at(ed)) want.push_back(vnode.at(v));
      } else {
        if (!g.E.count(sid)) fail(path, c.get(), "composite refers to edge " + std::to_string(sid) + " which is not defined");
        want = {vnode.at(g.E.at(sid)[0]), vnode.at(g.E.at(sid)[1])};
      }
      const SideIndex::Hit* hit = sides.find(want);
      if (!hit) fail(path, c.get(), "composite side " + std::to_string(sid) + " is not a side of any element");
      ElementBlock& b = m.block(faces ? (g.F.at(sid).size() == 4 ? Shape::Quad : Shape::Tri) : Shape::Line, P, dim - 1, (int)cid);
      const ElementBlock& vb = m.blocks[hit->block];  // after m.block(): it may have grown m.blocks
      const auto& side = dim == 3 ? face_nodes(vb.shape, P)[std::size_t(hit->side)] : edge_nodes(vb.shape, P)[std::size_t(hit->side)];
      const std::uint32_t* nd = vb.element(hit->element);
      std::vector<std::uint32_t> sn;
      for (int ln : side) sn.push_back(nd[ln]);
      b.add(sn.data());
    }
  }
}

Mesh read_nektar(const std::filesystem::path& fp) {
  const std::string path = fp.string();
  const std::string data = detail::slurp(fp);
  auto root = nektar::parse_xml(path, data);
  if (!root || root->name != "NEKTAR") fail(path, root.get(), "not a Nektar++ file (root element is not <NEKTAR>)");
  const Node* geo = root->child("GEOMETRY");
  if (!geo) fail(path, root.get(), "no <GEOMETRY>");
  const int dim = geo->attr.count("DIM") ? std::atoi(geo->attr.at("DIM").c_str()) : 3;
  Geo g = nektar::read_sections(path, geo, dim);
  const int P = g.order;
  if (P > 6) fail(path, geo, "curved data of order " + std::to_string(P) + " (supported up to 6)");

  Mesh m;
  std::map<long, std::uint32_t> vnode;
  for (auto& [id, x] : g.V) vnode[id] = m.add_node(x[0], x[1], x[2]);
  std::map<std::pair<long, int>, std::uint32_t> enode;              // (edge, index from its v0)
  std::map<std::pair<long, std::array<int, 3>>, std::uint32_t> fnode;  // (face, lattice in face frame)
  std::set<std::pair<long, std::array<int, 3>>> fcomputed;
  // elements
  struct Elem {
    Shape s;
    long id;
    char letter;
    std::vector<long> verts;
    std::vector<long> sides;  // edges (2D) or faces (3D)
  };
  std::vector<Elem> elems;
  for (auto& raw : g.elements) {
    const Geo::Element* e = &raw;
    Elem el;
    el.id = raw.id;
    el.letter = raw.letter.empty() ? '?' : raw.letter[0];
    el.sides = raw.sides;
    if (dim == 2 && (e->letter == "Q" || e->letter == "T")) {
      el.s = e->letter == "Q" ? Shape::Quad : Shape::Tri;
      const size_t ns = el.s == Shape::Quad ? 4 : 3;
      if (el.sides.size() != ns) fail(path, e->node, "element needs " + std::to_string(ns) + " edge IDs");
      for (long s : el.sides)
        if (!g.E.count(s)) fail(path, e->node, "element refers to edge " + std::to_string(s) + " which is not defined");
      for (size_t i = 0; i < ns; ++i) el.verts.push_back(common_vertex(g, el.sides[(i + ns - 1) % ns], el.sides[i], path, e->node));
    } else if (dim == 3 && e->letter == "A") {
      el.s = Shape::Tet;
      if (el.sides.size() != 4) fail(path, e->node, "a tetrahedron needs 4 face IDs");
      for (long s : el.sides)
        if (!g.F.count(s)) fail(path, e->node, "element refers to face " + std::to_string(s) + " which is not defined");
      const auto& f0 = g.F.at(el.sides[0]);
      for (int i = 0; i < 3; ++i) el.verts.push_back(common_vertex(g, f0[(i + 2) % 3], f0[i], path, e->node));
      std::set<long> all;
      for (long s : el.sides)
        for (long ed : g.F.at(s))
          for (long v : g.E.at(ed)) all.insert(v);
      for (long v : all)
        if (std::find(el.verts.begin(), el.verts.end(), v) == el.verts.end()) el.verts.push_back(v);
      if (el.verts.size() != 4) fail(path, e->node, "the faces of this tetrahedron do not close");
      // our convention: positive volume of the straight element
      auto X = [&](int i) { return g.V.at(el.verts[i]); };
      double a[3], b[3], c3[3];
      for (int r = 0; r < 3; ++r) a[r] = X(1)[r] - X(0)[r], b[r] = X(2)[r] - X(0)[r], c3[r] = X(3)[r] - X(0)[r];
      double vol = a[0] * (b[1] * c3[2] - b[2] * c3[1]) - a[1] * (b[0] * c3[2] - b[2] * c3[0]) + a[2] * (b[0] * c3[1] - b[1] * c3[0]);
      if (vol < 0) std::swap(el.verts[1], el.verts[2]);
    } else if (dim == 3 && (e->letter == "R" || e->letter == "P" || e->letter == "H")) {
      // Nektar++'s prism/pyramid/hexahedron: faces in its order (F0 the base quad, ...);
      // vertex i is the one common to the faces VertexFaceConnectivity[i] (Nektar++'s
      // PrismGeom/HexGeom tables), then renumbered to Gmsh's vertex order.
      static const std::vector<std::vector<int>> hexVF = {{0, 1, 4}, {0, 1, 2}, {0, 2, 3}, {0, 3, 4},
                                                         {1, 4, 5}, {1, 2, 5}, {2, 3, 5}, {3, 4, 5}};
      static const std::vector<std::vector<int>> prismVF = {{0, 1, 4}, {0, 1, 2}, {0, 2, 3}, {0, 3, 4}, {1, 2, 4}, {2, 3, 4}};
      static const std::vector<std::vector<int>> pyrVF = {{0, 1, 4}, {0, 1, 2}, {0, 2, 3}, {0, 3, 4}, {1, 2, 3, 4}};
      el.s = e->letter == "H" ? Shape::Hex : e->letter == "R" ? Shape::Prism : Shape::Pyramid;
      const auto& VF = el.s == Shape::Hex ? hexVF : el.s == Shape::Prism ? prismVF : pyrVF;
      const size_t nf = el.s == Shape::Hex ? 6 : 5;
      if (el.sides.size() != nf) fail(path, e->node, "element <" + e->letter + "> needs " + std::to_string(nf) + " face IDs");
      std::vector<std::set<long>> fverts;
      for (long sd : el.sides) {
        if (!g.F.count(sd)) fail(path, e->node, "element refers to face " + std::to_string(sd) + " which is not defined");
        std::set<long> vs;
        for (long ed : g.F.at(sd))
          for (long v : g.E.at(ed)) vs.insert(v);
        fverts.push_back(vs);
      }
      std::vector<long> nv;
      for (auto& fs : VF) {
        std::set<long> common = fverts[fs[0]];
        for (size_t k = 1; k < fs.size(); ++k) {
          std::set<long> t;
          for (long v : common)
            if (fverts[fs[k]].count(v)) t.insert(v);
          common = t;
        }
        if (common.size() != 1) fail(path, e->node, "the faces of this element do not meet in its vertices as Nektar++ orders them");
        nv.push_back(*common.begin());
      }
      // Nektar++ -> Gmsh vertex order (the prism's triangles are Nektar's faces 1 and 3)
      if (el.s == Shape::Prism) el.verts = {nv[0], nv[1], nv[4], nv[3], nv[2], nv[5]};
      else el.verts = nv;
      auto X = [&](int i) { return g.V.at(el.verts[i]); };
      const int o3 = el.s == Shape::Prism ? 2 : 3, o4 = el.s == Shape::Prism ? 3 : 4;
      double a[3], b[3], c3[3];
      for (int r = 0; r < 3; ++r) a[r] = X(1)[r] - X(0)[r], b[r] = X(o3)[r] - X(0)[r], c3[r] = X(o4)[r] - X(0)[r];
      double vol = a[0] * (b[1] * c3[2] - b[2] * c3[1]) - a[1] * (b[0] * c3[2] - b[2] * c3[0]) + a[2] * (b[0] * c3[1] - b[1] * c3[0]);
      if (vol < 0) {  // left-handed in the file: mirror to our positive orientation
        if (el.s == Shape::Prism) std::swap(el.verts[1], el.verts[2]), std::swap(el.verts[4], el.verts[5]);
        else {
          std::swap(el.verts[1], el.verts[3]);
          if (el.s == Shape::Hex) std::swap(el.verts[5], el.verts[7]);
        }
      }
    } else {
      fail(path, e->node, "element type <" + e->letter + "> in a " + std::to_string(dim) +
                              "D mesh is not supported (supported: T, Q in 2D; A, R, P, H in 3D)");
    }
    elems.push_back(std::move(el));
  }
  // edge lookup by vertex pair
  std::map<std::pair<long, long>, long> edge_of;
  for (auto& [id, e] : g.E) edge_of[{std::min(e[0], e[1]), std::max(e[0], e[1])}] = id;
  std::map<std::set<long>, long> face_of;
  for (auto& [id, f] : g.F) {
    std::set<long> vs;
    for (long ed : f)
      for (long v : g.E.at(ed)) vs.insert(v);
    face_of[vs] = id;
  }
  auto edge_point = [&](long eid, double t) -> Vec3 {  // t in [0,1] from the edge's own v0
    auto it = g.CE.find(eid);
    const Vec3 a = g.V.at(g.E.at(eid)[0]), b = g.V.at(g.E.at(eid)[1]);
    if (it == g.CE.end()) return {a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1]), a[2] + t * (b[2] - a[2])};
    const auto& c = it->second;
    auto ts = points1d(c.type, c.n, path, c.node);
    // the curve's first point is one of the edge's vertices: it gives the direction
    double d0 = 0, d1 = 0;
    for (int r = 0; r < 3; ++r) d0 += std::pow(c.xyz[r] - a[r], 2), d1 += std::pow(c.xyz[r] - b[r], 2);
    double s = d0 <= d1 ? t : 1 - t;
    Vec3 x;
    for (int r = 0; r < 3; ++r) {
      std::vector<double> f(c.n);
      for (int i = 0; i < c.n; ++i) f[i] = c.xyz[3 * i + r];
      x[r] = lagrange1d(ts, f, s);
    }
    return x;
  };

  std::map<std::tuple<int, int, int>, size_t> blk;  // (shape) -> block index; entity tag = domain composite
  for (auto& el : elems) {
    const int n = num_nodes(el.s, P);
    const auto& lat = lattice(el.s, P);
    const int nv = num_vertices(el.s);
    std::vector<std::uint32_t> nodes(n, 0xffffffffu);
    std::vector<Vec3> pos(n);
    std::vector<int> known(n, 0);  // 1 = given by the file (or shared and computed)
    std::vector<Vec3> vx;
    for (long v : el.verts) vx.push_back(g.V.at(v));
    const auto& ref = reference_nodes(el.s, P);
    for (int i = 0; i < n; ++i) pos[i] = map_linear(el.s, vx, ref[i]);
    if (el.s == Shape::Prism || el.s == Shape::Pyramid || el.s == Shape::Hex) {
      auto edge_id = [&](long va, long vb) {
        auto it = edge_of.find({std::min(va, vb), std::max(va, vb)});
        if (it == edge_of.end()) fail(path, nullptr, "element " + std::to_string(el.id) + ": an edge of its faces is not in <EDGE>");
        return it->second;
      };
      for (int i = 0; i < nv; ++i) nodes[i] = vnode.at(el.verts[i]), known[i] = 1;
      const auto& EN = edge_nodes(el.s, P);
      for (size_t e = 0; e < EN.size(); ++e) {
        const long va = el.verts[edge_vertices(el.s)[e][0]], vb = el.verts[edge_vertices(el.s)[e][1]];
        const long eid = edge_id(va, vb);
        for (int k = 2; k < (int)EN[e].size(); ++k) {  // Gmsh line order: v0, v1, then 1..P-1
          const int from_v0 = g.E.at(eid)[0] == va ? k - 1 : P - (k - 1);
          auto key = std::make_pair(eid, from_v0);
          auto f = enode.find(key);
          if (f == enode.end()) {
            Vec3 x = edge_point(eid, double(from_v0) / P);
            f = enode.emplace(key, m.add_node(x[0], x[1], x[2])).first;
          }
          nodes[EN[e][k]] = f->second;
          known[EN[e][k]] = 1;
        }
      }
      // face nodes, keyed by their lattice point in the Nektar++ face's own frame (vertex q0 =
      // common vertex of its last and first edge, axis 0 towards q1, axis 1 towards q3 (quad)
      // or q2 (triangle)), the frame of its CURVED points
      const auto& FN = face_nodes(el.s, P);
      std::vector<int> face_of_node(n, -1);
      for (size_t f = 0; f < FN.size(); ++f) {
        const auto& fv = face_vertices(el.s)[f];
        const bool quad = fv.size() == 4;
        std::set<long> vs;
        for (int v : fv) vs.insert(el.verts[v]);
        auto fit = face_of.find(vs);
        if (fit == face_of.end()) fail(path, nullptr, "element " + std::to_string(el.id) + ": a face is not in <FACE>");
        const long fid = fit->second;
        const auto& fe = g.F.at(fid);
        if (fe.size() != fv.size()) fail(path, nullptr, "element " + std::to_string(el.id) + ": face " + std::to_string(fid) + " has the wrong number of edges");
        std::vector<long> q;
        for (size_t k = 0; k < fe.size(); ++k) q.push_back(common_vertex(g, fe[(k + fe.size() - 1) % fe.size()], fe[k], path, nullptr));
        static const int CQ[4][2] = {{0, 0}, {1, 0}, {1, 1}, {0, 1}}, CT[3][2] = {{0, 0}, {1, 0}, {0, 1}};
        auto corner = [&](int local) {
          const long v = el.verts[fv[local]];
          const int idx = (int)(std::find(q.begin(), q.end(), v) - q.begin());
          if (idx >= (int)q.size()) fail(path, nullptr, "face " + std::to_string(fid) + " does not have the element's vertices");
          return quad ? CQ[idx] : CT[idx];
        };
        const auto& flat = lattice(quad ? Shape::Quad : Shape::Tri, P);
        for (size_t k = 0; k < FN[f].size(); ++k) {
          const Lattice& L = flat[k];
          const bool interior = quad ? (L[0] > 0 && L[0] < P && L[1] > 0 && L[1] < P) : (L[0] > 0 && L[1] > 0 && L[0] + L[1] < P);
          if (!interior) continue;
          const int li = FN[f][k];
          face_of_node[li] = (int)f;
          std::array<int, 3> key = {0, 0, 0};
          for (int c = 0; c < 2; ++c) {
            if (quad)  // bilinear in our face frame (exact for the symmetries of the square)
              key[c] = ((P - L[0]) * (P - L[1]) * corner(0)[c] + L[0] * (P - L[1]) * corner(1)[c] + L[0] * L[1] * corner(2)[c] +
                        (P - L[0]) * L[1] * corner(3)[c]) / P;
            else
              key[c] = (P - L[0] - L[1]) * corner(0)[c] + L[0] * corner(1)[c] + L[1] * corner(2)[c];
          }
          auto fkey = std::make_pair(fid, key);
          auto fn = fnode.find(fkey);
          if (fn == fnode.end()) {
            Vec3 x = pos[li];
            auto cf = g.CF.find(fid);
            if (cf != g.CF.end()) {
              const auto& c = cf->second;
              const double sx = double(key[0]) / P, sy = double(key[1]) / P;
              x = {0, 0, 0};
              if (quad) {
                int n1 = 0;
                while (n1 * n1 < c.n) ++n1;
                if (n1 * n1 != c.n) fail(path, c.node, "NUMPOINTS of a quadrilateral face is not a square");
                auto ts = points1d(c.type, n1, path, c.node);
                std::vector<double> la(n1), lb(n1), unit(n1, 0.0);
                for (int a = 0; a < n1; ++a) {
                  unit.assign(n1, 0.0);
                  unit[a] = 1;
                  la[a] = lagrange1d(ts, unit, sx);
                  lb[a] = lagrange1d(ts, unit, sy);
                }
                for (int b2 = 0; b2 < n1; ++b2)
                  for (int a = 0; a < n1; ++a)
                    for (int r = 0; r < 3; ++r) x[r] += la[a] * lb[b2] * c.xyz[3 * (a + n1 * b2) + r];
              } else {
                int Pf = 0;
                while ((Pf + 1) * (Pf + 2) / 2 < c.n) ++Pf;
                if ((Pf + 1) * (Pf + 2) / 2 != c.n) fail(path, c.node, "NUMPOINTS is not a triangle number");
                LagrangeBasis fb(Shape::Tri, Pf, tri_points(c.type, Pf, path, c.node));
                std::vector<double> N(fb.size());
                fb.eval({sx, sy, 0}, N.data());
                for (int kk = 0; kk < fb.size(); ++kk)
                  for (int r = 0; r < 3; ++r) x[r] += N[kk] * c.xyz[3 * kk + r];
              }
              fcomputed.insert(fkey);
            }
            fn = fnode.emplace(fkey, m.add_node(x[0], x[1], x[2])).first;
          }
          nodes[li] = fn->second;
          known[li] = fcomputed.count(fkey) ? 1 : 2;
        }
      }
      // missing nodes (faces without CURVED data, interiors): discrete harmonic extension of
      // the displacement from the straight element over the lattice (face nodes stay on their face)
      for (int i = 0; i < n; ++i)
        if (known[i] == 1) pos[i] = {m.x[nodes[i]], m.y[nodes[i]], m.z[nodes[i]]};
        else if (known[i] == 0) known[i] = 3;
      std::vector<Vec3> lin(n);
      for (int i = 0; i < n; ++i) lin[i] = map_linear(el.s, vx, ref[i]);
      const auto& lat = lattice(el.s, P);
      std::map<Lattice, int> at;
      for (int i = 0; i < n; ++i) at[lat[i]] = i;
      std::vector<std::set<int>> fset(FN.size());
      for (size_t f = 0; f < FN.size(); ++f) fset[f].insert(FN[f].begin(), FN[f].end());
      for (int which : {2, 3})
        for (int it = 0; it < 300; ++it)
          for (int i = 0; i < n; ++i) {
            if (known[i] != which) continue;
            Vec3 sum = {0, 0, 0};
            int cnt = 0;
            for (int d = 0; d < 3; ++d)
              for (int sg : {1, -1}) {
                Lattice qn = lat[i];
                qn[d] += sg;
                auto fq = at.find(qn);
                if (fq == at.end()) continue;
                if (which == 2 && !fset[face_of_node[i]].count(fq->second)) continue;
                for (int r = 0; r < 3; ++r) sum[r] += pos[fq->second][r] - lin[fq->second][r];
                ++cnt;
              }
            if (cnt)
              for (int r = 0; r < 3; ++r) pos[i][r] = lin[i][r] + sum[r] / cnt;
          }
      for (int i = 0; i < n; ++i) {
        if (known[i] == 2) {
          m.x[nodes[i]] = pos[i][0], m.y[nodes[i]] = pos[i][1], m.z[nodes[i]] = pos[i][2];
          for (auto& [k, v] : fnode)
            if (v == nodes[i]) fcomputed.insert(k);
        }
        if (known[i] == 3) nodes[i] = m.add_node(pos[i][0], pos[i][1], pos[i][2]);
      }
      ElementBlock& b = m.block(el.s, P, dim, 1);
      b.add(nodes.data());
      b.tags.push_back(el.id + 1);
      continue;
    }
    // barycentric-like lattice weights of each node relative to the vertices
    auto weights = [&](const Lattice& L) {
      std::vector<int> w(nv, 0);
      if (el.s == Shape::Tet || el.s == Shape::Tri) {
        w[0] = P - L[0] - L[1] - L[2], w[1] = L[0], w[2] = L[1];
        if (el.s == Shape::Tet) w[3] = L[2];
      }
      return w;
    };
    for (int i = 0; i < n; ++i) {
      if (i < nv) {
        nodes[i] = vnode.at(el.verts[i]);
        known[i] = 1;
        continue;
      }
      // which vertices span the node's sub-entity
      std::vector<int> sup;
      std::vector<int> w;
      if (el.s == Shape::Quad) {
        const Lattice& L = lat[i];
        bool bi = L[0] == 0 || L[0] == P, bj = L[1] == 0 || L[1] == P;
        if (bi || bj) {  // on an edge
          for (int e = 0; e < 4; ++e) {
            auto [a, b] = edge_vertices(Shape::Quad)[e];
            const auto& en = edge_nodes(Shape::Quad, P)[e];
            auto it = std::find(en.begin(), en.end(), i);
            if (it == en.end()) continue;
            int k = (int)(it - en.begin());  // Gmsh line order: 0, P, 1..P-1
            int along = k == 0 ? 0 : (k == 1 ? P : k - 1);
            long va = el.verts[a], vb = el.verts[b];
            long eid = edge_of.at({std::min(va, vb), std::max(va, vb)});
            int from_v0 = g.E.at(eid)[0] == va ? along : P - along;
            auto key = std::make_pair(eid, from_v0);
            auto f = enode.find(key);
            if (f == enode.end()) {
              Vec3 x = edge_point(eid, double(from_v0) / P);
              f = enode.emplace(key, m.add_node(x[0], x[1], x[2])).first;
            }
            nodes[i] = f->second;
            known[i] = 1;
            break;
          }
        }
        continue;
      }
      w = weights(lat[i]);
      for (int v = 0; v < nv; ++v)
        if (w[v]) sup.push_back(v);
      if (sup.size() == 2) {
        long va = el.verts[sup[0]], vb = el.verts[sup[1]];
        long eid = edge_of.at({std::min(va, vb), std::max(va, vb)});
        int from_v0 = g.E.at(eid)[0] == va ? w[sup[1]] : w[sup[0]];
        auto key = std::make_pair(eid, from_v0);
        auto f = enode.find(key);
        if (f == enode.end()) {
          Vec3 x = edge_point(eid, double(from_v0) / P);
          f = enode.emplace(key, m.add_node(x[0], x[1], x[2])).first;
        }
        nodes[i] = f->second;
        known[i] = 1;
      } else if (sup.size() == 3 && el.s == Shape::Tet) {
        std::set<long> vs = {el.verts[sup[0]], el.verts[sup[1]], el.verts[sup[2]]};
        long fid = face_of.at(vs);
        const auto& fe = g.F.at(fid);
        long f0 = common_vertex(g, fe[2], fe[0], path, nullptr), f1 = common_vertex(g, fe[0], fe[1], path, nullptr),
             f2 = common_vertex(g, fe[1], fe[2], path, nullptr);
        auto wv = [&](long v) {
          for (int s : sup)
            if (el.verts[s] == v) return w[s];
          return 0;
        };
        std::array<int, 3> fl = {wv(f0), wv(f1), wv(f2)};
        auto key = std::make_pair(fid, fl);
        auto f = fnode.find(key);
        if (f == fnode.end()) {
          Vec3 x = pos[i];
          auto cf = g.CF.find(fid);
          if (cf != g.CF.end()) {
            const auto& c = cf->second;
            int Pf = 0;
            while ((Pf + 1) * (Pf + 2) / 2 < c.n) ++Pf;
            if ((Pf + 1) * (Pf + 2) / 2 != c.n) fail(path, c.node, "NUMPOINTS is not a triangle number");
            auto src = tri_points(c.type, Pf, path, c.node);
            // orientation: the first three points are the face's vertices
            const Vec3 fv[3] = {g.V.at(f0), g.V.at(f1), g.V.at(f2)};
            int map3[3];
            for (int q = 0; q < 3; ++q) {
              double best = 1e300;
              for (int r = 0; r < 3; ++r) {
                double d = 0;
                for (int k = 0; k < 3; ++k) d += std::pow(c.xyz[3 * q + k] - fv[r][k], 2);
                if (d < best) best = d, map3[q] = r;
              }
            }
            // barycentric of our node in the file's vertex order
            double lam[3];
            for (int q = 0; q < 3; ++q) lam[q] = fl[map3[q]] / double(P);
            LagrangeBasis fb(Shape::Tri, Pf, src);
            std::vector<double> N(fb.size());
            fb.eval({lam[1], lam[2], 0}, N.data());
            x = {0, 0, 0};
            for (int k = 0; k < fb.size(); ++k)
              for (int r = 0; r < 3; ++r) x[r] += N[k] * c.xyz[3 * k + r];
            fcomputed.insert(key);
          }
          f = fnode.emplace(key, m.add_node(x[0], x[1], x[2])).first;
        }
        nodes[i] = f->second;
        known[i] = fcomputed.count(key) ? 1 : 2;  // 2: shared face node to be filled
      }
    }
    // positions of known nodes; fill the others harmonically (faces first, then interior)
    for (int i = 0; i < n; ++i)
      if (known[i] == 1) pos[i] = {m.x[nodes[i]], m.y[nodes[i]], m.z[nodes[i]]};
    std::vector<Vec3> lin(n);
    for (int i = 0; i < n; ++i) lin[i] = map_linear(el.s, vx, ref[i]);
    std::map<Lattice, int> at;
    for (int i = 0; i < n; ++i) at[lat[i]] = i;
    std::vector<Lattice> dirs = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}, {1, -1, 0}, {0, 1, -1}, {1, 0, -1}};
    if (el.s == Shape::Quad) dirs = {{1, 0, 0}, {0, 1, 0}};
    auto fill = [&](int which) {
      for (int it = 0; it < 400; ++it)
        for (int i = 0; i < n; ++i) {
          if (known[i] != which) continue;
          auto wi = weights(lat[i]);
          Vec3 s = {0, 0, 0};
          int cnt = 0;
          for (auto d : dirs)
            for (int sg : {1, -1}) {
              Lattice q = {lat[i][0] + sg * d[0], lat[i][1] + sg * d[1], lat[i][2] + sg * d[2]};
              auto f = at.find(q);
              if (f == at.end()) continue;
              if (which == 2) {  // stay on the face: the neighbour's support within the node's
                auto wq = weights(q);
                bool ok = true;
                for (int v = 0; v < nv; ++v) ok = ok && (wi[v] != 0 || wq[v] == 0);
                if (!ok) continue;
              }
              for (int r = 0; r < 3; ++r) s[r] += pos[f->second][r] - lin[f->second][r];
              ++cnt;
            }
          if (cnt)
            for (int r = 0; r < 3; ++r) pos[i][r] = lin[i][r] + s[r] / cnt;
        }
    };
    fill(2);
    for (int i = 0; i < n; ++i)
      if (nodes[i] == 0xffffffffu) known[i] = 3;
    if (el.s == Shape::Quad) {
      // Nektar++'s own rule (modified basis, zero interior modes): each edge's deviation
      // from the straight edge, blended linearly to zero at the opposite edge.
      auto D = [&](int i, int j) {
        int q = at.at({i, j, 0});
        return Vec3{pos[q][0] - lin[q][0], pos[q][1] - lin[q][1], pos[q][2] - lin[q][2]};
      };
      for (int q = 0; q < n; ++q) {
        if (known[q] != 3) continue;
        const int i = lat[q][0], j = lat[q][1];
        Vec3 a = D(i, 0), b = D(i, P), c = D(0, j), d = D(P, j);
        for (int r = 0; r < 3; ++r)
          pos[q][r] = lin[q][r] + (a[r] * (P - j) + b[r] * j + c[r] * (P - i) + d[r] * i) / P;
      }
    } else {
      fill(3);
    }
    for (int i = 0; i < n; ++i) {
      if (known[i] == 2) {
        std::uint32_t id = nodes[i];
        m.x[id] = pos[i][0], m.y[id] = pos[i][1], m.z[id] = pos[i][2];
      }
      if (nodes[i] == 0xffffffffu) nodes[i] = m.add_node(pos[i][0], pos[i][1], pos[i][2]);
    }
    // mark shared face nodes as computed so the neighbour keeps them
    for (int i = 0; i < n; ++i)
      if (known[i] == 2)
        for (auto& [k, v] : fnode)
          if (v == nodes[i]) fcomputed.insert(k);
    ElementBlock& b = m.block(el.s, P, dim, 1);
    b.add(nodes.data());
    b.tags.push_back(el.id + 1);
  }
  // composites -> physical groups: domain composites on the volume entity, the others on
  // one boundary entity each (tag = composite ID)
  m.add_entity(dim, 1);
  std::set<long> domain;
  if (const Node* d = geo->child("DOMAIN")) {
    std::string t = d->text;
    for (auto& ch : t)
      if (!std::isdigit((unsigned char)ch) && ch != '-' && ch != ',') ch = ' ';
    std::istringstream is(t);
    std::string tok;
    while (is >> tok)
      for (std::string part; std::getline(std::istringstream(tok) >> std::ws, part);) {
        (void)part;
        break;
      }
    std::string s2 = d->text;
    size_t p = s2.find('[');
    if (p != std::string::npos) {
      std::string inner = s2.substr(p + 1, s2.find(']') - p - 1);
      std::istringstream ls(inner);
      std::string item;
      while (std::getline(ls, item, ',')) {
        auto dash = item.find('-');
        if (dash == std::string::npos) domain.insert(std::atol(item.c_str()));
        else
          for (long k = std::atol(item.substr(0, dash).c_str()); k <= std::atol(item.substr(dash + 1).c_str()); ++k) domain.insert(k);
      }
    }
  }
  if (const Node* comp = geo->child("COMPOSITE")) read_composites(comp, g, vnode, domain, dim, P, path, m);
  try {
    m.check();
  } catch (const std::invalid_argument& e) {
    throw MeshIOError(path + ": " + e.what());
  }
  return m;
}

}  // namespace meshflow::io
