// Geometry benchmark (issue 4): building the parametric wing_body half model (default CRM-like
// flat tip, and round tip + ogive nose) and healing it, and the cost of heal's self-intersection
// check (check_self_intersection full / edges / off) on the wing_body, the Rotor 67 sector, the
// paper's wing STEP and the DLR-F6 BREP. Writes a Markdown fragment to bench/results/wing_body.md (argv[1] overrides).
// Build and run: cmake --build BUILD --target geometry_bench && BUILD/bench/geometry_bench
#include "bench_context.hpp"
#include "engine/registry.hpp"
#include "engine/stage.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <sstream>
#include <unistd.h>
#include <vector>

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;
using meshflow::bench::BenchContext;
using meshflow::bench::secs;
using nlohmann::json;

namespace {
struct Run {
  double seconds = 0;
  json stats;
  meshflow::Artifact out;
};
Run run(const std::string& kind, json params, std::vector<meshflow::Artifact> in, const fs::path& dir) {
  BenchContext c(kind, std::move(params), std::move(in), dir);
  auto t0 = Clock::now();
  meshflow::find_stage_kind(kind)->run(c);
  return {secs(t0), c.st_, c.out_};
}
// Median wall time of n runs (after one warm-up run whose result is returned with it).
Run median(int n, const std::string& kind, const json& params, const std::vector<meshflow::Artifact>& in,
           const fs::path& dir) {
  Run r = run(kind, params, in, dir);
  std::vector<double> t;
  for (int i = 0; i < n; ++i) t.push_back(run(kind, params, in, dir).seconds);
  std::sort(t.begin(), t.end());
  r.seconds = t[t.size() / 2];
  return r;
}
std::string f3(double v) {
  char b[32];
  std::snprintf(b, sizeof b, "%.3f", v);
  return b;
}
double loadavg() {
  double l = 0;
  if (FILE* f = std::fopen("/proc/loadavg", "r")) {
    if (std::fscanf(f, "%lf", &l) != 1) l = 0;
    std::fclose(f);
  }
  return l;
}
}  // namespace

int main(int argc, char** argv) {
  fs::path out = argc > 1 ? fs::path(argv[1]) : fs::path(MESHFLOW_SOURCE_DIR) / "bench/results/wing_body.md";
  fs::path data = MESHFLOW_DATA_DIR;
  fs::path dir = fs::temp_directory_path() / ("meshflow-geometry-bench-" + std::to_string(::getpid()));
  fs::create_directories(dir);
  std::ostringstream md;
  md << "## Geometry: wing_body and heal's self-intersection check\n\n"
        "`cmake --build build --target geometry_bench && build/bench/geometry_bench` (Release, 1 thread; wall time, "
        "median of 3 runs after a warm-up unless noted; load average at start "
     << f3(loadavg()) << " on the shared 2-core machine).\n\n";
  md << "| model | build s | heal s (check full) | heal s (edges) | heal s (off) | faces | junction edges / length | "
        "self-intersections |\n|---|---|---|---|---|---|---|---|\n";
  struct Case {
    const char* name;
    json params;
  };
  for (const Case& c : {Case{"wing_body default (CRM-like, flat tip)", json::object()},
                        Case{"wing_body round tip, ogive nose", {{"tip", "round"}, {"nose", "ogive"}}}}) {
    Run g = median(3, "wing_body", c.params, {}, dir);
    Run on = median(3, "heal", json::object(), {g.out}, dir);
    Run edges = median(3, "heal", {{"check_self_intersection", "edges"}}, {g.out}, dir);
    Run off = median(3, "heal", {{"check_self_intersection", "off"}}, {g.out}, dir);
    std::ostringstream row;
    row << "| " << c.name << " | " << f3(g.seconds) << " | " << f3(on.seconds) << " | " << f3(edges.seconds) << " | "
        << f3(off.seconds) << " | "
        << g.stats["faces"].get<int>() << " | " << g.stats["junction"]["edges"].get<int>() << " / "
        << f3(g.stats["junction"]["length"].get<double>()) << " | " << on.stats["self_intersections"].get<int>()
        << " |\n";
    md << row.str();
    std::cout << row.str() << std::flush;
  }
  md << "\nFiles (one run each, no warm-up):\n\n"
        "| input | import/build s | heal s (check full) | heal s (edges) | heal s (off) | faces after heal | "
        "self-intersections |\n|---|---|---|---|---|---|---|\n";
  for (auto name : {"rotor67/rotor67geometry.dat", "wingtip/3d_bl_wing.stp", "dlr_f6/dlr_f6.brep"}) {
    bool rotor = std::string(name).find("rotor67") != std::string::npos;
    Run imp = rotor ? run("blade_sector", {{"file", (data / name).string()}, {"format", "rotor67"}, {"upstream", 1.0},
                                           {"downstream", 1.0}}, {}, dir)
                    : run("step", {{"file", (data / name).string()}}, {}, dir);
    Run on = run("heal", json::object(), {imp.out}, dir);
    Run edges = run("heal", {{"check_self_intersection", "edges"}}, {imp.out}, dir);
    Run off = run("heal", {{"check_self_intersection", "off"}}, {imp.out}, dir);
    std::ostringstream row;
    row << "| " << name << " | " << f3(imp.seconds) << " | " << f3(on.seconds) << " | " << f3(edges.seconds) << " | "
        << f3(off.seconds) << " | "
        << on.stats["after"]["faces"].get<int>() << " | " << on.stats["self_intersections"].get<int>() << " |\n";
    md << row.str();
    std::cout << row.str() << std::flush;
  }
  std::ofstream(out) << md.str();
  fs::remove_all(dir);
  std::cout << "wrote " << out << "\n";
}
