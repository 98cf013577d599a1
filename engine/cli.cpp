#include "engine/cli.hpp"

#include "engine/command.hpp"
#include "engine/fsutil.hpp"
#include "engine/golden.hpp"
#include "engine/registry.hpp"
#include "engine/runner.hpp"
#include "engine/schema.hpp"
#include "engine/workflow.hpp"

#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include <cstdlib>
#include <iomanip>
#include <iostream>
#include <sstream>

namespace fs = std::filesystem;
using nlohmann::json;

namespace meshflow {
namespace {

// Exit codes: 0 success, 1 a stage or a check failed, 2 bad input (workflow, arguments).
constexpr int kFailed = 1, kBadInput = 2;

std::string commands_footer() {
  std::string s;
  for (auto* c : all_commands()) s += "\n  " + c->usage + "\n      " + c->summary;
  return s.empty() ? s : "\nMesh and file tools:" + s;
}

std::optional<std::uint64_t> parse_size(const std::string& s) {
  if (s.empty()) return std::nullopt;
  double v = std::stod(s);
  char u = char(std::toupper(static_cast<unsigned char>(s.back())));
  double m = u == 'K' ? 1e3 : u == 'M' ? 1e6 : u == 'G' ? 1e9 : u == 'T' ? 1e12 : 1;
  return std::uint64_t(v * m);
}

void print_kind(const StageKind& k) {
  std::cout << k.kind << " (version " << k.version << "): " << k.summary << "\n";
  const json* s = kind_schema(k);
  if (!s || !s->contains("properties")) return;
  for (auto& [name, p] : (*s)["properties"].items()) {
    std::cout << "  " << name;
    if (p.contains("type")) std::cout << " (" << (p["type"].is_string() ? p["type"].get<std::string>() : p["type"].dump()) << ")";
    if (p.contains("default")) std::cout << " = " << p["default"].dump();
    if (p.contains("enum")) std::cout << " one of " << p["enum"].dump();
    if (p.contains("minimum")) std::cout << " >= " << p["minimum"].dump();
    if (p.contains("exclusiveMinimum")) std::cout << " > " << p["exclusiveMinimum"].dump();
    if (p.contains("maximum")) std::cout << " <= " << p["maximum"].dump();
    std::cout << "\n      " << p.value("description", "") << "\n";
  }
}

// Every registered kind has a schema that only uses supported keywords; every schema file
// belongs to a kind. Returns problems (empty = consistent).
std::vector<std::string> self_check() {
  std::vector<std::string> problems;
  for (auto* k : all_stage_kinds()) {
    const json* s = kind_schema(*k);
    if (!s) {
      problems.push_back("kind '" + k->kind + "' has no schemas/" + k->kind + ".schema.json");
      continue;
    }
    try {
      check_schema_keywords(*s, "schemas/" + k->kind + ".schema.json");
    } catch (const std::exception& e) {
      problems.push_back(e.what());
    }
  }
  try {
    check_schema_keywords(*schema_for("workflow"), "schemas/workflow.schema.json");
  } catch (const std::exception& e) {
    problems.push_back(e.what());
  }
  return problems;
}

}  // namespace

int cli_main(int argc, char** argv) {
  // Registered tool commands (meshflow quality FILE, meshflow convert IN OUT, ...).
  if (argc > 1) {
    if (const Command* c = find_command(argv[1])) {
      std::vector<std::string> args(argv + 2, argv + argc);
      try {
        return c->run(args);
      } catch (const std::exception& e) {
        std::cerr << "error: " << e.what() << "\n";
        return kBadInput;
      }
    }
  }

  CLI::App app{"meshflow: valid high-order curvilinear hybrid meshes for CFD, from a workflow file"};
  app.require_subcommand(1);
  app.footer(commands_footer());
  std::string workflow_file, stage, cache_dir, out_dir, max_size;
  std::vector<std::string> sets;
  int jobs = 0, threads = 0;
  bool verbose = false, dot = false, update = false, verify = false, repair = false, json_out = false;
  double max_age_days = -1, grace = 3600;

  auto add_common = [&](CLI::App* sc, bool with_run_opts) {
    sc->add_option("workflow", workflow_file, "workflow YAML file")->required();
    sc->add_option("--set", sets, "override a parameter: STAGE.PARAM=VALUE (repeatable)");
    sc->add_option("--cache", cache_dir, "cache folder (default: $MESHFLOW_CACHE, else .meshflow/ beside the workflow)");
    if (with_run_opts) {
      sc->add_option("-j,--jobs", jobs, "stages run at once (default: number of cores)");
      sc->add_option("--threads", threads, "total thread budget shared by running stages (default: number of cores)");
      sc->add_option("--out", out_dir, "output folder (default: out/<workflow name>/)");
      sc->add_flag("-v,--verbose", verbose, "show each stage's log lines");
    }
  };
  auto* run = app.add_subcommand("run", "run the stale stages of a workflow, write outputs and report.json");
  add_common(run, true);
  auto* status = app.add_subcommand("status", "show which stages are fresh, stale (and why) or never run");
  add_common(status, false);
  auto* explain = app.add_subcommand("explain", "why a stage is stale: the field-by-field diff of its key");
  add_common(explain, false);
  explain->add_option("stage", stage, "stage name")->required();
  auto* dag = app.add_subcommand("dag", "print the stage graph in run order (or Graphviz with --dot)");
  add_common(dag, false);
  dag->add_flag("--dot", dot, "Graphviz dot output");
  auto* check = app.add_subcommand("check", "run, then compare the outputs with the golden summary");
  add_common(check, true);
  auto* golden = app.add_subcommand("golden", "run, then write the golden summary (--update; refused when CI=true)");
  add_common(golden, true);
  golden->add_flag("--update", update, "rewrite golden/<name>/summary.json")->required();
  auto* clean = app.add_subcommand("clean", "delete the workflow's cache folder");
  add_common(clean, false);
  auto* gc = app.add_subcommand("gc", "trim the cache by size and age; --verify re-hashes every object");
  add_common(gc, false);
  gc->add_option("--max-size", max_size, "keep at most this many bytes of objects, least recently used first out (e.g. 10G)");
  gc->add_option("--max-age-days", max_age_days, "drop results unused for longer than this");
  gc->add_option("--grace", grace, "never delete unreferenced objects younger than this many seconds (a run may be storing them)");
  gc->add_flag("--verify", verify, "re-hash every object and check every action entry");
  gc->add_flag("--repair", repair, "with --verify: remove what is corrupt");
  auto* kinds = app.add_subcommand("kinds", "list stage kinds with their parameters, and artifact types with formats");
  std::string kind_name;
  kinds->add_option("kind", kind_name, "only this kind");
  kinds->add_flag("--json", json_out, "machine-readable");
  kinds->add_flag("--check", verify, "self-check: every kind has a valid schema; exit 1 otherwise");

  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e) == 0 ? 0 : kBadInput;
  }

  if (kinds->parsed()) {
    if (verify) {
      auto problems = self_check();
      for (auto& p : problems) std::cerr << "error: " << p << "\n";
      if (!problems.empty()) return kFailed;
      std::cout << all_stage_kinds().size() << " stage kinds, " << all_artifact_types().size() << " artifact types: consistent\n";
      return 0;
    }
    if (json_out) {
      json j = json::object();
      for (auto* k : all_stage_kinds())
        j["kinds"][k->kind] = {{"version", k->version}, {"summary", k->summary}, {"schema", kind_schema(*k) ? *kind_schema(*k) : json()}};
      for (auto* t : all_artifact_types()) {
        json f = json::array();
        for (auto& [n, x] : t->formats) f.push_back(n);
        j["artifact_types"][t->type] = {{"summary", t->summary}, {"formats", f}};
      }
      std::cout << j.dump(2) << "\n";
      return 0;
    }
    bool found = false;
    for (auto* k : all_stage_kinds())
      if (kind_name.empty() || k->kind == kind_name) {
        print_kind(*k);
        found = true;
      }
    if (!kind_name.empty() && !found) {
      std::cerr << "error: no stage kind '" << kind_name << "' (meshflow kinds lists them)\n";
      return kBadInput;
    }
    if (kind_name.empty()) {
      std::cout << "\nartifact types:\n";
      for (auto* t : all_artifact_types()) {
        std::cout << "  " << t->type << ": " << t->summary;
        for (auto& [n, f] : t->formats) std::cout << "\n      format " << n << " (" << f.extension << "): " << f.summary;
        std::cout << "\n";
      }
    }
    return 0;
  }

  Workflow wf;
  try {
    wf = load_workflow(workflow_file, sets);
  } catch (const WorkflowError& e) {
    std::cerr << "error: " << e.what() << "\n";
    return kBadInput;
  }

  try {
    if (dag->parsed()) {
      if (dot) {
        std::cout << "digraph \"" << wf.name << "\" {\n  rankdir=LR;\n";
        for (auto& s : wf.stages) {
          std::cout << "  \"" << s.name << "\" [label=\"" << s.name << "\\n(" << s.kind << ")\"];\n";
          for (auto& n : s.needs) std::cout << "  \"" << n << "\" -> \"" << s.name << "\";\n";
        }
        std::cout << "}\n";
      } else {
        for (auto& s : wf.stages) {
          std::cout << s.name << " (" << s.kind << ")";
          if (!s.needs.empty()) {
            std::cout << " <- ";
            for (size_t i = 0; i < s.needs.size(); ++i) std::cout << (i ? ", " : "") << s.needs[i];
          }
          std::cout << "\n";
        }
      }
      return 0;
    }
    if (clean->parsed()) {
      fs::path dir = resolve_cache_dir(wf, cache_dir);
      std::error_code ec;
      auto n = fs::remove_all(dir, ec);
      if (ec) {
        std::cerr << "error: cannot remove " << dir << ": " << ec.message() << "\n";
        return kFailed;
      }
      std::cout << "removed " << dir.string() << " (" << n << " files)\n";
      return 0;
    }
    Cache cache(resolve_cache_dir(wf, cache_dir));
    if (status->parsed()) {
      for (auto& s : workflow_status(wf, cache))
        std::cout << std::left << std::setw(16) << s.name << std::setw(10) << s.state << (s.reason.empty() ? "" : "  " + s.reason)
                  << "\n";
      return 0;
    }
    if (explain->parsed()) {
      for (auto& l : explain_stage(wf, cache, stage)) std::cout << l << "\n";
      return 0;
    }
    if (gc->parsed()) {
      if (verify) {
        auto r = cache.verify(repair);
        for (auto& p : r.problems) std::cout << (repair ? "removed: " : "problem: ") << p << "\n";
        std::cout << "verified " << r.objects << " objects and " << r.actions << " action entries: "
                  << (r.problems.empty() ? "consistent" : std::to_string(r.problems.size()) + " problems") << "\n";
        return r.problems.empty() || repair ? 0 : kFailed;
      }
      GcOptions o;
      o.max_bytes = parse_size(max_size);
      if (max_age_days >= 0) o.max_age_days = max_age_days;
      o.grace_seconds = grace;
      auto r = cache.gc(o);
      std::cout << "gc: removed " << r.actions_removed << " action entries, " << r.objects_removed << " objects, "
                << r.tmp_removed << " temp entries; objects " << r.bytes_before << " -> " << r.bytes_after << " bytes\n";
      return 0;
    }
    if (golden->parsed() && std::getenv("CI") && std::string(std::getenv("CI")) == "true") {
      std::cerr << "error: `meshflow golden --update` is refused when CI=true: goldens are updated by a person, "
                   "reviewed and committed, never by CI.\n";
      return kBadInput;
    }
    if (check->parsed() || golden->parsed()) {
      if (!wf.golden) {
        std::cerr << "error: " << wf.file.string() << ": the workflow has no `golden:` folder; add `golden: ../golden/"
                  << wf.name << "` (relative to the workflow file).\n";
        return kBadInput;
      }
    }
    RunOptions ro;
    ro.cache_dir = cache_dir;
    ro.out_dir = out_dir;
    ro.jobs = jobs;
    ro.threads = threads;
    ro.verbose = verbose;
    RunResult rr = run_workflow(wf, ro);
    if (!rr.ok) return kFailed;
    if (run->parsed()) return 0;
    json summary = golden_summary(wf, rr);
    fs::path gfile = wf.golden->dir / "summary.json";
    if (golden->parsed()) {
      fs::create_directories(wf.golden->dir);
      atomic_write(gfile, summary.dump(2) + "\n");
      std::cout << "golden: wrote " << gfile.string() << "\n";
      return 0;
    }
    json g;
    try {
      g = json::parse(read_file(gfile));
    } catch (const std::exception& e) {
      std::cerr << "error: cannot read the golden summary " << gfile.string()
                << ": run `meshflow golden " << wf.file.string() << " --update` to create it, then review and commit it.\n";
      return kBadInput;
    }
    auto diffs = golden_compare(g, summary, *wf.golden);
    fs::path obtained = wf.golden->dir / "summary.obtained.json";
    if (diffs.empty()) {
      std::error_code ec;
      fs::remove(obtained, ec);
      std::cout << "check: outputs agree with " << gfile.string() << "\n";
      return 0;
    }
    atomic_write(obtained, summary.dump(2) + "\n");
    std::cerr << "check: " << diffs.size() << " field(s) differ from " << gfile.string() << ":\n";
    for (auto& d : diffs) std::cerr << "  " << d << "\n";
    std::cerr << "The obtained summary is in " << obtained.string()
              << ". If the change is intended, run `meshflow golden " << wf.file.string() << " --update` and commit.\n";
    return kFailed;
  } catch (const WorkflowError& e) {
    std::cerr << "error: " << e.what() << "\n";
    return kBadInput;
  } catch (const std::exception& e) {
    std::cerr << "error: " << e.what() << "\n";
    return kFailed;
  }
}

}  // namespace meshflow
