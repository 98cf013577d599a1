// `meshflow init SECTIONS --blades N`: a blade row's workflow, its layer thickness and wall sizes
// derived from the measured sections (chord, leading-edge radius, throat between neighbouring
// blades, blade height), each written as a comment with the figure it came from.
#include "stages/init/init.hpp"

#include "engine/stage.hpp"
#include "stages/geometry/section_util.hpp"

#include <algorithm>
#include <cmath>

namespace meshflow::init {
namespace {
using geometry::BladeSections;
using geometry::Cyl;

constexpr double kPi = 3.14159265358979323846;

// A section unrolled on its mean radius: (x, r_mean θ).
struct P2 {
  double x, y;
};
std::vector<P2> unroll(const std::vector<Cyl>& loop, double& r_mean) {
  r_mean = 0;
  for (auto& p : loop) r_mean += p.r / loop.size();
  std::vector<P2> out;
  for (auto& p : loop) out.push_back({p.x, r_mean * p.t});
  return out;
}
double dist(P2 a, P2 b) { return std::hypot(a.x - b.x, a.y - b.y); }
// Radius of the circle through three points (inf when they are collinear).
double circumradius(P2 a, P2 b, P2 c) {
  double cross = (b.x - a.x) * (c.y - a.y) - (b.y - a.y) * (c.x - a.x);
  if (std::abs(cross) < 1e-300) return INFINITY;
  return dist(a, b) * dist(b, c) * dist(c, a) / (2 * std::abs(cross));
}
// Radius of curvature at point i of a closed loop: the circle through it and its two neighbours.
double radius_at(const std::vector<P2>& s, size_t i) {
  size_t n = s.size();
  return circumradius(s[(i + n - 1) % n], s[i], s[(i + 1) % n]);
}

// Angle of a mean line (x increasing) at x, linear between its points.
double angle_at(const std::vector<Cyl>& m, double x) {
  for (size_t j = 0; j + 1 < m.size(); ++j)
    if (x >= m[j].x && x <= m[j + 1].x)
      return m[j + 1].x > m[j].x ? m[j].t + (x - m[j].x) / (m[j + 1].x - m[j].x) * (m[j + 1].t - m[j].t) : m[j].t;
  return x < m[0].x ? m[0].t : m.back().t;
}

}  // namespace

BladeFigures measure_blade(const BladeSections& bs, int blades, double to_result) {
  BladeFigures f;
  f.blades = blades;
  f.pitch_angle = 2 * kPi / blades;
  f.chord = INFINITY, f.le_radius = INFINITY, f.min_radius = INFINITY, f.throat = INFINITY;
  for (size_t k = 0; k < bs.loops.size(); ++k) {
    double rm = 0;
    auto s = unroll(bs.loops[k], rm);
    for (auto& p : s) p.x *= to_result, p.y *= to_result;
    rm *= to_result;
    size_t n = s.size();
    // the leading edge: the smallest x (loops start within a few points of it); the chord: the
    // farthest point from it
    size_t ile = 0;
    for (size_t i = 1; i < n; ++i)
      if (s[i].x < s[ile].x) ile = i;
    double chord = 0;
    for (auto& p : s) chord = std::max(chord, dist(p, s[ile]));
    if (chord < f.chord) f.chord = chord, f.chord_section = (int)k;
    double le = radius_at(s, ile);
    if (le < f.le_radius) f.le_radius = le, f.le_section = (int)k;
    for (size_t i = 0; i < n; ++i) {
      double r = radius_at(s, i);
      if (r < f.min_radius) f.min_radius = r, f.min_radius_section = (int)k;
    }
    // throat: nearest distance from the blade to its neighbour one pitch round (r_mean 2π/N away)
    const double shift = rm * f.pitch_angle;
    for (size_t i = 0; i < n; ++i)
      for (size_t j = 0; j < n; ++j) {
        double d = std::hypot(s[i].x - s[j].x, s[i].y + shift - s[j].y);
        if (d < f.throat) f.throat = d, f.throat_section = (int)k, f.throat_radius = rm;
      }
  }
  // the widest angle from the camber line: the blade fits a pitch of twice that
  for (size_t k = 0; k < bs.loops.size() && k < bs.mean.size(); ++k)
    for (auto& p : bs.loops[k]) {
      double half = std::abs(p.t - angle_at(bs.mean[k], p.x));
      if (half > f.half_angle) f.half_angle = half, f.half_angle_section = (int)k, f.half_angle_radius = p.r * to_result;
    }
  f.max_blades = f.half_angle > 0 ? (int)std::floor(kPi / f.half_angle - 1e-9) : 1000;
  double rh = bs.hub.front().r, rc = bs.casing.front().r;
  for (auto& p : bs.hub) rh = std::min(rh, p.r);
  for (auto& p : bs.casing) rc = std::max(rc, p.r);
  f.height = (rc - rh) * to_result;
  f.hub_radius = rh * to_result;
  return f;
}

BladeChoices choose_blade(const BladeFigures& f) {
  BladeChoices c;
  // the layer: a twentieth of the shortest chord, at most a fifth of the throat (the shell's medial
  // limit is half the passage's half-width: a quarter of the throat) and a twentieth of the height
  const double by_chord = 0.05 * f.chord, by_throat = 0.2 * f.throat, by_height = 0.05 * f.height;
  c.thickness = std::min({by_chord, by_throat, by_height});
  c.thickness_why = by_chord <= std::min(by_throat, by_height)
                        ? "5% of the shortest chord " + fmt(f.chord) + " (section " + std::to_string(f.chord_section + 1) + ")"
                    : by_throat <= by_height
                        ? "a fifth of the narrowest throat between neighbouring blades, " + fmt(f.throat) + " (section " +
                              std::to_string(f.throat_section + 1) + ", pitch 2*pi*r/N = " + fmt(f.throat_radius * f.pitch_angle) +
                              ")"
                        : "5% of the blade height " + fmt(f.height);
  // the smallest element: one 30-degree turn on the leading edge's radius (half of it)
  c.min_size = 0.5 * f.le_radius;
  c.min_size_why = "half the leading-edge radius " + fmt(f.le_radius) + " (section " + std::to_string(f.le_section + 1) +
                   "): 30-degree turns resolve the nose";
  // the largest: a tenth of the shortest chord, at most a third of the throat and the layer's
  // thickness (twice it left 4 of 10,014 prisms folded round a synthetic blade's leading edge,
  // where the chordwise size is the nose's and the spanwise one max_size)
  const double by_chord_max = 0.1 * f.chord, by_throat_max = f.throat / 3;
  c.max_size = std::min({by_chord_max, by_throat_max, c.thickness});
  c.max_size_why = c.max_size == c.thickness ? "the layer's thickness, so that the prisms round the leading edge stay valid"
                   : c.max_size == by_chord_max ? "a tenth of the shortest chord " + fmt(f.chord)
                                                : "a third of the narrowest throat " + fmt(f.throat);
  c.max_size = std::max(c.max_size, c.min_size);
  return c;
}

}  // namespace meshflow::init
