// meshflow stage kind `tet` (paper §III.D): reads the near-field "mesh" artifact (sweep's),
// fills the far field with TetGen (tet.hpp) and writes the whole linear hybrid mesh.
#include "engine/stage.hpp"
#include "stages/contract/contract.hpp"
#include "stages/io/mesh_io.hpp"
#include "stages/tet/tet.hpp"
#include "stages/tet/tetgen_call.hpp"

#include <nlohmann/json.hpp>

namespace meshflow::tet {
namespace {

Options options_from(const nlohmann::json& p, int threads) {
  Options o;
  o.radius_edge = p.at("radius_edge").get<double>();
  o.min_dihedral = p.at("min_dihedral_deg").get<double>();
  o.max_volume = p.at("max_volume").get<double>();
  o.size_growth = p.at("size_growth").get<double>();
  o.pyramid_height = p.at("pyramid_height").get<double>();
  o.max_steiner = p.at("max_steiner_points").get<int>();
  o.optimisation = p.at("optimisation_level").get<int>();
  o.max_elements = p.at("max_elements").get<long>();
  o.threads = threads;
  return o;
}

void run(StageContext& ctx) {
  Options opt = options_from(ctx.params(), ctx.threads());
  ctx.progress(0, "reading the near-field mesh");
  model::Mesh near;
  try {
    near = io::read_mesh(ctx.input("mesh").path);
  } catch (const io::MeshIOError& e) {
    throw StageError(std::string("tet: cannot read the input mesh: ") + e.what());
  }
  ctx.progress(0.1, "tetrahedralising the far field");
  Report rep;
  model::Mesh out = fill_far_field(near, opt, rep, [&](const std::string& l) { ctx.log(l); });
  ctx.progress(0.9, "writing the mesh");
  io::write_mesh(out, ctx.output("mesh", "mesh"), io::MeshFormat::MshBinary);
  io::write_quality(out, contract::record(ctx, out, contract::Extent::Domain, nullptr),
                    ctx.output("quality", "mesh_quality"));
  nlohmann::json t = rep.to_json();
  t["radius_edge"] = opt.radius_edge;
  t["min_dihedral_deg"] = opt.min_dihedral;
  t["max_volume"] = opt.max_volume;
  t["size_growth"] = opt.size_growth;
  ctx.stats()["tet"] = t;
  ctx.log("tet: " + std::to_string(rep.tets) + " tets, " + std::to_string(rep.pyramids) + " pyramids, " +
          std::to_string(rep.steiner_points) + " Steiner points (none on the boundary), TetGen -" + rep.switches);
  ctx.progress(1, "done");
}

StageRegistrar reg({.kind = "tet",
                    .version = 2,  // 2: also stores the mesh's per-element quality ("quality")
                    .summary = "fill the far field with tetrahedra (TetGen), conforming to the shell; pyramids on quads",
                    .libraries = {std::string("TetGen ") + detail::tetgen_version()},
                    .needs = {"mesh"},
                    .produces = {{"mesh", "mesh"}, {"quality", "mesh_quality"}},
                    .run = run});

}  // namespace
}  // namespace meshflow::tet
