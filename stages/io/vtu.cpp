// VTU (VTK XML UnstructuredGrid) writer with appended raw binary data and VTK Lagrange cells,
// and a reader for the files it writes (appended raw, UInt64 headers). Node orderings from
// model::vtk_to_gmsh (checked against VTK's own cells in tests/io).
#include "stages/io/mesh_io.hpp"
#include "stages/io/reader.hpp"
#include "stages/model/quality.hpp"

#include <cstdio>
#include <cstring>
#include <fstream>
#include <map>
#include <functional>
#include <set>
#include <tuple>

namespace meshflow::io {

using namespace model;

namespace {
// One appended array as the file holds it: its byte count (UInt64), then its bytes.
template <class T>
void write_appended(std::ofstream& f, const std::vector<T>& v) {
  const std::uint64_t n = v.size() * sizeof(T);
  f.write(reinterpret_cast<const char*>(&n), 8);
  f.write(reinterpret_cast<const char*>(v.data()), static_cast<std::streamsize>(n));
}
std::string attr(const std::string& tag, const std::string& name) {
  auto p = tag.find(" " + name + "=\"");
  if (p == std::string::npos) return {};
  p += name.size() + 3;
  return tag.substr(p, tag.find('"', p) - p);
}
}  // namespace

void write_vtu(const Mesh& m, const std::filesystem::path& path, const MeshQuality* stored) {
  m.check();
  MeshQuality computed;
  if (!stored) computed = mesh_quality(m);
  const MeshQuality& quality = stored ? *stored : computed;
  if (quality.size() != m.blocks.size())
    throw MeshIOError(path.string() + ": the quality given for the cell fields has " + std::to_string(quality.size()) +
                      " blocks, the mesh " + std::to_string(m.blocks.size()));
  std::vector<double> pts(3 * m.num_nodes());
  for (size_t i = 0; i < m.num_nodes(); ++i) pts[3 * i] = m.x[i], pts[3 * i + 1] = m.y[i], pts[3 * i + 2] = m.z[i];
  std::vector<std::int64_t> conn, offs;
  std::vector<std::uint8_t> types, valid;
  std::vector<std::int32_t> gtype, edim, etag, phys, order;
  std::vector<double> sj;
  std::set<std::int32_t> linearised;  // VTK cell types written with their vertices only
  {  // sized before they are filled (a doubling vector holds both copies while it moves)
    std::size_t cells = 0, nconn = 0;
    for (const auto& b : m.blocks)
      cells += b.size(), nconn += b.size() * std::size_t(vtk_cell_type(b.shape, b.order) ? b.nodes_per_element() : 5);
    conn.reserve(nconn);
    offs.reserve(cells), types.reserve(cells), valid.reserve(cells), sj.reserve(cells);
    gtype.reserve(cells), edim.reserve(cells), etag.reserve(cells), phys.reserve(cells), order.reserve(cells);
  }
  for (size_t bi = 0; bi < m.blocks.size(); ++bi) {
    const auto& b = m.blocks[bi];
    int vt = vtk_cell_type(b.shape, b.order);
    const std::vector<int>* perm = vt ? &vtk_to_gmsh(b.shape, b.order) : nullptr;
    // Pyramid of order >= 3: VTK has no such cell (VTK_LAGRANGE_PYRAMID, 74, is only a reserved
    // number: VTK 9.1's reader keeps the type but GetCell gives no cell for it), so its vertices
    // only, named in the file's FieldData: meshflow_linearised_cells lists the VTK cell types
    // these cells would have had (74, VTK_LAGRANGE_PYRAMID). Numbers, not a String array:
    // meshio 5 refuses a VTU with a String array ("Illegal data type 'String'").
    if (!vt) vt = 14, linearised.insert(74);
    // File version 1.0 (meshio 5 reads only 0.1/1.0): Lagrange hexahedra are then stored in
    // VTK's legacy order (vertical edges of vertices 2 and 3 swapped), which VTK >= 9.1
    // converts on reading (it does so for every file of version < 2.2) and VTK 9.0 reads as is.
    const bool legacy_hex = vt == 72 && b.order >= 2;
    const Entity* ent = m.find_entity(b.entity_dim, b.entity_tag);
    const int ph = ent && !ent->physicals.empty() ? ent->physicals[0] : 0;
    for (size_t e = 0; e < b.size(); ++e) {
      const std::uint32_t* nd = b.element(e);
      if (perm && legacy_hex) {  // see the file version note below
        const int pm1 = b.order - 1, vbase = 8 + 8 * pm1;
        for (int k = 0; k < (int)perm->size(); ++k) {
          int src = k;
          if (k >= vbase + 2 * pm1 && k < vbase + 4 * pm1) src = k < vbase + 3 * pm1 ? k + pm1 : k - pm1;
          conn.push_back(nd[(*perm)[src]]);
        }
      } else if (perm)
        for (int k : *perm) conn.push_back(nd[k]);
      else
        for (int k = 0; k < 5; ++k) conn.push_back(nd[k]);
      offs.push_back((std::int64_t)conn.size());
      types.push_back((std::uint8_t)vt);
      gtype.push_back(gmsh_type(b.shape, b.order));
      edim.push_back(b.entity_dim), etag.push_back(b.entity_tag), phys.push_back(ph), order.push_back(b.order);
      const bool q = !quality[bi].empty();
      if (q && quality[bi].size() != b.size())
        throw MeshIOError(path.string() + ": the quality given for block " + std::to_string(bi) + " has " +
                          std::to_string(quality[bi].size()) + " elements, the block " + std::to_string(b.size()));
      sj.push_back(q ? quality[bi][e].scaled_jacobian : 1.0);
      valid.push_back(q ? quality[bi][e].valid : 1);
    }
  }
  // The header names each array's offset in the appended data (its byte count and bytes, in
  // order), known from the sizes alone: the header is written first, then each array straight
  // from its vector (an appended-data string held a second copy of the whole file)
  std::string head;
  size_t off = 0;
  std::vector<std::function<void(std::ofstream&)>> appended;
  auto add = [&](const auto& v) {
    appended.push_back([&v](std::ofstream& f) { write_appended(f, v); });
    off += 8 + v.size() * sizeof(v[0]);
  };
  auto arr = [&](const char* type, const char* name, int comps, auto& v) {
    head += std::string("        <DataArray type=\"") + type + "\"" + (name ? std::string(" Name=\"") + name + "\"" : "") +
            (comps > 1 ? " NumberOfComponents=\"" + std::to_string(comps) + "\"" : "") +
            " format=\"appended\" offset=\"" + std::to_string(off) + "\"/>\n";
    add(v);
  };
  head += "<?xml version=\"1.0\"?>\n<VTKFile type=\"UnstructuredGrid\" version=\"1.0\" byte_order=\"LittleEndian\" header_type=\"UInt64\">\n";
  head += "  <UnstructuredGrid>\n";
  const std::vector<std::int32_t> types_linearised(linearised.begin(), linearised.end());
  if (!linearised.empty()) {
    head += "    <FieldData>\n        <DataArray type=\"Int32\" Name=\"meshflow_linearised_cells\" NumberOfTuples=\"" +
            std::to_string(types_linearised.size()) + "\" format=\"appended\" offset=\"" + std::to_string(off) + "\"/>\n    </FieldData>\n";
    add(types_linearised);
  }
  head += "    <Piece NumberOfPoints=\"" + std::to_string(m.num_nodes()) + "\" NumberOfCells=\"" +
          std::to_string(types.size()) + "\">\n      <Points>\n";
  arr("Float64", "Points", 3, pts);
  head += "      </Points>\n      <Cells>\n";
  arr("Int64", "connectivity", 1, conn);
  arr("Int64", "offsets", 1, offs);
  arr("UInt8", "types", 1, types);
  head += "      </Cells>\n      <CellData Scalars=\"scaled_jacobian\">\n";
  arr("Int32", "gmsh_type", 1, gtype);
  arr("Int32", "order", 1, order);
  arr("Int32", "entity_dim", 1, edim);
  arr("Int32", "entity_tag", 1, etag);
  arr("Int32", "physical", 1, phys);
  arr("Float64", "scaled_jacobian", 1, sj);
  arr("UInt8", "valid", 1, valid);
  head += "      </CellData>\n    </Piece>\n  </UnstructuredGrid>\n  <AppendedData encoding=\"raw\">\n   _";
  std::ofstream f(path, std::ios::binary);
  if (!f) throw MeshIOError(path.string() + ": cannot open the file for writing");
  f << head;
  for (auto& w : appended) w(f);
  f << "\n  </AppendedData>\n</VTKFile>\n";
  if (!f) throw MeshIOError(path.string() + ": write failed (disk full?)");
}

Mesh read_vtu(const std::filesystem::path& path) {
  const std::string d = detail::slurp(path);
  detail::Cursor c(path.string(), d);
  if (d.find("<VTKFile") == std::string::npos || d.find("UnstructuredGrid") == std::string::npos)
    c.fail("not a VTK XML UnstructuredGrid file (no <VTKFile type=\"UnstructuredGrid\">)", false, 0);
  size_t app = d.find("<AppendedData");
  if (app == std::string::npos) c.fail("only VTU files with appended raw data (as meshflow writes them) can be read", false, 0);
  if (d.find("header_type=\"UInt64\"") == std::string::npos || d.find("encoding=\"raw\"") == std::string::npos ||
      d.find("compressor=") < app)
    c.fail("only uncompressed appended raw VTU with UInt64 headers can be read", false, 0);
  size_t base = d.find('_', app);
  if (base == std::string::npos) c.fail("AppendedData has no '_' marker", false, app);
  ++base;
  std::map<std::string, std::pair<std::string, size_t>> arrays;  // name -> (type, offset)
  std::string piece;
  for (size_t p = d.find("<DataArray"); p != std::string::npos && p < app; p = d.find("<DataArray", p + 1)) {
    std::string tag = d.substr(p, d.find('>', p) - p);
    if (attr(tag, "format") != "appended") c.fail("DataArray not in appended format", false, p);
    // The offset must be a plain decimal (std::stoull would throw on garbage; found by fuzzing).
    std::string off = attr(tag, "offset");
    if (off.empty()) off = "0";
    if (off.size() > 19 || off.find_first_not_of("0123456789") != std::string::npos)
      c.fail("DataArray " + attr(tag, "Name") + " has offset \"" + off.substr(0, 40) + "\", not a byte offset", false, p);
    arrays[attr(tag, "Name")] = {attr(tag, "type"), size_t(std::stoull(off))};
  }
  auto get = [&](const std::string& name, const std::string& type, size_t elem) -> std::pair<const char*, size_t> {
    auto it = arrays.find(name);
    if (it == arrays.end()) c.fail("missing DataArray " + name, false, 0);
    if (it->second.first != type) c.fail("DataArray " + name + " has type " + it->second.first + ", expected " + type, false, 0);
    size_t at = base + it->second.second;
    if (at + 8 > d.size()) c.fail("DataArray " + name + " lies past the end of the file (truncated?)", true, at);
    std::uint64_t n;
    std::memcpy(&n, d.data() + at, 8);
    if (at + 8 + n > d.size() || n % elem) c.fail("DataArray " + name + " is truncated or has a bad size", true, at);
    return {d.data() + at + 8, n / elem};
  };
  auto [pp, np3] = get("Points", "Float64", 8);
  auto [cp, nc] = get("connectivity", "Int64", 8);
  auto [op, no] = get("offsets", "Int64", 8);
  auto [tp, nt] = get("types", "UInt8", 1);
  if (np3 % 3) c.fail("Points size is not a multiple of 3", false, 0);
  if (no != nt) c.fail("inconsistent counts: " + std::to_string(no) + " offsets for " + std::to_string(nt) + " cell types", false, 0);
  Mesh m;
  const size_t nn = np3 / 3;
  m.x.resize(nn), m.y.resize(nn), m.z.resize(nn);
  for (size_t i = 0; i < nn; ++i) {
    double p[3];
    std::memcpy(p, pp + 24 * i, 24);
    if (!std::isfinite(p[0]) || !std::isfinite(p[1]) || !std::isfinite(p[2]))
      c.fail("point " + std::to_string(i) + " has a non-finite coordinate", true, (pp - d.data()) + 24 * i);
    m.x[i] = p[0], m.y[i] = p[1], m.z[i] = p[2];
  }
  std::vector<std::int32_t> edim(nt, -1), etag(nt, 0), phys(nt, 0);
  for (auto [name, vec] : {std::pair<const char*, std::vector<std::int32_t>*>{"entity_dim", &edim}, {"entity_tag", &etag}, {"physical", &phys}})
    if (arrays.count(name)) {
      auto [q, n] = get(name, "Int32", 4);
      if (n != nt) c.fail(std::string("inconsistent counts in cell data ") + name, false, 0);
      std::memcpy(vec->data(), q, 4 * n);
    }
  // VTK XML files before version 2.2 used the legacy Lagrange hexahedron order, in which
  // the vertical edges of vertices 2 and 3 come in the other order (VTK 9.1's reader converts
  // those files the same way; we write 2.2).
  bool legacy_hex = false;
  {
    size_t vf = d.find("<VTKFile");
    std::string tag = d.substr(vf, d.find('>', vf) - vf);
    std::string ver = attr(tag, "version");
    int major = 0, minor = 0;
    if (!ver.empty() && std::sscanf(ver.c_str(), "%d.%d", &major, &minor) >= 1)
      legacy_hex = major < 2 || (major == 2 && minor < 2);
  }
  std::map<std::tuple<int, int, int, int>, size_t> block_of;
  std::int64_t prev = 0;
  for (size_t e = 0; e < nt; ++e) {
    std::int64_t end;
    std::memcpy(&end, op + 8 * e, 8);
    if (end < prev || (std::uint64_t)end > nc) c.fail("cell " + std::to_string(e) + " has an offset out of range", true, (op - d.data()) + 8 * e);
    Shape s;
    int order;
    const int vt = (std::uint8_t)tp[e];
    if (!from_vtk_cell_type(vt, (int)(end - prev), s, order))
      c.fail("cell " + std::to_string(e) + ": unsupported VTK cell type " + std::to_string(vt) + " with " +
             std::to_string(end - prev) + " points", true, (tp - d.data()) + e);
    const int dim = edim[e] >= 0 ? edim[e] : dimension(s);
    auto key = std::make_tuple(dim, (int)etag[e], (int)s, order);
    auto it = block_of.find(key);
    if (it == block_of.end()) {
      it = block_of.emplace(key, m.blocks.size()).first;
      ElementBlock b;
      b.shape = s, b.order = order, b.entity_dim = dim, b.entity_tag = etag[e];
      m.blocks.push_back(b);
      if (phys[e]) m.add_entity(dim, etag[e], {phys[e]});
    }
    auto& b = m.blocks[it->second];
    // a VTK_LAGRANGE_WEDGE of 6 points is a wedge in Gmsh's orientation, unlike VTK_WEDGE
    static const std::vector<int> lagrange_wedge1 = {0, 1, 2, 3, 4, 5};
    const auto& perm = vt == 73 && order == 1 ? lagrange_wedge1 : vtk_to_gmsh(s, order);
    std::vector<std::uint32_t> nodes(b.nodes_per_element(), 0xffffffffu);
    const int pm1 = order - 1, vbase = 8 + 8 * pm1;  // first vertical-edge node (VTK order)
    const bool swap_edges = legacy_hex && vt == 72 && order >= 2;
    for (size_t k = 0; k < perm.size(); ++k) {
      std::int64_t id;
      size_t src = k;
      if (swap_edges && (int)k >= vbase + 2 * pm1 && (int)k < vbase + 4 * pm1)
        src = (int)k < vbase + 3 * pm1 ? k + pm1 : k - pm1;
      std::memcpy(&id, cp + 8 * (prev + src), 8);
      if (id < 0 || (std::uint64_t)id >= nn)
        c.fail("cell " + std::to_string(e) + " refers to point " + std::to_string(id) + " (out of range)", true, (cp - d.data()) + 8 * (prev + k));
      nodes[perm[k]] = (std::uint32_t)id;
    }
    if (perm.size() != nodes.size())  // quadratic pyramid: VTK has no base-centre node
      c.fail("cell " + std::to_string(e) + ": a VTK quadratic pyramid cannot be read back losslessly", true, 0);
    b.add(nodes.data());
    prev = end;
  }
  try {
    m.check();
  } catch (const std::invalid_argument& e) {
    throw MeshIOError(path.string() + ": " + e.what());
  }
  return m;
}

}  // namespace meshflow::io
