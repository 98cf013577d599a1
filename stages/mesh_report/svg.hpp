// stages/mesh_report (internal) — a small SVG canvas and the quality colour scale.
// Coordinates are pixels, y down; numbers are written with one decimal (0.1 px).
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

namespace meshflow::mesh_report {

using P2 = std::array<double, 2>;

struct Rgb {
  std::uint8_t r = 0, g = 0, b = 0;
  std::string hex() const;  // "#rrggbb"
};

// Scaled Jacobian to colour: <= 0 (invalid) purple; 0 .. 1 red, orange, yellow, green.
Rgb quality_colour(double scaled_jacobian);
// Light grey shading of a surface by how much it faces the viewer (0 .. 1).
Rgb grey(double facing);

class Svg {
 public:
  Svg(double width, double height) : w_(width), h_(height) {}
  double width() const { return w_; }
  double height() const { return h_; }
  // Paths drawn between begin_group and end_group with an empty stroke take the group's.
  void begin_group(std::string_view stroke, double stroke_width);
  void end_group();
  // A closed polygon; points closer than 0.4 px to the previous one are dropped.
  void polygon(const std::vector<P2>& pts, std::string_view fill, std::string_view stroke, double stroke_width,
               double opacity = 1);
  // Several closed loops in one path (even-odd fill: a loop inside another is a hole).
  void loops(const std::vector<std::vector<P2>>& loops, std::string_view fill, std::string_view stroke, double stroke_width);
  void polyline(const std::vector<P2>& pts, std::string_view stroke, double stroke_width);
  void rect(double x, double y, double w, double h, std::string_view fill, std::string_view stroke = "none");
  void circle(double x, double y, double r, std::string_view fill, std::string_view stroke, double stroke_width);
  // anchor: "start", "middle" or "end"
  void text(double x, double y, std::string_view text, double size = 11, std::string_view anchor = "start",
            std::string_view fill = "#222");
  // The element with a title (tooltip) and an accessible label.
  std::string str(std::string_view title) const;

 private:
  void points(const std::vector<P2>& pts, char first);
  double w_, h_;
  std::string body_;
};

// A horizontal colour bar of quality_colour from -0.1 to 1 with labels, at (x, y).
void quality_legend(Svg& svg, double x, double y, double width);

}  // namespace meshflow::mesh_report
