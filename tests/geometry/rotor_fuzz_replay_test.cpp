// Replays the rotor fuzz corpus (seeds and reproducers of fixed crashes) through the same
// entry point as tests/fuzz/rotor_fuzz.cpp, in the normal build.
#include <doctest/doctest.h>

#include "support.hpp"

#include <filesystem>
#include <fstream>
#include <sstream>

#include "../fuzz/rotor_fuzz.cpp"

TEST_CASE("rotor fuzz corpus replays without a crash") {
  CHECK(mftest::replay_corpus(std::filesystem::path(MESHFLOW_SOURCE_DIR) / "tests/fuzz/corpus/rotor", LLVMFuzzerTestOneInput) >= 8);
}
