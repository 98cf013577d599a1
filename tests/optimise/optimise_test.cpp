// The optimise algorithm (stages/optimise/optimise.hpp) on curved meshes built here on an
// OCCT sphere and cylinder with badly placed high-order nodes.
#include <doctest/doctest.h>

#include "builders.hpp"
#include "engine/stage.hpp"
#include "stages/io/mesh_io.hpp"
#include "stages/model/element.hpp"
#include "stages/model/quality.hpp"
#include "stages/model/topology.hpp"
#include "stages/optimise/optimise.hpp"
#include "stages/optimise/untangle.hpp"

#include <nlohmann/json.hpp>

#include <atomic>
#include <cmath>
#include <fstream>
#include <sstream>
#include <unistd.h>

using meshflow::cad::Shape;
using meshflow::model::Mesh;
namespace model = meshflow::model;
namespace opt = meshflow::optimise;
namespace fs = std::filesystem;

namespace {

fs::path scratch() {
  static std::atomic<int> n{0};
  auto d = fs::temp_directory_path() / ("meshflow-opt-" + std::to_string(getpid()) + "-" + std::to_string(n++));
  fs::create_directories(d);
  return d;
}

struct Shapes {
  fs::path dir = scratch();
  Shape sphere, cylinder;
  Shapes() {
    opttest::save_sphere(dir / "sphere.mfshape");
    opttest::save_cylinder(dir / "cyl.mfshape");
    sphere = Shape::load(dir / "sphere.mfshape");
    cylinder = Shape::load(dir / "cyl.mfshape");
  }
  ~Shapes() { fs::remove_all(dir); }
};
Shapes& shapes() {
  static Shapes s;
  return s;
}

struct P3 {
  double x, y, z;
};
P3 at(const Mesh& m, std::uint32_t n) { return {m.x[n], m.y[n], m.z[n]}; }
double dist(P3 a, P3 b) { return std::hypot(a.x - b.x, a.y - b.y, a.z - b.z); }

// For every high-order edge of the 2D elements: ratio longest/shortest chord between
// consecutive nodes (worst over edges).
double worst_chord_ratio(const Mesh& m) {
  double worst = 1;
  for (const auto& b : m.blocks) {
    if (model::dimension(b.shape) != 2) continue;
    for (std::size_t e = 0; e < b.size(); ++e)
      for (const auto& ed : model::edge_nodes(b.shape, b.order)) {
        std::vector<std::uint32_t> chain = {b.element(e)[ed[0]]};
        for (std::size_t q = 2; q < ed.size(); ++q) chain.push_back(b.element(e)[ed[q]]);
        chain.push_back(b.element(e)[ed[1]]);
        double lo = 1e300, hi = 0;
        for (std::size_t q = 0; q + 1 < chain.size(); ++q) {
          double L = dist(at(m, chain[q]), at(m, chain[q + 1]));
          lo = std::min(lo, L), hi = std::max(hi, L);
        }
        worst = std::max(worst, hi / lo);
      }
  }
  return worst;
}

std::size_t invalid_count(const Mesh& m) {
  std::size_t n = 0;
  for (auto& b : model::mesh_quality(m, 1))
    for (auto& q : b) n += !q.valid;
  return n;
}

}  // namespace

TEST_CASE("sphere patch P=4: energy drops, nodes stay on the sphere within bounds, edges become equally spaced geodesics") {
  const Shape& s = shapes().sphere;
  opttest::Distortion d;
  d.bunch = 0.35, d.bump = 0.1, d.interior_u = 0.05, d.interior_v = 0.03;
  Mesh m = opttest::sphere_patch(s, 4, {}, d);
  REQUIRE(invalid_count(m) == 0);
  const double ratio_before = worst_chord_ratio(m);
  CHECK(ratio_before > 1.5);  // the test mesh is really bad
  opt::Report r = opt::optimise_mesh(m, s, {}, 1);
  MESSAGE("energy " << r.energy_before << " -> " << r.energy_after << ", chord ratio " << ratio_before << " -> "
                    << worst_chord_ratio(m) << ", iterations " << r.iterations << " max " << r.max_unit_iterations
                    << ", moved " << r.nodes_moved << ", dist " << r.max_cad_distance);
  CHECK(r.surface_edges > 0);
  CHECK(r.faces == 24);
  CHECK(r.energy_after < 0.9 * r.energy_before);
  CHECK(r.max_cad_distance < 1e-7);
  CHECK(opttest::max_param_error(m, s) < 1e-7);
  CHECK(r.invalid_before == 0);
  CHECK(r.invalid_after == 0);
  CHECK(invalid_count(m) == 0);
  CHECK(worst_chord_ratio(m) < 1.01);
  auto fb = s.face_uv_bounds(0);
  double plane = 0;
  for (std::size_t i = 0; i < m.num_nodes(); ++i) {
    CHECK(std::abs(std::hypot(m.x[i], m.y[i], m.z[i]) - 1.0) < 1e-9);
    CHECK((m.node_u[i] >= fb.u0 && m.node_u[i] <= fb.u1 && m.node_v[i] >= fb.v0 && m.node_v[i] <= fb.v1));
  }
  // every edge's nodes lie on the great circle through its ends (the geodesic)
  for (const auto& b : m.blocks)
    for (std::size_t e = 0; e < b.size(); ++e)
      for (const auto& ed : model::edge_nodes(b.shape, b.order)) {
        P3 a = at(m, b.element(e)[ed[0]]), c = at(m, b.element(e)[ed[1]]);
        P3 n{a.y * c.z - a.z * c.y, a.z * c.x - a.x * c.z, a.x * c.y - a.y * c.x};
        double L = std::hypot(n.x, n.y, n.z);
        for (std::size_t q = 2; q < ed.size(); ++q) {
          P3 p = at(m, b.element(e)[ed[q]]);
          plane = std::max(plane, std::abs(p.x * n.x + p.y * n.y + p.z * n.z) / L);
        }
      }
  MESSAGE("distance to the great circles " << plane);
  CHECK(plane < 1e-6);
}

TEST_CASE("cylinder with a seam, P=3 quads: circle edges equally spaced in angle, seam and line edges in range, all on the CAD") {
  const Shape& s = shapes().cylinder;
  opttest::Distortion d;
  d.bunch = 0.4, d.bump = 0.08, d.interior_u = 0.05, d.interior_v = 0.05;
  Mesh m = opttest::cylinder_quads(s, 3, 8, 3, d);
  REQUIRE(invalid_count(m) == 0);
  Mesh before = m;
  opt::Report r = opt::optimise_mesh(m, s, {}, 1);
  MESSAGE("energy " << r.energy_before << " -> " << r.energy_after << ", units " << r.curve_edges << "/" << r.surface_edges
                    << "/" << r.faces << ", chord ratio " << worst_chord_ratio(before) << " -> " << worst_chord_ratio(m));
  CHECK(r.curve_edges == 8 + 8 + 3);  // two circles and the seam
  CHECK(r.surface_edges == 8 * 2 + 7 * 3);
  CHECK(r.faces == 24);
  CHECK(r.skipped_inconsistent + r.skipped_seam == 0);
  CHECK(r.energy_after < r.energy_before);
  CHECK(r.max_cad_distance < 1e-7);
  CHECK(opttest::max_param_error(m, s) < 1e-7);
  CHECK(r.invalid_after == 0);
  CHECK(worst_chord_ratio(before) > 1.7);
  CHECK(worst_chord_ratio(m) < 1.0001);  // circle arcs and straight generators: exactly equal chords
  // nodes on the circles and the seam: parameters within the edge; circles keep z, the seam
  // keeps x and y; all keep the radius
  for (const auto& b : m.blocks) {
    if (b.shape != model::Shape::Line) continue;
    auto rg = s.edge_range(b.entity_tag - 1);
    const bool circle = s.edge_curve_type(b.entity_tag - 1) == "circle";
    for (std::size_t e = 0; e < b.size(); ++e)
      for (int q = 2; q < b.nodes_per_element(); ++q) {
        auto n = b.element(e)[q];
        CHECK(m.node_entity_dim[n] == 1);
        CHECK((m.node_u[n] > rg.lo && m.node_u[n] < rg.hi));
        if (circle) CHECK(m.z[n] == doctest::Approx(before.z[n]).epsilon(1e-12));
        else CHECK((m.x[n] == doctest::Approx(before.x[n]).epsilon(1e-12) && m.y[n] == doctest::Approx(before.y[n]).epsilon(1e-12)));
        CHECK(std::hypot(m.x[n], m.y[n]) == doctest::Approx(1.0).epsilon(1e-12));
      }
  }
}

TEST_CASE("prisms on the sphere: volume nodes follow by blending, every prism stays valid, the mesh stays conforming") {
  const Shape& s = shapes().sphere;
  opttest::Distortion d;
  d.bunch = 0.35, d.bump = 0.1, d.interior_u = 0.05, d.interior_v = 0.03;
  Mesh m = opttest::sphere_patch(s, 4, {}, d, 0.05);
  REQUIRE(invalid_count(m) == 0);
  Mesh before = m;
  opt::Report r = opt::optimise_mesh(m, s, {}, 1);
  MESSAGE("prisms: energy " << r.energy_before << " -> " << r.energy_after << ", blended " << r.nodes_blended
                            << ", checked " << r.elements_checked << ", backtracked " << r.backtracked_units);
  CHECK(r.elements_checked == 24);
  CHECK(r.nodes_blended > 0);
  CHECK(r.invalid_after == 0);
  CHECK(invalid_count(m) == 0);
  CHECK(r.energy_after < 0.9 * r.energy_before);
  CHECK(model::build_topology(m).nonconforming_faces == 0);
  // top vertices and top-face edge nodes (not on the CAD, on unmoved edges) did not move; a
  // blended layer node moved less than the wall node below it
  std::size_t moved_volume = 0;
  for (std::size_t i = 0; i < m.num_nodes(); ++i)
    if (m.node_entity_dim[i] == 3) moved_volume += m.x[i] != before.x[i] || m.y[i] != before.y[i] || m.z[i] != before.z[i];
  CHECK(moved_volume == r.nodes_blended);
}

TEST_CASE("validity guard: a move that would invert an element is backtracked, and without the guard it does invert") {
  // One cell (two P=3 triangles); the first triangle's bottom edge bows outwards and its interior
  // node sits in that bow, beyond the straight chord. With faces off (the interior node stays),
  // straightening the edge onto the geodesic puts the interior node outside: inverted.
  const Shape& s = shapes().sphere;
  opttest::Distortion d;
  d.bunch = 0.0, d.bump = -0.4, d.interior_u = 0.0, d.interior_v = -0.2, d.interior_only = 0;
  opttest::Patch pa;
  pa.nu = 1, pa.nv = 1, pa.u1 = pa.u0 + 0.3, pa.v1 = pa.v0 + 0.3;
  Mesh m0 = opttest::sphere_patch(s, 3, pa, d);
  REQUIRE(invalid_count(m0) == 0);
  opt::Options o;
  o.faces = false;
  o.keep_valid = false;
  o.keep_quality = false;  // this test shows the validity guard alone
  Mesh unguarded = m0;
  opt::Report ru = opt::optimise_mesh(unguarded, s, o, 1);
  MESSAGE("unguarded: invalid " << ru.invalid_before << " -> " << ru.invalid_after);
  CHECK(ru.invalid_after > 0);
  CHECK(invalid_count(unguarded) > 0);
  o.keep_valid = true;
  Mesh guarded = m0;
  opt::Report rg = opt::optimise_mesh(guarded, s, o, 1);
  MESSAGE("guarded: invalid " << rg.invalid_before << " -> " << rg.invalid_after << ", backtracked " << rg.backtracked_units
                              << ", reverted " << rg.reverted_units << ", rounds " << rg.guard_rounds << ", energy "
                              << rg.energy_before << " -> " << rg.energy_after);
  CHECK(rg.invalid_after == 0);
  CHECK(invalid_count(guarded) == 0);
  CHECK(rg.backtracked_units > 0);
  CHECK(rg.energy_after <= rg.energy_before);
  CHECK(opttest::max_param_error(guarded, s) < 1e-7);
}

TEST_CASE("same bytes at 1 and 2 threads") {
  const Shape& s = shapes().sphere;
  opttest::Distortion d;
  d.bunch = 0.35, d.bump = 0.1, d.interior_u = 0.05, d.interior_v = 0.03;
  opttest::Patch pa;
  pa.nu = 8, pa.nv = 6;
  Mesh a = opttest::sphere_patch(s, 4, pa, d, 0.05), b = a;
  auto ra = opt::optimise_mesh(a, s, {}, 1);
  auto rb = opt::optimise_mesh(b, s, {}, 2);
  fs::path dir = scratch();
  meshflow::io::write_mesh(a, dir / "a.msh");
  meshflow::io::write_mesh(b, dir / "b.msh");
  auto slurp = [](const fs::path& p) {
    std::ifstream in(p, std::ios::binary);
    std::stringstream ss;
    ss << in.rdbuf();
    return ss.str();
  };
  CHECK(ra.nodes_moved > 0);
  CHECK(slurp(dir / "a.msh") == slurp(dir / "b.msh"));
  CHECK(ra.energy_after == rb.energy_after);
  CHECK(ra.to_json()["iterations"] == rb.to_json()["iterations"]);
  fs::remove_all(dir);
}

TEST_CASE("refusals: a linear mesh, nodes on the CAD without parameters, ids not in the shape") {
  const Shape& s = shapes().sphere;
  Mesh lin = opttest::sphere_patch(s, 1, {}, {});
  CHECK_THROWS_WITH_AS(opt::optimise_mesh(lin, s, {}), doctest::Contains("linear"), meshflow::StageError);
  Mesh m = opttest::sphere_patch(s, 3, {}, {});
  Mesh noparam = m;
  noparam.node_v[10] = NAN;
  CHECK_THROWS_WITH_AS(opt::optimise_mesh(noparam, s, {}), doctest::Contains("no parameters"), meshflow::StageError);
  Mesh noclass = m;
  noclass.node_u.clear();
  noclass.node_v.clear();
  CHECK_THROWS_WITH_AS(opt::optimise_mesh(noclass, s, {}), doctest::Contains("no CAD classification"), meshflow::StageError);
  Mesh wrong = m;
  wrong.node_entity_tag[5] = 7;
  CHECK_THROWS_WITH_AS(opt::optimise_mesh(wrong, s, {}), doctest::Contains("do not belong together"), meshflow::StageError);
}

TEST_CASE("parameters in a chart shifted by a period (u - 2 pi) are unwrapped: same optimised positions, stored within the bounds") {
  const Shape& s = shapes().cylinder;
  opttest::Distortion d;
  d.bunch = 0.4, d.bump = 0.08, d.interior_u = 0.05, d.interior_v = 0.05;
  Mesh plain = opttest::cylinder_quads(s, 4, 7, 2, d);
  Mesh shifted = plain;
  const double kTwoPi = 6.283185307179586;
  std::size_t n_shifted = 0;
  for (std::size_t i = 0; i < shifted.num_nodes(); ++i)
    if (shifted.node_entity_dim[i] == 2 && shifted.node_u[i] > 0.5 * kTwoPi) shifted.node_u[i] -= kTwoPi, ++n_shifted;
  REQUIRE(n_shifted > 20);
  auto rp = opt::optimise_mesh(plain, s, {}, 1);
  auto rs = opt::optimise_mesh(shifted, s, {}, 1);
  CHECK(rp.unwrapped_seam == 0);
  CHECK(rs.unwrapped_seam > 0);
  CHECK(rs.skipped_seam + rs.skipped_inconsistent == 0);
  CHECK(rs.faces == rp.faces);
  CHECK(rs.surface_edges == rp.surface_edges);
  double diff = 0;
  for (std::size_t i = 0; i < plain.num_nodes(); ++i)
    diff = std::max(diff, std::hypot(plain.x[i] - shifted.x[i], plain.y[i] - shifted.y[i], plain.z[i] - shifted.z[i]));
  CHECK(diff < 1e-8);
  auto fb = s.face_uv_bounds(0);
  for (std::size_t i = 0; i < shifted.num_nodes(); ++i)
    if (shifted.node_entity_dim[i] == 2 && (shifted.x[i] != plain.x[i] || shifted.y[i] != plain.y[i])) {
      CHECK(shifted.node_u[i] >= fb.u0 - 1e-12);
      CHECK(shifted.node_u[i] <= fb.u1 + 1e-12);
    }
  CHECK(opttest::max_param_error(shifted, s) < 1e-7);
  CHECK(rs.energy_after == doctest::Approx(rp.energy_after).epsilon(1e-9));
}

TEST_CASE("untangle: a wall triangle folded on the CAD is repaired only by sliding its nodes on the CAD") {
  // One layer of P=4 prisms on a sphere patch; the face-interior nodes of the first wall triangle
  // are shifted in (u,v) towards its edges, so the triangle folds on the sphere and its prism is
  // inverted at the wall. No off-CAD node can repair that. (At this shift the samples of the
  // first two attempts are satisfied while det J is negative between them: only the third
  // attempt, on det J's Bernstein coefficients, repairs it.)
  const Shape& s = shapes().sphere;
  opttest::Distortion d;
  d.bunch = 0.0, d.bump = 0.0, d.interior_u = 0.45, d.interior_v = 0.45, d.interior_only = 0;
  Mesh m0 = opttest::sphere_patch(s, 4, {}, d, 0.05);
  const std::size_t bad = invalid_count(m0);
  REQUIRE(bad > 0);
  opt::UntangleOptions uo;
  uo.max_rings = 1;  // the first ring suffices when sliding; more only makes the failing runs slower
  Mesh volume_only = m0;
  auto rv = opt::untangle(volume_only, uo, 1);  // no shape: nodes on the CAD never move
  MESSAGE("volume only: " << rv.invalid_before << " -> " << rv.invalid_after);
  CHECK(rv.invalid_after > 0);
  CHECK(rv.surface_nodes_moved == 0);
  uo.surface = false;
  Mesh off = m0;
  auto ro = opt::untangle(off, uo, 1, {}, &s);  // sliding turned off
  CHECK(ro.invalid_after > 0);
  CHECK(ro.surface_nodes_moved == 0);
  uo.surface = true;
  Mesh m = m0;
  std::string log;
  auto r = opt::untangle(m, uo, 1, [&](const std::string& l) { log += l + "\n"; }, &s);
  MESSAGE(log);
  MESSAGE("sliding: " << r.invalid_before << " -> " << r.invalid_after << ", " << r.repaired_sliding << " patches slid "
                      << r.surface_nodes_moved << " nodes on the CAD, " << r.nodes_moved << " off it");
  CHECK(r.invalid_before == bad);
  CHECK(r.invalid_after == 0);
  CHECK(invalid_count(m) == 0);
  CHECK(r.repaired_sliding > 0);
  CHECK(r.surface_nodes_moved > 0);
  // the folded wall face is seen before any attempt: its element slides first, so its first
  // attempt (the log's first line) is a sliding one and no off-CAD attempt precedes the repair
  CHECK(r.folded_wall >= 1);
  CHECK(r.folded_wall <= r.invalid_before);
  const std::string first = log.substr(0, log.find('\n'));
  CHECK(first.find("sliding on the CAD") != std::string::npos);
  CHECK(opttest::max_param_error(m, s) < 1e-7);  // every node on the CAD is still on it, parameters updated
  std::size_t vertices_moved = 0;
  for (const auto& b : m.blocks)
    for (std::size_t e = 0; e < b.size(); ++e)
      for (int k = 0; k < model::num_vertices(b.shape); ++k) {
        const auto v = b.element(e)[k];
        vertices_moved += m.x[v] != m0.x[v] || m.y[v] != m0.y[v] || m.z[v] != m0.z[v];
      }
  CHECK(vertices_moved == 0);
  // deterministic: the same bytes again
  Mesh again = m0;
  opt::untangle(again, uo, 2, {}, &s);
  CHECK(again.x == m.x);
  bool same_params = true;
  for (std::size_t i = 0; i < m.num_nodes(); ++i)
    same_params = same_params && (std::isnan(m.node_u[i]) ? std::isnan(again.node_u[i]) : again.node_u[i] == m.node_u[i]);
  CHECK(same_params);
}

TEST_CASE("untangle: a prism inverted by its off-CAD nodes, wall face not folded, is repaired off the CAD, not slid first") {
  // The same sphere patch without the fold; the high-order nodes inside the first prism (in no
  // other element) are pushed through its wall, half a layer thickness inside the sphere, so det
  // J is negative while its wall triangle is the curved one curving made.
  const Shape& s = shapes().sphere;
  opttest::Distortion d;
  d.bunch = 0.0;
  Mesh m0 = opttest::sphere_patch(s, 4, {}, d, 0.05);
  REQUIRE(invalid_count(m0) == 0);
  const auto& b = m0.blocks.back();
  REQUIRE(b.shape == model::Shape::Prism);
  const std::uint32_t* en = b.element(0);
  std::vector<int> uses(m0.num_nodes(), 0);
  for (const auto& bb : m0.blocks)
    for (std::size_t e = 0; e < bb.size(); ++e)
      for (int a = 0; a < bb.nodes_per_element(); ++a) ++uses[bb.element(e)[a]];
  const double R = std::hypot(m0.x[en[0]], m0.y[en[0]], m0.z[en[0]]);  // a wall vertex: on the sphere
  int pushed = 0;
  for (int a = model::num_vertices(b.shape); a < b.nodes_per_element(); ++a) {
    const auto v = en[a];
    if (m0.node_entity_dim[v] != 3 || uses[v] != 1) continue;
    const double k = (R - 0.5 * 0.05) / std::hypot(m0.x[v], m0.y[v], m0.z[v]);
    m0.x[v] *= k, m0.y[v] *= k, m0.z[v] *= k;
    ++pushed;
  }
  REQUIRE(pushed > 0);
  REQUIRE(invalid_count(m0) > 0);
  Mesh m = m0;
  std::string log;
  auto r = opt::untangle(m, {}, 1, [&](const std::string& l) { log += l + "\n"; }, &s);
  MESSAGE(log);
  CHECK(r.folded_wall == 0);
  CHECK(r.invalid_after == 0);
  CHECK(r.surface_nodes_moved == 0);
  CHECK(log.substr(0, log.find('\n')).find("sliding on the CAD") == std::string::npos);
}

namespace {

double min_sj(const Mesh& m) {
  double q = INFINITY;
  for (auto& b : model::mesh_quality(m, 1))
    for (auto& e : b) q = std::min(q, e.scaled_jacobian);
  return q;
}

}  // namespace

TEST_CASE("quality guard: optimise never lowers the min scaled Jacobian, which the spring optimisation without the guard does while every element stays valid") {
  // One layer of P=4 prisms on a 2 x 2 sphere patch whose wall edges bow sideways in (u,v),
  // with the face-interior nodes of the first wall triangle shifted along v: min scaled Jacobian
  // 0.42. Straightening the edges onto the geodesic (what the springs do, blind to the
  // elements) while the interior nodes stay leaves a prism much worse (0.18 when measured),
  // still valid, so the validity guard alone lets it through.
  const Shape& s = shapes().sphere;
  opttest::Distortion d;
  d.bunch = 0.0, d.bump = 0.1, d.interior_u = 0.0, d.interior_v = 0.05, d.interior_only = 0;
  opttest::Patch pa;
  pa.nu = 2, pa.nv = 2, pa.u1 = pa.u0 + 0.6, pa.v1 = pa.v0 + 0.6;
  Mesh m0 = opttest::sphere_patch(s, 4, pa, d, 0.05);
  REQUIRE(invalid_count(m0) == 0);
  const double q0 = min_sj(m0);
  opt::Options o;
  o.faces = false;  // the interior nodes stay: only the edges move
  o.keep_quality = false;
  Mesh unguarded = m0;
  opt::Report ru = opt::optimise_mesh(unguarded, s, o, 1);
  const double qu = min_sj(unguarded);
  MESSAGE("min scaled Jacobian: input " << q0 << ", unguarded " << qu << " (invalid " << ru.invalid_after << ")");
  REQUIRE(ru.invalid_after == 0);  // the validity guard alone lets it through
  CHECK(qu < q0 - 0.05);
  o.keep_quality = true;
  Mesh guarded = m0;
  opt::Report rg = opt::optimise_mesh(guarded, s, o, 1);
  const double qg = min_sj(guarded);
  MESSAGE("guarded " << qg << ", backtracked " << rg.backtracked_units << " (" << rg.quality_backtracked_units << " for quality), energy "
                     << rg.energy_before << " -> " << rg.energy_after);
  CHECK(qg >= q0);
  CHECK(rg.min_sj_after >= rg.min_sj_before);
  CHECK(rg.quality_backtracked_units > 0);
  CHECK(rg.invalid_after == 0);
  CHECK(rg.energy_after < rg.energy_before);  // the units that do not worsen anything still move
  CHECK(opttest::max_param_error(guarded, s) < 1e-7);
  // and with the stage's defaults (faces on as well) on a patch where the face springs do it:
  // bowed in the other direction, interior nodes pulled towards the bow
  d.bump = -0.2, d.interior_v = -0.2;
  Mesh m1 = opttest::sphere_patch(s, 4, pa, d, 0.05);
  REQUIRE(invalid_count(m1) == 0);
  const double q1 = min_sj(m1);
  opt::Options all;
  all.keep_quality = false;
  Mesh u1 = m1;
  opt::optimise_mesh(u1, s, all, 1);
  MESSAGE("defaults: input " << q1 << ", unguarded " << min_sj(u1));
  CHECK(min_sj(u1) < q1);
  Mesh g1 = m1;
  opt::Report r1 = opt::optimise_mesh(g1, s, {}, 1);
  MESSAGE("defaults: guarded " << min_sj(g1));
  CHECK(min_sj(g1) >= q1);
  CHECK(r1.quality_backtracked_units > 0);
  CHECK(invalid_count(g1) == 0);
}
