// Untangling of invalid curved elements by local volume optimisation (untangle.hpp).
// Libraries: LBFGSpp (L-BFGS), Eigen (its vectors), TBB only through model::mesh_quality.
#include "stages/optimise/untangle.hpp"

#include "stages/model/basis.hpp"
#include "stages/model/element.hpp"
#include "stages/model/quality.hpp"

#include <Eigen/Core>
#include <LBFGS.h>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cmath>
#include <map>
#include <mutex>
#include <tuple>
#include <numeric>
#include <stdexcept>
#include <utility>
#include <vector>

namespace meshflow::optimise {

using model::Mesh;
using model::Shape;

nlohmann::json UntangleReport::to_json() const {
  return {{"invalid", {{"before", invalid_before}, {"after", invalid_after}}},
          {"attempts", attempts},
          {"repaired", repaired},
          {"repaired_at_ring", repaired_at_ring},
          {"skipped_in_failed_patch", skipped},
          {"nodes_moved", nodes_moved},
          {"max_move_relative", max_move},
          {"unresolved", unresolved},
          {"seconds", seconds}};
}

namespace {

struct ElemRef {
  std::uint32_t block = 0;
  std::uint32_t index = 0;
  bool operator<(const ElemRef& o) const { return block != o.block ? block < o.block : index < o.index; }
  bool operator==(const ElemRef& o) const { return block == o.block && index == o.index; }
};

// Basis gradients at the sample points of one (shape, order): dN[(s * n + a) * 3 + c].
struct SampleTable {
  int n = 0, ns = 0;
  std::vector<double> dN;
};

// Sample lattice order: P + 2 (a P=4 tet: 84 points, prism: 28 x 7 = 196), and for a second
// attempt the degree of det J on simplices, 3 (P - 1) (a P=4 tet: 220 points), capped at the
// model's order limit. The samples only steer the optimisation; validity is decided by the
// Bezier bounds afterwards.
int sample_order(int P, bool dense) { return std::min(model::kMaxOrder, dense ? std::max(P + 2, 3 * (P - 1)) : P + 2); }

const SampleTable& samples(Shape s, int order, bool dense) {
  static std::mutex mutex;
  static std::map<std::tuple<int, int, bool>, SampleTable> cache;  // entries never move once made
  std::lock_guard<std::mutex> lock(mutex);
  auto key = std::make_tuple(int(s), order, dense);
  auto it = cache.find(key);
  if (it != cache.end()) return it->second;
  const auto& b = model::LagrangeBasis::get(s, order);
  const auto& pts = model::reference_nodes(s, sample_order(order, dense));
  SampleTable t;
  t.n = b.size();
  t.ns = int(pts.size());
  t.dN.resize(std::size_t(t.ns) * t.n * 3);
  for (int k = 0; k < t.ns; ++k) b.grad(pts[k], &t.dN[std::size_t(k) * t.n * 3]);
  return cache.emplace(key, std::move(t)).first->second;
}

double det3(const double J[9]) {
  return J[0] * (J[4] * J[8] - J[5] * J[7]) - J[1] * (J[3] * J[8] - J[5] * J[6]) + J[2] * (J[3] * J[7] - J[4] * J[6]);
}

// The patch problem: free nodes, objective elements, their straight reference det J.
struct Patch {
  const Mesh& m;
  std::vector<std::uint32_t> free;          // node indices
  std::map<std::uint32_t, int> free_index;  // node -> position in free
  std::vector<ElemRef> elems;               // elements with at least one free node
  std::vector<std::vector<int>> slots;      // per element and local node: position in free, or -1
  std::vector<double> jref;                 // straight det J per element
  std::vector<double> x0;                   // 3 * free.size()
  double h = 1, target = 0.2, spring = 1e-3;
  bool dense = false;  // sample lattice (sample_order)

  explicit Patch(const Mesh& mesh) : m(mesh) {}

  // Energy and gradient at y (variables (x - x0) / h).
  double operator()(const Eigen::VectorXd& y, Eigen::VectorXd& g) const {
    g.setZero(y.size());
    double E = 0;
    std::vector<double> X;
    for (std::size_t ie = 0; ie < elems.size(); ++ie) {
      const auto& b = m.blocks[elems[ie].block];
      const std::uint32_t* nodes = b.element(elems[ie].index);
      const auto& t = samples(b.shape, b.order, dense);
      const std::vector<int>& slot = slots[ie];
      X.resize(std::size_t(t.n) * 3);
      for (int a = 0; a < t.n; ++a) {
        if (slot[a] >= 0) {
          for (int c = 0; c < 3; ++c) X[3 * a + c] = x0[3 * slot[a] + c] + h * y[3 * slot[a] + c];
        } else {
          X[3 * a] = m.x[nodes[a]];
          X[3 * a + 1] = m.y[nodes[a]];
          X[3 * a + 2] = m.z[nodes[a]];
        }
      }
      const double w = 1.0 / t.ns;
      for (int s = 0; s < t.ns; ++s) {
        const double* dN = &t.dN[std::size_t(s) * t.n * 3];
        double J[9] = {0, 0, 0, 0, 0, 0, 0, 0, 0};
        for (int a = 0; a < t.n; ++a)
          for (int r = 0; r < 3; ++r)
            for (int c = 0; c < 3; ++c) J[3 * r + c] += X[3 * a + r] * dN[3 * a + c];
        const double r = det3(J) / jref[ie];
        if (r >= target) continue;
        const double d = target - r;
        E += w * d * d;
        // dE/dr = -2 w d; dr/dJ = cof(J) / jref
        const double k = -2 * w * d / jref[ie] * h;
        double C[9];
        C[0] = J[4] * J[8] - J[5] * J[7];
        C[1] = J[5] * J[6] - J[3] * J[8];
        C[2] = J[3] * J[7] - J[4] * J[6];
        C[3] = J[2] * J[7] - J[1] * J[8];
        C[4] = J[0] * J[8] - J[2] * J[6];
        C[5] = J[1] * J[6] - J[0] * J[7];
        C[6] = J[1] * J[5] - J[2] * J[4];
        C[7] = J[2] * J[3] - J[0] * J[5];
        C[8] = J[0] * J[4] - J[1] * J[3];
        for (int a = 0; a < t.n; ++a) {
          if (slot[a] < 0) continue;
          for (int r2 = 0; r2 < 3; ++r2) {
            double v = 0;
            for (int c = 0; c < 3; ++c) v += C[3 * r2 + c] * dN[3 * a + c];
            g[3 * slot[a] + r2] += k * v;
          }
        }
      }
    }
    for (Eigen::Index i = 0; i < y.size(); ++i) {
      E += spring * y[i] * y[i];
      g[i] += 2 * spring * y[i];
    }
    return E;
  }
};

}  // namespace

UntangleReport untangle(Mesh& m, const UntangleOptions& opt, int threads, const std::function<void(const std::string&)>& log) {
  const auto t0 = std::chrono::steady_clock::now();
  UntangleReport rep;
  rep.repaired_at_ring.assign(std::max(1, opt.max_rings), 0);
  const int dim = m.dimension();
  const std::size_t N = m.num_nodes();

  // node -> 3D elements (CSR), vertex flags, nodes of lower-dimensional elements and pyramids
  std::vector<char> fixed(N, 0);
  std::vector<std::uint32_t> start(N + 1, 0);
  for (std::uint32_t bi = 0; bi < m.blocks.size(); ++bi) {
    const auto& b = m.blocks[bi];
    const int n = b.nodes_per_element(), nv = model::num_vertices(b.shape);
    const bool vol = model::dimension(b.shape) == dim && dim == 3;
    for (std::size_t e = 0; e < b.size(); ++e) {
      const std::uint32_t* en = b.element(e);
      for (int a = 0; a < n; ++a) {
        if (!vol || a < nv || b.shape == Shape::Pyramid) fixed[en[a]] = 1;
        if (vol) ++start[en[a] + 1];
      }
    }
  }
  if (dim != 3) {
    rep.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    return rep;
  }
  if (!m.node_entity_dim.empty())
    for (std::size_t i = 0; i < N; ++i)
      if (m.node_entity_dim[i] >= 0 && m.node_entity_dim[i] < 3) fixed[i] = 1;
  for (std::size_t i = 0; i < N; ++i) start[i + 1] += start[i];
  std::vector<ElemRef> adj(start[N]);
  {
    std::vector<std::uint32_t> fill(start.begin(), start.end() - 1);
    for (std::uint32_t bi = 0; bi < m.blocks.size(); ++bi) {
      const auto& b = m.blocks[bi];
      if (model::dimension(b.shape) != 3) continue;
      const int n = b.nodes_per_element();
      for (std::uint32_t e = 0; e < b.size(); ++e)
        for (int a = 0; a < n; ++a) adj[fill[b.element(e)[a]]++] = {bi, e};
    }
  }

  auto quality = model::mesh_quality(m, threads);
  std::vector<std::vector<char>> valid(m.blocks.size());
  std::vector<ElemRef> invalid;
  for (std::uint32_t bi = 0; bi < m.blocks.size(); ++bi) {
    valid[bi].assign(quality[bi].size(), 1);
    for (std::uint32_t e = 0; e < quality[bi].size(); ++e)
      if (!quality[bi][e].valid) {
        valid[bi][e] = 0;
        invalid.push_back({bi, e});
      }
  }
  quality.clear();
  rep.invalid_before = invalid.size();

  auto element_X = [&](const ElemRef& r, std::vector<double>& X) {
    const auto& b = m.blocks[r.block];
    const int n = b.nodes_per_element();
    const std::uint32_t* en = b.element(r.index);
    X.resize(std::size_t(n) * 3);
    for (int a = 0; a < n; ++a) X[3 * a] = m.x[en[a]], X[3 * a + 1] = m.y[en[a]], X[3 * a + 2] = m.z[en[a]];
  };
  auto is_valid = [&](const ElemRef& r) {
    std::vector<double> X;
    element_X(r, X);
    const auto& b = m.blocks[r.block];
    return model::element_quality(b.shape, b.order, X.data()).valid;
  };
  // det J of the straight element (vertices only) at its reference centroid
  auto straight_det = [&](const ElemRef& r) {
    const auto& b = m.blocks[r.block];
    const int nv = model::num_vertices(b.shape);
    const std::uint32_t* en = b.element(r.index);
    std::vector<double> X(std::size_t(nv) * 3);
    for (int a = 0; a < nv; ++a) X[3 * a] = m.x[en[a]], X[3 * a + 1] = m.y[en[a]], X[3 * a + 2] = m.z[en[a]];
    const auto& lin = model::LagrangeBasis::get(b.shape, 1);
    const auto& ref = model::reference_nodes(b.shape, 1);
    model::Vec3 c{0, 0, 0};
    for (const auto& p : ref)
      for (int k = 0; k < 3; ++k) c[k] += p[k] / double(ref.size());
    double J[9];
    model::jacobian(lin, X.data(), c, J);
    return det3(J);
  };

  // Invalid elements inside the largest patch of an element that could not be repaired: their own
  // patches are nearly the same nodes and elements, so they are not tried again (an unrepairable
  // cluster, e.g. a folded face on the CAD, would otherwise cost max_rings attempts per member).
  std::vector<std::vector<char>> hopeless(m.blocks.size());
  for (std::uint32_t bi = 0; bi < m.blocks.size(); ++bi) hopeless[bi].assign(valid[bi].size(), 0);
  for (const ElemRef& bad : invalid) {
    if (valid[bad.block][bad.index]) continue;  // repaired with an earlier patch
    if (hopeless[bad.block][bad.index]) {
      ++rep.skipped;
      continue;
    }
    // element size h: mean vertex-edge length
    double h = 0;
    {
      const auto& b = m.blocks[bad.block];
      const std::uint32_t* en = b.element(bad.index);
      const auto& ev = model::edge_vertices(b.shape);
      for (auto [a, c] : ev)
        h += std::hypot(m.x[en[a]] - m.x[en[c]], m.y[en[a]] - m.y[en[c]], m.z[en[a]] - m.z[en[c]]);
      h /= double(ev.size());
    }
    if (!(h > 0)) continue;
    std::vector<ElemRef> patch{bad};
    bool done = false;
    for (int ring = 1; ring <= opt.max_rings && !done; ++ring) {
      // grow the patch by one ring of node neighbours
      {
        std::vector<ElemRef> grown = patch;
        for (const ElemRef& r : patch) {
          const auto& b = m.blocks[r.block];
          const std::uint32_t* en = b.element(r.index);
          for (int a = 0; a < b.nodes_per_element(); ++a)
            for (std::uint32_t k = start[en[a]]; k < start[en[a] + 1]; ++k) grown.push_back(adj[k]);
        }
        std::sort(grown.begin(), grown.end());
        grown.erase(std::unique(grown.begin(), grown.end()), grown.end());
        patch = std::move(grown);
      }
      Patch P(m);
      P.h = h;
      P.target = opt.target;
      P.spring = opt.spring;
      // free nodes: off the CAD, not a vertex, every element in the patch
      for (const ElemRef& r : patch) {
        const auto& b = m.blocks[r.block];
        const std::uint32_t* en = b.element(r.index);
        for (int a = 0; a < b.nodes_per_element(); ++a) {
          const std::uint32_t v = en[a];
          if (fixed[v] || P.free_index.count(v)) continue;
          bool inside = true;
          for (std::uint32_t k = start[v]; k < start[v + 1] && inside; ++k)
            inside = std::binary_search(patch.begin(), patch.end(), adj[k]);
          if (!inside) continue;
          P.free_index.emplace(v, 0);
        }
      }
      if (P.free_index.empty()) continue;
      int idx = 0;
      for (auto& [v, i] : P.free_index) {  // node order: deterministic
        i = idx++;
        P.free.push_back(v);
        P.x0.insert(P.x0.end(), {m.x[v], m.y[v], m.z[v]});
      }
      bool degenerate = false;
      for (const ElemRef& r : patch) {
        const auto& b = m.blocks[r.block];
        const std::uint32_t* en = b.element(r.index);
        std::vector<int> slot(b.nodes_per_element(), -1);
        bool has = false;
        for (int a = 0; a < b.nodes_per_element(); ++a) {
          auto f = P.free_index.find(en[a]);
          if (f != P.free_index.end()) slot[a] = f->second, has = true;
        }
        if (!has) continue;
        const double j = straight_det(r);
        if (!(j > 0)) degenerate = true;
        P.elems.push_back(r);
        P.slots.push_back(std::move(slot));
        P.jref.push_back(j);
      }
      if (degenerate) continue;  // a straight element is not valid: nothing to aim at
      // the target on the coarse samples first, then a higher one on the dense samples: samples
      // just above the target can leave det J negative between them, which the Bezier check finds
      for (int attempt = 0; attempt < 2 && !done; ++attempt) {
        P.target = attempt == 0 ? opt.target : std::max(opt.target, std::min(1.0, 2.5 * opt.target));
        P.dense = attempt == 1;
        ++rep.attempts;

        LBFGSpp::LBFGSParam<double> param;
        param.m = 8;
        param.epsilon = 1e-10;
        param.epsilon_rel = 0;
        param.max_iterations = opt.max_iterations;
        param.max_linesearch = 40;
        LBFGSpp::LBFGSSolver<double> solver(param);
        Eigen::VectorXd y = Eigen::VectorXd::Zero(Eigen::Index(P.free.size() * 3));
        double fx = 0;
        int iters = 0;
        const auto ta = std::chrono::steady_clock::now();
        try {
          iters = solver.minimize(P, y, fx);
        } catch (const std::exception&) {
          // a failed line search leaves y at the last accepted point, which is a descent of the energy
        }
        // a diverged line search can leave non-finite values: that attempt failed, nothing moves
        if (!y.allFinite()) continue;
        // apply, check, keep or restore
        for (std::size_t i = 0; i < P.free.size(); ++i) {
          const std::uint32_t v = P.free[i];
          m.x[v] = P.x0[3 * i] + h * y[Eigen::Index(3 * i)];
          m.y[v] = P.x0[3 * i + 1] + h * y[Eigen::Index(3 * i + 1)];
          m.z[v] = P.x0[3 * i + 2] + h * y[Eigen::Index(3 * i + 2)];
        }
        bool ok = true;
        std::vector<std::pair<ElemRef, char>> now;
        for (const ElemRef& r : P.elems) {
          const char v = is_valid(r) ? 1 : 0;
          now.push_back({r, v});
          if (valid[r.block][r.index] && !v) ok = false;
          if (r == bad && !v) ok = false;
        }
        if (log) {
          Eigen::VectorXd g0(y.size()), z0 = Eigen::VectorXd::Zero(y.size());
          char line[256];
          std::snprintf(line, sizeof line, "untangle: element %u/%u ring %d: %zu free nodes, %zu elements, energy %g -> %g, %d iterations, %.2f s: %s",
                        bad.block, bad.index, ring, P.free.size(), P.elems.size(), P(z0, g0), fx, iters,
                        std::chrono::duration<double>(std::chrono::steady_clock::now() - ta).count(), ok ? "repaired" : "not repaired");
          log(line);
          for (auto& [r, v] : now)
            if (!v) {
              std::snprintf(line, sizeof line, "untangle:   still invalid %u/%u (valid before: %d)", r.block, r.index, int(valid[r.block][r.index]));
              log(line);
            }
        }
        if (!ok) {
          for (std::size_t i = 0; i < P.free.size(); ++i) {
            const std::uint32_t v = P.free[i];
            m.x[v] = P.x0[3 * i];
            m.y[v] = P.x0[3 * i + 1];
            m.z[v] = P.x0[3 * i + 2];
          }
          continue;
        }
        for (auto& [r, v] : now) valid[r.block][r.index] = v;
        for (std::size_t i = 0; i < P.free.size(); ++i) {
          const double d = std::sqrt(y[Eigen::Index(3 * i)] * y[Eigen::Index(3 * i)] + y[Eigen::Index(3 * i + 1)] * y[Eigen::Index(3 * i + 1)] +
                                     y[Eigen::Index(3 * i + 2)] * y[Eigen::Index(3 * i + 2)]);
          if (d > 0) ++rep.nodes_moved;
          rep.max_move = std::max(rep.max_move, d);
        }
        ++rep.repaired;
        ++rep.repaired_at_ring[ring - 1];
        done = true;
      }
    }
    if (!done)
      for (const ElemRef& r : patch)
        if (!valid[r.block][r.index]) hopeless[r.block][r.index] = 1;
  }

  std::uint64_t running = 0;
  for (std::uint32_t bi = 0; bi < m.blocks.size(); ++bi) {
    const auto& b = m.blocks[bi];
    for (std::uint32_t e = 0; e < valid[bi].size(); ++e)
      if (!valid[bi][e]) {
        ++rep.invalid_after;
        if (rep.unresolved.size() < 100) rep.unresolved.push_back(b.tags.empty() ? running + e + 1 : b.tags[e]);
      }
    running += b.size();
  }
  rep.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return rep;
}

}  // namespace meshflow::optimise
