// Replays every input of the fuzz corpora (seeds and the reproducers of crashes that were
// found and fixed) through the same entry points as the fuzzers, in the normal build.
#include <doctest/doctest.h>

#include "support.hpp"

#include <filesystem>
#include <fstream>
#include <sstream>

#include "../fuzz/workflow_fuzz.cpp"

namespace fs = std::filesystem;

TEST_CASE("workflow fuzz corpus replays without a crash") {
  CHECK(mftest::replay_corpus(fs::path(MESHFLOW_SOURCE_DIR) / "tests/fuzz/corpus/workflow", LLVMFuzzerTestOneInput) >= 5);
}
