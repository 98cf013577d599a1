#include "engine/cli.hpp"
#include <cstdio>
namespace meshflow {
int cli_main(int, char**) { std::puts("meshflow: engine under construction"); return 0; }
}
