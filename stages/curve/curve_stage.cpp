// The "curve" stage kind: reads the linear hybrid "mesh" (tet's) and the healed "shape", writes
// the order-P "mesh" (curve.hpp) with stats.mesh (model::mesh_stats) and stats.curve.
#include "engine/stage.hpp"
#include "stages/cad/cad.hpp"
#include "stages/contract/contract.hpp"
#include "stages/curve/curve.hpp"
#include "stages/io/mesh_io.hpp"
#include "stages/model/quality.hpp"

#include <nlohmann/json.hpp>

namespace meshflow::curve {
namespace {

void run(StageContext& ctx) {
  const auto& p = ctx.params();
  Options opt;
  opt.order = p.value("order", 4);
  opt.follow_wall = p.value("follow_wall", true);
  opt.equalise_arc_length = p.value("equalise_arc_length", true);
  opt.threads = ctx.threads();
  ctx.progress(0.0, "reading the mesh and the shape");
  model::Mesh in;
  try {
    in = io::read_mesh(ctx.input("mesh").path);
  } catch (const io::MeshIOError& e) {
    throw StageError(std::string("curve: cannot read the input mesh: ") + e.what());
  }
  cad::Shape shape = cad::Shape::load(ctx.input("shape").path);
  ctx.progress(0.1, "placing high-order nodes");
  Report rep;
  model::Mesh out = curve_mesh(in, shape, opt, rep, [&](const std::string& l) { ctx.log(l); });
  ctx.progress(0.8, "writing");
  io::write_mesh(out, ctx.output("mesh", "mesh"), io::MeshFormat::MshBinary);
  ctx.progress(0.9, "statistics");
  const auto quality = contract::record(ctx, out, contract::Extent::Domain, &shape,
                   "curving inverted them; optimise (untangle: true) repairs such elements, or a thinner shell / lower order avoids them",
                   rep.quality.empty() ? nullptr : &rep.quality);
  model::MeshQuality().swap(rep.quality);
  io::write_quality(out, quality, ctx.output("quality", "mesh_quality"));
  ctx.stats()["curve"] = rep.to_json();
  ctx.progress(1.0, "done");
}

StageRegistrar reg({.kind = "curve",
                    .version = 3,  // 3: also stores the mesh's per-element quality ("quality")
                    .summary = "order-P mesh on the CAD, bottom-up: CAD curves, CAD surfaces in (u,v), the boundary layer following the curved wall, blended interiors",
                    .needs = {"mesh", "shape"},
                    .reads = {"cad_reference"},
                    .produces = {{"mesh", "mesh"}, {"quality", "mesh_quality"}},
                    .run = run});

}  // namespace
}  // namespace meshflow::curve
