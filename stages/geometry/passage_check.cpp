// meshflow geometry — each surface of a blade passage checked against the others (see
// passage_check.hpp).
#include "stages/geometry/passage_check.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>

namespace meshflow::geometry {
namespace {

constexpr double kPi = 3.14159265358979323846;

std::string num(double v) {
  char b[32];
  std::snprintf(b, sizeof b, "%.4g", v);
  return b;
}

// Radius of a meridian at axial position x (held constant beyond its ends).
double radius_at(const std::vector<Cyl>& m, double x) {
  for (size_t j = 0; j + 1 < m.size(); ++j)
    if (x >= m[j].x && x <= m[j + 1].x)
      return m[j + 1].x > m[j].x ? m[j].r + (x - m[j].x) / (m[j + 1].x - m[j].x) * (m[j + 1].r - m[j].r) : m[j].r;
  return x < m[0].x ? m[0].r : m.back().r;
}
// Angle of a row (x increasing) at x, linear between its points (held beyond its ends).
double angle_at(const std::vector<Cyl>& row, double x) {
  for (size_t j = 0; j + 1 < row.size(); ++j)
    if (x >= row[j].x && x <= row[j + 1].x)
      return row[j + 1].x > row[j].x ? row[j].t + (x - row[j].x) / (row[j + 1].x - row[j].x) * (row[j + 1].t - row[j].t)
                                     : row[j].t;
  return x < row[0].x ? row[0].t : row.back().t;
}

// The smallest margin of one check (positive: clear) and where it occurs.
struct Margin {
  double value = 1e300;
  Cyl at;
  int section = -1;  // 0-based file section, where it applies
  bool hi = false;   // periodic check: the blade meets periodic_hi (else periodic_lo)
  double need = 0;   // periodic check: the largest half tangential thickness, as an angle
  void take(double v, const Cyl& p, int k = -1, bool h = false) {
    if (v < value) value = v, at = p, section = k, hi = h;
  }
  bool seen() const { return value < 1e299; }
};

struct Margins {
  Margin hub_in, hub_out, cas_in, cas_out;  // the hub / casing reach the inflow / outflow plane
  Margin gap;                               // casing above hub between the planes
  Margin root, tip;                         // the blade reaches through the hub / the casing
  Margin p_root, p_tip, p_in, p_out;        // the periodic surface reaches beyond hub, casing, planes
  Margin pitch;                             // the blade between periodic_lo and periodic_hi
  Margin angle;                             // hub and casing faces cover the periodic surfaces
  Margin below_hub, above_casing;           // file sections outside the passage (notes, not faults)
};

bool inside(const PassageSamples& s, const Cyl& p, double tol) {
  return p.r >= radius_at(s.hub, p.x) - tol && p.r <= radius_at(s.casing, p.x) + tol;
}

Margins measure(const PassageSamples& s) {
  Margins m;
  const double tol = 1e-6 * s.height;
  m.hub_in.take(s.x_in - s.hub.front().x, s.hub.front());
  m.hub_out.take(s.hub.back().x - s.x_out, s.hub.back());
  m.cas_in.take(s.x_in - s.casing.front().x, s.casing.front());
  m.cas_out.take(s.casing.back().x - s.x_out, s.casing.back());
  for (int i = 0; i <= 400; ++i) {
    double x = s.x_in + (s.x_out - s.x_in) * i / 400;
    m.gap.take(radius_at(s.casing, x) - radius_at(s.hub, x), Cyl{x, radius_at(s.hub, x), 0});
  }
  for (auto& p : s.blade_root) m.root.take(radius_at(s.hub, p.x) - p.r, p);
  for (auto& p : s.blade_tip) m.tip.take(p.r - radius_at(s.casing, p.x), p);
  for (auto& p : s.periodic_root)
    if (p.x >= s.x_in && p.x <= s.x_out) m.p_root.take(radius_at(s.hub, p.x) - p.r, p);
  for (auto& p : s.periodic_tip)
    if (p.x >= s.x_in && p.x <= s.x_out) m.p_tip.take(p.r - radius_at(s.casing, p.x), p);
  for (auto& p : s.periodic_in)
    if (inside(s, p, 0)) m.p_in.take(s.x_in - p.x, p);
  for (auto& p : s.periodic_out)
    if (inside(s, p, 0)) m.p_out.take(p.x - s.x_out, p);
  for (auto* c : {&s.periodic_root, &s.periodic_tip, &s.periodic_in, &s.periodic_out})
    for (auto& p : *c) m.angle.take(p.r * std::min(p.t - s.ta, s.tb - (p.t + s.pitch)), p);
  for (size_t k = 0; k < s.sections.size() && k < s.periodic_rows.size(); ++k)
    for (auto& p : s.sections[k]) {
      m.below_hub.take(p.r - radius_at(s.hub, p.x), p, (int)k);
      m.above_casing.take(radius_at(s.casing, p.x) - p.r, p, (int)k);
      if (!inside(s, p, tol)) continue;
      double lo = angle_at(s.periodic_rows[k], p.x), mid = lo + 0.5 * s.pitch;
      m.pitch.need = std::max(m.pitch.need, std::abs(p.t - mid));
      m.pitch.take(p.r * (p.t - lo), p, (int)k, false);
      m.pitch.take(p.r * (lo + s.pitch - p.t), p, (int)k, true);
    }
  return m;
}

std::string where(const Cyl& p, const std::string& u) {
  return "x = " + num(p.x) + ", r = " + num(p.r) + " " + u;
}

}  // namespace

std::vector<Finding> check_passage(const PassageSamples& s) {
  const Margins m = measure(s);
  const double tol = 1e-6 * s.height;
  const std::string& u = s.units;
  std::vector<Finding> out;
  auto fatal = [&](const Margin& g, const std::string& surface, const std::string& text) {
    if (g.seen() && g.value <= tol) out.push_back({true, surface, text});
  };
  fatal(m.hub_in, "hub", "the hub does not reach the inflow plane x = " + num(s.x_in) + ": it starts " + num(-m.hub_in.value) + " " + u + " downstream of it");
  fatal(m.cas_in, "casing", "the casing does not reach the inflow plane x = " + num(s.x_in) + ": it starts " + num(-m.cas_in.value) + " " + u + " downstream of it");
  fatal(m.hub_out, "hub", "the hub does not reach the outflow plane x = " + num(s.x_out) + ": it ends " + num(-m.hub_out.value) + " " + u + " upstream of it");
  fatal(m.cas_out, "casing", "the casing does not reach the outflow plane x = " + num(s.x_out) + ": it ends " + num(-m.cas_out.value) + " " + u + " upstream of it");
  fatal(m.gap, "casing", "the casing is not above the hub at " + where(m.gap.at, u) + " (by " + num(-m.gap.value) + " " + u +
                             "): check hub_radius and casing_radius, or the file's first and last sections");
  fatal(m.root, "blade", "the blade does not reach through the hub: its extension below the first section stays " +
                             num(-m.root.value) + " " + u + " above the hub at " + where(m.root.at, u) +
                             "; the first section must lie on the hub (or hub_radius must be at most the first section's smallest radius)");
  fatal(m.tip, "blade", "the blade does not reach through the casing: its extension above the last section stays " +
                            num(-m.tip.value) + " " + u + " below the casing at " + where(m.tip.at, u) +
                            "; the last section must reach the casing (or casing_radius must be at least the last section's largest radius)");
  fatal(m.p_root, "periodic", "the periodic surface does not reach below the hub: it stays " + num(-m.p_root.value) + " " + u +
                                  " above the hub at " + where(m.p_root.at, u) + " (its camber line is extended straight there: shorten upstream/downstream)");
  fatal(m.p_tip, "periodic", "the periodic surface does not reach above the casing: it stays " + num(-m.p_tip.value) + " " + u +
                                 " below the casing at " + where(m.p_tip.at, u) + " (its camber line is extended straight there: shorten upstream/downstream)");
  fatal(m.p_in, "periodic", "the periodic surface does not reach the inflow plane: it ends " + num(-m.p_in.value) + " " + u +
                                " downstream of it at " + where(m.p_in.at, u));
  fatal(m.p_out, "periodic", "the periodic surface does not reach the outflow plane: it ends " + num(-m.p_out.value) + " " + u +
                                 " upstream of it at " + where(m.p_out.at, u));
  if (m.pitch.seen() && m.pitch.value <= tol) {
    const Cyl& p = m.pitch.at;
    int fit = (int)std::floor(kPi / m.pitch.need);
    double pitch_len = p.r * s.pitch;
    out.push_back({true, "periodic",
                   std::string("the periodic surface cuts the blade: at section ") + std::to_string(m.pitch.section + 1) + ", " +
                       where(p, u) + ", the blade reaches " + num(-m.pitch.value) + " " + u + " beyond periodic_" +
                       (m.pitch.hi ? "hi" : "lo") + " (half a pitch, " + num(0.5 * pitch_len) + " " + u +
                       ", from its camber line): the blade is thicker across the passage than the pitch 2*pi*r/N = " +
                       num(pitch_len) + " " + u + " there; at most " + std::to_string(fit) +
                       " blades fit this blade (set `blades`, or thin the sections)"});
  }
  fatal(m.angle, "hub", "the hub and casing faces' angular range does not cover the periodic surfaces (short by " +
                            num(-m.angle.value) + " " + u + " at " + where(m.angle.at, u) + "); report it with the section file");
  auto note = [&](const Margin& g, const std::string& surface, const std::string& text) {
    if (g.seen() && g.value < -1e-4 * s.height) out.push_back({false, surface, text});
  };
  note(m.below_hub, "hub", "section " + std::to_string(m.below_hub.section + 1) + " lies up to " + num(-m.below_hub.value) +
                               " " + u + " inside the hub (at " + where(m.below_hub.at, u) + "): the hub cuts the blade there");
  note(m.above_casing, "casing", "section " + std::to_string(m.above_casing.section + 1) + " lies up to " +
                                     num(-m.above_casing.value) + " " + u + " outside the casing radius (at " +
                                     where(m.above_casing.at, u) + "): the casing cuts the blade there");
  std::stable_sort(out.begin(), out.end(), [](const Finding& a, const Finding& b) { return a.fatal > b.fatal; });
  return out;
}

std::string passage_margins(const PassageSamples& s) {
  const Margins m = measure(s);
  const std::string& u = s.units;
  auto line = [&](const char* what, const Margin& g) {
    return g.seen() ? std::string(what) + " " + num(g.value) + " " + u : std::string(what) + " (not sampled)";
  };
  return "surface checks, smallest margins (positive: clear): " + line("blade below hub by", m.root) + "; " +
         line("blade above casing by", m.tip) + "; " + line("blade inside the pitch by", m.pitch) + "; " +
         line("periodic below hub by", m.p_root) + "; " + line("periodic above casing by", m.p_tip) + "; " +
         line("periodic upstream of inflow by", m.p_in) + "; " + line("periodic downstream of outflow by", m.p_out) + "; " +
         line("hub/casing upstream of inflow by", m.hub_in.value < m.cas_in.value ? m.hub_in : m.cas_in) + "; " +
         line("hub/casing downstream of outflow by", m.hub_out.value < m.cas_out.value ? m.hub_out : m.cas_out) + "; " +
         line("casing above hub by", m.gap) + "; " + line("hub/casing faces round the periodic by", m.angle);
}

}  // namespace meshflow::geometry
