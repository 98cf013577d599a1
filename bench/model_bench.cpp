// Benchmark of the mesh model (issue 3): on a 1-million-element P=4 tet mesh made here,
//   - validity + quality (Bezier det J bounds, scaled Jacobian, aspect ratio) in elements/s
//     on one core (mesh_quality with 1 thread), and the whole mesh_stats (adds topology,
//     conformity, histograms) on one core;
//   - binary MSH 4.1 write and read in MB/s (file in the temp directory);
//   - memory of the model per P=4 tet: the bytes its arrays hold, and the growth of the
//     process's resident set while the mesh is built.
// Writes bench/results/model.md. Usage: model_bench [cubes_per_side=56] (6 n^3 tets).
#include "stages/io/mesh_io.hpp"
#include "stages/model/element.hpp"
#include "stages/model/mesh.hpp"
#include "stages/model/quality.hpp"

#include <nlohmann/json.hpp>

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
  auto q = mesh_quality(m, 1);
  const double t_quality = now() - t0;
  std::size_t invalid = 0, sampled = 0, inconclusive = 0;
  for (auto& e : q[0]) invalid += !e.valid, sampled += e.sampled, inconclusive += e.inconclusive;
  q.clear();
  q.shrink_to_fit();
  t0 = now();
  auto stats = mesh_stats(m, 1);
  const double t_stats = now() - t0;
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

  const double q_rate = ne / t_quality, s_rate = ne / t_stats, w_rate = mb / t_write, r_rate = mb / t_read;
  auto verdict = [](bool ok) { return ok ? "meets" : "**misses**"; };
  std::ostringstream o;
  o << "## Mesh model\n\n"
    << "Command: `build/bench/model_bench " << n << "` (the unit cube in " << n << "^3 cells x 6 Kuhn tets = " << ne
    << " P=4 tets, " << m.num_nodes() << " shared nodes, curved by a smooth displacement; one run; timings on this "
    << "shared 2-core machine vary by tens of percent).\n\n"
    << "| figure | value | target |\n|---|---|---|\n"
    << "| validity + quality, 1 thread (`mesh_quality`: Bezier det J bounds, scaled Jacobian, aspect ratio) | "
    << q_rate << " elements/s (" << t_quality << " s) | >= 100000 |\n"
    << "| whole `mesh_stats`, 1 thread (adds topology, conformity, histograms) | " << s_rate << " elements/s (" << t_stats
    << " s) | - |\n"
    << "| invalid / sampled / inconclusive elements | " << invalid << " / " << sampled << " / " << inconclusive
    << " | 0 / 0 / 0 |\n"
    << "| validity_method | " << stats["validity_method"].get<std::string>() << " | - |\n"
    << "| binary MSH 4.1 write | " << w_rate << " MB/s (" << mb << " MB in " << t_write << " s) | >= 200 |\n"
    << "| binary MSH 4.1 read (identical mesh back: " << (same ? "yes" : "NO") << ") | " << r_rate << " MB/s (" << t_read
    << " s) | >= 200 |\n"
    << "| model memory per P=4 tet (bytes held by the node and element arrays) | " << per_tet_model << " B | <= 1024 |\n"
    << "| growth of the resident set while building the mesh, per tet | " << per_tet_rss << " B | <= 1024 |\n"
    << "| peak resident set of the process (two meshes alive during the read) | " << hwm_before_read / 1024 << " MB before the read, "
    << status_kb("VmHWM:") / 1024 << " MB after | - |\n\n";
  o << "Validity + quality " << verdict(q_rate >= 1e5) << " its target; MSH write " << verdict(w_rate >= 200) << ", read "
    << verdict(r_rate >= 200) << " theirs; memory " << verdict(per_tet_model <= 1024 && per_tet_rss <= 1024) << " its target.\n";
  o << "\nWhat dominates (per P=4 tet, by operation count, consistent with the ~30 us measured): the det J "
       "samples at the 220 points of the degree-9 Bezier lattice (G X: 660x35 times 35x3, ~70 kflop) and the "
       "Lagrange-to-Bezier transform of the 220 values (220x220, ~97 kflop); everything else is small. What "
       "would reach 100k/s: skip the transform when the samples alone decide (straight/affine elements have a "
       "constant det J; far-field tets are straight), a float32 SIMD first pass with the rounding guard widened, "
       "or Bernstein arithmetic on the mapping's control points (det J coefficients as sums of products, no "
       "dense transform). MSH write (83 MB/s before this benchmark showed that write_msh copied the whole "
       "mesh to classify unclassified nodes; now classified into separate arrays, buffer reserved): it "
       "formats the whole file into one freshly allocated 668 MB buffer (page faults on first touch) and "
       "then writes it; formatting and writing in blocks of a few MB would overlap the two and avoid the "
       "faults. Both MSH figures include the file system of this shared machine (/tmp on disk). The peak "
       "resident set "
       "comes from mesh_stats (topology: face maps of "
       "4.2 M faces) and the quality vectors, not from the model itself.\n";
  std::cout << o.str();
  fs::create_directories(fs::path(MESHFLOW_SOURCE_DIR) / "bench/results");
  std::ofstream(fs::path(MESHFLOW_SOURCE_DIR) / "bench/results/model.md") << o.str();
  return same && invalid == 0 ? 0 : 1;
}
