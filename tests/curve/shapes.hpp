// Shapes for the curve tests, made with OCCT in shapes.cpp (this header includes no OCCT).
#pragma once

#include "stages/cad/cad.hpp"

namespace curvetest {
// Fluid between spheres of radii r1 < r2 (inner face: wall, outer: farfield).
meshflow::cad::Shape sphere_shell(double r1, double r2);
// Fluid between coaxial cylinders r1 < r2 on the z axis, 0 <= z <= h (inner: wall, outer:
// farfield, the two planar annuli: symmetry).
meshflow::cad::Shape cylinder_shell(double r1, double r2, double h);
}  // namespace curvetest
