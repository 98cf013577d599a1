// meshflow tet stage — the narrow door to TetGen (private to stages/tet).
//
// TetGen defines REAL and must be the only foreign library in its translation unit, so it is
// included by tetgen_call.cpp only; this header speaks plain vectors. TetGen runs in a forked
// child process: its chatter (stdout/stderr, even with -Q on errors and warnings) is captured
// and returned as text, and TetGen 1.5.0's crash after reporting bad input (it frees its mesh
// twice when it throws) cannot take the stage down with it; the result comes back on a pipe.
#pragma once

#include <cstdint>
#include <stdexcept>
#include <string>
#include <vector>

namespace meshflow::tet::detail {

// A piecewise linear complex of triangles (0-based point indices).
struct Plc {
  std::vector<double> points;             // x y z per point
  std::vector<double> point_size;         // empty, or the desired edge length at each point (-m)
  std::vector<std::uint32_t> triangles;   // 3 per facet
  std::vector<int> markers;               // one per facet
  std::vector<double> holes;              // x y z per hole point
};

struct TetgenResult {
  std::vector<double> points;             // input points first (same order), then Steiner points
  std::vector<std::uint32_t> tets;        // 4 per tetrahedron (TetGen's orientation)
  std::vector<std::uint32_t> faces;       // boundary triangles, 3 each
  std::vector<int> face_markers;          // the marker of the input facet each one lies on
  std::string output;                     // what TetGen printed
};

// TetGen refused the input (throw code: 1 out of memory, 2 internal error, 3 self-
// intersection, 4 tiny feature, 5 close facets, 10 input error).
struct TetgenFailure : std::runtime_error {
  TetgenFailure(int c, std::string out, const std::string& what)
      : std::runtime_error(what), code(c), output(std::move(out)) {}
  int code;
  std::string output;
};

// Runs tetrahedralize(switches) on the PLC; throws TetgenFailure.
TetgenResult run_tetgen(const Plc& plc, const std::string& switches);

// "1.5.0" (the Debian package's library; the header carries no version macro).
const char* tetgen_version();

}  // namespace meshflow::tet::detail
