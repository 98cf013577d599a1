// Tests of the untangler (stages/optimise/untangle.hpp) and of linearising what it cannot repair
// (stages/optimise/linearise.hpp) on a P=4 tetrahedral cube whose high-order nodes are pushed
// across their elements, as curving does next to a curved face.
#include <doctest/doctest.h>

#include "stages/model/element.hpp"
#include "stages/model/quality.hpp"
#include "stages/optimise/linearise.hpp"
#include "stages/optimise/untangle.hpp"

#include <nlohmann/json.hpp>

#include <cmath>
#include <map>
#include <tuple>

namespace model = meshflow::model;
using meshflow::model::Mesh;
using meshflow::model::Shape;

namespace {

// The unit cube in n^3 cells, 6 tets each (Kuhn), promoted to order P with straight nodes
// shared between elements; nodes on the cube's faces classified (2, 1), others (3, 1).
Mesh cube_tets(int n, int P) {
  Mesh m;
  std::vector<int> dims;
  std::map<std::tuple<long, long, long>, std::uint32_t> at;  // exact lattice key (n*P steps)
  const long S = long(n) * P;
  auto node = [&](long i, long j, long k) {
    auto key = std::make_tuple(i, j, k);
    auto it = at.find(key);
    if (it != at.end()) return it->second;
    std::uint32_t v = m.add_node(double(i) / S, double(j) / S, double(k) / S);
    bool bnd = i == 0 || j == 0 || k == 0 || i == S || j == S || k == S;
    dims.push_back(bnd ? 2 : 3);
    at.emplace(key, v);
    return v;
  };
  auto& b = m.block(Shape::Tet, P, 3, 1);
  const auto& ref = model::reference_nodes(Shape::Tet, P);
  // Kuhn subdivision: the 6 permutations of the axes, corner path 0 -> e_a -> e_a+e_b -> 1
  const int perms[6][3] = {{0, 1, 2}, {0, 2, 1}, {1, 0, 2}, {1, 2, 0}, {2, 0, 1}, {2, 1, 0}};
  for (int ci = 0; ci < n; ++ci)
    for (int cj = 0; cj < n; ++cj)
      for (int ck = 0; ck < n; ++ck)
        for (auto& p : perms) {
          std::array<std::array<long, 3>, 4> V;
          V[0] = {long(ci) * P, long(cj) * P, long(ck) * P};
          V[1] = V[0], V[1][p[0]] += P;
          V[2] = V[1], V[2][p[1]] += P;
          V[3] = V[2], V[3][p[2]] += P;
          // orientation: positive volume
          auto d = [&](int a, int c) { return V[a][c] - V[0][c]; };
          long det = d(1, 0) * (d(2, 1) * d(3, 2) - d(2, 2) * d(3, 1)) - d(1, 1) * (d(2, 0) * d(3, 2) - d(2, 2) * d(3, 0)) +
                     d(1, 2) * (d(2, 0) * d(3, 1) - d(2, 1) * d(3, 0));
          if (det < 0) std::swap(V[1], V[2]);
          std::vector<std::uint32_t> en;
          for (const auto& r : ref) {
            // reference tet (0,0,0),(1,0,0),(0,1,0),(0,0,1): x = V0 + r0 (V1-V0) + r1 (V2-V0) + r2 (V3-V0)
            long q[3];
            for (int c = 0; c < 3; ++c) {
              double x = V[0][c] + r[0] * (V[1][c] - V[0][c]) + r[1] * (V[2][c] - V[0][c]) + r[2] * (V[3][c] - V[0][c]);
              q[c] = std::lround(x);
            }
            en.push_back(node(q[0], q[1], q[2]));
          }
          b.add(en.data());
        }
  m.node_entity_dim = dims;
  m.node_entity_tag.assign(dims.size(), 1);
  return m;
}

std::size_t invalid(const Mesh& m) {
  std::size_t k = 0;
  for (auto& qb : model::mesh_quality(m, 1))
    for (auto& q : qb) k += !q.valid;
  return k;
}

// Pushes the middle node of local edge `e` of element `el` towards and past the opposite edge's
// midpoint by `f` of the distance (f > 1: across the element).
void push_edge_node(Mesh& m, std::size_t el, int edge, double f) {
  const auto& b = m.blocks[0];
  const std::uint32_t* en = b.element(el);
  const auto& nodes = model::edge_nodes(Shape::Tet, b.order);
  std::uint32_t v = en[nodes[edge][2 + (b.order - 1) / 2]];  // middle interior node of the edge
  auto ev = model::edge_vertices(Shape::Tet)[edge];
  int o[2], k = 0;
  for (int i = 0; i < 4; ++i)
    if (i != ev[0] && i != ev[1]) o[k++] = i;
  double tx = 0.5 * (m.x[en[o[0]]] + m.x[en[o[1]]]), ty = 0.5 * (m.y[en[o[0]]] + m.y[en[o[1]]]), tz = 0.5 * (m.z[en[o[0]]] + m.z[en[o[1]]]);
  m.x[v] += f * (tx - m.x[v]), m.y[v] += f * (ty - m.y[v]), m.z[v] += f * (tz - m.z[v]);
}

}  // namespace

TEST_CASE("untangle: interior high-order nodes pushed across their tets are repaired, nothing on the boundary or at a vertex moves") {
  Mesh m = cube_tets(3, 4);
  REQUIRE(invalid(m) == 0);
  // an interior tet: one whose vertices are all interior or whose edge 0 is interior
  std::size_t el = SIZE_MAX;
  int edge = -1;
  const auto& b = m.blocks[0];
  for (std::size_t e = 0; e < b.size() && el == SIZE_MAX; ++e)
    for (int k = 0; k < 6; ++k) {
      std::uint32_t v = b.element(e)[model::edge_nodes(Shape::Tet, 4)[k][3]];
      if (m.node_entity_dim[v] == 3) {
        el = e, edge = k;
        break;
      }
    }
  REQUIRE(el != SIZE_MAX);
  push_edge_node(m, el, edge, 1.6);
  const std::size_t bad = invalid(m);
  REQUIRE(bad > 0);
  Mesh before = m;
  auto rep = meshflow::optimise::untangle(m, {}, 1);
  MESSAGE("untangle: " << rep.invalid_before << " -> " << rep.invalid_after << " invalid, " << rep.nodes_moved
                       << " nodes moved, attempts " << rep.attempts);
  CHECK(rep.invalid_before == bad);
  CHECK(rep.invalid_after == 0);
  CHECK(invalid(m) == 0);
  CHECK(rep.nodes_moved > 0);
  // vertices and boundary nodes did not move
  std::vector<char> vertex(m.num_nodes(), 0);
  for (std::size_t e = 0; e < b.size(); ++e)
    for (int a = 0; a < 4; ++a) vertex[b.element(e)[a]] = 1;
  for (std::size_t i = 0; i < m.num_nodes(); ++i)
    if (vertex[i] || m.node_entity_dim[i] != 3) {
      CHECK(m.x[i] == before.x[i]);
      CHECK(m.y[i] == before.y[i]);
      CHECK(m.z[i] == before.z[i]);
    }
}

TEST_CASE("untangle: an element inverted by a node on the boundary cannot be repaired, it is reported and the mesh is left exactly as it was") {
  Mesh m = cube_tets(2, 4);
  const auto& b = m.blocks[0];
  // a boundary face node pushed deep inside its tet and beyond: the only nodes that could
  // compensate are fixed (boundary) or vertices
  std::size_t el = SIZE_MAX;
  int edge = -1;
  for (std::size_t e = 0; e < b.size() && el == SIZE_MAX; ++e)
    for (int k = 0; k < 6; ++k) {
      const auto& en = model::edge_nodes(Shape::Tet, 4)[k];
      std::uint32_t v = b.element(e)[en[3]];
      if (m.node_entity_dim[v] == 2 && m.node_entity_dim[b.element(e)[en[2]]] == 2 && m.node_entity_dim[b.element(e)[en[4]]] == 2) {
        el = e, edge = k;
        break;
      }
    }
  REQUIRE(el != SIZE_MAX);
  push_edge_node(m, el, edge, 3.0);
  REQUIRE(invalid(m) > 0);
  Mesh before = m;
  auto rep = meshflow::optimise::untangle(m, {}, 1);
  MESSAGE("untangle: " << rep.invalid_before << " -> " << rep.invalid_after);
  CHECK(rep.invalid_after > 0);
  CHECK(rep.unrepaired.size() == std::min<std::size_t>(rep.invalid_after, 20));
  CHECK(rep.unrepaired_by_reason.size() >= 1);
  CHECK(!rep.advice().empty());
  CHECK(invalid(m) == rep.invalid_after);
  CHECK(rep.invalid_after <= rep.invalid_before);  // never worse
}

TEST_CASE("untangle: the same result at 1 and 2 threads, and nothing to do on a valid mesh") {
  Mesh a = cube_tets(2, 3);
  Mesh v = a;
  auto r0 = meshflow::optimise::untangle(v, {}, 2);
  CHECK(r0.invalid_before == 0);
  CHECK(r0.attempts == 0);
  CHECK(v.x == a.x);
  // push an interior node (order 3: the edge's first interior node)
  const auto& b = a.blocks[0];
  bool pushed = false;
  for (std::size_t e = 0; e < b.size() && !pushed; ++e)
    for (int k = 0; k < 6 && !pushed; ++k) {
      std::uint32_t nd = b.element(e)[model::edge_nodes(Shape::Tet, 3)[k][2]];
      if (a.node_entity_dim[nd] == 3) push_edge_node(a, e, k, 1.8), pushed = true;
    }
  REQUIRE(pushed);
  Mesh c = a;
  auto r1 = meshflow::optimise::untangle(a, {}, 1);
  auto r2 = meshflow::optimise::untangle(c, {}, 2);
  CHECK(r1.invalid_before > 0);
  CHECK(r1.invalid_after == r2.invalid_after);
  CHECK(a.x == c.x);
  CHECK(a.y == c.y);
  CHECK(a.z == c.z);
}

namespace {

// A P=4 cube whose boundary face node is pushed across its tet (as in the test above): the
// element cannot be repaired (the nodes that could compensate are on the boundary, fixed).
// Returns the mesh and the pushed element's index.
std::pair<Mesh, std::size_t> impossible_cube(int n) {
  Mesh m = cube_tets(n, 4);
  const auto& b = m.blocks[0];
  for (std::size_t e = 0; e < b.size(); ++e)
    for (int k = 0; k < 6; ++k) {
      const auto& en = model::edge_nodes(Shape::Tet, 4)[k];
      if (m.node_entity_dim[b.element(e)[en[3]]] == 2 && m.node_entity_dim[b.element(e)[en[2]]] == 2 &&
          m.node_entity_dim[b.element(e)[en[4]]] == 2) {
        push_edge_node(m, e, k, 3.0);
        return {m, e};
      }
    }
  return {m, SIZE_MAX};
}

}  // namespace

TEST_CASE("untangle budget: an element that cannot be repaired is given up on its element budget, in bounded work, and listed with where it is and why") {
  auto [m0, el] = impossible_cube(2);
  REQUIRE(el != SIZE_MAX);
  REQUIRE(invalid(m0) > 0);
  // unlimited: what it costs to try everything
  meshflow::optimise::UntangleOptions uo;
  uo.element_budget = 0, uo.stage_budget = 0;
  Mesh full = m0;
  auto rf = meshflow::optimise::untangle(full, uo, 1);
  MESSAGE("unlimited: " << rf.invalid_before << " -> " << rf.invalid_after << ", work " << rf.work << " samples, most for one element "
                        << rf.max_element_work << ", " << rf.seconds << " s");
  REQUIRE(rf.invalid_after > 0);
  REQUIRE(rf.budget_exhausted == 0);
  // a tenth of that per element: given up on its budget
  uo.element_budget = 0.1 * rf.max_element_work;
  Mesh m = m0;
  auto r = meshflow::optimise::untangle(m, uo, 1);
  MESSAGE("budget " << uo.element_budget << ": " << r.invalid_before << " -> " << r.invalid_after << ", work " << r.work << ", "
                    << r.seconds << " s; advice: " << r.advice());
  CHECK(r.budget_exhausted >= 1);
  CHECK(r.max_element_work <= uo.element_budget);
  CHECK(r.work < rf.work);
  CHECK(r.invalid_after == invalid(m));
  CHECK(r.unrepaired_by_reason["budget"] >= 1);
  // the pushed element is listed, with its tag (1-based index: the block has no tags) and its centroid
  const std::uint32_t* en = m.blocks[0].element(el);
  double c[3] = {0, 0, 0};
  for (int a = 0; a < 4; ++a) c[0] += m.x[en[a]] / 4, c[1] += m.y[en[a]] / 4, c[2] += m.z[en[a]] / 4;
  bool listed = false;
  for (const auto& u : r.unrepaired)
    if (u.tag == el + 1) {
      listed = true;
      CHECK(u.reason == "budget");
      CHECK(std::hypot(u.centroid[0] - c[0], u.centroid[1] - c[1], u.centroid[2] - c[2]) < 1e-12);
    }
  CHECK(listed);
  CHECK(r.unrepaired.size() == std::min<std::size_t>(r.invalid_after, uo.max_listed));
  CHECK(r.advice().find("untangle_element_budget") != std::string::npos);
  CHECK(!r.time_limit_fired);
  // deterministic: a work count, not a time, so the same result at 2 threads
  Mesh m2 = m0;
  auto r2 = meshflow::optimise::untangle(m2, uo, 2);
  CHECK(r2.work == r.work);
  CHECK(m2.x == m.x);
  CHECK(m2.y == m.y);
  CHECK(m2.z == m.z);
}

TEST_CASE("untangle budget: the no-progress budget and the time limit stop the untangling, the rest is reported as not tried") {
  // several separate unrepairable elements: each boundary edge node of a 3x3x3 cube's bottom face pushed
  Mesh m0 = cube_tets(3, 4);
  const auto& b = m0.blocks[0];
  std::vector<char> used(m0.num_nodes(), 0);
  int pushed = 0;
  for (std::size_t e = 0; e < b.size() && pushed < 4; ++e)
    for (int k = 0; k < 6; ++k) {
      const auto& en = model::edge_nodes(Shape::Tet, 4)[k];
      const std::uint32_t v = b.element(e)[en[3]];
      if (m0.node_entity_dim[v] == 2 && m0.node_entity_dim[b.element(e)[en[2]]] == 2 && m0.node_entity_dim[b.element(e)[en[4]]] == 2 &&
          !used[b.element(e)[0]] && !used[b.element(e)[1]] && !used[b.element(e)[2]] && !used[b.element(e)[3]]) {
        for (int a = 0; a < 4; ++a) used[b.element(e)[a]] = 1;
        push_edge_node(m0, e, k, 3.0);
        ++pushed;
        break;
      }
    }
  REQUIRE(pushed >= 2);
  const std::size_t bad = invalid(m0);
  meshflow::optimise::UntangleOptions uo;
  uo.max_rings = 1;
  uo.element_budget = 0, uo.stage_budget = 0;
  Mesh full = m0;
  auto rf = meshflow::optimise::untangle(full, uo, 1);
  REQUIRE(rf.invalid_after > 1);
  // nothing can be repaired: a no-progress budget of half the work stops it, and says so
  uo.stage_budget = 0.5 * rf.work;
  Mesh m = m0;
  auto r = meshflow::optimise::untangle(m, uo, 1);
  MESSAGE("no progress: " << r.invalid_before << " -> " << r.invalid_after << ", work " << r.work << " of " << rf.work);
  CHECK(r.stage_budget_exhausted);
  CHECK(r.work < rf.work);
  CHECK(r.work >= uo.stage_budget);  // checked between elements: it stops on the first element after the budget
  CHECK(r.unrepaired_by_reason["no progress"] >= 1);
  CHECK(r.invalid_after == invalid(m));
  CHECK(r.invalid_after <= bad);
  std::size_t total = 0;
  for (auto& [why, n] : r.unrepaired_by_reason) total += n;
  CHECK(total == r.invalid_after);
  // the safety-net time limit: a limit that has passed before the first evaluation
  uo.stage_budget = 0;
  uo.time_limit = 1e-9;
  Mesh t = m0;
  auto rt = meshflow::optimise::untangle(t, uo, 1);
  CHECK(rt.time_limit_fired);
  CHECK(rt.work == 0);
  CHECK(rt.invalid_after == bad);
  CHECK(rt.unrepaired_by_reason["time limit"] == bad);
  CHECK(t.x == m0.x);
  CHECK(rt.advice().find("untangle_time_limit") != std::string::npos);
}

TEST_CASE("untangle budget: after repairs, one element given up does not stop the stage, before any repair the no-progress budget does") {
  // a 4x4x4 cube: interior edge nodes pushed across their tets (repairable) in the first cells,
  // one boundary edge node pushed (not repairable: the boundary does not move) after them, and one
  // more repairable push in the last cells. Elements are tried in index order.
  Mesh m0 = cube_tets(4, 4);
  const auto& b = m0.blocks[0];
  const auto& edges = model::edge_nodes(Shape::Tet, 4);
  // the elements holding node v, lowest and highest index
  auto span_of = [&](std::uint32_t v) {
    std::size_t lo = SIZE_MAX, hi = 0;
    for (std::size_t e = 0; e < b.size(); ++e)
      for (int a = 0; a < b.nodes_per_element(); ++a)
        if (b.element(e)[a] == v) lo = std::min(lo, e), hi = std::max(hi, e);
    return std::pair{lo, hi};
  };
  std::vector<char> used(m0.num_nodes(), 0);
  auto free_vertices = [&](std::size_t e) {
    for (int a = 0; a < 4; ++a)
      if (used[b.element(e)[a]]) return false;
    return true;
  };
  auto take = [&](std::size_t e) {
    for (int a = 0; a < 4; ++a) used[b.element(e)[a]] = 1;
  };
  std::size_t after = 0;  // every element of a later push has a higher index than this
  int repairable = 0;
  auto push_interior = [&](std::size_t from, std::size_t to) {
    for (std::size_t e = from; e < to; ++e)
      for (int k = 0; k < 6; ++k) {
        const std::uint32_t v = b.element(e)[edges[k][3]];
        auto [lo, hi] = span_of(v);
        if (m0.node_entity_dim[v] != 3 || lo <= after || !free_vertices(e)) continue;
        take(e);
        push_edge_node(m0, e, k, 1.25);
        after = hi;
        ++repairable;
        return true;
      }
    return false;
  };
  while (repairable < 8 && push_interior(after + 1, b.size() / 2)) {
  }
  REQUIRE(repairable == 8);
  bool boundary = false;
  for (std::size_t e = after + 1; e < b.size() && !boundary; ++e)
    for (int k = 0; k < 6 && !boundary; ++k) {
      const std::uint32_t v = b.element(e)[edges[k][3]];
      if (m0.node_entity_dim[v] != 2 || m0.node_entity_dim[b.element(e)[edges[k][2]]] != 2 ||
          m0.node_entity_dim[b.element(e)[edges[k][4]]] != 2 || span_of(v).first <= after || !free_vertices(e))
        continue;
      take(e);
      push_edge_node(m0, e, k, 3.0);
      after = span_of(v).second;
      boundary = true;
    }
  REQUIRE(boundary);
  REQUIRE(push_interior(after + 1, b.size()));
  meshflow::optimise::UntangleOptions uo;
  uo.max_rings = 2;
  uo.element_budget = 0, uo.stage_budget = 0;
  Mesh full = m0;
  auto rf = meshflow::optimise::untangle(full, uo, 1);
  MESSAGE("unlimited: " << rf.invalid_before << " invalid, " << rf.repaired << " repaired, " << rf.invalid_after << " left");
  REQUIRE(rf.repaired >= 2);
  REQUIRE(rf.invalid_after >= 1);
  // a no-progress budget of one sample: the failure after the repairs (given up on its element
  // budget, or not repaired) does not stop the stage, and the last push is repaired too
  uo.stage_budget = 1;
  uo.element_budget = std::max(rf.max_element_work, 1.0);
  Mesh m = m0;
  auto r = meshflow::optimise::untangle(m, uo, 1);
  MESSAGE("repairs' work " << r.repair_work << " of " << r.work << "; unlimited: " << rf.repaired << " repaired, "
                           << rf.invalid_after << " left");
  CHECK(r.repaired == rf.repaired);
  CHECK(r.invalid_after == rf.invalid_after);
  CHECK(!r.stage_budget_exhausted);
  CHECK(r.repair_work > 0);
  CHECK(r.repair_work < r.work);
  // a stage that repaired nothing still stops after the budget: the boundary push alone
  Mesh lone = cube_tets(4, 4);
  for (std::size_t e = 0; e < b.size(); ++e) {
    bool done = false;
    for (int k = 0; k < 6 && !done; ++k) {
      const std::uint32_t v = lone.blocks[0].element(e)[edges[k][3]];
      if (lone.node_entity_dim[v] == 2 && lone.node_entity_dim[lone.blocks[0].element(e)[edges[k][2]]] == 2 &&
          lone.node_entity_dim[lone.blocks[0].element(e)[edges[k][4]]] == 2)
        push_edge_node(lone, e, k, 3.0), done = true;
    }
    if (done && e > 40) break;  // a few boundary pushes
  }
  auto rl = meshflow::optimise::untangle(lone, uo, 1);
  CHECK(rl.repaired == 0);
  CHECK(rl.stage_budget_exhausted);
}

TEST_CASE("untangle in parallel: many invalid elements, some with overlapping patches, give byte-identical meshes and reports at 1 and 2 threads") {
  // order 3 on 4^3 cells: push interior edge nodes of elements spread through the cube, so that
  // some patches are node-disjoint (run at once) and some overlap (run one after another)
  Mesh a = cube_tets(4, 3);
  const auto& b = a.blocks[0];
  std::size_t pushed = 0;
  for (std::size_t e = 0; e < b.size(); e += 37)
    for (int k = 0; k < 6; ++k) {
      std::uint32_t nd = b.element(e)[model::edge_nodes(Shape::Tet, 3)[k][2]];
      if (a.node_entity_dim[nd] == 3) {
        push_edge_node(a, e, k, 1.8);
        ++pushed;
        break;
      }
    }
  REQUIRE(pushed >= 4);
  Mesh c = a;
  std::vector<std::string> log1, log2;
  auto r1 = meshflow::optimise::untangle(a, {}, 1, [&](const std::string& l) { log1.push_back(l); });
  auto r2 = meshflow::optimise::untangle(c, {}, 2, [&](const std::string& l) { log2.push_back(l); });
  CHECK(r1.invalid_before >= 4);
  CHECK(r1.repaired > 1);
  CHECK(r1.invalid_after == r2.invalid_after);
  CHECK(r1.repaired == r2.repaired);
  CHECK(r1.attempts == r2.attempts);
  CHECK(r1.work == r2.work);
  CHECK(r1.nodes_moved == r2.nodes_moved);
  CHECK(a.x == c.x);
  CHECK(a.y == c.y);
  CHECK(a.z == c.z);
  // the per-attempt log lines come in the order of the invalid elements, whatever ran first
  // (their times differ, so compare what precedes the time)
  // (", 0.12 s: repaired" -> ": repaired"; a line without a time as it is)
  auto untimed = [](const std::string& l) {
    const auto e = l.rfind(" s: ");
    if (e == std::string::npos) return l;
    return l.substr(0, l.rfind(", ", e)) + l.substr(e + 2);
  };
  REQUIRE(log1.size() == log2.size());
  for (std::size_t i = 0; i < log1.size(); ++i) CHECK(untimed(log1[i]) == untimed(log2[i]));
  CHECK(invalid(a) == r1.invalid_after);
}

namespace {

// The P=4 cube of cube_tets(3, 4) with its top face (z = 1) curved: every high-order node on it
// moved down by a * sin(3 pi x) sin(3 pi y), a bulge per cell face that vanishes at the element
// vertices (x, y multiples of 1/3), down into the cube in half of the cells, as a CAD face
// pushes the tets under it when curving. Only the top face's nodes move.
Mesh bulged_cube(double a) {
  Mesh m = cube_tets(3, 4);
  const double pi = std::acos(-1.0);
  for (std::size_t i = 0; i < m.num_nodes(); ++i)
    if (m.z[i] == 1.0) m.z[i] -= a * std::sin(3 * pi * m.x[i]) * std::sin(3 * pi * m.y[i]);
  return m;
}

}  // namespace

TEST_CASE("untangle lift: a node pushed across its tets goes back to its straight place, with no optimisation") {
  Mesh m = cube_tets(3, 4);
  const Mesh straight = m;
  const auto& b = m.blocks[0];
  std::size_t el = SIZE_MAX;
  int edge = -1;
  for (std::size_t e = 0; e < b.size() && el == SIZE_MAX; ++e)
    for (int k = 0; k < 6; ++k)
      if (m.node_entity_dim[b.element(e)[model::edge_nodes(Shape::Tet, 4)[k][3]]] == 3) {
        el = e, edge = k;
        break;
      }
  REQUIRE(el != SIZE_MAX);
  push_edge_node(m, el, edge, 1.6);
  REQUIRE(invalid(m) > 0);
  auto rep = meshflow::optimise::untangle(m, {}, 1);
  CHECK(rep.invalid_after == 0);
  CHECK(rep.repaired_by_lift == rep.repaired);
  CHECK(rep.attempts == 0);  // no L-BFGS attempt
  CHECK(rep.lifts >= 1);
  // the boundary data of the lift are straight: its solution is the straight mesh
  double worst = 0;
  for (std::size_t i = 0; i < m.num_nodes(); ++i)
    worst = std::max({worst, std::abs(m.x[i] - straight.x[i]), std::abs(m.y[i] - straight.y[i]), std::abs(m.z[i] - straight.z[i])});
  CHECK(worst < 1e-12);
}

TEST_CASE("untangle lift: tets under a curved face are repaired by the lift alone, with less work than the optimisation, nothing on the face moves") {
  const Mesh start = bulged_cube(0.06);
  const std::size_t bad = invalid(start);
  REQUIRE(bad > 0);
  Mesh with = start, without = start;
  meshflow::optimise::UntangleOptions off;
  off.lift = false;
  const auto r1 = meshflow::optimise::untangle(with, {}, 1);
  const auto r0 = meshflow::optimise::untangle(without, off, 1);
  MESSAGE("lift: " << r1.invalid_before << " -> " << r1.invalid_after << " invalid, " << r1.repaired_by_lift << " of " << r1.repaired
                   << " repairs by the lift alone, " << r1.attempts << " attempts, work " << r1.work << "; without: " << r0.invalid_after
                   << " invalid, " << r0.attempts << " attempts, work " << r0.work);
  CHECK(r1.invalid_before == bad);
  CHECK(r1.invalid_after == 0);
  CHECK(invalid(with) == 0);
  CHECK(r1.repaired_by_lift > 0);
  CHECK(r0.repaired_by_lift == 0);
  CHECK(r0.lifts == 0);
  CHECK(r1.work < r0.work);
  for (std::size_t i = 0; i < start.num_nodes(); ++i)
    if (start.node_entity_dim[i] != 3) {
      CHECK(with.x[i] == start.x[i]);
      CHECK(with.y[i] == start.y[i]);
      CHECK(with.z[i] == start.z[i]);
    }
}

TEST_CASE("untangle floor: a repaired element ends at the early exit's floor, or a later attempt was tried for it first") {
  Mesh m = cube_tets(3, 4);
  const auto& b = m.blocks[0];
  // interior edge nodes of several tets pushed by different amounts, so that some repairs end
  // close to invalid after the first attempt
  std::vector<std::size_t> pushed;
  const double f[] = {1.3, 1.6, 2.0, 2.4};
  for (std::size_t e = 0; e < b.size() && pushed.size() < 4; e += 7)
    for (int k = 0; k < 6; ++k) {
      std::uint32_t v = b.element(e)[model::edge_nodes(Shape::Tet, 4)[k][3]];
      if (m.node_entity_dim[v] == 3) {
        push_edge_node(m, e, k, f[pushed.size()]);
        pushed.push_back(e);
        break;
      }
    }
  REQUIRE(pushed.size() == 4);
  std::vector<char> was_invalid;
  const auto before = model::mesh_quality(m, 1);
  for (auto& q : before[0]) was_invalid.push_back(!q.valid);
  auto rep = meshflow::optimise::untangle(m, {}, 1);
  const auto after = model::mesh_quality(m, 1)[0];
  double lowest = INFINITY;
  for (std::size_t e = 0; e < after.size(); ++e)
    if (was_invalid[e]) lowest = std::min(lowest, after[e].scaled_jacobian);
  MESSAGE("floor: " << rep.invalid_before << " -> " << rep.invalid_after << " invalid, lowest repaired scaled Jacobian " << lowest
                    << ", below-floor retries " << rep.below_floor << ", attempts " << rep.attempts);
  CHECK(rep.invalid_before > 0);
  CHECK(rep.invalid_after == 0);
  CHECK((lowest >= 0.05 || rep.below_floor > 0));
  CHECK(rep.to_json().at("below_floor_retries") == rep.below_floor);
}

TEST_CASE("linearise: an element untangle cannot repair is made valid by taking back part of its curvature: vertices stay, moved boundary nodes are counted and lose their parameters") {
  auto [m, el] = impossible_cube(2);
  REQUIRE(el != SIZE_MAX);
  m.node_u.assign(m.num_nodes(), 0.25);  // stand-in parameters: the moved boundary nodes must lose theirs
  m.node_v.assign(m.num_nodes(), 0.75);
  const std::size_t bad = invalid(m);
  REQUIRE(bad > 0);
  const Mesh before = m;
  auto rep = meshflow::optimise::linearise_invalid(m, {}, 1);
  MESSAGE("linearise: " << rep.invalid_before << " -> " << rep.invalid_after << " invalid, " << rep.regions << " regions of "
                        << rep.elements << " elements, " << rep.cad_nodes_moved << " boundary nodes moved by at most "
                        << rep.max_cad_move << ", min scaled Jacobian " << rep.min_scaled_jacobian);
  CHECK(rep.invalid_before == bad);
  CHECK(rep.invalid_after == 0);
  CHECK(invalid(m) == 0);
  CHECK(rep.regions >= 1);
  CHECK(rep.cad_nodes_moved > 0);
  CHECK(rep.max_cad_move > 0);
  CHECK(rep.min_scaled_jacobian > 0);
  CHECK(rep.unrepaired_by_reason.empty());
  const auto& b = m.blocks[0];
  std::vector<char> vertex(m.num_nodes(), 0), in_region(m.num_nodes(), 0);
  for (std::size_t e = 0; e < b.size(); ++e)
    for (int a = 0; a < 4; ++a) vertex[b.element(e)[a]] = 1;
  std::size_t moved = 0, moved_on_boundary = 0;
  for (std::size_t i = 0; i < m.num_nodes(); ++i) {
    const bool same = m.x[i] == before.x[i] && m.y[i] == before.y[i] && m.z[i] == before.z[i];
    if (vertex[i]) CHECK(same);
    if (same) {
      CHECK(m.node_u[i] == 0.25);
      continue;
    }
    ++moved;
    if (m.node_entity_dim[i] == 2) {
      ++moved_on_boundary;
      CHECK(std::isnan(m.node_u[i]));
      CHECK(std::isnan(m.node_v[i]));
    }
  }
  CHECK(moved == rep.nodes_moved);
  CHECK(moved_on_boundary == rep.cad_nodes_moved);
  // only nodes of the pushed element's neighbourhood moved: far fewer than the mesh has
  CHECK(moved < m.num_nodes() / 10);
}

TEST_CASE("linearise: the same bytes at 1 and 2 threads, nothing to do on a valid mesh, and an element whose straight version is inverted is left exactly as it was") {
  auto [a, el] = impossible_cube(2);
  REQUIRE(el != SIZE_MAX);
  Mesh c = a;
  auto r1 = meshflow::optimise::linearise_invalid(a, {}, 1);
  auto r2 = meshflow::optimise::linearise_invalid(c, {}, 2);
  CHECK(r1.invalid_after == 0);
  CHECK(a.x == c.x);
  CHECK(a.y == c.y);
  CHECK(a.z == c.z);
  auto j1 = r1.to_json(), j2 = r2.to_json();
  j1.erase("seconds"), j2.erase("seconds");
  CHECK(j1 == j2);
  // a valid mesh: nothing moves
  Mesh v = cube_tets(2, 3), v0 = v;
  auto r0 = meshflow::optimise::linearise_invalid(v, {}, 2);
  CHECK(r0.invalid_before == 0);
  CHECK(r0.regions == 0);
  CHECK(v.x == v0.x);
  // an element turned inside out at its vertices (a linear mesh that broke its contract): its
  // straight version is invalid, so nothing is moved and the reason is given
  Mesh w = cube_tets(2, 2);
  auto& wb = w.blocks[0];
  const std::uint32_t* en = wb.element(0);
  const std::uint32_t apex = en[3];
  w.x[apex] = 2 * w.x[en[0]] - w.x[apex];  // the fourth vertex reflected through the first
  w.y[apex] = 2 * w.y[en[0]] - w.y[apex];
  w.z[apex] = 2 * w.z[en[0]] - w.z[apex];
  REQUIRE(invalid(w) > 0);
  const Mesh w0 = w;
  auto rw = meshflow::optimise::linearise_invalid(w, {}, 1);
  CHECK(rw.invalid_after > 0);
  CHECK(rw.unrepaired_by_reason.count("straight element invalid") == 1);
  CHECK(w.x == w0.x);
  CHECK(w.y == w0.y);
  CHECK(w.z == w0.z);
}

TEST_CASE("linearise: a high-order node in a periodic pair is never moved (its partner would not follow)") {
  auto [m, el] = impossible_cube(2);
  REQUIRE(el != SIZE_MAX);
  const auto& b = m.blocks[0];
  meshflow::model::PeriodicLink link;
  link.dim = 2, link.tag = 2, link.master_tag = 1;
  link.nodes.push_back({b.element(el)[4], b.element(el)[4]});  // the element's first edge node, paired
  m.periodic.push_back(link);
  const Mesh before = m;
  auto rep = meshflow::optimise::linearise_invalid(m, {}, 1);
  CHECK(rep.invalid_after > 0);
  CHECK(rep.unrepaired_by_reason.count("in a periodic pair") == 1);
  CHECK(m.x[b.element(el)[4]] == before.x[b.element(el)[4]]);
}
