// periodic_match: find() on the Rotor 67 sector (rotation about the machine axis by 2π/22) and
// on shapes made in shapes.cpp (OCCT): a box with translational sides, annulus sectors about the
// x axis and about an oblique axis, perturbed, different, symmetric and untagged sides; the
// image() helper; the artifact round trip and determinism; the stage with and without divisions.
#include <doctest/doctest.h>

#include "../cad/test_context.hpp"
#include "shapes.hpp"
#include "stages/balance/balance.hpp"
#include "stages/cad/cad.hpp"
#include "stages/periodic_match/periodic.hpp"

#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <set>
#include <sstream>

using meshflow::StageError;
using meshflow::cad::Shape;
using meshflow::cad::Tag;
using meshflow::cad::Vec3;
using meshflow::testing::TestContext;
namespace fs = std::filesystem;
namespace per = meshflow::periodic;
using P3 = std::array<double, 3>;

namespace {
const fs::path kRotor = fs::path(MESHFLOW_DATA_DIR) / "rotor67/rotor67geometry.dat";

std::string slurp(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}
P3 p3(const Vec3& v) { return {v.x, v.y, v.z}; }
double dist(const P3& a, const P3& b) { return std::hypot(a[0] - b[0], a[1] - b[1], a[2] - b[2]); }

// The Rotor 67 sector through blade_sector and heal, made once per test process.
struct Rotor {
  std::unique_ptr<TestContext> geo, heal;
  meshflow::Artifact shape;
};
Rotor& rotor() {
  static Rotor r = [] {
    Rotor x;
    x.geo = std::make_unique<TestContext>("blade_sector", nlohmann::json{{"file", kRotor.string()}});
    x.geo->run();
    x.heal = std::make_unique<TestContext>("heal", nlohmann::json::object(), std::vector<meshflow::Artifact>{x.geo->artifact("shape")});
    x.heal->run();
    x.shape = x.heal->artifact("shape");
    return x;
  }();
  return r;
}

// Tags planar faces by a predicate on their bounding box; returns how many got `t`.
template <class Pred>
int tag_faces(Shape& s, Tag t, Pred pred) {
  int n = 0;
  for (int f = 0; f < s.num_faces(); ++f)
    if (pred(s.face_box(f))) s.set_face_tag(f, t), ++n;
  return n;
}
bool near(double a, double b) { return std::abs(a - b) < 1e-6; }

// The box with a through hole, x = 0 periodic_lo, x = L periodic_hi.
Shape tagged_box(double L, bool through = true) {
  Shape s = pmtest::box_with_hole(L, through);
  for (int f = 0; f < s.num_faces(); ++f) s.set_face_tag(f, Tag::wall);
  REQUIRE(tag_faces(s, Tag::periodic_lo, [](const meshflow::cad::Box& b) { return near(b.lo.x, 0) && near(b.hi.x, 0); }) == 1);
  REQUIRE(tag_faces(s, Tag::periodic_hi, [&](const meshflow::cad::Box& b) { return near(b.lo.x, L) && near(b.hi.x, L); }) == 1);
  return s;
}

// Annulus sectors about x: the planar faces at theta0 are periodic_lo, at theta0 + alpha periodic_hi.
Shape tagged_sectors(const std::vector<std::array<double, 2>>& ta) {
  Shape s = pmtest::annulus_sectors(0, 1, 1, 2, ta);
  for (int f = 0; f < s.num_faces(); ++f) {
    s.set_face_tag(f, Tag::wall);
    if (s.face_surface_type(f) != "plane") continue;
    auto b = s.face_uv_bounds(f);
    Vec3 p = s.face_point(f, 0.5 * (b.u0 + b.u1), 0.5 * (b.v0 + b.v1));
    if (std::abs(p.x) < 1e-9 || std::abs(p.x - 1) < 1e-9) continue;  // the x = const annulus faces
    double th = std::atan2(p.z, p.y);
    for (auto [t0, a] : ta) {
      if (std::abs(std::remainder(th - t0, 2 * M_PI)) < 1e-9) s.set_face_tag(f, Tag::periodic_lo);
      if (std::abs(std::remainder(th - t0 - a, 2 * M_PI)) < 1e-9) s.set_face_tag(f, Tag::periodic_hi);
    }
  }
  return s;
}

// Independent checks of a match: every lo vertex carried onto its partner, edge and face samples
// carried onto their partners (through the cad interface only), pairs bijective.
double verify(const Shape& s, const per::Match& m) {
  double worst = 0;
  std::set<int> his;
  for (auto& p : m.vertices) {
    worst = std::max(worst, dist(m.transform.apply(p3(s.vertex_point(p.lo))), p3(s.vertex_point(p.hi))));
    CHECK(his.insert(p.hi).second);
  }
  his.clear();
  for (auto& p : m.edges) {
    CHECK(his.insert(p.hi).second);
    auto r = s.edge_range(p.lo);
    for (int k = 0; k <= 10; ++k) {
      auto d = s.edge_eval(p.lo, r.lo + (r.hi - r.lo) * k / 10);
      P3 y = m.transform.apply(p3(d.p));
      auto pr = s.project_to_edge(p.hi, {y[0], y[1], y[2]});
      worst = std::max(worst, pr.distance);
      if (k == 5) {  // orientation flag against the tangents
        P3 t = m.transform.apply_vector(p3(d.d1));
        auto e = s.edge_eval(p.hi, pr.t).d1;
        CHECK(((t[0] * e.x + t[1] * e.y + t[2] * e.z) < 0) == p.reversed);
      }
    }
  }
  his.clear();
  for (auto& p : m.faces) {
    CHECK(s.face_tag(p.lo) == Tag::periodic_lo);
    CHECK(s.face_tag(p.hi) == Tag::periodic_hi);
    CHECK(his.insert(p.hi).second);
    auto b = s.face_uv_bounds(p.lo);
    for (int i = 1; i < 10; ++i)
      for (int j = 1; j < 10; ++j) {
        double u = b.u0 + (b.u1 - b.u0) * i / 10, v = b.v0 + (b.v1 - b.v0) * j / 10;
        if (!s.face_contains_uv(p.lo, u, v)) continue;
        P3 y = m.transform.apply(p3(s.face_point(p.lo, u, v)));
        worst = std::max(worst, s.project_to_face(p.hi, {y[0], y[1], y[2]}).distance);
      }
  }
  return worst;
}

std::size_t side_count(const Shape& s, Tag t, int dim) {
  std::set<int> out;
  for (int f : s.faces_with_tag(t)) {
    if (dim == 2) out.insert(f);
    for (int e : s.face_edges(f)) {
      if (dim == 1 && !s.edge_degenerate(e)) out.insert(e);
      if (dim == 0) for (int v : s.edge_vertices(e)) out.insert(v);
    }
  }
  return out.size();
}
}  // namespace

// One test case (one process under CTest): the Rotor 67 sector is built once (~10 s).
TEST_CASE("Rotor 67: the periodic sides of the blade_sector passage") {
  REQUIRE(fs::exists(kRotor));
  const double kTol = 1e-5;  // the stage default: the intersection-curve edges deviate by ~1e-6
  SUBCASE("rotation about the machine axis by 2 pi / 22, every periodic entity paired") {
    Shape s = Shape::load(rotor().shape.path);
    std::vector<std::string> log;
    auto t0 = std::chrono::steady_clock::now();
    per::Match m = per::find(s, kTol, [&](const std::string& l) { log.push_back(l); });
    double sec = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    for (auto& l : log) MESSAGE(l);
    double radius = 0;  // the casing radius: the largest distance of a periodic vertex from the axis
    for (auto& p : m.vertices) radius = std::max(radius, std::hypot(s.vertex_point(p.lo).y, s.vertex_point(p.lo).z));
    MESSAGE("Rotor 67 find(): " << sec << " s; " << m.faces.size() << " face, " << m.edges.size() << " edge, " << m.vertices.size()
                                << " vertex pairs; mismatch / radius: faces " << m.face_mismatch / radius << ", edges "
                                << m.edge_mismatch / radius << ", vertices " << m.vertex_mismatch / radius << " (radius " << radius << " "
                                << m.units << ", model size " << m.model_size << ")");
    CHECK(m.transform.kind == "rotation");
    CHECK(m.transform.snapped);
    CHECK(m.transform.axis_dir == P3{1, 0, 0});
    CHECK(m.transform.axis_point == P3{0, 0, 0});
    CHECK(m.transform.angle == doctest::Approx(2 * M_PI / 22).epsilon(1e-15));
    CHECK(m.transform.affine[5] == std::cos(2 * M_PI / 22));
    CHECK(m.transform.affine[9] == std::sin(2 * M_PI / 22));  // right-handed about +x: y -> z
    CHECK(m.units == "ft");
    // every periodic face, edge and vertex paired
    CHECK(m.faces.size() == side_count(s, Tag::periodic_lo, 2));
    CHECK(m.faces.size() == side_count(s, Tag::periodic_hi, 2));
    CHECK(m.edges.size() == side_count(s, Tag::periodic_lo, 1));
    CHECK(m.edges.size() == side_count(s, Tag::periodic_hi, 1));
    CHECK(m.vertices.size() == side_count(s, Tag::periodic_lo, 0));
    CHECK(m.faces.size() >= 1);
    CHECK(m.edges.size() >= 4);
    // the periodic surfaces are exact images (blade_sector rotates the poles): 1e-9 of the radius
    CHECK(m.face_mismatch <= 1e-9 * radius);
    // their boundaries are intersection curves (OCCT approximations): within the tolerance
    CHECK(m.max_mismatch <= kTol * m.model_size);
    CHECK(verify(s, m) <= kTol * m.model_size);
    CHECK(sec < 30);
  }

  SUBCASE("image() of lo points on the hi partner") {
    Shape s = Shape::load(rotor().shape.path);
    per::Match m = per::find(s, kTol);
    double radius = 0;
    for (auto& p : m.vertices) radius = std::max(radius, std::hypot(s.vertex_point(p.lo).y, s.vertex_point(p.lo).z));
    // faces: a 40 x 40 grid of the lo face, projected with the previous node's (u,v) as hint
    double face_worst = 0, edge_worst = 0;
    long n = 0;
    auto t0 = std::chrono::steady_clock::now();
    for (auto& p : m.faces) {
      auto b = s.face_uv_bounds(p.lo);
      std::optional<std::array<double, 2>> hint;
      for (int i = 0; i <= 40; ++i)
        for (int j = 0; j <= 40; ++j) {
          double u = b.u0 + (b.u1 - b.u0) * i / 40, v = b.v0 + (b.v1 - b.v0) * j / 40;
          if (!s.face_contains_uv(p.lo, u, v)) continue;
          P3 x = p3(s.face_point(p.lo, u, v));
          per::Image im = per::image(s, m, 2, p.lo, x, hint);
          hint = std::array<double, 2>{im.u, im.v};
          face_worst = std::max(face_worst, im.distance);
          CHECK(dist(p3(s.face_point(p.hi, im.u, im.v)), im.point) < 1e-12 * radius);
          ++n;
        }
    }
    double sec = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    for (auto& p : m.edges) {
      auto r = s.edge_range(p.lo);
      std::optional<std::array<double, 2>> hint;
      for (int k = 0; k <= 50; ++k) {
        P3 x = p3(s.edge_point(p.lo, r.lo + (r.hi - r.lo) * k / 50));
        per::Image im = per::image(s, m, 1, p.lo, x, hint);
        hint = std::array<double, 2>{im.t, 0};
        edge_worst = std::max(edge_worst, im.distance);
      }
    }
    for (auto& p : m.vertices) CHECK(per::image(s, m, 0, p.lo, p3(s.vertex_point(p.lo))).distance <= m.vertex_mismatch);
    MESSAGE("Rotor 67 image(): " << n << " face points in " << sec << " s; after projection |T(x) - image| / radius: faces "
                                 << face_worst / radius << ", edges " << edge_worst / radius);
    CHECK(n > 500);
    CHECK(face_worst <= 1e-12 * radius);  // the target, met on the periodic surfaces
    CHECK(edge_worst <= kTol * m.model_size);
    CHECK_THROWS_AS(per::image(s, m, 2, 9999, {0, 0, 0}), std::out_of_range);
  }

  SUBCASE("a bulge on the periodic_hi face is refused, naming the faces") {
    Shape s = Shape::load(rotor().shape.path);
    int lo = s.faces_with_tag(Tag::periodic_lo).at(0), hi = s.faces_with_tag(Tag::periodic_hi).at(0);
    Shape bad = [&] {
      try {
        return pmtest::bulged(s, hi, {0, 0, 1e-3});  // ft
      } catch (const std::exception& e) {
        MESSAGE(std::string(e.what()));
        FAIL("bulged failed");
        throw;
      }
    }();
    // the vertices and edges did not move: the transform is still found, the faces differ
    try {
      per::find(bad, kTol);
      FAIL("a perturbed periodic side was accepted");
    } catch (const StageError& e) {
      std::string w = e.what();
      MESSAGE(w);
      CHECK(w.find("periodic_lo face " + std::to_string(lo)) != std::string::npos);
      CHECK(w.find("periodic_hi face " + std::to_string(hi)) != std::string::npos);
    }
    // the same bulge below the tolerance passes
    Shape tiny = pmtest::bulged(s, hi, {0, 0, 1e-9});
    CHECK(per::find(tiny, kTol).faces.size() == 1);
  }

  SUBCASE("moved onto an oblique axis: the rotation is found and refined on the surfaces") {
    Shape s0 = Shape::load(rotor().shape.path);
    P3 c{0.1, -0.2, 0.3}, d{1, 2, 3}, shift{0.05, 0.01, -0.02};
    Shape s = pmtest::moved(s0, c, d, 0.4, shift);
    std::vector<std::string> log;
    per::Match m = per::find(s, kTol, [&](const std::string& l) { log.push_back(l); });
    for (auto& l : log) MESSAGE(l);
    per::Transform R = per::Transform::rotation(c, d, 0.4);
    P3 a = R.apply_vector({1, 0, 0});
    const P3& f = m.transform.axis_dir;
    double off = std::hypot(a[1] * f[2] - a[2] * f[1], a[2] * f[0] - a[0] * f[2], a[0] * f[1] - a[1] * f[0]);  // sin of the angle between
    double radius = 0.84296;  // ft, the casing radius (the first test case)
    MESSAGE("oblique Rotor 67: axis off by " << off << " rad, angle off by "
                                            << std::abs(std::abs(m.transform.angle) - 2 * M_PI / 22) << "; face mismatch / radius "
                                            << m.face_mismatch / radius);
    CHECK(m.transform.kind == "rotation");
    CHECK(off < 1e-9);
    CHECK(std::abs(std::abs(m.transform.angle) - 2 * M_PI / 22) < 1e-9);
    CHECK(m.face_mismatch <= 1e-12 * radius);
  }
  SUBCASE("the stage twice on the same shape: byte-identical artifacts") {
    TestContext one("periodic_match", nlohmann::json::object(), {rotor().shape});
    TestContext two("periodic_match", nlohmann::json::object(), {rotor().shape});
    one.run();
    two.run();
    CHECK(slurp(one.artifact("periodic").path) == slurp(two.artifact("periodic").path));
    CHECK(one.stats_["kind"] == "rotation");
    CHECK(one.stats_["sectors"].get<double>() == doctest::Approx(22).epsilon(1e-14));
    MESSAGE("Rotor 67 stage stats: " << one.stats_.dump());
  }
}

TEST_CASE("box with a hole: translation, paired faces, edges with orientation, vertices") {
  Shape s = tagged_box(2.0);
  per::Match m = per::find(s, 1e-6);
  CHECK(m.transform.kind == "translation");
  CHECK(dist(m.transform.translation, {2, 0, 0}) < 1e-12);
  CHECK(m.faces.size() == 1);
  CHECK(m.edges.size() == 5);     // the square and the circle
  CHECK(m.vertices.size() == 5);  // 4 corners and the circle's seam vertex
  CHECK(m.max_mismatch < 1e-12);
  CHECK(verify(s, m) < 1e-12);
  CHECK(dist(m.transform.apply_inverse(m.transform.apply({0.3, 0.2, 0.1})), {0.3, 0.2, 0.1}) < 1e-15);
  // the opposite tagging gives the opposite translation
  for (int f = 0; f < s.num_faces(); ++f)
    if (s.face_tag(f) == Tag::periodic_lo) s.set_face_tag(f, Tag::periodic_hi);
    else if (s.face_tag(f) == Tag::periodic_hi) s.set_face_tag(f, Tag::periodic_lo);
  CHECK(dist(per::find(s, 1e-6).transform.translation, {-2, 0, 0}) < 1e-12);
}

TEST_CASE("sectors: rotation about x snapped to 2 pi / 7, about an oblique axis fitted") {
  Shape s = tagged_sectors({{0.3, 2 * M_PI / 7}});
  per::Match m = per::find(s, 1e-6);
  CHECK(m.transform.kind == "rotation");
  CHECK(m.transform.axis_dir == P3{1, 0, 0});
  CHECK(m.transform.angle == doctest::Approx(2 * M_PI / 7).epsilon(1e-15));
  CHECK(m.faces.size() == 1);
  CHECK(m.edges.size() == 4);
  CHECK(m.vertices.size() == 4);
  CHECK(verify(s, m) < 1e-12);

  // the same sector moved: axis through (0.5, -1, 2) along (1, 2, 3)/|.|, then shifted
  P3 c{0.5, -1, 2}, d{1, 2, 3}, shift{0.25, 0, -0.5};
  Shape t = pmtest::moved(s, c, d, 0.7, shift);
  per::Match mt = per::find(t, 1e-6);
  CHECK(mt.transform.kind == "rotation");
  // the axis is oblique: not snapped to a coordinate axis (the angle, exactly 2 pi / 7, may snap)
  CHECK(std::abs(mt.transform.axis_dir[0]) < 0.9);
  // expected: the image of the x axis under the motion p -> R(p) + shift
  per::Transform R = per::Transform::rotation(c, d, 0.7);
  auto M = [&](P3 p) { P3 q = R.apply(p); return P3{q[0] + shift[0], q[1] + shift[1], q[2] + shift[2]}; };
  P3 a = R.apply_vector({1, 0, 0}), o = M({0, 0, 0});
  double sgn = a[0] * mt.transform.axis_dir[0] + a[1] * mt.transform.axis_dir[1] + a[2] * mt.transform.axis_dir[2];
  CHECK(std::abs(std::abs(sgn) - 1) < 1e-12);
  CHECK(mt.transform.angle * (sgn > 0 ? 1 : -1) == doctest::Approx(2 * M_PI / 7).epsilon(1e-12));
  // o lies on the found axis
  P3 w{o[0] - mt.transform.axis_point[0], o[1] - mt.transform.axis_point[1], o[2] - mt.transform.axis_point[2]};
  double along = w[0] * a[0] + w[1] * a[1] + w[2] * a[2];
  CHECK(std::sqrt(std::max(0.0, w[0] * w[0] + w[1] * w[1] + w[2] * w[2] - along * along)) < 1e-9);
  CHECK(verify(t, mt) < 1e-10);
  MESSAGE("oblique axis: max mismatch " << mt.max_mismatch << " (model size " << mt.model_size << ")");
}

TEST_CASE("a full wedge: the axis edge lies on both sides and is its own partner") {
  Shape w = pmtest::annulus_sectors(0, 1, 0, 1, {{0, 2 * M_PI / 5}});  // r from 0: an edge on the axis
  int lo = 0, hi = 0;
  for (int f = 0; f < w.num_faces(); ++f) {
    w.set_face_tag(f, Tag::wall);
    if (w.face_surface_type(f) != "plane") continue;
    auto b = w.face_uv_bounds(f);
    Vec3 p = w.face_point(f, 0.5 * (b.u0 + b.u1), 0.5 * (b.v0 + b.v1));
    if (std::abs(p.x) < 1e-9 || std::abs(p.x - 1) < 1e-9) continue;
    double th = std::atan2(p.z, p.y);
    if (std::abs(th) < 1e-9) w.set_face_tag(f, Tag::periodic_lo), ++lo;
    if (std::abs(th - 2 * M_PI / 5) < 1e-9) w.set_face_tag(f, Tag::periodic_hi), ++hi;
  }
  REQUIRE(lo == 1);
  REQUIRE(hi == 1);
  per::Match m = per::find(w, 1e-6);
  CHECK(m.transform.kind == "rotation");
  CHECK(m.transform.angle == doctest::Approx(2 * M_PI / 5).epsilon(1e-15));
  int self = 0;
  for (auto& p : m.edges) self += p.lo == p.hi;
  CHECK(self == 1);  // the edge on the x axis
  CHECK(verify(w, m) < 1e-12);
}

TEST_CASE("refusals: no tags, one side only, different shape, symmetric sides with two maps") {
  Shape none = pmtest::box_with_hole(2.0);
  CHECK_THROWS_WITH_AS(per::find(none, 1e-6), doctest::Contains("no face tagged periodic_lo or periodic_hi"), StageError);
  Shape one = tagged_box(2.0);
  for (int f : one.faces_with_tag(Tag::periodic_hi)) one.set_face_tag(f, Tag::wall);
  int lo = one.faces_with_tag(Tag::periodic_lo)[0];
  CHECK_THROWS_WITH_AS(per::find(one, 1e-6), doctest::Contains(doctest::String(("faces " + std::to_string(lo) + " are tagged periodic_lo but no face is tagged periodic_hi").c_str())),
                       StageError);
  // a blind hole: the hi side has no circle
  Shape blind = tagged_box(2.0, false);
  try {
    per::find(blind, 1e-6);
    FAIL("different sides accepted");
  } catch (const StageError& e) {
    std::string w = e.what();
    MESSAGE(w);
    CHECK(w.find("do not have the same shape") != std::string::npos);
    CHECK(w.find("periodic_lo faces " + std::to_string(blind.faces_with_tag(Tag::periodic_lo)[0])) != std::string::npos);
    CHECK(w.find("periodic_hi faces " + std::to_string(blind.faces_with_tag(Tag::periodic_hi)[0])) != std::string::npos);
  }
  // a longer box tagged with the same faces works; a sector whose hi side is at another angle
  // than its lo side's partner would be has no common map: lo at 0 and 180 deg, hi at 90 and 300
  Shape two = tagged_sectors({{0, M_PI / 2}, {M_PI, M_PI / 2}});  // quarters [0,90] and [180,270]
  CHECK(two.faces_with_tag(Tag::periodic_lo).size() == 2);
  CHECK(two.faces_with_tag(Tag::periodic_hi).size() == 2);
  // +90 deg (0 -> 90, 180 -> 270) and -90 deg (0 -> 270, 180 -> 90) both glue the sides
  CHECK_THROWS_WITH_AS(per::find(two, 1e-6), doctest::Contains("several candidate transforms"), StageError);
  // a tolerance too tight for the geometry is refused too, not silently accepted
  Shape ok = tagged_sectors({{0.3, 2 * M_PI / 7}});
  CHECK_THROWS_AS(per::find(ok, 0), StageError);
}

TEST_CASE("artifact: round trip, byte-identical reruns, corrupt files refused") {
  auto dir = meshflow::testing::scratch_dir("periodic-io");
  Shape s = tagged_box(2.0);
  per::Match m = per::find(s, 1e-6);
  per::write(m, dir / "a.mfper");
  per::Match r = per::read(dir / "a.mfper");
  CHECK(r.transform.affine == m.transform.affine);
  CHECK(r.transform.kind == m.transform.kind);
  CHECK(r.edges.size() == m.edges.size());
  for (std::size_t i = 0; i < r.edges.size(); ++i)
    CHECK((r.edges[i].lo == m.edges[i].lo && r.edges[i].hi == m.edges[i].hi && r.edges[i].reversed == m.edges[i].reversed));
  CHECK(r.max_mismatch == m.max_mismatch);
  CHECK(r.summary() == m.summary());
  // same input, same bytes (a fresh load of the saved shape, a second run)
  s.save(dir / "box.mfshape");
  per::write(per::find(Shape::load(dir / "box.mfshape"), 1e-6), dir / "b.mfper");
  per::write(per::find(Shape::load(dir / "box.mfshape"), 1e-6), dir / "c.mfper");
  CHECK(slurp(dir / "b.mfper") == slurp(dir / "c.mfper"));
  std::ofstream(dir / "bad.mfper") << "{\"format\":\"meshflow-periodic 1\"}\n";
  CHECK_THROWS_WITH_AS(per::read(dir / "bad.mfper"), doctest::Contains("inconsistent"), StageError);
  std::ofstream(dir / "junk.mfper") << "not json";
  CHECK_THROWS_AS(per::read(dir / "junk.mfper"), StageError);
  CHECK_THROWS_AS(per::read(dir / "missing.mfper"), StageError);
  fs::remove_all(dir);
}

namespace {
// A divisions artifact naming the periodic edges "e<id>" with the given count per edge.
meshflow::Artifact divisions(const fs::path& file, const Shape& s, const std::map<int, int>& n) {
  meshflow::balance::Divisions d;
  d.units = s.units();
  for (auto [e, k] : n) {
    meshflow::balance::EdgeDivision x;
    x.name = "e" + std::to_string(e), x.cad_edge = e, x.kind = "periodic", x.n = k, x.target = k, x.length = s.edge_length(e);
    x.param = "cad";
    auto r = s.edge_range(e);
    for (int i = 0; i <= k; ++i) x.nodes.push_back(r.lo + (r.hi - r.lo) * i / k);
    d.edges.push_back(x);
  }
  std::sort(d.edges.begin(), d.edges.end(), [](auto& a, auto& b) { return a.name < b.name; });
  meshflow::balance::write(d, file);
  meshflow::Artifact a;
  a.name = "divisions", a.type = "divisions", a.path = file;
  return a;
}
}  // namespace

TEST_CASE("stage: stats, equal divisions accepted, unequal ones refused naming the edges") {
  auto dir = meshflow::testing::scratch_dir("periodic-stage");
  Shape s = tagged_box(2.0);
  s.save(dir / "box.mfshape");
  meshflow::Artifact shape;
  shape.name = "shape", shape.type = "shape", shape.path = dir / "box.mfshape";
  per::Match m = per::find(s, 1e-6);
  std::map<int, int> n;
  for (auto& p : m.edges) n[p.lo] = n[p.hi] = 3 + p.lo % 3;
  {
    TestContext ctx("periodic_match", nlohmann::json::object(), {shape, divisions(dir / "ok.mfdiv", s, n)});
    ctx.run();
    per::Match out = per::read(ctx.artifact("periodic").path);
    CHECK(out.transform.kind == "translation");
    CHECK(ctx.stats_["kind"] == "translation");
    CHECK(ctx.stats_["pairs"]["edges"] == 5);
    CHECK(ctx.stats_["divisions"]["checked"] == true);
    CHECK(ctx.stats_["divisions"]["edge_pairs"] == 5);
    CHECK(ctx.stats_["divisions"]["nodes_max_mismatch_rel"].get<double>() < 1e-12);  // equal spacing: nodes coincide
    CHECK(ctx.stats_["max_mismatch_rel"].get<double>() < 1e-12);
    CHECK(ctx.progress_ok_);
  }
  {
    auto bad = n;
    const per::Pair& p = m.edges[1];
    bad[p.hi] += 1;
    TestContext ctx("periodic_match", nlohmann::json::object(), {shape, divisions(dir / "bad.mfdiv", s, bad)});
    CHECK_THROWS_WITH_AS(ctx.run(),
                         doctest::Contains(doctest::String(("e" + std::to_string(p.lo) + " (" + std::to_string(n[p.lo]) + ") ~ e" +
                                                            std::to_string(p.hi) + " (" + std::to_string(bad[p.hi]) + ")").c_str())),
                         StageError);
  }
  {
    auto missing = n;
    missing.erase(m.edges[0].lo);
    TestContext ctx("periodic_match", nlohmann::json::object(), {shape, divisions(dir / "miss.mfdiv", s, missing)});
    CHECK_THROWS_WITH_AS(ctx.run(), doctest::Contains("no entry"), StageError);
  }
  {
    TestContext ctx("periodic_match", nlohmann::json::object(), {shape});
    ctx.run();
    CHECK(ctx.stats_["divisions"]["checked"] == false);
  }
  fs::remove_all(dir);
}
