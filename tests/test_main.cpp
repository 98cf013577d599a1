// Shared main of every test executable. `test_X --as-meshflow ARGS...` behaves exactly like
// `meshflow ARGS...` but with the stage kinds the test executable registers (tests define
// their own kinds), so end-to-end tests can run the CLI in a child process and kill it.
//
// A run with a test-case filter (CTest runs every test case as `test_X --test-case=NAME`) that
// matches no test case FAILS: a name CTest cannot pass through intact (a ';' splits it into
// several filters, none matching) would otherwise run nothing and pass. A passing run removes
// the temp folders its tests made (mftest::temp_dir).
#define DOCTEST_CONFIG_IMPLEMENT
#include <doctest/doctest.h>

#include "engine/cli.hpp"
#include "support.hpp"

#include <atomic>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>

namespace {

std::atomic<unsigned> g_matched{0};

// Listens for the end of the run to learn how many test cases passed the filters.
struct MatchCounter : doctest::IReporter {
  explicit MatchCounter(const doctest::ContextOptions&) {}
  void report_query(const doctest::QueryData&) override {}
  void test_run_start() override {}
  void test_run_end(const doctest::TestRunStats& s) override { g_matched = s.numTestCasesPassingFilters; }
  void test_case_start(const doctest::TestCaseData&) override {}
  void test_case_reenter(const doctest::TestCaseData&) override {}
  void test_case_end(const doctest::CurrentTestCaseStats&) override {}
  void test_case_exception(const doctest::TestCaseException&) override {}
  void subcase_start(const doctest::SubcaseSignature&) override {}
  void subcase_end() override {}
  void log_assert(const doctest::AssertData&) override {}
  void log_message(const doctest::MessageData&) override {}
  void test_case_skipped(const doctest::TestCaseData&) override {}
};
DOCTEST_REGISTER_LISTENER("meshflow-match-counter", 1, MatchCounter);

}  // namespace

int main(int argc, char** argv) {
  if (argc > 1 && std::strcmp(argv[1], "--as-meshflow") == 0) {
    argv[1] = argv[0];
    return meshflow::cli_main(argc - 1, argv + 1);
  }
  bool filtered = false, listing = false;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    for (const char* f : {"--test-case=", "-tc=", "--dt-test-case=", "--dt-tc="}) filtered = filtered || a.rfind(f, 0) == 0;
    for (const char* f : {"--list", "-ltc", "-lts", "-lr", "--dt-list", "--dt-ltc", "-h", "--help", "-?", "-v", "--version"})
      listing = listing || a.rfind(f, 0) == 0;
  }
  doctest::Context ctx(argc, argv);
  const int r = ctx.run();
  if (r == 0 && filtered && !listing && g_matched == 0) {
    std::fprintf(stderr, "error: the test-case filter matched no test case (a name with ';' is split by CTest: rename it)\n");
    return 1;
  }
  // a passing run leaves no temp folders (a full suite left 31 GB of them)
  if (r == 0 && !std::getenv("MESHFLOW_KEEP_TEST_DIRS")) mftest::remove_temp_dirs();
  return r;
}
