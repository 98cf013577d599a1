// meshflow periodic_match — paper §III.E: the rigid map between the periodic sides of a shape,
// and the pairing of their faces, edges and vertices, so that sweep can mesh the periodic_lo
// side once and copy it onto periodic_hi (nodes matching after the map), and write the MSH
// $Periodic node pairs. This header includes no foreign library (OCCT stays behind cad.hpp;
// Eigen is used in periodic.cpp only).
//
// ── What find() does ───────────────────────────────────────────────────────────────────
// 1. Sides: the faces tagged periodic_lo and periodic_hi (cad::Shape tags), their edges and
//    vertices. An edge or vertex on both sides (e.g. on the rotation axis of a full wedge) is
//    on both lists and must be its own partner.
// 2. Transform: rigid motions are fitted to "features" of the two sides — the vertices and the
//    arc-length midpoints of the non-degenerate edges (both intrinsic: a rigid map carries them
//    onto the partner's). A feature's signature is its sorted distances to the other features
//    of its side; for three non-collinear lo features, every choice of hi features with equal
//    signatures gives a proper rotation R and translation t (Kabsch fit, Eigen SVD, det R = +1),
//    kept when it carries every lo feature onto a distinct hi feature. Each such map is then
//    checked on the faces (below, a few samples per face), including orientation: a periodic
//    map glues the domain, so the fluid side of lo goes to the outside of hi (R n_lo = -n_hi).
//    None left: refused naming the faces and the features that found no partner; more than
//    one: refused listing them ("several candidate transforms"). The surviving map is refitted
//    on all its feature pairs and classified: translation (angle < 1e-9), or rotation about an
//    axis (axis point = the point of the axis nearest the origin). A screw motion (a rotation
//    with a translation along its axis) is refused.
//    Refinement: the features are vertices of intersection curves, accurate to ~1e-7 of the
//    model size, while the periodic surfaces of a good CAD model are exact images; so the map is
//    refined by point-to-plane Gauss-Newton on the paired faces (the images of lo face samples
//    onto the hi surfaces; the features with a small weight hold what the surfaces leave free)
//    and kept when its face mismatch is smaller (Rotor 67: 3.9e-9 -> 2.5e-14 ft).
//    Snapping: a rotation axis within 1e-6 rad of a coordinate axis, an axis point within the
//    tolerance of a coordinate line, an angle within 1e-6 rad of ±2π/N (N ≤ 10000), and
//    translation components below the tolerance are candidates for their exact values; the
//    snapped map is kept only when its face mismatch (points of the lo faces carried to the
//    hi surfaces) is no larger than the refined map's (+1e-13 of the model size). stats/Match
//    report whether it snapped.
// 3. Pairing: every lo face with the hi face on which the images of its sample points lie
//    (projection distance ≤ tol, inside the trimmed hi face, normals opposite) and conversely
//    (hi samples carried back by the inverse land on the lo face): both ways, so a hi face
//    larger or smaller than its partner is refused too. Every lo edge with the hi edge its
//    sampled image lies on (both ways; `reversed` when the hi curve runs against T(lo's));
//    every lo vertex with the hi vertex at its image. Unpaired entities on either side, or an
//    entity with two partners, are refused with a message naming them and the distance found.
//    tol = rel_tol × model_size, model_size = the diagonal of the shape's bounding box.
//    max_mismatch = the largest distance over all those samples (faces, edges, vertices);
//    Match keeps the face/edge/vertex maxima separately too.
//
// ── The "periodic" artifact (extension ".mfper") ───────────────────────────────────────
// One line of JSON, keys sorted (nlohmann; numbers round-trip exactly): deterministic bytes.
//   {"format":"meshflow-periodic 1", "units":"ft",
//    "transform":{"kind":"rotation"|"translation", "axis_point":[x,y,z], "axis_dir":[x,y,z],
//                 "angle":a, "translation":[x,y,z], "affine":[16 numbers, row-major],
//                 "snapped":true|false},
//    "faces":[[lo,hi,reversed]...], "edges":[[lo,hi,reversed]...], "vertices":[[lo,hi,false]...],
//    "model_size":s, "max_mismatch":m, "face_mismatch":..., "edge_mismatch":..., "vertex_mismatch":...}
// (reversed is always false for faces and vertices.)
#pragma once

#include <array>
#include <filesystem>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json_fwd.hpp>

namespace meshflow::cad {
class Shape;
}

namespace meshflow::periodic {

struct Transform {                       // maps periodic_lo onto periodic_hi
  std::string kind;                      // "rotation" | "translation"
  std::array<double, 3> axis_point{}, axis_dir{};  // rotation: axis through axis_point along unit axis_dir
  double angle = 0;                      // rotation (radians, right-handed about axis_dir)
  std::array<double, 3> translation{};   // translation
  std::array<double, 16> affine{};       // row-major 4x4, the same map (MSH $Periodic wants it)
  bool snapped = false;                  // axis/angle/translation snapped to exact values (see above)

  std::array<double, 3> apply(const std::array<double, 3>& p) const;          // affine · p
  std::array<double, 3> apply_inverse(const std::array<double, 3>& p) const;  // its inverse
  std::array<double, 3> apply_vector(const std::array<double, 3>& v) const;   // rotation part only

  // Builds the transform (affine included) from its parameters.
  static Transform rotation(const std::array<double, 3>& axis_point, const std::array<double, 3>& axis_dir, double angle);
  static Transform translation_by(const std::array<double, 3>& t);
};

struct Pair {
  int lo = -1, hi = -1;
  bool reversed = false;  // edges: hi's curve runs against T(lo's)
};

struct Match {
  Transform transform;
  std::vector<Pair> faces, edges, vertices;  // CAD ids, sorted by lo
  double model_size = 0, max_mismatch = 0;   // geometric check of the pairing (sampled points), absolute
  double face_mismatch = 0, edge_mismatch = 0, vertex_mismatch = 0;  // the same, per entity kind
  std::string units;

  // The hi partner of lo entity `lo` of dimension dim (0 vertex, 1 edge, 2 face), or nullptr.
  const Pair* partner(int dim, int lo) const;
  nlohmann::json summary() const;  // golden regression: kind, axis/angle or translation, pair counts, mismatch
};

// Finds the transform and the pairs (see above). Throws StageError (periodic_match: ...) when the
// shape has no periodic tags, the sides do not match (different shape, an entity without a
// partner, several candidate transforms, a screw motion). rel_tol > 0: tolerance relative to the
// model size. `log` (may be empty) receives a few lines (candidates, snapping).
Match find(const cad::Shape& shape, double rel_tol);
Match find(const cad::Shape& shape, double rel_tol, const std::function<void(const std::string&)>& log);

void write(const Match& m, const std::filesystem::path& file);
// Throws StageError naming the file when missing, not a periodic artifact or inconsistent.
Match read(const std::filesystem::path& file);

// ── For sweep: the hi image of a point on a lo entity ─────────────────────────────────────
struct Image {
  std::array<double, 3> point{};  // on the hi partner (projected)
  double t = 0;                   // dim 1: parameter on the hi edge
  double u = 0, v = 0;            // dim 2: parameters on the hi face
  double distance = 0;            // |transform.apply(x) - point| (the residual of the projection)
};
// For a point x on lo entity (dim, lo id): its image on the hi partner and the hi parameters
// (t on an edge, (u,v) on a face), by projecting transform.apply(x) with a hint (a hi parameter
// of a neighbouring node: (t, 0) for an edge, (u, v) for a face). dim 0: the partner vertex's
// point. Throws std::out_of_range when (dim, lo) has no partner.
// Accuracy (Rotor 67, measured in tests/periodic_match): on the faces |T(x) - image| ≤ 4e-16 of
// the radius (the periodic surfaces are exact images); on the edges up to 4e-8 of the radius and
// at the vertices 8e-9: the hi boundary curves are intersection curves computed independently
// of the lo ones (OCCT approximations). Nodes that must match to 1e-12 after the map (MSH
// $Periodic) should therefore be placed at transform.apply(x) on hi edges and vertices, with
// their parameters from image() (off the hi curve by `distance`, within the CAD tolerance). Not thread safe on one
// Shape (projection caches): use one Shape::clone() per thread.
Image image(const cad::Shape& shape, const Match& m, int dim, int lo, const std::array<double, 3>& x,
            std::optional<std::array<double, 2>> hint = {});

}  // namespace meshflow::periodic
