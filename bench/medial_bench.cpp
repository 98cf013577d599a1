// Medial benchmark (issue 5): (1) the CGAL core (Delaunay + poles + filter + LFS) versus the
// number of boundary samples at 3 sizes (expect n log n), on samples of a sphere inside a box;
// (2) the whole medial stage (sampling through the CAD, 2 passes, core, radius refinement) on
// the parametric naca_wing, the paper's wing STEP and the DLR-F6 BREP (after heal).
// Writes a Markdown fragment to bench/results/medial.md (argv[1] overrides the path).
// Build and run: cmake --build BUILD --target medial_bench && BUILD/bench/medial_bench
#include "bench_context.hpp"
#include "engine/registry.hpp"
#include "engine/stage.hpp"
#include "stages/medial/medial.hpp"

#include <nlohmann/json.hpp>

#include <sys/resource.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <sstream>
#include <vector>

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;
using namespace meshflow::medial;

namespace {
double peak_mb() {
  rusage ru{};
  getrusage(RUSAGE_SELF, &ru);
  return ru.ru_maxrss / 1024.0;
}
using meshflow::bench::BenchContext;
using meshflow::bench::secs;
meshflow::Artifact run(const std::string& kind, nlohmann::json p, std::vector<meshflow::Artifact> in, const fs::path& dir,
                       nlohmann::json* stats = nullptr) {
  BenchContext c(kind, std::move(p), std::move(in), dir);
  meshflow::find_stage_kind(kind)->run(c);
  if (stats) *stats = c.st_;
  return c.out_;
}

// About n samples: a unit sphere (Fibonacci points, a wall) inside the box [-2,2]^3.
std::vector<Sample> sphere_in_box(long n) {
  std::vector<Sample> S;
  const double area_s = 4 * M_PI, area_b = 6 * 16.0;
  long ns = static_cast<long>(n * area_s / (area_s + area_b));
  const double ga = M_PI * (3 - std::sqrt(5.0));
  for (long i = 0; i < ns; ++i) {
    double z = 1 - 2 * (i + 0.5) / ns, r = std::sqrt(1 - z * z), t = ga * i;
    Sample s;
    s.p = {r * std::cos(t), r * std::sin(t), z};
    s.n = {-s.p[0], -s.p[1], -s.p[2]};
    s.faces = {6, -1, -1};
    s.refined = true;
    S.push_back(s);
  }
  long per_face = (n - ns) / 6;
  int m = std::max(2, static_cast<int>(std::sqrt(static_cast<double>(per_face))));
  double h = 4.0 / m;
  std::uint64_t seed = 1;
  auto rnd = [&]() {
    seed = seed * 6364136223846793005ULL + 1442695040888963407ULL;
    return static_cast<double>(seed >> 11) / static_cast<double>(1ULL << 53) - 0.5;
  };
  for (int f = 0; f < 6; ++f) {
    int ax = f / 2, a1 = (ax + 1) % 3, a2 = (ax + 2) % 3;
    for (int i = 0; i < m; ++i)
      for (int j = 0; j < m; ++j) {
        Sample s;
        s.p[ax] = f % 2 ? 2 : -2;
        s.p[a1] = -2 + (i + 0.5 + 0.4 * rnd()) * h;
        s.p[a2] = -2 + (j + 0.5 + 0.4 * rnd()) * h;
        s.n = {0, 0, 0};
        s.n[ax] = f % 2 ? 1 : -1;
        s.faces = {f, -1, -1};
        S.push_back(s);
      }
  }
  return S;
}
}  // namespace

int main(int argc, char** argv) {
  fs::path out = argc > 1 ? fs::path(argv[1]) : fs::path(MESHFLOW_SOURCE_DIR) / "bench/results/medial.md";
  fs::path data = MESHFLOW_DATA_DIR;
  fs::path dir = fs::temp_directory_path() / ("meshflow-medial-bench-" + std::to_string(::getpid()));
  fs::create_directories(dir);
  std::ostringstream md;
  md << "## Medial\n\n`cmake --build build --target medial_bench && build/bench/medial_bench` (Release, 1 thread, wall time).\n\n";
  md << "Core (CGAL Delaunay + poles + filter + LFS) versus the number of samples (unit sphere in a box; "
        "t / (n log2 n) flat means n log n):\n\n";
  md << "| samples | Delaunay s | poles+filter s | LFS s | total s | ns per n log2 n | medial points |\n|---|---|---|---|---|---|---|\n";
  for (long n : {25000L, 100000L, 400000L}) {
    auto S = sphere_in_box(n);
    CoreTimes t;
    auto t0 = Clock::now();
    MedialObject M = medial_from_samples(S, {}, &t);
    double tot = secs(t0);
    double nn = static_cast<double>(S.size());
    char b[256];
    std::snprintf(b, sizeof b, "| %zu | %.2f | %.2f | %.2f | %.2f | %.3f | %zu |\n", S.size(), t.delaunay, t.poles, t.lfs, tot,
                  1e9 * tot / (nn * std::log2(nn)), M.points.size());
    md << b;
    std::cout << b << std::flush;
  }
  md << "\nThe whole stage (default parameters: 2 sampling passes, radius refinement through the CAD), after heal; "
        "peak RSS is the bench process's (cumulative):\n\n";
  md << "| input | samples (pass 1 → 2) | medial points fluid / body | halos | sampling s | Delaunay s | poles s | LFS s | "
        "projection s | total s | peak MB |\n|---|---|---|---|---|---|---|---|---|---|---|\n";
  struct Case {
    std::string name;
    std::function<meshflow::Artifact()> shape;
  };
  std::vector<Case> cases = {
      {"naca_wing (parametric)", [&] { return run("naca_wing", nlohmann::json::object(), {}, dir); }},
      {"wingtip/3d_bl_wing.stp",
       [&] { return run("heal", nlohmann::json::object(), {run("step", {{"file", (data / "wingtip/3d_bl_wing.stp").string()}}, {}, dir)}, dir); }},
      {"dlr_f6/dlr_f6.brep",
       [&] { return run("heal", nlohmann::json::object(), {run("step", {{"file", (data / "dlr_f6/dlr_f6.brep").string()}}, {}, dir)}, dir); }},
  };
  for (auto& c : cases) {
    nlohmann::json st;
    try {
      auto shape = c.shape();
      run("medial", nlohmann::json::object(), {shape}, dir, &st);
    } catch (const std::exception& e) {
      md << "| " << c.name << " | failed: " << e.what() << " |\n";
      std::cout << c.name << " failed: " << e.what() << "\n";
      continue;
    }
    auto& t = st["time"];
    char b[512];
    std::snprintf(b, sizeof b, "| %s | %ld → %ld | %ld / %ld | %ld | %.2f | %.2f | %.2f | %.2f | %.2f | %.2f | %.0f |\n", c.name.c_str(),
                  st["samples_per_pass"][0].get<long>(), st["samples_per_pass"][1].get<long>(),
                  st["medial_points"]["fluid"].get<long>(), st["medial_points"]["body"].get<long>(), st["halos"].get<long>(),
                  t["sampling"].get<double>(), t["delaunay"].get<double>(), t["poles"].get<double>(), t["lfs"].get<double>(),
                  t["projection"].get<double>(), t["total"].get<double>(), peak_mb());
    md << b;
    std::cout << b << std::flush;
  }
  fs::remove_all(dir);
  fs::create_directories(out.parent_path());
  std::ofstream(out) << md.str();
  std::cout << "wrote " << out << "\n";
}
