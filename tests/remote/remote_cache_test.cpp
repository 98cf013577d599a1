// The remote cache's HTTP client and its fetch/upload against a tiny local server started by
// the test (tests/remote/tiny_server.py: Python's http.server storing what is PUT, or never
// answering, or refusing PUT). The end-to-end runs with nginx are remote_cache_test.sh.
#include "engine/cache.hpp"
#include "engine/hash.hpp"
#include "engine/http.hpp"
#include "engine/remote_cache.hpp"
#include "engine/workflow.hpp"
#include "support.hpp"

#include <doctest/doctest.h>
#include <nlohmann/json.hpp>

#include <arpa/inet.h>
#include <chrono>
#include <csignal>
#include <cstdlib>
#include <netinet/in.h>
#include <sstream>
#include <sys/socket.h>
#include <thread>
#include <unistd.h>

namespace fs = std::filesystem;
using nlohmann::json;
using Clock = std::chrono::steady_clock;
using namespace meshflow;

namespace {

double since(Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); }

// tiny_server.py in a child process, stopped when this goes out of scope.
struct Server {
  int pid = -1;
  int port = 0;
  fs::path root;
  explicit Server(const std::vector<std::string>& extra = {}) {
    fs::path dir = mftest::temp_dir("remote-server");
    root = dir / "root";
    fs::create_directories(root);
    fs::path port_file = dir / "port";
    std::vector<std::string> argv = {MESHFLOW_PYTHON, std::string(MESHFLOW_SOURCE_DIR) + "/tests/remote/tiny_server.py",
                                     port_file.string(), root.string()};
    argv.insert(argv.end(), extra.begin(), extra.end());
    pid = mftest::spawn(argv, dir / "server.log");
    for (int i = 0; i < 200 && !fs::exists(port_file); ++i) std::this_thread::sleep_for(std::chrono::milliseconds(50));
    REQUIRE_MESSAGE(fs::exists(port_file), "the test server did not start: " << mftest::read_text(dir / "server.log"));
    port = std::stoi(mftest::read_text(port_file));
  }
  ~Server() {
    ::kill(pid, SIGTERM);
    mftest::wait_exit(pid);
  }
  std::string url() const { return "http://127.0.0.1:" + std::to_string(port); }
};

// A port on 127.0.0.1 nobody listens on (bound, then closed).
int closed_port() {
  int s = ::socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  ::bind(s, reinterpret_cast<sockaddr*>(&a), sizeof a);
  socklen_t n = sizeof a;
  ::getsockname(s, reinterpret_cast<sockaddr*>(&a), &n);
  ::close(s);
  return ntohs(a.sin_port);
}

RemoteCacheOptions options(const std::string& url, double timeout = 10) {
  RemoteCacheOptions o;
  o.url = url;
  o.client.timeout_s = timeout;
  o.client.connect_timeout_s = 2;
  return o;
}

// A stage result in `cache`: one object of `bytes` and the entry naming it. Returns the entry.
json store_result(Cache& cache, const std::string& bytes, const json& preimage) {
  fs::path f = cache.tmp_dir() / "result";
  mftest::write_text(f, bytes);
  std::string digest = cache.store_object(f);
  std::string key = sha256_hex(canonical_json(preimage));
  json entry = {{"key", key},
                {"preimage", preimage},
                {"stage", "s"},
                {"workflow", "w"},
                {"log", {"a log line"}},
                {"outputs", {{{"name", "mesh"}, {"type", "t"}, {"digest", digest}, {"size", bytes.size()}}}},
                {"stats", {{"count", 3}}}};
  cache.write_action(key, entry);
  return entry;
}

size_t files_in(const fs::path& dir) {
  size_t n = 0;
  std::error_code ec;
  for (auto& e : fs::recursive_directory_iterator(dir, ec))
    if (e.is_regular_file()) ++n;
  return n;
}

}  // namespace

TEST_CASE("the HTTP client puts, gets and heads against a local server") {
  Server srv;
  http::Client c({});
  fs::path dir = mftest::temp_dir("remote-client");
  CHECK(c.put(srv.url() + "/ac/k1", "entry bytes").ok());
  CHECK(c.head(srv.url() + "/ac/k1").status == 200);
  CHECK(c.head(srv.url() + "/ac/k2").not_found());
  std::string body;
  CHECK(c.get(srv.url() + "/ac/k1", &body).ok());
  CHECK(body == "entry bytes");
  // A body larger than allowed is refused, not truncated silently.
  CHECK(!c.get(srv.url() + "/ac/k1", &body, 4).ok());

  // A 3 MB file (many chunks) round trip, GET written atomically.
  std::string big(3u << 20, '\0');
  for (size_t i = 0; i < big.size(); ++i) big[i] = char((i * 2654435761u) >> 13);
  mftest::write_text(dir / "big", big);
  auto put = c.put_file(srv.url() + "/cas/big", dir / "big");
  CHECK(put.ok());
  CHECK(put.bytes == big.size());
  fs::create_directories(dir / "tmp");
  auto got = c.get_to_file(srv.url() + "/cas/big", dir / "copy", dir / "tmp");
  CHECK(got.ok());
  CHECK(got.bytes == big.size());
  CHECK(mftest::read_text(dir / "copy") == big);
  // A 404 leaves neither the target nor a temp file.
  auto miss = c.get_to_file(srv.url() + "/cas/none", dir / "none", dir / "tmp");
  CHECK(miss.not_found());
  CHECK(!fs::exists(dir / "none"));
  CHECK(files_in(dir / "tmp") == 0);
}

TEST_CASE("credentials come from a netrc file or a header, never the URL") {
  fs::path dir = mftest::temp_dir("remote-creds");
  {
    Server srv({"--require-basic", "alice:s3cret"});
    CHECK(http::Client({}).put(srv.url() + "/ac/k", "x").status == 401);
    mftest::write_text(dir / "netrc", "machine 127.0.0.1 login alice password s3cret\n");
    http::ClientOptions o;
    o.netrc = dir / "netrc";
    CHECK(http::Client(o).put(srv.url() + "/ac/k", "x").ok());
  }
  {
    Server srv({"--require-header", "Authorization: Bearer t0ken"});
    CHECK(http::Client({}).head(srv.url() + "/ac/k").status == 401);
    http::ClientOptions o;
    o.header = "Authorization: Bearer t0ken";
    CHECK(http::Client(o).put(srv.url() + "/ac/k", "x").ok());
  }
  CHECK(http::check_url("http://127.0.0.1:8080/cache").empty());
  CHECK(http::check_url("HTTPS://cache.example.org").empty());
  CHECK(http::check_url("http://alice:pw@cache.example.org").find("netrc") != std::string::npos);
  CHECK(http::check_url("ftp://cache.example.org").find("http://") != std::string::npos);
  CHECK(http::check_url("cache.example.org:8080").find("http://") != std::string::npos);
  CHECK(!http::check_url("http://").empty());
  CHECK(!http::check_url("http://h/c?x=1").empty());

  CHECK_THROWS_AS(resolve_remote_cache("file:///tmp/cache", "", 5, 60), WorkflowError);
  CHECK_THROWS_AS(resolve_remote_cache("http://h", (dir / "no-netrc").string(), 5, 60), WorkflowError);
  CHECK_THROWS_AS(resolve_remote_cache("http://h", "", 5, 0), WorkflowError);
  ::setenv("MESHFLOW_REMOTE_CACHE_HEADER", "no colon here", 1);
  CHECK_THROWS_AS(resolve_remote_cache("http://h", "", 5, 60), WorkflowError);
  ::unsetenv("MESHFLOW_REMOTE_CACHE_HEADER");
  CHECK(resolve_remote_cache("http://h/c/", "", 5, 60).url == "http://h/c");
  ::setenv("MESHFLOW_REMOTE_CACHE", "http://from-env:1", 1);
  CHECK(resolve_remote_cache("", "", 5, 60).url == "http://from-env:1");
  ::unsetenv("MESHFLOW_REMOTE_CACHE");
  CHECK(resolve_remote_cache("", "", 5, 60).url.empty());
}

TEST_CASE("a server that never answers times out within the set timeout, a closed port fails at once") {
  Server hang({"--mode", "hang"});
  http::ClientOptions o;
  o.timeout_s = 1;
  http::Client c(o);
  auto t = Clock::now();
  auto r = c.head(hang.url() + "/ac/k");
  double s = since(t);
  CHECK(r.transport_failed());
  CHECK(s >= 0.9);
  CHECK(s < 3);

  auto t2 = Clock::now();
  auto r2 = http::Client({}).head("http://127.0.0.1:" + std::to_string(closed_port()) + "/ac/k");
  CHECK(r2.transport_failed());
  CHECK(since(t2) < 2);

  // The remote cache gives up on a hanging server after the first timeout: later stages do not wait.
  fs::path dir = mftest::temp_dir("remote-hang");
  Cache cache(dir / "cache");
  std::ostringstream err;
  RemoteCache rc(options(hang.url(), 1), cache, err);
  auto t3 = Clock::now();
  CHECK(!rc.fetch(std::string(64, 'a'), "one"));
  CHECK(!rc.fetch(std::string(64, 'b'), "two"));
  CHECK(since(t3) < 3);
  CHECK(rc.report()["warnings"].size() == 1);
  CHECK(err.str().find("local cache only") != std::string::npos);
}

TEST_CASE("an upload serves an empty cache, a corrupt object is discarded and replaced") {
  Server srv;
  fs::path dir = mftest::temp_dir("remote-roundtrip");
  Cache a(dir / "a");
  std::ostringstream err;
  const std::string bytes = "the bytes of a mesh artifact\n";
  json entry = store_result(a, bytes, {{"kind", "test"}, {"params", {{"n", 1}}}});
  const std::string key = entry["key"], digest = entry["outputs"][0]["digest"];
  {
    RemoteCache ra(options(srv.url()), a, err);
    ra.upload(key, entry, "s");
    CHECK(ra.report()["uploaded"] == 1);
    CHECK(ra.report()["bytes_up"].get<std::uint64_t>() >= bytes.size());
  }
  CHECK(mftest::read_text(srv.root / "cas" / digest) == bytes);
  json sent = json::parse(mftest::read_text(srv.root / "ac" / key));
  CHECK(!sent.contains("log"));  // what is sent: digests, preimage, stats; not the log or workflow name
  CHECK(!sent.contains("workflow"));
  CHECK(sent["stats"]["count"] == 3);

  Cache b(dir / "b");
  RemoteCache rb(options(srv.url()), b, err);
  CHECK(rb.fetch(key, "s"));
  CHECK(!rb.fetch(key, "s"));  // asked once per run
  auto got = b.load_action(key);
  REQUIRE(got);
  CHECK((*got)["outputs"] == entry["outputs"]);
  CHECK(mftest::read_text(b.object_path(digest)) == bytes);
  CHECK(rb.report()["served"] == 1);
  CHECK(rb.report()["warnings"].empty());

  // One byte changed on the server: discarded with a warning, nothing kept locally.
  std::string bad = bytes;
  bad[4] = 'X';
  mftest::write_text(srv.root / "cas" / digest, bad);
  Cache c(dir / "c");
  std::ostringstream cerr_;
  RemoteCache rc(options(srv.url()), c, cerr_);
  CHECK(!rc.fetch(key, "s"));
  CHECK(cerr_.str().find("does not match its digest") != std::string::npos);
  CHECK(!c.load_action(key));
  CHECK(files_in(dir / "c" / "objects") == 0);
  CHECK(files_in(dir / "c" / "tmp") == 0);
  CHECK(rc.report()["served"] == 0);
  // The stage recomputed here (same bytes) replaces the corrupt object on the server, although
  // the server already has a file under that name.
  json again = store_result(c, bytes, entry["preimage"]);
  rc.upload(key, again, "s");
  CHECK(mftest::read_text(srv.root / "cas" / digest) == bytes);
}

TEST_CASE("an entry that is not the key's, or names no SHA-256, is refused") {
  Server srv;
  fs::path dir = mftest::temp_dir("remote-entries");
  Cache a(dir / "a");
  json entry = store_result(a, "bytes", {{"kind", "test"}});
  const std::string key = entry["key"];
  std::ostringstream err;
  RemoteCache ra(options(srv.url()), a, err);
  ra.upload(key, entry, "s");
  json other = remote_entry(entry);
  // "" when `e` on the server is served to an empty cache, else the warning printed.
  auto try_entry = [&](const json& e) {
    mftest::write_text(srv.root / "ac" / key, e.dump());
    Cache fresh(mftest::temp_dir("remote-entries-b"));
    std::ostringstream e2;
    RemoteCache r(options(srv.url()), fresh, e2);
    if (r.fetch(key, "s")) return std::string();
    CHECK(files_in(fresh.root() / "actions") == 0);
    CHECK(!e2.str().empty());
    return e2.str();
  };
  CHECK(try_entry(other).empty());  // the genuine entry is served
  json wrong_pre = other;
  wrong_pre["preimage"]["kind"] = "other";
  CHECK(try_entry(wrong_pre).find("does not hash to its key") != std::string::npos);
  json traversal = other;
  traversal["outputs"][0]["digest"] = "../../../../etc/passwd";
  CHECK(try_entry(traversal).find("SHA-256") != std::string::npos);
  mftest::write_text(srv.root / "ac" / key, "{not json");
  Cache fresh(dir / "f");
  std::ostringstream e3;
  CHECK(!RemoteCache(options(srv.url()), fresh, e3).fetch(key, "s"));
  CHECK(e3.str().find("not JSON") != std::string::npos);
}

TEST_CASE("a server that refuses PUT (405) is one warning, uploads stop") {
  Server srv({"--mode", "no-put"});
  fs::path dir = mftest::temp_dir("remote-405");
  Cache a(dir / "a");
  json e1 = store_result(a, "one", {{"kind", "one"}});
  json e2 = store_result(a, "two", {{"kind", "two"}});
  std::ostringstream err;
  RemoteCache ra(options(srv.url()), a, err);
  ra.upload(e1["key"], e1, "one");
  ra.upload(e2["key"], e2, "two");
  CHECK(ra.report()["uploaded"] == 0);
  CHECK(ra.report()["warnings"].size() == 1);
  CHECK(err.str().find("HTTP 405") != std::string::npos);
  CHECK(!ra.fetch(e1["key"], "one"));  // reading still works: a miss, no warning
  CHECK(ra.report()["warnings"].size() == 1);
}
