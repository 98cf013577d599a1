// `meshflow init`'s measurements of a CAD file: body or domain, walls, length scales, curvature.
#include "stages/init/init.hpp"

#include "stages/cad/domain_rules.hpp"

#include "engine/stage.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <thread>

namespace meshflow::init {

std::string fmt(double v) {
  char b[32];
  std::snprintf(b, sizeof b, "%.4g", v);
  return b;
}

namespace {
using cad::Box;
using cad::Shape;
using cad::Vec3;
using cad::box_sides;

double side(const Box& b, int k) { return b.hi[k] - b.lo[k]; }
double largest_side(const Box& b) { return std::max({side(b, 0), side(b, 1), side(b, 2)}); }
double smallest_side(const Box& b) { return std::min({side(b, 0), side(b, 1), side(b, 2)}); }
double distance(const Vec3& a, const Vec3& b) { return std::hypot(a.x - b.x, a.y - b.y, a.z - b.z); }

// A solid with more shells than solids: inner shells, holes in the fluid.
bool has_voids(const Analysis& a) { return a.solids > 0 && a.shells > a.solids; }

// The faces of a domain's outer shell: those connected (through shared edges) to a face that
// reaches the bounding box. With holes (inner shells), heal tags the outer shell farfield and the
// inner shells walls, whatever their shapes (a far-field sphere is not on a box plane).
std::vector<char> outer_shell(const Shape& s, const Box& b, double tol) {
  std::vector<char> outer(s.num_faces(), 0);
  std::vector<int> stack;
  for (int f = 0; f < s.num_faces(); ++f) {
    Box fb = s.face_box(f);
    for (int k = 0; k < 3; ++k)
      if (std::abs(fb.lo[k] - b.lo[k]) <= 2 * tol || std::abs(fb.hi[k] - b.hi[k]) <= 2 * tol) {
        if (!outer[f]) outer[f] = 1, stack.push_back(f);
        break;
      }
  }
  while (!stack.empty()) {
    int f = stack.back();
    stack.pop_back();
    for (int g : s.face_neighbours(f))
      if (!outer[g]) outer[g] = 1, stack.push_back(g);
  }
  return outer;
}

// Every face next to planar face f leaves its plane at a right angle (within 60 degrees) at
// its shared edges' midpoints: a duct's sides at its open end; a rounded box's fillets, tangent
// to its flat faces, do not.
bool walls_leave_square(const Shape& s, int f, const Vec3& n) {
  for (int e : s.face_edges(f)) {
    if (s.edge_degenerate(e)) continue;
    auto r = s.edge_range(e);
    const Vec3 mid = s.edge_point(e, 0.5 * (r.lo + r.hi));
    for (int g : s.edge_faces(e)) {
      if (g == f) continue;
      auto pr = s.project_to_face(g, mid);
      const Vec3 m = s.face_normal(g, pr.u, pr.v);
      if (std::abs(n.x * m.x + n.y * m.y + n.z * m.z) > 0.5) return false;
    }
  }
  return true;
}

// The ports of an internal flow: planar faces bounded by one loop, compact (area / perimeter^2
// at least 0.05: a circle 0.08, a square 0.0625, a 2.6:1 rectangle 0.05, an airfoil section
// 0.02), left at a right angle by the faces next to them, the whole shape on one side of their
// plane (the open ends of a duct, not a pocket's floor), and no other port next to them (a box's
// faces are next to each other; a duct's ends are not).
std::vector<Analysis::Port> find_ports(const Shape& s, double tol) {
  std::vector<Analysis::Port> cand;
  std::vector<Vec3> vertices;
  for (int v = 0; v < s.num_vertices(); ++v) vertices.push_back(s.vertex_point(v));
  for (int f = 0; f < s.num_faces(); ++f) {
    if (s.face_surface_type(f) != "plane" || s.face_wires(f).size() != 1) continue;
    double perimeter = 0;
    for (int e : s.face_edges(f)) perimeter += s.edge_length(e);
    const double area = s.face_area(f);
    if (!(perimeter > 0) || area / (perimeter * perimeter) < 0.05) continue;
    auto uv = s.face_uv_bounds(f);
    Vec3 p = s.face_point(f, 0.5 * (uv.u0 + uv.u1), 0.5 * (uv.v0 + uv.v1)), n = s.face_normal(f, 0.5 * (uv.u0 + uv.u1), 0.5 * (uv.v0 + uv.v1));
    if (!walls_leave_square(s, f, n)) continue;
    int above = 0, below = 0;
    for (auto& q : vertices) {
      double d = (q.x - p.x) * n.x + (q.y - p.y) * n.y + (q.z - p.z) * n.z;
      above += d > 2 * tol, below += d < -2 * tol;
    }
    if (above && below) continue;
    if (above) n = {-n.x, -n.y, -n.z};  // outward: away from the shape
    cand.push_back({f, p, n, area});
  }
  std::vector<Analysis::Port> ports;
  for (auto& c : cand) {
    bool next_to_port = false;
    for (int g : s.face_neighbours(c.face))
      for (auto& d : cand) next_to_port |= d.face == g;
    if (!next_to_port) ports.push_back(c);
  }
  return ports;
}

// An internal flow: three ports or more (a tee, a manifold), or two that do not face away from
// each other (a bend), or two facing away three port diameters apart or more (a pipe, a nozzle;
// a cylinder as long as it is wide is a body). Returns why, or "" when it is none.
std::string internal_flow(const Shape& s, Analysis& a, double tol) {
  auto ports = find_ports(s, tol);
  if (ports.size() < 2) return "";
  std::string why;
  if (ports.size() >= 3) {
    why = std::to_string(ports.size()) + " ports (planar open ends, the shape behind each)";
  } else {
    const auto &p = ports[0], &q = ports[1];
    const double cosine = p.normal.x * q.normal.x + p.normal.y * q.normal.y + p.normal.z * q.normal.z;
    const double apart = distance(p.point, q.point);
    const double across = 2 * std::sqrt(std::max(p.area, q.area) / 3.14159265358979);
    if (cosine > -0.95)
      why = "2 ports (planar open ends) whose outward normals turn by " + fmt(std::acos(std::clamp(cosine, -1.0, 1.0)) * 180 / 3.14159265358979) + " degrees (a bend)";
    else if (apart >= 3 * across)
      why = "2 opposite ports (planar open ends) " + fmt(apart / across) + " port diameters apart (a pipe or nozzle)";
    else
      return "";
  }
  a.ports = ports;
  return why + ": the file is the fluid volume of an internal flow; the ports are inflow and outflow (farfield), the "
               "other faces walls. Give --fluid box to mesh the flow around it instead";
}

// The body-or-domain rule, with the figures it used. A tunnel or channel covers each side of its
// box with its walls (a machined block with 8 corners on its box does not: its steps and pockets
// leave the sides open); a body cut into a symmetry plane leaves that plane mostly whole and its
// walls a small part of the domain's surface (a pocket milled into a part does not).
void classify(const Shape& s, Analysis& a, double tol, const std::vector<char>& far) {
  a.corners = cad::box_corner_vertices(s, a.box, tol);
  const auto cover = cad::box_side_coverage(s, a.box, tol);
  const double least_cover = *std::min_element(cover.begin(), cover.end());
  double area = 0, off_box = 0;
  for (int f = 0; f < a.faces; ++f) {
    double fa = s.face_area(f);
    area += fa;
    if (box_sides(s, f, a.box, tol).empty() && !far[f]) off_box += fa;
  }
  const double wall_share = area > 0 ? off_box / area : 1;
  // a cut face counts only in a far field that is no box (a half sphere, a half cylinder): in a
  // box it is a tunnel (the rule above); with no far field at all it is a block with a hole
  // through it, a body (random-cad's filleted blocks were read as domains and failed in sweep)
  const bool curved_far_field = std::find(far.begin(), far.end(), 1) != far.end();
  std::vector<int> cut;
  if (curved_far_field)
    for (int f : cad::cut_box_faces(s, a.box, tol))
      for (auto [k, hi] : box_sides(s, f, a.box, tol))
        if (cover[2 * k + hi] >= 0.5 && wall_share < 0.5) cut.push_back(f);
  if (has_voids(a)) {
    a.domain = true;
    a.why = std::to_string(a.solids) + " solid(s) with " + std::to_string(a.shells) +
            " shells: the inner shells are holes in the fluid, so the file is the fluid domain";
  } else if (a.corners == 8 && a.faces > 6 && least_cover >= 0.9) {
    a.domain = true;
    a.why = "all 8 corners of its bounding box are vertices, its planar faces cover every side of the box (at least " +
            fmt(100 * least_cover) + " %) and it has " + std::to_string(a.faces) +
            " faces: a box-shaped tunnel or channel with the body cut out of it, so the file is the fluid domain";
  } else if (!cut.empty()) {
    a.domain = true;
    a.why = "face " + std::to_string(cut[0]) + (cut.size() > 1 ? " (and " + std::to_string(cut.size() - 1) + " more)" : "") +
            " lies on a plane of its bounding box and has a hole bounded by faces off that plane, which (but for a curved far "
            "field) make " +
            fmt(100 * wall_share) + " % of its area: a symmetry plane or tunnel wall with a body cut into it, which only "
            "the fluid around a body has, so the file is the fluid domain";
  } else if (std::string why = a.solids == 1 && a.shells == 1 ? internal_flow(s, a, tol) : std::string(); !why.empty()) {
    a.domain = a.internal = true;
    a.why = why;
  } else {
    a.domain = false;
    a.why = std::to_string(a.corners) + " of the 8 corners of its bounding box are vertices (its planar faces cover " +
            fmt(100 * least_cover) + " % of its least covered side), no face on its box has a body cut into it and it "
            "has no inner shell: a body, meshed in a far-field box around it";
  }
}

// A solid with inner shells whose every face connects to its outer shell has no separate body
// inside: the shells are cavities of a body (an airliner's tanks, a loose surface), not holes in
// a fluid. It is read as a body; heal drops the enclosed cavities.
void body_with_cavities(Analysis& a) {
  a.domain = false;
  a.why = std::to_string(a.solids) + " solid(s) with " + std::to_string(a.shells) +
          " shells, but every face connects to the outer shell (no body lies inside it): a body with enclosed "
          "cavities, meshed in a far-field box around it (heal drops the cavities)";
}

// A length unit whose figures make an implausible object: a declared mm (or inch) with a whole
// model under a millimetre is a file in metres written as mm; a declared m with a model over a
// kilometre is one in mm written as m. Empty when the size is plausible.
std::string likely_units(const std::string& declared, double extent) {
  if ((declared == "mm" || declared == "in" || declared == "inch") && extent < 1) return "m";
  if (declared == "m" && extent > 2000) return "mm";
  return "";
}

// Smallest radius of curvature over a grid of points inside each wall face (both principal
// curvatures, convex and concave alike): the balance stage's curvature rule needs it.
// Samples near a singular point (a vertex of a degenerate edge: a sphere's pole, a cone's apex)
// are not counted: an apex's curvature is unbounded and a pole's grid is crowded, neither a
// feature size the walls can be meshed to; the surface mesher grades into them.
void sample_curvature(const Shape& s, Analysis& a) {
  constexpr int n = 12;
  std::vector<Vec3> singular;
  for (int e = 0; e < s.num_edges(); ++e)
    if (s.edge_degenerate(e)) singular.push_back(s.vertex_point(s.edge_vertices(e)[0]));
  a.singular_points = (int)singular.size();
  const double near = 0.05 * a.wall_max;
  double kmax = 0;
  for (int f : a.walls) {
    auto uv = s.face_uv_bounds(f);
    for (int i = 0; i < n; ++i)
      for (int j = 0; j < n; ++j) {
        double u = uv.u0 + (i + 0.5) / n * (uv.u1 - uv.u0), v = uv.v0 + (j + 0.5) / n * (uv.v1 - uv.v0);
        if (!s.face_contains_uv(f, u, v)) continue;
        Vec3 p = s.face_point(f, u, v);
        if (std::any_of(singular.begin(), singular.end(), [&](const Vec3& q) { return distance(p, q) < near; })) {
          ++a.curvature_skipped;
          continue;
        }
        auto c = s.face_curvature(f, u, v);
        if (!c.defined) continue;
        ++a.curvature_samples;
        double k = std::max(std::abs(c.k1), std::abs(c.k2));
        if (k > kmax) kmax = k, a.min_radius_face = f;
      }
  }
  a.min_radius = kmax > 0 ? 1 / kmax : std::numeric_limits<double>::infinity();
}

// Does the body stand on one side of its bounding box, as a half model stands on its root
// plane? Per side, the area of its planar faces lying on that side's plane. A side with such
// faces whose opposite side has none, or less than half as much (a wing's root against its
// smaller flat tip), is a root plane; a cylinder's or a box's two equal ends are not. Exactly
// one root plane makes a half model.
void find_root_plane(const Shape& s, Analysis& a, double tol) {
  double area[3][2] = {};
  int faces[3][2] = {};
  for (int f : a.walls)
    for (auto [k, hi] : box_sides(s, f, a.box, tol)) area[k][hi] += s.face_area(f), ++faces[k][hi];
  std::vector<std::string> roots;
  std::string figures;
  for (int k = 0; k < 3; ++k)
    for (int hi = 0; hi < 2; ++hi) {
      if (!faces[k][hi]) continue;
      std::string name = std::string(1, char('x' + k)) + (hi ? "+" : "-");
      figures += (figures.empty() ? "" : "; ") + std::to_string(faces[k][hi]) + " planar face(s) of area " +
                 fmt(area[k][hi]) + " on its " + name + " side";
      if (area[k][hi] >= 2 * area[k][1 - hi]) roots.push_back(name);
    }
  if (roots.size() == 1) {
    a.symmetry_plane = roots[0];
    a.stands_why = figures + ": it stands on its " + roots[0] +
                   " side, as a half model on its root plane (the opposite side has none, or less than half that area)";
  } else {
    a.stands_why = figures.empty() ? "no planar face lies on a side of its bounding box"
                                   : figures + ": " + (roots.empty() ? "no side has twice the area of its opposite side"
                                                                     : std::to_string(roots.size()) + " sides could be a root");
    a.stands_why += ", so it is not read as a half model";
  }
}

// The faces that will be walls: all of a body's; of a domain, those off its box's planes, not on
// its outer shell when it has holes, and not its curved far field when a body is cut into it.
void find_walls(const Shape& s, Analysis& a, double tol, const std::vector<char>& curved_far) {
  a.walls.clear();
  if (a.internal) {
    for (int f = 0; f < a.faces; ++f)
      if (std::none_of(a.ports.begin(), a.ports.end(), [&](const Analysis::Port& p) { return p.face == f; })) a.walls.push_back(f);
    return;
  }
  const std::vector<char> outer = a.domain && has_voids(a) ? outer_shell(s, a.box, tol) : std::vector<char>(a.faces, 0);
  const bool curved = a.domain && !has_voids(a) && a.corners < 8;
  for (int f = 0; f < a.faces; ++f)
    if (!a.domain || (box_sides(s, f, a.box, tol).empty() && !outer[f] && !(curved && curved_far[f]))) a.walls.push_back(f);
}

}  // namespace

Analysis analyse(const Shape& s, bool as_body) {
  Analysis a;
  a.units = s.units();
  a.solids = s.num_solids();
  a.shells = s.num_shells();
  a.faces = s.num_faces();
  if (a.faces == 0) throw StageError("the CAD file holds no faces: nothing to mesh");
  a.box = s.box(static_cast<int>(std::max(1u, std::thread::hardware_concurrency())));  // the faces' boxes in parallel: the same box
  a.extent = largest_side(a.box);
  const double tol = 1e-6 * std::hypot(side(a.box, 0), side(a.box, 1), side(a.box, 2));
  // the faces of a curved far field (cad::curved_farfield), found once for both rules
  std::vector<char> far(a.faces, 0);
  for (int f : cad::curved_farfield(s, a.box, tol)) far[f] = 1;
  classify(s, a, tol, far);
  if (as_body && a.domain) {
    a.domain = a.internal = false;
    a.ports.clear();
    a.why = "read as a body because --fluid box says so (the rules said: " + a.why + ")";
  }
  find_walls(s, a, tol, far);
  if (a.walls.empty() && a.domain && has_voids(a)) {
    body_with_cavities(a);
    find_walls(s, a, tol, far);
  }
  if (a.walls.empty())
    throw StageError("every face of the domain lies on its bounding box: there is no body to put a boundary layer on");
  a.likely_units = likely_units(a.units, a.extent);
  if (!a.likely_units.empty())
    a.units_note = "the file declares " + a.units + " but its largest side is " + fmt(a.extent) + " " + a.units +
                   ": likely " + a.likely_units + " (rerun with --units " + a.likely_units + " if so; meshing is the same, the figures' unit changes)";
  a.wall_box = s.face_box(a.walls[0]);
  for (int f : a.walls) {
    Box b = s.face_box(f);
    a.wall_box.lo = {std::min(a.wall_box.lo.x, b.lo.x), std::min(a.wall_box.lo.y, b.lo.y), std::min(a.wall_box.lo.z, b.lo.z)};
    a.wall_box.hi = {std::max(a.wall_box.hi.x, b.hi.x), std::max(a.wall_box.hi.y, b.hi.y), std::max(a.wall_box.hi.z, b.hi.z)};
  }
  a.wall_max = largest_side(a.wall_box);
  a.wall_min = smallest_side(a.wall_box);
  sample_curvature(s, a);
  if (!a.domain) find_root_plane(s, a, tol);
  return a;
}

Choices choose(const Analysis& a) {
  Choices c;
  // Layer thickness: 5% of the body's largest side (a wing's span or chord, a sphere's diameter),
  // and at most a quarter of its smallest side, so that a slender body (a wing's thickness, a
  // thin cylinder's diameter) keeps room outside its layer. The shell thins it further where
  // walls face each other closely.
  double by_length = 0.05 * a.wall_max, by_width = 0.25 * a.wall_min;
  c.thickness = std::min(by_length, by_width);
  c.thickness_why = by_length <= by_width
                        ? "5% of the walls' largest side " + fmt(a.wall_max) + " " + a.units
                        : "a quarter of the walls' smallest side " + fmt(a.wall_min) + " " + a.units +
                              " (5% of the largest side, " + fmt(by_length) + ", would leave too little room)";
  // Smallest wall element: one element turns by at most 30 degrees on the tightest curvature
  // (balance's curvature rule), bounded to [0.3%, 1%] of the walls' largest side.
  constexpr double turn = 30 * 3.14159265358979 / 180;
  double by_curvature = std::isfinite(a.min_radius) ? turn * a.min_radius / a.wall_max : 1.0;
  c.min_size = std::clamp(by_curvature, 0.003, 0.01);
  c.min_size_why = std::isfinite(a.min_radius)
                       ? "the tightest radius of curvature on the walls is " + fmt(a.min_radius) + " " + a.units +
                             " (face " + std::to_string(a.min_radius_face) + ", " + std::to_string(a.curvature_samples) +
                             " samples" +
                             (a.curvature_skipped ? "; " + std::to_string(a.curvature_skipped) + " within 5% of the walls' "
                                                    "largest side of " + std::to_string(a.singular_points) +
                                                    " singular point(s), a pole or an apex, not counted: the mesher "
                                                    "grades into them"
                                                  : std::string()) +
                             "): 30 degrees of it is " + fmt(by_curvature) +
                             " of the walls' largest side, kept within [0.003, 0.01]"
                       : "the walls are flat (" + std::to_string(a.curvature_samples) + " samples): the default 0.01";
  // Far-field elements: the walls' largest side in a body's box (5 body lengths away); in a
  // given domain, a tenth of the domain's extent when that is larger, so that a far field many
  // body lengths away gets large elements rather than millions of small ones.
  if (a.domain) {
    double by_domain = 0.1 * a.extent / a.wall_max;
    c.farfield_size = std::max(1.0, by_domain);
    c.farfield_why = "the domain's largest side is " + fmt(a.extent) + " " + a.units + ", " +
                     fmt(a.extent / a.wall_max) + " times the walls' largest side: far-field elements of " +
                     (by_domain > 1.0 ? "a tenth of the domain's side" : "the walls' largest side");
  } else {
    c.farfield_size = 1.0;
    c.farfield_why = "the far-field box is 11 times the body's largest side (heal's box_padding 5): far-field elements "
                     "of the body's largest side";
  }
  return c;
}

}  // namespace meshflow::init
