#include <doctest/doctest.h>
#include "engine/registry.hpp"
TEST_CASE("workflow schema is embedded") { CHECK(meshflow::schema_for("workflow") != nullptr); }
