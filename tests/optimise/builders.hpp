// Curved order-P test meshes on CAD for the optimise tests, built from the faces' (u,v)
// parameterisations with nodes classified by the linear mesh contract (stages/sweep/sweep.hpp)
// and with high-order nodes DELIBERATELY badly placed: edge nodes bunched towards one end
// (s = xi - bunch xi (1 - xi) along the (u,v) segment) and bowed sideways in (u,v) (bump),
// face-interior nodes shifted in (u,v). Every node lies exactly on the CAD.
#pragma once

#include "stages/cad/cad.hpp"
#include "stages/model/mesh.hpp"

#include <filesystem>

namespace opttest {

// OCCT-made shapes saved as "shape" artifacts (shapes.cpp): a sphere of radius R at the origin
// (one face, a seam and two pole edges) and a cylinder of radius R, height H on z = 0.
void save_sphere(const std::filesystem::path& file, double R = 1.0);
void save_cylinder(const std::filesystem::path& file, double R = 1.0, double H = 1.0);

struct Distortion {
  double bunch = 0.3;     // edge nodes towards the edge's lower-numbered end (|bunch| < 1 keeps them ordered)
  double bump = 0.0;      // sideways bow of edges inside faces, fraction of the edge's (u,v) length
  // shift of face-interior nodes (at the element's centre), fraction of the element's (u,v) size
  double interior_u = 0.0, interior_v = 0.0;
  int interior_only = -1;  // >= 0: shift only the face nodes of this element (in build order)
};

// Triangles of order P on the sphere's face over u in [u0,u1], v in [v0,v1] (nu x nv cells,
// two triangles each), all nodes classified on the face. thickness > 0 adds a layer of prisms
// lifted radially by `thickness` (layer nodes in the volume (3,1), no parameters).
struct Patch {
  double u0 = 0.6, u1 = 2.2, v0 = -0.6, v1 = 0.6;
  int nu = 4, nv = 3;
};
meshflow::model::Mesh sphere_patch(const meshflow::cad::Shape& s, int P, const Patch& patch, const Distortion& d,
                                   double thickness = 0);

// The whole lateral face of the cylinder in nu x nv quads of order P, with lines on its CAD
// edges (the two circles and the seam); nodes on the circles and the seam are classified on
// those edges (t by projection), the two CAD vertices on the vertices.
meshflow::model::Mesh cylinder_quads(const meshflow::cad::Shape& s, int P, int nu, int nv, const Distortion& d);

// Largest |S(u,v) - x| (or |C(t) - x|) over the nodes classified on CAD edges and faces.
double max_param_error(const meshflow::model::Mesh& m, const meshflow::cad::Shape& s);

}  // namespace opttest
