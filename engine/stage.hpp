// meshflow engine — the public interface a stage kind is written against.
//
// A stage kind is a pure function of its cache key: validated parameters (schema defaults
// filled), the digests of its input artifacts, the digests of external files named by its
// parameters, its own `version` and the versions of the libraries it declares. It reads input
// artifacts (files in the content-addressed store, read-only), writes output artifacts to the
// paths the engine hands it, and fills `stats`. It never reads or writes anything else that
// could change its result, and it touches no globals shared with other stages.
//
// Each stage runs in its own child process (fork), so a crash, an abort or an out-of-memory
// kill in a stage is reported as that stage's failure and never corrupts the engine or the
// cache; peak memory is measured per stage.
//
// Registration (in the stage's own folder, e.g. stages/heal/heal.cpp):
//
//   static meshflow::StageRegistrar reg({
//       .kind = "heal", .version = 1,
//       .summary = "sew, fix and close the CAD into a watertight fluid solid",
//       .libraries = {"OCCT " OCC_VERSION_COMPLETE},
//       .needs = {"shape"}, .produces = {{"shape", "shape"}},
//       .run = [](meshflow::StageContext& ctx) { ... }});
//
// The kind's parameters are described by schemas/<kind>.schema.json (embedded at build
// time); a kind without a schema file is a build error caught by the engine's self-check
// (`meshflow kinds`).
#pragma once

#include <nlohmann/json_fwd.hpp>

#include <filesystem>
#include <functional>
#include <stdexcept>
#include <string>
#include <vector>

namespace meshflow {

// One artifact: one file in the content-addressed store.
struct Artifact {
  std::string name;            // the producing stage's name for it: "shape", "mesh", ...
  std::string type;            // a registered artifact type (see artifact_type.hpp)
  std::string digest;          // SHA-256 (hex) of the file's bytes
  std::string stage;           // name of the stage instance that produced it
  std::filesystem::path path;  // read-only file in the store
};

// A stage reports a problem with its input or parameters by throwing StageError with a
// message a user can act on (what is wrong, where, what to do). The engine prefixes the
// workflow file and stage name, exits non-zero and stores nothing for the stage.
struct StageError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

class StageContext {
 public:
  virtual ~StageContext() = default;

  // Parameters after schema validation with defaults filled (an object).
  virtual const nlohmann::json& params() const = 0;
  // Name of this stage instance in the workflow ("split", "split_fine", ...).
  virtual const std::string& stage_name() const = 0;

  // Output artifacts of the stages listed in `needs`, in the order of `needs`, each stage's
  // outputs in the order it declared them.
  virtual const std::vector<Artifact>& inputs() const = 0;
  // The first input of `type`; throws StageError naming the stage and the type if none.
  const Artifact& input(const std::string& type) const;
  // All inputs of `type` (possibly empty).
  std::vector<const Artifact*> inputs_of(const std::string& type) const;

  // Declares output artifact `name` of `type` and returns the path the stage must write it
  // to (a private scratch file). The engine hashes and stores it when run() returns, so the
  // stage must check its writes (stream state after close): a short write on a full disk
  // must throw, or a truncated artifact would be stored as complete.
  virtual std::filesystem::path output(const std::string& name, const std::string& type) = 0;

  // Resolves a file parameter (a schema property with "x-meshflow-file": true) to the path the
  // engine hashed for the key: relative paths are relative to the workflow file's folder.
  virtual std::filesystem::path file(const std::string& param_value) const = 0;

  // Progress of this stage, fraction in [0,1]; `what` is a short phrase ("sewing 12/40").
  virtual void progress(double fraction, const std::string& what = {}) = 0;
  // A line for the engine log (kept in the action entry, shown with --verbose).
  virtual void log(const std::string& line) = 0;
  // Free-form statistics of this run (an object); stored with the action entry and shown in
  // report.json. Mesh-producing stages put the mesh statistics under "mesh".
  // The result's contract: a stage whose output breaks what it promises (a mesh with inverted,
  // degenerate or untagged elements, ...) still writes it and lists the breaches under
  // "problems": an array of {"clause", "what", "count", "blocking", "where": [...], "hint"}.
  // The result is cached like any other (it is deterministic), but the engine gives the stage
  // the status "invalid" when a problem is blocking (no later stage can repair it: the stages
  // that need it are not run) or when the stage's result is delivered (an output, or no stage
  // needs it); the run then is not a success. A non-blocking problem of an intermediate result
  // (e.g. curving's inverted elements, which optimise repairs) is reported and passed on.
  virtual nlohmann::json& stats() = 0;
  // Number of threads this stage may use (the runner's budget for it).
  virtual int threads() const = 0;
};

// An artifact a kind writes: its name (ctx.output's first argument) and registered type.
struct ArtifactDecl {
  std::string name, type;
};

struct StageKind {
  std::string kind;                    // e.g. "heal"
  int version = 1;                     // bump when the output for the same key changes
  std::string summary;                 // one line for `meshflow kinds` and README
  std::vector<std::string> libraries;  // "name version" of libraries whose version is in the key
  // What the kind reads and writes, so that a workflow whose `needs` cannot supply a stage is
  // refused at load (exit 2) before anything runs, and `meshflow kinds KIND` can say it:
  //   needs     artifact types it must find among its inputs (ctx.input)
  //   reads     types it uses when a stage in its `needs` produces one (ctx.inputs_of)
  //   produces  what it writes (ctx.output), in that order; the first is an output's default
  // Every product kind declares `produces` (`meshflow kinds --check`), and the runner refuses an
  // undeclared ctx.output. Test kinds may leave all three empty: nothing is checked for them.
  std::vector<std::string> needs;
  std::vector<std::string> reads;
  std::vector<ArtifactDecl> produces;
  std::function<void(StageContext&)> run;
  // Inline JSON schema of the parameters. Empty (the rule for every product kind): the
  // schema is schemas/<kind>.schema.json. Tests define throwaway kinds with inline schemas.
  std::string schema;
  // The module (stages/ folder) the kind is compiled in: set by StageRegistrar. The SHA-256
  // of that module's code is part of the cache key, so a changed algorithm never hits a
  // stale cache entry even if `version` was not bumped.
  std::string module;
};

// Registers a stage kind; called from static initialisers (StageRegistrar).
void register_stage(StageKind kind);

// Code digest of a module, registered by the file cmake/module_digest.cmake generates for it.
void register_module_code(const std::string& module, const std::string& digest);
const std::string& module_code(const std::string& module);  // "" when unknown
struct ModuleCodeRegistrar {
  ModuleCodeRegistrar(const char* module, const char* digest) { register_module_code(module, digest); }
};

#ifndef MESHFLOW_MODULE_NAME
#define MESHFLOW_MODULE_NAME ""  // outside stages/ (tests): no module, no code digest
#endif
// Internal linkage: each translation unit's registrar picks up the module name it is compiled
// with (meshflow_module() defines MESHFLOW_MODULE_NAME for its sources).
namespace {
struct StageRegistrar {
  explicit StageRegistrar(StageKind kind) {
    if (kind.module.empty()) kind.module = MESHFLOW_MODULE_NAME;
    register_stage(std::move(kind));
  }
};
}  // namespace

}  // namespace meshflow
