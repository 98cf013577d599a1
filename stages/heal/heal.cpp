// meshflow stage kind `heal` (paper §III.A): sews, fixes and closes a shape into a watertight
// fluid solid, reporting every fix, and refuses with a precise message what it cannot repair.
//
// Steps (each optional step reported in stats.fixes with counts):
//   1. duplicate faces (same surface within tolerance) are dropped        [sew]
//   2. sewing of all faces with the tolerance (BRepBuilderAPI_Sewing)       [sew]
//   3. ShapeFix_Shape (wires, edges, orientation, tolerances)
//   4. small edges (< tolerance) merged into neighbours (ShapeFix_Wireframe) [fix_small_edges]
//   5. spot/strip faces (< tolerance wide) removed (ShapeFix_FixSmallFace) [fix_small_faces]
//   1-5 again until the shape is closed (repair_closed): a closed input that they opened is
//      repaired with a lower tolerance (healing never opens a closed solid); an open input (a
//      surface model) is sewn with the gaps measured between its free edges, then its planar
//      openings are capped with plane faces, each reported                   [cap_planar_holes]
//   6. the fluid solid: the given closed shell(s) (outer minus inner), or a box around the body
//      minus the body; of a region in several pieces the largest is kept, the enclosed voids
//      dropped with a note                                                 [fluid]
//   7. same-domain faces and edges unified (ShapeUpgrade_UnifySameDomain)  [unify]
//   8. checks: BRepCheck valid, every edge bounds exactly two faces, positive volume, no
//      self-interference (faces of the solid crossing each other, or an edge or vertex lying
//      on a face it does not bound: BOPAlgo_ArgumentAnalyzer in self-interference mode, i.e.
//      BOPAlgo_CheckerSI; BRepCheck does not look for this) [check_self_intersection], no face
//      narrower than the tolerance. Failure of any check is a StageError naming the entities.
// Face tags: carried over from the input by geometry (a point inside each new face lies on the
// old face), or, when the input has none (a raw STEP), by the box rule (cad::occt::tags_by_box).
#include "engine/stage.hpp"
#include "stages/cad/cad.hpp"
#include "stages/cad/domain_rules.hpp"
#include "stages/cad/occt.hpp"
#include "stages/cad/tag_rules.hpp"
#include "stages/contract/contract.hpp"

#include <nlohmann/json.hpp>

#include <BOPAlgo_CheckerSI.hxx>
#include <BOPDS_DS.hxx>
#include <BOPDS_MapOfPair.hxx>
#include <BRepAlgoAPI_Cut.hxx>
#include <BRepAlgoAPI_Fuse.hxx>
#include <BRepAdaptor_Curve.hxx>
#include <BRepBndLib.hxx>
#include <BRepBuilderAPI_MakeEdge.hxx>
#include <BRepBuilderAPI_MakeFace.hxx>
#include <BRepBuilderAPI_MakeWire.hxx>
#include <BRepBuilderAPI_MakeSolid.hxx>
#include <BRepBuilderAPI_MakeVertex.hxx>
#include <BRepBuilderAPI_Sewing.hxx>
#include <BRepCheck_Analyzer.hxx>
#include <BRepClass3d.hxx>
#include <BRepClass3d_SolidClassifier.hxx>
#include <BRepExtrema_DistShapeShape.hxx>
#include <BRepGProp.hxx>
#include <BRepLib_FindSurface.hxx>
#include <BRepPrimAPI_MakeBox.hxx>
#include <BRep_Builder.hxx>
#include <BRep_Tool.hxx>
#include <Bnd_Box.hxx>
#include <GProp_GProps.hxx>
#include <Geom_Plane.hxx>
#include <gp_Pln.hxx>
#include <ShapeAnalysis_FreeBounds.hxx>
#include <ShapeExtend_Status.hxx>
#include <ShapeFix_Face.hxx>
#include <ShapeFix_FixSmallFace.hxx>
#include <ShapeFix_Shape.hxx>
#include <ShapeFix_Shell.hxx>
#include <ShapeFix_Solid.hxx>
#include <ShapeFix_Wireframe.hxx>
#include <ShapeUpgrade_UnifySameDomain.hxx>
#include <Standard_Failure.hxx>
#include <Standard_Version.hxx>
#include <TopExp.hxx>
#include <TopExp_Explorer.hxx>
#include <TopTools_HSequenceOfShape.hxx>
#include <TopTools_IndexedMapOfShape.hxx>
#include <TopoDS.hxx>
#include <TopoDS_Compound.hxx>
#include <TopoDS_Shell.hxx>
#include <TopoDS_Solid.hxx>
#include <TopoDS_Wire.hxx>

#include <algorithm>
#include <array>
#include <set>
#include <cmath>
#include <cstdio>
#include <limits>
#include <optional>
#include <sstream>

namespace meshflow::heal {
namespace {
using cad::Shape;
using cad::Tag;
using nlohmann::json;

struct Counts {
  int faces = 0, edges = 0, free_edges = 0, multiple_edges = 0, small_edges = 0, shells = 0, solids = 0;
};

Counts count(const TopoDS_Shape& s, double tol) {
  Shape sh = cad::occt::make_shape(s, "");
  Counts c;
  c.faces = sh.num_faces();
  c.edges = sh.num_edges();
  c.shells = sh.num_shells();
  c.solids = sh.num_solids();
  c.free_edges = (int)sh.free_edges().size();
  c.multiple_edges = (int)sh.multiple_edges().size();
  for (int e = 0; e < sh.num_edges(); ++e)
    if (!sh.edge_degenerate(e) && sh.edge_length(e) < tol) ++c.small_edges;
  return c;
}
json to_json(const Counts& c) {
  return {{"faces", c.faces}, {"edges", c.edges}, {"free_edges", c.free_edges}, {"multiple_edges", c.multiple_edges},
          {"small_edges", c.small_edges}, {"shells", c.shells}, {"solids", c.solids}};
}

std::string fmt(double v) {
  char b[32];
  std::snprintf(b, sizeof b, "%.6g", v);
  return b;
}
std::string pt(const cad::Vec3& p) { return "(" + fmt(p.x) + ", " + fmt(p.y) + ", " + fmt(p.z) + ")"; }

// "edge 4 from (..) to (..), length L, bounding only face 2 (...)" for up to `maxn` edges.
std::string describe_edges(const Shape& s, const std::vector<int>& edges, size_t maxn = 8) {
  std::string out;
  for (size_t i = 0; i < edges.size() && i < maxn; ++i) {
    int e = edges[i];
    auto r = s.edge_range(e);
    out += "\n  - edge " + std::to_string(e) + " from " + pt(s.edge_point(e, r.lo)) + " to " + pt(s.edge_point(e, r.hi)) +
           ", length " + fmt(s.edge_length(e)) + ", on ";
    auto fs = s.edge_faces(e);
    for (size_t k = 0; k < fs.size(); ++k) out += (k ? " and " : "") + cad::occt::describe_face(s, fs[k]);
  }
  if (edges.size() > maxn) out += "\n  - ... and " + std::to_string(edges.size() - maxn) + " more";
  return out;
}

// Length, area or volume of a shape (dim 1, 2, 3): OCCT's global properties.
double measure(const TopoDS_Shape& s, int dim) {
  GProp_GProps g;
  if (dim == 1) BRepGProp::LinearProperties(s, g);
  else if (dim == 2) BRepGProp::SurfaceProperties(s, g);
  else BRepGProp::VolumeProperties(s, g);
  return g.Mass();
}
double face_area(const TopoDS_Shape& f) { return measure(f, 2); }
double perimeter(const TopoDS_Shape& f) { return measure(f, 1); }
double volume_of(const TopoDS_Shape& s) { return measure(s, 3); }

// Drops faces that duplicate an earlier face (an interior point of each lies on the other
// within tol and the areas agree); returns the kept faces as a compound.
TopoDS_Shape drop_duplicates(const TopoDS_Shape& s, double tol, int& dropped, StageContext& ctx) {
  TopTools_IndexedMapOfShape faces;
  TopExp::MapShapes(s, TopAbs_FACE, faces);
  int n = faces.Extent();
  std::vector<double> area(n);
  std::vector<Bnd_Box> box(n);
  std::vector<gp_Pnt> inner(n);
  for (int i = 0; i < n; ++i) {
    area[i] = face_area(faces(i + 1));
    BRepBndLib::Add(faces(i + 1), box[i]);
    box[i].Enlarge(tol);
    inner[i] = cad::occt::interior_point(TopoDS::Face(faces(i + 1)));
  }
  auto on = [&](const gp_Pnt& p, int j) {
    BRepExtrema_DistShapeShape d(BRepBuilderAPI_MakeVertex(p).Vertex(), faces(j + 1));
    return d.IsDone() && d.Value() <= tol;
  };
  std::vector<char> drop(n, 0);
  for (int j = 0; j < n; ++j)
    for (int i = 0; i < j && !drop[j]; ++i) {
      if (drop[i] || box[i].IsOut(box[j])) continue;
      if (std::abs(area[i] - area[j]) > 1e-6 * std::max(area[i], area[j]) + tol * tol) continue;
      if (on(inner[j], i) && on(inner[i], j)) {
        drop[j] = 1;
        ctx.log("heal: face " + std::to_string(j) + " duplicates face " + std::to_string(i) + ": dropped");
      }
    }
  dropped = (int)std::count(drop.begin(), drop.end(), 1);
  if (!dropped) return s;
  TopoDS_Compound c;
  BRep_Builder b;
  b.MakeCompound(c);
  for (int i = 0; i < n; ++i)
    if (!drop[i]) b.Add(c, faces(i + 1));
  return c;
}

// The shells of a shape, with its faces that no shell holds gathered into shells of connected
// faces. Sewing gives back a closed body of one face (a sphere, a torus; each sphere of two) as
// that face alone, not as a shell: it is closed by itself (seam and pole edges), so it is a shell.
std::vector<TopoDS_Shell> shells_of(const TopoDS_Shape& s) {
  std::vector<TopoDS_Shell> out;
  TopTools_IndexedMapOfShape in_shell;
  for (TopExp_Explorer ex(s, TopAbs_SHELL); ex.More(); ex.Next()) {
    out.push_back(TopoDS::Shell(ex.Current()));
    TopExp::MapShapes(ex.Current(), TopAbs_FACE, in_shell);
  }
  TopoDS_Shell loose;
  BRep_Builder b;
  b.MakeShell(loose);
  int n = 0;
  for (TopExp_Explorer ex(s, TopAbs_FACE); ex.More(); ex.Next())
    if (!in_shell.Contains(ex.Current())) b.Add(loose, ex.Current()), ++n;
  if (!n) return out;
  // ShapeFix_Shell orients the faces consistently and splits them into connected shells
  ShapeFix_Shell fix;
  fix.FixFaceOrientation(loose, Standard_True, Standard_False);
  for (TopExp_Explorer ex(fix.Shape(), TopAbs_SHELL); ex.More(); ex.Next()) out.push_back(TopoDS::Shell(ex.Current()));
  return out;
}

// A domain with holes (a far-field sphere or cylinder around a body): the faces of its outer
// shell that the box rule left as walls (not on the bounding box's planes) are the far field.
void outer_shell_farfield(const TopoDS_Shape& fluid, std::vector<Tag>& tags) {
  TopoDS_Solid solid;
  int shells = 0;
  for (TopExp_Explorer ex(fluid, TopAbs_SOLID); ex.More(); ex.Next()) solid = TopoDS::Solid(ex.Current());
  for (TopExp_Explorer ex(solid, TopAbs_SHELL); ex.More(); ex.Next()) ++shells;
  if (solid.IsNull() || shells < 2) return;
  TopoDS_Shell outer = BRepClass3d::OuterShell(solid);
  if (outer.IsNull()) return;
  TopTools_IndexedMapOfShape faces, outer_faces;
  TopExp::MapShapes(fluid, TopAbs_FACE, faces);
  TopExp::MapShapes(outer, TopAbs_FACE, outer_faces);
  for (int i = 1; i <= faces.Extent(); ++i)
    if (outer_faces.Contains(faces(i)) && tags[i - 1] == Tag::wall) tags[i - 1] = Tag::farfield;
}

double diag_of(const Bnd_Box& b) { return b.IsVoid() ? 0 : std::sqrt(b.SquareExtent()); }

// A given domain that is not box-shaped and has no holes (a half sphere or half cylinder around a
// half model cut into its symmetry plane): its large curved faces next to the box planes are the
// far field, not walls (cad::curved_farfield, the rule init reads the file with).
void curved_farfield_tags(const TopoDS_Shape& fluid, std::vector<Tag>& tags, double tol) {
  Shape sh = cad::occt::make_shape(fluid, "");
  if (sh.num_shells() != 1) return;
  const cad::Box b = sh.box();
  if (cad::box_corner_vertices(sh, b, tol) == 8) return;
  for (int f : cad::curved_farfield(sh, b, tol))
    if (tags[f] == Tag::wall) tags[f] = Tag::farfield;
}

// The solids of `s` fused into one body (BRepAlgoAPI_Fuse, then the faces the fusion split on
// one surface unified); `s` as it is with fewer than two solids or when the solids are apart.
TopoDS_Shape fuse_solids(const TopoDS_Shape& s, json& fixes, StageContext& ctx) {
  TopTools_ListOfShape first, rest;
  int n = 0;
  for (TopExp_Explorer ex(s, TopAbs_SOLID); ex.More(); ex.Next()) (n++ ? rest : first).Append(ex.Current());
  if (n < 2) return s;
  BRepAlgoAPI_Fuse fuse;
  fuse.SetArguments(first);
  fuse.SetTools(rest);
  fuse.Build();
  if (!fuse.IsDone() || fuse.HasErrors())
    throw StageError("heal: fusing the body's " + std::to_string(n) +
                     " solids failed in OpenCASCADE; fuse them in the CAD system, or give them as separate files");
  // Unifying is a simplification: where OpenCASCADE throws on it (an aircraft of 27 touching
  // parts), the fused body keeps the faces the fusion split.
  TopoDS_Shape out = fuse.Shape();
  try {
    ShapeUpgrade_UnifySameDomain un(out, Standard_True, Standard_True, Standard_False);
    un.Build();
    out = un.Shape();
  } catch (const Standard_Failure& e) {  // the fused body with its split faces: still one body
    ctx.log(std::string("heal: unifying the faces the fusion split failed in OpenCASCADE (") + e.GetMessageString() +
            "); the fused body keeps them split");
  }
  int after = 0;
  for (TopExp_Explorer ex(out, TopAbs_SOLID); ex.More(); ex.Next()) ++after;
  fixes["solids_fused"] = {{"before", n}, {"after", after}};
  ctx.log("heal: the body's " + std::to_string(n) + " solids fused into " + std::to_string(after));
  return out;
}

// The length the default tolerance is relative to: the bounding-box diagonal of the shape, or,
// when a solid has inner shells (a far field given around the body), of its smallest shell (the
// body): a far field 100 chords away must not make the tolerance 100 times coarser on the body.
double body_diagonal(const TopoDS_Shape& s, double whole) {
  double d = whole;
  for (TopExp_Explorer so(s, TopAbs_SOLID); so.More(); so.Next()) {
    std::vector<double> shells;
    for (TopExp_Explorer sh(so.Current(), TopAbs_SHELL); sh.More(); sh.Next()) {
      Bnd_Box b;
      BRepBndLib::Add(sh.Current(), b);
      shells.push_back(diag_of(b));
    }
    if (shells.size() >= 2) d = std::min(d, *std::min_element(shells.begin(), shells.end()));
  }
  return d;
}

TopoDS_Solid solid_of(const TopoDS_Shell& sh) {
  BRepBuilderAPI_MakeSolid ms(sh);
  TopoDS_Solid so = ms.Solid();
  ShapeFix_Solid fs(so);
  fs.Perform();
  return TopoDS::Solid(fs.Solid());  // oriented so that its volume is positive
}

// Self-interference of a closed solid: pairs of sub-shapes that interfere although they are
// not adjacent, and faces whose surface crosses itself inside the face (BOPAlgo_CheckerSI, as
// BOPAlgo_ArgumentAnalyzer runs it, but with its level: 5 "full" = also face/face and face
// self-intersection, 4 "edges" = vertex/edge/face interferences up to edge/face only). With
// `parallel` OCCT intersects on its thread pool: the set found is the same and is sorted here,
// so the result does not depend on the thread count. Interferences are mapped to pairs of face
// ids of `s` (an edge or vertex stands for the faces it bounds); the others are described.
struct SelfInterference {
  int pairs = 0;
  bool aborted = false;  // OCCT's checker stopped with an error: the answer is unknown
  std::vector<std::array<int, 2>> face_pairs;
  std::vector<std::string> other;  // interferences not between two distinct faces, described
};
SelfInterference self_interference(const Shape& s, int level, bool parallel, double fuzzy) {
  BOPAlgo_CheckerSI ch;
  TopTools_ListOfShape args;
  args.Append(cad::occt::shape(s));
  ch.SetArguments(args);
  ch.SetNonDestructive(Standard_True);
  ch.SetLevelOfCheck(level);
  ch.SetRunParallel(parallel);
  if (fuzzy > 0) ch.SetFuzzyValue(fuzzy);
  ch.Perform();
  SelfInterference r;
  r.aborted = ch.HasErrors();
  const BOPDS_DS& ds = *ch.PDS();
  std::vector<std::array<int, 2>> idx;  // DS indices, sorted: the map's order is a hash order
  for (BOPDS_MapIteratorOfMapOfPair it(ds.Interferences()); it.More(); it.Next()) {
    int n1, n2;
    it.Value().Indices(n1, n2);
    idx.push_back({std::min(n1, n2), std::max(n1, n2)});
  }
  std::sort(idx.begin(), idx.end());
  std::vector<std::array<TopoDS_Shape, 2>> found;
  for (auto& [n1, n2] : idx) found.push_back({ds.Shape(n1), ds.Shape(n2)});
  const auto& I = s.impl();
  auto faces_of = [&](const TopoDS_Shape& x) {
    std::vector<int> f;
    if (x.ShapeType() == TopAbs_FACE) {
      if (int i = I.faces.FindIndex(x)) f.push_back(i - 1);
    } else if (x.ShapeType() == TopAbs_EDGE) {
      if (int i = I.edges.FindIndex(x)) f = s.edge_faces(i - 1);
    } else {
      TopTools_IndexedMapOfShape fs;
      for (TopExp_Explorer ex(I.shape, TopAbs_FACE); ex.More(); ex.Next())
        for (TopExp_Explorer v(ex.Current(), TopAbs_VERTEX); v.More(); v.Next())
          if (v.Current().IsSame(x)) fs.Add(ex.Current());
      for (int k = 1; k <= fs.Extent(); ++k)
        if (int i = I.faces.FindIndex(fs(k))) f.push_back(i - 1);
    }
    return f;
  };
  std::set<std::array<int, 2>> pairs;
  for (auto& both : found) {
    ++r.pairs;
    std::vector<TopoDS_Shape> sub = {both[0]};
    if (!both[1].IsSame(both[0])) sub.push_back(both[1]);
    bool distinct = false;
    if (sub.size() >= 2)
      for (int a : faces_of(sub[0]))
        for (int b : faces_of(sub[1]))
          if (a != b) distinct = true, pairs.insert({std::min(a, b), std::max(a, b)});
    if (!distinct && r.other.size() < 8) {
      std::string d;
      if (sub.size() == 1 && sub[0].ShapeType() == TopAbs_FACE && !faces_of(sub[0]).empty()) {
        r.other.push_back(cad::occt::describe_face(s, faces_of(sub[0])[0]) + " intersects itself");
        continue;
      }
      for (auto& x : sub) {
        static const char* type[] = {"compound", "compsolid", "solid", "shell", "face", "wire", "edge", "vertex", "shape"};
        std::string fs;
        for (int f : faces_of(x)) fs += (fs.empty() ? "" : ",") + std::to_string(f);
        d += std::string(d.empty() ? "" : " with ") + type[std::min<int>(x.ShapeType(), 8)] + " of face(s) " + fs;
        if (x.ShapeType() == TopAbs_VERTEX) {
          gp_Pnt p = BRep_Tool::Pnt(TopoDS::Vertex(x));
          d += " at " + pt({p.X(), p.Y(), p.Z()});
        }
      }
      r.other.push_back(d);
    }
  }
  r.face_pairs.assign(pairs.begin(), pairs.end());
  return r;
}

// The heal parameters, read once.
struct Options {
  double tol = 0;   // the tolerance asked for (0 in the params: 1e-6 of the body's diagonal)
  bool sew = true, small_edges = true, small_faces = true, unify = true, cap_holes = true, check_si = true;
  int si_level = 5;
  double si_tol = 0;  // 0: 10 x the default tolerance
  std::string fluid, tags, symmetry_plane;
};
Options read_options(const nlohmann::json& P, const TopoDS_Shape& in, double diag) {
  Options o;
  o.tol = P.at("tolerance").get<double>();
  if (o.tol <= 0) o.tol = 1e-6 * body_diagonal(in, diag);
  o.sew = P.at("sew").get<bool>();
  o.small_edges = P.at("fix_small_edges").get<bool>();
  o.small_faces = P.at("fix_small_faces").get<bool>();
  o.unify = P.at("unify").get<bool>();
  o.cap_holes = P.at("cap_planar_holes").get<bool>();
  o.check_si = P.at("check_self_intersection").get<std::string>() != "off";
  o.si_level = P.at("check_self_intersection").get<std::string>() == "edges" ? 4 : 5;
  o.si_tol = P.at("self_intersection_tolerance").get<double>();
  o.fluid = P.at("fluid").get<std::string>();
  o.tags = P.at("tags").get<std::string>();
  o.symmetry_plane = P.at("symmetry_plane").get<std::string>();
  return o;
}

// Which repairs one attempt makes (steps 1-2, 4, 5; ShapeFix always runs).
struct Steps {
  bool sew = true, small_edges = true, small_faces = true;
};

// Steps 1-5 with tolerance `tol`: drop duplicate faces, sew, ShapeFix, small edges, small
// faces. Each step's counts go to `fixes`.
TopoDS_Shape repair(TopoDS_Shape s, double tol, double diag, const Steps& steps, json& fixes, StageContext& ctx,
                    const std::string& src) {
  try {
    // 1-2. duplicates, sewing
    if (steps.sew) {
      ctx.progress(0.05, "duplicate faces");
      int dropped = 0;
      s = drop_duplicates(s, tol, dropped, ctx);
      fixes["duplicate_faces_removed"] = dropped;
      ctx.progress(0.15, "sewing");
      BRepBuilderAPI_Sewing sw(tol, Standard_True, Standard_True, Standard_True, Standard_False);
      sw.Add(s);
      sw.Perform();
      s = sw.SewedShape();
      fixes["sewing"] = {{"contiguous_edges", sw.NbContigousEdges()}, {"free_edges_after", sw.NbFreeEdges()},
                         {"multiple_edges_after", sw.NbMultipleEdges()}, {"degenerated_shapes", sw.NbDegeneratedShapes()},
                         {"deleted_faces", sw.NbDeletedFaces()}};
      ctx.log("heal: sewing with tolerance " + fmt(tol) + " joined " + std::to_string(sw.NbContigousEdges()) +
              " edge pairs; free edges left " + std::to_string(sw.NbFreeEdges()));
    }
    // 3. ShapeFix
    ctx.progress(0.3, "ShapeFix");
    {
      Handle(ShapeFix_Shape) fx = new ShapeFix_Shape(s);
      fx->SetPrecision(tol);
      fx->SetMaxTolerance(std::max(tol, 1e-3 * diag));
      fx->Perform();
      s = fx->Shape();
      fixes["shapefix"] = {{"done", (bool)fx->Status(ShapeExtend_DONE)}, {"failed", (bool)fx->Status(ShapeExtend_FAIL)}};
    }
    // 4. small edges
    if (steps.small_edges) {
      ctx.progress(0.4, "small edges");
      int before = count(s, tol).small_edges;
      Handle(ShapeFix_Wireframe) wf = new ShapeFix_Wireframe(s);
      wf->SetPrecision(tol);
      wf->SetMaxTolerance(std::max(tol, 1e-3 * diag));
      wf->ModeDropSmallEdges() = Standard_True;
      wf->FixSmallEdges();
      wf->FixWireGaps();
      s = wf->Shape();
      int after = count(s, tol).small_edges;
      fixes["small_edges"] = {{"before", before}, {"after", after}};
    }
    // 5. small faces
    if (steps.small_faces) {
      ctx.progress(0.5, "small faces");
      int before = count(s, tol).faces;
      ShapeFix_FixSmallFace sf;
      sf.Init(s);
      sf.SetPrecision(tol);
      sf.SetMaxTolerance(std::max(tol, 1e-3 * diag));
      sf.Perform();
      s = sf.FixShape();
      fixes["small_faces_removed"] = before - count(s, tol).faces;
    }
  } catch (const Standard_Failure& e) {
    throw StageError(src + ": OpenCASCADE failed while repairing the shape (" + e.GetMessageString() +
                     "); try another tolerance or repair the CAD in its source system");
  }
  return s;
}

// Step 0 (fuse_solids), an OCCT failure reported as repair() reports its own.
TopoDS_Shape fuse_step(const TopoDS_Shape& s, json& fixes, StageContext& ctx, const std::string& src) {
  try {
    return fuse_solids(s, fixes, ctx);
  } catch (const Standard_Failure& e) {
    throw StageError(src + ": OpenCASCADE failed while fusing the body's solids (" + e.GetMessageString() +
                     "); try another tolerance or repair the CAD in its source system");
  }
}

int free_edge_count(const TopoDS_Shape& s) { return (int)cad::occt::make_shape(s, "").free_edges().size(); }

// The gaps between a shape's free edges: for each free edge, the distance from its midpoint to
// the nearest free edge that shares no vertex with it or shares both (two faces' edges that
// should have been sewn lie that far apart). Sorted, ascending; edges with no such neighbour give none.
std::vector<double> free_edge_gaps(const TopoDS_Shape& s) {
  Shape sh = cad::occt::make_shape(s, "");
  const std::vector<int> fe = sh.free_edges();
  std::vector<Bnd_Box> boxes(fe.size());
  for (size_t i = 0; i < fe.size(); ++i) BRepBndLib::Add(sh.impl().edge(fe[i]), boxes[i]);
  std::vector<double> gaps;
  for (size_t i = 0; i < fe.size(); ++i) {
    const TopoDS_Edge& e = sh.impl().edge(fe[i]);
    auto r = sh.edge_range(fe[i]);
    TopoDS_Vertex mid = BRepBuilderAPI_MakeVertex(cad::occt::pnt(sh.edge_point(fe[i], 0.5 * (r.lo + r.hi))));
    TopoDS_Vertex a, b;
    TopExp::Vertices(e, a, b);
    double best = std::numeric_limits<double>::infinity();
    for (size_t j = 0; j < fe.size(); ++j) {
      if (j == i) continue;
      const TopoDS_Edge& g = sh.impl().edge(fe[j]);
      TopoDS_Vertex c, d;
      TopExp::Vertices(g, c, d);
      // neighbours along one opening share a vertex; two edges with the same two ends are two
      // faces' copies of one boundary (a cascade passage's blade face and end face) apart by the gap
      const bool same_ends = (a.IsSame(c) && b.IsSame(d)) || (a.IsSame(d) && b.IsSame(c));
      if (!same_ends && (a.IsSame(c) || a.IsSame(d) || b.IsSame(c) || b.IsSame(d))) continue;
      if (std::isfinite(best)) {
        Bnd_Box q = boxes[i];
        q.Enlarge(best);
        if (q.IsOut(boxes[j])) continue;
      }
      if (same_ends) {  // the widest the two copies lie apart: sewing needs all of it
        double far = 0;
        for (int k = 1; k < 16; ++k)
          far = std::max(far, sh.project_to_edge(fe[j], sh.edge_point(fe[i], r.lo + (r.hi - r.lo) * k / 16)).distance);
        best = std::min(best, far);
        continue;
      }
      BRepExtrema_DistShapeShape dist(mid, g);
      if (dist.IsDone() && dist.Value() < best) best = dist.Value();
    }
    if (std::isfinite(best)) gaps.push_back(best);
  }
  std::sort(gaps.begin(), gaps.end());
  return gaps;
}

// The openings of a shape: its free edges joined into wires (closed loops and open chains).
struct Openings {
  std::vector<TopoDS_Wire> closed, open;
};
Openings openings_of(const TopoDS_Shape& s, double tol) {
  // ShapeAnalysis_FreeBounds reads the faces of a compound or shell: a lone face (a surface model
  // of one face, which sewing returns as it is: a half hull whose whole rim lies on its
  // centreplane and deck) gave no openings at all
  TopoDS_Shape faces = s;
  if (s.ShapeType() == TopAbs_FACE) {
    TopoDS_Compound c;
    BRep_Builder b;
    b.MakeCompound(c);
    b.Add(c, s);
    faces = c;
  }
  ShapeAnalysis_FreeBounds fb(faces, tol, Standard_True, Standard_True);  // closed sub-loops split out of longer chains
  Openings o;
  for (TopExp_Explorer ex(fb.GetClosedWires(), TopAbs_WIRE); ex.More(); ex.Next()) o.closed.push_back(TopoDS::Wire(ex.Current()));
  for (TopExp_Explorer ex(fb.GetOpenWires(), TopAbs_WIRE); ex.More(); ex.Next()) o.open.push_back(TopoDS::Wire(ex.Current()));
  return o;
}

// "opening 2: 4 edges, centre (..), across 1.2, planar" for a message.
std::string describe_opening(const TopoDS_Wire& w, int i, double tol, bool closed) {
  Bnd_Box b;
  BRepBndLib::Add(w, b);
  double x0, y0, z0, x1, y1, z1;
  b.Get(x0, y0, z0, x1, y1, z1);
  int n = 0;
  for (TopExp_Explorer ex(w, TopAbs_EDGE); ex.More(); ex.Next()) ++n;
  BRepLib_FindSurface fs(w, tol, Standard_True);
  return "opening " + std::to_string(i) + ": " + std::to_string(n) + " free edge(s) around " +
         pt({(x0 + x1) / 2, (y0 + y1) / 2, (z0 + z1) / 2}) + ", across " + fmt(diag_of(b)) + ", " +
         (!closed ? "not a closed loop" : fs.Found() ? "planar" : "not planar");
}

// The plane face closing loop w, when w is planar and the face is no face of s already (a loop
// round a loose flat sheet is no opening to close).
std::optional<TopoDS_Face> cap_of(const TopoDS_Wire& w, const TopoDS_Shape& s, double tol, Handle(Geom_Plane)& plane) {
  BRepLib_FindSurface fs(w, tol, Standard_True);
  if (!fs.Found()) return std::nullopt;
  plane = Handle(Geom_Plane)::DownCast(fs.Surface());
  if (plane.IsNull()) return std::nullopt;
  BRepBuilderAPI_MakeFace mf(plane, w, Standard_True);
  if (!mf.IsDone()) return std::nullopt;
  ShapeFix_Face fix(mf.Face());
  fix.Perform();
  TopoDS_Face cap = fix.Face();
  BRepExtrema_DistShapeShape on(BRepBuilderAPI_MakeVertex(cad::occt::interior_point(cap)).Vertex(), s);
  if (on.IsDone() && on.Value() <= 10 * tol) return std::nullopt;
  return cap;
}

// The point where three planes meet, or nothing when two of them are (nearly) parallel.
std::optional<gp_Pnt> plane_corner(const gp_Pln& p1, const gp_Pln& p2, const gp_Pln& p3) {
  double a[3][4];
  p1.Coefficients(a[0][0], a[0][1], a[0][2], a[0][3]);
  p2.Coefficients(a[1][0], a[1][1], a[1][2], a[1][3]);
  p3.Coefficients(a[2][0], a[2][1], a[2][2], a[2][3]);
  auto det = [&](int c0, int c1, int c2) {
    return a[0][c0] * (a[1][c1] * a[2][c2] - a[1][c2] * a[2][c1]) - a[0][c1] * (a[1][c0] * a[2][c2] - a[1][c2] * a[2][c0]) +
           a[0][c2] * (a[1][c0] * a[2][c1] - a[1][c1] * a[2][c0]);
  };
  const double d = det(0, 1, 2);
  if (std::abs(d) < 1e-6) return std::nullopt;  // unit normals: |d| is the volume they span
  // a x = -coef: Cramer's rule with the right-hand side in column 3 (negated)
  return gp_Pnt(-det(3, 1, 2) / d, -det(0, 3, 2) / d, -det(0, 1, 3) / d);
}

// Closes an open chain of free edges lying in plane `pl` by the straight segment between its
// ends, where both ends lie on another plane of the opening too: the segment is then where the
// two planes meet, an edge two missing flat faces shared (a half hull's deck and centreplane
// meet along its deck centreline; a block that lost two adjacent flat faces, along their
// corner), and the cap on the other plane closes its own chain with the same segment, so the
// two caps are sewn along it; or, with its ends on two other planes, through the corner the
// three planes share. Returns false (w unchanged) when neither closes it.
bool close_on_crossing_plane(TopoDS_Wire& w, const gp_Pln& pl, const std::vector<gp_Pln>& planes, double tol) {
  TopoDS_Vertex a, b;
  TopExp::Vertices(w, a, b);
  if (a.IsNull() || b.IsNull()) return false;
  const gp_Pnt pa = BRep_Tool::Pnt(a), pb = BRep_Tool::Pnt(b);
  if (pa.Distance(pb) <= tol) return false;
  std::vector<const gp_Pln*> at_a, at_b;  // other planes through each end
  for (auto& q : planes)
    if (!q.Axis().Direction().IsParallel(pl.Axis().Direction(), 1e-9)) {
      if (q.Distance(pa) <= 10 * tol) at_a.push_back(&q);
      if (q.Distance(pb) <= 10 * tol) at_b.push_back(&q);
    }
  BRepBuilderAPI_MakeWire mw(w);
  bool crossing = false;
  for (auto* q : at_a) crossing = crossing || std::find(at_b.begin(), at_b.end(), q) != at_b.end();
  if (crossing) {
    mw.Add(BRepBuilderAPI_MakeEdge(b, a).Edge());
  } else {
    // the ends on two other planes (a hull's keel line ends on its deck at the bow and on its
    // transom at the stern): closed through the corner where the three planes meet, each segment
    // on one plane's crossing with `pl`
    std::optional<gp_Pnt> corner;
    for (auto* qa : at_a)
      for (auto* qb : at_b)
        if (!corner && qa != qb)
          if (auto c = plane_corner(pl, *qa, *qb); c && c->Distance(pa) > tol && c->Distance(pb) > tol) corner = c;
    if (!corner) return false;
    TopoDS_Vertex vc = BRepBuilderAPI_MakeVertex(*corner).Vertex();
    mw.Add(BRepBuilderAPI_MakeEdge(b, vc).Edge());
    mw.Add(BRepBuilderAPI_MakeEdge(vc, a).Edge());
  }
  if (!mw.IsDone() || !BRep_Tool::IsClosed(mw.Wire())) return false;
  w = mw.Wire();
  return true;
}

// The planar closed loops inside openings that are not planar as a whole: a surface model that
// lost several flat faces (an export that dropped a block's flat faces: the free edges round
// them join into one chain that is not planar as a whole). Each
// plane through two free edges meeting at a vertex is a candidate; the free edges lying in it
// (within 10 x tol at 5 points each) are joined into wires, and each closed one is a loop to cap.
std::vector<TopoDS_Wire> planar_subloops(const std::vector<TopoDS_Edge>& edges, double tol) {
  auto on_plane = [&](const TopoDS_Edge& e, const gp_Pln& pl) {
    BRepAdaptor_Curve c(e);
    for (int k = 0; k <= 4; ++k)
      if (pl.Distance(c.Value(c.FirstParameter() + (c.LastParameter() - c.FirstParameter()) * k / 4)) > 10 * tol) return false;
    return true;
  };
  std::vector<gp_Pln> planes;
  auto add_plane = [&](const TopoDS_Shape& edges_of) {
    BRepLib_FindSurface fs(edges_of, tol, Standard_True);
    if (!fs.Found()) return;
    Handle(Geom_Plane) gp = Handle(Geom_Plane)::DownCast(fs.Surface());
    if (gp.IsNull()) return;
    const gp_Pln pl = gp->Pln();
    for (auto& q : planes)
      if (q.Axis().Direction().IsParallel(pl.Axis().Direction(), 1e-9) && q.Distance(pl.Location()) <= tol) return;
    planes.push_back(pl);
  };
  for (auto& e : edges)
    if (BRepAdaptor_Curve(e).GetType() != GeomAbs_Line) add_plane(e);  // a planar curve's own plane
  for (size_t i = 0; i < edges.size(); ++i)
    for (size_t j = i + 1; j < edges.size(); ++j) {
      TopoDS_Vertex a, b, c, d;
      TopExp::Vertices(edges[i], a, b);
      TopExp::Vertices(edges[j], c, d);
      if (!(a.IsSame(c) || a.IsSame(d) || b.IsSame(c) || b.IsSame(d))) continue;
      TopoDS_Compound pair;
      BRep_Builder bb;
      bb.MakeCompound(pair);
      bb.Add(pair, edges[i]);
      bb.Add(pair, edges[j]);
      add_plane(pair);
    }
  std::vector<TopoDS_Wire> loops;
  std::set<std::vector<const void*>> taken;  // each loop once, by its edges
  for (auto& pl : planes) {
    Handle(TopTools_HSequenceOfShape) in = new TopTools_HSequenceOfShape, out;
    for (auto& e : edges)
      if (on_plane(e, pl)) in->Append(e);
    if (in->Length() < 1) continue;
    ShapeAnalysis_FreeBounds::ConnectEdgesToWires(in, tol, Standard_True, out);
    for (int k = 1; !out.IsNull() && k <= out->Length(); ++k) {
      TopoDS_Wire w = TopoDS::Wire(out->Value(k));
      if (!BRep_Tool::IsClosed(w) && !close_on_crossing_plane(w, pl, planes, tol)) continue;
      std::vector<const void*> key;
      for (TopExp_Explorer ex(w, TopAbs_EDGE); ex.More(); ex.Next()) key.push_back(ex.Current().TShape().get());
      std::sort(key.begin(), key.end());
      if (taken.insert(key).second) loops.push_back(w);
    }
  }
  return loops;
}

// Planar openings closed by a plane face each and sewn on (a blade's root and tip, a pipe's end
// left open by a surface model), and the planar loops inside openings that are not planar as a
// whole (planar_subloops). Returns the shape with the caps, or `s` when none was planar.
TopoDS_Shape cap_planar_openings(const TopoDS_Shape& s, double tol, json& fixes, StageContext& ctx) {
  Openings o = openings_of(s, tol);
  std::vector<TopoDS_Face> caps;
  json made = json::array();
  std::vector<TopoDS_Edge> rest;  // the edges of the openings no cap closed as a whole
  auto add_cap = [&](const TopoDS_Face& cap, const Handle(Geom_Plane)& plane, const std::string& what) {
    gp_Pnt c = cad::occt::interior_point(cap);
    gp_Dir n = plane->Position().Direction();
    caps.push_back(cap);
    made.push_back({{"edges", what}, {"area", face_area(cap)}, {"point", {c.X(), c.Y(), c.Z()}}, {"normal", {n.X(), n.Y(), n.Z()}}});
  };
  auto keep_edges = [&](const TopoDS_Wire& w) {
    for (TopExp_Explorer ex(w, TopAbs_EDGE); ex.More(); ex.Next()) rest.push_back(TopoDS::Edge(ex.Current()));
  };
  for (size_t i = 0; i < o.closed.size(); ++i) {
    Handle(Geom_Plane) plane;
    if (auto cap = cap_of(o.closed[i], s, tol, plane))
      add_cap(*cap, plane, describe_opening(o.closed[i], (int)i, tol, true));
    else
      keep_edges(o.closed[i]);
  }
  for (auto& w : o.open) keep_edges(w);
  if (rest.size() >= 2) {
    int k = 0;
    for (auto& w : planar_subloops(rest, tol)) {
      Handle(Geom_Plane) plane;
      if (auto cap = cap_of(w, s, tol, plane))
        add_cap(*cap, plane, "a planar loop of a larger opening: " + describe_opening(w, k, tol, true)), ++k;
    }
  }
  if (caps.empty()) return s;
  BRepBuilderAPI_Sewing sw(tol, Standard_True, Standard_True, Standard_True, Standard_False);
  sw.Add(s);
  for (auto& f : caps) sw.Add(f);
  sw.Perform();
  for (auto& m : made) fixes["planar_holes_capped"].push_back(m);
  ctx.log("heal: " + std::to_string(caps.size()) + " planar opening(s) closed by a plane face each (stats.fixes.planar_holes_capped)");
  return sw.SewedShape();
}

// Steps 0-5 until the shape is closed, where it can be without inventing geometry:
//   - a closed input that repairing opened (the tolerance collapsed small features: a trailing
//     edge's faces on a domain many chords across) is repaired again with the tolerance lowered
//     100 and 10,000 times, then with ShapeFix alone: healing never opens a closed solid;
//   - an open input (a surface model) is sewn again with the gaps measured between its free
//     edges (up to 1 % of its diagonal: a gap wider than that is a missing face, not an
//     inaccuracy), then its planar openings are capped.
// Returns the repaired shape and the sewing tolerance used (`tol`); what was tried goes to fixes.
// Step 0 first, once: with fluid: box a body of several solids (a wing and a fuselage, parts
// that share faces or overlap) is one body, fused before anything is sewn or cut so that their
// shared faces go; every attempt starts from the fused body.
TopoDS_Shape repair_closed(const TopoDS_Shape& input, bool input_closed, const Options& o, double diag, double& tol,
                           json& fixes, StageContext& ctx, const std::string& src) {
  json fused = json::object();
  const TopoDS_Shape in = o.fluid == "box" ? fuse_step(input, fused, ctx, src) : input;
  fixes.update(fused);
  const Steps asked{o.sew, o.small_edges, o.small_faces};
  auto take = [&](const json& f) { fixes = f, fixes.update(fused); };  // an attempt's fixes, the fusion's kept
  TopoDS_Shape s = repair(in, tol, diag, asked, fixes, ctx, src);
  int fe = free_edge_count(s);
  if (fe == 0) return s;
  if (input_closed) {
    for (double t : {tol / 100, tol / 1e4}) {
      json f = json::object();
      TopoDS_Shape r = repair(in, t, diag, asked, f, ctx, src);
      if (free_edge_count(r) == 0) {
        take(f);
        fixes["tolerance_lowered"] = {{"from", tol}, {"to", t}, {"free_edges_at_first", fe}};
        ctx.log("heal: the input was closed and repairing with tolerance " + fmt(tol) + " left " + std::to_string(fe) +
                " free edge(s) (features smaller than the tolerance collapsed): repaired again with " + fmt(t));
        tol = t;
        return r;
      }
    }
    json f = json::object();
    TopoDS_Shape r = repair(in, tol, diag, Steps{false, false, false}, f, ctx, src);
    if (free_edge_count(r) == 0) {
      take(f);
      fixes["repairs_skipped"] = {{"why", "sewing and the small-entity fixes opened the closed input"}, {"free_edges_at_first", fe}};
      ctx.log("heal: the input was closed and sewing or the small-entity fixes opened it at every tolerance tried: "
              "only ShapeFix was applied");
      return r;
    }
    return s;
  }
  if (asked.sew) {
    const std::vector<double> gaps = free_edge_gaps(s);
    std::vector<double> tries;
    for (double g : gaps)
      if (g > tol && g <= 1e-2 * diag && (tries.empty() || g > 2 * tries.back())) tries.push_back(g);
    if (tries.size() > 4) tries.erase(tries.begin(), tries.end() - 4);
    for (double g : tries) {
      json f = json::object();
      const double t = 1.5 * g;
      TopoDS_Shape r = repair(in, t, diag, asked, f, ctx, src);
      const int n = free_edge_count(r);
      if (n < fe) {
        f["sewing_gap_measured"] = {{"gap", g}, {"tolerance", t}, {"free_edges_before", fe}, {"free_edges_after", n}};
        ctx.log("heal: the free edges lie up to " + fmt(g) + " apart: sewn again with tolerance " + fmt(t) + ", " +
                std::to_string(fe) + " -> " + std::to_string(n) + " free edge(s)");
        s = r, fe = n, tol = t;
        take(f);
        if (fe == 0) return s;
      }
    }
  }
  // Caps sewn on can leave a loop planar and closed that was not before (an outline that ran
  // round a dropped flat face and its neighbours' now capped ones): up to 3 rounds, while each
  // closes free edges. A round is kept only if its caps make no edge of three faces (a cap over
  // a loop some faces already close); caps that cut through the model (a filleted block's
  // missing flat faces closed through the sharp corner its fillets round off) are left to the
  // self-intersection check below, which refuses them naming the faces.
  for (int round = 0; o.cap_holes && round < 3 && fe > 0; ++round) {
    json f = json::object();
    TopoDS_Shape capped = cap_planar_openings(s, tol, f, ctx);
    const Shape cs = cad::occt::make_shape(capped, "");
    const int n = static_cast<int>(cs.free_edges().size());
    if (n >= fe) break;
    if (const std::size_t multiple = cs.multiple_edges().size()) {
      ctx.log("heal: planar caps not kept: they overlap the model (" + std::to_string(multiple) + " edge(s) of three faces)");
      break;
    }
    for (auto& c : f["planar_holes_capped"]) fixes["planar_holes_capped"].push_back(c);
    s = capped, fe = n;
  }
  return s;
}

// Refuses a shape that is still open or has edges shared by more than two faces, naming the
// openings and what to do.
void refuse_open(const TopoDS_Shape& s, const std::string& units, double tol, bool input_closed, bool caps,
                 const std::string& src) {
  Shape cur = cad::occt::make_shape(s, units);
  auto fe = cur.free_edges();
  if (!fe.empty()) {
    Openings op = openings_of(s, tol);
    std::string where;
    int i = 0;
    for (auto& w : op.closed)
      if (i < 8) where += "\n  - " + describe_opening(w, i++, tol, true);
    for (auto& w : op.open)
      if (i < 8) where += "\n  - " + describe_opening(w, i++, tol, false);
    throw StageError(src + ": the shape is not closed after sewing with tolerance " + fmt(tol) + ": " +
                     std::to_string(fe.size()) + " free edge(s) bound only one face " +
                     (input_closed ? "although the input was closed (healing collapsed features smaller than the tolerance):"
                                   : "(a missing face or a gap wider than the tolerance):") +
                     describe_edges(cur, fe) + (where.empty() ? "" : "\nThe openings:" + where) +
                     (input_closed ? "\nLower `tolerance` (e.g. " + fmt(tol / 100) + "), or set sew, fix_small_edges and "
                                     "fix_small_faces to false for CAD that is closed already."
                                   : std::string("\nAdd the missing faces in the CAD") +
                                         (caps ? " (planar openings are capped already; these are not planar or not "
                                                 "closed loops)"
                                               : " (or set cap_planar_holes: true to close the planar ones)") +
                                         ", or raise `tolerance` if a gap is a modelling inaccuracy."));
  }
  auto me = cur.multiple_edges();
  if (!me.empty())
    throw StageError(src + ": " + std::to_string(me.size()) +
                     " edge(s) are shared by more than two faces (overlapping, duplicated or T-joined faces):" +
                     describe_edges(cur, me) + "\nRemove the extra faces in the CAD.");
}

// {volume, box} of a region heal leaves out, for stats.fixes.
json region_json(const TopoDS_Shape& s) {
  Bnd_Box b;
  BRepBndLib::Add(s, b);
  double x0, y0, z0, x1, y1, z1;
  b.Get(x0, y0, z0, x1, y1, z1);
  return {{"volume", volume_of(s)}, {"box", {{x0, y0, z0}, {x1, y1, z1}}}};
}

// A solid lying outside `outer` (an interior point of its first face classified outside): a
// second part beside the domain, not a body inside it.
bool outside_of(const TopoDS_Shape& outer, const TopoDS_Shape& solid) {
  TopExp_Explorer ex(solid, TopAbs_FACE);
  if (!ex.More()) return false;
  BRepClass3d_SolidClassifier c(outer, cad::occt::interior_point(TopoDS::Face(ex.Current())), 1e-9);
  return c.State() == TopAbs_OUT;
}

// One connected fluid region: the solid with the far field (the largest; with fluid: box, the
// one holding the box), the others (the inside of a hollow part, a pipe's bore closed off by the
// body, the space between an assembly's parts) dropped with a note: they are voids no flow reaches.
TopoDS_Shape one_region(const TopoDS_Shape& fluid, json& fixes, StageContext& ctx, const std::string& src) {
  std::vector<TopoDS_Shape> so;
  for (TopExp_Explorer ex(fluid, TopAbs_SOLID); ex.More(); ex.Next()) so.push_back(ex.Current());
  if (so.empty()) throw StageError(src + ": building the fluid region left no solid");
  if (so.size() == 1) return so[0];
  std::vector<double> vol(so.size());
  for (size_t i = 0; i < so.size(); ++i) vol[i] = volume_of(so[i]);
  const size_t keep = std::max_element(vol.begin(), vol.end()) - vol.begin();
  json dropped = json::array();
  for (size_t i = 0; i < so.size(); ++i)
    if (i != keep) dropped.push_back(region_json(so[i]));
  fixes["enclosed_regions_dropped"] = dropped;
  ctx.log("heal: the fluid region is made of " + std::to_string(so.size()) + " disconnected solids: the largest (volume " +
          fmt(vol[keep]) + ") is kept, " + std::to_string(so.size() - 1) +
          " enclosed region(s) no flow from it reaches are dropped (stats.fixes.enclosed_regions_dropped)");
  return so[keep];
}

// The interferences `a` and `b` both found: face pairs in both; `a`'s other descriptions when
// `b` has some too (they cannot be matched one to one; kept, not dropped, so that nothing real
// is lost).
SelfInterference both(const SelfInterference& a, const SelfInterference& b) {
  SelfInterference r;
  r.aborted = a.aborted || b.aborted;
  std::set_intersection(a.face_pairs.begin(), a.face_pairs.end(), b.face_pairs.begin(), b.face_pairs.end(),
                        std::back_inserter(r.face_pairs));
  if (!b.other.empty()) r.other = a.other;
  r.pairs = (int)(r.face_pairs.size() + r.other.size());
  return r;
}

void run(StageContext& ctx) {
  const auto& P = ctx.params();
  Shape in = Shape::load(ctx.input("shape").path);
  cad::occt::Log log([&](const std::string& s) { ctx.log(s); });
  const std::string src = "heal stage '" + ctx.stage_name() + "'";

  Bnd_Box bb;
  BRepBndLib::Add(cad::occt::shape(in), bb);
  const double diag = diag_of(bb);
  const Options opt = read_options(P, cad::occt::shape(in), diag);
  const std::string& fluid_mode = opt.fluid;
  const std::string& tag_mode = opt.tags;
  const std::string& symmetry_plane = opt.symmetry_plane;
  if (symmetry_plane != "none" && fluid_mode != "box")
    throw StageError(src + ": symmetry_plane: " + symmetry_plane + " needs fluid: box (it says which side of the body's "
                     "far-field box lies on its root plane)");
  auto& st = ctx.stats();
  double tol = opt.tol;
  json fixes = json::object();
  const TopoDS_Shape& input = cad::occt::shape(in);
  const Counts before = count(input, tol);
  const bool input_closed = before.free_edges == 0 && before.solids > 0;
  st["before"] = to_json(before);
  if (in.num_faces() == 0) throw StageError(src + ": the input shape has no faces: nothing to heal");

  // 0-5, until closed where that can be done without inventing geometry
  TopoDS_Shape s = repair_closed(input, input_closed, opt, diag, tol, fixes, ctx, src);
  st["tolerance"] = tol;
  // 6. the fluid solid
  ctx.progress(0.6, "fluid solid");
  refuse_open(s, in.units(), tol, input_closed, opt.cap_holes, src);
  std::vector<TopoDS_Solid> solids;
  for (TopExp_Explorer ex(s, TopAbs_SOLID); ex.More(); ex.Next()) solids.push_back(TopoDS::Solid(ex.Current()));
  if (solids.empty())
    for (auto& sh : shells_of(s)) solids.push_back(solid_of(sh));
  if (solids.empty()) throw StageError(src + ": the shape holds no shell: nothing can enclose a fluid");
  // outer first: the largest bounding box
  std::stable_sort(solids.begin(), solids.end(), [](const TopoDS_Solid& a, const TopoDS_Solid& b) {
    Bnd_Box x, y;
    BRepBndLib::Add(a, x);
    BRepBndLib::Add(b, y);
    return x.SquareExtent() > y.SquareExtent();
  });
  TopoDS_Shape fluid;
  bool body_in_box = false;
  try {
    if (fluid_mode == "box") {
      Bnd_Box body;
      BRepBndLib::AddOptimal(s, body, Standard_False, Standard_False);
      body.SetGap(0.0);
      double x0, y0, z0, x1, y1, z1;
      body.Get(x0, y0, z0, x1, y1, z1);
      double pad = P.at("box_padding").get<double>() * std::max({x1 - x0, y1 - y0, z1 - z0});
      // a half model: no padding on the side of its root plane (axis k, lo or hi side)
      double lo[3] = {x0 - pad, y0 - pad, z0 - pad}, hi[3] = {x1 + pad, y1 + pad, z1 + pad};
      if (symmetry_plane != "none") {
        int k = symmetry_plane[0] - 'x';
        if (symmetry_plane[1] == '-') lo[k] += pad;
        else hi[k] -= pad;
        fixes["symmetry_plane"] = symmetry_plane;
      }
      TopoDS_Shape box = BRepPrimAPI_MakeBox(gp_Pnt(lo[0], lo[1], lo[2]), gp_Pnt(hi[0], hi[1], hi[2])).Shape();
      TopoDS_Compound bodies;
      BRep_Builder b;
      b.MakeCompound(bodies);
      for (auto& so : solids) b.Add(bodies, so);
      BRepAlgoAPI_Cut cut(box, bodies);
      if (!cut.IsDone() || cut.HasErrors()) throw StageError(src + ": cutting the body from the far-field box failed");
      fluid = cut.Shape();
      body_in_box = true;
      fixes["fluid"] = "box minus " + std::to_string(solids.size()) + " body solid(s)";
    } else if (solids.size() == 1) {
      fluid = solids[0];
      fixes["fluid"] = "given closed shell";
    } else {
      TopoDS_Compound inner;
      BRep_Builder b;
      b.MakeCompound(inner);
      json outside = json::array();
      for (size_t i = 1; i < solids.size(); ++i) {
        if (outside_of(solids[0], solids[i])) {
          outside.push_back(region_json(solids[i]));
          continue;
        }
        b.Add(inner, solids[i]);
      }
      if (!outside.empty()) {
        fixes["regions_outside_dropped"] = outside;
        ctx.log("heal: " + std::to_string(outside.size()) + " closed shell(s) lie outside the largest one: no part of "
                "its fluid, dropped (stats.fixes.regions_outside_dropped)");
      }
      BRepAlgoAPI_Cut cut(solids[0], inner);
      if (!cut.IsDone() || cut.HasErrors())
        throw StageError(src + ": the input has " + std::to_string(solids.size()) +
                         " closed shells and subtracting the inner ones from the outer one failed; use fluid: given with "
                         "one closed shell, or fluid: box with the body alone");
      fluid = cut.Shape();
      fixes["fluid"] = "outer shell minus " + std::to_string(solids.size() - 1) + " inner shell(s)";
    }
    // 7. unify
    if (opt.unify) {
      ctx.progress(0.75, "unify");
      int before = count(fluid, tol).faces;
      // Unifying is a simplification, never a repair: a result OCCT's own check rejects (it can
      // merge a capsule's hemisphere with its seam into an invalid face) is not taken, nor is
      // one OCCT throws on (an aircraft of 27 fused parts): the faces are kept as they were.
      std::string rejected;
      try {
        ShapeUpgrade_UnifySameDomain un(fluid, Standard_True, Standard_True, Standard_False);
        un.SetLinearTolerance(tol);
        un.Build();
        if (BRepCheck_Analyzer(un.Shape()).IsValid() || !BRepCheck_Analyzer(fluid).IsValid()) {
          fluid = un.Shape();
          fixes["unified_faces"] = before - count(fluid, tol).faces;
        } else {
          rejected = "the unified solid fails BRepCheck";
        }
      } catch (const Standard_Failure& e) {
        rejected = std::string("OpenCASCADE failed unifying them (") + e.GetMessageString() + ")";
      }
      if (!rejected.empty()) {
        fixes["unified_faces"] = 0;
        fixes["unify_rejected"] = rejected + "; the faces are kept as they were";
        ctx.log("heal: unifying same-domain faces: " + rejected + ": faces kept as they were");
      }
    }
  } catch (const Standard_Failure& e) {
    throw StageError(src + ": OpenCASCADE failed building the fluid solid (" + e.GetMessageString() + ")");
  }
  fluid = one_region(fluid, fixes, ctx, src);

  // 8. checks
  ctx.progress(0.85, "checking");
  std::vector<Tag> tags;
  bool have_tags = false;
  for (int f = 0; f < in.num_faces(); ++f) have_tags |= in.face_tag(f) != Tag::none;
  // A body's box: its faces are farfield, or symmetry on a half model's root plane (the box face
  // the body stands on, which tags_by_box marks symmetry because wall faces meet it).
  const bool keep_symmetry = symmetry_plane != "none";
  if (tag_mode == "box" || (tag_mode == "auto" && !have_tags)) {
    tags = cad::occt::tags_by_box(fluid, 1e-6 * diag);
    if (body_in_box)
      for (auto& t : tags)
        if (t == Tag::symmetry && !keep_symmetry) t = Tag::farfield;
    outer_shell_farfield(fluid, tags);
    if (!body_in_box) curved_farfield_tags(fluid, tags, 1e-6 * diag);
  } else {
    tags = cad::occt::transfer_tags(in, fluid, std::max(10 * tol, 1e-7 * diag));
    if (body_in_box) {  // new box faces
      auto bt = cad::occt::tags_by_box(fluid, 1e-6 * diag);
      for (size_t i = 0; i < tags.size(); ++i)
        if (bt[i] != Tag::wall) tags[i] = bt[i] == Tag::symmetry && keep_symmetry ? Tag::symmetry : Tag::farfield;
    }
  }
  Shape out = cad::occt::make_shape(fluid, in.units(), tags);
  if (!out.valid()) {
    std::string bad;
    int nbad = 0;
    for (int f = 0; f < out.num_faces(); ++f) {
      BRepCheck_Analyzer a(out.impl().face(f));
      if (!a.IsValid() && nbad++ < 8) bad += "\n  - " + cad::occt::describe_face(out, f);
    }
    throw StageError(src + ": the healed solid fails OpenCASCADE's validity check (BRepCheck)" +
                     (nbad ? ": invalid faces:" + bad : std::string(" (self-intersecting or inconsistent topology)")) +
                     "\nRepair the CAD in its source system or try another tolerance.");
  }
  auto fe = out.free_edges(), me = out.multiple_edges();
  if (!fe.empty() || !me.empty())
    throw StageError(src + ": the fluid solid is not watertight:" + describe_edges(out, fe.empty() ? me : fe));
  if (opt.check_si) {
    ctx.progress(0.9, "self-intersection");
    // interferences within this distance are touches, not crossings (a wing tip's cap fitted to
    // its surfaces within a hundred-thousandth of the body)
    const double si_tol = opt.si_tol > 0 ? opt.si_tol : 10 * opt.tol;
    st["self_intersection_tolerance"] = si_tol;
    SelfInterference si;
    try {
      si = self_interference(out, opt.si_level, ctx.threads() > 1, 0);
      // What OCCT finds exactly is checked again with the fuzzy tolerance: a pair that is gone
      // then only touches within it (a tip cap fitted to its wing within 1e-5 of the body). A
      // pair found only with the tolerance is no crossing either (entities merely closer than it:
      // a blunt trailing edge), so the two are intersected and only pairs found by both count.
      if (si.pairs > 0 && si_tol > 0) {
        SelfInterference fuzzy = self_interference(out, opt.si_level, ctx.threads() > 1, si_tol);
        const int exact = si.pairs;
        si = both(si, fuzzy);
        st["self_intersections_touching"] = exact - si.pairs;
        if (exact > si.pairs)
          ctx.log("heal: " + std::to_string(exact - si.pairs) + " of " + std::to_string(exact) +
                  " self-interference(s) only touch within " + fmt(si_tol) + " (self_intersection_tolerance): not crossings");
      }
    } catch (const Standard_Failure& e) {
      throw StageError(src + ": OpenCASCADE failed checking the fluid solid for self-intersections (" +
                       e.GetMessageString() + "); set check_self_intersection: off to skip the check");
    }
    st["self_intersections"] = si.pairs;
    if (si.aborted) {
      st["self_intersection_check_aborted"] = true;
      ctx.log("heal: warning: OpenCASCADE's self-intersection checker stopped with an error; what it found before "
              "is reported, the rest of the solid is unchecked");
    }
    if (si.pairs > 0) {
      std::string m;
      for (size_t i = 0; i < si.face_pairs.size() && i < 8; ++i)
        m += "\n  - " + cad::occt::describe_face(out, si.face_pairs[i][0]) + " and " +
             cad::occt::describe_face(out, si.face_pairs[i][1]);
      if (si.face_pairs.size() > 8) m += "\n  - ... and " + std::to_string(si.face_pairs.size() - 8) + " more pairs";
      for (auto& o : si.other) m += "\n  - " + o;
      std::string ids;
      std::set<int> fs;
      for (auto& p : si.face_pairs) fs.insert(p.begin(), p.end());
      for (int f : fs) ids += (ids.empty() ? "" : ", ") + std::to_string(f);
      throw StageError(src + ": the fluid solid intersects itself (" + std::to_string(si.pairs) +
                       " interference(s) between non-adjacent faces, edges or vertices that sewing and the boolean "
                       "operations did not resolve)" + (ids.empty() ? std::string(":") : "; faces " + ids + ":") + m +
                       "\nRepair the CAD in its source system (the named faces cross each other)." +
                       (fixes.contains("planar_holes_capped")
                            ? " Heal capped planar openings of this surface model (stats.fixes.planar_holes_capped): "
                              "a cap can cut through the model where the missing face was not flat; "
                              "cap_planar_holes: false shows the openings instead."
                            : ""));
    }
  }
  const double volume = out.volume();
  if (volume <= 0) throw StageError(src + ": the fluid solid has volume " + fmt(volume) + " <= 0 (inside out)");
  std::vector<int> slivers;
  std::string sliver_msg;
  for (int f = 0; f < out.num_faces(); ++f) {
    double a = out.face_area(f), per = perimeter(out.impl().face(f));
    double width = per > 0 ? 2 * a / per : 0;
    if (width < std::min(tol, opt.tol)) {
      slivers.push_back(f);
      sliver_msg += "\n  - " + cad::occt::describe_face(out, f) + ": width about " + fmt(width);
    }
  }
  if (!slivers.empty())
    throw StageError(src + ": " + std::to_string(slivers.size()) + " face(s) are narrower than the tolerance " + fmt(tol) +
                     " (slivers that cannot be meshed)" + (opt.small_faces ? " and fix_small_faces could not remove them:" : ":") +
                     sliver_msg + "\nMerge or remove them in the CAD" +
                     (opt.small_faces ? std::string(".") : std::string(", or set fix_small_faces: true.")));
  cad::apply_tag_rules(out, P.at("tag_overrides"), src);
  for (int f = 0; f < out.num_faces(); ++f) tags[f] = out.face_tag(f);
  if (tags.end() != std::find(tags.begin(), tags.end(), Tag::none)) {
    int nnone = (int)std::count(tags.begin(), tags.end(), Tag::none);
    ctx.log("heal: warning: " + std::to_string(nnone) + " face(s) have no tag");
  }

  st["fixes"] = fixes;
  st["after"] = to_json(count(fluid, tol));
  json summary = cad::occt::summarize(out, ctx.threads(), volume);
  st["volume"] = summary["volume"];
  st["area"] = summary["area"];
  st["face_tags"] = summary["face_tags"];
  st["tag_overrides"] = (int)P.at("tag_overrides").size();
  st["watertight"] = true;
  st["self_intersection_check"] = P.at("check_self_intersection");
  const std::filesystem::path saved = ctx.output("shape", "shape");
  out.save(saved);
  // the contract's figures of the shape as the mesh stages load it (the saved bytes, read back)
  ctx.progress(0.95, "areas and volume for the mesh contract");
  contract::write_cad_reference(contract::cad_reference(cad::Shape::load(saved), ctx.threads()), ctx.output("cad_reference", "cad_reference"));
  ctx.progress(1.0, "done");
}

StageRegistrar reg({.kind = "heal",
                    .version = 6,  // 6: faces kept split where OpenCASCADE throws while unifying them; 3: also writes the CAD reference of the mesh contract; 4: lowers a tolerance that opens a closed input, sews at measured gaps, caps planar openings, tags a curved far field, drops enclosed regions; 5: gaps measured along edges with the same ends, planar loops inside larger openings capped (closed along two planes' crossing), a lone face's openings
                    .summary = "sew, fix and close the CAD into a watertight fluid solid; refuse what cannot be repaired",
                    .libraries = {"OCCT " OCC_VERSION_COMPLETE},
                    .needs = {"shape"},
                    .produces = {{"shape", "shape"}, {"cad_reference", "cad_reference"}},
                    .run = run});
}  // namespace
}  // namespace meshflow::heal
