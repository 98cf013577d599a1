// Shared main of every test executable. `test_X --as-meshflow ARGS...` behaves exactly like
// `meshflow ARGS...` but with the stage kinds the test executable registers (tests define
// their own kinds), so end-to-end tests can run the CLI in a child process and kill it.
#define DOCTEST_CONFIG_IMPLEMENT
#include <doctest/doctest.h>

#include "engine/cli.hpp"

#include <cstring>

int main(int argc, char** argv) {
  if (argc > 1 && std::strcmp(argv[1], "--as-meshflow") == 0) {
    argv[1] = argv[0];
    return meshflow::cli_main(argc - 1, argv + 1);
  }
  doctest::Context ctx(argc, argv);
  return ctx.run();
}
