// meshflow engine — artifact types.
//
// The engine stores artifacts as opaque files. What a type means is known only to the folder
// that registers it (e.g. stages/io registers "mesh", stages/cad registers "shape"). A type
// tells the engine:
//   - the file extension used when the artifact is materialised as is (`outputs:` without
//     `formats`),
//   - exporters: named formats (`outputs: {mesh: {from: split, formats: [msh, vtu]}}`), each
//     writing the artifact to a file in that format,
//   - summarize: a JSON summary of the artifact for golden regression (`meshflow check`),
//     compared field by field with the tolerances of the workflow, and for report.json.
#pragma once

#include <nlohmann/json_fwd.hpp>

#include <filesystem>
#include <functional>
#include <map>
#include <string>

namespace meshflow {

struct ArtifactFormat {
  std::string extension;  // ".msh"
  std::string summary;    // "Gmsh MSH 4.1 binary"
  std::function<void(const std::filesystem::path& in, const std::filesystem::path& out)> write;
};

struct ArtifactType {
  std::string type;       // "mesh"
  std::string extension;  // extension of the stored file itself, e.g. ".msh"
  std::string summary;
  std::map<std::string, ArtifactFormat> formats;  // by format name ("msh", "vtu", "nektar")
  // Summary for golden comparison; optional (a type without it is compared by digest).
  std::function<nlohmann::json(const std::filesystem::path& artifact)> summarize;
};

void register_artifact_type(ArtifactType type);

struct ArtifactTypeRegistrar {
  explicit ArtifactTypeRegistrar(ArtifactType type) { register_artifact_type(std::move(type)); }
};

// The registered type, or nullptr.
const ArtifactType* find_artifact_type(const std::string& type);

}  // namespace meshflow
