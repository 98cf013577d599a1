// Benchmark of the mesh model (issue 3): on a 1-million-element P=4 tet mesh made here,
//   - validity + quality (Bezier det J bounds, scaled Jacobian, aspect ratio) in elements/s
//     on one core (mesh_quality with 1 thread), and the whole mesh_stats (adds topology,
//     conformity, histograms) on one core;
//   - binary MSH 4.1 write and read in MB/s (file in the temp directory);
//   - memory of the model per P=4 tet: the bytes its arrays hold, and the growth of the
//     process's resident set while the mesh is built;
//   - validity + quality of stretched boundary layers: the split tests' cylinder-on-plate
//     junction near field at P=4 split into 10 layers (ratio 1.5; prisms and hexes of aspect
//     ratio up to ~450), one thread.
// Writes bench/results/model.md. Usage: model_bench [cubes_per_side=56] (6 n^3 tets) [quality]
// (`quality`: only the validity + quality rate, printed; no results file).
#include "../tests/split/builders.hpp"
#include "stages/io/mesh_io.hpp"
#include "stages/split/split.hpp"
#include "stages/model/element.hpp"
#include "stages/model/mesh.hpp"
#include "stages/model/quality.hpp"

#include <nlohmann/json.hpp>

#include <time.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <sstream>
#include <string>

using namespace meshflow;
using namespace meshflow::model;
namespace fs = std::filesystem;

namespace {
double now() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}
double cpu_now() {  // CPU time of the process (all threads): the per-core figure on a shared machine
  timespec ts{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return ts.tv_sec + 1e-9 * ts.tv_nsec;
}
long status_kb(const char* key) {  // VmRSS / VmHWM of this process in kB
  std::ifstream in("/proc/self/status");
  std::string line;
  while (std::getline(in, line))
    if (line.rfind(key, 0) == 0) return std::atol(line.c_str() + std::strlen(key));
  return -1;
}
template <class V>
std::size_t bytes(const V& v) {
  return v.capacity() * sizeof(typename V::value_type);
}
std::size_t model_bytes(const Mesh& m) {
  std::size_t b = bytes(m.x) + bytes(m.y) + bytes(m.z) + bytes(m.node_entity_dim) + bytes(m.node_entity_tag) +
                  bytes(m.node_u) + bytes(m.node_v) + bytes(m.node_tags);
  for (auto& blk : m.blocks) b += bytes(blk.nodes) + bytes(blk.tags);
  return b;
}

// A cube [0,1]^3 of n^3 cells, each split into 6 Kuhn tets, P=4 nodes on the global lattice
// of spacing 1/(4n) (shared between elements), then curved by a smooth displacement.
Mesh make_mesh(int n) {
  const int P = 4, N = P * n + 1;
  Mesh m;
  const std::size_t nn = std::size_t(N) * N * N;
  m.x.resize(nn), m.y.resize(nn), m.z.resize(nn);
  for (int i = 0; i < N; ++i)
    for (int j = 0; j < N; ++j)
      for (int k = 0; k < N; ++k) {
        const std::size_t id = (std::size_t(i) * N + j) * N + k;
        const double x = double(i) / (N - 1), y = double(j) / (N - 1), z = double(k) / (N - 1);
        m.x[id] = x + 0.02 * std::sin(3 * y) * std::sin(2 * z);
        m.y[id] = y + 0.02 * std::sin(2 * x + z);
        m.z[id] = z + 0.015 * std::cos(3 * x) * y;
      }
  m.add_physical(3, 1, "fluid");
  m.add_entity(3, 1, {1});
  ElementBlock& b = m.block(Shape::Tet, P, 3, 1);
  const auto& lat = lattice(Shape::Tet, P);
  const int npe = num_nodes(Shape::Tet, P);
  b.nodes.reserve(std::size_t(6) * n * n * n * npe);
  const int perms[6][3] = {{0, 1, 2}, {0, 2, 1}, {1, 0, 2}, {1, 2, 0}, {2, 0, 1}, {2, 1, 0}};
  const bool odd[6] = {false, true, true, false, false, true};
  std::vector<std::uint32_t> el(npe);
  for (int ci = 0; ci < n; ++ci)
    for (int cj = 0; cj < n; ++cj)
      for (int ck = 0; ck < n; ++ck)
        for (int t = 0; t < 6; ++t) {
          std::array<std::array<int, 3>, 4> v;
          v[0] = {ci, cj, ck};
          for (int s = 1; s < 4; ++s) {
            v[s] = v[s - 1];
            v[s][perms[t][s - 1]] += 1;
          }
          if (odd[t]) std::swap(v[1], v[2]);  // positive orientation
          for (int q = 0; q < npe; ++q) {
            const auto& L = lat[q];
            const int a[4] = {P - L[0] - L[1] - L[2], L[0], L[1], L[2]};
            int f[3] = {0, 0, 0};
            for (int s = 0; s < 4; ++s)
              for (int r = 0; r < 3; ++r) f[r] += a[s] * v[s][r];
            el[q] = static_cast<std::uint32_t>((std::size_t(f[0]) * N + f[1]) * N + f[2]);
          }
          b.add(el.data());
        }
  return m;
}
}  // namespace

int main(int argc, char** argv) {
  const int n = argc > 1 ? std::atoi(argv[1]) : 56;
  const long rss0 = status_kb("VmRSS:");
  double t0 = now();
  Mesh m = make_mesh(n);
  const double t_make = now() - t0;
  const long rss1 = status_kb("VmRSS:");
  const std::size_t ne = m.num_elements();
  const double per_tet_model = double(model_bytes(m)) / ne;
  const double per_tet_rss = 1024.0 * (rss1 - rss0) / ne;
  std::cerr << "mesh: " << ne << " P=4 tets, " << m.num_nodes() << " nodes, made in " << t_make << " s\n";

  {  // build the cached Jacobian space of P=4 tets (one-time setup, not per-element work)
    const double t_setup0 = now();
    std::vector<double> X;
    for (auto& rn : reference_nodes(Shape::Tet, 4)) X.insert(X.end(), rn.begin(), rn.end());
    element_quality(Shape::Tet, 4, X.data());
    std::cerr << "one-time setup of the P=4 tet Bezier transform: " << now() - t_setup0 << " s\n";
  }
  t0 = now();
  double c0 = cpu_now();
  auto q = mesh_quality(m, 1);
  const double t_quality = now() - t0, c_quality = cpu_now() - c0;
  std::size_t invalid = 0, sampled = 0, inconclusive = 0;
  for (auto& e : q[0]) invalid += !e.valid, sampled += e.sampled, inconclusive += e.inconclusive;
  q.clear();
  q.shrink_to_fit();
  if (argc > 2 && std::string(argv[2]) == "quality") {  // quick profiling run: no stats, IO or results file
    std::cout << ne / c_quality << " elements per CPU second (" << c_quality << " s CPU, " << t_quality
              << " s wall), invalid " << invalid << ", inconclusive " << inconclusive << "\n";
    return invalid == 0 ? 0 : 1;
  }
  t0 = now();
  c0 = cpu_now();
  auto stats = mesh_stats(m, 1);
  const double t_stats = now() - t0, c_stats = cpu_now() - c0;
  std::cerr << "quality " << t_quality << " s, stats " << t_stats << " s, invalid " << invalid << "\n";

  const fs::path file = fs::temp_directory_path() / ("model_bench_" + std::to_string(::getpid()) + ".msh");
  t0 = now();
  io::write_msh(m, file, true);
  const double t_write = now() - t0;
  const double mb = fs::file_size(file) / 1e6;
  const long hwm_before_read = status_kb("VmHWM:");
  t0 = now();
  Mesh r = io::read_msh(file);
  const double t_read = now() - t0;
  const bool same = r.num_nodes() == m.num_nodes() && r.num_elements() == m.num_elements() &&
                    r.blocks[0].nodes == m.blocks[0].nodes && r.x == m.x;
  fs::remove(file);
  std::cerr << "write " << t_write << " s, read " << t_read << " s, " << mb << " MB, same " << same << "\n";

  // stretched boundary layers (split P=4 junction, as in bench/split_bench.cpp)
  double t_bl = 0, c_bl = 0, bl_ar = 0;
  std::size_t bl_n = 0, bl_prisms = 0, bl_hexes = 0, bl_bad = 0, bl_inc = 0, bl_sampled = 0;
  {
    auto J = splittest::junction_mesh(4, 150, false);
    split::Options so;
    so.layers = 10, so.ratio = 1.5, so.check_conformity = false;
    auto r = split::split_mesh(J.mesh, so, 1);
    mesh_quality(r.mesh, 1);  // one-time setup of the prism and hex spaces
    t0 = now();
    const double cb = cpu_now();
    auto bq = mesh_quality(r.mesh, 1);
    t_bl = now() - t0, c_bl = cpu_now() - cb;
    for (std::size_t bi = 0; bi < bq.size(); ++bi)
      for (auto& e : bq[bi]) {
        ++bl_n;
        (r.mesh.blocks[bi].shape == Shape::Prism ? bl_prisms : bl_hexes)++;
        bl_bad += !e.valid, bl_inc += e.inconclusive, bl_sampled += e.sampled;
        bl_ar = std::max(bl_ar, e.aspect_ratio);
      }
    std::cerr << "boundary layers: " << bl_n << " elements in " << t_bl << " s\n";
  }

  const double q_rate = ne / c_quality, s_rate = ne / c_stats, w_rate = mb / t_write, r_rate = mb / t_read;
  auto verdict = [](bool ok) { return ok ? "meets" : "**misses**"; };
  std::ostringstream o;
  o << "## Mesh model\n\n"
    << "Command: `build/bench/model_bench " << n << "` (the unit cube in " << n << "^3 cells x 6 Kuhn tets = " << ne
    << " P=4 tets, " << m.num_nodes() << " shared nodes, curved by a smooth displacement; one run; rates per CPU second of the "
    << "process, since this 2-core machine is shared and wall times vary by tens of percent).\n\n"
    << "| figure | value | target |\n|---|---|---|\n"
    << "| validity + quality, 1 thread (`mesh_quality`: Bezier det J bounds, scaled Jacobian, aspect ratio) | "
    << q_rate << " elements per CPU second (" << c_quality << " s CPU, " << t_quality << " s wall) | >= 100000 |\n"
    << "| whole `mesh_stats`, 1 thread (adds topology, conformity, histograms) | " << s_rate << " elements per CPU second ("
    << c_stats << " s CPU, " << t_stats << " s wall) | - |\n"
    << "| invalid / sampled / inconclusive elements | " << invalid << " / " << sampled << " / " << inconclusive
    << " | 0 / 0 / 0 |\n"
    << "| validity_method | " << stats["validity_method"].get<std::string>() << " | - |\n"
    << "| binary MSH 4.1 write | " << w_rate << " MB/s (" << mb << " MB in " << t_write << " s) | >= 200 |\n"
    << "| binary MSH 4.1 read (identical mesh back: " << (same ? "yes" : "NO") << ") | " << r_rate << " MB/s (" << t_read
    << " s) | >= 200 |\n"
    << "| model memory per P=4 tet (bytes held by the node and element arrays) | " << per_tet_model << " B | <= 1024 |\n"
    << "| growth of the resident set while building the mesh, per tet | " << per_tet_rss << " B | <= 1024 |\n"
    << "| validity + quality of stretched boundary layers, 1 thread: split P=4 junction, 10 layers (" << bl_prisms
    << " prisms + " << bl_hexes << " hexes, max aspect ratio " << bl_ar << "; invalid / inconclusive / sampled "
    << bl_bad << " / " << bl_inc << " / " << bl_sampled << ") | " << bl_n / c_bl << " elements per CPU second (" << c_bl
    << " s CPU, " << t_bl << " s wall) | - |\n"
    << "| peak resident set of the process (two meshes alive during the read) | " << hwm_before_read / 1024 << " MB before the read, "
    << status_kb("VmHWM:") / 1024 << " MB after | - |\n\n";
  o << "Validity + quality " << verdict(q_rate >= 1e5) << " its target; MSH write " << verdict(w_rate >= 200) << ", read "
    << verdict(r_rate >= 200) << " theirs; memory " << verdict(per_tet_model <= 1024 && per_tet_rss <= 1024) << " its target.\n";
  o << "\n"
       "What dominates (perf on mesh_quality, P=4 tets): most tets are proven valid by the perturbation "
       "proof (stages/model/quality.hpp: the Bernstein coefficients of J, 20 per entry, from one 20x20 "
       "transform; ||K J - I|| < 1 proves det J > 0), so they skip det J's Lagrange-to-Bezier transform "
       "(T V, 220x220: ~48k multiply-adds per tet), the subdivision and the rounding guard; what remains is "
       "Eigen's GEMM kernel (~50% of the time) for J at the 220 points of the degree-9 lattice (E Hs X: ~46k "
       "multiply-adds per tet), needed for the scaled Jacobian's min/max det J, then the proof itself and det "
       "J at the samples (~20%). Before the proof: 65.5k tets per CPU second (the GEMMs ~78% of the "
       "instructions). The chunk size matters: with 64 or 128 tets per chunk the products leave the L2 cache "
       "and run 2-2.5x slower. The build targets SSE2 (no -march); AVX2/FMA code for the products would "
       "give up to 2x more (a build decision for the whole project). MSH write: "
       "streamed in 8 MB blocks with binary rows formatted in place and entity bounding boxes computed per "
       "block (was: the whole 668 MB file formatted into one buffer, one map lookup per element node for the"
       " boxes; 188 MB/s). MSH read (perf): this virtual machine's page faults were most of the time; the "
       "file is now mapped (MAP_POPULATE) instead of read into a zero-filled string, node and element blocks "
       "are copied in bulk, node tags 1..n are indexed as tag - 1 (a lookup table of 11M nodes cost a cache "
       "miss per element node) and the new arrays are hinted for transparent huge pages (was 170-266 MB/s). "
       "Both MSH figures include the file system of this shared machine (/tmp on disk). "
       "Stretched boundary layers: prisms and hexes get J by sum factorisation (a P=4 hex: ~120k multiply-"
       "adds instead of 1.9M); the rounding bound is per element and per direction, so aspect ratios of 1000"
       " and more are proven, not sampled; before, this mesh took 12.5 s (2.2k elements/s). The peak "
       "resident set comes from mesh_stats (topology: face maps of 4.2 M faces) and the quality vectors, not"
       " from the model itself."
       "\n";
  std::cout << o.str();
  fs::create_directories(fs::path(MESHFLOW_SOURCE_DIR) / "bench/results");
  std::ofstream(fs::path(MESHFLOW_SOURCE_DIR) / "bench/results/model.md") << o.str();
  return same && invalid == 0 && bl_bad == 0 && bl_inc == 0 ? 0 : 1;
}
