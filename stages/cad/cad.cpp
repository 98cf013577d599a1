// meshflow CAD interface: cad::Shape over an OCCT B-rep (see cad.hpp).
#include "stages/cad/cad.hpp"

#include "engine/stage.hpp"
#include "stages/cad/occt.hpp"

#include <nlohmann/json.hpp>

#include <BRepAdaptor_Curve.hxx>
#include <BRepBndLib.hxx>
#include <BRepCheck_Analyzer.hxx>
#include <BRepClass_FaceClassifier.hxx>
#include <BRepExtrema_DistShapeShape.hxx>
#include <BRepGProp.hxx>
#include <BRepBuilderAPI_MakeVertex.hxx>
#include <BRepTools.hxx>
#include <BRepTools_WireExplorer.hxx>
#include <BRep_Builder.hxx>
#include <BRep_Tool.hxx>
#include <Bnd_Box.hxx>
#include <GCPnts_AbscissaPoint.hxx>
#include <GProp_GProps.hxx>
#include <GeomAdaptor_Curve.hxx>
#include <GeomAdaptor_Surface.hxx>
#include <GeomLProp_SLProps.hxx>
#include <Geom2d_Curve.hxx>
#include <Geom_Plane.hxx>
#include <Geom_RectangularTrimmedSurface.hxx>
#include <Message.hxx>
#include <IGESControl_Controller.hxx>
#include <IGESControl_Writer.hxx>
#include <IGESData_GlobalSection.hxx>
#include <IGESData_IGESModel.hxx>
#include <Message_PrinterOStream.hxx>
#include <APIHeaderSection_MakeHeader.hxx>
#include <STEPControl_Writer.hxx>
#include <StepBasic_Product.hxx>
#include <Interface_InterfaceModel.hxx>
#include <TCollection_HAsciiString.hxx>
#include <StepData_StepModel.hxx>
#include <Interface_Static.hxx>
#include <ShapeAnalysis_Curve.hxx>
#include <TopExp.hxx>
#include <TopExp_Explorer.hxx>
#include <TopoDS_Iterator.hxx>
#include <TopoDS_Wire.hxx>
#include <TopoDS_Vertex.hxx>

#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <ctime>
#include <fstream>
#include <mutex>
#include <set>
#include <sstream>
#include <stdexcept>

namespace meshflow::cad {

// ───────────────────────────── tags ─────────────────────────────
const char* tag_name(Tag t) {
  switch (t) {
    case Tag::none: return "none";
    case Tag::wall: return "wall";
    case Tag::farfield: return "farfield";
    case Tag::symmetry: return "symmetry";
    case Tag::periodic_lo: return "periodic_lo";
    case Tag::periodic_hi: return "periodic_hi";
  }
  return "none";
}

Tag tag_from_name(const std::string& n) {
  for (Tag t : {Tag::none, Tag::wall, Tag::farfield, Tag::symmetry, Tag::periodic_lo, Tag::periodic_hi})
    if (n == tag_name(t)) return t;
  throw std::invalid_argument("unknown face tag '" + n +
                              "' (expected none, wall, farfield, symmetry, periodic_lo or periodic_hi)");
}

// ───────────────────────────── Impl ─────────────────────────────
void Shape::Impl::index() {
  solids.Clear(); shells.Clear(); faces.Clear(); edges.Clear(); vertices.Clear(); edge_faces.Clear();
  TopExp::MapShapes(shape, TopAbs_SOLID, solids);
  TopExp::MapShapes(shape, TopAbs_SHELL, shells);
  TopExp::MapShapes(shape, TopAbs_FACE, faces);
  TopExp::MapShapes(shape, TopAbs_EDGE, edges);
  TopExp::MapShapes(shape, TopAbs_VERTEX, vertices);
  TopExp::MapShapesAndUniqueAncestors(shape, TopAbs_EDGE, TopAbs_FACE, edge_faces);
  tags.assign(faces.Extent(), Tag::none);
  surfaces.resize(faces.Extent());
  for (int i = 0; i < faces.Extent(); ++i) surfaces[i] = BRep_Tool::Surface(TopoDS::Face(faces(i + 1)));
  curves.resize(edges.Extent());
  ranges.resize(edges.Extent());
  for (int i = 0; i < edges.Extent(); ++i) {
    const TopoDS_Edge& e = TopoDS::Edge(edges(i + 1));
    double f = 0, l = 0;
    BRep_Tool::Range(e, f, l);
    ranges[i] = {f, l};
    if (!BRep_Tool::Degenerated(e)) curves[i] = BRep_Tool::Curve(e, f, l);
  }
  face_proj.assign(faces.Extent(), {});
  face_seeds.assign(faces.Extent(), {});
  face_class.clear();
  face_class.resize(faces.Extent());
}

const TopoDS_Face& Shape::Impl::face(int i) const {
  if (i < 0 || i >= faces.Extent()) throw std::out_of_range("cad: face id " + std::to_string(i) + " out of range");
  return TopoDS::Face(faces(i + 1));
}
const TopoDS_Edge& Shape::Impl::edge(int i) const {
  if (i < 0 || i >= edges.Extent()) throw std::out_of_range("cad: edge id " + std::to_string(i) + " out of range");
  return TopoDS::Edge(edges(i + 1));
}

// ───────────────────────────── Shape basics ─────────────────────────────
Shape::Shape() : impl_(std::make_unique<Impl>()) {}
Shape::~Shape() = default;
Shape::Shape(Shape&&) noexcept = default;
Shape& Shape::operator=(Shape&&) noexcept = default;
Shape::Shape(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}

Shape Shape::clone() const {
  auto c = std::make_unique<Impl>();
  c->shape = impl_->shape;
  c->units = impl_->units;
  c->solids = impl_->solids; c->shells = impl_->shells; c->faces = impl_->faces;
  c->edges = impl_->edges; c->vertices = impl_->vertices; c->edge_faces = impl_->edge_faces;
  c->tags = impl_->tags; c->surfaces = impl_->surfaces; c->curves = impl_->curves; c->ranges = impl_->ranges;
  c->face_proj.assign(impl_->faces.Extent(), {});
  c->face_seeds.assign(impl_->faces.Extent(), {});
  c->face_class.resize(impl_->faces.Extent());
  return Shape(std::move(c));
}

namespace {
const char* kMagic = "meshflow-shape 1";

std::string brep_text_raw(const TopoDS_Shape& s) {
  std::ostringstream os;
  BRepTools::Write(s, os, Standard_False, Standard_False, TopTools_FormatVersion_VERSION_1);
  return os.str();
}
// Canonical BREP text: written, read back and written again, so that transient state of the
// in-memory shape (BRepCheck's "checked" flags, signed zeros of recomputed directions) does not
// reach the bytes. Reading then writing a canonical text gives the same text (tested).
std::string brep_text(const TopoDS_Shape& s) {
  std::istringstream is(brep_text_raw(s));
  TopoDS_Shape r;
  BRep_Builder b;
  BRepTools::Read(r, is, b);
  return brep_text_raw(r);
}
}  // namespace

Shape Shape::load(const std::filesystem::path& path) {
  occt::silence();
  std::ifstream in(path, std::ios::binary);
  if (!in)
    throw StageError("cannot open the shape artifact '" + path.string() +
                     "': the file is missing or unreadable (re-run the stage that produces it)");
  std::string magic, header;
  std::getline(in, magic);
  std::getline(in, header);
  if (magic != kMagic)
    throw StageError("'" + path.string() + "' is not a meshflow shape artifact (first line is not '" + kMagic +
                     "'): it is corrupt or of another type; re-run the stage that produces it");
  nlohmann::json h;
  try {
    h = nlohmann::json::parse(header);
  } catch (const std::exception& e) {
    throw StageError("shape artifact '" + path.string() + "': its header line is not valid JSON (" + e.what() +
                     "): the file is corrupt; re-run the stage that produces it");
  }
  auto impl = std::make_unique<Impl>();
  BRep_Builder b;
  try {
    BRepTools::Read(impl->shape, in, b);
  } catch (const Standard_Failure& e) {
    throw StageError("shape artifact '" + path.string() + "': its B-rep cannot be read (" +
                     std::string(e.GetMessageString()) + "): the file is corrupt; re-run the stage that produces it");
  }
  if (impl->shape.IsNull())
    throw StageError("shape artifact '" + path.string() +
                     "': the B-rep part is empty or corrupt; re-run the stage that produces it");
  impl->index();
  impl->units = h.value("units", "mm");
  auto tags = h.value("face_tags", nlohmann::json::array());
  if (!tags.is_array() || (int)tags.size() != impl->faces.Extent())
    throw StageError("shape artifact '" + path.string() + "': it lists " + std::to_string(tags.size()) +
                     " face tags for " + std::to_string(impl->faces.Extent()) +
                     " faces: the file is corrupt; re-run the stage that produces it");
  try {
    for (size_t i = 0; i < tags.size(); ++i) impl->tags[i] = tag_from_name(tags[i].get<std::string>());
  } catch (const std::exception& e) {
    throw StageError("shape artifact '" + path.string() + "': " + e.what());
  }
  return Shape(std::move(impl));
}

void Shape::save(const std::filesystem::path& path) const {
  nlohmann::json h;
  h["units"] = impl_->units;
  auto tags = nlohmann::json::array();
  for (Tag t : impl_->tags) tags.push_back(tag_name(t));
  h["face_tags"] = tags;
  h["counts"] = {{"solids", num_solids()}, {"shells", num_shells()}, {"faces", num_faces()},
                 {"edges", num_edges()}, {"vertices", num_vertices()}};
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  if (!out) throw StageError("cannot write the shape artifact '" + path.string() + "'");
  out << kMagic << "\n" << h.dump() << "\n" << brep_text(impl_->shape);
  if (!out) throw StageError("writing the shape artifact '" + path.string() + "' failed (disk full?)");
}

void Shape::export_brep(const std::filesystem::path& file) const {
  std::ofstream out(file, std::ios::binary | std::ios::trunc);
  out << brep_text(impl_->shape);
  if (!out) throw StageError("writing '" + file.string() + "' failed");
}

namespace {
// The time written into STEP and IGES headers, formatted by strftime's `format`:
// $SOURCE_DATE_EPOCH (seconds, the reproducible-builds convention) when set, else the epoch
// itself. Never the wall clock: two runs of one workflow write byte-identical files.
std::string header_time(const char* format) {
  long long t = 0;
  if (const char* e = std::getenv("SOURCE_DATE_EPOCH"); e && *e) {
    char* end = nullptr;
    long long v = std::strtoll(e, &end, 10);
    if (end && *end == '\0' && v >= 0) t = v;
  }
  std::time_t tt = std::time_t(t);
  std::tm tm{};
  gmtime_r(&tt, &tm);
  char buf[32];
  std::strftime(buf, sizeof buf, format, &tm);
  return buf;
}
}  // namespace

namespace {
// OCCT names each product "Open CASCADE STEP translator 7.6 N", N counting the shapes this process
// has written: the same shape would give another file in a matrix run. One fixed name instead.
void name_products(const Handle(Interface_InterfaceModel)& model) {
  for (Standard_Integer i = 1; i <= model->NbEntities(); ++i)
    if (Handle(StepBasic_Product) p = Handle(StepBasic_Product)::DownCast(model->Value(i)); !p.IsNull()) {
      p->SetId(new TCollection_HAsciiString("meshflow"));
      p->SetName(new TCollection_HAsciiString("meshflow"));
    }
}
}  // namespace

// OpenCASCADE's data exchange (STEP, IGES) keeps its parameters in one process-wide table
// (Interface_Static) that each writer sets: two writers at once race on it. The runner writes an
// output's formats in parallel threads, so a shape's STEP and IGES files are written one at a
// time. (A test run writing a shape's brep, step and iges at once ended once with SIGSEGV under
// load, after its stages and before its report: this race is the likely cause, not a proven one.)
static std::mutex& data_exchange_mutex() {
  static std::mutex m;
  return m;
}

void Shape::export_step(const std::filesystem::path& file) const {
  std::lock_guard<std::mutex> lock(data_exchange_mutex());
  occt::silence();
  const std::string& un = impl_->units;
  double mm = un == "m" ? 1000 : un == "cm" ? 10 : un == "in" ? 25.4 : un == "ft" ? 304.8 : 1;
  const char* u = un == "m" ? "M" : un == "cm" ? "CM" : un == "in" ? "INCH" : un == "ft" ? "FT" : "MM";
  STEPControl_Writer w;  // (initialises the STEP statics: set them after)
  Interface_Static::SetCVal("xstep.cascade.unit", u);
  Interface_Static::SetCVal("write.step.unit", u);
  Interface_Static::SetCVal("write.step.schema", "AP214IS");
  // the shape's coordinates are in its own unit, and so is the file: no conversion
  w.Model()->SetLocalLengthUnit(mm);
  w.Model()->SetWriteLengthUnit(mm);
  if (w.Transfer(impl_->shape, STEPControl_AsIs) != IFSelect_RetDone)
    throw StageError("writing the STEP file '" + file.string() + "' failed");
  name_products(w.Model());
  APIHeaderSection_MakeHeader header(w.Model());
  header.SetTimeStamp(new TCollection_HAsciiString(header_time("%Y-%m-%dT%H:%M:%S").c_str()));
  if (w.Write(file.c_str()) != IFSelect_RetDone) throw StageError("writing the STEP file '" + file.string() + "' failed");
}

void Shape::export_iges(const std::filesystem::path& file) const {
  std::lock_guard<std::mutex> lock(data_exchange_mutex());
  occt::silence();
  const std::string& un = impl_->units;
  const char* u = un == "m" ? "M" : un == "cm" ? "CM" : un == "in" ? "IN" : un == "ft" ? "FT" : "MM";
  IGESControl_Controller::Init();
  // the shape's coordinates are in its own unit, and so is the file: no conversion
  Interface_Static::SetCVal("xstep.cascade.unit", u);
  IGESControl_Writer w(u, 1);  // mode 1: BRep (manifold solids with faces and edges), not trimmed surfaces
  if (!w.AddShape(impl_->shape)) throw StageError("writing the IGES file '" + file.string() + "' failed");
  IGESData_GlobalSection& header = w.Model()->ChangeGlobalSection();
  Handle(TCollection_HAsciiString) date = new TCollection_HAsciiString(header_time("%Y%m%d.%H%M%S").c_str());
  header.SetDate(date);
  header.SetLastChangeDate(date);
  header.SetAuthorName(new TCollection_HAsciiString("meshflow"));  // not the login name: same file for every user
  if (!w.Write(file.c_str())) throw StageError("writing the IGES file '" + file.string() + "' failed");
}

const std::string& Shape::units() const { return impl_->units; }
int Shape::num_solids() const { return impl_->solids.Extent(); }
int Shape::num_shells() const { return impl_->shells.Extent(); }
int Shape::num_faces() const { return impl_->faces.Extent(); }
int Shape::num_edges() const { return impl_->edges.Extent(); }
int Shape::num_vertices() const { return impl_->vertices.Extent(); }

Tag Shape::face_tag(int f) const {
  impl_->face(f);
  return impl_->tags[f];
}
void Shape::set_face_tag(int f, Tag t) {
  impl_->face(f);
  impl_->tags[f] = t;
}
std::vector<int> Shape::faces_with_tag(Tag t) const {
  std::vector<int> r;
  for (int i = 0; i < num_faces(); ++i)
    if (impl_->tags[i] == t) r.push_back(i);
  return r;
}

namespace {
Box to_box(const Bnd_Box& b) {
  if (b.IsVoid()) return {};
  double x0, y0, z0, x1, y1, z1;
  b.Get(x0, y0, z0, x1, y1, z1);
  return {{x0, y0, z0}, {x1, y1, z1}};
}
Box box_of(const TopoDS_Shape& s) {
  Bnd_Box b;
  BRepBndLib::AddOptimal(s, b, Standard_False, Standard_False);
  return to_box(b);
}
}  // namespace

// BRepBndLib::AddOptimal of a shape adds each face's box (TopExp_Explorer over the faces), then
// the boxes of the edges outside faces and of the vertices outside edges. Where there are none
// (a solid, a closed shell), the union of the faces' own AddOptimal boxes, taken in parallel,
// is the same box: a union is a min and a max per coordinate, exact in any order. DLR-F6's
// healed solid: 0.72 s on one thread (the optimal box of a B-spline face is an optimisation).
Box Shape::box(int threads) const {
  if (threads <= 1 || TopExp_Explorer(impl_->shape, TopAbs_EDGE, TopAbs_FACE).More() ||
      TopExp_Explorer(impl_->shape, TopAbs_VERTEX, TopAbs_EDGE).More())
    return box_of(impl_->shape);
  const int nf = impl_->faces.Extent();
  std::vector<Bnd_Box> fb(static_cast<std::size_t>(nf));
  tbb::task_arena(threads).execute([&] {
    tbb::parallel_for(0, nf, [&](int f) { BRepBndLib::AddOptimal(impl_->faces(f + 1), fb[std::size_t(f)], Standard_False, Standard_False); });
  });
  Bnd_Box b;
  for (const Bnd_Box& x : fb) b.Add(x);
  return to_box(b);
}
double Shape::volume() const {
  double v = 0;
  for (int i = 1; i <= impl_->solids.Extent(); ++i) {
    GProp_GProps g;
    BRepGProp::VolumeProperties(impl_->solids(i), g);
    v += g.Mass();
  }
  return v;
}
double Shape::area() const {
  GProp_GProps g;
  BRepGProp::SurfaceProperties(impl_->shape, g);
  return g.Mass();
}

bool Shape::valid() const {
  BRepCheck_Analyzer a(impl_->shape);
  return a.IsValid();
}
std::vector<int> Shape::free_edges() const {
  std::vector<int> r;
  for (int e = 0; e < num_edges(); ++e) {
    if (edge_degenerate(e)) continue;
    auto f = edge_faces(e);
    if (f.size() == 1 && !edge_is_seam(e, f[0])) r.push_back(e);
  }
  return r;
}
std::vector<int> Shape::multiple_edges() const {
  std::vector<int> r;
  for (int e = 0; e < num_edges(); ++e)
    if (edge_faces(e).size() > 2) r.push_back(e);
  return r;
}

// ───────────────────────────── vertices ─────────────────────────────
Vec3 Shape::vertex_point(int v) const {
  if (v < 0 || v >= num_vertices()) throw std::out_of_range("cad: vertex id out of range");
  return occt::vec(BRep_Tool::Pnt(TopoDS::Vertex(impl_->vertices(v + 1))));
}
double Shape::vertex_tolerance(int v) const {
  if (v < 0 || v >= num_vertices()) throw std::out_of_range("cad: vertex id out of range");
  return BRep_Tool::Tolerance(TopoDS::Vertex(impl_->vertices(v + 1)));
}

// ───────────────────────────── edges ─────────────────────────────
bool Shape::edge_degenerate(int e) const { return BRep_Tool::Degenerated(impl_->edge(e)); }
Range Shape::edge_range(int e) const {
  impl_->edge(e);
  return impl_->ranges[e];
}
Vec3 Shape::edge_point(int e, double t) const {
  const auto& c = impl_->curves[(impl_->edge(e), e)];
  if (c.IsNull()) return vertex_point(edge_vertices(e)[0]);
  return occt::vec(c->Value(t));
}
CurveDeriv Shape::edge_eval(int e, double t) const {
  const auto& c = impl_->curves[(impl_->edge(e), e)];
  CurveDeriv d;
  if (c.IsNull()) {
    d.p = vertex_point(edge_vertices(e)[0]);
    return d;
  }
  gp_Pnt p;
  gp_Vec v1, v2;
  c->D2(t, p, v1, v2);
  d.p = occt::vec(p); d.d1 = occt::vec(v1); d.d2 = occt::vec(v2);
  return d;
}
double Shape::edge_length(int e) const {
  auto r = edge_range(e);
  return edge_length(e, r.lo, r.hi);
}
double Shape::edge_length(int e, double t0, double t1) const {
  const auto& c = impl_->curves[(impl_->edge(e), e)];
  if (c.IsNull()) return 0;
  GeomAdaptor_Curve a(c);
  return GCPnts_AbscissaPoint::Length(a, std::min(t0, t1), std::max(t0, t1));
}
std::array<int, 2> Shape::edge_vertices(int e) const {
  const TopoDS_Edge& ed = impl_->edge(e);
  TopoDS_Vertex v0, v1;
  TopExp::Vertices(TopoDS::Edge(ed.Oriented(TopAbs_FORWARD)), v0, v1);
  return {v0.IsNull() ? -1 : impl_->vertices.FindIndex(v0) - 1, v1.IsNull() ? -1 : impl_->vertices.FindIndex(v1) - 1};
}
std::vector<int> Shape::edge_faces(int e) const {
  const TopoDS_Edge& ed = impl_->edge(e);
  std::vector<int> r;
  if (const TopTools_ListOfShape* l = impl_->edge_faces.Seek(ed))
    for (const auto& f : *l) r.push_back(impl_->faces.FindIndex(f) - 1);
  std::sort(r.begin(), r.end());
  r.erase(std::unique(r.begin(), r.end()), r.end());
  return r;
}
bool Shape::edge_is_seam(int e, int f) const { return BRep_Tool::IsClosed(impl_->edge(e), impl_->face(f)); }

CurveProjection Shape::project_to_edge(int e, const Vec3& p, std::optional<double> hint) const {
  const auto& c = impl_->curves[(impl_->edge(e), e)];
  auto r = impl_->ranges[e];
  CurveProjection res;
  if (c.IsNull()) {
    res.t = r.lo;
    res.point = edge_point(e, r.lo);
  } else {
    ShapeAnalysis_Curve sac;
    gp_Pnt proj;
    double t = 0;
    GeomAdaptor_Curve a(c, r.lo, r.hi);
    if (hint)
      sac.NextProject(*hint, c, occt::pnt(p), 1e-12, proj, t, r.lo, r.hi, Standard_False);
    else
      sac.Project(a, occt::pnt(p), 1e-12, proj, t, Standard_False);
    res.t = t;
    res.point = occt::vec(proj);
  }
  res.distance = std::sqrt((p.x - res.point.x) * (p.x - res.point.x) + (p.y - res.point.y) * (p.y - res.point.y) +
                           (p.z - res.point.z) * (p.z - res.point.z));
  return res;
}

Vec2 Shape::edge_uv(int e, int f, double t, bool reversed) const {
  TopoDS_Edge ed = TopoDS::Edge(impl_->edge(e).Oriented(reversed ? TopAbs_REVERSED : TopAbs_FORWARD));
  TopoDS_Face fa = TopoDS::Face(impl_->face(f).Oriented(TopAbs_FORWARD));
  double a = 0, b = 0;
  Handle(Geom2d_Curve) pc = BRep_Tool::CurveOnSurface(ed, fa, a, b);
  if (pc.IsNull())
    throw std::invalid_argument("cad: edge " + std::to_string(e) + " is not on face " + std::to_string(f));
  gp_Pnt2d uv = pc->Value(t);
  return {uv.X(), uv.Y()};
}
Box Shape::edge_box(int e) const { return box_of(impl_->edge(e)); }

// ───────────────────────────── faces ─────────────────────────────
UVBounds Shape::face_uv_bounds(int f) const {
  UVBounds b;
  BRepTools::UVBounds(impl_->face(f), b.u0, b.u1, b.v0, b.v1);
  return b;
}
Vec3 Shape::face_point(int f, double u, double v) const {
  impl_->face(f);
  return occt::vec(impl_->surfaces[f]->Value(u, v));
}
SurfDeriv Shape::face_eval(int f, double u, double v) const {
  impl_->face(f);
  gp_Pnt p;
  gp_Vec du, dv, duu, dvv, duv;
  impl_->surfaces[f]->D2(u, v, p, du, dv, duu, dvv, duv);
  return {occt::vec(p), occt::vec(du), occt::vec(dv), occt::vec(duu), occt::vec(duv), occt::vec(dvv)};
}
bool Shape::face_reversed(int f) const { return impl_->face(f).Orientation() == TopAbs_REVERSED; }
Vec3 Shape::face_normal(int f, double u, double v) const {
  bool rev = face_reversed(f);
  GeomLProp_SLProps props(impl_->surfaces[f], u, v, 1, 1e-12);
  if (!props.IsNormalDefined()) return {};
  gp_Dir n = props.Normal();
  if (rev) n.Reverse();
  return {n.X(), n.Y(), n.Z()};
}
Curvature Shape::face_curvature(int f, double u, double v) const {
  bool rev = face_reversed(f);
  GeomLProp_SLProps props(impl_->surfaces[f], u, v, 2, 1e-12);
  Curvature c;
  if (!props.IsCurvatureDefined()) return c;
  c.defined = true;
  double s = rev ? -1 : 1;
  double kmax = props.MaxCurvature() * s, kmin = props.MinCurvature() * s;
  gp_Dir dmax, dmin;
  props.CurvatureDirections(dmax, dmin);
  if (kmax >= kmin) {
    c.k1 = kmax; c.k2 = kmin; c.dir1 = {dmax.X(), dmax.Y(), dmax.Z()}; c.dir2 = {dmin.X(), dmin.Y(), dmin.Z()};
  } else {
    c.k1 = kmin; c.k2 = kmax; c.dir1 = {dmin.X(), dmin.Y(), dmin.Z()}; c.dir2 = {dmax.X(), dmax.Y(), dmax.Z()};
  }
  c.mean = props.MeanCurvature() * s;
  c.gauss = props.GaussianCurvature();
  return c;
}
// OCCT's own fast path (as its solid classifier uses): BRepTopAdaptor_FClass2d, built once per face
// and tolerance, classifies against a polygon of the face's boundary in (u,v) and hands every
// point within the polygon's deflection band of it to the exact BRepClass_FaceClassifier, which
// intersects a ray with each edge's p-curve (the wing's shell spent 56% of its time there, one
// classifier per call). Without re-framing on periods, as the exact classifier alone.
bool Shape::face_contains_uv(int f, double u, double v, double tol) const {
  const TopoDS_Face& face = impl_->face(f);
  if (impl_->face_class.size() != std::size_t(impl_->faces.Extent())) impl_->face_class.resize(impl_->faces.Extent());
  auto& c = impl_->face_class[std::size_t(f)][tol];
  if (!c) c = std::make_unique<BRepTopAdaptor_FClass2d>(face, tol);
  const TopAbs_State st = c->Perform(gp_Pnt2d(u, v), Standard_False);
  return st == TopAbs_IN || st == TopAbs_ON;
}

// The face's (u,v) box (face_uv_bounds), computed once per face and shape copy.
const UVBounds& Shape::seed_box(int f) const {
  auto& box = impl_->face_seeds[f].box;
  if (!box) box = face_uv_bounds(f);
  return *box;
}

SurfaceProjection Shape::project_to_face(int f, const Vec3& p, std::optional<Vec2> hint) const {
  impl_->face(f);
  auto& sas = impl_->face_proj[f];
  const auto& surf = impl_->surfaces[f];
  if (sas.IsNull()) sas = new ShapeAnalysis_Surface(surf);
  gp_Pnt P = occt::pnt(p);
  gp_Pnt2d uv;
  if (hint) {
    uv = sas->NextValueOfUV(gp_Pnt2d(hint->u, hint->v), P, 1e-12);
  } else {
    // Start Newton from the nearest point of a grid over the face; fall back to OCCT's global
    // search (Extrema) when that does not improve on the grid point.
    auto& sd = impl_->face_seeds[f];
    if (sd.p.empty()) {
      const UVBounds& b = seed_box(f);
      const int n = 24;
      for (int i = 0; i <= n; ++i)
        for (int j = 0; j <= n; ++j) {
          double u = b.u0 + (b.u1 - b.u0) * i / n, v = b.v0 + (b.v1 - b.v0) * j / n;
          sd.u.push_back(u);
          sd.v.push_back(v);
          sd.p.push_back(surf->Value(u, v));
        }
    }
    // Newton from the 4 nearest grid points (two sheets of a surface can be close, e.g. the
    // two sides of a sharp trailing edge), the best result wins.
    std::vector<std::pair<double, size_t>> near;
    near.reserve(sd.p.size());
    for (size_t k = 0; k < sd.p.size(); ++k) near.push_back({sd.p[k].SquareDistance(P), k});
    std::partial_sort(near.begin(), near.begin() + 4, near.end());
    double bd = 1e300;
    for (int k = 0; k < 4; ++k) {
      gp_Pnt2d c = sas->NextValueOfUV(gp_Pnt2d(sd.u[near[k].second], sd.v[near[k].second]), P, 1e-12);
      double d = surf->Value(c.X(), c.Y()).SquareDistance(P);
      if (d < bd) bd = d, uv = c;
    }
    if (bd > near[0].first * (1 + 1e-12)) uv = sas->ValueOfUV(P, 1e-12);
  }
  SurfaceProjection r;
  r.u = uv.X();
  r.v = uv.Y();
  gp_Pnt q = surf->Value(r.u, r.v);
  r.point = occt::vec(q);
  r.distance = q.Distance(P);
  return r;
}

// OCCT has no bounded local search for this: ShapeAnalysis_Surface::NextValueOfUV falls back to
// its global search whenever Newton leaves the surface's bounds (a point past a face's side:
// the wing's shell clearance spent 0.85 s in it, an Extrema_GenExtPS grid built per call on
// extruded surfaces), and Extrema_GenLocateExtPS is unbounded (BFGS) or stops at a bound
// without a root. This is the textbook projected Newton for min |S(u,v) - p|^2 on a box.
SurfaceProjection Shape::project_to_face_near(int f, const Vec3& p, Vec2 hint) const {
  impl_->face(f);
  const UVBounds& box = seed_box(f);
  const auto& surf = impl_->surfaces[f];
  const gp_Pnt P = occt::pnt(p);
  double u = std::clamp(hint.u, box.u0, box.u1), v = std::clamp(hint.v, box.v0, box.v1);
  gp_Pnt S;
  gp_Vec Su, Sv, Suu, Svv, Suv;
  surf->D2(u, v, S, Su, Sv, Suu, Svv, Suv);
  double f0 = S.SquareDistance(P);
  const double tol = 1e-12 * (1 + gp_Vec(P.XYZ()).Magnitude());  // 3D step length
  for (int it = 0; it < 50; ++it) {
    const gp_Vec r(P, S);  // S - P
    const double gu = r.Dot(Su), gv = r.Dot(Sv);
    double huu = Su.Dot(Su) + r.Dot(Suu), hvv = Sv.Dot(Sv) + r.Dot(Svv), huv = Su.Dot(Sv) + r.Dot(Suv);
    if (!(huu > 0 && hvv > 0 && huu * hvv - huv * huv > 0))  // not convex here: Gauss-Newton
      huu = Su.Dot(Su), hvv = Sv.Dot(Sv), huv = Su.Dot(Sv);
    // a parameter at its side of the box with the gradient pointing out stays there
    const bool fu = (u <= box.u0 && gu > 0) || (u >= box.u1 && gu < 0);
    const bool fv = (v <= box.v0 && gv > 0) || (v >= box.v1 && gv < 0);
    double du = 0, dv = 0;
    if (fu && fv) break;
    if (fu) {
      if (!(hvv > 0)) break;
      dv = -gv / hvv;
    } else if (fv) {
      if (!(huu > 0)) break;
      du = -gu / huu;
    } else {
      const double det = huu * hvv - huv * huv;
      if (!(det > 0)) break;
      du = (-gu * hvv + gv * huv) / det;
      dv = (-gv * huu + gu * huv) / det;
    }
    // halve the step until the clamped point is nearer (at most 30 halvings)
    bool moved = false;
    for (int h = 0; h < 30; ++h) {
      const double un = std::clamp(u + du, box.u0, box.u1), vn = std::clamp(v + dv, box.v0, box.v1);
      const gp_Pnt Sn = surf->Value(un, vn);
      const double fn = Sn.SquareDistance(P);
      if (fn <= f0) {
        const double step = Sn.Distance(S);
        u = un, v = vn, f0 = fn, moved = step > tol;
        surf->D2(u, v, S, Su, Sv, Suu, Svv, Suv);
        break;
      }
      du *= 0.5, dv *= 0.5;
    }
    if (!moved) break;
  }
  SurfaceProjection r;
  r.u = u;
  r.v = v;
  r.point = occt::vec(S);
  r.distance = S.Distance(P);
  return r;
}

namespace {

// One edge use of a wire with its p-curve's ends on the face, in the direction of use.
struct WireUse {
  TopoDS_Edge edge;  // oriented as in the wire
  gp_Pnt2d start, end;
};

std::vector<WireUse> wire_occurrences(const TopoDS_Wire& w, const TopoDS_Face& fa) {
  std::vector<WireUse> r;
  for (TopoDS_Iterator it(w); it.More(); it.Next()) {
    TopoDS_Edge e = TopoDS::Edge(it.Value());
    double a = 0, b = 0;
    Handle(Geom2d_Curve) pc = BRep_Tool::CurveOnSurface(e, fa, a, b);
    WireUse u{e, {}, {}};
    if (!pc.IsNull()) u.start = pc->Value(a), u.end = pc->Value(b);
    if (e.Orientation() == TopAbs_REVERSED) std::swap(u.start, u.end);
    r.push_back(u);
  }
  return r;
}

// The occurrences chained end to start in the parameter plane: from the first, each next use
// is the unused one whose p-curve starts nearest the current one's end (the first such in the
// wire's own order on ties).
std::vector<WireUse> chain_in_uv(std::vector<WireUse> occ) {
  std::vector<WireUse> r;
  if (occ.empty()) return r;
  std::vector<char> used(occ.size(), 0);
  std::size_t cur = 0;
  for (std::size_t n = 0; n < occ.size(); ++n) {
    used[cur] = 1;
    r.push_back(occ[cur]);
    std::size_t best = occ.size();
    double bd = INFINITY;
    for (std::size_t k = 0; k < occ.size(); ++k)
      if (!used[k] && occ[k].start.Distance(occ[cur].end) < bd) bd = occ[k].start.Distance(occ[cur].end), best = k;
    if (best == occ.size()) break;
    cur = best;
  }
  return r;
}

}  // namespace

// BRepTools_WireExplorer follows the wire through its vertices. Where one vertex is shared by
// more than two uses (a torus face: two seams, each used twice, all four ends at one vertex) or
// a degenerate edge closes the loop (a sphere's north pole), it returns an edge twice in the
// same orientation or a pole edge in the wrong one (corpus torus: e0 e1 e0 e1 for the wire
// e0 e1r e0r e1; sphere: the north pole's degenerate edge forward for reversed), and the loop
// no longer closes in the parameter plane. The explorer's order is kept when it uses every
// occurrence of the wire once with its orientation; otherwise the occurrences are chained by
// their p-curves' ends in the parameter plane.
std::vector<std::vector<EdgeUse>> Shape::face_wires(int f) const {
  TopoDS_Face fa = TopoDS::Face(impl_->face(f).Oriented(TopAbs_FORWARD));
  TopoDS_Wire outer = BRepTools::OuterWire(fa);
  std::vector<TopoDS_Wire> wires;
  if (!outer.IsNull()) wires.push_back(outer);
  for (TopoDS_Iterator it(fa); it.More(); it.Next())
    if (it.Value().ShapeType() == TopAbs_WIRE && !it.Value().IsSame(outer)) wires.push_back(TopoDS::Wire(it.Value()));
  std::vector<std::vector<EdgeUse>> r;
  auto index = [&](const TopoDS_Edge& e) { return impl_->edges.FindIndex(e) - 1; };
  for (const auto& w : wires) {
    std::vector<EdgeUse> uses;
    for (BRepTools_WireExplorer ex(w, fa); ex.More(); ex.Next())
      uses.push_back({index(ex.Current()), ex.Orientation() == TopAbs_REVERSED});
    std::vector<WireUse> occ = wire_occurrences(w, fa);
    std::multiset<std::pair<int, bool>> want, got;
    for (auto& o : occ) want.insert({index(o.edge), o.edge.Orientation() == TopAbs_REVERSED});
    for (auto& u : uses) got.insert({u.edge, u.reversed});
    if (got != want) {
      uses.clear();
      for (auto& o : chain_in_uv(occ)) uses.push_back({index(o.edge), o.edge.Orientation() == TopAbs_REVERSED});
    }
    r.push_back(std::move(uses));
  }
  return r;
}
std::vector<int> Shape::face_edges(int f) const {
  std::set<int> s;
  for (TopExp_Explorer ex(impl_->face(f), TopAbs_EDGE); ex.More(); ex.Next()) s.insert(impl_->edges.FindIndex(ex.Current()) - 1);
  return {s.begin(), s.end()};
}
std::vector<int> Shape::face_neighbours(int f) const {
  std::set<int> s;
  for (int e : face_edges(f))
    for (int g : edge_faces(e))
      if (g != f) s.insert(g);
  return {s.begin(), s.end()};
}
double Shape::face_area(int f) const {
  GProp_GProps g;
  BRepGProp::SurfaceProperties(impl_->face(f), g);
  return g.Mass();
}
// OCCT's adaptive integration (the Eps overloads). Neither it nor the fixed Gauss rule of the
// plain overloads is right on every trimmed face: the fixed rule gives Rotor 67's casing (a
// surface of revolution trimmed by B-spline edges, 0.208 ft^2 by sampling its trimmed
// parameter domain and by the mesh) 0.233, the adaptive one the demo's wing 2% too little.
// stages/contract uses a figure only where the two agree.
double Shape::face_area(int f, double rel_tolerance) const {
  GProp_GProps g;
  BRepGProp::SurfaceProperties(impl_->face(f), g, rel_tolerance);
  return g.Mass();
}
double Shape::volume(double rel_tolerance) const {
  double v = 0;
  for (int i = 1; i <= impl_->solids.Extent(); ++i) {
    GProp_GProps g;
    BRepGProp::VolumeProperties(impl_->solids(i), g, rel_tolerance);
    v += g.Mass();
  }
  return v;
}
Box Shape::face_box(int f) const { return box_of(impl_->face(f)); }

std::string Shape::face_surface_type(int f) const {
  impl_->face(f);
  static const char* names[] = {"plane", "cylinder", "cone", "sphere", "torus", "bezier", "bspline",
                                "revolution", "extrusion", "offset", "other"};
  GeomAdaptor_Surface a(impl_->surfaces[f]);
  int t = (int)a.GetType();
  return t >= 0 && t < 11 ? names[t] : "other";
}
std::array<double, 2> Shape::face_periods(int f) const {
  impl_->face(f);
  const auto& S = impl_->surfaces[f];
  return {S->IsUPeriodic() ? S->UPeriod() : 0.0, S->IsVPeriodic() ? S->VPeriod() : 0.0};
}
std::string Shape::edge_curve_type(int e) const {
  const auto& c = impl_->curves[(impl_->edge(e), e)];
  if (c.IsNull()) return "degenerate";
  static const char* names[] = {"line", "circle", "ellipse", "hyperbola", "parabola", "bezier", "bspline", "offset", "other"};
  GeomAdaptor_Curve a(c);
  int t = (int)a.GetType();
  return t >= 0 && t < 9 ? names[t] : "other";
}

// ───────────────────────────── occt helpers ─────────────────────────────
namespace occt {

Shape make_shape(const TopoDS_Shape& s, const std::string& units, std::vector<Tag> tags) {
  BRepTools::Clean(s);
  auto impl = std::make_unique<Shape::Impl>();
  impl->shape = s;
  impl->units = units;
  impl->index();
  if (!tags.empty()) {
    if ((int)tags.size() != impl->faces.Extent())
      throw std::logic_error("cad::occt::make_shape: " + std::to_string(tags.size()) + " tags for " +
                             std::to_string(impl->faces.Extent()) + " faces");
    impl->tags = std::move(tags);
  }
  return Shape(std::move(impl));
}

gp_Pnt interior_point(const TopoDS_Face& f) {
  double u0, u1, v0, v1;
  BRepTools::UVBounds(f, u0, u1, v0, v1);
  Handle(Geom_Surface) s = BRep_Tool::Surface(f);
  // Search a grid of growing resolution for a point classified IN, nearest to the centre.
  for (int n : {2, 4, 8, 16, 32, 64}) {
    double best = 1e300;
    gp_Pnt2d bestp;
    bool found = false;
    for (int i = 1; i < n; ++i)
      for (int j = 1; j < n; ++j) {
        double u = u0 + (u1 - u0) * i / n, v = v0 + (v1 - v0) * j / n;
        BRepClass_FaceClassifier cl(f, gp_Pnt2d(u, v), 1e-9);
        if (cl.State() != TopAbs_IN) continue;
        double d = std::abs(i - n / 2.0) + std::abs(j - n / 2.0);
        if (d < best) best = d, bestp = gp_Pnt2d(u, v), found = true;
      }
    if (found) return s->Value(bestp.X(), bestp.Y());
  }
  return s->Value(0.5 * (u0 + u1), 0.5 * (v0 + v1));
}

std::vector<Tag> transfer_tags(const Shape& from, const TopoDS_Shape& to, double tol) {
  TopTools_IndexedMapOfShape faces;
  TopExp::MapShapes(to, TopAbs_FACE, faces);
  std::vector<Tag> r(faces.Extent(), Tag::none);
  std::vector<Box> boxes;
  for (int j = 0; j < from.num_faces(); ++j) boxes.push_back(from.face_box(j));
  for (int i = 1; i <= faces.Extent(); ++i) {
    gp_Pnt p = interior_point(TopoDS::Face(faces(i)));
    TopoDS_Vertex v = BRepBuilderAPI_MakeVertex(p);
    double best = tol;
    for (int j = 0; j < from.num_faces(); ++j) {
      const Box& b = boxes[j];
      if (p.X() < b.lo.x - tol || p.X() > b.hi.x + tol || p.Y() < b.lo.y - tol || p.Y() > b.hi.y + tol ||
          p.Z() < b.lo.z - tol || p.Z() > b.hi.z + tol)
        continue;
      BRepExtrema_DistShapeShape d(v, from.impl().face(j));
      if (d.IsDone() && d.Value() <= best) {
        best = d.Value();
        r[i - 1] = from.face_tag(j);
      }
    }
  }
  return r;
}

std::vector<Tag> tags_by_box(const TopoDS_Shape& s, double tol) {
  TopTools_IndexedMapOfShape faces;
  TopExp::MapShapes(s, TopAbs_FACE, faces);
  Box bb = box_of(s);
  std::vector<char> on_box(faces.Extent(), 0);
  for (int i = 1; i <= faces.Extent(); ++i) {
    Handle(Geom_Surface) g = BRep_Tool::Surface(TopoDS::Face(faces(i)));
    if (auto tr = Handle(Geom_RectangularTrimmedSurface)::DownCast(g)) g = tr->BasisSurface();
    auto pl = Handle(Geom_Plane)::DownCast(g);
    if (pl.IsNull()) continue;
    gp_Dir d = pl->Position().Direction();
    gp_Pnt o = pl->Location();
    double oc[3] = {o.X(), o.Y(), o.Z()}, dc[3] = {d.X(), d.Y(), d.Z()};
    for (int k = 0; k < 3; ++k) {
      if (std::abs(std::abs(dc[k]) - 1) > 1e-12) continue;
      if (std::abs(oc[k] - bb.lo[k]) <= tol || std::abs(oc[k] - bb.hi[k]) <= tol) on_box[i - 1] = 1;
    }
  }
  TopTools_IndexedDataMapOfShapeListOfShape ef;
  TopExp::MapShapesAndUniqueAncestors(s, TopAbs_EDGE, TopAbs_FACE, ef);
  std::vector<Tag> tags(faces.Extent(), Tag::wall);
  for (int i = 1; i <= faces.Extent(); ++i) {
    if (!on_box[i - 1]) continue;
    tags[i - 1] = Tag::farfield;
    for (TopExp_Explorer ex(faces(i), TopAbs_EDGE); ex.More(); ex.Next())
      if (const TopTools_ListOfShape* l = ef.Seek(ex.Current()))
        for (const auto& g : *l)
          if (!on_box[faces.FindIndex(g) - 1]) tags[i - 1] = Tag::symmetry;
  }
  return tags;
}

std::string describe_face(const Shape& s, int f) {
  Box b = s.face_box(f);
  char buf[256];
  std::snprintf(buf, sizeof buf, "face %d (%s, %s, box (%.6g,%.6g,%.6g)-(%.6g,%.6g,%.6g))", f, tag_name(s.face_tag(f)),
                s.face_surface_type(f).c_str(), b.lo.x, b.lo.y, b.lo.z, b.hi.x, b.hi.y, b.hi.z);
  return buf;
}

namespace {
class FnPrinter : public Message_Printer {
 public:
  explicit FnPrinter(std::function<void(const std::string&)> fn) : fn_(std::move(fn)) {}

 protected:
  void send(const TCollection_AsciiString& s, const Message_Gravity g) const override {
    if (!fn_) return;
    static const char* lv[] = {"trace", "info", "warning", "alarm", "fail"};
    std::string line = std::string("OCCT ") + lv[std::clamp((int)g, 0, 4)] + ": " + s.ToCString();
    while (!line.empty() && (line.back() == '\n' || line.back() == ' ')) line.pop_back();
    fn_(line);
  }

 private:
  std::function<void(const std::string&)> fn_;
};
}  // namespace

Log::Log(std::function<void(const std::string&)> sink) : messenger_(Message::DefaultMessenger()) {
  saved_ = messenger_->Printers();
  messenger_->ChangePrinters().Clear();
  Handle(FnPrinter) p = new FnPrinter(std::move(sink));
  p->SetTraceLevel(Message_Info);
  messenger_->AddPrinter(p);
}
Log::~Log() {
  messenger_->ChangePrinters().Clear();
  for (const auto& p : saved_) {
    if (!p->IsKind(STANDARD_TYPE(Message_PrinterOStream))) messenger_->AddPrinter(p);
  }
}

void silence() {
  Handle(Message_Messenger) m = Message::DefaultMessenger();
  m->RemovePrinters(STANDARD_TYPE(Message_PrinterOStream));
}

}  // namespace occt
}  // namespace meshflow::cad
