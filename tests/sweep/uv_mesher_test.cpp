// The 2D mesher of sweep (stages/sweep/uv_mesher.hpp, private to sweep): smooth boundary points.
#include <doctest/doctest.h>

#include "stages/sweep/uv_mesher.hpp"

#include <algorithm>
#include <cmath>
#include <set>

using meshflow::sweep::detail::mesh_uv;
using meshflow::sweep::detail::UVMeshInput;

TEST_CASE("uv mesher: no triangle has two boundary segments meeting at a smooth boundary point") {
  // a 10 x 1 strip whose right end stands for a one-segment arc: the boundary is tangent-
  // continuous at (10,0) and (10,1), as where a blunt trailing edge meets its semicircular tip
  UVMeshInput in;
  in.uv = {{0, 0}, {10, 0}, {10, 1}, {0, 1}};
  in.segments = {{0, 1}, {1, 2}, {2, 3}, {3, 0}};
  in.point = [](double u, double v) { return std::array<double, 3>{u, v, 0}; };
  in.size = [](double, double) { return 100.0; };  // no refinement: the CDT's two triangles
  auto plain = mesh_uv(in);
  REQUIRE(plain.tris.size() == 2);
  CHECK(plain.smooth_corner_splits == 0);

  in.smooth = {0, 1, 1, 0};
  auto out = mesh_uv(in);
  std::set<std::pair<int, int>> seg;
  for (auto& s : in.segments) seg.insert({std::min(s[0], s[1]), std::max(s[0], s[1])});
  auto is_seg = [&](int a, int b) { return seg.count({std::min(a, b), std::max(a, b)}) > 0; };
  CHECK(out.smooth_corner_splits > 0);
  for (auto& t : out.tris) {
    for (int k = 0; k < 3; ++k) {
      int v = t[k], a = t[(k + 2) % 3], b = t[(k + 1) % 3];
      if (v < 4 && in.smooth[v]) CHECK_FALSE((is_seg(a, v) && is_seg(v, b)));
    }
    // counter-clockwise, non-degenerate
    auto& p = out.uv;
    double o = (p[t[1]][0] - p[t[0]][0]) * (p[t[2]][1] - p[t[0]][1]) - (p[t[1]][1] - p[t[0]][1]) * (p[t[2]][0] - p[t[0]][0]);
    CHECK(o > 0);
  }
  // the split points lie inside the strip, and the corner at a smooth point opens to about 90
  // degrees (the new point sits off the short end's middle, not at a sliver's centroid)
  for (std::size_t i = 4; i < out.uv.size(); ++i) {
    CHECK(out.uv[i][0] > 0);
    CHECK(out.uv[i][0] < 10);
    CHECK(out.uv[i][1] > 0);
    CHECK(out.uv[i][1] < 1);
  }
  CHECK(std::any_of(out.uv.begin() + 4, out.uv.end(), [](auto& q) { return std::abs(q[1] - 0.5) < 1e-12 && q[0] > 8.9; }));
}

// A face bounded by one closed circular edge (a cylinder's end disc) is a regular polygon of
// boundary points, all on one circle: every triangle of the first refinement pass has the disc's
// centre as circumcentre, up to rounding. Points of one pass were chosen against the
// triangulation before the pass, so 12 of them were inserted within 1e-15 of one another at the
// centre (issue 20: coincident nodes, zero-area wall triangles). No two points may coincide, no
// triangle may be degenerate, and the disc is still refined to its size.
TEST_CASE("uv mesher: a disc bounded by one closed circular edge gets one point at its centre, not several coincident ones") {
  const int n = 32;
  const double R = 0.5;
  UVMeshInput in;
  for (int i = 0; i < n; ++i) {
    double a = 2 * M_PI * i / n;
    in.uv.push_back({R * std::cos(a), R * std::sin(a)});
    in.segments.push_back({i, (i + 1) % n});
  }
  in.smooth.assign(n, 1);
  in.smooth[0] = 0;  // the closed edge's one vertex
  in.point = [](double u, double v) { return std::array<double, 3>{u, v, 0}; };
  in.size = [](double, double) { return 0.1; };
  auto out = mesh_uv(in);
  REQUIRE(out.uv.size() > static_cast<std::size_t>(n) + 10);  // refined inside
  double min_d = INFINITY;
  int at_centre = 0;
  for (std::size_t i = 0; i < out.uv.size(); ++i) {
    if (std::hypot(out.uv[i][0], out.uv[i][1]) < 1e-9) ++at_centre;
    for (std::size_t j = i + 1; j < out.uv.size(); ++j)
      min_d = std::min(min_d, std::hypot(out.uv[i][0] - out.uv[j][0], out.uv[i][1] - out.uv[j][1]));
  }
  INFO("points " << out.uv.size() << ", within 1e-9 of the centre " << at_centre << ", closest pair " << min_d);
  CHECK(at_centre <= 1);
  CHECK(min_d > 0.01);  // a quarter of the size 0.1 is the mesher's own spacing rule; 0.01 leaves room
  double min_ratio = INFINITY;
  for (auto& t : out.tris) {
    auto& p = out.uv;
    double o = (p[t[1]][0] - p[t[0]][0]) * (p[t[2]][1] - p[t[0]][1]) - (p[t[1]][1] - p[t[0]][1]) * (p[t[2]][0] - p[t[0]][0]);
    CHECK(o > 0);
    double l[3];
    for (int k = 0; k < 3; ++k) l[k] = std::hypot(p[t[k]][0] - p[t[(k + 1) % 3]][0], p[t[k]][1] - p[t[(k + 1) % 3]][1]);
    min_ratio = std::min(min_ratio, std::min({l[0], l[1], l[2]}) / std::max({l[0], l[1], l[2]}));
  }
  CHECK(min_ratio > 0.1);
  CHECK(out.min_quality > 0.3);
}

// A triangle folded in 3D at the end of the meshing (its normal opposes the surface's: a point
// nearly on a curved boundary segment's chord, bottle.brep's torus fillet) is repaired where it
// is. The surface here is the plane, whose normal is made to point down inside a small disc
// round the centroid of one triangle of the plain mesh, so that exactly that triangle counts
// as folded; the result must have no folded triangle, still cover the square, and keep no
// unused point.
TEST_CASE("uv mesher: a triangle left folded at the end is repaired by a flip, a move or a collapse, and the face stays covered") {
  UVMeshInput in;
  in.uv = {{0, 0}, {1, 0}, {1, 1}, {0, 1}};
  in.segments = {{0, 1}, {1, 2}, {2, 3}, {3, 0}};
  in.point = [](double u, double v) { return std::array<double, 3>{u, v, 0}; };
  in.size = [](double, double) { return 0.2; };
  in.normal = [](double, double) { return std::array<double, 3>{0, 0, 1}; };
  in.orientation = 1;
  const auto plain = mesh_uv(in);
  REQUIRE(plain.folded == 0);
  CHECK(plain.unfold_repairs == 0);
  // the first triangle with a new (interior) point, and a disc well inside it round its centroid
  std::array<double, 2> c{0, 0};
  double r = 0;
  for (auto& t : plain.tris) {
    if (std::max({t[0], t[1], t[2]}) < 4) continue;
    auto& p = plain.uv;
    c = {(p[t[0]][0] + p[t[1]][0] + p[t[2]][0]) / 3, (p[t[0]][1] + p[t[1]][1] + p[t[2]][1]) / 3};
    double l = INFINITY;
    for (int k = 0; k < 3; ++k) l = std::min(l, std::hypot(p[t[k]][0] - p[t[(k + 1) % 3]][0], p[t[k]][1] - p[t[(k + 1) % 3]][1]));
    r = 0.05 * l;
    break;
  }
  REQUIRE(r > 0);
  in.normal = [c, r](double u, double v) {
    return std::array<double, 3>{0, 0, std::hypot(u - c[0], v - c[1]) < r ? -1.0 : 1.0};
  };
  const auto out = mesh_uv(in);
  INFO("points " << plain.uv.size() << " -> " << out.uv.size() << ", repairs " << out.unfold_repairs);
  CHECK(out.unfold_repairs > 0);
  CHECK(out.folded == 0);
  double area = 0;
  std::vector<char> used(out.uv.size(), 0);
  for (auto& t : out.tris) {
    auto& p = out.uv;
    double o = (p[t[1]][0] - p[t[0]][0]) * (p[t[2]][1] - p[t[0]][1]) - (p[t[1]][1] - p[t[0]][1]) * (p[t[2]][0] - p[t[0]][0]);
    CHECK(o > 0);
    area += 0.5 * o;
    for (int v : t) used[v] = 1;
    // no triangle's centroid in the disc: none is folded
    double gu = (p[t[0]][0] + p[t[1]][0] + p[t[2]][0]) / 3, gv = (p[t[0]][1] + p[t[1]][1] + p[t[2]][1]) / 3;
    CHECK(std::hypot(gu - c[0], gv - c[1]) >= r);
  }
  CHECK(area == doctest::Approx(1.0).epsilon(1e-12));
  CHECK(std::all_of(used.begin(), used.end(), [](char u) { return u; }));
}
