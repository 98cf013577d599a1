// High-order stages benchmark (issue 7): curve, optimise (with its untangling) and split on the
// real workflows (NACA, the STEP wing, Rotor 67: ~20 min of it), run by the meshflow executable as a user runs them. First a cold run of each
// workflow at P=4 (the linear stages are then cached), then the NACA case at P = 2, 3, 5 and 6
// with only the high-order stages re-running (`--set curve.order=P`). Per stage: wall time and
// peak memory from report.json (each stage runs in its own process: wait4's ru_maxrss);
// split's throughput in sub-elements per second; invalid elements before and after untangling.
// Writes bench/results/highorder.md.
#include <nlohmann/json.hpp>

#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <sstream>
#include <string>
#include <unistd.h>
#include <vector>

namespace fs = std::filesystem;
using nlohmann::json;

namespace {

struct Run {
  double wall = 0;
  json report;
  int code = 0;
};

Run run(const fs::path& dir, const std::string& workflow, const std::string& extra) {
  std::string cmd = "cd " + dir.string() + " && " + MESHFLOW_EXE + " run " + workflow + " --cache " + (dir / "cache").string() +
                    " --out " + (dir / "out").string() + " " + extra + " > " + (dir / "log.txt").string() + " 2>&1";
  auto t0 = std::chrono::steady_clock::now();
  Run r;
  r.code = std::system(cmd.c_str());
  r.wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  std::ifstream in(dir / "out" / "report.json");
  if (in) r.report = json::parse(in);
  return r;
}

const json* stage(const json& rep, const std::string& name) {
  for (auto& s : rep.at("stages"))
    if (s.at("name") == name) return &s;
  return nullptr;
}

std::string fmt(double v, int prec = 2) {
  std::ostringstream o;
  o << std::fixed << std::setprecision(prec) << v;
  return o.str();
}

long sub_elements(const json& split) {
  long n = 0;
  for (auto& [k, v] : split.at("stats").at("split").at("sub").items()) n += v.get<long>();
  return n;
}

// One table row per high-order stage of a run.
void rows(std::ostringstream& md, const std::string& label, const json& rep) {
  for (const char* name : {"curve", "optimise", "split"}) {
    const json* s = stage(rep, name);
    if (!s) continue;
    const json& st = s->at("stats");
    std::string extra;
    if (std::string(name) == "curve")
      extra = "invalid after curving " + std::to_string(st.at("curve").at("validity").at("invalid").get<long>()) + " of " +
              std::to_string(st.at("curve").at("validity").at("elements").get<long>());
    if (std::string(name) == "optimise") {
      const json& u = st.at("optimise").value("untangle", json::object());
      if (!u.empty())
        extra = "untangle " + std::to_string(u.at("invalid").at("before").get<long>()) + " -> " +
                std::to_string(u.at("invalid").at("after").get<long>()) + " invalid in " + fmt(u.at("seconds").get<double>()) + " s";
    }
    if (std::string(name) == "split") {
      long n = sub_elements(*s);
      double sec = s->at("seconds").get<double>();
      extra = std::to_string(n) + " sub-elements, " + fmt(n / std::max(sec, 1e-9), 0) + " /s (stage wall time, incl. I/O and quality)";
    }
    md << "| " << label << " | " << name << " | " << fmt(s->at("seconds").get<double>()) << " | "
       << fmt(s->at("peak_rss_mb").get<double>(), 0) << " | " << st.at("mesh").at("invalid").get<long>() << " | "
       << fmt(st.at("mesh").at("min_scaled_jacobian").get<double>(), 3) << " | " << extra << " |\n";
  }
}

}  // namespace

int main() {
  const std::string src = MESHFLOW_SOURCE_DIR;
  std::ostringstream md;
  md << "## High-order stages (issue 7): curve, optimise, split\n\n"
     << "`build/bench/highorder_bench`: each workflow from an empty cache at P=4, then the NACA case re-run with "
        "`--set curve.order=P` (only curve, optimise and split run). Seconds are each stage's wall time, peak MB its "
        "process's maximum resident set; invalid is the stage's output mesh by meshflow's Bezier check "
        "(pyramids sampled); split throughput counts the sub-elements it writes per second of its whole stage "
        "(reading, splitting, quality statistics, writing).\n\n"
     << "| case | stage | seconds | peak MB | invalid | min scaled Jacobian | notes |\n|---|---|---|---|---|---|---|\n";
  struct W {
    std::string file, label;
  };
  std::vector<W> ws = {{"workflows/naca_wingtip.yaml", "NACA, P=4"},
                       {"workflows/wingtip_step.yaml", "STEP wing, P=4"},
                       {"workflows/wing_body.yaml", "DLR-F6, P=4"},
                       {"workflows/rotor67.yaml", "Rotor 67, P=4"}};
  std::vector<std::string> failed;
  fs::path naca_dir;
  for (auto& w : ws) {
    fs::path dir = fs::temp_directory_path() / ("mf-highorder-bench-" + std::to_string(getpid()) + "-" + std::to_string(&w - ws.data()));
    fs::remove_all(dir);
    fs::create_directories(dir);
    std::cerr << "highorder_bench: " << w.file << " (cold)\n";
    Run r = run(dir, src + "/" + w.file, "");
    if (r.code != 0 || r.report.is_null()) {
      failed.push_back(w.file + " (exit " + std::to_string(r.code) + ")");
      continue;
    }
    rows(md, w.label, r.report);
    if (w.file.find("naca") != std::string::npos) naca_dir = dir;
    else fs::remove_all(dir);
  }
  if (!naca_dir.empty()) {
    for (int P : {2, 3, 5, 6}) {
      std::cerr << "highorder_bench: NACA at P=" << P << "\n";
      Run r = run(naca_dir, src + "/workflows/naca_wingtip.yaml", "--set curve.order=" + std::to_string(P));
      if (r.code != 0 || r.report.is_null()) {
        failed.push_back("NACA at P=" + std::to_string(P) + " (exit " + std::to_string(r.code) + ")");
        continue;
      }
      rows(md, "NACA, P=" + std::to_string(P), r.report);
    }
    fs::remove_all(naca_dir);
  }
  md << "\n";
  for (auto& f : failed) md << "- FAILED: " << f << "\n";
  fs::create_directories(src + "/bench/results");
  std::ofstream(src + "/bench/results/highorder.md") << md.str();
  std::cout << md.str();
  return failed.empty() ? 0 : 1;
}
