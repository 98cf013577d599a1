// The split stage: composition validity on random curved macro elements, agreement with
// model::map_sub_element, counts, conformity with the far field, geometric progression,
// first_height, boundary faces / CAD lines / parameters, determinism, refusals.
#include <doctest/doctest.h>

#include "support.hpp"

#include "builders.hpp"
#include "engine/stage.hpp"
#include "stages/io/mesh_io.hpp"
#include "stages/model/basis.hpp"
#include "stages/model/quality.hpp"
#include "stages/model/topology.hpp"
#include "stages/split/split.hpp"

#include <nlohmann/json.hpp>

#include <fstream>
#include <set>
#include <sstream>
#include <unistd.h>

using namespace splittest;
using meshflow::StageError;
using meshflow::split::Options;
using meshflow::split::split_mesh;

namespace {


std::filesystem::path tmpdir(const std::string& tag) {
  static int n = 0;
  auto d = std::filesystem::temp_directory_path() / ("meshflow-split-" + tag + "-" + std::to_string(getpid()) + "-" + std::to_string(n++));
  std::filesystem::remove_all(d);
  std::filesystem::create_directories(d);
  return d;
}

const meshflow::model::ElementBlock* find_block(const Mesh& m, Shape s) {
  for (auto& b : m.blocks)
    if (b.shape == s && b.size()) return &b;
  return nullptr;
}

std::vector<double> coords(const Mesh& m, const std::uint32_t* e, int n) {
  std::vector<double> X;
  for (int i = 0; i < n; ++i) X.insert(X.end(), {m.x[e[i]], m.y[e[i]], m.z[e[i]]});
  return X;
}

// Sub-element vertices in the parent's reference space (first layer at the wall), as the
// paper defines them: for the test's independent check against model::map_sub_element.
std::vector<std::vector<Vec3>> expected_sub_vertices(Shape s, const int ds[3], int L, double ratio) {
  auto t = meshflow::split::layer_cuts(L, ratio);
  auto range = [&](int d, int m) -> std::pair<double, double> {  // layer m counted from the wall
    if (!ds[d]) return {-1, 1};
    if (ds[d] < 0) return {-1 + 2 * t[m], -1 + 2 * t[m + 1]};
    return {1 - 2 * t[m + 1], 1 - 2 * t[m]};
  };
  int n[3];
  for (int d = 0; d < 3; ++d) n[d] = ds[d] && L > 1 ? L : 1;
  std::vector<std::vector<Vec3>> out;
  for (int w2 = 0; w2 < n[2]; ++w2)
    for (int w1 = 0; w1 < n[1]; ++w1)
      for (int w0 = 0; w0 < n[0]; ++w0) {
        auto r0 = range(0, w0), r1 = range(1, w1), r2 = range(2, w2);
        std::vector<Vec3> v;
        if (s == Shape::Prism) {
          for (double z : {r2.first, r2.second})
            for (Vec3 c : {Vec3{0, 0, 0}, Vec3{1, 0, 0}, Vec3{0, 1, 0}}) v.push_back({c[0], c[1], z});
        } else {
          for (auto& c : meshflow::model::reference_nodes(Shape::Hex, 1))
            v.push_back({c[0] < 0 ? r0.first : r0.second, c[1] < 0 ? r1.first : r1.second, c[2] < 0 ? r2.first : r2.second});
        }
        out.push_back(v);
      }
  return out;
}

}  // namespace

TEST_CASE("layer cuts: geometric progression, first_height ratio solve") {
  auto t = meshflow::split::layer_cuts(10, 1.5);
  REQUIRE(t.size() == 11);
  CHECK(t[0] == 0);
  CHECK(t[10] == 1);
  for (int k = 1; k < 10; ++k) CHECK((t[k + 1] - t[k]) / (t[k] - t[k - 1]) == doctest::Approx(1.5).epsilon(1e-12));
  CHECK(t[1] == doctest::Approx(0.5 / (std::pow(1.5, 10) - 1)).epsilon(1e-13));
  auto u = meshflow::split::layer_cuts(4, 1.0);
  CHECK(u[1] == doctest::Approx(0.25));
  CHECK(u[3] == doctest::Approx(0.75));
  double r = meshflow::split::ratio_for_first_fraction(10, t[1]);
  CHECK(r == doctest::Approx(1.5).epsilon(1e-10));
  CHECK(meshflow::split::ratio_for_first_fraction(10, 0.1) == 1.0);
  CHECK_THROWS_AS(meshflow::split::ratio_for_first_fraction(10, 0.2), StageError);
  CHECK_THROWS_AS(meshflow::split::ratio_for_first_fraction(10, 1e-12), StageError);
}

TEST_CASE("property: random valid curved macro prisms and hexes (P = 2..4) give valid sub-elements equal to chi o f, at ratios 1, 1.5, 3") {
  std::mt19937_64 rng(20180108);
  long macros = 0, subs = 0, invalid = 0, inconclusive = 0, prisms = 0, hexes = 0;
  double worst = 0, min_sj = 1;
  for (int P = 2; P <= 4; ++P)
    for (double ratio : {1.0, 1.5, 3.0})
      for (int trial = 0; trial < 8; ++trial) {
        Shape s = trial % 2 ? Shape::Hex : Shape::Prism;
        std::vector<int> walls;
        int ds[3] = {0, 0, 0};
        if (s == Shape::Prism) {
          walls = {int(rng() % 2)};
          ds[2] = walls[0] == 0 ? -1 : 1;
        } else {
          // one, two or three wall faces on distinct axes
          int nw = 1 + int(rng() % 3);
          std::vector<int> axes = {0, 1, 2};
          std::shuffle(axes.begin(), axes.end(), rng);
          for (int k = 0; k < nw; ++k) {
            int d = axes[k], side = int(rng() % 2);
            for (int f = 0; f < 6; ++f) {
              const auto& fv = meshflow::model::face_vertices(Shape::Hex)[f];
              const auto& r1 = meshflow::model::reference_nodes(Shape::Hex, 1);
              bool on = true;
              for (int v : fv) on = on && r1[v][d] == (side ? 1.0 : -1.0);
              if (on) walls.push_back(f);
            }
            ds[d] = side ? 1 : -1;
          }
        }
        Mesh m;
        for (int tries = 0;; ++tries) {
          try {
            m = random_macro(s, P, walls, rng);
            break;
          } catch (const std::runtime_error&) {
            REQUIRE(tries < 20);
          }
        }
        const auto& mb = m.blocks[0];
        REQUIRE(meshflow::model::element_quality(s, P, coords(m, mb.element(0), mb.nodes_per_element()).data()).valid);
        ++macros;
        (s == Shape::Prism ? prisms : hexes)++;
        const int L = 5;
        Options o;
        o.layers = L;
        o.ratio = ratio;
        auto r = split_mesh(m, o, 1);
        const auto* sb = find_block(r.mesh, s);
        REQUIRE(sb);
        int nsplit = (ds[0] != 0) + (ds[1] != 0) + (ds[2] != 0);
        CHECK(sb->size() == std::size_t(std::pow(L, nsplit)));
        auto expect = expected_sub_vertices(s, ds, L, ratio);
        REQUIRE(expect.size() == sb->size());
        std::vector<double> Xm = coords(m, mb.element(0), mb.nodes_per_element());
        for (std::size_t e = 0; e < sb->size(); ++e) {
          auto X = coords(r.mesh, sb->element(e), sb->nodes_per_element());
          auto q = meshflow::model::element_quality(s, P, X.data());
          ++subs;
          if (!q.valid) ++invalid;
          if (q.inconclusive) ++inconclusive;
          min_sj = std::min(min_sj, q.scaled_jacobian);
          auto ref = meshflow::model::map_sub_element(s, P, Xm.data(), s, P, expect[e]);
          for (std::size_t k = 0; k < ref.size(); ++k) worst = std::max(worst, std::abs(ref[k] - X[k]));
        }
        // wall faces keep their nodes; the wall sub-face count is L^(nsplit-1) per wall face
        CHECK(r.stats.macro_prisms + r.stats.macro_hexes_1wall + r.stats.macro_hexes_2wall + r.stats.macro_hexes_3wall == 1);
      }
  MESSAGE("property test: " << macros << " random curved macro elements (" << prisms << " prisms, " << hexes
                            << " hexes; P = 2..4; ratios 1, 1.5, 3; 5 layers) -> " << subs << " sub-elements, " << invalid
                            << " invalid, " << inconclusive << " inconclusive, min scaled Jacobian " << min_sj
                            << ", max |node - map_sub_element| " << worst);
  CHECK(macros == 72);
  CHECK(invalid == 0);
  CHECK(worst < 1e-12);
}

TEST_CASE("geometric progression: layer heights of a straight prism and a straight junction hex, first_height") {
  // straight prism: wall triangle at z = 0, thickness T = 0.3 along z (top wall variant too)
  for (int top = 0; top < 2; ++top) {
    const int P = 3;
    const double T = 0.3;
    Mesh m;
    add_groups(m);
    std::vector<std::uint32_t> ids;
    for (auto& x : meshflow::model::reference_nodes(Shape::Prism, P)) ids.push_back(m.add_node(2 * x[0], 2 * x[1], T * (x[2] + 1) / 2));
    m.block(Shape::Prism, P, 3, kVol).add(ids.data());
    std::vector<std::uint32_t> w;
    for (int k : meshflow::model::face_nodes(Shape::Prism, P)[top]) w.push_back(ids[k]);
    m.block(Shape::Tri, P, 2, kWall).add(w.data());
    for (double ratio : {1.0, 1.5, 3.0}) {
      Options o;
      o.layers = 10;
      o.ratio = ratio;
      auto r = split_mesh(m, o, 1);
      const auto* sb = find_block(r.mesh, Shape::Prism);
      REQUIRE(sb->size() == 10);
      double expect_first = ratio == 1 ? T / 10 : T * (ratio - 1) / (std::pow(ratio, 10) - 1);
      for (int k = 0; k < 10; ++k) {
        const std::uint32_t* e = sb->element(k);
        double h = std::abs(r.mesh.z[e[3]] - r.mesh.z[e[0]]);
        CHECK(h == doctest::Approx(expect_first * std::pow(ratio, k)).epsilon(1e-12));
        // sub-element k is layer k from the wall
        double dist = top ? T - std::max(r.mesh.z[e[0]], r.mesh.z[e[3]]) : std::min(r.mesh.z[e[0]], r.mesh.z[e[3]]);
        double before = ratio == 1 ? T * k / 10 : expect_first * (std::pow(ratio, k) - 1) / (ratio - 1);
        CHECK(dist == doctest::Approx(before).epsilon(1e-12).scale(T));
      }
      CHECK(r.stats.first_height_min == doctest::Approx(expect_first).epsilon(1e-12));
      CHECK(r.stats.thickness_max == doctest::Approx(T).epsilon(1e-12));
      auto stats = meshflow::model::mesh_stats(r.mesh, 1);
      CHECK(stats["max_aspect_ratio"].get<double>() == doctest::Approx(2 * std::sqrt(2.0) / expect_first).epsilon(1e-9));
    }
    Options o;
    o.layers = 10;
    o.first_height = T / 40;
    auto r = split_mesh(m, o, 1);
    CHECK(r.stats.ratio_from_first_height);
    CHECK(r.stats.ratio > 1);
    CHECK(r.stats.first_height_max == doctest::Approx(T / 40).epsilon(1e-9));
    o.first_height = T / 5;  // uniform layers are already thinner
    CHECK_THROWS_AS(split_mesh(m, o, 1), StageError);
  }
  // straight hex with walls at x = 0 and y = 0: layers x layers, first cell = h1 x h1
  {
    const int P = 2;
    Mesh m;
    add_groups(m);
    std::vector<std::uint32_t> ids;
    for (auto& x : meshflow::model::reference_nodes(Shape::Hex, P)) ids.push_back(m.add_node(0.1 * (x[0] + 1), 0.2 * (x[1] + 1), x[2]));
    m.block(Shape::Hex, P, 3, kVol).add(ids.data());
    for (int f : {2, 1}) {  // xi = -1 and eta = -1
      std::vector<std::uint32_t> w;
      for (int k : meshflow::model::face_nodes(Shape::Hex, P)[f]) w.push_back(ids[k]);
      m.block(Shape::Quad, P, 2, kWall).add(w.data());
    }
    Options o;
    o.layers = 6;
    o.ratio = 2;
    auto r = split_mesh(m, o, 1);
    const auto* sb = find_block(r.mesh, Shape::Hex);
    REQUIRE(sb->size() == 36);
    double f1 = 1.0 / 63;  // (2-1)/(2^6-1)
    const std::uint32_t* e = sb->element(0);
    CHECK(std::abs(r.mesh.x[e[1]] - r.mesh.x[e[0]]) == doctest::Approx(0.2 * f1).epsilon(1e-12));
    CHECK(std::abs(r.mesh.y[e[3]] - r.mesh.y[e[0]]) == doctest::Approx(0.4 * f1).epsilon(1e-12));
    CHECK(r.stats.macro_hexes_2wall == 1);
    CHECK(r.stats.first_height_min == doctest::Approx(0.2 * f1).epsilon(1e-12));
    CHECK(r.stats.first_height_max == doctest::Approx(0.4 * f1).epsilon(1e-12));
    // the wall faces are split into the sub-hexes' wall faces: 6 each
    std::size_t quads = 0;
    for (auto& b : r.mesh.blocks)
      if (b.shape == Shape::Quad) quads += b.size();
    CHECK(quads == 12);
  }
}

TEST_CASE("junction mesh (cylinder on a plate, prisms + C-type hexes + tets): counts, conformity, unchanged far field, boundary faces, lines, parameters") {
  for (int P : {1, 2, 4}) {
    auto J = junction_mesh(P);
    const Mesh& in = J.mesh;
    auto tin = meshflow::model::build_topology(in);
    REQUIRE(tin.nonconforming_faces == 0);
    auto qin = meshflow::model::mesh_stats(in, 1);
    REQUIRE(qin["invalid"].get<long>() == 0);
    for (int L : {1, 3, 10}) {
      Options o;
      o.layers = L;
      o.ratio = 1.5;
      auto r = split_mesh(in, o, 2);
      const Mesh& out = r.mesh;
      CAPTURE(P);
      CAPTURE(L);
      // counts
      CHECK(r.stats.macro_prisms == J.prisms_a + J.prisms_c);
      CHECK(r.stats.macro_hexes_2wall == J.hexes);
      std::size_t np = 0, nh = 0, nt = 0, ntri = 0, nquad = 0, nline = 0, nsym = 0, nfar = 0;
      for (auto& b : out.blocks) {
        if (b.shape == Shape::Prism) np += b.size();
        if (b.shape == Shape::Hex) nh += b.size();
        if (b.shape == Shape::Tet) nt += b.size();
        if (b.shape == Shape::Tri) ntri += b.size();
        if (b.shape == Shape::Quad) nquad += b.size();
        if (b.shape == Shape::Line) nline += b.size();
        if (b.shape == Shape::Quad && b.entity_tag == kSym) nsym += b.size();
        if (b.shape == Shape::Quad && b.entity_tag == kFar) nfar += b.size();
      }
      CHECK(np == std::size_t(L) * (J.prisms_a + J.prisms_c));
      CHECK(nh == std::size_t(L) * L * J.hexes);
      CHECK(nt == J.tets);
      CHECK(nline == std::size_t(L));
      CHECK(nsym == std::size_t(L) * 12);
      CHECK(nfar == std::size_t(L) * 12);  // C's face at r = R2 spans theta x z: split along z
      // wall triangles unchanged in number; each wall quad of a junction hex becomes L quads
      CHECK(ntri == J.prisms_a + J.prisms_c);
      CHECK(nquad == 2 * std::size_t(L) * J.hexes + nsym + nfar);
      CHECK(r.stats.boundary_faces_split == (L > 1 ? 2 * J.hexes + 24 : 0));
      CHECK(r.stats.lines_split == (L > 1 ? 1u : 0u));
      // conformity with the far field
      auto t = meshflow::model::build_topology(out);
      CHECK(t.nonconforming_faces == 0);
      // tets unchanged (same coordinates, element by element)
      const auto* tb_in = find_block(in, Shape::Tet);
      const auto* tb_out = find_block(out, Shape::Tet);
      REQUIRE(tb_in);
      REQUIRE(tb_out);
      bool same = tb_in->size() == tb_out->size();
      for (std::size_t e = 0; same && e < tb_in->size(); ++e)
        same = coords(in, tb_in->element(e), tb_in->nodes_per_element()) == coords(out, tb_out->element(e), tb_out->nodes_per_element());
      CHECK(same);
      // every tet face on a prism's outer face is an interior face of (prism, tet)
      std::size_t tet_prism = 0;
      for (auto& f : t.faces)
        if (f.elements.size() == 2) {
          Shape a = out.blocks[f.elements[0].block].shape, b = out.blocks[f.elements[1].block].shape;
          if ((a == Shape::Tet && b == Shape::Prism) || (a == Shape::Prism && b == Shape::Tet)) ++tet_prism;
        }
      CHECK(tet_prism == J.tets);
      auto q = meshflow::model::mesh_stats(out, 2);
      CHECK(q["invalid"].get<long>() == 0);
      CHECK(q["nonconforming_faces"].get<long>() == 0);
      // all nodes used, none duplicated: nodes = distinct coordinates
      std::set<std::array<double, 3>> pts;
      for (std::size_t i = 0; i < out.num_nodes(); ++i) pts.insert({out.x[i], out.y[i], out.z[i]});
      CHECK(pts.size() == out.num_nodes());
      // new nodes on the symmetry plane carry (u, v) interpolated in the parent face: = (x, y)
      std::size_t sym_nodes = 0, sym_bad = 0;
      for (std::size_t i = 0; i < out.num_nodes(); ++i)
        if (out.node_entity_dim[i] == 2 && out.node_entity_tag[i] == kSym) {
          ++sym_nodes;
          if (!(std::abs(out.node_u[i] - out.x[i]) < 1e-12 && std::abs(out.node_v[i] - out.y[i]) < 1e-12)) ++sym_bad;
          if (std::abs(out.z[i] - 1.0) > 1e-12) ++sym_bad;
        }
      CHECK(sym_bad == 0);
      CHECK(sym_nodes == std::size_t(12 * P) * (L * P + 1));
      if (L == 10 && P == 4)
        MESSAGE("junction P=4, 10 layers: " << J.prisms_a + J.prisms_c << " macro prisms + " << J.hexes << " junction hexes + "
                                            << J.tets << " tets -> " << np << " prisms + " << nh << " hexes; nodes "
                                            << in.num_nodes() << " -> " << out.num_nodes() << ", max aspect ratio "
                                            << q["max_aspect_ratio"] << ", min scaled Jacobian " << q["min_scaled_jacobian"]);
    }
  }
}

TEST_CASE("determinism: identical bytes at 1, 2 and 4 threads") {
  auto J = junction_mesh(3);
  auto d = tmpdir("det");
  std::string ref;
  for (int th : {1, 2, 4}) {
    Options o;
    o.layers = 7;
    o.ratio = 1.3;
    auto r = split_mesh(J.mesh, o, th);
    auto p = d / ("t" + std::to_string(th) + ".msh");
    meshflow::io::write_mesh(r.mesh, p, meshflow::io::MeshFormat::MshBinary);
    std::string s = mftest::read_text(p);
    REQUIRE(s.size() > 1000);
    if (ref.empty()) ref = s;
    CHECK(s == ref);
  }
  std::filesystem::remove_all(d);
}

TEST_CASE("consuming the input (split_mesh(Mesh&&)): the same bytes as splitting a copy, the input's nodes released") {
  auto J = junction_mesh(3);
  auto d = tmpdir("consume");
  Options o;
  o.layers = 5;
  o.ratio = 1.4;
  auto kept = split_mesh(J.mesh, o, 2);
  Mesh in = J.mesh;
  auto consumed = split_mesh(std::move(in), o, 2);
  CHECK(in.x.empty());
  CHECK(in.node_u.empty());
  CHECK(consumed.passed_through == kept.passed_through);
  CHECK(consumed.stats.nodes_out == kept.stats.nodes_out);
  meshflow::io::write_mesh(kept.mesh, d / "kept.msh", meshflow::io::MeshFormat::MshBinary);
  meshflow::io::write_mesh(consumed.mesh, d / "consumed.msh", meshflow::io::MeshFormat::MshBinary);
  const std::string a = mftest::read_text(d / "kept.msh"), b = mftest::read_text(d / "consumed.msh");
  REQUIRE(a.size() > 1000);
  CHECK(a == b);
  std::filesystem::remove_all(d);
}

TEST_CASE("refusals: no wall, a prism without a wall face, order mismatch, opposite wall faces, a non-conforming split") {
  auto J = junction_mesh(2, 8, false);
  Options o;
  o.layers = 3;
  {  // no wall group
    Mesh m = J.mesh;
    for (auto& g : m.physicals)
      if (g.name == "wall") g.name = "body";
    try {
      split_mesh(m, o, 1);
      FAIL("expected a StageError");
    } catch (const StageError& e) {
      CHECK(std::string(e.what()).find("no wall faces") != std::string::npos);
    }
  }
  {  // drop the cylinder's wall triangles: A's prisms have no wall face
    Mesh m = J.mesh;
    for (auto& b : m.blocks)
      if (b.shape == Shape::Tri && b.entity_tag == kWall) b.nodes.clear();
    try {
      split_mesh(m, o, 1);
      FAIL("expected a StageError");
    } catch (const StageError& e) {
      CHECK(std::string(e.what()).find("no triangular face on a wall") != std::string::npos);
    }
  }
  {  // a boundary block of another order
    Mesh m = J.mesh;
    m.block(Shape::Line, 1, 1, kLine).add({0, 1});
    CHECK_THROWS_AS(split_mesh(m, o, 1), StageError);
  }
  {  // opposite wall faces of a hex
    Mesh m;
    add_groups(m);
    std::vector<std::uint32_t> ids;
    for (auto& x : meshflow::model::reference_nodes(Shape::Hex, 1)) ids.push_back(m.add_node(x[0], x[1], 0.1 * x[2]));
    m.block(Shape::Hex, 1, 3, kVol).add(ids.data());
    for (int f : {0, 5}) {
      std::vector<std::uint32_t> w;
      for (int k : meshflow::model::face_nodes(Shape::Hex, 1)[f]) w.push_back(ids[k]);
      m.block(Shape::Quad, 1, 2, kWall).add(w.data());
    }
    try {
      split_mesh(m, o, 1);
      FAIL("expected a StageError");
    } catch (const StageError& e) {
      CHECK(std::string(e.what()).find("opposite faces") != std::string::npos);
    }
  }
  {  // two stacked prisms sharing a quad face but walls on opposite sides: the shared face
     // would be split from different ends -> non-conforming -> refused
    Mesh m;
    add_groups(m);
    const int P = 1;
    // prism A: triangle (0,0),(1,0),(0,1) z in [0,1], wall at z=0; prism B: triangle
    // (1,0),(1,1),(0,1) z in [0,1], wall at z=1. They share the quad face over edge (1,0)-(0,1).
    std::uint32_t v[8];
    double xy[4][2] = {{0, 0}, {1, 0}, {0, 1}, {1, 1}};
    for (int k = 0; k < 4; ++k) v[k] = m.add_node(xy[k][0], xy[k][1], 0), v[4 + k] = m.add_node(xy[k][0], xy[k][1], 1);
    m.block(Shape::Prism, P, 3, kVol).add({v[0], v[1], v[2], v[4], v[5], v[6]});
    m.block(Shape::Prism, P, 3, kVol).add({v[1], v[3], v[2], v[5], v[7], v[6]});
    m.block(Shape::Tri, P, 2, kWall).add({v[0], v[2], v[1]});
    m.block(Shape::Tri, P, 2, kWall).add({v[5], v[7], v[6]});
    REQUIRE(meshflow::model::build_topology(m).nonconforming_faces == 0);
    Options o2;
    o2.layers = 4;
    o2.ratio = 2;
    try {
      split_mesh(m, o2, 1);
      FAIL("expected a StageError");
    } catch (const StageError& e) {
      CHECK(std::string(e.what()).find("non-conforming") != std::string::npos);
    }
    try {  // the same, consuming a copy: the message still says where (from the output's nodes)
      Mesh c = m;
      split_mesh(std::move(c), o2, 1);
      FAIL("expected a StageError");
    } catch (const StageError& e) {
      CHECK(std::string(e.what()).find("non-conforming") != std::string::npos);
      CHECK(std::string(e.what()).find("near (") != std::string::npos);
    }
    o2.ratio = 1;  // uniform: both ends give the same points, but keys still differ -> refused
    CHECK_THROWS_AS(split_mesh(m, o2, 1), StageError);
  }
}

TEST_CASE("periodic: a channel of prisms on a flat wall, periodic in y: the new nodes of the split periodic faces are linked to their masters") {
  for (int P : {1, 3})
  for (bool edge_links : {false, true}) {
    const int Nx = 4, Ny = 3;
    const double T = 0.2;
    Mesh m;
    add_groups(m);
    m.add_physical(2, 5, "periodic_lo");
    m.add_physical(2, 6, "periodic_hi");
    m.add_entity(2, 30, {5});
    m.add_entity(2, 31, {6});
    std::map<std::array<int, 3>, std::uint32_t> at;
    auto node = [&](int i, int j, int k) {
      auto it = at.find({i, j, k});
      if (it != at.end()) return it->second;
      double x = 2.0 * i / (Nx * P), y = double(j) / (Ny * P), z = T * k / P;
      // a gentle bump of the wall along x keeps the elements curved (periodic in y)
      std::uint32_t id = m.add_node(x, y, z + 0.05 * std::sin(kPi * x) * (1 - double(k) / (2 * P)));
      return at[{i, j, k}] = id;
    };
    const auto& plat = meshflow::model::lattice(Shape::Prism, P);
    for (int ci = 0; ci < Nx; ++ci)
      for (int cj = 0; cj < Ny; ++cj) {
        int i0 = ci * P, i1 = i0 + P, j0 = cj * P, j1 = j0 + P;
        for (auto tri : {std::array<std::array<int, 2>, 3>{{{i0, j0}, {i1, j0}, {i1, j1}}},
                         std::array<std::array<int, 2>, 3>{{{i0, j0}, {i1, j1}, {i0, j1}}}}) {
          std::vector<std::uint32_t> ids;
          for (auto& l : plat)
            ids.push_back(node(tri[0][0] + ((tri[1][0] - tri[0][0]) * l[0] + (tri[2][0] - tri[0][0]) * l[1]) / P,
                               tri[0][1] + ((tri[1][1] - tri[0][1]) * l[0] + (tri[2][1] - tri[0][1]) * l[1]) / P, l[2]));
          m.block(Shape::Prism, P, 3, kVol).add(ids.data());
          std::vector<std::uint32_t> w;
          for (int k : meshflow::model::face_nodes(Shape::Prism, P)[0]) w.push_back(ids[k]);
          m.block(Shape::Tri, P, 2, kWall).add(w.data());
        }
      }
    for (int side = 0; side < 2; ++side)
      for (int ci = 0; ci < Nx; ++ci) {
        std::vector<std::uint32_t> q;
        for (auto& l : meshflow::model::lattice(Shape::Quad, P)) q.push_back(node(ci * P + l[0], side * Ny * P, l[1]));
        m.block(Shape::Quad, P, 2, side ? 31 : 30).add(q.data());
      }
    meshflow::model::PeriodicLink link;
    link.dim = 2, link.tag = 31, link.master_tag = 30;
    // edge_links: as sweep writes it, the face's link has only the nodes inside the face and the
    // nodes on its boundary (the wall line k = 0, the ends i = 0 and i = Nx P) are in a link of
    // their own (a CAD edge's), which split must consult for the split faces' corner masters
    meshflow::model::PeriodicLink elink;
    elink.dim = 1, elink.tag = 41, elink.master_tag = 40;
    for (int i = 0; i <= Nx * P; ++i)
      for (int k = 0; k <= P; ++k) {
        bool boundary = k == 0 || i == 0 || i == Nx * P;
        (edge_links && boundary ? elink : link).nodes.emplace_back(node(i, Ny * P, k), node(i, 0, k));
      }
    m.periodic.push_back(link);
    if (edge_links) m.add_entity(1, 40), m.add_entity(1, 41), m.periodic.push_back(elink);
    m.check();
    REQUIRE(meshflow::model::mesh_stats(m, 1)["invalid"] == 0);
    Options o;
    o.layers = 5;
    o.ratio = 2;
    auto r = split_mesh(m, o, 2);
    const Mesh& out = r.mesh;
    REQUIRE(out.periodic.size() == (edge_links ? 2u : 1u));
    std::vector<std::pair<std::uint32_t, std::uint32_t>> pl;
    for (auto& L : out.periodic) pl.insert(pl.end(), L.nodes.begin(), L.nodes.end());
    CAPTURE(P);
    CAPTURE(edge_links);
    CHECK(pl.size() == std::size_t(Nx * P + 1) * (5 * P + 1));
    CHECK(r.stats.periodic_pairs_added == std::size_t(Nx * P + 1) * (5 * P - 1));
    double worst = 0;
    std::set<std::uint32_t> slaves;
    for (auto [s, mm] : pl) {
      worst = std::max({worst, std::abs(out.x[s] - out.x[mm]), std::abs(out.y[s] - out.y[mm] - 1.0), std::abs(out.z[s] - out.z[mm])});
      slaves.insert(s);
    }
    CHECK(worst < 1e-12);
    std::size_t on_hi = 0;
    for (std::size_t i = 0; i < out.num_nodes(); ++i) on_hi += std::abs(out.y[i] - 1.0) < 1e-14;
    CHECK(on_hi == slaves.size());
    CHECK(meshflow::model::mesh_stats(out, 1)["invalid"] == 0);
  }
}
