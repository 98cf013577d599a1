// wing_body geometry kind: closed fluid solid, tags, junction curve, exact NACA sections after
// the planform transforms, volume against an independent quadrature, refusals, determinism.
// The body radius, planform and NACA formulas are written here independently of the generator.
#include <doctest/doctest.h>

#include "support.hpp"

#include "../cad/test_context.hpp"
#include "stages/cad/cad.hpp"
#include "stages/cad/occt.hpp"

#include <BRepGProp.hxx>
#include <GProp_GProps.hxx>

#include <algorithm>
#include <cstdint>
#include <iomanip>
#include <cmath>
#include <map>
#include <set>

using meshflow::StageError;
using meshflow::cad::Shape;
using meshflow::cad::Tag;
using meshflow::cad::Vec3;
using meshflow::testing::TestContext;
using nlohmann::json;

namespace {
constexpr double kPi = 3.14159265358979323846;

// The model's parameters, as the test reads them (schema defaults + overrides).
struct Model {
  double R, Ln, Lc, Lt, rt;
  bool ogive;
  double c0, lambda, semispan, sweep, dihedral, alpha, x0, z0, ff, wake;
  double m = 0, p = 0, t = 0.12;
  bool sharp = false, round = false;
  double y_tip = 0;  // span station of the tip section (tip_station(), cached)
  double L() const { return Ln + Lc + Lt; }
  double r(double x) const {  // body radius at x
    if (x < 0 || x > L()) return 0;
    if (x < Ln) {
      if (!ogive) return R * std::sqrt(std::max(0.0, 1 - std::pow((Ln - x) / Ln, 2)));
      double rho = (R * R + Ln * Ln) / (2 * R);
      return std::sqrt(std::max(0.0, rho * rho - std::pow(Ln - x, 2))) - (rho - R);
    }
    if (x <= Ln + Lc) return R;
    double s = (x - Ln - Lc) / Lt;
    return R - (R - rt) * s * s * (3 - 2 * s);
  }
  double yt_naca(double x) const {  // half thickness, chord 1
    return 5 * t * (0.2969 * std::sqrt(x) - 0.1260 * x - 0.3516 * x * x + 0.2843 * x * x * x +
                    (sharp ? -0.1036 : -0.1015) * x * x * x * x);
  }
  double tip_station() const {  // y of the tip section
    if (!round) return semispan;
    double ymax = 0;
    for (int i = 0; i <= 100000; ++i) ymax = std::max(ymax, yt_naca(i / 100000.0));
    return semispan - ymax * lambda * c0;
  }
  double chord(double y) const { return c0 * (1 - (1 - lambda) * y / y_tip); }
  // The point of the streamwise section at span station y of the profile point at chord
  // fraction x, upper or lower surface: NACA 4-digit, then scale, incidence, sweep, dihedral.
  Vec3 section(double y, double x, bool upper) const {
    double yt = yt_naca(x), yc = 0, dyc = 0;
    if (m > 0) {
      yc = x < p ? m / (p * p) * (2 * p * x - x * x) : m / std::pow(1 - p, 2) * (1 - 2 * p + 2 * p * x - x * x);
      dyc = x < p ? 2 * m / (p * p) * (p - x) : 2 * m / std::pow(1 - p, 2) * (p - x);
    }
    double th = std::atan(dyc), sg = upper ? 1 : -1;
    double px = x - sg * yt * std::sin(th), pz = yc + sg * yt * std::cos(th);
    double c = chord(y);
    // leading edge: the quarter-chord line (x projection) is swept by `sweep` from the root's
    double xle = x0 + y * std::tan(sweep) + 0.25 * std::cos(alpha) * (c0 - c);
    double zle = z0 + y * std::tan(dihedral);
    // nose up by alpha: the trailing edge goes down
    return {xle + c * (px * std::cos(alpha) + pz * std::sin(alpha)), y,
            zle + c * (-px * std::sin(alpha) + pz * std::cos(alpha))};
  }
};

Model model_of(const TestContext& ctx) {
  const json& P = ctx.params();
  auto d = [&](const char* k) { return P.at(k).get<double>(); };
  Model M{d("body_radius"), d("nose_length"), d("cylinder_length"), d("tail_length"), d("tail_radius"),
          P.at("nose") == "ogive", d("root_chord"), d("taper_ratio"), d("semispan"), d("sweep_deg") * kPi / 180,
          d("dihedral_deg") * kPi / 180, d("incidence_deg") * kPi / 180, d("wing_x"), d("wing_z"),
          d("farfield_lengths"), d("wake_lengths")};
  std::string prof = P.at("profile");
  M.m = (prof[0] - '0') / 100.0;
  M.p = (prof[1] - '0') / 10.0;
  M.t = std::stoi(prof.substr(2)) / 100.0;
  M.sharp = P.at("trailing_edge") == "sharp";
  M.round = P.at("tip") == "round";
  M.y_tip = M.tip_station();
  return M;
}

Vec3 face_mid(const Shape& s, int f) {
  auto b = s.face_uv_bounds(f);
  // a point inside the trimmed face: scan a grid for the first contained (u,v)
  for (int j = 1; j < 20; ++j)
    for (int i = 1; i < 20; ++i) {
      double u = b.u0 + (b.u1 - b.u0) * ((i * 7) % 20) / 20.0, v = b.v0 + (b.v1 - b.v0) * ((j * 11) % 20) / 20.0;
      if (s.face_contains_uv(f, u, v, 0)) return s.face_point(f, u, v);
    }
  return s.face_point(f, 0.5 * (b.u0 + b.u1), 0.5 * (b.v0 + b.v1));
}

bool on_body(const Model& M, const Vec3& p, double tol) {
  double rr = std::hypot(p.y, p.z);
  if (p.x >= -tol && p.x <= M.L() + tol && std::abs(rr - M.r(std::clamp(p.x, 0.0, M.L()))) < tol) return true;
  return rr <= M.rt + tol && std::abs(p.x - M.L()) < tol;  // the base
}

struct Parts {
  std::vector<int> body, wing;
};
Parts split_walls(const Shape& s, const Model& M) {
  Parts P;
  for (int f : s.faces_with_tag(Tag::wall)) (on_body(M, face_mid(s, f), 1e-7 * M.L()) ? P.body : P.wing).push_back(f);
  return P;
}

// Volume by OCCT's adaptive integration (relative error 1e-10): cad::Shape::volume() uses the
// fixed-order default, which is about 0.5% off on the degree-8 wing surface.
double accurate_volume(const Shape& s) {
  GProp_GProps g;
  BRepGProp::VolumeProperties(meshflow::cad::occt::shape(s), g, 1e-10);
  return g.Mass();
}

void check_closed(const Shape& s) {
  CHECK(s.num_solids() == 1);
  CHECK(s.free_edges().empty());
  CHECK(s.multiple_edges().empty());
  CHECK(s.valid());
  CHECK(s.volume() > 0);
}

// Largest distance (in local chords) from points of the 4-digit section at station y to the
// nearest wing face.
double section_error(const Shape& s, const Model& M, const std::vector<int>& wing, double y) {
  double worst = 0;
  for (double x : {1e-6, 1e-4, 0.003, 0.0125, 0.05, 0.1, 0.2, 0.29, 0.3, 0.41, 0.5, 0.6, 0.77, 0.9, 0.99, 1.0})
    for (bool up : {true, false}) {
      Vec3 q = M.section(y, x, up);
      double d = 1e300;
      for (int f : wing) d = std::min(d, s.project_to_face(f, q).distance);
      worst = std::max(worst, d / M.chord(y));
    }
  return worst;
}

// Volume of the half body (∫ π r² / 2) and of the part of the wing outside the body, by
// quadrature of the formulas (independent of OpenCASCADE).
double solid_volume_estimate(const Model& M) {
  double vb = 0;
  const int nx = 200000;
  for (int i = 0; i < nx; ++i) {
    double x = (i + 0.5) * M.L() / nx;
    vb += 0.5 * kPi * std::pow(M.r(x), 2) * M.L() / nx;
  }
  // wing: sections y in [0, tip], chord-frame points (xi, eta) with x = s^2 (dense at the
  // leading edge), thickness direction split in ne cells; a cell counts when its centre is
  // outside the body. Section area element c^2 dxi deta.
  double vw = 0;
  const double yt = M.y_tip;
  const int ny = 500, ns = 500, ne = 40;
  for (int k = 0; k < ny; ++k) {
    double y = (k + 0.5) * yt / ny, c = M.chord(y);
    for (int i = 0; i < ns; ++i) {
      double s = (i + 0.5) / ns, x = s * s, dx = 2 * s / ns;
      Vec3 lo = M.section(y, x, false), up = M.section(y, x, true);
      int out = 0;
      for (int j = 0; j < ne; ++j) {
        double f = (j + 0.5) / ne;
        Vec3 q{lo.x + f * (up.x - lo.x), y, lo.z + f * (up.z - lo.z)};
        out += std::hypot(q.y, q.z) > M.r(q.x);
      }
      // area of the strip between the lower and upper points: 2 y_t c^2 dx (thickness normal to
      // the chord for a symmetric profile; the camber shear does not change the area)
      vw += 2 * M.yt_naca(x) * c * c * dx * out / ne * yt / ny;
    }
  }
  return vb + vw;
}

// Edges shared by a wing face and a body face.
std::vector<int> junction_edges(const Shape& s, const Parts& P) {
  std::set<int> body(P.body.begin(), P.body.end()), wing(P.wing.begin(), P.wing.end());
  std::vector<int> j;
  for (int e = 0; e < s.num_edges(); ++e) {
    auto fs = s.edge_faces(e);
    if (fs.size() != 2) continue;
    if ((body.count(fs[0]) && wing.count(fs[1])) || (body.count(fs[1]) && wing.count(fs[0]))) j.push_back(e);
  }
  return j;
}
}  // namespace

TEST_CASE("wing_body default (CRM-like): closed fluid solid, tags, junction curve, exact sections, volume") {
  TestContext ctx("wing_body", {});
  ctx.run();
  Model M = model_of(ctx);
  Shape s = Shape::load(ctx.artifact("shape").path);
  check_closed(s);
  CHECK(s.units() == "m");
  CHECK(ctx.progress_ok_);
  CHECK(s.faces_with_tag(Tag::farfield).size() == 5);
  REQUIRE(s.faces_with_tag(Tag::symmetry).size() == 1);
  CHECK(s.faces_with_tag(Tag::none).empty());
  // the symmetry face is the plane y = 0, its normal out of the fluid (-y)
  int sym = s.faces_with_tag(Tag::symmetry)[0];
  CHECK(std::abs(s.face_box(sym).lo.y) < 1e-6);
  CHECK(std::abs(s.face_box(sym).hi.y) < 1e-6);
  auto b = s.face_uv_bounds(sym);
  CHECK(s.face_normal(sym, b.u0 + 0.01 * (b.u1 - b.u0), b.v0 + 0.01 * (b.v1 - b.v0)).y == doctest::Approx(-1).epsilon(1e-12));
  // the box: x from -2L to L + 3L, y from 0 to 2L, z from -2L to 2L
  auto bb = s.box();
  CHECK(bb.lo.x == doctest::Approx(-M.ff * M.L()).epsilon(1e-6));
  CHECK(bb.hi.x == doctest::Approx((1 + M.wake) * M.L()).epsilon(1e-6));
  CHECK(bb.hi.y == doctest::Approx(M.ff * M.L()).epsilon(1e-6));
  CHECK(bb.hi.z == doctest::Approx(M.ff * M.L()).epsilon(1e-6));
  // every wall face lies on the body (by the radius formula) or is a wing face; the body has
  // nose, cylinder, tail and base, the wing its surface, trailing edge and tip
  Parts P = split_walls(s, M);
  CHECK(P.body.size() == 4);
  CHECK(P.wing.size() == 3);
  CHECK(ctx.stats_["body_faces"] == 4);
  CHECK(ctx.stats_["wing_faces"] == 3);
  // body faces: the whole face on the body surface (samples over the trimmed face)
  for (int f : P.body) {
    auto u = s.face_uv_bounds(f);
    for (int i = 0; i <= 6; ++i)
      for (int j = 0; j <= 6; ++j) {
        double uu = u.u0 + (u.u1 - u.u0) * i / 6, vv = u.v0 + (u.v1 - u.v0) * j / 6;
        if (s.face_contains_uv(f, uu, vv)) CHECK(on_body(M, s.face_point(f, uu, vv), 1e-7 * M.L()));
      }
  }
  // the junction: edges shared by a wing face and a body face, one closed loop, on both surfaces
  auto J = junction_edges(s, P);
  REQUIRE(!J.empty());
  CHECK(ctx.stats_["junction"]["edges"] == (int)J.size());
  std::map<int, int> degree;
  double len = 0;
  for (int e : J) {
    for (int v : s.edge_vertices(e)) degree[v]++;
    len += s.edge_length(e);
    auto r = s.edge_range(e);
    for (int k = 0; k <= 10; ++k) {
      Vec3 q = s.edge_point(e, r.lo + (r.hi - r.lo) * k / 10);
      CHECK(on_body(M, q, 1e-6 * M.L()));
      CHECK(q.y > 0.5 * M.R);  // outside the symmetry plane: the wing pierces the body's side
      double d = 1e300;
      for (int f : P.wing) d = std::min(d, s.project_to_face(f, q).distance);
      CHECK(d < 1e-6 * M.L());
    }
  }
  for (auto& [v, d] : degree) CHECK(d == 2);
  // its length: a bit more than twice the root chord (upper and lower surface)
  CHECK(len > 2 * M.chord(M.R));
  CHECK(len < 2.3 * M.c0);
  // streamwise sections of the exposed wing: the 4-digit formula to 1e-9 chord
  for (double y : {5.0, 12.0, 20.0, 29.0}) {
    INFO("station y = " << y);
    CHECK(section_error(s, M, P.wing, y) < 1e-9);
  }
  CHECK(ctx.stats_["profile_exact"] == true);
  // the flat tip is the tip section: the wing ends at y = semispan
  double ymax = 0;
  for (int f : P.wing) ymax = std::max(ymax, s.face_box(f).hi.y);
  CHECK(ymax == doctest::Approx(M.semispan).epsilon(1e-6));
  // volume: box minus (half body + exposed wing), the latter by quadrature
  double box = (1 + M.ff + M.wake) * M.L() * M.ff * M.L() * 2 * M.ff * M.L();
  double solid = box - accurate_volume(s), est = solid_volume_estimate(M);
  INFO("solid volume " << solid << ", estimate " << est);
  CHECK(std::abs(solid - est) < 1e-4 * est);
  // the wing's part inside the body is substantial: an estimate without it would fail
  CHECK(ctx.stats_["wing_volume"].get<double>() + ctx.stats_["body_volume"].get<double>() - solid > 3e-3 * est);
}

TEST_CASE("wing_body: round tip, ogive nose, mid wing, no dihedral: sections exact and tip at the semispan") {
  TestContext ctx("wing_body", {{"tip", "round"}, {"nose", "ogive"}, {"profile", "0015"}, {"wing_z", 0.0},
                                {"dihedral_deg", 0.0}, {"sweep_deg", 25.0}, {"incidence_deg", 0.0}});
  ctx.run();
  Model M = model_of(ctx);
  Shape s = Shape::load(ctx.artifact("shape").path);
  check_closed(s);
  Parts P = split_walls(s, M);
  CHECK(P.body.size() == 4);
  bool revolution = false;
  double ymax = 0;
  for (int f : P.wing) {
    revolution |= s.face_surface_type(f) == "revolution";
    ymax = std::max(ymax, s.face_box(f).hi.y);
  }
  CHECK(revolution);
  CHECK(ymax == doctest::Approx(M.semispan).epsilon(1e-6));
  CHECK(!junction_edges(s, P).empty());
  for (double y : {6.0, 15.0, 25.0}) CHECK(section_error(s, M, P.wing, y) < 1e-9);
  double box = (1 + M.ff + M.wake) * M.L() * M.ff * M.L() * 2 * M.ff * M.L();
  double solid = box - accurate_volume(s), est = solid_volume_estimate(M);
  CHECK(std::abs(solid - est) < 1e-4 * est);
}

TEST_CASE("wing_body: cambered 2412, sharp trailing edge, flat tip: the interpolated profile within 1e-6") {
  TestContext ctx("wing_body", {{"profile", "2412"}, {"trailing_edge", "sharp"}, {"incidence_deg", 1.5}});
  ctx.run();
  Model M = model_of(ctx);
  Shape s = Shape::load(ctx.artifact("shape").path);
  check_closed(s);
  CHECK(ctx.stats_["profile_exact"] == false);
  Parts P = split_walls(s, M);
  CHECK(P.wing.size() == 3);  // lower and upper surfaces meeting at the trailing edge, and the tip
  for (double y : {8.0, 20.0}) CHECK(section_error(s, M, P.wing, y) < 1e-6);
  // heal accepts it: no face touches itself along a trailing-edge seam
  TestContext h("heal", {}, {ctx.artifact("shape")});
  h.run();
  CHECK(h.stats_["self_intersections"] == 0);
}

TEST_CASE("wing_body: refusals") {
  TestContext long_span("wing_body", {{"semispan", 200.0}});
  CHECK_THROWS_WITH_AS(long_span.run(), doctest::Contains("too long for the far-field box"), StageError);
  TestContext high_wing("wing_body", {{"wing_z", 2.9}});
  CHECK_THROWS_WITH_AS(high_wing.run(), doctest::Contains("does not reach into the body"), StageError);
  TestContext off_body("wing_body", {{"wing_x", 58.0}});
  CHECK_THROWS_WITH_AS(off_body.run(), doctest::Contains("does not reach into the body"), StageError);
  TestContext short_span("wing_body", {{"semispan", 2.5}});
  CHECK_THROWS_WITH_AS(short_span.run(), doctest::Contains("does not reach out of the body"), StageError);
  TestContext fat_tail("wing_body", {{"tail_radius", 3.0}});
  CHECK_THROWS_WITH_AS(fat_tail.run(), doctest::Contains("tail_radius"), StageError);
  TestContext round_cambered("wing_body", {{"profile", "4412"}, {"tip", "round"}});
  CHECK_THROWS_WITH_AS(round_cambered.run(), doctest::Contains("use tip: flat"), StageError);
  TestContext short_wake("wing_body", {{"wake_lengths", 0.2}, {"cylinder_length", 20.0}, {"tail_length", 5.0}});
  CHECK_THROWS_WITH_AS(short_wake.run(), doctest::Contains("closer than 0.1 body lengths"), StageError);
}

TEST_CASE("wing_body is deterministic and heals to a watertight fluid with the same tags") {
  TestContext a("wing_body", {}), b("wing_body", {});
  a.run();
  b.run();
  CHECK(mftest::read_text(a.artifact("shape").path) == mftest::read_text(b.artifact("shape").path));
  TestContext h("heal", {}, {a.artifact("shape")});
  h.run();
  Shape s = Shape::load(h.artifact("shape").path);
  CHECK(s.watertight());
  CHECK(s.faces_with_tag(Tag::wall).size() == 7);
  CHECK(s.faces_with_tag(Tag::symmetry).size() == 1);
  CHECK(s.faces_with_tag(Tag::farfield).size() == 5);
  CHECK(h.stats_["self_intersections"] == 0);
  CHECK(s.volume() == doctest::Approx(Shape::load(a.artifact("shape").path).volume()).epsilon(1e-9));
}

TEST_CASE("workflows/wing_body_parametric.yaml runs to balance and the shell puts junction blocks at the wing-body junction") {
  auto d = mftest::temp_dir("wing-body-workflow");
  std::string wf = std::string(MESHFLOW_SOURCE_DIR) + "/workflows/wing_body_parametric.yaml";
  auto r = mftest::sh(std::string(MESHFLOW_EXE) + " run " + wf + " --cache " + (d / "cache").string() + " --out " +
                      (d / "out").string() + " 2>&1");
  INFO(r.out);
  REQUIRE(r.code == 0);
  json rep = json::parse(mftest::read_text(d / "out/report.json"));
  json shell_stats;
  for (auto& s : rep["stages"])
    if (s["name"] == "shell") shell_stats = s["stats"];
  REQUIRE(shell_stats.is_object());
  CHECK(shell_stats["counts"]["hex_junction_blocks"].get<int>() >= 1);
  // the healed shape (from the cache, by its digest) and the shell's blocks (JSON header)
  std::string dg = rep["outputs"]["shape"]["digest"];
  Shape s = Shape::load(d / "cache/objects" / dg.substr(0, 2) / dg);
  std::string sh = mftest::read_text(d / "out/shell.mfshell");
  REQUIRE(sh.size() > 12);
  std::uint32_t hl = 0;
  for (int i = 0; i < 4; ++i) hl |= std::uint32_t(static_cast<unsigned char>(sh[8 + i])) << (8 * i);
  json header = json::parse(sh.substr(12, hl));
  // the model's parameters as the workflow sets them (the defaults of the kind, see the schema)
  TestContext defaults("wing_body", {{"incidence_deg", 3.0}});
  Model M = model_of(defaults);
  Parts P = split_walls(s, M);
  std::set<int> body(P.body.begin(), P.body.end()), wing(P.wing.begin(), P.wing.end());
  int at_junction = 0;
  for (auto& b : header["blocks"]) {
    if (b["kind"] != "hex_junction") continue;
    int f = b["face"], g = b["partner"];
    at_junction += (body.count(f) && wing.count(g)) || (body.count(g) && wing.count(f));
  }
  CHECK(at_junction >= 1);
  CHECK(at_junction == shell_stats["counts"]["hex_junction_blocks"].get<int>());  // only there (junction_with: [wall])
  MESSAGE("wing_body_parametric shell: " << shell_stats["counts"].dump() << ", self_intersections "
                                         << shell_stats["self_intersections"]);
  std::filesystem::remove_all(d);
}
