// Shapes for the curve tests, made with OCCT in shapes.cpp (this header includes no OCCT).
#pragma once

#include "stages/cad/cad.hpp"

namespace curvetest {
// Fluid between spheres of radii r1 < r2 (inner face: wall, outer: farfield).
meshflow::cad::Shape sphere_shell(double r1, double r2);
// Fluid between coaxial cylinders r1 < r2 on the z axis, 0 <= z <= h (inner: wall, outer:
// farfield, the two planar annuli: symmetry).
meshflow::cad::Shape cylinder_shell(double r1, double r2, double h);
// One face, tagged wall: the sector -a <= u <= a of the cylinder of radius r on the z axis,
// 0 <= z <= h, on an untrimmed cylindrical surface, so that its parameter range straddles the
// surface's seam u = 0 but the face has no seam edge (Rotor 67's hub and casing sectors are
// faces of that kind).
meshflow::cad::Shape cylinder_sector_face(double r, double h, double a);
}  // namespace curvetest
