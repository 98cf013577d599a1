// The only translation unit that includes tetgen.h (TetGen 1.5, built with -DTETLIBRARY: on
// failure the library throws an int instead of calling exit()). No other foreign library here.
#include "stages/tet/tetgen_call.hpp"

#include <tetgen.h>

#include <cerrno>
#include <csignal>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <sys/wait.h>
#include <unistd.h>

namespace meshflow::tet::detail {
namespace {

const char* code_text(int code) {
  switch (code) {
    case 1: return "out of memory";
    case 2: return "internal error";
    case 3: return "self-intersecting input surface";
    case 4: return "input feature smaller than the tolerance";
    case 5: return "two input facets are too close";
    case 10: return "input error";
    default: return "failure";
  }
}

}  // namespace

const char* tetgen_version() { return "1.5.0"; }

namespace {

// The child's answer on the pipe: code (0 = success), counts, then the arrays.
bool write_all(int fd, const void* p, std::size_t n) {
  const char* c = static_cast<const char*>(p);
  while (n) {
    ssize_t w = ::write(fd, c, n);
    if (w < 0 && errno == EINTR) continue;
    if (w <= 0) return false;
    c += w, n -= static_cast<std::size_t>(w);
  }
  return true;
}

void fill_input(const Plc& plc, tetgenio& in) {
  in.firstnumber = 0;
  in.mesh_dim = 3;
  in.numberofpoints = static_cast<int>(plc.points.size() / 3);
  in.pointlist = new REAL[plc.points.size()];
  std::memcpy(in.pointlist, plc.points.data(), plc.points.size() * sizeof(double));
  if (!plc.point_size.empty()) {
    in.numberofpointmtrs = 1;
    in.pointmtrlist = new REAL[plc.point_size.size()];
    std::memcpy(in.pointmtrlist, plc.point_size.data(), plc.point_size.size() * sizeof(double));
  }
  int nf = static_cast<int>(plc.triangles.size() / 3);
  in.numberoffacets = nf;
  in.facetlist = new tetgenio::facet[nf];
  in.facetmarkerlist = new int[nf];
  for (int f = 0; f < nf; ++f) {
    tetgenio::facet& F = in.facetlist[f];
    tetgenio::init(&F);
    F.numberofpolygons = 1;
    F.polygonlist = new tetgenio::polygon[1];
    tetgenio::init(&F.polygonlist[0]);
    F.polygonlist[0].numberofvertices = 3;
    F.polygonlist[0].vertexlist = new int[3];
    for (int k = 0; k < 3; ++k) F.polygonlist[0].vertexlist[k] = static_cast<int>(plc.triangles[3 * f + k]);
    in.facetmarkerlist[f] = plc.markers[f];
  }
  if (!plc.holes.empty()) {
    in.numberofholes = static_cast<int>(plc.holes.size() / 3);
    in.holelist = new REAL[plc.holes.size()];
    std::memcpy(in.holelist, plc.holes.data(), plc.holes.size() * sizeof(double));
  }
}

// In the child: run TetGen, send the result (or the error code) on fd, exit.
[[noreturn]] void child(const Plc& plc, const std::string& switches, int fd, int out_fd) {
  // the parent's signal handlers (test frameworks, the engine) must not run in this child
  for (int sig : {SIGABRT, SIGSEGV, SIGBUS, SIGFPE, SIGILL, SIGTERM, SIGINT}) std::signal(sig, SIG_DFL);
  ::dup2(out_fd, 1);
  ::dup2(out_fd, 2);
  std::setvbuf(stdout, nullptr, _IONBF, 0);  // nothing lost if TetGen crashes
  tetgenio in, out;
  fill_input(plc, in);
  tetgenbehavior b;
  std::vector<char> sw(switches.begin(), switches.end());
  sw.push_back('\0');
  std::int64_t head[5] = {0, 0, 0, 0, 0};
  if (!b.parse_commandline(sw.data())) {
    head[0] = 10;
    write_all(fd, head, sizeof head);
    ::_exit(0);
  }
  try {
    tetrahedralize(&b, &in, &out);
  } catch (int code) {
    // (TetGen 1.5.0 frees its mesh twice when it throws: the child may die in the unwinding
    // before reaching this point; the parent then reads the code from TetGen's message.)
    head[0] = code;
    write_all(fd, head, sizeof head);
    ::_exit(0);
  }
  head[1] = out.numberofpoints;
  head[2] = out.numberoftetrahedra;
  head[3] = out.numberoftrifaces;
  head[4] = out.trifacemarkerlist != nullptr;
  bool ok = write_all(fd, head, sizeof head);
  ok = ok && write_all(fd, out.pointlist, sizeof(double) * 3 * static_cast<std::size_t>(out.numberofpoints));
  std::vector<std::uint32_t> t(4 * static_cast<std::size_t>(out.numberoftetrahedra));
  for (std::size_t i = 0; i < t.size(); ++i)
    t[i] = static_cast<std::uint32_t>(out.tetrahedronlist[(i / 4) * out.numberofcorners + i % 4] - out.firstnumber);
  ok = ok && write_all(fd, t.data(), t.size() * sizeof(std::uint32_t));
  std::vector<std::uint32_t> f(3 * static_cast<std::size_t>(out.numberoftrifaces));
  for (std::size_t i = 0; i < f.size(); ++i) f[i] = static_cast<std::uint32_t>(out.trifacelist[i] - out.firstnumber);
  ok = ok && write_all(fd, f.data(), f.size() * sizeof(std::uint32_t));
  if (head[4]) ok = ok && write_all(fd, out.trifacemarkerlist, sizeof(int) * static_cast<std::size_t>(out.numberoftrifaces));
  ::_exit(ok ? 0 : 3);
}

std::string read_text(std::FILE* f) {
  std::string s;
  std::rewind(f);
  char buf[4096];
  std::size_t n;
  while ((n = std::fread(buf, 1, sizeof buf, f)) > 0) s.append(buf, n);
  return s;
}

}  // namespace

// TetGen runs in a child process: it prints to stdout/stderr (captured into a temporary file
// and returned), and on bad input version 1.5.0 throws and then may crash while unwinding (a
// double free of its mesh): the parent survives it and still reports TetGen's message.
TetgenResult run_tetgen(const Plc& plc, const std::string& switches) {
  std::FILE* text = std::tmpfile();
  int fds[2];
  if (!text || ::pipe(fds) != 0) {
    if (text) std::fclose(text);
    throw TetgenFailure(1, "", "cannot create the pipe/temporary file to run TetGen");
  }
  std::fflush(stdout);
  std::fflush(stderr);
  pid_t pid = ::fork();
  if (pid < 0) {
    ::close(fds[0]), ::close(fds[1]), std::fclose(text);
    throw TetgenFailure(1, "", "cannot fork to run TetGen");
  }
  if (pid == 0) {
    ::close(fds[0]);
    child(plc, switches, fds[1], ::fileno(text));
  }
  ::close(fds[1]);
  std::string data;
  {
    char buf[1 << 16];
    for (;;) {
      ssize_t n = ::read(fds[0], buf, sizeof buf);
      if (n < 0 && errno == EINTR) continue;
      if (n <= 0) break;
      data.append(buf, static_cast<std::size_t>(n));
    }
  }
  ::close(fds[0]);
  int status = 0;
  while (::waitpid(pid, &status, 0) < 0 && errno == EINTR) {
  }
  std::string printed = read_text(text);
  std::fclose(text);

  std::int64_t head[5] = {-1, 0, 0, 0, 0};
  if (data.size() >= sizeof head) std::memcpy(head, data.data(), sizeof head);
  if (head[0] < 0) {  // no answer: the child died
    int code = printed.find("intersect") != std::string::npos ? 3
               : printed.find("very close") != std::string::npos ? 5
                                                                  : 2;
    std::string how = WIFSIGNALED(status) ? "signal " + std::to_string(WTERMSIG(status))
                                          : "exit status " + std::to_string(WEXITSTATUS(status));
    throw TetgenFailure(code, printed, std::string("TetGen: ") + code_text(code) + " (TetGen stopped with " + how + ")");
  }
  if (head[0] > 0) throw TetgenFailure(static_cast<int>(head[0]), printed, std::string("TetGen: ") + code_text(static_cast<int>(head[0])));
  std::size_t np = static_cast<std::size_t>(head[1]), nt = static_cast<std::size_t>(head[2]), nf = static_cast<std::size_t>(head[3]);
  std::size_t need = sizeof head + np * 3 * sizeof(double) + (4 * nt + 3 * nf) * sizeof(std::uint32_t) + (head[4] ? nf * sizeof(int) : 0);
  if (data.size() != need || !WIFEXITED(status) || WEXITSTATUS(status) != 0)
    throw TetgenFailure(2, printed, "TetGen: the result could not be transferred from the TetGen process");
  TetgenResult r;
  const char* p = data.data() + sizeof head;
  r.points.resize(3 * np);
  std::memcpy(r.points.data(), p, 3 * np * sizeof(double)), p += 3 * np * sizeof(double);
  r.tets.resize(4 * nt);
  std::memcpy(r.tets.data(), p, 4 * nt * sizeof(std::uint32_t)), p += 4 * nt * sizeof(std::uint32_t);
  r.faces.resize(3 * nf);
  std::memcpy(r.faces.data(), p, 3 * nf * sizeof(std::uint32_t)), p += 3 * nf * sizeof(std::uint32_t);
  if (head[4]) {
    r.face_markers.resize(nf);
    std::memcpy(r.face_markers.data(), p, nf * sizeof(int));
  }
  r.output = std::move(printed);
  return r;
}

}  // namespace meshflow::tet::detail
