// Issue 6's benchmark for the workflows that end at the linear hybrid mesh (tet) or before it:
// time and peak memory per stage from an empty cache, and what the last stage produced. The
// workflows that run to split (NACA, the STEP wing) are measured with their re-runs by
// pipeline_bench; this one covers Rotor 67 and DLR-F6 (both now to split), each once from an
// empty cache. Writes bench/results/linear.md.
// Usage: build/bench/linear_bench
#include "bench_util.hpp"

#include <nlohmann/json.hpp>

#include <filesystem>
#include <fstream>
#include <iostream>
#include <sstream>
#include <unistd.h>

namespace fs = std::filesystem;
using nlohmann::json;
using namespace meshflow::bench;

int main() {
  const std::string src = MESHFLOW_SOURCE_DIR;
  struct W {
    std::string file, title, extra;
  };
  std::vector<W> ws = {{"workflows/rotor67.yaml", "Rotor 67 blade sector (`workflows/rotor67.yaml`, to split)", ""},
                       {"workflows/wing_body.yaml", "DLR-F6 wing-body (`workflows/wing_body.yaml`, to split)", ""}};
  std::ostringstream md;
  md << "## Linear hybrid mesh (issue 6): stages of the real-CAD workflows\n\n"
     << "Produced by `cmake --build build --target linear_bench && build/bench/linear_bench` (part of `make bench`): "
        "each workflow once from an empty cache, `meshflow run WORKFLOW --cache DIR --out DIR`; seconds and peak MB "
        "are each stage process's (report.json), wall the whole process. The NACA and STEP wings, which run to "
        "split, are in the whole-pipeline section (pipeline_bench). The machine has 2 cores and was not otherwise "
        "busy unless said.\n\n";
  bool all_ok = true;
  for (auto& w : ws) {
    std::cerr << "linear_bench: " << w.file << "\n";
    fs::path dir = fresh_dir("linear-bench");
    Run r = run_meshflow(dir, src + "/" + w.file, w.extra);
    md << "### " << w.title << "\n\n";
    if (r.report.is_null()) {
      md << "FAILED (exit " << r.code << ", no report.json)\n\n";
      all_ok = false;
      fs::remove_all(dir);
      continue;
    }
    md << "| stage | kind | seconds | peak MB | notes |\n|---|---|---|---|---|\n";
    for (auto& st : r.report.at("stages")) {
      std::string name = st.at("name"), note;
      const json& s = st.value("stats", json::object());
      if (name == "shell" && s.contains("self_intersections"))
        note = std::to_string(s.at("self_intersections").get<long>()) + " crossing pairs in the sampled shell";
      if (name == "sweep" && s.contains("sweep")) {
        const json& q = s.at("sweep");
        note = std::to_string(q.value("prisms", 0L)) + " prisms, " + std::to_string(q.value("hexes", 0L)) +
               " hexes; outer-surface crossings " + std::to_string(q.value("outer_crossings_before", 0L)) + " -> " +
               std::to_string(q.value("outer_crossings", 0L));
      }
      if (s.contains("mesh")) {
        const json& m = s.at("mesh");
        note += (note.empty() ? "" : "; ") + std::to_string(volume_elements(m)) + " elements " + m.at("elements").dump() +
                ", invalid " + m.at("invalid").dump() + ", min scaled Jacobian " +
                fmt(m.at("min_scaled_jacobian").get<double>(), 3);
      }
      md << "| " << name << " | " << st.at("kind").get<std::string>() << " | "
         << (st.contains("seconds") ? fmt(st.at("seconds").get<double>()) : std::string("-")) << " | "
         << (st.contains("peak_rss_mb") ? fmt(st.at("peak_rss_mb").get<double>(), 0) : std::string("-")) << " | " << note
         << " |\n";
    }
    md << "\nwall " << fmt(r.wall) << " s, exit " << r.code << (r.code ? " (FAILED)" : "") << "\n\n";
    all_ok = all_ok && r.code == 0;
    fs::remove_all(dir);
  }
  fs::create_directories(src + "/bench/results");
  std::ofstream(src + "/bench/results/linear.md") << md.str();
  std::cout << md.str();
  return all_ok ? 0 : 1;
}
