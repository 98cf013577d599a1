// The "optimise" stage kind: reads the curved "mesh" and the healed "shape", optimises the
// surface nodes (optimise.hpp), writes the "mesh" and stats.optimise + stats.mesh.
#include "engine/stage.hpp"
#include "stages/cad/cad.hpp"
#include "stages/contract/contract.hpp"
#include "stages/io/mesh_io.hpp"
#include "stages/model/quality.hpp"
#include "stages/optimise/linearise.hpp"
#include "stages/optimise/optimise.hpp"
#include "stages/optimise/untangle.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <functional>
#include <sstream>

namespace meshflow::optimise {
namespace {

std::string duration(double s) {
  char b[64];
  if (s < 60) std::snprintf(b, sizeof b, "%.0f s", s);
  else std::snprintf(b, sizeof b, "%d min %02d s", int(s / 60), int(s) % 60);
  return b;
}

void log_linearised(StageContext& ctx, const LineariseReport& lr) {
  std::ostringstream s;
  s << "optimise: linearise: " << lr.invalid_before << " invalid elements -> " << lr.invalid_after << "; " << lr.regions
    << " regions of " << lr.elements << " elements took back curvature (" << lr.straight_elements << " made straight), "
    << lr.cad_nodes_moved << " boundary nodes moved off the CAD by at most " << lr.max_cad_move << " ("
    << lr.max_cad_move_relative << " x the element's edge); " << lr.seconds << " s";
  for (const auto& [why, n] : lr.unrepaired_by_reason) s << "; " << n << " not linearised: " << why;
  ctx.log(s.str());
  if (lr.cad_nodes_moved)
    ctx.log("optimise: warning: " + std::to_string(lr.cad_nodes_moved) +
            " high-order nodes of boundary faces no longer lie on the CAD (stats.optimise.linearise); "
            "a thinner shell or a lower curve.order keeps them on it, linearise_invalid: false refuses instead");
}

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
  // the quality the input's stage stored, at the input's coordinates: every pass below computes
  // only the elements whose nodes moved since
  const model::MeshQuality known = contract::input_quality(ctx, m, "optimise").value_or(model::MeshQuality());
  const std::vector<double> x0 = known.empty() ? std::vector<double>() : m.x;
  const std::vector<double> y0 = known.empty() ? std::vector<double>() : m.y;
  const std::vector<double> z0 = known.empty() ? std::vector<double>() : m.z;
  auto moved_since_input = [&] { return known.empty() ? std::vector<char>() : model::moved_nodes(m, x0, y0, z0); };
  ctx.progress(0.1, "optimising surface nodes");
  Report r = optimise_mesh(m, shape, opt, ctx.threads());
  UntangleReport ur;
  const bool do_untangle = p.value("untangle", true);
  if (do_untangle) {
    ctx.progress(0.5, "untangling invalid elements");
    UntangleOptions uo;
    uo.max_rings = p.value("untangle_rings", 3);
    uo.surface = p.value("untangle_surface", true);
    uo.lift = p.value("untangle_lift", true);
    uo.element_budget = 1e6 * p.value("untangle_element_budget", 200.0);
    uo.stage_budget = 1e6 * p.value("untangle_budget", 40.0);
    uo.time_limit = p.value("untangle_time_limit", 1800.0);
    const std::vector<char> moved = moved_since_input();
    if (!known.empty()) uo.known_quality = &known, uo.moved_since_known = &moved;
    std::function<void(const std::string&)> dbg;
    if (std::getenv("MESHFLOW_UNTANGLE_DEBUG")) dbg = [&](const std::string& l) { ctx.log(l); };
    ur = untangle(m, uo, ctx.threads(), dbg, &shape, [&](const UntangleProgress& g) {
      ctx.progress(0.5 + 0.2 * double(g.visited) / double(std::max<std::size_t>(g.total, 1)),
                   "untangling: " + std::to_string(g.repaired) + " of " + std::to_string(g.total) + " repaired (" +
                       std::to_string(g.visited) + " tried), " + duration(g.seconds));
    });
  }
  // the quality after untangling, computed once: linearise starts from it, and the mesh
  // contract's record copies it for every element linearise did not move
  const std::vector<char> untangled = moved_since_input();
  const model::MeshQuality quality_now =
      model::mesh_quality(m, ctx.threads(), known.empty() ? nullptr : &known, known.empty() ? nullptr : &untangled);
  // the last resort for what is still invalid (linearise.hpp): as little of its curvature taken back as makes it valid
  LineariseReport lr;
  std::vector<char> linearised;
  const bool do_linearise = p.at("linearise_invalid").get<bool>();
  if (do_linearise) {
    ctx.progress(0.65, "linearising the elements still invalid");
    LineariseOptions lo;
    lo.known_quality = &quality_now;
    lr = linearise_invalid(m, lo, ctx.threads(), &linearised);
    if (lr.invalid_before) log_linearised(ctx, lr);
  }
  ctx.progress(0.7, "writing");
  io::write_mesh(m, ctx.output("mesh", "mesh"), io::MeshFormat::MshBinary);
  ctx.progress(0.8, "quality");
  const auto quality = contract::record(ctx, m, contract::Extent::Domain, &shape,
                   do_untangle ? "optimise could not repair them: stats.optimise.untangle.unrepaired lists them with the "
                                 "reason and what to change (a thinner shell, a lower curve.order, larger untangle_rings or budgets); "
                                 "stats.optimise.linearise says why linearising them failed"
                               : "untangling is off (optimise.untangle: false): turn it on to repair them",
                   &quality_now, linearised.empty() ? nullptr : &linearised);
  io::write_quality(m, quality, ctx.output("quality", "mesh_quality"));
  ctx.stats()["optimise"] = r.to_json();
  if (do_untangle) ctx.stats()["optimise"]["untangle"] = ur.to_json();
  if (do_linearise && lr.invalid_before) ctx.stats()["optimise"]["linearise"] = lr.to_json();
  std::ostringstream s;
  s << "optimise: P=" << r.order << ", " << r.curve_edges << " curve edges, " << r.surface_edges << " surface edges, "
    << r.faces << " faces; energy " << r.energy_before << " -> " << r.energy_after << ", " << r.nodes_moved
    << " nodes moved (max distance to CAD " << r.max_cad_distance << "), invalid " << r.invalid_before << " -> "
    << r.invalid_after << " of " << r.elements_checked << " checked, " << r.backtracked_units << " units backtracked ("
    << r.reverted_units << " reverted, " << r.quality_backtracked_units << " for quality alone)";
  if (r.elements_checked) s << "; min scaled Jacobian of the checked elements " << r.min_sj_before << " -> " << r.min_sj_after;
  if (r.skipped_inconsistent + r.skipped_seam)
    s << "; skipped " << r.skipped_inconsistent << " units whose parameters do not reproduce their nodes and "
      << r.skipped_seam << " across a seam";
  ctx.log(s.str());
  if (do_untangle) {
    std::ostringstream u;
    u << "optimise: untangle: " << ur.invalid_before << " invalid elements -> " << ur.invalid_after << " (" << ur.repaired
      << " patches repaired in " << ur.attempts << " attempts, " << ur.repaired_sliding << " of them sliding "
      << ur.surface_nodes_moved << " nodes on the CAD; " << ur.folded_wall << " with a folded wall face slid first; " << ur.nodes_moved << " off-CAD nodes moved, largest move "
      << ur.max_move << " x element size; work " << ur.work / 1e6 << " M Jacobian samples, at most " << ur.max_element_work / 1e6
      << " M for one element; " << ur.seconds << " s)";
    ctx.log(u.str());
    if (ur.invalid_after) {
      std::ostringstream w;
      w << "optimise: untangle could not repair " << ur.invalid_after << " elements (";
      bool first = true;
      for (const auto& [why, n] : ur.unrepaired_by_reason) w << (first ? "" : ", ") << n << " " << why, first = false;
      w << ")";
      if (ur.budget_exhausted) w << "; " << ur.budget_exhausted << " gave up on untangle_element_budget";
      if (ur.stage_budget_exhausted) w << "; untangle_budget of work passed without a repair (no progress): the rest were not tried";
      if (ur.time_limit_fired) w << "; the safety-net untangle_time_limit fired (this result depends on the machine's speed)";
      ctx.log(w.str());
      for (const auto& e : ur.unrepaired) {
        char line[256];
        std::snprintf(line, sizeof line, "optimise:   element %llu at (%.6g, %.6g, %.6g): %s", (unsigned long long)e.tag, e.centroid[0],
                      e.centroid[1], e.centroid[2], e.reason.c_str());
        ctx.log(line);
      }
      if (ur.unrepaired.size() < ur.invalid_after)
        ctx.log("optimise:   ... and " + std::to_string(ur.invalid_after - ur.unrepaired.size()) + " more (stats.optimise.untangle.unrepaired)");
      ctx.log("optimise: what to change: " + ur.advice());
    }
  }
  ctx.progress(1.0, "done");
}

StageRegistrar reg({.kind = "optimise",
                    .version = 8,  // 5: also stores the mesh's per-element quality ("quality"); 6: a folded wall face slides first; 7: the lift; 8: linearise_invalid
                    .summary = "surface node optimisation: spring energy of high-order edges/faces in CAD parameter space, bounded L-BFGS-B, validity kept",
                    .libraries = {"LBFGSpp 0.1.0"},
                    .needs = {"mesh", "shape"},
                    .reads = {"mesh_quality", "cad_reference"},
                    .produces = {{"mesh", "mesh"}, {"quality", "mesh_quality"}},
                    .run = run});

}  // namespace
}  // namespace meshflow::optimise
