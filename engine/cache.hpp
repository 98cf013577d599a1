// meshflow engine — the content-addressed artifact cache (DESIGN.md §4).
//
// Layout under the cache root (default `.meshflow/` beside the workflow file):
//   objects/ab/<sha256>      artifact bytes, named by their own SHA-256, read-only
//   actions/<key>.json       action entry of one stage run: preimage, outputs, stats; written
//                            LAST, by temp file + rename, so its presence means "complete"
//   last/<workflow>/<stage>.json  the preimage of the latest run of that stage (for explain)
//   locks/<key>.lock         who computes <key> now: pid, host, nonce; mtime = keep-alive
//   tmp/                     every temp file and stage scratch dir, named <host>_<pid>_...
//
// Correctness does not depend on the locks: objects and entries appear by atomic rename and
// are deterministic, so two processes computing the same key write the same bytes. Locks
// only keep two processes from doing the same work (ccache's lockfile idea).
#pragma once

#include <nlohmann/json.hpp>

#include <cstdint>
#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <vector>

namespace meshflow {

class CacheLock {
 public:
  CacheLock(std::filesystem::path file, std::string nonce) : file_(std::move(file)), nonce_(std::move(nonce)) {}
  ~CacheLock();
  CacheLock(const CacheLock&) = delete;
  CacheLock& operator=(const CacheLock&) = delete;
  void keep_alive();  // refreshes the mtime; call every few seconds while holding it
 private:
  std::filesystem::path file_;
  std::string nonce_;
};

struct GcOptions {
  std::optional<std::uint64_t> max_bytes;  // keep at most this many object bytes (LRU)
  std::optional<double> max_age_days;      // drop action entries unused for longer
  double grace_seconds = 3600;             // never delete unreferenced objects younger than this
};

struct GcReport {
  int actions_removed = 0, objects_removed = 0, tmp_removed = 0;
  std::uint64_t bytes_before = 0, bytes_after = 0;
};

struct VerifyReport {
  int objects = 0, actions = 0;
  std::vector<std::string> problems;  // empty = consistent
};

class Cache {
 public:
  explicit Cache(std::filesystem::path root);
  const std::filesystem::path& root() const { return root_; }

  std::filesystem::path object_path(const std::string& digest) const;
  // Hashes `file` and moves it into objects/ (or drops it if the object exists). Returns digest.
  std::string store_object(const std::filesystem::path& file);

  // The action entry, if present and every object it names exists; refreshes its mtime (LRU).
  std::optional<nlohmann::json> load_action(const std::string& key) const;
  void write_action(const std::string& key, const nlohmann::json& entry);

  void record_last(const std::string& workflow, const std::string& stage, const nlohmann::json& last);
  std::optional<nlohmann::json> last(const std::string& workflow, const std::string& stage) const;

  // Takes the lock for `key`, breaking it first if its holder is dead (same host, pid gone)
  // or its keep-alive is older than `stale_seconds`. Returns nullptr while a live holder has
  // it; `holder` then describes it ("pid 123 on host h").
  std::unique_ptr<CacheLock> try_lock(const std::string& key, std::string* holder = nullptr,
                                      double stale_seconds = 30) const;

  // A fresh scratch directory under tmp/ for one stage run.
  std::filesystem::path make_scratch() const;
  std::filesystem::path tmp_dir() const { return root_ / "tmp"; }
  // Removes tmp/ debris of dead processes on this host (and anything older than a day).
  int clean_stale_tmp() const;

  GcReport gc(const GcOptions& options) const;
  VerifyReport verify(bool repair) const;

 private:
  std::filesystem::path root_;
};

}  // namespace meshflow
