// `meshflow init`: what a CAD file is (a body to put in a far field, or a fluid domain given as it
// is) and the figures a workflow's choices come from. Measured with cad::Shape's queries only.
#pragma once

#include "stages/cad/cad.hpp"
#include "stages/geometry/blade_sections.hpp"

#include <string>
#include <vector>

namespace meshflow::init {

using cad::Vec3;

struct Analysis {
  std::string units;
  std::string likely_units;  // non-empty: the declared unit gives an implausible size; this one fits
  std::string units_note;    // why, for the workflow's header and init's output
  int solids = 0, shells = 0, faces = 0;
  cad::Box box;        // the whole shape
  double extent = 0;   // largest side of `box`
  // body: a closed body (or several) meshed in a far-field box; domain: the fluid region itself
  // (a solid with a void, or a box-shaped tunnel or channel with the body cut out of it)
  bool domain = false;
  std::string why;     // the rule and figures that decided body vs domain
  // an internal flow (a pipe, tee, nozzle or duct given as its fluid volume): the domain is the
  // solid, its ports (planar open ends) are inflow/outflow, every other face a wall
  bool internal = false;
  struct Port {
    int face = -1;
    Vec3 point, normal;  // a point of the port's plane and its outward normal
    double area = 0;
  };
  std::vector<Port> ports;
  int corners = 0;     // corners of `box` that are vertices of the shape (8: a box-shaped domain)
  std::vector<int> walls;  // faces that will be walls (a domain's faces on its box planes are not)
  cad::Box wall_box;
  double wall_max = 0, wall_min = 0;  // largest and smallest side of wall_box
  // smallest radius of curvature sampled on the walls (inf: all flat) and its face
  double min_radius = 0;
  int min_radius_face = -1;
  int curvature_samples = 0;
  int curvature_skipped = 0;  // samples near a singular point (pole, apex), not counted
  int singular_points = 0;    // vertices of degenerate edges
  // A body standing on a plane (a half model's root): "x-" .. "z+" (the side of its bounding
  // box), or "none"; `stands_why` the faces and areas that decided it.
  std::string symmetry_plane = "none";
  std::string stands_why;
};

// Throws StageError when the shape has no faces or no face could be a wall. `as_body`: read the
// shape as a body whatever the rules say (init's --fluid box).
Analysis analyse(const cad::Shape& shape, bool as_body = false);

// The choices written into the workflow, each with the figure it came from.
struct Choices {
  double thickness = 0;        // shell thickness (a length in the shape's units)
  std::string thickness_why;
  double min_size = 0;         // balance.min_size, a fraction of the walls' largest side
  std::string min_size_why;
  double farfield_size = 1.0;  // sweep.farfield_size, a multiple of the walls' largest side
  std::string farfield_why;
};
Choices choose(const Analysis& a);

// A blade row's figures, measured on its sections in the result's unit (`to_result` converts the
// file's lengths), for the layer thickness and the wall sizes.
struct BladeFigures {
  int blades = 0;
  double pitch_angle = 0;           // 2π/N
  double chord = 0;                 // the shortest section chord
  int chord_section = 0;
  double le_radius = 0;             // the smallest leading-edge radius of curvature
  int le_section = 0;
  double min_radius = 0;            // the smallest radius of curvature anywhere on a section
  int min_radius_section = 0;
  double throat = 0;                // nearest distance to the neighbouring blade, one pitch round
  int throat_section = 0;
  double throat_radius = 0;         // mean radius of that section
  double height = 0, hub_radius = 0;
  // The blade's widest angle from its camber line (half its angular thickness) and where: more
  // than floor(π / half_angle) blades do not fit round the row.
  double half_angle = 0;
  int half_angle_section = 0;
  double half_angle_radius = 0;
  int max_blades = 0;
};
BladeFigures measure_blade(const geometry::BladeSections& bs, int blades, double to_result);

struct BladeChoices {
  double thickness = 0, min_size = 0, max_size = 0;  // lengths in the result's unit
  std::string thickness_why, min_size_why, max_size_why;
};
BladeChoices choose_blade(const BladeFigures& f);

// A figure for the workflow's comments (4 significant digits).
std::string fmt(double v);

}  // namespace meshflow::init
