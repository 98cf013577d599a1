// Reading a CAD file (STEP, IGES, BREP) into a cad::Shape, keeping the file's length unit: used
// by the `step` stage and by `meshflow init`.
#include "stages/geometry/import.hpp"

#include "engine/stage.hpp"
#include "stages/cad/occt.hpp"

#include <BRepBuilderAPI_Transform.hxx>
#include <BRepTools.hxx>
#include <BRep_Builder.hxx>
#include <IGESControl_Reader.hxx>
#include <IGESData_GlobalSection.hxx>
#include <IGESData_IGESModel.hxx>
#include <Interface_Static.hxx>
#include <UnitsMethods.hxx>
#include <STEPControl_Reader.hxx>
#include <StepData_StepModel.hxx>
#include <Standard_Failure.hxx>
#include <TColStd_SequenceOfAsciiString.hxx>
#include <gp_Trsf.hxx>

#include <algorithm>
#include <cctype>
#include <fstream>

namespace meshflow::geometry {
namespace fs = std::filesystem;
namespace {
using Log = std::function<void(const std::string&)>;

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

TopoDS_Shape read_step(const fs::path& p, std::string& units, const Log& log) {
  STEPControl_Reader r;
  if (r.ReadFile(p.c_str()) != IFSelect_RetDone)
    throw StageError("cannot read '" + p.string() +
                     "' as STEP: the file is not valid ISO-10303-21 (truncated or another format?); "
                     "export it again from the CAD system, or give a .iges/.brep file");
  TColStd_SequenceOfAsciiString len, ang, sol;
  r.FileUnits(len, ang, sol);
  std::string label = len.IsEmpty() ? "" : label_of_step_unit(len.First().ToCString());
  if (!len.IsEmpty()) log("STEP length unit: " + std::string(len.First().ToCString()));
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

TopoDS_Shape read_iges(const fs::path& p, std::string& units, const Log& log) {
  auto read = [&](IGESControl_Reader& r) {
    if (r.ReadFile(p.c_str()) != IFSelect_RetDone)
      throw StageError("cannot read '" + p.string() + "' as IGES: the file is not valid IGES; export it again");
  };
  int flag = 0;
  {
    IGESControl_Reader probe;
    read(probe);
    flag = probe.IGESModel()->GlobalSection().UnitFlag();
  }
  static const char* by_flag[] = {"", "in", "mm", "", "ft", "mi", "m", "km", "mil", "um", "cm", "uin"};
  units = flag >= 1 && flag <= 11 && *by_flag[flag] ? by_flag[flag] : "mm";
  log("IGES unit flag " + std::to_string(flag) + " -> " + units);
  // Keep the file's unit. OCCT takes its working unit into the model when the file is read, from
  // process-wide settings: set to the file's unit before reading (not after, which the next
  // import in the same process would see: init's preflight read a file in m 1000 times smaller
  // than a run from a fresh process did).
  Interface_Static::SetCVal("xstep.cascade.unit", occt_unit(units));
  UnitsMethods::SetCasCadeLengthUnit(unit_mm(units));
  IGESControl_Reader r;
  read(r);
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

}  // namespace

cad::Shape import_cad(const fs::path& path, const std::string& units_param, double scale, const Log& log) {
  if (!fs::exists(path))
    throw StageError("geometry file '" + path.string() + "' does not exist: fix the path");
  std::string ext = path.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return std::tolower(c); });
  cad::occt::Log occt_log(log);
  std::string units = "mm";
  TopoDS_Shape s;
  try {
    if (ext == ".step" || ext == ".stp")
      s = read_step(path, units, log);
    else if (ext == ".iges" || ext == ".igs")
      s = read_iges(path, units, log);
    else if (ext == ".brep" || ext == ".brp") {
      s = read_brep(path);
      units = units_param.empty() ? "mm" : units_param;  // BREP carries no unit
    } else
      throw StageError("geometry file '" + path.string() + "' has extension '" + ext +
                       "': meshflow reads .step/.stp, .iges/.igs and .brep/.brp");
  } catch (const Standard_Failure& e) {
    throw StageError("reading '" + path.string() + "' failed inside OpenCASCADE: " + e.GetMessageString());
  }
  if (!units_param.empty()) units = units_param;
  if (scale != 1.0) {
    gp_Trsf t;
    t.SetScale(gp_Pnt(0, 0, 0), scale);
    s = BRepBuilderAPI_Transform(s, t, Standard_True).Shape();
  }
  return cad::occt::make_shape(s, units);
}

}  // namespace meshflow::geometry
