// meshflow geometry kind `step`: imports a STEP, IGES or BREP file as a "shape" artifact,
// keeping the file's length unit (a STEP in mm stays in mm) unless `scale`/`units` say otherwise.
#include "engine/stage.hpp"
#include "stages/cad/cad.hpp"
#include "stages/cad/occt.hpp"
#include "stages/cad/tag_rules.hpp"

#include <nlohmann/json.hpp>

#include <BRepBuilderAPI_Transform.hxx>
#include <BRepTools.hxx>
#include <BRep_Builder.hxx>
#include <BRep_Tool.hxx>
#include <IGESControl_Reader.hxx>
#include <IGESData_GlobalSection.hxx>
#include <IGESData_IGESModel.hxx>
#include <Interface_Static.hxx>
#include <STEPControl_Reader.hxx>
#include <StepData_StepModel.hxx>
#include <Standard_Failure.hxx>
#include <Standard_Version.hxx>
#include <TColStd_SequenceOfAsciiString.hxx>
#include <TopExp.hxx>
#include <TopExp_Explorer.hxx>
#include <TopoDS.hxx>
#include <gp_Trsf.hxx>

#include <algorithm>
#include <cctype>
#include <filesystem>
#include <fstream>

namespace meshflow::geometry {
namespace {
namespace fs = std::filesystem;
using cad::Shape;

// OCCT's xstep.cascade.unit names <-> meshflow unit labels.
struct UnitName {
  const char* occt;
  const char* label;
  double mm;  // length of the unit in mm
};
constexpr UnitName kUnits[] = {{"MM", "mm", 1},     {"M", "m", 1000},        {"CM", "cm", 10},
                               {"INCH", "in", 25.4}, {"FT", "ft", 304.8},     {"KM", "km", 1e6},
                               {"UM", "um", 1e-3},   {"MIL", "mil", 0.0254}, {"MI", "mi", 1609344},
                               {"UIN", "uin", 2.54e-5}};
double unit_mm(const std::string& label) {
  for (auto& u : kUnits)
    if (label == u.label) return u.mm;
  return 1;
}

std::string label_of_step_unit(std::string n) {
  std::transform(n.begin(), n.end(), n.begin(), [](unsigned char c) { return std::toupper(c); });
  if (n == "MILLIMETRE" || n == "MILLIMETER") return "mm";
  if (n == "METRE" || n == "METER") return "m";
  if (n == "CENTIMETRE" || n == "CENTIMETER") return "cm";
  if (n == "INCH" || n == "IN") return "in";
  if (n == "FOOT" || n == "FT") return "ft";
  for (auto& u : kUnits)
    if (n == u.occt) return u.label;
  return "";
}
const char* occt_unit(const std::string& label) {
  for (auto& u : kUnits)
    if (label == u.label) return u.occt;
  return nullptr;
}

TopoDS_Shape read_step(const fs::path& p, std::string& units, StageContext& ctx) {
  STEPControl_Reader r;
  if (r.ReadFile(p.c_str()) != IFSelect_RetDone)
    throw StageError("cannot read '" + p.string() +
                     "' as STEP: the file is not valid ISO-10303-21 (truncated or another format?); "
                     "export it again from the CAD system, or give a .iges/.brep file");
  TColStd_SequenceOfAsciiString len, ang, sol;
  r.FileUnits(len, ang, sol);
  std::string label = len.IsEmpty() ? "" : label_of_step_unit(len.First().ToCString());
  if (!len.IsEmpty()) ctx.log("STEP length unit: " + std::string(len.First().ToCString()));
  if (label.empty()) label = "mm";
  units = label;
  // Keep the file's unit: make OCCT's working unit the file's unit (no conversion).
  Interface_Static::SetCVal("xstep.cascade.unit", occt_unit(label));
  r.StepModel()->SetLocalLengthUnit(unit_mm(label));
  r.TransferRoots();
  if (r.NbShapes() == 0)
    throw StageError("STEP file '" + p.string() +
                     "' contains no shape that can be transferred (only annotations or an empty assembly?)");
  return r.OneShape();
}

TopoDS_Shape read_iges(const fs::path& p, std::string& units, StageContext& ctx) {
  IGESControl_Reader r;
  if (r.ReadFile(p.c_str()) != IFSelect_RetDone)
    throw StageError("cannot read '" + p.string() + "' as IGES: the file is not valid IGES; export it again");
  int flag = r.IGESModel()->GlobalSection().UnitFlag();
  static const char* by_flag[] = {"", "in", "mm", "", "ft", "mi", "m", "km", "mil", "um", "cm", "uin"};
  units = flag >= 1 && flag <= 11 && *by_flag[flag] ? by_flag[flag] : "mm";
  ctx.log("IGES unit flag " + std::to_string(flag) + " -> " + units);
  Interface_Static::SetCVal("xstep.cascade.unit", occt_unit(units));
  r.TransferRoots();
  if (r.NbShapes() == 0) throw StageError("IGES file '" + p.string() + "' contains no transferable shape");
  return r.OneShape();
}

TopoDS_Shape read_brep(const fs::path& p) {
  TopoDS_Shape s;
  BRep_Builder b;
  std::ifstream in(p, std::ios::binary);
  std::string first;
  while (first.empty() && std::getline(in, first)) {
  }
  if (first.rfind("DBRep_DrawableShape", 0) != 0 && first.rfind("CASCADE Topology", 0) != 0)
    throw StageError("cannot read '" + p.string() +
                     "' as BREP: it is not an OpenCASCADE BREP file (its first line should be 'DBRep_DrawableShape' "
                     "or 'CASCADE Topology V..'); check the file or its extension");
  in.seekg(0);
  try {
    BRepTools::Read(s, in, b);
  } catch (const Standard_Failure& e) {
    throw StageError("cannot read '" + p.string() + "' as BREP: " + e.GetMessageString());
  }
  if (s.IsNull())
    throw StageError("cannot read '" + p.string() +
                     "' as BREP: it is not an OpenCASCADE BREP file (or it is empty/truncated)");
  return s;
}

void run(StageContext& ctx) {
  const auto& P = ctx.params();
  std::string name = P.at("file").get<std::string>();
  fs::path path = ctx.file(name);
  double scale = P.value("scale", 1.0);
  std::string units_param = P.value("units", "");
  if (!fs::exists(path))
    throw StageError("geometry file '" + path.string() + "' (parameter file: \"" + name +
                     "\") does not exist: fix the path (relative paths are relative to the workflow file)");
  std::string ext = path.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return std::tolower(c); });

  cad::occt::Log log([&](const std::string& s) { ctx.log(s); });
  ctx.progress(0.0, "reading " + path.filename().string());
  std::string units = "mm";
  TopoDS_Shape s;
  try {
    if (ext == ".step" || ext == ".stp")
      s = read_step(path, units, ctx);
    else if (ext == ".iges" || ext == ".igs")
      s = read_iges(path, units, ctx);
    else if (ext == ".brep" || ext == ".brp") {
      s = read_brep(path);
      units = units_param.empty() ? "mm" : units_param;  // BREP carries no unit
    } else
      throw StageError("geometry file '" + path.string() + "' has extension '" + ext +
                       "': the step kind reads .step/.stp, .iges/.igs and .brep/.brp");
  } catch (const Standard_Failure& e) {
    throw StageError("reading '" + path.string() + "' failed inside OpenCASCADE: " + e.GetMessageString());
  }
  if (!units_param.empty()) units = units_param;
  if (scale != 1.0) {
    gp_Trsf t;
    t.SetScale(gp_Pnt(0, 0, 0), scale);
    s = BRepBuilderAPI_Transform(s, t, Standard_True).Shape();
  }
  ctx.progress(0.8, "indexing");
  Shape shape = cad::occt::make_shape(s, units);
  int free_edges = 0, small_edges = 0, degenerate = 0;
  cad::Box bb = shape.box();
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
                    .version = 1,
                    .summary = "import a STEP/IGES/BREP file as a shape, keeping its units",
                    .libraries = {"OCCT " OCC_VERSION_COMPLETE},
                    .run = run});
}  // namespace
}  // namespace meshflow::geometry
