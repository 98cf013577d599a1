#include "engine/remote_cache.hpp"

#include "engine/cache.hpp"
#include "engine/fsutil.hpp"
#include "engine/hash.hpp"
#include "engine/workflow.hpp"

#include <openssl/crypto.h>
#include <openssl/evp.h>
#include <openssl/hmac.h>

#include <cstdlib>
#include <fstream>
#include <ostream>
#include <sstream>

namespace fs = std::filesystem;
using nlohmann::json;

namespace meshflow {

namespace {
std::string env(const char* name) {
  const char* v = std::getenv(name);
  return v ? v : "";
}

bool is_sha256(const std::string& s) {
  if (s.size() != 64) return false;
  for (char c : s)
    if (!((c >= '0' && c <= '9') || (c >= 'a' && c <= 'f'))) return false;
  return true;
}

std::string short_digest(const std::string& d) { return d.substr(0, 12) + "..."; }

// The signing key: the bytes of the file $MESHFLOW_REMOTE_KEY_FILE names, a final newline
// dropped ("" when the variable is unset).
constexpr std::size_t kMinKeyBytes = 16;
std::string read_signing_key(const std::string& file) {
  if (file.empty()) return "";
  const std::string what = "MESHFLOW_REMOTE_KEY_FILE '" + file + "'";
  std::error_code ec;
  if (!fs::is_regular_file(file, ec))
    throw WorkflowError(what + " is not a file: give the file holding the team's remote cache key (e.g. made once with "
                               "`openssl rand -hex 32 > key`, shared with every machine that uses the cache).");
  std::ifstream in(file, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  if (!in && !in.eof()) throw WorkflowError(what + " cannot be read: check its permissions.");
  std::string key = ss.str();
  while (!key.empty() && (key.back() == '\n' || key.back() == '\r')) key.pop_back();
  if (key.size() < kMinKeyBytes)
    throw WorkflowError(what + " holds " + std::to_string(key.size()) + " bytes; a key needs at least " +
                        std::to_string(kMinKeyBytes) + " (make one with `openssl rand -hex 32`).");
  return key;
}
}  // namespace

std::string entry_signature(const json& entry, const std::string& secret) {
  json unsigned_entry = entry;
  if (unsigned_entry.is_object()) unsigned_entry.erase("signature");
  const std::string text = canonical_json(unsigned_entry);
  unsigned char mac[EVP_MAX_MD_SIZE];
  unsigned int n = 0;
  if (!HMAC(EVP_sha256(), secret.data(), static_cast<int>(secret.size()), reinterpret_cast<const unsigned char*>(text.data()),
            text.size(), mac, &n))
    throw std::runtime_error("OpenSSL HMAC-SHA256 failed");
  static const char* hex = "0123456789abcdef";
  std::string out;
  for (unsigned int i = 0; i < n; ++i) out += hex[mac[i] >> 4], out += hex[mac[i] & 15];
  return out;
}

bool entry_signed_by(const json& entry, const std::string& secret) {
  if (!entry.is_object() || !entry.contains("signature") || !entry["signature"].is_string()) return false;
  const std::string given = entry["signature"].get<std::string>(), want = entry_signature(entry, secret);
  return given.size() == want.size() && CRYPTO_memcmp(given.data(), want.data(), want.size()) == 0;
}

RemoteCacheOptions resolve_remote_cache(const std::string& url_option, const std::string& netrc_option,
                                        double connect_timeout_s, double timeout_s) {
  RemoteCacheOptions o;
  const bool from_env = url_option.empty();
  o.url = from_env ? env("MESHFLOW_REMOTE_CACHE") : url_option;
  if (o.url.empty()) return o;
  const std::string where = from_env ? "MESHFLOW_REMOTE_CACHE" : "--remote-cache";
  if (std::string why = http::check_url(o.url); !why.empty())
    throw WorkflowError(where + " '" + o.url + "' is not a remote cache URL: " + why + ".");
  while (!o.url.empty() && o.url.back() == '/') o.url.pop_back();
  if (!(connect_timeout_s > 0) || !(timeout_s > 0))
    throw WorkflowError("--remote-connect-timeout and --remote-timeout must be positive numbers of seconds.");
  o.client.connect_timeout_s = connect_timeout_s;
  o.client.timeout_s = timeout_s;
  std::string netrc = netrc_option.empty() ? env("MESHFLOW_REMOTE_CACHE_NETRC") : netrc_option;
  if (!netrc.empty()) {
    std::error_code ec;
    if (!fs::is_regular_file(netrc, ec))
      throw WorkflowError((netrc_option.empty() ? "MESHFLOW_REMOTE_CACHE_NETRC" : "--remote-netrc") + std::string(" '") +
                          netrc + "' is not a file: give a netrc file with `machine HOST login USER password PASS`.");
    o.client.netrc = netrc;
  }
  o.key = read_signing_key(env("MESHFLOW_REMOTE_KEY_FILE"));
  if (!o.key.empty()) o.key_source = "the key in MESHFLOW_REMOTE_KEY_FILE (" + env("MESHFLOW_REMOTE_KEY_FILE") + ")";
  o.client.header = env("MESHFLOW_REMOTE_CACHE_HEADER");
  if (!o.client.header.empty()) {
    auto colon = o.client.header.find(':');
    if (colon == std::string::npos || colon == 0 || o.client.header.find_first_of("\r\n") != std::string::npos)
      throw WorkflowError("MESHFLOW_REMOTE_CACHE_HEADER must be one header line 'Name: value' (e.g. 'Authorization: "
                          "Bearer TOKEN'); it is not.");
  }
  return o;
}

json remote_entry(const json& entry) {
  json r = json::object();
  for (auto k : {"key", "preimage", "outputs", "stats", "seconds", "peak_rss_mb"})
    if (entry.contains(k)) r[k] = entry[k];
  return r;
}

std::string check_remote_entry(const json& entry, const std::string& key) {
  if (!entry.is_object()) return "it is not a JSON object";
  if (!entry.contains("key") || entry["key"] != key) return "its key field is not the key asked for";
  if (!entry.contains("preimage") || !entry["preimage"].is_object()) return "it has no preimage";
  if (sha256_hex(canonical_json(entry["preimage"])) != key) return "its preimage does not hash to its key";
  if (!entry.contains("outputs") || !entry["outputs"].is_array()) return "it has no outputs";
  for (auto& o : entry["outputs"]) {
    if (!o.is_object() || !o.contains("name") || !o["name"].is_string() || !o.contains("type") || !o["type"].is_string())
      return "an output has no name or type";
    if (!o.contains("digest") || !o["digest"].is_string() || !is_sha256(o["digest"].get<std::string>()))
      return "an output's digest is not a SHA-256 (64 lowercase hex digits)";
  }
  if (entry.contains("stats") && !entry["stats"].is_object()) return "its stats are not an object";
  return "";
}

RemoteCache::RemoteCache(const RemoteCacheOptions& options, Cache& local, std::ostream& err)
    : url_(options.url), client_(options.client), local_(local), err_(err), key_(options.key), key_source_(options.key_source) {}

void RemoteCache::note_unsigned_once() {
  if (!key_.empty() || noted_unsigned_) return;
  noted_unsigned_ = true;
  err_ << "note: remote cache " << url_ << " is unauthenticated: its entries are trusted as far as their preimage "
       << "hashes to the key, so anyone who can write to it can change this run's results; set "
          "MESHFLOW_REMOTE_KEY_FILE to the team's key file to sign entries and use only signed ones (README, \"Shared "
          "cache\").\n";
}

void RemoteCache::warn(const std::string& message) {
  err_ << "warning: remote cache " << url_ << ": " << message << "\n";
  warnings_.push_back(message);
}

void RemoteCache::give_up(const std::string& what, const http::Response& r) {
  off_ = true;
  warn(what + " failed (" + r.describe() + "); this run goes on with the local cache only");
}

std::optional<json> RemoteCache::fetch_entry(const std::string& key, const std::string& stage) {
  std::string body;
  http::Response r = client_.get(url_ + "/ac/" + key, &body, 64u << 20);
  bytes_down_ += r.bytes;
  if (r.not_found()) return std::nullopt;  // a plain miss
  if (!r.ok()) {
    give_up("GET ac/" + short_digest(key) + " (stage '" + stage + "')", r);
    return std::nullopt;
  }
  json entry;
  try {
    entry = json::parse(body);
  } catch (const std::exception&) {
    warn("the entry of stage '" + stage + "' (ac/" + short_digest(key) + ") is not JSON; ignored, the stage runs here");
    return std::nullopt;
  }
  if (std::string why = check_remote_entry(entry, key); !why.empty()) {
    warn("the entry of stage '" + stage + "' (ac/" + short_digest(key) + ") is unusable: " + why +
         "; ignored, the stage runs here");
    return std::nullopt;
  }
  if (!key_.empty() && !entry_signed_by(entry, key_)) {
    warn("the entry of stage '" + stage + "' (ac/" + short_digest(key) + ") " +
         (entry.contains("signature") ? "has a signature that does not verify with " : "is not signed with ") +
         key_source_ + " (forged, changed on the server, or uploaded by a client without the key); ignored and not kept, " +
         "the stage runs here and its signed entry replaces it on the server");
    return std::nullopt;
  }
  return entry;
}

bool RemoteCache::fetch_object(const std::string& digest, const std::string& stage, const std::string& output) {
  if (local_.verify_object(digest)) return true;  // present and intact here already
  fs::path file = local_.tmp_dir() / ("remote." + unique_suffix());
  http::Response r = client_.get_to_file(url_ + "/cas/" + digest, file, local_.tmp_dir());
  bytes_down_ += r.bytes;
  if (r.not_found()) {
    warn("object " + short_digest(digest) + " (output '" + output + "' of stage '" + stage +
         "') is missing on the server; the stage runs here");
    return false;
  }
  if (!r.ok()) {
    give_up("GET cas/" + short_digest(digest) + " (stage '" + stage + "')", r);
    return false;
  }
  std::string actual;
  try {
    actual = sha256_file(file);
  } catch (const std::exception&) {
  }
  std::error_code ec;
  if (actual != digest) {
    fs::remove(file, ec);
    bad_remote_.insert(digest);
    warn("object " + short_digest(digest) + " (output '" + output + "' of stage '" + stage + "', " +
         std::to_string(r.bytes) + " bytes) does not match its digest (its bytes hash to " + short_digest(actual) +
         "); discarded, the stage runs here and its result replaces the object on the server");
    return false;
  }
  try {
    local_.store_object(file);
  } catch (const std::exception& e) {
    fs::remove(file, ec);
    warn(std::string("cannot store a downloaded object in the local cache: ") + e.what());
    return false;
  }
  local_.mark_verified(digest);
  return true;
}

bool RemoteCache::fetch(const std::string& key, const std::string& stage) {
  if (off_ || !asked_.insert(key).second) return false;
  note_unsigned_once();
  auto entry = fetch_entry(key, stage);
  if (!entry) return false;
  for (auto& o : (*entry)["outputs"])
    if (off_ || !fetch_object(o["digest"], stage, o["name"])) return false;
  json local = *entry;
  local["stage"] = stage;
  local["served_by"] = url_;
  try {
    local_.write_action(key, local);  // last, as for a run: its presence means complete
  } catch (const std::exception& e) {
    warn(std::string("cannot write the downloaded entry into the local cache: ") + e.what());
    return false;
  }
  ++served_;
  return true;
}

bool RemoteCache::upload_object(const std::string& digest, const std::string& stage) {
  const std::string url = url_ + "/cas/" + digest;
  if (!bad_remote_.count(digest) && client_.head(url).ok()) return true;  // the server has it
  http::Response r = client_.put_file(url, local_.object_path(digest));
  bytes_up_ += r.bytes;
  if (r.ok()) return true;
  if (r.transport_failed()) give_up("PUT cas/" + short_digest(digest) + " (stage '" + stage + "')", r);
  else {
    uploads_off_ = true;
    warn("the server refused PUT cas/" + short_digest(digest) + " (stage '" + stage + "'): " + r.describe() +
         "; nothing more is uploaded in this run (is the server writable, e.g. nginx's `dav_methods PUT`?)");
  }
  return false;
}

void RemoteCache::upload(const std::string& key, const json& entry, const std::string& stage) {
  if (off_ || uploads_off_) return;
  for (auto& o : entry["outputs"])
    if (!upload_object(o["digest"], stage)) return;
  json signed_entry = remote_entry(entry);
  if (!key_.empty()) signed_entry["signature"] = entry_signature(signed_entry, key_);
  std::string text = signed_entry.dump(1);
  http::Response r = client_.put(url_ + "/ac/" + key, text);
  bytes_up_ += r.bytes;
  if (r.ok()) {
    ++uploaded_;
    for (auto& o : entry["outputs"]) bad_remote_.erase(o["digest"].get<std::string>());
    return;
  }
  if (r.transport_failed()) give_up("PUT ac/" + short_digest(key) + " (stage '" + stage + "')", r);
  else {
    uploads_off_ = true;
    warn("the server refused PUT ac/" + short_digest(key) + " (stage '" + stage + "'): " + r.describe() +
         "; nothing more is uploaded in this run");
  }
}

json RemoteCache::report() const {
  return {{"url", url_},           {"signed", !key_.empty()},   {"served", served_},         {"uploaded", uploaded_},
          {"warnings", warnings_}, {"bytes_down", bytes_down_}, {"bytes_up", bytes_up_}};
}

}  // namespace meshflow
