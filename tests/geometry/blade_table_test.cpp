// blade_sector's section tables (csv x,y,z and zrt z,r,theta: header or not, separators, section
// column, BOM, CRLF, units), their refusals (file, line, what to do), and the passage closure
// checks (passage_check: which surface fails and by how much). The blade is
// scripts/synthetic-blade.py's cambered NACA-like profile on 6 sections, r = 15 .. 30 cm.
#include <doctest/doctest.h>

#include "../cad/test_context.hpp"
#include "stages/cad/cad.hpp"
#include "stages/geometry/blade_sections.hpp"
#include "stages/geometry/passage_check.hpp"
#include "support.hpp"

#include <cmath>
#include <filesystem>
#include <fstream>
#include <sstream>

using meshflow::StageError;
using meshflow::cad::Shape;
using meshflow::geometry::BladeSections;
using meshflow::geometry::parse_blade_table;
using meshflow::geometry::TableLayout;
using meshflow::geometry::TableOptions;
using meshflow::testing::TestContext;
namespace fs = std::filesystem;

namespace {
// A temporary folder removed when the test ends, passed or not.
struct Scratch {
  fs::path dir = mftest::temp_dir("bladetable");
  ~Scratch() {
    std::error_code ec;
    fs::remove_all(dir, ec);
  }
};

// scripts/synthetic-blade.py OUT ARGS: the file's text.
std::string synthetic(const Scratch& s, const std::string& name, const std::string& args) {
  fs::path out = s.dir / name;
  auto r = mftest::sh(std::string(MESHFLOW_PYTHON) + " " + MESHFLOW_SOURCE_DIR "/scripts/synthetic-blade.py " + out.string() +
                      " " + args + " 2>&1");
  REQUIRE_MESSAGE(r.code == 0, r.out);
  return mftest::read_text(out);
}

BladeSections table(const std::string& text, TableLayout layout = TableLayout::xyz, const std::string& angle = "") {
  return parse_blade_table(text, "test.csv", TableOptions{layout, angle, 0, 0});
}

// Largest difference between two readings' loops (Cartesian, relative to the largest radius).
double difference(const BladeSections& a, const BladeSections& b) {
  REQUIRE(a.loops.size() == b.loops.size());
  double worst = 0, rmax = 0;
  for (size_t k = 0; k < a.loops.size(); ++k) {
    REQUIRE(a.loops[k].size() == b.loops[k].size());
    for (size_t i = 0; i < a.loops[k].size(); ++i) {
      auto& p = a.loops[k][i];
      auto& q = b.loops[k][i];
      double d = std::hypot(p.x - q.x, p.r * std::cos(p.t) - q.r * std::cos(q.t), p.r * std::sin(p.t) - q.r * std::sin(q.t));
      worst = std::max(worst, d), rmax = std::max(rmax, p.r);
    }
  }
  return worst / rmax;
}

std::string replace_all(std::string s, const std::string& a, const std::string& b) {
  for (size_t i = s.find(a); i != std::string::npos; i = s.find(a, i + b.size())) s.replace(i, a.size(), b);
  return s;
}

// The message of the StageError `f` throws ("" when it throws none).
template <class F>
std::string error_of(F f) {
  try {
    f();
  } catch (const StageError& e) {
    return e.what();
  }
  return "";
}
}  // namespace

TEST_CASE("blade_sector tables: every csv variant reads the same sections") {
  Scratch s;
  const auto base = table(synthetic(s, "base.csv", ""));
  CHECK(base.loops.size() == 6);
  CHECK(base.loops[0].size() == 80);
  CHECK(base.units.empty());
  const std::vector<std::pair<std::string, std::string>> variants = {
      {"no header", "--no-header"},
      {"semicolons", "--sep semicolon"},
      {"tabs", "--sep tab"},
      {"blanks, no header", "--sep space --no-header"},
      {"section column", "--section-column"},
      {"section column, no header", "--section-column --no-header --sep space"},
      {"BOM and CRLF", "--bom --crlf"},
      {"units comment", "--units-comment cm"},
  };
  for (auto& [what, args] : variants) {
    CAPTURE(what);
    auto b = table(synthetic(s, "v.csv", args));
    CHECK(difference(base, b) == 0.0);
    CHECK(b.mean.size() == 6);
  }
  CHECK(table(synthetic(s, "u.csv", "--units-comment cm")).units == "cm");
  // a header with units; semicolons with decimal commas (a European spreadsheet's export)
  std::string text = synthetic(s, "b.csv", "");
  auto with_units = table(replace_all(text, "x,y,z", "x [cm], y [cm], z [cm]"));
  CHECK(with_units.units == "cm");
  CHECK(difference(base, with_units) == 0.0);
  std::string euro = replace_all(replace_all(synthetic(s, "e.csv", "--sep semicolon"), ".", ","), "x;y;z", "X;Y;Z");
  CHECK(difference(base, table(euro)) == 0.0);
  // sections written tip to hub, or one of them the other way round, read the same blade
  auto sections = [&](const std::string& t) {
    std::vector<std::string> out(1);
    std::istringstream in(t);
    std::string l;
    std::getline(in, l);  // header
    while (std::getline(in, l))
      if (l.empty()) out.emplace_back();
      else out.back() += l + "\n";
    return out;
  };
  auto secs = sections(text);
  REQUIRE(secs.size() == 6);
  std::string reversed = "x,y,z\n";
  for (size_t k = secs.size(); k-- > 0;) reversed += secs[k] + "\n";
  auto rev = table(reversed);
  CHECK(difference(base, rev) == 0.0);
  CHECK(rev.notes.back().find("reversed") != std::string::npos);
  // different point counts per section: resampled to a common count, the blade nearly the same
  auto coarse = sections(synthetic(s, "c.csv", "--points 30"));
  std::string mixed = "x,y,z\n" + secs[0] + "\n" + coarse[1];
  for (size_t k = 2; k < 6; ++k) mixed += "\n" + secs[k];
  auto m = table(mixed);
  CHECK(m.resampled_from == 80);
  CHECK(m.loops[1].size() == m.loops[0].size());
}

TEST_CASE("blade_sector tables: the z, r, theta layout, degrees or radians, reads the x, y, z blade") {
  Scratch s;
  const auto base = table(synthetic(s, "base.csv", ""));
  const std::string deg = synthetic(s, "deg.zrt", "--layout zrt");
  CHECK(meshflow::geometry::detect_table_layout(deg) == TableLayout::zrt);
  CHECK(meshflow::geometry::detect_table_layout(synthetic(s, "xyz.csv", "")) == TableLayout::xyz);
  CHECK(difference(base, table(deg, TableLayout::zrt)) < 1e-8);
  CHECK(difference(base, table(synthetic(s, "rad.zrt", "--layout zrt --radians"), TableLayout::zrt)) < 1e-8);
  CHECK(difference(base, table(synthetic(s, "col.zrt", "--layout zrt --section-column --sep tab"), TableLayout::zrt)) < 1e-8);
  // no header: degrees unless angle_unit says radians
  CHECK(difference(base, table(synthetic(s, "nh.zrt", "--layout zrt --no-header"), TableLayout::zrt)) < 1e-8);
  CHECK(difference(base, table(synthetic(s, "nhr.zrt", "--layout zrt --no-header --radians"), TableLayout::zrt, "rad")) < 1e-8);
  // read as degrees, a radian table's blade would wrap round the axis: the stage says so
  const std::string rad = synthetic(s, "r.zrt", "--layout zrt --no-header --radians");
  auto wrong = table(rad, TableLayout::zrt);
  CHECK(difference(base, wrong) > 1e-3);
}

TEST_CASE("blade_sector tables: a z, r, theta table in cm makes the same passage as its x, y, z table") {
  Scratch s;
  synthetic(s, "b.csv", "--units-comment cm");
  synthetic(s, "b.zrt", "--layout zrt --units-comment cm");
  TestContext a("blade_sector", {{"file", (s.dir / "b.csv").string()}, {"format", "csv"}, {"blades", 24}});
  TestContext b("blade_sector", {{"file", (s.dir / "b.zrt").string()}, {"format", "zrt"}, {"blades", 24}});
  TestContext m("blade_sector", {{"file", (s.dir / "b.zrt").string()}, {"format", "zrt"}, {"blades", 24}, {"units", "m"}});
  a.run();
  b.run();
  m.run();
  Shape sa = Shape::load(a.artifact("shape").path), sb = Shape::load(b.artifact("shape").path);
  Shape sm = Shape::load(m.artifact("shape").path);
  CHECK(sa.units() == "cm");
  CHECK(sb.units() == "cm");
  CHECK(sm.units() == "m");
  CHECK(sa.num_solids() == 1);
  CHECK(sa.free_edges().empty());
  // the tables hold 9 significant digits: the passages agree to 1e-4 (9e-6 measured)
  CHECK(std::abs(sb.volume() / sa.volume() - 1) < 1e-4);
  // cm to m: lengths x 0.01 (OCCT's volume of the trimmed B-spline faces varies by 1.4% between
  // the two scales: compared through the blade height instead)
  CHECK(double(m.stats_["blade_height"]) == doctest::Approx(0.01 * double(a.stats_["blade_height"])).epsilon(1e-9));
  CHECK(double(m.stats_["axial_chord"]) == doctest::Approx(0.01 * double(a.stats_["axial_chord"])).epsilon(1e-9));
  CHECK(a.stats_["format"] == "csv");
  CHECK(b.stats_["format"] == "zrt");
}

TEST_CASE("blade_sector tables: bad files are refused with the file, the line and what to do") {
  Scratch s;
  const std::string good = synthetic(s, "g.csv", "");
  auto bad = [&](const std::string& text, TableLayout layout = TableLayout::xyz) {
    return error_of([&] { table(text, layout); });
  };
  std::string t = good;
  t.replace(t.find('\n', t.find('\n') + 1) + 1, 0, "1.0, 2.0, abc\n");  // line 3
  auto e = bad(t);
  CHECK(e.find("test.csv") != std::string::npos);
  CHECK(e.find("line 3") != std::string::npos);
  CHECK(e.find("'abc' is not a number") != std::string::npos);
  e = bad(replace_all(good, "x,y,z", "x,y,z,pressure"));
  CHECK(e.find("line 1") != std::string::npos);
  CHECK(e.find("'pressure'") != std::string::npos);
  CHECK(e.find("remove the column") != std::string::npos);
  e = bad(replace_all(good, "x,y,z", "z,r,theta"));
  CHECK(e.find("format: zrt") != std::string::npos);
  e = bad(replace_all(good, "x,y,z", "x [cm],y [mm],z [cm]"));
  CHECK(e.find("different units") != std::string::npos);
  e = bad("# units: parsecs\n" + good);
  CHECK(e.find("line 1") != std::string::npos);
  CHECK(e.find("mm, cm, m, in or ft") != std::string::npos);
  t = good;
  t.insert(t.find('\n') + 1, "1,2\n");
  e = bad(t);
  CHECK(e.find("line 2") != std::string::npos);
  CHECK(e.find("expected 3 numbers") != std::string::npos);
  // a section column whose value comes back after another section
  std::string col = synthetic(s, "c.csv", "--section-column");
  col += "1,0.5,15,0.1\n";
  e = bad(col);
  CHECK(e.find("appears again") != std::string::npos);
  CHECK(e.find("keep each section's rows together") != std::string::npos);
  e = bad(good.substr(0, good.find("\n\n")));
  CHECK(e.find("at least two sections") != std::string::npos);
  e = bad("x,y,z\n0,1,0\n0,1,1\n0,2,0\n\n0,2,1\n0,2,2\n1,2,2\n");
  CHECK(e.find("at least 8") != std::string::npos);
  // the stage refuses as the parser does, naming the file
  std::ofstream(s.dir / "bad.csv") << replace_all(good, "x,y,z", "x,y,z,pressure");
  TestContext ctx("blade_sector", {{"file", (s.dir / "bad.csv").string()}, {"format", "csv"}, {"blades", 12}});
  CHECK_THROWS_WITH_AS(ctx.run(), doctest::Contains("bad.csv"), StageError);
}

TEST_CASE("blade_sector: a blade thicker than the pitch is refused naming the periodic surface, the place and the blade count that fits") {
  Scratch s;
  synthetic(s, "b.csv", "--units-comment cm");
  TestContext ctx("blade_sector", {{"file", (s.dir / "b.csv").string()}, {"format", "csv"}, {"blades", 200}});
  std::string e = error_of([&] { ctx.run(); });
  CAPTURE(e);
  CHECK(e.find("the periodic surface cuts the blade") != std::string::npos);
  CHECK(e.find("section 1") != std::string::npos);
  CHECK(e.find(" cm beyond periodic_") != std::string::npos);
  CHECK(e.find("at most 1") != std::string::npos);  // 135: the blade spans 2.67 degrees at the hub
  CHECK(e.find("do not close") == std::string::npos);  // refused before the boolean, not after
}

TEST_CASE("blade_sector: passage_check names the surface that fails and by how much") {
  using meshflow::geometry::Cyl;
  using meshflow::geometry::PassageSamples;
  // a straight blade of half-angle 0.05 rad on r = 1 .. 2, periodic surfaces at +-0.25 rad
  PassageSamples p;
  p.units = "mm", p.pitch = 0.5, p.x_in = -1, p.x_out = 1, p.height = 1, p.ta = -1, p.tb = 1;
  p.hub = {{-1.1, 1.0, 0}, {1.1, 1.0, 0}};
  p.casing = {{-1.1, 2.0, 0}, {1.1, 2.0, 0}};
  for (int i = 0; i <= 20; ++i) {
    double x = -0.2 + 0.02 * i;
    p.blade_root.push_back({x, 0.9, 0});
    p.blade_tip.push_back({x, 2.1, 0});
    p.periodic_root.push_back({-1.2 + 0.12 * i, 0.9, -0.25});
    p.periodic_tip.push_back({-1.2 + 0.12 * i, 2.1, -0.25});
    p.periodic_in.push_back({-1.2, 0.9 + 0.06 * i, -0.25});
    p.periodic_out.push_back({1.2, 0.9 + 0.06 * i, -0.25});
  }
  for (double r : {1.0, 1.5, 2.0}) {
    std::vector<Cyl> loop;
    for (int i = 0; i < 16; ++i) {
      double a = 2 * M_PI * i / 16;
      loop.push_back({0.2 * std::cos(a), r, 0.05 * std::sin(a)});
    }
    p.sections.push_back(loop);
    p.periodic_rows.push_back({{-1.2, r, -0.25}, {1.2, r, -0.25}});
  }
  CHECK(meshflow::geometry::check_passage(p).empty());
  CHECK(meshflow::geometry::passage_margins(p).find("blade above casing by 0.1 mm") != std::string::npos);
  auto first = [](const PassageSamples& q) {
    auto f = meshflow::geometry::check_passage(q);
    REQUIRE(!f.empty());
    CHECK(f[0].fatal);
    return f[0].surface + ": " + f[0].text;
  };
  {  // the blade's tip extension 3 mm short of the casing
    auto q = p;
    for (auto& c : q.blade_tip) c.r = 1.997;
    auto t = first(q);
    CHECK(t.find("blade: the blade does not reach through the casing") == 0);
    CHECK(t.find("0.003 mm below the casing") != std::string::npos);
  }
  {  // the hub ends before the inflow plane
    auto q = p;
    q.hub.front().x = -0.8;
    auto t = first(q);
    CHECK(t.find("hub: the hub does not reach the inflow plane") == 0);
    CHECK(t.find("starts 0.2 mm downstream") != std::string::npos);
  }
  {  // the periodic surface stops short of the outflow plane
    auto q = p;
    for (auto& c : q.periodic_out) c.x = 0.9;
    CHECK(first(q).find("periodic: the periodic surface does not reach the outflow plane: it ends 0.1 mm upstream") == 0);
  }
  {  // a blade as thick as the pitch
    auto q = p;
    for (auto& l : q.sections)
      for (auto& c : l) c.t *= 6;  // half-angle 0.3 > 0.25
    auto t = first(q);
    CHECK(t.find("periodic: the periodic surface cuts the blade") == 0);
    CHECK(t.find("at most 10 blades fit") != std::string::npos);  // floor(pi / 0.3)
  }
  {  // a section outside the casing radius is a note, not a failure
    auto q = p;
    for (auto& c : q.sections.back()) c.r = 2.003;
    auto f = meshflow::geometry::check_passage(q);
    REQUIRE(f.size() == 1);
    CHECK(!f[0].fatal);
    CHECK(f[0].text.find("section 3 lies up to 0.003 mm outside the casing radius") == 0);
  }
}
