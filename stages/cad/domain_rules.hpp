// meshflow CAD — how a shape's faces sit on its bounding box: the rules `meshflow init` reads a
// file with (a body, or the fluid domain itself) and heal tags a domain's faces with. Only the
// cad::Shape interface (no OCCT), so init and heal share one definition.
#pragma once

#include "stages/cad/cad.hpp"

#include <array>
#include <utility>
#include <vector>

namespace meshflow::cad {

// The sides of `b` (axis k, 0 = lo / 1 = hi) on whose plane the planar face `f` lies, within tol.
std::vector<std::pair<int, int>> box_sides(const Shape& s, int f, const Box& b, double tol);

// Corners of `b` that are vertices of the shape (8: a box-shaped tunnel or channel).
int box_corner_vertices(const Shape& s, const Box& b, double tol);

// Per side of `b` (index 2k + hi), the share of its area that planar faces lying on it cover:
// a tunnel's or channel's walls cover each side whole (0.99 and more on every tunnel seen), a
// machined block's steps and pockets leave most of its sides open (0.1 to 0.8).
std::array<double, 6> box_side_coverage(const Shape& s, const Box& b, double tol);

// Planar faces on a plane of `b` that have a hole (an inner wire) bounded by faces off the box
// planes: a tunnel wall or a symmetry plane with a body cut into it (a half model's root, a
// strut's foot). A body never has one: only the fluid domain around a body does.
std::vector<int> cut_box_faces(const Shape& s, const Box& b, double tol);

// The far field of a domain that is not box-shaped (a half sphere or half cylinder around a half
// model): faces off the box planes that span at least half of `b` along two axes and are
// connected, through faces of that size, to a face on a box plane. A body's walls are smaller
// than the domain around them; a tunnel's far field lies on its box planes and needs no rule.
std::vector<int> curved_farfield(const Shape& s, const Box& b, double tol);

}  // namespace meshflow::cad
