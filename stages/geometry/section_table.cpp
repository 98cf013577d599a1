// meshflow geometry — section tables for `blade_sector`: csv (x, y, z) and zrt (z, r, θ) layouts,
// with or without a header, any common separator, sections by blank lines or a section column,
// declared units (see blade_sections.hpp for the layout's definition).
#include "engine/stage.hpp"
#include "stages/geometry/blade_sections.hpp"
#include "stages/geometry/section_util.hpp"

#include <algorithm>
#include <array>
#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <map>
#include <optional>
#include <string>

namespace meshflow::geometry {
namespace {

constexpr double kPi = 3.14159265358979323846;

std::string lower(std::string s) {
  std::transform(s.begin(), s.end(), s.begin(), [](unsigned char c) { return (char)std::tolower(c); });
  return s;
}
std::string trim(const std::string& s) {
  size_t a = 0, b = s.size();
  while (a < b && std::isspace((unsigned char)s[a])) ++a;
  while (b > a && std::isspace((unsigned char)s[b - 1])) --b;
  return s.substr(a, b - a);
}

// Splits a line into fields. With a semicolon on the line the separators are semicolons and
// blanks, and a comma is a decimal point ("1,5;2,25"); otherwise commas, tabs and blanks.
std::vector<std::string> fields(const std::string& line) {
  const bool semi = line.find(';') != std::string::npos;
  std::vector<std::string> out;
  std::string cur;
  for (char c : line) {
    bool sep = std::isspace((unsigned char)c) || c == ';' || (!semi && c == ',');
    if (sep) {
      if (!cur.empty()) out.push_back(cur), cur.clear();
    } else {
      cur += semi && c == ',' ? '.' : c;
    }
  }
  if (!cur.empty()) out.push_back(cur);
  return out;
}

// A decimal number filling the whole field (no hex, inf or nan).
std::optional<double> number(const std::string& f) {
  if (f.empty() || f.find_first_of("xXpPnNiI") != std::string::npos) return std::nullopt;
  char* end = nullptr;
  errno = 0;
  double v = std::strtod(f.c_str(), &end);
  if (end != f.c_str() + f.size() || !std::isfinite(v)) return std::nullopt;
  return v;
}

const std::vector<std::string> kLengthUnits = {"mm", "cm", "m", "in", "ft"};
// "deg" | "rad" for the spellings of an angle unit, "" otherwise.
std::string angle_unit(const std::string& u) {
  if (u == "deg" || u == "degree" || u == "degrees" || u == "\xC2\xB0") return "deg";
  if (u == "rad" || u == "radian" || u == "radians") return "rad";
  return "";
}

// A column of the header: role and unit.
enum class Role { x, y, z, axial, r, theta, section, unknown };
struct Column {
  Role role = Role::unknown;
  std::string name, unit;
};

Role role_of(const std::string& n, TableLayout layout) {
  static const std::vector<std::string> sec = {"section", "sec", "sect", "index", "idx", "id", "station", "span", "profile", "k"};
  if (std::find(sec.begin(), sec.end(), n) != sec.end()) return Role::section;
  if (n == "r" || n == "radius" || n == "rad.") return Role::r;
  if (n == "theta" || n == "\xCE\xB8" || n == "th" || n == "t" || n == "angle") return Role::theta;
  if (n == "axial") return Role::axial;
  if (layout == TableLayout::zrt && (n == "z" || n == "x")) return Role::axial;
  if (n == "x") return Role::x;
  if (n == "y") return Role::y;
  if (n == "z") return Role::z;
  return Role::unknown;
}

// "x [cm]", "x(cm)", "x_cm", "theta_deg", "θ(°)": the name and the unit (lower case).
Column parse_column(std::string f, TableLayout layout) {
  f = lower(trim(f));
  Column c;
  size_t b = f.find_first_of("[(");
  if (b != std::string::npos) {
    size_t e = f.find_first_of("])", b);
    c.unit = trim(f.substr(b + 1, (e == std::string::npos ? f.size() : e) - b - 1));
    f = trim(f.substr(0, b));
  } else if (size_t u = f.rfind('_'); u != std::string::npos && u > 0) {
    std::string unit = f.substr(u + 1);
    if (std::find(kLengthUnits.begin(), kLengthUnits.end(), unit) != kLengthUnits.end() || !angle_unit(unit).empty())
      c.unit = unit, f = f.substr(0, u);
  }
  c.name = f;
  c.role = role_of(f, layout);
  return c;
}

// One line of the table, classified.
struct Row {
  size_t line = 0;  // 1-based
  enum { blank, text, data } kind = blank;
  std::vector<std::string> f;
  std::vector<double> v;
};

// "# units: cm" (or "unit = cm") in a comment: the unit, or "" when the comment is something else.
std::string units_comment(const std::string& comment, const std::string& source, size_t line) {
  std::string c = lower(trim(comment));
  for (const char* key : {"units", "unit"}) {
    size_t n = std::string(key).size();
    if (c.compare(0, n, key) != 0) continue;
    std::string rest = trim(c.substr(n));
    if (rest.empty() || (rest[0] != ':' && rest[0] != '=')) return "";
    std::string u = trim(rest.substr(1));
    if (std::find(kLengthUnits.begin(), kLengthUnits.end(), u) == kLengthUnits.end())
      fail(source, line, "unknown length unit '" + u + "' in the units comment: use mm, cm, m, in or ft");
    return u;
  }
  return "";
}

struct Table {
  std::vector<Column> cols;  // empty: no header
  size_t header_line = 0;
  std::string units;         // declared length unit
  size_t units_line = 0;
  std::vector<Row> rows;
};

Table read_rows(std::string_view text, const std::string& source, TableLayout layout) {
  Table t;
  auto lines = split_lines(text);
  bool seen_data = false;
  for (size_t i = 0; i < lines.size(); ++i) {
    Row row;
    row.line = i + 1;
    std::string l = lines[i];
    if (size_t h = l.find('#'); h != std::string::npos) {
      std::string u = units_comment(l.substr(h + 1), source, i + 1);
      if (!u.empty()) {
        if (!t.units.empty() && u != t.units)
          fail(source, i + 1, "units '" + u + "' contradict '" + t.units + "' (line " + std::to_string(t.units_line) + "): keep one");
        t.units = u, t.units_line = i + 1;
      }
      l = l.substr(0, h);
    }
    row.f = fields(l);
    if (row.f.empty()) {
      t.rows.push_back(row);
      continue;
    }
    bool all_numbers = true;
    for (auto& f : row.f) {
      auto v = number(f);
      if (!v) {
        all_numbers = false;
        break;
      }
      row.v.push_back(*v);
    }
    row.kind = all_numbers ? Row::data : Row::text;
    if (!all_numbers && number(row.f[0]))
      for (auto& f : row.f)
        if (!number(f))
          fail(source, i + 1, "'" + f + "' is not a number: a data line holds numbers only (a line of text, e.g. "
                              "\"section 2\", separates sections)");
    bool numeric_field = false;
    for (auto& f : row.f) numeric_field |= (bool)number(f);
    if (row.kind == Row::text && !seen_data && t.cols.empty() && !numeric_field) {
      // a header when one of its fields names a column ("[cm]" tokens are the previous one's unit)
      std::vector<Column> cols;
      bool any = false;
      for (auto& f : row.f) {
        if ((f[0] == '[' || f[0] == '(') && !cols.empty()) {
          cols.back().unit = parse_column("u" + f, layout).unit;
          continue;
        }
        cols.push_back(parse_column(f, layout));
        any |= cols.back().role != Role::unknown;
      }
      if (any) {
        for (auto& c : cols)
          if (c.role == Role::unknown)
            fail(source, i + 1, "the header's column '" + c.name + "' is not one meshflow reads: name the columns " +
                                    (layout == TableLayout::xyz ? "x, y, z" : "z, r, theta") +
                                    " (and optionally section), or remove the column");
        t.cols = cols, t.header_line = i + 1;
        continue;
      }
    }
    seen_data |= row.kind == Row::data;
    t.rows.push_back(std::move(row));
  }
  return t;
}

// Where each value of a data row goes: indices of the section column (-1: none) and the three
// coordinates in the layout's order; the length unit and angle unit the header gives.
struct ColumnMap {
  int section = -1;
  int c[3] = {-1, -1, -1};
  size_t count = 0;
  std::string length_unit, angle_unit;
};

ColumnMap map_columns(const Table& t, const std::string& source, TableLayout layout) {
  ColumnMap m;
  const bool zrt = layout == TableLayout::zrt;
  const char* names[3] = {zrt ? "z (axial)" : "x", zrt ? "r" : "y", zrt ? "theta" : "z"};
  if (t.cols.empty()) {
    size_t n = 0;
    for (auto& r : t.rows)
      if (r.kind == Row::data) {
        n = r.v.size();
        if (n != 3 && n != 4)
          fail(source, r.line, std::string("expected three numbers (") + names[0] + ", " + names[1] + ", " + names[2] +
                                   ") or four (section, " + names[0] + ", " + names[1] + ", " + names[2] + "), found " +
                                   std::to_string(n));
        break;
      }
    m.count = n;
    m.section = n == 4 ? 0 : -1;
    for (int k = 0; k < 3; ++k) m.c[k] = (int)n - 3 + k;
    return m;
  }
  m.count = t.cols.size();
  const Role want[3] = {zrt ? Role::axial : Role::x, zrt ? Role::r : Role::y, zrt ? Role::theta : Role::z};
  for (size_t i = 0; i < t.cols.size(); ++i) {
    const Column& c = t.cols[i];
    int slot = -1;
    for (int k = 0; k < 3; ++k)
      if (c.role == want[k]) slot = k;
    if (c.role == Role::section) {
      if (m.section >= 0) fail(source, t.header_line, "two section columns in the header: keep one");
      m.section = (int)i;
      continue;
    }
    if (slot < 0) {
      if (!zrt && (c.role == Role::r || c.role == Role::theta))
        fail(source, t.header_line, "the header names r and theta columns: this is a z, r, theta table; set format: zrt");
      fail(source, t.header_line, "the header's column '" + c.name + "' does not belong in a " +
                                      (zrt ? std::string("z, r, theta") : std::string("x, y, z")) + " table");
    }
    if (m.c[slot] >= 0) fail(source, t.header_line, std::string("two ") + names[slot] + " columns in the header");
    m.c[slot] = (int)i;
    if (c.unit.empty()) continue;
    if (zrt && slot == 2) {
      m.angle_unit = angle_unit(c.unit);
      if (m.angle_unit.empty()) fail(source, t.header_line, "the angle column's unit '" + c.unit + "' is not deg or rad");
    } else {
      if (std::find(kLengthUnits.begin(), kLengthUnits.end(), c.unit) == kLengthUnits.end())
        fail(source, t.header_line, "column '" + c.name + "': unknown length unit '" + c.unit + "': use mm, cm, m, in or ft");
      if (!m.length_unit.empty() && m.length_unit != c.unit)
        fail(source, t.header_line, "the header's columns are in different units (" + m.length_unit + ", " + c.unit +
                                        "): give them in one unit");
      m.length_unit = c.unit;
    }
  }
  for (int k = 0; k < 3; ++k)
    if (m.c[k] < 0) fail(source, t.header_line, std::string("the header has no ") + names[k] + " column");
  return m;
}

// The points of each section in file order (three coordinates as read) and the line each starts.
struct RawSections {
  std::vector<std::vector<std::array<double, 3>>> pts;
  std::vector<size_t> line;
  bool by_column = false;
};

RawSections group_sections(const Table& t, const ColumnMap& m, const std::string& source) {
  RawSections s;
  std::map<double, size_t> seen;  // section value -> first line
  double current = 0;
  bool open = false;
  size_t total = 0;
  for (auto& r : t.rows) {
    if (r.kind != Row::data) {
      if (m.section < 0) open = false;  // a blank or text line ends the section
      continue;
    }
    if (r.v.size() != m.count)
      fail(source, r.line, "expected " + std::to_string(m.count) + " numbers (as " +
                               (t.cols.empty() ? "the first data line" : "the header") + " says), found " +
                               std::to_string(r.v.size()));
    bool start = !open;
    if (m.section >= 0) {
      double v = r.v[m.section];
      start = !open || v != current;
      if (start) {
        if (auto it = seen.find(v); it != seen.end())
          fail(source, r.line, "section " + r.f[m.section] + " appears again (it started at line " +
                                   std::to_string(it->second) + "): keep each section's rows together");
        seen[v] = r.line, current = v;
      }
    }
    if (start) s.pts.emplace_back(), s.line.push_back(r.line), open = true;
    s.pts.back().push_back({r.v[m.c[0]], r.v[m.c[1]], r.v[m.c[2]]});
    if (++total > 2000000) fail(source, r.line, "too many points (more than 2,000,000)");
  }
  s.by_column = m.section >= 0;
  return s;
}

// Cylindrical points of one section (angles unwrapped along the loop, the first point near
// `prev_mean`, the previous section's mean angle); the first point is not repeated at the end.
std::vector<Cyl> to_cyl(std::vector<std::array<double, 3>> pts, TableLayout layout, double angle_factor,
                        double prev_mean, bool first, const std::string& source, size_t line, size_t k) {
  if (pts.size() > 3 && pts.front() == pts.back()) pts.pop_back();
  std::vector<Cyl> loop;
  double last = 0;
  for (size_t i = 0; i < pts.size(); ++i) {
    auto& p = pts[i];
    double x, r, t;
    if (layout == TableLayout::xyz) x = p[0], r = std::hypot(p[1], p[2]), t = std::atan2(p[2], p[1]);
    else x = p[0], r = p[1], t = p[2] * angle_factor;
    if (!(r > 0) || !std::isfinite(r))
      fail(source, line, "section " + std::to_string(k + 1) + ", point " + std::to_string(i + 1) +
                             ": the point lies on the axis (radius " + std::to_string(r) + "); the machine axis is " +
                             (layout == TableLayout::xyz ? "x" : "z") + " and every radius must be positive");
    if (i == 0 && !first) t += 2 * kPi * std::round((prev_mean - t) / (2 * kPi));
    if (i > 0) t += 2 * kPi * std::round((last - t) / (2 * kPi));  // unwrap
    last = t;
    loop.push_back({x, r, t});
  }
  return loop;
}

double mean_radius(const std::vector<Cyl>& l) {
  double s = 0;
  for (auto& p : l) s += p.r;
  return s / l.size();
}
double mean_angle(const std::vector<Cyl>& l) {
  double s = 0;
  for (auto& p : l) s += p.t;
  return s / l.size();
}
// Signed area of the loop in the (x, r_mean θ) plane: its sense of rotation.
double signed_area(const std::vector<Cyl>& l) {
  double rm = mean_radius(l), a = 0;
  for (size_t i = 0; i < l.size(); ++i) {
    const Cyl &p = l[i], &q = l[(i + 1) % l.size()];
    a += p.x * rm * q.t - q.x * rm * p.t;
  }
  return 0.5 * a;
}
size_t argmin_x(const std::vector<Cyl>& l) {
  size_t le = 0;
  for (size_t i = 1; i < l.size(); ++i)
    if (l[i].x < l[le].x) le = i;
  return le;
}
size_t argmax_x(const std::vector<Cyl>& l) {
  size_t te = 0;
  for (size_t i = 1; i < l.size(); ++i)
    if (l[i].x > l[te].x) te = i;
  return te;
}

// Every loop made to start at its leading edge (smallest x). The blade surface joins point i of
// each section to point i of the next, so when the file's sections start at the same relative
// point (their smallest-x points at the same index, give or take a tenth of the loop: a twisted
// blade's leading edge moves by a point or two between sections) all loops are turned by the
// same count, section 1's: the file's own correspondence is kept (turning each to its own
// smallest x shifted it by those points, and a sharp trailing edge then ran diagonally across
// the surface, which folded there). Otherwise each loop starts at its own smallest x.
void start_at_leading_edge(std::vector<std::vector<Cyl>>& loops, std::vector<std::string>& notes) {
  const size_t n = loops[0].size();
  const size_t s0 = argmin_x(loops[0]);
  bool common = true;
  for (auto& l : loops) {
    if (l.size() != n) {
      common = false;  // resampled afterwards, from each loop's own leading edge
      break;
    }
    size_t d = (argmin_x(l) + n - s0) % n;
    common &= std::min(d, n - d) <= n / 10;
  }
  for (auto& l : loops) std::rotate(l.begin(), l.begin() + (common ? s0 : argmin_x(l)), l.end());
  if (!common && loops.back().size() == n)
    notes.push_back("the sections start at different points of their loops: each turned to start at its smallest x");
}

// A polyline resampled to n points at cosine-spaced arc length (ends kept, dense at both ends).
std::vector<Cyl> resample(const std::vector<Cyl>& s, size_t n) {
  std::vector<double> len(s.size(), 0.0);
  for (size_t i = 1; i < s.size(); ++i) {
    double rm = 0.5 * (s[i].r + s[i - 1].r);
    len[i] = len[i - 1] + std::hypot(s[i].x - s[i - 1].x, s[i].r - s[i - 1].r, rm * (s[i].t - s[i - 1].t));
  }
  std::vector<Cyl> out;
  size_t j = 0;
  for (size_t i = 0; i < n; ++i) {
    double target = len.back() * 0.5 * (1 - std::cos(kPi * i / (n - 1)));
    while (j + 2 < s.size() && len[j + 1] < target) ++j;
    double w = len[j + 1] > len[j] ? std::clamp((target - len[j]) / (len[j + 1] - len[j]), 0.0, 1.0) : 0.0;
    out.push_back({s[j].x + w * (s[j + 1].x - s[j].x), s[j].r + w * (s[j + 1].r - s[j].r), s[j].t + w * (s[j + 1].t - s[j].t)});
  }
  return out;
}

// Loops with different point counts: each side (leading edge = smallest x to trailing edge =
// largest x, and back) resampled to the largest section's side counts.
void resample_loops(std::vector<std::vector<Cyl>>& loops) {
  size_t na = 0, nb = 0;
  for (auto& l : loops) {
    size_t te = argmax_x(l);  // loops start at the leading edge
    na = std::max(na, te + 1), nb = std::max(nb, l.size() - te + 1);
  }
  for (auto& l : loops) {
    size_t te = argmax_x(l);
    std::vector<Cyl> a(l.begin(), l.begin() + te + 1), b(l.begin() + te, l.end());
    b.push_back(l.front());
    a = resample(a, na), b = resample(b, nb);
    a.insert(a.end(), b.begin() + 1, b.end() - 1);
    l = a;
  }
}

// Mean lines: both sides from the leading edge (min x) to the trailing edge (max x), at common
// cosine-spaced axial stations, θ and r averaged.
std::vector<std::vector<Cyl>> mean_lines(const std::vector<std::vector<Cyl>>& loops, const std::string& source) {
  const int M = 41;
  std::vector<std::vector<Cyl>> out;
  for (auto& given : loops) {
    // from this loop's own leading edge (the loops may start a few points away: see
    // start_at_leading_edge)
    std::vector<Cyl> loop = given;
    std::rotate(loop.begin(), loop.begin() + argmin_x(loop), loop.end());
    size_t n = loop.size(), te = argmax_x(loop);
    if (te == 0 || !(loop[te].x > loop[0].x))
      fail(source, 0, "a section has no axial extent (leading and trailing edge at the same x)");
    std::vector<Cyl> A(loop.begin(), loop.begin() + te + 1), B;
    for (size_t i = n; i >= te; --i) B.push_back(loop[i % n]);
    auto at = [](const std::vector<Cyl>& s, double x) {
      for (size_t i = 0; i + 1 < s.size(); ++i) {
        double a = s[i].x, c = s[i + 1].x;
        if ((x >= std::min(a, c) && x <= std::max(a, c))) {
          double w = c != a ? (x - a) / (c - a) : 0.5;
          return Cyl{x, s[i].r + w * (s[i + 1].r - s[i].r), s[i].t + w * (s[i + 1].t - s[i].t)};
        }
      }
      return s.back();
    };
    std::vector<Cyl> mean;
    for (int i = 0; i < M; ++i) {
      double x = loop[0].x + (loop[te].x - loop[0].x) * 0.5 * (1 - std::cos(kPi * i / (M - 1)));
      Cyl a = at(A, x), c = at(B, x);
      mean.push_back({x, 0.5 * (a.r + c.r), 0.5 * (a.t + c.t)});
    }
    out.push_back(std::move(mean));
  }
  return out;
}

// The declared length unit: the header's and a "# units:" comment must agree.
std::string declared_units(const Table& t, const ColumnMap& m, const std::string& source, std::vector<std::string>& notes) {
  if (!m.length_unit.empty() && !t.units.empty() && m.length_unit != t.units)
    fail(source, t.header_line, "the header's unit '" + m.length_unit + "' contradicts '# units: " + t.units + "' (line " +
                                    std::to_string(t.units_line) + "): keep one");
  if (!m.length_unit.empty()) notes.push_back("lengths in " + m.length_unit + " (header, line " + std::to_string(t.header_line) + ")");
  else if (!t.units.empty()) notes.push_back("lengths in " + t.units + " (line " + std::to_string(t.units_line) + ": units comment)");
  return !m.length_unit.empty() ? m.length_unit : t.units;
}

double angle_factor(const TableOptions& o, const ColumnMap& m, std::vector<std::string>& notes) {
  if (o.layout != TableLayout::zrt) return 1.0;
  std::string u = !o.angle_unit.empty() ? o.angle_unit : !m.angle_unit.empty() ? m.angle_unit : "deg";
  notes.push_back(std::string("theta in ") + (u == "rad" ? "radians" : "degrees") +
                  (!o.angle_unit.empty() ? " (angle_unit)" : !m.angle_unit.empty() ? " (header)" : " (the default: the header does not say)"));
  return u == "rad" ? 1.0 : kPi / 180.0;
}

}  // namespace

double length_unit_in_m(const std::string& u) {
  if (u == "mm") return 1e-3;
  if (u == "cm") return 1e-2;
  if (u == "in") return 0.0254;
  if (u == "ft") return 0.3048;
  return 1.0;
}

TableLayout detect_table_layout(std::string_view text) {
  auto lines = split_lines(text);
  for (auto& l0 : lines) {
    std::string l = l0.substr(0, l0.find('#'));
    auto f = fields(l);
    if (f.empty()) continue;
    bool has_r = false, has_t = false, any_text = false;
    for (auto& x : f) {
      if (number(x)) continue;
      any_text = true;
      Role r = parse_column(x, TableLayout::zrt).role;
      has_r |= r == Role::r, has_t |= r == Role::theta;
    }
    if (!any_text) return TableLayout::xyz;  // data before any header
    if (has_r && has_t) return TableLayout::zrt;
  }
  return TableLayout::xyz;
}

BladeSections parse_blade_table(std::string_view text, const std::string& source, const TableOptions& o) {
  BladeSections b;
  b.format = o.layout == TableLayout::xyz ? "csv" : "zrt";
  Table t = read_rows(text, source, o.layout);
  ColumnMap m = map_columns(t, source, o.layout);
  b.units = declared_units(t, m, source, b.notes);
  const double af = angle_factor(o, m, b.notes);
  RawSections raw = group_sections(t, m, source);
  if (raw.pts.size() < 2)
    fail(source, 0, "needs at least two sections (separated by blank lines, or numbered in a section column), found " +
                        std::to_string(raw.pts.size()));
  b.notes.push_back(std::to_string(raw.pts.size()) + " sections " +
                    (raw.by_column ? "by the section column" : "separated by blank or text lines") +
                    (t.cols.empty() ? ", no header" : ", header on line " + std::to_string(t.header_line)));
  double prev = 0;
  for (size_t k = 0; k < raw.pts.size(); ++k) {
    if (raw.pts[k].size() < 8)
      fail(source, raw.line[k], "section " + std::to_string(k + 1) + " has " + std::to_string(raw.pts[k].size()) +
                                    " points; a section needs at least 8 around its loop");
    b.loops.push_back(to_cyl(raw.pts[k], o.layout, af, prev, k == 0, source, raw.line[k], k));
    prev = mean_angle(b.loops.back());
  }
  // hub to tip; the same sense of rotation as the first section; each starting at its leading edge
  if (mean_radius(b.loops.front()) > mean_radius(b.loops.back())) {
    std::reverse(b.loops.begin(), b.loops.end());
    b.notes.push_back("sections given tip to hub: reversed");
  }
  const bool sense = signed_area(b.loops.front()) > 0;
  for (size_t k = 0; k < b.loops.size(); ++k) {
    auto& l = b.loops[k];
    if ((signed_area(l) > 0) != sense) {
      std::reverse(l.begin(), l.end());
      b.notes.push_back("section " + std::to_string(k + 1) + " runs the other way round: reversed");
    }
  }
  start_at_leading_edge(b.loops, b.notes);
  size_t nmax = 0;
  bool differ = false;
  for (auto& l : b.loops) differ |= l.size() != b.loops[0].size(), nmax = std::max(nmax, l.size());
  if (differ) {
    resample_loops(b.loops);
    b.resampled_from = (int)nmax;
    b.notes.push_back("sections have different point counts: each side resampled to " +
                      std::to_string(b.loops[0].size()) + " points per section (the blade passes through the resampled points)");
  }
  check_loops(b, source);
  b.mean = mean_lines(b.loops, source);
  double xmin = 1e300, xmax = -1e300;
  for (auto& ml : b.mean) xmin = std::min(xmin, ml.front().x), xmax = std::max(xmax, ml.back().x);
  double rh = 1e300, rc = 0;
  for (auto& p : b.loops.front()) rh = std::min(rh, p.r);
  for (auto& p : b.loops.back()) rc = std::max(rc, p.r);
  if (o.hub_radius > 0) rh = o.hub_radius;
  if (o.casing_radius > 0) rc = o.casing_radius;
  if (!(rc > rh))
    fail(source, 0, "the casing radius " + std::to_string(rc) + " is not larger than the hub radius " + std::to_string(rh) +
                        ": check hub_radius and casing_radius");
  b.hub = {{xmin, rh, 0}, {xmax, rh, 0}};
  b.casing = {{xmin, rc, 0}, {xmax, rc, 0}};
  return b;
}

BladeSections parse_blade_csv(std::string_view text, const std::string& source, double hub_radius, double casing_radius) {
  return parse_blade_table(text, source, TableOptions{TableLayout::xyz, "", hub_radius, casing_radius});
}

}  // namespace meshflow::geometry
