// Nektar++ XML geometry (uncompressed): read and write.
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
#include "stages/io/reader.hpp"
#include "stages/model/basis.hpp"
#include "stages/model/topology.hpp"

#include <expat.h>

#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <string_view>
#include <tuple>
#include <fstream>
#include <map>
#include <memory>
#include <set>
#include <sstream>
#include <stdexcept>

namespace meshflow::io {

using namespace model;

namespace {

struct Node {
  std::string name;
  std::map<std::string, std::string> attr;
  std::string text;
  long line = 0;
  std::vector<std::unique_ptr<Node>> kids;
  const Node* child(const std::string& n) const {
    for (auto& k : kids)
      if (k->name == n) return k.get();
    return nullptr;
  }
};

struct Parser {
  std::unique_ptr<Node> root;
  std::vector<Node*> stack;
  XML_Parser p;
};

void XMLCALL on_start(void* ud, const XML_Char* name, const XML_Char** atts) {
  auto* ps = static_cast<Parser*>(ud);
  auto n = std::make_unique<Node>();
  n->name = name;
  n->line = (long)XML_GetCurrentLineNumber(ps->p);
  for (int i = 0; atts[i]; i += 2) n->attr[atts[i]] = atts[i + 1];
  Node* raw = n.get();
  if (ps->stack.empty()) ps->root = std::move(n);
  else ps->stack.back()->kids.push_back(std::move(n));
  ps->stack.push_back(raw);
}
void XMLCALL on_end(void* ud, const XML_Char*) { static_cast<Parser*>(ud)->stack.pop_back(); }
void XMLCALL on_text(void* ud, const XML_Char* s, int len) {
  auto* ps = static_cast<Parser*>(ud);
  if (!ps->stack.empty()) ps->stack.back()->text.append(s, len);
}

std::unique_ptr<Node> parse_xml(const std::string& path, const std::string& data) {
  Parser ps;
  ps.p = XML_ParserCreate(nullptr);
  XML_SetUserData(ps.p, &ps);
  XML_SetElementHandler(ps.p, on_start, on_end);
  XML_SetCharacterDataHandler(ps.p, on_text);
  if (XML_Parse(ps.p, data.data(), (int)data.size(), 1) == XML_STATUS_ERROR) {
    std::string msg = path + ":line " + std::to_string(XML_GetCurrentLineNumber(ps.p)) + ": XML error: " +
                      XML_ErrorString(XML_GetErrorCode(ps.p)) + " (truncated or malformed file?)";
    XML_ParserFree(ps.p);
    throw MeshIOError(msg);
  }
  XML_ParserFree(ps.p);
  return std::move(ps.root);
}

[[noreturn]] void fail(const std::string& path, const Node* n, const std::string& what) {
  throw MeshIOError(path + ":line " + std::to_string(n ? n->line : 0) + ": " + what);
}

std::vector<double> numbers(const std::string& path, const Node* n) {
  std::vector<double> v;
  const char* s = n->text.c_str();
  const char* e = s + n->text.size();
  while (true) {
    while (s < e && std::isspace((unsigned char)*s)) ++s;
    if (s >= e) break;
    const char* b = s;
    while (s < e && !std::isspace((unsigned char)*s)) ++s;
    double x;
    auto r = std::from_chars(b, s, x);
    if (r.ec != std::errc() || r.ptr != s) fail(path, n, "expected a number, found '" + std::string(b, s) + "'");
    v.push_back(x);
  }
  return v;
}
long id_of(const std::string& path, const Node* n) {
  auto it = n->attr.find("ID");
  if (it == n->attr.end()) fail(path, n, "<" + n->name + "> without ID");
  try {
    return std::stol(it->second);
  } catch (...) {
    fail(path, n, "bad ID '" + it->second + "'");
  }
}

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

struct Geo {
  std::map<long, Vec3> V;
  std::map<long, std::array<long, 2>> E;
  std::map<long, std::vector<long>> F;  // edges
  struct Curve {
    std::string type;
    int n = 0;
    std::vector<double> xyz;
    const Node* node = nullptr;
  };
  std::map<long, Curve> CE, CF;
};

long common_vertex(const Geo& g, long e1, long e2, const std::string& path, const Node* at) {
  auto a = g.E.at(e1), b = g.E.at(e2);
  for (long x : a)
    for (long y : b)
      if (x == y) return x;
  fail(path, at, "edges " + std::to_string(e1) + " and " + std::to_string(e2) + " share no vertex");
}

}  // namespace

Mesh read_nektar(const std::filesystem::path& fp) {
  const std::string path = fp.string();
  const std::string data = detail::slurp(fp);
  auto root = parse_xml(path, data);
  if (!root || root->name != "NEKTAR") fail(path, root.get(), "not a Nektar++ file (root element is not <NEKTAR>)");
  const Node* geo = root->child("GEOMETRY");
  if (!geo) fail(path, root.get(), "no <GEOMETRY>");
  if (geo->attr.count("COMPRESSED") || (geo->child("VERTEX") && geo->child("VERTEX")->attr.count("COMPRESSED")))
    fail(path, geo, "compressed Nektar++ geometry is not supported (convert with NekMesh ...:xml:uncompress)");
  const int dim = geo->attr.count("DIM") ? std::atoi(geo->attr.at("DIM").c_str()) : 3;
  Geo g;
  auto need = [&](const char* n) {
    const Node* x = geo->child(n);
    if (!x) fail(path, geo, std::string("no <") + n + "> in <GEOMETRY>");
    return x;
  };
  for (auto& v : need("VERTEX")->kids) {
    auto c = numbers(path, v.get());
    if (c.size() != 3) fail(path, v.get(), "a vertex needs 3 coordinates");
    for (double x : c)
      if (!std::isfinite(x)) fail(path, v.get(), "vertex has a non-finite coordinate");
    g.V[id_of(path, v.get())] = {c[0], c[1], c[2]};
  }
  for (auto& e : need("EDGE")->kids) {
    auto c = numbers(path, e.get());
    if (c.size() != 2) fail(path, e.get(), "an edge needs 2 vertex IDs");
    for (double x : c)
      if (!g.V.count((long)x)) fail(path, e.get(), "edge refers to vertex " + std::to_string((long)x) + " which is not defined");
    g.E[id_of(path, e.get())] = {(long)c[0], (long)c[1]};
  }
  if (dim == 3)
    for (auto& f : need("FACE")->kids) {
      if (f->name != "T" && f->name != "Q") fail(path, f.get(), "face type <" + f->name + "> not supported (T, Q)");
      auto c = numbers(path, f.get());
      if (c.size() != (f->name == "T" ? 3u : 4u)) fail(path, f.get(), "a face <" + f->name + "> needs " + (f->name == "T" ? "3" : "4") + " edge IDs");
      std::vector<long> es;
      for (double x : c) {
        if (!g.E.count((long)x)) fail(path, f.get(), "face refers to edge " + std::to_string((long)x) + " which is not defined");
        es.push_back((long)x);
      }
      g.F[id_of(path, f.get())] = es;
    }
  int P = 1;
  if (const Node* cv = geo->child("CURVED"))
    for (auto& k : cv->kids) {
      Geo::Curve c;
      c.type = k->attr.count("TYPE") ? k->attr.at("TYPE") : "";
      c.n = k->attr.count("NUMPOINTS") ? std::atoi(k->attr.at("NUMPOINTS").c_str()) : 0;
      c.xyz = numbers(path, k.get());
      c.node = k.get();
      if (k->name == "E") {
        long eid = std::atol(k->attr.count("EDGEID") ? k->attr.at("EDGEID").c_str() : "-1");
        if (!g.E.count(eid)) fail(path, k.get(), "curved edge refers to an undefined EDGEID");
        if ((int)c.xyz.size() != 3 * c.n) fail(path, k.get(), "inconsistent counts: NUMPOINTS=" + std::to_string(c.n) + " but " + std::to_string(c.xyz.size()) + " numbers");
        P = std::max(P, c.n - 1);
        g.CE[eid] = c;
      } else if (k->name == "F") {
        long fid = std::atol(k->attr.count("FACEID") ? k->attr.at("FACEID").c_str() : "-1");
        if (!g.F.count(fid)) fail(path, k.get(), "curved face refers to an undefined FACEID");
        if ((int)c.xyz.size() != 3 * c.n) fail(path, k.get(), "inconsistent counts: NUMPOINTS=" + std::to_string(c.n) + " but " + std::to_string(c.xyz.size()) + " numbers");
        g.CF[fid] = c;
      }
    }
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
  for (auto& e : need("ELEMENT")->kids) {
    Elem el;
    el.id = id_of(path, e.get());
    el.letter = e->name.empty() ? '?' : e->name[0];
    auto c = numbers(path, e.get());
    for (double x : c) el.sides.push_back((long)x);
    if (dim == 2 && (e->name == "Q" || e->name == "T")) {
      el.s = e->name == "Q" ? Shape::Quad : Shape::Tri;
      const size_t ns = el.s == Shape::Quad ? 4 : 3;
      if (el.sides.size() != ns) fail(path, e.get(), "element needs " + std::to_string(ns) + " edge IDs");
      for (long s : el.sides)
        if (!g.E.count(s)) fail(path, e.get(), "element refers to edge " + std::to_string(s) + " which is not defined");
      for (size_t i = 0; i < ns; ++i) el.verts.push_back(common_vertex(g, el.sides[(i + ns - 1) % ns], el.sides[i], path, e.get()));
    } else if (dim == 3 && e->name == "A") {
      el.s = Shape::Tet;
      if (el.sides.size() != 4) fail(path, e.get(), "a tetrahedron needs 4 face IDs");
      for (long s : el.sides)
        if (!g.F.count(s)) fail(path, e.get(), "element refers to face " + std::to_string(s) + " which is not defined");
      const auto& f0 = g.F.at(el.sides[0]);
      for (int i = 0; i < 3; ++i) el.verts.push_back(common_vertex(g, f0[(i + 2) % 3], f0[i], path, e.get()));
      std::set<long> all;
      for (long s : el.sides)
        for (long ed : g.F.at(s))
          for (long v : g.E.at(ed)) all.insert(v);
      for (long v : all)
        if (std::find(el.verts.begin(), el.verts.end(), v) == el.verts.end()) el.verts.push_back(v);
      if (el.verts.size() != 4) fail(path, e.get(), "the faces of this tetrahedron do not close");
      // our convention: positive volume of the straight element
      auto X = [&](int i) { return g.V.at(el.verts[i]); };
      double a[3], b[3], c3[3];
      for (int r = 0; r < 3; ++r) a[r] = X(1)[r] - X(0)[r], b[r] = X(2)[r] - X(0)[r], c3[r] = X(3)[r] - X(0)[r];
      double vol = a[0] * (b[1] * c3[2] - b[2] * c3[1]) - a[1] * (b[0] * c3[2] - b[2] * c3[0]) + a[2] * (b[0] * c3[1] - b[1] * c3[0]);
      if (vol < 0) std::swap(el.verts[1], el.verts[2]);
    } else if (dim == 3 && (e->name == "R" || e->name == "P" || e->name == "H")) {
      // Nektar++'s prism/pyramid/hexahedron: faces in its order (F0 the base quad, ...);
      // vertex i is the one common to the faces VertexFaceConnectivity[i] (Nektar++'s
      // PrismGeom/HexGeom tables), then renumbered to Gmsh's vertex order.
      static const std::vector<std::vector<int>> hexVF = {{0, 1, 4}, {0, 1, 2}, {0, 2, 3}, {0, 3, 4},
                                                         {1, 4, 5}, {1, 2, 5}, {2, 3, 5}, {3, 4, 5}};
      static const std::vector<std::vector<int>> prismVF = {{0, 1, 4}, {0, 1, 2}, {0, 2, 3}, {0, 3, 4}, {1, 2, 4}, {2, 3, 4}};
      static const std::vector<std::vector<int>> pyrVF = {{0, 1, 4}, {0, 1, 2}, {0, 2, 3}, {0, 3, 4}, {1, 2, 3, 4}};
      el.s = e->name == "H" ? Shape::Hex : e->name == "R" ? Shape::Prism : Shape::Pyramid;
      const auto& VF = el.s == Shape::Hex ? hexVF : el.s == Shape::Prism ? prismVF : pyrVF;
      const size_t nf = el.s == Shape::Hex ? 6 : 5;
      if (el.sides.size() != nf) fail(path, e.get(), "element <" + e->name + "> needs " + std::to_string(nf) + " face IDs");
      std::vector<std::set<long>> fverts;
      for (long sd : el.sides) {
        if (!g.F.count(sd)) fail(path, e.get(), "element refers to face " + std::to_string(sd) + " which is not defined");
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
        if (common.size() != 1) fail(path, e.get(), "the faces of this element do not meet in its vertices as Nektar++ orders them");
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
      fail(path, e.get(), "element type <" + e->name + "> in a " + std::to_string(dim) +
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
  if (const Node* comp = geo->child("COMPOSITE")) {
    std::map<std::set<std::uint32_t>, std::pair<int, std::vector<std::uint32_t>>> side_nodes;  // unused placeholder
    (void)side_nodes;
    for (auto& c : comp->kids) {
      long cid = id_of(path, c.get());
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
      // boundary composite of edges (2D) or faces (3D): boundary elements of order P
      const bool faces = kind == 'F';
      if (!(faces && dim == 3) && !(kind == 'E' && dim == 2)) continue;
      m.add_physical(dim - 1, (int)cid, name);
      m.add_entity(dim - 1, (int)cid, {(int)cid});
      for (long sid : ids) {
        ElementBlock& b = m.block(faces ? (g.F.count(sid) && g.F.at(sid).size() == 4 ? Shape::Quad : Shape::Tri) : Shape::Line, P,
                                  dim - 1, (int)cid);
        // find an element using this side and extract the side's nodes from it
        std::vector<long> sv;
        if (faces) {
          if (!g.F.count(sid)) fail(path, c.get(), "composite refers to face " + std::to_string(sid) + " which is not defined");
          std::set<long> vs;
          for (long ed : g.F.at(sid))
            for (long v : g.E.at(ed)) vs.insert(v);
          sv.assign(vs.begin(), vs.end());
        } else {
          if (!g.E.count(sid)) fail(path, c.get(), "composite refers to edge " + std::to_string(sid) + " which is not defined");
          sv = {g.E.at(sid)[0], g.E.at(sid)[1]};
        }
        std::set<std::uint32_t> want;
        for (long v : sv) want.insert(vnode.at(v));
        bool found = false;
        for (auto& bb : m.blocks) {
          if (dimension(bb.shape) != dim || found) continue;
          const auto& sides = dim == 3 ? face_nodes(bb.shape, P) : edge_nodes(bb.shape, P);
          const auto& svs = dim == 3 ? face_vertices(bb.shape) : std::vector<std::vector<int>>{};
          for (size_t e = 0; e < bb.size() && !found; ++e) {
            const std::uint32_t* nd = bb.element(e);
            for (size_t s = 0; s < sides.size() && !found; ++s) {
              std::set<std::uint32_t> have;
              if (dim == 3)
                for (int v : svs[s]) have.insert(nd[v]);
              else
                have = {nd[edge_vertices(bb.shape)[s][0]], nd[edge_vertices(bb.shape)[s][1]]};
              if (have != want) continue;
              std::vector<std::uint32_t> sn;
              for (int ln : sides[s]) sn.push_back(nd[ln]);
              b.add(sn.data());
              found = true;
            }
          }
        }
        if (!found) fail(path, c.get(), "composite side " + std::to_string(sid) + " is not a side of any element");
      }
    }
  }
  try {
    m.check();
  } catch (const std::invalid_argument& e) {
    throw MeshIOError(path + ": " + e.what());
  }
  return m;
}

namespace {
// Output buffer for write_nektar: numbers by std::to_chars (doubles as %.17g, what the stream
// with precision 17 wrote), flushed to the file in 8 MB blocks.
struct NekOut {
  std::ofstream f;
  std::string s;
  const std::filesystem::path& fp;
  explicit NekOut(const std::filesystem::path& p) : f(p, std::ios::binary), fp(p) {
    if (!f) throw MeshIOError(fp.string() + ": cannot open the file for writing");
    s.reserve((8u << 20) + 4096);
  }
  void flush_if_full() {
    if (s.size() >= (8u << 20)) flush();
  }
  void flush() {
    f.write(s.data(), static_cast<std::streamsize>(s.size()));
    if (!f) throw MeshIOError(fp.string() + ": write failed (disk full?)");
    s.clear();
  }
  NekOut& operator<<(std::string_view t) {
    s.append(t);
    return *this;
  }
  NekOut& operator<<(const char* t) { return *this << std::string_view(t); }
  NekOut& operator<<(const std::string& t) { return *this << std::string_view(t); }
  NekOut& operator<<(long v) {
    char buf[24];
    auto r = std::to_chars(buf, buf + sizeof buf, v);
    s.append(buf, r.ptr);
    return *this;
  }
  NekOut& operator<<(int v) { return *this << static_cast<long>(v); }
  NekOut& operator<<(double v) {
    char buf[40];
    auto r = std::to_chars(buf, buf + sizeof buf, v, std::chars_format::general, 17);
    s.append(buf, r.ptr);
    return *this;
  }
};

// A face's vertices, sorted, compared as std::set<uint32_t> compares (lexicographically, a
// prefix first): the order the faces were numbered in when they were keyed by std::set.
struct FaceKey {
  std::uint32_t v[4] = {0, 0, 0, 0};
  std::uint8_t n = 0;
  bool operator<(const FaceKey& o) const { return std::lexicographical_compare(v, v + n, o.v, o.v + o.n); }
  bool operator==(const FaceKey& o) const { return n == o.n && std::equal(v, v + n, o.v); }
};
FaceKey face_key(const std::uint32_t* nd, const int* local, int count) {
  if (count < 3 || count > 4) throw std::logic_error("Nektar++ writer: a face with " + std::to_string(count) + " vertices");
  FaceKey k;
  k.n = static_cast<std::uint8_t>(count);
  for (int i = 0; i < count; ++i) k.v[i] = nd[local[i]];
  std::sort(k.v, k.v + count);
  return k;
}
// Where an edge or face was first seen: block, element, local index (its nodes come from there).
struct Seen {
  std::uint32_t block, element, local;
};
}  // namespace

// Numbering follows the first writer of this format (maps keyed by vertex pairs and vertex
// sets): vertices by node index, edges by their vertex pair, faces by their sorted vertices, the
// nodes of an edge or face from the first element that uses it. Sorted vectors instead of maps
// of sets: the demo's order-4 mesh (1.3M nodes) took 47 s, mostly allocation.
void write_nektar(const Mesh& m, const std::filesystem::path& fp) {
  m.check();
  const int dim = m.dimension();
  const int P = m.order();
  for (auto& b : m.blocks) {
    if (dimension(b.shape) != dim) continue;
    bool ok = (dim == 2 && (b.shape == Shape::Tri || b.shape == Shape::Quad)) || dim == 3;
    if (!ok)
      throw MeshIOError(fp.string() + ": Nektar++ output supports triangles/quadrilaterals (2D) and tetrahedra, prisms, pyramids, hexahedra (3D); this mesh has " +
                        shape_name(b.shape) + " elements");
    if (b.order != P) throw MeshIOError(fp.string() + ": Nektar++ output needs one element order for all elements");
  }
  NekOut o(fp);
  o << "<?xml version=\"1.0\" encoding=\"utf-8\" ?>\n<NEKTAR>\n  <GEOMETRY DIM=\"" << dim << "\" SPACE=\"3\">\n";
  // vertices: element vertex nodes in node order
  std::vector<long> vid(m.num_nodes(), -1);
  for (auto& b : m.blocks)
    if (dimension(b.shape) == dim)
      for (size_t e = 0; e < b.size(); ++e)
        for (int v = 0; v < num_vertices(b.shape); ++v) vid[b.element(e)[v]] = 0;
  long k = 0;
  o << "    <VERTEX>\n";
  for (std::uint32_t n = 0; n < vid.size(); ++n) {
    if (vid[n] < 0) continue;
    vid[n] = k++;
    o << "      <V ID=\"" << vid[n] << "\">" << m.x[n] << " " << m.y[n] << " " << m.z[n] << "</V>\n";
    o.flush_if_full();
  }
  o << "    </VERTEX>\n";
  // edges and faces: every use with where it was seen, sorted by key then first use, deduplicated
  using EdgeKey = std::pair<std::uint32_t, std::uint32_t>;
  std::vector<std::pair<EdgeKey, Seen>> edges;
  std::vector<std::pair<FaceKey, Seen>> faces;
  for (std::uint32_t bi = 0; bi < m.blocks.size(); ++bi) {
    auto& b = m.blocks[bi];
    if (dimension(b.shape) != dim) continue;
    for (size_t e = 0; e < b.size(); ++e) {
      const std::uint32_t* nd = b.element(e);
      const auto& ev = edge_vertices(b.shape);
      for (std::uint32_t ei = 0; ei < ev.size(); ++ei) {
        const std::uint32_t va = nd[ev[ei][0]], vc = nd[ev[ei][1]];
        edges.push_back({{std::min(va, vc), std::max(va, vc)}, {bi, static_cast<std::uint32_t>(e), ei}});
      }
      if (dim == 3) {
        const auto& fvs = face_vertices(b.shape);
        for (std::uint32_t fi = 0; fi < fvs.size(); ++fi)
          faces.push_back({face_key(nd, fvs[fi].data(), (int)fvs[fi].size()), {bi, static_cast<std::uint32_t>(e), fi}});
      }
    }
  }
  auto seen_before = [](const Seen& a, const Seen& c) {
    return std::tie(a.block, a.element, a.local) < std::tie(c.block, c.element, c.local);
  };
  std::sort(edges.begin(), edges.end(), [&](const auto& a, const auto& c) {
    return a.first != c.first ? a.first < c.first : seen_before(a.second, c.second);
  });
  edges.erase(std::unique(edges.begin(), edges.end(), [](const auto& a, const auto& c) { return a.first == c.first; }), edges.end());
  std::sort(faces.begin(), faces.end(), [&](const auto& a, const auto& c) {
    return !(a.first == c.first) ? a.first < c.first : seen_before(a.second, c.second);
  });
  faces.erase(std::unique(faces.begin(), faces.end(), [](const auto& a, const auto& c) { return a.first == c.first; }), faces.end());
  // id of the edge a-b (-1 if no element has it)
  auto eid = [&](std::uint32_t a, std::uint32_t c) -> long {
    const EdgeKey key{std::min(a, c), std::max(a, c)};
    auto it = std::lower_bound(edges.begin(), edges.end(), key, [](const auto& x, const EdgeKey& y) { return x.first < y; });
    return it != edges.end() && it->first == key ? it - edges.begin() : -1;
  };
  auto find_face = [&](const FaceKey& key) -> long {
    auto it = std::lower_bound(faces.begin(), faces.end(), key, [](const auto& x, const FaceKey& y) { return x.first < y; });
    return it != faces.end() && it->first == key ? it - faces.begin() : -1;
  };
  // nodes of edge i from key.first to key.second, of face i in its first element's face order
  auto edge_line = [&](std::size_t i, std::vector<std::uint32_t>& line) {
    const Seen& w = edges[i].second;
    const auto& b = m.blocks[w.block];
    const std::uint32_t* nd = b.element(w.element);
    const auto& loc = edge_nodes(b.shape, P)[w.local];  // v0, v1, interior from v0
    line.assign(1, nd[loc[0]]);
    for (size_t q = 2; q < loc.size(); ++q) line.push_back(nd[loc[q]]);
    line.push_back(nd[loc[1]]);
    if (nd[loc[0]] != edges[i].first.first) std::reverse(line.begin(), line.end());
  };
  auto face_first = [&](std::size_t i) {
    const Seen& w = faces[i].second;
    const auto& b = m.blocks[w.block];
    return std::make_pair(b.element(w.element), &b);
  };
  o << "    <EDGE>\n";
  for (std::size_t i = 0; i < edges.size(); ++i) {
    o << "      <E ID=\"" << (long)i << "\">" << vid[edges[i].first.first] << " " << vid[edges[i].first.second] << "</E>\n";
    o.flush_if_full();
  }
  o << "    </EDGE>\n";
  if (dim == 3) {
    o << "    <FACE>\n";
    for (std::size_t i = 0; i < faces.size(); ++i) {
      auto [nd, b] = face_first(i);
      const auto& fv = face_vertices(b->shape)[faces[i].second.local];
      const char* L = fv.size() == 4 ? "Q" : "T";
      o << "      <" << L << " ID=\"" << (long)i << "\">";
      for (size_t q = 0; q < fv.size(); ++q) o << (q ? " " : "") << eid(nd[fv[q]], nd[fv[(q + 1) % fv.size()]]);
      o << "</" << L << ">\n";
      o.flush_if_full();
    }
    o << "    </FACE>\n";
  }
  o << "    <ELEMENT>\n";
  std::map<std::pair<int, std::string>, std::vector<long>> dom_ids;  // (entity tag, letter) -> element ids
  long elid = 0;
  // Nektar++'s face order of each shape, as Gmsh vertex indices (prism: Nektar's
  // vertices 0,1,2,3,4,5 are our 0,1,4,3,2,5: its triangles are faces 1 and 3)
  static const std::vector<std::vector<int>> FT = {{0, 1, 2}, {0, 1, 3}, {1, 2, 3}, {0, 2, 3}};
  static const std::vector<std::vector<int>> FH = {{0, 1, 2, 3}, {0, 1, 5, 4}, {1, 2, 6, 5}, {3, 2, 6, 7}, {0, 3, 7, 4}, {4, 5, 6, 7}};
  static const std::vector<std::vector<int>> FR = {{0, 1, 4, 3}, {0, 1, 2}, {1, 4, 5, 2}, {3, 4, 5}, {0, 3, 5, 2}};
  static const std::vector<std::vector<int>> FP = {{0, 1, 2, 3}, {0, 1, 4}, {1, 2, 4}, {3, 2, 4}, {0, 3, 4}};
  for (auto& b : m.blocks) {
    if (dimension(b.shape) != dim) continue;
    const char* L = dim == 3 ? (b.shape == Shape::Tet ? "A" : b.shape == Shape::Hex ? "H" : b.shape == Shape::Prism ? "R" : "P")
                             : (b.shape == Shape::Quad ? "Q" : "T");
    auto& ids = dom_ids[{b.entity_tag, L}];
    const auto& F = b.shape == Shape::Tet ? FT : b.shape == Shape::Hex ? FH : b.shape == Shape::Prism ? FR : FP;
    for (size_t e = 0; e < b.size(); ++e) {
      const std::uint32_t* nd = b.element(e);
      o << "      <" << L << " ID=\"" << elid << "\">";
      if (dim == 2) {
        int nv = num_vertices(b.shape);
        for (int v = 0; v < nv; ++v) o << (v ? " " : "") << eid(nd[v], nd[(v + 1) % nv]);
      } else {
        for (size_t f = 0; f < F.size(); ++f) o << (f ? " " : "") << find_face(face_key(nd, F[f].data(), (int)F[f].size()));
      }
      o << "</" << L << ">\n";
      o.flush_if_full();
      ids.push_back(elid++);
    }
  }
  o << "    </ELEMENT>\n";
  if (P >= 2) {
    o << "    <CURVED>\n";
    std::vector<std::uint32_t> line;
    for (std::size_t i = 0; i < edges.size(); ++i) {
      edge_line(i, line);
      o << "      <E ID=\"" << (long)i << "\" EDGEID=\"" << (long)i << "\" NUMPOINTS=\"" << P + 1 << "\" TYPE=\"PolyEvenlySpaced\">";
      for (auto n : line) o << " " << m.x[n] << " " << m.y[n] << " " << m.z[n];
      o << " </E>\n";
      o.flush_if_full();
    }
    if (dim == 3) {
      long cid = 0;
      // Nektar order of the equispaced triangle: vertices, edges, interior row by row
      std::vector<int> order;
      {
        const auto& tl = lattice(Shape::Tri, P);
        std::map<Lattice, int> at;
        for (int i = 0; i < (int)tl.size(); ++i) at[tl[i]] = i;
        order = {at[{0, 0, 0}], at[{P, 0, 0}], at[{0, P, 0}]};
        for (int i = 1; i < P; ++i) order.push_back(at[{i, 0, 0}]);
        for (int i = 1; i < P; ++i) order.push_back(at[{P - i, i, 0}]);
        for (int i = 1; i < P; ++i) order.push_back(at[{0, P - i, 0}]);
        for (int j = 1; j < P; ++j)
          for (int i = 1; i + j < P; ++i) order.push_back(at[{i, j, 0}]);
      }
      // quadrilateral faces: (P+1)^2 equispaced points, index i + (P+1) j in the face's
      // frame (vertex 0 = common vertex of its edges 3 and 0, i towards vertex 1, j towards 3)
      std::vector<int> qorder((P + 1) * (P + 1));
      {
        const auto& ql = lattice(Shape::Quad, P);
        for (int i = 0; i < (int)ql.size(); ++i) qorder[ql[i][0] + (P + 1) * ql[i][1]] = i;
      }
      for (std::size_t i = 0; i < faces.size(); ++i) {
        const bool quad = faces[i].first.n == 4;
        if (!quad && P < 3) continue;
        auto [nd, b] = face_first(i);
        const auto& fn = face_nodes(b->shape, P)[faces[i].second.local];
        o << "      <F ID=\"" << cid++ << "\" FACEID=\"" << (long)i << "\" NUMPOINTS=\""
          << (quad ? (P + 1) * (P + 1) : (P + 1) * (P + 2) / 2) << "\" TYPE=\"" << (quad ? "PolyEvenlySpaced" : "NodalTriEvenlySpaced") << "\">";
        for (int q : quad ? qorder : order) {
          auto n = nd[fn[q]];
          o << " " << m.x[n] << " " << m.y[n] << " " << m.z[n];
        }
        o << " </F>\n";
        o.flush_if_full();
      }
    }
    o << "    </CURVED>\n";
  }
  // composites: one per domain entity, one per boundary entity
  o << "    <COMPOSITE>\n";
  std::vector<long> domain;
  long next_c = 0;
  auto ranges = [](const std::vector<long>& ids) {
    std::string s;
    for (size_t i = 0; i < ids.size();) {
      size_t j = i;
      while (j + 1 < ids.size() && ids[j + 1] == ids[j] + 1) ++j;
      if (!s.empty()) s += ",";
      s += std::to_string(ids[i]) + (j > i ? "-" + std::to_string(ids[j]) : "");
      i = j + 1;
    }
    return s;
  };
  for (auto& [tl, ids] : dom_ids) {
    if (ids.empty()) continue;
    const int tag = tl.first;
    const std::string L = tl.second;
    std::string name = m.group_name(dim, tag);
    o << "      <C ID=\"" << next_c << "\"" << (name.empty() ? "" : " NAME=\"" + name + "\"") << "> " << L << "[" << ranges(ids) << "] </C>\n";
    domain.push_back(next_c++);
  }
  std::map<int, std::vector<long>> bnd;
  for (auto& b : m.blocks) {
    if (dimension(b.shape) != dim - 1) continue;
    for (size_t e = 0; e < b.size(); ++e) {
      const std::uint32_t* nd = b.element(e);
      static const int kVertices[4] = {0, 1, 2, 3};
      const long id = dim == 3 ? find_face(face_key(nd, kVertices, num_vertices(b.shape))) : eid(nd[0], nd[1]);
      if (id >= 0) bnd[b.entity_tag].push_back(id);
    }
  }
  for (auto& [tag, ids] : bnd) {
    std::sort(ids.begin(), ids.end());
    std::string name = m.group_name(dim - 1, tag);
    o << "      <C ID=\"" << next_c++ << "\"" << (name.empty() ? "" : " NAME=\"" + name + "\"") << "> " << (dim == 3 ? "F" : "E") << "["
      << ranges(ids) << "] </C>\n";
  }
  o << "    </COMPOSITE>\n    <DOMAIN> C[" << ranges(domain) << "] </DOMAIN>\n  </GEOMETRY>\n</NEKTAR>\n";
  o.flush();
}

}  // namespace meshflow::io
