// Whole-pipeline benchmark: the real workflows run by the meshflow executable as a user runs
// them, each from a cold cache, then incremental re-runs (no change; a tet-only parameter; a
// shell parameter). Per stage: wall time and peak memory from report.json (the runner measures
// each stage in its own process: wait4's ru_maxrss). Writes bench/results/pipeline.md.
#include <nlohmann/json.hpp>

#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <sstream>
#include <string>
#include <unistd.h>
#include <vector>

namespace fs = std::filesystem;

namespace {

struct Run {
  double wall = 0;
  nlohmann::json report;
  int code = 0;
};

Run run(const fs::path& dir, const std::string& workflow, const std::string& extra) {
  std::string cmd = "cd " + dir.string() + " && " + MESHFLOW_EXE + " run " + workflow + " --cache " +
                    (dir / "cache").string() + " " + extra + " > " + (dir / "log.txt").string() + " 2>&1";
  auto t0 = std::chrono::steady_clock::now();
  Run r;
  r.code = std::system(cmd.c_str());
  r.wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  for (auto& e : fs::recursive_directory_iterator(dir / "out"))
    if (e.path().filename() == "report.json") {
      std::ifstream in(e.path());
      r.report = nlohmann::json::parse(in);
    }
  return r;
}

std::string ran(const nlohmann::json& rep) {
  std::string s;
  for (auto& st : rep.at("stages"))
    if (st.at("status") == "ran") s += (s.empty() ? "" : ", ") + st.at("name").get<std::string>();
  return s.empty() ? "none" : s;
}

}  // namespace

int main() {
  const std::string src = MESHFLOW_SOURCE_DIR;
  std::ostringstream md;
  md << "## Whole pipeline (issue 6/8): per stage, cold, and incremental re-runs\n\n"
     << "`build/bench/pipeline_bench` runs `meshflow run WORKFLOW` on the real workflows from an empty cache "
        "(stages one after the other as their dependencies allow, `-j` default), then again with no change, with "
        "`--set tet.radius_edge=1.4` and with `--set shell.thickness=0.04`. Seconds are wall time; peak MB is each "
        "stage process's maximum resident set.\n\n";
  struct W {
    std::string file, title;
  };
  std::vector<W> ws = {{"workflows/naca_wingtip.yaml", "NACA 0012 wing tip (parametric, `make demo`)"},
                       {"workflows/wingtip_step.yaml", "the paper's wing (STEP)"}};
  for (auto& w : ws) {
    fs::path dir = fs::temp_directory_path() / ("mf-pipeline-bench-" + std::to_string(getpid()));
    fs::remove_all(dir);
    fs::create_directories(dir);
    std::string wf = src + "/" + w.file;
    Run cold = run(dir, wf, "");
    if (cold.code != 0 || cold.report.is_null()) {
      md << "### " << w.title << "\n\nFAILED (exit " << cold.code << "); see a run of `meshflow run " << w.file << "`.\n\n";
      std::cerr << "failed: " << w.file << "\n";
      continue;
    }
    md << "### " << w.title << "\n\n| stage | kind | seconds | peak MB |\n|---|---|---|---|\n";
    double sum = 0;
    std::string mesh_line;
    for (auto& st : cold.report.at("stages")) {
      md << "| " << st.at("name").get<std::string>() << " | " << st.at("kind").get<std::string>() << " | "
         << st.at("seconds").get<double>() << " | " << st.at("peak_rss_mb").get<double>() << " |\n";
      sum += st.at("seconds").get<double>();
      if (st.at("stats").contains("mesh") && st.at("name") == "tet") {
        auto& m = st.at("stats").at("mesh");
        mesh_line = "linear hybrid mesh: " + m.at("elements").dump() + ", invalid " + m.at("invalid").dump() +
                    ", non-conforming faces " + m.at("nonconforming_faces").dump() + "\n\n";
      }
    }
    md << "\n" << mesh_line << "cold run: " << cold.wall << " s wall (stages sum " << sum << " s)\n\n";
    md << "| re-run | wall s | vs cold | stages that ran |\n|---|---|---|---|\n";
    for (auto [label, extra] : std::vector<std::pair<std::string, std::string>>{
             {"no change", ""}, {"`--set tet.radius_edge=1.4`", "--set tet.radius_edge=1.4"},
             {"`--set shell.thickness=0.04`", "--set shell.thickness=0.04"}}) {
      Run r = run(dir, wf, extra);
      md << "| " << label << " | " << r.wall << " | " << 100 * r.wall / cold.wall << "% | "
         << (r.code == 0 ? ran(r.report) : std::string("FAILED")) << " |\n";
    }
    md << "\n";
    fs::remove_all(dir);
  }
  fs::create_directories(src + "/bench/results");
  std::ofstream(src + "/bench/results/pipeline.md") << md.str();
  std::cout << md.str();
  return 0;
}
