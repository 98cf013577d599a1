// Gmsh MSH 4.1 (ASCII, binary) reader and writer, MSH 2.2 ASCII reader. Format reference:
// the Gmsh reference manual, section "MSH file format". Written by hand because no
// maintained C++ library reads and writes MSH 4.1 with entities, parametric nodes and
// periodic links without pulling in all of Gmsh.
#include "stages/io/mesh_io.hpp"
#include "stages/io/reader.hpp"

#include <algorithm>
#include <array>
#include <climits>
#include <cstring>
#include <limits>
#include <charconv>
#include <cmath>
#include <fstream>
#include <map>
#include <set>
#include <tuple>

#include <sys/mman.h>

namespace meshflow::io {

using namespace model;
using detail::Cursor;

namespace {

// Node tag -> index lookup (dense when tags are compact, sorted otherwise).
struct TagIndex {
  std::vector<std::uint32_t> dense;
  std::vector<std::pair<std::uint64_t, std::uint32_t>> sparse;
  bool use_dense = true;
  // tags 1..n in order (what meshflow and Gmsh usually write): the index is tag - 1, with no
  // table (a lookup in a table of 11M nodes is a cache miss per element node)
  bool identity = false;
  std::uint64_t count = 0;
  static constexpr std::uint32_t kNone = 0xffffffffu;
  void build(const std::vector<std::uint64_t>& tags, std::uint64_t max_tag) {
    count = tags.size();
    identity = true;
    for (std::size_t i = 0; i < tags.size() && identity; ++i) identity = tags[i] == i + 1;
    if (identity) return;
    use_dense = max_tag <= 4 * tags.size() + 1024;
    if (use_dense) {
      dense.assign(max_tag + 1, kNone);
      for (std::uint32_t i = 0; i < tags.size(); ++i) dense[tags[i]] = i;
    } else {
      for (std::uint32_t i = 0; i < tags.size(); ++i) sparse.push_back({tags[i], i});
      std::sort(sparse.begin(), sparse.end());
    }
  }
  std::uint32_t find(std::uint64_t t) const {
    if (identity) return t >= 1 && t <= count ? static_cast<std::uint32_t>(t - 1) : kNone;
    if (use_dense) return t < dense.size() ? dense[t] : kNone;
    auto it = std::lower_bound(sparse.begin(), sparse.end(), std::make_pair(t, std::uint32_t(0)));
    return it != sparse.end() && it->first == t ? it->second : kNone;
  }
};

// Asks for transparent huge pages on a large freshly reserved array (a hint; no effect where
// THP is off). A big mesh's arrays are touched for the first time while reading; on this kind
// of virtual machine each 4 KiB page fault is costly, and a 700 MB mesh takes ~170k of them.
template <class V>
void hint_huge_pages(V& v) {
  constexpr std::uintptr_t kHuge = std::uintptr_t(2) << 20;
  const std::uintptr_t b = reinterpret_cast<std::uintptr_t>(v.data());
  const std::uintptr_t e = b + v.capacity() * sizeof(typename V::value_type);
  const std::uintptr_t b2 = (b + kHuge - 1) & ~(kHuge - 1), e2 = e & ~(kHuge - 1);
  if (e2 > b2) ::madvise(reinterpret_cast<void*>(b2), e2 - b2, MADV_HUGEPAGE);
}

// `identity`: the node tags are 1..n in order (TagIndex::identity), so the mesh keeps none.
void finish_tags(Mesh& m, std::vector<std::uint64_t>& node_tags, bool identity) {
  if (!identity) m.node_tags = node_tags;
  std::uint64_t next = 1;
  bool etrivial = true;
  for (auto& b : m.blocks)
    for (auto t : b.tags) etrivial = etrivial && t == next++;
  if (etrivial)
    for (auto& b : m.blocks) b.tags.clear();
}

Mesh read_msh4(Cursor& c, bool binary, const std::string& path) {
  Mesh m;
  auto I = [&](const char* what) -> long long { return binary ? c.bin<int>(what) : c.integer<long long>(what); };
  auto S = [&](const char* what) -> std::uint64_t {
    if (binary) return c.bin<std::uint64_t>(what);
    long long v = c.integer<long long>(what);
    if (v < 0) c.fail(std::string("negative value for ") + what);
    return static_cast<std::uint64_t>(v);
  };
  auto D = [&](const char* what) -> double { return binary ? c.bin<double>(what) : c.real(what); };
  std::vector<std::uint64_t> node_tags;
  TagIndex index;
  bool have_nodes = false;
  while (true) {
    c.skip_ws();
    if (c.eof()) break;
    size_t at = c.pos();
    std::string head = c.line();
    if (head.empty() || head[0] != '$') c.fail("expected a section ($Name), found '" + head.substr(0, 40) + "'", false, at);
    std::string name = head.substr(1);
    if (name == "PhysicalNames") {
      long long n = c.integer<long long>("number of physical names");
      for (long long i = 0; i < n; ++i) {
        int dim = c.integer<int>("physical dimension");
        int tag = c.integer<int>("physical tag");
        c.skip_ws();
        size_t lat = c.pos();
        std::string rest = c.line();
        auto q1 = rest.find('"'), q2 = rest.rfind('"');
        if (q1 == std::string::npos || q2 == q1) c.fail("physical name must be quoted", false, lat);
        m.add_physical(dim, tag, rest.substr(q1 + 1, q2 - q1 - 1));
      }
      c.expect("$EndPhysicalNames");
    } else if (name == "Entities") {
      std::uint64_t n[4];
      for (int d = 0; d < 4; ++d) n[d] = S("number of entities");
      for (int d = 0; d < 4; ++d)
        for (std::uint64_t i = 0; i < n[d]; ++i) {
          Entity e;
          e.dim = d;
          e.tag = static_cast<int>(I("entity tag"));
          if (d == 0) {
            for (int k = 0; k < 3; ++k) e.bbox[k] = e.bbox[k + 3] = D("point coordinate");
          } else {
            for (int k = 0; k < 6; ++k) e.bbox[k] = D("bounding box");
          }
          std::uint64_t np = S("number of physical tags");
          if (np > 1000000) c.fail("implausible number of physical tags", binary);
          for (std::uint64_t k = 0; k < np; ++k) e.physicals.push_back(static_cast<int>(I("physical tag")));
          if (d > 0) {
            std::uint64_t nb = S("number of bounding entities");
            if (nb > 100000000) c.fail("implausible number of bounding entities", binary);
            for (std::uint64_t k = 0; k < nb; ++k) e.boundary.push_back(static_cast<int>(I("bounding entity")));
          }
          m.entities.push_back(std::move(e));
        }
      c.expect("$EndEntities");
    } else if (name == "Nodes") {
      std::uint64_t nblocks = S("number of node blocks"), nnodes = S("number of nodes");
      S("min node tag");
      std::uint64_t maxtag = S("max node tag");
      if (nnodes > (1ull << 32) - 2) c.fail("too many nodes", binary);
      const size_t reserve = std::min<std::uint64_t>(nnodes, c.data().size() / 8 + 1);
      m.x.reserve(reserve), m.y.reserve(reserve), m.z.reserve(reserve);
      m.node_entity_dim.reserve(reserve), m.node_entity_tag.reserve(reserve);
      node_tags.reserve(reserve);
      hint_huge_pages(m.x), hint_huge_pages(m.y), hint_huge_pages(m.z), hint_huge_pages(node_tags);
      hint_huge_pages(m.node_entity_dim), hint_huge_pages(m.node_entity_tag);
      bool any_param = false;
      for (std::uint64_t b = 0; b < nblocks; ++b) {
        c.done_before_here();  // the blocks before are parsed
        int dim = static_cast<int>(I("entity dimension"));
        int tag = static_cast<int>(I("entity tag"));
        int param = static_cast<int>(I("parametric flag"));
        std::uint64_t n = S("number of nodes in block");
        if (dim < 0 || dim > 3) c.fail("entity dimension " + std::to_string(dim) + " is not 0..3", binary);
        if (node_tags.size() + n > nnodes)
          c.fail("inconsistent counts: the node blocks hold more nodes than the " + std::to_string(nnodes) +
                     " declared in the $Nodes header", binary);
        size_t first = node_tags.size();
        const int npar = param ? dim : 0;
        if (param && !any_param) {
          any_param = true;
          m.node_u.reserve(reserve), m.node_v.reserve(reserve);
          hint_huge_pages(m.node_u), hint_huge_pages(m.node_v);
          m.node_u.assign(first, NAN);
          m.node_v.assign(first, NAN);
        }
        // node i of the file (its tag read), coordinates (x y z u v) starting at byte/char `at`
        auto add_node = [&](const double* p, size_t i, size_t at) {
          if (!std::isfinite(p[0]) || !std::isfinite(p[1]) || !std::isfinite(p[2]))
            c.fail("node " + std::to_string(node_tags[i]) + " has a non-finite coordinate", binary, at);
          m.x.push_back(p[0]), m.y.push_back(p[1]), m.z.push_back(p[2]);
          if (any_param) {
            m.node_u.push_back(npar >= 1 && dim <= 2 ? p[3] : NAN);
            m.node_v.push_back(npar >= 2 && dim <= 2 ? p[4] : NAN);
          }
          m.node_entity_dim.push_back(dim);
          m.node_entity_tag.push_back(tag);
        };
        if (binary && c.has(n * 8 * (4 + npar))) {
          // fast path (the whole block is there): tags, then x y z (u v) per node, copied in bulk
          node_tags.resize(first + n);
          std::memcpy(node_tags.data() + first, c.at(), n * 8);
          c.skip(n * 8);
          const size_t rec = 8 * (3 + npar);
          for (std::uint64_t i = 0; i < n; ++i) {
            double v[6] = {0, 0, 0, NAN, NAN, NAN};
            std::memcpy(v, c.at() + rec * i, rec);
            add_node(v, first + i, c.pos() + rec * i);
            if ((i & 0xffff) == 0xffff) c.done_before(c.pos() + rec * i);  // parsed: may leave memory
          }
          c.skip(n * rec);
          continue;
        }
        for (std::uint64_t i = 0; i < n; ++i) node_tags.push_back(S("node tag"));
        for (std::uint64_t i = 0; i < n; ++i) {
          size_t at = c.pos();
          double p[6] = {0, 0, 0, NAN, NAN, NAN};
          for (int k = 0; k < 3 + npar; ++k) p[k] = D("node coordinate");
          add_node(p, first + i, at);
        }
      }
      if (node_tags.size() != nnodes)
        c.fail("inconsistent counts: $Nodes header declares " + std::to_string(nnodes) + " nodes, blocks hold " +
               std::to_string(node_tags.size()), binary);
      index.build(node_tags, std::max<std::uint64_t>(maxtag, node_tags.empty() ? 0 : *std::max_element(node_tags.begin(), node_tags.end())));
      for (size_t i = 0; i < node_tags.size(); ++i)
        if (index.find(node_tags[i]) != i) c.fail("duplicate node tag " + std::to_string(node_tags[i]), binary);
      have_nodes = true;
      c.done_before_here();
      c.expect("$EndNodes");
    } else if (name == "Elements") {
      if (!have_nodes) c.fail("$Elements before $Nodes", false, at);
      std::uint64_t nblocks = S("number of element blocks"), nelem = S("number of elements");
      S("min element tag");
      S("max element tag");
      std::uint64_t total = 0;
      for (std::uint64_t b = 0; b < nblocks; ++b) {
        c.done_before_here();
        int dim = static_cast<int>(I("entity dimension"));
        int tag = static_cast<int>(I("entity tag"));
        size_t tat = c.pos();
        int type = static_cast<int>(I("element type"));
        std::uint64_t n = S("number of elements in block");
        Shape s;
        int order;
        if (!from_gmsh_type(type, s, order))
          c.fail("unknown or unsupported element type " + std::to_string(type) +
                     " (supported: complete Lagrange points, lines, triangles, quadrangles, tetrahedra, prisms, "
                     "pyramids, hexahedra of order 1-6)", binary, tat);
        if (total + n > nelem)
          c.fail("inconsistent counts: element blocks hold more than the " + std::to_string(nelem) + " declared", binary);
        total += n;
        ElementBlock blk;
        blk.shape = s, blk.order = order, blk.entity_dim = dim, blk.entity_tag = tag;
        const int npe = blk.nodes_per_element();
        if (n > c.data().size()) c.fail("implausible element count " + std::to_string(n) + " (truncated file?)", binary);
        blk.nodes.reserve(n * npe);
        blk.tags.reserve(n);
        hint_huge_pages(blk.nodes), hint_huge_pages(blk.tags);
        if (binary && c.has(n * 8 * (1 + npe))) {
          // fast path (the whole block is there): tag and node tags per element, no check per value
          const char* p = c.at();
          const size_t rec = 8 * (1 + npe);
          auto u64 = [](const char* q) {
            std::uint64_t v;
            std::memcpy(&v, q, 8);
            return v;
          };
          for (std::uint64_t e = 0; e < n; ++e, p += rec) {
            if ((e & 0xffff) == 0xffff) c.done_before(c.pos() + e * rec);
            const std::uint64_t etag = u64(p);
            blk.tags.push_back(etag);
            for (int k = 0; k < npe; ++k) {
              const std::uint64_t t = u64(p + 8 * (1 + k));
              std::uint32_t idx = index.find(t);
              if (idx == TagIndex::kNone)
                c.fail("element " + std::to_string(etag) + " refers to node " + std::to_string(t) +
                           ", which is not in $Nodes (node index out of range)",
                       binary, c.pos() + e * rec + 8 * (1 + k));
              blk.nodes.push_back(idx);
            }
          }
          c.skip(n * rec);
          m.blocks.push_back(std::move(blk));
          continue;
        }
        for (std::uint64_t e = 0; e < n; ++e) {
          blk.tags.push_back(S("element tag"));
          for (int k = 0; k < npe; ++k) {
            size_t nat = c.pos();
            std::uint64_t t = S("element node tag");
            std::uint32_t idx = index.find(t);
            if (idx == TagIndex::kNone)
              c.fail("element " + std::to_string(blk.tags.back()) + " refers to node " + std::to_string(t) +
                         ", which is not in $Nodes (node index out of range)", binary, nat);
            blk.nodes.push_back(idx);
          }
        }
        m.blocks.push_back(std::move(blk));
      }
      if (total != nelem)
        c.fail("inconsistent counts: $Elements header declares " + std::to_string(nelem) + " elements, blocks hold " +
               std::to_string(total), binary);
      c.expect("$EndElements");
    } else if (name == "Periodic") {
      if (!have_nodes) c.fail("$Periodic before $Nodes", false, at);
      std::uint64_t n = S("number of periodic links");
      for (std::uint64_t l = 0; l < n; ++l) {
        PeriodicLink pl;
        pl.dim = static_cast<int>(I("entity dimension"));
        pl.tag = static_cast<int>(I("entity tag"));
        pl.master_tag = static_cast<int>(I("master entity tag"));
        std::uint64_t na = S("number of affine values");
        if (na != 0 && na != 16) c.fail("periodic affine transform must have 0 or 16 values", binary);
        for (std::uint64_t k = 0; k < na; ++k) pl.affine.push_back(D("affine value"));
        std::uint64_t nn = S("number of periodic nodes");
        if (nn > c.data().size()) c.fail("implausible periodic node count (truncated file?)", binary);
        for (std::uint64_t k = 0; k < nn; ++k) {
          std::uint64_t a = S("periodic node"), b = S("periodic master node");
          std::uint32_t ia = index.find(a), ib = index.find(b);
          if (ia == TagIndex::kNone || ib == TagIndex::kNone) c.fail("periodic link refers to a node not in $Nodes", binary);
          pl.nodes.push_back({ia, ib});
        }
        m.periodic.push_back(std::move(pl));
      }
      c.expect("$EndPeriodic");
    } else if (name == "PartitionedEntities" || name == "GhostElements") {
      c.fail("partitioned meshes are not supported (section $" + name + ")", false, at);
    } else {  // skip unknown sections ($NodeData, $Comments, ...)
      std::string end = "\n$End" + name;
      size_t e = c.data().find(end, c.pos());
      if (e == std::string::npos) c.fail("section $" + name + " has no $End" + name + " (truncated file?)", false, at);
      c.seek(e + end.size());
    }
  }
  if (!have_nodes) throw MeshIOError(path + ": no $Nodes section");
  finish_tags(m, node_tags, index.identity);
  return m;
}

Mesh read_msh2(Cursor& c, const std::string& path) {
  Mesh m;
  std::vector<std::uint64_t> node_tags;
  TagIndex index;
  bool have_nodes = false;
  std::map<std::tuple<int, int, int, int>, size_t> block_of;  // (dim, entity, shape, order)
  std::map<std::pair<int, int>, std::set<int>> entity_phys;
  while (true) {
    c.skip_ws();
    if (c.eof()) break;
    size_t at = c.pos();
    std::string head = c.line();
    if (head.empty() || head[0] != '$') c.fail("expected a section ($Name), found '" + head.substr(0, 40) + "'", false, at);
    std::string name = head.substr(1);
    if (name == "PhysicalNames") {
      long long n = c.integer<long long>("number of physical names");
      for (long long i = 0; i < n; ++i) {
        int dim = c.integer<int>("physical dimension");
        int tag = c.integer<int>("physical tag");
        c.skip_ws();
        size_t lat = c.pos();
        std::string rest = c.line();
        auto q1 = rest.find('"'), q2 = rest.rfind('"');
        if (q1 == std::string::npos || q2 == q1) c.fail("physical name must be quoted", false, lat);
        m.add_physical(dim, tag, rest.substr(q1 + 1, q2 - q1 - 1));
      }
      c.expect("$EndPhysicalNames");
    } else if (name == "Nodes") {
      long long n = c.integer<long long>("number of nodes");
      if (n < 0 || n > (long long)c.data().size()) c.fail("implausible node count " + std::to_string(n));
      std::uint64_t maxtag = 0;
      for (long long i = 0; i < n; ++i) {
        size_t nat = (c.skip_ws(), c.pos());
        std::uint64_t t = c.integer<std::uint64_t>("node tag");
        double p[3];
        for (double& v : p) v = c.real("node coordinate");
        if (!std::isfinite(p[0]) || !std::isfinite(p[1]) || !std::isfinite(p[2]))
          c.fail("node " + std::to_string(t) + " has a non-finite coordinate", false, nat);
        node_tags.push_back(t);
        maxtag = std::max(maxtag, t);
        m.x.push_back(p[0]), m.y.push_back(p[1]), m.z.push_back(p[2]);
      }
      index.build(node_tags, maxtag);
      for (size_t i = 0; i < node_tags.size(); ++i)
        if (index.find(node_tags[i]) != i) c.fail("duplicate node tag " + std::to_string(node_tags[i]));
      have_nodes = true;
      c.expect("$EndNodes");
    } else if (name == "Elements") {
      if (!have_nodes) c.fail("$Elements before $Nodes", false, at);
      long long n = c.integer<long long>("number of elements");
      if (n < 0 || n > (long long)c.data().size()) c.fail("implausible element count " + std::to_string(n));
      for (long long i = 0; i < n; ++i) {
        std::uint64_t tag = c.integer<std::uint64_t>("element tag");
        size_t tat = (c.skip_ws(), c.pos());
        int type = c.integer<int>("element type");
        int ntags = c.integer<int>("number of element tags");
        std::vector<int> tags(std::max(ntags, 0));
        for (int& t : tags) t = c.integer<int>("element tag value");
        Shape s;
        int order;
        if (!from_gmsh_type(type, s, order))
          c.fail("unknown or unsupported element type " + std::to_string(type), false, tat);
        int phys = ntags > 0 ? tags[0] : 0, ent = ntags > 1 ? tags[1] : 0;
        int dim = dimension(s);
        auto key = std::make_tuple(dim, ent, (int)s, order);
        auto it = block_of.find(key);
        if (it == block_of.end()) {
          it = block_of.emplace(key, m.blocks.size()).first;
          ElementBlock b;
          b.shape = s, b.order = order, b.entity_dim = dim, b.entity_tag = ent;
          m.blocks.push_back(std::move(b));
        }
        auto& b = m.blocks[it->second];
        b.tags.push_back(tag);
        for (int k = 0; k < b.nodes_per_element(); ++k) {
          size_t nat = (c.skip_ws(), c.pos());
          std::uint64_t t = c.integer<std::uint64_t>("element node tag");
          std::uint32_t idx = index.find(t);
          if (idx == TagIndex::kNone)
            c.fail("element " + std::to_string(tag) + " refers to node " + std::to_string(t) +
                       ", which is not in $Nodes (node index out of range)", false, nat);
          b.nodes.push_back(idx);
        }
        if (phys) entity_phys[{dim, ent}].insert(phys);
        else entity_phys[{dim, ent}];
      }
      c.expect("$EndElements");
    } else {
      std::string end = "\n$End" + name;
      size_t e = c.data().find(end, c.pos());
      if (e == std::string::npos) c.fail("section $" + name + " has no $End" + name + " (truncated file?)", false, at);
      c.seek(e + end.size());
    }
  }
  if (!have_nodes) throw MeshIOError(path + ": no $Nodes section");
  for (auto& [k, ph] : entity_phys) m.add_entity(k.first, k.second, std::vector<int>(ph.begin(), ph.end()));
  // MSH 2.2 blocks are in order of first appearance; Gmsh's element order is kept per block
  std::uint64_t next = 1;
  bool etrivial = true;
  for (auto& b : m.blocks)
    for (auto t : b.tags) etrivial = etrivial && t == next++;
  (void)etrivial;
  finish_tags(m, node_tags, index.identity);
  return m;
}

// ---- writing ----
constexpr int kMaxRow = (kMaxOrder + 1) * (kMaxOrder + 1) * (kMaxOrder + 1);  // nodes of a hex of order kMaxOrder
// Formats into a buffer of a few MB that is written to the file whenever it fills (formatting
// and writing overlap in the page cache; no buffer of the file's size, no page faults on it).
struct Out {
  std::string s;
  bool binary;
  std::ofstream* f = nullptr;
  const std::filesystem::path* path = nullptr;
  static constexpr size_t kBlock = 8u << 20;
  void flush() {
    f->write(s.data(), static_cast<std::streamsize>(s.size()));
    if (!*f) throw MeshIOError(path->string() + ": write failed (disk full?)");
    s.clear();
  }
  void maybe_flush() {
    if (s.size() >= kBlock) flush();
  }
  // room for n more bytes, returns where to put them (binary rows formatted in place)
  char* grow(size_t n) {
    const size_t at = s.size();
    s.resize(at + n);
    return s.data() + at;
  }
  void raw(const void* p, size_t n) { s.append(static_cast<const char*>(p), n); }
  void txt(std::string_view t) { s.append(t); }
  void i(int v) {
    if (binary) raw(&v, 4);
    else num(v), s += ' ';
  }
  void z(std::uint64_t v) {
    if (binary) raw(&v, 8);
    else num(v), s += ' ';
  }
  void d(double v) {
    if (binary) raw(&v, 8);
    else {
      char buf[32];
      auto r = std::to_chars(buf, buf + sizeof buf, v);
      s.append(buf, r.ptr);
      s += ' ';
    }
  }
  template <class T>
  void num(T v) {
    char buf[32];
    auto r = std::to_chars(buf, buf + sizeof buf, v);
    s.append(buf, r.ptr);
  }
  void nl() {
    if (!binary) {
      if (!s.empty() && s.back() == ' ') s.back() = '\n';
      else s += '\n';
    }
  }
};

}  // namespace

namespace {
// The classification of classify_nodes into separate arrays (write_msh uses it without
// copying the mesh).
void classify_into(const Mesh& m, std::vector<int>& cdim, std::vector<int>& ctag) {
  const size_t n = m.num_nodes();
  if (m.node_entity_dim.size() == n && m.node_entity_tag.size() == n) {
    cdim = m.node_entity_dim;
    ctag = m.node_entity_tag;
  } else {
    cdim.assign(n, -1);
    ctag.assign(n, -1);
  }
  for (int d = 0; d <= 3; ++d)
    for (auto& b : m.blocks) {
      if (dimension(b.shape) != d) continue;
      for (auto idx : b.nodes)
        if (cdim[idx] < 0) {
          cdim[idx] = b.entity_dim;
          ctag[idx] = b.entity_tag;
        }
    }
  // nodes used by no element: the highest-dimensional entity (or a new volume entity)
  int fd = -1, ft = -1;
  for (auto& e : m.entities)
    if (e.dim > fd) fd = e.dim, ft = e.tag;
  for (auto& b : m.blocks)
    if (b.entity_dim > fd) fd = b.entity_dim, ft = b.entity_tag;
  if (fd < 0) fd = 3, ft = 1;
  for (size_t i = 0; i < n; ++i)
    if (cdim[i] < 0) cdim[i] = fd, ctag[i] = ft;
}
}  // namespace

void classify_nodes(Mesh& m) {
  std::vector<int> d, t;
  classify_into(m, d, t);
  m.node_entity_dim = std::move(d);
  m.node_entity_tag = std::move(t);
}

Mesh read_msh(const std::filesystem::path& path) {
  const detail::FileBytes data(path);
  Cursor c(path.string(), data.view());
  c.on_done([&data](size_t pos) { data.release_before(pos); });
  c.skip_ws();
  if (c.eof()) c.fail("empty file (not a Gmsh MSH file)");
  std::string head = c.line();
  if (head != "$MeshFormat") c.fail("not a Gmsh MSH file: the first line is not $MeshFormat", false, 0);
  size_t vat = (c.skip_ws(), c.pos());
  std::string version(c.token("MSH version"));
  int ftype = c.integer<int>("file type");
  int dsize = c.integer<int>("data size");
  if (version != "4.1" && version != "2.2" && version != "2.0" && version != "2.1")
    c.fail("unsupported MSH version " + version + " (supported: 4.1 ASCII/binary, 2.2 ASCII)", false, vat);
  if (ftype != 0 && ftype != 1) c.fail("file type must be 0 (ASCII) or 1 (binary)", false, vat);
  if (dsize != 8) c.fail("data size " + std::to_string(dsize) + " is not supported (must be 8)", false, vat);
  c.line();
  bool binary = ftype == 1;
  if (binary) {
    if (version != "4.1") c.fail("binary MSH " + version + " is not supported (only binary 4.1)", false, vat);
    int one = c.bin<int>("endianness marker");
    if (one != 1) c.fail("binary MSH with foreign endianness (marker " + std::to_string(one) + ")", true, c.pos() - 4);
  }
  c.expect("$EndMeshFormat");
  c.line();
  Mesh m = version == "4.1" ? read_msh4(c, binary, path.string()) : read_msh2(c, path.string());
  try {
    m.check();
  } catch (const std::invalid_argument& e) {
    throw MeshIOError(path.string() + ": " + e.what());
  }
  return m;
}

void write_msh(const Mesh& in, const std::filesystem::path& path, bool binary) {
  in.check();
  // node classification: the mesh's own, completed (classify_nodes) in separate arrays
  // when some nodes have none (no copy of the mesh)
  const Mesh& m = in;
  const std::vector<int>* ndim = &in.node_entity_dim;
  const std::vector<int>* ntag = &in.node_entity_tag;
  std::vector<int> cdim, ctag;
  bool need_classify = in.node_entity_dim.size() != in.num_nodes() || in.node_entity_tag.size() != in.num_nodes();
  if (!need_classify)
    for (int d : in.node_entity_dim)
      if (d < 0) need_classify = true;
  if (need_classify) {
    classify_into(in, cdim, ctag);
    ndim = &cdim, ntag = &ctag;
  }
  const size_t n = m.num_nodes();

  // entities: declared ones plus any referenced by blocks or nodes, sorted by (dim, tag)
  std::map<std::pair<int, int>, Entity> ents;
  for (auto& e : m.entities) ents[{e.dim, e.tag}] = e;
  for (auto& b : m.blocks) {
    auto& e = ents[{b.entity_dim, b.entity_tag}];
    e.dim = b.entity_dim, e.tag = b.entity_tag;
  }
  for (size_t i = 0; i < n; ++i) {
    auto& e = ents[{(*ndim)[i], (*ntag)[i]}];
    e.dim = (*ndim)[i], e.tag = (*ntag)[i];
  }
  // nodes grouped by entity (one map lookup per run of equal keys: nodes come entity by entity)
  std::map<std::pair<int, int>, std::vector<std::uint32_t>> groups;
  {
    std::pair<int, int> last{INT_MIN, INT_MIN};
    std::vector<std::uint32_t>* g = nullptr;
    for (size_t i = 0; i < n; ++i) {
      const std::pair<int, int> k{(*ndim)[i], (*ntag)[i]};
      if (!g || k != last) g = &groups[k], last = k;
      g->push_back((std::uint32_t)i);
    }
  }
  // bounding boxes missing: from the nodes of the entity's elements and its own nodes
  // (accumulated per block and per node group, no lookup per node)
  bool need_bb = false;
  for (auto& [k, e] : ents) need_bb = need_bb || !std::isfinite(e.bbox[0]);
  if (need_bb) {
    std::map<std::pair<int, int>, std::array<double, 6>> bb;
    auto merge = [&](std::pair<int, int> k, const std::array<double, 6>& a) {
      auto [it, fresh] = bb.emplace(k, a);
      if (!fresh)
        for (int r = 0; r < 3; ++r)
          it->second[r] = std::min(it->second[r], a[r]), it->second[3 + r] = std::max(it->second[3 + r], a[3 + r]);
    };
    auto box = [&](const std::uint32_t* idx, size_t cnt) {
      const double inf = std::numeric_limits<double>::infinity();
      std::array<double, 6> a{inf, inf, inf, -inf, -inf, -inf};
      for (size_t t = 0; t < cnt; ++t) {
        const std::uint32_t i = idx[t];
        a[0] = std::min(a[0], m.x[i]), a[3] = std::max(a[3], m.x[i]);
        a[1] = std::min(a[1], m.y[i]), a[4] = std::max(a[4], m.y[i]);
        a[2] = std::min(a[2], m.z[i]), a[5] = std::max(a[5], m.z[i]);
      }
      return a;
    };
    for (auto& b : m.blocks)
      if (!b.nodes.empty()) merge({b.entity_dim, b.entity_tag}, box(b.nodes.data(), b.nodes.size()));
    for (auto& [k, idx] : groups)
      if (!idx.empty()) merge(k, box(idx.data(), idx.size()));
    for (auto& [k, e] : ents)
      if (!std::isfinite(e.bbox[0])) {
        auto it = bb.find(k);
        for (int r = 0; r < 6; ++r) e.bbox[r] = it != bb.end() ? it->second[r] : 0.0;
      }
  }
  for (auto& b : m.blocks)  // refuse before creating the file
    if (b.size() && !gmsh_type(b.shape, b.order))
      throw MeshIOError(path.string() + ": MSH has no element type for a " + shape_name(b.shape) + " of order " +
                        std::to_string(b.order));
  std::ofstream f(path, std::ios::binary);
  if (!f) throw MeshIOError(path.string() + ": cannot open the file for writing");

  Out o{{}, binary, &f, &path};
  o.s.reserve(Out::kBlock + (1u << 20));
  o.txt(binary ? "$MeshFormat\n4.1 1 8\n" : "$MeshFormat\n4.1 0 8\n");
  if (binary) {
    int one = 1;
    o.raw(&one, 4);
    o.txt("\n");
  }
  o.txt("$EndMeshFormat\n");
  if (!m.physicals.empty()) {
    auto ph = m.physicals;
    std::sort(ph.begin(), ph.end(), [](auto& a, auto& b) { return std::tie(a.dim, a.tag) < std::tie(b.dim, b.tag); });
    o.txt("$PhysicalNames\n" + std::to_string(ph.size()) + "\n");
    for (auto& p : ph) o.txt(std::to_string(p.dim) + " " + std::to_string(p.tag) + " \"" + p.name + "\"\n");
    o.txt("$EndPhysicalNames\n");
  }
  o.txt("$Entities\n");
  std::uint64_t cnt[4] = {0, 0, 0, 0};
  for (auto& [k, e] : ents) cnt[k.first]++;
  for (int d = 0; d < 4; ++d) o.z(cnt[d]);
  o.nl();
  for (auto& [k, e] : ents) {
    o.i(e.tag);
    for (int r = 0; r < (e.dim == 0 ? 3 : 6); ++r) o.d(e.bbox[r]);
    o.z(e.physicals.size());
    for (int p : e.physicals) o.i(p);
    if (e.dim > 0) {
      o.z(e.boundary.size());
      for (int b : e.boundary) o.i(b);
    }
    o.nl();
  }
  o.txt(binary ? "\n$EndEntities\n" : "$EndEntities\n");

  std::uint64_t tmin = n ? ~0ull : 0, tmax = 0;
  for (size_t i = 0; i < n; ++i) tmin = std::min(tmin, m.node_tag(i)), tmax = std::max(tmax, m.node_tag(i));
  o.txt("$Nodes\n");
  o.z(groups.size()), o.z(n), o.z(tmin), o.z(tmax);
  o.nl();
  for (auto& [k, idx] : groups) {
    const int dim = k.first;
    bool param = m.has_parametric() && (dim == 1 || dim == 2);
    for (auto i : idx)
      if (param && (!std::isfinite(m.node_u[i]) || (dim == 2 && !std::isfinite(m.node_v[i])))) param = false;
    o.i(dim), o.i(k.second), o.i(param ? 1 : 0), o.z(idx.size());
    o.nl();
    if (binary) {  // rows formatted in place, in blocks
      const int nv = 3 + (param ? (dim == 2 ? 2 : 1) : 0);
      for (size_t t0 = 0; t0 < idx.size(); t0 += 65536) {
        const size_t t1 = std::min(idx.size(), t0 + 65536);
        char* w = o.grow(8 * (t1 - t0));
        for (size_t t = t0; t < t1; ++t, w += 8) {
          const std::uint64_t tag = m.node_tag(idx[t]);
          std::memcpy(w, &tag, 8);
        }
        o.maybe_flush();
      }
      for (size_t t0 = 0; t0 < idx.size(); t0 += 65536) {
        const size_t t1 = std::min(idx.size(), t0 + 65536);
        char* w = o.grow(8 * nv * (t1 - t0));
        for (size_t t = t0; t < t1; ++t) {
          const std::uint32_t i = idx[t];
          double v[5] = {m.x[i], m.y[i], m.z[i], 0, 0};
          if (param) v[3] = m.node_u[i], v[4] = dim == 2 ? m.node_v[i] : 0;
          std::memcpy(w, v, 8 * nv);
          w += 8 * nv;
        }
        o.maybe_flush();
      }
    } else {
      for (auto i : idx) o.z(m.node_tag(i)), o.nl(), o.maybe_flush();
      for (auto i : idx) {
        o.d(m.x[i]), o.d(m.y[i]), o.d(m.z[i]);
        if (param) {
          o.d(m.node_u[i]);
          if (dim == 2) o.d(m.node_v[i]);
        }
        o.nl();
        o.maybe_flush();
      }
    }
  }
  o.txt(binary ? "\n$EndNodes\n" : "$EndNodes\n");

  bool all_tagged = !m.blocks.empty();
  for (auto& b : m.blocks) all_tagged = all_tagged && b.tags.size() == b.size();
  std::uint64_t ne = m.num_elements(), emin = ne ? ~0ull : 0, emax = 0, next = 1;
  for (auto& b : m.blocks)
    for (size_t e = 0; e < b.size(); ++e) {
      std::uint64_t t = all_tagged ? b.tags[e] : next++;
      emin = std::min(emin, t), emax = std::max(emax, t);
    }
  size_t nonempty = 0;
  for (auto& b : m.blocks) nonempty += b.size() > 0;
  o.txt("$Elements\n");
  o.z(nonempty), o.z(ne), o.z(emin), o.z(emax);
  o.nl();
  next = 1;
  for (auto& b : m.blocks) {
    if (!b.size()) continue;
    const int type = gmsh_type(b.shape, b.order);
    o.i(b.entity_dim), o.i(b.entity_tag), o.i(type), o.z(b.size());
    o.nl();
    const int npe = b.nodes_per_element();
    if (binary) {  // rows formatted in place, in blocks of elements
      const bool plain = m.node_tags.empty();  // node tag = index + 1
      for (size_t e0 = 0; e0 < b.size(); e0 += 16384) {
        const size_t e1 = std::min(b.size(), e0 + 16384);
        std::uint64_t* w = reinterpret_cast<std::uint64_t*>(o.grow(8 * (1 + npe) * (e1 - e0)));
        std::uint64_t row[1 + kMaxRow];
        for (size_t e = e0; e < e1; ++e) {
          row[0] = all_tagged ? b.tags[e] : next++;
          const std::uint32_t* nd = b.element(e);
          if (plain)
            for (int k = 0; k < npe; ++k) row[1 + k] = std::uint64_t(nd[k]) + 1;
          else
            for (int k = 0; k < npe; ++k) row[1 + k] = m.node_tags[nd[k]];
          std::memcpy(w, row, 8 * (1 + npe));  // (the buffer need not be 8-byte aligned)
          w += 1 + npe;
        }
        o.maybe_flush();
      }
    } else {
      for (size_t e = 0; e < b.size(); ++e) {
        o.z(all_tagged ? b.tags[e] : next++);
        const std::uint32_t* nd = b.element(e);
        for (int k = 0; k < npe; ++k) o.z(m.node_tag(nd[k]));
        o.nl();
        o.maybe_flush();
      }
    }
  }
  o.txt(binary ? "\n$EndElements\n" : "$EndElements\n");
  if (!m.periodic.empty()) {
    o.txt("$Periodic\n");
    o.z(m.periodic.size());
    o.nl();
    for (auto& l : m.periodic) {
      o.i(l.dim), o.i(l.tag), o.i(l.master_tag);
      o.nl();
      o.z(l.affine.size());
      for (double a : l.affine) o.d(a);
      o.nl();
      o.z(l.nodes.size());
      o.nl();
      for (auto [a, b] : l.nodes) o.z(m.node_tag(a)), o.z(m.node_tag(b)), o.nl();
    }
    o.txt(binary ? "\n$EndPeriodic\n" : "$EndPeriodic\n");
  }
  o.flush();
  f.close();
  if (!f) throw MeshIOError(path.string() + ": write failed (disk full?)");
}

}  // namespace meshflow::io
