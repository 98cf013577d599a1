// Bodies with a narrow ledge for the junction-width tests, made with OCCT in ledge_shapes.cpp
// (this header includes no OCCT).
#pragma once

#include <filesystem>

namespace sweeptest {
// Writes a BREP (metres) of a block [0,4] x [0,4] x [0,1] with a block [w, 4-w] x [w, y1] x [1,2]
// fused on top (same-domain faces unified): the bottom block's top face is a ledge of width w
// along the upper block's sides, joined to them by concave 90-degree edges. y1 = 4 - w: a
// closed ring around the upper block; y1 = 4: a U open at y = 4, where the upper block is flush
// with the lower one.
void write_ledge_body(const std::filesystem::path& file, double w, bool open_u);
}  // namespace sweeptest
