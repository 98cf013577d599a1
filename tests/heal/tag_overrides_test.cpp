// Face-tag overrides (`tag_overrides`: faces / plane / box selectors, applied in order) on the
// hemisphere-cylinder (data/cad-defects/hemisph-cyl.stp, meshflow's stand-in for UGAWG's), whose automatic tags are meaningless, and on the naca_wing.
#include <doctest/doctest.h>

#include "../cad/test_context.hpp"
#include "stages/cad/cad.hpp"

#include <filesystem>

using meshflow::StageError;
using meshflow::cad::Shape;
using meshflow::cad::Tag;
using meshflow::testing::TestContext;
using nlohmann::json;
namespace fs = std::filesystem;

TEST_CASE("tag_overrides on heal: hemisph-cyl gets wall / symmetry / farfield right") {
  fs::path f = fs::path(MESHFLOW_DATA_DIR) / "cad-defects/hemisph-cyl.stp";
  REQUIRE(fs::exists(f));
  TestContext imp("step", {{"file", f.string()}});
  imp.run();
  // automatic tags: the far-field sphere (r = 100), on no plane of the box, is farfield
  // (cad::curved_farfield: a large face next to the box planes of a domain that is no box)
  TestContext plain("heal", json::object(), {imp.artifact("shape")});
  plain.run();
  Shape a = Shape::load(plain.artifact("shape").path);
  REQUIRE(a.num_faces() == 5);
  int far_sphere = -1;
  for (int i = 0; i < a.num_faces(); ++i) {
    auto b = a.face_box(i);
    if (a.face_surface_type(i) == "sphere" && b.hi.z - b.lo.z > 50) far_sphere = i;
  }
  REQUIRE(far_sphere >= 0);
  CHECK(a.face_tag(far_sphere) == Tag::farfield);

  json rules = json::array({
      {{"tag", "farfield"}, {"faces", {far_sphere}}},
      {{"tag", "symmetry"}, {"plane", {{"point", {0, 0, 0}}, {"normal", {0, 1, 0}}}}},
      {{"tag", "farfield"}, {"plane", {{"point", {10, 5, 5}}, {"normal", {2, 0, 0}}}}},  // outflow x = 10
      {{"tag", "wall"}, {"box", {{"min", {-0.01, -0.6, -0.6}}, {"max", {10.01, 0.6, 0.6}}}}},  // the body
  });
  TestContext h("heal", {{"tag_overrides", rules}}, {imp.artifact("shape")});
  h.run();
  Shape s = Shape::load(h.artifact("shape").path);
  CHECK(s.watertight());
  CHECK(s.faces_with_tag(Tag::symmetry).size() == 1);
  CHECK(s.faces_with_tag(Tag::farfield).size() == 2);
  CHECK(s.faces_with_tag(Tag::wall).size() == 2);
  for (int f : s.faces_with_tag(Tag::wall)) {
    auto b = s.face_box(f);
    CHECK(b.hi.z - b.lo.z < 1.1);  // the body (radius 0.5), not the far field
  }
  int sym = s.faces_with_tag(Tag::symmetry)[0];
  CHECK(s.face_surface_type(sym) == "plane");
  CHECK(std::abs(s.face_box(sym).hi.y) < 1e-6);
  CHECK(h.stats_["face_tags"]["wall"] == 2);

  // order matters: a later rule wins
  json later = rules;
  later.push_back({{"tag", "none"}, {"faces", {far_sphere}}});
  TestContext h2("heal", {{"tag_overrides", later}}, {imp.artifact("shape")});
  h2.run();
  CHECK(Shape::load(h2.artifact("shape").path).faces_with_tag(Tag::none).size() == 1);

  // refusals name the rule and the selector
  auto refuse = [&](json rule, const char* what) {
    TestContext bad("heal", {{"tag_overrides", json::array({rule})}}, {imp.artifact("shape")});
    CHECK_THROWS_WITH_AS(bad.run(), doctest::Contains(what), StageError);
  };
  refuse({{"tag", "wall"}, {"faces", {3, 99}}}, "face 99 does not exist");
  refuse({{"tag", "wall"}, {"plane", {{"point", {0, 0, 1234}}, {"normal", {0, 0, 1}}}}}, "matches no face");
  refuse({{"tag", "wall"}, {"box", {{"min", {500, 500, 500}}, {"max", {600, 600, 600}}}}}, "rule 1 (tag wall, box");
  refuse({{"tag", "wall"}, {"faces", {1}}, {"box", {{"min", {0, 0, 0}}, {"max", {1, 1, 1}}}}}, "exactly one selector");
  refuse({{"tag", "wall"}, {"plane", {{"point", {0, 0, 0}}, {"normal", {0, 0, 0}}}}}, "normal is zero");
}

TEST_CASE("tag_overrides on naca_wing: the root wall becomes farfield, the wing by box") {
  TestContext w("naca_wing", {{"tag_overrides", json::array({
                                   {{"tag", "farfield"}, {"plane", {{"point", {0, 0, 0}}, {"normal", {0, 0, 1}}}}},
                                   {{"tag", "periodic_lo"}, {"box", {{"min", {-0.5, -0.5, -0.5}}, {"max", {1.5, 0.5, 1.5}}}}},
                               })}});
  w.run();
  Shape s = Shape::load(w.artifact("shape").path);
  CHECK(s.faces_with_tag(Tag::symmetry).empty());
  CHECK(s.faces_with_tag(Tag::farfield).size() == 6);
  CHECK(s.faces_with_tag(Tag::wall).empty());  // every wing face is inside the box
  CHECK(s.faces_with_tag(Tag::periodic_lo).size() >= 3);
  TestContext bad("naca_wing", {{"tag_overrides", json::array({{{"tag", "wall"}, {"faces", {40}}}})}});
  CHECK_THROWS_WITH_AS(bad.run(), doctest::Contains("naca_wing stage"), StageError);
}
