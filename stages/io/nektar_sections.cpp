// Reading the sections of a Nektar++ XML geometry, plain or compressed, into a Geo
// (stages/io/nektar_xml.hpp). XML is parsed with expat.
#include "stages/io/nektar_xml.hpp"

#include "stages/io/mesh_io.hpp"
#include "stages/io/nektar_b64z.hpp"

#include <expat.h>

#include <charconv>
#include <functional>
#include <cmath>
#include <strings.h>

namespace meshflow::io::nektar {

namespace {
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

}  // namespace

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

namespace {

std::string where(const std::string& path, const Node* n) { return path + ":line " + std::to_string(n->line) + ": <" + n->name + ">"; }

// Is this section (or block) compressed? Only Nektar++'s one form is known.
bool compressed(const std::string& path, const Node* n) {
  auto it = n->attr.find("COMPRESSED");
  if (it == n->attr.end()) return false;
  if (strcasecmp(it->second.c_str(), kCompressed) != 0)
    fail(path, n, "<" + n->name + "> is compressed as '" + it->second + "', not " + kCompressed +
                      " (the only form supported; rewrite the file with NekMesh ...:xml:uncompress)");
  return true;
}

void add_vertex(const std::string& path, const Node* at, Geo& g, long id, double x, double y, double z) {
  if (!std::isfinite(x) || !std::isfinite(y) || !std::isfinite(z))
    fail(path, at, "vertex " + std::to_string(id) + " has a non-finite coordinate");
  g.V[id] = {x, y, z};
}
void add_edge(const std::string& path, const Node* at, Geo& g, long id, long a, long b) {
  for (long v : {a, b})
    if (!g.V.count(v)) fail(path, at, "edge " + std::to_string(id) + " refers to vertex " + std::to_string(v) + " which is not defined");
  g.E[id] = {a, b};
}
void add_face(const std::string& path, const Node* at, Geo& g, long id, const std::vector<long>& edges) {
  for (long e : edges)
    if (!g.E.count(e)) fail(path, at, "face " + std::to_string(id) + " refers to edge " + std::to_string(e) + " which is not defined");
  g.F[id] = edges;
}

void read_vertices(const std::string& path, const Node* sec, Geo& g) {
  if (compressed(path, sec)) {
    for (auto& v : decode_records<Vertex>(sec->text, where(path, sec), "MeshVertex")) add_vertex(path, sec, g, (long)v.id, v.x, v.y, v.z);
    return;
  }
  for (auto& v : sec->kids) {
    auto c = numbers(path, v.get());
    if (c.size() != 3) fail(path, v.get(), "a vertex needs 3 coordinates");
    add_vertex(path, v.get(), g, id_of(path, v.get()), c[0], c[1], c[2]);
  }
}

void read_edges(const std::string& path, const Node* sec, Geo& g) {
  if (compressed(path, sec)) {
    for (auto& e : decode_records<Edge>(sec->text, where(path, sec), "MeshEdge")) add_edge(path, sec, g, (long)e.id, (long)e.v0, (long)e.v1);
    return;
  }
  for (auto& e : sec->kids) {
    auto c = numbers(path, e.get());
    if (c.size() != 2) fail(path, e.get(), "an edge needs 2 vertex IDs");
    add_edge(path, e.get(), g, id_of(path, e.get()), (long)c[0], (long)c[1]);
  }
}

template <int N>
void read_compressed_sides(const std::string& path, const Node* blk, const char* record, std::vector<std::pair<long, std::vector<long>>>& out) {
  for (auto& r : decode_records<Sides<N>>(blk->text, where(path, blk), record)) out.push_back({(long)r.id, std::vector<long>(r.s, r.s + N)});
}

// The children of FACE or ELEMENT: (id, side ids) of each face or element, with its letter.
void read_side_lists(const std::string& path, const Node* sec, int dim, bool element,
                     const std::function<void(const Node*, const std::string&, long, std::vector<long>)>& add) {
  for (auto& k : sec->kids) {
    const Node* n = k.get();
    if (!compressed(path, n)) {
      std::vector<long> sides;
      for (double x : numbers(path, n)) sides.push_back((long)x);
      add(n, n->name, id_of(path, n), std::move(sides));
      continue;
    }
    std::vector<std::pair<long, std::vector<long>>> recs;
    const std::string& L = n->name;
    if (L == "T") read_compressed_sides<3>(path, n, "MeshTri", recs);
    else if (L == "Q") read_compressed_sides<4>(path, n, "MeshQuad", recs);
    else if (element && dim == 3 && L == "A") read_compressed_sides<4>(path, n, "MeshTet", recs);
    else if (element && dim == 3 && L == "P") read_compressed_sides<5>(path, n, "MeshPyr", recs);
    else if (element && dim == 3 && L == "R") read_compressed_sides<5>(path, n, "MeshPrism", recs);
    else if (element && dim == 3 && L == "H") read_compressed_sides<6>(path, n, "MeshHex", recs);
    else fail(path, n, "compressed <" + L + "> in <" + sec->name + "> is not supported (T, Q; A, P, R, H)");
    for (auto& [id, sides] : recs) add(n, L, id, std::move(sides));
  }
}

// Nektar++'s point set of a compressed curve, by name
std::string points_name(const std::string& path, const Node* at, std::int64_t ptype, bool face) {
  switch (ptype) {
    case kPolyEvenlySpaced: return "PolyEvenlySpaced";
    case kGaussLobattoLegendre: return "GaussLobattoLegendre";
    case kNodalTriElec: return "NodalTriElec";
    case kNodalTriEvenlySpaced: return "NodalTriEvenlySpaced";
    case kNodalTriEvenlySpacedPre5:
      if (face) return "NodalTriEvenlySpaced";
      break;
  }
  fail(path, at, "curved " + std::string(face ? "face" : "edge") + " with Nektar++ point type " + std::to_string(ptype) +
                     " (supported: " + std::to_string(kPolyEvenlySpaced) + " PolyEvenlySpaced, " + std::to_string(kGaussLobattoLegendre) +
                     " GaussLobattoLegendre, " + std::to_string(kNodalTriElec) + " NodalTriElec, " + std::to_string(kNodalTriEvenlySpaced) +
                     " NodalTriEvenlySpaced)");
}

void add_curve(const std::string& path, Geo& g, bool face, long entity, Geo::Curve c) {
  const Node* at = c.node;
  if (face ? !g.F.count(entity) : !g.E.count(entity))
    fail(path, at, std::string("curved ") + (face ? "face refers to an undefined FACEID " : "edge refers to an undefined EDGEID ") + std::to_string(entity));
  if ((int)c.xyz.size() != 3 * c.n)
    fail(path, at, "inconsistent counts: NUMPOINTS=" + std::to_string(c.n) + " but " + std::to_string(c.xyz.size()) + " numbers");
  if (!face) g.order = std::max(g.order, c.n - 1);
  (face ? g.CF : g.CE)[entity] = std::move(c);
}

void read_compressed_curves(const std::string& path, const Node* sec, Geo& g) {
  std::vector<std::int64_t> index;
  std::vector<Vertex> pts;
  bool have_points = false;
  for (auto& k : sec->kids)
    if (k->name == "DATAPOINTS") {
      const Node* ix = k->child("INDEX");
      const Node* ps = k->child("POINTS");
      if (!ix || !ps) fail(path, k.get(), "<DATAPOINTS> needs <INDEX> and <POINTS>");
      index = decode_records<std::int64_t>(ix->text, where(path, ix), "index (int64)");
      pts = decode_records<Vertex>(ps->text, where(path, ps), "MeshVertex");
      have_points = true;
    }
  for (auto& k : sec->kids) {
    const Node* n = k.get();
    if (n->name == "DATAPOINTS") continue;
    if (n->name != "E" && n->name != "F") fail(path, n, "unknown <" + n->name + "> in a compressed <CURVED> (E, F, DATAPOINTS)");
    if (!have_points) fail(path, sec, "compressed <CURVED> without <DATAPOINTS>");
    const bool face = n->name == "F";
    for (auto& ci : decode_records<CurvedInfo>(n->text, where(path, n), "MeshCurvedInfo")) {
      if (ci.npoints < 0 || ci.ptoffset < 0 || (std::uint64_t)(ci.ptoffset + ci.npoints) > index.size())
        fail(path, n, "curved " + std::string(face ? "face " : "edge ") + std::to_string(ci.entityid) + ": points " +
                          std::to_string(ci.ptoffset) + " + " + std::to_string(ci.npoints) + " reach past the " +
                          std::to_string(index.size()) + " entries of <INDEX>");
      Geo::Curve c;
      c.type = points_name(path, n, ci.ptype, face);
      c.n = (int)ci.npoints;
      c.node = n;
      for (std::int64_t j = 0; j < ci.npoints; ++j) {
        const std::int64_t q = index[ci.ptoffset + j];
        if (q < 0 || (std::uint64_t)q >= pts.size())
          fail(path, n, "curved entity " + std::to_string(ci.entityid) + " refers to point " + std::to_string(q) + " of " +
                            std::to_string(pts.size()) + " in <POINTS>");
        const Vertex& p = pts[q];
        if (!std::isfinite(p.x) || !std::isfinite(p.y) || !std::isfinite(p.z))
          fail(path, n, "curved entity " + std::to_string(ci.entityid) + " has a non-finite point");
        c.xyz.insert(c.xyz.end(), {p.x, p.y, p.z});
      }
      add_curve(path, g, face, (long)ci.entityid, std::move(c));
    }
  }
}

void read_curves(const std::string& path, const Node* sec, Geo& g) {
  if (compressed(path, sec)) return read_compressed_curves(path, sec, g);
  for (auto& k : sec->kids) {
    if (k->name != "E" && k->name != "F") continue;
    Geo::Curve c;
    c.type = k->attr.count("TYPE") ? k->attr.at("TYPE") : "";
    c.n = k->attr.count("NUMPOINTS") ? std::atoi(k->attr.at("NUMPOINTS").c_str()) : 0;
    c.xyz = numbers(path, k.get());
    c.node = k.get();
    const bool face = k->name == "F";
    const char* key = face ? "FACEID" : "EDGEID";
    add_curve(path, g, face, std::atol(k->attr.count(key) ? k->attr.at(key).c_str() : "-1"), std::move(c));
  }
}

}  // namespace

Geo read_sections(const std::string& path, const Node* geo, int dim) {
  Geo g;
  auto need = [&](const char* n) {
    const Node* x = geo->child(n);
    if (!x) fail(path, geo, std::string("no <") + n + "> in <GEOMETRY>");
    return x;
  };
  read_vertices(path, need("VERTEX"), g);
  read_edges(path, need("EDGE"), g);
  if (dim == 3)
    read_side_lists(path, need("FACE"), dim, false, [&](const Node* at, const std::string& L, long id, std::vector<long> edges) {
      if (L != "T" && L != "Q") fail(path, at, "face type <" + L + "> not supported (T, Q)");
      if (edges.size() != (L == "T" ? 3u : 4u)) fail(path, at, "a face <" + L + "> needs " + (L == "T" ? "3" : "4") + " edge IDs");
      add_face(path, at, g, id, edges);
    });
  if (const Node* cv = geo->child("CURVED")) read_curves(path, cv, g);
  read_side_lists(path, need("ELEMENT"), dim, true, [&](const Node* at, const std::string& L, long id, std::vector<long> sides) {
    g.elements.push_back({id, L, std::move(sides), at});
  });
  return g;
}

}  // namespace meshflow::io::nektar
