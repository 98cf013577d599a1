// stages/mesh_report — the "mesh" artifact's part of report.html (engine/run_report.hpp): each
// mesh's counts and quality histograms (from the stage's stats.mesh), and for a delivered or
// invalid mesh pictures drawn by a small renderer of its own (render.hpp): the surface (wall
// groups) coloured by scaled Jacobian from two sides, cuts through the boundary layer at stated
// planes with close-ups, and for an invalid mesh the bad elements listed by id and marked.
// Registered with the engine; linked into every meshflow executable as a module.
#pragma once

#include "engine/run_report.hpp"

#include <string>

namespace meshflow::mesh_report {

// The HTML fragment of one mesh artifact (inline SVG; no scripts, nothing external).
std::string mesh_section(const ArtifactReportInput& in);

}  // namespace meshflow::mesh_report
