// libFuzzer target: the blade section readers of the `blade_sector` kind (Rotor 67 export and
// CSV), from memory. The first byte selects the format (even: rotor67, odd: csv); the rest is
// the file. Anything but success or a meshflow::StageError is a bug.
#include "engine/stage.hpp"
#include "stages/geometry/blade_sections.hpp"

#include <cstddef>
#include <cstdint>
#include <string_view>

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size == 0) return 0;
  std::string_view text(reinterpret_cast<const char*>(data) + 1, size - 1);
  try {
    if (data[0] % 2 == 0)
      (void)meshflow::geometry::parse_rotor67(text, "fuzz");
    else
      (void)meshflow::geometry::parse_blade_csv(text, "fuzz");
  } catch (const meshflow::StageError&) {
  }
  return 0;
}
