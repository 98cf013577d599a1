// meshflow engine — the content-addressed artifact cache (DESIGN.md §4).
//
// Layout under the cache root (default `.meshflow/` beside the workflow file):
//   objects/ab/<sha256>      artifact bytes, named by their own SHA-256, read-only
//   actions/<key>.json       action entry of one stage run: preimage, outputs, stats; written
//                            LAST, by temp file + rename, so its presence means "complete"
//   last/<workflow>/<stage>.json  the preimage of the latest run of that stage (for explain)
//   locks/<key>.lock         who computes <key> now: pid, host, nonce; mtime = keep-alive
//   tmp/                     every temp file and stage scratch dir, named <host>_<pid>_...
//   quarantine/<sha256>.<suffix>  objects whose bytes did not match their name (verify on read),
//                            kept for inspection; gc removes them after its grace period
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
#include <set>
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
  int actions_removed = 0, objects_removed = 0, tmp_removed = 0, locks_removed = 0, quarantine_removed = 0;
  std::uint64_t bytes_before = 0, bytes_after = 0;
};

struct VerifyReport {
  int objects = 0, actions = 0;
  std::vector<std::string> problems;  // empty = consistent
};

// An object whose bytes do not hash to its name, found when it was about to be read.
struct BadObject {
  std::string digest;  // its name (what it should hash to)
  std::string actual;  // what it hashes to ("" when unreadable)
  std::uint64_t size = 0;
  std::filesystem::path quarantined;  // where it was moved ("" if it could not be moved)
};

// How long a lock's keep-alive (its mtime) may lag before the lock counts as abandoned, also
// for an empty or unreadable lock file. Holders refresh it every 2 s.
constexpr double kLockStaleSeconds = 30;

class Cache {
 public:
  explicit Cache(std::filesystem::path root);
  const std::filesystem::path& root() const { return root_; }

  std::filesystem::path object_path(const std::string& digest) const;
  // Hashes `file` and moves it into objects/ (or drops it if the object exists). Returns digest.
  std::string store_object(const std::filesystem::path& file);

  // Verify on read: true when the object's bytes hash to `digest`. An object verified once by
  // this Cache (or stored by this process) is not hashed again. A mismatch (or an unreadable
  // object) moves the object to quarantine/ and fills `bad`; a missing object returns false.
  bool verify_object(const std::string& digest, BadObject* bad = nullptr) const;
  // Records that `digest`'s bytes were hashed when stored (by a stage process of this run).
  void mark_verified(const std::string& digest) const;

  // The action entry, if present and every object it names exists; refreshes its mtime (LRU).
  std::optional<nlohmann::json> load_action(const std::string& key) const;
  void write_action(const std::string& key, const nlohmann::json& entry);

  void record_last(const std::string& workflow, const std::string& stage, const nlohmann::json& last);
  std::optional<nlohmann::json> last(const std::string& workflow, const std::string& stage) const;

  // Takes the lock for `key`, breaking it first if its holder is dead (same host, pid gone)
  // or its keep-alive is older than `stale_seconds`. Returns nullptr while a live holder has
  // it; `holder` then describes it ("pid 123 on host h").
  std::unique_ptr<CacheLock> try_lock(const std::string& key, std::string* holder = nullptr,
                                      double stale_seconds = kLockStaleSeconds) const;
  // Removes the locks of dead holders (same host, pid gone) and locks (also empty or garbage
  // ones) whose keep-alive is older than `stale_seconds`. Returns how many.
  int clean_stale_locks(double stale_seconds = kLockStaleSeconds) const;

  // A fresh scratch directory under tmp/ for one stage run.
  std::filesystem::path make_scratch() const;
  std::filesystem::path tmp_dir() const { return root_ / "tmp"; }
  // Removes tmp/ debris of dead processes on this host (and anything older than a day).
  int clean_stale_tmp() const;

  GcReport gc(const GcOptions& options) const;
  // Re-hashes every object and checks every entry: its key, its outputs (present and intact)
  // and its inputs (the preimage's input digests: an entry computed from a bad or missing
  // object is suspect, and so, transitively, is every entry that used its outputs).
  // `repair` removes bad objects (to quarantine/) and suspect entries.
  VerifyReport verify(bool repair) const;

 private:
  std::filesystem::path quarantine(const std::filesystem::path& object, const std::string& digest) const;
  std::filesystem::path root_;
  mutable std::set<std::string> verified_;
};

}  // namespace meshflow
