#include "engine/runner.hpp"

#include "engine/artifact_type.hpp"
#include "engine/fsutil.hpp"
#include "engine/hash.hpp"
#include "engine/registry.hpp"
#include "engine/run_report.hpp"
#include "engine/version.hpp"

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fcntl.h>
#include <iomanip>
#include <iostream>
#include <functional>
#include <map>
#include <mutex>
#include <set>
#include <poll.h>
#include <sstream>
#include <sys/prctl.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <sys/statvfs.h>
#include <sys/wait.h>
#include <thread>
#include <unistd.h>

namespace fs = std::filesystem;
using nlohmann::json;
using Clock = std::chrono::steady_clock;

namespace meshflow {

// GCC says a sanitizer build with __SANITIZE_*__, clang with __has_feature
#if defined(__SANITIZE_ADDRESS__) || defined(__SANITIZE_THREAD__)
#define MESHFLOW_SANITIZED 1
#elif defined(__has_feature)
#if __has_feature(address_sanitizer) || __has_feature(thread_sanitizer) || __has_feature(memory_sanitizer)
#define MESHFLOW_SANITIZED 1
#endif
#endif

unsigned long long memory_budget_bytes(double gb) {
#ifdef MESHFLOW_SANITIZED
  (void)gb;
  return 0;
#else
  if (gb == 0) return 0;
  if (gb > 0) return static_cast<unsigned long long>(gb * 1e9);
  const long pages = ::sysconf(_SC_PHYS_PAGES), page = ::sysconf(_SC_PAGESIZE);
  if (pages <= 0 || page <= 0) return 0;
  return static_cast<unsigned long long>(kDefaultMemoryShare * static_cast<double>(pages) * static_cast<double>(page));
#endif
}

fs::path resolve_cache_dir(const Workflow& wf, const fs::path& option) {
  if (!option.empty()) return fs::absolute(option);
  if (const char* env = std::getenv("MESHFLOW_CACHE"); env && *env) return fs::absolute(env);
  return wf.dir / ".meshflow";
}

namespace {

// ---------------------------------------------------------------------------------------
// Keys

struct KeyResult {
  json preimage;
  std::string key;
};

// The preimage of a stage's cache key (DESIGN.md §4). Throws WorkflowError for unreadable files.
KeyResult make_key(const Workflow& wf, const StageDecl& d, const std::vector<Artifact>& inputs) {
  const StageKind* kind = find_stage_kind(d.kind);
  json pre;
  pre["engine"] = kEngineFormat;
  pre["meshflow"] = version();  // a new release never serves an older one's results (CHANGELOG.md)
  pre["kind"] = d.kind;
  pre["kind_version"] = kind->version;
  pre["params"] = d.params;
  pre["libraries"] = kind->libraries;
  if (const std::string& code = module_code(kind->module); !code.empty()) pre["code"] = code;
  json ins = json::array();
  for (auto& a : inputs) ins.push_back({{"stage", a.stage}, {"name", a.name}, {"type", a.type}, {"digest", a.digest}});
  pre["inputs"] = ins;
  json files = json::object();
  for (auto& f : d.files) {
    std::error_code ec;
    if (!fs::is_regular_file(f.path, ec))
      throw WorkflowError(wf.file.string() + ":" + std::to_string(d.line) + ": stage '" + d.name + "', parameter '" +
                          f.pointer.substr(1) + "': cannot read '" + f.path.string() + "' (" +
                          (fs::is_directory(f.path, ec) ? "it is a folder: give the path of a file in it"
                                                        : "no such file") +
                          "). Relative paths are relative to the workflow file's folder.");
    try {
      files[f.pointer] = sha256_file(f.path);
    } catch (const std::exception& e) {
      throw WorkflowError(wf.file.string() + ":" + std::to_string(d.line) + ": stage '" + d.name + "', parameter '" +
                          f.pointer.substr(1) + "': " + e.what() + ". Check the file's permissions.");
    }
  }
  pre["files"] = files;
  return {pre, sha256_hex(canonical_json(pre))};
}

std::vector<Artifact> artifacts_of_entry(const Cache& cache, const std::string& stage, const json& entry) {
  std::vector<Artifact> v;
  for (auto& o : entry["outputs"])
    v.push_back({o["name"], o["type"], o["digest"], stage, cache.object_path(o["digest"])});
  return v;
}

std::vector<Artifact> gather_inputs(const StageDecl& d, const std::map<std::string, StageResult>& results) {
  std::vector<Artifact> in;
  for (auto& n : d.needs) {
    auto& r = results.at(n);
    in.insert(in.end(), r.outputs.begin(), r.outputs.end());
  }
  return in;
}

// ---------------------------------------------------------------------------------------
// The child side: one stage run in a forked process.

class ChildContext final : public StageContext {
 public:
  ChildContext(const StageDecl& d, std::vector<Artifact> inputs, fs::path scratch, int pipe_fd, int threads)
      : decl_(d), inputs_(std::move(inputs)), scratch_(std::move(scratch)), fd_(pipe_fd), threads_(threads) {}
  const json& params() const override { return decl_.params; }
  const std::string& stage_name() const override { return decl_.name; }
  const std::vector<Artifact>& inputs() const override { return inputs_; }
  fs::path output(const std::string& name, const std::string& type) override {
    if (!find_artifact_type(type))
      throw std::logic_error("stage kind '" + decl_.kind + "' declares an output of unregistered artifact type '" + type + "'");
    for (auto& o : outputs_)
      if (o.first == name) throw std::logic_error("stage kind '" + decl_.kind + "' declares output '" + name + "' twice");
    if (const StageKind* k = find_stage_kind(decl_.kind); k && !k->produces.empty() &&
        std::none_of(k->produces.begin(), k->produces.end(), [&](auto& a) { return a.name == name && a.type == type; }))
      throw std::logic_error("stage kind '" + decl_.kind + "' writes artifact '" + name + "' of type '" + type +
                             "', which its `produces` does not declare");
    outputs_.push_back({name, type});
    return scratch_ / ("out." + name);
  }
  fs::path file(const std::string& value) const override {
    for (auto& f : decl_.files)
      if (decl_.params.at(json::json_pointer(f.pointer)) == value) return f.path;
    throw std::logic_error("stage '" + decl_.name + "' asked for file '" + value +
                           "', which is not a parameter marked x-meshflow-file in its schema");
  }
  void progress(double fraction, const std::string& what) override {
    send("P " + std::to_string(std::clamp(fraction, 0.0, 1.0)) + " " + what);
  }
  void log(const std::string& line) override {
    log_.push_back(line);
    send("L " + line);
  }
  json& stats() override { return stats_; }
  int threads() const override { return threads_; }

  const std::vector<std::pair<std::string, std::string>>& declared() const { return outputs_; }
  void send_error(const std::string& message) { send("E " + message); }
  const std::vector<std::string>& log_lines() const { return log_; }

 private:
  void send(std::string msg) {
    for (auto& c : msg)
      if (c == '\n') c = ' ';
    msg += '\n';
    // Progress is advisory: a full pipe must never block or fail the stage.
    (void)!::write(fd_, msg.data(), msg.size());
  }
  const StageDecl& decl_;
  std::vector<Artifact> inputs_;
  fs::path scratch_;
  int fd_;
  int threads_;
  std::vector<std::pair<std::string, std::string>> outputs_;
  std::vector<std::string> log_;
  json stats_ = json::object();
};

// The budget's message: what was asked and how to change it.
std::string over_budget(unsigned long long budget) {
  char b[64];
  std::snprintf(b, sizeof b, "%.3g GB", budget / 1e9);
  return std::string("the stage needed more memory than its budget of ") + b +
         " (meshflow run --memory-budget GB; by default " + std::to_string(int(100 * kDefaultMemoryShare)) +
         " % of this machine's memory): make the mesh coarser (larger sizes, fewer layers, a lower order) or "
         "run it on a larger machine";
}

[[noreturn]] void child_main(const StageDecl& d, std::vector<Artifact> inputs, Cache& cache, const fs::path& scratch,
                             int fd, int threads, pid_t parent, unsigned long long budget) {
  // Die with the engine: a killed `meshflow` leaves no orphan stage writing into the cache.
  ::prctl(PR_SET_PDEATHSIG, SIGKILL);
  if (::getppid() != parent) std::_Exit(9);
  // Name the process (and the threads it starts) after its stage: "mf:optimise" in ps, top and
  // perf (perf report --comm mf:optimise gives one stage's profile); the kernel keeps 15 bytes.
  ::prctl(PR_SET_NAME, ("mf:" + d.name).substr(0, 15).c_str());
  // Library chatter goes to a file in the scratch dir, shown when the stage fails.
  int logfd = ::open((scratch / "stage.out").c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (logfd >= 0) {
    std::fflush(stdout);
    std::fflush(stderr);
    ::dup2(logfd, 1);
    ::dup2(logfd, 2);
    ::close(logfd);
  }
  if (budget > 0) {
    rlimit lim{static_cast<rlim_t>(budget), static_cast<rlim_t>(budget)};
    ::setrlimit(RLIMIT_AS, &lim);
  }
  json result;
  ChildContext ctx(d, std::move(inputs), scratch, fd, threads);
  try {
    find_stage_kind(d.kind)->run(ctx);
    json outs = json::array();
    for (auto& [name, type] : ctx.declared()) {
      fs::path p = scratch / ("out." + name);
      if (!fs::is_regular_file(p))
        throw std::logic_error("stage kind '" + d.kind + "' declared output '" + name + "' but did not write it");
      auto size = fs::file_size(p);
      std::string digest = cache.store_object(p);
      outs.push_back({{"name", name}, {"type", type}, {"digest", digest}, {"size", size}});
    }
    result = {{"ok", true}, {"outputs", outs}, {"stats", ctx.stats()}, {"log", ctx.log_lines()}};
  } catch (const StageError& e) {
    result = {{"ok", false}, {"error", e.what()}, {"internal", false}};
  } catch (const std::bad_alloc&) {
    result = {{"ok", false}, {"error", budget > 0 ? over_budget(budget) : "out of memory"}, {"internal", false}};
  } catch (const std::exception& e) {
    result = {{"ok", false}, {"error", e.what()}, {"internal", true}};
  } catch (...) {
    // a library's own out-of-memory exception (OpenCASCADE's Standard_OutOfMemory) is no
    // std::exception: with a budget set, that is the likely one
    result = {{"ok", false},
              {"error", budget > 0 ? "unknown exception; " + over_budget(budget) + " is the likely cause" : "unknown exception"},
              {"internal", true}};
  }
  if (!result["ok"].get<bool>()) ctx.send_error(result["error"].get<std::string>());
  try {
    atomic_write(scratch / "result.json", result.dump(), scratch);
  } catch (const std::exception& e) {
    // No room for the result file (disk full): the message still reaches the engine.
    ctx.send_error(result["ok"].get<bool>() ? std::string("could not record the stage's result: ") + e.what()
                                            : result["error"].get<std::string>());
    std::_Exit(4);
  }
  std::fflush(stdout);
  std::fflush(stderr);
  std::_Exit(result["ok"].get<bool>() ? 0 : 3);
}

// ---------------------------------------------------------------------------------------
// The parent side.

struct Running {
  size_t index;
  pid_t pid;
  int fd;
  fs::path scratch;
  std::unique_ptr<CacheLock> lock;
  KeyResult key;
  Clock::time_point start, last_touch;
  double fraction = -1;
  std::string what, buffer, error;
  double last_printed = -1;
};

std::string tail_of(const fs::path& file, size_t max = 1500) {
  try {
    std::string s = read_file(file);
    if (s.size() > max) s = "..." + s.substr(s.size() - max);
    while (!s.empty() && (s.back() == '\n' || s.back() == ' ')) s.pop_back();
    return s;
  } catch (...) {
    return {};
  }
}

std::string fmt(double v, int prec) {
  std::ostringstream s;
  s << std::fixed << std::setprecision(prec) << v;
  return s.str();
}

// The artifact an output names: the stage's `artifact`, else its first. nullptr when the stage
// produced nothing (failed or skipped).
const Artifact* output_artifact(const Workflow& wf, const RunResult& rr, const OutputDecl& od) {
  auto it = std::find_if(rr.stages.begin(), rr.stages.end(), [&](auto& s) { return s.name == od.from; });
  if (it == rr.stages.end() || it->outputs.empty()) return nullptr;
  if (od.artifact.empty()) return &it->outputs.front();
  for (auto& a : it->outputs)
    if (a.name == od.artifact) return &a;
  throw WorkflowError(wf.file.string() + ": output '" + od.name + "': stage '" + od.from + "' has no artifact '" +
                      od.artifact + "'.");
}

// The warning (or error) naming an object whose bytes do not match its digest.
std::string bad_object_text(const BadObject& b, const std::string& stage, const std::string& output) {
  std::string s = "cache object " + b.digest + " (output '" + output + "' of stage '" + stage + "', " +
                  std::to_string(b.size) + " bytes) does not match its digest";
  s += b.actual.empty() ? " (unreadable)" : " (its bytes hash to " + b.actual.substr(0, 12) + "...)";
  s += b.quarantined.empty() ? "; removed" : "; moved to " + b.quarantined.string();
  return s;
}

// Verify on read before materialising: throws naming the object when its bytes are not those
// its digest names (it is quarantined: the next run recomputes the stage that made it).
void verify_for_output(const Cache& cache, const Artifact& art) {
  BadObject bad;
  if (cache.verify_object(art.digest, &bad)) return;
  if (bad.digest.empty())
    throw std::runtime_error("cache object " + art.digest + " (output '" + art.name + "' of stage '" + art.stage +
                             "') vanished before it was written out: run again to recompute it");
  throw std::runtime_error(bad_object_text(bad, art.stage, art.name) + ". Run again: the stage is recomputed.");
}

// Writes one output file atomically: produced under a temp name in out_dir, then renamed.
void write_output_file(const fs::path& target, const std::function<void(const fs::path&)>& produce) {
  fs::path tmp = target.parent_path() / ("." + target.filename().string() + ".tmp." + unique_suffix());
  try {
    produce(tmp);
    fs::rename(tmp, target);
  } catch (...) {
    std::error_code ec;
    fs::remove(tmp, ec);
    throw;
  }
}

// An unformatted output is an independent copy of the object (reflink or bytes, never a hard
// link), checked against the digest after copying: what lands in out/ is what the digest names.
void copy_object_out(const Artifact& art, const fs::path& tmp) {
  clone_or_copy(art.path, tmp);
  if (sha256_file(tmp) != art.digest)
    throw std::runtime_error("copying cache object " + art.digest + " (output '" + art.name + "' of stage '" + art.stage +
                             "') to " + tmp.string() + " gave different bytes: the object changed while it was copied. Run again.");
}

// One file of out/ to write: its name there and the function producing it at a path.
struct OutputJob {
  std::string file;
  std::string format;  // "" for a copy of the object
  std::function<void(const fs::path&)> produce;
};

// Writes the jobs' files, at most `parallel` at once (each format writer reads the artifact and
// writes its own file). Two writers of one format never run at once: a format's library (CGNS's
// ADF) may keep global state. Every job runs to its end; the first failure in job order is
// rethrown after all have finished, so no writer is left running.
void write_output_files(const fs::path& out_dir, const std::vector<OutputJob>& jobs, unsigned parallel) {
  std::vector<std::exception_ptr> errors(jobs.size());
  std::map<std::string, std::mutex> format_lock;
  for (auto& j : jobs) format_lock[j.format];
  std::atomic<std::size_t> next{0};
  auto worker = [&] {
    for (std::size_t i; (i = next++) < jobs.size();) {
      try {
        std::lock_guard<std::mutex> lock(format_lock.at(jobs[i].format));
        write_output_file(out_dir / jobs[i].file, jobs[i].produce);
      } catch (...) {
        errors[i] = std::current_exception();
      }
    }
  };
  std::vector<std::thread> pool;
  for (unsigned t = 1; t < std::min<std::size_t>(parallel, jobs.size()); ++t) pool.emplace_back(worker);
  worker();
  for (auto& t : pool) t.join();
  for (auto& e : errors)
    if (e) std::rethrow_exception(e);
}

// The other artifacts of the stage that produced `art` (its companions, artifact_type.hpp).
std::vector<Artifact> companions_of(const RunResult& rr, const Artifact& art) {
  std::vector<Artifact> v;
  for (auto& s : rr.stages)
    if (s.name == art.stage)
      for (auto& a : s.outputs)
        if (a.name != art.name) v.push_back(a);
  return v;
}

// An output's artifact read once (ArtifactType::load) for all its formats that write from it:
// the first writer to need it loads it, the others wait for it; a failure is rethrown to each
// of them. The companions are verified on read (as the artifact is) when it is made, in the
// runner's thread (the cache's record of verified objects is not shared between threads).
class SharedLoad {
 public:
  SharedLoad(const Cache& cache, const ArtifactType* type, const Artifact* art, std::vector<Artifact> companions)
      : type_(type), art_(art), companions_(std::move(companions)) {
    for (auto& c : companions_) verify_for_output(cache, c);
  }
  const void* get() {
    std::lock_guard<std::mutex> lock(m_);
    if (!done_) {
      done_ = true;
      try {
        loaded_ = type_->load(art_->path, companions_);
      } catch (...) {
        error_ = std::current_exception();
      }
    }
    if (error_) std::rethrow_exception(error_);
    return loaded_.get();
  }

 private:
  const ArtifactType* type_;
  const Artifact* art_;
  std::vector<Artifact> companions_;
  std::mutex m_;
  bool done_ = false;
  std::shared_ptr<const void> loaded_;
  std::exception_ptr error_;
};

// Writes the workflow's outputs into out_dir. An output whose artifact digest and formats are
// those of the previous report.json there, with all its files present, is not written again
// (exporting a large mesh would dominate a no-change re-run). The files to write (every format
// of every changed output) are written in parallel, up to the number of cores: each format
// writer is serial, and a split-only change rewrites four formats of one mesh. The formats of
// a type with `load` that write from it share one reading of the artifact (and its companions:
// a mesh's stored quality, so the VTU writer does not recompute it).
void materialise(const Workflow& wf, const RunResult& rr, const Cache& cache, const fs::path& out_dir, json& report_outputs) {
  json previous;
  try {
    previous = json::parse(read_file(out_dir / "report.json")).at("outputs");
  } catch (...) {
    previous = json::object();
  }
  std::vector<OutputJob> jobs;
  json written = json::object();  // entries of the outputs written now: in the report once all are
  for (auto& od : wf.outputs) {
    const Artifact* art = output_artifact(wf, rr, od);
    if (!art) continue;
    const ArtifactType* type = find_artifact_type(art->type);
    if (previous.contains(od.name) && previous[od.name].value("digest", "") == art->digest &&
        previous[od.name].value("formats", json()) == json(od.formats)) {
      bool all = true;  // and none is a hard link (into the store, as older meshflows wrote them)
      for (auto& f : previous[od.name]["files"]) {
        struct stat st;
        all = all && ::stat((out_dir / f.get<std::string>()).c_str(), &st) == 0 && st.st_nlink == 1;
      }
      if (all) {
        report_outputs[od.name] = previous[od.name];
        continue;
      }
    }
    verify_for_output(cache, *art);
    json files = json::array();
    std::shared_ptr<SharedLoad> loader;  // made by the first format that writes from it
    auto write_one = [&](const std::string& ext, const std::string& format, std::function<void(const fs::path&)> produce) {
      jobs.push_back({od.name + ext, format, std::move(produce)});
      files.push_back(od.name + ext);
    };
    if (od.formats.empty()) write_one(type ? type->extension : "", "", [art](const fs::path& tmp) { copy_object_out(*art, tmp); });
    for (auto& f : od.formats) {
      if (!type || !type->formats.count(f)) {
        std::string known;
        if (type)
          for (auto& [n, x] : type->formats) known += (known.empty() ? "" : ", ") + n;
        throw WorkflowError(wf.file.string() + ": output '" + od.name + "': artifact type '" + art->type +
                            "' has no format '" + f + "'" + (known.empty() ? "" : " (formats: " + known + ")") + ".");
      }
      const ArtifactFormat* fmtd = &type->formats.at(f);
      if (type->load && fmtd->write_loaded) {
        if (!loader) loader = std::make_shared<SharedLoad>(cache, type, art, companions_of(rr, *art));
        write_one(fmtd->extension, f, [fmtd, loader](const fs::path& tmp) { fmtd->write_loaded(loader->get(), tmp); });
      } else {
        write_one(fmtd->extension, f, [fmtd, art](const fs::path& tmp) { fmtd->write(art->path, tmp); });
      }
    }
    written[od.name] = {{"from", od.from},        {"artifact", art->name}, {"type", art->type},
                        {"digest", art->digest}, {"formats", od.formats}, {"files", files}};
  }
  write_output_files(out_dir, jobs, std::max(1u, std::thread::hardware_concurrency()));
  for (auto& [name, entry] : written.items()) report_outputs[name] = entry;
}

// When a stage fails on a nearly full disk, say so: the stage's own message may only be a
// short write.
std::string disk_hint(const fs::path& root) {
  struct statvfs st;
  if (::statvfs(root.c_str(), &st) != 0) return {};
  double free_bytes = double(st.f_bavail) * double(st.f_frsize);
  if (free_bytes > 64e6 && free_bytes > 0.01 * double(st.f_blocks) * double(st.f_frsize)) return {};
  return " (the cache's filesystem has only " + std::to_string(std::llround(free_bytes / 1024)) +
         " KiB free: free some space, run `meshflow gc --max-size ...`, or use another cache with --cache DIR)";
}

// The contract problems a stage listed in its stats (an empty array when none).
json problems_of(const json& stats) {
  if (stats.is_object() && stats.contains("problems") && stats["problems"].is_array()) return stats["problems"];
  return json::array();
}
bool has_blocking(const json& problems) {
  for (auto& p : problems)
    if (p.is_object() && p.value("blocking", false)) return true;
  return false;
}

// "split: validity: 37 element(s) with det J <= 0 somewhere; the worst, element 1234 (prism4), at (x, y, z)"
std::string problem_line(const std::string& stage, const json& p) {
  std::ostringstream s;
  s << stage << ": " << p.value("clause", std::string("?")) << ": " << p.value("what", std::string());
  if (p.contains("where") && p["where"].is_array() && !p["where"].empty()) {
    const json& w = p["where"][0];
    s << "; first listed";
    if (w.contains("element")) s << ": element " << w["element"].dump();
    if (w.contains("type")) s << " (" << w["type"].get<std::string>() << ")";
    if (w.contains("face_of")) s << ": face of element(s) " << w["face_of"].dump();
    if (w.contains("cad_face")) s << ": CAD face " << w["cad_face"].dump() << " (" << w.value("group", std::string()) << ")";
    else if (w.contains("group")) s << ": group " << w["group"].dump();
    if (w.contains("mesh_area") && w.contains("cad_area"))
      s << std::setprecision(6) << ", mesh area " << w["mesh_area"].get<double>() << " of " << w["cad_area"].get<double>();
    if (w.contains("edge")) s << ": edge " << w["edge"].dump();
    if (w.contains("at") && w["at"].is_array() && w["at"].size() == 3)
      s << std::setprecision(6) << " at (" << w["at"][0].get<double>() << ", " << w["at"][1].get<double>() << ", "
        << w["at"][2].get<double>() << ")";
  }
  if (p.contains("hint") && p["hint"].is_string()) s << ". " << p["hint"].get<std::string>();
  return s.str();
}

// One human line of a stage's stats.mesh (the engine knows the field names, not meshes).
std::string mesh_line(const std::string& stage, const json& m) {
  std::ostringstream s;
  auto num = [&](const char* k) { return m.contains(k) && m[k].is_number() ? m[k].get<double>() : NAN; };
  s << "mesh " << stage << ": order " << m.value("order", 0) << ", " << m.value("nodes", 0) << " nodes,";
  if (m.contains("elements") && m["elements"].is_object())
    for (auto k : {"tet", "prism", "hex", "pyramid"})
      if (m["elements"].value(k, 0) > 0) s << " " << m["elements"][k].get<long long>() << " " << k;
  s << "; invalid " << m.value("invalid", -1) << ", non-conforming faces " << m.value("nonconforming_faces", -1)
    << ", min scaled Jacobian " << fmt(num("min_scaled_jacobian"), 3) << ", max aspect ratio " << fmt(num("max_aspect_ratio"), 1);
  if (m.contains("validity_method"))
    s << " (validity: " << (m["validity_method"].is_string() ? m["validity_method"].get<std::string>() : m["validity_method"].dump()) << ")";
  return s.str();
}

// Verify on read of a cache hit: every object the entry names hashes to its digest. Each bad
// one is quarantined, named in a warning and listed in `quarantined`; then the entry is not
// used and its stage is recomputed (so every stage downstream reads the right bytes).
bool entry_intact(const Cache& cache, const std::string& stage, const json& entry, std::ostream& err, json& quarantined) {
  bool ok = true;
  for (auto& o : entry["outputs"]) {
    BadObject bad;
    std::string digest = o.value("digest", "");
    if (cache.verify_object(digest, &bad)) continue;
    ok = false;
    if (bad.digest.empty()) continue;  // vanished meanwhile: a plain miss
    std::string output = o.value("name", "");
    err << "warning: " << bad_object_text(bad, stage, output) << "; recomputing stage '" << stage << "'.\n";
    quarantined.push_back({{"stage", stage},
                           {"output", output},
                           {"digest", bad.digest},
                           {"actual", bad.actual},
                           {"moved_to", bad.quarantined.string()}});
  }
  return ok;
}

// out_dir/report.html from the report and the artifacts of this run (or, with `report: false`,
// no page: an older one is removed rather than left to describe another run).
void write_report_page(const Workflow& wf, RunResult& rr, int threads, std::ostream& out, std::ostream& err) {
  const fs::path page = rr.out_dir / "report.html";
  if (!wf.report) {
    std::error_code ec;
    fs::remove(page, ec);
    return;
  }
  std::map<std::string, fs::path> by_digest;
  for (auto& r : rr.stages)
    for (auto& a : r.outputs) by_digest[a.digest] = a.path;
  ArtifactLocator locate = [&](const std::string& digest) {
    auto it = by_digest.find(digest);
    return it == by_digest.end() ? fs::path() : it->second;
  };
  try {
    const auto t = Clock::now();
    write_report_html(rr.out_dir, rr.report, locate, threads);
    out << "report: " << page.string() << " (" << fmt(std::chrono::duration<double>(Clock::now() - t).count(), 2) << " s)\n";
  } catch (const std::exception& e) {
    rr.ok = false;
    rr.failed = true;
    err << "error: cannot write " << page.string() << ": " << e.what() << "\n";
  }
}

}  // namespace

RunResult run_workflow(const Workflow& wf, const RunOptions& opt) {
  std::ostream& out = opt.out ? *opt.out : std::cout;
  std::ostream& err = opt.err ? *opt.err : std::cerr;
  const int cores = int(std::max(1u, std::thread::hardware_concurrency()));
  const int jobs = opt.jobs > 0 ? opt.jobs : cores;
  const int threads = opt.threads > 0 ? opt.threads : cores;
  const bool tty = (&out == &std::cout) && ::isatty(1);

  RunResult rr;
  // The output folder is checked before any stage runs (not after an hour of meshing).
  if (opt.materialise) {
    rr.out_dir = opt.out_dir.empty() ? fs::current_path() / "out" / wf.name : fs::absolute(opt.out_dir);
    std::string why;
    if (!writable_dir(rr.out_dir, &why))
      throw WorkflowError("the output folder " + rr.out_dir.string() + " is not writable: " + why +
                          ". Choose another with --out DIR; no stage was run.");
    remove_stale_tmp_files(rr.out_dir);  // left by a run killed while writing outputs
  }
  Cache cache(resolve_cache_dir(wf, opt.cache_dir));
  const unsigned long long budget = memory_budget_bytes(opt.memory_budget_gb);
  cache.clean_stale_tmp();
  cache.clean_stale_locks();
  json quarantined = json::array();
  std::optional<RemoteCache> remote;
  if (!opt.remote.url.empty()) remote.emplace(opt.remote, cache, err);

  std::map<std::string, StageResult> results;
  for (auto& d : wf.stages) {
    results[d.name].name = d.name;
    results[d.name].kind = d.kind;
  }
  enum State { Pending, Waiting, Active, Done };
  std::vector<State> state(wf.stages.size(), Pending);
  std::vector<Running> running;
  std::map<size_t, std::string> waiting_on;
  const auto t0 = Clock::now();
  size_t finished = 0;
  bool any_failed = false, any_invalid = false, any_bad_input = false;
  // A stage's result is delivered when an output is materialised from it or no stage needs it:
  // a contract problem there fails the run even when it is repairable by a later stage.
  // (With deliver = false, `run --only`, nothing is: the run that writes the outputs judges.)
  std::vector<bool> delivered(wf.stages.size(), opt.deliver);
  for (auto& s : wf.stages)
    for (auto& n : s.needs)
      for (size_t i = 0; i < wf.stages.size(); ++i)
        if (wf.stages[i].name == n) delivered[i] = false;
  for (auto& o : wf.outputs)
    for (size_t i = 0; i < wf.stages.size(); ++i)
      if (wf.stages[i].name == o.from) delivered[i] = true;

  auto secs = [](Clock::time_point a) { return std::chrono::duration<double>(Clock::now() - a).count(); };
  auto status_line = [&]() {
    if (!tty) return;
    std::string s = "[" + std::to_string(finished) + "/" + std::to_string(wf.stages.size()) + "]";
    for (auto& r : running) {
      s += "  " + wf.stages[r.index].name + " " + fmt(secs(r.start), 1) + "s";
      if (r.fraction >= 0) s += " " + std::to_string(int(std::lround(r.fraction * 100))) + "%";
      if (!r.what.empty() && running.size() == 1) s += " " + r.what;
    }
    for (auto& [i, who] : waiting_on) s += "  " + wf.stages[i].name + " (waiting for " + who + ")";
    if (s.size() > 150) s = s.substr(0, 147) + "...";
    out << "\r\033[K" << s << std::flush;
  };
  auto line = [&](const std::string& s) {
    if (tty) out << "\r\033[K";
    out << s << "\n" << std::flush;
  };
  auto finish = [&](size_t i, const std::string& status) {
    state[i] = Done;
    ++finished;
    auto& r = results[wf.stages[i].name];
    r.status = status;
    if (status == "failed") any_failed = true;
    const json problems = problems_of(r.stats);
    const bool invalid = !problems.empty() && (has_blocking(problems) || delivered[i]);
    if (status == "ran") line("  ran     " + r.name + " (" + fmt(r.seconds, 2) + " s, " + fmt(r.peak_rss_mb, 0) + " MB)");
    else if (status == "cached") line("  cached  " + r.name + (r.remote ? " (remote)" : ""));
    else if (status == "failed") line("  FAILED  " + r.name);
    for (auto& p : problems)
      line(std::string(invalid ? "  INVALID " : "  note    ") + problem_line(r.name, p) +
           (invalid ? "" : " (not delivered: a later stage may repair it)"));
    if (invalid) {
      r.computed = status;
      r.status = "invalid";
      any_invalid = true;
    }
  };

  // Reads what a stage process sent: progress (P), log (L) and error (E) lines.
  auto drain = [&](Running& r) {
    char buf[4096];
    ssize_t n;
    while ((n = ::read(r.fd, buf, sizeof buf)) > 0) r.buffer.append(buf, size_t(n));
    size_t nl;
    while ((nl = r.buffer.find('\n')) != std::string::npos) {
      std::string msg = r.buffer.substr(0, nl);
      r.buffer.erase(0, nl + 1);
      if (msg.rfind("P ", 0) == 0) {
        std::istringstream in(msg.substr(2));
        in >> r.fraction;
        std::getline(in >> std::ws, r.what);
        if (!tty && (r.fraction - r.last_printed >= 0.25 || r.fraction >= 1.0) && r.fraction > r.last_printed) {
          line("          " + wf.stages[r.index].name + " " + std::to_string(int(std::lround(r.fraction * 100))) + "% " + r.what);
          r.last_printed = r.fraction;
        }
      } else if (msg.rfind("E ", 0) == 0) {
        r.error = msg.substr(2);
      } else if (msg.rfind("L ", 0) == 0 && opt.verbose) {
        line("          " + wf.stages[r.index].name + ": " + msg.substr(2));
      }
    }
  };

  line("meshflow: " + wf.name + " (" + wf.file.string() + "), " + std::to_string(wf.stages.size()) + " stages, cache " +
       cache.root().string());

  auto index_of = [&](const std::string& name) {
    return size_t(std::find_if(wf.stages.begin(), wf.stages.end(), [&](auto& s) { return s.name == name; }) - wf.stages.begin());
  };
  // Whether every stage that stage i needs is done (i is ready to run or to be found in the cache).
  auto needs_done = [&](size_t i) {
    for (auto& n : wf.stages[i].needs)
      if (state[index_of(n)] != Done) return false;
    return true;
  };
  while (finished < wf.stages.size()) {
    // Start what is ready, in topological order, within the job budget. A stage's share of the
    // thread budget is split among the stages that run with it: those running and those ready
    // after it in this pass, at most `jobs` (a chain of stages gives each one every thread; a
    // fixed budget / jobs left one of two cores idle through the whole demo). Outputs do not
    // depend on it: every stage gives the same bytes at any thread count.
    size_t ready_left = 0;
    for (size_t i = 0; i < wf.stages.size(); ++i) ready_left += (state[i] == Pending || state[i] == Waiting) && needs_done(i);
    for (size_t i = 0; i < wf.stages.size(); ++i) {
      if (state[i] != Pending && state[i] != Waiting) continue;
      const StageDecl& d = wf.stages[i];
      bool ready = true, blocked = false;
      for (auto& n : d.needs) {
        auto& nr = results[n];
        if (state[index_of(n)] != Done) ready = false;
        else if (nr.status == "failed" || nr.status == "skipped") blocked = true;
        else if (nr.status == "invalid" && has_blocking(problems_of(nr.stats)) && !opt.allow_invalid) blocked = true;
      }
      if (ready && ready_left > 0) --ready_left;  // ready_left: the ready stages after this one
      if (blocked) {
        results[d.name].error = "not run: a stage it needs failed or broke its contract";
        finish(i, "skipped");
        continue;
      }
      if (!ready) continue;
      auto& r = results[d.name];
      KeyResult key;
      try {
        key = make_key(wf, d, gather_inputs(d, results));
      } catch (const WorkflowError& e) {
        r.error = e.what();
        err << "error: " << e.what() << "\n";
        any_bad_input = true;
        finish(i, "failed");
        continue;
      }
      r.key = key.key;
      auto hit = [&](const json& entry) {
        r.outputs = artifacts_of_entry(cache, d.name, entry);
        r.stats = entry.value("stats", json::object());
        r.seconds = 0;
        r.peak_rss_mb = 0;
        waiting_on.erase(i);
        cache.record_last(wf.name, d.name, {{"key", key.key}, {"preimage", key.preimage}});
        finish(i, "cached");
      };
      // Verify on read: a hit whose objects do not match their digests is a miss (recomputed).
      // Local first, then the remote cache (which verifies what it downloads).
      auto verified_entry = [&]() -> std::optional<json> {
        auto entry = cache.load_action(key.key);
        if (entry && !entry_intact(cache, d.name, *entry, err, quarantined)) entry.reset();
        if (!entry && remote && remote->fetch(key.key, d.name)) {
          entry = cache.load_action(key.key);
          if (entry && !entry_intact(cache, d.name, *entry, err, quarantined)) entry.reset();
          r.remote = entry.has_value();
        }
        return entry;
      };
      if (auto entry = verified_entry()) {
        hit(*entry);
        continue;
      }
      if (int(running.size()) >= jobs) continue;
      std::string holder;
      auto lock = cache.try_lock(key.key, &holder);
      if (!lock) {
        if (state[i] != Waiting) line("  waiting " + d.name + ": " + holder + " is computing it");
        state[i] = Waiting;
        waiting_on[i] = holder;
        continue;
      }
      if (auto entry = verified_entry()) {  // finished while we were not looking
        hit(*entry);
        continue;
      }
      waiting_on.erase(i);
      fs::path scratch = cache.make_scratch();
      int fds[2];
      if (::pipe2(fds, O_CLOEXEC) != 0) throw std::runtime_error(std::string("pipe: ") + std::strerror(errno));
      // Flush every buffer before fork, or the child would write the parent's pending output again.
      std::cout.flush();
      std::cerr.flush();
      std::fflush(nullptr);
      const int together = std::min<int>(jobs, int(running.size() + 1 + ready_left));
      const int stage_threads = std::max(1, threads / std::max(1, together));
      pid_t parent = ::getpid();
      pid_t pid = ::fork();
      if (pid < 0) throw std::runtime_error(std::string("fork: ") + std::strerror(errno));
      if (pid == 0) {
        ::close(fds[0]);
        child_main(d, gather_inputs(d, results), cache, scratch, fds[1], stage_threads, parent, budget);
      }
      ::close(fds[1]);
      ::fcntl(fds[0], F_SETFL, O_NONBLOCK);
      state[i] = Active;
      if (!tty) line("  start   " + d.name + " (" + d.kind + ")");
      Running rn;
      rn.index = i;
      rn.pid = pid;
      rn.fd = fds[0];
      rn.scratch = scratch;
      rn.lock = std::move(lock);
      rn.key = key;
      rn.start = rn.last_touch = Clock::now();
      running.push_back(std::move(rn));
    }
    if (finished == wf.stages.size()) break;

    // Wait for progress messages (or 200 ms), then reap finished children.
    std::vector<pollfd> pfds;
    for (auto& r : running) pfds.push_back({r.fd, POLLIN, 0});
    if (!pfds.empty()) ::poll(pfds.data(), pfds.size(), 200);
    else std::this_thread::sleep_for(std::chrono::milliseconds(200));
    for (auto& r : running) {
      drain(r);
      if (secs(r.last_touch) > 2) {
        r.lock->keep_alive();
        r.last_touch = Clock::now();
      }
    }
    for (size_t k = 0; k < running.size();) {
      auto& r = running[k];
      int wstatus = 0;
      struct rusage ru {};
      pid_t w = ::wait4(r.pid, &wstatus, WNOHANG, &ru);
      if (w == 0) {
        ++k;
        continue;
      }
      drain(r);  // what it sent just before exiting
      const StageDecl& d = wf.stages[r.index];
      auto& res = results[d.name];
      res.seconds = secs(r.start);
      res.peak_rss_mb = double(ru.ru_maxrss) / 1024.0;
      ::close(r.fd);
      json result;
      try {
        result = json::parse(read_file(r.scratch / "result.json"));
      } catch (...) {
      }
      std::string status = "failed";
      if (WIFEXITED(wstatus) && WEXITSTATUS(wstatus) == 0 && result.value("ok", false)) {
        json entry = {{"key", r.key.key},
                      {"preimage", r.key.preimage},
                      {"stage", d.name},
                      {"workflow", wf.name},
                      {"outputs", result["outputs"]},
                      {"stats", result["stats"]},
                      {"log", result["log"]},
                      {"seconds", res.seconds},
                      {"peak_rss_mb", res.peak_rss_mb}};
        try {
          cache.write_action(r.key.key, entry);  // last: its presence means the run is complete
          cache.record_last(wf.name, d.name, {{"key", r.key.key}, {"preimage", r.key.preimage}});
          res.outputs = artifacts_of_entry(cache, d.name, entry);
          for (auto& a : res.outputs) cache.mark_verified(a.digest);  // hashed as they were stored
          res.stats = result["stats"];
          status = "ran";
          if (remote) remote->upload(r.key.key, entry, d.name);
        } catch (const std::exception& e) {
          res.error = std::string("could not record the result in the cache: ") + e.what();
        }
      } else if (!result.is_null() && result.contains("error")) {
        res.error = result["error"].get<std::string>();
        if (result.value("internal", false)) res.error = "internal error in kind '" + d.kind + "': " + res.error;
      } else if (!r.error.empty()) {
        res.error = r.error;
      } else if (WIFSIGNALED(wstatus)) {
        int sig = WTERMSIG(wstatus);
        res.error = "the stage process was killed by signal " + std::to_string(sig) + " (" + strsignal(sig) + ")" +
                    (sig == SIGKILL ? ", possibly out of memory" : "");
        std::string t = tail_of(r.scratch / "stage.out");
        if (!t.empty()) res.error += ". Its last output:\n" + t;
      } else {
        res.error = "the stage process exited with code " + std::to_string(WEXITSTATUS(wstatus)) + " without a result";
        std::string t = tail_of(r.scratch / "stage.out");
        if (!t.empty()) res.error += ". Its last output:\n" + t;
      }
      if (status == "failed") res.error += disk_hint(cache.root());
      if (status == "failed")
        err << "error: " << wf.file.string() << ": stage '" << d.name << "' (kind " << d.kind << ") failed: " << res.error
            << "\n";
      std::error_code ec;
      fs::remove_all(r.scratch, ec);
      r.lock.reset();
      size_t idx = r.index;
      running.erase(running.begin() + long(k));
      finish(idx, status);
    }
    status_line();
  }
  if (tty) out << "\r\033[K";

  rr.invalid = any_invalid;
  rr.failed = any_failed;
  rr.bad_input = any_bad_input;
  rr.ok = !rr.failed && (!rr.invalid || opt.allow_invalid);
  json stages = json::array();
  json all_problems = json::array();
  for (auto& d : wf.stages) {
    auto& r = results[d.name];
    rr.stages.push_back(r);
    json s = {{"name", r.name},       {"kind", r.kind},
              {"status", r.status},   {"key", r.key},
              {"seconds", r.seconds}, {"peak_rss_mb", r.peak_rss_mb},
              {"stats", r.stats}};
    if (!r.error.empty()) s["error"] = r.error;
    if (!r.computed.empty()) s["computed"] = r.computed;
    if (remote) s["remote"] = r.remote;
    if (!r.outputs.empty()) {  // what report.html (and `meshflow report`) looks up by digest
      s["outputs"] = json::array();
      for (auto& a : r.outputs) s["outputs"].push_back({{"name", a.name}, {"type", a.type}, {"digest", a.digest}});
    }
    stages.push_back(s);
    if (r.status == "invalid")
      for (auto p : problems_of(r.stats)) {
        p["stage"] = r.name;
        all_problems.push_back(std::move(p));
      }
  }
  rr.report = {{"workflow", wf.name}, {"file", wf.file.string()}, {"ok", rr.ok},          {"invalid", rr.invalid},
               {"problems", all_problems}, {"stages", stages}, {"seconds", secs(t0)}, {"outputs", json::object()}};
  rr.report["cache"] = cache.root().string();
  if (rr.invalid && opt.allow_invalid) rr.report["invalid_accepted"] = true;
  if (!quarantined.empty()) rr.report["quarantined"] = quarantined;
  if (remote) rr.report["remote_cache"] = remote->report();

  // The summary's first line says when the mesh breaks the contract, and where.
  if (rr.invalid) {
    out << "\n" << (opt.allow_invalid ? "INVALID (accepted by --allow-invalid)" : "INVALID")
        << ": the mesh breaks the contract (" << all_problems.size() << " problem(s); report.json lists them)\n";
    for (auto& p : all_problems) out << "  " << problem_line(p["stage"].get<std::string>(), p) << "\n";
  }

  // Summary table.
  out << "\n" << std::left << std::setw(16) << "stage" << std::setw(14) << "kind" << std::setw(8) << "status" << std::right
      << std::setw(9) << "seconds" << std::setw(9) << "peak MB" << "  key\n";
  for (auto& r : rr.stages)
    out << std::left << std::setw(16) << r.name << std::setw(14) << r.kind << std::setw(8) << r.status << std::right
        << std::setw(9) << (r.peak_rss_mb > 0 ? fmt(r.seconds, 2) : "-") << std::setw(9)
        << (r.peak_rss_mb > 0 ? fmt(r.peak_rss_mb, 0) : "-") << "  " << r.key.substr(0, 12) << "\n";
  for (auto& r : rr.stages)
    if (r.stats.contains("mesh") && r.stats["mesh"].is_object()) out << mesh_line(r.name, r.stats["mesh"]) << "\n";

  if (opt.materialise) {
    try {
      fs::create_directories(rr.out_dir);
      // An invalid mesh is written too, so that the user can look at it; report.json marks it.
      if (!any_failed) materialise(wf, rr, cache, rr.out_dir, rr.report["outputs"]);
      for (auto& o : wf.outputs)
        if (results[o.from].status == "invalid" && rr.report["outputs"].contains(o.name))
          rr.report["outputs"][o.name]["invalid"] = true;
    } catch (const std::exception& e) {
      rr.ok = false;
      rr.failed = true;
      rr.report["ok"] = false;
      rr.report["error"] = e.what();
      err << "error: " << e.what() << "\n";
    }
    try {
      atomic_write(rr.out_dir / "report.json", rr.report.dump(2) + "\n", {}, /*durable=*/false);
      out << (rr.invalid ? "outputs (INVALID mesh, written for inspection): " : "outputs: ") << rr.out_dir.string() << " (report.json";
      for (auto& [n, o] : rr.report["outputs"].items())
        for (auto& f : o["files"]) out << ", " << f.get<std::string>();
      out << ")\n";
    } catch (const std::exception& e) {
      rr.ok = false;
      rr.failed = true;
      err << "error: cannot write " << (rr.out_dir / "report.json").string() << ": " << e.what() << "\n";
    }
    write_report_page(wf, rr, threads, out, err);
  }
  if (remote)
    out << "remote cache " << opt.remote.url << ": " << rr.report["remote_cache"]["served"] << " stage(s) served, "
        << rr.report["remote_cache"]["uploaded"] << " uploaded, " << rr.report["remote_cache"]["warnings"].size()
        << " warning(s)\n";
  out << (rr.failed ? "FAILED" : !rr.ok ? "INVALID" : rr.invalid ? "ok (INVALID mesh accepted)" : "ok") << " in "
      << fmt(secs(t0), 2) << " s\n"
      << std::flush;
  return rr;
}

std::vector<std::string> json_diff(const json& a, const json& b, const std::string& path) {
  std::vector<std::string> out;
  if (a == b) return out;
  if (a.is_object() && b.is_object()) {
    std::set<std::string> keys;
    for (auto& [k, v] : a.items()) keys.insert(k);
    for (auto& [k, v] : b.items()) keys.insert(k);
    for (auto& k : keys) {
      std::string p = path.empty() ? k : path + "." + k;
      if (!a.contains(k)) out.push_back(p + ": (absent) -> " + b[k].dump());
      else if (!b.contains(k)) out.push_back(p + ": " + a[k].dump() + " -> (absent)");
      else {
        auto sub = json_diff(a[k], b[k], p);
        out.insert(out.end(), sub.begin(), sub.end());
      }
    }
    return out;
  }
  if (a.is_array() && b.is_array() && a.size() == b.size()) {
    for (size_t i = 0; i < a.size(); ++i) {
      auto sub = json_diff(a[i], b[i], path + "[" + std::to_string(i) + "]");
      out.insert(out.end(), sub.begin(), sub.end());
    }
    return out;
  }
  auto show = [](const json& v) {
    std::string s = v.dump();
    return s.size() > 80 ? s.substr(0, 77) + "..." : s;
  };
  out.push_back(path + ": " + show(a) + " -> " + show(b));
  return out;
}

std::vector<StageStatus> workflow_status(const Workflow& wf, Cache& cache) {
  std::vector<StageStatus> out;
  std::map<std::string, StageResult> results;
  std::map<std::string, bool> fresh;
  for (auto& d : wf.stages) {
    StageStatus s{d.name, "", "", ""};
    bool inputs_known = true;
    std::string stale_need;
    for (auto& n : d.needs)
      if (!fresh[n]) {
        inputs_known = false;
        if (stale_need.empty()) stale_need = n;
      }
    fresh[d.name] = false;
    if (!inputs_known) {
      s.state = "stale";
      s.reason = "needs '" + stale_need + "', which will run first";
      out.push_back(s);
      continue;
    }
    KeyResult key;
    try {
      key = make_key(wf, d, gather_inputs(d, results));
    } catch (const WorkflowError& e) {
      s.state = "error";
      s.reason = e.what();
      out.push_back(s);
      continue;
    }
    s.key = key.key;
    if (auto entry = cache.load_action(key.key)) {
      s.state = "fresh";
      fresh[d.name] = true;
      results[d.name].outputs = artifacts_of_entry(cache, d.name, *entry);
    } else if (auto last = cache.last(wf.name, d.name)) {
      s.state = "stale";
      auto diff = json_diff((*last)["preimage"], key.preimage);
      s.reason = diff.empty() ? "its last result is no longer in the cache" : diff.front() +
                                                                                  (diff.size() > 1 ? " (+" + std::to_string(diff.size() - 1) + " more)" : "");
    } else {
      s.state = "never run";
    }
    out.push_back(s);
  }
  return out;
}

std::vector<std::string> explain_stage(const Workflow& wf, Cache& cache, const std::string& stage) {
  const StageDecl* d = wf.find(stage);
  if (!d) {
    std::string known;
    for (auto& s : wf.stages) known += (known.empty() ? "" : ", ") + s.name;
    throw WorkflowError(wf.file.string() + ": no stage '" + stage + "' (stages: " + known + ").");
  }
  std::vector<std::string> lines;
  auto status = workflow_status(wf, cache);
  auto it = std::find_if(status.begin(), status.end(), [&](auto& s) { return s.name == stage; });
  std::map<std::string, StageResult> results;
  for (auto& s : status)
    if (s.state == "fresh")
      if (auto e = cache.load_action(s.key)) results[s.name].outputs = artifacts_of_entry(cache, s.name, *e);
  if (it->state == "fresh") {
    lines.push_back(stage + " is fresh: key " + it->key + " is in the cache.");
    return lines;
  }
  auto last = cache.last(wf.name, stage);
  if (!last) {
    lines.push_back(stage + " has never run with this cache (" + cache.root().string() + ").");
    return lines;
  }
  bool inputs_known = true;
  for (auto& n : d->needs)
    if (!results.count(n)) inputs_known = false;
  if (!inputs_known) {
    lines.push_back(stage + " is stale because a stage it needs is stale:");
    for (auto& n : d->needs)
      if (!results.count(n)) {
        auto nit = std::find_if(status.begin(), status.end(), [&](auto& s) { return s.name == n; });
        lines.push_back("  " + n + ": " + nit->state + (nit->reason.empty() ? "" : " (" + nit->reason + ")"));
      }
    lines.push_back("Its inputs will be known after those run; its own parameters against the last run:");
    json cur = make_key(wf, *d, {}).preimage;
    json old = (*last)["preimage"];
    cur.erase("inputs");
    old.erase("inputs");
    for (auto& l : json_diff(old, cur)) lines.push_back("  " + l);
    return lines;
  }
  KeyResult key = make_key(wf, *d, gather_inputs(*d, results));
  lines.push_back(stage + " is stale: its key " + key.key.substr(0, 12) + " differs from the last run's " +
                  (*last)["key"].get<std::string>().substr(0, 12) + " in:");
  auto diff = json_diff((*last)["preimage"], key.preimage);
  if (diff.empty()) lines.push_back("  nothing: the last run's result was removed from the cache (gc?)");
  for (auto& l : diff) lines.push_back("  " + l);
  return lines;
}

}  // namespace meshflow
