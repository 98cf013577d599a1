// The "split" stage kind: reads a "mesh" artifact, splits its near-field macro elements
// (split.hpp), writes a "mesh" artifact, its per-element quality ("quality", a "mesh_quality")
// and stats.mesh + stats.split.
#include "engine/stage.hpp"
#include "stages/contract/contract.hpp"
#include "stages/io/mesh_io.hpp"
#include "stages/model/quality.hpp"
#include "stages/split/split.hpp"

#include <nlohmann/json.hpp>

#include <optional>
#include <sstream>

namespace meshflow::split {
namespace {

nlohmann::json to_json(const Stats& s) {
  return {{"layers", s.layers},
          {"ratio", s.ratio},
          {"ratio_source", s.ratio_from_first_height ? "first_height" : "ratio"},
          {"order", s.order},
          {"macro", {{"prism", s.macro_prisms}, {"hex_1wall", s.macro_hexes_1wall}, {"hex_2wall", s.macro_hexes_2wall},
                     {"hex_3wall", s.macro_hexes_3wall}}},
          {"sub", {{"prism", s.sub_prisms}, {"hex", s.sub_hexes}}},
          {"passthrough_elements", s.passthrough_elements},
          {"first_layer_height", {{"min", s.first_height_min}, {"max", s.first_height_max}}},
          {"thickness", {{"min", s.thickness_min}, {"max", s.thickness_max}}},
          {"nodes", {{"in", s.nodes_in}, {"out", s.nodes_out}, {"new", s.new_nodes}, {"dropped", s.dropped_nodes}}},
          {"boundary_faces_split", s.boundary_faces_split},
          {"boundary_subfaces", s.boundary_subfaces},
          {"lines_split", s.lines_split},
          {"nodes_without_params", s.nodes_without_params},
          {"periodic_pairs_added", s.periodic_pairs_added}};
}

// The quality of the blocks split passes through unchanged, from the quality the input's stage
// stored beside the mesh (contract::input_quality, read against the input before it is split:
// split consumes it): the contract takes it instead of computing it again (the far-field
// tetrahedra: most of a domain's elements). Other blocks empty.
model::MeshQuality passed_through_quality(std::optional<model::MeshQuality> stored, const Result& r) {
  if (!stored) return {};
  model::MeshQuality known = std::move(*stored);
  for (std::size_t b = 0; b < known.size(); ++b)
    if (b >= r.passed_through.size() || !r.passed_through[b]) model::MeshQuality::value_type().swap(known[b]);
  return known;
}

void run(StageContext& ctx) {
  const auto& p = ctx.params();
  Options opt;
  opt.layers = p.value("layers", 10);
  opt.ratio = p.value("ratio", 1.5);
  if (p.contains("first_height") && !p["first_height"].is_null()) opt.first_height = p["first_height"].get<double>();
  ctx.progress(0.0, "reading the mesh");
  model::Mesh in;
  try {
    in = io::read_mesh(ctx.input("mesh").path);
  } catch (const io::MeshIOError& e) {
    throw StageError(std::string("split: cannot read the input mesh: ") + e.what());
  }
  // Splitting maps sub-elements through their macro element: the domain it fills is the input's.
  contract::CadReference input_volume;
  input_volume.volume = contract::enclosed_volume(in);
  input_volume.source = "the input mesh";
  ctx.progress(0.1, "splitting");
  auto stored = contract::input_quality(ctx, in, "split");
  Result r = split_mesh(std::move(in), opt, ctx.threads());  // releases the input's nodes as it goes
  const model::MeshQuality known = passed_through_quality(std::move(stored), r);
  in = model::Mesh();  // not needed any more: the writer and the contract hold the split mesh alone
  ctx.progress(0.6, "writing");
  io::write_mesh(r.mesh, ctx.output("mesh", "mesh"), io::MeshFormat::MshBinary);
  ctx.progress(0.7, "quality");
  // The contract's per-element quality is stored with the mesh: the VTU writer reads it.
  io::write_quality(r.mesh, contract::record_against(ctx, r.mesh, contract::Extent::Domain, input_volume, {}, &known),
                    ctx.output("quality", "mesh_quality"));
  ctx.stats()["split"] = to_json(r.stats);
  std::ostringstream s;
  s << "split: " << r.stats.macro_prisms << " macro prisms, "
    << r.stats.macro_hexes_1wall + r.stats.macro_hexes_2wall + r.stats.macro_hexes_3wall << " macro hexes -> "
    << r.stats.sub_prisms << " prisms, " << r.stats.sub_hexes << " hexes (" << r.stats.layers << " layers, ratio "
    << r.stats.ratio << (r.stats.ratio_from_first_height ? " from first_height" : "") << "), first layer "
    << r.stats.first_height_min << ".." << r.stats.first_height_max;
  ctx.log(s.str());
  ctx.progress(1.0, "done");
}

StageRegistrar reg({.kind = "split",
                    .version = 2,  // 2: also stores the mesh's per-element quality ("quality")
                    .summary = "isoparametric boundary-layer splitting of near-field prisms/hexes into `layers` sub-elements with geometric growth",
                    .needs = {"mesh"},
                    .reads = {"mesh_quality"},
                    .produces = {{"mesh", "mesh"}, {"quality", "mesh_quality"}},
                    .run = run});

}  // namespace
}  // namespace meshflow::split
