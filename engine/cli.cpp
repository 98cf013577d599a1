#include "engine/cli.hpp"

#include "engine/artifact_type.hpp"
#include "engine/command.hpp"
#include "engine/export_snakemake.hpp"
#include "engine/fsutil.hpp"
#include "engine/golden.hpp"
#include "engine/matrix.hpp"
#include "engine/registry.hpp"
#include "engine/run_report.hpp"
#include "engine/runner.hpp"
#include "engine/schema.hpp"
#include "engine/version.hpp"
#include "engine/workflow.hpp"

#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <cstdlib>
#include <iomanip>
#include <iostream>
#include <sstream>

namespace fs = std::filesystem;
using nlohmann::json;

namespace meshflow {
namespace {

// Exit codes: 0 success, 1 a stage or a check failed, 2 bad input (workflow, arguments),
// 3 a mesh breaks the contract (invalid, degenerate, non-conforming, untagged, not covering
// the CAD or not filling its volume): outputs are written for inspection, report.json lists
// the problems.
constexpr int kFailed = 1, kBadInput = 2, kInvalid = 3;

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

json produces_json(const StageKind& k) {
  json a = json::array();
  for (auto& p : k.produces) a.push_back({{"name", p.name}, {"type", p.type}});
  return a;
}

std::string joined(const std::vector<std::string>& v) {
  std::string s;
  for (auto& x : v) s += (s.empty() ? "" : ", ") + x;
  return s;
}

// What a kind reads and writes, as `meshflow kinds KIND` prints it.
void print_flow(const StageKind& k) {
  if (k.produces.empty()) return;  // a test kind: undeclared
  std::cout << "  needs:    " << (k.needs.empty() ? "nothing (a source stage: no `needs`)" : joined(k.needs) + " (from the stages in its `needs`)")
            << "\n";
  if (!k.reads.empty()) std::cout << "  reads:    " << joined(k.reads) << " when a stage in its `needs` produces it\n";
  for (auto& p : k.produces) {
    std::cout << "  produces: " << p.name << " (type " << p.type;
    if (const ArtifactType* t = find_artifact_type(p.type); t && !t->formats.empty()) {
      std::vector<std::string> f;
      for (auto& [n, x] : t->formats) f.push_back(n);
      std::cout << "; output formats " << joined(f);
    }
    std::cout << ")\n";
  }
}

void print_kind(const StageKind& k) {
  std::cout << k.kind << " (version " << k.version << "): " << k.summary << "\n";
  print_flow(k);
  const json* s = kind_schema(k);
  if (!s || !s->contains("properties")) return;
  std::cout << "  parameters:\n";
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

// Every registered kind has a schema that only uses supported keywords and declares what it
// produces, of registered types; every schema file belongs to a kind. Returns problems (empty =
// consistent).
std::vector<std::string> self_check() {
  std::vector<std::string> problems;
  for (auto* k : all_stage_kinds()) {
    if (k->schema.empty() && k->produces.empty())
      problems.push_back("kind '" + k->kind + "' declares no `produces` (the artifacts it writes)");
    for (auto& t : k->needs) if (!find_artifact_type(t)) problems.push_back("kind '" + k->kind + "' needs unregistered type '" + t + "'");
    for (auto& t : k->reads) if (!find_artifact_type(t)) problems.push_back("kind '" + k->kind + "' reads unregistered type '" + t + "'");
    for (auto& a : k->produces)
      if (!find_artifact_type(a.type)) problems.push_back("kind '" + k->kind + "' produces unregistered type '" + a.type + "'");
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

// The workflow schema for editors (yaml-language-server): workflow.schema.json with, for each
// product kind, "if kind is K then with is schemas/K.schema.json", so editors complete and
// check parameters. Generated from the registry; a test keeps the committed copy current.
// (meshflow's own validator checks `with` separately and does not need if/then/$ref.)
json editor_schema_json() {
  json s = *schema_for("workflow");
  s["title"] = "meshflow workflow (editor schema, generated by `meshflow kinds --editor-schema`)";
  json& stage = s["properties"]["stages"]["additionalProperties"];
  json kinds = json::array();
  json all_of = json::array();
  for (auto* k : all_stage_kinds()) {
    if (!k->schema.empty()) continue;  // test-only kinds
    kinds.push_back(k->kind);
    all_of.push_back({{"if", {{"properties", {{"kind", {{"const", k->kind}}}}}}},
                      {"then", {{"properties", {{"with", {{"$ref", k->kind + ".schema.json"}}}}}}}});
  }
  stage["properties"]["kind"]["enum"] = kinds;
  stage["allOf"] = all_of;
  return s;
}

// Writes the exported Snakefile, making its folder first (`-o study/Snakefile` in a new folder).
void write_snakefile(const fs::path& path, const std::string& text) {
  const fs::path dir = path.parent_path();
  std::error_code ec;
  if (!dir.empty()) fs::create_directories(dir, ec);
  if (ec) throw WorkflowError("cannot make the folder " + dir.string() + " for the Snakefile: " + ec.message());
  atomic_write(path, text);
}

}  // namespace

int cli_main(int argc, char** argv) {
  // Registered tool commands (meshflow quality FILE, meshflow convert IN OUT, ...).
  if (argc > 1) {
    if (const Command* c = find_command(argv[1])) {
      std::vector<std::string> args(argv + 2, argv + argc);
      if (std::find(args.begin(), args.end(), "--help") != args.end() || std::find(args.begin(), args.end(), "-h") != args.end()) {
        std::cout << "usage: meshflow " << c->usage << "\n  " << c->summary << "\n";
        return 0;
      }
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
  app.set_version_flag("--version", version_line());
  app.footer(commands_footer() +
             "\n\nExit codes: 0 success; 1 a stage failed or `check` found differences; 2 bad input (workflow, "
             "arguments); 3 a mesh breaks the contract (invalid, degenerate, non-conforming or untagged elements, CAD faces "
             "not covered, volume not filled): outputs are written for inspection and report.json lists the problems.");
  std::string workflow_file, stage, cache_dir, out_dir, max_size, variant, only, target, snakefile_path = "Snakefile", exe;
  std::vector<std::string> sets;
  int jobs = 0, threads = 0;
  bool verbose = false, dot = false, update = false, verify = false, repair = false, json_out = false;
  bool allow_invalid = false;
  double max_age_days = -1, grace = 3600;
  std::string remote_url, remote_netrc;
  double remote_timeout = 60, remote_connect_timeout = 5;
  double memory_budget = -1;  // RunOptions' default (a share of the machine)

  auto add_common = [&](CLI::App* sc, bool with_run_opts) {
    sc->add_option("workflow", workflow_file, "workflow YAML file")->required();
    sc->add_option("--set", sets, "override a parameter: STAGE.PARAM=VALUE (repeatable)");
    sc->add_option("--cache", cache_dir, "cache folder (default: $MESHFLOW_CACHE, else .meshflow/ beside the workflow)");
    sc->add_option("--variant", variant, "one variant of the workflow's matrix (by name; `meshflow dag` lists them)");
    if (with_run_opts) {
      sc->add_option("-j,--jobs", jobs, "stages run at once (default: number of cores)")->check(CLI::NonNegativeNumber);
      sc->add_option("--threads", threads, "total thread budget shared by running stages (default: number of cores)")
          ->check(CLI::NonNegativeNumber);
      sc->add_option("--memory-budget", memory_budget,
                     "GB of memory each stage may take; past it the stage fails with a message (default: 80 % of the "
                     "machine's memory; 0: no limit)")
          ->check(CLI::NonNegativeNumber);
      sc->add_option("--out", out_dir, "output folder (default: out/<workflow name>/)");
      sc->add_flag("-v,--verbose", verbose, "show each stage's log lines");
      sc->add_option("--remote-cache", remote_url,
                     "shared HTTP cache (Bazel layout: URL/cas/<sha256>, URL/ac/<key>) looked up after the local one; "
                     "what runs is uploaded (default: $MESHFLOW_REMOTE_CACHE)");
      sc->add_option("--remote-netrc", remote_netrc,
                     "netrc file with the remote cache's credentials (default: $MESHFLOW_REMOTE_CACHE_NETRC, else ~/.netrc)");
      sc->add_option("--remote-timeout", remote_timeout, "seconds one remote cache request may take, transfer included (default 60)");
      sc->add_option("--remote-connect-timeout", remote_connect_timeout,
                     "seconds to wait for the remote cache to accept a connection (default 5)");
    }
    if (sc->get_name() == "run")
      sc->add_flag("--allow-invalid", allow_invalid,
                   "debugging: accept meshes that break the contract (exit 0, report.json \"invalid_accepted\"); "
                   "check and golden never accept them");
  };
  auto* run = app.add_subcommand("run", "run the stale stages of a workflow, write outputs and report.json");
  add_common(run, true);
  run->add_option("--only", only, "run this stage (and what it needs, if stale) and nothing else; no outputs (a Snakemake rule's command)");
  auto* exp = app.add_subcommand("export", "write the workflow (each matrix variant) as a Snakefile: export snakemake WORKFLOW");
  exp->add_option("target", target, "what to export: snakemake")->required()->check(CLI::IsMember({"snakemake"}));
  exp->add_option("workflow", workflow_file, "workflow YAML file")->required();
  exp->add_option("--set", sets, "override a parameter in every rule: STAGE.PARAM=VALUE (repeatable)");
  exp->add_option("--cache", cache_dir, "the cache the rules share (default: $MESHFLOW_CACHE, else .meshflow/ beside the workflow)");
  exp->add_option("--out", out_dir, "output folder (default: out/<workflow name>/, a folder per variant in it)");
  exp->add_option("-o,--output", snakefile_path, "the Snakefile to write (default: Snakefile; - for stdout)");
  exp->add_option("--threads", threads, "threads per stage rule (default 2)")->check(CLI::NonNegativeNumber);
  exp->add_option("--exe", exe, "the meshflow command the rules run (default: this executable)");
  exp->add_option("--remote-cache", remote_url, "a remote cache every rule uses (see run --remote-cache)");
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
  golden->add_flag("--update", update, "rewrite golden/<name>/summary.json (needed: golden does nothing else)");
  auto* clean = app.add_subcommand("clean", "delete the workflow's cache folder");
  add_common(clean, false);
  auto* gc = app.add_subcommand("gc", "trim the cache by size and age; --verify re-hashes every object");
  add_common(gc, false);
  gc->add_option("--max-size", max_size, "keep at most this many bytes of objects, least recently used first out (e.g. 10G)");
  gc->add_option("--max-age-days", max_age_days, "drop results unused for longer than this");
  gc->add_option("--grace", grace, "never delete unreferenced objects younger than this many seconds (a run may be storing them)");
  gc->add_flag("--verify", verify, "re-hash every object and check every action entry");
  gc->add_flag("--repair", repair, "with --verify: remove what is corrupt, and the entries computed from it");
  gc->add_option("--out", out_dir, "output folder whose stale temp files to remove (default: out/<workflow name>/)");
  auto* report = app.add_subcommand("report", "write OUT_DIR/report.html again from what a run wrote there (report.json, the cache)");
  std::string report_dir;
  report->add_option("out_dir", report_dir, "a run's output folder (out/<workflow name>/)")->required();
  report->add_option("--cache", cache_dir, "the cache holding the run's artifacts (default: the one report.json names)");
  report->add_option("--threads", threads, "threads for the pictures (default: number of cores)")->check(CLI::NonNegativeNumber);
  auto* kinds = app.add_subcommand("kinds", "list stage kinds with their parameters, and artifact types with formats");
  std::string kind_name;
  kinds->add_option("kind", kind_name, "only this kind");
  kinds->add_flag("--json", json_out, "machine-readable");
  kinds->add_flag("--check", verify, "self-check: every kind has a valid schema; exit 1 otherwise");
  bool editor_schema = false;
  kinds->add_flag("--editor-schema", editor_schema,
                  "print schemas/workflow-editor.json: the workflow schema with each kind's parameters, for editors");

  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e) == 0 ? 0 : kBadInput;
  }

  if (report->parsed()) return rebuild_report(report_dir, cache_dir, threads > 0 ? threads : 0);

  if (kinds->parsed()) {
    if (editor_schema) {
      std::cout << editor_schema_json().dump(2) << "\n";
      return 0;
    }
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
        j["kinds"][k->kind] = {{"version", k->version},     {"summary", k->summary},   {"needs", k->needs},
                               {"reads", k->reads},         {"produces", produces_json(*k)},
                               {"schema", kind_schema(*k) ? *kind_schema(*k) : json()}};
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

  if (golden->parsed() && !update) {
    std::cerr << "error: `meshflow golden` rewrites the golden summary only when asked: run `meshflow golden "
              << workflow_file << " --update`.\n";
    return kBadInput;
  }

  Workflow wf;
  std::vector<Variant> variants;
  try {
    wf = load_workflow(workflow_file, sets);
    variants = matrix_variants(wf);
    if (!variants.empty() && variant.empty() && ((run->parsed() && only.empty()) || exp->parsed())) {
      // the whole study: run_matrix or the export below
    } else if (!variant.empty()) {  // one variant: the workflow with its values, outputs in out/<name>/<variant>/
      const Variant& v = find_variant(variants, variant, wf);
      auto o = sets;
      o.insert(o.end(), v.overrides.begin(), v.overrides.end());
      wf = load_workflow(workflow_file, o);
      if (out_dir.empty()) out_dir = (fs::current_path() / "out" / wf.name / v.name).string();
    } else if (!variants.empty() && !dag->parsed() && !clean->parsed() && !gc->parsed()) {
      std::string names;
      for (auto& x : variants) names += (names.empty() ? "" : ", ") + x.name;
      std::cerr << "error: " << wf.file.string() << " has a matrix of " << variants.size()
                << " variants; this command takes one: add --variant NAME (" << names << ").\n";
      return kBadInput;
    }
  } catch (const WorkflowError& e) {
    std::cerr << "error: " << e.what() << "\n";
    return kBadInput;
  }

  try {
    RemoteCacheOptions remote_opts;  // checked before any folder is made or stage run
    if (run->parsed() || check->parsed() || golden->parsed())
      remote_opts = resolve_remote_cache(remote_url, remote_netrc, remote_connect_timeout, remote_timeout);
    auto run_options = [&] {
      RunOptions ro;
      ro.remote = remote_opts;
      ro.cache_dir = cache_dir;
      ro.out_dir = out_dir;
      ro.jobs = jobs;
      ro.threads = threads;
      ro.memory_budget_gb = memory_budget;
      ro.verbose = verbose;
      ro.allow_invalid = allow_invalid && run->parsed();
      return ro;
    };
    if (exp->parsed()) {
      SnakemakeExport so;
      so.exe = exe.empty() ? fs::read_symlink("/proc/self/exe").string() : exe;
      so.cache_dir = fs::absolute(resolve_cache_dir(wf, cache_dir));
      so.out_dir = fs::absolute(out_dir.empty() ? fs::current_path() / "out" / wf.name : fs::path(out_dir));
      so.threads = threads > 0 ? threads : 2;
      so.sets = sets;
      if (!remote_url.empty()) so.extra = {"--remote-cache", remote_url};
      const std::string text = snakefile(wf, so);
      if (snakefile_path == "-") {
        std::cout << text;
      } else {
        write_snakefile(snakefile_path, text);
        std::cout << "wrote " << snakefile_path << ": run it with `snakemake -s " << snakefile_path
                  << " --cores N` (or --slurm / --cluster on a cluster whose nodes share " << so.cache_dir.string() << ")\n";
      }
      return 0;
    }
    if (!variants.empty() && variant.empty() && run->parsed()) {  // the whole study
      auto res = run_matrix(wf, sets, run_options());
      return res.ok ? 0 : res.bad_input ? kBadInput : res.failed ? kFailed : kInvalid;
    }
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
        if (!variants.empty() && variant.empty()) {
          std::cout << "matrix: " << variants.size() << " variants:";
          for (auto& v : variants) std::cout << " " << v.name;
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
      fs::path out = out_dir.empty() ? fs::current_path() / "out" / wf.name : fs::path(out_dir);
      int out_tmp = remove_stale_tmp_files(out);  // left by runs killed while writing outputs
      if (verify) {
        cache.clean_stale_locks();
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
                << r.tmp_removed << " temp entries, " << r.locks_removed << " stale locks, " << r.quarantine_removed
                << " quarantined objects, " << out_tmp << " stale temp files in " << out.string() << "; objects "
                << r.bytes_before << " -> " << r.bytes_after << " bytes\n";
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
    RunOptions ro = run_options();
    if (!only.empty()) {  // one stage (and what it needs), no outputs: a Snakemake rule
      wf = wf.upstream_of(only);
      ro.materialise = false;
      ro.deliver = false;
    }
    RunResult rr = run_workflow(wf, ro);
    if (!rr.ok) return rr.bad_input ? kBadInput : rr.failed ? kFailed : kInvalid;
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
