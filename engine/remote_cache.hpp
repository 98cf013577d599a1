// meshflow engine — a shared remote cache over HTTP, in the layout of Bazel's HTTP remote cache:
//   <url>/cas/<sha256>   artifact bytes, named by their SHA-256 (GET, HEAD, PUT)
//   <url>/ac/<key>       the action entry of a stage key (our JSON: preimage, outputs, stats)
// Any server that stores what is PUT serves it (nginx with WebDAV `dav_methods PUT`, bazel-remote
// with its AC validation off, a WebDAV or S3 gateway).
//
// Looked up after the local cache misses; what a stage ran is uploaded (objects first, entry
// last). The remote is never trusted over a digest: every downloaded object is hashed and a
// mismatch is discarded (the stage recomputes), an entry must hash to its key. A remote that
// is down, refuses or is slow is a warning and a local run, never a failure.
//
// Trust in entries: a digest proves an object's bytes, not that they are the stage's result:
// an entry whose preimage hashes to its key but whose outputs name another valid object would
// be served as that stage's result. With a team key (the file $MESHFLOW_REMOTE_KEY_FILE names)
// every uploaded entry carries "signature", the HMAC-SHA256 (OpenSSL) under that key of the
// entry's canonical JSON without the signature, and a downloaded entry is used only when its
// signature verifies: any other is ignored with a warning, never copied into the local cache,
// and the stage runs here (its own signed entry then replaces it on the server). Without a key
// the run says once that the remote is unauthenticated. README, "Shared cache", says what this
// protects against and what not.
#pragma once

#include "engine/http.hpp"

#include <nlohmann/json.hpp>

#include <filesystem>
#include <iosfwd>
#include <optional>
#include <set>
#include <string>
#include <vector>

namespace meshflow {

class Cache;

struct RemoteCacheOptions {
  std::string url;  // base URL without a trailing '/'; empty: no remote cache
  http::ClientOptions client;
  std::string key;         // the team's signing key (the key file's bytes); empty: entries unsigned
  std::string key_source;  // where the key came from, for messages
};

// The remote cache a run uses: `url_option` (--remote-cache) else $MESHFLOW_REMOTE_CACHE;
// credentials from `netrc_option` (--remote-netrc) else $MESHFLOW_REMOTE_CACHE_NETRC (else
// ~/.netrc if present), and an extra header from $MESHFLOW_REMOTE_CACHE_HEADER
// ("Authorization: Bearer ..."), and the signing key from the file $MESHFLOW_REMOTE_KEY_FILE
// names (its bytes, a final newline dropped; at least 16 bytes, e.g. `openssl rand -hex 32`).
// Throws WorkflowError (exit 2) for a URL that is not http(s), a netrc file that does not
// exist, a header without "Name: value", a timeout <= 0, or a key file that is missing,
// unreadable, not a file or shorter than 16 bytes.
RemoteCacheOptions resolve_remote_cache(const std::string& url_option, const std::string& netrc_option,
                                        double connect_timeout_s, double timeout_s);

class RemoteCache {
 public:
  RemoteCache(const RemoteCacheOptions& options, Cache& local, std::ostream& err);

  // Downloads the entry of `key` and the objects it names into the local cache, each object
  // verified against its digest. True when the local cache now holds the whole entry. A miss,
  // a bad object or entry, or a remote that fails returns false (the last two with a warning).
  // A key is asked for once per run.
  bool fetch(const std::string& key, const std::string& stage);
  // Uploads the objects `entry` names (those the server lacks) and then the entry. Failures
  // are warnings; after one, this run uploads nothing more.
  void upload(const std::string& key, const nlohmann::json& entry, const std::string& stage);

  // {url, signed, served, uploaded, warnings, bytes_down, bytes_up}
  nlohmann::json report() const;

 private:
  std::optional<nlohmann::json> fetch_entry(const std::string& key, const std::string& stage);
  bool fetch_object(const std::string& digest, const std::string& stage, const std::string& output);
  bool upload_object(const std::string& digest, const std::string& stage);
  void warn(const std::string& message);
  void note_unsigned_once();
  void give_up(const std::string& what, const http::Response& r);

  std::string url_;
  http::Client client_;
  Cache& local_;
  std::ostream& err_;
  std::string key_, key_source_;  // signing key (empty: unsigned) and where it came from
  bool noted_unsigned_ = false;
  bool off_ = false;          // the remote failed: no more requests this run
  bool uploads_off_ = false;  // an upload was refused: no more uploads this run
  std::set<std::string> asked_;        // keys fetched once already
  std::set<std::string> bad_remote_;   // digests whose remote bytes were wrong: always re-PUT
  int served_ = 0, uploaded_ = 0;
  std::uint64_t bytes_down_ = 0, bytes_up_ = 0;
  std::vector<std::string> warnings_;
};

// What an action entry holds that is uploaded: key, preimage, outputs, stats and measured
// seconds and memory (not the workflow's name, nor the stage's log).
nlohmann::json remote_entry(const nlohmann::json& entry);
// "" when `entry` is a well-formed action entry of `key` (its preimage hashes to the key, its
// outputs name SHA-256 digests), else what is wrong.
std::string check_remote_entry(const nlohmann::json& entry, const std::string& key);
// The hex HMAC-SHA256 under `secret` of the entry's canonical JSON, its "signature" left out.
std::string entry_signature(const nlohmann::json& entry, const std::string& secret);
// True when `entry` carries a "signature" equal to entry_signature(entry, secret) (compared in
// constant time).
bool entry_signed_by(const nlohmann::json& entry, const std::string& secret);

}  // namespace meshflow
