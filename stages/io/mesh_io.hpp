// meshflow mesh formats: Gmsh MSH 4.1 (ASCII and binary, read+write) and MSH 2.2 (ASCII,
// read), VTU (XML, appended raw binary, VTK Lagrange cells; write+read), Nektar++ XML
// (compressed B64Z-LittleEndian sections, as NekMesh writes them, or plain; read+write), CGNS
// (libcgns: unstructured zone, orders 1-4; write+read).
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
//
// A mesh stage also stores the per-element quality its contract computed, as the artifact
// "quality" of type "mesh_quality" beside its mesh (contract::record returns it):
//   auto q = meshflow::contract::record(ctx, mesh, ...);
//   meshflow::io::write_quality(mesh, q, ctx.output("quality", "mesh_quality"));
// The mesh type's formats are given it (the engine hands a format the other artifacts of the
// stage that made the mesh: ArtifactType::load), so VTU's cell fields are not computed again
// (2.5 s CPU of the demo's ~10 s split-only change). Why an artifact of the stage rather than a
// quality cache keyed by the mesh's digest: the stage has computed it anyway, the artifact is
// stored, verified, kept, collected and shipped to a remote cache with the mesh by the
// machinery every artifact already has, and the stage stays a pure function of its key; a side
// cache would need its own store, locking and garbage collection in the engine or a writer
// writing into the cache folder.
#pragma once

#include "stages/model/mesh.hpp"
#include "stages/model/quality.hpp"

#include <filesystem>
#include <optional>
#include <stdexcept>
#include <vector>
#include <string>

namespace meshflow {
struct Artifact;  // engine/stage.hpp
}

namespace meshflow::io {

struct MeshIOError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

enum class MeshFormat { MshBinary, MshAscii, Vtu, Nektar, NektarPlain, Cgns };

// By extension: .msh (any supported MSH version/encoding), .vtu, .xml, .cgns. Without an extension
// match (e.g. a file in the artifact store), the content decides ($MeshFormat, <VTKFile,
// <NEKTAR).
model::Mesh read_mesh(const std::filesystem::path& path);
// By extension (.msh: binary MSH 4.1; .vtu; .xml; .cgns) unless `format` is given.
void write_mesh(const model::Mesh& m, const std::filesystem::path& path);
void write_mesh(const model::Mesh& m, const std::filesystem::path& path, MeshFormat format);

model::Mesh read_msh(const std::filesystem::path& path);
void write_msh(const model::Mesh& m, const std::filesystem::path& path, bool binary = true);
model::Mesh read_vtu(const std::filesystem::path& path);
// The cell fields scaled_jacobian and valid come from `quality` (mesh_quality of m: read_quality
// of the stage's stored quality) when given, else they are computed (model::mesh_quality).
void write_vtu(const model::Mesh& m, const std::filesystem::path& path, const model::MeshQuality* quality = nullptr);

// The "mesh_quality" artifact (layout in quality_io.cpp): q = model::mesh_quality(m) of the mesh
// as the stage wrote it (write_msh keeps the non-empty blocks in order, and each element's
// quality is a function of its node coordinates only, which binary MSH keeps exactly).
void write_quality(const model::Mesh& m, const model::MeshQuality& q, const std::filesystem::path& path);
// Aligned with m's blocks (as mesh_quality(m) is). Throws MeshIOError when the file is not a
// quality file or its blocks (type, entity, count) are not m's.
model::MeshQuality read_quality(const std::filesystem::path& path, const model::Mesh& m);
// The quality a stage stored beside mesh m: the first "mesh_quality" among `artifacts` (of
// `stage`, when one is named), read with read_quality. None when there is none, or when it is not
// m's (`why`, when given, then says why): the caller computes it.
std::optional<model::MeshQuality> stored_quality(const std::vector<Artifact>& artifacts, const model::Mesh& m,
                                                 const std::string& stage = {}, std::string* why = nullptr);
// Reads both forms (plain and compressed sections, also mixed).
model::Mesh read_nektar(const std::filesystem::path& path);
// Compressed (Nektar++'s B64Z-LittleEndian VERTEX, EDGE, FACE, ELEMENT and CURVED sections)
// unless `compressed` is false; with an EXPANSIONS section (the mesh's order, every volume
// composite) so that the file is a session Nektar++ can start from.
void write_nektar(const model::Mesh& m, const std::filesystem::path& path, bool compressed = true);

// CGNS through libcgns, CGNS/ADF storage (HDF5 files carry time stamps): one base (cell dimension = the mesh's, physical 3), one
// unstructured zone "Zone" whose FamilyName is the volume's physical group; coordinates
// CoordinateX/Y/Z (RealDouble) of every node; one Elements_t section per cell shape and order
// (complete Lagrange types TETRA_4/10/20/35, PYRA_5/14/30/55, PENTA_6/18/40/75,
// HEXA_8/27/64/125; nodes in CGNS order), then per boundary physical group its TRI/QUAD
// sections, a BC_t over their element range (PointRange, GridLocation FaceCenter) with
// FamilyName = the group and BCType from the name (wall* BCWall, farfield BCFarfield,
// symmetry* BCSymmetryPlane, inlet/outlet BCInflow/BCOutflow, else FamilySpecified with a
// BCTypeUserDefined family), and a Family_t per group. Boundary elements in no physical group
// form groups "surface_<entity tag>"; a boundary entity in several groups is written under its
// first (a BC's range holds each element once); lines and points are not written. No DimensionalUnits:
// the mesh does not know its length unit (DataClass NormalizedByUnknownDimensional instead). Orders above 4 (CGNS has no such types), meshes
// past libcgns's 32-bit sizes and group names past 32 characters are refused (MeshIOError)
// before the file is made; the file is written under a temporary name and renamed.
void write_cgns(const model::Mesh& m, const std::filesystem::path& path);
// Reads what write_cgns writes and other tools' single-zone unstructured files of those types:
// coordinates, cells (one entity), boundary sections grouped by the BC that names their
// elements (its FamilyName, else its name; else the section's name) as physical groups of the
// boundary dimension; the zone's FamilyName as the cells' group. MIXED/NGON sections and
// incomplete types (QUAD_8, HEXA_20, ...) are refused, edge and point sections of a 3D zone
// skipped.
model::Mesh read_cgns(const std::filesystem::path& path);

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
