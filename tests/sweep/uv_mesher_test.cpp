// The 2D mesher of sweep (stages/sweep/uv_mesher.hpp, private to sweep): smooth boundary points.
#include <doctest/doctest.h>

#include "stages/sweep/uv_mesher.hpp"

#include <algorithm>
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
