// Internal: a bounds-checked cursor over a whole file in memory, for text and binary data.
// Errors name the file and the line (text) or the byte offset (binary).
#pragma once

#include "stages/io/mesh_io.hpp"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <fstream>
#include <functional>
#include <sstream>
#include <string>
#include <string_view>

#include <fcntl.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>

namespace meshflow::io::detail {

inline std::string slurp(const std::filesystem::path& p) {
  std::ifstream in(p, std::ios::binary);
  if (!in) throw MeshIOError(p.string() + ": cannot open the file for reading");
  // one read into a buffer of the file's size (a stringstream copies a 700 MB mesh twice)
  std::error_code ec;
  const auto size = std::filesystem::file_size(p, ec);
  if (!ec) {
    std::string s;
    s.resize(size);
    in.read(s.data(), static_cast<std::streamsize>(size));
    s.resize(static_cast<size_t>(in.gcount()));
    if (in.gcount() == static_cast<std::streamsize>(size)) return s;
    in.clear();
    in.seekg(0);
  }
  std::ostringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

// A whole file's bytes, mapped read-only (prefaulted: MAP_POPULATE) where it is a regular
// non-empty file, else read. Mapping skips the zero-filled buffer and the kernel's copy into it,
// which on this kind of virtual machine were most of a large binary MSH read's time.
class FileBytes {
 public:
  explicit FileBytes(const std::filesystem::path& p) {
    const int fd = ::open(p.c_str(), O_RDONLY | O_CLOEXEC);
    if (fd < 0) throw MeshIOError(p.string() + ": cannot open the file for reading");
    struct stat st {};
    if (::fstat(fd, &st) == 0 && S_ISREG(st.st_mode) && st.st_size > 0) {
      void* a = ::mmap(nullptr, static_cast<size_t>(st.st_size), PROT_READ, MAP_PRIVATE | MAP_POPULATE, fd, 0);
      if (a != MAP_FAILED) {
        map_ = a, size_ = static_cast<size_t>(st.st_size);
        ::close(fd);
        return;
      }
    }
    ::close(fd);
    copy_ = slurp(p);
  }
  ~FileBytes() {
    if (map_) ::munmap(map_, size_);
  }
  FileBytes(const FileBytes&) = delete;
  FileBytes& operator=(const FileBytes&) = delete;
  std::string_view view() const { return map_ ? std::string_view(static_cast<const char*>(map_), size_) : std::string_view(copy_); }
  // The mapped pages before byte `pos` (whole pages) are dropped from memory: a reader that has
  // parsed them holds the mesh, not the file as well (Rotor 67's 1.08 GB MSH read: 2.66 GB peak
  // RSS with the whole file resident). Reading them again faults them in from the file (a
  // private read-only mapping); a copied file keeps its bytes.
  void release_before(size_t pos) const {
    if (!map_) return;
    static const size_t page = static_cast<size_t>(::sysconf(_SC_PAGESIZE));
    const size_t end = std::min(pos, size_) / page * page;
    if (end <= released_) return;
    ::madvise(static_cast<char*>(map_) + released_, end - released_, MADV_DONTNEED);
    released_ = end;
  }

 private:
  void* map_ = nullptr;
  size_t size_ = 0;
  mutable size_t released_ = 0;
  std::string copy_;
};

class Cursor {
 public:
  Cursor(std::string path, std::string_view data) : path_(std::move(path)), d_(data) {}
  // Where the reader is done with the bytes before the current position (a section or block
  // parsed): `release` (FileBytes::release_before) may drop them from memory.
  void on_done(std::function<void(size_t)> release) { release_ = std::move(release); }
  void done_before_here() const { done_before(pos_); }
  void done_before(size_t p) const {
    if (release_) release_(p);
  }
  size_t pos() const { return pos_; }
  void seek(size_t p) { pos_ = p; }
  bool eof() const { return pos_ >= d_.size(); }
  std::string_view data() const { return d_; }

  size_t line_at(size_t p) const { return 1 + std::count(d_.begin(), d_.begin() + std::min(p, d_.size()), '\n'); }
  [[noreturn]] void fail(const std::string& what, bool binary = false, size_t at = std::string::npos) const {
    size_t p = at == std::string::npos ? pos_ : at;
    std::string where = binary ? "byte offset " + std::to_string(p) : "line " + std::to_string(line_at(p));
    throw MeshIOError(path_ + ":" + where + ": " + what);
  }
  void skip_ws() {
    while (pos_ < d_.size() && (d_[pos_] == ' ' || d_[pos_] == '\t' || d_[pos_] == '\n' || d_[pos_] == '\r')) ++pos_;
  }
  std::string_view token(const char* what) {
    skip_ws();
    if (pos_ >= d_.size()) fail(std::string("unexpected end of file while reading ") + what + " (truncated file?)");
    size_t b = pos_;
    while (pos_ < d_.size() && !std::isspace(static_cast<unsigned char>(d_[pos_]))) ++pos_;
    return d_.substr(b, pos_ - b);
  }
  template <class T>
  T integer(const char* what) {
    size_t at = (skip_ws(), pos_);
    auto t = token(what);
    T v{};
    auto r = std::from_chars(t.data(), t.data() + t.size(), v);
    if (r.ec != std::errc() || r.ptr != t.data() + t.size())
      fail(std::string("expected an integer for ") + what + ", found '" + std::string(t.substr(0, 40)) + "'", false, at);
    return v;
  }
  double real(const char* what) {
    size_t at = (skip_ws(), pos_);
    auto t = token(what);
    double v = 0;
    auto r = std::from_chars(t.data(), t.data() + t.size(), v);
    if (r.ec == std::errc::result_out_of_range) v = HUGE_VAL;
    else if (r.ec != std::errc() || r.ptr != t.data() + t.size())
      fail(std::string("expected a number for ") + what + ", found '" + std::string(t.substr(0, 40)) + "'", false, at);
    return v;
  }
  std::string line() {  // rest of the current line
    size_t b = pos_;
    while (pos_ < d_.size() && d_[pos_] != '\n') ++pos_;
    std::string s(d_.substr(b, pos_ - b));
    if (pos_ < d_.size()) ++pos_;
    if (!s.empty() && s.back() == '\r') s.pop_back();
    return s;
  }
  // Binary bulk reads: true when `bytes` more bytes are there (then `at()` points at them and
  // `skip` moves past), so fixed-size records can be copied without a check per value.
  bool has(size_t bytes) const { return pos_ <= d_.size() && d_.size() - pos_ >= bytes; }
  const char* at() const { return d_.data() + pos_; }
  void skip(size_t bytes) { pos_ += bytes; }
  template <class T>
  T bin(const char* what) {
    if (pos_ + sizeof(T) > d_.size())
      fail(std::string("unexpected end of file while reading ") + what + " (truncated file?)", true);
    T v;
    std::memcpy(&v, d_.data() + pos_, sizeof(T));
    pos_ += sizeof(T);
    return v;
  }
  void expect(std::string_view word) {
    size_t at = (skip_ws(), pos_);
    if (pos_ >= d_.size()) fail("unexpected end of file, expected '" + std::string(word) + "' (truncated file?)");
    auto t = token("section end");
    if (t != word) fail("expected '" + std::string(word) + "', found '" + std::string(t.substr(0, 40)) + "'", false, at);
  }

 private:
  std::string path_;
  std::string_view d_;
  size_t pos_ = 0;
  std::function<void(size_t)> release_;
};

}  // namespace meshflow::io::detail
