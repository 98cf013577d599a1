// Shell benchmark (issue 5): (1) medial + shell at default parameters on the paper's wing STEP
// and on the DLR-F6 BREP (after heal): wall time of each stage and peak RSS; (2) the medial
// stage's time versus its number of samples at 3 sampling densities on the wing STEP (one
// pass, `spacing` 0.01 / 0.005 / 0.0025 of the walls' diagonal), with the exponent of
// t = c n^k fitted by least squares in log-log (n log n shows as k slightly above 1).
// Writes a Markdown fragment to bench/results/shell.md (argv[1] overrides the path).
// Build and run: cmake --build BUILD --target shell_bench && BUILD/bench/shell_bench
#include "bench_context.hpp"
#include "engine/registry.hpp"
#include "engine/stage.hpp"

#include <nlohmann/json.hpp>

#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iostream>
#include <sstream>
#include <vector>

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;
using meshflow::bench::BenchContext;
using meshflow::bench::secs;

namespace {
double peak_mb() {
  rusage ru{};
  getrusage(RUSAGE_SELF, &ru);
  return ru.ru_maxrss / 1024.0;
}
meshflow::Artifact run(const std::string& kind, nlohmann::json p, std::vector<meshflow::Artifact> in, const fs::path& dir,
                       nlohmann::json* stats = nullptr, double* seconds = nullptr) {
  BenchContext c(kind, std::move(p), std::move(in), dir);
  auto t0 = Clock::now();
  meshflow::find_stage_kind(kind)->run(c);
  if (seconds) *seconds = secs(t0);
  if (stats) *stats = c.st_;
  return c.out_;
}
// Runs f in a forked child so that its peak RSS is its own (not the cumulative one of the
// bench process); the child writes one line of text into a pipe.
std::string in_child(const std::function<std::string()>& f) {
  int fd[2];
  if (pipe(fd) != 0) return "pipe failed";
  pid_t pid = fork();
  if (pid == 0) {
    close(fd[0]);
    std::string s;
    try {
      s = f();
    } catch (const std::exception& e) {
      s = std::string("failed: ") + e.what();
    }
    if (write(fd[1], s.data(), s.size()) < 0) _exit(2);
    close(fd[1]);
    _exit(0);
  }
  close(fd[1]);
  std::string out;
  char buf[4096];
  ssize_t n;
  while ((n = read(fd[0], buf, sizeof buf)) > 0) out.append(buf, static_cast<std::size_t>(n));
  close(fd[0]);
  int status = 0;
  waitpid(pid, &status, 0);
  return out;
}
}  // namespace

int main(int argc, char** argv) {
  fs::path out = argc > 1 ? fs::path(argv[1]) : fs::path(MESHFLOW_SOURCE_DIR) / "bench/results/shell.md";
  fs::path data = MESHFLOW_DATA_DIR;
  fs::path dir = fs::temp_directory_path() / ("meshflow-shell-bench-" + std::to_string(::getpid()));
  fs::create_directories(dir);
  auto healed = [&](const std::string& file, nlohmann::json extra) {
    nlohmann::json p = {{"file", (data / file).string()}};
    p.update(extra);
    return run("heal", nlohmann::json::object(), {run("step", p, {}, dir)}, dir);
  };
  std::ostringstream md;
  md << "## Shell\n\n`cmake --build build --target shell_bench && build/bench/shell_bench` (Release, 1 thread, wall time; "
        "each case in its own forked process, so peak RSS is that case's: geometry + heal + medial + shell). The machine is a shared 2-core box: the same run varied 2-3x in wall time between repetitions, so the exponent is the meaningful figure, not the seconds.\n\n";
  md << "Medial + shell at default parameters (shell: thickness 0.05 of the walls' box, topology C, spacing 0.01):\n\n";
  md << "| input | medial samples | medial s | shell s | medial + shell s | peak MB | shell triangles | junction blocks | "
        "self-intersecting pairs | faces unsampled |\n|---|---|---|---|---|---|---|---|---|---|\n";
  struct Case {
    std::string name, file;
    nlohmann::json extra;
  };
  for (const Case& c : {Case{"wingtip/3d_bl_wing.stp", "wingtip/3d_bl_wing.stp", nlohmann::json::object()},
                        Case{"dlr_f6/dlr_f6.brep", "dlr_f6/dlr_f6.brep", {{"units", "mm"}}}}) {
    std::string row = in_child([&] {
      auto shape = healed(c.file, c.extra);
      nlohmann::json ms, ss;
      double tm = 0, ts = 0;
      auto med = run("medial", nlohmann::json::object(), {shape}, dir, &ms, &tm);
      run("shell", nlohmann::json::object(), {shape, med}, dir, &ss, &ts);
      char b[512];
      std::snprintf(b, sizeof b, "| %s | %ld | %.2f | %.2f | %.2f | %.0f | %ld | %ld | %ld | %ld |\n", c.name.c_str(),
                    ms["samples_per_pass"].back().get<long>(), tm, ts, tm + ts, peak_mb(), ss["shell_triangles"].get<long>(),
                    ss["counts"]["hex_junction_blocks"].get<long>(), ss["self_intersections"].get<long>(),
                    ss["faces_unsampled"].get<long>());
      return std::string(b);
    });
    if (row.rfind("failed", 0) == 0) row = "| " + c.name + " | " + row + " |\n";
    md << row;
    std::cout << row << std::flush;
  }
  md << "\nMedial stage time versus samples (wing STEP, passes 1, spacing 0.01 / 0.005 / 0.0025; core = Delaunay + poles + LFS; "
        "total includes sampling through the CAD and the radius projection):\n\n";
  md << "| spacing | samples | core s | total s | core ns per n log2 n |\n|---|---|---|---|---|\n";
  std::vector<double> ln, lc, lt;
  for (double sp : {0.01, 0.005, 0.0025}) {
    std::string row = in_child([&] {
      auto shape = healed("wingtip/3d_bl_wing.stp", nlohmann::json::object());
      nlohmann::json ms;
      run("medial", {{"spacing", sp}, {"passes", 1}, {"min_spacing", 0.0005}}, {shape}, dir, &ms);
      auto& t = ms["time"];
      double core = t["delaunay"].get<double>() + t["poles"].get<double>() + t["lfs"].get<double>();
      std::ostringstream o;
      o.precision(17);
      o << ms["samples_per_pass"].back().get<long>() << " " << core << " " << t["total"].get<double>();
      return o.str();
    });
    std::istringstream is(row);
    double n = 0, core = 0, tot = 0;
    if (!(is >> n >> core >> tot)) {
      md << "| " << sp << " | " << row << " |\n";
      continue;
    }
    ln.push_back(std::log(n)), lc.push_back(std::log(core)), lt.push_back(std::log(tot));
    char b[256];
    std::snprintf(b, sizeof b, "| %.4f | %.0f | %.2f | %.2f | %.0f |\n", sp, n, core, tot, 1e9 * core / (n * std::log2(n)));
    md << b;
    std::cout << b << std::flush;
  }
  auto slope = [](const std::vector<double>& x, const std::vector<double>& y) {
    double mx = 0, my = 0;
    for (std::size_t i = 0; i < x.size(); ++i) mx += x[i] / x.size(), my += y[i] / y.size();
    double sxy = 0, sxx = 0;
    for (std::size_t i = 0; i < x.size(); ++i) sxy += (x[i] - mx) * (y[i] - my), sxx += (x[i] - mx) * (x[i] - mx);
    return sxx > 0 ? sxy / sxx : NAN;
  };
  if (ln.size() >= 2) {
    // the exponent n log n has over the same range, for comparison
    std::vector<double> lnl;
    for (double x : ln) lnl.push_back(x + std::log(x));
    char b[256];
    std::snprintf(b, sizeof b,
                  "\nFitted exponent k of t = c n^k: core %.2f, whole stage %.2f (n log n over this range gives %.2f).\n",
                  slope(ln, lc), slope(ln, lt), slope(ln, lnl));
    md << b;
    std::cout << b;
  }
  fs::remove_all(dir);
  fs::create_directories(out.parent_path());
  std::ofstream(out) << md.str();
  std::cout << "wrote " << out << "\n";
}
