// meshflow engine — the project's version and the commit a build is made from. The version
// (CMakeLists.txt's project(VERSION), also in CHANGELOG.md) is part of every cache key's
// preimage; the commit is not (it changes with every edit of the tree, not only the algorithms).
#pragma once

#include <string>

namespace meshflow {

// "0.1.0"
const char* version();

// "1acee48d93ee", "1acee48d93ee-dirty" (built with uncommitted changes), or "" when built
// outside a git checkout (a source tarball) without -DMESHFLOW_COMMIT=...
const char* build_commit();

// What `meshflow --version` prints: "meshflow 0.1.0 (commit 1acee48d93ee)", or
// "meshflow 0.1.0 (commit unknown: built outside a git checkout)".
std::string version_line();

}  // namespace meshflow
