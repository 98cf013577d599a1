// The curve stage on small meshes built in the tests (builders.hpp) on OCCT shapes
// (shapes.cpp): a sphere (poles, seam) and a cylinder (seam, circles, planes) in a shell of
// fluid, each with one thin layer of prisms on the wall and tets outside.
#include <doctest/doctest.h>

#include "builders.hpp"
#include "engine/stage.hpp"
#include "stages/curve/curve.hpp"
#include "stages/io/mesh_io.hpp"
#include "stages/model/basis.hpp"
#include "stages/model/quality.hpp"
#include "stages/model/topology.hpp"

#include <nlohmann/json.hpp>

#include <cmath>
#include <fstream>
#include <iostream>
#include <sstream>
#include <unistd.h>

using namespace curvetest;
namespace mc = meshflow::curve;
namespace model = meshflow::model;

namespace {

struct Case {
  meshflow::cad::Shape shape;
  Built built;
};
Case sphere_case(int na = 16, int nb = 8, double thickness = 0.05, int far_layers = 3) {
  Case c{sphere_shell(1.0, 3.0), {}};
  c.built = build(c.shape, sphere_grid(na, nb, 1.0, thickness, 3.0, far_layers));
  return c;
}
Case cylinder_case(int na = 16, int nb = 3, double thickness = 0.05, int far_layers = 3) {
  Case c{cylinder_shell(1.0, 3.0, 1.0), {}};
  c.built = build(c.shape, cylinder_grid(na, nb, 1.0, thickness, 3.0, 1.0, far_layers));
  return c;
}

model::Mesh curve(const Case& c, int P, mc::Report& r, bool follow = true, int threads = 1) {
  mc::Options o;
  o.order = P;
  o.follow_wall = follow;
  o.threads = threads;
  return mc::curve_mesh(c.built.mesh, c.shape, o, r);
}

// Every high-order node of every element edge stays near its straight position (a folded
// edge at a seam or a pole would wrap around the body); returns the worst ratio
// |node - straight| / edge length.
double worst_edge_bulge(const model::Mesh& m) {
  double worst = 0;
  for (auto& b : m.blocks) {
    if (b.order < 2) continue;
    const int P = b.order;
    for (std::size_t e = 0; e < b.size(); ++e) {
      const auto* o = b.element(e);
      for (auto& en : model::edge_nodes(b.shape, P)) {
        double ax = m.x[o[en[0]]], ay = m.y[o[en[0]]], az = m.z[o[en[0]]];
        double bx = m.x[o[en[1]]], by = m.y[o[en[1]]], bz = m.z[o[en[1]]];
        double len = std::hypot(bx - ax, by - ay, bz - az);
        for (std::size_t k = 2; k < en.size(); ++k) {
          double s = double(k - 1) / P;
          auto n = o[en[k]];
          double d = std::hypot(m.x[n] - (ax + s * (bx - ax)), m.y[n] - (ay + s * (by - ay)), m.z[n] - (az + s * (bz - az)));
          worst = std::max(worst, d / len);
        }
      }
    }
  }
  return worst;
}

// Largest distance of a node classified on a CAD curve/face from the point its parameters give.
double worst_parameter_gap(const model::Mesh& m, const meshflow::cad::Shape& S) {
  double worst = 0;
  for (std::size_t n = 0; n < m.num_nodes(); ++n) {
    meshflow::cad::Vec3 p{};
    if (m.node_entity_dim[n] == 1) p = S.edge_point(m.node_entity_tag[n] - 1, m.node_u[n]);
    else if (m.node_entity_dim[n] == 2) p = S.face_point(m.node_entity_tag[n] - 1, m.node_u[n], m.node_v[n]);
    else continue;
    worst = std::max(worst, std::hypot(p.x - m.x[n], p.y - m.y[n], p.z - m.z[n]));
  }
  return worst;
}

}  // namespace

TEST_CASE("curve: sphere and cylinder, P = 2..6: nodes on the CAD, every element valid, conforming") {
  for (int which = 0; which < 2; ++which) {
    Case c = which == 0 ? sphere_case() : cylinder_case();
    for (int P = 2; P <= 6; ++P) {
      INFO(std::string(which == 0 ? "sphere" : "cylinder") << " P=" << P);
      mc::Report r;
      auto m = curve(c, P, r);
      CHECK(m.order() == P);
      CHECK(r.invalid_linear == 0);
      CHECK(r.invalid == 0);
      CHECK(r.max_distance_curve < 1e-7);
      CHECK(r.max_distance_surface < 1e-7);
      CHECK(r.fallback_projections == 0);
      CHECK(r.nodes_on_surfaces > 0);
      CHECK(model::build_topology(m).nonconforming_faces == 0);
      if (which == 1) CHECK(r.nodes_on_curves > 0);
      if (which == 0) CHECK(r.pole_ends > 0);
      CHECK(r.seam_choices > 0);
      CHECK(worst_parameter_gap(m, c.shape) < 1e-9);
      CHECK(worst_edge_bulge(m) < 0.25);
      MESSAGE(r.to_json().dump());
    }
  }
}

TEST_CASE("curve: a thin layer on a coarse wall is valid only when the shell face follows the wall") {
  // 8 divisions around the cylinder (45 degrees): the wall bulges 0.076 beyond each chord, the
  // layer is 0.01 thick, so a prism with a straight outer face inverts. (Two far-field layers:
  // the tets on the shell are as thick as they are wide, so its curvature does not invert them.)
  for (int which = 0; which < 2; ++which) {
    Case c = which == 0 ? cylinder_case(8, 2, 0.01, 2) : sphere_case(8, 4, 0.01, 2);
    INFO(std::string(which == 0 ? "cylinder" : "sphere"));
    for (int P : {2, 4}) {
      INFO("P=" << P);
      mc::Report straight, follow;
      curve(c, P, straight, false);
      auto m = curve(c, P, follow, true);
      CHECK(straight.invalid_near_field > 0);
      CHECK(follow.invalid_near_field == 0);
      // on the cylinder the whole mesh is valid; on this very coarse sphere (45 degree cells,
      // faces bulging 0.15 into far-field tets 0.7 thick and sheared by the prism split) some
      // far-field tets on the shell are not: that is left to optimise
      if (which == 0) CHECK(follow.invalid == 0);
      MESSAGE(std::string(which == 0 ? "cylinder" : "sphere") << " P=" << P << ": straight outer face: " << straight.invalid_near_field
              << " of " << c.built.prisms << " prisms invalid; following the wall: " << follow.invalid_near_field << " (far field: "
              << follow.invalid - follow.invalid_near_field << ")");
      CHECK(follow.near_field_prisms == c.built.prisms);
      CHECK(follow.invalid_linear == 0);
    }
  }
}

TEST_CASE("curve: the shell face of each prism is the wall face plus the linearly interpolated layer vector") {
  for (int which = 0; which < 2; ++which) {
    Case c = which == 0 ? cylinder_case(12, 3, 0.05) : sphere_case(12, 6, 0.05);
    mc::Report r;
    const int P = 4;
    auto m = curve(c, P, r);
    const auto& ref = model::reference_nodes(Shape::Prism, P);
    std::size_t checked = 0;
    double worst = 0, worst_edge = 0;
    for (auto& b : m.blocks) {
      if (b.shape != Shape::Prism) continue;
      for (std::size_t e = 0; e < b.size(); ++e) {
        const auto* o = b.element(e);
        for (int i = 0; i < int(ref.size()); ++i) {
          double x = ref[i][0], y = ref[i][1], z = ref[i][2];
          // wall counterpart
          int j = -1;
          for (int k = 0; k < int(ref.size()); ++k)
            if (std::abs(ref[k][0] - x) < 1e-12 && std::abs(ref[k][1] - y) < 1e-12 && std::abs(ref[k][2] + 1) < 1e-12) j = k;
          REQUIRE(j >= 0);
          double w[3] = {1 - x - y, x, y}, t = (z + 1) / 2;
          for (int c3 = 0; c3 < 3; ++c3) {
            auto X = [&](std::uint32_t n) { return c3 == 0 ? m.x[n] : c3 == 1 ? m.y[n] : m.z[n]; };
            double L = 0;
            for (int v = 0; v < 3; ++v) L += w[v] * (X(o[v + 3]) - X(o[v]));
            double gap = std::abs(X(o[i]) - (X(o[j]) + t * L));
            worst = std::max(worst, gap);
            if (std::abs(x) < 1e-12 && std::abs(y) < 1e-12) worst_edge = std::max(worst_edge, gap);  // a layer edge: straight
          }
          ++checked;
        }
      }
    }
    CHECK(checked > 0);
    CHECK(worst < 1e-12);
    CHECK(worst_edge < 1e-12);
  }
}

TEST_CASE("curve: an element with no curved boundary stays exactly straight") {
  Case c = sphere_case(12, 6, 0.05);  // far-field layers: r = 1.05 .. 3 in three layers of tets
  mc::Report r;
  const int P = 4;
  auto m = curve(c, P, r);
  const auto& ref = model::reference_nodes(Shape::Tet, P);
  const auto& b1 = model::LagrangeBasis::get(Shape::Tet, 1);
  std::size_t straight = 0, curved = 0;
  for (auto& b : m.blocks) {
    if (b.shape != Shape::Tet) continue;
    for (std::size_t e = 0; e < b.size(); ++e) {
      const auto* o = b.element(e);
      // touches the shell (r = 1.05) or the outer sphere (r = 3)?
      bool touches = false;
      for (int v = 0; v < 4; ++v) {
        double rr = std::hypot(m.x[o[v]], m.y[o[v]], m.z[o[v]]);
        touches = touches || std::abs(rr - 1.05) < 1e-9 || std::abs(rr - 3.0) < 1e-9;
      }
      double X[12];
      for (int v = 0; v < 4; ++v) X[3 * v] = m.x[o[v]], X[3 * v + 1] = m.y[o[v]], X[3 * v + 2] = m.z[o[v]];
      double worst = 0;
      for (int i = 4; i < int(ref.size()); ++i) {
        auto p = model::map_point(b1, X, ref[i]);
        worst = std::max({worst, std::abs(p[0] - m.x[o[i]]), std::abs(p[1] - m.y[o[i]]), std::abs(p[2] - m.z[o[i]])});
      }
      if (!touches) {
        CHECK(worst < 1e-12);
        ++straight;
      } else if (worst > 1e-6) {
        ++curved;
      }
    }
  }
  CHECK(straight > 0);
  CHECK(curved > 0);
}

TEST_CASE("curve: same bytes at 1 and 2 threads and on a second run") {
  Case c = sphere_case(12, 6, 0.05);
  auto dir = std::filesystem::temp_directory_path() / ("meshflow-curve-det-" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  std::vector<std::string> bytes;
  for (int th : {1, 2, 2}) {
    mc::Report r;
    auto m = curve(c, 4, r, true, th);
    auto f = dir / ("m" + std::to_string(bytes.size()) + ".msh");
    meshflow::io::write_mesh(m, f, meshflow::io::MeshFormat::MshBinary);
    std::ifstream in(f, std::ios::binary);
    std::stringstream ss;
    ss << in.rdbuf();
    bytes.push_back(ss.str());
  }
  CHECK(bytes[0].size() > 1000);
  CHECK(bytes[0] == bytes[1]);
  CHECK(bytes[1] == bytes[2]);
  // the artifact keeps the classification and the parameters
  auto back = meshflow::io::read_mesh(dir / "m0.msh");
  CHECK(back.order() == 4);
  CHECK(worst_parameter_gap(back, c.shape) < 1e-9);
  std::filesystem::remove_all(dir);
}

TEST_CASE("curve: bad input is refused with a clear message") {
  Case c = cylinder_case(8, 2, 0.05);
  mc::Report r;
  auto msg = [&](const model::Mesh& m, int P) -> std::string {
    mc::Options o;
    o.order = P;
    try {
      mc::curve_mesh(m, c.shape, o, r);
    } catch (const meshflow::StageError& e) {
      return e.what();
    }
    return "";
  };
  CHECK(msg(c.built.mesh, 7).find("order 7 is outside 2..6") != std::string::npos);
  CHECK(msg(c.built.mesh, 1).find("order 1 is outside 2..6") != std::string::npos);
  model::Mesh bare = c.built.mesh;
  bare.node_entity_dim.clear(), bare.node_entity_tag.clear(), bare.node_u.clear(), bare.node_v.clear();
  CHECK(msg(bare, 4).find("no CAD classification") != std::string::npos);
  model::Mesh vol = c.built.mesh;
  for (auto& d : vol.node_entity_dim) d = 3;
  CHECK(msg(vol, 4).find("no node of the input mesh lies on the CAD") != std::string::npos);
  auto quad = curve(c, 2, r);
  CHECK(msg(quad, 4).find("already of order 2") != std::string::npos);
  model::Mesh wrong = c.built.mesh;
  for (auto& b : wrong.blocks)
    if (b.entity_dim == 2) b.entity_tag = 99;
  CHECK(msg(wrong, 4).find("was not made from this shape") != std::string::npos);
  model::Mesh badt = c.built.mesh;
  for (std::size_t n = 0; n < badt.num_nodes(); ++n)
    if (badt.node_entity_dim[n] == 1) {
      badt.node_u[n] += 100;
      break;
    }
  CHECK(msg(badt, 4).find("outside the edge's range") != std::string::npos);
}

// A face whose parameter range straddles its surface's seam but which has no seam edge (a
// cylinder sector, u in [-pi/3, pi/3]; Rotor 67's hub and casing sectors): node parameters may be given
// in any period (the mesh contract), here u in [0, 2 pi) as a projection answers, so the nodes
// on either side of u = 0 are a period apart in (u,v). Interpolating across without unwrapping
// goes the long way round: the high-order nodes land on the far side of the cylinder, on the CAD.
TEST_CASE("curve: a face straddling its surface's seam without a seam edge does not fold") {
  auto S = cylinder_sector_face(1.0, 1.0, kPi / 3);
  int f = -1;
  for (int k = 0; k < S.num_faces(); ++k)
    if (S.face_tag(k) == meshflow::cad::Tag::wall) f = k;
  REQUIRE(f >= 0);
  REQUIRE(std::abs(S.face_periods(f)[0] - 2 * kPi) < 1e-9);
  for (int e : S.face_edges(f)) REQUIRE_FALSE(S.edge_is_seam(e, f));
  // a (theta, z) grid on the wall, theta in [-pi/3, pi/3], classified by projection
  const int na = 8, nb = 2;
  model::Mesh m;
  std::vector<std::uint32_t> id;
  for (int j = 0; j <= nb; ++j)
    for (int i = 0; i <= na; ++i) {
      double th = -kPi / 3 + 2 * kPi / 3 * i / na;
      id.push_back(m.add_node(std::cos(th), std::sin(th), double(j) / nb));
    }
  const std::size_t N = m.num_nodes();
  m.node_entity_dim.assign(N, 2), m.node_entity_tag.assign(N, f + 1), m.node_u.assign(N, NAN), m.node_v.assign(N, NAN);
  int below = 0, above = 0;
  for (std::size_t n = 0; n < N; ++n) {
    meshflow::cad::Vec3 p{m.x[n], m.y[n], m.z[n]};
    bool done = false;
    for (int v = 0; v < S.num_vertices() && !done; ++v) {
      auto q = S.vertex_point(v);
      if (std::hypot(q.x - p.x, q.y - p.y, q.z - p.z) < 1e-9) m.node_entity_dim[n] = 0, m.node_entity_tag[n] = v + 1, done = true;
    }
    for (int e : S.face_edges(f)) {
      double t = 0;
      if (!done && on_edge(S, e, p, 1e-9, t)) m.node_entity_dim[n] = 1, m.node_entity_tag[n] = e + 1, m.node_u[n] = t, done = true;
    }
    if (done) continue;
    auto pr = S.project_to_face(f, p);
    REQUIRE(pr.distance < 1e-9);
    double u = std::fmod(pr.u, 2 * kPi);
    if (u < 0) u += 2 * kPi;
    (u < kPi ? below : above)++;
    m.node_u[n] = u, m.node_v[n] = pr.v;
  }
  REQUIRE(below > 0);  // both representations occur
  REQUIRE(above > 0);
  for (int v = 0; v < S.num_vertices(); ++v) m.add_entity(0, v + 1);
  for (int e = 0; e < S.num_edges(); ++e) m.add_entity(1, e + 1);
  m.add_physical(2, 1, "wall");
  for (int k = 0; k < S.num_faces(); ++k) m.add_entity(2, k + 1, k == f ? std::vector<int>{1} : std::vector<int>{});
  auto& tri = m.block(model::Shape::Tri, 1, 2, f + 1);
  for (int j = 0; j < nb; ++j)
    for (int i = 0; i < na; ++i) {
      auto a = id[j * (na + 1) + i], b = id[j * (na + 1) + i + 1], c = id[(j + 1) * (na + 1) + i + 1], d = id[(j + 1) * (na + 1) + i];
      tri.add({a, b, c}), tri.add({a, c, d});
    }
  m.check();
  for (int P : {2, 4}) {
    INFO("P=" << P);
    mc::Options o;
    o.order = P;
    mc::Report r;
    auto out = mc::curve_mesh(m, S, o, r);
    CHECK(r.fallback_projections == 0);
    CHECK(r.max_distance_surface < 1e-7);
    CHECK(worst_parameter_gap(out, S) < 1e-9);
    // the chord of a pi/12 arc sags 0.016 of its length: a node a period away bulges by ~1
    CHECK(worst_edge_bulge(out) < 0.05);
  }
}
