#include "stages/contract/contract.hpp"

#include "engine/artifact_type.hpp"
#include "engine/stage.hpp"
#include "stages/cad/cad.hpp"
#include "stages/io/mesh_io.hpp"
#include "stages/model/basis.hpp"
#include "stages/model/quality.hpp"
#include "stages/model/topology.hpp"

#include <tbb/parallel_for.h>
#include <tbb/parallel_invoke.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <fstream>
#include <map>
#include <numeric>
#include <sstream>

namespace meshflow::contract {
namespace {

using nlohmann::json;
using model::Mesh;
using model::Shape;

// Gauss-Legendre points and weights on [0, 1] (Newton on the Legendre recurrence: the rule
// is a few lines and exact to degree 2n-1; no library here provides it for our reference
// shapes with Gmsh's node numbering, and the points only feed the sums below).
void gauss_legendre(int n, std::vector<double>& x, std::vector<double>& w) {
  x.assign(size_t(n), 0);
  w.assign(size_t(n), 0);
  for (int i = 0; i < n; ++i) {
    double z = std::cos(M_PI * (i + 0.75) / (n + 0.5)), dp = 1;
    for (int it = 0; it < 100; ++it) {
      double p0 = 1, p1 = z;
      for (int k = 2; k <= n; ++k) {
        double p2 = ((2 * k - 1) * z * p1 - (k - 1) * p0) / k;
        p0 = p1, p1 = p2;
      }
      if (n == 1) p1 = z, p0 = 1;
      dp = n * (z * p1 - p0) / (z * z - 1);
      double dz = p1 / dp;
      z -= dz;
      if (std::abs(dz) < 1e-16) break;
    }
    x[size_t(i)] = 0.5 * (1 - z);
    w[size_t(i)] = 1.0 / ((1 - z * z) * dp * dp);  // 2/((1-z^2) p'^2) on [-1,1], halved
  }
}

// Quadrature of a triangle or quad face of order P: basis values and gradients at the points.
struct FaceRule {
  int n = 0;  // nodes per face
  std::vector<double> w, N, dN;  // per point: weight; n values; 3n gradients
};

FaceRule make_rule(Shape s, int order) {
  const auto& basis = model::LagrangeBasis::get(s, order);
  FaceRule r;
  r.n = basis.size();
  std::vector<double> g, gw;
  gauss_legendre((3 * order + 3) / 2 + 1, g, gw);
  for (size_t i = 0; i < g.size(); ++i)
    for (size_t j = 0; j < g.size(); ++j) {
      model::Vec3 xi;
      double wt;
      if (s == Shape::Tri) {  // Duffy: u = a (1 - b), v = b on the unit triangle
        xi = {g[i] * (1 - g[j]), g[j], 0};
        wt = gw[i] * gw[j] * (1 - g[j]);
      } else {  // [-1, 1]^2
        xi = {2 * g[i] - 1, 2 * g[j] - 1, 0};
        wt = 4 * gw[i] * gw[j];
      }
      r.w.push_back(wt);
      size_t o = r.N.size();
      r.N.resize(o + size_t(r.n));
      r.dN.resize(3 * (o + size_t(r.n)));
      basis.eval(xi, r.N.data() + o);
      basis.grad(xi, r.dN.data() + 3 * o);
    }
  return r;
}

class FaceIntegrator {
 public:
  // Area and flux of (x - c) through the face: X = 3 n coordinates in the face's node order.
  void integrate(Shape s, int order, const double* X, const double c[3], double& area, double& flux) {
    auto key = std::make_pair(int(s), order);
    auto it = rules_.find(key);
    if (it == rules_.end()) it = rules_.emplace(key, make_rule(s, order)).first;
    const FaceRule& r = it->second;
    area = flux = 0;
    for (size_t q = 0; q < r.w.size(); ++q) {
      const double* N = r.N.data() + q * size_t(r.n);
      const double* dN = r.dN.data() + 3 * q * size_t(r.n);
      double x[3] = {0, 0, 0}, xu[3] = {0, 0, 0}, xv[3] = {0, 0, 0};
      for (int i = 0; i < r.n; ++i)
        for (int k = 0; k < 3; ++k) {
          x[k] += N[i] * (X[3 * i + k] - c[k]);
          xu[k] += dN[3 * i] * X[3 * i + k];
          xv[k] += dN[3 * i + 1] * X[3 * i + k];
        }
      double nrm[3] = {xu[1] * xv[2] - xu[2] * xv[1], xu[2] * xv[0] - xu[0] * xv[2], xu[0] * xv[1] - xu[1] * xv[0]};
      area += r.w[q] * std::sqrt(nrm[0] * nrm[0] + nrm[1] * nrm[1] + nrm[2] * nrm[2]);
      flux += r.w[q] * (x[0] * nrm[0] + x[1] * nrm[1] + x[2] * nrm[2]);
    }
  }

 private:
  std::map<std::pair<int, int>, FaceRule> rules_;
};

// Flux of (x - c0) through boundary face f of the volume mesh, oriented out of its element
// (Gmsh's face tables are outward): a third of it summed over the boundary is the enclosed volume.
double face_flux(const Mesh& m, const model::TopoFace& f, FaceIntegrator& integ, std::vector<double>& X, const double c0[3]) {
  const auto& er = f.elements[0];
  const auto& b = m.blocks[er.block];
  const auto& fn = model::face_nodes(b.shape, b.order)[er.local];
  const std::uint32_t* nn = b.element(er.element);
  X.resize(3 * fn.size());
  for (size_t i = 0; i < fn.size(); ++i) X[3 * i] = m.x[nn[fn[i]]], X[3 * i + 1] = m.y[nn[fn[i]]], X[3 * i + 2] = m.z[nn[fn[i]]];
  double a, fl;
  integ.integrate(f.num_vertices == 3 ? Shape::Tri : Shape::Quad, b.order, X.data(), c0, a, fl);
  return fl;
}

std::string type_name(const model::ElementBlock& b) { return std::string(model::shape_name(b.shape)) + std::to_string(b.order); }

json point(const double p[3]) { return json::array({p[0], p[1], p[2]}); }

// Mean of the element's vertices.
void centroid(const Mesh& m, const model::ElementBlock& b, std::size_t e, double c[3]) {
  const std::uint32_t* n = b.element(e);
  const int nv = model::num_vertices(b.shape);
  c[0] = c[1] = c[2] = 0;
  for (int v = 0; v < nv; ++v) c[0] += m.x[n[v]], c[1] += m.y[n[v]], c[2] += m.z[n[v]];
  for (int k = 0; k < 3; ++k) c[k] /= nv;
}

// Why an element is degenerate ("" when it is not), from its straight (vertex) geometry.
std::string degeneracy(const Mesh& m, const model::ElementBlock& b, std::size_t e, double& ratio) {
  const std::uint32_t* n = b.element(e);
  auto P = [&](int v) { return std::array<double, 3>{m.x[n[v]] - m.x[n[0]], m.y[n[v]] - m.y[n[0]], m.z[n[v]] - m.z[n[0]]}; };
  auto sub = [](const std::array<double, 3>& a, const std::array<double, 3>& c) {
    return std::array<double, 3>{a[0] - c[0], a[1] - c[1], a[2] - c[2]};
  };
  auto cross = [](const std::array<double, 3>& a, const std::array<double, 3>& c) {
    return std::array<double, 3>{a[1] * c[2] - a[2] * c[1], a[2] * c[0] - a[0] * c[2], a[0] * c[1] - a[1] * c[0]};
  };
  auto norm = [](const std::array<double, 3>& a) { return std::sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]); };
  double lo = INFINITY, hi = 0;
  for (auto ev : model::edge_vertices(b.shape)) {
    double l = norm(sub(P(ev[1]), P(ev[0])));
    lo = std::min(lo, l), hi = std::max(hi, l);
  }
  if (!(hi > 0)) {
    ratio = 0;
    return "all vertices coincide";
  }
  if (lo < kMinEdgeRatio * hi) {
    ratio = lo / hi;
    return "zero-length edge";
  }
  // Vector area of each face; the volume by the divergence theorem over the straight faces.
  double volume = 0, min_area = INFINITY;
  for (const auto& fv : model::face_vertices(b.shape)) {
    std::array<double, 3> A, c = {0, 0, 0};
    if (fv.size() == 3) {
      auto x = cross(sub(P(fv[1]), P(fv[0])), sub(P(fv[2]), P(fv[0])));
      A = {x[0] / 2, x[1] / 2, x[2] / 2};
    } else {
      auto x = cross(sub(P(fv[2]), P(fv[0])), sub(P(fv[3]), P(fv[1])));
      A = {x[0] / 2, x[1] / 2, x[2] / 2};
    }
    for (int v : fv)
      for (int k = 0; k < 3; ++k) c[k] += P(v)[k] / double(fv.size());
    min_area = std::min(min_area, norm(A));
    volume += (c[0] * A[0] + c[1] * A[1] + c[2] * A[2]) / 3;
  }
  if (min_area < kMinAreaRatio * hi * hi) {
    ratio = min_area / (hi * hi);
    return "zero-area face";
  }
  if (model::dimension(b.shape) == 3 && std::abs(volume) < kMinVolumeRatio * hi * hi * hi) {
    ratio = std::abs(volume) / (hi * hi * hi);
    return "zero volume";
  }
  return "";
}

// Tag of element e of block bi as the mesh's files number it (implicit: running index + 1).
struct Tags {
  explicit Tags(const Mesh& m) : m_(m) {
    std::uint64_t run = 0;
    for (auto& b : m.blocks) offset_.push_back(run), run += b.size();
  }
  std::uint64_t operator()(std::size_t bi, std::size_t e) const {
    const auto& b = m_.blocks[bi];
    return b.tags.empty() ? offset_[bi] + e + 1 : b.tags[e];
  }
  const Mesh& m_;
  std::vector<std::uint64_t> offset_;
};

json problem(const std::string& clause, const std::string& what, std::size_t count, bool blocking, json where,
             const std::string& hint) {
  json p = {{"clause", clause}, {"what", what}, {"count", count}, {"blocking", blocking}, {"where", std::move(where)}};
  if (!hint.empty()) p["hint"] = hint;
  return p;
}

// What the clause checks share: the mesh, its element tags, the result being filled, and the
// quadrature of boundary faces.
struct Checker {
  const Mesh& m;
  const Tags tags;
  Result& r;
  FaceIntegrator integ;
  std::vector<double> X;
  double c0[3];
  Checker(const Mesh& mesh, Result& result) : m(mesh), tags(mesh), r(result) {
    for (int k = 0; k < 3; ++k) c0[k] = m.num_nodes() ? (k == 0 ? m.x[0] : k == 1 ? m.y[0] : m.z[0]) : 0;
  }

  void face_centre(const model::TopoFace& f, double c[3]) const {
    c[0] = c[1] = c[2] = 0;
    for (int k = 0; k < f.num_vertices; ++k) {
      auto v = f.vertices[size_t(k)];
      c[0] += m.x[v] / f.num_vertices, c[1] += m.y[v] / f.num_vertices, c[2] += m.z[v] / f.num_vertices;
    }
  }

  // validity: invalid or inconclusive elements, the worst first
  void validity(const std::vector<std::vector<model::ElementQuality>>& q) {
    struct Bad {
      double sj;
      std::size_t bi, e;
    };
    std::vector<Bad> bad;
    std::size_t inconclusive = 0;
    for (std::size_t bi = 0; bi < m.blocks.size(); ++bi)
      for (std::size_t e = 0; e < q[bi].size(); ++e) {
        const auto& eq = q[bi][e];
        if (!eq.valid || eq.inconclusive) bad.push_back({eq.scaled_jacobian, bi, e});
        if (eq.valid && eq.inconclusive) ++inconclusive;
      }
    r.contract["invalid"] = bad.size() - inconclusive;
    r.contract["inconclusive"] = inconclusive;
    if (bad.empty()) return;
    std::stable_sort(bad.begin(), bad.end(), [](const Bad& a, const Bad& b) { return a.sj < b.sj; });
    json where = json::array();
    for (std::size_t i = 0; i < bad.size() && i < kWhereListed; ++i) {
      double c[3];
      centroid(m, m.blocks[bad[i].bi], bad[i].e, c);
      where.push_back({{"element", tags(bad[i].bi, bad[i].e)},
                       {"type", type_name(m.blocks[bad[i].bi])},
                       {"at", point(c)},
                       {"scaled_jacobian", bad[i].sj},
                       {"inconclusive", q[bad[i].bi][bad[i].e].valid}});
    }
    std::string what = std::to_string(bad.size()) + " element(s) with det J <= 0 somewhere";
    if (inconclusive) what += " (" + std::to_string(inconclusive) + " of them not proven valid: Bezier bounds inconclusive)";
    r.problems.push_back(problem("validity", what, bad.size(), false, where, ""));
  }

  void degenerate() {
    const int dim = m.dimension();
    std::size_t count = 0;
    json where = json::array();
    for (std::size_t bi = 0; bi < m.blocks.size(); ++bi) {
      const auto& b = m.blocks[bi];
      if (model::dimension(b.shape) != dim) continue;
      for (std::size_t e = 0; e < b.size(); ++e) {
        double ratio = 0;
        std::string why = degeneracy(m, b, e, ratio);
        if (why.empty()) continue;
        if (++count > std::size_t(kWhereListed)) continue;
        double c[3];
        centroid(m, b, e, c);
        where.push_back({{"element", tags(bi, e)}, {"type", type_name(b)}, {"at", point(c)}, {"why", why}, {"ratio", ratio}});
      }
    }
    r.contract["degenerate"] = count;
    if (count)
      r.problems.push_back(problem("degenerate",
                                   std::to_string(count) + " degenerate element(s) (zero-length edge, zero-area face or zero volume)",
                                   count, true, where, ""));
  }

  void conformity(const model::Topology& topo) {
    if (!topo.nonconforming_faces) return;
    json where = json::array();
    for (const auto& f : topo.faces) {
      if (f.conforming || where.size() >= std::size_t(kWhereListed)) continue;
      double c[3];
      face_centre(f, c);
      json els = json::array();
      for (auto& er : f.elements) els.push_back(tags(er.block, er.element));
      where.push_back({{"face_of", els}, {"at", point(c)}});
    }
    r.problems.push_back(problem("conformity",
                                 std::to_string(topo.nonconforming_faces) +
                                     " face(s) not shared by exactly two elements with the same face nodes",
                                 topo.nonconforming_faces, true, where, ""));
  }

  // Area of the boundary elements (the 2D blocks) per entity.
  std::map<int, double> entity_areas() {
    std::map<int, double> area;
    for (const auto& b : m.blocks) {
      if (model::dimension(b.shape) != 2) continue;
      const int n = b.nodes_per_element();
      X.resize(3 * size_t(n));
      double& sum = area[b.entity_tag];
      for (std::size_t e = 0; e < b.size(); ++e) {
        const std::uint32_t* nn = b.element(e);
        for (int i = 0; i < n; ++i) X[3 * i] = m.x[nn[i]], X[3 * i + 1] = m.y[nn[i]], X[3 * i + 2] = m.z[nn[i]];
        double a, f;
        integ.integrate(b.shape, b.order, X.data(), c0, a, f);
        sum += a;
      }
    }
    return area;
  }

  // tags (each boundary face of the volume mesh is a tagged boundary element) and volume (the
  // one the boundary faces enclose, against the reference's)
  void tags_and_volume(const model::Topology& topo, const CadReference* cad, double tol) {
    // Boundary elements by their sorted vertices, to find the one on each boundary face.
    struct Key {
      std::array<std::uint32_t, 4> v;
      std::uint32_t block, element;
      bool operator<(const Key& o) const { return v < o.v; }
    };
    std::vector<Key> keys;
    for (std::uint32_t bi = 0; bi < m.blocks.size(); ++bi) {
      const auto& b = m.blocks[bi];
      if (model::dimension(b.shape) != 2) continue;
      const int nv = model::num_vertices(b.shape);
      for (std::uint32_t e = 0; e < b.size(); ++e) {
        Key k{{UINT32_MAX, UINT32_MAX, UINT32_MAX, UINT32_MAX}, bi, e};
        for (int v = 0; v < nv; ++v) k.v[size_t(v)] = b.element(e)[v];
        std::sort(k.v.begin(), k.v.begin() + nv);
        keys.push_back(k);
      }
    }
    std::sort(keys.begin(), keys.end());
    std::size_t untagged = 0;
    json where = json::array();
    double flux = 0;
    for (const auto& f : topo.faces) {
      if (f.elements.size() != 1) continue;
      const auto& er = f.elements[0];
      flux += face_flux(m, f, integ, X, c0);
      Key probe{f.vertices, 0, 0};
      auto it = std::lower_bound(keys.begin(), keys.end(), probe);
      bool tagged = false;
      if (it != keys.end() && it->v == f.vertices) {
        const model::Entity* ent = m.find_entity(2, m.blocks[it->block].entity_tag);
        tagged = ent && !ent->physicals.empty();
      }
      if (tagged) continue;
      ++untagged;
      if (where.size() < std::size_t(kWhereListed)) {
        double c[3];
        face_centre(f, c);
        where.push_back({{"face_of", tags(er.block, er.element)}, {"at", point(c)}});
      }
    }
    const double volume = flux / 3;
    r.contract["untagged_faces"] = untagged;
    r.contract["volume"] = volume;
    if (untagged)
      r.problems.push_back(problem("tags",
                                   std::to_string(untagged) +
                                       " boundary face(s) of the volume mesh without a tagged boundary element (no physical group)",
                                   untagged, true, where, ""));
    if (!cad || !(cad->volume > 0)) return;
    if (!cad->volume_reliable) {
      r.contract["reference_volume_unreliable"] = cad->volume;
      return;
    }
    const double rel = std::abs(volume - cad->volume) / cad->volume;
    r.contract["reference_volume"] = cad->volume;
    r.contract["reference"] = cad->source;
    r.contract["volume_rel_error"] = rel;
    if (rel <= tol) return;
    std::ostringstream s;
    s << "the mesh encloses a volume of " << volume << ", " << cad->source << " " << cad->volume << " (relative difference "
      << rel << ", tolerance " << tol << ")";
    if (inverted()) s << " (with inverted elements, whose folded faces are not the surface)";
    r.problems.push_back(problem("volume", s.str(), 1, !inverted(), json::array(), ""));
  }

  // The boundary elements close: every edge of theirs is used by an even number of them (two
  // on a manifold surface); an edge used once is the rim of a hole.
  void closure() {
    std::vector<std::array<std::uint32_t, 2>> edges;
    for (const auto& b : m.blocks) {
      if (model::dimension(b.shape) != 2) continue;
      for (std::size_t e = 0; e < b.size(); ++e)
        for (auto ev : model::edge_vertices(b.shape)) {
          std::uint32_t a = b.element(e)[ev[0]], c = b.element(e)[ev[1]];
          edges.push_back({std::min(a, c), std::max(a, c)});
        }
    }
    std::sort(edges.begin(), edges.end());
    std::size_t rim = 0;
    json where = json::array();
    for (std::size_t i = 0; i < edges.size();) {
      std::size_t j = i;
      while (j < edges.size() && edges[j] == edges[i]) ++j;
      if ((j - i) % 2 == 1) {
        ++rim;
        if (where.size() < std::size_t(kWhereListed)) {
          double c[3] = {(m.x[edges[i][0]] + m.x[edges[i][1]]) / 2, (m.y[edges[i][0]] + m.y[edges[i][1]]) / 2,
                         (m.z[edges[i][0]] + m.z[edges[i][1]]) / 2};
          where.push_back({{"edge", {edges[i][0] + 1, edges[i][1] + 1}}, {"at", point(c)}});
        }
      }
      i = j;
    }
    r.contract["boundary_rim_edges"] = rim;
    if (rim)
      r.problems.push_back(problem("coverage",
                                   "the boundary elements do not close: " + std::to_string(rim) +
                                       " edge(s) used by an odd number of them (the rim of a hole)",
                                   rim, true, where, ""));
  }

  // Whether the validity clause found inverted elements. Their folded boundary faces count area
  // (and the volume behind them) twice, so the area and volume clauses measure no surface: then
  // they are, like validity, repairable by a later stage, which is judged again (a delivered
  // stage is judged as it is, and fails on validity anyway).
  bool inverted() const {
    for (const auto& p : r.problems)
      if (p.value("clause", std::string()) == "validity") return true;
    return false;
  }

  // Each CAD face has boundary elements; each group's boundary area matches its faces' area.
  // (Per face, the areas are reported but not compared: junction strips are elements of one
  // face that can reach onto its neighbour, which moves area between faces, not out of a group.)
  void coverage(const CadReference& cad, double tol) {
    const std::map<int, double> entity_area = entity_areas();
    std::size_t uncovered = 0;
    double worst = 0;
    json where = json::array();
    std::map<std::string, std::array<double, 2>> by_group;  // mesh, CAD
    json unreliable = json::array();
    for (const auto& f : cad.faces) {
      if (!(f.area > 0)) continue;
      auto it = entity_area.find(f.entity);
      const double a = it == entity_area.end() ? 0.0 : it->second;
      if (f.reliable) {
        worst = std::max(worst, std::abs(a - f.area) / f.area);
        by_group[f.group][0] += a;
        by_group[f.group][1] += f.area;
      } else {
        unreliable.push_back(f.entity - 1);
      }
      if (a > 0) continue;
      ++uncovered;
      if (where.size() < std::size_t(kWhereListed))
        where.push_back({{"cad_face", f.entity - 1}, {"group", f.group}, {"mesh_area", a}, {"cad_area", f.area}});
    }
    r.contract["faces_checked"] = cad.faces.size();
    r.contract["faces_area_unreliable"] = unreliable;
    r.contract["face_area_worst_rel_error"] = worst;
    if (uncovered)
      r.problems.push_back(problem("coverage",
                                   std::to_string(uncovered) + " face(s) of the healed CAD without any boundary element",
                                   uncovered, true, where, ""));
    json groups = json::object();
    json gwhere = json::array();
    std::size_t off = 0;
    for (auto& [g, a] : by_group) {
      const double rel = std::abs(a[0] - a[1]) / a[1];
      groups[g.empty() ? "(untagged)" : g] = {{"mesh_area", a[0]}, {"cad_area", a[1]}, {"rel_error", rel}};
      if (rel <= tol) continue;
      ++off;
      gwhere.push_back({{"group", g}, {"mesh_area", a[0]}, {"cad_area", a[1]}});
    }
    r.contract["group_areas"] = groups;
    if (off) {
      std::ostringstream s;
      s << off << " group(s) whose boundary elements' area differs from their CAD faces' by more than " << tol << " relative";
      if (inverted()) s << " (with inverted elements, whose folded faces are not the surface)";
      r.problems.push_back(problem("coverage", s.str(), off, !inverted(), gwhere, ""));
    }
  }
};

}  // namespace

Result check(const Mesh& m, Extent extent, const CadReference* cad, int threads, const model::MeshQuality* known,
             const std::vector<char>* moved) {
  Result r;
  r.problems = json::array();
  r.quality = model::mesh_quality(m, threads, known, moved);
  const auto& q = r.quality;
  const auto topo = model::build_topology(m);
  r.mesh = model::mesh_stats(m, q, topo);
  const int dim = m.dimension();
  const double tol = m.order() <= 1 ? kLinearTolerance : kCurvedTolerance;
  r.contract = {{"extent", extent == Extent::Domain ? "domain" : "near_field"},
                {"tolerances",
                 {{"min_edge_ratio", kMinEdgeRatio},
                  {"min_area_ratio", kMinAreaRatio},
                  {"min_volume_ratio", kMinVolumeRatio},
                  {"area_volume_rel", tol}}}};
  Checker c(m, r);
  c.validity(q);
  c.degenerate();
  c.conformity(topo);
  if (dim == 3 && extent == Extent::Domain) c.tags_and_volume(topo, cad, tol);
  if (dim == 3) c.closure();  // a 2D mesh's elements are the domain, not its boundary
  if (dim >= 2 && cad && !cad->faces.empty()) c.coverage(*cad, tol);
  return r;
}

double enclosed_volume(const Mesh& m) {
  if (m.dimension() != 3 || m.num_nodes() == 0) return 0;
  const auto topo = model::build_topology(m);
  FaceIntegrator integ;
  std::vector<double> X;
  const double c0[3] = {m.x[0], m.y[0], m.z[0]};
  double flux = 0;
  for (const auto& f : topo.faces)
    if (f.elements.size() == 1) flux += face_flux(m, f, integ, X, c0);
  return flux / 3;
}

CadReference cad_reference(const cad::Shape& shape, int threads) {
  auto agree = [](double a, double b) { return std::abs(a - b) <= kReferenceAgreement * std::max(std::abs(a), std::abs(b)); };
  // each figure on its own (the shape's const integrations may run concurrently: cad.hpp)
  const int nf = shape.num_faces();
  std::vector<double> fixed(nf), adaptive(nf);
  double volume = 0, volume_adaptive = 0;
  tbb::task_arena arena(std::max(1, threads));
  arena.execute([&] {
    tbb::parallel_invoke([&] { volume = shape.volume(); }, [&] { volume_adaptive = shape.volume(1e-7); },
                         [&] {
                           tbb::parallel_for(0, 2 * nf, [&](int k) {
                             if (k < nf) fixed[k] = shape.face_area(k);
                             else adaptive[k - nf] = shape.face_area(k - nf, 1e-7);
                           });
                         });
  });
  CadReference ref;
  ref.volume = volume;
  ref.volume_reliable = agree(volume, volume_adaptive);
  for (int f = 0; f < nf; ++f) {
    cad::Tag t = shape.face_tag(f);
    ref.faces.push_back({f + 1, fixed[f], t == cad::Tag::none ? "" : cad::tag_name(t), agree(fixed[f], adaptive[f])});
  }
  return ref;
}

void write_cad_reference(const CadReference& ref, const std::filesystem::path& path) {
  json faces = json::array();
  for (auto& f : ref.faces)
    faces.push_back({{"entity", f.entity}, {"area", f.area}, {"group", f.group}, {"reliable", f.reliable}});
  const json j = {{"format", "meshflow cad_reference 1"},
                  {"volume", ref.volume},
                  {"volume_reliable", ref.volume_reliable},
                  {"source", ref.source},
                  {"faces", faces}};
  std::ofstream o(path, std::ios::binary);
  o << j.dump(1) << "\n";
  o.close();
  if (!o) throw StageError("cannot write the CAD reference " + path.string() + " (disk full?)");
}

CadReference read_cad_reference(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  json j;
  try {
    j = json::parse(in);
    if (j.at("format") != "meshflow cad_reference 1") throw std::runtime_error("not a meshflow cad_reference 1 file");
    CadReference ref;
    ref.volume = j.at("volume").get<double>();
    ref.volume_reliable = j.at("volume_reliable").get<bool>();
    ref.source = j.at("source").get<std::string>();
    for (auto& f : j.at("faces"))
      ref.faces.push_back({f.at("entity").get<int>(), f.at("area").get<double>(), f.at("group").get<std::string>(),
                           f.at("reliable").get<bool>()});
    return ref;
  } catch (const std::exception& e) {
    throw StageError("cannot read the CAD reference " + path.string() + ": " + e.what() + "; re-run the stage that wrote it");
  }
}

const ArtifactTypeRegistrar cad_reference_type({
    .type = "cad_reference",
    .extension = ".json",
    .summary = "the fluid solid's volume and each face's area and tag, the figures the mesh contract compares with",
});

namespace {
model::MeshQuality publish(StageContext& ctx, Result r, const std::string& hint) {
  if (!hint.empty())
    for (auto& p : r.problems)
      if (p["clause"] == "validity") p["hint"] = hint;
  ctx.stats()["mesh"] = std::move(r.mesh);
  ctx.stats()["contract"] = std::move(r.contract);
  ctx.stats()["problems"] = std::move(r.problems);
  return std::move(r.quality);
}
}  // namespace

// The CAD reference of the stage's shape: stored beside it by the stage that wrote it, else computed.
static CadReference reference_of(StageContext& ctx, const cad::Shape& shape) {
  const auto shapes = ctx.inputs_of("shape");
  if (!shapes.empty())
    for (const Artifact* a : ctx.inputs_of("cad_reference"))
      if (a->stage == shapes[0]->stage) return read_cad_reference(a->path);
  return cad_reference(shape, ctx.threads());
}

std::optional<model::MeshQuality> input_quality(StageContext& ctx, const Mesh& m, const std::string& who) {
  std::string why;
  auto stored = io::stored_quality(ctx.inputs(), m, ctx.input("mesh").stage, &why);
  if (!why.empty()) ctx.log(who + ": the input's stored quality is not this mesh's (" + why + "); computing it");
  return stored;
}

model::MeshQuality record(StageContext& ctx, const Mesh& m, Extent extent, const cad::Shape* shape, const std::string& hint,
                          const model::MeshQuality* known, const std::vector<char>* moved) {
  CadReference ref;
  if (shape) ref = reference_of(ctx, *shape);
  return publish(ctx, check(m, extent, shape ? &ref : nullptr, ctx.threads(), known, moved), hint);
}

model::MeshQuality record_against(StageContext& ctx, const Mesh& m, Extent extent, const CadReference& ref,
                                  const std::string& hint, const model::MeshQuality* known,
                                  const std::vector<char>* moved) {
  return publish(ctx, check(m, extent, &ref, ctx.threads(), known, moved), hint);
}

}  // namespace meshflow::contract
