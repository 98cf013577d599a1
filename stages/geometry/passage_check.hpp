// meshflow geometry — does a blade passage close? Each of blade_sector's surfaces checked against
// the others on samples, before the boolean that builds the passage (OCCT-free: the samples are
// taken in blade_sector.cpp).
//
// The passage is bounded by the hub and the casing (surfaces of revolution about x), the inflow and
// outflow planes x = x_in, x_out, and the periodic surfaces periodic_lo (through the middle of the
// passage, half a pitch below the blade's camber line) and periodic_hi (periodic_lo rotated by one
// pitch); the blade crosses it from below the hub to above the casing. It closes when
//   - the hub and the casing reach both planes and the casing stays above the hub between them;
//   - the blade's extensions reach through the hub and through the casing all round the blade;
//   - the periodic surface reaches below the hub and above the casing over the whole axial range,
//     and beyond both planes over the whole radial range;
//   - the blade lies between periodic_lo and periodic_hi (it is thinner than the pitch) wherever
//     it is inside the passage;
//   - the hub's and casing's angular range covers the periodic surfaces.
#pragma once

#include "stages/geometry/blade_sections.hpp"

#include <string>
#include <vector>

namespace meshflow::geometry {

struct PassageSamples {
  std::string units;
  double pitch = 0, x_in = 0, x_out = 0, height = 0;
  double ta = 0, tb = 0;                      // angular range of the hub and casing faces
  std::vector<Cyl> hub, casing;               // meridians (x, r), upstream to downstream
  std::vector<Cyl> blade_root, blade_tip;     // the blade surface's lower and upper boundary
  std::vector<std::vector<Cyl>> sections;     // the file's sections (closed loops)
  std::vector<std::vector<Cyl>> periodic_rows;  // periodic_lo's rows through each section (same index)
  // periodic_lo's four boundary curves: below the hub, above the casing, upstream, downstream
  std::vector<Cyl> periodic_root, periodic_tip, periodic_in, periodic_out;
};

struct Finding {
  bool fatal = false;    // the passage cannot close (or would be wrong) with this surface as it is
  std::string surface;   // the surface at fault: "blade", "hub", "casing", "periodic", ...
  std::string text;      // what fails, where and by how much, and what to change
};

// The surfaces checked against each other: findings, the fatal ones first.
std::vector<Finding> check_passage(const PassageSamples& s);
// One line per check with its margin (positive: clear), for messages when a later step fails.
std::string passage_margins(const PassageSamples& s);

}  // namespace meshflow::geometry
