// meshflow optimise — linearising what the untangler could not repair (method: linearise.hpp).
#include "stages/optimise/linearise.hpp"

#include "stages/model/basis.hpp"

#include <nlohmann/json.hpp>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <map>
#include <set>
#include <utility>
#include <vector>

namespace meshflow::optimise {
namespace {

using model::Mesh;
using model::Vec3;

struct Ref {
  std::uint32_t block = 0, element = 0;
  bool operator<(const Ref& o) const { return block != o.block ? block < o.block : element < o.element; }
  bool operator==(const Ref& o) const { return block == o.block && element == o.element; }
};

// Valid as the mesh contract counts it: proven, not merely not shown invalid.
bool proven_valid(const model::ElementQuality& q) { return q.valid && !q.inconclusive; }

constexpr double kBlends[] = {0.9, 0.75, 0.5, 0.25, 0.0};  // fraction of each node's curvature kept, tried in turn

// The mesh's elements of its highest dimension, the elements around each node, and what each
// node may do.
struct Index {
  int dim = 0;
  std::vector<std::uint32_t> blocks;                 // blocks of dimension dim
  std::vector<std::size_t> first;                    // CSR: node n's elements are refs[first[n] .. first[n+1])
  std::vector<Ref> refs;
  std::vector<char> on_cad, periodic;
};

Index index_mesh(const Mesh& m) {
  Index ix;
  for (const auto& b : m.blocks) ix.dim = std::max(ix.dim, model::dimension(b.shape));
  for (std::uint32_t bi = 0; bi < m.blocks.size(); ++bi)
    if (model::dimension(m.blocks[bi].shape) == ix.dim) ix.blocks.push_back(bi);
  const std::size_t nn = m.num_nodes();
  ix.first.assign(nn + 1, 0);
  for (std::uint32_t bi : ix.blocks)
    for (std::uint32_t n : m.blocks[bi].nodes) ++ix.first[n + 1];
  for (std::size_t n = 0; n < nn; ++n) ix.first[n + 1] += ix.first[n];
  ix.refs.resize(ix.first[nn]);
  std::vector<std::size_t> fill(ix.first.begin(), ix.first.end() - 1);
  for (std::uint32_t bi : ix.blocks) {
    const auto& b = m.blocks[bi];
    const int np = b.nodes_per_element();
    for (std::uint32_t e = 0; e < b.size(); ++e)
      for (int k = 0; k < np; ++k) ix.refs[fill[b.element(e)[k]]++] = {bi, e};
  }
  // a node is on the CAD when classified on a point, curve or face, or (unclassified meshes)
  // when a boundary element holds it
  ix.on_cad.assign(nn, 0);
  if (m.node_entity_dim.size() == nn) {
    for (std::size_t n = 0; n < nn; ++n) ix.on_cad[n] = m.node_entity_dim[n] >= 0 && m.node_entity_dim[n] < ix.dim;
  } else {
    for (const auto& b : m.blocks)
      if (model::dimension(b.shape) < ix.dim)
        for (std::uint32_t n : b.nodes) ix.on_cad[n] = 1;
  }
  ix.periodic.assign(nn, 0);
  for (const auto& l : m.periodic)
    for (const auto& [s, t] : l.nodes) ix.periodic[s] = ix.periodic[t] = 1;
  return ix;
}

std::vector<double> coordinates(const Mesh& m, const model::ElementBlock& b, std::uint32_t e) {
  const int np = b.nodes_per_element();
  std::vector<double> X(3 * np);
  for (int k = 0; k < np; ++k) {
    const std::uint32_t n = b.element(e)[k];
    X[3 * k] = m.x[n], X[3 * k + 1] = m.y[n], X[3 * k + 2] = m.z[n];
  }
  return X;
}

// The straight position of each high-order node of element e: its linear (vertex) map at the
// node's reference coordinates. Pairs (node, position) in the element's node order.
std::vector<std::pair<std::uint32_t, Vec3>> straight_nodes(const Mesh& m, const model::ElementBlock& b, std::uint32_t e) {
  const int nv = model::num_vertices(b.shape), np = b.nodes_per_element();
  std::vector<Vec3> vertices(nv);
  for (int a = 0; a < nv; ++a) {
    const std::uint32_t n = b.element(e)[a];
    vertices[a] = {m.x[n], m.y[n], m.z[n]};
  }
  const auto& ref = model::reference_nodes(b.shape, b.order);
  std::vector<std::pair<std::uint32_t, Vec3>> out;
  for (int k = nv; k < np; ++k) out.push_back({b.element(e)[k], model::map_linear(b.shape, vertices, ref[k])});
  return out;
}

double mean_vertex_edge(const Mesh& m, const model::ElementBlock& b, std::uint32_t e) {
  double sum = 0;
  const auto& edges = model::edge_vertices(b.shape);
  for (const auto& ed : edges) {
    const std::uint32_t p = b.element(e)[ed[0]], q = b.element(e)[ed[1]];
    sum += std::hypot(m.x[p] - m.x[q], m.y[p] - m.y[q], m.z[p] - m.z[q]);
  }
  return sum / double(edges.size());
}

// One invalid element's attempt: the region, its moved nodes and where they were.
class Region {
 public:
  Region(Mesh& m, const Index& ix, tbb::task_arena& arena) : m_(m), ix_(ix), arena_(arena) {}

  // Adds elements (sorted, unique); false with a reason when one cannot be linearised.
  bool add(const std::vector<Ref>& more, std::string& why) {
    for (const Ref& r : more) {
      if (!members_.insert(r).second) continue;
      const auto& b = m_.blocks[r.block];
      const auto sn = straight_nodes(m_, b, r.element);
      for (const auto& [n, xs] : sn) {
        if (ix_.periodic[n]) return why = "in a periodic pair", false;
        if (straight_.emplace(n, xs).second) before_.emplace(n, Vec3{m_.x[n], m_.y[n], m_.z[n]});
      }
      // the element made straight must be valid (the linear mesh's contract), or nothing here helps
      std::vector<double> X = coordinates(m_, b, r.element);
      const int nv = model::num_vertices(b.shape);
      for (std::size_t k = 0; k < sn.size(); ++k)
        for (int c = 0; c < 3; ++c) X[3 * (nv + k) + c] = sn[k].second[c];
      if (!proven_valid(model::element_quality(b.shape, b.order, X.data()))) return why = "straight element invalid", false;
    }
    return true;
  }
  std::size_t size() const { return members_.size(); }

  // Moves every node of the region to x_s + t (x_0 - x_s).
  void blend(double t) {
    for (const auto& [n, xs] : straight_) {
      const Vec3& x0 = before_.at(n);
      m_.x[n] = xs[0] + t * (x0[0] - xs[0]);
      m_.y[n] = xs[1] + t * (x0[1] - xs[1]);
      m_.z[n] = xs[2] + t * (x0[2] - xs[2]);
    }
  }
  // Puts every node of the region back exactly where it was.
  void restore() {
    for (const auto& [n, x0] : before_) m_.x[n] = x0[0], m_.y[n] = x0[1], m_.z[n] = x0[2];
  }

  // The elements with a moved node, sorted.
  std::vector<Ref> touched() const {
    std::vector<Ref> a;
    for (const auto& [n, xs] : straight_)
      for (std::size_t i = ix_.first[n]; i < ix_.first[n + 1]; ++i) a.push_back(ix_.refs[i]);
    std::sort(a.begin(), a.end());
    a.erase(std::unique(a.begin(), a.end()), a.end());
    return a;
  }

  std::vector<model::ElementQuality> quality(const std::vector<Ref>& a) const {
    std::vector<model::ElementQuality> q(a.size());
    arena_.execute([&] {
      tbb::parallel_for(std::size_t(0), a.size(), [&](std::size_t i) {
        const auto& b = m_.blocks[a[i].block];
        const std::vector<double> X = coordinates(m_, b, a[i].element);
        q[i] = model::element_quality(b.shape, b.order, X.data());
      });
    });
    return q;
  }

  // Figures of an accepted region into the report.
  void account(double t, double min_sj, double scale, LineariseReport& rep, std::vector<char>* moved) {
    ++rep.regions;
    rep.elements += members_.size();
    if (t == 0) rep.straight_elements += members_.size();
    rep.min_scaled_jacobian = std::min(rep.min_scaled_jacobian, min_sj);
    for (const auto& [n, xs] : straight_) {
      const Vec3& x0 = before_.at(n);
      const double d = std::hypot(m_.x[n] - x0[0], m_.y[n] - x0[1], m_.z[n] - x0[2]);
      if (d == 0) continue;
      ++rep.nodes_moved;
      if (moved) (*moved)[n] = 1;
      if (!ix_.on_cad[n]) continue;
      ++rep.cad_nodes_moved;
      if (!m_.node_u.empty()) m_.node_u[n] = std::numeric_limits<double>::quiet_NaN();
      if (!m_.node_v.empty()) m_.node_v[n] = std::numeric_limits<double>::quiet_NaN();
      rep.max_cad_move = std::max(rep.max_cad_move, d);
      if (scale > 0) rep.max_cad_move_relative = std::max(rep.max_cad_move_relative, d / scale);
    }
  }

 private:
  Mesh& m_;
  const Index& ix_;
  tbb::task_arena& arena_;
  std::set<Ref> members_;
  std::map<std::uint32_t, Vec3> straight_, before_;  // ordered: blends and sums in node order
};

struct Blend {
  double t = -1;  // < 0: none accepted
  double min_sj = -1;
};

// Tries the blends on the region and keeps one (t < 0: none, the region restored); when none is
// valid, the elements still invalid at t = 0 are returned in invalid_at_straight.
Blend try_blends(Region& R, const LineariseOptions& opt, std::vector<Ref>& invalid_at_straight, std::vector<Ref>& touched) {
  touched = R.touched();
  std::vector<Blend> valid;  // in the order of kBlends: most curvature first
  for (double t : kBlends) {
    R.blend(t);
    const auto q = R.quality(touched);
    if (!std::all_of(q.begin(), q.end(), proven_valid)) {
      if (t == 0)
        for (std::size_t i = 0; i < q.size(); ++i)
          if (!proven_valid(q[i])) invalid_at_straight.push_back(touched[i]);
      continue;
    }
    double sj = 1;
    for (const auto& e : q) sj = std::min(sj, e.scaled_jacobian);
    valid.push_back({t, sj});
  }
  if (valid.empty()) {
    R.restore();
    return {};
  }
  // the most curvature whose worst element is at the floor, or at half the best any blend gives
  // (the touched elements may be poor in the linear mesh already: the floor is then out of reach)
  double best = 0;
  for (const Blend& b : valid) best = std::max(best, b.min_sj);
  const double enough = std::min(opt.floor, 0.5 * best);
  Blend kept = valid.back();
  for (const Blend& b : valid)
    if (b.min_sj >= enough) {
      kept = b;
      break;
    }
  R.blend(kept.t);
  return kept;
}

}  // namespace

nlohmann::json LineariseReport::to_json() const {
  return {{"invalid", {{"before", invalid_before}, {"after", invalid_after}}},
          {"regions", regions},
          {"elements", elements},
          {"straight_elements", straight_elements},
          {"nodes_moved", nodes_moved},
          {"cad_nodes_moved", cad_nodes_moved},
          {"max_cad_move", max_cad_move},
          {"max_cad_move_relative", max_cad_move_relative},
          {"min_scaled_jacobian", elements ? nlohmann::json(min_scaled_jacobian) : nlohmann::json(nullptr)},
          {"unrepaired_by_reason", unrepaired_by_reason},
          {"seconds", seconds}};
}

LineariseReport linearise_invalid(Mesh& m, const LineariseOptions& opt, int threads, std::vector<char>* moved) {
  const auto t0 = std::chrono::steady_clock::now();
  LineariseReport rep;
  tbb::task_arena arena(threads > 0 ? threads : tbb::task_arena::automatic);
  const Index ix = index_mesh(m);
  std::vector<std::vector<char>> valid(m.blocks.size());
  std::vector<Ref> invalid;
  {
    // a quality that holds for every element as it is now is read as it is (the stage passes the
    // one it computed after untangling): copying it would cost a pass over the whole mesh
    const model::MeshQuality* given = opt.known_quality;
    bool whole = given && !opt.moved_since_known;
    for (std::uint32_t bi : ix.blocks) whole = whole && bi < given->size() && (*given)[bi].size() == m.blocks[bi].size();
    model::MeshQuality computed;
    if (!whole) computed = model::mesh_quality(m, threads, opt.known_quality, opt.moved_since_known);
    const model::MeshQuality& quality = whole ? *given : computed;
    for (std::uint32_t bi : ix.blocks) {
      valid[bi].assign(quality[bi].size(), 1);
      for (std::uint32_t e = 0; e < quality[bi].size(); ++e)
        if (!proven_valid(quality[bi][e])) valid[bi][e] = 0, invalid.push_back({bi, e});
    }
  }
  rep.invalid_before = invalid.size();
  if (moved) moved->assign(m.num_nodes(), 0);
  for (const Ref& start : invalid) {
    if (valid[start.block][start.element]) continue;  // a region before took it
    Region R(m, ix, arena);
    std::string why;
    std::vector<Ref> grow = {start};
    bool done = false;
    for (int round = 0; round <= opt.max_rounds && why.empty(); ++round) {
      if (!R.add(grow, why)) break;
      if (R.size() > opt.max_elements) {
        why = "region too large";
        break;
      }
      std::vector<Ref> bad, touched;
      const Blend b = try_blends(R, opt, bad, touched);
      if (b.t >= 0) {
        for (const Ref& r : touched) valid[r.block][r.element] = 1;
        R.account(b.t, b.min_sj, mean_vertex_edge(m, m.blocks[start.block], start.element), rep, moved);
        done = true;
        break;
      }
      grow = std::move(bad);
      if (round == opt.max_rounds) why = "region too large";
    }
    if (!done) {
      R.restore();
      ++rep.unrepaired_by_reason[why.empty() ? "region too large" : why];
    }
  }
  for (std::uint32_t bi : ix.blocks)
    for (char v : valid[bi]) rep.invalid_after += !v;
  rep.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return rep;
}

}  // namespace meshflow::optimise
