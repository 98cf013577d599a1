// Replays every input of the MSH and Nektar++ fuzz corpora (seeds and the reproducers of
// crashes found and fixed) through the fuzz targets' entry points, in the normal build.
#include <doctest/doctest.h>

#define MESHFLOW_MSH_FUZZ_ENTRY meshflow_msh_fuzz_one
#include "../fuzz/msh_fuzz.cpp"
#define MESHFLOW_NEKTAR_FUZZ_ENTRY meshflow_nektar_fuzz_one
#include "../fuzz/nektar_fuzz.cpp"

#include <sstream>

namespace {
int replay(const char* corpus, int (*entry)(const std::uint8_t*, std::size_t)) {
  int n = 0;
  for (auto& e : std::filesystem::directory_iterator(std::filesystem::path(MESHFLOW_SOURCE_DIR) / "tests/fuzz/corpus" / corpus)) {
    std::ifstream in(e.path(), std::ios::binary);
    std::ostringstream s;
    s << in.rdbuf();
    const std::string data = s.str();
    INFO(e.path().string());
    CHECK_NOTHROW(CHECK(entry(reinterpret_cast<const std::uint8_t*>(data.data()), data.size()) == 0));
    ++n;
  }
  return n;
}
}  // namespace

TEST_CASE("msh fuzz corpus replays without a crash or an unclean error") { CHECK(replay("msh", meshflow_msh_fuzz_one) >= 10); }

TEST_CASE("nektar fuzz corpus replays without a crash or an unclean error") {
  CHECK(replay("nektar", meshflow_nektar_fuzz_one) >= 7);
}
