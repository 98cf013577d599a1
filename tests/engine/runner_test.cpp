// The runner and the cache: hits, partial re-runs, failures, kills, concurrency, locks,
// determinism, status/explain, golden, gc.
#include <doctest/doctest.h>

#include "engine/cache.hpp"
#include "engine/fsutil.hpp"
#include "test_kinds.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <chrono>
#include <csignal>
#include <cstdlib>
#include <thread>
#include <unistd.h>

using namespace mftest;
using nlohmann::json;

namespace {
const char* kChain = R"(meshflow: 1
name: chain
stages:
  a: {kind: t_source, with: {text: "ab", repeat: 3}}
  b: {kind: t_cat, needs: [a], with: {suffix: "-b"}}
  c: {kind: t_cat, needs: [b], with: {suffix: "-c"}}
  d: {kind: t_cat, needs: [a], with: {suffix: "-d"}}
outputs:
  final: {from: c, formats: [upper]}
  raw: {from: d}
golden: golden
)";

struct Fixture : WorkflowFixture {
  Fixture(const std::string& yaml = kChain) : WorkflowFixture(yaml) {}
};
}  // namespace

TEST_CASE("a second run is all cache hits and calls no stage function") {
  Fixture f;
  auto r1 = f.run();
  INFO(r1.out, r1.err);
  REQUIRE(r1.code == 0);
  CHECK(f.calls().size() == 4);
  CHECK(read_text(f.out / "final.upper.txt") == "ABABAB-B-C");
  CHECK(read_text(f.out / "raw.txt") == "ababab-d");
  json report = json::parse(read_text(f.out / "report.json"));
  CHECK(report["ok"] == true);
  CHECK(report["stages"].size() == 4);
  CHECK(report["stages"][2]["stats"]["bytes"] == 10);
  CHECK(report["stages"][0]["status"] == "ran");
  CHECK(report["stages"][0]["peak_rss_mb"].get<double>() > 0);
  // the summary has a human line per mesh-producing stage
  CHECK(r1.out.find("mesh c: order 4, 10 nodes, 3 tet; invalid 0, non-conforming faces 0, min scaled Jacobian 0.500, max aspect ratio 70.0") !=
        std::string::npos);

  f.reset_calls();
  auto r2 = f.run();
  REQUIRE(r2.code == 0);
  CHECK(f.calls().empty());
  json report2 = json::parse(read_text(f.out / "report.json"));
  for (auto& s : report2["stages"]) CHECK(s["status"] == "cached");
  CHECK(report2["stages"][2]["stats"]["bytes"] == 10);  // stats of the cached run are kept
  CHECK(read_text(f.out / "final.upper.txt") == "ABABAB-B-C");
}

TEST_CASE("outputs re-written over themselves leave no temporary file in the output folder") {
  Fixture f;
  REQUIRE(f.run().code == 0);
  // without report.json the runner cannot tell that raw.txt is already the cache object's link:
  // it links it again (rename onto the same inode, which leaves the source)
  fs::remove(f.out / "report.json");
  auto r = f.run();
  INFO(r.out, r.err);
  REQUIRE(r.code == 0);
  std::vector<std::string> names;
  for (auto& e : fs::directory_iterator(f.out)) names.push_back(e.path().filename().string());
  std::sort(names.begin(), names.end());
  std::string all;
  for (auto& n : names) all += n + " ";
  CHECK(all == "final.upper.txt raw.txt report.html report.json ");
  CHECK(read_text(f.out / "raw.txt") == "ababab-d");
}

TEST_CASE("--set on one stage re-runs it and its descendants only") {
  Fixture f;
  REQUIRE(f.run().code == 0);
  f.reset_calls();
  auto r = f.run({"--set", "b.suffix=-B2"});
  REQUIRE(r.code == 0);
  auto c = f.calls();
  std::sort(c.begin(), c.end());
  CHECK(c == std::vector<std::string>{"b", "c"});
  CHECK(read_text(f.out / "final.upper.txt") == "ABABAB-B2-C");
  // status and explain see the difference against the last run of each stage
  f.reset_calls();
  auto st = f.run({"--set", "a.repeat=4"}, "status");
  CHECK(st.out.find("a               stale") != std::string::npos);
  CHECK(st.out.find("params.repeat: 3 -> 4") != std::string::npos);
  auto ex = f.run({"--set", "a.repeat=4"}, "explain");
  (void)ex;
  auto ex2 = cli({"explain", f.wf.string(), "a", "--cache", f.cache.string(), "--set", "a.repeat=4"});
  CHECK(ex2.code == 0);
  CHECK(ex2.out.find("params.repeat: 3 -> 4") != std::string::npos);
  auto ex3 = cli({"explain", f.wf.string(), "c", "--cache", f.cache.string(), "--set", "a.repeat=4"});
  CHECK(ex3.out.find("c is stale because a stage it needs is stale") != std::string::npos);
  CHECK(ex3.out.find("b: stale") != std::string::npos);
  CHECK(f.calls().empty());  // status/explain never run stages
}

TEST_CASE("a failing stage: message, non-zero exit, no cache entry, dependents skipped, siblings run") {
  Fixture f(R"(meshflow: 1
name: failing
stages:
  a: {kind: t_source}
  bad: {kind: t_fail, needs: [a], with: {message: "the wing has a hole at face 12: heal it first"}}
  after: {kind: t_cat, needs: [bad]}
  other: {kind: t_cat, needs: [a]}
)");
  auto r = f.run();
  CHECK(r.code == 1);
  CHECK(r.err.find("stage 'bad' (kind t_fail) failed: the wing has a hole at face 12") != std::string::npos);
  CHECK(r.err.find("w.yaml") != std::string::npos);
  CHECK(action_count(f.cache) == 2);  // a and other
  json report = json::parse(read_text(f.out / "report.json"));
  CHECK(report["ok"] == false);
  CHECK(report["stages"][1]["status"] == "failed");
  CHECK(report["stages"][2]["status"] == "skipped");
  CHECK(report["stages"][3]["status"] == "ran");
  CHECK(tmp_count(f.cache) == 0);
}

TEST_CASE("a crashing stage is reported with its signal and output, and leaves nothing") {
  Fixture f("meshflow: 1\nname: crash\nstages:\n  boom: {kind: t_crash}\n");
  auto r = f.run();
  CHECK(r.code == 1);
  CHECK(r.err.find("signal 6") != std::string::npos);
  CHECK(r.err.find("about to abort") != std::string::npos);
  CHECK(action_count(f.cache) == 0);
  CHECK(tmp_count(f.cache) == 0);
}

TEST_CASE("a missing input file is a clear error before anything runs") {
  Fixture f("meshflow: 1\nname: files\nstages:\n  c: {kind: t_file, with: {path: data/in.txt}}\n");
  auto r = f.run();
  CHECK(r.code == 2);  // bad input, as --help says
  CHECK(r.err.find("parameter 'path': cannot read") != std::string::npos);
  CHECK(action_count(f.cache) == 0);
  // the file's content is in the key: same path, new content -> re-run
  write_text(f.dir / "data/in.txt", "one");
  REQUIRE(f.run().code == 0);
  CHECK(read_text(f.out / "report.json").find("\"ran\"") != std::string::npos);
  f.reset_calls();
  REQUIRE(f.run().code == 0);
  CHECK(f.calls().empty());
  write_text(f.dir / "data/in.txt", "two");
  REQUIRE(f.run().code == 0);
  CHECK(f.calls().size() == 1);
}

TEST_CASE("SIGKILL mid-write leaves no action entry and the next run recomputes") {
  Fixture f("meshflow: 1\nname: slow\nstages:\n  s: {kind: t_slow, with: {chunks: 40, ms: 25}}\noutputs:\n  s: {from: s}\n");
  fs::path log = f.dir / "log.txt";
  int pid = spawn_meshflow({"run", f.wf.string(), "--cache", f.cache.string(), "--out", f.out.string()}, log);
  // wait until the stage is writing (its output file grows in the scratch dir)
  bool writing = false;
  for (int i = 0; i < 200 && !writing; ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
    if (fs::exists(f.cache / "tmp"))
      for (auto& e : fs::recursive_directory_iterator(f.cache / "tmp"))
        if (e.path().filename() == "out.blob" && e.file_size() > 65536 * 3) writing = true;
  }
  REQUIRE(writing);
  kill(pid, SIGKILL);
  CHECK(wait_exit(pid) == 128 + SIGKILL);
  std::this_thread::sleep_for(std::chrono::milliseconds(200));  // the stage child dies with its parent
  CHECK(action_count(f.cache) == 0);
  f.reset_calls();
  auto r = f.run();
  REQUIRE(r.code == 0);
  CHECK(f.calls().size() == 1);
  CHECK(fs::file_size(f.out / "s.txt") == 40 * 65536);
  CHECK(tmp_count(f.cache) == 0);  // the dead run's scratch was cleaned
  CHECK(cli({"gc", f.wf.string(), "--cache", f.cache.string(), "--verify"}).code == 0);
}

TEST_CASE("two processes on one cache: both succeed, identical outputs, consistent cache") {
  Fixture f(R"(meshflow: 1
name: conc
stages:
  s: {kind: t_slow, with: {chunks: 10, ms: 30}}
  t: {kind: t_cat, needs: [s], with: {suffix: end}}
  u: {kind: t_par, with: {n: 50000}}
outputs:
  o: {from: t}
)");
  int p1 = spawn_meshflow({"run", f.wf.string(), "--cache", f.cache.string(), "--out", (f.dir / "o1").string()}, f.dir / "l1");
  int p2 = spawn_meshflow({"run", f.wf.string(), "--cache", f.cache.string(), "--out", (f.dir / "o2").string()}, f.dir / "l2");
  CHECK(wait_exit(p1) == 0);
  CHECK(wait_exit(p2) == 0);
  INFO(read_text(f.dir / "l1"), read_text(f.dir / "l2"));
  CHECK(read_text(f.dir / "o1/o.txt") == read_text(f.dir / "o2/o.txt"));
  CHECK(action_count(f.cache) == 3);
  // the lock made one of them wait instead of computing `s` twice
  CHECK(calls(f.calls_file).size() == 3);
  auto v = cli({"gc", f.wf.string(), "--cache", f.cache.string(), "--verify"});
  CHECK(v.code == 0);
  CHECK(v.out.find("consistent") != std::string::npos);
  CHECK(tmp_count(f.cache) == 0);
}

TEST_CASE("a stale lock left by a dead pid is broken") {
  Fixture f("meshflow: 1\nname: lock\nstages:\n  a: {kind: t_source}\n");
  // the key of `a`: run once, read it, then remove the entry and plant a dead holder's lock
  REQUIRE(f.run().code == 0);
  json report = json::parse(read_text(f.out / "report.json"));
  std::string key = report["stages"][0]["key"];
  fs::remove(f.cache / "actions" / (key + ".json"));
  pid_t dead = fork();
  if (dead == 0) _exit(0);
  wait_exit(dead);
  write_text(f.cache / "locks" / (key + ".lock"),
             json{{"pid", dead}, {"host", meshflow::hostname()}, {"nonce", "x"}}.dump());
  auto t0 = std::chrono::steady_clock::now();
  auto r = f.run();
  CHECK(r.code == 0);
  CHECK(std::chrono::steady_clock::now() - t0 < std::chrono::seconds(10));
  CHECK(!fs::exists(f.cache / "locks" / (key + ".lock")));
  // a live holder (this process) is waited for, not broken
  meshflow::Cache cache(f.cache);
  auto mine = cache.try_lock("k1");
  REQUIRE(mine);
  std::string holder;
  CHECK(!cache.try_lock("k1", &holder));
  CHECK(holder.find("pid " + std::to_string(getpid())) != std::string::npos);
}

TEST_CASE("same key gives byte-identical artifacts at --jobs 1 and --jobs 4") {
  const char* yaml = R"(meshflow: 1
name: det
stages:
  p1: {kind: t_par, with: {n: 200000}}
  p2: {kind: t_par, with: {n: 100000}}
  a: {kind: t_source, with: {text: x}}
  j: {kind: t_cat, needs: [p1, p2, a]}
outputs:
  o: {from: j}
)";
  Fixture f1(yaml), f4(yaml);
  auto r1 = f1.run({"--jobs", "1", "--threads", "1"});
  auto r4 = f4.run({"--jobs", "4", "--threads", "8"});
  REQUIRE(r1.code == 0);
  REQUIRE(r4.code == 0);
  CHECK(read_text(f1.out / "o.txt") == read_text(f4.out / "o.txt"));
  json a = json::parse(read_text(f1.out / "report.json")), b = json::parse(read_text(f4.out / "report.json"));
  for (size_t i = 0; i < a["stages"].size(); ++i) CHECK(a["stages"][i]["key"] == b["stages"][i]["key"]);
  CHECK(a["stages"][0]["stats"]["threads_used"] == 1);
  CHECK(b["stages"][0]["stats"]["threads_used"] == 2);
}

TEST_CASE("the thread budget is shared by the stages that run together: a chain gets all of it at every step") {
  // the threads each t_par stage used, run with -j 2 --threads 2
  auto threads_used = [](const std::string& p2_needs) {
    Fixture f("meshflow: 1\nname: budget\nstages:\n  p1: {kind: t_par, with: {n: 1000}}\n  p2: {kind: t_par, " + p2_needs +
              "with: {n: 2000}}\noutputs:\n  o: {from: p2}\n");
    auto r = f.run({"--jobs", "2", "--threads", "2"});
    REQUIRE(r.code == 0);
    json rep = json::parse(read_text(f.out / "report.json"));
    return std::make_pair(rep["stages"][0]["stats"]["threads_used"].get<int>(), rep["stages"][1]["stats"]["threads_used"].get<int>());
  };
  CHECK(threads_used("needs: [p1], ") == std::make_pair(2, 2));  // a chain: each alone, every thread (not 2 / jobs)
  CHECK(threads_used("") == std::make_pair(1, 1));               // two ready at once: one thread each
}

TEST_CASE("golden: check passes, reports differing fields, refuses --update under CI") {
  Fixture f;
  unsetenv("CI");
  auto g = f.run({"--update"}, "golden");
  REQUIRE(g.code == 0);
  CHECK(fs::exists(f.dir / "golden/summary.json"));
  auto c = f.run({}, "check");
  CHECK(c.code == 0);
  auto bad = f.run({"--set", "c.suffix=-cc"}, "check");
  CHECK(bad.code == 1);
  CHECK(bad.err.find("outputs.final.bytes: golden 10, obtained 11") != std::string::npos);
  CHECK(fs::exists(f.dir / "golden/summary.obtained.json"));
  setenv("CI", "true", 1);
  auto refused = f.run({"--update"}, "golden");
  unsetenv("CI");
  CHECK(refused.code == 2);
  CHECK(refused.err.find("refused when CI=true") != std::string::npos);
}

TEST_CASE("gc: size budget removes least recently used results, verify finds corruption") {
  Fixture f;
  REQUIRE(f.run().code == 0);
  REQUIRE(f.run({"--set", "a.repeat=5000"}).code == 0);
  int before = action_count(f.cache);
  CHECK(before == 8);
  auto g = cli({"gc", f.wf.string(), "--cache", f.cache.string(), "--max-size", "30K", "--grace", "0"});
  CHECK(g.code == 0);
  CHECK(action_count(f.cache) < before);
  CHECK(cli({"gc", f.wf.string(), "--cache", f.cache.string(), "--verify"}).code == 0);
  // corrupt one object: verify reports it, --repair removes it and its entries, a run recomputes
  fs::path obj;
  for (auto& e : fs::recursive_directory_iterator(f.cache / "objects"))
    if (e.is_regular_file()) obj = e.path();
  REQUIRE(!obj.empty());
  fs::permissions(obj, fs::perms::owner_write, fs::perm_options::add);
  write_text(obj, "garbage");
  auto v = cli({"gc", f.wf.string(), "--cache", f.cache.string(), "--verify"});
  CHECK(v.code == 1);
  CHECK(v.out.find("problem: object") != std::string::npos);
  CHECK(cli({"gc", f.wf.string(), "--cache", f.cache.string(), "--verify", "--repair"}).code == 0);
  CHECK(cli({"gc", f.wf.string(), "--cache", f.cache.string(), "--verify"}).code == 0);
  CHECK(f.run().code == 0);
}

TEST_CASE("CLI: dag, kinds, clean, bad workflow exit code 2") {
  Fixture f;
  auto d = f.run({"--dot"}, "dag");
  CHECK(d.code == 0);
  CHECK(d.out.find("\"a\" -> \"b\"") != std::string::npos);
  auto k = cli({"kinds", "t_source"});
  CHECK(k.out.find("repeat (integer) = 1 >= 1") != std::string::npos);
  CHECK(cli({"kinds", "--check"}).code == 0);
  write_text(f.dir / "bad.yaml", "meshflow: 1\nname: x\nstages:\n  a: {kind: t_source, with: {repeat: 0}}\n");
  auto b = cli({"run", (f.dir / "bad.yaml").string(), "--cache", f.cache.string()});
  CHECK(b.code == 2);
  CHECK(b.err.find("bad.yaml:4:") != std::string::npos);
  CHECK(action_count(f.cache) == 0);
  REQUIRE(f.run().code == 0);
  CHECK(cli({"clean", f.wf.string(), "--cache", f.cache.string()}).code == 0);
  CHECK(!fs::exists(f.cache));
}

TEST_CASE("disk full: a clear message, non-zero exit, a consistent cache") {
  Fixture f(R"(meshflow: 1
name: full
stages:
  small: {kind: t_source, with: {text: "x"}}
  big: {kind: t_source, with: {text: "0123456789abcdef", repeat: 200000}}
)");
  // A 1 MiB tmpfs as the cache (needs root, as in CI; elsewhere the case is reported skipped).
  fs::path mnt = f.dir / "mnt";
  fs::create_directories(mnt);
  if (geteuid() != 0 || std::system(("mount -t tmpfs -o size=1m tmpfs " + mnt.string() + " 2>/dev/null").c_str()) != 0) {
    MESSAGE("not root or tmpfs mount refused: disk-full case not run");
    return;
  }
  struct Unmount {
    fs::path p;
    ~Unmount() { (void)!std::system(("umount " + p.string()).c_str()); }
  } unmount{mnt};
  auto r = cli({"run", f.wf.string(), "--cache", (mnt / "cache").string(), "--out", f.out.string(), "-j", "1"});
  CHECK(r.code == 1);
  INFO(r.err);
  CHECK(r.err.find("No space left on device") != std::string::npos);
  CHECK(r.err.find("KiB free") != std::string::npos);
  CHECK(action_count(mnt / "cache") == 1);  // `small` completed, `big` left nothing
  CHECK(tmp_count(mnt / "cache") == 0);
  auto v = cli({"gc", f.wf.string(), "--cache", (mnt / "cache").string(), "--verify"});
  CHECK(v.code == 0);
}

TEST_CASE("the cache folder: beside the workflow by default, MESHFLOW_CACHE, then --cache") {
  Fixture f("meshflow: 1\nname: where\nstages:\n  a: {kind: t_source}\n");
  auto run = [&](std::vector<std::string> extra) {
    std::vector<std::string> a = {"run", f.wf.string(), "--out", f.out.string()};
    a.insert(a.end(), extra.begin(), extra.end());
    return cli(a);
  };
  unsetenv("MESHFLOW_CACHE");
  REQUIRE(run({}).code == 0);
  CHECK(action_count(f.dir / ".meshflow") == 1);
  setenv("MESHFLOW_CACHE", (f.dir / "env-cache").c_str(), 1);
  REQUIRE(run({}).code == 0);
  CHECK(action_count(f.dir / "env-cache") == 1);
  REQUIRE(run({"--cache", (f.dir / "opt-cache").string()}).code == 0);
  CHECK(action_count(f.dir / "opt-cache") == 1);
  unsetenv("MESHFLOW_CACHE");
}

TEST_CASE("gc --max-age-days drops results unused for longer, keeps recent ones") {
  Fixture f;
  REQUIRE(f.run().code == 0);
  REQUIRE(action_count(f.cache) == 4);
  // age two entries by 10 days
  int aged = 0;
  for (auto& e : fs::directory_iterator(f.cache / "actions")) {
    if (aged == 2) break;
    auto old = fs::file_time_type::clock::now() - std::chrono::hours(24 * 10);
    fs::last_write_time(e.path(), old);
    ++aged;
  }
  auto g = cli({"gc", f.wf.string(), "--cache", f.cache.string(), "--max-age-days", "7", "--grace", "0"});
  CHECK(g.code == 0);
  CHECK(g.out.find("removed 2 action entries") != std::string::npos);
  CHECK(action_count(f.cache) == 2);
  CHECK(cli({"gc", f.wf.string(), "--cache", f.cache.string(), "--verify"}).code == 0);
  f.reset_calls();
  REQUIRE(f.run().code == 0);
  CHECK(f.calls().size() >= 1);  // what was dropped is recomputed
}
