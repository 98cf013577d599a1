// Reading a CAD file into a cad::Shape (no OCCT in this header).
#pragma once

#include "stages/cad/cad.hpp"

#include <filesystem>
#include <functional>
#include <string>

namespace meshflow::geometry {

// Reads a .step/.stp, .iges/.igs or .brep/.brp file, keeping the file's length unit (a STEP in
// mm stays in mm; a BREP carries none: mm unless `units` is given). `units` non-empty relabels
// the unit; `scale` scales about the origin. Throws StageError with the file and what to do.
cad::Shape import_cad(const std::filesystem::path& path, const std::string& units, double scale,
                      const std::function<void(const std::string&)>& log);

}  // namespace meshflow::geometry
