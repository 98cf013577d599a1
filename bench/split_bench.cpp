// Split benchmark (issue 7): throughput of the isoparametric boundary-layer split
// (sub-elements per second) at orders P = 2..5, 10 layers, ratio 1.5, on the split tests'
// cylinder-on-plate junction near field (prisms on the cylinder and on the plate, C-type
// junction hexes split 10 x 10), sized like the paper's NACA wing tip near field (about 1,200
// macro prisms). Times split_mesh only (no I/O, no quality), best of 3, at 1 and 2 threads;
// then the cost of the stage's mesh_stats on the result for comparison.
// Writes a Markdown fragment to bench/results/split.md (argv[1] overrides the path).
// Build and run: cmake --build BUILD --target split_bench && BUILD/bench/split_bench
#include "../tests/split/builders.hpp"
#include "stages/model/quality.hpp"
#include "stages/split/split.hpp"

#include <nlohmann/json.hpp>

#include <sys/resource.h>

#include <chrono>
#include <cstdio>
#include <filesystem>
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
  fs::path out = argc > 1 ? fs::path(argv[1]) : fs::path(MESHFLOW_SOURCE_DIR) / "bench" / "results" / "split.md";
  const int ntheta = 150;  // 6*150 + 2*150 = 1,200 macro prisms, 150 junction hexes
  std::ostringstream md;
  md << "## Split\n\n"
     << "Isoparametric boundary-layer split (`stages/split`), `split_mesh` only (no I/O), best of 3; 10 layers, ratio 1.5; "
     << "cylinder-on-plate junction near field of the split tests (" << 8 * ntheta << " macro prisms + " << ntheta
     << " two-wall junction hexes, no far field). Sub-elements = 10 x prisms + 100 x hexes. "
     << "`cmake --build BUILD --target split_bench && BUILD/bench/split_bench`.\n\n"
     << "| P | macro elements | sub-elements | nodes out | 1 thread (s) | sub-elements/s | 2 threads (s) | sub-elements/s | mesh_stats (s, 2 threads) |\n"
     << "|---|---|---|---|---|---|---|---|---|\n";
  for (int P = 2; P <= 5; ++P) {
    auto J = splittest::junction_mesh(P, ntheta, false);
    meshflow::split::Options o;
    o.layers = 10;
    o.ratio = 1.5;
    o.check_conformity = false;  // measured separately: the conformity check is topology, not splitting
    double best[3] = {1e30, 1e30, 1e30};
    meshflow::split::Result r;
    for (int th : {1, 2})
      for (int rep = 0; rep < 3; ++rep) {
        auto t0 = Clock::now();
        r = meshflow::split::split_mesh(J.mesh, o, th);
        best[th] = std::min(best[th], secs(t0));
      }
    std::size_t subs = r.stats.sub_prisms + r.stats.sub_hexes;
    auto t0 = Clock::now();
    auto q = meshflow::model::mesh_stats(r.mesh, 2);
    double tq = secs(t0);
    char line[512];
    std::snprintf(line, sizeof line, "| %d | %zu | %zu | %zu | %.3f | %.0f | %.3f | %.0f | %.2f |\n", P,
                  J.prisms_a + J.prisms_c + J.hexes, subs, r.mesh.num_nodes(), best[1], subs / best[1], best[2],
                  subs / best[2], tq);
    md << line;
    std::cout << line << std::flush;
    if (q["invalid"].get<long>() != 0) std::cerr << "P=" << P << ": " << q["invalid"] << " invalid sub-elements\n";
  }
  md << "\nPeak memory of the benchmark process: " << int(peak_mb()) << " MB.\n";
  fs::create_directories(out.parent_path());
  std::ofstream(out) << md.str();
  std::cout << md.str();
  return 0;
}
