#include "support.hpp"

#include "engine/cli.hpp"

#include <iostream>
#include <sstream>
#include <stdexcept>

#include <doctest/doctest.h>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <array>
#include <atomic>
#include <mutex>
#include <cctype>
#include <cstdio>
#include <fcntl.h>
#include <fstream>
#include <memory>
#include <random>
#include <sstream>
#include <sys/wait.h>
#include <unistd.h>

namespace mftest {

namespace {
std::mutex g_temp_mutex;
std::vector<fs::path> g_temp_dirs;  // made by temp_dir in this process
}  // namespace

void remove_temp_dirs() {
  std::lock_guard<std::mutex> lock(g_temp_mutex);
  for (const fs::path& p : g_temp_dirs) {
    std::error_code ec;
    fs::remove_all(p, ec);
  }
  g_temp_dirs.clear();
}

fs::path temp_dir(const std::string& tag) {
  static std::atomic<int> counter{0};
  static const unsigned salt = std::random_device{}();
  fs::path p = fs::temp_directory_path() /
               ("meshflow-test-" + tag + "-" + std::to_string(getpid()) + "-" + std::to_string(salt % 100000) + "-" +
                std::to_string(counter++));
  fs::remove_all(p);
  fs::create_directories(p);
  std::lock_guard<std::mutex> lock(g_temp_mutex);
  g_temp_dirs.push_back(p);
  return p;
}

void write_text(const fs::path& p, const std::string& text) {
  if (p.has_parent_path()) fs::create_directories(p.parent_path());
  std::ofstream(p, std::ios::binary) << text;
}

std::string read_text(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

int spawn(const std::vector<std::string>& args, const fs::path& log) {
  pid_t pid = fork();
  if (pid == 0) {
    int fd = open(log.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    dup2(fd, 1);
    dup2(fd, 2);
    std::vector<std::string> a = args;
    std::vector<char*> argv;
    for (auto& s : a) argv.push_back(s.data());
    argv.push_back(nullptr);
    execv(argv[0], argv.data());
    _exit(127);
  }
  return pid;
}

int wait_exit(int pid) {
  int st = 0;
  waitpid(pid, &st, 0);
  return WIFEXITED(st) ? WEXITSTATUS(st) : 128 + WTERMSIG(st);
}

ShellResult sh(const std::string& command) {
  std::string full = command + " 2>&1";
  FILE* p = popen(full.c_str(), "r");
  if (!p) return {127, "popen failed"};
  std::string out;
  std::array<char, 4096> buf;
  size_t n;
  while ((n = fread(buf.data(), 1, buf.size(), p)) > 0) out.append(buf.data(), n);
  int st = pclose(p);
  return {WIFEXITED(st) ? WEXITSTATUS(st) : 128, out};
}

int replay_corpus(const fs::path& dir, int (*entry)(const std::uint8_t*, std::size_t)) {
  std::vector<fs::path> files;
  for (auto& e : fs::directory_iterator(dir))
    if (e.is_regular_file()) files.push_back(e.path());
  std::sort(files.begin(), files.end());
  for (auto& f : files) {
    std::string data = read_text(f);
    INFO(f.string());
    CHECK_NOTHROW(CHECK(entry(reinterpret_cast<const std::uint8_t*>(data.data()), data.size()) == 0));
  }
  return int(files.size());
}

Cli run_cli(std::vector<std::string> args) {
  args.insert(args.begin(), "meshflow");
  std::vector<char*> argv;
  for (auto& s : args) argv.push_back(s.data());
  argv.push_back(nullptr);
  std::ostringstream out, err;
  auto* o = std::cout.rdbuf(out.rdbuf());
  auto* e = std::cerr.rdbuf(err.rdbuf());
  int code = meshflow::cli_main(int(args.size()), argv.data());
  std::cout.rdbuf(o);
  std::cerr.rdbuf(e);
  return {code, out.str(), err.str()};
}

nlohmann::json stage_stats(const nlohmann::json& report, const std::string& stage) {
  for (auto& s : report.at("stages"))
    if (s.value("name", "") == stage) return s.value("stats", nlohmann::json::object());
  return nlohmann::json::object();
}
nlohmann::json stage_stats(const fs::path& out, const std::string& stage) {
  return stage_stats(nlohmann::json::parse(read_text(out / "report.json")), stage);
}

std::string workflow_without(const fs::path& src, const fs::path& dst, const std::vector<std::string>& drop) {
  std::istringstream in(read_text(src));
  std::ostringstream out;
  std::string line;
  std::vector<int> found(drop.size(), 0);
  while (std::getline(in, line)) {
    bool skip = false;
    for (std::size_t k = 0; k < drop.size(); ++k)
      if (line.rfind("  " + drop[k] + ":", 0) == 0) skip = true, ++found[k];
    if (skip) continue;
    // a relative `file:` is relative to the workflow's folder: make it absolute for the copy
    auto at = line.find("file: ");
    while (at != std::string::npos && at > 0 && std::isalnum(static_cast<unsigned char>(line[at - 1])))  // not e.g. "profile: "
      at = line.find("file: ", at + 1);
    if (at != std::string::npos) {
      auto b = at + 6, e = line.find_first_of(",}", b);
      if (e == std::string::npos) e = line.size();
      std::string f = line.substr(b, e - b);
      if (!f.empty() && f[0] != '/') line.replace(b, e - b, (src.parent_path() / f).lexically_normal().string());
    }
    out << line << "\n";
  }
  for (std::size_t k = 0; k < drop.size(); ++k)
    if (found[k] != 1) throw std::runtime_error("workflow_without: '" + drop[k] + "' is not one entry of " + src.string());
  write_text(dst, out.str());
  return dst.string();
}

}  // namespace mftest
