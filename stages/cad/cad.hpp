// meshflow CAD interface — the only place meshing code asks geometry questions.
//
// This header includes no OpenCASCADE header (OCCT's Handle macro breaks CGAL, and other
// stages must be able to include it): the B-rep lives behind a pimpl. OCCT is used only in
// stages/cad, stages/geometry and stages/heal .cpp files (and their private headers, e.g.
// stages/cad/occt.hpp).
//
// ── The "shape" artifact ────────────────────────────────────────────────────────────────
// One file (extension ".mfshape"), text:
//   line 1: "meshflow-shape 1"
//   line 2: one line of JSON, the header:
//           {"units":"mm","face_tags":["wall","farfield",...],"counts":{"solids":1,...}}
//           face_tags[i] is the tag of face id i (see ids below); tags are
//           none|wall|farfield|symmetry|periodic_lo|periodic_hi.
//   rest:   the B-rep in OCCT's BREP text format (BRepTools::Write, no triangulation).
// Writing is deterministic: the same shape gives byte-identical files.
//
// ── Ids ────────────────────────────────────────────────────────────────────────────────
// Solids, shells, faces, edges and vertices are numbered 0..n-1 in the order of a depth-first
// traversal of the stored B-rep (TopExp::MapShapes). Ids are stable: loading the same artifact
// always gives the same ids, and a stage that does not change the shape keeps them.
//
// ── Use from a stage ───────────────────────────────────────────────────────────────────
//   auto shape = meshflow::cad::Shape::load(ctx.input("shape").path);
//   for (int f : shape.faces_with_tag(cad::Tag::wall)) {
//     auto [u0, u1, v0, v1] = shape.face_uv_bounds(f);
//     auto d = shape.face_eval(f, u, v);               // point + 1st and 2nd derivatives
//     auto pr = shape.project_to_face(f, p);          // {u, v, distance, point}
//     auto pr2 = shape.project_to_face(f, p2, {{pr.u, pr.v}});   // faster with a hint
//   }
//
// Thread safety: all const queries may run concurrently EXCEPT the project_* functions and
// face_contains_uv, which fill lazy per-face/per-edge caches. For parallel projection give each thread its own
// copy: `Shape mine = shape.clone();` (cheap: geometry is shared, caches are not), or one per
// thread of a parallel loop: cad::ShapeClones (shape_clones.hpp).
//
// Errors: load() throws meshflow::StageError (file, what is wrong, what to do); an id out of
// range throws std::out_of_range.
#pragma once

#include <array>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

namespace meshflow::cad {

struct Vec3 {
  double x = 0, y = 0, z = 0;
  double operator[](int i) const { return i == 0 ? x : i == 1 ? y : z; }
};
struct Vec2 {
  double u = 0, v = 0;
};
struct Box {
  Vec3 lo, hi;  // axis-aligned, enlarged by the shape tolerances as OCCT does
};
struct Range {
  double lo = 0, hi = 0;
};
struct UVBounds {
  double u0 = 0, u1 = 0, v0 = 0, v1 = 0;
};

// Physical group of a boundary face.
enum class Tag : std::uint8_t { none, wall, farfield, symmetry, periodic_lo, periodic_hi };
const char* tag_name(Tag t);
// Throws std::invalid_argument for an unknown name.
Tag tag_from_name(const std::string& name);

struct CurveDeriv {
  Vec3 p, d1, d2;  // C(t), C'(t), C''(t)
};
struct SurfDeriv {
  Vec3 p, du, dv, duu, duv, dvv;
};
struct Curvature {
  bool defined = false;  // false at umbilic-free singular points (e.g. a pole)
  double k1 = 0, k2 = 0; // principal curvatures (signed w.r.t. face_normal), k1 >= k2
  Vec3 dir1, dir2;       // principal directions
  double mean = 0, gauss = 0;
};
struct CurveProjection {
  double t = 0;         // parameter on the edge's curve, within edge_range
  double distance = 0;  // |p - point|
  Vec3 point;
};
struct SurfaceProjection {
  double u = 0, v = 0;  // parameters on the face's surface (natural bounds, not trimmed)
  double distance = 0;
  Vec3 point;
};
// One edge as used in a face's wire.
struct EdgeUse {
  int edge = -1;
  bool reversed = false;  // the wire runs the edge against its curve's parametrisation
};

class Shape {
 public:
  struct Impl;

  Shape();
  ~Shape();
  Shape(Shape&&) noexcept;
  Shape& operator=(Shape&&) noexcept;
  Shape(const Shape&) = delete;
  Shape& operator=(const Shape&) = delete;
  // Shares the (immutable) geometry, own caches: one per thread for parallel projections.
  Shape clone() const;

  // Loads a "shape" artifact; throws meshflow::StageError when the file is missing or corrupt.
  static Shape load(const std::filesystem::path& artifact);
  // Writes a "shape" artifact (deterministic bytes).
  void save(const std::filesystem::path& artifact) const;
  // Writes plain OCCT BREP / STEP AP214 (for materialising outputs).
  void export_brep(const std::filesystem::path& file) const;
  void export_step(const std::filesystem::path& file) const;
  // IGES 5.3 (BRep mode: faces, edges, vertices as IGES 186/514 entities), in the shape's units.
  void export_iges(const std::filesystem::path& file) const;

  const std::string& units() const;  // "mm", "m", "in", ... as in the source

  int num_solids() const;
  int num_shells() const;
  int num_faces() const;
  int num_edges() const;
  int num_vertices() const;

  // ── tags ──
  Tag face_tag(int face) const;
  void set_face_tag(int face, Tag tag);
  std::vector<int> faces_with_tag(Tag tag) const;

  // ── whole shape ──
  // OCCT's optimal box (BRepBndLib::AddOptimal); threads > 1: its faces' boxes computed in
  // parallel in a task arena of that many threads, their union the same box
  Box box(int threads = 1) const;
  double volume() const;  // of the solids (0 without solids)
  // The same by OCCT's adaptive integration to a relative tolerance (slower; not right on every
  // trimmed face either: see cad.cpp).
  double volume(double rel_tolerance) const;
  double area() const;    // of all faces
  // BRepCheck validity of the whole B-rep (topology and geometry consistency).
  bool valid() const;
  // Non-degenerate edges bounding only one face (not seams): holes in the shell.
  std::vector<int> free_edges() const;
  // Edges shared by more than two faces: non-manifold (duplicated or T-joined faces).
  std::vector<int> multiple_edges() const;
  // Closed: at least one solid, no free edge, no multiple edge, valid.
  bool watertight() const { return num_solids() > 0 && free_edges().empty() && multiple_edges().empty() && valid(); }

  // ── vertices ──
  Vec3 vertex_point(int vertex) const;
  double vertex_tolerance(int vertex) const;

  // ── edges (3D curves) ──
  bool edge_degenerate(int edge) const;  // collapsed to a point (pole of a surface): no 3D curve
  Range edge_range(int edge) const;
  Vec3 edge_point(int edge, double t) const;
  CurveDeriv edge_eval(int edge, double t) const;
  double edge_length(int edge) const;
  double edge_length(int edge, double t0, double t1) const;
  // {first, last} vertex ids in the curve's direction (equal for a closed edge).
  std::array<int, 2> edge_vertices(int edge) const;
  // Faces using the edge, ascending (a seam edge lists its face once).
  std::vector<int> edge_faces(int edge) const;
  bool edge_is_seam(int edge, int face) const;
  // Parameter on the edge of the point nearest p (restricted to edge_range). A hint (a nearby
  // parameter, e.g. of the neighbouring node) makes it a local Newton search.
  CurveProjection project_to_edge(int edge, const Vec3& p, std::optional<double> hint = {}) const;
  // (u,v) on `face` of the edge point at t (the edge's p-curve on that face). For a seam
  // edge, `reversed` selects which of its two p-curves (the EdgeUse of the wire).
  Vec2 edge_uv(int edge, int face, double t, bool reversed = false) const;
  Box edge_box(int edge) const;

  // ── faces (surfaces) ──
  UVBounds face_uv_bounds(int face) const;  // bounds of the trimmed face in its surface's (u,v)
  Vec3 face_point(int face, double u, double v) const;
  SurfDeriv face_eval(int face, double u, double v) const;
  // Unit normal pointing out of the face's solid (face orientation accounted for); at a
  // singular point (pole) the limit normal. Returns {0,0,0} where it is undefined.
  Vec3 face_normal(int face, double u, double v) const;
  Curvature face_curvature(int face, double u, double v) const;
  bool face_reversed(int face) const;  // the face's orientation in its shell is REVERSED
  // Point is inside the trimmed face (or on its boundary within tol).
  bool face_contains_uv(int face, double u, double v, double tol = 1e-9) const;
  // Nearest point of the face's surface (within its natural bounds, not the trimmed face).
  // Without a hint: Newton from the 4 nearest points of a 25x25 grid over face_uv_bounds, or
  // OCCT's global search when that is not closer than the nearest grid point (~3e4 points/s on
  // the wing); with a hint (the (u,v) of a neighbouring node): Newton from it (~1e6 points/s).
  // Meant for points near the face (mesh nodes); a far point may get a local minimum.
  SurfaceProjection project_to_face(int face, const Vec3& p, std::optional<Vec2> hint = {}) const;
  // Nearest point of the face's (u,v) box (face_uv_bounds) found by a local search from `hint`:
  // Newton on the squared distance, a parameter held at the box's side while the gradient
  // points out of it. Never a global search: it finds the minimum next to the hint, which a
  // point just off the face (past its side, or at the layer's offset above it) has. Any result
  // is a point of the surface, so its distance is an upper bound of the distance to the face.
  SurfaceProjection project_to_face_near(int face, const Vec3& p, Vec2 hint) const;
  // Wires of the face, the outer wire first; each edge use with its orientation.
  std::vector<std::vector<EdgeUse>> face_wires(int face) const;
  std::vector<int> face_edges(int face) const;  // distinct edge ids, ascending
  std::vector<int> face_neighbours(int face) const;  // faces sharing an edge, ascending
  double face_area(int face) const;
  double face_area(int face, double rel_tolerance) const;  // adaptive, as volume(rel_tolerance)
  Box face_box(int face) const;
  std::string face_surface_type(int face) const;  // "plane", "bspline", "revolution", ...
  // Periods of the face's surface in u and v (0: not periodic), e.g. {2 pi, 0} for a surface of
  // revolution: a (u,v) and (u + k period, v) are the same point.
  std::array<double, 2> face_periods(int face) const;
  // Periodic parameters along a boundary loop (sweep's and shell's face loops): a and b are a
  // period apart when they differ by more than 3/4 of one (a jump across the seam; a one-division
  // edge or a pole's p-curve may span half a period). unwrap_towards moves x by whole periods
  // towards ref when they are.
  static bool period_jump(double a, double b, double period) { return period > 0 && std::abs(a - b) > 0.75 * period; }
  static double unwrap_towards(double x, double ref, double period) {
    return period_jump(x, ref, period) ? x - period * std::round((x - ref) / period) : x;
  }
  std::string edge_curve_type(int edge) const;    // "line", "circle", "bspline", ...

  Impl& impl() { return *impl_; }
  const Impl& impl() const { return *impl_; }
  explicit Shape(std::unique_ptr<Impl> impl);

 private:
  const UVBounds& seed_box(int face) const;  // face_uv_bounds, cached with the projection seeds
  std::unique_ptr<Impl> impl_;
};

}  // namespace meshflow::cad
