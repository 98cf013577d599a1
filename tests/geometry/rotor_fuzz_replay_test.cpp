// Replays the rotor fuzz corpus (seeds and reproducers of fixed crashes) through the same
// entry point as tests/fuzz/rotor_fuzz.cpp, in the normal build.
#include <doctest/doctest.h>

#include <filesystem>
#include <fstream>
#include <sstream>

#include "../fuzz/rotor_fuzz.cpp"

TEST_CASE("rotor fuzz corpus replays without a crash") {
  namespace fs = std::filesystem;
  int n = 0;
  for (auto& e : fs::directory_iterator(fs::path(MESHFLOW_SOURCE_DIR) / "tests/fuzz/corpus/rotor")) {
    std::ifstream in(e.path(), std::ios::binary);
    std::ostringstream s;
    s << in.rdbuf();
    std::string data = s.str();
    INFO(e.path().string());
    CHECK(LLVMFuzzerTestOneInput(reinterpret_cast<const std::uint8_t*>(data.data()), data.size()) == 0);
    ++n;
  }
  CHECK(n >= 8);
}

TEST_CASE("rotor reader: the small seed parses, broken seeds are StageErrors") {
  namespace fs = std::filesystem;
  auto read = [](const char* name) {
    std::ifstream in(fs::path(MESHFLOW_SOURCE_DIR) / "tests/fuzz/corpus/rotor" / name, std::ios::binary);
    std::ostringstream s;
    s << in.rdbuf();
    return s.str().substr(1);
  };
  auto b = meshflow::geometry::parse_rotor67(read("seed-small-valid"), "seed");
  CHECK(b.blades == 22);
  CHECK(b.loops.size() == 2);
  CHECK(b.loops[0].size() == 7 + 5);  // JLE..JTE upper (7) + lower without the edges (5)
  CHECK(b.mean[0].size() == 12);
  CHECK(b.hub.size() == 12);
  for (const char* bad : {"seed-truncated", "seed-bad-header", "seed-nan", "seed-negative-radius", "seed-huge-jm"})
    CHECK_THROWS_AS(meshflow::geometry::parse_rotor67(read(bad), bad), meshflow::StageError);
  CHECK(meshflow::geometry::parse_blade_csv(read("seed-csv-valid"), "csv").loops.size() == 2);
}
