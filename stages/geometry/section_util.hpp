// meshflow geometry — helpers shared by the blade section readers (blade_sections.cpp,
// section_table.cpp); internal to stages/geometry.
#pragma once

#include "stages/geometry/blade_sections.hpp"

#include <cstddef>
#include <string>
#include <string_view>
#include <vector>

namespace meshflow::geometry {

// Throws StageError "blade section file 'SOURCE', line LINE: WHAT" (no line when 0).
[[noreturn]] void fail(const std::string& source, size_t line, const std::string& what);
// The text's lines without a leading UTF-8 byte order mark, '\r' line ends, NULs made '?'.
std::vector<std::string> split_lines(std::string_view text);
// Consecutive points of every loop distinct (interpolation needs it), relative to the extent.
void check_loops(const BladeSections& b, const std::string& source);

}  // namespace meshflow::geometry

namespace meshflow::geometry {
// Metres per unit of "mm", "cm", "m", "in", "ft" (1 for anything else).
double length_unit_in_m(const std::string& unit);
}  // namespace meshflow::geometry
