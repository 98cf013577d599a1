// Optimise benchmark (issue 7): time of the surface node optimisation per moved node at orders
// P = 2..5, on a curved prism layer over a sphere patch (1,200 wall triangles + 1,200 prisms,
// about the paper's NACA wing tip near field), high-order nodes deliberately badly placed as in
// tests/optimise (bunched and bowed edges, shifted face nodes). Times optimise_mesh only (no
// I/O), best of 3, at 1 and 2 threads, split into the L-BFGS-B part and the blend + validity
// guard part. Writes a Markdown fragment to bench/results/optimise.md (argv[1] overrides it).
// Build and run: cmake --build BUILD --target optimise_bench && BUILD/bench/optimise_bench
#include "../tests/optimise/builders.cpp"
#include "../tests/optimise/shapes.cpp"
#include "stages/model/quality.hpp"
#include "stages/optimise/optimise.hpp"

#include <sys/resource.h>
#include <unistd.h>

#include <chrono>
#include <fstream>
#include <iostream>
#include <sstream>

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

namespace {
double secs(Clock::time_point a) { return std::chrono::duration<double>(Clock::now() - a).count(); }
double peak_mb() {
  rusage ru{};
  getrusage(RUSAGE_SELF, &ru);
  return ru.ru_maxrss / 1024.0;
}
}  // namespace

int main(int argc, char** argv) {
  fs::path out = argc > 1 ? fs::path(argv[1]) : fs::path(MESHFLOW_SOURCE_DIR) / "bench" / "results" / "optimise.md";
  fs::path tmp = fs::temp_directory_path() / ("meshflow-optbench-" + std::to_string(getpid()) + ".mfshape");
  opttest::save_sphere(tmp);
  auto shape = meshflow::cad::Shape::load(tmp);
  fs::remove(tmp);
  opttest::Patch pa;
  pa.u0 = 0.3, pa.u1 = 2.8, pa.v0 = -1.2, pa.v1 = 1.2, pa.nu = 30, pa.nv = 20;
  const double kThickness = 0.05;
  opttest::Distortion d;
  d.bunch = 0.35, d.bump = 0.1, d.interior_u = 0.05, d.interior_v = 0.03;
  std::ostringstream md;
  md << "## Optimise\n\n"
     << "Surface node optimisation (`stages/optimise`), `optimise_mesh` only (no I/O), best of 3 at P=2, one run above; a layer of "
     << 2 * pa.nu * pa.nv << " curved prisms (thickness " << kThickness << ") on " << 2 * pa.nu * pa.nv
     << " wall triangles of a unit sphere (OCCT), high-order nodes bunched (0.35), bowed (0.1) and shifted as in "
     << "tests/optimise. Units = edges on the surface + faces (2D element interiors); per node = per moved node, "
     << "whole call. `cmake --build BUILD --target optimise_bench && BUILD/bench/optimise_bench`.\n\n"
     << "| P | invalid in → out | units | nodes moved | blended | L-BFGS-B its/unit | energy before → after | 1 thread (s) | µs/node | "
        "2 threads (s) | µs/node | of which L-BFGS-B / blend+guard (s, 2 thr) | mesh_quality of the input (s, 2 thr) |\n"
     << "|---|---|---|---|---|---|---|---|---|---|---|---|---|\n";
  for (int P = 2; P <= 5; ++P) {
    auto base = opttest::sphere_patch(shape, P, pa, d, kThickness);
    std::size_t invalid_in = 0;
    auto tq = Clock::now();
    auto qin = meshflow::model::mesh_quality(base, 2);
    double quality_s = secs(tq);
    for (auto& b : qin)
      for (auto& q : b) invalid_in += !q.valid;
    double best[3] = {1e30, 1e30, 1e30};
    meshflow::optimise::Report r;
    for (int th : {1, 2})
      for (int rep = 0; rep < (P <= 2 ? 3 : 1); ++rep) {
        auto m = base;
        auto t0 = Clock::now();
        r = meshflow::optimise::optimise_mesh(m, shape, {}, th);
        best[th] = std::min(best[th], secs(t0));
      }
    std::size_t units = r.surface_edges + r.curve_edges + r.faces;
    char line[512];
    std::snprintf(line, sizeof line, "| %d | %zu → %zu | %zu | %zu | %zu | %.1f | %.4g → %.4g | %.3f | %.1f | %.3f | %.1f | %.3f / %.3f | %.3f |\n", P,
                  invalid_in, r.invalid_after, units, r.nodes_moved, r.nodes_blended, double(r.iterations) / double(units ? units : 1), r.energy_before,
                  r.energy_after, best[1], 1e6 * best[1] / double(r.nodes_moved), best[2],
                  1e6 * best[2] / double(r.nodes_moved), r.optimise_seconds, r.guard_seconds, quality_s);
    md << line;
    std::cerr << line;
    if (r.invalid_after > invalid_in || r.max_cad_distance > 1e-7) {
      std::cerr << "optimise_bench: unexpected result (invalid " << r.invalid_after << ", distance " << r.max_cad_distance << ")\n";
      return 1;
    }
  }
  md << "\nPeak memory of the benchmark process: " << int(peak_mb()) << " MB.\n";
  std::ofstream(out) << md.str();
  std::cout << md.str();
}
