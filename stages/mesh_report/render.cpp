#include "stages/mesh_report/render.hpp"

#include "stages/model/quality.hpp"
#include "stages/model/topology.hpp"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <mutex>

namespace meshflow::mesh_report {

using model::Shape;

namespace {

// ---------------------------------------------------------------------------------------
// Faces of order P: the outline and the small triangles of the node lattice, as positions in
// the face's node list (Gmsh triangle/quad order).

struct FaceTable {
  std::vector<int> outline;
  std::vector<std::array<int, 3>> triangles;  // of a triangle's lattice
  std::vector<std::array<int, 4>> cells;      // of a quad's lattice (split by split_cell)
};

FaceTable make_face_table(Shape s, int order) {
  FaceTable t;
  const int nv = s == Shape::Tri ? 3 : 4, inner = order - 1;
  for (int k = 0; k < nv; ++k) {  // Gmsh order: vertices, then the edges' inner nodes edge by edge
    t.outline.push_back(k);
    for (int j = 0; j < inner; ++j) t.outline.push_back(nv + k * inner + j);
  }
  const auto& lat = model::lattice(s, order);
  std::map<std::pair<int, int>, int> at;
  for (std::size_t i = 0; i < lat.size(); ++i) at[{lat[i][0], lat[i][1]}] = int(i);
  auto n = [&](int i, int j) { return at.at({i, j}); };
  for (int i = 0; i < order; ++i)
    for (int j = 0; j < order; ++j) {
      if (s == Shape::Tri) {
        if (i + j < order) t.triangles.push_back({n(i, j), n(i + 1, j), n(i, j + 1)});
        if (i + j + 1 < order) t.triangles.push_back({n(i + 1, j), n(i + 1, j + 1), n(i, j + 1)});
      } else {
        t.cells.push_back({n(i, j), n(i + 1, j), n(i + 1, j + 1), n(i, j + 1)});
      }
    }
  return t;
}

const FaceTable& face_table(Shape s, int order) {
  static std::mutex mu;
  static std::map<std::pair<int, int>, FaceTable> tables;
  std::lock_guard<std::mutex> lock(mu);
  auto key = std::make_pair(int(s), order);
  auto it = tables.find(key);
  if (it == tables.end()) it = tables.emplace(key, make_face_table(s, order)).first;
  return it->second;
}

Shape face_shape(Shape element, int face) {
  return model::face_vertices(element)[face].size() == 3 ? Shape::Tri : Shape::Quad;
}

// A quad cell in two triangles along the diagonal at its smallest global node: the same
// diagonal from both elements sharing the face (whatever their local numbering), so that
// their cut outlines meet (a warped face cut along different diagonals leaves gaps).
void split_cell(const std::array<std::uint32_t, 4>& c, std::vector<std::array<std::uint32_t, 3>>& out) {
  const std::size_t k = std::size_t(std::min_element(c.begin(), c.end()) - c.begin());
  if (k % 2 == 0) {
    out.push_back({c[0], c[1], c[2]});
    out.push_back({c[0], c[2], c[3]});
  } else {
    out.push_back({c[0], c[1], c[3]});
    out.push_back({c[1], c[2], c[3]});
  }
}

// A face of an element (or a 2D element itself) as global node lists.
SurfaceFace face_of(const model::ElementBlock& b, std::size_t e, int face) {
  const std::uint32_t* nodes = b.element(e);
  SurfaceFace f;
  f.corners = face < 0 ? model::num_vertices(b.shape) : int(model::face_vertices(b.shape)[face].size());
  if (face < 0) {  // the 2D element itself
    const FaceTable& t = face_table(b.shape, b.order);
    for (int p : t.outline) f.outline.push_back(nodes[p]);
    for (auto& tr : t.triangles) f.triangles.push_back({nodes[tr[0]], nodes[tr[1]], nodes[tr[2]]});
    for (auto& c : t.cells) split_cell({nodes[c[0]], nodes[c[1]], nodes[c[2]], nodes[c[3]]}, f.triangles);
    return f;
  }
  const auto& local = model::face_nodes(b.shape, b.order)[face];
  const FaceTable& t = face_table(face_shape(b.shape, face), b.order);
  for (int p : t.outline) f.outline.push_back(nodes[local[p]]);
  for (auto& tr : t.triangles) f.triangles.push_back({nodes[local[tr[0]]], nodes[local[tr[1]]], nodes[local[tr[2]]]});
  for (auto& c : t.cells)
    split_cell({nodes[local[c[0]]], nodes[local[c[1]]], nodes[local[c[2]]], nodes[local[c[3]]]}, f.triangles);
  return f;
}

using VKey = std::array<std::uint32_t, 4>;  // sorted vertex nodes, UINT32_MAX padded
VKey vertex_key(const std::uint32_t* nodes, const std::vector<int>& local) {
  VKey k;
  k.fill(std::numeric_limits<std::uint32_t>::max());
  for (std::size_t i = 0; i < local.size(); ++i) k[i] = nodes[local[i]];
  std::sort(k.begin(), k.end());
  return k;
}

P3 sub(P3 a, P3 b) { return {a[0] - b[0], a[1] - b[1], a[2] - b[2]}; }
P3 cross(P3 a, P3 b) { return {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]}; }
double dot(P3 a, P3 b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }
P3 normalized(P3 a) {
  double n = std::sqrt(dot(a, a));
  return n > 0 ? P3{a[0] / n, a[1] / n, a[2] / n} : a;
}

// ---------------------------------------------------------------------------------------
// Plane sections: segments keyed by the (sorted) node pairs of the small triangles' edges
// they cross, chained into polylines and loops.

using EKey = std::uint64_t;
EKey edge_key(std::uint32_t a, std::uint32_t b) {
  if (a > b) std::swap(a, b);
  return (EKey(a) << 32) | b;
}

struct Section {
  const Scene& scene;
  int axis;
  double value;
  std::vector<std::pair<EKey, EKey>> segments;

  double side(std::uint32_t n) const { return scene.node(n)[axis] - value; }
  void add_triangle(const std::array<std::uint32_t, 3>& t) {
    EKey k[2];
    int found = 0;
    for (int i = 0; i < 3; ++i) {
      std::uint32_t a = t[i], b = t[(i + 1) % 3];
      if ((side(a) < 0) != (side(b) < 0) && found < 2) k[found++] = edge_key(a, b);
    }
    if (found == 2) segments.push_back({k[0], k[1]});
  }
  // Where the plane crosses the edge, computed from the sorted pair (bitwise the same for
  // every triangle sharing the edge); in plane coordinates (u, v).
  P2 point(EKey k) const {
    std::uint32_t lo = std::uint32_t(k >> 32), hi = std::uint32_t(k & 0xffffffffu);
    P3 a = scene.node(lo), b = scene.node(hi);
    double sa = a[axis] - value, sb = b[axis] - value, t = sa / (sa - sb);
    int u = (axis + 1) % 3, v = (axis + 2) % 3;
    return {a[u] + t * (b[u] - a[u]), a[v] + t * (b[v] - a[v])};
  }
  // Open chains first (from their ends), then closed loops (the first point not repeated).
  std::vector<std::vector<P2>> chains() const {
    std::map<EKey, std::vector<int>> at;
    for (int i = 0; i < int(segments.size()); ++i) {
      at[segments[i].first].push_back(i);
      at[segments[i].second].push_back(i);
    }
    std::vector<char> used(segments.size(), 0);
    std::vector<std::vector<P2>> out;
    auto walk = [&](EKey start, int seg) {
      std::vector<P2> c{point(start)};
      EKey cur = start;
      while (seg >= 0) {
        used[seg] = 1;
        cur = segments[seg].first == cur ? segments[seg].second : segments[seg].first;
        c.push_back(point(cur));
        seg = -1;
        for (int s : at[cur])
          if (!used[s]) {
            seg = s;
            break;
          }
      }
      if (cur == start && c.size() > 1) c.pop_back();
      out.push_back(std::move(c));
    };
    for (auto& [k, segs] : at)
      if (segs.size() % 2 == 1)
        for (int s : segs)
          if (!used[s]) walk(k, s);
    for (int i = 0; i < int(segments.size()); ++i)
      if (!used[i]) walk(segments[i].first, i);
    return out;
  }
};

// A scale bar of a round length near a fifth of the window.
void scale_bar(Svg& svg, double px_per_unit) {
  double target = svg.width() / 5 / px_per_unit;
  double p = std::pow(10.0, std::floor(std::log10(target)));
  double len = target >= 5 * p ? 5 * p : target >= 2 * p ? 2 * p : p;
  double x = 10, y = svg.height() - 10, w = len * px_per_unit;
  svg.rect(x - 3, y - 16, w + 6, 20, "#ffffff", "none");
  svg.polyline({{x, y}, {x + w, y}}, "#000", 2);
  char b[32];
  std::snprintf(b, sizeof b, "%g", len);
  svg.text(x + w / 2, y - 5, b, 10, "middle");
}

}  // namespace

// ---------------------------------------------------------------------------------------
// Scene

Scene::Scene(const model::Mesh& mesh, int threads) : m_(mesh), threads_(std::max(1, threads)) {
  dim_ = m_.dimension();
  std::uint64_t running = 0;  // implicit element tags count every block (mesh_stats' rule)
  for (std::uint32_t bi = 0; bi < m_.blocks.size(); ++bi) {
    const auto& b = m_.blocks[bi];
    if (model::dimension(b.shape) == dim_ && dim_ >= 2)
      for (std::uint32_t e = 0; e < b.size(); ++e) {
        elements_.push_back({bi, e});
        tags_.push_back(b.tags.empty() ? running + e + 1 : b.tags[e]);
      }
    running += b.size();
  }
  for (std::uint32_t i = 0; i < tags_.size(); ++i) by_tag_.push_back({tags_[i], i});
  std::sort(by_tag_.begin(), by_tag_.end());
  quality_.resize(elements_.size());
  have_quality_.assign(elements_.size(), 0);
  collect_surface();
  link_surface_to_elements();
}

std::int64_t Scene::find(std::uint64_t tag) const {
  auto it = std::lower_bound(by_tag_.begin(), by_tag_.end(), std::make_pair(tag, std::uint32_t(0)));
  return it != by_tag_.end() && it->first == tag ? std::int64_t(it->second) : -1;
}

P3 Scene::centroid(std::size_t e) const {
  const auto& b = m_.blocks[elements_[e].block];
  const std::uint32_t* n = b.element(elements_[e].element);
  P3 c{0, 0, 0};
  const int nn = b.nodes_per_element();
  for (int i = 0; i < nn; ++i)
    for (int r = 0; r < 3; ++r) c[r] += node(n[i])[r];
  for (auto& x : c) x /= nn;
  return c;
}

std::string Scene::type_name(std::size_t e) const {
  const auto& b = m_.blocks[elements_[e].block];
  return std::string(model::shape_name(b.shape)) + std::to_string(b.order);
}

void Scene::collect_surface() {
  if (dim_ == 2) {  // the elements are the surface
    for (std::size_t i = 0; i < elements_.size(); ++i) {
      SurfaceFace f = face_of(m_.blocks[elements_[i].block], elements_[i].element, -1);
      f.element = std::int64_t(i);
      surface_.push_back(std::move(f));
    }
    surface_groups_ = "every element (a 2D mesh)";
    return;
  }
  if (dim_ != 3) return;
  for (int pass = 0; pass < 2 && surface_.empty(); ++pass) {  // wall groups, else every boundary block
    std::map<std::string, int> names;
    for (const auto& b : m_.blocks) {
      if (model::dimension(b.shape) != 2) continue;
      std::string g = m_.group_name(b.entity_dim, b.entity_tag);
      if (pass == 0 && g.rfind("wall", 0) != 0) continue;
      names[g.empty() ? "untagged" : g] += 1;
      for (std::size_t e = 0; e < b.size(); ++e) surface_.push_back(face_of(b, e, -1));
    }
    for (auto& [n, c] : names) surface_groups_ += (surface_groups_.empty() ? "" : ", ") + n;
  }
  if (!surface_.empty()) return;
  // No boundary elements in the mesh: the boundary faces of the volume elements.
  model::Topology topo = model::build_topology(m_);
  for (const auto& tf : topo.faces)
    if (tf.elements.size() == 1) surface_.push_back(face_of(m_.blocks[tf.elements[0].block], tf.elements[0].element, int(tf.elements[0].local)));
  surface_groups_ = "every boundary face";
}

void Scene::link_surface_to_elements() {
  if (dim_ != 3 || surface_.empty()) return;
  std::vector<std::pair<VKey, std::uint32_t>> keys;
  for (std::uint32_t i = 0; i < surface_.size(); ++i) {
    const auto& f = surface_[i];
    VKey k;
    k.fill(std::numeric_limits<std::uint32_t>::max());
    const std::size_t step = f.outline.size() / std::size_t(f.corners);
    for (int c = 0; c < f.corners; ++c) k[std::size_t(c)] = f.outline[std::size_t(c) * step];
    std::sort(k.begin(), k.end());
    keys.push_back({k, i});
  }
  std::sort(keys.begin(), keys.end());
  for (std::size_t ei = 0; ei < elements_.size(); ++ei) {
    const auto& b = m_.blocks[elements_[ei].block];
    const std::uint32_t* nodes = b.element(elements_[ei].element);
    const auto& fv = model::face_vertices(b.shape);
    for (const auto& local : fv) {
      VKey k = vertex_key(nodes, local);
      auto it = std::lower_bound(keys.begin(), keys.end(), std::make_pair(k, std::uint32_t(0)));
      for (; it != keys.end() && it->first == k; ++it)
        if (surface_[it->second].element < 0) surface_[it->second].element = std::int64_t(ei);
    }
  }
}

void Scene::need_quality(const std::vector<std::int64_t>& wanted) {
  std::vector<std::size_t> todo;
  for (auto e : wanted)
    if (e >= 0 && !have_quality_[std::size_t(e)]) {
      have_quality_[std::size_t(e)] = 1;
      todo.push_back(std::size_t(e));
    }
  auto one = [&](std::size_t e) {
    const auto& b = m_.blocks[elements_[e].block];
    const std::uint32_t* n = b.element(elements_[e].element);
    const int nn = b.nodes_per_element();
    std::vector<double> X(3 * std::size_t(nn));
    for (int i = 0; i < nn; ++i) {
      X[3 * i] = m_.x[n[i]];
      X[3 * i + 1] = m_.y[n[i]];
      X[3 * i + 2] = m_.z[n[i]];
    }
    model::ElementQuality q = model::element_quality(b.shape, b.order, X.data());
    quality_[e] = {q.scaled_jacobian, q.valid && !q.inconclusive};
  };
  tbb::task_arena arena(threads_);
  arena.execute([&] {
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, todo.size(), 16), [&](const tbb::blocked_range<std::size_t>& r) {
      for (std::size_t i = r.begin(); i != r.end(); ++i) one(todo[i]);
    });
  });
}

void Scene::use_quality(const model::MeshQuality& q) {
  for (std::size_t e = 0; e < elements_.size(); ++e) {
    const model::ElementQuality& x = q.at(elements_[e].block).at(elements_[e].element);
    quality_[e] = {x.scaled_jacobian, x.valid && !x.inconclusive};
    have_quality_[e] = 1;
  }
}

std::vector<std::vector<std::uint32_t>> Scene::element_face_outlines(std::size_t e) const {
  const auto& b = m_.blocks[elements_[e].block];
  std::vector<std::vector<std::uint32_t>> out;
  if (dim_ == 2) {
    out.push_back(face_of(b, elements_[e].element, -1).outline);
    return out;
  }
  for (int f = 0; f < int(model::face_vertices(b.shape).size()); ++f) out.push_back(face_of(b, elements_[e].element, f).outline);
  return out;
}

// ---------------------------------------------------------------------------------------
// Surface pictures

P2 Projection::operator()(const P3& p) const { return {ox + scale * dot(p, right), oy - scale * dot(p, up)}; }
double Projection::depth(const P3& p) const { return dot(p, eye); }

Svg surface_picture(Scene& scene, const View& view, double width, double height, bool grey_only, Projection* project) {
  Projection pr;
  pr.eye = normalized(view.eye);
  P3 U{0, 0, 0};
  U[view.up] = 1;
  if (std::abs(dot(U, pr.eye)) > 0.99) U = {U[2], U[0], U[1]};
  pr.right = normalized(cross(U, pr.eye));
  pr.up = cross(pr.eye, pr.right);

  struct Drawn {
    double depth;
    std::size_t face;
    double facing;
  };
  std::vector<Drawn> drawn;
  const auto& faces = scene.surface();
  std::vector<std::int64_t> elems;
  for (std::size_t i = 0; i < faces.size(); ++i) {
    const auto& f = faces[i];
    P3 n{0, 0, 0}, c{0, 0, 0};
    for (std::size_t k = 0; k < f.outline.size(); ++k) {  // Newell's normal of the outline
      P3 a = scene.node(f.outline[k]), b = scene.node(f.outline[(k + 1) % f.outline.size()]);
      n[0] += (a[1] - b[1]) * (a[2] + b[2]);
      n[1] += (a[2] - b[2]) * (a[0] + b[0]);
      n[2] += (a[0] - b[0]) * (a[1] + b[1]);
      for (int r = 0; r < 3; ++r) c[r] += a[r] / double(f.outline.size());
    }
    n = normalized(n);
    double facing = 1;
    if (scene.dimension() == 3 && f.element >= 0) {
      if (dot(n, sub(scene.centroid(std::size_t(f.element)), c)) < 0) n = {-n[0], -n[1], -n[2]};  // toward the fluid
      facing = dot(n, pr.eye);
      if (facing <= 0) continue;  // seen from inside the body
    } else {
      facing = std::abs(dot(n, pr.eye));
    }
    drawn.push_back({pr.depth(c), i, facing});
    elems.push_back(f.element);
  }
  if (!grey_only) scene.need_quality(elems);
  std::stable_sort(drawn.begin(), drawn.end(), [](const Drawn& a, const Drawn& b) { return a.depth < b.depth; });

  // Fit the visible faces into the picture (10 px margin; 34 px below for the legend).
  const double legend = grey_only ? 0 : 34;
  double x0 = 1e300, x1 = -1e300, y0 = 1e300, y1 = -1e300;
  for (auto& d : drawn)
    for (auto n : faces[d.face].outline) {
      P3 p = scene.node(n);
      double x = dot(p, pr.right), y = dot(p, pr.up);
      x0 = std::min(x0, x), x1 = std::max(x1, x), y0 = std::min(y0, y), y1 = std::max(y1, y);
    }
  if (drawn.empty()) x0 = y0 = 0, x1 = y1 = 1;
  const double aw = width - 20, ah = height - 20 - legend;
  pr.scale = std::min(aw / std::max(x1 - x0, 1e-300), ah / std::max(y1 - y0, 1e-300));
  pr.ox = 10 + (aw - pr.scale * (x1 - x0)) / 2 - pr.scale * x0;
  pr.oy = 10 + (ah - pr.scale * (y1 - y0)) / 2 + pr.scale * y1;

  Svg svg(width, height);
  const double stroke = drawn.size() > 20000 ? 0.15 : 0.3;
  std::vector<P2> pts;
  svg.begin_group(grey_only ? "#8a8f96" : "#262a30", stroke);
  for (auto& d : drawn) {
    const auto& f = faces[d.face];
    pts.clear();
    for (auto n : f.outline) pts.push_back(pr(scene.node(n)));
    std::string fill;
    if (grey_only || f.element < 0) fill = grey(d.facing).hex();
    else {
      Rgb c = quality_colour(scene.quality(std::size_t(f.element)).scaled_jacobian);
      double shade = 0.75 + 0.25 * d.facing;  // a little light from the viewer
      fill = Rgb{std::uint8_t(c.r * shade), std::uint8_t(c.g * shade), std::uint8_t(c.b * shade)}.hex();
    }
    svg.polygon(pts, fill, "", stroke);
  }
  svg.end_group();
  if (!grey_only) quality_legend(svg, 10, height - 28, 220);
  if (project) *project = pr;
  return svg;
}

// ---------------------------------------------------------------------------------------
// Cut pictures

std::vector<std::vector<P2>> surface_trace(const Scene& scene, int axis, double value) {
  Section sec{scene, axis, value, {}};
  for (const auto& f : scene.surface())
    for (const auto& t : f.triangles) sec.add_triangle(t);
  return sec.chains();
}

std::vector<CutPiece> cut_elements(const Scene& scene, const Cut& cut) {
  const int u = (cut.axis + 1) % 3, v = (cut.axis + 2) % 3;
  const model::Mesh& m = scene.mesh();
  std::vector<CutPiece> pieces;
  const auto& E = scene.elements();
  for (std::size_t ei = 0; ei < E.size(); ++ei) {
    const auto& b = m.blocks[E[ei].block];
    const std::uint32_t* n = b.element(E[ei].element);
    const int nn = b.nodes_per_element();
    double lo[3] = {1e300, 1e300, 1e300}, hi[3] = {-1e300, -1e300, -1e300};
    for (int i = 0; i < nn; ++i) {
      P3 p = scene.node(n[i]);
      for (int r = 0; r < 3; ++r) lo[r] = std::min(lo[r], p[r]), hi[r] = std::max(hi[r], p[r]);
    }
    if (lo[cut.axis] > cut.value || hi[cut.axis] < cut.value) continue;
    if (hi[u] < cut.u0 || lo[u] > cut.u1 || hi[v] < cut.v0 || lo[v] > cut.v1) continue;
    Section sec{scene, cut.axis, cut.value, {}};
    for (int f = 0; f < int(model::face_vertices(b.shape).size()); ++f)
      for (const auto& t : face_of(b, E[ei].element, f).triangles) sec.add_triangle(t);
    if (sec.segments.empty()) continue;
    pieces.push_back({ei, sec.chains()});
  }
  return pieces;
}

Svg cut_picture(Scene& scene, const Cut& cut, double width, const std::vector<std::int64_t>& marked) {
  const double du = cut.u1 - cut.u0, dv = cut.v1 - cut.v0;
  const double scale = width / du, height = std::round(dv * scale);
  auto px = [&](const P2& p) { return P2{(p[0] - cut.u0) * scale, (cut.v1 - p[1]) * scale}; };

  std::vector<CutPiece> pieces = cut_elements(scene, cut);
  std::vector<std::int64_t> elems;
  for (auto& p : pieces) elems.push_back(std::int64_t(p.element));
  scene.need_quality(elems);

  Svg svg(width, height);
  const double stroke = pieces.size() > 4000 ? 0.2 : 0.4;
  std::vector<std::vector<P2>> loops;
  svg.begin_group("#262a30", stroke);
  for (auto& p : pieces) {
    loops.clear();
    for (auto& l : p.loops) {
      std::vector<P2> q;
      for (auto& x : l) q.push_back(px(x));
      loops.push_back(std::move(q));
    }
    svg.loops(loops, quality_colour(scene.quality(p.element).scaled_jacobian).hex(), "", stroke);
  }
  svg.end_group();
  for (auto& chain : surface_trace(scene, cut.axis, cut.value)) {
    std::vector<P2> q;
    for (auto& x : chain) q.push_back(px(x));
    svg.polyline(q, "#000", 1.4);
  }
  // Marks: a ring and the tag at each marked element's cut.
  for (auto& p : pieces) {
    if (std::find(marked.begin(), marked.end(), std::int64_t(p.element)) == marked.end()) continue;
    P2 c{0, 0};
    std::size_t k = 0;
    for (auto& l : p.loops)
      for (auto& x : l) {
        P2 q = px(x);
        c[0] += q[0], c[1] += q[1], ++k;
      }
    if (!k) continue;
    c[0] /= double(k), c[1] /= double(k);
    svg.circle(c[0], c[1], 7, "none", "#d4006a", 2);
    svg.text(c[0] + 9, c[1] - 6, std::to_string(scene.tag(p.element)), 12, "start", "#d4006a");
  }
  scale_bar(svg, scale);
  return svg;
}

}  // namespace meshflow::mesh_report
