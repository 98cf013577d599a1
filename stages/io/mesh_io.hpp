// meshflow mesh formats: Gmsh MSH 4.1 (ASCII and binary, read+write) and MSH 2.2 (ASCII,
// read), VTU (XML, appended raw binary, VTK Lagrange cells; write+read), Nektar++ XML
// (compressed B64Z-LittleEndian sections, as NekMesh writes them, or plain; read+write).
//
// Every reader throws MeshIOError on bad input with a message naming the file and the line
// (text) or byte offset (binary) and what is wrong: truncation, wrong magic/version, unknown
// element type, node index out of range, non-finite coordinates, inconsistent counts.
//
// The "mesh" artifact (registered by stages/io) is stored as binary MSH 4.1, written
// deterministically: a stage writes its mesh with
//   meshflow::io::write_mesh(mesh, ctx.output("mesh", "mesh"));   // .msh binary
//   ctx.stats()["mesh"] = meshflow::model::mesh_stats(mesh, ctx.threads());
// and reads its input with meshflow::io::read_mesh(ctx.input("mesh").path).
#pragma once

#include "stages/model/mesh.hpp"

#include <filesystem>
#include <stdexcept>
#include <string>

namespace meshflow::io {

struct MeshIOError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

enum class MeshFormat { MshBinary, MshAscii, Vtu, Nektar, NektarPlain };

// By extension: .msh (any supported MSH version/encoding), .vtu, .xml. Without an extension
// match (e.g. a file in the artifact store), the content decides ($MeshFormat, <VTKFile,
// <NEKTAR).
model::Mesh read_mesh(const std::filesystem::path& path);
// By extension (.msh: binary MSH 4.1; .vtu; .xml) unless `format` is given.
void write_mesh(const model::Mesh& m, const std::filesystem::path& path);
void write_mesh(const model::Mesh& m, const std::filesystem::path& path, MeshFormat format);

model::Mesh read_msh(const std::filesystem::path& path);
void write_msh(const model::Mesh& m, const std::filesystem::path& path, bool binary = true);
model::Mesh read_vtu(const std::filesystem::path& path);
void write_vtu(const model::Mesh& m, const std::filesystem::path& path);
// Reads both forms (plain and compressed sections, also mixed).
model::Mesh read_nektar(const std::filesystem::path& path);
// Compressed (Nektar++'s B64Z-LittleEndian VERTEX, EDGE, FACE, ELEMENT and CURVED sections)
// unless `compressed` is false; with an EXPANSIONS section (the mesh's order, every volume
// composite) so that the file is a session Nektar++ can start from.
void write_nektar(const model::Mesh& m, const std::filesystem::path& path, bool compressed = true);

// Solver-ready MSH (what PyFR's importer and meshio take; the `msh-ascii`, `msh-plain` and
// `pyfr` formats and `meshflow convert` to .msh): every element written belongs to a physical
// group. Gmsh's own rule when a model has physical groups (Mesh.SaveAll = 0) is to write only
// the elements of entities in one; we follow it for faces, curves and points, whose elements in
// no group (the CAD curves' edges) are dropped. Volume entities in no group join the volume group
// ("fluid", made if absent) instead: a volume element is never dropped. A mesh without physical
// groups is left as it is. Also drops the nodes' CAD parameters unless `keep_parametric`.
void make_solver_ready(model::Mesh& m, bool keep_parametric = false);
// PyFR's naming rules on top of make_solver_ready: physical tags unique across dimensions, and
// the periodic pair periodic_lo / periodic_hi named `periodic_0_l` / `periodic_0_r` (PyFR pairs
// `periodic_<name>_l` with `periodic_<name>_r`).
void apply_pyfr_names(model::Mesh& m);

// Classifies unclassified nodes on the lowest-dimensional entity whose elements use them
// (as Gmsh does), so that every node belongs to an entity block of MSH 4.1.
void classify_nodes(model::Mesh& m);

}  // namespace meshflow::io
