// meshflow engine — the command-line interface (`meshflow run|status|explain|dag|check|golden|clean|gc|kinds`).
#pragma once
namespace meshflow {
int cli_main(int argc, char** argv);
}
