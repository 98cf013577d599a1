// Scaling benchmark (issue 8): the NACA wing tip (workflows/naca_wingtip.yaml, to split at P=4)
// at three mesh sizes, roughly 20k, 150k and 1M final (split) elements, each from an empty cache
// as a user runs it (`meshflow run ... --set ...`). The size is set by one length factor s
// applied to every mesh-size parameter of the workflow: balance.min_size = 0.01 s,
// balance.max_size = 0.1 s, balance.turn_angle_deg = 30 s (the curvature rule), and
// sweep.farfield_size = 1.0 s (sizes on the far-field, symmetry faces); the tet far field grades
// from those surface sizes (tet.size_growth). medial and shell do not depend on the mesh size
// (their sampling follows the geometry), so they are left as the workflow has them.
// Per size: wall time and peak memory per stage (report.json: each stage is its own process,
// wait4's ru_maxrss), total wall time, final elements; least-squares fit of log time against
// log elements, overall and per stage. Then orders 2..6 on the smallest size (after its P=4 cold
// run, `--set curve.order=P`: curve, optimise and split re-run).
// A size whose run exceeds the time limit (env MESHFLOW_SCALING_TIMEOUT, seconds, default
// 1500) or fails is reported with how far it got (the runner's log lines).
// Writes bench/results/scaling.md and bench/results/scaling.json, then draws
// bench/results/scaling.png with bench/plot.py.
#include "bench_util.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <map>
#include <sstream>
#include <string>
#include <sys/wait.h>
#include <unistd.h>
#include <vector>

namespace fs = std::filesystem;
using nlohmann::json;
using namespace meshflow::bench;  // bench_util.hpp: Clock, fmt, median, Run, secs, stage, ...

namespace {

Run run(const fs::path& dir, const std::string& extra, int timeout_s) {
  return meshflow::bench::run_meshflow(dir, std::string(MESHFLOW_SOURCE_DIR) + "/workflows/naca_wingtip.yaml", extra, timeout_s);
}

// Least squares of log y = a + b log x: the exponent b (NaN with fewer than 2 usable points).
double exponent(const std::vector<double>& x, const std::vector<double>& y) {
  std::vector<std::pair<double, double>> p;
  for (size_t i = 0; i < x.size(); ++i)
    if (x[i] > 0 && y[i] > 0) p.push_back({std::log(x[i]), std::log(y[i])});
  if (p.size() < 2) return std::nan("");
  double mx = 0, my = 0;
  for (auto& [a, b] : p) mx += a, my += b;
  mx /= double(p.size());
  my /= double(p.size());
  double sxy = 0, sxx = 0;
  for (auto& [a, b] : p) sxy += (a - mx) * (b - my), sxx += (a - mx) * (a - mx);
  return sxx > 0 ? sxy / sxx : std::nan("");
}

// The runner's "  ran     NAME (S s, M MB)" and "  start   NAME (kind)" lines: how far a run got.
std::string progress_of(const std::string& log) {
  std::istringstream in(log);
  std::string line, done, last_start;
  while (std::getline(in, line)) {
    if (line.rfind("  ran     ", 0) == 0) done += (done.empty() ? "" : "; ") + line.substr(10);
    if (line.rfind("  start   ", 0) == 0) last_start = line.substr(10);
  }
  return "finished: " + (done.empty() ? std::string("none") : done) + (last_start.empty() ? "" : "; last started: " + last_start);
}

std::string sets_for(double s) {
  std::ostringstream o;
  o << std::setprecision(4) << "--set balance.min_size=" << 0.01 * s << " --set balance.max_size=" << 0.1 * s
    << " --set balance.turn_angle_deg=" << std::min(90.0, 30 * s) << " --set sweep.farfield_size=" << 1.0 * s;
  return o.str();
}

}  // namespace

int main() {
  const std::string src = MESHFLOW_SOURCE_DIR;
  const int timeout_s = std::getenv("MESHFLOW_SCALING_TIMEOUT") ? std::atoi(std::getenv("MESHFLOW_SCALING_TIMEOUT")) : 1500;
  // Size factors s (1 is the workflow as committed, about 70k final elements); chosen so the
  // final meshes come out near 20k, 150k and 1M elements. Repetitions: the cheap sizes twice.
  struct Size {
    std::string label;
    double s;
    int reps;
  };
  const std::vector<Size> sizes = {{"~20k", 2.0, 2}, {"~150k", 0.68, 2}, {"~1M", 0.295, 1}};
  const std::vector<std::string> order = {"geometry", "heal",  "medial", "shell",    "balance",
                                          "sweep",    "tet",   "curve",  "optimise", "split"};
  json data = {{"stage_order", order}, {"sizes", json::array()}};
  std::ostringstream md;
  md << "## Scaling with size (issue 8): the NACA wing tip at three sizes, P=4, 10 layers\n\n"
     << "Produced by `cmake --build build --target scaling_bench && build/bench/scaling_bench` (part of `make bench`). "
        "`meshflow run workflows/naca_wingtip.yaml` from an empty cache with every mesh-size parameter scaled by one "
        "length factor s: `balance.min_size = 0.01 s`, `balance.max_size = 0.1 s`, `balance.turn_angle_deg = 30 s` (at most "
        "90), `sweep.farfield_size = 1.0 s` (s = 1 is the workflow as committed); the far-field tets grade from these "
        "surface sizes. `medial` and `shell` follow the geometry, not the mesh size, and are left as the workflow has "
        "them. Seconds and peak MB per stage are each stage process's (report.json); total is the wall time of the "
        "whole `meshflow` process, outputs (msh, vtu, nektar) included. Exponents: least squares of log time on log "
        "final elements. Cheap sizes run twice (medians), the largest once; time limit "
     << timeout_s << " s per run.\n\n"
     << "The machine (2 cores) was shared with the lead's builds and tests while this ran: timings are noisy.\n\n";

  std::vector<json> results;
  fs::path small_dir;
  std::string small_sets;
  for (auto& sz : sizes) {
    std::string sets = sets_for(sz.s);
    fs::path dir = fs::temp_directory_path() / ("mf-scaling-bench-" + std::to_string(getpid()) + "-" + std::to_string(&sz - sizes.data()));
    std::vector<double> walls, runners;
    std::map<std::string, std::vector<double>> st_secs, st_mb;
    json res = {{"label", sz.label}, {"s", sz.s}, {"sets", sets}, {"complete", false}};
    for (int rep = 0; rep < sz.reps; ++rep) {
      fs::remove_all(dir);
      fs::create_directories(dir);
      std::cerr << "scaling_bench: size " << sz.label << " (s = " << sz.s << "), run " << rep + 1 << "\n";
      Run r = run(dir, sets, timeout_s);
      if (r.code != 0 || r.report.is_null() || !r.report.value("ok", false)) {
        res["failure"] = (r.code == 124 ? "stopped by the time limit (" + std::to_string(timeout_s) + " s)"
                                        : "exit " + std::to_string(r.code)) +
                         " after " + fmt(r.wall, 0) + " s; " + progress_of(r.log);
        res["failed_wall_s"] = r.wall;
        break;
      }
      walls.push_back(r.wall);
      runners.push_back(r.report.at("seconds").get<double>());
      for (auto& s : r.report.at("stages")) {
        st_secs[s.at("name")].push_back(s.at("seconds").get<double>());
        st_mb[s.at("name")].push_back(s.at("peak_rss_mb").get<double>());
      }
      const json& m = stage(r.report, "split")->at("stats").at("mesh");
      res["elements"] = volume_elements(m);
      res["by_type"] = m.at("elements");
      res["nodes"] = m.at("nodes");
      res["invalid"] = m.at("invalid");
      res["min_scaled_jacobian"] = m.at("min_scaled_jacobian");
      if (const json* t = stage(r.report, "tet")) res["linear_elements"] = volume_elements(t->at("stats").at("mesh"));
      res["complete"] = true;
    }
    if (res["complete"]) {
      res["wall_s"] = median(walls);
      res["walls"] = walls;
      res["runner_s"] = median(runners);
      for (auto& [n, v] : st_secs) res["stages"][n] = {{"seconds", median(v)}, {"peak_rss_mb", median(st_mb[n])}};
      double peak = 0;
      for (auto& [n, v] : st_mb) peak = std::max(peak, median(v));
      res["peak_rss_mb"] = peak;
    }
    if (&sz == &sizes.front() && res["complete"]) {
      small_dir = dir;
      small_sets = sets;
    } else {
      fs::remove_all(dir);
    }
    results.push_back(res);
    data["sizes"].push_back(res);
  }

  // Size table.
  md << "| size | s | final elements (prism/hex/tet/pyramid) | linear elements (tet stage) | nodes | invalid | total wall s | runner s | start-up + writing out/ s | peak MB (largest stage) |\n"
     << "|---|---|---|---|---|---|---|---|---|---|\n";
  for (auto& r : results) {
    if (!r["complete"]) {
      md << "| " << r["label"].get<std::string>() << " | " << r["s"] << " | not finished: " << r["failure"].get<std::string>()
         << " | | | | | | | |\n";
      continue;
    }
    auto& bt = r["by_type"];
    md << "| " << r["label"].get<std::string>() << " | " << r["s"] << " | " << r["elements"] << " (" << bt.value("prism", 0)
       << "/" << bt.value("hex", 0) << "/" << bt.value("tet", 0) << "/" << bt.value("pyramid", 0) << ") | "
       << r["linear_elements"] << " | " << r["nodes"] << " | " << r["invalid"] << " | " << fmt(r["wall_s"].get<double>(), 1)
       << " | " << fmt(r["runner_s"].get<double>(), 1) << " | " << fmt(r["wall_s"].get<double>() - r["runner_s"].get<double>(), 1)
       << " | " << fmt(r["peak_rss_mb"].get<double>(), 0) << " |\n";
  }
  md << "\n";

  // Per stage: seconds and peak MB at each size, and the fitted exponent.
  std::vector<json> done;
  for (auto& r : results)
    if (r["complete"]) done.push_back(r);
  std::vector<double> xs;
  for (auto& r : done) xs.push_back(r["elements"].get<double>());
  md << "| stage |";
  for (auto& r : done) md << " s at " << r["elements"] << " |";
  for (auto& r : done) md << " MB at " << r["elements"] << " |";
  md << " exponent (time) |\n|---|";
  for (size_t i = 0; i < 2 * done.size() + 1; ++i) md << "---|";
  md << "\n";
  for (auto& n : order) {
    std::vector<double> ys;
    md << "| " << n << " |";
    for (auto& r : done) {
      double v = r["stages"].contains(n) ? r["stages"][n]["seconds"].get<double>() : 0;
      ys.push_back(v);
      md << " " << fmt(v) << " |";
    }
    for (auto& r : done) md << " " << fmt(r["stages"].contains(n) ? r["stages"][n]["peak_rss_mb"].get<double>() : 0, 0) << " |";
    double e = exponent(xs, ys);
    data["exponents"][n] = std::isnan(e) ? json() : json(e);
    md << " " << (std::isnan(e) ? "–" : fmt(e)) << " |\n";
  }
  std::vector<double> tw, trn;
  for (auto& r : done) tw.push_back(r["wall_s"].get<double>()), trn.push_back(r["runner_s"].get<double>());
  double e_total = exponent(xs, tw), e_runner = exponent(xs, trn);
  data["exponents"]["total_wall"] = std::isnan(e_total) ? json() : json(e_total);
  data["exponents"]["runner"] = std::isnan(e_runner) ? json() : json(e_runner);
  md << "| **total wall** |";
  for (double v : tw) md << " " << fmt(v, 1) << " |";
  for (size_t i = 0; i < done.size(); ++i) md << " |";
  md << " **" << (std::isnan(e_total) ? "–" : fmt(e_total)) << "** |\n\n";
  if (!std::isnan(e_total)) {
    md << "Fitted exponent of total wall time against final elements: **" << fmt(e_total) << "** over " << done.size()
       << " sizes (target <= 1.15: " << (e_total <= 1.15 ? "met" : "missed") << "); runner only (without writing the outputs): "
       << fmt(e_runner) << ". Slope between consecutive sizes (total wall / runner):";
    for (size_t i = 1; i < done.size(); ++i) {
      double sw = exponent({xs[i - 1], xs[i]}, {tw[i - 1], tw[i]}), sr = exponent({xs[i - 1], xs[i]}, {trn[i - 1], trn[i]});
      data["pair_slopes"].push_back({{"from", xs[i - 1]}, {"to", xs[i]}, {"total_wall", sw}, {"runner", sr}});
      md << (i > 1 ? ";" : "") << " " << done[i - 1]["elements"] << " -> " << done[i]["elements"] << ": " << fmt(sw) << " / "
         << fmt(sr);
    }
    md << ".";
    // The stage with the largest exponent among those that take at least 10% of the largest run.
    std::string worst;
    double we = -1e9;
    const json& big = done.back();
    for (auto& n : order) {
      double e = data["exponents"][n].is_null() ? -1e9 : data["exponents"][n].get<double>();
      double share = big["stages"].contains(n) ? big["stages"][n]["seconds"].get<double>() / big["wall_s"].get<double>() : 0;
      if (share >= 0.1 && e > we) we = e, worst = n;
    }
    if (!worst.empty())
      md << " Steepest stage among those taking >= 10% of the largest run: " << worst << " (exponent " << fmt(we) << ").";
    md << " With 3 sizes a fit says little about curvature: stages that do not depend on the size (medial, shell) pull the "
          "small sizes up and the exponent down.\n\n";
  }
  for (auto& r : results)
    if (!r["complete"]) md << "- size " << r["label"].get<std::string>() << " (`" << r["sets"].get<std::string>() << "`) did not finish: " << r["failure"].get<std::string>() << "\n";
  md << "\nParameters per size (`--set`):\n\n";
  for (auto& r : results) md << "- " << r["label"].get<std::string>() << ": `" << r["sets"].get<std::string>() << "`\n";
  md << "\n";

  // Orders 2..6 on the smallest size.
  if (!small_dir.empty()) {
    md << "### Orders 2 to 6 on the smallest size\n\n"
       << "After the smallest size's cold run at P=4, `--set curve.order=P` with the same size parameters (only curve, "
          "optimise and split re-run; P=4 is that cold run's stages). Seconds, peak MB per stage process; invalid and min "
          "scaled Jacobian of split's final mesh (meshflow's Bezier check).\n\n"
       << "| P | curve s | optimise s | split s | curve MB | optimise MB | split MB | re-run wall s | final nodes | invalid | min scaled Jacobian | untangle (invalid before -> after) |\n"
       << "|---|---|---|---|---|---|---|---|---|---|---|---|\n";
    for (int P : {2, 3, 4, 5, 6}) {
      std::cerr << "scaling_bench: smallest size at P=" << P << "\n";
      Run r = run(small_dir, small_sets + " --set curve.order=" + std::to_string(P), timeout_s);
      if (r.code != 0 || r.report.is_null()) {
        md << "| " << P << " | FAILED (exit " << r.code << "): " << progress_of(r.log) << " | | | | | | | | | | |\n";
        continue;
      }
      json row = {{"order", P}, {"wall_s", r.wall}};
      md << "| " << P << " |";
      // P=4 is in the cache already: take its stage figures from the cold run.
      const json& rep = r.report;
      const json& cold = results.front()["stages"];
      for (const char* n : {"curve", "optimise", "split"}) {
        const json* s = stage(rep, n);
        double v = s->at("status") == "ran" ? s->at("seconds").get<double>() : cold[n]["seconds"].get<double>();
        row[n]["seconds"] = v;
        md << " " << fmt(v) << " |";
      }
      for (const char* n : {"curve", "optimise", "split"}) {
        const json* s = stage(rep, n);
        double v = s->at("status") == "ran" ? s->at("peak_rss_mb").get<double>() : cold[n]["peak_rss_mb"].get<double>();
        row[n]["peak_rss_mb"] = v;
        md << " " << fmt(v, 0) << " |";
      }
      const json& m = stage(rep, "split")->at("stats").at("mesh");
      const json& u = stage(rep, "optimise")->at("stats").at("optimise").value("untangle", json::object());
      std::string untangle = u.empty() ? "–" : u.at("invalid").at("before").dump() + " -> " + u.at("invalid").at("after").dump();
      md << " " << (P == 4 ? "(cold run)" : fmt(r.wall)) << " | " << m.at("nodes") << " | " << m.at("invalid") << " | "
         << fmt(m.at("min_scaled_jacobian").get<double>(), 3) << " | " << untangle << " |\n";
      data["orders"].push_back(row);
    }
    md << "\n";
    fs::remove_all(small_dir);
  }
  fs::create_directories(src + "/bench/results");
  std::ofstream(src + "/bench/results/scaling.json") << data.dump(1) << "\n";
  int plot = std::system(("/usr/bin/python3 " + src + "/bench/plot.py scaling " + src + "/bench/results/scaling.json " + src +
                          "/bench/results/scaling.png")
                             .c_str());
  md << (plot == 0 ? "![time vs elements](scaling.png)\n" : "(plot not drawn: `bench/plot.py` failed)\n");
  std::ofstream(src + "/bench/results/scaling.md") << md.str();
  std::cout << md.str();
  bool ok = true;
  for (auto& r : results) ok = ok && r["complete"].get<bool>();
  return ok ? 0 : 1;
}
