// meshflow engine — a small HTTP client (libcurl) for the remote cache: GET to a file, GET of a
// small body, PUT from a file or bytes, HEAD. One connection is reused between requests.
// libcurl stays out of this header.
#pragma once

#include <cstdint>
#include <filesystem>
#include <memory>
#include <string>
#include <string_view>

namespace meshflow::http {

struct ClientOptions {
  double connect_timeout_s = 5;  // giving up on a server that does not accept the connection
  double timeout_s = 60;         // a whole request, transfer included
  // Credentials: a netrc file (curl's rules: `machine HOST login USER password PASS`); empty:
  // ~/.netrc when it exists. Never in the URL (check_url refuses user:password@).
  std::filesystem::path netrc;
  std::string header;  // an extra request header, "Name: value" (e.g. "Authorization: Bearer ..."); empty: none
};

struct Response {
  long status = 0;     // HTTP status; 0 when none arrived
  std::string error;   // transport failure (refused, timed out, DNS, TLS): curl's words; empty otherwise
  std::uint64_t bytes = 0;  // body bytes received (GET) or sent (PUT)
  bool ok() const { return error.empty() && status >= 200 && status < 300; }
  bool not_found() const { return error.empty() && status == 404; }
  bool transport_failed() const { return !error.empty(); }
  std::string describe() const;  // "HTTP 405" or the transport error
};

// An http:// or https:// URL with a host, no user or password, no query or fragment. Returns
// "" when it is one, else what is wrong with it (a sentence).
std::string check_url(const std::string& url);

class Client {
 public:
  explicit Client(ClientOptions options);
  ~Client();
  Client(const Client&) = delete;
  Client& operator=(const Client&) = delete;

  // GET into `target`, atomically: the body goes to a temp file in `tmp_dir` (target's folder
  // when empty) that is renamed to `target` only on a 2xx answer, else removed.
  Response get_to_file(const std::string& url, const std::filesystem::path& target,
                       const std::filesystem::path& tmp_dir = {});
  // GET of a small body (at most `max_bytes`; more is a transport error).
  Response get(const std::string& url, std::string* body, std::uint64_t max_bytes = 64u << 20);
  Response put_file(const std::string& url, const std::filesystem::path& source);
  Response put(const std::string& url, std::string_view bytes);
  Response head(const std::string& url);

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace meshflow::http
