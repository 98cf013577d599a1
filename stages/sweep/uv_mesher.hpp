// meshflow sweep — PRIVATE header: the 2D mesher of one face's parameter domain (CGAL's
// constrained Delaunay triangulation, in uv_mesher.cpp only). No CGAL type here.
//
// Why our own refinement loop around CGAL's CDT instead of CGAL::Delaunay_mesher_2: the mesher
// splits constrained edges that are encroached, and our boundary nodes are fixed (they are the
// divisions the integer program chose and the nodes neighbouring faces share). Here a
// candidate point that would encroach on a constraint is replaced by the bad triangle's
// centroid, so the boundary is never touched, and no point (centroids too) is inserted inside
// the still empty diametral sphere of a segment (its triangle's apex would come ever closer:
// slivers; see mesh_uv). Sizes are 3D: a triangle is refined while its
// longest 3D edge exceeds `refine_ratio` × size(centroid), so the surface metric needs no
// parameterisation-specific handling (poles, stretched B-splines).
#pragma once

#include <array>
#include <cstddef>
#include <functional>
#include <vector>

namespace meshflow::sweep::detail {

struct UVMeshInput {
  std::vector<std::array<double, 2>> uv;     // boundary points (any scaling of u, v)
  std::vector<std::array<int, 2>> segments;  // closed loops of constrained segments
  // optional, per boundary point: 1 where the segment starting there is a pole (a degenerate
  // edge: both its ends are one point of the surface); segments of zero 3D length are poles too
  std::vector<char> pole;
  // optional, per boundary point: 1 where the boundary is tangent-continuous in 3D. No output
  // triangle has two boundary segments meeting at such a point (curved, its corner there would
  // open to 180 degrees): at the end such a triangle is split (a point off the shorter segment,
  // or its centroid), or, when it is flat (that point falls outside it), its third edge flipped.
  std::vector<char> smooth;
  std::function<std::array<double, 3>(double, double)> point;  // surface point at (u, v)
  std::function<double(double, double)> size;                  // target 3D edge length at (u, v)
  // optional turn-angle rule: a triangle whose vertex normals differ by more than max_turn
  // (radians) is refined while its longest edge exceeds min_length
  std::function<std::array<double, 3>(double, double)> normal;
  double max_turn = 0, min_length = 0;
  // optional: +1 or -1, the sign of (dS/dU x dS/dV) . normal on this face (0: unknown). With it,
  // a triangle whose 3D normal opposes the surface's at its centroid (folded: round a pole, where
  // the parameter plane's triangles fan over more than half a turn, or thin in a strongly sheared
  // plane) is counted: the swaps are redone refusing folds where they fold one, no smoothing move
  // makes one; those left at the end are repaired where they are (an edge flipped, a new point
  // moved or collapsed into a neighbour), and out.folded counts any still left.
  int orientation = 0;
  double refine_ratio = 1.3;
  double min_quality = 0.4;  // 3D shape quality 4 sqrt(3) area / sum l^2 below which a triangle gets its circumcentre
  int max_passes = 60;
  int smooth_passes = 4;
  std::size_t max_points = 400000;
};

struct UVMeshOutput {
  std::vector<std::array<double, 2>> uv;  // the input boundary points (same indices), then new points
  std::vector<std::array<int, 3>> tris;   // counter-clockwise in (u, v), inside the loops only
  int passes = 0;
  int smooth_corner_splits = 0;  // triangles split because two boundary segments met at a smooth point
  int smooth_corner_flips = 0;   // such flat triangles whose third edge was flipped instead
  double min_quality = 1;  // of the result (a pole's own triangles, points in 3D, left out)
  int folded = 0;          // triangles whose 3D normal opposes the surface's (with in.orientation), left at the end
  int unfold_repairs = 0;  // flips, moves and collapses that repaired folded triangles at the end
  // a folded triangle left (the first on a boundary segment, else the first): its 3D centroid,
  // and whether one of its sides is a boundary segment (then the face is narrower there than
  // the segment's chord sags: no point inside the face unfolds it)
  std::array<double, 3> folded_at{0, 0, 0};
  bool folded_on_segment = false;
};

// Throws std::runtime_error (crossing constraints, a point budget exceeded) with the reason.
UVMeshOutput mesh_uv(const UVMeshInput& in);

}  // namespace meshflow::sweep::detail
