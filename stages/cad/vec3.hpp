// meshflow — small 3-vector helpers on std::array<double, 3> shared by the stages that do
// geometry outside OCCT (shell, balance, sweep), and the conversions to and from cad::Vec3.
// Header-only and dependency-free (Eigen would be heavier than these few lines for the
// per-point arithmetic the stages do).
#pragma once

#include "stages/cad/cad.hpp"

#include <array>
#include <cmath>

namespace meshflow::cad::vec {

using V3 = std::array<double, 3>;

inline V3 v3(const cad::Vec3& p) { return {p.x, p.y, p.z}; }
inline cad::Vec3 cv(const V3& p) { return {p[0], p[1], p[2]}; }
inline V3 add(V3 a, V3 b) { return {a[0] + b[0], a[1] + b[1], a[2] + b[2]}; }
inline V3 sub(V3 a, V3 b) { return {a[0] - b[0], a[1] - b[1], a[2] - b[2]}; }
inline V3 mul(V3 a, double s) { return {a[0] * s, a[1] * s, a[2] * s}; }
inline double dot(V3 a, V3 b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }
inline V3 cross(V3 a, V3 b) { return {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]}; }
inline double norm(V3 a) { return std::sqrt(dot(a, a)); }

}  // namespace meshflow::cad::vec
