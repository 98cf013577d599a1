// The interval-assignment integer program on hand-made block structures (solve_intervals
// called directly, checked against brute-force enumeration), and the balance stage end to end
// on the parametric naca_wing through `meshflow run`.
#include <doctest/doctest.h>

#include "support.hpp"

#include "stages/balance/balance.hpp"
#include "stages/cad/cad.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <functional>
#include <map>
#include <random>
#include <set>

namespace bal = meshflow::balance;

namespace {

bal::IPProblem make(const std::vector<std::pair<std::string, double>>& edges) {
  bal::IPProblem p;
  for (auto& [n, t] : edges) p.edges.push_back({n, t, 1.0});
  return p;
}
void group(bal::IPProblem& p, std::string name, std::string kind, std::vector<int> e, std::optional<int> v = {}) {
  p.groups.push_back({std::move(name), std::move(kind), std::move(e), v});
}

bool feasible(const bal::IPProblem& p, const std::vector<int>& n) {
  for (auto& g : p.groups) {
    long s = 0;
    for (int e : g.edges) {
      s += n[e];
      if (g.value && n[e] != *g.value) return false;
      if ((g.kind == "equal" || g.kind == "periodic") && n[e] != n[g.edges[0]]) return false;
    }
    if (g.kind == "even" && s % 2) return false;
  }
  return true;
}
double objective(const bal::IPProblem& p, const std::vector<int>& n) {
  double s = 0;
  for (std::size_t e = 0; e < n.size(); ++e) s += p.edges[e].weight * std::abs(n[e] - p.edges[e].target) / p.edges[e].target;
  return s;
}
// Minimum objective over n in [1, nmax]^E (infinity when infeasible in that box).
double brute_force(const bal::IPProblem& p, int nmax) {
  std::vector<int> n(p.edges.size(), 1);
  double best = INFINITY;
  while (true) {
    if (feasible(p, n)) best = std::min(best, objective(p, n));
    std::size_t i = 0;
    while (i < n.size() && n[i] == nmax) n[i++] = 1;
    if (i == n.size()) break;
    ++n[i];
  }
  return best;
}

}  // namespace

TEST_CASE("IP: a structured quad block gets equal opposite sides, at the brute-force optimum") {
  // bottom a, right b, top c, left d: a = c, b = d; the loop is quad-meshed (even, implied)
  bal::IPProblem p = make({{"a", 4.3}, {"b", 2.2}, {"c", 5.6}, {"d", 2.9}});
  group(p, "block: equal [a,c]", "equal", {0, 2});
  group(p, "block: equal [b,d]", "equal", {1, 3});
  group(p, "block: even loop", "even", {0, 1, 2, 3});
  bal::IPSolution s = bal::solve_intervals(p);
  REQUIRE(s.n.size() == 4);
  CHECK(s.n[0] == s.n[2]);
  CHECK(s.n[1] == s.n[3]);
  // relative deviation favours the smaller target: a = c = 5 (0.270) beats 4 (0.355); b = d = 2 or 3
  CHECK(s.n[0] == 5);
  CHECK(s.n[1] == 3);  // |3-2.2|/2.2 + |3-2.9|/2.9 = 0.398 < |2-2.2|/2.2 + |2-2.9|/2.9 = 0.401
  CHECK(s.objective == doctest::Approx(brute_force(p, 10)).epsilon(1e-9));
  CHECK(s.total_deviation == doctest::Approx(objective(p, s.n)));
  CHECK(s.optimal);
}

TEST_CASE("IP: random block structures match brute-force enumeration (equal, periodic, layer, even)") {
  std::mt19937 rng(12345);
  std::uniform_real_distribution<double> tgt(0.3, 7.5);
  int feasible_cases = 0, infeasible_cases = 0;
  for (int trial = 0; trial < 60; ++trial) {
    int E = 3 + trial % 3;  // 3..5 edges
    bal::IPProblem p;
    for (int e = 0; e < E; ++e) p.edges.push_back({"e" + std::to_string(e), tgt(rng), 0.5 + (e % 2)});
    std::uniform_int_distribution<int> pick(0, E - 1), kind(0, 3);
    int ng = 1 + trial % 3;
    for (int g = 0; g < ng; ++g) {
      int a = pick(rng), b = pick(rng), c = pick(rng);
      switch (kind(rng)) {
        case 0: group(p, "g" + std::to_string(g), "equal", {a, b}); break;
        case 1: group(p, "g" + std::to_string(g), "periodic", {a, b}); break;
        case 2: group(p, "g" + std::to_string(g), "layer", {a}, 1 + (trial % 2)); break;
        default: group(p, "g" + std::to_string(g), "even", {a, b, c}); break;
      }
    }
    // n never needs to exceed 2 * max target + 2 here; enumerate to 17
    double bf = brute_force(p, 17);
    if (std::isfinite(bf)) {
      bal::IPSolution s = bal::solve_intervals(p);
      CHECK(feasible(p, s.n));
      CHECK(s.objective == doctest::Approx(bf).epsilon(1e-9));
      ++feasible_cases;
    } else {
      CHECK_THROWS_AS(bal::solve_intervals(p), bal::InfeasibleError);
      ++infeasible_cases;
    }
  }
  CHECK(feasible_cases > 30);
  MESSAGE("feasible " << feasible_cases << ", infeasible " << infeasible_cases);
}

TEST_CASE("IP: periodic partner edges get equal counts") {
  // a periodic sector: the two sides' edges pair up; their targets differ (different sizing),
  // the counts do not
  bal::IPProblem p = make({{"w1", 6.2}, {"w2", 9.8}, {"e7", 3.1}, {"e8", 2.0}, {"free", 4.4}});
  group(p, "periodic w1 ~ w2", "periodic", {0, 1});
  group(p, "periodic e7 ~ e8", "periodic", {2, 3});
  bal::IPSolution s = bal::solve_intervals(p);
  CHECK(s.n[0] == s.n[1]);
  CHECK(s.n[2] == s.n[3]);
  CHECK(s.n[0] >= 6);
  CHECK(s.n[0] <= 10);
  CHECK(s.n[4] == 4);
  CHECK(s.objective == doctest::Approx(brute_force(p, 12)).epsilon(1e-9));
}

TEST_CASE("IP: a minimum of divisions (a narrow face's edge) is a bound, not a target: its equal group follows it") {
  // w20 along a 0.7 mm ring would take 9 divisions (its shell image's target pulls it down);
  // the width asks for 20 at least: both get 20, the free edge keeps its optimum
  bal::IPProblem p = make({{"w20", 19.9}, {"s20", 8.0}, {"free", 4.4}});
  group(p, "prism_sweep face 1: equal [w20, s20]", "equal", {0, 1});
  bal::IPSolution s0 = bal::solve_intervals(p);
  CHECK(s0.n[0] == s0.n[1]);
  CHECK(s0.n[0] < 20);
  p.edges[0].min_n = 20;
  bal::IPSolution s = bal::solve_intervals(p);
  CHECK(s.n[0] == 20);
  CHECK(s.n[1] == 20);
  CHECK(s.n[2] == 4);
  // a bound on the other member of the group acts the same; the larger of two bounds wins
  p.edges[0].min_n = 1, p.edges[1].min_n = 23;
  CHECK(bal::solve_intervals(p).n[0] == 23);
  p.edges[0].min_n = 25;
  CHECK(bal::solve_intervals(p).n[1] == 25);
}

TEST_CASE("IP: an infeasible problem names a minimal set of conflicting constraints") {
  // A quad-meshed face with three sides a, b, c needs an even sum; a one-layer sweep edge
  // forces a = 1 and a block forces b = c, so the sum 1 + 2b is odd. Unrelated constraints
  // (even one on edge a) must not be named.
  bal::IPProblem p = make({{"a", 1.2}, {"b", 1.0}, {"c", 1.4}, {"d", 3.0}, {"e", 3.3}, {"f", 2.0}, {"g", 1.1}});
  group(p, "unrelated: equal [d,e]", "equal", {3, 4});
  group(p, "redundant: equal [a,g]", "equal", {0, 6});
  group(p, "unrelated: even [d,e,f]", "even", {3, 4, 5});
  group(p, "block 2: equal [b,c]", "equal", {1, 2});
  group(p, "face 9: even loop", "even", {0, 1, 2});
  group(p, "junction: layer a", "layer", {0}, 1);
  try {
    bal::solve_intervals(p);
    FAIL("expected InfeasibleError");
  } catch (const bal::InfeasibleError& e) {
    std::set<std::string> got(e.conflict.begin(), e.conflict.end());
    CHECK(got == std::set<std::string>{"block 2: equal [b,c]", "face 9: even loop", "junction: layer a"});
    std::string m = e.what();
    CHECK(m.find("face 9: even loop") != std::string::npos);
    CHECK(m.find("edges a, b, c") != std::string::npos);
    CHECK(m.find("unrelated") == std::string::npos);
    CHECK(m.find("redundant") == std::string::npos);
  }
  // dropping any one of the named groups makes it feasible (minimality)
  for (long g : {3, 4, 5}) {
    bal::IPProblem q = p;
    q.groups.erase(q.groups.begin() + g);
    CHECK_NOTHROW(bal::solve_intervals(q));
  }
}

TEST_CASE("IP: an equal group that forces a count below 1 is named") {
  bal::IPProblem p = make({{"x0", 0.4}, {"x1", 0.5}, {"y", 2.0}});
  group(p, "hex_junction edge 3: equal [x0,x1]", "equal", {0, 1});
  group(p, "bad: layer x1 = 0", "layer", {1}, 0);
  group(p, "fine: layer y = 2", "layer", {2}, 2);
  try {
    bal::solve_intervals(p);
    FAIL("expected InfeasibleError");
  } catch (const bal::InfeasibleError& e) {
    REQUIRE(e.conflict.size() == 1);
    CHECK(e.conflict[0] == "bad: layer x1 = 0");
    CHECK(std::string(e.what()).find("n >= 1") != std::string::npos);
  }
}

TEST_CASE("IP: integral, deterministic, rejects malformed problems") {
  bal::IPProblem p;
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> tgt(0.5, 40);
  for (int e = 0; e < 300; ++e) p.edges.push_back({"e" + std::to_string(e), tgt(rng), 1.0});
  for (int b = 0; b + 3 < 300; b += 4) {  // 75 structured quad blocks, chained: c of one = a of next
    group(p, "blk" + std::to_string(b) + ": equal [a,c]", "equal", {b, b + 2});
    group(p, "blk" + std::to_string(b) + ": equal [b,d]", "equal", {b + 1, b + 3});
    if (b + 4 < 300) group(p, "chain" + std::to_string(b), "equal", {b + 2, b + 4});
    group(p, "blk" + std::to_string(b) + ": even", "even", {b, b + 1, b + 2, b + 3});
  }
  bal::IPSolution s1 = bal::solve_intervals(p), s2 = bal::solve_intervals(p);
  CHECK(s1.n == s2.n);
  CHECK(s1.objective == s2.objective);
  CHECK(feasible(p, s1.n));
  for (int n : s1.n) CHECK(n >= 1);
  CHECK(s1.objective == doctest::Approx(objective(p, s1.n)));
  MESSAGE("300 edges: solve " << s1.solve_time * 1e3 << " ms, " << s1.bb_nodes << " B&B nodes, max rel dev " << s1.max_rel_deviation);

  bal::IPProblem bad = make({{"a", 0.0}});
  CHECK_THROWS_AS(bal::solve_intervals(bad), std::invalid_argument);
  bal::IPProblem bad2 = make({{"a", 1.0}});
  group(bad2, "g", "equal", {0, 3});
  CHECK_THROWS_AS(bal::solve_intervals(bad2), std::invalid_argument);
}

TEST_CASE("divisions artifact: write/read round trip, refuses corrupt files") {
  namespace fs = std::filesystem;
  fs::path dir = mftest::temp_dir("balance-io");
  bal::Divisions d;
  d.units = "m";
  d.edges.push_back({"s1", 1, "shell", 2, 2.2, 0.3, "cad", {0.0, 0.5, 1.0}});
  d.edges.push_back({"w1", 1, "wall", 2, 2.1, 0.3, "cad", {0.0, 0.5, 1.0}});
  bal::write(d, dir / "a.mfdiv");
  bal::Divisions r = bal::read(dir / "a.mfdiv");
  CHECK(r.count("w1") == 2);
  CHECK(r.find("x") == nullptr);
  CHECK_THROWS_AS(r.count("x"), std::out_of_range);
  CHECK(r.find("s1")->nodes == std::vector<double>{0.0, 0.5, 1.0});
  bal::write(r, dir / "b.mfdiv");
  CHECK(mftest::read_text(dir / "a.mfdiv") == mftest::read_text(dir / "b.mfdiv"));
  mftest::write_text(dir / "c.mfdiv", "{\"format\":\"meshflow-divisions 1\"}");
  CHECK_THROWS_AS(bal::read(dir / "c.mfdiv"), meshflow::StageError);
  CHECK_THROWS_AS(bal::read(dir / "missing.mfdiv"), meshflow::StageError);
  fs::remove_all(dir);
}

TEST_CASE("meshflow run: naca_wing -> heal -> medial -> shell -> balance, divisions obey the blocks") {
  namespace fs = std::filesystem;
  fs::path dir = mftest::temp_dir("balance-e2e");
  mftest::write_text(dir / "wf.yaml",
                     "meshflow: 1\nname: balance-e2e\nstages:\n"
                     "  geometry: {kind: naca_wing, with: {profile: \"0012\", chord: 1.0, span: 1.0, incidence_deg: 10, tip: round, trailing_edge: blunt}}\n"
                     "  heal: {kind: heal, needs: [geometry]}\n"
                     "  medial: {kind: medial, needs: [heal]}\n"
                     "  shell: {kind: shell, needs: [heal, medial], with: {thickness: 0.05, topology: C}}\n"
                     "  balance: {kind: balance, needs: [heal, shell], with: {turn_angle_deg: 30}}\n"
                     "outputs:\n  divisions: {from: balance}\n  shape: {from: heal}\n  shell: {from: shell}\n");
  std::string cmd = std::string(MESHFLOW_EXE) + " run " + (dir / "wf.yaml").string() + " --threads 2 --cache " +
                    (dir / "cache").string() + " --out " + (dir / "out").string() + " > " + (dir / "log").string() + " 2>&1";
  int rc = std::system(cmd.c_str());
  if (rc != 0) MESSAGE(mftest::read_text(dir / "log"));
  REQUIRE(rc == 0);
  fs::path div;
  for (auto& f : fs::recursive_directory_iterator(dir / "out"))
    if (f.path().extension() == ".mfdiv") div = f.path();
  REQUIRE(!div.empty());
  bal::Divisions d = bal::read(div);
  nlohmann::json st = nlohmann::json::parse(d.stats_json);
  MESSAGE("naca_wing balance stats: " << st.dump());
  REQUIRE(d.edges.size() > 10);
  // every equal group and layer constraint of the blocks holds; nodes increase from end to end
  nlohmann::json C = nlohmann::json::parse(d.constraints_json);
  long njunction = 0;
  for (auto& c : C) {
    std::vector<int> n;
    for (auto& e : c.at("edges")) n.push_back(d.count(e.get<std::string>()));
    if (c.at("kind") == "equal" || c.at("kind") == "periodic")
      for (int k : n) CHECK(k == n[0]);
    if (c.at("kind") == "layer") {
      CHECK(n[0] == 1);
      ++njunction;
    }
    if (c.at("kind") == "even") {
      long s = 0;
      for (int k : n) s += k;
      CHECK(s % 2 == 0);
    }
  }
  CHECK(njunction >= 2);  // the root of the wing sits on the symmetry wall: junction blocks
  meshflow::cad::Shape shape = meshflow::cad::Shape::load(dir / "out" / "shape.mfshape");
  double dev = 0;
  long wall_edges = 0;
  for (auto& e : d.edges) {
    REQUIRE(e.nodes.size() == static_cast<std::size_t>(e.n) + 1);
    for (std::size_t k = 1; k < e.nodes.size(); ++k) CHECK(e.nodes[k] > e.nodes[k - 1]);
    dev = std::max(dev, std::abs(e.n - e.target) / e.target);
    if (e.kind == "wall") {
      ++wall_edges;
      auto r = shape.edge_range(e.cad_edge);
      CHECK(e.nodes.front() == r.lo);
      CHECK(e.nodes.back() == r.hi);
      // graded by the sizing: each division holds target/n of the integral of ds/h, and
      // min_size <= h <= max_size (0.01 and 0.1 of the 1.04 wall box), so its length lies in
      // [h_min, h_max] * target / n; the lengths add up to the edge
      double L = shape.edge_length(e.cad_edge);
      CHECK(L == doctest::Approx(e.length).epsilon(1e-6));
      const double Lref = 1.04, hmin = 0.01 * Lref, hmax = 0.1 * Lref * 1.001;
      double sum = 0;
      for (int k = 0; k < e.n; ++k) {
        double s = shape.edge_length(e.cad_edge, e.nodes[k], e.nodes[k + 1]);
        sum += s;
        if (L < hmin) continue;  // a target below 1 was raised to 1: one division, any length
        CHECK(s >= 0.98 * hmin * e.target / e.n);
        CHECK(s <= 1.02 * hmax * e.target / e.n);
      }
      CHECK(sum == doctest::Approx(L).epsilon(1e-6));
      std::string s = "s" + std::to_string(e.cad_edge), jc = "j" + std::to_string(e.cad_edge) + "c";
      REQUIRE((d.find(s) || d.find(jc)));
      CHECK((d.find(s) ? d.find(s) : d.find(jc))->n == e.n);  // shell image / junction corner: same count
    }
  }
  CHECK(wall_edges >= 4);
  CHECK(st.at("max_rel_deviation").get<double>() == doctest::Approx(dev));
  fs::remove_all(dir);
}
