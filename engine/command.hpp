// meshflow engine — extra subcommands registered by modules (e.g. `meshflow quality FILE`,
// `meshflow convert IN OUT` from stages/io), so the CLI stays ignorant of meshes and CAD.
#pragma once

#include <functional>
#include <string>
#include <vector>

namespace meshflow {

struct Command {
  std::string name;     // "quality"
  std::string usage;    // "quality FILE [--json]"
  std::string summary;  // one line for `meshflow --help`
  // args excludes the program and command names; returns the process exit code.
  // Errors: print a one-paragraph message to stderr (file, line/offset, what to do), return 2.
  std::function<int(const std::vector<std::string>& args)> run;
};

void register_command(Command command);
const Command* find_command(const std::string& name);
std::vector<const Command*> all_commands();  // sorted by name

// The arguments of a command of the form `NAME FILE [--json] [--threads N]` (quality,
// contract). False after printing what is wrong and the usage to stderr (exit 2).
struct FileCommandArgs {
  std::string file;
  bool json = false;
  int threads = 0;
};
bool parse_file_command(const std::string& name, const std::vector<std::string>& args, FileCommandArgs& out);

struct CommandRegistrar {
  explicit CommandRegistrar(Command c) { register_command(std::move(c)); }
};

}  // namespace meshflow
