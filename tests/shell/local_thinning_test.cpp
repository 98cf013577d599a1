// The shell's thickness limit is local (stages/shell/shell_stage.cpp, "2. thickness on the wall
// samples"): a few small medial balls thin the layer where they are instead of refusing the whole
// wall; balls of sampling gaps at a junction edge are corner balls (the layer is swept along both
// walls there); a refusal is left for a thickness the domain cannot hold over most of the wall,
// and names the place and a thickness that works.
#include <doctest/doctest.h>

#include "support.hpp"

#include "../cad/test_context.hpp"
#include "wall_inputs.hpp"
#include "engine/stage.hpp"
#include "stages/medial/medial.hpp"

#include <nlohmann/json.hpp>

#include <array>
#include <cmath>
#include <filesystem>
#include <memory>
#include <string>

using meshflow::Artifact;
using meshflow::StageError;
using meshflow::testing::TestContext;

namespace {

using Walls = shelltest::WallInputs;

// the figure after `key` in a message ("... at most 0.3606 ...")
double number_after(const std::string& text, const std::string& key) {
  auto at = text.find(key);
  REQUIRE(at != std::string::npos);
  return std::stod(text.substr(at + key.size()));
}

}  // namespace

// NekMesh's boundary-layer cylinder (r 0.1 spanning a channel 0.5 high, heal's default unify: one
// seamed face) with the corpus workflow's thickness (0.04 x the wall box = 0.02). Before: refused,
// "the largest alpha x medial radius is 0.000260925": the medial stage's uv polygon of the seamed
// face took the wrong p-curve of the seam (a bow-tie), so half of each junction circle had no
// face sample within 9e-3, and 36 edge samples there had gap balls (refined radius <= 5.2e-4,
// empty ball 3e-3..5e-3) that the shell's corner test missed.
TEST_CASE("shell on NekMesh's BL cylinder: sampled all round its junction circles, the full thickness everywhere") {
  namespace fs = std::filesystem;
  const fs::path file = fs::path(MESHFLOW_DATA_DIR) / "corpus/nekmesh_bl_cylinder.stp";
  REQUIRE(fs::exists(file));
  Walls w("step", {{"file", file.string()}});
  // the seamed wall face is sampled next to both circles (z = 0, 0.5) in every 30 degree sector
  // (before: none within 5e-3 in 4 of 12 sectors of each circle)
  auto M = meshflow::medial::read(w.medial.path);
  std::array<std::array<int, 12>, 2> near{};
  for (auto& s : M.samples) {
    if (s.kind != 0 || !s.refined) continue;
    const int sector = static_cast<int>(std::floor((std::atan2(s.p[1], s.p[0]) + M_PI) / (2 * M_PI) * 12)) % 12;
    if (s.p[2] < 3e-3) ++near[0][sector];
    if (s.p[2] > 0.5 - 3e-3) ++near[1][sector];
  }
  for (int c = 0; c < 2; ++c)
    for (int k = 0; k < 12; ++k) {
      INFO("circle z = " << 0.5 * c << ", sector " << k);
      CHECK(near[c][k] > 0);
    }
  TestContext s("shell", {{"thickness", 0.04}}, {w.shape, w.medial});
  s.run();
  MESSAGE("NekMesh cylinder shell: thickness " << s.stats_.at("thickness").dump() << ", not honoured " << s.stats_.at("not_honoured").dump());
  const double T = s.stats_.at("thickness_requested").get<double>();
  CHECK(T == doctest::Approx(0.02));
  CHECK(s.stats_.at("thickness").at("min").get<double>() == doctest::Approx(T).epsilon(1e-9));
  CHECK(s.stats_.at("thickness").at("grid_min").get<double>() == doctest::Approx(T).epsilon(1e-9));
  CHECK(s.stats_.at("not_honoured").at("samples").get<long>() == 0);
  CHECK(s.stats_.at("counts").at("hex_junction_blocks").get<long>() == 2);
  CHECK(s.stats_.at("self_intersections").get<long>() == 0);
}

// The parametric wing in a far field half a chord away: the medial radius is small beside the
// wing, not everywhere. Before: 0.3 chord was refused ("at every wall sample ... at most 0.165").
TEST_CASE("shell: a narrow far field thins the layer locally, an impossible thickness names the place and a thickness that works") {
  Walls w("naca_wing", {{"incidence_deg", 0.0}, {"farfield_chords", 0.5}, {"wake_chords", 0.5}, {"span", 0.8}});
  TestContext s("shell", {{"thickness", 0.3}}, {w.shape, w.medial});
  s.run();
  const auto& lt = s.stats_.at("local_thinning");
  MESSAGE("narrow far field, 0.3 chord: " << lt.dump());
  const double T = s.stats_.at("thickness_requested").get<double>();
  CHECK(lt.at("samples").get<long>() > 0);
  CHECK(lt.at("area_fraction_below").get<double>() <= 0.5);
  CHECK(lt.at("min").get<double>() < 0.5 * T);
  CHECK(s.stats_.at("thickness").at("max").get<double>() == doctest::Approx(T).epsilon(1e-9));  // the full layer somewhere
  CHECK(lt.at("where").get<std::string>().find("on face") != std::string::npos);

  // 2 chords: most of the wall would be thinner than half of it
  TestContext big("shell", {{"thickness", 2.0}}, {w.shape, w.medial});
  std::string msg;
  try {
    big.run();
  } catch (const StageError& e) {
    msg = e.what();
  }
  MESSAGE("2 chords: " << msg);
  REQUIRE(!msg.empty());
  CHECK(msg.find("the narrowest place is (") != std::string::npos);
  CHECK(msg.find("on face") != std::string::npos);
  const double works = number_after(msg, "Use a thickness of at most ");
  CHECK(works < 2.0);
  CHECK(works > 0.1);
  // and the thickness it names works
  TestContext ok("shell", {{"thickness", works}}, {w.shape, w.medial});
  CHECK_NOTHROW(ok.run());
  CHECK(ok.stats_.at("local_thinning").at("area_fraction_below").get<double>() <= 0.5);
}
