// CGNS (CFD General Notation System) through libcgns 3.4 (Debian's libcgns-dev), written as
// CGNS/ADF (byte-identical files, see fix_adf_dates; libcgns reads ADF and HDF5 alike): what FLEXI's
// HOPR, SU2 and most CFD tools read. What is written (see mesh_io.hpp for the summary):
//   Base "Base" (cell dimension = the mesh's, physical dimension 3)
//   └ Zone "Zone" (Unstructured; a zone may not share its name with the family beside it)
//     ├ GridCoordinates: CoordinateX/Y/Z, RealDouble, every node of the mesh in its order
//     ├ one Elements_t section per volume shape and order (TETRA_35, PENTA_75, ...), then one
//     │ per boundary group and shape (TRI_15, QUAD_25, ...), element numbers consecutive
//     ├ ZoneBC: one BC_t per boundary group: PointRange over its sections' ElementRange,
//     │ GridLocation FaceCenter (EdgeCenter in 2D), BCType FamilySpecified, FamilyName = the group
//     └ FamilyName: the volume's group (when it has exactly one)
//   Family_t per group (FamilyBC for boundary groups: BCType from the group's name).
// Nodes are permuted between Gmsh's ordering (the model's) and CGNS's (cgns_layout.hpp).
// No DimensionalUnits: the mesh model carries no length unit, so none is claimed; the base's
// DataClass is NormalizedByUnknownDimensional (lengths in a unit the file does not state).
// Elements of lower dimension than the boundary (CAD curves' edges, points) are not written.
#include "stages/io/cgns_layout.hpp"
#include "stages/io/mesh_io.hpp"

#include <cgnslib.h>

#include <algorithm>
#include <climits>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <ctime>
#include <fstream>
#include <map>
#include <set>

#include <unistd.h>

#if CGNS_VERSION < 3400
#error "meshflow needs libcgns 3.4 or newer (the quartic element types)"
#endif

namespace meshflow::io {

using model::ElementBlock;
using model::Mesh;
using model::Shape;

namespace {

// ---- element types ----

struct TypeRow {
  Shape shape;
  int order;
  CGNS_ENUMT(ElementType_t) type;
};
constexpr TypeRow kTypes[] = {
    {Shape::Point, 1, CGNS_ENUMV(NODE)},
    {Shape::Line, 1, CGNS_ENUMV(BAR_2)},      {Shape::Line, 2, CGNS_ENUMV(BAR_3)},
    {Shape::Line, 3, CGNS_ENUMV(BAR_4)},      {Shape::Line, 4, CGNS_ENUMV(BAR_5)},
    {Shape::Tri, 1, CGNS_ENUMV(TRI_3)},       {Shape::Tri, 2, CGNS_ENUMV(TRI_6)},
    {Shape::Tri, 3, CGNS_ENUMV(TRI_10)},      {Shape::Tri, 4, CGNS_ENUMV(TRI_15)},
    {Shape::Quad, 1, CGNS_ENUMV(QUAD_4)},     {Shape::Quad, 2, CGNS_ENUMV(QUAD_9)},
    {Shape::Quad, 3, CGNS_ENUMV(QUAD_16)},    {Shape::Quad, 4, CGNS_ENUMV(QUAD_25)},
    {Shape::Tet, 1, CGNS_ENUMV(TETRA_4)},     {Shape::Tet, 2, CGNS_ENUMV(TETRA_10)},
    {Shape::Tet, 3, CGNS_ENUMV(TETRA_20)},    {Shape::Tet, 4, CGNS_ENUMV(TETRA_35)},
    {Shape::Pyramid, 1, CGNS_ENUMV(PYRA_5)},  {Shape::Pyramid, 2, CGNS_ENUMV(PYRA_14)},
    {Shape::Pyramid, 3, CGNS_ENUMV(PYRA_30)}, {Shape::Pyramid, 4, CGNS_ENUMV(PYRA_55)},
    {Shape::Prism, 1, CGNS_ENUMV(PENTA_6)},   {Shape::Prism, 2, CGNS_ENUMV(PENTA_18)},
    {Shape::Prism, 3, CGNS_ENUMV(PENTA_40)},  {Shape::Prism, 4, CGNS_ENUMV(PENTA_75)},
    {Shape::Hex, 1, CGNS_ENUMV(HEXA_8)},      {Shape::Hex, 2, CGNS_ENUMV(HEXA_27)},
    {Shape::Hex, 3, CGNS_ENUMV(HEXA_64)},     {Shape::Hex, 4, CGNS_ENUMV(HEXA_125)},
};

CGNS_ENUMT(ElementType_t) cgns_type(Shape s, int order) {
  for (auto& r : kTypes)
    if (r.shape == s && r.order == order) return r.type;
  return CGNS_ENUMV(ElementTypeNull);
}
bool from_cgns_type(CGNS_ENUMT(ElementType_t) t, Shape& s, int& order) {
  for (auto& r : kTypes)
    if (r.type == t) return s = r.shape, order = r.order, true;
  return false;
}
std::string type_name(CGNS_ENUMT(ElementType_t) t) {
  const char* n = cg_ElementTypeName(t);
  return n ? n : "type " + std::to_string(static_cast<int>(t));
}

// BCType from a boundary group's name: wall-like, farfield, symmetry, inflow/outflow; others
// (periodic_lo/hi, named parts) are user-defined, their meaning carried by the family's name.
CGNS_ENUMT(BCType_t) bc_type(const std::string& name) {
  std::string n = name;
  for (auto& c : n) c = (char)std::tolower((unsigned char)c);
  if (n.find("wall") != std::string::npos) return CGNS_ENUMV(BCWall);
  if (n.find("farfield") != std::string::npos || n == "far_field" || n == "freestream") return CGNS_ENUMV(BCFarfield);
  if (n.rfind("symmetry", 0) == 0) return CGNS_ENUMV(BCSymmetryPlane);
  if (n.rfind("inlet", 0) == 0 || n.rfind("inflow", 0) == 0) return CGNS_ENUMV(BCInflow);
  if (n.rfind("outlet", 0) == 0 || n.rfind("outflow", 0) == 0) return CGNS_ENUMV(BCOutflow);
  return CGNS_ENUMV(BCTypeUserDefined);
}

// ---- libcgns calls ----

void ok(int rc, const std::filesystem::path& p, const std::string& what) {
  if (rc != CG_OK) throw MeshIOError(p.string() + ": CGNS: " + what + " failed: " + cg_get_error());
}

// An open CGNS file, closed on scope exit (also when an exception leaves the scope).
struct CgFile {
  int fn = -1;
  CgFile(const std::filesystem::path& p, int mode) {
    if (cg_open(p.c_str(), mode, &fn) != CG_OK) {
      fn = -1;
      throw MeshIOError(p.string() + ": cannot open as CGNS (" + cg_get_error() + ")" +
                        (mode == CG_MODE_READ ? "" : ": check that the folder exists and is writable"));
    }
  }
  ~CgFile() {
    if (fn >= 0) cg_close(fn);
  }
  void close(const std::filesystem::path& p) {
    const int f = fn;
    fn = -1;
    ok(cg_close(f), p, "closing the file");
  }
  CgFile(const CgFile&) = delete;
  CgFile& operator=(const CgFile&) = delete;
};

constexpr std::size_t kMaxCg = static_cast<std::size_t>(INT32_MAX);  // cgsize_t is 32-bit in Debian's libcgns

// ---- writing ----

std::string group_of(const Mesh& m, const ElementBlock& b) {
  std::string g = m.group_name(b.entity_dim, b.entity_tag);
  return g.empty() ? "surface_" + std::to_string(b.entity_tag) : g;
}

// Blocks of one (shape, order), written as one section.
struct Section {
  std::string name;
  Shape shape;
  int order;
  std::vector<const ElementBlock*> blocks;
  std::size_t size() const {
    std::size_t n = 0;
    for (auto* b : blocks) n += b->size();
    return n;
  }
};

// The cells' sections: one per (shape, order), in Shape then order order.
std::vector<Section> cell_sections(const Mesh& m, int dim) {
  std::map<std::pair<int, int>, Section> by;
  for (auto& b : m.blocks)
    if (b.size() && model::dimension(b.shape) == dim) {
      auto& s = by[{static_cast<int>(b.shape), b.order}];
      s.shape = b.shape, s.order = b.order, s.blocks.push_back(&b);
    }
  std::vector<Section> out;
  for (auto& [k, s] : by) {
    s.name = type_name(cgns_type(s.shape, s.order));
    out.push_back(std::move(s));
  }
  return out;
}

// The boundary groups (by name, sorted), each a list of sections (one per shape and order).
std::map<std::string, std::vector<Section>> boundary_sections(const Mesh& m, int dim) {
  std::map<std::string, std::map<std::pair<int, int>, Section>> by;
  for (auto& b : m.blocks)
    if (b.size() && model::dimension(b.shape) == dim - 1) {
      auto& s = by[group_of(m, b)][{static_cast<int>(b.shape), b.order}];
      s.shape = b.shape, s.order = b.order, s.blocks.push_back(&b);
    }
  std::map<std::string, std::vector<Section>> out;
  for (auto& [g, secs] : by) {
    for (auto& [k, s] : secs) {
      s.name = secs.size() == 1 ? g : g + "_" + model::shape_name(s.shape) + std::to_string(s.order);
      out[g].push_back(std::move(s));
    }
  }
  return out;
}

void check_writable(const Mesh& m, const std::filesystem::path& path, int dim) {
  if (dim < 2) throw MeshIOError(path.string() + ": CGNS output needs a 2D or 3D mesh (this one has no cells)");
  for (auto& b : m.blocks) {
    if (!b.size() || model::dimension(b.shape) < dim - 1) continue;
    if (b.order > detail::kCgnsMaxOrder)
      throw MeshIOError(path.string() + ": CGNS has no element type for a " + model::shape_name(b.shape) + " of order " +
                        std::to_string(b.order) + " (CGNS 3.4 stops at quartic: use order 4 or less, or write .msh/.vtu/.xml)");
    if (b.nodes.size() > kMaxCg)
      throw MeshIOError(path.string() + ": a block of " + std::to_string(b.size()) + " elements is too large for libcgns's 32-bit sizes");
  }
  if (m.num_nodes() > kMaxCg || m.num_elements() > kMaxCg)
    throw MeshIOError(path.string() + ": too many nodes or elements for libcgns's 32-bit sizes");
  for (auto& [g, secs] : boundary_sections(m, dim))
    for (auto& s : secs)
      if (s.name.size() > 32 || g.size() > 32)
        throw MeshIOError(path.string() + ": CGNS names are at most 32 characters; boundary group '" + g +
                          "' is longer: rename it (heal.tag_overrides)");
}

// Coordinates, each with DimensionalExponents "length" (the unit itself is unknown).
void write_coordinates(int fn, int B, int Z, const Mesh& m, const std::filesystem::path& p) {
  const std::pair<const char*, const std::vector<double>*> xyz[3] = {{"CoordinateX", &m.x}, {"CoordinateY", &m.y}, {"CoordinateZ", &m.z}};
  const double length[5] = {0, 1, 0, 0, 0};  // mass, length, time, temperature, angle
  for (auto [name, v] : xyz) {
    int C = 0;
    ok(cg_coord_write(fn, B, Z, CGNS_ENUMV(RealDouble), name, v->data(), &C), p, std::string("writing ") + name);
    ok(cg_goto(fn, B, "Zone_t", Z, "GridCoordinates_t", 1, "DataArray_t", C, "end"), p, std::string("going to ") + name);
    ok(cg_exponents_write(CGNS_ENUMV(RealDouble), length), p, std::string("writing the exponents of ") + name);
  }
}

// Writes one section as elements first .. first + size - 1; returns the next free number.
cgsize_t write_section(int fn, int B, int Z, const Section& s, cgsize_t first, const std::filesystem::path& p) {
  const auto& perm = detail::cgns_to_gmsh(s.shape, s.order);
  const int npe = model::num_nodes(s.shape, s.order);
  if (s.size() * npe > kMaxCg)
    throw MeshIOError(p.string() + ": section " + s.name + " of " + std::to_string(s.size()) +
                      " elements is too large for libcgns's 32-bit sizes");
  std::vector<cgsize_t> conn;
  conn.reserve(s.size() * npe);
  for (auto* b : s.blocks)
    for (std::size_t e = 0; e < b->size(); ++e) {
      const std::uint32_t* nd = b->element(e);
      for (int i = 0; i < npe; ++i) conn.push_back(static_cast<cgsize_t>(nd[perm[i]]) + 1);
    }
  const cgsize_t last = first + static_cast<cgsize_t>(s.size()) - 1;
  int S = 0;
  ok(cg_section_write(fn, B, Z, s.name.c_str(), cgns_type(s.shape, s.order), first, last, 0, conn.data(), &S), p,
     "writing section " + s.name);
  return last + 1;
}

void write_boundary_group(int fn, int B, int Z, int dim, const std::string& g, cgsize_t first, cgsize_t last,
                          const std::filesystem::path& p) {
  const auto t = bc_type(g);
  int F = 0, FBC = 0, BC = 0;
  ok(cg_family_write(fn, B, g.c_str(), &F), p, "writing family " + g);
  ok(cg_fambc_write(fn, B, F, "FamBC", t, &FBC), p, "writing FamilyBC of " + g);
  const cgsize_t range[2] = {first, last};
  // FamilySpecified: the type lives on the family alone, as the SIDS recommends; VTK's CGNS
  // reader (ParaView) skips a BC_t of type BCFarfield or BCSymmetryPlane but reads these.
  ok(cg_boco_write(fn, B, Z, g.c_str(), CGNS_ENUMV(FamilySpecified), CGNS_ENUMV(PointRange), 2, range, &BC),
     p, "writing BC " + g);
  ok(cg_boco_gridlocation_write(fn, B, Z, BC, dim == 3 ? CGNS_ENUMV(FaceCenter) : CGNS_ENUMV(EdgeCenter)), p,
     "writing the GridLocation of BC " + g);
  ok(cg_goto(fn, B, "Zone_t", Z, "ZoneBC_t", 1, "BC_t", BC, "end"), p, "going to BC " + g);
  ok(cg_famname_write(g.c_str()), p, "writing the FamilyName of BC " + g);
}

// The volume's physical group when every cell is in exactly that one ("" otherwise).
std::string volume_group(const Mesh& m, int dim) {
  std::set<std::string> names;
  for (auto& b : m.blocks)
    if (b.size() && model::dimension(b.shape) == dim) names.insert(m.group_name(b.entity_dim, b.entity_tag));
  return names.size() == 1 && !names.begin()->empty() && names.begin()->size() <= 32 ? *names.begin() : "";
}

// CGNS/ADF's header holds the file's creation and modification times (asctime text after the
// markers "AdF0" and "AdF1"): both are set to SOURCE_DATE_EPOCH (or 1970-01-01), so that the
// same mesh gives the same bytes. (CGNS/HDF5 is not used: libcgns 3.4 leaves HDF5's object
// time stamps on, and two writes a second apart differed in 956 bytes.)
void fix_adf_dates(const std::filesystem::path& p) {
  std::fstream f(p, std::ios::in | std::ios::out | std::ios::binary);
  char head[96] = {0};
  f.read(head, sizeof head);
  if (!f || std::memcmp(head + 4, "ADF Database Version", 20) != 0 || std::memcmp(head + 32, "AdF0", 4) != 0 || std::memcmp(head + 64, "AdF1", 4) != 0)
    throw MeshIOError(p.string() + ": libcgns wrote an ADF header of an unexpected layout (no AdF0/AdF1 date fields)");
  const char* env = std::getenv("SOURCE_DATE_EPOCH");
  const std::time_t t = env ? static_cast<std::time_t>(std::strtoll(env, nullptr, 10)) : 0;
  std::tm tm{};
  gmtime_r(&t, &tm);
  char date[29];
  std::memset(date, ' ', 28);
  date[28] = 0;
  const std::size_t n = std::strftime(date, sizeof date, "%a %b %e %H:%M:%S %Y", &tm);
  if (n < 28) date[n] = ' ';
  f.seekp(36);
  f.write(date, 28);
  f.seekp(68);
  f.write(date, 28);
  f.close();
  if (!f) throw MeshIOError(p.string() + ": could not set the ADF header's dates");
}

void write_file(const Mesh& m, const std::filesystem::path& tmp, int dim) {
  ok(cg_set_file_type(CG_FILE_ADF), tmp, "choosing CGNS/ADF");
  CgFile f(tmp, CG_MODE_WRITE);
  int B = 0, Z = 0;
  ok(cg_base_write(f.fn, "Base", dim, 3, &B), tmp, "writing the base");
  // The mesh knows no length unit: its data class says so instead of claiming one.
  ok(cg_goto(f.fn, B, "end"), tmp, "going to the base");
  ok(cg_dataclass_write(CGNS_ENUMV(NormalizedByUnknownDimensional)), tmp, "writing the DataClass");
  const auto cells = cell_sections(m, dim);
  const auto bnd = boundary_sections(m, dim);
  std::size_t ncells = 0;
  for (auto& s : cells) ncells += s.size();
  const std::string vol = volume_group(m, dim);
  cgsize_t size[3] = {static_cast<cgsize_t>(m.num_nodes()), static_cast<cgsize_t>(ncells), 0};
  ok(cg_zone_write(f.fn, B, "Zone", size, CGNS_ENUMV(Unstructured), &Z), tmp, "writing the zone");
  write_coordinates(f.fn, B, Z, m, tmp);
  cgsize_t next = 1;
  for (auto& s : cells) next = write_section(f.fn, B, Z, s, next, tmp);
  for (auto& [g, secs] : bnd) {
    const cgsize_t first = next;
    for (auto& s : secs) next = write_section(f.fn, B, Z, s, next, tmp);
    write_boundary_group(f.fn, B, Z, dim, g, first, next - 1, tmp);
  }
  if (!vol.empty()) {
    int F = 0;
    ok(cg_family_write(f.fn, B, vol.c_str(), &F), tmp, "writing family " + vol);
    ok(cg_goto(f.fn, B, "Zone_t", Z, "end"), tmp, "going to the zone");
    ok(cg_famname_write(vol.c_str()), tmp, "writing the zone's FamilyName");
  }
  f.close(tmp);
  fix_adf_dates(tmp);
}

// ---- reading ----

struct ZoneRef {
  int fn, B, Z;
  const std::filesystem::path& p;
};

// Element number -> boundary group name, from the BCs that name element ranges or lists.
std::map<cgsize_t, std::string> bc_names(const ZoneRef& z) {
  std::map<cgsize_t, std::string> out;
  int nb = 0;
  ok(cg_nbocos(z.fn, z.B, z.Z, &nb), z.p, "counting the BCs");
  for (int bc = 1; bc <= nb; ++bc) {
    char name[33] = {0};
    CGNS_ENUMT(BCType_t) type;
    CGNS_ENUMT(PointSetType_t) pst;
    cgsize_t npnts = 0, nlist = 0;
    int nidx = 0, nds = 0;
    CGNS_ENUMT(DataType_t) ndt;
    ok(cg_boco_info(z.fn, z.B, z.Z, bc, name, &type, &pst, &npnts, &nidx, &nlist, &ndt, &nds), z.p, "reading BC info");
    CGNS_ENUMT(GridLocation_t) loc = CGNS_ENUMV(Vertex);
    ok(cg_boco_gridlocation_read(z.fn, z.B, z.Z, bc, &loc), z.p, std::string("reading the GridLocation of BC ") + name);
    const bool elements = pst == CGNS_ENUMV(ElementRange) || pst == CGNS_ENUMV(ElementList) ||
                          ((pst == CGNS_ENUMV(PointRange) || pst == CGNS_ENUMV(PointList)) && loc != CGNS_ENUMV(Vertex));
    if (!elements || npnts <= 0) continue;  // a BC on nodes names no element
    std::vector<cgsize_t> pts(static_cast<std::size_t>(npnts));
    ok(cg_boco_read(z.fn, z.B, z.Z, bc, pts.data(), nullptr), z.p, std::string("reading BC ") + name);
    std::string group = name;
    char fam[33] = {0};
    if (cg_goto(z.fn, z.B, "Zone_t", z.Z, "ZoneBC_t", 1, "BC_t", bc, "end") == CG_OK && cg_famname_read(fam) == CG_OK && fam[0])
      group = fam;
    if (pst == CGNS_ENUMV(PointRange) || pst == CGNS_ENUMV(ElementRange)) {
      if (npnts != 2) throw MeshIOError(z.p.string() + ": BC " + name + ": a range needs 2 values, found " + std::to_string(npnts));
      for (cgsize_t e = pts[0]; e <= pts[1]; ++e) out[e] = group;
    } else {
      for (cgsize_t e : pts) out[e] = group;
    }
  }
  return out;
}

std::vector<double> read_coordinate(const ZoneRef& z, const char* name, cgsize_t n) {
  std::vector<double> v(static_cast<std::size_t>(n));
  cgsize_t lo = 1, hi = n;
  if (n > 0) ok(cg_coord_read(z.fn, z.B, z.Z, name, CGNS_ENUMV(RealDouble), &lo, &hi, v.data()), z.p, std::string("reading ") + name);
  for (double x : v)
    if (!std::isfinite(x)) throw MeshIOError(z.p.string() + ": " + name + " holds a non-finite value");
  return v;
}

// Group name -> physical/entity tag (dimension dim), made on first use.
int group_tag(Mesh& m, std::map<std::string, int>& tags, int dim, const std::string& name) {
  auto it = tags.find(name);
  if (it != tags.end()) return it->second;
  const int t = static_cast<int>(tags.size()) + 1;
  tags[name] = t;
  m.add_physical(dim, t, name);
  m.add_entity(dim, t, {t});
  return t;
}

void read_sections(const ZoneRef& z, Mesh& m, int cell_dim, cgsize_t nvertex) {
  const auto names = bc_names(z);
  std::map<std::string, int> tags;
  int ns = 0;
  ok(cg_nsections(z.fn, z.B, z.Z, &ns), z.p, "counting the sections");
  for (int S = 1; S <= ns; ++S) {
    char sname[33] = {0};
    CGNS_ENUMT(ElementType_t) type;
    cgsize_t start = 0, end = 0, datasize = 0;
    int nbndry = 0, parent = 0;
    ok(cg_section_read(z.fn, z.B, z.Z, S, sname, &type, &start, &end, &nbndry, &parent), z.p, "reading section info");
    Shape shape;
    int order = 0;
    if (!from_cgns_type(type, shape, order))
      throw MeshIOError(z.p.string() + ": section " + sname + ": element type " + type_name(type) +
                        " is not supported (meshflow reads the complete Lagrange types of orders 1-4, one type per section)");
    const int d = model::dimension(shape);
    if (d != cell_dim && d != cell_dim - 1) continue;  // edges and points of a 3D zone: not part of the model
    ok(cg_ElementDataSize(z.fn, z.B, z.Z, S, &datasize), z.p, std::string("sizing section ") + sname);
    const int npe = model::num_nodes(shape, order);
    const cgsize_t count = end - start + 1;
    if (count < 0 || datasize != count * npe)
      throw MeshIOError(z.p.string() + ": section " + sname + ": " + std::to_string(datasize) + " node indices for " +
                        std::to_string(count) + " elements of " + std::to_string(npe) + " nodes (inconsistent counts)");
    std::vector<cgsize_t> conn(static_cast<std::size_t>(datasize));
    if (datasize) ok(cg_elements_read(z.fn, z.B, z.Z, S, conn.data(), nullptr), z.p, std::string("reading section ") + sname);
    const auto& perm = detail::cgns_to_gmsh(shape, order);
    std::vector<std::uint32_t> el(static_cast<std::size_t>(npe));
    ElementBlock* blk = d == cell_dim ? &m.block(shape, order, cell_dim, 1) : nullptr;
    for (cgsize_t e = 0; e < count; ++e) {
      for (int i = 0; i < npe; ++i) {
        const cgsize_t v = conn[static_cast<std::size_t>(e * npe + i)];
        if (v < 1 || v > nvertex)
          throw MeshIOError(z.p.string() + ": section " + sname + ", element " + std::to_string(start + e) + ": node " +
                            std::to_string(v) + " is outside 1.." + std::to_string(nvertex));
        el[perm[i]] = static_cast<std::uint32_t>(v - 1);
      }
      if (!blk) {
        auto it = names.find(start + e);
        const int t = group_tag(m, tags, d, it != names.end() ? it->second : std::string(sname));
        m.block(shape, order, d, t).add(el.data());
      } else {
        blk->add(el.data());
      }
    }
  }
}

// libcgns 3.4 aborts (an assertion in ADF_internals.c) on some damaged ADF files, e.g. a
// truncated one: check the header and that the file reaches the end-of-file address the
// header records (ADF disk pointers: 8 hex digits of 4096-byte block, 4 of offset).
void check_adf_header(const std::filesystem::path& p) {
  std::ifstream in(p, std::ios::binary);
  char h[256] = {0};
  in.read(h, sizeof h);
  const std::string s(h, static_cast<std::size_t>(in.gcount()));
  if (s.size() < 24 || s.compare(4, 20, "ADF Database Version") != 0) return;  // not ADF: HDF5 reports its own errors
  const auto at = s.find("AdF4");
  if (at == std::string::npos || at + 4 + 24 > s.size())
    throw MeshIOError(p.string() + ": damaged CGNS/ADF file header (no AdF4 field): not a readable CGNS file");
  std::uint64_t eof = 0;
  try {
    eof = std::stoull(s.substr(at + 16, 8), nullptr, 16) * 4096 + std::stoull(s.substr(at + 24, 4), nullptr, 16);
  } catch (const std::exception&) {
    throw MeshIOError(p.string() + ": damaged CGNS/ADF file header (end-of-file address is not hexadecimal)");
  }
  const auto size = std::filesystem::file_size(p);
  if (eof > size)
    throw MeshIOError(p.string() + ": truncated CGNS/ADF file: " + std::to_string(size) + " bytes, its header says " +
                      std::to_string(eof) + " (copy it again)");
}

}  // namespace

void write_cgns(const Mesh& m, const std::filesystem::path& path) {
  const int dim = m.dimension();
  check_writable(m, path, dim);
  // written under a temporary name and renamed: a failure leaves no partial file
  std::filesystem::path tmp = path;
  tmp += ".tmp" + std::to_string(::getpid());
  try {
    write_file(m, tmp, dim);
    std::filesystem::rename(tmp, path);
  } catch (...) {
    std::error_code ec;
    std::filesystem::remove(tmp, ec);
    throw;
  }
}

Mesh read_cgns(const std::filesystem::path& path) {
  if (!std::filesystem::exists(path)) throw MeshIOError(path.string() + ": no such file");
  check_adf_header(path);
  int ftype = 0;
  if (cg_is_cgns(path.c_str(), &ftype) != CG_OK)
    throw MeshIOError(path.string() + ": not a CGNS file (neither CGNS/HDF5 nor CGNS/ADF; is it complete?)");
  CgFile f(path, CG_MODE_READ);
  int nb = 0, nz = 0, cell_dim = 0, phys_dim = 0;
  ok(cg_nbases(f.fn, &nb), path, "counting the bases");
  if (nb < 1) throw MeshIOError(path.string() + ": the CGNS file holds no base (no mesh)");
  char bname[33] = {0};
  ok(cg_base_read(f.fn, 1, bname, &cell_dim, &phys_dim), path, "reading the base");
  ok(cg_nzones(f.fn, 1, &nz), path, "counting the zones");
  if (nz != 1)
    throw MeshIOError(path.string() + ": base " + bname + " holds " + std::to_string(nz) +
                      " zones; meshflow reads one unstructured zone (merge the zones first)");
  CGNS_ENUMT(ZoneType_t) zt;
  ok(cg_zone_type(f.fn, 1, 1, &zt), path, "reading the zone type");
  if (zt != CGNS_ENUMV(Unstructured)) throw MeshIOError(path.string() + ": the zone is structured; meshflow reads unstructured zones");
  char zname[33] = {0};
  cgsize_t size[3] = {0, 0, 0};
  ok(cg_zone_read(f.fn, 1, 1, zname, size), path, "reading the zone");
  const ZoneRef z{f.fn, 1, 1, path};
  Mesh m;
  m.x = read_coordinate(z, "CoordinateX", size[0]);
  m.y = read_coordinate(z, "CoordinateY", size[0]);
  m.z = read_coordinate(z, "CoordinateZ", size[0]);
  char fam[33] = {0};
  if (cg_goto(f.fn, 1, "Zone_t", 1, "end") == CG_OK && cg_famname_read(fam) == CG_OK && fam[0]) {
    m.add_physical(cell_dim, 1, fam);
    m.add_entity(cell_dim, 1, {1});
  } else {
    m.add_entity(cell_dim, 1);
  }
  read_sections(z, m, cell_dim, size[0]);
  f.close(path);
  try {
    m.check();
  } catch (const std::exception& e) {
    throw MeshIOError(path.string() + ": " + e.what());
  }
  return m;
}

}  // namespace meshflow::io
