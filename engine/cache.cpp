#include "engine/cache.hpp"

#include "engine/fsutil.hpp"
#include "engine/hash.hpp"

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cstring>
#include <fcntl.h>
#include <map>
#include <set>
#include <stdexcept>
#include <sys/stat.h>
#include <unistd.h>

namespace fs = std::filesystem;
using nlohmann::json;

namespace meshflow {

namespace {
double age_seconds(const fs::path& p) {
  struct stat st;
  if (::stat(p.c_str(), &st) != 0) return 0;
  return double(std::time(nullptr) - st.st_mtime);
}
void touch(const fs::path& p) { ::utimensat(AT_FDCWD, p.c_str(), nullptr, 0); }
}  // namespace

CacheLock::~CacheLock() {
  // Remove only our own lock (a breaker may have replaced it after a long stall).
  try {
    json j = json::parse(read_file(file_));
    if (j.value("nonce", "") == nonce_) ::unlink(file_.c_str());
  } catch (...) {
  }
}

void CacheLock::keep_alive() { touch(file_); }

Cache::Cache(fs::path root) : root_(std::move(root)) {
  std::error_code ec;
  for (auto d : {"objects", "actions", "last", "locks", "tmp"}) {
    fs::create_directories(root_ / d, ec);
    if (ec)
      throw std::runtime_error("cannot create the cache folder '" + (root_ / d).string() + "': " + ec.message() +
                               ". Choose a writable cache with --cache DIR or MESHFLOW_CACHE.");
  }
}

fs::path Cache::object_path(const std::string& digest) const {
  return root_ / "objects" / digest.substr(0, 2) / digest;
}

std::string Cache::store_object(const fs::path& file) {
  std::string digest = sha256_file(file);
  fs::path target = object_path(digest);
  std::error_code ec;
  fs::create_directories(target.parent_path(), ec);
  if (fs::exists(target)) {
    fs::remove(file, ec);
    return digest;
  }
  // fsync the data before it becomes visible under its name.
  int fd = ::open(file.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd >= 0) {
    ::fsync(fd);
    ::close(fd);
  }
  ::chmod(file.c_str(), 0444);
  if (::rename(file.c_str(), target.c_str()) != 0)
    throw std::runtime_error("cannot store '" + file.string() + "' in the cache: " + std::strerror(errno));
  return digest;
}

std::optional<json> Cache::load_action(const std::string& key) const {
  fs::path p = root_ / "actions" / (key + ".json");
  std::error_code ec;
  if (!fs::exists(p, ec)) return std::nullopt;
  json entry;
  try {
    entry = json::parse(read_file(p));
  } catch (...) {
    return std::nullopt;  // unreadable entry: recompute (rename makes this very unlikely)
  }
  if (!entry.is_object() || entry.value("key", "") != key || !entry.contains("outputs")) return std::nullopt;
  for (auto& o : entry["outputs"])
    if (!fs::exists(object_path(o.value("digest", "")), ec)) return std::nullopt;
  touch(p);
  return entry;
}

void Cache::write_action(const std::string& key, const json& entry) {
  atomic_write(root_ / "actions" / (key + ".json"), entry.dump(1), tmp_dir());
}

void Cache::record_last(const std::string& workflow, const std::string& stage, const json& last) {
  fs::path dir = root_ / "last" / workflow;
  fs::path file = dir / (stage + ".json");
  std::string text = last.dump(1);
  std::error_code ec;
  if (fs::exists(file, ec)) {
    try {
      if (read_file(file) == text) return;  // unchanged: a no-change re-run writes nothing
    } catch (...) {
    }
  }
  fs::create_directories(dir);
  atomic_write(file, text, tmp_dir(), /*durable=*/false);  // advisory: only `explain` reads it
}

std::optional<json> Cache::last(const std::string& workflow, const std::string& stage) const {
  fs::path p = root_ / "last" / workflow / (stage + ".json");
  std::error_code ec;
  if (!fs::exists(p, ec)) return std::nullopt;
  try {
    return json::parse(read_file(p));
  } catch (...) {
    return std::nullopt;
  }
}

std::unique_ptr<CacheLock> Cache::try_lock(const std::string& key, std::string* holder, double stale_seconds) const {
  fs::path lock = root_ / "locks" / (key + ".lock");
  std::string nonce = unique_suffix();
  json me = {{"pid", long(getpid())}, {"host", hostname()}, {"nonce", nonce}};
  for (int attempt = 0; attempt < 3; ++attempt) {
    // Write our claim to a temp file, then link() it into place: link fails if the lock exists,
    // and the lock never appears half-written.
    fs::path tmp = tmp_dir() / ("lock.tmp." + nonce);
    atomic_write(tmp, me.dump(), tmp_dir());
    int rc = ::link(tmp.c_str(), lock.c_str());
    ::unlink(tmp.c_str());
    if (rc == 0) return std::make_unique<CacheLock>(lock, nonce);
    if (errno != EEXIST) throw std::runtime_error("cannot create lock '" + lock.string() + "': " + std::strerror(errno));
    // Someone holds it: is the holder alive?
    json other;
    std::string text;
    try {
      text = read_file(lock);
      other = json::parse(text);
    } catch (...) {
      continue;  // vanished or being replaced: try again
    }
    long pid = other.value("pid", 0L);
    std::string host = other.value("host", "");
    bool dead = (host == hostname() && !process_alive(pid)) || age_seconds(lock) > stale_seconds;
    if (!dead) {
      if (holder) *holder = "pid " + std::to_string(pid) + " on host " + host;
      return nullptr;
    }
    // Break the stale lock: move it aside, and put it back if it was not the one we judged.
    fs::path aside = tmp_dir() / ("lock.broken." + unique_suffix());
    if (::rename(lock.c_str(), aside.c_str()) != 0) continue;
    std::string moved;
    try {
      moved = read_file(aside);
    } catch (...) {
    }
    if (moved != text) ::link(aside.c_str(), lock.c_str());
    ::unlink(aside.c_str());
  }
  if (holder) *holder = "a process that keeps replacing the lock";
  return nullptr;
}

fs::path Cache::make_scratch() const {
  fs::path p = tmp_dir() / ("run." + unique_suffix());
  fs::create_directories(p);
  return p;
}

int Cache::clean_stale_tmp() const {
  int removed = 0;
  std::error_code ec;
  const std::string me = sanitized_hostname();
  for (auto& e : fs::directory_iterator(tmp_dir(), ec)) {
    std::string host;
    long pid = 0;
    std::string name = e.path().filename().string();
    bool dead = false;
    if (parse_owner(name, &host, &pid)) dead = host == me && !process_alive(pid);
    if (!dead && age_seconds(e.path()) > 86400) dead = true;
    if (dead) {
      fs::remove_all(e.path(), ec);
      ++removed;
    }
  }
  return removed;
}

GcReport Cache::gc(const GcOptions& opt) const {
  GcReport r;
  r.tmp_removed = clean_stale_tmp();
  std::error_code ec;
  struct Action {
    fs::path file;
    double age;
    std::vector<std::string> digests;
  };
  std::vector<Action> actions;
  for (auto& e : fs::directory_iterator(root_ / "actions", ec)) {
    Action a{e.path(), age_seconds(e.path()), {}};
    try {
      json j = json::parse(read_file(e.path()));
      for (auto& o : j.at("outputs")) a.digests.push_back(o.at("digest"));
    } catch (...) {
      fs::remove(e.path(), ec);  // unreadable entry: worthless
      ++r.actions_removed;
      continue;
    }
    actions.push_back(std::move(a));
  }
  std::map<std::string, std::pair<std::uint64_t, double>> objects;  // digest -> size, age
  for (auto& e : fs::recursive_directory_iterator(root_ / "objects", ec))
    if (e.is_regular_file()) {
      objects[e.path().filename().string()] = {e.file_size(), age_seconds(e.path())};
      r.bytes_before += e.file_size();
    }
  // Most recently used first; drop by age, then by size budget.
  std::sort(actions.begin(), actions.end(), [](const Action& a, const Action& b) {
    return a.age != b.age ? a.age < b.age : a.file < b.file;
  });
  std::set<std::string> kept_digests;
  std::uint64_t kept_bytes = 0;
  for (auto& a : actions) {
    bool drop = opt.max_age_days && a.age > *opt.max_age_days * 86400;
    std::uint64_t add = 0;
    for (auto& d : a.digests)
      if (!kept_digests.count(d) && objects.count(d)) add += objects[d].first;
    if (!drop && opt.max_bytes && kept_bytes + add > *opt.max_bytes) drop = true;
    if (drop) {
      fs::remove(a.file, ec);
      ++r.actions_removed;
      continue;
    }
    kept_bytes += add;
    kept_digests.insert(a.digests.begin(), a.digests.end());
  }
  for (auto& [d, sa] : objects) {
    if (kept_digests.count(d) || sa.second < opt.grace_seconds) continue;
    fs::remove(object_path(d), ec);
    ++r.objects_removed;
  }
  for (auto& [d, sa] : objects)
    if (fs::exists(object_path(d), ec)) r.bytes_after += sa.first;
  return r;
}

VerifyReport Cache::verify(bool repair) const {
  VerifyReport r;
  std::error_code ec;
  std::set<std::string> bad;
  for (auto& e : fs::recursive_directory_iterator(root_ / "objects", ec)) {
    if (!e.is_regular_file()) continue;
    ++r.objects;
    std::string name = e.path().filename().string();
    std::string actual = sha256_file(e.path());
    if (actual != name) {
      r.problems.push_back("object " + name + " has content " + actual);
      bad.insert(name);
      if (repair) fs::remove(e.path(), ec);
    }
  }
  for (auto& e : fs::directory_iterator(root_ / "actions", ec)) {
    if (e.path().extension() != ".json") {
      r.problems.push_back("stray file in actions/: " + e.path().filename().string());
      if (repair) fs::remove(e.path(), ec);
      continue;
    }
    ++r.actions;
    std::string key = e.path().stem().string();
    bool ok = true;
    try {
      json j = json::parse(read_file(e.path()));
      if (j.at("key") != key) throw std::runtime_error("key field differs from the file name");
      if (sha256_hex(canonical_json(j.at("preimage"))) != key)
        throw std::runtime_error("key is not the SHA-256 of the stored preimage");
      for (auto& o : j.at("outputs")) {
        std::string d = o.at("digest");
        if (bad.count(d) || !fs::exists(object_path(d), ec))
          throw std::runtime_error("output '" + o.value("name", "") + "' object " + d + " is missing or corrupt");
      }
    } catch (const std::exception& ex) {
      ok = false;
      r.problems.push_back("action " + key + ": " + ex.what());
    }
    if (!ok && repair) fs::remove(e.path(), ec);
  }
  return r;
}

}  // namespace meshflow
