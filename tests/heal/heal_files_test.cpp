// heal on the real CAD files of data/ (the paper's wing, Gmsh's defects, meshflow's stand-in for UGAWG's
// hemisphere-cylinder, DLR-F6). The files are in the repository: a missing one fails the test.
#include <doctest/doctest.h>

#include "../cad/test_context.hpp"
#include "stages/cad/cad.hpp"

#include <filesystem>
#include <set>

using meshflow::StageError;
using meshflow::cad::Shape;
using meshflow::cad::Tag;
using meshflow::testing::TestContext;
namespace fs = std::filesystem;

namespace {
const fs::path data = MESHFLOW_DATA_DIR;
std::unique_ptr<TestContext> import(const fs::path& file) {
  auto c = std::make_unique<TestContext>("step", nlohmann::json{{"file", file.string()}});
  c->run();
  return c;
}
}  // namespace

TEST_CASE("heal: the paper's wing STEP becomes a watertight fluid solid with the wing faces tagged wall") {
  fs::path f = data / "wingtip/3d_bl_wing.stp";
  REQUIRE(fs::exists(f));
  auto imp = import(f);
  auto& is = imp->stats_;
  CHECK(is["units"] == "mm");
  CHECK(is["faces"] == 9);
  CHECK(is["shells"] == 6);  // the faces are not sewn
  // 25 free edges as imported: 24 boundary edges plus the 8e-9 mm edge, whose two vertices
  // OCCT merges on import (it becomes a degenerated edge on one face)
  CHECK(is["free_edges"] == 24);
  CHECK(is["degenerate_edges"] == 1);
  TestContext h("heal", nlohmann::json::object(), {imp->artifact("shape")});
  h.run();
  Shape s = Shape::load(h.artifact("shape").path);
  CHECK(s.watertight());
  CHECK(s.num_solids() == 1);
  CHECK(s.num_faces() == 9);
  CHECK(s.units() == "mm");
  CHECK(h.stats_["before"]["free_edges"] == 24);
  CHECK(h.stats_["after"]["free_edges"] == 0);
  CHECK(h.stats_["fixes"]["sewing"]["contiguous_edges"] == 12);
  CHECK(s.volume() > 1e10);  // mm^3: the tunnel section is 812 x 1219 mm
  // tunnel walls: 5 farfield + the wall the wing is mounted on
  CHECK(s.faces_with_tag(Tag::farfield).size() == 5);
  CHECK(s.faces_with_tag(Tag::symmetry).size() == 1);
  // wing: the extruded profile, the revolved tip and the planar blunt trailing edge
  auto walls = s.faces_with_tag(Tag::wall);
  REQUIRE(walls.size() == 3);
  std::multiset<std::string> types;
  for (int w : walls) types.insert(s.face_surface_type(w));
  CHECK(types == std::multiset<std::string>{"extrusion", "plane", "revolution"});
  for (int w : walls) {  // every wall face touches another wall face
    bool touches = false;
    for (int g : s.face_neighbours(w)) touches |= s.face_tag(g) == Tag::wall;
    CHECK(touches);
  }
}

TEST_CASE("heal: sewfaces.step (open box bottom) gets its planar opening capped, and with caps off it is refused naming the 6 free edges") {
  fs::path f = data / "cad-defects/sewfaces.step";
  REQUIRE(fs::exists(f));
  auto imp = import(f);
  CHECK(imp->stats_["faces"] == 22);
  CHECK(imp->stats_["free_edges"] == 14);
  TestContext capped("heal", nlohmann::json::object(), {imp->artifact("shape")});
  capped.run();
  CHECK(Shape::load(capped.artifact("shape").path).watertight());
  auto caps = capped.stats_["fixes"]["planar_holes_capped"];
  REQUIRE(caps.size() == 1);
  CHECK(caps[0]["edges"].get<std::string>().find("6 free edge(s)") != std::string::npos);
  TestContext h("heal", nlohmann::json{{"cap_planar_holes", false}}, {imp->artifact("shape")});
  try {
    h.run();
    FAIL("sewfaces.step must be refused with cap_planar_holes: false");
  } catch (const StageError& e) {
    std::string m = e.what();
    CHECK(m.find("heal stage 'heal'") != std::string::npos);
    CHECK(m.find("6 free edge(s)") != std::string::npos);
    CHECK(m.find("edge 10 from (5, 0, 0) to (10, 0, 0)") != std::string::npos);
    CHECK(m.find("Add the missing faces") != std::string::npos);
    CHECK(m.find("planar") != std::string::npos);
  }
  // a larger tolerance does not invent the missing face
  TestContext h2("heal", nlohmann::json{{"tolerance", 0.5}, {"cap_planar_holes", false}}, {imp->artifact("shape")});
  CHECK_THROWS_WITH_AS(h2.run(), doctest::Contains("6 free edge(s)"), StageError);
}

TEST_CASE("heal: hemisph-cyl.stp with its degenerate edges heals to a valid solid") {
  fs::path f = data / "cad-defects/hemisph-cyl.stp";
  REQUIRE(fs::exists(f));
  auto imp = import(f);
  CHECK(imp->stats_["faces"] == 5);
  TestContext h("heal", nlohmann::json::object(), {imp->artifact("shape")});
  h.run();
  Shape s = Shape::load(h.artifact("shape").path);
  CHECK(s.watertight());
  CHECK(s.num_faces() == 5);
  CHECK(s.volume() > 0);
}

TEST_CASE("dlr_f6.brep: 130 faces as stored, one duplicates another, heal gives a valid 129-face solid") {
  fs::path f = data / "dlr_f6/dlr_f6.brep";
  REQUIRE(fs::exists(f));
  auto imp = import(f);
  CHECK(imp->stats_["solids"] == 1);
  CHECK(imp->stats_["faces"] == 130);
  CHECK(imp->stats_["multiple_edges"] == 10);  // the 10 edges of the duplicated face
  TestContext h("heal", nlohmann::json{{"unify", false}}, {imp->artifact("shape")});
  h.run();
  CHECK(h.stats_["fixes"]["duplicate_faces_removed"] == 1);
  Shape s = Shape::load(h.artifact("shape").path);
  CHECK(s.watertight());
  CHECK(s.num_solids() == 1);
  CHECK(s.num_faces() == 129);
  CHECK(s.faces_with_tag(Tag::symmetry).size() == 1);  // y = 0, where the fuselage sits
  CHECK(s.faces_with_tag(Tag::farfield).size() == 5);
  CHECK(s.faces_with_tag(Tag::wall).size() == 123);
}

// The corpus (data/corpus): closed bodies nobody tuned heal for, in a far-field box.
namespace {
std::unique_ptr<TestContext> heal_in_box(const fs::path& file, bool unify = true) {
  auto imp = import(file);
  auto h = std::make_unique<TestContext>("heal", nlohmann::json{{"fluid", "box"}, {"unify", unify}},
                                         std::vector{imp->artifact("shape")});
  h->run();
  return h;
}
}  // namespace

TEST_CASE("heal: a body of one closed face (sphere, torus, two spheres) is a shell, cut out of the box") {
  struct Case {
    const char* file;
    int bodies;
    double body_volume;
  };
  const double pi = 3.14159265358979;
  for (Case c : {Case{"sphere.step", 1, 4 * pi / 3 * 0.125}, Case{"torus.step", 1, 2 * pi * pi * 1 * 0.0625},
                 Case{"two_spheres.step", 2, 2 * 4 * pi / 3 * 0.125}}) {
    fs::path f = data / "corpus" / c.file;
    if (!fs::exists(f)) continue;
    CAPTURE(c.file);
    auto h = heal_in_box(f);
    Shape s = Shape::load(h->artifact("shape").path);
    CHECK(s.watertight());
    CHECK(s.num_solids() == 1);
    // six box faces and the body's faces, which are walls
    CHECK(s.faces_with_tag(Tag::farfield).size() == 6);
    CHECK(s.faces_with_tag(Tag::wall).size() == (size_t)c.bodies);
    CHECK(h->stats_["fixes"]["fluid"] == "box minus " + std::to_string(c.bodies) + " body solid(s)");
    // the box's volume less the bodies' (a body left in, or not cut, would show here)
    auto b = s.box();
    double box = (b.hi.x - b.lo.x) * (b.hi.y - b.lo.y) * (b.hi.z - b.lo.z);
    CHECK(box - s.volume() == doctest::Approx(c.body_volume).epsilon(1e-3));
  }
}

TEST_CASE("heal: unifying faces is not taken when its solid fails BRepCheck (the capsule's hemispheres)") {
  fs::path f = data / "corpus/capsule.step";
  REQUIRE(fs::exists(f));
  auto h = heal_in_box(f);
  Shape s = Shape::load(h->artifact("shape").path);
  CHECK(s.valid());
  CHECK(s.watertight());
  CHECK(h->stats_["fixes"]["unified_faces"] == 0);
  CHECK(h->stats_["fixes"].contains("unify_rejected"));
  // the body's faces as imported (the cylinder and the hemispheres), none merged
  CHECK(s.faces_with_tag(Tag::wall).size() == (size_t)import(f)->stats_["faces"].get<int>());
}

TEST_CASE("heal: symmetry_plane puts a half model on its root plane: no padding there, that box face symmetry") {
  fs::path f = data / "corpus/swept_wing.step";
  REQUIRE(fs::exists(f));
  auto imp = import(f);
  TestContext h("heal", nlohmann::json{{"fluid", "box"}, {"symmetry_plane", "z-"}}, {imp->artifact("shape")});
  h.run();
  Shape s = Shape::load(h.artifact("shape").path);
  CHECK(s.watertight());
  auto b = s.box();
  CHECK(std::abs(b.lo.z) < 1e-6);  // the root plane z = 0 is the box's side
  CHECK(b.hi.z > 10);               // padded by 5 x the body's largest side (2) elsewhere
  auto sym = s.faces_with_tag(Tag::symmetry);
  REQUIRE(sym.size() == 1);
  CHECK(s.face_box(sym[0]).hi.z < 1e-6);
  CHECK(s.faces_with_tag(Tag::farfield).size() == 5);
  // the root face is gone (it lies on the symmetry face): the wing's other faces are walls
  CHECK(s.faces_with_tag(Tag::wall).size() == (size_t)imp->stats_["faces"].get<int>() - 1);
  CHECK(h.stats_["fixes"]["symmetry_plane"] == "z-");
  // a given domain has no box to put on a plane
  TestContext bad("heal", nlohmann::json{{"fluid", "given"}, {"symmetry_plane", "z-"}}, {imp->artifact("shape")});
  CHECK_THROWS_WITH_AS(bad.run(), doctest::Contains("needs fluid: box"), StageError);
}

// A body of 27 solids that touch (bench/corpus/real/simple_plane_multisolid.brep, an aircraft of
// parts): they fuse exactly, but OpenCASCADE throws while unifying the faces the fusion split and
// again while unifying the fluid's faces. Unifying is a simplification, so the faces are kept
// split and heal goes on: one closed fluid solid with the aircraft as its wall.
TEST_CASE("heal: an aircraft of 27 touching solids is fused and cut from the box even where unifying its faces throws") {
  const fs::path f = fs::path(MESHFLOW_SOURCE_DIR) / "bench/corpus/real/simple_plane_multisolid.brep";
  REQUIRE(fs::exists(f));
  auto h = heal_in_box(f);
  const auto& fx = h->stats_["fixes"];
  MESSAGE("fixes: " << fx.dump());
  CHECK(fx["solids_fused"]["before"] == 27);
  CHECK(fx["solids_fused"]["after"] == 1);
  Shape s = Shape::load(h->artifact("shape").path);
  CHECK(s.watertight());
  CHECK(s.num_solids() == 1);
  CHECK(s.faces_with_tag(Tag::farfield).size() == 6);
  CHECK(s.faces_with_tag(Tag::wall).size() > 27);
}
