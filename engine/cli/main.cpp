#include "engine/cli.hpp"
int main(int argc, char** argv) { return meshflow::cli_main(argc, argv); }
