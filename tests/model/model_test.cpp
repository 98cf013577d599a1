// Tests of the mesh model: node layouts (against Gmsh itself), Lagrange bases, mappings,
// validity (Bezier bounds) and quality, topology.
#include <doctest/doctest.h>

#include "stages/model/basis.hpp"
#include "stages/model/element.hpp"
#include "stages/model/mesh.hpp"
#include "stages/model/quality.hpp"
#include "stages/model/topology.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <random>
#include <set>
#include <sstream>
#include <string>

using namespace meshflow::model;

namespace {
const Shape kAll[] = {Shape::Line, Shape::Tri, Shape::Quad, Shape::Tet, Shape::Prism, Shape::Pyramid, Shape::Hex};

std::string run_python(const std::string& script) {
  auto dir = std::filesystem::temp_directory_path() / ("mf_model_" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  auto py = dir / "s.py", out = dir / "out.txt";
  std::ofstream(py) << script;
  std::string cmd = std::string(MESHFLOW_PYTHON) + " " + py.string() + " > " + out.string() + " 2>/dev/null";
  int rc = std::system(cmd.c_str());
  REQUIRE_MESSAGE(rc == 0, "python failed: " << cmd);
  std::ifstream in(out);
  std::stringstream ss;
  ss << in.rdbuf();
  std::filesystem::remove_all(dir);
  return ss.str();
}

// Reference element nodes mapped affinely: an undistorted element of the shape.
std::vector<double> straight(Shape s, int p, double sx = 1, double sy = 1, double sz = 1) {
  std::vector<double> X;
  for (auto& r : reference_nodes(s, p)) {
    X.push_back(r[0] * sx + 0.1 * r[1]);
    X.push_back(r[1] * sy);
    X.push_back(r[2] * sz);
  }
  return X;
}
}  // namespace

TEST_CASE("node layouts have the right size and distinct nodes, vertices first") {
  for (Shape s : kAll)
    for (int p = 1; p <= kMaxOrder; ++p) {
      const auto& l = lattice(s, p);
      CHECK(l.size() == (size_t)num_nodes(s, p));
      std::set<Lattice> u(l.begin(), l.end());
      CHECK(u.size() == l.size());
      for (int v = 0; v < num_vertices(s); ++v) CHECK(reference_nodes(s, p)[v] == reference_nodes(s, 1)[v]);
    }
}

TEST_CASE("node layouts equal Gmsh's own (getElementProperties), orders 1-6") {
  std::string script =
      "import gmsh\ngmsh.initialize()\ngmsh.option.setNumber('General.Terminal',0)\n"
      "gmsh.option.setNumber('General.AbortOnError',0)\n"
      "for t in [1,8,26,27,28,62,2,9,21,23,25,42,3,10,36,37,38,47,4,11,29,30,31,71,6,13,90,91,106,107,"
      "7,14,118,119,120,121,5,12,92,93,94,95]:\n"
      "  p=gmsh.model.mesh.getElementProperties(t)\n"
      "  print(t, p[1], len(p[4]), ' '.join('%.15g'%v for v in p[4]))\n";
  std::istringstream in(run_python(script));
  int t, n, dim, checked = 0;
  while (in >> t >> dim >> n) {
    Shape s;
    int p;
    REQUIRE(from_gmsh_type(t, s, p));
    std::vector<double> c(n);
    for (auto& v : c) in >> v;
    const auto& ref = reference_nodes(s, p);
    REQUIRE(c.size() == dim * ref.size());
    double err = 0;
    for (size_t i = 0; i < ref.size(); ++i)
      for (int r = 0; r < dim; ++r) err = std::max(err, std::abs(ref[i][r] - c[dim * i + r]));
    INFO("gmsh type " << t << " (" << shape_name(s) << " order " << p << ")");
    CHECK(err < 1e-12);
    ++checked;
  }
  CHECK(checked == 42);
}

TEST_CASE("Lagrange bases interpolate at their nodes and reproduce linear fields") {
  for (Shape s : kAll)
    for (int p = 1; p <= 6; ++p) {
      const LagrangeBasis& b = LagrangeBasis::get(s, p);
      std::vector<double> N(b.size()), dN(3 * b.size());
      double err = 0;
      for (int i = 0; i < b.size(); ++i) {
        if (s == Shape::Pyramid && b.nodes()[i][2] > 1 - 1e-12) continue;
        b.eval(b.nodes()[i], N.data());
        for (int k = 0; k < b.size(); ++k) err = std::max(err, std::abs(N[k] - (i == k)));
      }
      INFO(std::string(shape_name(s)) << " order " << p);
      CHECK(err < 1e-8);
      // gradient of x + 2y - z is (1, 2, -1) everywhere
      Vec3 xi = {0.21, 0.13, s == Shape::Pyramid ? 0.3 : 0.11};
      if (dimension(s) < 3) xi[2] = 0;
      if (dimension(s) < 2) xi[1] = 0;
      b.grad(xi, dN.data());
      double g[3] = {0, 0, 0};
      for (int i = 0; i < b.size(); ++i) {
        auto& r = b.nodes()[i];
        double f = r[0] + 2 * r[1] - r[2];
        for (int c = 0; c < 3; ++c) g[c] += f * dN[3 * i + c];
      }
      CHECK(g[0] == doctest::Approx(1).epsilon(1e-7));
      if (dimension(s) >= 2) CHECK(g[1] == doctest::Approx(2).epsilon(1e-7));
      if (dimension(s) >= 3) CHECK(g[2] == doctest::Approx(-1).epsilon(1e-7));
    }
}

TEST_CASE("straight elements are valid with scaled Jacobian 1, swapped vertices are invalid") {
  for (Shape s : {Shape::Tri, Shape::Quad, Shape::Tet, Shape::Prism, Shape::Hex, Shape::Pyramid})
    for (int p = 1; p <= 6; ++p) {
      auto X = straight(s, p, 2, 1, 0.5);
      auto q = element_quality(s, p, X.data());
      INFO(std::string(shape_name(s)) << " order " << p);
      CHECK(q.valid);
      CHECK(q.scaled_jacobian == doctest::Approx(1).epsilon(1e-9));
      // mirror the element: every det J < 0
      for (size_t i = 0; i < X.size(); i += 3) X[i] = -X[i];
      auto m = element_quality(s, p, X.data(), dimension(s) == 2 ? std::array<double, 3>{0, 0, 1}.data() : nullptr);
      CHECK_FALSE(m.valid);
      CHECK(m.scaled_jacobian < 0);
    }
}

TEST_CASE("a P=4 tet valid at every node but invalid between them is reported invalid") {
  const int P = 4;
  const LagrangeBasis& b = LagrangeBasis::get(Shape::Tet, P);
  std::vector<double> X0;  // the reference tet itself
  for (auto& r : reference_nodes(Shape::Tet, P)) X0.insert(X0.end(), r.begin(), r.end());
  // the edge node of edge 0 (vertices 0-1) nearest vertex 0 is local node 4; moving it along
  // the edge makes dx/dxi = 1 + delta L4'(xi) along that edge.
  auto det_min = [&](const std::vector<double>& X, const std::vector<Vec3>& pts) {
    double mn = 1e300, J[9];
    for (auto& xi : pts) {
      jacobian(b, X.data(), xi, J);
      mn = std::min(mn, jacobian_determinant(3, J, nullptr));
    }
    return mn;
  };
  std::vector<Vec3> fine;
  const int F = 40;
  for (int i = 0; i <= F; ++i)
    for (int j = 0; i + j <= F; ++j)
      for (int k = 0; i + j + k <= F; ++k) fine.push_back({i / double(F), j / double(F), k / double(F)});
  // The middle node of edge 0-1, pushed 0.14 towards the inside (+y): found by a search in
  // Python (numpy, Gmsh's node coordinates); both facts are checked here independently.
  auto X = X0;
  X[3 * 5 + 1] += 0.14;
  const double at_nodes = det_min(X, b.nodes());
  const double between = det_min(X, fine);
  INFO("min det J at nodes " << at_nodes << ", between nodes " << between);
  REQUIRE(at_nodes > 0.1);
  REQUIRE(between < -0.01);
  auto q = element_quality(Shape::Tet, P, X.data());
  CHECK_FALSE(q.valid);
  CHECK(q.scaled_jacobian <= 0);
  // and a smaller push stays valid (certified)
  X[3 * 5 + 1] -= 0.1;
  CHECK(element_quality(Shape::Tet, P, X.data()).valid);
}

TEST_CASE("curved but valid P=4 elements are certified valid") {
  for (Shape s : {Shape::Tet, Shape::Prism, Shape::Hex, Shape::Tri, Shape::Quad}) {
    auto X = straight(s, 4);
    for (size_t i = 0; i < X.size(); i += 3) {  // smooth bending
      X[i + 1] += 0.05 * std::sin(2 * X[i]);
      X[i + 2] += 0.05 * std::cos(X[i + 1]) * (dimension(s) == 3);
    }
    auto q = element_quality(s, 4, X.data());
    INFO(std::string(shape_name(s)));
    CHECK(q.valid);
    CHECK(q.scaled_jacobian < 1);
    CHECK(q.scaled_jacobian > 0.5);
  }
}

TEST_CASE("aspect ratio of a thin prism is tangential size over thickness") {
  auto X = straight(Shape::Prism, 2, 1, 1, 0.01);  // z in [-0.01, 0.01]: thickness 0.02
  auto q = element_quality(Shape::Prism, 2, X.data());
  double longest = std::sqrt(1.1 * 1.1 + 1.0);  // hypotenuse of the sheared triangle
  (void)longest;
  CHECK(q.aspect_ratio == doctest::Approx(std::sqrt((0.9 * 0.9 + 1.0)) / 0.02).epsilon(1e-9));
}

TEST_CASE("sub-element mapping: the identity sub-element reproduces the parent's nodes") {
  auto X = straight(Shape::Tet, 4);
  for (size_t i = 0; i < X.size(); i += 3) X[i + 2] += 0.1 * X[i] * X[i];
  auto same = map_sub_element(Shape::Tet, 4, X.data(), Shape::Tet, 4, {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}});
  for (size_t i = 0; i < X.size(); ++i) CHECK(same[i] == doctest::Approx(X[i]).epsilon(1e-10));
  // a prism split in two layers: the lower sub-prism's top nodes are the parent's mid-plane
  auto P = straight(Shape::Prism, 3);
  auto lo = map_sub_element(Shape::Prism, 3, P.data(), Shape::Prism, 3,
                            {{0, 0, -1}, {1, 0, -1}, {0, 1, -1}, {0, 0, 0}, {1, 0, 0}, {0, 1, 0}});
  CHECK(lo[3 * 3 + 2] == doctest::Approx(0.0));
  CHECK(lo[3 * 0 + 2] == doctest::Approx(-1.0));
}

TEST_CASE("topology of two P=2 tets sharing a face, conformity") {
  Mesh m;
  auto X = straight(Shape::Tet, 2);
  for (size_t i = 0; i < X.size(); i += 3) m.add_node(X[i], X[i + 1], X[i + 2]);
  auto& b = m.block(Shape::Tet, 2, 3, 1);
  std::vector<std::uint32_t> e1(10);
  for (int i = 0; i < 10; ++i) e1[i] = i;
  b.add(e1.data());
  // second tet: mirror vertex 3 through the face (0,1,2); shares face 0 and its edge nodes
  std::uint32_t apex = m.add_node(0, 0, -1);
  // local edges of a tet: 01,12,20,30,32,31 -> nodes 4..9
  std::uint32_t n30 = m.add_node(0, 0, -0.5), n32 = m.add_node(0, 0.5, -0.5), n31 = m.add_node(0.5, 0, -0.5);
  std::vector<std::uint32_t> e2 = {0, 2, 1, apex, 6, 5, 4, n30, n31, n32};
  b.add(e2.data());
  auto t = build_topology(m);
  CHECK(t.faces.size() == 7);
  CHECK(t.boundary_faces == 6);
  CHECK(t.nonconforming_faces == 0);
  CHECK(t.edges.size() == 9);
  auto stats = mesh_stats(m);
  CHECK(stats["invalid"] == 0);
  CHECK(stats["elements"]["tet"] == 2);
  // break conformity: the second element gets its own copy of a shared edge node
  m.blocks[0].nodes[10 + 4] = m.add_node(0.5, 0.5, 0.0);
  CHECK(build_topology(m).nonconforming_faces == 1);
  CHECK(mesh_stats(m)["nonconforming_faces"] == 1);
}

TEST_CASE("an element whose det J has a minimum of 1e-10 inside is inconclusive, and the stats do not call it proven") {
  // P=3 hex x = F(xi), y = eta, z = zeta with F'(xi) = (xi - 0.1234567)^2 + 1e-10: det J > 0
  // everywhere (no sample is <= 0, so nothing shows it invalid), but its minimum 1e-10 lies on a
  // plane through the element, far below what Bezier refinement within its limits can prove.
  auto X = straight(Shape::Hex, 3);
  const auto& r = reference_nodes(Shape::Hex, 3);
  const double x0 = 0.1234567, eps = 1e-10;
  for (size_t i = 0; i < r.size(); ++i) {
    const double t = r[i][0] - x0;
    X[3 * i] = t * t * t / 3 + eps * r[i][0];
    X[3 * i + 1] = r[i][1];
    X[3 * i + 2] = r[i][2];
  }
  const auto q = element_quality(Shape::Hex, 3, X.data());
  CHECK(q.min_det > 0);
  CHECK(q.inconclusive);
  Mesh m;
  m.add_physical(3, 1, "fluid");
  m.add_entity(3, 1, {1});
  std::vector<std::uint32_t> ids;
  for (size_t i = 0; i < X.size(); i += 3) ids.push_back(m.add_node(X[i], X[i + 1], X[i + 2]));
  m.block(Shape::Hex, 3, 3, 1).add(ids.data());
  const auto st = mesh_stats(m, 1);
  CHECK(st["inconclusive"] == 1);
  const std::string method = st["validity_method"];
  INFO(method);
  CHECK(method.find("every element") == std::string::npos);
  CHECK(method.find("inconclusive") != std::string::npos);
}

TEST_CASE("mesh check names bad node indices and non-finite coordinates") {
  Mesh m;
  m.add_node(0, 0, 0);
  m.add_node(1, 0, 0);
  m.block(Shape::Line, 1, 1, 1).add({0, 5});
  CHECK_THROWS_WITH_AS(m.check(), doctest::Contains("node index 5"), std::invalid_argument);
  m.blocks[0].nodes[1] = 1;
  CHECK_NOTHROW(m.check());
  m.x[1] = NAN;
  CHECK_THROWS_WITH_AS(m.check(), doctest::Contains("non-finite"), std::invalid_argument);
}

TEST_CASE("high orders: Bezier validity is proven (not sampled) up to P=6 (prisms to P=5), and sound") {
  // Randomly perturbed elements: an element we call valid with a proof (not sampled, not
  // inconclusive) must have det J > 0 at every point of a fine lattice; one we call invalid
  // has a sample with det J <= 0 (checked the same way); both verdicts must occur.
  // Prisms of order 6: the values -> Bezier transform amplifies the samples' rounding ~2e11x,
  // beyond what a rigorous rounding bound allows (see quality.hpp): reported as sampled.
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> U(-1, 1);
  for (Shape s : {Shape::Tet, Shape::Prism, Shape::Hex})
    for (int p : {4, 5, 6}) {
      const LagrangeBasis& b = LagrangeBasis::get(s, p);
      int proven = 0, invalid = 0;
      for (int trial = 0; trial < 8; ++trial) {
        auto X = straight(s, p);
        const double amp = 0.02 + 0.04 * (trial % 4);
        for (size_t i = 0; i < X.size(); ++i) X[i] += amp * U(rng) / p;
        auto q = element_quality(s, p, X.data());
        INFO(std::string(shape_name(s)) << " P=" << p << " trial " << trial);
        const bool unprovable = s == Shape::Prism && p == 6;
        CHECK(q.sampled == unprovable);
        const int F = s == Shape::Hex ? 7 : 10;
        double mn = 1e300, J[9];
        for (int i = 0; i <= F; ++i)
          for (int j = 0; j <= F; ++j)
            for (int k = 0; k <= F; ++k) {
              Vec3 xi;
              if (s == Shape::Hex) xi = {-1 + 2. * i / F, -1 + 2. * j / F, -1 + 2. * k / F};
              else if (s == Shape::Prism) {
                if (i + j > F) continue;
                xi = {double(i) / F, double(j) / F, -1 + 2. * k / F};
              } else {
                if (i + j + k > F) continue;
                xi = {double(i) / F, double(j) / F, double(k) / F};
              }
              jacobian(b, X.data(), xi, J);
              mn = std::min(mn, jacobian_determinant(3, J, nullptr));
            }
        if (q.valid && !q.sampled && !q.inconclusive) {
          ++proven;
          CHECK(mn > 0);
        }
        if (!q.valid) {
          ++invalid;
          CHECK(q.min_det <= 0);
        }
        CHECK_FALSE(q.inconclusive);
      }
      INFO(std::string(shape_name(s)) << " P=" << p << ": proven " << proven << ", invalid " << invalid);
      CHECK((proven > 0) == !(s == Shape::Prism && p == 6));
      CHECK(invalid > 0);
    }
}

TEST_CASE("thin boundary layers: 10 split P=4 layers of aspect ratio > 1000 are judged quickly and correctly") {
  // A curved P=4 macro prism (and hex) on a bent slab of thickness 0.2 is split into 10 layers
  // (geometric ratio 1.7 from the wall: first layer ~7e-4 thick, edges 1 to 1.4 long) by mapping
  // sub-elements through the macro element (what the split stage does). Every layer is valid
  // and must be proven so (not sampled, not inconclusive); a copy of the thinnest layer with an
  // interior node pushed 3 thicknesses across the layer is invalid (checked against a fine
  // lattice of det J samples), one pushed by 5% of a thickness stays proven valid.
  const int P = 4, L = 10;
  const double T = 0.2, ratio = 1.7;
  auto slab = [&](const Vec3& r, Shape s) {  // reference point -> bent slab
    const double xi = s == Shape::Hex ? (r[0] + 1) / 2 : r[0], eta = s == Shape::Hex ? (r[1] + 1) / 2 : r[1];
    const double u = xi + 0.1 * eta * eta, v = eta + 0.05 * xi * eta, w = T * (r[2] + 1) / 2;
    return Vec3{u, (3 + w) * std::sin(v / 3), (3 + w) * std::cos(v / 3) - 3};
  };
  std::vector<double> cuts = {-1};
  for (int k = 1; k <= L; ++k) cuts.push_back(-1 + 2 * (std::pow(ratio, k) - 1) / (std::pow(ratio, L) - 1));
  cuts.back() = 1;
  for (Shape s : {Shape::Prism, Shape::Hex}) {
    INFO(std::string(shape_name(s)));
    std::vector<double> macro;
    for (auto& r : reference_nodes(s, P))
      for (double c : slab(r, s)) macro.push_back(c);
    REQUIRE(element_quality(s, P, macro.data()).valid);
    const auto& rv = reference_nodes(s, 1);
    Mesh m;
    m.add_physical(3, 1, "fluid");
    m.add_entity(3, 1, {1});
    std::vector<std::vector<double>> layers;
    for (int k = 0; k < L; ++k) {
      std::vector<Vec3> verts;
      for (auto v : rv) verts.push_back({v[0], v[1], v[2] < 0 ? cuts[k] : cuts[k + 1]});
      layers.push_back(map_sub_element(s, P, macro.data(), s, P, verts));
      std::vector<std::uint32_t> ids;
      for (size_t i = 0; i < layers.back().size(); i += 3)
        ids.push_back(m.add_node(layers.back()[i], layers.back()[i + 1], layers.back()[i + 2]));
      m.block(s, P, 3, 1).add(ids.data());
    }
    const auto t0 = std::chrono::steady_clock::now();
    int proven = 0;
    for (auto& X : layers) {
      auto q = element_quality(s, P, X.data());
      proven += q.valid && !q.sampled && !q.inconclusive;
    }
    auto st = mesh_stats(m, 1);
    const double secs = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    CHECK(proven == L);
    CHECK(st["invalid"] == 0);
    CHECK(st["inconclusive"] == 0);
    CHECK(st["max_aspect_ratio"].get<double>() > 1000);
    CHECK_MESSAGE(secs < 2.0, "20 thin P=4 elements took " << secs << " s");
    MESSAGE(std::string(shape_name(s)) << ": max aspect ratio " << st["max_aspect_ratio"].get<double>() << ", min scaled Jacobian " << st["min_scaled_jacobian"].get<double>() << ", judged in " << secs << " s");
    // the thinnest layer with an interior node pushed across it
    const auto& lat = lattice(s, P);
    const Lattice target = s == Shape::Hex ? Lattice{2, 2, 2} : Lattice{1, 1, 2};
    const int node = int(std::find(lat.begin(), lat.end(), target) - lat.begin());
    REQUIRE(node < (int)lat.size());
    const double h = T * (cuts[1] + 1) / 2;  // first layer thickness
    const LagrangeBasis& b = LagrangeBasis::get(s, P);
    for (double push : {-3.0, 0.05}) {
      auto X = layers[0];
      // the layer direction at that node: d x / d zeta, normalised
      double J[9];
      jacobian(b, X.data(), reference_nodes(s, P)[node], J);
      const double n = std::sqrt(J[2] * J[2] + J[5] * J[5] + J[8] * J[8]);
      for (int r = 0; r < 3; ++r) X[3 * node + r] += push * h * J[3 * r + 2] / n;
      double mn = 1e300;
      const int F = 24;
      for (int i = 0; i <= F; ++i)
        for (int j = 0; j <= F; ++j)
          for (int k = 0; k <= F; ++k) {
            if (s == Shape::Prism && i + j > F) continue;
            const Vec3 xi = s == Shape::Hex ? Vec3{-1 + 2. * i / F, -1 + 2. * j / F, -1 + 2. * k / F}
                                            : Vec3{double(i) / F, double(j) / F, -1 + 2. * k / F};
            jacobian(b, X.data(), xi, J);
            mn = std::min(mn, jacobian_determinant(3, J, nullptr));
          }
      auto q = element_quality(s, P, X.data());
      CAPTURE(push);
      if (push < 0) {
        REQUIRE(mn < 0);  // truth: inverted somewhere
        CHECK_FALSE(q.valid);
      } else {
        REQUIRE(mn > 0);
        CHECK(q.valid);
        CHECK_FALSE(q.sampled);
        CHECK_FALSE(q.inconclusive);
      }
    }
  }
}

TEST_CASE("tets: the perturbation proof gives the same verdicts as the Bezier path, P=2..6") {
  // Random curved tets from barely to strongly perturbed: every verdict with the fast path (the
  // perturbation proof first) equals the verdict of the Bezier path alone; both verdicts occur;
  // and the fast path's min det J is never
  // below the Bezier path's (the latter may add subdivision samples, never remove lattice points).
  // (That the fast path proves elements at all is measured by bench/model_bench.)
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> U(-1, 1);
  for (int p = 2; p <= 6; ++p) {
    int valid = 0, invalid = 0, differ = 0;
    double t_fast = 0, t_bezier = 0;
    for (int trial = 0; trial < 200; ++trial) {
      auto X = straight(Shape::Tet, p, 1 + 0.5 * U(rng), 1 + 0.5 * U(rng), 1 + 0.5 * U(rng));
      const double amp = 0.3 * double(trial % 20) / 19.0;  // 0 .. 0.3 of the element size
      for (size_t i = 3 * 4; i < X.size(); ++i) X[i] += amp * U(rng) / p;  // high-order nodes only
      set_tet_perturbation_proof(true);
      auto t0 = std::chrono::steady_clock::now();
      auto fast = element_quality(Shape::Tet, p, X.data());
      auto t1 = std::chrono::steady_clock::now();
      set_tet_perturbation_proof(false);
      auto slow = element_quality(Shape::Tet, p, X.data());
      auto t2 = std::chrono::steady_clock::now();
      t_fast += std::chrono::duration<double>(t1 - t0).count();
      t_bezier += std::chrono::duration<double>(t2 - t1).count();
      INFO("P=" << p << " trial " << trial << " amplitude " << amp);
      CHECK(fast.valid == slow.valid);
      CHECK_FALSE(fast.inconclusive);
      differ += fast.valid != slow.valid;
      if (slow.valid) {
        ++valid;
        CHECK(fast.min_det >= slow.min_det);
        CHECK(fast.max_det == slow.max_det);
      } else {
        ++invalid;
      }
    }
    set_tet_perturbation_proof(true);
    // (times include the first call's one-time tables, which the fast path builds)
    MESSAGE("P=" << p << ": " << valid << " valid, " << invalid << " invalid, " << differ << " verdicts differ; time fast "
                 << t_fast << " s, Bezier only " << t_bezier << " s");
    CHECK(valid > 20);
    CHECK(invalid > 10);
  }
}

namespace {
// min det J of a pyramid over an (F+1)^3 grid of collapsed coordinates (a, b, c) in
// [-1,1]^2 x [0, 1 - 1e-3]: x = (1-c) a, y = (1-c) b, z = c (Gmsh's reference pyramid)
double pyramid_grid_min(const LagrangeBasis& b, const std::vector<double>& X, int F) {
  double mn = 1e300, J[9];
  for (int i = 0; i <= F; ++i)
    for (int j = 0; j <= F; ++j)
      for (int k = 0; k <= F; ++k) {
        const double a = -1 + 2. * i / F, bb = -1 + 2. * j / F, c = (1 - 1e-3) * k / F;
        jacobian(b, X.data(), {(1 - c) * a, (1 - c) * bb, c}, J);
        mn = std::min(mn, jacobian_determinant(3, J, nullptr));
      }
  return mn;
}
}  // namespace

TEST_CASE("pyramids: validity is proven by Bernstein coefficients in collapsed coordinates, P=1..6, and sound") {
  // Gmsh's (Bergot's) pyramid space is rational, so det J is no polynomial in (x, y, z); in
  // collapsed coordinates it is (quality.hpp). Randomly perturbed pyramids: one we call valid
  // is proven (not sampled, not inconclusive) and has det J > 0 on a fine grid; one we call
  // invalid has det J < 0 somewhere on a fine grid or at a sample; both verdicts occur.
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> U(-1, 1);
  for (int p = 1; p <= 6; ++p) {
    const LagrangeBasis& b = LagrangeBasis::get(Shape::Pyramid, p);
    int proven = 0, invalid = 0;
    for (int trial = 0; trial < 8; ++trial) {
      auto X = straight(Shape::Pyramid, p, 1.5, 1, 0.7);
      const double amp = (0.05 + 0.12 * (trial % 4)) * (p == 1 ? 3 : 1);
      for (size_t i = 0; i < X.size(); ++i) X[i] += amp * U(rng) / p;
      auto q = element_quality(Shape::Pyramid, p, X.data());
      INFO("P=" << p << " trial " << trial);
      CHECK_FALSE(q.sampled);
      CHECK_FALSE(q.inconclusive);
      const double mn = pyramid_grid_min(b, X, p <= 4 ? 16 : 10);
      if (q.valid) {
        ++proven;
        CHECK(mn > 0);
      } else {
        ++invalid;
        CHECK((mn <= 0 || q.min_det <= 0));
      }
    }
    INFO("P=" << p << ": proven " << proven << ", invalid " << invalid);
    CHECK(proven > 0);
    CHECK(invalid > 0);
  }
}

TEST_CASE("pyramids: a P=4 pyramid valid at every sample of the order-14 lattice but invalid between is found") {
  // One high-order node pushed by t along a direction: as t grows, det J first turns negative
  // somewhere (t*). The Bernstein check must flip at t* (never later); the samples of the
  // pyramid lattice of order 3P+2 (what meshflow used to rely on) flip later where the negative
  // region starts between them. Search nodes and directions for such a gap, then check at a t
  // inside it that the samples are positive, a dense grid finds det J < 0, and we say invalid.
  const int P = 4;
  const LagrangeBasis& b = LagrangeBasis::get(Shape::Pyramid, P);
  const auto X0 = straight(Shape::Pyramid, P, 1, 1, 1);
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> U(-1, 1);
  auto flip = [&](auto&& invalid_at, double hi) {  // smallest t in (0, hi] with invalid_at(t)
    double lo = 0;
    if (!invalid_at(hi)) return -1.0;
    for (int it = 0; it < 40; ++it) {
      const double mid = (lo + hi) / 2;
      (invalid_at(mid) ? hi : lo) = mid;
    }
    return hi;
  };
  int found = 0;
  for (int trial = 0; trial < 60 && found < 2; ++trial) {
    const int node = 5 + trial % (num_nodes(Shape::Pyramid, P) - 5);  // not a vertex
    double d[3] = {U(rng), U(rng), U(rng)};
    auto moved = [&](double t) {
      auto X = X0;
      for (int r = 0; r < 3; ++r) X[3 * node + r] += t * d[r];
      return X;
    };
    const double t_bez = flip([&](double t) { return !element_quality(Shape::Pyramid, P, moved(t).data()).valid; }, 3.0);
    const double t_smp = flip([&](double t) { return element_quality(Shape::Pyramid, P, moved(t).data()).min_det <= 0; }, 3.0);
    if (t_bez < 0) continue;
    INFO("node " << node << " t_bezier " << t_bez << " t_samples " << t_smp);
    REQUIRE(t_smp > 0);
    CHECK(t_bez <= t_smp * (1 + 1e-9));  // sound: never valid where a sample is negative
    if (t_smp - t_bez < 0.02 * t_smp) continue;
    const double t = t_bez + 0.5 * (t_smp - t_bez);
    auto X = moved(t);
    auto q = element_quality(Shape::Pyramid, P, X.data());
    const double dense = pyramid_grid_min(b, X, 48);
    INFO("at t " << t << ": min det at the samples " << q.min_det << ", on the dense grid " << dense);
    CHECK(q.min_det > 0);
    CHECK_FALSE(q.valid);
    CHECK(dense < 0);
    ++found;
  }
  CHECK(found >= 1);
}

TEST_CASE("mesh_quality with a known quality and the nodes moved since computes those elements only, to the same numbers") {
  // 40 curved P=3 tets (and 20 prisms) in a row, each with its own nodes, perturbed at random
  Mesh m;
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> d(-0.04, 0.04);
  for (Shape s : {Shape::Tet, Shape::Prism}) {
    auto& b = m.block(s, 3, 3, 1);
    for (int e = 0; e < (s == Shape::Tet ? 40 : 20); ++e) {
      std::vector<std::uint32_t> nodes;
      for (auto& r : reference_nodes(s, 3)) nodes.push_back(m.add_node(r[0] + 2 * e + d(rng), r[1] + d(rng), r[2] + d(rng)));
      b.add(nodes.data());
    }
  }
  const auto before = mesh_quality(m, 2);
  const std::vector<double> x0 = m.x, y0 = m.y, z0 = m.z;
  // move one node of every fifth element of each block
  std::set<std::pair<std::size_t, std::size_t>> touched;
  for (std::size_t bi = 0; bi < m.blocks.size(); ++bi)
    for (std::size_t e = 0; e < m.blocks[bi].size(); e += 5) {
      const std::uint32_t n = m.blocks[bi].element(e)[m.blocks[bi].nodes_per_element() - 1];
      m.x[n] += 0.05, m.z[n] -= 0.03;
      touched.insert({bi, e});
    }
  const auto moved = moved_nodes(m, x0, y0, z0);
  CHECK(std::count(moved.begin(), moved.end(), 1) == long(touched.size()));
  const auto full = mesh_quality(m, 2);
  const auto updated = mesh_quality(m, 1, &before, &moved);
  // a known quality marked: the untouched elements keep it, the touched ones are computed
  auto marked = before;
  for (auto& b : marked)
    for (auto& q : b) q.scaled_jacobian = 42;
  const auto from_marked = mesh_quality(m, 2, &marked, &moved);
  for (std::size_t bi = 0; bi < m.blocks.size(); ++bi) {
    REQUIRE(updated[bi].size() == full[bi].size());
    for (std::size_t e = 0; e < full[bi].size(); ++e) {
      CAPTURE(bi);
      CAPTURE(e);
      CHECK(updated[bi][e].scaled_jacobian == full[bi][e].scaled_jacobian);
      CHECK(updated[bi][e].min_det == full[bi][e].min_det);
      CHECK(updated[bi][e].max_det == full[bi][e].max_det);
      CHECK(updated[bi][e].aspect_ratio == full[bi][e].aspect_ratio);
      CHECK(updated[bi][e].valid == full[bi][e].valid);
      if (touched.count({bi, e})) CHECK(from_marked[bi][e].scaled_jacobian == full[bi][e].scaled_jacobian);
      else CHECK(from_marked[bi][e].scaled_jacobian == 42);
    }
  }
  // without `moved`, a known block is taken whole; one of another size is computed
  auto short_known = marked;
  short_known[0].pop_back();
  const auto taken = mesh_quality(m, 2, &short_known);
  CHECK(taken[0][0].scaled_jacobian == full[0][0].scaled_jacobian);
  CHECK(taken[1][0].scaled_jacobian == 42);
}
