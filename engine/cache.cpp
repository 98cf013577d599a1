#include "engine/cache.hpp"

#include "engine/fsutil.hpp"
#include "engine/hash.hpp"

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cstring>
#include <fcntl.h>
#include <functional>
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

// What lies at an object's path, looked at without following links and without throwing:
// the store only ever renames regular files there, so anything else (a folder, a symlink, a
// loop of symlinks, a device, a path the system refuses to resolve) is a corrupt object.
enum class AtObjectPath { Missing, File, Foreign };
AtObjectPath at_object_path(const fs::path& p) {
  std::error_code ec;
  const fs::file_status st = fs::symlink_status(p, ec);
  if (st.type() == fs::file_type::not_found) return AtObjectPath::Missing;
  if (ec) return AtObjectPath::Foreign;
  return st.type() == fs::file_type::regular ? AtObjectPath::File : AtObjectPath::Foreign;
}
const char* foreign_kind(const fs::path& p) {
  std::error_code ec;
  const fs::file_status st = fs::symlink_status(p, ec);
  if (ec) return "something the system cannot resolve";
  if (st.type() == fs::file_type::directory) return "a folder";
  if (st.type() == fs::file_type::symlink) return "a symbolic link";
  return "not a regular file";
}
// Every path under objects/<ab>/ (the names objects are stored under), without following
// links or entering what lies at an object's path; `fn(path)` for each. Never throws.
void for_each_object_path(const fs::path& objects, const std::function<void(const fs::path&)>& fn) {
  std::error_code ec;
  for (fs::directory_iterator d(objects, ec), end; !ec && d != end; d.increment(ec)) {
    std::error_code ec2;
    if (!d->is_directory(ec2) || d->is_symlink(ec2)) continue;  // objects/ holds only the <ab> folders
    for (fs::directory_iterator o(d->path(), ec2), oend; !ec2 && o != oend; o.increment(ec2)) fn(o->path());
  }
}

// What a lock file says about its holder.
struct LockFile {
  bool exists = false;  // false: vanished while we looked
  bool readable = false;  // a JSON object with pid and host (we never write anything else)
  std::string text, host;
  long pid = 0;
  double age = 0;  // seconds since the last keep-alive
};

LockFile read_lock(const fs::path& lock) {
  LockFile l;
  try {
    l.text = read_file(lock);
  } catch (...) {
    return l;
  }
  l.exists = true;
  l.age = age_seconds(lock);
  try {
    json j = json::parse(l.text);
    l.pid = j.at("pid").get<long>();
    l.host = j.at("host").get<std::string>();
    l.readable = true;
  } catch (...) {
  }
  return l;
}

// A lock nobody holds: its holder died (this host), or its keep-alive stopped (any host; an
// empty or garbage lock was never written by a holder, so only its age counts).
bool abandoned(const LockFile& l, double stale_seconds) {
  if (l.age > stale_seconds) return true;
  return l.readable && l.host == hostname() && !process_alive(l.pid);
}

// Removes `lock` if it still holds `text` (a breaker that raced us may have replaced it): moved
// aside first, put back when it was not the one judged. True when removed.
bool break_lock(const fs::path& lock, const std::string& text, const fs::path& tmp_dir) {
  fs::path aside = tmp_dir / ("lock.broken." + unique_suffix());
  if (::rename(lock.c_str(), aside.c_str()) != 0) return false;
  std::string moved;
  try {
    moved = read_file(aside);
  } catch (...) {
  }
  bool same = moved == text;
  if (!same) (void)::link(aside.c_str(), lock.c_str());
  ::unlink(aside.c_str());
  return same;
}
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
  for (auto d : {"objects", "actions", "last", "locks", "tmp", "quarantine"}) {
    fs::create_directories(root_ / d, ec);
    if (ec)
      throw std::runtime_error("cannot create the cache folder '" + (root_ / d).string() + "': " + ec.message() +
                               ". Choose a writable cache with --cache DIR or MESHFLOW_CACHE.");
  }
}

fs::path Cache::object_path(const std::string& digest) const {
  return root_ / "objects" / digest.substr(0, 2) / digest;
}

fs::path Cache::quarantine(const fs::path& object, const std::string& digest) const {
  fs::path q = root_ / "quarantine" / (digest + "." + unique_suffix());
  std::error_code ec;
  fs::create_directories(q.parent_path(), ec);
  if (::rename(object.c_str(), q.c_str()) == 0) return q;
  fs::remove_all(object, ec);  // could not keep it: at least never serve it
  return {};
}

bool Cache::verify_object(const std::string& digest, BadObject* bad) const {
  if (verified_.count(digest)) return true;
  fs::path p = object_path(digest);
  std::error_code ec;
  const AtObjectPath at = at_object_path(p);
  if (at == AtObjectPath::Missing) return false;
  std::string actual;
  try {
    if (at == AtObjectPath::File) actual = sha256_file(p);
  } catch (...) {
  }
  if (actual == digest) {
    verified_.insert(digest);
    return true;
  }
  BadObject b{digest, actual, std::uint64_t(fs::file_size(p, ec)), {}};
  if (ec) b.size = 0;
  b.quarantined = quarantine(p, digest);
  if (bad) *bad = b;
  return false;
}

void Cache::mark_verified(const std::string& digest) const { verified_.insert(digest); }

std::string Cache::store_object(const fs::path& file) {
  std::string digest = sha256_file(file);
  fs::path target = object_path(digest);
  std::error_code ec;
  fs::create_directories(target.parent_path(), ec);
  if (const AtObjectPath at = at_object_path(target); at != AtObjectPath::Missing) {
    std::string present;
    try {
      if (at == AtObjectPath::File) present = sha256_file(target);
    } catch (...) {
    }
    if (present == digest) {
      fs::remove(file, ec);
      return digest;
    }
    quarantine(target, digest);  // a corrupt copy (or a folder, a link) under this name: replaced
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
    if (at_object_path(object_path(o.value("digest", ""))) != AtObjectPath::File) return std::nullopt;
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
    LockFile other = read_lock(lock);
    if (!other.exists) continue;  // released meanwhile: try again
    if (!abandoned(other, stale_seconds)) {
      if (holder)
        *holder = other.readable ? "pid " + std::to_string(other.pid) + " on host " + other.host
                                 : "an unreadable lock file " + lock.string() + " (broken when its keep-alive is " +
                                       std::to_string(int(stale_seconds)) + " s old; now " + std::to_string(int(other.age)) + " s)";
      return nullptr;
    }
    break_lock(lock, other.text, tmp_dir());
  }
  if (holder) *holder = "a process that keeps replacing the lock";
  return nullptr;
}

fs::path Cache::make_scratch() const {
  fs::path p = tmp_dir() / ("run." + unique_suffix());
  fs::create_directories(p);
  return p;
}

int Cache::clean_stale_locks(double stale_seconds) const {
  int removed = 0;
  std::error_code ec;
  for (auto& e : fs::directory_iterator(root_ / "locks", ec)) {
    if (e.path().extension() != ".lock") continue;
    LockFile l = read_lock(e.path());
    if (l.exists && abandoned(l, stale_seconds) && break_lock(e.path(), l.text, tmp_dir())) ++removed;
  }
  return removed;
}

int Cache::clean_stale_tmp() const {
  int removed = 0;
  std::error_code ec;
  for (auto& e : fs::directory_iterator(tmp_dir(), ec)) {
    if (stale_debris(e.path(), e.path().filename().string())) {
      fs::remove_all(e.path(), ec);
      ++removed;
    }
  }
  return removed;
}

GcReport Cache::gc(const GcOptions& opt) const {
  GcReport r;
  r.tmp_removed = clean_stale_tmp();
  r.locks_removed = clean_stale_locks();
  std::error_code ec;
  for (auto& e : fs::directory_iterator(root_ / "quarantine", ec))
    if (age_seconds(e.path()) >= opt.grace_seconds && fs::remove_all(e.path(), ec) > 0) ++r.quarantine_removed;
  // What an entry keeps alive: its outputs and the inputs it was computed from (verify checks
  // those, and drops an entry whose inputs are gone: its provenance can no longer be checked).
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
      for (auto& in : j.at("preimage").value("inputs", json::array())) a.digests.push_back(in.at("digest"));
    } catch (...) {
      fs::remove(e.path(), ec);  // unreadable entry: worthless
      ++r.actions_removed;
      continue;
    }
    actions.push_back(std::move(a));
  }
  std::map<std::string, std::pair<std::uint64_t, double>> objects;  // digest -> size, age
  for_each_object_path(root_ / "objects", [&](const fs::path& p) {
    if (at_object_path(p) != AtObjectPath::File) return;  // gc --verify --repair removes those
    std::error_code e2;
    const std::uint64_t size = fs::file_size(p, e2);
    if (e2) return;
    objects[p.filename().string()] = {size, age_seconds(p)};
    r.bytes_before += size;
  });
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
    if (at_object_path(object_path(d)) == AtObjectPath::File) r.bytes_after += sa.first;
  return r;
}

namespace {
// One action entry as verify sees it.
struct EntryFacts {
  fs::path file;
  std::string key;
  std::vector<std::string> inputs, outputs;  // digests
  std::string problem;  // set when the entry itself is unusable
};

EntryFacts read_entry(const fs::path& file, const std::function<bool(const std::string&)>& object_ok) {
  EntryFacts f{file, file.stem().string(), {}, {}, {}};
  try {
    json j = json::parse(read_file(file));
    if (j.at("key") != f.key) throw std::runtime_error("key field differs from the file name");
    if (sha256_hex(canonical_json(j.at("preimage"))) != f.key)
      throw std::runtime_error("key is not the SHA-256 of the stored preimage");
    for (auto& in : j.at("preimage").value("inputs", json::array())) f.inputs.push_back(in.at("digest"));
    for (auto& o : j.at("outputs")) {
      std::string d = o.at("digest");
      f.outputs.push_back(d);
      if (!object_ok(d)) throw std::runtime_error("output '" + o.value("name", "") + "' object " + d + " is missing or corrupt");
    }
  } catch (const std::exception& ex) {
    f.problem = ex.what();
  }
  return f;
}
// Sets the problem of every entry computed from a suspect object. Suspect: a bad or missing
// object, then (to a fixed point) the outputs of entries that used a suspect input (what was
// computed from bad bytes is not to be trusted either).
void mark_computed_from_suspect(std::vector<EntryFacts>& entries, const std::function<bool(const std::string&)>& object_ok) {
  std::set<std::string> suspect;
  for (auto& f : entries)
    for (auto& d : f.inputs)
      if (!object_ok(d)) suspect.insert(d);
  for (bool grew = true; grew;) {
    grew = false;
    for (auto& f : entries) {
      if (!f.problem.empty()) continue;
      auto it = std::find_if(f.inputs.begin(), f.inputs.end(), [&](auto& d) { return suspect.count(d) > 0; });
      if (it == f.inputs.end()) continue;
      f.problem = "input object " + *it + (object_ok(*it) ? " was computed from a bad or missing object" : " is missing or corrupt");
      suspect.insert(f.outputs.begin(), f.outputs.end());
      grew = true;
    }
  }
}
}  // namespace

VerifyReport Cache::verify(bool repair) const {
  VerifyReport r;
  std::error_code ec;
  std::set<std::string> bad;
  for_each_object_path(root_ / "objects", [&](const fs::path& p) {
    ++r.objects;
    std::string name = p.filename().string();
    if (at_object_path(p) != AtObjectPath::File) {
      r.problems.push_back("object " + name + " is " + foreign_kind(p) + ", not a file");
      bad.insert(name);
      if (repair) quarantine(p, name);
      return;
    }
    std::string actual;
    try {
      actual = sha256_file(p);
    } catch (...) {
      actual = "(unreadable)";
    }
    if (actual != name) {
      r.problems.push_back("object " + name + " has content " + actual);
      bad.insert(name);
      if (repair) quarantine(p, name);
    }
  });
  auto object_ok = [&](const std::string& d) { return !bad.count(d) && at_object_path(object_path(d)) == AtObjectPath::File; };
  std::vector<EntryFacts> entries;
  for (auto& e : fs::directory_iterator(root_ / "actions", ec)) {
    if (e.path().extension() != ".json") {
      r.problems.push_back("stray file in actions/: " + e.path().filename().string());
      if (repair) fs::remove(e.path(), ec);
      continue;
    }
    ++r.actions;
    entries.push_back(read_entry(e.path(), object_ok));
  }
  std::sort(entries.begin(), entries.end(), [](auto& a, auto& b) { return a.key < b.key; });
  mark_computed_from_suspect(entries, object_ok);
  for (auto& f : entries) {
    if (f.problem.empty()) continue;
    r.problems.push_back("action " + f.key + ": " + f.problem);
    if (repair) fs::remove(f.file, ec);
  }
  return r;
}

}  // namespace meshflow
