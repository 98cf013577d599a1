// meshflow CAD — faces against a shape's bounding box (see domain_rules.hpp).
#include "stages/cad/domain_rules.hpp"

#include <algorithm>
#include <cmath>

namespace meshflow::cad {
namespace {
double side(const Box& b, int k) { return b.hi[k] - b.lo[k]; }
double distance(const Vec3& a, const Vec3& b) { return std::hypot(a.x - b.x, a.y - b.y, a.z - b.z); }
}  // namespace

std::vector<std::pair<int, int>> box_sides(const Shape& s, int f, const Box& b, double tol) {
  std::vector<std::pair<int, int>> sides;
  if (s.face_surface_type(f) != "plane") return sides;
  Box fb = s.face_box(f);
  for (int k = 0; k < 3; ++k) {
    if (side(fb, k) > 2 * tol) continue;
    for (int hi = 0; hi < 2; ++hi)
      if (std::abs((hi ? fb.hi[k] : fb.lo[k]) - (hi ? b.hi[k] : b.lo[k])) <= 2 * tol) sides.push_back({k, hi});
  }
  return sides;
}

int box_corner_vertices(const Shape& s, const Box& b, double tol) {
  int n = 0;
  for (int c = 0; c < 8; ++c) {
    Vec3 p{c & 1 ? b.hi.x : b.lo.x, c & 2 ? b.hi.y : b.lo.y, c & 4 ? b.hi.z : b.lo.z};
    for (int v = 0; v < s.num_vertices(); ++v)
      if (distance(s.vertex_point(v), p) <= tol + s.vertex_tolerance(v)) {
        ++n;
        break;
      }
  }
  return n;
}

std::array<double, 6> box_side_coverage(const Shape& s, const Box& b, double tol) {
  std::array<double, 6> area{};
  for (int f = 0; f < s.num_faces(); ++f)
    for (auto [k, hi] : box_sides(s, f, b, tol)) area[2 * k + hi] += s.face_area(f);
  for (int k = 0; k < 3; ++k)
    for (int hi = 0; hi < 2; ++hi) {
      const double side_area = side(b, (k + 1) % 3) * side(b, (k + 2) % 3);
      area[2 * k + hi] = side_area > 0 ? area[2 * k + hi] / side_area : 0;
    }
  return area;
}

std::vector<int> cut_box_faces(const Shape& s, const Box& b, double tol) {
  std::vector<char> on_box(s.num_faces(), 0);
  for (int f = 0; f < s.num_faces(); ++f) on_box[f] = !box_sides(s, f, b, tol).empty();
  std::vector<int> cut;
  for (int f = 0; f < s.num_faces(); ++f) {
    if (!on_box[f]) continue;
    auto wires = s.face_wires(f);
    bool hole = false;
    for (size_t w = 1; w < wires.size() && !hole; ++w)
      for (auto& use : wires[w])
        for (int g : s.edge_faces(use.edge))
          if (g != f && !on_box[g]) hole = true;
    if (hole) cut.push_back(f);
  }
  return cut;
}

std::vector<int> curved_farfield(const Shape& s, const Box& b, double tol) {
  const int n = s.num_faces();
  std::vector<char> on_box(n, 0), large(n, 0), far(n, 0);
  for (int f = 0; f < n; ++f) {
    on_box[f] = !box_sides(s, f, b, tol).empty();
    Box fb = s.face_box(f);
    int wide = 0;
    for (int k = 0; k < 3; ++k) wide += side(fb, k) >= 0.5 * side(b, k);
    large[f] = !on_box[f] && wide >= 2;
  }
  std::vector<int> stack;
  for (int f = 0; f < n; ++f)
    if (large[f])
      for (int g : s.face_neighbours(f))
        if (on_box[g] && !far[f]) far[f] = 1, stack.push_back(f);
  while (!stack.empty()) {
    int f = stack.back();
    stack.pop_back();
    for (int g : s.face_neighbours(f))
      if (large[g] && !far[g]) far[g] = 1, stack.push_back(g);
  }
  std::vector<int> out;
  for (int f = 0; f < n; ++f)
    if (far[f]) out.push_back(f);
  return out;
}

}  // namespace meshflow::cad
