// meshflow CAD: registers the "shape" artifact type (file format: see cad.hpp).
#include "engine/artifact_type.hpp"
#include "stages/cad/cad.hpp"
#include "stages/cad/occt.hpp"

#include <nlohmann/json.hpp>

#include <map>

namespace meshflow::cad {

// Summary for golden regression and report.json.
nlohmann::json occt::summarize(const Shape& s, int threads, std::optional<double> volume) {
  nlohmann::json j;
  j["units"] = s.units();
  j["solids"] = s.num_solids();
  j["shells"] = s.num_shells();
  j["faces"] = s.num_faces();
  j["edges"] = s.num_edges();
  j["vertices"] = s.num_vertices();
  j["volume"] = volume ? *volume : s.volume();
  j["area"] = s.area();
  Box b = s.box(threads);
  j["bbox"] = {{"min", {b.lo.x, b.lo.y, b.lo.z}}, {"max", {b.hi.x, b.hi.y, b.hi.z}}};
  std::map<std::string, int> tags;
  for (int f = 0; f < s.num_faces(); ++f) tags[tag_name(s.face_tag(f))]++;
  j["face_tags"] = tags;
  return j;
}

namespace {
ArtifactTypeRegistrar reg({
    .type = "shape",
    .extension = ".mfshape",
    .summary = "B-rep with face tags and units (meshflow-shape 1: JSON header line + OCCT BREP text)",
    .formats = {{"brep", {".brep", "OpenCASCADE BREP (text)",
                          [](const std::filesystem::path& in, const std::filesystem::path& out) {
                            Shape::load(in).export_brep(out);
                          }}},
                {"step", {".step", "STEP AP214 (in the shape's units)",
                          [](const std::filesystem::path& in, const std::filesystem::path& out) {
                            Shape::load(in).export_step(out);
                          }}},
                {"iges", {".igs", "IGES 5.3, BRep mode (in the shape's units)",
                          [](const std::filesystem::path& in, const std::filesystem::path& out) {
                            Shape::load(in).export_iges(out);
                          }}}},
    .summarize = [](const std::filesystem::path& p) { return occt::summarize(Shape::load(p)); },
});
}  // namespace
}  // namespace meshflow::cad
