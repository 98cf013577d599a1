#include "engine/fsutil.hpp"

#include <atomic>
#include <cctype>
#include <cerrno>
#include <cstring>
#include <fcntl.h>
#include <fstream>
#include <random>
#include <signal.h>
#include <sstream>
#include <vector>
#include <stdexcept>
#include <linux/fs.h>
#include <sys/ioctl.h>
#include <sys/stat.h>
#include <ctime>
#include <unistd.h>

namespace fs = std::filesystem;

namespace meshflow {

std::string unique_suffix() {
  static std::atomic<unsigned> counter{0};
  static const unsigned long long salt = std::random_device{}();
  std::ostringstream s;
  s << sanitized_hostname() << '_' << getpid() << '_' << counter++ << '_' << std::hex << (salt & 0xffffff);
  return s.str();
}

std::string sanitized_hostname() {
  std::string h = hostname();
  for (auto& c : h)
    if (!std::isalnum(static_cast<unsigned char>(c))) c = 'x';
  return h;
}

bool parse_owner(const std::string& name, std::string* host, long* pid) {
  // <host>_<pid>_<counter>_<random>[anything without '_']
  auto r3 = name.rfind('_');
  if (r3 == std::string::npos || r3 == 0) return false;
  auto r2 = name.rfind('_', r3 - 1);
  if (r2 == std::string::npos || r2 == 0) return false;
  auto r1 = name.rfind('_', r2 - 1);
  if (r1 == std::string::npos) return false;
  // the host part may be preceded by a prefix ending in '.' (e.g. "x.json.tmp.")
  std::string h = name.substr(0, r1);
  auto dot = h.rfind('.');
  if (dot != std::string::npos) h = h.substr(dot + 1);
  try {
    *pid = std::stol(name.substr(r1 + 1, r2 - r1 - 1));
  } catch (...) {
    return false;
  }
  *host = h;
  return true;
}

void atomic_write(const fs::path& target, std::string_view bytes, const fs::path& tmp_dir, bool durable) {
  fs::path tmp = tmp_dir.empty() ? target : tmp_dir / target.filename();
  tmp += ".tmp." + unique_suffix();
  int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0644);
  if (fd < 0) throw std::runtime_error("cannot create '" + tmp.string() + "': " + std::strerror(errno));
  const char* p = bytes.data();
  size_t left = bytes.size();
  while (left > 0) {
    ssize_t w = ::write(fd, p, left);
    if (w < 0) {
      if (errno == EINTR) continue;
      int e = errno;
      ::close(fd);
      ::unlink(tmp.c_str());
      throw std::runtime_error("cannot write '" + tmp.string() + "': " + std::strerror(e));
    }
    p += w;
    left -= size_t(w);
  }
  if ((durable && ::fsync(fd) != 0) || ::close(fd) != 0) {
    int e = errno;
    ::unlink(tmp.c_str());
    throw std::runtime_error("cannot write '" + tmp.string() + "': " + std::strerror(e));
  }
  if (::rename(tmp.c_str(), target.c_str()) != 0) {
    int e = errno;
    ::unlink(tmp.c_str());
    throw std::runtime_error("cannot rename to '" + target.string() + "': " + std::strerror(e));
  }
}

std::string read_file(const fs::path& file) {
  std::ifstream in(file, std::ios::binary);
  if (!in) throw std::runtime_error("cannot read '" + file.string() + "'");
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

namespace {
// Copies the rest of `in` to `out` (copy_file_range, then read/write where it is refused).
void copy_bytes(int in, int out, const fs::path& source, const fs::path& target) {
  while (true) {
    ssize_t n = ::copy_file_range(in, nullptr, out, nullptr, 1 << 30, 0);
    if (n == 0) return;
    if (n > 0) continue;
    if (errno == EINTR) continue;
    if (errno != EXDEV && errno != ENOSYS && errno != EINVAL && errno != EOPNOTSUPP)
      throw std::runtime_error("cannot copy '" + source.string() + "' to '" + target.string() + "': " + std::strerror(errno));
    break;
  }
  std::vector<char> buf(1 << 20);
  while (true) {
    ssize_t n = ::read(in, buf.data(), buf.size());
    if (n == 0) return;
    if (n < 0) {
      if (errno == EINTR) continue;
      throw std::runtime_error("cannot read '" + source.string() + "': " + std::strerror(errno));
    }
    for (ssize_t done = 0; done < n;) {
      ssize_t w = ::write(out, buf.data() + done, size_t(n - done));
      if (w < 0 && errno == EINTR) continue;
      if (w < 0) throw std::runtime_error("cannot write '" + target.string() + "': " + std::strerror(errno));
      done += w;
    }
  }
}
}  // namespace

void clone_or_copy(const fs::path& source, const fs::path& target) {
  int in = ::open(source.c_str(), O_RDONLY | O_CLOEXEC);
  if (in < 0) throw std::runtime_error("cannot read '" + source.string() + "': " + std::strerror(errno));
  int out = ::open(target.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0644);
  if (out < 0) {
    int e = errno;
    ::close(in);
    throw std::runtime_error("cannot create '" + target.string() + "': " + std::strerror(e));
  }
  try {
    if (::ioctl(out, FICLONE, in) != 0) copy_bytes(in, out, source, target);
    ::fchmod(out, 0644);
  } catch (...) {
    ::close(in);
    ::close(out);
    ::unlink(target.c_str());
    throw;
  }
  ::close(in);
  if (::close(out) != 0) {
    int e = errno;
    ::unlink(target.c_str());
    throw std::runtime_error("cannot write '" + target.string() + "': " + std::strerror(e));
  }
}

int remove_stale_tmp_files(const fs::path& dir) {
  int removed = 0;
  std::error_code ec;
  for (auto& e : fs::directory_iterator(dir, ec)) {
    std::string name = e.path().filename().string();
    auto at = name.find(".tmp.");
    if (at == std::string::npos || !e.is_regular_file(ec)) continue;
    std::string host;
    long pid = 0;
    if (!parse_owner(name.substr(at + 1), &host, &pid)) continue;  // not one of ours
    if (stale_debris(e.path(), name.substr(at + 1))) removed += fs::remove(e.path(), ec) ? 1 : 0;
  }
  return removed;
}

bool stale_debris(const fs::path& p, const std::string& owner_name) {
  std::string host;
  long pid = 0;
  if (parse_owner(owner_name, &host, &pid) && host == sanitized_hostname() && !process_alive(pid)) return true;
  struct stat st;
  return ::stat(p.c_str(), &st) == 0 && std::time(nullptr) - st.st_mtime > 86400;
}

bool writable_dir(const fs::path& dir, std::string* why) {
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec) {
    *why = "cannot create it: " + ec.message();
    return false;
  }
  if (!fs::is_directory(dir, ec)) {
    *why = "it is not a folder";
    return false;
  }
  fs::path probe = dir / (".write-probe.tmp." + unique_suffix());
  int fd = ::open(probe.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0644);
  if (fd < 0) {
    *why = std::string("cannot create a file in it: ") + std::strerror(errno);
    return false;
  }
  ::close(fd);
  ::unlink(probe.c_str());
  return true;
}

std::string hostname() {
  char buf[256] = {0};
  if (gethostname(buf, sizeof buf - 1) != 0) return "unknown";
  return buf;
}

bool process_alive(long pid) {
  if (pid <= 0) return false;
  if (::kill(pid_t(pid), 0) == 0) return true;
  return errno == EPERM;
}

}  // namespace meshflow
