#include "stages/mesh_report/svg.hpp"

#include "engine/run_report.hpp"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstdio>

namespace meshflow::mesh_report {

namespace {

// One decimal, no trailing ".0", no "-0".
void num(std::string& out, double v) {
  long long t = std::llround(v * 10);
  if (t < 0) {
    out += '-';
    t = -t;
  }
  char b[32];
  auto r = std::to_chars(b, b + sizeof b, t / 10);
  out.append(b, r.ptr);
  if (t % 10) {
    out += '.';
    out += char('0' + t % 10);
  }
}

Rgb mix(Rgb a, Rgb b, double t) {
  auto l = [t](int x, int y) { return std::uint8_t(std::lround(x + (y - x) * t)); };
  return {l(a.r, b.r), l(a.g, b.g), l(a.b, b.b)};
}

}  // namespace

std::string Rgb::hex() const {
  char buf[8];
  std::snprintf(buf, sizeof buf, "#%02x%02x%02x", r, g, b);
  return buf;
}

Rgb quality_colour(double q) {
  if (!(q > 0)) return {123, 50, 148};  // invalid (and NaN)
  static const Rgb stops[] = {{165, 0, 38}, {244, 109, 67}, {254, 224, 139}, {166, 217, 106}, {26, 152, 80}};
  q = std::min(q, 1.0) * 4;
  int i = std::min(3, int(q));
  return mix(stops[i], stops[i + 1], q - i);
}

Rgb grey(double facing) {
  std::uint8_t v = std::uint8_t(std::lround(150 + 90 * std::clamp(facing, 0.0, 1.0)));
  return {v, v, v};
}

// Absolute first point, then relative steps ("l"), in tenths of a pixel rounded once from the
// absolute positions (no drift); steps shorter than `min_step` px are dropped.
void Svg::points(const std::vector<P2>& pts, char first) {
  constexpr double min_step = 0.4;
  long long lx = 0, ly = 0;
  bool started = false, rel = false;
  for (auto& p : pts) {
    long long x = std::llround(p[0] * 10), y = std::llround(p[1] * 10);
    if (!started) {
      body_ += first;
      num(body_, double(x) / 10);
      body_ += ',';
      num(body_, double(y) / 10);
    } else {
      if (std::abs(x - lx) < min_step * 10 && std::abs(y - ly) < min_step * 10) continue;
      body_ += rel ? ' ' : 'l';
      rel = true;
      num(body_, double(x - lx) / 10);
      if (y - ly >= 0) body_ += ',';
      num(body_, double(y - ly) / 10);
    }
    lx = x, ly = y;
    started = true;
  }
}

namespace {
// Appends ` name="value"` (the one way every element below writes an attribute).
void attr(std::string& s, std::string_view name, double v) {
  s += ' ';
  s += name;
  s += "=\"";
  num(s, v);
  s += '"';
}
void attr(std::string& s, std::string_view name, std::string_view v) {
  s += ' ';
  s += name;
  s += "=\"";
  s += v;
  s += '"';
}
}  // namespace

void Svg::begin_group(std::string_view stroke, double stroke_width) {
  body_ += "<g stroke=\"";
  body_ += stroke;
  body_ += "\" stroke-width=\"";
  num(body_, stroke_width);
  body_ += "\">\n";
}
void Svg::end_group() { body_ += "</g>\n"; }

void Svg::polygon(const std::vector<P2>& pts, std::string_view fill, std::string_view stroke, double sw, double opacity) {
  if (pts.size() < 3) return;
  body_ += "<path d=\"";
  points(pts, 'M');
  body_ += "Z\" fill=\"";
  body_ += fill;
  if (!stroke.empty()) {
    body_ += "\" stroke=\"";
    body_ += stroke;
    body_ += "\" stroke-width=\"";
    num(body_, sw * 10 < 1 ? 0.1 : sw);
  }
  if (opacity < 1) {
    body_ += "\" fill-opacity=\"";
    num(body_, opacity);
  }
  body_ += "\"/>\n";
}

void Svg::loops(const std::vector<std::vector<P2>>& ls, std::string_view fill, std::string_view stroke, double sw) {
  body_ += ls.size() > 1 ? "<path fill-rule=\"evenodd\" d=\"" : "<path d=\"";
  for (auto& l : ls) {
    points(l, 'M');
    body_ += 'Z';
  }
  body_ += "\" fill=\"";
  body_ += fill;
  if (!stroke.empty()) {
    body_ += "\" stroke=\"";
    body_ += stroke;
    body_ += "\" stroke-width=\"";
    num(body_, sw);
  }
  body_ += "\"/>\n";
}

void Svg::polyline(const std::vector<P2>& pts, std::string_view stroke, double sw) {
  if (pts.size() < 2) return;
  body_ += "<path d=\"";
  points(pts, 'M');
  body_ += "\" fill=\"none\" stroke=\"";
  body_ += stroke;
  body_ += "\" stroke-width=\"";
  num(body_, sw);
  body_ += "\"/>\n";
}

void Svg::rect(double x, double y, double w, double h, std::string_view fill, std::string_view stroke) {
  body_ += "<rect";
  attr(body_, "x", x);
  attr(body_, "y", y);
  attr(body_, "width", w);
  attr(body_, "height", h);
  attr(body_, "fill", fill);
  attr(body_, "stroke", stroke);
  body_ += "/>\n";
}

void Svg::circle(double x, double y, double r, std::string_view fill, std::string_view stroke, double sw) {
  body_ += "<circle";
  attr(body_, "cx", x);
  attr(body_, "cy", y);
  attr(body_, "r", r);
  attr(body_, "fill", fill);
  attr(body_, "stroke", stroke);
  attr(body_, "stroke-width", sw);
  body_ += "/>\n";
}

void Svg::text(double x, double y, std::string_view t, double size, std::string_view anchor, std::string_view fill) {
  body_ += "<text";
  attr(body_, "x", x);
  attr(body_, "y", y);
  attr(body_, "font-size", size);
  attr(body_, "text-anchor", anchor);
  attr(body_, "fill", fill);
  body_ += '>';
  body_ += html_escape(t);
  body_ += "</text>\n";
}

std::string Svg::str(std::string_view title) const {
  std::string s = "<svg viewBox=\"0 0 ";
  num(s, w_);
  s += ' ';
  num(s, h_);
  s += "\" width=\"";
  num(s, w_);
  s += "\" height=\"";
  num(s, h_);
  s += "\" role=\"img\" aria-label=\"" + html_escape(title) + "\" font-family=\"sans-serif\"><title>" + html_escape(title) +
       "</title>\n";
  return s + body_ + "</svg>";
}

void quality_legend(Svg& svg, double x, double y, double width) {
  const int n = 44;
  const double w = width / n;
  for (int i = 0; i < n; ++i) {
    double q = -0.1 + 1.1 * (i + 0.5) / n;
    svg.rect(x + i * w, y, w + 0.3, 10, quality_colour(q).hex());
  }
  svg.text(x + 2, y + 22, "< 0", 10, "start");
  for (double q : {0.5, 1.0}) svg.text(x + width * (q + 0.1) / 1.1, y + 22, q == 0 ? "0" : q == 1 ? "1" : "0.5", 10, "middle");
  svg.text(x + width + 6, y + 9, "scaled Jacobian", 10, "start");
}

}  // namespace meshflow::mesh_report
