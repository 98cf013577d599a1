// `meshflow contract FILE`: the mesh contract's clauses that need no CAD (validity, degenerate,
// conformity, tags, closure of the boundary) on any mesh file meshflow reads, e.g. one written
// by another tool or by an earlier meshflow. Exit 0 when it keeps them, 3 when not (as `run`).
#include "engine/command.hpp"
#include "stages/contract/contract.hpp"
#include "stages/io/mesh_io.hpp"

#include <cstdlib>
#include <iostream>

namespace meshflow::contract {
namespace {

int contract_cmd(const std::vector<std::string>& args) {
  const char* usage = "usage: meshflow contract FILE [--json] [--threads N]\n";
  std::string file;
  bool as_json = false;
  int threads = 0;
  for (size_t i = 0; i < args.size(); ++i) {
    if (args[i] == "--json") as_json = true;
    else if (args[i] == "--threads" && i + 1 < args.size()) threads = std::atoi(args[++i].c_str());
    else if (!args[i].empty() && args[i][0] == '-') {
      std::cerr << "meshflow contract: unknown option " << args[i] << "\n" << usage;
      return 2;
    } else if (file.empty()) file = args[i];
    else {
      std::cerr << "meshflow contract: one FILE expected\n" << usage;
      return 2;
    }
  }
  if (file.empty()) {
    std::cerr << usage;
    return 2;
  }
  Result r;
  try {
    r = check(io::read_mesh(file), Extent::Domain, nullptr, threads);
  } catch (const std::exception& e) {
    std::cerr << "meshflow contract: " << e.what() << "\n";
    return 2;
  }
  if (as_json) {
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
