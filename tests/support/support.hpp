// Helpers shared by the test executables: temp folders, files, child processes.
#pragma once

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <nlohmann/json_fwd.hpp>
#include <string>
#include <vector>

namespace mftest {

namespace fs = std::filesystem;

// A fresh empty folder under the system temp folder, unique to this process and call. The
// shared test main removes every such folder when the run passes (kept when a test fails, or
// with MESHFLOW_KEEP_TEST_DIRS set, to look into).
fs::path temp_dir(const std::string& tag);
void remove_temp_dirs();
void write_text(const fs::path& p, const std::string& text);  // creates parent folders
std::string read_text(const fs::path& p);                      // "" if unreadable
// A copy of the workflow `src` at `dst` without the top-level entries (stages and outputs)
// named in `drop` (lines "  <name>:" of the file; each must exist): a shorter variant of a
// real workflow; relative `file:` paths are made absolute (they are relative to src's folder).
// Returns dst as a string.
std::string workflow_without(const fs::path& src, const fs::path& dst, const std::vector<std::string>& drop);

// The `stats` of the stage named `stage` in a run's report.json (parsed, or in the output folder
// `out`); an empty object when the report has no such stage or it has no stats.
nlohmann::json stage_stats(const nlohmann::json& report, const std::string& stage);
nlohmann::json stage_stats(const fs::path& out, const std::string& stage);

// Starts argv[0] with argv (stdout and stderr to `log`); returns the pid.
int spawn(const std::vector<std::string>& argv, const fs::path& log);
// Exit code of the child, or 128 + signal.
int wait_exit(int pid);

struct ShellResult {
  int code;
  std::string out;  // stdout and stderr
};
// Runs a shell command line.
ShellResult sh(const std::string& command);

// Feeds every file of a fuzz corpus folder to a libFuzzer entry point (as the fuzzer would),
// checking that it returns 0 and throws nothing; a crash fails the test process. Returns the
// number of files.
int replay_corpus(const fs::path& dir, int (*entry)(const std::uint8_t*, std::size_t));

// Runs the meshflow command line in this process (meshflow::cli_main with "meshflow" as
// argv[0]), capturing what it prints.
struct Cli {
  int code;
  std::string out, err;
};
Cli run_cli(std::vector<std::string> args);

}  // namespace mftest
