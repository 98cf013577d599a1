// meshflow CAD — PRIVATE header: OCCT types behind cad::Shape. Include it only from .cpp files
// of stages/cad, stages/geometry and stages/heal (never from a public header).
#pragma once

#include "stages/cad/cad.hpp"

#include <BRepTopAdaptor_FClass2d.hxx>
#include <Geom_Curve.hxx>
#include <Geom_Surface.hxx>
#include <Message_Printer.hxx>
#include <Message_Messenger.hxx>
#include <ShapeAnalysis_Surface.hxx>
#include <TopTools_IndexedDataMapOfShapeListOfShape.hxx>
#include <TopTools_IndexedMapOfShape.hxx>
#include <TopoDS.hxx>
#include <TopoDS_Edge.hxx>
#include <TopoDS_Face.hxx>
#include <TopoDS_Shape.hxx>
#include <gp_Pnt.hxx>
#include <gp_Vec.hxx>

#include <nlohmann/json_fwd.hpp>

#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

namespace meshflow::cad {

struct Shape::Impl {
  TopoDS_Shape shape;
  std::string units = "mm";
  TopTools_IndexedMapOfShape solids, shells, faces, edges, vertices;
  std::vector<Tag> tags;  // by face id
  TopTools_IndexedDataMapOfShapeListOfShape edge_faces;  // edge -> faces (unique)
  std::vector<Handle(Geom_Surface)> surfaces;            // by face id, location applied
  std::vector<Handle(Geom_Curve)> curves;                // by edge id (null when degenerate)
  std::vector<Range> ranges;                             // by edge id
  // lazy projection caches (not thread safe: see Shape::clone)
  mutable std::vector<Handle(ShapeAnalysis_Surface)> face_proj;
  struct Seeds {
    std::vector<gp_Pnt> p;
    std::vector<double> u, v;
    std::optional<UVBounds> box;  // face_uv_bounds, kept (the grid above and project_to_face_near)
  };
  mutable std::vector<Seeds> face_seeds;  // a grid over the face's (u,v) bounds: start points
  // point-in-face classifiers, by face id and tolerance (face_contains_uv)
  mutable std::vector<std::map<double, std::unique_ptr<BRepTopAdaptor_FClass2d>>> face_class;

  // Builds the maps and geometry caches from `shape`; tags sized to the faces (none).
  void index();
  const TopoDS_Face& face(int i) const;
  const TopoDS_Edge& edge(int i) const;
};

namespace occt {

inline Vec3 vec(const gp_Pnt& p) { return {p.X(), p.Y(), p.Z()}; }
inline Vec3 vec(const gp_Vec& p) { return {p.X(), p.Y(), p.Z()}; }
inline gp_Pnt pnt(const Vec3& p) { return gp_Pnt(p.x, p.y, p.z); }

// A Shape around an OCCT shape. `tags` (by face id in TopExp::MapShapes order) may be empty
// (all none). The shape's triangulations are removed so that saving is deterministic.
Shape make_shape(const TopoDS_Shape& s, const std::string& units, std::vector<Tag> tags = {});
inline const TopoDS_Shape& shape(const Shape& s) { return s.impl().shape; }

// Tags for the faces of `to` (MapShapes order), taken from the face of `from` on which an
// interior point of each face of `to` lies (within tol); none where no face matches.
std::vector<Tag> transfer_tags(const Shape& from, const TopoDS_Shape& to, double tol);

// A point strictly inside the trimmed face (for classification and tag transfer).
gp_Pnt interior_point(const TopoDS_Face& f);

// Tags of a fluid domain inside an axis-aligned box, by geometry (faces in MapShapes order):
// a face lying in a plane of the shape's bounding box (within tol) is `farfield`, or
// `symmetry` when it shares an edge with a face that is not on the box (the wall a body is
// mounted on: a wing root, a half model's symmetry plane); every other face is `wall`.
std::vector<Tag> tags_by_box(const TopoDS_Shape& s, double tol);

// "face 3 (wall, bspline, centre (1,2,3))": for error messages.
std::string describe_face(const Shape& s, int face);

// Routes OCCT's Message output (the default messenger: STEP/IGES readers, ShapeFix, Sewing)
// to `sink` while alive, instead of the console; restores the previous printers after.
class Log {
 public:
  explicit Log(std::function<void(const std::string&)> sink);
  ~Log();
  Log(const Log&) = delete;
  Log& operator=(const Log&) = delete;

 private:
  Handle(Message_Messenger) messenger_;
  Message_SequenceOfPrinters saved_;
};

// Summary of a shape for golden regression and stats (counts, volume, area, bbox, tags).
// threads: for the box (Shape::box); volume: the shape's volume() when the caller has it already.
nlohmann::json summarize(const Shape& s, int threads = 1, std::optional<double> volume = {});

// Removes OCCT's console printers for good (used where no sink is available).
void silence();

}  // namespace occt
}  // namespace meshflow::cad
