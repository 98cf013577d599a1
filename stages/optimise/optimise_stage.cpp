// The "optimise" stage kind: reads the curved "mesh" and the healed "shape", optimises the
// surface nodes (optimise.hpp), writes the "mesh" and stats.optimise + stats.mesh.
#include "engine/stage.hpp"
#include "stages/cad/cad.hpp"
#include "stages/contract/contract.hpp"
#include "stages/io/mesh_io.hpp"
#include "stages/model/quality.hpp"
#include "stages/optimise/optimise.hpp"
#include "stages/optimise/untangle.hpp"

#include <nlohmann/json.hpp>

#include <cstdlib>
#include <functional>
#include <sstream>

namespace meshflow::optimise {
namespace {

void run(StageContext& ctx) {
  const auto& p = ctx.params();
  Options opt;
  opt.curve_edges = p.value("curve_edges", true);
  opt.surface_edges = p.value("surface_edges", true);
  opt.faces = p.value("faces", true);
  opt.max_iterations = p.value("max_iterations", 200);
  opt.tolerance = p.value("tolerance", 1e-9);
  const std::string vol = p.value("volume", std::string("blend"));
  if (vol == "blend") opt.volume = VolumeMethod::blend;
  else throw StageError("optimise: unknown volume method '" + vol + "' (schemas/optimise.schema.json lists them)");

  ctx.progress(0.0, "reading the mesh and the shape");
  model::Mesh m;
  try {
    m = io::read_mesh(ctx.input("mesh").path);
  } catch (const io::MeshIOError& e) {
    throw StageError(std::string("optimise: cannot read the input mesh: ") + e.what());
  }
  cad::Shape shape = cad::Shape::load(ctx.input("shape").path);
  ctx.progress(0.1, "optimising surface nodes");
  Report r = optimise_mesh(m, shape, opt, ctx.threads());
  UntangleReport ur;
  const bool do_untangle = p.value("untangle", true);
  if (do_untangle) {
    ctx.progress(0.5, "untangling invalid elements");
    UntangleOptions uo;
    uo.max_rings = p.value("untangle_rings", 3);
    uo.surface = p.value("untangle_surface", true);
    std::function<void(const std::string&)> dbg;
    if (std::getenv("MESHFLOW_UNTANGLE_DEBUG")) dbg = [&](const std::string& l) { ctx.log(l); };
    ur = untangle(m, uo, ctx.threads(), dbg, &shape, [&](std::size_t k, std::size_t n) {
      if (k % 10 == 0) ctx.progress(0.5 + 0.2 * double(k) / double(n), "untangling: " + std::to_string(k) + " of " + std::to_string(n) + " invalid elements");
    });
  }
  ctx.progress(0.7, "writing");
  io::write_mesh(m, ctx.output("mesh", "mesh"), io::MeshFormat::MshBinary);
  ctx.progress(0.8, "quality");
  contract::record(ctx, m, contract::Extent::Domain, &shape,
                   "optimise could not repair them: see stats.optimise.untangle; a thinner shell (shell.thickness), a lower "
                   "curve.order or a larger untangle_rings may help");
  ctx.stats()["optimise"] = r.to_json();
  if (do_untangle) ctx.stats()["optimise"]["untangle"] = ur.to_json();
  std::ostringstream s;
  s << "optimise: P=" << r.order << ", " << r.curve_edges << " curve edges, " << r.surface_edges << " surface edges, "
    << r.faces << " faces; energy " << r.energy_before << " -> " << r.energy_after << ", " << r.nodes_moved
    << " nodes moved (max distance to CAD " << r.max_cad_distance << "), invalid " << r.invalid_before << " -> "
    << r.invalid_after << " of " << r.elements_checked << " checked, " << r.backtracked_units << " units backtracked ("
    << r.reverted_units << " reverted)";
  if (r.skipped_inconsistent + r.skipped_seam)
    s << "; skipped " << r.skipped_inconsistent << " units whose parameters do not reproduce their nodes and "
      << r.skipped_seam << " across a seam";
  ctx.log(s.str());
  if (do_untangle) {
    std::ostringstream u;
    u << "optimise: untangle: " << ur.invalid_before << " invalid elements -> " << ur.invalid_after << " (" << ur.repaired
      << " patches repaired in " << ur.attempts << " attempts, " << ur.repaired_sliding << " of them sliding "
      << ur.surface_nodes_moved << " nodes on the CAD; " << ur.nodes_moved << " off-CAD nodes moved, largest move "
      << ur.max_move << " x element size, " << ur.seconds << " s)";
    ctx.log(u.str());
    for (auto t : ur.unresolved) ctx.log("optimise:   still invalid: element " + std::to_string(t));
  }
  ctx.progress(1.0, "done");
}

StageRegistrar reg({.kind = "optimise",
                    .version = 1,
                    .summary = "surface node optimisation: spring energy of high-order edges/faces in CAD parameter space, bounded L-BFGS-B, validity kept",
                    .libraries = {"LBFGSpp 0.1.0"},
                    .run = run});

}  // namespace
}  // namespace meshflow::optimise
