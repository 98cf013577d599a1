// meshflow medial object — paper §III.B: the medial object of the fluid domain (and of the
// bodies) from the Delaunay triangulation of dense boundary samples, the local feature size on
// the walls and the "medial halos" where offsets of neighbouring faces collide.
//
// This header includes neither CGAL nor OpenCASCADE: the shell and sweep stages include it to
// read the "medial" artifact. CGAL lives in medial_core.cpp only; the CAD is reached through
// stages/cad/cad.hpp in medial_stage.cpp only.
//
// ── Method ─────────────────────────────────────────────────────────────────────────────
// 1. Sampling (sampling.cpp, over the abstract BoundaryModel so that it is testable on
//    analytic shapes): every face is split in its (u,v) box by a kd-split until each cell's 3D
//    extent along u and along v is below the target spacing h(p) at its centre; one sample per
//    leaf cell inside the trimmed face, at the cell centre moved by a deterministic jitter of at
//    most ±20 % of the cell (a hash of the face and cell: it breaks the co-spherical
//    degeneracies of regular grids without randomness). Edges are split the same way in their
//    parameter, one sample per leaf interval; every CAD vertex is one sample. Edge and vertex
//    samples belong to all their faces and carry the normalised mean of the faces' normals.
//    Target spacing: h = min(base, max_turn / curvature), base = `spacing` × (diagonal of the
//    refined faces' box) on refined faces (walls) and `farfield_spacing` × (diagonal of the
//    whole box) elsewhere, graded away from the walls (h ≤ h_j + grading·|p − p_j| over the
//    nearest wall samples j), never below `min_spacing` × (walls' diagonal).
//    Feature-size refinement: after each pass the medial object is computed and every sample
//    gets t_i = min(h_i, lfs_fraction × lfs_wall_i), lfs_wall being the distance to the nearest
//    medial point that touches a refined face; the next pass samples with h ≤ t_j + grading·d_j
//    over the nearest samples of the previous pass (an ε-sampling in the sense of Amenta et
//    al. with ε = lfs_fraction, where it matters for the walls).
// 2. Delaunay (CGAL Delaunay_triangulation_3, exact predicates): the Voronoi vertices are the
//    circumcentres of the tetrahedra (computed here from the vertices sorted by sample id, so
//    the doubles do not depend on CGAL's internal vertex order; flat tetrahedra, whose centre
//    is undefined, are skipped).
// 3. Poles (Amenta, Choi & Kolluri, "The power crust", 2001): for each sample p with outward
//    normal n (out of the fluid domain), its interior pole is the farthest Voronoi vertex c of
//    its cell with (c − p)·n < 0 (fluid side); its exterior pole the farthest with (c − p)·n > 0
//    (body side; none for samples on the convex hull, whose cell is unbounded).
// 4. Filter. A pole (the centre c of an empty Delaunay ball of radius R through 4 samples,
//    its "contacts") is kept as a medial point when
//      (a) side: every contact q on a face interior sees c on the pole's side of its tangent
//          plane: σ(c − q)·n_q ≥ −0.05 R (σ = −1 fluid, +1 body);
//      (b) object angle: the largest angle ∠(q_a, c, q_b) between two contacts is at least
//          `min_object_angle_deg` (Dey & Zhao's angle condition): the ball touches the boundary
//          at two well-separated places, as a medial ball does. This removes the spurious
//          flat balls of sampling noise and the unstable branches of the medial axis that end
//          at edges with a dihedral angle above 180° − min_object_angle (offsets of such faces
//          do not collide).
//    The radius of a medial point is the distance to the boundary: the ball radius R (the
//    distance to the nearest sample, exact by the empty-ball property) refined down to the
//    distance to the tangent planes of the face contacts whose normal is within 25° of the
//    contact direction (exact for planes, second order for curved faces). The stage then sets
//    it to the exact distance to the contact faces through the CAD interface: the distance to
//    the plane for planar faces, else the foot point found by a damped Newton iteration from the
//    contact sample's (u,v) (accepted when it is within two spacings of the contact, else only
//    if the face classifier says it is inside the trimmed face), never above R.
//    (The stage classifies (u,v) points against each face's wires as uv polygons and calls the
//    exact OCCT classifier only within 4× the polygons' measured chord error of the boundary. On a
//    face with a seam the polygon must classify like OCCT on both sides of its own boundary,
//    else the seam's p-curves are chosen by continuity in (u,v) instead of by the names of the
//    wire's orientations (after heal's unify NekMesh's cylinder face named them the other way
//    round: a bow-tie polygon, half of each junction circle unsampled), else OCCT classifies
//    that face alone; stats.uv_polygons counts them when it happens.)
// 5. Local feature size at every sample: the distance to the nearest medial point (either side).
// 6. Halos: a fluid-side medial ball whose contacts lie on two faces with no face in common
//    (an edge or vertex sample belongs to all its faces) is where the offsets of those faces
//    collide at distance = its radius: concave wall edges (e.g. a wing root) and thin gaps.
//    Each sample whose own interior pole is such a ball records the other face (halo_face).
//
// ── The "medial" artifact (extension ".mfmedial") ───────────────────────────────────────
// Binary, little-endian, deterministic (same input ⇒ same bytes at any thread count):
//   char[8]  "MFMEDIAL"
//   u32      format version (1)
//   u32      header length L, then L bytes of JSON (keys sorted): {"units", "params" (used),
//            "counts": {"samples","medial_points","halos"}, "faces": number of faces,
//            "refined_faces": [ids]}
//   u64      number of samples S, then S records of 132 bytes:
//              f64 x, y, z          point on the boundary
//              f64 nx, ny, nz       unit normal out of the fluid domain
//              f64 u, v             face parameters (face samples), t in u (edge samples)
//              f64 h                sampling spacing used there
//              f64 lfs              local feature size (distance to the nearest medial point)
//              f64 r_in, r_out      radius of the sample's kept interior (fluid) / exterior
//                                   (body) pole, −1 when none
//              i32 kind             0 face interior, 1 edge, 2 CAD vertex
//              i32 id               the face, edge or vertex id
//              i32 faces[3]         faces the sample belongs to, ascending, −1 padded
//              i32 pole_in, pole_out  medial point indices, −1 when none
//              i32 halo_face        the other face touched by the interior pole ball, −1
//              u8  refined          the sample lies on a refined (wall) face
//              u8  pad[3]
//   u64      number of medial points M, then M records of 60 bytes:
//              f64 x, y, z, radius, ball_radius
//              i32 contacts[4]      sample ids, ascending
//              u8  side             0 fluid (interior of the domain), 1 body (exterior)
//              u8  halo             1 when the contacts span two faces with no face in common
//              u8  object_angle_deg rounded, 0..180
//              u8  pad
//   u64      number of halos H, then H records of 24 bytes:
//              i32 medial, sample_a, sample_b, face_a, face_b (face_a < face_b), pad
// Samples are in sampling order (faces by id, then edges, then vertices); medial points are
// sorted by (side, contacts); halos by (face_a, face_b, medial).
//
// ── Reading it (e.g. in the shell stage) ───────────────────────────────────────────────
//   auto m = meshflow::medial::read(ctx.input("medial").path);       // StageError if corrupt
//   for (size_t i = 0; i < m.samples.size(); ++i) {
//     if (!m.samples[i].refined) continue;                            // wall samples
//     double reach = m.info[i].r_in;    // fluid-side medial ball radius tangent here (-1: none)
//     double lfs = m.info[i].lfs;       // distance to the medial object
//     int other = m.info[i].halo_face;  // offsets of this face collide with `other` at r_in
//   }
//   // LFS at any point: nearest wall sample
//   std::vector<Vec3> pts; for (auto& s : m.samples) pts.push_back(s.p);
//   meshflow::medial::NearestIndex near(pts);  auto [i, d] = near.nearest(q, 1)[0];
#pragma once

#include <array>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include <nlohmann/json_fwd.hpp>

namespace meshflow::medial {

using Vec3 = std::array<double, 3>;

struct Sample {
  Vec3 p{}, n{};
  double u = 0, v = 0;
  double h = 0;
  std::int32_t kind = 0, id = -1;
  std::array<std::int32_t, 3> faces{-1, -1, -1};
  bool refined = false;
};

// Per-sample results (same index as the samples).
struct SampleInfo {
  double lfs = -1, r_in = -1, r_out = -1;
  std::int32_t pole_in = -1, pole_out = -1, halo_face = -1;
};

enum class Side : std::uint8_t { fluid = 0, body = 1 };

struct MedialPoint {
  Vec3 c{};
  double radius = 0;       // distance to the boundary (refined)
  double ball_radius = 0;  // empty Delaunay ball radius (distance to the nearest sample)
  std::array<std::int32_t, 4> contacts{};
  Side side = Side::fluid;
  bool halo = false;
  std::uint8_t object_angle_deg = 0;
};

struct Halo {
  std::int32_t medial = -1, sample_a = -1, sample_b = -1, face_a = -1, face_b = -1;
};

struct MedialObject {
  std::string header = "{}";  // the JSON header (text, keys sorted)
  std::vector<Sample> samples;
  std::vector<SampleInfo> info;
  std::vector<MedialPoint> points;
  std::vector<Halo> halos;

  // Largest / median radius etc. used by summaries.
  nlohmann::json summary() const;
};

// Writes / reads the artifact. read() throws meshflow::StageError naming the file when it is
// missing, truncated or not a medial artifact.
void write(const MedialObject& m, const std::filesystem::path& file);
MedialObject read(const std::filesystem::path& file);

// ── core (CGAL) ──────────────────────────────────────────────────────────────────────────
struct CoreOptions {
  double min_object_angle_deg = 60;
};
struct CoreTimes {
  double delaunay = 0, poles = 0, lfs = 0;
};
// Medial points, per-sample LFS, poles and halos from boundary samples (normals out of the
// domain). Throws meshflow::StageError with fewer than 8 distinct samples or a flat set.
// Parallel (oneTBB) in the caller's task arena; the result does not depend on its size.
MedialObject medial_from_samples(std::vector<Sample> samples, const CoreOptions& opt,
                                 CoreTimes* times = nullptr);

// Nearest-point queries (a CGAL kd-tree behind a pimpl).
class NearestIndex {
 public:
  explicit NearestIndex(const std::vector<Vec3>& points);
  ~NearestIndex();
  NearestIndex(NearestIndex&&) noexcept;
  NearestIndex& operator=(NearestIndex&&) noexcept;
  // The k nearest points to q: (index, distance), nearest first (ties by index).
  std::vector<std::pair<std::int32_t, double>> nearest(const Vec3& q, int k) const;
  std::size_t size() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// ── sampling (plain C++, any boundary representation) ────────────────────────────────────
// A closed boundary: faces with a (u,v) parametrisation, edges, vertices. Normals point out of
// the fluid domain. The stage implements it over cad::Shape; tests over analytic shapes.
// The sampling calls its const queries from several threads at once: they must be safe to call
// concurrently (the stage's CadModel classifies through one cad::Shape clone per thread).
class BoundaryModel {
 public:
  virtual ~BoundaryModel() = default;
  virtual int num_faces() const = 0;
  virtual std::array<double, 4> face_bounds(int f) const = 0;  // u0, u1, v0, v1
  virtual Vec3 face_point(int f, double u, double v) const = 0;
  virtual Vec3 face_normal(int f, double u, double v) const = 0;   // {0,0,0} if undefined
  virtual double face_curvature(int f, double u, double v) const = 0;  // max |k|, 0 if none
  virtual bool face_contains(int f, double u, double v) const = 0;
  virtual bool face_refined(int f) const = 0;  // a wall: fine spacing and LFS refinement
  virtual int num_edges() const = 0;
  virtual bool edge_degenerate(int e) const = 0;
  virtual std::array<double, 2> edge_range(int e) const = 0;
  virtual Vec3 edge_point(int e, double t) const = 0;
  virtual Vec3 edge_normal(int e, double t) const = 0;  // mean of the faces' normals, unit
  virtual std::vector<int> edge_faces(int e) const = 0;
  virtual int num_vertices() const = 0;
  virtual Vec3 vertex_point(int v) const = 0;
  virtual Vec3 vertex_normal(int v) const = 0;
  virtual std::vector<int> vertex_faces(int v) const = 0;
};

struct Params {
  double spacing = 0.02;           // × diagonal of the refined faces' box
  double farfield_spacing = 0.05;  // × diagonal of the whole box
  double min_spacing = 0.002;      // × diagonal of the refined faces' box
  double max_turn_deg = 10;        // curvature: spacing ≤ radius of curvature × this angle
  double lfs_fraction = 0.25;      // spacing ≤ this × local feature size near the walls
  double grading = 0.4;            // spacing growth per unit distance
  int passes = 2;                  // sampling passes (1: no feature-size refinement)
  double min_object_angle_deg = 60;
  long max_samples = 3000000;
  static Params from_json(const nlohmann::json& j);  // keys as in schemas/medial.schema.json
  nlohmann::json to_json() const;
};

struct RunReport {
  std::vector<long> samples_per_pass;
  double t_sampling = 0, t_delaunay = 0, t_poles = 0, t_lfs = 0;
};

// Samples `model` with spacing field h(p) (see the method above, one pass).
// `sources`/`source_h`: the graded size sources (may be empty).
std::vector<Sample> sample_boundary(const BoundaryModel& model, const Params& prm,
                                    const std::vector<Vec3>& source_p, const std::vector<double>& source_h);

// The whole method: passes of sampling + core, feature-size refinement in between.
// `progress(fraction, what)` may be empty; it is called from the calling thread only.
// Parallel in the caller's task arena (the stage runs it in one of its thread budget): every
// loop writes per-index slots, reduced in index order, so the bytes do not depend on the threads.
MedialObject compute(const BoundaryModel& model, const Params& prm, RunReport* report = nullptr,
                     const std::function<void(double, const std::string&)>& progress = {});

}  // namespace meshflow::medial
