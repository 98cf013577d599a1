// meshflow mesh contract — what every mesh a stage produces must satisfy, checked where it is
// made (DESIGN.md §4-5), and the problems it reports when the mesh breaks it.
//
// Clauses (each one a problem entry when broken):
//   validity    det J > 0 over each whole element (Bezier bounds, stages/model/quality.hpp);
//               an element the bounds leave inconclusive is not a pass. Not blocking: a later
//               stage (optimise) may repair it; the run fails if the mesh is delivered so.
//   degenerate  an element with a zero-length vertex edge (shortest / longest < kMinEdgeRatio),
//               a zero-area face (straight face area / longest edge^2 < kMinAreaRatio) or a
//               zero volume (straight volume / longest edge^3 < kMinVolumeRatio). Such elements
//               can pass the det J check (a prism collapsed along one edge keeps a positive
//               scaled Jacobian) and are inverted by any curving. Blocking.
//   conformity  every interior face shared by exactly two elements with the same face nodes.
//               Blocking.
//   tags        (domain meshes) every boundary face of the volume mesh is a boundary element of
//               an entity with a physical group. Blocking.
//   coverage    the boundary elements close (every edge of theirs used by an even number of
//               them), and (with the CAD) every face of the healed CAD has boundary elements and
//               each group's (wall, farfield, ...) boundary area is its CAD faces' area within the
//               tolerance. Blocking.
//   volume      (domain meshes with the CAD) the volume the mesh's boundary encloses (divergence
//               theorem over the boundary faces, Gauss quadrature exact for the mapping's
//               polynomial degree) equals the CAD fluid volume within the tolerance. Blocking.
// Tolerances of coverage and volume: a linear mesh's facets cut chords of curved faces, so its
// area differs from the CAD's by O(h^2) (3% on the demo's wing at a 30 degree turn angle) and
// more on a narrow rounded face spanned by one or two elements (two chords of a half circle cut
// 10%): kLinearTolerance; a curved mesh follows the CAD to O(h^(P+1)): kCurvedTolerance. A
// small hole is not seen in an area; it is seen by the closure of the boundary elements.
#pragma once

#include "stages/model/mesh.hpp"
#include "stages/model/quality.hpp"

#include <nlohmann/json.hpp>

#include <optional>
#include <string>
#include <vector>

namespace meshflow {
class StageContext;
}
namespace meshflow::cad {
class Shape;
}

namespace meshflow::contract {

inline constexpr double kMinEdgeRatio = 1e-9;
inline constexpr double kMinAreaRatio = 1e-12;
inline constexpr double kMinVolumeRatio = 1e-12;
inline constexpr double kLinearTolerance = 0.1;
inline constexpr double kCurvedTolerance = 1e-2;
inline constexpr int kWhereListed = 10;  // elements or faces named per problem

// Which clauses apply: a near-field mesh (sweep's one layer) has an open, untagged outer
// surface, so tags and volume do not apply to it.
enum class Extent { NearField, Domain };

// The healed CAD's figures the mesh is compared with (plain numbers: the model knows no CAD).
struct CadReference {
  struct Face {
    int entity = 0;     // the mesh's 2D entity tag of the face (CAD face index + 1)
    double area = 0;
    std::string group;  // "wall", "farfield", ... or "" untagged
    bool reliable = true;  // false: the area is not trusted (see cad_reference); not compared
  };
  double volume = 0;
  bool volume_reliable = true;
  std::vector<Face> faces;
  std::string source = "the healed fluid solid";  // what the figures are of, for messages
};

struct Result {
  nlohmann::json mesh;      // model::mesh_stats of the mesh
  nlohmann::json contract;  // the measured figures of each clause and the tolerances
  nlohmann::json problems;  // array of {clause, what, count, blocking, where: [...], hint}
  model::MeshQuality quality;  // model::mesh_quality of the mesh (validity and stats.mesh come from it)
  bool ok() const { return problems.empty(); }
};

// `known`, `moved`: quality known already, taken instead of computed (model::mesh_quality's).
Result check(const model::Mesh& m, Extent extent, const CadReference* cad, int threads,
             const model::MeshQuality* known = nullptr, const std::vector<char>* moved = nullptr);

// The CAD reference of a healed shape (its solids' volume, each face's area and tag). OCCT's
// integrations are not right on every trimmed face: its fixed Gauss rule gives Rotor 67's
// casing 0.2328 ft^2 where the trimmed domain sampled and the mesh give 0.208, and its adaptive
// rule gives the demo's wing 2% less area than both its fixed rule and the order-4 mesh. A
// figure is used only when the two agree to kReferenceAgreement; otherwise it is marked not
// reliable, listed in stats.contract, and not compared (a face must still have elements).
CadReference cad_reference(const cad::Shape& shape, int threads = 1);
inline constexpr double kReferenceAgreement = 1e-3;

// The "cad_reference" artifact: cad_reference of a shape, stored beside it by the stage that
// writes the fluid solid (heal), so that each mesh stage's contract reads it instead of
// integrating every face and the volume again (DLR-F6: 64% of the sweep stage, and the same in
// curve and optimise). JSON; its doubles read back bit for bit. record() takes it from the
// inputs when the stage's shape comes from the stage that wrote it.
void write_cad_reference(const CadReference& ref, const std::filesystem::path& path);
CadReference read_cad_reference(const std::filesystem::path& path);  // throws StageError when unreadable

// The volume the boundary faces of a volume mesh enclose (the volume clause's measure). A stage
// that transforms a domain mesh without the CAD (split) compares its result with its input's.
double enclosed_volume(const model::Mesh& m);

// What a mesh-producing stage calls on the mesh it wrote: stats.mesh, stats.contract and
// stats.problems (the engine reads "problems": see engine/stage.hpp). `hint` is appended to the
// validity problem: what the user can change at this stage. Returns the per-element quality it
// computed, which the stage stores beside its mesh (io::write_quality, the "quality" artifact)
// so that no format writer computes it again.
// `known`, `moved` as for check: what the stage knows of the quality already (computed on its
// way, or its input's stored quality and the nodes it moved since).
model::MeshQuality record(StageContext& ctx, const model::Mesh& m, Extent extent, const cad::Shape* shape,
                          const std::string& hint = {}, const model::MeshQuality* known = nullptr,
                          const std::vector<char>* moved = nullptr);
// The same against a reference given as figures (e.g. only the volume of split's input);
// `known` as for check (split: the blocks it passes through, with its input's stored quality).
model::MeshQuality record_against(StageContext& ctx, const model::Mesh& m, Extent extent, const CadReference& ref,
                                  const std::string& hint = {}, const model::MeshQuality* known = nullptr,
                                  const std::vector<char>* moved = nullptr);

// What the stage knows of its input's quality: the quality the stage that made its "mesh" input
// stored beside it (io::stored_quality), at the input's coordinates, for `known` above. None
// when it stored none, or when it is not m's: logged as "<who>: the input's stored quality is not
// this mesh's (why); computing it".
std::optional<model::MeshQuality> input_quality(StageContext& ctx, const model::Mesh& m, const std::string& who);

}  // namespace meshflow::contract
