#include <doctest/doctest.h>

#include "support.hpp"

#include "../cad/test_context.hpp"
#include "stages/cad/cad.hpp"

#include <cmath>
#include <fstream>
#include <sstream>

using meshflow::StageError;
using meshflow::cad::Shape;
using meshflow::cad::Tag;
using meshflow::cad::Vec3;
using meshflow::testing::TestContext;

namespace {
// The NACA 4-digit formula, written independently of the generator.
Vec3 naca(double m, double p, double t, bool sharp, double x, bool upper, double chord, double z, double inc_deg) {
  double yt = 5 * t * (0.2969 * std::sqrt(x) - 0.1260 * x - 0.3516 * x * x + 0.2843 * std::pow(x, 3) +
                       (sharp ? -0.1036 : -0.1015) * std::pow(x, 4));
  double yc = 0, dyc = 0;
  if (m > 0) {
    yc = x < p ? m / (p * p) * (2 * p * x - x * x) : m / std::pow(1 - p, 2) * (1 - 2 * p + 2 * p * x - x * x);
    dyc = x < p ? 2 * m / (p * p) * (p - x) : 2 * m / std::pow(1 - p, 2) * (p - x);
  }
  double th = std::atan(dyc), s = upper ? 1 : -1;
  double px = (x - s * yt * std::sin(th)) * chord, py = (yc + s * yt * std::cos(th)) * chord;
  double a = -inc_deg * M_PI / 180;
  return {px * std::cos(a) - py * std::sin(a), px * std::sin(a) + py * std::cos(a), z};
}
void check_closed(const Shape& s) {
  CHECK(s.num_solids() == 1);
  CHECK(s.free_edges().empty());
  CHECK(s.multiple_edges().empty());
  CHECK(s.valid());
  CHECK(s.volume() > 0);
}
double profile_error(const Shape& s, double m, double p, double t, bool sharp, double chord, double z, double inc) {
  std::vector<int> wing;  // the wing surface: one face, or lower and upper with a sharp trailing edge
  for (int f : s.faces_with_tag(Tag::wall))
    if (s.face_surface_type(f) == "extrusion") wing.push_back(f);
  REQUIRE(!wing.empty());
  double worst = 0;
  for (double x : {1e-6, 1e-4, 0.003, 0.0125, 0.05, 0.1, 0.2, 0.29, 0.3, 0.41, 0.5, 0.6, 0.77, 0.9, 0.99, 1.0})
    for (bool up : {true, false}) {
      auto q = naca(m, p, t, sharp, x, up, chord, z, inc);
      double d = 1e300;
      for (int f : wing) d = std::min(d, s.project_to_face(f, q).distance);
      worst = std::max(worst, d / chord);
    }
  return worst;
}
}  // namespace

TEST_CASE("naca_wing default: closed fluid solid, tags, exact NACA 0012 profile") {
  TestContext ctx("naca_wing", {});
  ctx.run();
  Shape s = Shape::load(ctx.artifact("shape").path);
  check_closed(s);
  CHECK(s.faces_with_tag(Tag::farfield).size() == 5);
  CHECK(s.faces_with_tag(Tag::symmetry).size() == 1);
  CHECK(s.faces_with_tag(Tag::wall).size() >= 3);  // wing surface, trailing edge, round tip
  CHECK(s.faces_with_tag(Tag::none).empty());
  // the symmetry face is the root wall z = 0 and its normal points out of the fluid (-z)
  int sym = s.faces_with_tag(Tag::symmetry)[0];
  auto b = s.face_uv_bounds(sym);
  Vec3 n = s.face_normal(sym, 0.5 * (b.u0 + b.u1), 0.5 * (b.v0 + b.v1));
  CHECK(n.z == doctest::Approx(-1).epsilon(1e-12));
  CHECK(std::abs(s.face_box(sym).hi.z) < 1e-6);
  // volume: box minus a wing of about 0.082 c^2 x span
  double box = (5 + 11) * 10 * 6.0;
  CHECK(s.volume() < box);
  CHECK(s.volume() > box - 0.1);
  CHECK(s.units() == "m");
  // the profile at mid straight span and near the root: the 4-digit formula to 1e-9 chord
  CHECK(profile_error(s, 0, 0, 0.12, false, 1.0, 0.5, 10.0) < 1e-9);
  CHECK(profile_error(s, 0, 0, 0.12, false, 1.0, 0.01, 10.0) < 1e-9);
  CHECK(ctx.stats_["profile_exact"] == true);
  CHECK(ctx.progress_ok_);
}

TEST_CASE("naca_wing: round tip reaches the span exactly and is wall") {
  TestContext ctx("naca_wing", {{"chord", 2.0}, {"span", 3.0}, {"incidence_deg", 0.0}, {"profile", "0015"}});
  ctx.run();
  Shape s = Shape::load(ctx.artifact("shape").path);
  check_closed(s);
  double zmax = -1;
  for (int f : s.faces_with_tag(Tag::wall)) zmax = std::max(zmax, s.face_box(f).hi.z);
  CHECK(zmax == doctest::Approx(3.0).epsilon(1e-6));
  CHECK(profile_error(s, 0, 0, 0.15, false, 2.0, 1.0, 0.0) < 1e-9);
  bool has_revolution = false;
  for (int f : s.faces_with_tag(Tag::wall)) has_revolution |= s.face_surface_type(f) == "revolution";
  CHECK(has_revolution);
}

TEST_CASE("naca_wing: sharp trailing edge, flat tip, cambered 2412") {
  TestContext ctx("naca_wing", {{"profile", "2412"}, {"tip", "flat"}, {"trailing_edge", "sharp"}, {"incidence_deg", 4.0}});
  ctx.run();
  Shape s = Shape::load(ctx.artifact("shape").path);
  check_closed(s);
  CHECK(ctx.stats_["profile_exact"] == false);
  CHECK(ctx.stats_["profile_max_error"].get<double>() < 1e-6);
  CHECK(profile_error(s, 0.02, 0.4, 0.12, true, 1.0, 0.5, 4.0) < 1e-6);
  // the sharp trailing edge is an edge between the lower and upper faces; heal accepts the solid
  // (a single closed face would touch itself along its seam: a self-intersection for OCCT)
  int extrusions = 0;
  for (int f : s.faces_with_tag(Tag::wall)) extrusions += s.face_surface_type(f) == "extrusion";
  CHECK(extrusions == 2);
  TestContext h("heal", {}, {ctx.artifact("shape")});
  h.run();
  CHECK(h.stats_["self_intersections"] == 0);
}

TEST_CASE("naca_wing: refusals") {
  TestContext round_cambered("naca_wing", {{"profile", "4412"}, {"tip", "round"}});
  CHECK_THROWS_WITH_AS(round_cambered.run(), doctest::Contains("use tip: flat"), StageError);
  TestContext short_span("naca_wing", {{"span", 0.08}});
  CHECK_THROWS_WITH_AS(short_span.run(), doctest::Contains("too short"), StageError);
  TestContext no_pos("naca_wing", {{"profile", "2012"}});
  CHECK_THROWS_AS(no_pos.run(), StageError);
}

TEST_CASE("naca_wing is deterministic and survives save/load") {
  TestContext a("naca_wing", {}), b("naca_wing", {});
  a.run();
  b.run();
  CHECK(mftest::read_text(a.artifact("shape").path) == mftest::read_text(b.artifact("shape").path));
  Shape s = Shape::load(a.artifact("shape").path);
  auto dir = meshflow::testing::scratch_dir("resave");
  s.save(dir / "again.mfshape");
  CHECK(mftest::read_text(dir / "again.mfshape") == mftest::read_text(a.artifact("shape").path));
  Shape t = Shape::load(dir / "again.mfshape");
  for (int f = 0; f < s.num_faces(); ++f) {
    CHECK(t.face_tag(f) == s.face_tag(f));
    CHECK(t.face_area(f) == doctest::Approx(s.face_area(f)).epsilon(1e-12));
  }
  std::filesystem::remove_all(dir);
}
