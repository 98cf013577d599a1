// meshflow geometry — readers of blade section files for the `blade_sector` kind (OCCT-free, so
// that the libFuzzer target tests/fuzz/rotor_fuzz.cpp can drive them from memory).
//
// Frame: the machine axis is the x axis; a point at axial position x, radius r and angle θ is
// (x, r cos θ, r sin θ). Angles are radians, lengths in the file's unit.
//
// Formats
//   rotor67  NASA's Rotor 67 "geometry for export" file (Wood, Strazisar; NASA TP-2879): a header
//            line "JM NS NB JLE JTE" followed by a line of those five integers (points per
//            streamsurface, number of streamsurfaces, blades, leading- and trailing-edge index,
//            1-based), then NS blocks "Surface number k" each holding four quantities (title line,
//            scale factor line, JM values): axial distance x, r·θ of the upper (suction) surface,
//            the tangential thickness Δ(r·θ) (subtracted from the upper surface to give the lower
//            one), radius r. Surface 1 is the hub, surface NS the casing; the blade spans
//            JLE..JTE with circular leading and trailing edges; the points outside are the
//            streamsurface's extension upstream and downstream (thickness 0).
//   csv      one point per line "x,y,z" (commas, semicolons or blanks), '#' comments; sections are
//            separated by a blank line or a text line (e.g. "section 2"); each section is a
//            closed loop around the blade (the first point may be repeated at the end), all with
//            the same number of points, ordered hub to tip, the first on the hub, the last on the
//            casing (both cylinders about x unless given otherwise).
//
// Errors: every malformed input throws meshflow::StageError naming the source, the line and
// what is wrong; no other exception escapes (the fuzz target checks this).
#pragma once

#include <cstddef>
#include <string>
#include <string_view>
#include <vector>

namespace meshflow::geometry {

struct Cyl {
  double x = 0, r = 0, t = 0;  // axial, radius, angle θ (radians)
};

struct BladeSections {
  std::string format;  // "rotor67" | "csv"
  int blades = 0;      // from the file (rotor67), 0 when the file does not say (csv)
  // One closed loop per section, hub to tip (not repeated at the end): suction side from the
  // leading to the trailing edge, then the pressure side back.
  std::vector<std::vector<Cyl>> loops;
  // The mean (camber) line of each section, upstream to downstream, the same count in every
  // section; for rotor67 the whole streamsurface (its extension up- and downstream included).
  std::vector<std::vector<Cyl>> mean;
  // Meridians (x, r) of the hub and the casing, upstream to downstream (Cyl::t unused).
  std::vector<Cyl> hub, casing;
  int tip_section = -1;  // rotor67: NS-2 (section 13 of 14, 0-based 12): the blade tip of the file
};

// A Rotor 67 export: the text has a "Surface number" block (any case), as parse_rotor67 needs.
bool is_rotor67_export(std::string_view text);
// Parses a Rotor 67 export file held in memory. `source` names it in messages.
BladeSections parse_rotor67(std::string_view text, const std::string& source);
// Parses a CSV section file held in memory. Hub and casing radii: when <= 0, the smallest radius
// of the first section and the largest of the last one.
BladeSections parse_blade_csv(std::string_view text, const std::string& source, double hub_radius = 0,
                              double casing_radius = 0);

}  // namespace meshflow::geometry
