#include "engine/http.hpp"

#include "engine/fsutil.hpp"

#include <curl/curl.h>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <mutex>
#include <stdexcept>

namespace fs = std::filesystem;

namespace meshflow::http {

std::string Response::describe() const {
  if (!error.empty()) return error;
  return "HTTP " + std::to_string(status);
}

std::string check_url(const std::string& url) {
  std::string lower = url;
  std::transform(lower.begin(), lower.end(), lower.begin(), [](unsigned char c) { return char(std::tolower(c)); });
  if (lower.rfind("http://", 0) != 0 && lower.rfind("https://", 0) != 0)
    return "it must start with http:// or https:// (e.g. http://cache.example.org:8080/meshflow)";
  CURLU* u = curl_url();
  if (!u) return "out of memory while parsing it";
  std::string why;
  if (CURLUcode rc = curl_url_set(u, CURLUPART_URL, url.c_str(), 0); rc != CURLUE_OK) {
    why = std::string("it is not a valid URL (") + curl_url_strerror(rc) + ")";
  } else {
    auto part = [&](CURLUPart p) {
      char* s = nullptr;
      std::string v;
      if (curl_url_get(u, p, &s, 0) == CURLUE_OK && s) v = s;
      curl_free(s);
      return v;
    };
    if (part(CURLUPART_HOST).empty()) why = "it has no host";
    else if (!part(CURLUPART_USER).empty() || !part(CURLUPART_PASSWORD).empty())
      why = "it holds a user name or password: give credentials in a netrc file (--remote-netrc) or a header "
            "(MESHFLOW_REMOTE_CACHE_HEADER) instead, so they appear in no command line or report";
    else if (!part(CURLUPART_QUERY).empty() || !part(CURLUPART_FRAGMENT).empty())
      why = "it has a query or fragment (?... or #...): give the cache's base URL, under which cas/ and ac/ live";
  }
  curl_url_cleanup(u);
  return why;
}

namespace {
void global_init() {
  static std::once_flag once;
  std::call_once(once, [] { curl_global_init(CURL_GLOBAL_DEFAULT); });
}

size_t write_to_file(char* data, size_t size, size_t n, void* user) {
  return std::fwrite(data, size, n, static_cast<std::FILE*>(user)) * size;
}

struct StringSink {
  std::string* body;
  std::uint64_t max;
  bool overflow = false;
};
size_t write_to_string(char* data, size_t size, size_t n, void* user) {
  auto* s = static_cast<StringSink*>(user);
  if (s->body->size() + size * n > s->max) {
    s->overflow = true;
    return 0;  // curl stops with CURLE_WRITE_ERROR
  }
  s->body->append(data, size * n);
  return size * n;
}

struct ByteSource {
  std::string_view bytes;
  size_t at = 0;
};
size_t read_from_bytes(char* buf, size_t size, size_t n, void* user) {
  auto* s = static_cast<ByteSource*>(user);
  size_t k = std::min(size * n, s->bytes.size() - s->at);
  std::memcpy(buf, s->bytes.data() + s->at, k);
  s->at += k;
  return k;
}
}  // namespace

struct Client::Impl {
  ClientOptions options;
  CURL* curl = nullptr;
  curl_slist* headers = nullptr;
  char error[CURL_ERROR_SIZE] = {0};

  // Resets the handle (the connection stays open for the next request) to this request's URL,
  // timeouts, credentials and headers.
  void prepare(const std::string& url) {
    curl_easy_reset(curl);
    error[0] = 0;
    curl_easy_setopt(curl, CURLOPT_URL, url.c_str());
    curl_easy_setopt(curl, CURLOPT_PROTOCOLS_STR, "http,https");
    curl_easy_setopt(curl, CURLOPT_NOSIGNAL, 1L);  // timeouts without SIGALRM (stage threads, forks)
    curl_easy_setopt(curl, CURLOPT_CONNECTTIMEOUT_MS, long(options.connect_timeout_s * 1000));
    curl_easy_setopt(curl, CURLOPT_TIMEOUT_MS, long(options.timeout_s * 1000));
    curl_easy_setopt(curl, CURLOPT_ERRORBUFFER, error);
    curl_easy_setopt(curl, CURLOPT_USERAGENT, "meshflow/" MESHFLOW_VERSION);
    curl_easy_setopt(curl, CURLOPT_NETRC, long(CURL_NETRC_OPTIONAL));
    if (!options.netrc.empty()) curl_easy_setopt(curl, CURLOPT_NETRC_FILE, options.netrc.c_str());
    curl_easy_setopt(curl, CURLOPT_HTTPHEADER, headers);
  }

  Response perform() {
    Response r;
    CURLcode rc = curl_easy_perform(curl);
    curl_easy_getinfo(curl, CURLINFO_RESPONSE_CODE, &r.status);
    if (rc != CURLE_OK) r.error = error[0] ? std::string(error) : std::string(curl_easy_strerror(rc));
    curl_off_t n = 0;
    if (curl_easy_getinfo(curl, CURLINFO_SIZE_DOWNLOAD_T, &n) == CURLE_OK && n > 0) r.bytes = std::uint64_t(n);
    if (curl_easy_getinfo(curl, CURLINFO_SIZE_UPLOAD_T, &n) == CURLE_OK && n > 0) r.bytes = std::uint64_t(n);
    return r;
  }
};

Client::Client(ClientOptions options) : impl_(std::make_unique<Impl>()) {
  global_init();
  impl_->options = std::move(options);
  impl_->curl = curl_easy_init();
  if (!impl_->curl) throw std::runtime_error("cannot start libcurl (curl_easy_init failed)");
  if (!impl_->options.header.empty()) impl_->headers = curl_slist_append(impl_->headers, impl_->options.header.c_str());
  // No "Expect: 100-continue" round trip before large PUTs (a server that ignores it costs a second).
  impl_->headers = curl_slist_append(impl_->headers, "Expect:");
}

Client::~Client() {
  curl_slist_free_all(impl_->headers);
  curl_easy_cleanup(impl_->curl);
}

Response Client::get_to_file(const std::string& url, const fs::path& target, const fs::path& tmp_dir) {
  fs::path tmp = (tmp_dir.empty() ? target.parent_path() : tmp_dir) / ("." + target.filename().string() + ".tmp." + unique_suffix());
  std::FILE* f = std::fopen(tmp.c_str(), "wbx");
  if (!f) return {0, "cannot create '" + tmp.string() + "': " + std::strerror(errno), 0};
  impl_->prepare(url);
  curl_easy_setopt(impl_->curl, CURLOPT_FOLLOWLOCATION, 1L);
  curl_easy_setopt(impl_->curl, CURLOPT_MAXREDIRS, 5L);
  curl_easy_setopt(impl_->curl, CURLOPT_WRITEFUNCTION, write_to_file);
  curl_easy_setopt(impl_->curl, CURLOPT_WRITEDATA, f);
  Response r = impl_->perform();
  bool written = std::fflush(f) == 0 && !std::ferror(f);
  written = (std::fclose(f) == 0) && written;
  if (r.ok() && !written) r.error = "cannot write '" + tmp.string() + "'";
  if (r.ok() && ::rename(tmp.c_str(), target.c_str()) != 0) r.error = "cannot rename to '" + target.string() + "': " + std::strerror(errno);
  if (!r.ok()) ::unlink(tmp.c_str());
  return r;
}

Response Client::get(const std::string& url, std::string* body, std::uint64_t max_bytes) {
  body->clear();
  StringSink sink{body, max_bytes, false};
  impl_->prepare(url);
  curl_easy_setopt(impl_->curl, CURLOPT_FOLLOWLOCATION, 1L);
  curl_easy_setopt(impl_->curl, CURLOPT_MAXREDIRS, 5L);
  curl_easy_setopt(impl_->curl, CURLOPT_WRITEFUNCTION, write_to_string);
  curl_easy_setopt(impl_->curl, CURLOPT_WRITEDATA, &sink);
  Response r = impl_->perform();
  if (sink.overflow)
    r.error = "the answer is larger than " + std::to_string(max_bytes) + " bytes";
  return r;
}

Response Client::put_file(const std::string& url, const fs::path& source) {
  std::FILE* f = std::fopen(source.c_str(), "rb");
  if (!f) return {0, "cannot read '" + source.string() + "': " + std::strerror(errno), 0};
  std::error_code ec;
  auto size = fs::file_size(source, ec);
  impl_->prepare(url);
  curl_easy_setopt(impl_->curl, CURLOPT_UPLOAD, 1L);
  curl_easy_setopt(impl_->curl, CURLOPT_READDATA, f);
  curl_easy_setopt(impl_->curl, CURLOPT_INFILESIZE_LARGE, curl_off_t(ec ? 0 : size));
  std::string ignored;
  StringSink sink{&ignored, 1u << 20, false};
  curl_easy_setopt(impl_->curl, CURLOPT_WRITEFUNCTION, write_to_string);
  curl_easy_setopt(impl_->curl, CURLOPT_WRITEDATA, &sink);
  Response r = impl_->perform();
  std::fclose(f);
  return r;
}

Response Client::put(const std::string& url, std::string_view bytes) {
  ByteSource src{bytes, 0};
  impl_->prepare(url);
  curl_easy_setopt(impl_->curl, CURLOPT_UPLOAD, 1L);
  curl_easy_setopt(impl_->curl, CURLOPT_READFUNCTION, read_from_bytes);
  curl_easy_setopt(impl_->curl, CURLOPT_READDATA, &src);
  curl_easy_setopt(impl_->curl, CURLOPT_INFILESIZE_LARGE, curl_off_t(bytes.size()));
  std::string ignored;
  StringSink sink{&ignored, 1u << 20, false};
  curl_easy_setopt(impl_->curl, CURLOPT_WRITEFUNCTION, write_to_string);
  curl_easy_setopt(impl_->curl, CURLOPT_WRITEDATA, &sink);
  return impl_->perform();
}

Response Client::head(const std::string& url) {
  impl_->prepare(url);
  curl_easy_setopt(impl_->curl, CURLOPT_NOBODY, 1L);
  return impl_->perform();
}

}  // namespace meshflow::http
