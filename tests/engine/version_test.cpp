// The project's version: part of every cache key (a new release never serves an older one's
// results), and `meshflow --version` names it with the commit the program was built from.
#include <doctest/doctest.h>

#include "engine/hash.hpp"
#include "engine/runner.hpp"
#include "engine/version.hpp"
#include "test_kinds.hpp"

#include <nlohmann/json.hpp>

#include <regex>

using namespace mftest;
using nlohmann::json;

TEST_CASE("version: every cache key's preimage names meshflow's version, and the key is the hash of that preimage") {
  WorkflowFixture f(R"(meshflow: 1
name: versioned
stages:
  a: {kind: t_source, with: {text: "ab", repeat: 2}}
  b: {kind: t_cat, needs: [a], with: {suffix: "-b"}}
)");
  auto r = f.run();
  INFO(r.out, r.err);
  REQUIRE(r.code == 0);
  CHECK(std::regex_match(std::string(meshflow::version()), std::regex(R"(\d+\.\d+\.\d+)")));
  int entries = 0;
  for (auto& e : fs::directory_iterator(f.cache / "actions")) {
    if (e.path().extension() != ".json") continue;
    json entry = json::parse(read_text(e.path()));
    const json& pre = entry.at("preimage");
    CHECK(pre.at("meshflow") == meshflow::version());
    CHECK(pre.at("engine") == meshflow::kEngineFormat);
    CHECK(e.path().stem().string() == meshflow::sha256_hex(meshflow::canonical_json(pre)));
    // another version gives another key
    json other = pre;
    other["meshflow"] = "0.0.0-other";
    CHECK(meshflow::sha256_hex(meshflow::canonical_json(other)) != e.path().stem().string());
    ++entries;
  }
  CHECK(entries == 2);
}

TEST_CASE("version: meshflow --version names the version and a commit of this repository, or says it has none") {
  auto r = sh(std::string(MESHFLOW_EXE) + " --version 2>&1");
  INFO(r.out);
  REQUIRE(r.code == 0);
  std::smatch m;
  const std::string out = r.out;
  REQUIRE(std::regex_search(out, m, std::regex(R"(^meshflow (\S+) \(commit ([0-9a-f]{12}|unknown: built outside a git checkout)(, with uncommitted changes)?\)\n$)")));
  CHECK(m[1].str() == meshflow::version());
  const std::string commit = m[2].str();
  if (fs::exists(fs::path(MESHFLOW_SOURCE_DIR) / ".git")) {
    REQUIRE(commit.size() == 12);  // built in a git checkout: the commit is known
    CHECK(sh("git -C " + std::string(MESHFLOW_SOURCE_DIR) + " cat-file -e " + commit + "^{commit} 2>&1").code == 0);
  }
}
