#include <doctest/doctest.h>

#include "../cad/test_context.hpp"
#include "stages/cad/cad.hpp"
#include "stages/geometry/blade_sections.hpp"

#include <cmath>
#include <filesystem>
#include <fstream>
#include <sstream>

using meshflow::StageError;
using meshflow::cad::Shape;
using meshflow::cad::Tag;
using meshflow::cad::Vec3;
using meshflow::testing::TestContext;
namespace fs = std::filesystem;

namespace {
const fs::path kRotor = fs::path(MESHFLOW_DATA_DIR) / "rotor67/rotor67geometry.dat";

std::string slurp(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

// An independent minimal reader of the Rotor 67 export: after each "Surface number" line, four
// blocks (title, scale, JM values): x, r*theta (upper), thickness, r. Returns the blade points
// (upper and lower surfaces between JLE and JTE) in Cartesian coordinates (x, r cos t, r sin t).
struct RotorPoints {
  std::vector<std::vector<Vec3>> sections;
  double hub_r_le = 0, casing_r_le = 0;
};
RotorPoints read_rotor_points(const fs::path& p) {
  std::ifstream in(p);
  std::string line;
  const int JM = 110, JLE = 16, JTE = 85;  // from the file's header (checked below)
  RotorPoints out;
  std::string text = slurp(p);
  REQUIRE(text.find("  110   14   22   16   85") != std::string::npos);
  while (std::getline(in, line)) {
    if (line.find("Surface number") == std::string::npos) continue;
    std::vector<double> q[4];
    for (int k = 0; k < 4; ++k) {
      std::getline(in, line);  // title
      std::getline(in, line);  // scale
      while ((int)q[k].size() < JM && std::getline(in, line)) {
        std::istringstream ls(line);
        double v;
        while (ls >> v) q[k].push_back(v);
      }
    }
    std::vector<Vec3> pts;
    for (int j = JLE - 1; j < JTE; ++j)
      for (bool upper : {true, false}) {
        double r = q[3][j], t = (q[1][j] - (upper ? 0 : q[2][j])) / r;
        pts.push_back({q[0][j], r * std::cos(t), r * std::sin(t)});
      }
    if (out.sections.empty()) out.hub_r_le = q[3][JLE - 1];
    out.casing_r_le = q[3][JLE - 1];
    out.sections.push_back(pts);
  }
  return out;
}

void check_closed(const Shape& s) {
  CHECK(s.num_solids() == 1);
  CHECK(s.free_edges().empty());
  CHECK(s.multiple_edges().empty());
  CHECK(s.valid());
  CHECK(s.volume() > 0);
  CHECK(s.faces_with_tag(Tag::none).empty());
}

std::vector<int> bspline_walls(const Shape& s) {
  std::vector<int> out;
  for (int f : s.faces_with_tag(Tag::wall))
    if (s.face_surface_type(f) == "bspline") out.push_back(f);
  return out;
}

// Largest distance (relative to `ref`) of points on `lo` rotated by `angle` about x to face `hi`.
double periodic_mismatch(const Shape& s, int lo, int hi, double angle, int& n) {
  auto b = s.face_uv_bounds(lo);
  double worst = 0;
  n = 0;
  const int K = 30;
  for (int i = 0; i <= K; ++i)
    for (int j = 0; j <= K; ++j) {
      double u = b.u0 + (b.u1 - b.u0) * i / K, v = b.v0 + (b.v1 - b.v0) * j / K;
      if (!s.face_contains_uv(lo, u, v)) continue;
      Vec3 p = s.face_point(lo, u, v);
      Vec3 q{p.x, p.y * std::cos(angle) - p.z * std::sin(angle), p.y * std::sin(angle) + p.z * std::cos(angle)};
      double r = std::hypot(p.y, p.z);
      worst = std::max(worst, s.project_to_face(hi, q).distance / r);
      ++n;
    }
  return worst;
}

// Largest distance (relative to the radius) of points of `lo`'s boundary edges, rotated, to the
// nearest boundary edge of `hi`.
double boundary_mismatch(const Shape& s, int lo, int hi, double angle) {
  double worst = 0;
  for (int e : s.face_edges(lo)) {
    if (s.edge_degenerate(e)) continue;
    auto r = s.edge_range(e);
    for (int i = 0; i <= 20; ++i) {
      Vec3 p = s.edge_point(e, r.lo + (r.hi - r.lo) * i / 20);
      Vec3 q{p.x, p.y * std::cos(angle) - p.z * std::sin(angle), p.y * std::sin(angle) + p.z * std::cos(angle)};
      double best = 1e300;
      for (int h : s.face_edges(hi))
        if (!s.edge_degenerate(h)) best = std::min(best, s.project_to_edge(h, q).distance);
      worst = std::max(worst, best / std::hypot(p.y, p.z));
    }
  }
  return worst;
}

// Largest distance of the points to the nearest of `faces` (projection on their surfaces).
double max_distance(const Shape& s, const std::vector<int>& faces, const std::vector<Vec3>& pts) {
  double worst = 0;
  for (auto& p : pts) {
    double best = 1e300;
    for (int f : faces) best = std::min(best, s.project_to_face(f, p).distance);
    worst = std::max(worst, best);
  }
  return worst;
}
}  // namespace

TEST_CASE("blade_sector: Rotor 67 passage, tags, blade through the file's points, exact periodic sides") {
  REQUIRE(fs::exists(kRotor));
  TestContext ctx("blade_sector", {{"file", kRotor.string()}});
  ctx.run();
  Shape s = Shape::load(ctx.artifact("shape").path);
  check_closed(s);
  CHECK(s.units() == "ft");
  CHECK(ctx.stats_["blades"] == 22);
  CHECK(s.faces_with_tag(Tag::periodic_lo).size() == 1);
  CHECK(s.faces_with_tag(Tag::periodic_hi).size() == 1);
  CHECK(s.faces_with_tag(Tag::farfield).size() == 2);
  CHECK(s.faces_with_tag(Tag::symmetry).empty());
  auto blade = bspline_walls(s);
  CHECK(blade.size() >= 1);
  CHECK(s.faces_with_tag(Tag::wall).size() == blade.size() + 2);  // + hub and casing (revolution)
  for (int f : s.faces_with_tag(Tag::wall))
    if (s.face_surface_type(f) != "bspline") CHECK(s.face_surface_type(f) == "revolution");
  // the blade meets hub and casing: every blade face shares edges with the revolution faces
  int junction = 0;
  for (int e = 0; e < s.num_edges(); ++e) {
    auto fs = s.edge_faces(e);
    bool b = false, w = false;
    for (int f : fs) {
      b |= std::find(blade.begin(), blade.end(), f) != blade.end();
      w |= s.face_surface_type(f) == "revolution";
    }
    junction += b && w;
  }
  CHECK(junction >= 2);

  // every point of the 14 streamsurfaces' blade sections lies on the blade (1e-6 blade height)
  auto rp = read_rotor_points(kRotor);
  REQUIRE(rp.sections.size() == 14);
  double height = rp.casing_r_le - rp.hub_r_le;
  std::vector<Vec3> all;
  for (auto& sec : rp.sections) all.insert(all.end(), sec.begin(), sec.end());
  CHECK(all.size() == 14 * 140);
  double err = max_distance(s, blade, all);
  MESSAGE("Rotor 67 section points: max distance to the blade " << err << " ft = " << err / height << " blade heights");
  CHECK(err < 1e-6 * height);
  CHECK(double(ctx.stats_["section_points_max_error"]) < 1e-9 * height);

  // periodic_lo rotated by 2 pi / 22 lands on periodic_hi
  int lo = s.faces_with_tag(Tag::periodic_lo)[0], hi = s.faces_with_tag(Tag::periodic_hi)[0];
  int n = 0;
  double mis = periodic_mismatch(s, lo, hi, 2 * M_PI / 22, n);
  MESSAGE("periodic match: " << n << " points, max distance / radius " << mis);
  CHECK(n > 100);
  CHECK(mis < 1e-9);
  // the trimmed boundaries match too (they are intersection curves: OCCT's approximation)
  double bmis = boundary_mismatch(s, lo, hi, 2 * M_PI / 22);
  MESSAGE("periodic boundary match: max distance / radius " << bmis);
  CHECK(bmis < 1e-5);
  // and the rotation the other way does not (the test can fail)
  CHECK(periodic_mismatch(s, lo, hi, -2 * M_PI / 22, n) > 1e-3);
  // the periodic sides do not touch the blade: the passage spans one pitch
  CHECK(s.volume() > 0);
}

TEST_CASE("blade_sector: CSV sections, scale and units, byte-identical reruns") {
  // a staggered elliptic blade on 5 cylindrical sections r = 1 .. 2, 12 blades
  auto dir = meshflow::testing::scratch_dir("bladecsv");
  std::ofstream out(dir / "blade.csv");
  out << "# test blade\nx,y,z\n";
  const int M = 40;
  std::vector<Vec3> pts;
  for (int k = 0; k < 5; ++k) {
    double r = 1.0 + 0.25 * k, stagger = 0.5 + 0.2 * k;
    out << "section " << k + 1 << "\n";
    for (int i = 0; i < M; ++i) {
      double a = 2 * M_PI * i / M, c = 0.3, t = 0.03;
      double xs = 0.5 * c * std::cos(a), ys = 0.5 * t * std::sin(a);  // chordwise, thickness
      double x = xs * std::cos(stagger) - ys * std::sin(stagger), rt = xs * std::sin(stagger) + ys * std::cos(stagger);
      Vec3 p{x, r * std::cos(rt / r), r * std::sin(rt / r)};
      pts.push_back(p);
      char b[128];
      std::snprintf(b, sizeof b, "%.17g, %.17g, %.17g\n", p.x, p.y, p.z);
      out << b;
    }
    out << "\n";
  }
  out.close();
  nlohmann::json P = {{"file", (dir / "blade.csv").string()}, {"format", "csv"}, {"blades", 12}, {"units", "m"}};
  TestContext ctx("blade_sector", P);
  try { ctx.run(); } catch (...) { for (auto& l : ctx.log_) MESSAGE(l); throw; }
  Shape s = Shape::load(ctx.artifact("shape").path);
  check_closed(s);
  CHECK(s.faces_with_tag(Tag::periodic_lo).size() == 1);
  CHECK(s.faces_with_tag(Tag::periodic_hi).size() == 1);
  CHECK(s.faces_with_tag(Tag::farfield).size() == 2);
  auto blade = bspline_walls(s);
  REQUIRE(!blade.empty());
  CHECK(max_distance(s, blade, pts) < 1e-6);
  int lo = s.faces_with_tag(Tag::periodic_lo)[0], hi = s.faces_with_tag(Tag::periodic_hi)[0], n = 0;
  CHECK(periodic_mismatch(s, lo, hi, 2 * M_PI / 12, n) < 1e-9);
  CHECK(boundary_mismatch(s, lo, hi, 2 * M_PI / 12) < 1e-5);
  // hub and casing cylinders r = 1 and 2
  for (int f : s.faces_with_tag(Tag::wall))
    if (s.face_surface_type(f) != "bspline") {
      auto b = s.face_box(f);
      double r = std::max({std::abs(b.hi.y), std::abs(b.lo.y), std::abs(b.hi.z), std::abs(b.lo.z)});
      CHECK((std::abs(r - 1.0) < 0.05 || std::abs(r - 2.0) < 0.05));
    }
  // same key, same bytes
  TestContext again("blade_sector", P);
  again.run();
  CHECK(slurp(ctx.artifact("shape").path) == slurp(again.artifact("shape").path));
  // a UTF-8 byte order mark before the header (spreadsheet exports) reads the same sections
  {
    std::ofstream bom(dir / "bom.csv", std::ios::binary);
    bom << "\xEF\xBB\xBF" << slurp(dir / "blade.csv");
  }
  auto plain = meshflow::geometry::parse_blade_csv(slurp(dir / "blade.csv"), "blade.csv");
  auto with_bom = meshflow::geometry::parse_blade_csv(slurp(dir / "bom.csv"), "bom.csv");
  REQUIRE(with_bom.loops.size() == plain.loops.size());
  for (size_t k = 0; k < plain.loops.size(); ++k) {
    REQUIRE(with_bom.loops[k].size() == plain.loops[k].size());
    for (size_t i = 0; i < plain.loops[k].size(); ++i) CHECK(with_bom.loops[k][i].t == plain.loops[k][i].t);
  }
  // csv without blades: refused
  TestContext nob("blade_sector", {{"file", (dir / "blade.csv").string()}, {"format", "csv"}});
  CHECK_THROWS_WITH_AS(nob.run(), doctest::Contains("blades"), StageError);
  fs::remove_all(dir);
}

TEST_CASE("blade_sector: broken section files are refused with the file and line") {
  auto dir = meshflow::testing::scratch_dir("bladebad");
  auto write = [&](const std::string& name, const std::string& text) {
    std::ofstream(dir / name) << text;
    return (dir / name).string();
  };
  TestContext a("blade_sector", {{"file", write("empty.dat", "")}});
  CHECK_THROWS_WITH_AS(a.run(), doctest::Contains("Surface number"), StageError);
  if (fs::exists(kRotor)) {
    std::string t = slurp(kRotor);
    TestContext b("blade_sector", {{"file", write("trunc.dat", t.substr(0, t.size() / 2))}});
    CHECK_THROWS_WITH_AS(b.run(), doctest::Contains("ends"), StageError);
    std::string c = t;
    c.replace(c.find("0.309143"), 8, "0.3091x3");
    TestContext d("blade_sector", {{"file", write("garbage.dat", c)}});
    CHECK_THROWS_WITH_AS(d.run(), doctest::Contains("line"), StageError);
  }
  TestContext e("blade_sector", {{"file", write("one.csv", "0,1,0\n0,1,1\n")}, {"format", "csv"}, {"blades", 3}});
  CHECK_THROWS_WITH_AS(e.run(), doctest::Contains("two sections"), StageError);
  TestContext f("blade_sector", {{"file", (dir / "missing.dat").string()}});
  CHECK_THROWS_AS(f.run(), StageError);
  fs::remove_all(dir);
}
