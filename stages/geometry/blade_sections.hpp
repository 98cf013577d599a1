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
//   csv, zrt section tables (section_table.cpp): one point per line, three coordinates: csv
//            x, y, z (Cartesian, x the machine axis); zrt z, r, θ (axial, radius, angle about the
//            axis, degrees unless the header or `angle_unit` says radians). Any of: a UTF-8 byte
//            order mark, CRLF line ends, '#' comments ("# units: cm" declares the length unit),
//            a header line naming the columns (x, y, z / z, r, theta, plus an optional section
//            column; units in brackets, parentheses or after '_': "x [cm]", "theta_deg"),
//            fields separated by commas, tabs or blanks, or by semicolons (then a comma inside a
//            number is its decimal point). Sections are separated by blank lines or text lines
//            ("section 2"), or given by a section column (consecutive rows with one value); each
//            section is a closed loop around the blade (the first point may be repeated at the
//            end); sections go hub to tip (tip to hub is reversed), the first on the hub, the
//            last on the casing (cylinders about x unless given otherwise). Sections with
//            different point counts are resampled to a common count (stats and notes say so).
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
  std::string format;  // "rotor67" | "csv" | "zrt"
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
  std::string units;      // the length unit the file declares ("" when it does not say)
  // How the file was read (header, separators, sections, units, resampling), one line each, for
  // logs and init's comments.
  std::vector<std::string> notes;
  int resampled_from = 0;  // >0: the file's sections had different point counts (the largest)
};

// A section table's coordinates: csv x, y, z or zrt z, r, θ.
enum class TableLayout { xyz, zrt };
struct TableOptions {
  TableLayout layout = TableLayout::xyz;
  std::string angle_unit;  // zrt: "deg" | "rad" | "" (the header's unit, else degrees)
  // Hub and casing radii: when <= 0, the smallest radius of the first section and the largest of
  // the last one.
  double hub_radius = 0, casing_radius = 0;
};

// A Rotor 67 export: the text has a "Surface number" block (any case), as parse_rotor67 needs.
bool is_rotor67_export(std::string_view text);
// Parses a Rotor 67 export file held in memory. `source` names it in messages.
BladeSections parse_rotor67(std::string_view text, const std::string& source);
// Parses a section table held in memory (csv or zrt layout, see above).
BladeSections parse_blade_table(std::string_view text, const std::string& source, const TableOptions& o);
// The csv layout (x, y, z) with the given hub and casing radii.
BladeSections parse_blade_csv(std::string_view text, const std::string& source, double hub_radius = 0,
                              double casing_radius = 0);
// The layout a table's header names: zrt when it has r and theta columns, else xyz.
TableLayout detect_table_layout(std::string_view text);

}  // namespace meshflow::geometry
