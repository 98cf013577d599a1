// CAD benchmark (issue 4): import + heal of the paper's wing STEP and of the DLR-F6 BREP, and
// point projection throughput onto the wing's B-spline (extruded NACA profile) surface, without
// and with a hint, 1 and 2 threads (one Shape::clone() per thread).
// Writes a Markdown fragment to bench/results/cad.md (argv[1] overrides the path).
// Build and run: cmake --build BUILD --target cad_bench && BUILD/bench/cad_bench
#include "bench_context.hpp"
#include "engine/registry.hpp"
#include "engine/stage.hpp"
#include "stages/cad/cad.hpp"

#include <nlohmann/json.hpp>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <random>
#include <sstream>
#include <thread>
#include <unistd.h>
#include <vector>

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;
using meshflow::cad::Shape;

namespace {
using meshflow::bench::BenchContext;
using meshflow::bench::secs;

struct ImportHeal {
  double t_import, t_heal;
  int faces_in, faces_out;
  meshflow::Artifact healed;
};
ImportHeal import_heal(const fs::path& file, const fs::path& dir) {
  ImportHeal r;
  BenchContext imp("step", {{"file", file.string()}}, {}, dir);
  auto t0 = Clock::now();
  meshflow::find_stage_kind("step")->run(imp);
  r.t_import = secs(t0);
  r.faces_in = imp.st_["faces"];
  BenchContext h("heal", nlohmann::json::object(), {imp.out_}, dir);
  t0 = Clock::now();
  meshflow::find_stage_kind("heal")->run(h);
  r.t_heal = secs(t0);
  r.faces_out = h.st_["after"]["faces"];
  r.healed = h.out_;
  return r;
}
}  // namespace

int main(int argc, char** argv) {
  fs::path out = argc > 1 ? fs::path(argv[1]) : fs::path(MESHFLOW_SOURCE_DIR) / "bench/results/cad.md";
  fs::path data = MESHFLOW_DATA_DIR;
  fs::path dir = fs::temp_directory_path() / ("meshflow-cad-bench-" + std::to_string(::getpid()));
  fs::create_directories(dir);
  std::ostringstream md;
  md << "## CAD\n\n`cmake --build build --target cad_bench && build/bench/cad_bench` (Release; wall time, one run after a warm-up).\n\n";
  md << "| input | import s | heal s | faces in → out |\n|---|---|---|---|\n";
  meshflow::Artifact wing;
  for (auto name : {"wingtip/3d_bl_wing.stp", "dlr_f6/dlr_f6.brep"}) {
    import_heal(data / name, dir);  // warm-up
    auto r = import_heal(data / name, dir);
    char b[256];
    std::snprintf(b, sizeof b, "| %s | %.3f | %.3f | %d → %d |\n", name, r.t_import, r.t_heal, r.faces_in, r.faces_out);
    md << b;
    std::cout << b;
    if (std::string(name).find("wing") != std::string::npos) wing = r.healed;
  }
  Shape s = Shape::load(wing.path);
  int f = -1;
  for (int i = 0; i < s.num_faces(); ++i)
    if (s.face_tag(i) == meshflow::cad::Tag::wall && s.face_surface_type(i) == "extrusion") f = i;
  auto b = s.face_uv_bounds(f);
  const int N = 100000;
  std::mt19937 rng(42);
  std::uniform_real_distribution<double> U(0, 1), D(-1, 1);
  struct Q {
    meshflow::cad::Vec3 p;
    double u, v;
  };
  std::vector<Q> pts(N);
  for (auto& q : pts) {
    q.u = b.u0 + (b.u1 - b.u0) * U(rng);
    q.v = b.v0 + (b.v1 - b.v0) * U(rng);
    auto p = s.face_point(f, q.u, q.v);
    auto n = s.face_normal(f, q.u, q.v);
    double d = 1.0 * D(rng);  // up to 1 mm off the surface (chord 1219 mm)
    q.p = {p.x + d * n.x, p.y + d * n.y, p.z + d * n.z};
  }
  md << "\nProjection onto the wing surface (face " << f << ", " << s.face_surface_type(f)
     << " of a B-spline profile), " << N << " points within 1 mm of it:\n\n| mode | threads | points/s | max |uv error| |\n|---|---|---|---|\n";
  for (bool hint : {false, true})
    for (int nt : {1, 2}) {
      std::vector<double> err(nt, 0);
      auto t0 = Clock::now();
      std::vector<std::thread> th;
      for (int k = 0; k < nt; ++k)
        th.emplace_back([&, k] {
          Shape mine = s.clone();
          for (int i = k; i < N; i += nt) {
            auto& q = pts[i];
            auto r = hint ? mine.project_to_face(f, q.p, meshflow::cad::Vec2{q.u + 1e-4 * (b.u1 - b.u0), q.v})
                          : mine.project_to_face(f, q.p);
            err[k] = std::max(err[k], std::max(std::abs(r.u - q.u) / (b.u1 - b.u0), std::abs(r.v - q.v) / (b.v1 - b.v0)));
          }
        });
      for (auto& t : th) t.join();
      double dt = secs(t0);
      char line[256];
      std::snprintf(line, sizeof line, "| %s | %d | %.0f | %.1e |\n", hint ? "with hint (Newton)" : "no hint", nt, N / dt,
                    *std::max_element(err.begin(), err.end()));
      md << line;
      std::cout << line;
    }
  fs::remove_all(dir);
  fs::create_directories(out.parent_path());
  std::ofstream(out) << md.str();
  std::cout << "wrote " << out << "\n";
}
