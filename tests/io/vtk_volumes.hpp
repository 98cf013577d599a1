// VTK's own measure of a mesh file, for the tests of this folder: tests/io/vtk_cell_volumes.py
// run with Debian's /usr/bin/python3 (MESHFLOW_PYTHON): per VTK cell class the cells, those
// with volume <= 0 and the total volume (vtkCellSizeFilter), and for a CGNS file the boundary
// patches VTK's CGNS reader (ParaView's) produced, with their cell counts.
#pragma once

#include <doctest/doctest.h>

#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>
#include <string>

namespace mfvtk {
struct Volumes {
  long cells = 0, nonpositive = 0;
  double total = 0;
};
struct Measure {
  std::map<std::string, Volumes> by_class;
  std::map<std::string, long> patches;
};
inline Measure measure(const std::filesystem::path& file) {
  const auto out = std::filesystem::temp_directory_path() / ("mf_vtk_volumes_" + std::to_string(::getpid()) + ".txt");
  const std::string cmd = std::string(MESHFLOW_PYTHON) + " " + MESHFLOW_SOURCE_DIR + "/tests/io/vtk_cell_volumes.py " +
                          file.string() + " > " + out.string() + " 2>&1";
  const int rc = std::system(cmd.c_str());
  std::ifstream in(out);
  std::stringstream text;
  text << in.rdbuf();
  INFO(text.str());
  REQUIRE(rc == 0);
  Measure m;
  std::string cls;
  while (text >> cls) {
    if (cls == "patch") {
      std::string name;
      long n = 0;
      text >> name >> n;
      m.patches[name] = n;
      continue;
    }
    Volumes v;
    REQUIRE(static_cast<bool>(text >> v.cells >> v.nonpositive >> v.total));
    m.by_class[cls] = v;
  }
  return m;
}
}  // namespace mfvtk
