// meshflow geometry — the Rotor 67 export reader and the helpers the section readers share (see
// blade_sections.hpp; section tables: section_table.cpp).
#include "stages/geometry/blade_sections.hpp"
#include "stages/geometry/section_util.hpp"

#include "engine/stage.hpp"

#include <algorithm>
#include <array>
#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <string>

namespace meshflow::geometry {
namespace {

constexpr double kPi = 3.14159265358979323846;

struct Lines {
  std::vector<std::string> v;
  explicit Lines(std::string_view t) {
    // a UTF-8 byte order mark (spreadsheet exports write one) is not part of the first line
    if (t.substr(0, 3) == "\xEF\xBB\xBF") t.remove_prefix(3);
    size_t i = 0;
    while (i < t.size()) {
      size_t j = t.find('\n', i);
      if (j == std::string_view::npos) j = t.size();
      std::string l(t.substr(i, j - i));
      if (!l.empty() && l.back() == '\r') l.pop_back();
      // NUL bytes would end strtod's view of the line early: make them visible as garbage
      std::replace(l.begin(), l.end(), '\0', '?');
      v.push_back(std::move(l));
      i = j + 1;
    }
  }
};

std::string upper(std::string s) {
  std::transform(s.begin(), s.end(), s.begin(), [](unsigned char c) { return (char)std::toupper(c); });
  return s;
}
std::vector<std::string> tokens(const std::string& l) {
  std::vector<std::string> out;
  size_t i = 0;
  while (i < l.size()) {
    while (i < l.size() && std::isspace((unsigned char)l[i])) ++i;
    size_t j = i;
    while (j < l.size() && !std::isspace((unsigned char)l[j])) ++j;
    if (j > i) out.push_back(l.substr(i, j - i));
    i = j;
  }
  return out;
}
bool blank(const std::string& l) {
  return std::all_of(l.begin(), l.end(), [](unsigned char c) { return std::isspace(c); });
}

// Parses all numbers of a line (fixed-width fields may touch: "-0.1-0.2" is two numbers).
// Returns false when something else than numbers and separators is on the line.
bool numbers(const std::string& l, std::vector<double>& out, const char* seps = "") {
  const char* p = l.c_str();
  const char* end = p + l.size();
  while (p < end) {
    while (p < end && (std::isspace((unsigned char)*p) || (*seps && std::strchr(seps, *p) && *p))) ++p;
    if (p >= end) break;
    if (!(std::isdigit((unsigned char)*p) || *p == '-' || *p == '+' || *p == '.')) return false;
    char* q = nullptr;
    errno = 0;
    double v = std::strtod(p, &q);
    if (q == p) return false;
    // strtod also reads hex floats ("0x1p3"): the formats are decimal
    for (const char* c = p; c < q; ++c)
      if (*c == 'x' || *c == 'X' || *c == 'p' || *c == 'P') return false;
    if (!std::isfinite(v)) return false;
    out.push_back(v);
    p = q;
  }
  return true;
}


double dist(const Cyl& a, const Cyl& b) {
  double ax = a.r * std::cos(a.t), ay = a.r * std::sin(a.t), bx = b.r * std::cos(b.t), by = b.r * std::sin(b.t);
  return std::sqrt((a.x - b.x) * (a.x - b.x) + (ax - bx) * (ax - bx) + (ay - by) * (ay - by));
}

}  // namespace

[[noreturn]] void fail(const std::string& source, size_t line, const std::string& what) {
  throw StageError("blade section file '" + source + "'" + (line ? ", line " + std::to_string(line) : std::string()) +
                   ": " + what);
}

std::vector<std::string> split_lines(std::string_view t) { return Lines(t).v; }

void check_loops(const BladeSections& b, const std::string& source) {
  for (size_t k = 0; k < b.loops.size(); ++k) {
    const auto& L = b.loops[k];
    double ext = 0;
    for (auto& p : L) ext = std::max(ext, dist(p, L[0]));
    if (!(ext > 0)) fail(source, 0, "section " + std::to_string(k + 1) + " collapses to a point");
    for (size_t i = 0; i < L.size(); ++i)
      if (dist(L[i], L[(i + 1) % L.size()]) <= 1e-9 * ext)
        fail(source, 0, "section " + std::to_string(k + 1) + ": points " + std::to_string(i + 1) + " and " +
                            std::to_string((i + 1) % L.size() + 1) + " of the blade loop coincide");
  }
}

bool is_rotor67_export(std::string_view text) {
  return upper(std::string(text)).find("SURFACE NUMBER") != std::string::npos;
}

BladeSections parse_rotor67(std::string_view text, const std::string& source) {
  Lines L(text);
  const auto& v = L.v;
  // the first "Surface number" line
  size_t first_surface = v.size();
  for (size_t i = 0; i < v.size(); ++i)
    if (upper(v[i]).find("SURFACE NUMBER") != std::string::npos) {
      first_surface = i;
      break;
    }
  if (first_surface == v.size())
    fail(source, 0, "no \"Surface number\" block: this is not a Rotor 67 export file (format: rotor67)");
  // the last "JM NS NB JLE JTE" header before it, and its values on the next line
  long jm = -1, ns = -1, nb = -1, jle = -1, jte = -1;
  size_t hline = 0;
  for (size_t i = 0; i + 1 < first_surface; ++i) {
    auto t = tokens(upper(v[i]));
    if (t == std::vector<std::string>{"JM", "NS", "NB", "JLE", "JTE"}) {
      std::vector<double> x;
      if (!numbers(v[i + 1], x) || x.size() != 5)
        fail(source, i + 2, "expected the five integers JM NS NB JLE JTE after the header line");
      for (double d : x)
        if (d != std::floor(d) || std::abs(d) > 1e9) fail(source, i + 2, "JM NS NB JLE JTE must be integers");
      jm = (long)x[0], ns = (long)x[1], nb = (long)x[2], jle = (long)x[3], jte = (long)x[4];
      hline = i + 2;
    }
  }
  if (jm < 0) fail(source, 0, "no \"JM NS NB JLE JTE\" header line with its values before the first surface");
  if (jm < 4 || jm > 100000) fail(source, hline, "JM (points per streamsurface) = " + std::to_string(jm) + " is not in 4..100000");
  if (ns < 2 || ns > 1000) fail(source, hline, "NS (streamsurfaces) = " + std::to_string(ns) + " is not in 2..1000");
  if (nb < 1 || nb > 1000) fail(source, hline, "NB (blades) = " + std::to_string(nb) + " is not in 1..1000");
  if (jm * ns > 2000000) fail(source, hline, "JM x NS is too large (more than 2,000,000 points)");
  if (!(1 <= jle && jle + 3 <= jte && jte <= jm))
    fail(source, hline, "JLE = " + std::to_string(jle) + " and JTE = " + std::to_string(jte) +
                            " must satisfy 1 <= JLE, JLE + 3 <= JTE <= JM = " + std::to_string(jm));

  // data[s][q][j]: surface s, quantity q (x, r·θ, thickness, r), point j
  std::vector<std::array<std::vector<double>, 4>> data(ns);
  static const char* qname[4] = {"axial distance", "radius*theta", "tangential thickness", "radius"};
  size_t i = first_surface;
  for (long s = 0; s < ns; ++s) {
    while (i < v.size() && upper(v[i]).find("SURFACE NUMBER") == std::string::npos) {
      if (!blank(v[i])) fail(source, i + 1, "expected \"Surface number " + std::to_string(s + 1) + "\"");
      ++i;
    }
    if (i >= v.size())
      fail(source, 0, "the file ends after " + std::to_string(s) + " of its NS = " + std::to_string(ns) +
                          " streamsurfaces (truncated?)");
    ++i;
    for (int q = 0; q < 4; ++q) {
      // title line, scale factor, JM values
      while (i < v.size() && blank(v[i])) ++i;
      if (i >= v.size()) fail(source, 0, "surface " + std::to_string(s + 1) + ": the file ends before the " + qname[q]);
      std::vector<double> tmp;
      if (numbers(v[i], tmp) && !tmp.empty())
        fail(source, i + 1, "surface " + std::to_string(s + 1) + ": expected the title line of the " + qname[q] +
                                " block, found numbers");
      ++i;
      while (i < v.size() && blank(v[i])) ++i;
      std::vector<double> sc;
      if (i >= v.size() || !numbers(v[i], sc) || sc.size() != 1)
        fail(source, i + 1, "surface " + std::to_string(s + 1) + ": expected the scale factor of the " + qname[q]);
      if (!(sc[0] > 0)) fail(source, i + 1, "scale factor must be positive");
      ++i;
      auto& d = data[s][q];
      while ((long)d.size() < jm) {
        if (i >= v.size())
          fail(source, 0, "surface " + std::to_string(s + 1) + ": the file ends inside the " + qname[q] + " (" +
                              std::to_string(d.size()) + " of " + std::to_string(jm) + " values)");
        if (!numbers(v[i], d))
          fail(source, i + 1, "surface " + std::to_string(s + 1) + ", " + qname[q] + ": not a number");
        if ((long)d.size() > jm)
          fail(source, i + 1, "surface " + std::to_string(s + 1) + ", " + qname[q] + ": more than JM = " +
                                  std::to_string(jm) + " values");
        ++i;
      }
      for (double& x : d) x *= sc[0];
    }
  }

  BladeSections b;
  b.format = "rotor67";
  b.blades = (int)nb;
  b.tip_section = (int)ns - 2;
  const double pitch = 2 * kPi / nb;
  for (long s = 0; s < ns; ++s) {
    const auto &X = data[s][0], &RT = data[s][1], &T = data[s][2], &R = data[s][3];
    for (long j = 0; j < jm; ++j) {
      if (!(R[j] > 0)) fail(source, 0, "surface " + std::to_string(s + 1) + ", point " + std::to_string(j + 1) + ": radius " + std::to_string(R[j]) + " is not positive");
      if (T[j] < 0) fail(source, 0, "surface " + std::to_string(s + 1) + ", point " + std::to_string(j + 1) + ": negative thickness");
      if (T[j] / R[j] >= pitch)
        fail(source, 0, "surface " + std::to_string(s + 1) + ", point " + std::to_string(j + 1) +
                            ": the blade is thicker than the blade pitch 2*pi*r/NB (NB = " + std::to_string(nb) + ")");
    }
    if (s > 0)
      for (long j = 0; j < jm; ++j)
        if (!(R[j] > data[s - 1][3][j]))
          fail(source, 0, "surface " + std::to_string(s + 1) + ", point " + std::to_string(j + 1) +
                              ": radius not above that of surface " + std::to_string(s) + " (surfaces must go hub to casing)");
    std::vector<Cyl> loop, mean;
    for (long j = jle - 1; j <= jte - 1; ++j) loop.push_back({X[j], R[j], RT[j] / R[j]});
    const double eps = 1e-12 * R[jle - 1];
    for (long j = jte - 1; j >= jle - 1; --j)
      if (T[j] > eps) loop.push_back({X[j], R[j], (RT[j] - T[j]) / R[j]});
      else if (j != jte - 1 && j != jle - 1)
        fail(source, 0, "surface " + std::to_string(s + 1) + ", point " + std::to_string(j + 1) +
                            ": zero thickness inside the blade (between JLE and JTE)");
    for (long j = 0; j < jm; ++j) mean.push_back({X[j], R[j], (RT[j] - 0.5 * T[j]) / R[j]});
    b.loops.push_back(std::move(loop));
    b.mean.push_back(std::move(mean));
  }
  for (long j = 0; j < jm; ++j) {
    b.hub.push_back({data[0][0][j], data[0][3][j], 0});
    b.casing.push_back({data[ns - 1][0][j], data[ns - 1][3][j], 0});
  }
  for (auto* m : {&b.hub, &b.casing})
    for (size_t j = 1; j < m->size(); ++j)
      if (!((*m)[j].x > (*m)[j - 1].x))
        fail(source, 0, std::string(m == &b.hub ? "hub" : "casing") + " streamsurface: axial distance not increasing at point " + std::to_string(j + 1));
  check_loops(b, source);
  return b;
}

}  // namespace meshflow::geometry
