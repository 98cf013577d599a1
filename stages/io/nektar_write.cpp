// Nektar++ XML geometry: write, in Nektar++'s compressed form (B64Z-LittleEndian sections, what
// NekMesh writes by default and Nektar++ reads) or plain text, plus an EXPANSIONS section so that
// the file is a session a solver can start from. Conventions (face order, vertex order, point
// sets) as described at the top of nektar_read.cpp; the compressed layout in nektar_b64z.hpp.
#include "stages/io/mesh_io.hpp"
#include "stages/io/nektar_b64z.hpp"
#include "stages/model/topology.hpp"

#include <algorithm>
#include <charconv>
#include <cstdint>
#include <fstream>
#include <map>
#include <string_view>
#include <tuple>

namespace meshflow::io {

using namespace model;

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
    if (t.size() < (1u << 20)) {
      s.append(t);
      return *this;
    }
    // a compressed section (up to hundreds of MB): written as it is, not copied into the buffer
    flush();
    f.write(t.data(), static_cast<std::streamsize>(t.size()));
    if (!f) throw MeshIOError(fp.string() + ": write failed (disk full?)");
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

// Nektar++'s numbering of a mesh. Numbering follows the first writer of this format (maps keyed
// by vertex pairs and vertex sets): vertices by node index, edges by their vertex pair, faces by
// their sorted vertices, the nodes of an edge or face from the first element that uses it.
// Sorted vectors instead of maps of sets: the demo's order-4 mesh (1.3M nodes) took 47 s, mostly
// allocation.
struct Numbering {
  using EdgeKey = std::pair<std::uint32_t, std::uint32_t>;
  const Mesh& m;
  int dim, P;
  std::vector<long> vid;                  // node -> vertex id, -1 if not an element vertex
  std::vector<std::uint32_t> vnode;       // vertex id -> node
  std::vector<std::pair<EdgeKey, Seen>> edges;
  std::vector<std::pair<FaceKey, Seen>> faces;

  explicit Numbering(const Mesh& mesh) : m(mesh), dim(mesh.dimension()), P(mesh.order()) {
    vid.assign(m.num_nodes(), -1);
    for (auto& b : m.blocks)
      if (dimension(b.shape) == dim)
        for (size_t e = 0; e < b.size(); ++e)
          for (int v = 0; v < num_vertices(b.shape); ++v) vid[b.element(e)[v]] = 0;
    for (std::uint32_t n = 0; n < vid.size(); ++n)
      if (vid[n] >= 0) vid[n] = static_cast<long>(vnode.size()), vnode.push_back(n);
    // edges and faces: every use with where it was seen, sorted by key then first use, deduplicated
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
    auto seen_before = [](const Seen& a, const Seen& c) { return std::tie(a.block, a.element, a.local) < std::tie(c.block, c.element, c.local); };
    std::sort(edges.begin(), edges.end(), [&](const auto& a, const auto& c) { return a.first != c.first ? a.first < c.first : seen_before(a.second, c.second); });
    edges.erase(std::unique(edges.begin(), edges.end(), [](const auto& a, const auto& c) { return a.first == c.first; }), edges.end());
    std::sort(faces.begin(), faces.end(), [&](const auto& a, const auto& c) { return !(a.first == c.first) ? a.first < c.first : seen_before(a.second, c.second); });
    faces.erase(std::unique(faces.begin(), faces.end(), [](const auto& a, const auto& c) { return a.first == c.first; }), faces.end());
  }
  // id of the edge a-b (-1 if no element has it)
  long eid(std::uint32_t a, std::uint32_t c) const {
    const EdgeKey key{std::min(a, c), std::max(a, c)};
    auto it = std::lower_bound(edges.begin(), edges.end(), key, [](const auto& x, const EdgeKey& y) { return x.first < y; });
    return it != edges.end() && it->first == key ? it - edges.begin() : -1;
  }
  long find_face(const FaceKey& key) const {
    auto it = std::lower_bound(faces.begin(), faces.end(), key, [](const auto& x, const FaceKey& y) { return x.first < y; });
    return it != faces.end() && it->first == key ? it - faces.begin() : -1;
  }
  // nodes of edge i from key.first to key.second
  void edge_line(std::size_t i, std::vector<std::uint32_t>& line) const {
    const Seen& w = edges[i].second;
    const auto& b = m.blocks[w.block];
    const std::uint32_t* nd = b.element(w.element);
    const auto& loc = edge_nodes(b.shape, P)[w.local];  // v0, v1, interior from v0
    line.assign(1, nd[loc[0]]);
    for (size_t q = 2; q < loc.size(); ++q) line.push_back(nd[loc[q]]);
    line.push_back(nd[loc[1]]);
    if (nd[loc[0]] != edges[i].first.first) std::reverse(line.begin(), line.end());
  }
  // the face's vertices (Gmsh local indices) in the element it was first seen in
  const std::vector<int>& face_local(std::size_t i) const {
    const Seen& w = faces[i].second;
    return face_vertices(m.blocks[w.block].shape)[w.local];
  }
  const std::uint32_t* face_element(std::size_t i) const { return m.blocks[faces[i].second.block].element(faces[i].second.element); }
  // edge ids of face i, in order around it (its vertex 0 is the common vertex of its last and first edge)
  std::vector<long> face_edges(std::size_t i) const {
    const auto& fv = face_local(i);
    const std::uint32_t* nd = face_element(i);
    std::vector<long> out;
    for (size_t q = 0; q < fv.size(); ++q) out.push_back(eid(nd[fv[q]], nd[fv[(q + 1) % fv.size()]]));
    return out;
  }
  // face point nodes in Nektar++'s order (quads: (P+1)^2 points, index i + (P+1) j in the
  // face's frame; triangles: vertices, edges, interior row by row, equispaced)
  void face_points(std::size_t i, std::vector<std::uint32_t>& pts) const {
    const Seen& w = faces[i].second;
    const auto& b = m.blocks[w.block];
    const auto& fn = face_nodes(b.shape, P)[w.local];
    const std::uint32_t* nd = b.element(w.element);
    pts.clear();
    for (int q : faces[i].first.n == 4 ? quad_order() : tri_order()) pts.push_back(nd[fn[q]]);
  }
  const char* letter(Shape s) const {
    return dim == 3 ? (s == Shape::Tet ? "A" : s == Shape::Hex ? "H" : s == Shape::Prism ? "R" : "P") : (s == Shape::Quad ? "Q" : "T");
  }
  // side ids of element e of block b: edges (2D) or faces in Nektar++'s face order (3D)
  void element_sides(const ElementBlock& b, std::size_t e, std::vector<long>& out) const {
    // Nektar++'s face order of each shape, as Gmsh vertex indices (prism: Nektar's
    // vertices 0,1,2,3,4,5 are our 0,1,4,3,2,5: its triangles are faces 1 and 3)
    static const std::vector<std::vector<int>> FT = {{0, 1, 2}, {0, 1, 3}, {1, 2, 3}, {0, 2, 3}};
    static const std::vector<std::vector<int>> FH = {{0, 1, 2, 3}, {0, 1, 5, 4}, {1, 2, 6, 5}, {3, 2, 6, 7}, {0, 3, 7, 4}, {4, 5, 6, 7}};
    static const std::vector<std::vector<int>> FR = {{0, 1, 4, 3}, {0, 1, 2}, {1, 4, 5, 2}, {3, 4, 5}, {0, 3, 5, 2}};
    static const std::vector<std::vector<int>> FP = {{0, 1, 2, 3}, {0, 1, 4}, {1, 2, 4}, {3, 2, 4}, {0, 3, 4}};
    const std::uint32_t* nd = b.element(e);
    out.clear();
    if (dim == 2) {
      const int nv = num_vertices(b.shape);
      for (int v = 0; v < nv; ++v) out.push_back(eid(nd[v], nd[(v + 1) % nv]));
      return;
    }
    const auto& F = b.shape == Shape::Tet ? FT : b.shape == Shape::Hex ? FH : b.shape == Shape::Prism ? FR : FP;
    for (auto& f : F) out.push_back(find_face(face_key(nd, f.data(), (int)f.size())));
  }

 private:
  const std::vector<int>& tri_order() const {
    if (tri_.empty()) {
      const auto& tl = lattice(Shape::Tri, P);
      std::map<Lattice, int> at;
      for (int i = 0; i < (int)tl.size(); ++i) at[tl[i]] = i;
      tri_ = {at[{0, 0, 0}], at[{P, 0, 0}], at[{0, P, 0}]};
      for (int i = 1; i < P; ++i) tri_.push_back(at[{i, 0, 0}]);
      for (int i = 1; i < P; ++i) tri_.push_back(at[{P - i, i, 0}]);
      for (int i = 1; i < P; ++i) tri_.push_back(at[{0, P - i, 0}]);
      for (int j = 1; j < P; ++j)
        for (int i = 1; i + j < P; ++i) tri_.push_back(at[{i, j, 0}]);
    }
    return tri_;
  }
  const std::vector<int>& quad_order() const {
    if (quad_.empty()) {
      const auto& ql = lattice(Shape::Quad, P);
      quad_.resize((P + 1) * (P + 1));
      for (int i = 0; i < (int)ql.size(); ++i) quad_[ql[i][0] + (P + 1) * ql[i][1]] = i;
    }
    return quad_;
  }
  mutable std::vector<int> tri_, quad_;
};

bool curved_face(const Numbering& t, std::size_t i) { return t.faces[i].first.n == 4 || t.P >= 3; }

// --- plain sections ---

void plain_vertices(NekOut& o, const Numbering& t) {
  o << "    <VERTEX>\n";
  for (std::size_t k = 0; k < t.vnode.size(); ++k) {
    const auto n = t.vnode[k];
    o << "      <V ID=\"" << (long)k << "\">" << t.m.x[n] << " " << t.m.y[n] << " " << t.m.z[n] << "</V>\n";
    o.flush_if_full();
  }
  o << "    </VERTEX>\n";
}

void plain_edges(NekOut& o, const Numbering& t) {
  o << "    <EDGE>\n";
  for (std::size_t i = 0; i < t.edges.size(); ++i) {
    o << "      <E ID=\"" << (long)i << "\">" << t.vid[t.edges[i].first.first] << " " << t.vid[t.edges[i].first.second] << "</E>\n";
    o.flush_if_full();
  }
  o << "    </EDGE>\n";
}

void plain_faces(NekOut& o, const Numbering& t) {
  o << "    <FACE>\n";
  for (std::size_t i = 0; i < t.faces.size(); ++i) {
    const char* L = t.faces[i].first.n == 4 ? "Q" : "T";
    o << "      <" << L << " ID=\"" << (long)i << "\">";
    auto es = t.face_edges(i);
    for (size_t q = 0; q < es.size(); ++q) o << (q ? " " : "") << es[q];
    o << "</" << L << ">\n";
    o.flush_if_full();
  }
  o << "    </FACE>\n";
}

void plain_elements(NekOut& o, const Numbering& t) {
  o << "    <ELEMENT>\n";
  long elid = 0;
  std::vector<long> sides;
  for (auto& b : t.m.blocks) {
    if (dimension(b.shape) != t.dim) continue;
    const char* L = t.letter(b.shape);
    for (size_t e = 0; e < b.size(); ++e) {
      t.element_sides(b, e, sides);
      o << "      <" << L << " ID=\"" << elid++ << "\">";
      for (size_t f = 0; f < sides.size(); ++f) o << (f ? " " : "") << sides[f];
      o << "</" << L << ">\n";
      o.flush_if_full();
    }
  }
  o << "    </ELEMENT>\n";
}

void plain_curves(NekOut& o, const Numbering& t) {
  const Mesh& m = t.m;
  const int P = t.P;
  o << "    <CURVED>\n";
  std::vector<std::uint32_t> line;
  for (std::size_t i = 0; i < t.edges.size(); ++i) {
    t.edge_line(i, line);
    o << "      <E ID=\"" << (long)i << "\" EDGEID=\"" << (long)i << "\" NUMPOINTS=\"" << P + 1 << "\" TYPE=\"PolyEvenlySpaced\">";
    for (auto n : line) o << " " << m.x[n] << " " << m.y[n] << " " << m.z[n];
    o << " </E>\n";
    o.flush_if_full();
  }
  long cid = 0;
  for (std::size_t i = 0; t.dim == 3 && i < t.faces.size(); ++i) {
    if (!curved_face(t, i)) continue;
    const bool quad = t.faces[i].first.n == 4;
    t.face_points(i, line);
    o << "      <F ID=\"" << cid++ << "\" FACEID=\"" << (long)i << "\" NUMPOINTS=\"" << (long)line.size() << "\" TYPE=\""
      << (quad ? "PolyEvenlySpaced" : "NodalTriEvenlySpaced") << "\">";
    for (auto n : line) o << " " << m.x[n] << " " << m.y[n] << " " << m.z[n];
    o << " </F>\n";
    o.flush_if_full();
  }
  o << "    </CURVED>\n";
}

// --- compressed sections (one block of records each, as NekMesh writes them) ---

const char* kB64ZAttrs = " COMPRESSED=\"B64Z-LittleEndian\" BITSIZE=\"64\"";

void b64z_vertices(NekOut& o, const Numbering& t) {
  std::vector<nektar::Vertex> r(t.vnode.size());
  for (std::size_t k = 0; k < r.size(); ++k) r[k] = {(std::int64_t)k, t.m.x[t.vnode[k]], t.m.y[t.vnode[k]], t.m.z[t.vnode[k]]};
  o << "    <VERTEX" << kB64ZAttrs << ">" << nektar::encode(r) << "</VERTEX>\n";
}

void b64z_edges(NekOut& o, const Numbering& t) {
  std::vector<nektar::Edge> r(t.edges.size());
  for (std::size_t i = 0; i < r.size(); ++i) r[i] = {(std::int64_t)i, t.vid[t.edges[i].first.first], t.vid[t.edges[i].first.second]};
  o << "    <EDGE" << kB64ZAttrs << ">" << nektar::encode(r) << "</EDGE>\n";
}

template <int N>
void b64z_side_block(NekOut& o, const char* L, const std::vector<nektar::Sides<N>>& r) {
  if (!r.empty()) o << "      <" << L << kB64ZAttrs << ">" << nektar::encode(r) << "</" << L << ">\n";
}

void b64z_faces(NekOut& o, const Numbering& t) {
  std::vector<nektar::Sides<3>> tris;
  std::vector<nektar::Sides<4>> quads;
  for (std::size_t i = 0; i < t.faces.size(); ++i) {
    auto es = t.face_edges(i);
    if (es.size() == 4) quads.push_back({(std::int64_t)i, {es[0], es[1], es[2], es[3]}});
    else tris.push_back({(std::int64_t)i, {es[0], es[1], es[2]}});
  }
  o << "    <FACE>\n";
  b64z_side_block(o, "T", tris);
  b64z_side_block(o, "Q", quads);
  o << "    </FACE>\n";
}

template <int N>
void b64z_element_block(NekOut& o, const Numbering& t, const ElementBlock& b, long& elid) {
  std::vector<nektar::Sides<N>> r(b.size());
  std::vector<long> sides;
  for (size_t e = 0; e < b.size(); ++e) {
    t.element_sides(b, e, sides);
    r[e].id = elid++;
    std::copy(sides.begin(), sides.end(), r[e].s);
  }
  b64z_side_block(o, t.letter(b.shape), r);
}

void b64z_elements(NekOut& o, const Numbering& t) {
  o << "    <ELEMENT>\n";
  long elid = 0;
  for (auto& b : t.m.blocks) {
    if (dimension(b.shape) != t.dim) continue;
    const int n = t.dim == 2 ? num_vertices(b.shape) : (int)face_vertices(b.shape).size();
    if (n == 3) b64z_element_block<3>(o, t, b, elid);
    else if (n == 4) b64z_element_block<4>(o, t, b, elid);
    else if (n == 5) b64z_element_block<5>(o, t, b, elid);
    else b64z_element_block<6>(o, t, b, elid);
  }
  o << "    </ELEMENT>\n";
}

// Curved points are mesh nodes: POINTS holds each node once (in order of first use) and INDEX
// maps every curve's points onto them (Nektar++'s reader takes any such map; its own writer
// repeats shared points). Sharing the edge and face points is most of the size saved.
void b64z_curves(NekOut& o, const Numbering& t) {
  const Mesh& m = t.m;
  std::vector<std::int64_t> slot(m.num_nodes(), -1), index;
  std::vector<nektar::Vertex> pts;
  auto add_points = [&](const std::vector<std::uint32_t>& nodes) {
    for (auto n : nodes) {
      if (slot[n] < 0) slot[n] = (std::int64_t)pts.size(), pts.push_back({slot[n], m.x[n], m.y[n], m.z[n]});
      index.push_back(slot[n]);
    }
  };
  std::vector<nektar::CurvedInfo> einfo, finfo;
  std::vector<std::uint32_t> line;
  // sized before they are filled: a doubling vector moves while it holds both copies (Rotor 67's
  // order 4: ~10^8 indices); pts has at most one entry per node (untouched capacity is not resident)
  std::size_t nindex = t.edges.size() * std::size_t(t.P + 1), nfaces = 0;
  for (std::size_t i = 0; t.dim == 3 && i < t.faces.size(); ++i)
    if (curved_face(t, i)) {
      ++nfaces;
      nindex += t.faces[i].first.n == 4 ? std::size_t(t.P + 1) * (t.P + 1) : std::size_t(t.P + 1) * (t.P + 2) / 2;
    }
  index.reserve(nindex);
  pts.reserve(m.num_nodes());
  einfo.reserve(t.edges.size());
  finfo.reserve(nfaces);
  for (std::size_t i = 0; i < t.edges.size(); ++i) {
    t.edge_line(i, line);
    einfo.push_back({(std::int64_t)i, (std::int64_t)i, (std::int64_t)line.size(), 0, (std::int64_t)index.size(), nektar::kPolyEvenlySpaced});
    add_points(line);
  }
  for (std::size_t i = 0; t.dim == 3 && i < t.faces.size(); ++i) {
    if (!curved_face(t, i)) continue;
    t.face_points(i, line);
    const auto type = t.faces[i].first.n == 4 ? nektar::kPolyEvenlySpaced : nektar::kNodalTriEvenlySpaced;
    finfo.push_back({(std::int64_t)finfo.size(), (std::int64_t)i, (std::int64_t)line.size(), 0, (std::int64_t)index.size(), type});
    add_points(line);
  }
  // each array encoded, written and freed in turn: one encoded section in memory at a time
  // (one full expression kept every temporary string alive to its end)
  std::vector<std::int64_t>().swap(slot);
  o << "    <CURVED" << kB64ZAttrs << ">\n";
  if (!einfo.empty()) o << "      <E>" << nektar::encode(einfo) << "</E>\n";
  std::vector<nektar::CurvedInfo>().swap(einfo);
  if (!finfo.empty()) o << "      <F>" << nektar::encode(finfo) << "</F>\n";
  std::vector<nektar::CurvedInfo>().swap(finfo);
  o << "      <DATAPOINTS ID=\"0\">\n        <INDEX>" << nektar::encode(index) << "</INDEX>\n";
  std::vector<std::int64_t>().swap(index);
  o << "        <POINTS>" << nektar::encode(pts) << "</POINTS>\n      </DATAPOINTS>\n    </CURVED>\n";
}

// --- composites, domain, expansions ---

std::string ranges(const std::vector<long>& ids) {
  std::string s;
  for (size_t i = 0; i < ids.size();) {
    size_t j = i;
    while (j + 1 < ids.size() && ids[j + 1] == ids[j] + 1) ++j;
    if (!s.empty()) s += ",";
    s += std::to_string(ids[i]) + (j > i ? "-" + std::to_string(ids[j]) : "");
    i = j + 1;
  }
  return s;
}

// COMPOSITE (one per (domain entity, element letter), then one per boundary entity) and DOMAIN;
// returns the domain composites' ids
std::vector<long> composites(NekOut& o, const Numbering& t) {
  const Mesh& m = t.m;
  const int dim = t.dim;
  std::map<std::pair<int, std::string>, std::vector<long>> dom_ids;  // (entity tag, letter) -> element ids
  long elid = 0;
  for (auto& b : m.blocks) {
    if (dimension(b.shape) != dim) continue;
    auto& ids = dom_ids[{b.entity_tag, t.letter(b.shape)}];
    for (size_t e = 0; e < b.size(); ++e) ids.push_back(elid++);
  }
  o << "    <COMPOSITE>\n";
  std::vector<long> domain;
  long next_c = 0;
  for (auto& [tl, ids] : dom_ids) {
    if (ids.empty()) continue;
    std::string name = m.group_name(dim, tl.first);
    o << "      <C ID=\"" << next_c << "\"" << (name.empty() ? "" : " NAME=\"" + name + "\"") << "> " << tl.second << "[" << ranges(ids) << "] </C>\n";
    domain.push_back(next_c++);
  }
  std::map<int, std::vector<long>> bnd;
  for (auto& b : m.blocks) {
    if (dimension(b.shape) != dim - 1) continue;
    for (size_t e = 0; e < b.size(); ++e) {
      const std::uint32_t* nd = b.element(e);
      static const int kVertices[4] = {0, 1, 2, 3};
      const long id = dim == 3 ? t.find_face(face_key(nd, kVertices, num_vertices(b.shape))) : t.eid(nd[0], nd[1]);
      if (id >= 0) bnd[b.entity_tag].push_back(id);
    }
  }
  for (auto& [tag, ids] : bnd) {
    std::sort(ids.begin(), ids.end());
    std::string name = m.group_name(dim - 1, tag);
    o << "      <C ID=\"" << next_c++ << "\"" << (name.empty() ? "" : " NAME=\"" + name + "\"") << "> " << (dim == 3 ? "F" : "E") << "["
      << ranges(ids) << "] </C>\n";
  }
  o << "    </COMPOSITE>\n    <DOMAIN> C[" << ranges(domain) << "] </DOMAIN>\n";
  return domain;
}

// One expansion per domain composite, of the mesh's order (NUMMODES = order + 1: the modified
// basis of order P has P + 1 modes per direction), as NekMesh writes it: a session to start from.
void expansions(NekOut& o, const Numbering& t, const std::vector<long>& domain) {
  o << "  <EXPANSIONS>\n";
  for (long c : domain) o << "    <E COMPOSITE=\"C[" << c << "]\" NUMMODES=\"" << t.P + 1 << "\" TYPE=\"MODIFIED\" FIELDS=\"u\" />\n";
  o << "  </EXPANSIONS>\n";
}

void check_writable(const Mesh& m, const std::filesystem::path& fp) {
  const int dim = m.dimension(), P = m.order();
  for (auto& b : m.blocks) {
    if (dimension(b.shape) != dim) continue;
    bool ok = (dim == 2 && (b.shape == Shape::Tri || b.shape == Shape::Quad)) || dim == 3;
    if (!ok)
      throw MeshIOError(fp.string() + ": Nektar++ output supports triangles/quadrilaterals (2D) and tetrahedra, prisms, pyramids, hexahedra (3D); this mesh has " +
                        shape_name(b.shape) + " elements");
    if (b.order != P) throw MeshIOError(fp.string() + ": Nektar++ output needs one element order for all elements");
  }
}

void write_file(const Mesh& m, const std::filesystem::path& fp, const std::filesystem::path& out, bool compressed) {
  const Numbering t(m);
  NekOut o(out);
  o << "<?xml version=\"1.0\" encoding=\"utf-8\" ?>\n<NEKTAR>\n  <GEOMETRY DIM=\"" << t.dim << "\" SPACE=\"3\">\n";
  if (compressed) {
    b64z_vertices(o, t);
    b64z_edges(o, t);
    if (t.dim == 3) b64z_faces(o, t);
    b64z_elements(o, t);
    if (t.P >= 2) b64z_curves(o, t);
  } else {
    plain_vertices(o, t);
    plain_edges(o, t);
    if (t.dim == 3) plain_faces(o, t);
    plain_elements(o, t);
    if (t.P >= 2) plain_curves(o, t);
  }
  auto domain = composites(o, t);
  o << "  </GEOMETRY>\n";
  expansions(o, t, domain);
  o << "</NEKTAR>\n";
  o.flush();
  o.f.close();
  if (!o.f) throw MeshIOError(fp.string() + ": write failed (disk full?)");
}
}  // namespace

// Written to a temporary file beside the target and renamed: no partial file is left behind.
void write_nektar(const Mesh& m, const std::filesystem::path& fp, bool compressed) {
  m.check();
  check_writable(m, fp);
  auto tmp = fp;
  tmp += ".tmp";
  try {
    write_file(m, fp, tmp, compressed);
    std::filesystem::rename(tmp, fp);
  } catch (...) {
    std::error_code ec;
    std::filesystem::remove(tmp, ec);
    throw;
  }
}

}  // namespace meshflow::io
