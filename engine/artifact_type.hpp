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
//     compared field by field with the tolerances of the workflow, and for report.json,
//   - load (optional): reads the artifact once for all its formats, with its companions.
//
// Companions: the other artifacts the stage that produced the artifact wrote in the same run
// (e.g. the per-element quality a mesh stage computed for its contract and stored beside its
// mesh). A type's `load` may use them so that its formats do not recompute what the stage has
// already computed; the engine only hands them over (verified against their digests) and
// keeps what `load` returns opaque: it never looks inside an artifact.
#pragma once

#include "engine/stage.hpp"

#include <nlohmann/json_fwd.hpp>

#include <filesystem>
#include <functional>
#include <map>
#include <memory>
#include <string>
#include <vector>

namespace meshflow {

struct ArtifactFormat {
  std::string extension;  // ".msh"
  std::string summary;    // "Gmsh MSH 4.1 binary"
  // Standalone: reads the artifact at `in` itself (no companions) and writes `out`.
  std::function<void(const std::filesystem::path& in, const std::filesystem::path& out)> write;
  // Optional: writes `out` from what the type's `load` returned (the runner loads an output's
  // artifact once for all such formats, then writes them in parallel: must not modify it).
  std::function<void(const void* loaded, const std::filesystem::path& out)> write_loaded;
};

struct ArtifactType {
  std::string type;       // "mesh"
  std::string extension;  // extension of the stored file itself, e.g. ".msh"
  std::string summary;
  std::map<std::string, ArtifactFormat> formats;  // by format name ("msh", "vtu", "nektar")
  // Summary for golden comparison; optional (a type without it is compared by digest).
  std::function<nlohmann::json(const std::filesystem::path& artifact)> summarize;
  // Optional: the artifact at `artifact` read into memory, with what it needs of `companions`
  // (see above; may be empty), for the formats that have `write_loaded`.
  std::function<std::shared_ptr<const void>(const std::filesystem::path& artifact, const std::vector<Artifact>& companions)> load;
};

void register_artifact_type(ArtifactType type);

struct ArtifactTypeRegistrar {
  explicit ArtifactTypeRegistrar(ArtifactType type) { register_artifact_type(std::move(type)); }
};

// The registered type, or nullptr.
const ArtifactType* find_artifact_type(const std::string& type);

}  // namespace meshflow
