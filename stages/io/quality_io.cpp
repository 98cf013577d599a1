// The "mesh_quality" artifact: the per-element quality (model::mesh_quality) a mesh stage
// computed for its contract, stored beside its mesh so that the formats (VTU's cell fields)
// read it instead of recomputing it (see mesh_io.hpp).
//
// Layout (little-endian, as the binary MSH beside it):
//   "meshflow mesh_quality 1\n"
//   u64 number of blocks: the mesh's non-empty element blocks, in the order write_msh writes
//       them (which is the order read_msh gives back)
//   per block: i32 Gmsh element type, i32 entity dim, i32 entity tag, i32 measured (1: the
//       block is of the mesh's highest dimension and has a quality per element; 0: none),
//       u64 number of elements
//   per measured block: f64 min_det[n], f64 max_det[n], f64 scaled_jacobian[n],
//       f64 aspect_ratio[n], u8 flags[n] (1 valid, 2 inconclusive, 4 sampled)
// Every bit of an ElementQuality is kept: what a format writes from it is what it would have
// computed (mesh_quality is deterministic for any thread count).
#include "stages/io/mesh_io.hpp"

#include "engine/stage.hpp"
#include "stages/io/reader.hpp"

#include <fstream>

namespace meshflow::io {

using namespace model;

namespace {
constexpr char kMagic[] = "meshflow mesh_quality 1\n";

template <class T>
void put(std::string& s, T v) {
  s.append(reinterpret_cast<const char*>(&v), sizeof v);
}
}  // namespace

void write_quality(const Mesh& m, const MeshQuality& q, const std::filesystem::path& path) {
  if (q.size() != m.blocks.size())
    throw MeshIOError(path.string() + ": mesh quality of " + std::to_string(q.size()) + " blocks for a mesh of " +
                      std::to_string(m.blocks.size()));
  std::string s(kMagic);
  std::uint64_t nonempty = 0;
  for (auto& b : m.blocks) nonempty += b.size() > 0;
  put<std::uint64_t>(s, nonempty);
  for (size_t bi = 0; bi < m.blocks.size(); ++bi) {
    const auto& b = m.blocks[bi];
    if (!b.size()) continue;
    const bool measured = !q[bi].empty();
    if (measured && q[bi].size() != b.size())
      throw MeshIOError(path.string() + ": mesh quality of block " + std::to_string(bi) + " has " +
                        std::to_string(q[bi].size()) + " elements, the block " + std::to_string(b.size()));
    put<std::int32_t>(s, gmsh_type(b.shape, b.order));
    put<std::int32_t>(s, b.entity_dim);
    put<std::int32_t>(s, b.entity_tag);
    put<std::int32_t>(s, measured ? 1 : 0);
    put<std::uint64_t>(s, b.size());
  }
  for (size_t bi = 0; bi < m.blocks.size(); ++bi) {
    if (!m.blocks[bi].size() || q[bi].empty()) continue;
    for (auto& e : q[bi]) put(s, e.min_det);
    for (auto& e : q[bi]) put(s, e.max_det);
    for (auto& e : q[bi]) put(s, e.scaled_jacobian);
    for (auto& e : q[bi]) put(s, e.aspect_ratio);
    for (auto& e : q[bi]) put<std::uint8_t>(s, std::uint8_t((e.valid ? 1 : 0) | (e.inconclusive ? 2 : 0) | (e.sampled ? 4 : 0)));
  }
  std::ofstream f(path, std::ios::binary);
  if (!f) throw MeshIOError(path.string() + ": cannot open the file for writing");
  f.write(s.data(), (std::streamsize)s.size());
  f.close();
  if (!f) throw MeshIOError(path.string() + ": write failed (disk full?)");
}

MeshQuality read_quality(const std::filesystem::path& path, const Mesh& m) {
  const std::string d = detail::slurp(path);
  if (d.compare(0, sizeof kMagic - 1, kMagic) != 0)
    throw MeshIOError(path.string() + ": not a meshflow mesh quality file (no '" + std::string(kMagic, sizeof kMagic - 2) + "')");
  detail::Cursor in(path.string(), d);
  in.skip(sizeof kMagic - 1);
  std::vector<size_t> nonempty;
  for (size_t bi = 0; bi < m.blocks.size(); ++bi)
    if (m.blocks[bi].size()) nonempty.push_back(bi);
  const auto nb = in.bin<std::uint64_t>("the number of blocks");
  if (nb != nonempty.size())
    throw MeshIOError(path.string() + ": the quality of " + std::to_string(nb) + " element blocks for a mesh of " +
                      std::to_string(nonempty.size()) + ": not this mesh's");
  MeshQuality q(m.blocks.size());
  std::vector<bool> measured(m.blocks.size());
  for (size_t bi : nonempty) {
    const auto& b = m.blocks[bi];
    const auto type = in.bin<std::int32_t>("a block's element type"), edim = in.bin<std::int32_t>("a block's entity dim"),
               etag = in.bin<std::int32_t>("a block's entity tag"), meas = in.bin<std::int32_t>("a block's measured flag");
    const auto n = in.bin<std::uint64_t>("a block's element count");
    if (type != gmsh_type(b.shape, b.order) || edim != b.entity_dim || etag != b.entity_tag || n != b.size() ||
        (meas != 0 && meas != 1))
      throw MeshIOError(path.string() + ": the quality's block " + std::to_string(bi) + " (type " + std::to_string(type) +
                        ", entity " + std::to_string(edim) + "/" + std::to_string(etag) + ", " + std::to_string(n) +
                        " elements) is not the mesh's: not this mesh's quality");
    measured[bi] = meas == 1;
  }
  for (size_t bi : nonempty) {
    if (!measured[bi]) continue;
    auto& v = q[bi];
    v.resize(m.blocks[bi].size());
    for (auto& e : v) e.min_det = in.bin<double>("min_det");
    for (auto& e : v) e.max_det = in.bin<double>("max_det");
    for (auto& e : v) e.scaled_jacobian = in.bin<double>("scaled_jacobian");
    for (auto& e : v) e.aspect_ratio = in.bin<double>("aspect_ratio");
    for (auto& e : v) {
      const auto f = in.bin<std::uint8_t>("element flags");
      if (f > 7) in.fail("bad element flags " + std::to_string(f), true, in.pos() - 1);
      e.valid = f & 1, e.inconclusive = f & 2, e.sampled = f & 4;
    }
  }
  if (!in.eof()) in.fail(std::to_string(d.size() - in.pos()) + " bytes after the mesh quality's end", true);
  return q;
}

std::optional<MeshQuality> stored_quality(const std::vector<Artifact>& artifacts, const Mesh& m, const std::string& stage,
                                          std::string* why) {
  for (const Artifact& a : artifacts)
    if (a.type == "mesh_quality" && (stage.empty() || a.stage == stage)) {
      try {
        return read_quality(a.path, m);
      } catch (const MeshIOError& e) {
        if (why) *why = e.what();
        return std::nullopt;
      }
    }
  return std::nullopt;
}

}  // namespace meshflow::io
