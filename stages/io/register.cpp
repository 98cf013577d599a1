// stages/io's registrations with the engine: the "mesh" artifact type (stored as binary MSH
// 4.1; formats msh (the stored file), msh-ascii, msh-plain and pyfr (solver-ready), vtu, nektar (compressed), nektar-plain, cgns; summary =
// mesh_stats; load: the mesh read once for all formats, with the quality its stage stored), the
// "mesh_quality" type and the commands `meshflow quality FILE [--json] [--threads N]` and
// `meshflow convert IN OUT [--ascii] [--parametric] [--all-elements] [--plain]`.
#include "engine/artifact_type.hpp"
#include "engine/command.hpp"
#include "stages/io/mesh_io.hpp"
#include "stages/model/quality.hpp"

#include <nlohmann/json.hpp>

#include <cstdio>
#include <fstream>
#include <iostream>
#include <memory>
#include <optional>

namespace meshflow::io {

namespace {
std::string ext_of(const std::filesystem::path& p) {
  std::string e = p.extension().string();
  for (auto& c : e) c = (char)std::tolower((unsigned char)c);
  return e;
}
std::string sniff(const std::filesystem::path& p) {
  std::ifstream in(p, std::ios::binary);
  char buf[512] = {0};
  in.read(buf, sizeof buf - 1);
  std::string s(buf, (size_t)in.gcount());
  if (s.rfind("$MeshFormat", 0) == 0) return ".msh";
  if (s.find("<VTKFile") != std::string::npos) return ".vtu";
  if (s.find("<NEKTAR") != std::string::npos) return ".xml";
  if (s.rfind("\x89HDF\r\n\x1a\n", 0) == 0 || s.compare(4, 20, "ADF Database Version") == 0) return ".cgns";
  return {};
}
}  // namespace

model::Mesh read_mesh(const std::filesystem::path& path) {
  if (!std::filesystem::exists(path)) throw MeshIOError(path.string() + ": no such file");
  std::string e = ext_of(path);
  if (e != ".msh" && e != ".vtu" && e != ".xml" && e != ".cgns") e = sniff(path);
  if (e == ".msh") return read_msh(path);
  if (e == ".vtu") return read_vtu(path);
  if (e == ".xml") return read_nektar(path);
  if (e == ".cgns") return read_cgns(path);
  throw MeshIOError(path.string() + ": unknown mesh format (expected .msh, .vtu, Nektar++ .xml or .cgns)");
}

void write_mesh(const model::Mesh& m, const std::filesystem::path& path, MeshFormat f) {
  switch (f) {
    case MeshFormat::MshBinary: return write_msh(m, path, true);
    case MeshFormat::MshAscii: return write_msh(m, path, false);
    case MeshFormat::Vtu: return write_vtu(m, path);
    case MeshFormat::Nektar: return write_nektar(m, path, true);
    case MeshFormat::NektarPlain: return write_nektar(m, path, false);
    case MeshFormat::Cgns: return write_cgns(m, path);
  }
}

void write_mesh(const model::Mesh& m, const std::filesystem::path& path) {
  std::string e = ext_of(path);
  if (e == ".msh") return write_msh(m, path, true);
  if (e == ".vtu") return write_vtu(m, path);
  if (e == ".xml") return write_nektar(m, path);
  if (e == ".cgns") return write_cgns(m, path);
  throw MeshIOError(path.string() + ": unknown mesh format for writing (use .msh, .vtu, .xml or .cgns)");
}

namespace {

int quality_cmd(const std::vector<std::string>& args) {
  FileCommandArgs a;
  if (!parse_file_command("quality", args, a)) return 2;
  const std::string& file = a.file;
  try {
    auto m = read_mesh(file);
    auto s = model::mesh_stats(m, a.threads);
    if (a.json) {
      std::cout << s.dump(2) << "\n";
    } else {
      std::cout << file << ": order " << s["order"] << ", " << s["nodes"] << " nodes\n";
      std::cout << "  elements:";
      for (auto& [k, v] : s["elements"].items()) std::cout << " " << k << " " << v;
      std::cout << "\n  boundary:";
      for (auto& [k, v] : s["boundary"].items()) std::cout << " " << k << " " << v;
      std::cout << "\n  invalid elements: " << s["invalid"] << " (" << s["validity_method"].get<std::string>() << ")";
      if (s["invalid"].get<size_t>()) std::cout << "  tags: " << s["invalid_elements"].dump();
      std::cout << "\n  non-conforming faces: " << s["nonconforming_faces"] << "\n";
      std::cout << "  scaled Jacobian: min " << s["min_scaled_jacobian"] << ", median " << s["median_scaled_jacobian"] << "\n";
      std::cout << "  max aspect ratio: " << s["max_aspect_ratio"] << "\n";
    }
    return 0;
  } catch (const std::exception& e) {
    std::cerr << "meshflow quality: " << e.what() << "\n";
    return 2;
  }
}

const char* kConvertUsage =
    "usage: meshflow convert IN OUT [--ascii] [--parametric] [--all-elements] [--plain]\n"
    "  formats by extension: .msh (Gmsh MSH 4.1) .vtu .xml (Nektar++) .cgns (CGNS/ADF, orders 1-4)\n"
    "  to .msh: binary unless --ascii; solver-ready by default: no CAD parameters on the nodes (--parametric keeps\n"
    "  them, for Gmsh) and only elements in a physical group (--all-elements keeps the CAD curves' edges too)\n"
    "  to .xml: Nektar++'s compressed geometry (as NekMesh writes it) unless --plain (plain-text numbers)\n";

int convert_cmd(const std::vector<std::string>& args) {
  std::vector<std::string> files;
  bool ascii = false, parametric = false, all_elements = false, plain = false;
  for (auto& a : args) {
    if (a == "--ascii") ascii = true;
    else if (a == "--parametric") parametric = true;
    else if (a == "--no-parametric") parametric = false;  // the default; kept for scripts written before it was
    else if (a == "--all-elements") all_elements = true;
    else if (a == "--plain") plain = true;
    else if (a == "--help" || a == "-h") {
      std::cout << kConvertUsage;
      return 0;
    } else if (!a.empty() && a[0] == '-') {
      std::cerr << "meshflow convert: unknown option " << a << "\n" << kConvertUsage;
      return 2;
    } else files.push_back(a);
  }
  if (files.size() != 2) {
    std::cerr << kConvertUsage;
    return 2;
  }
  try {
    auto m = read_mesh(files[0]);
    std::string e = ext_of(files[1]);
    if (e == ".msh") {
      if (all_elements) {
        if (!parametric) m.node_u.clear(), m.node_v.clear();
      } else {
        make_solver_ready(m, parametric);
      }
      write_msh(m, files[1], !ascii);
      if (plain) std::cerr << "meshflow convert: --plain applies to .xml output only; ignored for " << files[1] << "\n";
    } else {
      if (ascii || parametric || all_elements)
        std::cerr << "meshflow convert: --ascii, --parametric and --all-elements apply to .msh output only; ignored for "
                  << files[1] << "\n";
      if (e == ".xml") write_nektar(m, files[1], !plain);
      else {
        if (plain) std::cerr << "meshflow convert: --plain applies to .xml output only; ignored for " << files[1] << "\n";
        write_mesh(m, files[1]);
      }
    }
    return 0;
  } catch (const std::exception& e) {
    std::cerr << "meshflow convert: " << e.what() << "\n";
    return 2;
  }
}

// The mesh artifact as the runner loads it once for all the formats of an output (ArtifactType::
// load): the mesh, and the quality its stage stored beside it (the companion of type
// "mesh_quality") for VTU's cell fields. A quality file that is not this mesh's (its blocks
// differ: never from a stage that wrote both) is not used: the cell fields are computed then.
struct LoadedMesh {
  model::Mesh mesh;
  std::optional<model::MeshQuality> quality;
};

std::shared_ptr<const void> load_mesh(const std::filesystem::path& in, const std::vector<Artifact>& companions) {
  auto l = std::make_shared<LoadedMesh>();
  l->mesh = read_msh(in);
  l->quality = stored_quality(companions, l->mesh);
  return l;
}
const LoadedMesh& loaded(const void* p) { return *static_cast<const LoadedMesh*>(p); }

ArtifactFormat fmt(const char* ext, const char* summary, MeshFormat f) {
  return {ext, summary,
          [f](const std::filesystem::path& in, const std::filesystem::path& out) { write_mesh(read_msh(in), out, f); },
          [f](const void* p, const std::filesystem::path& out) {
            const LoadedMesh& l = loaded(p);
            if (f == MeshFormat::Vtu) write_vtu(l.mesh, out, l.quality ? &*l.quality : nullptr);
            else write_mesh(l.mesh, out, f);
          }};
}

// The stored artifact is binary MSH 4.1 written by write_mesh: the msh format is a copy of it
// (reading and writing it again gave the same bytes and cost seconds on large meshes).
ArtifactFormat stored_copy() {
  return {".msh", "Gmsh MSH 4.1 binary", [](const std::filesystem::path& in, const std::filesystem::path& out) {
            namespace fs = std::filesystem;
            fs::copy_file(in, out, fs::copy_options::overwrite_existing);
            fs::permissions(out, fs::perms::owner_write, fs::perm_options::add);  // the store's objects are read-only
          }};
}

// The solver-ready MSH formats (make_solver_ready): no CAD parameters, every element in a
// physical group; `pyfr` adds PyFR's naming rules (apply_pyfr_names).
ArtifactFormat solver_msh(const char* ext, const char* summary, bool binary, bool pyfr) {
  auto write = [binary, pyfr](model::Mesh m, const std::filesystem::path& out) {
    make_solver_ready(m);
    if (pyfr) apply_pyfr_names(m);
    write_msh(m, out, binary);
  };
  return {ext, summary, [write](const std::filesystem::path& in, const std::filesystem::path& out) { write(read_msh(in), out); },
          [write](const void* p, const std::filesystem::path& out) { write(loaded(p).mesh, out); }};
}

// The per-element quality a mesh stage stores beside its mesh (quality_io.cpp): materialised
// as is (no formats); the mesh's formats read it.
const ArtifactTypeRegistrar quality_type({
    .type = "mesh_quality",
    .extension = ".quality",
    .summary = "per-element quality of the mesh its stage wrote beside it (det J bounds, scaled Jacobian, aspect ratio, validity)",
});

const ArtifactTypeRegistrar mesh_type({
    .type = "mesh",
    .extension = ".msh",
    .summary = "high-order hybrid mesh (stored as binary Gmsh MSH 4.1)",
    .formats = {{"msh", stored_copy()},
                {"msh-ascii", solver_msh(".ascii.msh", "Gmsh MSH 4.1 ASCII, solver-ready (no CAD parameters, every element in a physical group)", false, false)},
                {"msh-plain", solver_msh(".plain.msh", "Gmsh MSH 4.1 binary, solver-ready (no CAD parameters, every element in a physical group; meshio reads it)", true, false)},
                {"pyfr", solver_msh(".pyfr.msh", "Gmsh MSH 4.1 ASCII for `pyfr import`: solver-ready, physical tags unique, periodic pair named periodic_0_l / periodic_0_r", false, true)},
                {"vtu", fmt(".vtu", "VTK XML unstructured grid with Lagrange cells", MeshFormat::Vtu)},
                {"nektar", fmt(".xml", "Nektar++ XML session (compressed geometry, as NekMesh writes it, and EXPANSIONS)", MeshFormat::Nektar)},
                {"nektar-plain", fmt(".plain.xml", "Nektar++ XML session with plain-text geometry (NekMesh's :xml:uncompress form)", MeshFormat::NektarPlain)},
                {"cgns", fmt(".cgns", "CGNS (ADF): one unstructured zone, Lagrange sections at the mesh's order (1-4), a BC and family per boundary group", MeshFormat::Cgns)}},
    .summarize = [](const std::filesystem::path& p) { return model::mesh_stats(read_msh(p)); },
    .load = load_mesh,
});

const CommandRegistrar quality_reg({"quality", "quality FILE [--json] [--threads N]",
                                    "validity (Bezier bounds of det J), scaled Jacobian, aspect ratio of a mesh",
                                    quality_cmd});
const CommandRegistrar convert_reg({"convert", "convert IN OUT [--ascii] [--parametric] [--all-elements] [--plain]",
                                    "convert meshes between .msh (4.1; reads 2.2), .vtu, Nektar++ .xml and .cgns", convert_cmd});

}  // namespace
}  // namespace meshflow::io
