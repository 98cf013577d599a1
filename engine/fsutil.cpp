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
#include <stdexcept>
#include <sys/stat.h>
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
