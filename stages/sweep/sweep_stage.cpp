// meshflow stage kind `sweep` (paper §III.D): reads the healed shape, the shell and the
// divisions, writes the linear surface + one-layer near-field "mesh" (sweep.hpp).
#include "engine/stage.hpp"
#include "stages/balance/balance.hpp"
#include "stages/cad/cad.hpp"
#include "stages/contract/contract.hpp"
#include "stages/io/mesh_io.hpp"
#include "stages/model/quality.hpp"
#include "stages/periodic_match/periodic.hpp"
#include "stages/shell/shell.hpp"
#include "stages/sweep/sweep.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <optional>

namespace meshflow::sweep {
namespace {

void run(StageContext& ctx) {
  const nlohmann::json& P = ctx.params();
  ctx.progress(0, "reading shape, shell and divisions");
  cad::Shape shape = cad::Shape::load(ctx.input("shape").path);
  shell::ShellData sh = shell::read(ctx.input("shell").path);
  balance::Divisions div = balance::read(ctx.input("divisions").path);
  // optional: a periodic match (needs: [..., periodic_match]) makes the hi sides copies of the lo sides
  std::optional<periodic::Match> match;
  if (auto ps = ctx.inputs_of("periodic"); !ps.empty()) match = periodic::read(ps[0]->path);
  else if (!shape.faces_with_tag(cad::Tag::periodic_hi).empty())
    ctx.log("sweep: the shape has periodic_hi faces but no periodic_match in needs: they are meshed on their own (no $Periodic)");

  // the wall sizing is the divisions' own (balance's parameters), so faces match their edges
  nlohmann::json bp = nlohmann::json::parse(div.params_json);
  double Lref = 1;
  {
    double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (int f : shape.faces_with_tag(cad::Tag::wall)) {
      auto b = shape.face_box(f);
      for (int k = 0; k < 3; ++k) lo[k] = std::min(lo[k], b.lo[k]), hi[k] = std::max(hi[k], b.hi[k]);
    }
    if (!(hi[0] >= lo[0])) throw StageError("sweep: the shape has no wall face; the near field is swept from the walls");
    Lref = std::max({hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]});
  }
  double Lwall = bp.value("sizes_relative_to", std::string("wall_box")) == "wall_box" ? Lref : 1.0;
  Options o;
  o.turn_angle_deg = bp.value("turn_angle_deg", 30.0);
  o.min_size = bp.value("min_size", 0.01) * Lwall;
  o.max_size = bp.value("max_size", 0.1) * Lwall;
  o.farfield_size = P.at("farfield_size").get<double>() * Lref;
  o.grading = P.at("grading").get<double>();
  o.refine_ratio = P.at("refine_ratio").get<double>();
  o.smooth_passes = P.at("smooth_passes").get<int>();
  if (o.farfield_size < o.max_size) o.farfield_size = o.max_size;

  ctx.progress(0.1, "surface meshes and the near field");
  Report rep;
  model::Mesh m = sweep_mesh(shape, sh, div, o, rep, [&](const std::string& l) { ctx.log(l); }, match ? &*match : nullptr);
  ctx.progress(0.85, "checking");
  m.check();
  const auto quality = contract::record(ctx, m, contract::Extent::NearField, &shape);
  const nlohmann::json& ms = ctx.stats()["mesh"];
  if (ms.value("invalid", 0) > 0)
    throw StageError("sweep: " + std::to_string(ms.value("invalid", 0)) + " invalid near-field elements (" +
                     ms.at("invalid_elements").dump() + "); reduce shell.thickness");
  io::write_mesh(m, ctx.output("mesh", "mesh"), io::MeshFormat::MshBinary);
  io::write_quality(m, quality, ctx.output("quality", "mesh_quality"));
  ctx.stats()["sweep"] = rep.to_json();
  ctx.log("sweep: " + std::to_string(rep.prisms) + " prisms, " + std::to_string(rep.hexes) + " junction hexes, " +
          std::to_string(rep.wall_triangles) + " wall triangles, " + std::to_string(rep.boundary_triangles) +
          " other boundary triangles");
  ctx.progress(1, "done");
}

StageRegistrar reg({.kind = "sweep",
                    .version = 10,  // 9: also stores the mesh's per-element quality ("quality"); 10: folded face triangles repaired where they are
                    .summary = "surface meshes of all faces (CDT in the parameter plane) and the one-layer prism/hex near field",
                    .libraries = {},
                    .needs = {"shape", "shell", "divisions"},
                    .reads = {"periodic", "cad_reference"},
                    .produces = {{"mesh", "mesh"}, {"quality", "mesh_quality"}},
                    .run = run});

}  // namespace
}  // namespace meshflow::sweep
