#include "stages/mesh_report/mesh_report.hpp"

#include "stages/io/mesh_io.hpp"
#include "stages/mesh_report/render.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <set>

namespace meshflow::mesh_report {

using nlohmann::json;

namespace {

const char* kAxis = "xyz";

std::string g(double v, int digits = 4) {
  char b[64];
  std::snprintf(b, sizeof b, "%.*g", digits, v);
  return b;
}

std::string cell(const json& j) {
  if (j.is_string()) return html_escape(j.get<std::string>());
  if (j.is_number_float()) return g(j.get<double>());
  return html_escape(j.dump());
}

// ---------------------------------------------------------------------------------------
// Figures from stats.mesh

std::string counts_table(const json& m) {
  std::string s = "<table>";
  auto row = [&](const std::string& k, const std::string& v) { s += "<tr><th>" + k + "</th><td>" + v + "</td></tr>"; };
  row("order", cell(m.value("order", json())));
  row("nodes", cell(m.value("nodes", json())));
  for (const char* key : {"elements", "boundary", "groups"}) {
    if (!m.contains(key) || !m[key].is_object()) continue;
    std::string v;
    for (auto& [k, n] : m[key].items())
      if (!(n.is_number() && n.get<double>() == 0)) v += (v.empty() ? "" : ", ") + cell(n) + " " + html_escape(k);
    row(key, v.empty() ? "none" : v);
  }
  row("invalid elements", cell(m.value("invalid", json())) +
                              (m.value("inconclusive", 0) ? " (" + cell(m["inconclusive"]) + " inconclusive)" : ""));
  row("non-conforming faces", cell(m.value("nonconforming_faces", json())));
  row("scaled Jacobian", "min " + cell(m.value("min_scaled_jacobian", json())) + ", median " +
                             cell(m.value("median_scaled_jacobian", json())));
  row("max aspect ratio", cell(m.value("max_aspect_ratio", json())));
  if (m.contains("validity_method")) row("validity", cell(m["validity_method"]));
  return s + "</table>\n";
}

// A bar per bin; heights on a log scale (counts span orders of magnitude), the count above.
std::string histogram_svg(const json& h, const std::string& title, bool quality_colours) {
  if (!h.is_object() || !h.contains("counts") || !h.contains("edges")) return {};
  std::vector<double> counts, edges;
  for (auto& c : h["counts"]) counts.push_back(c.get<double>());
  for (auto& e : h["edges"]) edges.push_back(e.get<double>());
  if (counts.empty()) return {};
  const double W = 330, H = 180, left = 10, bottom = 36, top = 24;
  const double bw = (W - 2 * left) / double(counts.size());
  double mx = 0;
  for (double c : counts) mx = std::max(mx, std::log10(1 + c));
  Svg svg(W, H);
  svg.text(W / 2, 14, title + " (elements per bin, log scale)", 11, "middle");
  for (std::size_t i = 0; i < counts.size(); ++i) {
    double hgt = mx > 0 ? (H - bottom - top) * std::log10(1 + counts[i]) / mx : 0;
    double x = left + i * bw;
    std::string fill = "#5b7fa6";
    if (quality_colours) {
      double lo = edges[i], hi = i + 1 < edges.size() ? edges[i + 1] : lo;
      fill = quality_colour(hi <= 0 ? -1 : 0.5 * (lo + hi)).hex();
    }
    svg.rect(x + 1, H - bottom - hgt, bw - 2, hgt, fill, "#333");
    svg.text(x + bw / 2, H - bottom - hgt - 3, g(counts[i], 6), 9, "middle");
    svg.text(x, H - bottom + 12, g(edges[i], 3), 9, "middle");
  }
  if (edges.size() > counts.size()) svg.text(left + counts.size() * bw, H - bottom + 12, g(edges.back(), 3), 9, "middle");
  else svg.text(left + counts.size() * bw, H - bottom + 12, "+", 9, "middle");
  svg.polyline({{left, H - bottom}, {W - left, H - bottom}}, "#333", 1);
  return svg.str(title + " histogram");
}

// ---------------------------------------------------------------------------------------
// The elements to mark: stats.mesh.invalid_elements (validity), then the elements the
// problems name (degenerate, ...), each once, in that order.

struct Listed {
  std::uint64_t tag;
  std::string clause;
};

std::vector<Listed> listed_elements(const json& stats) {
  std::vector<Listed> out;
  std::set<std::uint64_t> seen;
  auto add = [&](const json& id, const std::string& clause) {
    if (!id.is_number_integer() && !id.is_number_unsigned()) return;
    std::uint64_t t = id.get<std::uint64_t>();
    if (seen.insert(t).second) out.push_back({t, clause});
  };
  if (stats.contains("mesh") && stats["mesh"].is_object())
    for (auto& id : stats["mesh"].value("invalid_elements", json::array())) add(id, "validity");
  if (stats.contains("problems") && stats["problems"].is_array())
    for (auto& p : stats["problems"])
      if (p.is_object() && p.contains("where") && p["where"].is_array())
        for (auto& w : p["where"])
          if (w.is_object() && w.contains("element")) add(w["element"], p.value("clause", std::string("?")));
  return out;
}

std::string listed_html(const json& stats, const std::vector<Listed>& listed) {
  if (listed.empty()) return {};
  const json& m = stats.contains("mesh") ? stats["mesh"] : json::object();
  std::string s = "<p><b class=\"invalid\">" + std::to_string(m.value("invalid", 0)) + " invalid element(s)</b>";
  if (m.value("invalid", 0) > int(m.value("invalid_elements", json::array()).size()))
    s += " (the first " + std::to_string(m["invalid_elements"].size()) + " are listed)";
  s += "; elements named by the contract: <code>";
  for (std::size_t i = 0; i < listed.size(); ++i) s += (i ? ", " : "") + std::to_string(listed[i].tag);
  return s + "</code></p>\n";
}

// ---------------------------------------------------------------------------------------
// Pictures

std::string figure(const Svg& svg, const std::string& title, const std::string& caption) {
  return "<figure style=\"width:" + std::to_string(int(svg.width())) + "px\">" + svg.str(title) + "<figcaption>" + caption + "</figcaption></figure>\n";
}

// The surface's extent: min and max of its nodes along each axis.
std::array<double, 6> surface_box(const Scene& s) {
  std::array<double, 6> b{1e300, 1e300, 1e300, -1e300, -1e300, -1e300};
  for (const auto& f : s.surface())
    for (auto n : f.outline) {
      P3 p = s.node(n);
      for (int r = 0; r < 3; ++r) b[r] = std::min(b[r], p[r]), b[3 + r] = std::max(b[3 + r], p[r]);
    }
  return b;
}

// Grows the shorter side of the window so that height / width lies in [lo, hi].
void shape_window(Cut& c, double lo, double hi) {
  double du = c.u1 - c.u0, dv = c.v1 - c.v0;
  if (dv < lo * du) {
    double e = (lo * du - dv) / 2;
    c.v0 -= e, c.v1 += e;
  } else if (dv > hi * du) {
    double e = (dv / hi - du) / 2;
    c.u0 -= e, c.u1 += e;
  }
}

std::string window_text(const Cut& c) {
  const int u = (c.axis + 1) % 3, v = (c.axis + 2) % 3;
  return std::string(1, kAxis[u]) + " &isin; [" + g(c.u0) + ", " + g(c.u1) + "], " + kAxis[v] + " &isin; [" + g(c.v0) +
         ", " + g(c.v1) + "]";
}

// Planes x, y and z through the middle of the surface, each with the whole section and a
// close-up at the section's extreme point along the picture's horizontal axis (a wing's
// leading edge in a z cut).
std::string cut_figures(Scene& scene, const std::array<double, 6>& box) {
  std::string s;
  for (int axis : {2, 0, 1}) {
    const double value = 0.5 * (box[axis] + box[3 + axis]);
    auto trace = surface_trace(scene, axis, value);
    double u0 = 1e300, u1 = -1e300, v0 = 1e300, v1 = -1e300;
    for (auto& ch : trace)
      for (auto& p : ch) u0 = std::min(u0, p[0]), u1 = std::max(u1, p[0]), v0 = std::min(v0, p[1]), v1 = std::max(v1, p[1]);
    if (trace.empty() || !(u1 > u0) || !(v1 >= v0)) continue;
    // The close-up: at the section's first point along its longer side (a wing's leading edge).
    const int along = u1 - u0 >= v1 - v0 ? 0 : 1;
    P2 extreme{1e300, 1e300};
    for (auto& ch : trace)
      for (auto& p : ch)
        if (p[along] < extreme[along] || (p[along] == extreme[along] && p[1 - along] < extreme[1 - along])) extreme = p;
    const double size = std::max(u1 - u0, v1 - v0);
    Cut whole{axis, value, u0 - 0.2 * size, u1 + 0.2 * size, v0 - 0.2 * size, v1 + 0.2 * size};
    shape_window(whole, 0.4, 1.0);
    const double w = 0.08 * size;
    Cut close{axis, value, extreme[0] - 0.5 * w, extreme[0] + 0.5 * w, extreme[1] - 0.5 * w, extreme[1] + 0.5 * w};
    (along == 0 ? close.u0 : close.v0) += 0.15 * w;  // more of the body side than of the outside
    (along == 0 ? close.u1 : close.v1) += 0.15 * w;
    const std::string plane = std::string(1, kAxis[axis]) + " = " + g(value, 6);
    const std::string axes = std::string("horizontal ") + kAxis[(axis + 1) % 3] + ", vertical " + kAxis[(axis + 2) % 3];
    s += "<div class=\"row\">";
    s += figure(cut_picture(scene, whole, 560), "cut " + plane,
                "Cut " + plane + " (the middle of the surface; " + axes + "), " + window_text(whole) +
                    ". Elements coloured by scaled Jacobian; the surface in black.");
    s += figure(cut_picture(scene, close, 340), "close-up of cut " + plane,
                "Close-up of the cut " + plane + " at (" + kAxis[(axis + 1) % 3] + ", " + kAxis[(axis + 2) % 3] + ") = (" +
                    g(extreme[0]) + ", " + g(extreme[1]) + "), the section's first point along its longer side: " + window_text(close) + ".");
    s += "</div>\n";
  }
  return s;
}

const View kViews[2] = {{{0.55, 0.75, 0.9}, 1, "from +x +y +z"}, {{-0.55, -0.75, -0.9}, 1, "from -x -y -z"}};

std::string surface_figures(Scene& scene) {
  std::string s = "<div class=\"row\">";
  for (const View& v : kViews)
    s += figure(surface_picture(scene, v, 560, 430, false, nullptr), "surface " + v.name,
                "Surface (" + html_escape(scene.surface_groups()) + ") seen " + v.name +
                    ", each face coloured by the scaled Jacobian of its element.");
  return s + "</div>\n";
}

// The surface in grey with the listed elements drawn over it and labelled, from both sides;
// a table of them; a close-up cut through the first.
std::string marked_figures(Scene& scene, const std::vector<Listed>& listed) {
  std::vector<std::int64_t> found;
  for (auto& l : listed) found.push_back(scene.find(l.tag));
  scene.need_quality(found);
  std::string s = "<div class=\"row\">";
  for (const View& v : kViews) {
    Projection pr;
    Svg svg = surface_picture(scene, v, 560, 430, true, &pr);
    for (auto e : found) {
      if (e < 0) continue;
      for (auto& outline : scene.element_face_outlines(std::size_t(e))) {
        std::vector<P2> pts;
        for (auto n : outline) pts.push_back(pr(scene.node(n)));
        svg.polygon(pts, "#7b3294", "#4a0e5c", 0.6, 0.45);
      }
    }
    for (auto e : found) {
      if (e < 0) continue;
      P2 c = pr(scene.centroid(std::size_t(e)));
      svg.circle(c[0], c[1], 6, "none", "#d4006a", 1.8);
      svg.text(c[0] + 8, c[1] - 5, std::to_string(scene.tag(std::size_t(e))), 11, "start", "#d4006a");
    }
    s += figure(svg, "elements named by the contract, " + v.name,
                "Where the listed elements are, seen " + v.name + ": each drawn in purple over the surface (grey) and "
                "ringed with its id (drawn on top even when the surface hides it).");
  }
  s += "</div>\n<table><tr><th>element</th><th>type</th><th>listed for</th><th>centroid</th><th>scaled Jacobian</th></tr>\n";
  for (std::size_t i = 0; i < listed.size(); ++i) {
    std::int64_t e = found[i];
    s += "<tr><td>" + std::to_string(listed[i].tag) + "</td>";
    if (e < 0) {
      s += "<td colspan=\"4\" class=\"note\">not an element of this mesh's highest dimension</td></tr>\n";
      continue;
    }
    P3 c = scene.centroid(std::size_t(e));
    s += "<td>" + scene.type_name(std::size_t(e)) + "</td><td>" + html_escape(listed[i].clause) + "</td><td>(" + g(c[0], 6) +
         ", " + g(c[1], 6) + ", " + g(c[2], 6) + ")</td><td class=\"n\">" +
         g(scene.quality(std::size_t(e)).scaled_jacobian) + "</td></tr>\n";
  }
  s += "</table>\n";
  // A close-up cut through the first listed element found, across its thinnest extent.
  for (auto e : found) {
    if (e < 0 || scene.dimension() != 3) continue;
    P3 c = scene.centroid(std::size_t(e));
    double lo[3] = {1e300, 1e300, 1e300}, hi[3] = {-1e300, -1e300, -1e300};
    for (auto& outline : scene.element_face_outlines(std::size_t(e)))
      for (auto n : outline) {
        P3 p = scene.node(n);
        for (int r = 0; r < 3; ++r) lo[r] = std::min(lo[r], p[r]), hi[r] = std::max(hi[r], p[r]);
      }
    int axis = 0;
    for (int r = 1; r < 3; ++r)
      if (hi[r] - lo[r] < hi[axis] - lo[axis]) axis = r;
    const int u = (axis + 1) % 3, v = (axis + 2) % 3;
    const double w = 3 * std::max(hi[u] - lo[u], hi[v] - lo[v]);
    Cut cut{axis, c[axis], c[u] - w, c[u] + w, c[v] - 0.75 * w, c[v] + 0.75 * w};
    const std::string plane = std::string(1, kAxis[axis]) + " = " + g(c[axis], 6);
    s += figure(cut_picture(scene, cut, 560, found), "cut through element " + std::to_string(scene.tag(std::size_t(e))),
                "Cut " + plane + " through the centroid of element " + std::to_string(scene.tag(std::size_t(e))) + ", " +
                    window_text(cut) + ": listed elements ringed with their ids, invalid ones purple.");
    break;
  }
  return s;
}

// The marked elements' pictures when there are any; the surface and the cuts when `all`.
std::string pictures_html(const ArtifactReportInput& in, const std::vector<Listed>& listed, bool all) {
  model::Mesh mesh = io::read_mesh(in.path);
  Scene scene(mesh, in.threads);
  // the quality the stage stored beside the mesh (the contract's), not computed a second time
  // (none, or not this mesh's: computed as needed)
  if (auto q = io::stored_quality(in.companions, mesh)) scene.use_quality(*q);
  if (scene.surface().empty()) return "<p class=\"note\">No surface to draw (the mesh has no 2D or 3D elements).</p>\n";
  std::string s;
  if (!listed.empty()) s += "<h4>Where the listed elements are</h4>\n" + marked_figures(scene, listed);
  if (!all) return s;
  s += "<h4>Surface</h4>\n" + surface_figures(scene);
  if (scene.dimension() == 3) s += "<h4>Cuts through the boundary layer</h4>\n" + cut_figures(scene, surface_box(scene));
  return s;
}

}  // namespace

std::string mesh_section(const ArtifactReportInput& in) {
  const json& stats = in.stats ? *in.stats : json::object();
  std::string s = "<h3>" + html_escape(in.artifact) + " <span class=\"note\">(" + html_escape(in.type) +
                  (in.delivered ? ", an output of the run" : "") + ")</span>" +
                  (in.invalid ? " <span class=\"invalid\">INVALID</span>" : "") + "</h3>\n";
  if (!stats.contains("mesh") || !stats["mesh"].is_object()) {
    s += "<p class=\"note\">The stage recorded no mesh statistics.</p>\n";
  } else {
    const json& m = stats["mesh"];
    s += "<div class=\"row\">" + counts_table(m);
    if (m.contains("histograms")) {
      s += "<div>" + histogram_svg(m["histograms"].value("scaled_jacobian", json()), "scaled Jacobian", true) + "</div>";
      s += "<div>" + histogram_svg(m["histograms"].value("aspect_ratio", json()), "aspect ratio", false) + "</div>";
    }
    s += "</div>\n";
  }
  const std::vector<Listed> listed = listed_elements(stats);
  s += listed_html(stats, listed);
  // Pictures of what the run delivers or what breaks the contract; an intermediate mesh with
  // elements listed (curving's inverted elements, which optimise repairs) gets their marks.
  const bool all = in.delivered || in.invalid;
  if (!all && listed.empty()) return s;
  if (in.path.empty())
    return s + "<p class=\"note\">The mesh itself is not at hand (not in the cache any more, nor among the outputs): "
               "no pictures.</p>\n";
  return s + pictures_html(in, listed, all);
}

namespace {
const ArtifactReportRegistrar reg("mesh", mesh_section);
}  // namespace

}  // namespace meshflow::mesh_report
