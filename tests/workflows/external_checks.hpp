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
// per Gmsh element type name: {elements, elements with minJ/maxJ <= 0}
inline std::map<std::string, std::pair<long, long>> gmsh_flags(const std::filesystem::path& msh) {
  auto g = mftest::sh(std::string(MESHFLOW_PYTHON) + " " + std::string(MESHFLOW_SOURCE_DIR) +
                      "/tests/workflows/gmsh_jacobian_check.py " + msh.string());
  INFO(g.out);
  REQUIRE(g.code == 0);
  std::istringstream in(g.out);
  std::map<std::string, std::pair<long, long>> by;
  std::string name;
  long n = 0, b = 0;
  while (in >> name >> n >> b) by[name] = {n, b};
  return by;
}
// per VTK Lagrange cell class: {cells, cells with det J <= 0 at a sample}
inline std::map<std::string, std::pair<long, long>> vtk_flags(const std::filesystem::path& vtu) {
  auto v = mftest::sh(std::string(MESHFLOW_PYTHON) + " " + std::string(MESHFLOW_SOURCE_DIR) +
                      "/tests/workflows/vtk_lagrange_check.py " + vtu.string());
  INFO(v.out);
  REQUIRE(v.code == 0);
  std::istringstream in(v.out);
  std::map<std::string, std::pair<long, long>> by;
  std::string cls;
  long cells = 0, bad = 0;
  double ratio = 0;
  while (in >> cls >> cells >> bad >> ratio) by[cls] = {cells, bad};
  return by;
}
}  // namespace mfcheck
