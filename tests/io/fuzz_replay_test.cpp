// Replays every input of the MSH, Nektar++ and VTU fuzz corpora (seeds and the reproducers of
// crashes found and fixed) through the fuzz targets' entry points, in the normal build.
#include <doctest/doctest.h>

#define MESHFLOW_MSH_FUZZ_ENTRY meshflow_msh_fuzz_one
#include "../fuzz/msh_fuzz.cpp"
#define MESHFLOW_NEKTAR_FUZZ_ENTRY meshflow_nektar_fuzz_one
#include "../fuzz/nektar_fuzz.cpp"
#define MESHFLOW_VTU_FUZZ_ENTRY meshflow_vtu_fuzz_one
#include "../fuzz/vtu_fuzz.cpp"

#include "support.hpp"

namespace {
int replay(const char* corpus, int (*entry)(const std::uint8_t*, std::size_t)) {
  return mftest::replay_corpus(std::filesystem::path(MESHFLOW_SOURCE_DIR) / "tests/fuzz/corpus" / corpus, entry);
}
}  // namespace

TEST_CASE("msh fuzz corpus replays without a crash or an unclean error") { CHECK(replay("msh", meshflow_msh_fuzz_one) >= 10); }

TEST_CASE("nektar fuzz corpus replays without a crash or an unclean error") {
  CHECK(replay("nektar", meshflow_nektar_fuzz_one) >= 7);
}

TEST_CASE("vtu fuzz corpus replays without a crash or an unclean error") { CHECK(replay("vtu", meshflow_vtu_fuzz_one) >= 8); }
