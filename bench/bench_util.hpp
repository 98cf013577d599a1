// Small helpers shared by the benchmarks that run the meshflow executable (pipeline, scaling):
// elapsed seconds, fixed-precision numbers for the tables, medians of repeated runs, one
// `meshflow run` with its report, and lookups in report.json.
#pragma once

#include <nlohmann/json.hpp>

#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <sstream>
#include <string>
#include <vector>

namespace meshflow::bench {

using Clock = std::chrono::steady_clock;

inline double secs(Clock::time_point a) { return std::chrono::duration<double>(Clock::now() - a).count(); }

inline std::string fmt(double v, int prec = 2) {
  std::ostringstream o;
  o << std::fixed << std::setprecision(prec) << v;
  return o.str();
}

inline double median(std::vector<double> v) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  const size_t n = v.size();
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

// One `meshflow run WORKFLOW --cache DIR/cache --out DIR/out EXTRA` in DIR (log in DIR/log.txt),
// under `timeout` when timeout_s > 0: wall time, exit code (124: the time limit), report.json, log.
struct Run {
  double wall = 0;
  nlohmann::json report;
  int code = 0;
  std::string log;
};

inline Run run_meshflow(const std::filesystem::path& dir, const std::string& workflow, const std::string& extra,
                        int timeout_s = 0) {
  const std::string limit = timeout_s > 0 ? "timeout -s TERM " + std::to_string(timeout_s) + " " : "";
  const std::string cmd = "cd " + dir.string() + " && " + limit + MESHFLOW_EXE + " run " + workflow + " --cache " +
                          (dir / "cache").string() + " --out " + (dir / "out").string() + " " + extra + " > " +
                          (dir / "log.txt").string() + " 2>&1";
  const auto t0 = Clock::now();
  Run r;
  const int st = std::system(cmd.c_str());
  r.wall = secs(t0);
  r.code = WIFEXITED(st) ? WEXITSTATUS(st) : 128 + WTERMSIG(st);
  std::ifstream in(dir / "out" / "report.json");
  if (in) r.report = nlohmann::json::parse(in);
  std::ifstream lg(dir / "log.txt");
  std::stringstream ss;
  ss << lg.rdbuf();
  r.log = ss.str();
  return r;
}

// An empty scratch folder for one benchmark case: $TMPDIR/mf-<name>-<pid>, removed and made again.
inline std::filesystem::path fresh_dir(const std::string& name) {
  auto dir = std::filesystem::temp_directory_path() / ("mf-" + name + "-" + std::to_string(getpid()));
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  return dir;
}

// The entry of stage `name` in a report.json (null if absent).
inline const nlohmann::json* stage(const nlohmann::json& rep, const std::string& name) {
  for (auto& s : rep.at("stages"))
    if (s.at("name") == name) return &s;
  return nullptr;
}

// 3D elements of a stats.mesh object.
inline long volume_elements(const nlohmann::json& mesh_stats) {
  long n = 0;
  for (const char* k : {"tet", "prism", "hex", "pyramid"}) n += mesh_stats.at("elements").value(k, 0L);
  return n;
}

}  // namespace meshflow::bench
