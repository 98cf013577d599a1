// stages/mesh_report (internal) — a small renderer of high-order meshes to SVG.
//
// Surface pictures: the boundary faces shown (the wall groups), each drawn as the polygon
// through its vertex and edge nodes (so curved edges look curved), orthographic view, painter's
// algorithm (faces sorted by depth, far first), faces whose fluid side looks away culled.
// Cut pictures: a plane x, y or z = const; each element's faces are split into the small
// triangles of their node lattice, the plane cuts those into segments, and the segments chain
// into the element's cut outline (a curved element's outline is curved). Faces and cut
// outlines are coloured by their element's scaled Jacobian (model::element_quality, computed
// for the elements drawn only, in parallel, deterministically).
#pragma once

#include "stages/mesh_report/svg.hpp"
#include "stages/model/mesh.hpp"
#include "stages/model/quality.hpp"

#include <cstdint>
#include <string>
#include <vector>

namespace meshflow::mesh_report {

using P3 = std::array<double, 3>;

// An element of the mesh's highest dimension.
struct ElemRef {
  std::uint32_t block = 0, element = 0;
};

// A face of the surface shown: its nodes and the element it bounds.
struct SurfaceFace {
  std::vector<std::uint32_t> outline;                     // vertex and edge nodes, in cyclic order
  std::vector<std::array<std::uint32_t, 3>> triangles;    // the node lattice's small triangles
  std::int64_t element = -1;                              // index into Scene::elements (-1: none)
  int corners = 3;                                        // 3 or 4: outline[k * outline.size() / corners]
};

struct Quality {
  double scaled_jacobian = 1;
  bool valid = true;
};

class Scene {
 public:
  Scene(const model::Mesh& mesh, int threads);
  const model::Mesh& mesh() const { return m_; }
  int dimension() const { return dim_; }
  const std::vector<ElemRef>& elements() const { return elements_; }
  std::uint64_t tag(std::size_t element) const { return tags_[element]; }
  // The element with this tag, or -1.
  std::int64_t find(std::uint64_t tag) const;
  P3 node(std::uint32_t i) const { return {m_.x[i], m_.y[i], m_.z[i]}; }
  P3 centroid(std::size_t element) const;  // mean of its nodes
  std::string type_name(std::size_t element) const;  // "prism4"

  // The faces of the pictures: the boundary groups named wall*, else every boundary face (a 2D
  // mesh: its elements). `groups` names them.
  const std::vector<SurfaceFace>& surface() const { return surface_; }
  const std::string& surface_groups() const { return surface_groups_; }

  // Quality of the elements asked for (computed once, in parallel).
  void need_quality(const std::vector<std::int64_t>& elements);
  // Takes every element's quality from `q` (model::mesh_quality of this mesh, as a stage stored
  // it: io::read_quality checks that its blocks are the mesh's); need_quality then computes nothing.
  void use_quality(const model::MeshQuality& q);
  const Quality& quality(std::size_t element) const { return quality_[element]; }

  // The outline loops of every face of an element (for marking it).
  std::vector<std::vector<std::uint32_t>> element_face_outlines(std::size_t element) const;

 private:
  void collect_surface();
  void link_surface_to_elements();
  const model::Mesh& m_;
  int dim_ = 0, threads_ = 1;
  std::vector<ElemRef> elements_;
  std::vector<std::uint64_t> tags_;
  std::vector<std::pair<std::uint64_t, std::uint32_t>> by_tag_;  // sorted
  std::vector<SurfaceFace> surface_;
  std::string surface_groups_;
  std::vector<Quality> quality_;
  std::vector<char> have_quality_;
};

// An orthographic view: `eye` points from the scene to the viewer; `up` is the world axis
// kept upright (0, 1, 2).
struct View {
  P3 eye{1, 1, 1};
  int up = 2;
  std::string name;  // "from +x +y +z"
};

// The surface coloured by quality (or shaded grey with `grey_only`), fitted to width x height.
// `project` (optional) receives the mapping for later marks.
struct Projection {
  P3 right{}, up{}, eye{};
  double scale = 1, ox = 0, oy = 0;
  P2 operator()(const P3& p) const;
  double depth(const P3& p) const;
};
Svg surface_picture(Scene& scene, const View& view, double width, double height, bool grey_only, Projection* project);

// A plane axis = value, and the window of the plane shown: [u0, u1] x [v0, v1] along the
// in-plane axes u = (axis + 1) % 3, v = (axis + 2) % 3.
struct Cut {
  int axis = 2;
  double value = 0;
  double u0 = 0, u1 = 1, v0 = 0, v1 = 1;
};
// The elements the plane cuts within the window: each element's outline loops in (u, v).
struct CutPiece {
  std::size_t element = 0;
  std::vector<std::vector<P2>> loops;
};
std::vector<CutPiece> cut_elements(const Scene& scene, const Cut& cut);
// The trace of the surface on the plane: chains of points (u, v).
std::vector<std::vector<P2>> surface_trace(const Scene& scene, int axis, double value);
// The elements cut, coloured by quality, the surface trace drawn over them, `marked` elements
// labelled with their tags; `width` px wide, the height from the window's aspect.
Svg cut_picture(Scene& scene, const Cut& cut, double width, const std::vector<std::int64_t>& marked = {});

}  // namespace meshflow::mesh_report
