// Independent verdicts on a written mesh, for the end-to-end tests of this folder: Gmsh's
// Plugin(AnalyseMeshQuality) (gmsh_jacobian_check.py) and VTK's Lagrange cells
// (vtk_lagrange_check.py), both run with Debian's /usr/bin/python3 (MESHFLOW_PYTHON).
#pragma once

#include "support.hpp"

#include <doctest/doctest.h>

#include <filesystem>
#include <map>
#include <sstream>
#include <string>
#include <utility>

namespace mfcheck {
// the output of tests/workflows/<script> FILE, which must exit 0
inline std::string run_check(const std::string& script, const std::filesystem::path& file) {
  auto r = mftest::sh(std::string(MESHFLOW_PYTHON) + " " + std::string(MESHFLOW_SOURCE_DIR) + "/tests/workflows/" + script + " " +
                      file.string());
  INFO(r.out);
  REQUIRE(r.code == 0);
  return r.out;
}
// per Gmsh element type name: {elements, elements with minJ/maxJ <= 0}
inline std::map<std::string, std::pair<long, long>> gmsh_flags(const std::filesystem::path& msh) {
  std::istringstream in(run_check("gmsh_jacobian_check.py", msh));
  std::map<std::string, std::pair<long, long>> by;
  std::string name;
  long n = 0, b = 0;
  while (in >> name >> n >> b) by[name] = {n, b};
  return by;
}
// per VTK Lagrange cell class: {cells, cells with det J <= 0 at a sample}
inline std::map<std::string, std::pair<long, long>> vtk_flags(const std::filesystem::path& vtu) {
  std::istringstream in(run_check("vtk_lagrange_check.py", vtu));
  std::map<std::string, std::pair<long, long>> by;
  std::string cls;
  long cells = 0, bad = 0;
  double ratio = 0;
  while (in >> cls >> cells >> bad >> ratio) by[cls] = {cells, bad};
  return by;
}
}  // namespace mfcheck
