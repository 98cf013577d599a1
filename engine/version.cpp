// meshflow engine — version() and version_line(). build_commit() is generated at build time
// (cmake/build_info.cmake) into the meshflow executable's own sources; the weak definition here
// ("" = unknown) serves the other programs that link the engine (tests, benchmarks, fuzzers), so
// that a new commit relinks only the meshflow executable.
#include "engine/version.hpp"

namespace meshflow {

const char* version() { return MESHFLOW_VERSION; }

__attribute__((weak)) const char* build_commit() { return ""; }

std::string version_line() {
  std::string c = build_commit();
  std::string line = std::string("meshflow ") + version() + " (commit ";
  if (c.empty()) return line + "unknown: built outside a git checkout)";
  const std::string dirty = "-dirty";
  if (c.size() > dirty.size() && c.compare(c.size() - dirty.size(), dirty.size(), dirty) == 0)
    return line + c.substr(0, c.size() - dirty.size()) + ", with uncommitted changes)";
  return line + c + ")";
}

}  // namespace meshflow
