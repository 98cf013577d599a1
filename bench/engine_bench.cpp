// Engine benchmark (issue 2): a synthetic 200-stage DAG of trivial stages — cold run and
// no-change re-run wall time — and SHA-256 throughput on a 1 GB artifact.
// Writes its figures to bench/results/engine.md (argv[1] overrides the path).
#include "engine/cache.hpp"
#include "engine/cli.hpp"
#include "engine/hash.hpp"
#include "engine/stage.hpp"
#include "engine/artifact_type.hpp"

#include <nlohmann/json.hpp>

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <sstream>
#include <vector>

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

namespace {
meshflow::ArtifactTypeRegistrar bytes_type({.type = "bench_bytes", .extension = ".bin", .summary = "bench bytes"});
// A trivial stage: writes its name and the digests of its inputs.
meshflow::StageRegistrar noop({.kind = "bench_noop",
                               .version = 1,
                               .summary = "trivial",
                               .run =
                                   [](meshflow::StageContext& ctx) {
                                     std::ofstream o(ctx.output("b", "bench_bytes"));
                                     o << ctx.stage_name();
                                     for (auto& a : ctx.inputs()) o << a.digest;
                                   },
                               .schema = R"({"type":"object","additionalProperties":false,"properties":{
                                 "salt":{"type":"integer","default":0,"description":"changes the key"}}})"});

double run_cli(const std::vector<std::string>& args) {
  std::vector<std::string> a = {"meshflow"};
  a.insert(a.end(), args.begin(), args.end());
  std::vector<char*> argv;
  for (auto& s : a) argv.push_back(s.data());
  std::ostringstream sink;
  auto* old = std::cout.rdbuf(sink.rdbuf());
  auto t0 = Clock::now();
  int code = meshflow::cli_main(int(a.size()), argv.data());
  double s = std::chrono::duration<double>(Clock::now() - t0).count();
  std::cout.rdbuf(old);
  if (code != 0) {
    std::cerr << sink.str();
    std::exit(1);
  }
  return s;
}
}  // namespace

int main(int argc, char** argv) {
  fs::path out = argc > 1 ? fs::path(argv[1]) : fs::path(MESHFLOW_SOURCE_DIR) / "bench/results/engine.md";
  fs::path dir = fs::temp_directory_path() / "meshflow-engine-bench";
  fs::remove_all(dir);
  fs::create_directories(dir);

  // 200 stages: 20 layers of 10, each stage needing two of the previous layer.
  std::ostringstream y;
  y << "meshflow: 1\nname: dag200\nstages:\n";
  for (int l = 0; l < 20; ++l)
    for (int i = 0; i < 10; ++i) {
      y << "  s" << l << "_" << i << ": {kind: bench_noop";
      if (l > 0) y << ", needs: [s" << l - 1 << "_" << i << ", s" << l - 1 << "_" << (i + 1) % 10 << "]";
      y << "}\n";
    }
  y << "outputs:\n  last: {from: s19_0}\n";
  std::ofstream(dir / "dag.yaml") << y.str();
  std::vector<std::string> common = {(dir / "dag.yaml").string(), "--cache", (dir / "cache").string(), "--out",
                                     (dir / "out").string()};
  auto with = [&](std::vector<std::string> a) {
    a.insert(a.begin() + 1, common.begin(), common.end());
    return a;
  };
  double cold = run_cli(with({"run"}));
  std::vector<double> warm;
  for (int i = 0; i < 5; ++i) warm.push_back(run_cli(with({"run"})));
  std::sort(warm.begin(), warm.end());
  double one = run_cli(with({"run", "--set", "s19_5.salt=1"}));

  // SHA-256 throughput on a 1 GB artifact (hash only, and store = hash + rename).
  const size_t gb = size_t(1) << 30;
  fs::path big = dir / "big.bin";
  {
    std::ofstream o(big, std::ios::binary);
    std::vector<char> buf(1 << 20);
    for (size_t i = 0; i < buf.size(); ++i) buf[i] = char(i * 2654435761u >> 13);
    for (size_t w = 0; w < gb; w += buf.size()) {
      buf[0] = char(w >> 20);
      o.write(buf.data(), std::streamsize(buf.size()));
    }
  }
  auto t0 = Clock::now();
  std::string digest = meshflow::sha256_file(big);
  double hash_s = std::chrono::duration<double>(Clock::now() - t0).count();
  meshflow::Cache cache(dir / "cache");
  t0 = Clock::now();
  cache.store_object(big);
  double store_s = std::chrono::duration<double>(Clock::now() - t0).count();
  fs::remove_all(dir);

  std::ostringstream md;
  md << "## Engine\n\n"
     << "Command: `make bench` (runs `build/bench/engine_bench`).\n\n"
     << "| figure | value | target |\n|---|---|---|\n"
     << "| 200-stage DAG, cold run (each stage forked) | " << cold << " s | - |\n"
     << "| 200-stage DAG, no-change re-run (median of 5) | " << warm[2] * 1000 << " ms | < 200 ms |\n"
     << "| 200-stage DAG, one leaf changed by --set | " << one * 1000 << " ms | - |\n"
     << "| SHA-256 of a 1 GiB artifact | " << (double(gb) / hash_s) / 1e9 << " GB/s | >= 1 GB/s |\n"
     << "| store of a 1 GiB artifact (hash + fsync + rename) | " << (double(gb) / store_s) / 1e9 << " GB/s | - |\n";
  bool ok_dag = warm[2] < 0.2, ok_hash = double(gb) / hash_s >= 1e9;
  md << "\n" << (ok_dag ? "No-change re-run meets its target." : "No-change re-run MISSES its 200 ms target.") << " "
     << (ok_hash ? "Hashing meets its target." : "Hashing MISSES its 1 GB/s target: OpenSSL's SHA-256 on this CPU "
                                                 "(no SHA extensions) is the bound; a faster key hash (BLAKE3) would fix it.")
     << "\n";
  fs::create_directories(out.parent_path());
  std::ofstream(out) << md.str();
  std::cout << md.str();
  return 0;
}
