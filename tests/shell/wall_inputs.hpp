// The shell's inputs for tests: a geometry kind's shape healed, and its medial object. The
// contexts own the files (they live as long as the WallInputs).
#pragma once

#include "../cad/test_context.hpp"
#include "engine/stage.hpp"

#include <nlohmann/json.hpp>

#include <memory>
#include <string>
#include <vector>

namespace shelltest {

struct WallInputs {
  std::unique_ptr<meshflow::testing::TestContext> geo, heal, med;
  meshflow::Artifact shape, medial;
  WallInputs(const std::string& kind, const nlohmann::json& geo_params) {
    using meshflow::testing::TestContext;
    geo = std::make_unique<TestContext>(kind, geo_params);
    geo->run();
    heal = std::make_unique<TestContext>("heal", nlohmann::json::object(),
                                         std::vector<meshflow::Artifact>{geo->artifact("shape")});
    heal->run();
    shape = heal->artifact("shape");
    med = std::make_unique<TestContext>("medial", nlohmann::json::object(), std::vector<meshflow::Artifact>{shape});
    med->run();
    medial = med->artifact("medial");
  }
};

}  // namespace shelltest
