// Replays every input of the fuzz corpora (seeds and the reproducers of crashes that were
// found and fixed) through the same entry points as the fuzzers, in the normal build.
#include <doctest/doctest.h>

#include <filesystem>
#include <fstream>
#include <sstream>

#include "../fuzz/workflow_fuzz.cpp"

namespace fs = std::filesystem;

TEST_CASE("workflow fuzz corpus replays without a crash") {
  int n = 0;
  for (auto& e : fs::directory_iterator(fs::path(MESHFLOW_SOURCE_DIR) / "tests/fuzz/corpus/workflow")) {
    std::ifstream in(e.path(), std::ios::binary);
    std::ostringstream s;
    s << in.rdbuf();
    std::string data = s.str();
    INFO(e.path().string());
    CHECK(LLVMFuzzerTestOneInput(reinterpret_cast<const std::uint8_t*>(data.data()), data.size()) == 0);
    ++n;
  }
  CHECK(n >= 5);
}
