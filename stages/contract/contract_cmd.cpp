// `meshflow contract FILE`: the mesh contract's clauses that need no CAD (validity, degenerate,
// conformity, tags, closure of the boundary) on any mesh file meshflow reads, e.g. one written
// by another tool or by an earlier meshflow. Exit 0 when it keeps them, 3 when not (as `run`).
#include "engine/command.hpp"
#include "stages/contract/contract.hpp"
#include "stages/io/mesh_io.hpp"

#include <iostream>

namespace meshflow::contract {
namespace {

int contract_cmd(const std::vector<std::string>& args) {
  FileCommandArgs a;
  if (!parse_file_command("contract", args, a)) return 2;
  const std::string& file = a.file;
  Result r;
  try {
    r = check(io::read_mesh(file), Extent::Domain, nullptr, a.threads);
  } catch (const std::exception& e) {
    std::cerr << "meshflow contract: " << e.what() << "\n";
    return 2;
  }
  if (a.json) {
    std::cout << nlohmann::json{{"file", file}, {"ok", r.ok()}, {"contract", r.contract}, {"problems", r.problems}}.dump(2)
              << "\n";
  } else {
    std::cout << file << ": " << (r.ok() ? "keeps the mesh contract (no CAD: coverage and volume not checked)" : "INVALID")
              << "\n";
    for (auto& p : r.problems) {
      std::cout << "  " << p["clause"].get<std::string>() << ": " << p["what"].get<std::string>();
      if (!p["where"].empty()) std::cout << "; first: " << p["where"][0].dump();
      std::cout << "\n";
    }
  }
  return r.ok() ? 0 : 3;
}

const CommandRegistrar reg({"contract", "contract FILE [--json] [--threads N]",
                            "check a mesh file against the mesh contract's clauses that need no CAD; exit 3 if it breaks one",
                            contract_cmd});

}  // namespace
}  // namespace meshflow::contract
