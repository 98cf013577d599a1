// heal on defects made here (OCCT is used to make them: this test is a leaf of stages/heal):
// a face moved by 1e-5, a face deleted, a sliver face, a duplicated face.
#include <doctest/doctest.h>

#include "../cad/test_context.hpp"
#include "stages/cad/cad.hpp"
#include "stages/cad/occt.hpp"

#include <BRepBuilderAPI_MakePolygon.hxx>
#include <BRepBuilderAPI_MakeFace.hxx>
#include <BRepBuilderAPI_Transform.hxx>
#include <BRepAlgoAPI_Common.hxx>
#include <BRepAlgoAPI_Cut.hxx>
#include <BRepAlgoAPI_Fuse.hxx>
#include <BRepPrimAPI_MakeBox.hxx>
#include <BRepPrimAPI_MakeSphere.hxx>
#include <BRepPrimAPI_MakePrism.hxx>
#include <BRep_Builder.hxx>
#include <TopExp_Explorer.hxx>
#include <TopoDS.hxx>
#include <TopoDS_Compound.hxx>
#include <Geom_BezierSurface.hxx>
#include <TColgp_Array2OfPnt.hxx>
#include <gp_Trsf.hxx>

#include <cmath>
#include <fstream>
#include <iterator>

using meshflow::StageError;
using meshflow::cad::Shape;
using meshflow::testing::TestContext;
namespace occt = meshflow::cad::occt;

namespace {
// The 6 faces of a unit box as separate (unsewn) faces, optionally transformed.
std::vector<TopoDS_Shape> box_faces() {
  TopoDS_Shape box = BRepPrimAPI_MakeBox(1.0, 1.0, 1.0).Shape();
  std::vector<TopoDS_Shape> f;
  for (TopExp_Explorer ex(box, TopAbs_FACE); ex.More(); ex.Next())
    f.push_back(BRepBuilderAPI_Transform(ex.Current(), gp_Trsf(), Standard_True).Shape());  // deep copy
  return f;
}
TopoDS_Shape compound(const std::vector<TopoDS_Shape>& v) {
  TopoDS_Compound c;
  BRep_Builder b;
  b.MakeCompound(c);
  for (auto& s : v) b.Add(c, s);
  return c;
}
struct Run {
  std::unique_ptr<TestContext> ctx;
  meshflow::Artifact input;
  std::filesystem::path dir;
};
// Saves `s` as a shape artifact and returns a heal context on it.
std::unique_ptr<TestContext> heal_on(const TopoDS_Shape& s, nlohmann::json params, std::filesystem::path& keep) {
  keep = meshflow::testing::scratch_dir("defect");
  meshflow::Artifact a;
  a.name = "shape";
  a.type = "shape";
  a.path = keep / "in.mfshape";
  occt::make_shape(s, "m").save(a.path);
  return std::make_unique<TestContext>("heal", params, std::vector<meshflow::Artifact>{a});
}
// Heals the unit box's faces `f` (some missing): the closed box's planar caps
// (stats.fixes.planar_holes_capped).
nlohmann::json capped_unit_box(const std::vector<TopoDS_Shape>& f) {
  std::filesystem::path d;
  auto h = heal_on(compound(f), nlohmann::json::object(), d);
  h->run();
  Shape s = Shape::load(h->artifact("shape").path);
  CHECK(s.watertight());
  CHECK(s.volume() == doctest::Approx(1.0).epsilon(1e-6));
  nlohmann::json caps = h->stats_["fixes"]["planar_holes_capped"];
  std::filesystem::remove_all(d);
  return caps;
}
// Heals the box faces `f`, whose gap sewing must measure and close: the closed box's stats.
nlohmann::json sewn_at_measured_gap(const std::vector<TopoDS_Shape>& f) {
  std::filesystem::path d;
  auto h = heal_on(compound(f), nlohmann::json::object(), d);
  h->run();
  Shape s = Shape::load(h->artifact("shape").path);
  CHECK(s.watertight());
  CHECK(s.num_faces() == 6);
  nlohmann::json st = h->stats_;
  REQUIRE(st["fixes"]["sewing_gap_measured"].is_object());
  CHECK(st["fixes"]["sewing_gap_measured"]["free_edges_after"] == 0);
  std::filesystem::remove_all(d);
  return st;
}
}  // namespace

TEST_CASE("defect: a face moved by 1e-5 is sewn with tolerance 1e-4, and with 1e-7 at the gap it measures") {
  auto f = box_faces();
  gp_Trsf t;
  t.SetTranslation(gp_Vec(0, 0, 1e-5));
  f[5] = BRepBuilderAPI_Transform(f[5], t, Standard_True).Shape();
  std::filesystem::path d1, d2;
  auto h = heal_on(compound(f), {{"tolerance", 1e-4}}, d1);
  h->run();
  Shape s = Shape::load(h->artifact("shape").path);
  CHECK(s.watertight());
  CHECK(s.num_faces() == 6);
  CHECK(s.volume() == doctest::Approx(1.0).epsilon(1e-4));
  CHECK(h->stats_["before"]["free_edges"] == 24);
  CHECK(h->stats_["fixes"]["sewing"]["contiguous_edges"] == 12);
  // with 1e-7 the first sewing leaves the face apart; the gap measured between the free edges
  // (1e-5, far below 1 % of the box) is the tolerance of the second
  auto strict = heal_on(compound(f), {{"tolerance", 1e-7}}, d2);
  strict->run();
  CHECK(Shape::load(strict->artifact("shape").path).watertight());
  CHECK(strict->stats_["fixes"]["sewing_gap_measured"]["gap"].get<double>() == doctest::Approx(1e-5).epsilon(0.05));
  std::filesystem::remove_all(d2);
}

TEST_CASE("defect: a sliver face is removed by default and refused when sewing and small-entity fixes are off") {
  // a prism whose section has a 1e-6 long side: its side face is a 1e-6 x 1 strip
  BRepBuilderAPI_MakePolygon poly;
  for (auto [x, y] : std::vector<std::pair<double, double>>{{0, 0}, {1, 0}, {1, 1}, {0, 1}, {0, 1 - 1e-6}}) poly.Add(gp_Pnt(x, y, 0));
  poly.Close();
  TopoDS_Face sec = BRepBuilderAPI_MakeFace(poly.Wire());
  TopoDS_Shape prism = BRepPrimAPI_MakePrism(sec, gp_Vec(0, 0, 1)).Shape();
  REQUIRE(occt::make_shape(prism, "m").num_faces() == 7);
  std::filesystem::path d1, d2;
  auto h = heal_on(prism, {{"tolerance", 1e-5}}, d1);
  h->run();
  Shape s = Shape::load(h->artifact("shape").path);
  CHECK(s.watertight());
  CHECK(s.num_faces() == 6);  // the strip and the split side merged into one face
  for (int i = 0; i < s.num_faces(); ++i) CHECK(s.face_area(i) > 0.5);
  auto off = heal_on(prism, {{"tolerance", 1e-5}, {"sew", false}, {"fix_small_edges", false}, {"fix_small_faces", false}, {"unify", false}}, d2);
  CHECK_THROWS_WITH_AS(off->run(), doctest::Contains("narrower than the tolerance"), StageError);
  std::filesystem::remove_all(d1);
  std::filesystem::remove_all(d2);
}

TEST_CASE("defect: a duplicated face is dropped before sewing") {
  auto f = box_faces();
  f.push_back(BRepBuilderAPI_Transform(f[2], gp_Trsf(), Standard_True).Shape());
  std::filesystem::path d;
  auto h = heal_on(compound(f), nlohmann::json::object(), d);
  h->run();
  CHECK(h->stats_["fixes"]["duplicate_faces_removed"] == 1);
  Shape s = Shape::load(h->artifact("shape").path);
  CHECK(s.watertight());
  CHECK(s.num_faces() == 6);
  std::filesystem::remove_all(d);
}

TEST_CASE("heal keeps the tags of a tagged input and is deterministic") {
  TestContext g("naca_wing", {{"span", 0.8}});
  g.run();
  TestContext h1("heal", nlohmann::json::object(), {g.artifact("shape")});
  TestContext h2("heal", nlohmann::json::object(), {g.artifact("shape")});
  h1.run();
  h2.run();
  Shape in = Shape::load(g.artifact("shape").path), out = Shape::load(h1.artifact("shape").path);
  CHECK(out.watertight());
  CHECK(out.num_faces() == in.num_faces());
  for (auto t : {meshflow::cad::Tag::wall, meshflow::cad::Tag::farfield, meshflow::cad::Tag::symmetry})
    CHECK(out.faces_with_tag(t).size() == in.faces_with_tag(t).size());
  CHECK(out.volume() == doctest::Approx(in.volume()).epsilon(1e-9));
  std::ifstream a(h1.artifact("shape").path), b(h2.artifact("shape").path);
  std::string sa((std::istreambuf_iterator<char>(a)), {}), sb((std::istreambuf_iterator<char>(b)), {});
  CHECK(sa == sb);
}

TEST_CASE("heal: fluid: box puts a closed body in a far-field box") {
  TopoDS_Shape body = BRepPrimAPI_MakeBox(gp_Pnt(0, 0, 0), 1, 2, 3).Shape();
  std::filesystem::path d;
  auto h = heal_on(body, {{"fluid", "box"}, {"box_padding", 2.0}}, d);
  h->run();
  Shape s = Shape::load(h->artifact("shape").path);
  CHECK(s.watertight());
  CHECK(s.faces_with_tag(meshflow::cad::Tag::wall).size() == 6);
  CHECK(s.faces_with_tag(meshflow::cad::Tag::farfield).size() == 6);
  CHECK(s.volume() == doctest::Approx(13.0 * 14 * 15 - 6).epsilon(1e-9));
  std::filesystem::remove_all(d);
}

TEST_CASE("heal: a far-field sphere around a body (a domain with a hole) is farfield, the body wall") {
  // a sphere R 50 around a box 1 x 2 x 3: the outer shell is on no plane of a bounding box
  TopoDS_Shape outer = BRepPrimAPI_MakeSphere(gp_Pnt(0.5, 1, 1.5), 50).Shape();
  TopoDS_Shape body = BRepPrimAPI_MakeBox(gp_Pnt(0, 0, 0), 1, 2, 3).Shape();
  TopoDS_Shape domain = BRepAlgoAPI_Cut(outer, body).Shape();
  std::filesystem::path d;
  auto h = heal_on(domain, {{"fluid", "given"}}, d);
  h->run();
  Shape s = Shape::load(h->artifact("shape").path);
  CHECK(s.watertight());
  CHECK(s.faces_with_tag(meshflow::cad::Tag::wall).size() == 6);
  auto far = s.faces_with_tag(meshflow::cad::Tag::farfield);
  REQUIRE(far.size() >= 1);
  for (int f : far) CHECK(s.face_surface_type(f) == "sphere");
  std::filesystem::remove_all(d);
}

TEST_CASE("heal: the default tolerance is relative to the body, not to a far field given around it") {
  // a box with a step 1e-4 high on its top, in a sphere R 100: 1e-6 of the domain's diagonal
  // (3.5e-4) is wider than the step's faces; 1e-6 of the body's (3.7e-6) is not
  TopoDS_Shape body = BRepAlgoAPI_Fuse(BRepPrimAPI_MakeBox(gp_Pnt(0, 0, 0), 1, 2, 3).Shape(),
                                       BRepPrimAPI_MakeBox(gp_Pnt(0.25, 0.5, 3), 0.5, 1, 1e-4).Shape()).Shape();
  TopoDS_Shape domain = BRepAlgoAPI_Cut(BRepPrimAPI_MakeSphere(gp_Pnt(0.5, 1, 1.5), 100).Shape(), body).Shape();
  const int faces = occt::make_shape(domain, "m").num_faces();
  std::filesystem::path d;
  auto h = heal_on(domain, {{"fluid", "given"}}, d);
  h->run();
  Shape s = Shape::load(h->artifact("shape").path);
  CHECK(s.watertight());
  CHECK(h->stats_["tolerance"].get<double>() == doctest::Approx(1e-6 * std::sqrt(1 + 4 + 9.0002)).epsilon(1e-3));
  CHECK(s.num_faces() == faces);  // the step's four 1e-4 wide faces are kept
  std::filesystem::remove_all(d);
}

TEST_CASE("heal: a body of several solids (sharing a face, overlapping) is fused before it is cut from the box") {
  // box A and box B share the face x = 1; sphere C overlaps B
  TopoDS_Compound parts;
  BRep_Builder b;
  b.MakeCompound(parts);
  b.Add(parts, BRepPrimAPI_MakeBox(gp_Pnt(0, 0, 0), 1, 1, 1).Shape());
  b.Add(parts, BRepPrimAPI_MakeBox(gp_Pnt(1, 0, 0), 1, 1, 1).Shape());
  b.Add(parts, BRepPrimAPI_MakeSphere(gp_Pnt(2, 0.5, 0.5), 0.25).Shape());
  std::filesystem::path d;
  auto h = heal_on(parts, {{"fluid", "box"}, {"box_padding", 1.0}}, d);
  h->run();
  Shape s = Shape::load(h->artifact("shape").path);
  CHECK(s.watertight());
  CHECK(h->stats_["fixes"]["solids_fused"]["before"] == 3);
  CHECK(h->stats_["fixes"]["solids_fused"]["after"] == 1);
  // the body's volume: two unit boxes and the half of the sphere outside them
  const double half_sphere = 2.0 / 3 * 3.14159265358979 * 0.25 * 0.25 * 0.25;
  auto bb = s.box();
  double box = (bb.hi.x - bb.lo.x) * (bb.hi.y - bb.lo.y) * (bb.hi.z - bb.lo.z);
  CHECK(box - s.volume() == doctest::Approx(2 + half_sphere).epsilon(1e-4));
  // no face inside the body: every wall face is on its outside (none at x = 1 between A and B)
  for (int f : s.faces_with_tag(meshflow::cad::Tag::wall)) {
    auto fb = s.face_box(f);
    CHECK(!(fb.hi.x - fb.lo.x < 1e-9 && std::abs(fb.lo.x - 1) < 1e-9));
  }
  std::filesystem::remove_all(d);
}

TEST_CASE("heal: a box missing a face (a surface model) gets its planar opening capped, or is refused with caps off") {
  auto f = box_faces();
  f.pop_back();
  const nlohmann::json caps = capped_unit_box(f);
  REQUIRE(caps.size() == 1);
  CHECK(caps[0]["area"].get<double>() == doctest::Approx(1.0).epsilon(1e-6));
  std::filesystem::path d2;
  auto off = heal_on(compound(f), {{"cap_planar_holes", false}}, d2);
  try {
    off->run();
    FAIL("an open box must be refused with cap_planar_holes: false");
  } catch (const StageError& e) {
    std::string m = e.what();
    CHECK(m.find("4 free edge(s)") != std::string::npos);
    CHECK(m.find("opening 0: 4 free edge(s)") != std::string::npos);
    CHECK(m.find("planar") != std::string::npos);
    CHECK(m.find("cap_planar_holes: true") != std::string::npos);
  }
  std::filesystem::remove_all(d2);
}

TEST_CASE("heal: a loose face whose edges are free is not capped by a copy of itself: refused, naming the openings") {
  auto f = box_faces();
  gp_Trsf t;
  t.SetTranslation(gp_Vec(0, 0, 0.3));  // 30 % of the box: a missing face, not a gap to sew
  f[5] = BRepBuilderAPI_Transform(f[5], t, Standard_True).Shape();
  std::filesystem::path d;
  auto h = heal_on(compound(f), nlohmann::json::object(), d);
  CHECK_THROWS_WITH_AS(h->run(), doctest::Contains("The openings:"), StageError);
  std::filesystem::remove_all(d);
}

TEST_CASE("heal: faces a measured gap apart are sewn with that gap, a gap above 1 % of the shape is not") {
  auto f = box_faces();
  gp_Trsf t;
  t.SetTranslation(gp_Vec(0, 0, 1e-3));
  f[5] = BRepBuilderAPI_Transform(f[5], t, Standard_True).Shape();
  const nlohmann::json st = sewn_at_measured_gap(f);
  CHECK(st["fixes"]["sewing_gap_measured"]["gap"].get<double>() == doctest::Approx(1e-3).epsilon(0.05));
  CHECK(st["tolerance"].get<double>() == doctest::Approx(1.5e-3).epsilon(0.05));
}

TEST_CASE("heal: a hollow body in a box: the cavity is no fluid, and a domain in two pieces keeps the larger, with a note") {
  TopoDS_Shape hollow = BRepAlgoAPI_Cut(BRepPrimAPI_MakeSphere(gp_Pnt(0, 0, 0), 1.0).Shape(),
                                        BRepPrimAPI_MakeSphere(gp_Pnt(0, 0, 0), 0.5).Shape()).Shape();
  std::filesystem::path d1, d2;
  auto h = heal_on(hollow, {{"fluid", "box"}, {"box_padding", 1.0}}, d1);
  h->run();
  Shape s = Shape::load(h->artifact("shape").path);
  CHECK(s.watertight());
  CHECK(s.num_solids() == 1);
  CHECK(s.volume() == doctest::Approx(6.0 * 6 * 6 - 4.0 / 3 * 3.14159265358979).epsilon(1e-4));
  // not sewn again (sew: false) the hollow solid stays one: the box minus it is two regions, the
  // ball inside the cavity is dropped with a note
  std::filesystem::path d3;
  auto k = heal_on(hollow, {{"fluid", "box"}, {"box_padding", 1.0}, {"sew", false}}, d3);
  k->run();
  CHECK(Shape::load(k->artifact("shape").path).num_solids() == 1);
  auto cavity = k->stats_["fixes"]["enclosed_regions_dropped"];
  REQUIRE(cavity.size() == 1);
  CHECK(cavity[0]["volume"].get<double>() == doctest::Approx(4.0 / 3 * 3.14159265358979 * 0.125).epsilon(1e-3));
  std::filesystem::remove_all(d3);
  // two boxes apart given as the fluid: one connected domain is kept, the other reported
  TopoDS_Compound two;
  BRep_Builder b;
  b.MakeCompound(two);
  b.Add(two, BRepPrimAPI_MakeBox(gp_Pnt(0, 0, 0), 2, 2, 2).Shape());
  b.Add(two, BRepPrimAPI_MakeBox(gp_Pnt(5, 0, 0), 1, 1, 1).Shape());
  auto g = heal_on(two, {{"fluid", "given"}}, d2);
  g->run();
  Shape t = Shape::load(g->artifact("shape").path);
  CHECK(t.num_solids() == 1);
  CHECK(t.volume() == doctest::Approx(8.0).epsilon(1e-9));
  auto dropped = g->stats_["fixes"]["regions_outside_dropped"];
  REQUIRE(dropped.size() == 1);
  CHECK(dropped[0]["volume"].get<double>() == doctest::Approx(1.0).epsilon(1e-9));
  std::filesystem::remove_all(d1);
  std::filesystem::remove_all(d2);
}

TEST_CASE("heal: a half sphere around a half body cut into its flat face: sphere farfield, flat face symmetry, body wall") {
  TopoDS_Shape half = BRepAlgoAPI_Common(BRepPrimAPI_MakeSphere(gp_Pnt(0, 0, 0), 10).Shape(),
                                         BRepPrimAPI_MakeBox(gp_Pnt(-20, -20, 0), 40, 40, 20).Shape()).Shape();
  TopoDS_Shape domain = BRepAlgoAPI_Cut(half, BRepPrimAPI_MakeBox(gp_Pnt(0, -0.1, -1), 1, 0.2, 3).Shape()).Shape();
  std::filesystem::path d;
  auto h = heal_on(domain, {{"fluid", "given"}}, d);
  h->run();
  Shape s = Shape::load(h->artifact("shape").path);
  CHECK(s.watertight());
  auto walls = s.faces_with_tag(meshflow::cad::Tag::wall);
  CHECK(walls.size() == 5);
  for (int f : walls) CHECK(s.face_box(f).hi.z < 2.1);
  auto far = s.faces_with_tag(meshflow::cad::Tag::farfield);
  REQUIRE(far.size() >= 1);
  for (int f : far) CHECK(s.face_surface_type(f) == "sphere");
  CHECK(s.faces_with_tag(meshflow::cad::Tag::symmetry).size() == 1);
  std::filesystem::remove_all(d);
}

// A box that lost two adjacent flat faces: the edge they shared is gone, so neither opening is a
// closed loop and the free edges form one chain of 6 round both. Each plane's free edges are
// closed by the segment where the two planes meet, both caps share it, and the box is closed.
TEST_CASE("heal: a box missing two adjacent faces gets both planes capped along their crossing") {
  auto f = box_faces();  // OCCT's order: x=0, x=1, y=0, y=1, z=0, z=1
  const nlohmann::json caps = capped_unit_box({f[0], f[1], f[3], f[4]});  // no y=0, no z=1
  REQUIRE(caps.size() == 2);
  for (auto& c : caps) {
    CHECK(c["area"].get<double>() == doctest::Approx(1.0).epsilon(1e-6));
    CHECK(c["edges"].get<std::string>().find("a planar loop of a larger opening") != std::string::npos);
  }
}

// Three faces missing round one corner (a hull without deck, centreplane and transom): each
// plane's chain of free edges ends on the two other planes, and is closed through the corner the
// three share.
TEST_CASE("heal: a box missing three faces round a corner gets them capped through the corner") {
  auto f = box_faces();  // OCCT's order: x=0, x=1, y=0, y=1, z=0, z=1
  CHECK(capped_unit_box({f[0], f[3], f[4]}).size() == 3);  // no x=1, y=0, z=1
}

// One face whose whole rim lies on two planes (a quarter of a sphere's surface, cut by z = 0
// and y = 0; a half hull's rim lies on its deck and centreplane the same way): a lone face, whose
// openings OCCT finds only in a compound, capped by two half discs along their shared diameter.
TEST_CASE("heal: a lone face with its rim on two planes is closed by a cap on each") {
  TopoDS_Shape ball = BRepPrimAPI_MakeSphere(1.0).Shape();
  TopoDS_Shape quarter = BRepAlgoAPI_Common(ball, BRepPrimAPI_MakeBox(gp_Pnt(-2, 0, 0), 4, 2, 2).Shape()).Shape();
  TopoDS_Shape skin;  // its spherical face only
  for (TopExp_Explorer ex(quarter, TopAbs_FACE); ex.More(); ex.Next())
    if (occt::make_shape(ex.Current(), "m").face_surface_type(0) == "sphere") skin = ex.Current();
  REQUIRE(!skin.IsNull());
  std::filesystem::path d;
  auto h = heal_on(skin, nlohmann::json::object(), d);
  h->run();
  Shape s = Shape::load(h->artifact("shape").path);
  CHECK(s.watertight());
  CHECK(s.volume() == doctest::Approx(M_PI / 3).epsilon(1e-3));
  auto caps = h->stats_["fixes"]["planar_holes_capped"];
  REQUIRE(caps.size() == 2);
  for (auto& c : caps) CHECK(c["area"].get<double>() == doctest::Approx(M_PI / 2).epsilon(1e-3));
  std::filesystem::remove_all(d);
}

// Two faces' copies of one boundary with the same two ends, 1e-4 apart in the middle (a top face
// whose edges bulge off the box's straight edges): the gap is measured along them, and the box
// is sewn with it.
TEST_CASE("heal: edges with the same ends a little apart along their length are sewn at the gap measured along them") {
  auto f = box_faces();
  TColgp_Array2OfPnt poles(1, 3, 1, 3);
  for (int i = 1; i <= 3; ++i)
    for (int j = 1; j <= 3; ++j) {
      const bool mid_edge = (i == 2) != (j == 2);  // the middle pole of each side
      poles(i, j) = gp_Pnt(0.5 * (i - 1), 0.5 * (j - 1), 1.0 + (mid_edge ? 2e-4 : 0.0));
    }
  Handle(Geom_BezierSurface) top = new Geom_BezierSurface(poles);
  f[5] = BRepBuilderAPI_MakeFace(top, 1e-7).Face();
  const nlohmann::json st = sewn_at_measured_gap(f);
  CHECK(st["fixes"]["sewing_gap_measured"]["gap"].get<double>() == doctest::Approx(1e-4).epsilon(0.1));
}
