#include "test_kinds.hpp"

#include "engine/artifact_type.hpp"
#include "engine/cli.hpp"
#include "engine/stage.hpp"

#include <nlohmann/json.hpp>

#include <chrono>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <fcntl.h>
#include <fstream>
#include <iostream>
#include <random>
#include <sstream>
#include <sys/wait.h>
#include <thread>
#include <unistd.h>

using nlohmann::json;

namespace mftest {

CliResult cli(const std::vector<std::string>& args) {
  std::vector<std::string> a = {"meshflow"};
  a.insert(a.end(), args.begin(), args.end());
  std::vector<char*> argv;
  for (auto& s : a) argv.push_back(s.data());
  argv.push_back(nullptr);
  std::ostringstream out, err;
  auto* old_out = std::cout.rdbuf(out.rdbuf());
  auto* old_err = std::cerr.rdbuf(err.rdbuf());
  int code = meshflow::cli_main(int(a.size()), argv.data());
  std::cout.rdbuf(old_out);
  std::cerr.rdbuf(old_err);
  return {code, out.str(), err.str()};
}

int spawn_meshflow(const std::vector<std::string>& args, const fs::path& log) {
  std::vector<std::string> a = {fs::read_symlink("/proc/self/exe").string(), "--as-meshflow"};
  a.insert(a.end(), args.begin(), args.end());
  return spawn(a, log);
}

std::vector<std::string> calls(const fs::path& file) {
  std::vector<std::string> v;
  std::ifstream in(file);
  std::string l;
  while (std::getline(in, l))
    if (!l.empty()) v.push_back(l);
  return v;
}

const char* const kStudy = R"(meshflow: 1
name: study
stages:
  a: {kind: t_source, with: {text: "ab", repeat: 2}}
  b: {kind: t_cat, needs: [a], with: {suffix: "-b"}}
  c: {kind: t_cat, needs: [b], with: {suffix: "-c"}}
outputs:
  final: {from: c}
matrix:
  b.suffix: ["-x", "-y"]
  c.suffix: ["-1", "-2", "-3"]
)";

int action_count(const fs::path& cache) {
  int n = 0;
  if (fs::exists(cache / "actions"))
    for (auto& e : fs::directory_iterator(cache / "actions")) n += e.path().extension() == ".json";
  return n;
}

int tmp_count(const fs::path& cache) {
  int n = 0;
  if (fs::exists(cache / "tmp"))
    for ([[maybe_unused]] auto& e : fs::directory_iterator(cache / "tmp")) ++n;
  return n;
}

WorkflowFixture::WorkflowFixture(const std::string& yaml, const std::string& tag)
    : dir(temp_dir(tag)), wf(dir / "w.yaml"), cache(dir / "cache"), calls_file(dir / "calls.txt"), out(dir / "out") {
  write_text(wf, yaml);
  setenv("MESHFLOW_TEST_CALLS", calls_file.c_str(), 1);
}

CliResult WorkflowFixture::run(std::vector<std::string> extra, const std::string& cmd) const {
  std::vector<std::string> a = {cmd, wf.string(), "--cache", cache.string()};
  if (cmd == "run" || cmd == "check" || cmd == "golden") {
    a.push_back("--out");
    a.push_back(out.string());
  }
  a.insert(a.end(), extra.begin(), extra.end());
  return cli(a);
}

nlohmann::json WorkflowFixture::report() const { return nlohmann::json::parse(read_text(out / "report.json")); }

nlohmann::json WorkflowFixture::stage(const std::string& name) const {
  const nlohmann::json rep = report();
  for (auto& s : rep["stages"])
    if (s["name"] == name) return s;
  return {};
}

}  // namespace mftest

// ---------------------------------------------------------------------------------------
// Test stage kinds. Each run appends its stage name to $MESHFLOW_TEST_CALLS (if set), so
// tests can count stage function calls across the forked stage processes.
namespace {

void record_call(meshflow::StageContext& ctx) {
  if (const char* f = std::getenv("MESHFLOW_TEST_CALLS")) {
    std::ofstream(f, std::ios::app) << ctx.stage_name() << "\n";
  }
}

meshflow::ArtifactTypeRegistrar blob_type({.type = "t_blob",
                                           .extension = ".txt",
                                           .summary = "test bytes",
                                           .formats = {{"upper",
                                                        {".upper.txt", "upper case",
                                                         [](const std::filesystem::path& in, const std::filesystem::path& out) {
                                                           std::string s = mftest::read_text(in);
                                                           for (auto& c : s) c = char(std::toupper(static_cast<unsigned char>(c)));
                                                           mftest::write_text(out, s);
                                                         }}}},
                                           .summarize = [](const std::filesystem::path& p) {
                                             std::string s = mftest::read_text(p);
                                             return json{{"bytes", s.size()}, {"head", s.substr(0, 16)}};
                                           }});

meshflow::StageRegistrar source({.kind = "t_source",
                                 .version = 1,
                                 .summary = "writes `text` `repeat` times",
                                 .libraries = {},
                                 .run =
                                     [](meshflow::StageContext& ctx) {
                                       record_call(ctx);
                                       std::string t = ctx.params()["text"];
                                       int n = ctx.params()["repeat"];
                                       std::ofstream o(ctx.output("blob", "t_blob"), std::ios::binary);
                                       for (int i = 0; i < n && o; ++i) o << t;
                                       o.close();
                                       if (!o) throw meshflow::StageError(std::string("cannot write the artifact: ") + std::strerror(errno));
                                     },
                                 .schema = R"({"type":"object","additionalProperties":false,"properties":{
                                   "text":{"type":"string","default":"hello","description":"what to write"},
                                   "repeat":{"type":"integer","default":1,"minimum":1,"maximum":100000000,"description":"how often"},
                                   "mode":{"type":"string","enum":["a","b"],"default":"a","description":"a mode"}}})"});

meshflow::StageRegistrar cat({.kind = "t_cat",
                              .version = 1,
                              .summary = "concatenates its inputs and `suffix`; may report a contract problem",
                              .libraries = {},
                              .run =
                                  [](meshflow::StageContext& ctx) {
                                    record_call(ctx);
                                    std::string s;
                                    for (auto& a : ctx.inputs()) s += mftest::read_text(a.path);
                                    s += ctx.params()["suffix"].get<std::string>();
                                    mftest::write_text(ctx.output("blob", "t_blob"), s);
                                    ctx.stats()["bytes"] = s.size();
                                    // the shape of stats.mesh, for the summary line
                                    ctx.stats()["mesh"] = {{"order", 4}, {"nodes", s.size()}, {"elements", {{"tet", 3}, {"prism", 0}}},
                                                           {"invalid", 0}, {"nonconforming_faces", 0},
                                                           {"min_scaled_jacobian", 0.5}, {"max_aspect_ratio", 70.0}};
                                    // a contract problem, as a mesh stage reports one for a broken mesh
                                    const std::string problem = ctx.params()["problem"];
                                    if (problem != "none")
                                      ctx.stats()["problems"] = nlohmann::json::array(
                                          {{{"clause", "validity"},
                                            {"what", "2 element(s) with det J <= 0 somewhere"},
                                            {"count", 2},
                                            {"blocking", problem == "blocking"},
                                            {"where", {{{"element", 17}, {"type", "tet4"}, {"at", {0.5, 0.25, 1.0}}}}}}});
                                  },
                              .schema = R"({"type":"object","additionalProperties":false,"properties":{
                                "suffix":{"type":"string","default":"","description":"appended text"},
                                "problem":{"type":"string","enum":["none","repairable","blocking"],"default":"none",
                                           "description":"a contract problem to report; blocking: no later stage can repair it"}}})"});

// Writes `chunks` chunks of 64 KiB, sleeping `ms` between them: a stage to kill mid-write.
meshflow::StageRegistrar slow({.kind = "t_slow",
                               .version = 1,
                               .summary = "writes slowly",
                               .libraries = {},
                               .run =
                                   [](meshflow::StageContext& ctx) {
                                     record_call(ctx);
                                     int chunks = ctx.params()["chunks"], ms = ctx.params()["ms"];
                                     std::ofstream o(ctx.output("blob", "t_blob"), std::ios::binary);
                                     std::string chunk(65536, 'x');
                                     for (int i = 0; i < chunks; ++i) {
                                       chunk[0] = char('a' + i % 26);
                                       o << chunk << std::flush;
                                       ctx.progress(double(i + 1) / chunks, "chunk " + std::to_string(i + 1));
                                       std::this_thread::sleep_for(std::chrono::milliseconds(ms));
                                     }
                                   },
                               .schema = R"({"type":"object","additionalProperties":false,"properties":{
                                 "chunks":{"type":"integer","default":50,"minimum":1,"description":"chunks"},
                                 "ms":{"type":"integer","default":20,"minimum":0,"description":"sleep per chunk"}}})"});

meshflow::StageRegistrar fail({.kind = "t_fail",
                               .version = 1,
                               .summary = "fails with a StageError",
                               .libraries = {},
                               .run =
                                   [](meshflow::StageContext& ctx) {
                                     record_call(ctx);
                                     ctx.output("blob", "t_blob");  // declared but never written
                                     throw meshflow::StageError(ctx.params()["message"].get<std::string>());
                                   },
                               .schema = R"({"type":"object","additionalProperties":false,"required":["message"],"properties":{
                                 "message":{"type":"string","description":"the error"}}})"});

meshflow::StageRegistrar crash({.kind = "t_crash",
                                .version = 1,
                                .summary = "aborts",
                                .libraries = {},
                                .run = [](meshflow::StageContext& ctx) {
                                  record_call(ctx);
                                  std::fprintf(stderr, "about to abort\n");
                                  std::abort();
                                },
                                .schema = R"({"type":"object","additionalProperties":false})"});

meshflow::StageRegistrar file_kind({.kind = "t_file",
                                    .version = 1,
                                    .summary = "copies the file `path`",
                                    .libraries = {},
                                    .run =
                                        [](meshflow::StageContext& ctx) {
                                          record_call(ctx);
                                          mftest::write_text(ctx.output("blob", "t_blob"),
                                                             mftest::read_text(ctx.file(ctx.params()["path"])));
                                        },
                                    .schema = R"({"type":"object","additionalProperties":false,"required":["path"],"properties":{
                                      "path":{"type":"string","x-meshflow-file":true,"description":"a file"}}})"});

// Computes n values with ctx.threads() threads into preallocated slots: the output must not
// depend on the thread count.
meshflow::StageRegistrar par({.kind = "t_par",
                              .version = 1,
                              .summary = "parallel computation",
                              .libraries = {},
                              .run =
                                  [](meshflow::StageContext& ctx) {
                                    record_call(ctx);
                                    int n = ctx.params()["n"];
                                    int t = ctx.threads();
                                    std::vector<double> v(size_t(n), 0.0);
                                    std::vector<std::thread> pool;
                                    for (int k = 0; k < t; ++k)
                                      pool.emplace_back([&, k] {
                                        for (int i = k; i < n; i += t) v[size_t(i)] = std::sin(0.001 * i) * std::exp(-1e-6 * i);
                                      });
                                    for (auto& th : pool) th.join();
                                    std::ofstream o(ctx.output("blob", "t_blob"), std::ios::binary);
                                    o.write(reinterpret_cast<const char*>(v.data()), std::streamsize(v.size() * sizeof(double)));
                                    ctx.stats()["threads_used"] = t;
                                  },
                              .schema = R"({"type":"object","additionalProperties":false,"properties":{
                                "n":{"type":"integer","default":100000,"minimum":1,"description":"values"}}})"});

}  // namespace
