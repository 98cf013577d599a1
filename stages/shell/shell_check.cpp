// meshflow shell — self-intersection check of the sampled shell surface with CGAL's AABB tree.
// The only translation unit of stages/shell that includes CGAL (no OCCT anywhere here).
#include "stages/shell/shell.hpp"

#include <CGAL/AABB_traits.h>
#include <CGAL/AABB_tree.h>
#include <CGAL/AABB_triangle_primitive.h>
#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#include <CGAL/intersections.h>
#include <CGAL/Constrained_Delaunay_triangulation_2.h>
#include <CGAL/Triangulation_vertex_base_with_info_2.h>
#include <CGAL/Constrained_triangulation_face_base_2.h>
#include <CGAL/Triangulation_face_base_with_info_2.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <stdexcept>

#include <algorithm>
#include <vector>

namespace meshflow::shell {

namespace {
using K = CGAL::Exact_predicates_inexact_constructions_kernel;
using Tri = K::Triangle_3;
using Iter = std::vector<Tri>::const_iterator;
using Prim = CGAL::AABB_triangle_primitive<K, Iter>;
using Tree = CGAL::AABB_tree<CGAL::AABB_traits<K, Prim>>;
}  // namespace

// Every pair of triangles that do not share a vertex index and intersect (exact predicate,
// CGAL::do_intersect on Triangle_3 with filtered exact predicates). Degenerate triangles are
// skipped. Deterministic: pairs are reported in (i, j) order, i < j, at any thread count (each
// triangle's partners are found in parallel into its own slot, then reported in order).
IntersectionReport self_intersections(const std::vector<Vec3>& points,
                                      const std::vector<std::array<std::int32_t, 3>>& tris, int threads) {
  IntersectionReport rep;
  std::vector<Tri> T;
  std::vector<int> id;
  T.reserve(tris.size());
  for (std::size_t i = 0; i < tris.size(); ++i) {
    auto& t = tris[i];
    K::Point_3 a(points[t[0]][0], points[t[0]][1], points[t[0]][2]);
    K::Point_3 b(points[t[1]][0], points[t[1]][1], points[t[1]][2]);
    K::Point_3 c(points[t[2]][0], points[t[2]][1], points[t[2]][2]);
    Tri tr(a, b, c);
    if (tr.is_degenerate()) continue;
    T.push_back(tr);
    id.push_back(static_cast<int>(i));
  }
  if (T.empty()) return rep;
  Tree tree(T.begin(), T.end());
  // The candidates are the triangles whose boxes meet this one's; those sharing a vertex with it
  // are dropped before the exact test, not after: a neighbour always touches it, nearly coplanar,
  // where the filtered predicate's interval fails (an exception, then exact arithmetic). Querying
  // the tree with the triangle itself ran that test on every neighbour: about half of the wing's
  // shell stage (bench/results/profile/wingtip_step.shell.txt: self_intersections 47%, 16% in
  // exception unwinding). The pairs found are the same.
  tree.build();  // built before the queries, which may then run concurrently
  std::vector<std::vector<int>> partners(T.size());
  auto find_partners = [&](std::size_t k) {
    std::vector<Prim::Id> hits;
    tree.all_intersected_primitives(T[k].bbox(), std::back_inserter(hits));
    std::vector<int>& js = partners[k];
    for (auto h : hits) {
      std::size_t j = static_cast<std::size_t>(h - T.cbegin());
      if (j <= k) continue;
      auto& a = tris[id[k]];
      auto& b = tris[id[j]];
      bool share = false;
      for (int x : a)
        for (int y : b) share |= x == y;
      if (share || !CGAL::do_intersect(T[k], T[j])) continue;
      js.push_back(static_cast<int>(j));
    }
    std::sort(js.begin(), js.end());
  };
  if (threads > 1 && T.size() >= 512) {
    tbb::task_arena arena(threads);
    arena.execute([&] {
      tbb::parallel_for(tbb::blocked_range<std::size_t>(0, T.size(), 256), [&](const tbb::blocked_range<std::size_t>& r) {
        for (std::size_t k = r.begin(); k != r.end(); ++k) find_partners(k);
      });
    });
  } else {
    for (std::size_t k = 0; k < T.size(); ++k) find_partners(k);
  }
  for (std::size_t k = 0; k < T.size(); ++k) {
    for (int j : partners[k]) {
      if (rep.pairs == 0) {
        auto& a = tris[id[k]];
        for (int c = 0; c < 3; ++c)
          rep.first[c] = (points[a[0]][c] + points[a[1]][c] + points[a[2]][c]) / 3;
      }
      ++rep.pairs;
      if (rep.examples.size() < 10) rep.examples.push_back({id[k], id[j]});
      rep.all.push_back({id[k], id[j]});
    }
  }
  return rep;
}

std::vector<std::array<std::int32_t, 3>> cdt2(const std::vector<std::array<double, 2>>& points,
                                              const std::vector<std::array<std::int32_t, 2>>& segments,
                                              std::vector<int>* depth) {
  using Vb = CGAL::Triangulation_vertex_base_with_info_2<std::int32_t, K>;
  using Fbb = CGAL::Triangulation_face_base_with_info_2<int, K>;  // nesting depth
  using Fb = CGAL::Constrained_triangulation_face_base_2<K, Fbb>;
  using Tds = CGAL::Triangulation_data_structure_2<Vb, Fb>;
  using CDT = CGAL::Constrained_Delaunay_triangulation_2<K, Tds, CGAL::Exact_predicates_tag>;
  CDT cdt;
  std::vector<CDT::Vertex_handle> vh(points.size());
  for (std::size_t i = 0; i < points.size(); ++i) {
    vh[i] = cdt.insert(K::Point_2(points[i][0], points[i][1]));
  }
  // assign indices in input order, keeping the first index for duplicates
  for (auto v = cdt.finite_vertices_begin(); v != cdt.finite_vertices_end(); ++v) v->info() = -1;
  const std::size_t nin = cdt.number_of_vertices();  // distinct input points
  for (std::size_t i = 0; i < points.size(); ++i)
    if (vh[i]->info() < 0) vh[i]->info() = static_cast<std::int32_t>(i);
  try {
    for (auto& s : segments)
      if (vh[s[0]] != vh[s[1]]) cdt.insert_constraint(vh[s[0]], vh[s[1]]);
  } catch (const std::exception& e) {
    throw std::runtime_error(std::string("constrained Delaunay triangulation failed: ") + e.what());
  }
  // crossing constraints make CGAL insert their intersection points (Exact_predicates_tag):
  // such a vertex has no input index, and the caller's boundary loops are not a valid domain
  if (cdt.number_of_vertices() != nin)
    throw std::runtime_error("constrained Delaunay triangulation: " + std::to_string(cdt.number_of_vertices() - nin) +
                             " boundary segment crossing(s) in (u,v)");
  if (depth) {
    // nesting depth: 0 for the faces reached from the unbounded face without crossing a
    // constrained segment, +1 across each one (flood fill by combinatorics, no geometric test)
    for (auto f = cdt.all_faces_begin(); f != cdt.all_faces_end(); ++f) f->info() = -1;
    std::vector<CDT::Face_handle> front = {cdt.infinite_face()}, next;
    for (int level = 0; !front.empty(); ++level, front.swap(next), next.clear()) {
      std::vector<CDT::Face_handle> stack;
      for (auto f : front)
        if (f->info() < 0) f->info() = level, stack.push_back(f);
      while (!stack.empty()) {
        auto f = stack.back();
        stack.pop_back();
        for (int i = 0; i < 3; ++i) {
          auto g = f->neighbor(i);
          if (g->info() >= 0) continue;
          if (cdt.is_constrained(CDT::Edge(f, i))) next.push_back(g);
          else g->info() = level, stack.push_back(g);
        }
      }
    }
  }
  std::vector<std::pair<std::array<std::int32_t, 3>, int>> out;
  for (auto f = cdt.finite_faces_begin(); f != cdt.finite_faces_end(); ++f)
    out.push_back({{f->vertex(0)->info(), f->vertex(1)->info(), f->vertex(2)->info()}, f->info()});
  std::sort(out.begin(), out.end());
  std::vector<std::array<std::int32_t, 3>> tris;
  tris.reserve(out.size());
  if (depth) depth->clear();
  for (auto& [t, d] : out) {
    tris.push_back(t);
    if (depth) depth->push_back(d);
  }
  return tris;
}

}  // namespace meshflow::shell
