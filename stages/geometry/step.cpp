// meshflow geometry kind `step`: imports a STEP, IGES or BREP file as a "shape" artifact,
// keeping the file's length unit (a STEP in mm stays in mm) unless `scale`/`units` say otherwise.
#include "engine/stage.hpp"
#include "stages/cad/cad.hpp"
#include "stages/cad/tag_rules.hpp"
#include "stages/geometry/import.hpp"

#include <nlohmann/json.hpp>

#include <Standard_Version.hxx>

#include <algorithm>
#include <cmath>
#include <filesystem>

namespace meshflow::geometry {
namespace {
namespace fs = std::filesystem;
using cad::Shape;

void run(StageContext& ctx) {
  const auto& P = ctx.params();
  std::string name = P.at("file").get<std::string>();
  fs::path path = ctx.file(name);
  double scale = P.value("scale", 1.0);
  std::string units_param = P.value("units", "");
  if (!fs::exists(path))
    throw StageError("geometry file '" + path.string() + "' (parameter file: \"" + name +
                     "\") does not exist: fix the path (relative paths are relative to the workflow file)");
  ctx.progress(0.0, "reading " + path.filename().string());
  Shape shape = import_cad(path, units_param, scale, [&](const std::string& m) { ctx.log(m); });
  ctx.progress(0.8, "indexing");
  const std::string units = shape.units();
  int free_edges = 0, small_edges = 0, degenerate = 0;
  cad::Box bb = shape.box(ctx.threads());  // OCCT's optimal box, the faces' in parallel
  double diag = std::hypot(bb.hi.x - bb.lo.x, bb.hi.y - bb.lo.y, bb.hi.z - bb.lo.z);
  double min_len = 1e300;
  for (int e = 0; e < shape.num_edges(); ++e) {
    if (shape.edge_degenerate(e)) {
      ++degenerate;
      continue;
    }
    if (shape.edge_faces(e).size() == 1 && !shape.edge_is_seam(e, shape.edge_faces(e)[0])) ++free_edges;
    double L = shape.edge_length(e);
    min_len = std::min(min_len, L);
    if (L < 1e-6 * diag) ++small_edges;
  }
  auto& st = ctx.stats();
  st["file"] = path.filename().string();
  st["units"] = units;
  st["scale"] = scale;
  st["solids"] = shape.num_solids();
  st["shells"] = shape.num_shells();
  st["faces"] = shape.num_faces();
  st["edges"] = shape.num_edges();
  st["vertices"] = shape.num_vertices();
  st["free_edges"] = free_edges;
  st["small_edges"] = small_edges;
  st["degenerate_edges"] = degenerate;  // collapsed edges (poles, or edges shorter than the vertex tolerance)
  st["multiple_edges"] = (int)shape.multiple_edges().size();
  st["shortest_edge"] = min_len == 1e300 ? 0.0 : min_len;
  st["bbox_diagonal"] = diag;
  if (shape.num_faces() == 0)
    throw StageError("geometry file '" + path.string() + "' holds no faces (only wires or points?): nothing to mesh");
  cad::apply_tag_rules(shape, P.at("tag_overrides"), "step stage '" + ctx.stage_name() + "'");
  shape.save(ctx.output("shape", "shape"));
  ctx.progress(1.0, "done");
}

StageRegistrar reg({.kind = "step",
                    .version = 2,  // 2: IGES read in its own unit whatever an earlier import in the process set
                    .summary = "import a STEP/IGES/BREP file as a shape, keeping its units",
                    .libraries = {"OCCT " OCC_VERSION_COMPLETE},
                    .produces = {{"shape", "shape"}},
                    .run = run});
}  // namespace
}  // namespace meshflow::geometry
