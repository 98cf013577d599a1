// Shapes for the periodic_match tests, made with OCCT in shapes.cpp (this header is OCCT-free;
// OCCT is used here as in tests/heal: the test is a leaf). Faces come untagged (none); the
// tests tag them with Shape::set_face_tag.
#pragma once

#include "stages/cad/cad.hpp"

#include <array>
#include <vector>

namespace pmtest {

using meshflow::cad::Shape;

// Box [0,L] x [0,1] x [0,1] with a cylindrical hole of radius 0.2 along x through (y,z) =
// (0.5,0.5): through the box, or blind (from x = 0 to x = L/2).
Shape box_with_hole(double L, bool through = true);

// Solids of revolution about the x axis: the rectangle x in [x0,x1], r in [r0,r1] of the
// half-plane theta = theta0 (theta about x, from +y towards +z) swept by alpha, one solid per
// {theta0, alpha}; several make a compound.
Shape annulus_sectors(double x0, double x1, double r0, double r1, const std::vector<std::array<double, 2>>& theta0_alpha);

// A copy of `s` (tags kept) moved by the rotation by `angle` about the axis through `point`
// along `dir`, then translated by `shift`.
Shape moved(const Shape& s, std::array<double, 3> point, std::array<double, 3> dir, double angle, std::array<double, 3> shift);

// A copy of `s` (tags kept) whose B-spline face `face` has its middle pole moved by `delta`
// (its edges and vertices unchanged): the face's surface bulges by ~delta inside.
Shape bulged(const Shape& s, int face, std::array<double, 3> delta);

}  // namespace pmtest
