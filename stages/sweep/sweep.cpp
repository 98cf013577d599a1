// meshflow sweep (see sweep.hpp): surface meshes of all faces and the one-layer near field.
// CAD through stages/cad/cad.hpp, the parameter-plane mesher in uv_mesher.cpp (CGAL).
#include "stages/sweep/sweep.hpp"

#include "engine/stage.hpp"
#include "stages/balance/balance.hpp"
#include "stages/cad/cad.hpp"
#include "stages/cad/vec3.hpp"
#include "stages/model/quality.hpp"
#include "stages/periodic_match/periodic.hpp"
#include "stages/shell/shell.hpp"
#include "stages/sweep/uv_mesher.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <map>
#include <optional>
#include <set>
#include <cstdlib>
#include <sstream>

namespace meshflow::sweep {
namespace {

using namespace cad::vec;  // V3, v3, cv, add, sub, mul, dot, cross, norm
constexpr std::uint32_t kNone = std::numeric_limits<std::uint32_t>::max();

V3 lerp(V3 a, V3 b, double s) { return add(a, mul(sub(b, a), s)); }

// Compass pattern search for a node position: from b (value q), try the 26 neighbours at the
// current step (those with inside(x)), move to the best one that raises value(x), halve the
// step when none does; at most 40 rounds, while the step exceeds min_step. value(x) places the
// node at x and measures; the node is left wherever value was last called: callers put it at b.
template <class Inside, class Value>
void pattern_search(V3& b, double& q, double step, double min_step, Inside inside, Value value) {
  for (int it = 0; it < 40 && step > min_step; ++it) {
    bool moved = false;
    for (int d = 0; d < 27; ++d) {
      if (d == 13) continue;  // (0, 0, 0)
      V3 x{b[0] + (d % 3 - 1) * step, b[1] + (d / 3 % 3 - 1) * step, b[2] + (d / 9 - 1) * step};
      if (!inside(x)) continue;
      if (double qx = value(x); qx > q) q = qx, b = x, moved = true;
    }
    if (!moved) step *= 0.5;
  }
}
V3 jv3(const nlohmann::json& j) { return {j.at(0).get<double>(), j.at(1).get<double>(), j.at(2).get<double>()}; }

std::string fmt(V3 p) {
  std::ostringstream o;
  o.precision(6);
  o << "(" << p[0] << ", " << p[1] << ", " << p[2] << ")";
  return o.str();
}

int tag_physical(cad::Tag t) {
  switch (t) {
    case cad::Tag::wall: return wall;
    case cad::Tag::farfield: return farfield;
    case cad::Tag::symmetry: return symmetry;
    case cad::Tag::periodic_lo: return periodic_lo;
    case cad::Tag::periodic_hi: return periodic_hi;
    default: return 0;
  }
}

struct Junction {
  int edge = -1, A = -1, B = -1;
  std::array<int, 2> vertices{-1, -1};
  struct Station {
    double t;
    V3 P0, PA, PB, PC;
    std::array<double, 2> uvA, uvB;
  };
  std::vector<Station> st;
  // per division node k of w<edge>: the four nodes
  std::vector<std::uint32_t> p0, pa, pb, pc;
  // interpolated station at edge parameter t; perA/perB: the periods of A's and B's surfaces
  // (0: none), so that (u,v) is interpolated across a seam (a revolved hub: 2 pi -> 0) and not
  // through the middle of the period
  Station at(double t, std::array<double, 2> perA = {0, 0}, std::array<double, 2> perB = {0, 0}) const {
    if (st.size() == 1 || t <= st.front().t) return st.front();
    if (t >= st.back().t) return st.back();
    auto it = std::upper_bound(st.begin(), st.end(), t, [](double x, const Station& s) { return x < s.t; });
    const Station& b = *it;
    const Station& a = *(it - 1);
    double s = (b.t > a.t) ? (t - a.t) / (b.t - a.t) : 0;
    Station r;
    r.t = t;
    r.P0 = lerp(a.P0, b.P0, s), r.PA = lerp(a.PA, b.PA, s), r.PB = lerp(a.PB, b.PB, s), r.PC = lerp(a.PC, b.PC, s);
    auto lerp_uv = [&](std::array<double, 2> p, std::array<double, 2> q, std::array<double, 2> per) {
      for (int c = 0; c < 2; ++c)
        if (per[c] > 0) q[c] -= per[c] * std::round((q[c] - p[c]) / per[c]);
      return std::array<double, 2>{p[0] + s * (q[0] - p[0]), p[1] + s * (q[1] - p[1])};
    };
    r.uvA = lerp_uv(a.uvA, b.uvA, perA);
    r.uvB = lerp_uv(a.uvB, b.uvB, perB);
    return r;
  }
};

// A cut of a CAD edge near one of its ends: the node at parameter t is a junction corner.
struct Cut {
  double t = 0;
  std::uint32_t node = kNone;
};

// The plane a face is triangulated in: (u,v) -> (U,V) with V the arc length along v (of the
// mean |S_v|) and U the arc length along u on each line v = const (|S_u| integrated along the
// line, tabulated on 65 lines and interpolated between them), or the same with u and v swapped
// when |S_v| varies more across u than |S_u| across v. Delaunay in (U,V) is then close to
// Delaunay on the surface for lofted, ruled and revolved faces: a wing whose chordwise
// parameter is cosine-spaced (|S_u| -> 0 at the leading edge), a rounded tip revolved about
// the chord line (|S_u| = radius, from the tip's full thickness down to a 0.00125-radius tube
// at a blunt trailing edge). Each line's map is strictly increasing (a floor of 2% of the
// mean speed), so the boundary loops keep their topology and the map inverts exactly.
class Reparam {
 public:
  Reparam(const cad::Shape& S, int f) {
    auto b = S.face_uv_bounds(f);
    lo_ = {b.u0, b.v0}, hi_ = {b.u1, b.v1};
    for (int k = 0; k < 2; ++k)
      if (!(hi_[k] > lo_[k])) hi_[k] = lo_[k] + 1;
    // speeds on a grid: sp[k][i][j] = |dS/d(param k)| at u_i, v_j; dots: dS/du . dS/dv there
    std::vector<double> su((N + 1) * (N + 1)), sv((N + 1) * (N + 1)), dots((N + 1) * (N + 1));
    for (int i = 0; i <= N; ++i)
      for (int j = 0; j <= N; ++j) {
        auto d = S.face_eval(f, at(0, i), at(1, j));
        su[i * (N + 1) + j] = std::sqrt(d.du.x * d.du.x + d.du.y * d.du.y + d.du.z * d.du.z);
        sv[i * (N + 1) + j] = std::sqrt(d.dv.x * d.dv.x + d.dv.y * d.dv.y + d.dv.z * d.dv.z);
        dots[i * (N + 1) + j] = d.du.x * d.dv.x + d.du.y * d.dv.y + d.du.z * d.dv.z;
      }
    if (conformal_setup(su, sv, dots)) return;
    // variation of the line means: how much the u-speed changes from one v-line to another
    auto spread = [&](const std::vector<double>& sp, bool along_u) {
      double mn = INFINITY, mx = 0;
      for (int l = 0; l <= N; ++l) {
        double m = 0;
        for (int k = 0; k <= N; ++k) m += along_u ? sp[k * (N + 1) + l] : sp[l * (N + 1) + k];
        mn = std::min(mn, m), mx = std::max(mx, m);
      }
      return mx / std::max(mn, 1e-300);
    };
    swap_ = spread(sv, false) > spread(su, true);
    // a = the parameter mapped line by line, b = the separable one
    const std::vector<double>& sa = swap_ ? sv : su;
    const std::vector<double>& sb = swap_ ? su : sv;
    int ia = swap_ ? 1 : 0;
    auto sp = [&](const std::vector<double>& v, int a, int bb) { return swap_ ? v[bb * (N + 1) + a] : v[a * (N + 1) + bb]; };
    double mean_a = 0, mean_b = 0;
    for (double x : sa) mean_a += x / sa.size();
    for (double x : sb) mean_b += x / sb.size();
    if (!(mean_a > 0)) mean_a = 1;
    if (!(mean_b > 0)) mean_b = 1;
    // B(b): arc length of the mean b-speed
    B_.assign(N + 1, 0.0);
    std::vector<double> mb(N + 1, 0.0);
    for (int j = 0; j <= N; ++j) {
      for (int i = 0; i <= N; ++i) mb[j] += sp(sb, i, j) / (N + 1);
      mb[j] = std::max(mb[j], 0.02 * mean_b);
    }
    double hb = (hi_[1 - ia] - lo_[1 - ia]) / N, ha = (hi_[ia] - lo_[ia]) / N;
    for (int j = 1; j <= N; ++j) B_[j] = B_[j - 1] + 0.5 * (mb[j - 1] + mb[j]) * hb;
    // A_j(a): arc length along a on line b_j
    A_.assign((N + 1) * (N + 1), 0.0);
    for (int j = 0; j <= N; ++j)
      for (int i = 1; i <= N; ++i) {
        double s0 = std::max(sp(sa, i - 1, j), 0.02 * mean_a), s1 = std::max(sp(sa, i, j), 0.02 * mean_a);
        A_[j * (N + 1) + i] = A_[j * (N + 1) + i - 1] + 0.5 * (s0 + s1) * ha;
      }
    ia_ = ia;
  }
  bool conformal() const { return conformal_; }
  double shear() const { return shear_; }
  std::array<double, 2> fwd(double u, double v) const {
    if (conformal_) {
      double a = ia_ == 0 ? u : v, b = ia_ == 0 ? v : u;
      double A = c_ * (a - lo_[ia_]), Bv = interp(B_.data(), (b - lo_[1 - ia_]) / (hi_[1 - ia_] - lo_[1 - ia_]) * N);
      return ia_ == 0 ? std::array<double, 2>{A, Bv} : std::array<double, 2>{Bv, A};
    }
    double a = ia_ == 0 ? u : v, b = ia_ == 0 ? v : u;
    double tb = (b - lo_[1 - ia_]) / (hi_[1 - ia_] - lo_[1 - ia_]) * N;
    double ta = (a - lo_[ia_]) / (hi_[ia_] - lo_[ia_]) * N;
    double Bv = interp(B_.data(), tb);
    int j = std::clamp(static_cast<int>(std::floor(tb)), 0, N - 1);
    double w = std::clamp(tb - j, 0.0, 1.0);
    double Av = (1 - w) * interp(&A_[j * (N + 1)], ta) + w * interp(&A_[(j + 1) * (N + 1)], ta);
    return ia_ == 0 ? std::array<double, 2>{Av, Bv} : std::array<double, 2>{Bv, Av};
  }
  std::array<double, 2> inv(double U, double V) const {
    double Av = ia_ == 0 ? U : V, Bv = ia_ == 0 ? V : U;
    if (conformal_) {
      double a = lo_[ia_] + Av / c_, b = lo_[1 - ia_] + inverse(B_.data(), Bv) / N * (hi_[1 - ia_] - lo_[1 - ia_]);
      return ia_ == 0 ? std::array<double, 2>{a, b} : std::array<double, 2>{b, a};
    }
    double tb = inverse(B_.data(), Bv);
    int j = std::clamp(static_cast<int>(std::floor(tb)), 0, N - 1);
    double w = std::clamp(tb - j, 0.0, 1.0);
    std::vector<double> row(N + 1);
    for (int i = 0; i <= N; ++i) row[i] = (1 - w) * A_[j * (N + 1) + i] + w * A_[(j + 1) * (N + 1) + i];
    double ta = inverse(row.data(), Av);
    double a = lo_[ia_] + ta / N * (hi_[ia_] - lo_[ia_]), b = lo_[1 - ia_] + tb / N * (hi_[1 - ia_] - lo_[1 - ia_]);
    return ia_ == 0 ? std::array<double, 2>{a, b} : std::array<double, 2>{b, a};
  }

 private:
  static constexpr int N = 64;
  std::array<double, 2> lo_{}, hi_{};
  bool swap_ = false;
  int ia_ = 0;
  bool conformal_ = false;  // the conformal map of a surface of revolution (conformal_setup)
  double c_ = 1;            // its scale: plane length per unit of the angle parameter
  double shear_ = 0;        // the arc-length map's shear on a surface of revolution (0: none)

  // A parameterisation whose speeds depend on one parameter only and whose derivatives are
  // orthogonal (|S_a| = r(b), |S_b| = s(b), S_a . S_b = 0: every surface of revolution with a
  // the angle, OCCT's spheres, tori, cones and cylinders and revolved curves) has a conformal
  // map: U = c a, V = c integral of s(b) / r(b) db (Mercator's, on a sphere). The line-by-line
  // arc-length map below shears such a face by (a - a0) r'(b) / s(b): on a whole sphere up to
  // 5 times at 60 degrees latitude, where Delaunay in the plane is far from Delaunay on the
  // surface; refining by 3D edge length then over-refines (8 times the triangles the size asks
  // for on the corpus sphere) and triangles fold near the poles (a far-field sphere at 0.2 R).
  // r is floored at 2% of its mean (as the arc-length map's speeds are), so a pole (r = 0)
  // maps to a segment of length 2 pi c at a finite V: the cap inside the floor, 1% of the
  // radius across, is the only non-conformal part. Where r is constant (planes, cylinders) the
  // arc-length map is an isometry already and is kept. Sets B_ (V over b), ia_ and c_.
  bool conformal_setup(const std::vector<double>& su, const std::vector<double>& sv, const std::vector<double>& dots) {
    const double smax = std::max(*std::max_element(su.begin(), su.end()), *std::max_element(sv.begin(), sv.end()));
    if (!(smax > 0)) return false;
    const double tol = 1e-6 * smax;
    for (int ia = 0; ia < 2; ++ia) {
      // speeds at (a index k, b index l)
      auto at_ab = [&](const std::vector<double>& g, int k, int l) { return ia == 0 ? g[k * (N + 1) + l] : g[l * (N + 1) + k]; };
      bool separable = true;
      for (int l = 0; l <= N && separable; ++l)
        for (int k = 0; k <= N && separable; ++k)
          separable = std::abs(at_ab(su, k, l) - at_ab(su, 0, l)) <= tol && std::abs(at_ab(sv, k, l) - at_ab(sv, 0, l)) <= tol &&
                      std::abs(at_ab(dots, k, l)) <= tol * smax;
      if (!separable) continue;
      const std::vector<double>& sa = ia == 0 ? su : sv;  // r(b)
      const std::vector<double>& sb = ia == 0 ? sv : su;  // s(b)
      double mean_r = 0, mean_s = 0;
      for (int l = 0; l <= N; ++l) mean_r += at_ab(sa, 0, l) / (N + 1), mean_s += at_ab(sb, 0, l) / (N + 1);
      if (!(mean_r > 0) || !(mean_s > 0)) continue;
      // r constant (planes, cylinders): the arc-length map is already an isometry, kept as it is
      double rmin = INFINITY, rmax = 0;
      for (int l = 0; l <= N; ++l) rmin = std::min(rmin, at_ab(sa, 0, l)), rmax = std::max(rmax, at_ab(sa, 0, l));
      if (rmax - rmin <= tol) return false;
      // the arc-length map's shear, (a range) |r'(b)| / s(b): the conformal map only where it
      // distorts angles by more than 45 degrees (a whole sphere, torus or cone); below, the
      // arc-length map keeps lengths (the size field stays isotropic in the plane), which the
      // conformal map trades for angles (its plane scale is c / r)
      const double hb = (hi_[1 - ia] - lo_[1 - ia]) / N, range_a = hi_[ia] - lo_[ia];
      shear_ = 0;
      for (int l = 0; l < N; ++l) {
        const double dr = std::abs(at_ab(sa, 0, l + 1) - at_ab(sa, 0, l)) / hb;
        const double sm = std::max(0.5 * (at_ab(sb, 0, l) + at_ab(sb, 0, l + 1)), 0.02 * mean_s);
        shear_ = std::max(shear_, range_a * dr / sm);
      }
      if (shear_ <= 1) return false;
      const double floor_r = 0.02 * mean_r;
      c_ = mean_r;
      B_.assign(N + 1, 0.0);
      auto g = [&](int l) { return std::max(at_ab(sb, 0, l), 0.02 * mean_s) / std::max(at_ab(sa, 0, l), floor_r); };
      for (int l = 1; l <= N; ++l) B_[l] = B_[l - 1] + c_ * 0.5 * (g(l - 1) + g(l)) * hb;
      if (!(B_[N] > 0)) continue;
      ia_ = ia;
      conformal_ = true;
      return true;
    }
    return false;
  }
  std::vector<double> B_, A_;
  double at(int k, int i) const { return lo_[k] + (hi_[k] - lo_[k]) * i / N; }
  // piecewise-linear table y[0..N] at fractional index t (linear extrapolation outside)
  static double interp(const double* y, double t) {
    int i = std::clamp(static_cast<int>(std::floor(t)), 0, N - 1);
    return y[i] + (t - i) * (y[i + 1] - y[i]);
  }
  static double inverse(const double* y, double Y) {
    int i = static_cast<int>(std::upper_bound(y, y + N + 1, Y) - y) - 1;
    i = std::clamp(i, 0, N - 1);
    return i + (Y - y[i]) / (y[i + 1] - y[i]);
  }
};

class Builder {
 public:
  Builder(const cad::Shape& s, const shell::ShellData& sh, const balance::Divisions& dv, const Options& o, Report& r,
          const std::function<void(const std::string&)>& log, const periodic::Match* pm)
      : S(s), SH(sh), DV(dv), O(o), R(r), log_(log), PM(pm) {}

  model::Mesh run();

 private:
  const cad::Shape& S;
  const shell::ShellData& SH;
  const balance::Divisions& DV;
  Options O;
  Report& R;
  std::function<void(const std::string&)> log_;
  const periodic::Match* PM = nullptr;           // periodic_hi faces are copies of their periodic_lo partners
  model::Mesh m;
  int nf = 0, ne = 0, nv = 0;
  std::vector<char> wall;
  std::vector<std::uint32_t> vnode;
  std::vector<std::vector<double>> et;           // node parameters per edge (increasing)
  std::vector<std::vector<std::uint32_t>> en;    // nodes per edge
  std::vector<std::array<Cut, 2>> cuts;          // per edge: at its first / last vertex
  std::vector<Junction> J;
  std::vector<int> junction_of;                  // edge -> index in J or -1
  std::vector<int> slide_other;                  // edge -> the non-wall face it slides on, or -1
  std::vector<int> slide_wall;                   // edge -> its wall face
  std::map<std::uint32_t, std::uint32_t> image;  // wall node -> shell node
  std::map<std::uint32_t, std::array<double, 2>> uv_on;  // node classified on a face -> (u, v) (lookup helper)
  std::vector<std::vector<std::array<std::uint32_t, 3>>> face_tris;  // per face
  std::vector<std::vector<std::array<std::uint32_t, 4>>> face_quads;  // per face

  void log(const std::string& s) {
    if (log_) log_(s);
  }
  std::uint32_t mk(V3 x, int dim, int tag, double u = NAN, double v = NAN) {
    std::uint32_t i = m.add_node(x[0], x[1], x[2]);
    if (m.node_entity_dim.size() <= i) {  // add_node extends the arrays only once they exist
      m.node_entity_dim.resize(i + 1, -1), m.node_entity_tag.resize(i + 1, -1);
      m.node_u.resize(i + 1, NAN), m.node_v.resize(i + 1, NAN);
    }
    m.node_entity_dim[i] = dim;
    m.node_entity_tag[i] = tag;
    m.node_u[i] = u;
    m.node_v[i] = v;
    return i;
  }
  V3 X(std::uint32_t i) const { return {m.x[i], m.y[i], m.z[i]}; }
  double edge_h(int e, double t, double hmax) const;
  std::vector<double> own_division(int e, double hmax) const;
  bool seam_of_wall(int e) const {
    for (int f : S.edge_faces(e))
      if (wall[f] && S.edge_is_seam(e, f)) return true;
    return false;
  }
  void junction_ends();
  void build_edges();
  void build_junction_curves();
  void build_slides();
  void slide_ends();
  std::map<std::pair<int, int>, std::uint32_t> slide_end_image;  // (vertex, other face) -> image node on an edge
  // the face mesher (mesh_face and its steps)
  struct LoopPoint {
    std::uint32_t node;
    std::array<double, 2> uv;
    bool pole = false;  // the start of a degenerate edge: the segment to the next point is the pole
    int edge = -1;      // the CAD edge whose segment starts here (-1: a pole or a substituted curve)
    bool reversed = false;
    bool first = false;  // the edge's first point in loop direction (a CAD vertex)
  };
  using Loop = std::vector<LoopPoint>;
  struct FaceBoundary {  // the boundary points of a face's parameter-plane mesh
    std::vector<std::uint32_t> node;
    std::vector<V3> x;
    std::vector<double> h;  // spacing: the mean length of the two segments at the point
  };
  void mesh_face(int f, int copy_from = -1);
  std::array<double, 2> uv_on_face(int f, std::uint32_t n, std::array<double, 2> hint) const;
  Loop wire_points(int f, const std::vector<cad::EdgeUse>& wire, const std::vector<char>& flip);
  static void drop_detours(Loop& raw, std::array<double, 2> per, double uv_tol);
  static void unwrap_loop(Loop& raw, std::array<double, 2> per);
  Loop build_wire(int f, const std::vector<cad::EdgeUse>& wire, const std::vector<char>& flip);
  static bool loop_closes(const Loop& raw, std::array<double, 2> per);
  Loop closed_wire(int f, const std::vector<cad::EdgeUse>& wire);
  void align_loops(int f, std::vector<Loop>& loops) const;
  std::vector<Loop> face_loops(int f);
  std::vector<char> smooth_points(const std::vector<Loop>& loops) const;
  detail::UVMeshInput uv_input(int f, const std::vector<Loop>& loops, const Reparam& RP, FaceBoundary& fb);
  detail::UVMeshOutput mesh_parameter_plane(int f, const detail::UVMeshInput& in);
  void face_triangles(int f, const detail::UVMeshOutput& out, const Reparam& RP, const std::vector<std::uint32_t>& bnode);
  void drop_pole_folds(int f);
  // periodic: hi face `hi` as the image of the meshed lo face `lo` (hb: hi's boundary loop nodes)
  std::vector<std::vector<std::uint32_t>> face_bnodes;  // per face: its boundary loop nodes (distinct, loop order)
  std::map<std::uint32_t, std::uint32_t> per_master;   // hi node -> lo node
  void snap(std::uint32_t h, std::uint32_t l);
  void periodic_edges();
  void copy_face(int lo, int hi, const std::vector<std::uint32_t>& hb);
  void periodic_links();
  std::uint32_t shell_image(std::uint32_t n, int face);
  std::pair<double, shell::Vec3> face_field(int face, double u, double v);
  void volume();
  std::string untangle_failure(const std::vector<std::vector<std::uint32_t>>& P, const std::vector<int>& pface,
                               const std::vector<char>& bad_before, const std::vector<std::size_t>& bad_after);
  void untangle(std::vector<std::vector<std::uint32_t>>& prisms);
  // linear validity of a prism or hex (model::element_quality), as given or in either
  // orientation (flip_of: the node order of the other orientation, which volume() writes)
  static const std::vector<int>& flip_of(model::Shape shape) {
    static const std::vector<int> prism{0, 2, 1, 3, 5, 4}, hex{0, 3, 2, 1, 4, 7, 6, 5};
    return shape == model::Shape::Hex ? hex : prism;
  }
  bool linear_valid(model::Shape shape, const std::vector<std::uint32_t>& nodes) const {
    std::vector<double> X3;
    X3.reserve(3 * nodes.size());
    for (auto n : nodes) X3.insert(X3.end(), {m.x[n], m.y[n], m.z[n]});
    return model::element_quality(shape, 1, X3.data()).valid;
  }
  bool valid_either(model::Shape shape, const std::vector<std::uint32_t>& nodes) const {
    if (linear_valid(shape, nodes)) return true;
    const auto& f = flip_of(shape);
    std::vector<std::uint32_t> g(nodes.size());
    for (std::size_t i = 0; i < nodes.size(); ++i) g[i] = nodes[f[i]];
    return linear_valid(shape, g);
  }
  // the hex of junction j between its division nodes k and k + 1
  static std::vector<std::uint32_t> junction_hex(const Junction& j, std::size_t k) {
    return {j.p0[k], j.p0[k + 1], j.pa[k + 1], j.pa[k], j.pb[k], j.pb[k + 1], j.pc[k + 1], j.pc[k]};
  }
  void clear_crossings(const std::vector<std::vector<std::uint32_t>>& prisms, const std::set<std::uint32_t>& frozen);
  // junction ends on a third face (find_caps, place_cap: see their definitions)
  struct Cap {
    int edge = -1;
    std::uint32_t V = kNone, Vi = kNone;             // the end vertex's node and its shell node V'
    std::vector<std::size_t> fan;                    // the prisms at V
    std::vector<std::vector<std::uint32_t>> tets, pyramids;
    std::string faces;                               // the fan's faces, for messages
    double moved = 0;                                // how far V' was moved
  };
  std::vector<Cap> caps;
  void find_caps(const std::vector<std::vector<std::uint32_t>>& P, const std::vector<int>& pface);
  double cap_quality(const Cap& c) const;
  double place_cap(Cap& c);
  void log_cap(const Cap& c, double q, const std::string& when);
};

double Builder::edge_h(int e, double t, double hmax) const {
  auto d = S.edge_eval(e, t);
  V3 d1 = v3(d.d1), d2 = v3(d.d2);
  double s = norm(d1);
  double k = s > 0 ? norm(cross(d1, d2)) / (s * s * s) : 0;
  // A seam of a wall face (the Rotor 67 blade's seam runs up its leading edge): the curve is
  // nearly straight but the surface turns sharply across it, and the triangles beside the seam
  // would be slivers along it cutting through the nose. Its size is the face's: the surface's
  // largest principal curvature at the seam point counts too.
  for (int f : S.edge_faces(e))
    if (wall[f] && S.edge_is_seam(e, f)) {
      auto uv = S.edge_uv(e, f, t, false);
      auto c = S.face_curvature(f, uv.u, uv.v);
      if (c.defined) k = std::max({k, std::abs(c.k1), std::abs(c.k2)});
    }
  double theta = O.turn_angle_deg * M_PI / 180;
  double h = k > 0 ? theta / k : hmax;
  return std::clamp(h, O.min_size, hmax);
}

// Divisions of an edge that balance did not divide (far field, symmetry, ...): the turn-angle
// rule capped by hmax, nodes at equal arc length (the same rule balance uses for targets).
std::vector<double> Builder::own_division(int e, double hmax) const {
  auto r = S.edge_range(e);
  const int M = 200;
  std::vector<double> t(M + 1), s(M + 1, 0.0);
  double target = 0;
  for (int i = 0; i <= M; ++i) t[i] = r.lo + (r.hi - r.lo) * i / M;
  for (int i = 1; i <= M; ++i) {
    double ds = S.edge_length(e, t[i - 1], t[i]);
    s[i] = s[i - 1] + ds;
    target += ds / edge_h(e, 0.5 * (t[i - 1] + t[i]), hmax);
  }
  int n = std::max(1, static_cast<int>(std::lround(target)));
  if (S.edge_vertices(e)[0] == S.edge_vertices(e)[1]) n = std::max(n, 3);  // a closed edge needs a polygon
  std::vector<double> out(n + 1);
  out[0] = r.lo, out[n] = r.hi;
  for (int k = 1; k < n; ++k) {
    double sk = s[M] * k / n;
    int i = static_cast<int>(std::upper_bound(s.begin(), s.end(), sk) - s.begin());
    i = std::clamp(i, 1, M);
    double a = (s[i] > s[i - 1]) ? (sk - s[i - 1]) / (s[i] - s[i - 1]) : 0;
    out[k] = t[i - 1] + a * (t[i] - t[i - 1]);
  }
  return out;
}

// ── junction ends: one shared cross-section per vertex ──────────────────────────────────
void Builder::junction_ends() {
  std::map<int, std::vector<std::pair<int, int>>> at;  // vertex -> (junction, end)
  for (int b = 0; b < static_cast<int>(J.size()); ++b)
    for (int end = 0; end < 2; ++end) at[J[b].vertices[end]].push_back({b, end});
  std::set<int> jedges;
  for (auto& j : J) jedges.insert(j.edge);
  for (auto& [V, list] : at) {
    // the edge of face `f` at V other than the junction edges: where the cross-section lies
    auto side_edge = [&](int f) {
      int found = -1;
      for (int e : S.face_edges(f)) {
        if (S.edge_degenerate(e) || jedges.count(e)) continue;
        auto vs = S.edge_vertices(e);
        if (vs[0] == V || vs[1] == V) {
          if (found >= 0 && found != e) return -2;  // ambiguous
          found = e;
        }
      }
      return found;
    };
    auto station = [&](int b, int end) -> const Junction::Station& { return end == 0 ? J[b].st.front() : J[b].st.back(); };
    // A side edge leaving V at an obtuse angle to the strip (DLR-F6's pylon nose, where the
    // pylon-nacelle curve goes on from the junction edge onto the pylon's leading-edge face) has
    // its point nearest the strip corner at V itself: cut there, the strip's end would have no
    // width (its corner 2e-4 mm from V) and the third face's triangle (V, PA, PB) would collapse.
    // Such a corner stays on the face (a face node, as without a side edge) and V a node of the
    // face's mesh beside the strip's end (sweep.hpp, "Junction ends on a third face"). Only where
    // the side edge is one of a third wall face (no A or B of a block ending at V).
    std::set<int> roles;  // the A and B faces of the blocks ending at V
    for (auto [b, end] : list) roles.insert(J[b].A), roles.insert(J[b].B);
    auto obtuse = [&](int e, V3 P) {
      if (e < 0) return false;
      bool third = false;  // only beside a third wall face
      for (int f : S.edge_faces(e)) third = third || (wall[f] && !roles.count(f));
      if (!third) return false;
      V3 xv = v3(S.vertex_point(V));
      return norm(sub(v3(S.project_to_edge(e, cv(P)).point), xv)) < 0.5 * norm(sub(P, xv));
    };
    // PA: per distinct A face; unified when the A faces share the edge leaving V
    std::map<int, std::vector<std::pair<int, int>>> byA;
    for (auto [b, end] : list) byA[J[b].A].push_back({b, end});
    std::map<int, std::uint32_t> pa_node, pc_node;  // per A face
    std::map<int, std::uint32_t> edge_corner;        // side edge -> PA node on it
    std::map<int, std::uint32_t> edge_corner_pc;
    std::map<int, V3> swapped_pc;                    // A faces also B at V: PC made below, when needed
    for (auto& [A, bl] : byA) {
      int e = side_edge(A);
      V3 PA{0, 0, 0}, PC{0, 0, 0};
      for (auto [b, end] : bl) PA = add(PA, station(b, end).PA), PC = add(PC, station(b, end).PC);
      PA = mul(PA, 1.0 / bl.size()), PC = mul(PC, 1.0 / bl.size());
      if (e >= 0 && !edge_corner.count(e) && obtuse(e, PA)) e = -1;
      if (e >= 0) {
        if (edge_corner.count(e)) {
          pa_node[A] = edge_corner[e], pc_node[A] = edge_corner_pc[e];
          continue;
        }
        // project the mean of all blocks' PA that lie near this edge (the A faces sharing it)
        std::vector<V3> pts;
        for (auto& [A2, bl2] : byA)
          if (side_edge(A2) == e)
            for (auto [b, end] : bl2) pts.push_back(station(b, end).PA);
        V3 mean{0, 0, 0};
        for (auto& p : pts) mean = add(mean, p);
        mean = mul(mean, 1.0 / pts.size());
        auto pr = S.project_to_edge(e, cv(mean));
        auto vs = S.edge_vertices(e);
        int cend = (vs[0] == V) ? 0 : 1;
        if (vs[0] == V && vs[1] == V) {  // a closed edge: the nearer end
          auto rr = S.edge_range(e);
          cend = (pr.t - rr.lo < rr.hi - pr.t) ? 0 : 1;
        }
        std::uint32_t n = mk(v3(pr.point), 1, e + 1, pr.t);
        cuts[e][cend] = {pr.t, n};
        ++R.edges_cut;
        auto [th, d] = SH.edge_field(e, pr.t, A);
        std::uint32_t c = mk(add(v3(pr.point), mul(V3{d[0], d[1], d[2]}, th)), 3, 1);
        edge_corner[e] = n, edge_corner_pc[e] = c;
        pa_node[A] = n, pc_node[A] = c;
      } else {
        auto& st0 = station(bl[0].first, bl[0].second);
        // A face that is A of some blocks at V and B of others (DLR-F6's fuselage at a vertex of
        // the wing root loop where the wing face changes: the fuselage is B of the junction on one
        // side of V and A of the next): one node on it for both roles, at the mean of all their
        // strip ends on it (the PB loop below reuses it), and its PC is chosen with the other
        // blocks of the same cross-section (below), so it is made only if none has one.
        std::vector<V3> both;
        for (auto [b, end] : list)
          if (J[b].B == A && J[b].A != A) both.push_back(station(b, end).PB);
        if (!both.empty()) {
          for (auto [b, end] : bl) both.push_back(station(b, end).PA);
          PA = V3{0, 0, 0};
          for (auto& p : both) PA = add(PA, p);
          PA = mul(PA, 1.0 / both.size());
          swapped_pc[A] = PC;
        }
        auto pr = S.project_to_face(A, cv(PA), cad::Vec2{st0.uvA[0], st0.uvA[1]});
        std::uint32_t n = mk(v3(pr.point), 2, A + 1, pr.u, pr.v);
        uv_on[n] = {pr.u, pr.v};
        pa_node[A] = n;
        if (both.empty()) pc_node[A] = mk(PC, 3, 1);
      }
    }
    // PB: per distinct B face
    std::map<int, std::vector<std::pair<int, int>>> byB;
    for (auto [b, end] : list) byB[J[b].B].push_back({b, end});
    std::map<int, std::uint32_t> pb_node;
    for (auto& [B, bl] : byB) {
      V3 PB{0, 0, 0};
      for (auto [b, end] : bl) PB = add(PB, station(b, end).PB);
      PB = mul(PB, 1.0 / bl.size());
      int e = side_edge(B);
      if (e >= 0 && !edge_corner.count(e) && obtuse(e, PB)) e = -1;
      if (e >= 0 && !edge_corner.count(e)) {
        // B faces sharing the side edge (the trailing-edge face and the wing surface, both
        // partners of a body's junctions) share one corner on it: the mean of all their PB
        std::vector<V3> pts;
        for (auto& [B2, bl2] : byB)
          if (side_edge(B2) == e)
            for (auto [b, end] : bl2) pts.push_back(station(b, end).PB);
        PB = V3{0, 0, 0};
        for (auto& p : pts) PB = add(PB, p);
        PB = mul(PB, 1.0 / pts.size());
        auto pr = S.project_to_edge(e, cv(PB));
        auto vs = S.edge_vertices(e);
        int cend = (vs[0] == V) ? 0 : 1;
        std::uint32_t n = mk(v3(pr.point), 1, e + 1, pr.t);
        cuts[e][cend] = {pr.t, n};
        ++R.edges_cut;
        pb_node[B] = n;
        edge_corner[e] = n;
      } else if (e >= 0) {
        pb_node[B] = edge_corner[e];
      } else if (swapped_pc.count(B)) {
        pb_node[B] = pa_node[B];  // the face is also an A face at V: its one node (above)
      } else {
        auto& st0 = station(bl[0].first, bl[0].second);
        auto pr = S.project_to_face(B, cv(PB), cad::Vec2{st0.uvB[0], st0.uvB[1]});
        std::uint32_t n = mk(v3(pr.point), 2, B + 1, pr.u, pr.v);
        uv_on[n] = {pr.u, pr.v};
        pb_node[B] = n;
      }
    }
    // Blocks whose end cross-sections have the same two strip corners (the swapped roles above:
    // (P0, PA, PB) of one is (P0, PB, PA) of the other) share one end face, so one PC: the first
    // such block's whose PC exists (a corner on a side edge, imaged by that edge's field), else
    // one made from the swapped face's mean station PC.
    for (auto [b, end] : list) {
      auto& j = J[b];
      if (pc_node.count(j.A)) continue;
      auto key = std::minmax(pa_node[j.A], pb_node[j.B]);
      std::uint32_t pc = kNone;
      for (auto [b2, end2] : list)
        if (std::minmax(pa_node[J[b2].A], pb_node[J[b2].B]) == key && pc_node.count(J[b2].A)) {
          pc = pc_node[J[b2].A];
          break;
        }
      pc_node[j.A] = pc != kNone ? pc : mk(swapped_pc.at(j.A), 3, 1);
    }
    for (auto [b, end] : list) {
      auto& j = J[b];
      std::size_t k = end == 0 ? 0 : j.pa.size() - 1;
      if (std::getenv("MESHFLOW_SWEEP_DEBUG"))
        log("junction of edge " + std::to_string(j.edge) + " at vertex " + std::to_string(V) + ": PA node " +
            std::to_string(pa_node[j.A]) + " PB node " + std::to_string(pb_node[j.B]) + " (B side edge " + std::to_string(side_edge(j.B)) + ")");
      j.pa[k] = pa_node[j.A], j.pc[k] = pc_node[j.A], j.pb[k] = pb_node[j.B];
    }
  }
}

void Builder::build_edges() {
  for (int e = 0; e < ne; ++e) {
    if (S.edge_degenerate(e)) continue;
    auto vs = S.edge_vertices(e);
    std::vector<double> t;
    if (auto* d = DV.find("w" + std::to_string(e)))
      t = d->nodes;
    else if (auto* d2 = DV.find("e" + std::to_string(e)))
      t = d2->nodes;
    else
      t = own_division(e, seam_of_wall(e) ? O.max_size : O.farfield_size);
    // cuts: [t0, c0] + the divisions mapped affinely onto [c0, c1] + [c1, tn]
    const Cut& c0 = cuts[e][0];
    const Cut& c1 = cuts[e][1];
    std::vector<double> nt;
    std::vector<std::uint32_t> nn;
    double a = c0.node != kNone ? c0.t : t.front(), b = c1.node != kNone ? c1.t : t.back();
    if (c0.node != kNone) nt.push_back(t.front()), nn.push_back(kNone);
    for (std::size_t k = 0; k < t.size(); ++k) {
      double s = (t[k] - t.front()) / (t.back() - t.front());
      nt.push_back(a + s * (b - a));
      nn.push_back(kNone);
    }
    if (c0.node != kNone) nn[1] = c0.node;
    if (c1.node != kNone) nt.push_back(t.back()), nn.push_back(kNone), nn[nn.size() - 2] = c1.node;
    // end vertices
    for (int end = 0; end < 2; ++end) {
      int V = vs[end];
      if (vnode[V] == kNone) vnode[V] = mk(v3(S.vertex_point(V)), 0, V + 1);
    }
    nn.front() = vnode[vs[0]];
    nn.back() = vnode[vs[1]];
    for (std::size_t k = 1; k + 1 < nn.size(); ++k)
      if (nn[k] == kNone) nn[k] = mk(v3(S.edge_point(e, nt[k])), 1, e + 1, nt[k]);
    for (std::size_t k = 1; k < nt.size(); ++k)
      if (!(nt[k] > nt[k - 1]))
        throw StageError("sweep: the nodes of CAD edge " + std::to_string(e) +
                         " are out of order after the junction corner was placed on it (the junction's strip is wider than "
                         "the edge's first division allows); reduce shell.thickness or refine the edge");
    et[e] = std::move(nt);
    en[e] = std::move(nn);
  }
}

// Strip boundaries next to a seam. Where a junction ends at a vertex on a seam of A or B (a
// closed junction edge around a wrapped face: Rotor 67's blade root and tip, the blade's seam
// along its leading edge), junction_ends put that end's PA / PB on the seam; the stations next to
// it, offset across the face by the shell's in-face direction, may land on the other side of the
// seam when the seam leans against that direction (at a leading edge the seam moves across the
// whole nose within one strip width), and the strip boundary then crosses the seam and folds. So
// within two strip widths (L) of such an end the point is blended in (u,v) towards the end's
// offset carried along the edge: uv = s (uv_edge(t) + (uv_end - uv_vertex)) + (1 - s) uv_station
// (the station's uv taken in the period nearest), s = 1 - smoothstep(|P0 - V| / L). Along a
// closed junction edge around a wrapped face (Rotor 67's blade root and tip: the blade's
// leading and trailing edges are far smaller than a strip width, and the station points,
// offset in 3D and projected, land on either side of the nose and fold the strip boundary
// there), L is infinite: the strip boundary is the edge's p-curve offset by the end's constant
// (u,v) offset, monotone along the edge like the edge itself.
void Builder::build_junction_curves() {
  struct SeamEnd {
    V3 p0{};
    std::array<double, 2> delta{};
    double L = 0;
  };
  auto seam_end = [&](const Junction& j, int face, std::uint32_t endnode, int end, std::uint32_t p0) -> std::optional<SeamEnd> {
    if (m.node_entity_dim[endnode] != 1) return std::nullopt;
    int e = m.node_entity_tag[endnode] - 1;
    if (!S.edge_is_seam(e, face)) return std::nullopt;
    auto rr = S.edge_range(e);
    auto vs = S.edge_vertices(e);
    int V = j.vertices[end];
    if (vs[0] != V && vs[1] != V) return std::nullopt;
    double tv = vs[0] == V ? rr.lo : rr.hi;
    auto a = S.edge_uv(e, face, tv, false), b = S.edge_uv(e, face, m.node_u[endnode], false);
    SeamEnd r;
    r.p0 = X(p0);
    r.delta = {b.u - a.u, b.v - a.v};
    // a closed junction edge around a wrapped face (both ends at V): the whole strip boundary
    // is the edge's p-curve offset by the end's (u,v) offset (for a lofted blade: the same
    // section parameter one strip width up the span); see above
    r.L = j.vertices[0] == j.vertices[1] ? INFINITY : 2 * norm(sub(X(endnode), r.p0));
    return r;
  };
  auto smoothstep = [](double x) { x = std::clamp(x, 0.0, 1.0); return x * x * (3 - 2 * x); };
  // the (u,v) of a station point near a seam end (see above); `uv` is the projection's
  auto blend = [&](const Junction& j, int face, const std::vector<std::optional<SeamEnd>>& ends, V3 P0, double t,
                   std::array<double, 2> uv) -> std::optional<std::array<double, 2>> {
    const SeamEnd* best = nullptr;
    double dbest = INFINITY;
    for (auto& se : ends)
      if (se) {
        double d = norm(sub(P0, se->p0));
        if (d < se->L && d < dbest) dbest = d, best = &*se;
      }
    if (!best) return std::nullopt;
    double s = 1 - smoothstep(dbest / best->L);
    auto eu = S.edge_uv(j.edge, face, t, false);
    std::array<double, 2> target{eu.u + best->delta[0], eu.v + best->delta[1]};
    auto per = S.face_periods(face);
    for (int c = 0; c < 2; ++c)
      if (per[c] > 0) uv[c] += per[c] * std::round((target[c] - uv[c]) / per[c]);
    if (std::isinf(best->L)) {
      // all along a closed edge: the station's own offset across the p-curve (its width varies
      // with the thickness), without its component along the p-curve (which folds at a nose)
      double dt = 1e-4 * (S.edge_range(j.edge).hi - S.edge_range(j.edge).lo);
      auto e1 = S.edge_uv(j.edge, face, t + dt, false), e0 = S.edge_uv(j.edge, face, t - dt, false);
      double tu = e1.u - e0.u, tv = e1.v - e0.v, tl = std::hypot(tu, tv);
      if (tl > 0) {
        double nu = -tv / tl, nv = tu / tl;
        double off = (uv[0] - eu.u) * nu + (uv[1] - eu.v) * nv;
        return std::array<double, 2>{eu.u + off * nu, eu.v + off * nv};
      }
    }
    return std::array<double, 2>{s * target[0] + (1 - s) * uv[0], s * target[1] + (1 - s) * uv[1]};
  };
  for (auto& j : J) {
    const auto& w = en[j.edge];
    const auto& t = et[j.edge];
    std::size_t n = w.size();
    std::vector<std::optional<SeamEnd>> endsA, endsB;
    for (int end = 0; end < 2; ++end) {
      std::size_t k = end == 0 ? 0 : n - 1;
      endsA.push_back(seam_end(j, j.A, j.pa[k], end, w[k]));
      endsB.push_back(seam_end(j, j.B, j.pb[k], end, w[k]));
    }
    for (std::size_t k = 0; k < n; ++k) {
      j.p0[k] = w[k];
      if (k == 0 || k + 1 == n) continue;  // shared end cross-sections, set by junction_ends
      auto s = j.at(t[k], S.face_periods(j.A), S.face_periods(j.B));
      auto pa = S.project_to_face(j.A, cv(s.PA), cad::Vec2{s.uvA[0], s.uvA[1]});
      auto pb = S.project_to_face(j.B, cv(s.PB), cad::Vec2{s.uvB[0], s.uvB[1]});
      if (auto uv = blend(j, j.A, endsA, X(w[k]), t[k], {pa.u, pa.v})) {
        pa.u = (*uv)[0], pa.v = (*uv)[1];
        pa.point = S.face_point(j.A, pa.u, pa.v);
      }
      if (auto uv = blend(j, j.B, endsB, X(w[k]), t[k], {pb.u, pb.v})) {
        pb.u = (*uv)[0], pb.v = (*uv)[1];
        pb.point = S.face_point(j.B, pb.u, pb.v);
      }
      j.pa[k] = mk(v3(pa.point), 2, j.A + 1, pa.u, pa.v);
      uv_on[j.pa[k]] = {pa.u, pa.v};
      j.pb[k] = mk(v3(pb.point), 2, j.B + 1, pb.u, pb.v);
      uv_on[j.pb[k]] = {pb.u, pb.v};
      if (std::getenv("MESHFLOW_SWEEP_DEBUG") && (k < 4 || k + 4 > n))
        log("junction " + std::to_string(j.edge) + " station " + std::to_string(k) + "/" + std::to_string(n) + " t " + std::to_string(t[k]) +
            ": P0 " + fmt(X(w[k])) + " PA " + fmt(v3(pa.point)) + " (uv " + std::to_string(pa.u) + "," + std::to_string(pa.v) + ") PB " +
            fmt(v3(pb.point)) + " (uv " + std::to_string(pb.u) + "," + std::to_string(pb.v) + ")");
      // the outer corner: PA's shell image along A's field, as the shell defines PC
      auto [th, d] = face_field(j.A, pa.u, pa.v);
      j.pc[k] = mk(add(v3(pa.point), mul(V3{d[0], d[1], d[2]}, th)), 3, 1);
    }
    for (std::size_t k = 0; k < n; ++k) {
      image[j.pa[k]] = j.pc[k];
      if (wall[j.B]) image[j.pb[k]] = j.pc[k];
    }
  }
}

// Wall|other edges that are not junctions: the shell images of their nodes lie on the other
// face (projected onto it exactly).
// The image of a sliding edge's end vertex lies on the other face's edge leaving that vertex
// (e.g. the hub's shell meets a periodic side along the side's inlet edge): that edge is cut
// there, as at junction corners, so the side face's boundary runs through the image.
void Builder::slide_ends() {
  for (int e = 0; e < ne; ++e) {
    if (slide_other[e] < 0) continue;
    int B = slide_other[e];
    auto vs = S.edge_vertices(e);
    for (int end = 0; end < 2; ++end) {
      int V = vs[end];
      if (slide_end_image.count({V, B})) continue;
      int found = -1;
      for (int e2 : S.face_edges(B)) {
        if (e2 == e || S.edge_degenerate(e2) || slide_other[e2] >= 0 || junction_of[e2] >= 0) continue;
        auto v2 = S.edge_vertices(e2);
        if (v2[0] == V || v2[1] == V) found = (found == -1) ? e2 : -2;
      }
      if (found < 0) continue;
      std::pair<double, shell::Vec3> td{0, {0, 0, 0}};
      bool ok = false;
      for (auto& vv : SH.vertices)
        if (vv.vertex == V) td = {vv.t, vv.d}, ok = true;
      if (!ok) continue;
      V3 x = add(v3(S.vertex_point(V)), mul(V3{td.second[0], td.second[1], td.second[2]}, td.first));
      auto pr = S.project_to_edge(found, cv(x));
      auto v2 = S.edge_vertices(found);
      int cend = v2[0] == V ? 0 : 1;
      if (cuts[found][cend].node != kNone) {
        slide_end_image[{V, B}] = cuts[found][cend].node;
        continue;
      }
      std::uint32_t n = mk(v3(pr.point), 1, found + 1, pr.t);
      cuts[found][cend] = {pr.t, n};
      ++R.edges_cut;
      slide_end_image[{V, B}] = n;
    }
  }
}

void Builder::build_slides() {
  for (int e = 0; e < ne; ++e) {
    if (slide_other[e] < 0) continue;
    int B = slide_other[e], W = slide_wall[e];
    for (std::size_t k = 0; k < en[e].size(); ++k) {
      std::uint32_t n = en[e][k];
      if (image.count(n)) continue;
      if (k == 0 || k + 1 == en[e].size()) {
        auto it = slide_end_image.find({S.edge_vertices(e)[k == 0 ? 0 : 1], B});
        if (it != slide_end_image.end()) {
          image[n] = it->second;
          continue;
        }
      }
      std::pair<double, shell::Vec3> td;
      bool is_vertex = (k == 0 || k + 1 == en[e].size());
      if (is_vertex) {
        int V = S.edge_vertices(e)[k == 0 ? 0 : 1];
        bool found = false;
        for (auto& vv : SH.vertices)
          if (vv.vertex == V) td = {vv.t, vv.d}, found = true;
        if (!found) td = SH.edge_field(e, et[e][k], W);
      } else {
        td = SH.edge_field(e, et[e][k], W);
      }
      V3 x = add(X(n), mul(V3{td.second[0], td.second[1], td.second[2]}, td.first));
      auto pr = S.project_to_face(B, cv(x));
      std::uint32_t img = mk(v3(pr.point), 2, B + 1, pr.u, pr.v);
      uv_on[img] = {pr.u, pr.v};
      image[n] = img;
    }
  }
}

// The shell's face field at (u,v), its direction corrected for the grid's resolution
// (shell::grid_field_on: the grid's period, and the deviation from the exact normal interpolated
// where the face turns within a cell, e.g. Rotor 67's blade noses); the shell stage samples the
// same field.
std::pair<double, shell::Vec3> Builder::face_field(int face, double u, double v) {
  for (auto& fg : SH.faces)
    if (fg.face == face) return shell::grid_field_on(fg, S, u, v);
  return SH.face_field(face, u, v);  // no grid: throws, naming the face
}

std::uint32_t Builder::shell_image(std::uint32_t n, int face) {
  auto it = image.find(n);
  if (it != image.end()) return it->second;
  int dim = m.node_entity_dim[n], tag = m.node_entity_tag[n];
  std::pair<double, shell::Vec3> td;
  if (dim == 0) {
    bool found = false;
    for (auto& vv : SH.vertices)
      if (vv.vertex == tag - 1) td = {vv.t, vv.d}, found = true;
    if (!found)
      throw StageError("sweep: wall vertex " + std::to_string(tag - 1) + " has no shell value; re-run shell (needs the same shape)");
  } else if (dim == 1) {
    td = SH.edge_field(tag - 1, m.node_u[n], face);
  } else {
    td = face_field(face, m.node_u[n], m.node_v[n]);
  }
  V3 x = add(X(n), mul(V3{td.second[0], td.second[1], td.second[2]}, td.first));
  std::uint32_t img = mk(x, 3, 1);
  image[n] = img;
  return img;
}

// ── one face: boundary loops in (u,v), the 2D mesher, nodes and triangles ────────────────
// The sign of (dS/du x dS/dv) . outward normal on face f (+1 or -1), where |dS/du x dS/dv| is
// largest on a 5 x 5 grid of its parameter box (a pole, where it vanishes, decides nothing);
// Reparam keeps it (both its coordinates increase with their parameters).
int parameter_orientation(const cad::Shape& S, int f) {
  auto b = S.face_uv_bounds(f);
  double best = 0;
  int sign = 0;
  for (int i = 0; i < 5; ++i)
    for (int j = 0; j < 5; ++j) {
      double u = b.u0 + (b.u1 - b.u0) * (i + 0.5) / 5, v = b.v0 + (b.v1 - b.v0) * (j + 0.5) / 5;
      auto d = S.face_eval(f, u, v);
      V3 n = cross(v3(d.du), v3(d.dv));
      double s = dot(n, v3(S.face_normal(f, u, v)));
      if (std::abs(s) > best) best = std::abs(s), sign = s > 0 ? 1 : -1;
    }
  return sign;
}

// (u,v) on f of a node classified elsewhere: through the p-curves of f's edges (a seam's two
// p-curves: the one nearer the hint), projection only for nodes off f's edges
std::array<double, 2> Builder::uv_on_face(int f, std::uint32_t n, std::array<double, 2> hint) const {
  int dim = m.node_entity_dim[n], tag = m.node_entity_tag[n];
  if (dim == 2 && tag == f + 1) return {m.node_u[n], m.node_v[n]};
  auto pick = [&](int e, double t) -> std::optional<std::array<double, 2>> {
    auto fs = S.edge_faces(e);
    if (std::find(fs.begin(), fs.end(), f) == fs.end()) return std::nullopt;
    cad::Vec2 a = S.edge_uv(e, f, t, false);
    std::array<double, 2> r{a.u, a.v};
    if (S.edge_is_seam(e, f) && !std::isnan(hint[0])) {
      cad::Vec2 b = S.edge_uv(e, f, t, true);
      if (std::hypot(b.u - hint[0], b.v - hint[1]) < std::hypot(a.u - hint[0], a.v - hint[1])) r = {b.u, b.v};
    }
    return r;
  };
  if (dim == 1)
    if (auto r = pick(tag - 1, m.node_u[n])) return *r;
  if (dim == 0)
    for (int e : S.face_edges(f)) {
      if (S.edge_degenerate(e)) continue;
      auto vs = S.edge_vertices(e);
      auto rr = S.edge_range(e);
      if (vs[0] == tag - 1)
        if (auto r = pick(e, rr.lo)) return *r;
      if (vs[1] == tag - 1)
        if (auto r = pick(e, rr.hi)) return *r;
    }
  auto pr = std::isnan(hint[0]) ? S.project_to_face(f, cv(X(n))) : S.project_to_face(f, cv(X(n)), cad::Vec2{hint[0], hint[1]});
  return {pr.u, pr.v};
}

// One wire's points in the parameter plane, as its edge uses give them (flip[i]: use i run
// against the wire's orientation; see closed_wire).
Builder::Loop Builder::wire_points(int f, const std::vector<cad::EdgeUse>& wire, const std::vector<char>& flip) {
  Loop raw;
  for (std::size_t iu = 0; iu < wire.size(); ++iu) {
    cad::EdgeUse eu = wire[iu];
    if (flip[iu]) eu.reversed = !eu.reversed;
    int e = eu.edge;
    if (S.edge_degenerate(e)) {
      auto r = S.edge_range(e);
      int V = S.edge_vertices(e)[0];
      cad::Vec2 q = S.edge_uv(e, f, eu.reversed ? r.hi : r.lo, eu.reversed);
      if (vnode[V] == kNone) vnode[V] = mk(v3(S.vertex_point(V)), 0, V + 1);
      raw.push_back({vnode[V], {q.u, q.v}, true});
      continue;
    }
    int jb = junction_of[e];
    std::vector<std::uint32_t> sub;  // substituted curve (both ends included), in the edge's direction
    if (jb >= 0 && J[jb].A == f) sub = J[jb].pa;
    if (jb >= 0 && J[jb].B == f) sub = J[jb].pb;
    if (jb < 0 && slide_other[e] == f) {
      for (auto n : en[e]) sub.push_back(image.at(n));
    }
    if (!sub.empty()) {
      if (eu.reversed) std::reverse(sub.begin(), sub.end());
      std::array<double, 2> hint{NAN, NAN};
      for (auto n : sub) {
        if (!raw.empty() && std::isnan(hint[0])) hint = raw.back().uv;
        auto q = uv_on_face(f, n, hint);
        raw.push_back({n, q});
        hint = q;
      }
      continue;
    }
    const auto& t = et[e];
    const auto& nn = en[e];
    std::size_t n = t.size();
    for (std::size_t s = 0; s + 1 < n; ++s) {
      std::size_t k = eu.reversed ? n - 1 - s : s;
      cad::Vec2 q = S.edge_uv(e, f, t[k], eu.reversed);
      raw.push_back({nn[k], {q.u, q.v}, false, e, eu.reversed, s == 0});
    }
  }
  return raw;
}

// Clean-up: consecutive duplicates and X,V,X detours (a junction vertex between a strip curve
// and the cut edge that continues from the strip's corner). A seam's node met on both sides of
// the face, a period apart, is no detour: taken for one, the sphere's seam (its node before the
// pole, the pole, the same node again on the far side) was zipped away from the pole down, the
// whole loop (34 points) down to 1, and the face got no triangle. A node twice in a row is one
// point when its two (u,v) agree within uv_tol (a millionth of the face's parameter box): the
// two p-curves of the edges meeting there, or an edge of rounding length between two CAD
// vertices that became one node (a blade passage's inflow plane, where the hub's junction strip
// meets the periodic side: 1e-7 apart, kept, it made the boundary cross itself in the plane).
// A pole's segment (one node, (u,v) a whole side of the face apart) is far above that.
void Builder::drop_detours(Loop& raw, std::array<double, 2> per, double uv_tol) {
  bool changed = true;
  while (changed && raw.size() > 2) {
    changed = false;
    for (std::size_t i = 0; i < raw.size() && raw.size() > 2; ++i) {
      std::size_t j = (i + 1) % raw.size();
      if (raw[i].node == raw[j].node && !raw[i].pole &&
          std::abs(raw[i].uv[0] - raw[j].uv[0]) + std::abs(raw[i].uv[1] - raw[j].uv[1]) <
              std::max(uv_tol, 1e-9 * (1 + std::abs(raw[i].uv[0]) + std::abs(raw[i].uv[1])))) {
        raw.erase(raw.begin() + static_cast<long>(j));
        changed = true;
        break;
      }
      std::size_t k = (i + 2) % raw.size();
      // (not a seam's node on either side of the face: a period apart)
      bool apart = cad::Shape::period_jump(raw[i].uv[0], raw[k].uv[0], per[0]) ||
                   cad::Shape::period_jump(raw[i].uv[1], raw[k].uv[1], per[1]);
      if (raw[i].node == raw[k].node && i != k && !apart) {
        // drop the detour i -> j -> k == i
        std::size_t first = std::max(j, k), second = std::min(j, k);
        raw.erase(raw.begin() + static_cast<long>(first));
        raw.erase(raw.begin() + static_cast<long>(second));
        changed = true;
        break;
      }
    }
  }
}

// Periodic surfaces: every point unwrapped to the period nearest the previous one of its loop,
// and the loop's last point dropped where it is its first again.
void Builder::unwrap_loop(Loop& raw, std::array<double, 2> per) {
  // periodic surfaces: a projected point may come back a period away from its neighbours
  // (OCCT returns u in [0, 2 pi) on a revolved hub whose sector straddles u = 0): unwrap
  // every point to the period nearest the previous point of its loop
  for (int k = 0; k < 2; ++k) {
    if (!(per[k] > 0)) continue;
    for (std::size_t i = 1; i < raw.size(); ++i) {
      if (raw[i - 1].pole) continue;  // a pole's p-curve may legitimately span half a period or more
      // only jumps beyond 3/4 of a period: a one-division edge may span half a period (the
      // semicircular trailing-edge arc of a revolved tip)
      raw[i].uv[k] = cad::Shape::unwrap_towards(raw[i].uv[k], raw[i - 1].uv[k], per[k]);
    }
  }
  // the loop's last point and its first, one node at one place after unwrapping (a wrapped
  // face's seam ends where its rebuilt wire starts)
  while (raw.size() > 3 && raw.front().node == raw.back().node &&
         std::abs(raw.front().uv[0] - raw.back().uv[0]) + std::abs(raw.front().uv[1] - raw.back().uv[1]) <
             1e-9 * (1 + std::abs(raw.front().uv[0]) + std::abs(raw.front().uv[1])))
    raw.pop_back();
}

Builder::Loop Builder::build_wire(int f, const std::vector<cad::EdgeUse>& wire, const std::vector<char>& flip) {
  Loop raw = wire_points(f, wire, flip);
  const auto per = S.face_periods(f);
  const auto box = S.face_uv_bounds(f);
  drop_detours(raw, per, 1e-6 * std::max(box.u1 - box.u0, box.v1 - box.v0));
  unwrap_loop(raw, per);
  return raw;
}

// A wire closes in the plane when its closing segment (last point -> first) does not jump by
// most of a period (a pole's segment may). A wrapped face (periodic in u, bounded by two closed
// edges and a seam used twice, e.g. a blade lofted around its sections) whose closed edges
// both run the same way round (Rotor 67's blade: hub and casing curves both u 1 -> 0, the seam
// up at u = 1 and down at u = 0) does not: the unwrapped chain ends two periods away from its
// start and the loop crosses the whole domain. The wire is then rebuilt with the first closed,
// full-period edge use (or its junction/slide curve) run the other way, which makes it the
// boundary of the face's band [0, period] x [v0, v1]; the 3D face is the same either way (an
// orientation defect of the wire, not of the geometry).
bool Builder::loop_closes(const Loop& raw, std::array<double, 2> per) {
  if (raw.size() < 3 || raw.back().pole) return true;
  for (int k = 0; k < 2; ++k)
    if (cad::Shape::period_jump(raw.front().uv[k], raw.back().uv[k], per[k])) return false;
  return true;
}

Builder::Loop Builder::closed_wire(int f, const std::vector<cad::EdgeUse>& wire) {
  const auto per = S.face_periods(f);
  std::vector<char> flip(wire.size(), 0);
  Loop raw = build_wire(f, wire, flip);
  if (loop_closes(raw, per)) return raw;
  for (std::size_t iu = 0; iu < wire.size(); ++iu) {
    int e = wire[iu].edge;
    auto vs = S.edge_vertices(e);
    if (S.edge_degenerate(e) || S.edge_is_seam(e, f) || vs[0] != vs[1]) continue;
    flip[iu] = 1;
    Loop r2 = build_wire(f, wire, flip);
    flip[iu] = 0;
    if (!loop_closes(r2, per)) continue;
    log("sweep: face " + std::to_string(f) + ": the wire does not close in the parameter plane (wrapped face); closed edge " +
        std::to_string(e) + " taken the other way round");
    return r2;
  }
  throw StageError("sweep: face " + std::to_string(f) + " (" + cad::tag_name(S.face_tag(f)) + ", " + S.face_surface_type(f) +
                   "): a boundary loop does not close in the parameter plane (it ends a period away from its start) "
                   "and no closed edge of the loop can be reversed to close it; heal the face (its wire orientation)");
}

// Inner loops a period away from the outer one (each loop was unwrapped on its own) are moved
// next to it, and all of them into the face's parameter range.
void Builder::align_loops(int f, std::vector<Loop>& loops) const {
  auto per = S.face_periods(f);
  for (int k = 0; k < 2; ++k) {
    if (!(per[k] > 0)) continue;
    double lo = INFINITY, hi = -INFINITY;
    for (auto& p : loops[0]) lo = std::min(lo, p.uv[k]), hi = std::max(hi, p.uv[k]);
    for (std::size_t l = 1; l < loops.size(); ++l) {
      double mean = 0;
      for (auto& p : loops[l]) mean += p.uv[k] / loops[l].size();
      double shift = 0;
      if (mean < lo) shift = per[k] * std::ceil((lo - mean) / per[k]);
      if (mean > hi) shift = -per[k] * std::ceil((mean - hi) / per[k]);
      for (auto& p : loops[l]) p.uv[k] += shift;
    }
    // all loops a period away from the face's parameter range (a rebuilt wrapped wire
    // unwrapped from its seam's far side): back into it, where Reparam's tables, the shell's
    // face grid and the node parameters of the contract live
    auto b = S.face_uv_bounds(f);
    double centre = k == 0 ? 0.5 * (b.u0 + b.u1) : 0.5 * (b.v0 + b.v1);
    double mid = 0.5 * (lo + hi);
    double n = std::round((centre - mid) / per[k]);
    if (n != 0)
      for (auto& l : loops)
        for (auto& p : l) p.uv[k] += n * per[k];
  }
}

// The face's boundary loops in its (unwrapped) parameter plane; throws when none is left.
std::vector<Builder::Loop> Builder::face_loops(int f) {
  std::vector<Loop> loops;
  for (auto& wire : S.face_wires(f)) {
    Loop raw = closed_wire(f, wire);
    if (raw.size() >= 3) loops.push_back(std::move(raw));
  }
  if (loops.empty())
    throw StageError("sweep: face " + std::to_string(f) + " (" + cad::tag_name(S.face_tag(f)) + ", " + S.face_surface_type(f) +
                     "): no boundary loop of three points or more is left in its parameter plane (" +
                     std::to_string(S.face_wires(f).size()) + " wire(s)); the face cannot be meshed: heal it (its wires)");
  align_loops(f, loops);
  return loops;
}

// Smooth boundary points: where the face's boundary is tangent-continuous in 3D, a curved
// triangle cannot have two boundary edges (its corner there opens to 180 degrees and det J
// vanishes): inside a CAD edge always, at a CAD vertex when the tangents of the edges that
// meet there differ by less than 20 degrees (the semicircular arc closing a blunt trailing
// edge at a revolved tip continues the straight trailing-edge lines).
std::vector<char> Builder::smooth_points(const std::vector<Loop>& loops) const {
  std::vector<char> smooth_of;
  auto tangent = [&](int e, bool at_end, bool reversed) {
    auto r = S.edge_range(e);
    double t = (at_end != reversed) ? r.hi : r.lo;
    V3 d = v3(S.edge_eval(e, t).d1);
    return reversed ? sub(V3{0, 0, 0}, d) : d;
  };
  for (auto& l : loops) {
    const std::size_t L = l.size();
    for (std::size_t i = 0; i < L; ++i) {
      const auto& cur = l[i];
      const auto& prev = l[(i + L - 1) % L];
      bool smooth = false;
      if (cur.edge >= 0 && !cur.first && !cur.pole) smooth = true;
      else if (cur.edge >= 0 && cur.first && prev.edge >= 0 && prev.edge != cur.edge && !S.edge_degenerate(prev.edge)) {
        V3 ti = tangent(prev.edge, true, prev.reversed), to = tangent(cur.edge, false, cur.reversed);
        double ni = norm(ti), no = norm(to);
        smooth = ni > 0 && no > 0 && dot(ti, to) > std::cos(20 * M_PI / 180) * ni * no;
      }
      smooth_of.push_back(smooth ? 1 : 0);
    }
  }
  return smooth_of;
}

// The parameter-plane mesher's input for face f: boundary points and segments in Reparam's
// plane, the surface, its normals and the size field (capturing rp and fb, which must outlive it).
detail::UVMeshInput Builder::uv_input(int f, const std::vector<Loop>& loops, const Reparam& RP, FaceBoundary& fb) {
  detail::UVMeshInput in;
  in.smooth = smooth_points(loops);
  for (auto& l : loops)
    for (auto& p : l) in.pole.push_back(p.pole ? 1 : 0);
  auto& bnode = fb.node;
  auto& bx = fb.x;
  auto& bh = fb.h;
  for (auto& l : loops) {
    int first = static_cast<int>(in.uv.size());
    for (std::size_t i = 0; i < l.size(); ++i) {
      in.uv.push_back(RP.fwd(l[i].uv[0], l[i].uv[1]));
      bnode.push_back(l[i].node);
      bx.push_back(X(l[i].node));
      in.segments.push_back({first + static_cast<int>(i), first + static_cast<int>((i + 1) % l.size())});
    }
    for (std::size_t i = 0; i < l.size(); ++i) {
      V3 a = X(l[(i + l.size() - 1) % l.size()].node), b = X(l[i].node), c = X(l[(i + 1) % l.size()].node);
      bh.push_back(0.5 * (norm(sub(b, a)) + norm(sub(c, b))));
    }
  }
  const bool is_wall = wall[f] != 0;
  const double hmax = is_wall ? O.max_size : O.farfield_size;
  in.point = [this, f, &RP](double U, double V) {
    auto q = RP.inv(U, V);
    return v3(S.face_point(f, q[0], q[1]));
  };
  in.size = [this, f, &RP, &bx, &bh, hmax](double u, double v) {
    auto q = RP.inv(u, v);
    double uu = q[0], vv = q[1];
    V3 x = v3(S.face_point(f, uu, vv));
    double h = hmax;  // curvature: the turn-angle rule on the vertex normals (in.normal below)
    (void)vv;
    // the interior is not made finer than its boundary (the edges carry the sizing the integer
    // program balanced): the curvature size is raised to the boundary spacing interpolated by
    // inverse squared distance, then graded from the boundary nodes
    double wsum = 0, hidw = 0, hgrad = INFINITY;
    for (std::size_t i = 0; i < bx.size(); ++i) {
      double d = norm(sub(x, bx[i]));
      double w = 1 / (d * d + 1e-30);
      wsum += w, hidw += w * bh[i];
      hgrad = std::min(hgrad, bh[i] + O.grading * d);
    }
    if (wsum > 0) h = std::max(h, hidw / wsum);
    h = std::min({h, hgrad, hmax});
    return std::max(h, O.min_size);
  };
  in.normal = [this, f, &RP](double U, double V) {
    auto q = RP.inv(U, V);
    return v3(S.face_normal(f, q[0], q[1]));
  };
  in.orientation = parameter_orientation(S, f);
  in.max_turn = O.turn_angle_deg * M_PI / 180;
  in.min_length = O.min_size;
  in.refine_ratio = O.refine_ratio;
  in.smooth_passes = O.smooth_passes;
  return in;
}

detail::UVMeshOutput Builder::mesh_parameter_plane(int f, const detail::UVMeshInput& in) {
  detail::UVMeshOutput out;
  try {
    out = detail::mesh_uv(in);
    if (std::getenv("MESHFLOW_SWEEP_DEBUG")) {
      int ns = 0;
      for (char c : in.smooth) ns += c;
      log("face " + std::to_string(f) + ": " + std::to_string(ns) + " smooth boundary points of " + std::to_string(in.smooth.size()) +
          ", " + std::to_string(out.smooth_corner_splits) + " triangles split at smooth corners");
    }
  } catch (const std::exception& ex) {
    throw StageError("sweep: face " + std::to_string(f) + " (" + cad::tag_name(S.face_tag(f)) + ", " +
                     S.face_surface_type(f) + ") cannot be triangulated in its parameter plane: " + ex.what());
  }
  if (std::getenv("MESHFLOW_SWEEP_DEBUG"))
    log("face " + std::to_string(f) + ": " + std::to_string(out.uv.size()) + " points, " + std::to_string(out.tris.size()) +
        " triangles, " + std::to_string(out.passes) + " passes, min quality " + std::to_string(out.min_quality));
  if (out.folded > 0) {
    char at[96];
    std::snprintf(at, sizeof at, "(%.6g, %.6g, %.6g)", out.folded_at[0], out.folded_at[1], out.folded_at[2]);
    throw StageError("sweep: face " + std::to_string(f) + " (" + cad::tag_name(S.face_tag(f)) + ", " + S.face_surface_type(f) +
                     "): " + std::to_string(out.folded) +
                     " triangle(s) of its parameter-plane mesh fold over in 3D (their normal opposes the surface's) after "
                     "refinement and repair, one at " + at +
                     (out.folded_on_segment
                          ? ", across a boundary segment: the face is narrower there than the segment's chord sags (a thin "
                            "strip or fillet whose edges have too few divisions); lower the wall sizes (balance.max_size) so "
                            "its edges get more, or remove the strip in the CAD"
                          : ", where the parameterisation is singular (a pole) or strongly sheared: lower the wall sizes or "
                            "heal the face"));
  }
  return out;
}

// The parameter-plane triangles as 3D triangles of face f, oriented out of the fluid; the new
// points become nodes on the face.
void Builder::face_triangles(int f, const detail::UVMeshOutput& out, const Reparam& RP, const std::vector<std::uint32_t>& bnode) {
  std::vector<std::uint32_t> node(out.uv.size(), kNone);
  for (std::size_t i = 0; i < bnode.size(); ++i) node[i] = bnode[i];
  for (std::size_t i = bnode.size(); i < out.uv.size(); ++i) {
    auto q = RP.inv(out.uv[i][0], out.uv[i][1]);
    double u = q[0], v = q[1];
    node[i] = mk(v3(S.face_point(f, u, v)), 2, f + 1, u, v);
  }
  for (auto& t : out.tris) {
    std::array<std::uint32_t, 3> g{node[t[0]], node[t[1]], node[t[2]]};
    if (g[0] == g[1] || g[1] == g[2] || g[0] == g[2]) continue;  // collapsed at a pole
    // orient out of the fluid (the face normal points out of the fluid solid)
    V3 a = X(g[0]), b = X(g[1]), c = X(g[2]);
    V3 nrm = cross(sub(b, a), sub(c, a));
    auto cq = RP.inv((out.uv[t[0]][0] + out.uv[t[1]][0] + out.uv[t[2]][0]) / 3,
                     (out.uv[t[0]][1] + out.uv[t[1]][1] + out.uv[t[2]][1]) / 3);
    double cu = cq[0], cvv = cq[1];
    V3 fn = v3(S.face_normal(f, cu, cvv));
    if (dot(nrm, fn) < 0) std::swap(g[1], g[2]);
    face_tris[f].push_back(g);
  }
}

// At a pole the parameter plane's pole segment collapses to one node: an edge x-y with the
// segment's two ends on opposite sides gives the triangles (pole, x, y) twice, a fold of the
// fan around the pole (the parametric body's nose). Both copies go: the pole's fan is closed
// by the triangles on either side of them, which share the edges pole-x and pole-y.
void Builder::drop_pole_folds(int f) {
  std::map<std::array<std::uint32_t, 3>, int> seen;
  auto key = [](std::array<std::uint32_t, 3> g) {
    std::sort(g.begin(), g.end());
    return g;
  };
  for (auto& g : face_tris[f]) ++seen[key(g)];
  std::size_t before = face_tris[f].size();
  face_tris[f].erase(std::remove_if(face_tris[f].begin(), face_tris[f].end(),
                                    [&](const std::array<std::uint32_t, 3>& g) { return seen[key(g)] == 2; }),
                     face_tris[f].end());
  for (auto& [k, c] : seen)
    if (c > 2)
      throw StageError("sweep: face " + std::to_string(f) + " has a triangle " + std::to_string(c) +
                       " times over after mapping its parameter plane to 3D (a pole or seam folded); refine the face");
  if (before != face_tris[f].size())
    log("sweep: face " + std::to_string(f) + ": " + std::to_string((before - face_tris[f].size()) / 2) +
        " folded triangle pair(s) at a pole removed");
}

void Builder::mesh_face(int f, int copy_from) {
  std::vector<Loop> loops = face_loops(f);
  {
    std::set<std::uint32_t> seen;
    face_bnodes[f].clear();
    for (auto& l : loops)
      for (auto& p : l)
        if (seen.insert(p.node).second) face_bnodes[f].push_back(p.node);
  }
  if (copy_from >= 0) {
    copy_face(copy_from, f, face_bnodes[f]);
    return;
  }
  if (std::getenv("MESHFLOW_SWEEP_DEBUG")) {
    std::ostringstream o;
    o << "face " << f << ": loops";
    for (auto& l : loops) o << " " << l.size();
    for (auto& l : loops) for (auto& p : l) o << " " << p.node << "[" << p.uv[0] << "," << p.uv[1] << "]";
    log(o.str());
  }
  Reparam RP(S, f);
  if (std::getenv("MESHFLOW_SWEEP_DEBUG")) log("face " + std::to_string(f) + ": " + (RP.conformal() ? "conformal" : "arc-length") + " plane, shear " + std::to_string(RP.shear()));
  FaceBoundary fb;
  detail::UVMeshInput in = uv_input(f, loops, RP, fb);
  detail::UVMeshOutput out = mesh_parameter_plane(f, in);
  face_triangles(f, out, RP, fb.node);
  drop_pole_folds(f);
  if (face_tris[f].empty())
    throw StageError("sweep: face " + std::to_string(f) + " (" + cad::tag_name(S.face_tag(f)) + ", " + S.face_surface_type(f) +
                     "): its parameter-plane mesh of " + std::to_string(out.tris.size()) +
                     " triangle(s) leaves none after mapping to 3D (all collapsed at poles); the face cannot be meshed");
  ++R.faces_meshed;
}

// Layer directions are smoothed where a prism is inverted (typically at convex corners where
// three walls meet and the shell's direction field turns faster than the triangles are
// wide): the direction of each wall node of an inverted prism and of its neighbours becomes
// the normalised mean of its own and its neighbours' directions, the layer height their mean
// (Jacobi passes, until every prism is valid or 60 passes, the last 40 also thinning the layer
// at the nodes of inverted prisms). Images sliding on other faces never move; junction corners
// only in a second round when the first fails (see below).
void Builder::untangle(std::vector<std::vector<std::uint32_t>>& P) {
  std::map<std::uint32_t, std::set<std::uint32_t>> nb;
  std::map<std::uint32_t, std::uint32_t> img;
  for (auto& p : P)
    for (int i = 0; i < 3; ++i) {
      img[p[i]] = p[i + 3];
      for (int j = 0; j < 3; ++j)
        if (j != i) nb[p[i]].insert(p[j]);
    }
  std::map<std::uint32_t, std::vector<std::size_t>> prisms_of_img;  // shell node -> prisms
  std::map<std::uint32_t, std::uint32_t> wall_of;                    // shell node -> its wall node
  for (std::size_t k = 0; k < P.size(); ++k)
    for (int c = 0; c < 3; ++c) prisms_of_img[P[k][c + 3]].push_back(k), wall_of[P[k][c + 3]] = P[k][c];
  auto either = [&](const std::vector<std::uint32_t>& p) { return valid_either(model::Shape::Prism, p); };
  std::set<std::uint32_t> fixed_img;
  auto movable = [&](std::uint32_t w) {
    std::uint32_t i = img.at(w);
    return !fixed_img.count(i) && m.node_entity_dim[i] == 3;
  };
  // one round of at most 60 passes; true when every prism is valid
  auto round = [&](const std::string& what) {
    for (int pass = 0; pass < 60; ++pass) {
      std::set<std::uint32_t> bad;
      for (auto& p : P)
        if (!either(p))  // valid in the other orientation: flipped later
          for (int i = 0; i < 3; ++i) bad.insert(p[i]);
      if (bad.empty()) {
        if (pass > 0)
          log("sweep: layer directions smoothed in " + std::to_string(pass) + " passes to untangle prisms" + what +
              (R.thinned ? ", layer thinned at " + std::to_string(R.thinned) + " node moves" : std::string()));
        return true;
      }
      std::set<std::uint32_t> move;
      for (auto w : bad) {
        if (movable(w)) move.insert(w);
        for (auto n : nb[w])
          if (movable(n)) move.insert(n);
      }
      std::vector<std::pair<std::uint32_t, V3>> upd;
      for (auto w : move) {
        V3 d{0, 0, 0};
        double t = 0;
        int k = 0;
        auto acc = [&](std::uint32_t n) {
          V3 l = sub(X(img.at(n)), X(n));
          double len = norm(l);
          if (len > 0) d = add(d, mul(l, 1 / len)), t += len, ++k;
        };
        acc(w);
        for (auto n : nb[w]) acc(n);
        if (k == 0 || norm(d) == 0) continue;
        double len = t / k;
        // after 20 passes of direction smoothing, the layer is also thinned where it stays tangled
        if (pass >= 20 && bad.count(w)) len = std::min(len, 0.8 * norm(sub(X(img.at(w)), X(w)))), ++R.thinned;
        upd.push_back({img.at(w), add(X(w), mul(d, len / norm(d)))});
      }
      // moves of neighbours (nodes that are not themselves in an inverted prism) must not invert
      // a prism that was valid: those are undone (DLR-F6's nacelle: valid prisms next to the
      // tangle were smoothed into it and then thinned to 3e-4 mm)
      std::set<std::size_t> touched;
      std::map<std::uint32_t, V3> before;
      for (auto& [i, x] : upd) {
        before[i] = X(i);
        for (auto k : prisms_of_img[i]) touched.insert(k);
      }
      std::map<std::size_t, bool> was_ok;
      for (auto k : touched) was_ok[k] = either(P[k]);
      for (auto& [i, x] : upd) m.x[i] = x[0], m.y[i] = x[1], m.z[i] = x[2];
      for (bool again = true; again;) {
        again = false;
        for (auto k : touched)
          if (was_ok[k] && !either(P[k]))
            for (int c = 3; c < 6; ++c) {
              auto i = P[k][c];
              auto b = before.find(i);
              if (b == before.end() || bad.count(wall_of.at(i))) continue;
              m.x[i] = b->second[0], m.y[i] = b->second[1], m.z[i] = b->second[2];
              before.erase(b);
              again = true;
            }
      }
    }
    return false;
  };
  // First with the junction corners fixed. Where that fails (Rotor 67: the hub and casing
  // junctions at the blade's sharp trailing edge, whose corners PC fan across the nose while
  // the blade's own directions flip), again from the start with the corners PC free to move too
  // (they are the images of the strip boundaries; the hexes are checked afterwards).
  auto fix_corners = [&] {
    for (auto& j : J)
      for (auto n : j.pc) fixed_img.insert(n);
  };
  auto inverted = [&] {
    std::size_t n = 0;
    for (auto& p : P) n += !either(p);
    return n;
  };
  fix_corners();
  std::vector<double> x0 = m.x, y0 = m.y, z0 = m.z;
  if (round("")) return;
  m.x = x0, m.y = y0, m.z = z0;
  R.thinned = 0;
  fixed_img.clear();
  if (round(" (junction corners moved too)")) return;
  // Where smoothing fails both ways (DLR-F6: a sliver of the pylon's face along its acute
  // averaged corner with the wing, 1.5 mm from the corner edge under a 1.2 mm layer: the
  // corner's direction, which the wing's prisms need, folds it; smoothing it towards the
  // pylon's neighbours folds the wing's prisms), each shell node of an inverted prism is
  // placed instead, from the layer as it came from the fields, by a pattern search that
  // maximises the smallest scaled Jacobian of the prisms around it (each in the orientation
  // its wall triangle had before: a prism folded through the wall does not count as valid),
  // node by node in node order, until every prism is valid or a sweep over them changes
  // nothing. The junction corners stay fixed. When that leaves more prisms inverted than the
  // smoothing did (the open U's caps, DLR-F6 with third_face_ends cap: 79 against 4), the
  // smoothed layer is kept.
  const std::vector<double> xs = m.x, ys = m.y, zs = m.z;
  const std::size_t thinned_smoothed = R.thinned;
  const std::size_t bad_smoothed = inverted();
  m.x = x0, m.y = y0, m.z = z0;
  R.thinned = 0;
  fix_corners();
  std::vector<char> flip(P.size(), 0);
  const auto& fl = flip_of(model::Shape::Prism);
  for (std::size_t k = 0; k < P.size(); ++k) {
    V3 b0 = X(P[k][0]), b1 = X(P[k][1]), b2 = X(P[k][2]);
    V3 up = sub(add(add(X(P[k][3]), X(P[k][4])), X(P[k][5])), add(add(b0, b1), b2));
    flip[k] = dot(cross(sub(b1, b0), sub(b2, b0)), up) < 0;
  }
  auto quality = [&](std::size_t k) {
    double X3[18];
    for (int c = 0; c < 6; ++c) {
      auto n = P[k][flip[k] ? fl[c] : c];
      X3[3 * c] = m.x[n], X3[3 * c + 1] = m.y[n], X3[3 * c + 2] = m.z[n];
    }
    auto q = model::element_quality(model::Shape::Prism, 1, X3);
    return q.valid ? std::max(q.scaled_jacobian, 1e-12) : std::min(q.scaled_jacobian, 0.0) - 1;
  };
  auto around = [&](std::uint32_t i) {
    double w = INFINITY;
    for (auto k : prisms_of_img[i]) w = std::min(w, quality(k));
    return w;
  };
  for (int pass = 0; pass < 20; ++pass) {
    std::set<std::uint32_t> bad;
    for (std::size_t k = 0; k < P.size(); ++k)
      if (!(quality(k) > 0))
        for (int c = 0; c < 3; ++c)
          if (movable(P[k][c])) bad.insert(img.at(P[k][c]));
    if (bad.empty()) {
      log("sweep: prisms untangled by " + std::to_string(R.placed) + " placements of shell nodes");
      return;
    }
    bool changed = false;
    for (auto i : bad) {
      const V3 start = X(i);
      V3 w = X(wall_of.at(i)), b = start;
      const double len = norm(sub(b, w)), reach = 1.5 * len;
      double q = around(i);
      auto put = [&](V3 x) { m.x[i] = x[0], m.y[i] = x[1], m.z[i] = x[2]; };
      pattern_search(
          b, q, 0.25 * len, 1e-4 * len, [&](V3 x) { return norm(sub(x, w)) <= reach; },
          [&](V3 x) { return put(x), around(i); });
      put(b);
      if (b != start) changed = true, ++R.placed;
    }
    if (!changed) break;
  }
  if (inverted() > bad_smoothed) m.x = xs, m.y = ys, m.z = zs, R.thinned = thinned_smoothed, R.placed = 0;
}

// ── crossings of the near field's outer surface ────────────────────────────────────────
// The elements are valid one by one, but the outer surface of the near field (the far field's
// boundary for tet) can still cross itself where the layers of two walls fan into each other:
// Rotor 67's hub and casing junctions around the blade's 1e-3 ft leading and trailing edges,
// where the blade's layer fans out around the nose by its own thickness while the hub's layer
// next to the junction strip is as thick. Only the discrete surface decides (the shell stage's
// fields agree with it up to their grid), so it is checked here: every face of the near field
// that is no face of two of its elements and has a node inside the volume, with every boundary
// face (walls, strips, the faces the layer slides on, far-field/periodic/symmetry faces), by
// shell::self_intersections (CGAL AABB tree, exact predicates; faces sharing a node are not
// tested, quads as two triangles). Where two cross, the layer is thinned at the volume nodes of
// both: each such node's height over its base (the wall node it was swept from; for a junction
// corner PC the edge node P0, so the hex's cross-section shrinks towards its diagonal) is scaled
// by 0.8 per round, down to `kMinScale` of the original, and the scale is made 0.15-Lipschitz in
// steps along the outer surface so the thinning fades out instead of leaving a step. A round
// that would make an element invalid is undone at that element's nodes, which are then kept.
// Rounds repeat until nothing crosses or nothing can move; what is left is reported (stats
// outer_crossings) and tet refuses it by name.
void Builder::clear_crossings(const std::vector<std::vector<std::uint32_t>>& P, const std::set<std::uint32_t>& frozen) {
  constexpr double kShrink = 0.8, kMinScale = 0.25, kLipschitz = 0.15;
  constexpr int kRounds = 40;
  std::vector<std::vector<std::uint32_t>> H;
  for (auto& j : J)
    for (std::size_t k = 0; k + 1 < j.p0.size(); ++k) H.push_back(junction_hex(j, k));
  // faces of the elements (Gmsh order), counted by their sorted nodes
  static const std::vector<std::vector<int>> prism_faces{{0, 1, 2}, {3, 4, 5}, {0, 1, 4, 3}, {1, 2, 5, 4}, {2, 0, 3, 5}};
  static const std::vector<std::vector<int>> hex_faces{{0, 1, 2, 3}, {4, 5, 6, 7}, {0, 1, 5, 4},
                                                       {1, 2, 6, 5}, {2, 3, 7, 6}, {3, 0, 4, 7}};
  std::vector<std::pair<std::vector<std::uint32_t>, std::vector<std::uint32_t>>> faces;  // (sorted key, face)
  auto add_faces = [&](const std::vector<std::vector<std::uint32_t>>& E, const std::vector<std::vector<int>>& F) {
    for (auto& e : E)
      for (auto& f : F) {
        std::vector<std::uint32_t> v;
        for (int i : f) v.push_back(e[i]);
        auto k = v;
        std::sort(k.begin(), k.end());
        faces.push_back({std::move(k), std::move(v)});
      }
  };
  add_faces(P, prism_faces);
  add_faces(H, hex_faces);
  std::sort(faces.begin(), faces.end());
  std::vector<std::array<std::int32_t, 3>> tris;
  std::vector<char> outer_tri;  // per triangle: part of the outer surface (else a boundary face)
  auto add_poly = [&](const std::vector<std::uint32_t>& v, bool outer) {
    for (std::size_t i = 1; i + 1 < v.size(); ++i) {
      tris.push_back({static_cast<std::int32_t>(v[0]), static_cast<std::int32_t>(v[i]), static_cast<std::int32_t>(v[i + 1])});
      outer_tri.push_back(outer);
    }
  };
  std::vector<std::vector<std::uint32_t>> outer;
  for (std::size_t i = 0; i < faces.size();) {
    std::size_t j = i + 1;
    while (j < faces.size() && faces[j].first == faces[i].first) ++j;
    bool inside = false;
    for (auto n : faces[i].second) inside = inside || m.node_entity_dim[n] == 3;
    if (j == i + 1 && inside) outer.push_back(faces[i].second), add_poly(faces[i].second, true);
    i = j;
  }
  for (int f = 0; f < nf; ++f)
    for (auto& t : face_tris[f]) add_poly({t[0], t[1], t[2]}, false);
  for (auto& h : H) add_poly({h[0], h[1], h[2], h[3]}, false), add_poly({h[0], h[1], h[5], h[4]}, false);
  for (int e = 0; e < ne; ++e)
    if (slide_other[e] >= 0)
      for (std::size_t k = 0; k + 1 < en[e].size(); ++k)
        add_poly({en[e][k], en[e][k + 1], image.at(en[e][k + 1]), image.at(en[e][k])}, false);
  // the base of every movable node: the wall node it was swept from (PC: its P0)
  std::map<std::uint32_t, std::uint32_t> base;
  for (auto& p : P)
    for (int i = 0; i < 3; ++i)
      if (p[i + 3] != p[i] && m.node_entity_dim[p[i + 3]] == 3) base[p[i + 3]] = p[i];
  for (auto& j : J)
    for (std::size_t k = 0; k < j.pc.size(); ++k)
      if (j.pc[k] != kNone && m.node_entity_dim[j.pc[k]] == 3) base[j.pc[k]] = j.p0[k];
  // outer-surface neighbours (for the Lipschitz fade) and the elements at each node
  std::map<std::uint32_t, std::set<std::uint32_t>> nb;
  for (auto& f : outer)
    for (std::size_t i = 0; i < f.size(); ++i) {
      auto a = f[i], b = f[(i + 1) % f.size()];
      if (base.count(a) && base.count(b)) nb[a].insert(b), nb[b].insert(a);
    }
  std::map<std::uint32_t, std::vector<std::pair<char, std::uint32_t>>> elems;  // node -> (prism 0 / hex 1, index)
  for (std::uint32_t i = 0; i < P.size(); ++i)
    for (auto n : P[i]) if (base.count(n)) elems[n].push_back({0, i});
  for (std::uint32_t i = 0; i < H.size(); ++i)
    for (auto n : H[i]) if (base.count(n)) elems[n].push_back({1, i});
  auto valid = [&](char kind, std::uint32_t i) {
    return kind ? valid_either(model::Shape::Hex, H[i]) : valid_either(model::Shape::Prism, P[i]);
  };
  std::map<std::uint32_t, V3> x0;
  std::map<std::uint32_t, double> scale;
  std::set<std::uint32_t> kept;
  auto place = [&](std::uint32_t n) {
    V3 b = X(base.at(n)), p = add(b, mul(sub(x0.at(n), b), scale.at(n)));
    m.x[n] = p[0], m.y[n] = p[1], m.z[n] = p[2];
  };
  std::vector<shell::Vec3> pts(m.num_nodes());
  long first = -1, last = 0;
  std::vector<std::array<int, 2>> left;
  // rounds of thinning at the crossing pairs not in `ignore`; leaves the pairs still crossing
  auto attempt = [&](const std::set<std::array<int, 2>>& ignore) {
    x0.clear(), scale.clear(), kept = frozen;
    for (int round = 0;; ++round) {
      for (std::size_t i = 0; i < pts.size(); ++i) pts[i] = {m.x[i], m.y[i], m.z[i]};
      auto rep = shell::self_intersections(pts, tris);
      if (first < 0) first = rep.pairs;
      last = rep.pairs;
      left = rep.all;
      if (rep.pairs == 0 || round == kRounds) return;
      std::set<std::uint32_t> hit;
      for (auto& pr : rep.all)
        if (!ignore.count(pr))
          for (int t : pr)
            for (auto n : tris[t])
              if (outer_tri[t] && base.count(n) && !kept.count(n)) hit.insert(n);
      std::map<std::uint32_t, double> old;
      for (auto n : hit) {
        if (!x0.count(n)) x0[n] = X(n), scale[n] = 1;
        if (scale[n] <= kMinScale) continue;
        old[n] = scale[n];
        scale[n] = std::max(kMinScale, scale[n] * kShrink);
      }
      if (old.empty()) return;
      // fade: scale(a) <= scale(b) + kLipschitz along the outer surface, spreading from the hits
      std::set<std::uint32_t> front(hit.begin(), hit.end());
      for (int step = 0; step < 8 && !front.empty(); ++step) {
        std::set<std::uint32_t> next;
        for (auto a : front)
          for (auto b : nb[a]) {
            if (kept.count(b) || !scale.count(a)) continue;
            double sb = scale.count(b) ? scale[b] : 1.0;
            if (sb > scale[a] + kLipschitz + 1e-12) {
              if (!x0.count(b)) x0[b] = X(b);
              if (!old.count(b)) old[b] = sb;
              scale[b] = scale[a] + kLipschitz;
              next.insert(b);
            }
          }
        front = std::move(next);
      }
      for (auto& [n, s0] : old) place(n);
      // undo at the elements this round made invalid (their nodes keep the previous heights and
      // are not moved again), until every element it touched is valid: at worst the previous state
      std::set<std::pair<char, std::uint32_t>> touched;
      for (auto& [n, s0] : old)
        for (auto& e : elems[n]) touched.insert(e);
      for (bool again = true; again;) {
        again = false;
        for (auto& [kind, i] : touched)
          if (!valid(kind, i))
            for (auto n : kind ? H[i] : P[i])
              if (old.count(n) && scale[n] != old[n]) scale[n] = old[n], place(n), kept.insert(n), again = true;
      }
    }
  };
  std::vector<double> X0 = m.x, Y0 = m.y, Z0 = m.z;
  attempt({});
  long found = first;
  if (last > 0 && found > last) {
    // some pairs cannot be cleared by thinning (an outer face crossing a wall face next to its
    // own base): again from the start without them, so that only what helps is thinned
    std::set<std::array<int, 2>> stuck(left.begin(), left.end());
    m.x = X0, m.y = Y0, m.z = Z0;
    attempt(stuck);
  } else if (last > 0) {
    m.x = X0, m.y = Y0, m.z = Z0;  // nothing was cleared: keep the layer as swept
    x0.clear(), scale.clear();
    last = found;  // what is left is what was found (not the count of the attempt undone)
  }
  first = found;
  if (std::getenv("MESHFLOW_SWEEP_DEBUG"))
    for (std::size_t i = 0; i < left.size() && i < 20; ++i) {
      std::string l = "outer crossing left:";
      for (int t : left[i]) {
        l += outer_tri[t] ? " outer" : " boundary";
        for (auto n : tris[t])
          l += " " + std::to_string(n) + fmt(X(n)) + "(" + std::to_string(m.node_entity_dim[n]) + "," +
               std::to_string(m.node_entity_tag[n]) + ")";
        l += " |";
      }
      log(l);
    }
  R.outer_crossings_before = first;
  R.outer_crossings = last;
  R.crossing_nodes_thinned = 0;
  R.crossing_min_scale = 1;
  for (auto& [n, s] : scale)
    if (s < 1) ++R.crossing_nodes_thinned, R.crossing_min_scale = std::min(R.crossing_min_scale, s);
  if (first > 0)
    log("sweep: the near field's outer surface crossed itself or a boundary face at " + std::to_string(first) +
        " face pairs" +
        (R.crossing_nodes_thinned ? "; the layer was thinned at " + std::to_string(R.crossing_nodes_thinned) + " nodes (to " +
                                        std::to_string(R.crossing_min_scale) + " of their height at least)"
                                  : std::string()) +
        (last ? "; " + std::to_string(last) + " pairs are left, which thinning does not clear (near-field elements overlap there)"
              : std::string("; none is left")));
}

// ── junction end caps (sweep.hpp, "Junction ends on a third face") ──────────────────────
// A junction end (V, PA, PC, PB) whose end face is no other block's, where the wall triangles at
// V (on faces other than the junction's, and on A or B when a strip corner is a face node beside
// a side edge: see junction_ends) form one fan from the edge V-PA to the edge V-PB, PA and PB
// swept to PC and V to its vertex image V': each
// prism of the fan (V, a, b | V', a', b') becomes the tet (V, a, b, V') and the pyramid
// (a, b, b', a'; V'), so that the fan's side faces are split along a-V' (conforming between
// neighbours: both halves have apex V'), and the pocket between the end face and the fan's first
// and last side faces is the pyramid (V, PA, PC, PB; V'). Its outer surface is then the prism
// tops (V', a', b'): the edge V'-PC has two faces. V' is used by these elements only, so it is
// moved (place_cap) to maximise their smallest scaled Jacobian.
void Builder::find_caps(const std::vector<std::vector<std::uint32_t>>& P, const std::vector<int>& pface) {
  auto det3 = [](V3 a, V3 b, V3 c) { return dot(a, cross(b, c)); };
  std::map<std::vector<std::uint32_t>, int> end_faces;  // sorted end-face nodes -> blocks ending with it
  auto end_face = [&](const Junction& j, std::size_t k) {
    std::vector<std::uint32_t> f{j.p0[k], j.pa[k], j.pc[k], j.pb[k]};
    std::sort(f.begin(), f.end());
    return f;
  };
  for (auto& j : J)
    for (std::size_t k : {std::size_t(0), j.p0.size() - 1}) ++end_faces[end_face(j, k)];
  std::map<std::uint32_t, std::vector<std::size_t>> at;  // wall node -> prisms having it
  for (std::size_t i = 0; i < P.size(); ++i)
    for (int c = 0; c < 3; ++c) at[P[i][c]].push_back(i);
  for (auto& j : J)
    for (std::size_t k : {std::size_t(0), j.p0.size() - 1}) {
      std::uint32_t V = j.p0[k], PA = j.pa[k], PB = j.pb[k], PC = j.pc[k];
      if (end_faces[end_face(j, k)] > 1 || PA == PB || !at.count(V)) {
        if (std::getenv("MESHFLOW_SWEEP_DEBUG"))
          log("no end cap for the junction along edge " + std::to_string(j.edge) + " at " + fmt(X(V)) + ": " +
              (end_faces[end_face(j, k)] > 1 ? "its end face is another block's too" : PA == PB ? "PA = PB" : "no prism at the vertex"));
        continue;
      }
      Cap cap;
      cap.edge = j.edge, cap.V = V, cap.fan = at[V];
      std::map<std::uint32_t, int> deg;  // rim node -> fan triangles using the edge V-rim
      std::uint32_t& Vi = cap.Vi;
      bool ok = true;
      for (auto i : cap.fan) {
        for (int c = 0; c < 3; ++c)
          if (P[i][c] == V) {
            if (Vi != kNone && Vi != P[i][3 + c]) ok = false;
            Vi = P[i][3 + c];
          } else {
            ++deg[P[i][c]];
            if ((P[i][c] == PA || P[i][c] == PB) && P[i][3 + c] != PC) ok = false;
          }
      }
      for (auto [n, d] : deg)
        if (d != ((n == PA || n == PB) ? 1 : 2)) ok = false;
      if (!ok || Vi == kNone || m.node_entity_dim[Vi] != 3 || !deg.count(PA) || !deg.count(PB) || deg.size() != cap.fan.size() + 1) {
        if (std::getenv("MESHFLOW_SWEEP_DEBUG")) {
          std::string l = "no end cap for the junction along edge " + std::to_string(j.edge) + " at " + fmt(X(V)) + ": " +
                          std::to_string(cap.fan.size()) + " prisms at the vertex, rim";
          for (auto [n, d] : deg) l += " " + std::to_string(n) + (n == PA ? "(PA)" : n == PB ? "(PB)" : "") + "x" + std::to_string(d);
          log(l + (ok ? "" : "; a prism on A or B, or PA/PB not swept to PC"));
        }
        continue;
      }
      // the elements, oriented by the side of the wall V' is on (tet (V, a, b, V') positive)
      for (auto i : cap.fan) {
        int c = 0;
        while (P[i][c] != V) ++c;
        int a = (c + 1) % 3, b = (c + 2) % 3;
        if (det3(sub(X(P[i][a]), X(V)), sub(X(P[i][b]), X(V)), sub(X(Vi), X(V))) < 0) std::swap(a, b);
        std::uint32_t na = P[i][a], nb = P[i][b], ia = P[i][3 + a], ib = P[i][3 + b];
        if (ia == ib) ok = false;  // a collapsed prism (refused before untangling)
        cap.tets.push_back({V, na, nb, Vi});
        cap.pyramids.push_back({na, ia, ib, nb, Vi});  // base normal towards the apex (Gmsh's pyramid)
      }
      if (det3(sub(X(PA), X(V)), sub(X(PB), X(V)), sub(X(Vi), X(V))) > 0)
        cap.pyramids.push_back({V, PA, PC, PB, Vi});
      else
        cap.pyramids.push_back({V, PB, PC, PA, Vi});
      if (!ok) continue;
      std::set<int> on;
      for (auto i : cap.fan) on.insert(pface[i]);
      for (int f : on) cap.faces += (cap.faces.empty() ? "" : ", ") + std::to_string(f);
      cap.faces = (on.size() > 1 ? "wall faces " : "wall face ") + cap.faces;
      caps.push_back(std::move(cap));
    }
}

// smallest scaled Jacobian of the cap's elements (below 0: one is inverted, by how much)
double Builder::cap_quality(const Cap& c) const {
  double w = INFINITY;
  for (auto* L : {&c.tets, &c.pyramids})
    for (auto& e : *L) {
      std::vector<double> X3;
      for (auto n : e) X3.push_back(m.x[n]), X3.push_back(m.y[n]), X3.push_back(m.z[n]);
      auto q = model::element_quality(e.size() == 4 ? model::Shape::Tet : model::Shape::Pyramid, 1, X3.data());
      w = std::min(w, q.valid ? std::max(q.scaled_jacobian, 1e-12) : std::min(q.scaled_jacobian, 0.0) - 1);
    }
  return w;
}

// V' by pattern search (26 directions, step halved when none helps) from each of: its position,
// V + the fan's mean layer vector (V' may be much thinner), the centroid of the fan's tops; the
// step a quarter of the larger of the first two lengths, V' within twice that length of V; V'
// left at the best position found. Returns the cap's quality there (cap_quality).
double Builder::place_cap(Cap& c) {
  std::uint32_t Vi = c.Vi;
  V3 xV = X(c.V), x0 = X(Vi), mean{0, 0, 0}, tops{0, 0, 0};
  int nrim = 0;
  for (auto& t : c.pyramids)
    if (t[0] != c.V) mean = add(mean, sub(X(t[1]), X(t[0]))), tops = add(tops, add(X(t[1]), X(t[2]))), ++nrim;
  mean = mul(mean, 1.0 / std::max(nrim, 1)), tops = mul(tops, 0.5 / std::max(nrim, 1));
  auto put = [&](V3 x) { m.x[Vi] = x[0], m.y[Vi] = x[1], m.z[Vi] = x[2]; };
  double step0 = 0.25 * std::max(norm(sub(x0, xV)), norm(mean)), reach = 8 * step0;
  V3 best = x0;
  double qb = -INFINITY;
  for (V3 start : {x0, add(xV, mean), tops}) {
    if (norm(sub(start, xV)) > reach) continue;
    put(start);
    V3 b = start;
    double q = cap_quality(c);
    pattern_search(
        b, q, step0, 0.0, [&](V3 x) { return norm(sub(x, xV)) <= reach; }, [&](V3 x) { return put(x), cap_quality(c); });
    if (q > qb) qb = q, best = b;
  }
  put(best);
  c.moved += norm(sub(best, x0));
  return qb;
}

void Builder::log_cap(const Cap& c, double q, const std::string& when) {
  std::string at = "the junction along edge " + std::to_string(c.edge) + " ends on " + c.faces + " at " + fmt(X(c.V));
  if (q > 0) {
    log("sweep: " + at + ", not one of its faces: end cap of " + std::to_string(c.tets.size()) + " tets and " +
        std::to_string(c.pyramids.size()) + " pyramids" + when + ", min scaled Jacobian " + std::to_string(q) +
        " (the vertex's shell node moved by " + std::to_string(c.moved) + ")");
    return;
  }
  log("sweep: " + at + ", not one of its faces; no position of the vertex's shell node makes its end cap (" +
      std::to_string(c.tets.size()) + " tets, " + std::to_string(c.pyramids.size()) + " pyramids) valid" + when + ": the prisms stay");
  if (!std::getenv("MESHFLOW_SWEEP_DEBUG")) return;
  for (auto* L : {&c.tets, &c.pyramids})
    for (auto& e : *L) {
      std::vector<double> X3;
      for (auto n : e) X3.push_back(m.x[n]), X3.push_back(m.y[n]), X3.push_back(m.z[n]);
      auto eq = model::element_quality(e.size() == 4 ? model::Shape::Tet : model::Shape::Pyramid, 1, X3.data());
      if (eq.valid) continue;
      std::string l = std::string("  invalid cap ") + (e.size() == 4 ? "tet" : "pyramid") + " (scaled Jacobian " +
                      std::to_string(eq.scaled_jacobian) + "):";
      for (auto n : e) l += " " + std::to_string(n) + fmt(X(n));
      log(l);
    }
}

// ── periodic: the hi side as the exact image of the lo side ─────────────────────────────
// A hi node gets the position transform.apply(x_lo) bit for bit (so matched nodes coincide to
// rounding after the map) and its parameters by projection onto its own CAD entity: on edges
// and vertices the hi curves are intersection curves computed independently of the lo ones
// (periodic.hpp: off by up to 4e-8 of the radius), so the node sits within that distance of its
// curve, inside the CAD tolerance.
void Builder::snap(std::uint32_t h, std::uint32_t l) {
  auto y = PM->transform.apply({m.x[l], m.y[l], m.z[l]});
  auto it = per_master.find(h);
  if (it != per_master.end()) {
    if (it->second != l)
      throw StageError("sweep: periodic node " + std::to_string(h) + " at " + fmt(X(h)) + " is the image of two lo nodes (" +
                       std::to_string(it->second) + " and " + std::to_string(l) + "); re-run periodic_match on the same heal output");
    return;
  }
  per_master[h] = l;
  m.x[h] = y[0], m.y[h] = y[1], m.z[h] = y[2];
  int dim = m.node_entity_dim[h], tag = m.node_entity_tag[h];
  if (dim == 1) {
    auto pr = S.project_to_edge(tag - 1, cad::Vec3{y[0], y[1], y[2]}, std::isnan(m.node_u[h]) ? std::optional<double>{} : m.node_u[h]);
    m.node_u[h] = pr.t;
  } else if (dim == 2) {
    auto pr = std::isnan(m.node_u[h]) ? S.project_to_face(tag - 1, cad::Vec3{y[0], y[1], y[2]})
                                      : S.project_to_face(tag - 1, cad::Vec3{y[0], y[1], y[2]}, cad::Vec2{m.node_u[h], m.node_v[h]});
    m.node_u[h] = pr.u, m.node_v[h] = pr.v;
    if (uv_on.count(h)) uv_on[h] = {pr.u, pr.v};
  }
}

// Paired edges: the same number of nodes (balance made the divisions equal; junction or slide
// cuts are placed alike on both sides), node k of hi = node k (or n-1-k, reversed) of lo.
void Builder::periodic_edges() {
  for (auto& pr : PM->vertices)
    if (pr.lo != pr.hi && vnode.at(pr.lo) != kNone && vnode.at(pr.hi) != kNone) snap(vnode[pr.hi], vnode[pr.lo]);
  for (auto& pr : PM->edges) {
    if (pr.lo == pr.hi) continue;
    const auto& a = en.at(pr.lo);
    const auto& b = en.at(pr.hi);
    if (a.size() != b.size())
      throw StageError("sweep: periodic edges " + std::to_string(pr.lo) + " (lo, " + std::to_string(a.size()) + " nodes) and " +
                       std::to_string(pr.hi) + " (hi, " + std::to_string(b.size()) +
                       " nodes) differ; balance must give them equal divisions (needs: [heal, shell] and the periodic tags)");
    for (std::size_t k = 0; k < a.size(); ++k) snap(b[pr.reversed ? b.size() - 1 - k : k], a[k]);
  }
}

// The hi face's boundary nodes are matched to the lo face's by position after the map (each lo
// node to the nearest hi node, which must be unambiguous: nearer than a third of the distance to
// the second nearest, one to one), snapped, and the lo triangulation is copied with new interior
// nodes; the triangles are reversed (the map carries lo's outward normal to hi's inward one) and
// each is checked against hi's face normal.
void Builder::copy_face(int lo, int hi, const std::vector<std::uint32_t>& hb) {
  const auto& lb = face_bnodes.at(lo);
  if (lb.size() != hb.size())
    throw StageError("sweep: periodic faces " + std::to_string(lo) + " (lo) and " + std::to_string(hi) + " (hi) have " +
                     std::to_string(lb.size()) + " and " + std::to_string(hb.size()) +
                     " boundary nodes: their edges were divided differently; re-run balance and periodic_match on the same heal output");
  std::map<std::uint32_t, std::uint32_t> P;  // lo -> hi
  std::set<std::uint32_t> used;
  // Known partners first: nodes of paired CAD edges and vertices (periodic_edges), and the shell
  // images of paired wall nodes (where a wall slides on a periodic side, e.g. the hub: its edge
  // on periodic_lo and the one on periodic_hi are paired, their nodes' images lie on the sides;
  // the thickness may differ a little between the sides, so these are matched by their wall
  // nodes and then snapped, not found by distance).
  {
    std::set<std::uint32_t> hset(hb.begin(), hb.end());
    std::map<std::uint32_t, std::uint32_t> lo_to_hi, wall_of;
    for (auto [h, l] : per_master) lo_to_hi[l] = h;
    for (auto [w, i] : image) wall_of.emplace(i, w);
    for (auto l : lb) {
      std::uint32_t h = kNone;
      if (auto it = lo_to_hi.find(l); it != lo_to_hi.end() && hset.count(it->second)) h = it->second;
      else if (auto iw = wall_of.find(l); iw != wall_of.end())
        if (auto ih = lo_to_hi.find(iw->second); ih != lo_to_hi.end())
          if (auto ii = image.find(ih->second); ii != image.end() && hset.count(ii->second)) h = ii->second;
      if (h != kNone && used.insert(h).second) P[l] = h;
    }
  }
  for (auto l : lb) {
    if (P.count(l)) continue;
    auto y = PM->transform.apply({m.x[l], m.y[l], m.z[l]});
    V3 Y{y[0], y[1], y[2]};
    double d1 = INFINITY, d2 = INFINITY;
    std::uint32_t best = kNone;
    for (auto h : hb) {
      if (used.count(h)) continue;
      double d = norm(sub(X(h), Y));
      if (d < d1) d2 = d1, d1 = d, best = h;
      else if (d < d2) d2 = d;
    }
    if (best == kNone || !(d1 < d2 / 3) || !used.insert(best).second)
      throw StageError("sweep: the boundary node " + std::to_string(l) + " of periodic_lo face " + std::to_string(lo) + " at " + fmt(X(l)) +
                       " has no unambiguous image on periodic_hi face " + std::to_string(hi) + " (nearest " + std::to_string(d1) +
                       ", next " + std::to_string(d2) + "); the two sides' boundaries differ (shell or junction asymmetric)");
    P[l] = best;
  }
  for (auto l : lb) snap(P[l], l);
  std::size_t added = 0;
  for (auto& t : face_tris.at(lo)) {
    std::array<std::uint32_t, 3> g{};
    for (int i = 0; i < 3; ++i) {
      std::uint32_t l = t[i];
      auto it = P.find(l);
      if (it == P.end()) {
        auto y = PM->transform.apply({m.x[l], m.y[l], m.z[l]});
        auto pr = S.project_to_face(hi, cad::Vec3{y[0], y[1], y[2]});
        std::uint32_t h = mk(V3{y[0], y[1], y[2]}, 2, hi + 1, pr.u, pr.v);
        per_master[h] = l;
        it = P.emplace(l, h).first;
        ++added;
      }
      g[i] = it->second;
    }
    std::swap(g[1], g[2]);
    V3 a = X(g[0]), b = X(g[1]), c = X(g[2]);
    V3 nrm = cross(sub(b, a), sub(c, a));
    V3 cen = mul(add(add(a, b), c), 1.0 / 3);
    auto pr = S.project_to_face(hi, cv(cen));
    if (dot(nrm, v3(S.face_normal(hi, pr.u, pr.v))) < 0)
      throw StageError("sweep: the image of a triangle of periodic_lo face " + std::to_string(lo) + " on periodic_hi face " +
                       std::to_string(hi) + " at " + fmt(cen) + " points into the fluid: the transform does not glue the sides");
    face_tris[hi].push_back(g);
  }
  ++R.faces_meshed;
  R.periodic_faces_copied++;
  log("sweep: periodic_hi face " + std::to_string(hi) + " = image of periodic_lo face " + std::to_string(lo) + ": " +
      std::to_string(face_tris[hi].size()) + " triangles, " + std::to_string(lb.size()) + " boundary and " + std::to_string(added) +
      " interior nodes");
}

// MSH $Periodic: one link per hi entity (face, edge, vertex) holding the pairs (hi node, lo node)
// of the nodes classified on it; the lo node must lie on the hi entity's partner.
void Builder::periodic_links() {
  std::map<std::pair<int, int>, int> master;  // (dim, hi tag) -> lo tag (mesh tags: CAD id + 1)
  for (auto& pr : PM->faces) master[{2, pr.hi + 1}] = pr.lo + 1;
  for (auto& pr : PM->edges) master[{1, pr.hi + 1}] = pr.lo + 1;
  for (auto& pr : PM->vertices) master[{0, pr.hi + 1}] = pr.lo + 1;
  std::map<std::pair<int, int>, model::PeriodicLink> links;
  double worst = 0;
  for (auto [h, l] : per_master) {
    int dim = m.node_entity_dim[h], tag = m.node_entity_tag[h];
    auto it = master.find({dim, tag});
    if (it == master.end() || it->second == tag) continue;  // not on a hi entity (e.g. a shell image on a face edge)
    if (m.node_entity_dim[l] != dim || m.node_entity_tag[l] != it->second)
      throw StageError("sweep: periodic node " + std::to_string(h) + " at " + fmt(X(h)) + " on entity (" + std::to_string(dim) + "," +
                       std::to_string(tag) + ") has its lo node on (" + std::to_string(m.node_entity_dim[l]) + "," +
                       std::to_string(m.node_entity_tag[l]) + "), not on the partner (" + std::to_string(dim) + "," +
                       std::to_string(it->second) + ")");
    auto& L = links[{dim, tag}];
    L.dim = dim, L.tag = tag, L.master_tag = it->second;
    L.affine.assign(PM->transform.affine.begin(), PM->transform.affine.end());
    L.nodes.push_back({h, l});
    auto y = PM->transform.apply({m.x[l], m.y[l], m.z[l]});
    worst = std::max(worst, std::hypot(y[0] - m.x[h], y[1] - m.y[h], y[2] - m.z[h]));
  }
  // faces, then edges, then vertices (Gmsh's order), each by tag; pairs by hi node
  for (int dim = 2; dim >= 0; --dim)
    for (auto& [k, L] : links)
      if (k.first == dim) {
        R.periodic_pairs += L.nodes.size();
        m.periodic.push_back(std::move(L));
      }
  R.periodic_max_mismatch = worst;
  R.periodic_model_size = PM->model_size;
}

void Builder::volume() {
  auto valid_or_flip = [&](model::Shape shape, std::vector<std::uint32_t>& nodes, const std::string& what) {
    if (linear_valid(shape, nodes)) return true;
    const auto& flip = flip_of(shape);
    std::vector<std::uint32_t> g(nodes.size());
    for (std::size_t i = 0; i < nodes.size(); ++i) g[i] = nodes[flip[i]];
    if (linear_valid(shape, g)) {
      nodes = g;
      return true;
    }
    V3 c{0, 0, 0};
    for (auto n : nodes) c = add(c, X(n));
    if (std::getenv("MESHFLOW_SWEEP_DEBUG"))
      for (auto n : nodes)
        log("  node " + std::to_string(n) + " " + fmt(X(n)) + " on (" + std::to_string(m.node_entity_dim[n]) + "," +
            std::to_string(m.node_entity_tag[n]) + ") u " + std::to_string(m.node_u[n]) + " v " + std::to_string(m.node_v[n]));
    throw StageError("sweep: the " + what + " at " + fmt(mul(c, 1.0 / nodes.size())) +
                     " is inverted (the shell is too close to the wall or folds there); reduce shell.thickness or "
                     "shell.max_gradient, or refine the walls (balance.max_size)");
  };
  // prisms: the wall triangle (pointing out of the fluid) reversed, then its shell image
  std::vector<std::vector<std::uint32_t>> P;
  std::vector<int> pface;
  for (int f = 0; f < nf; ++f) {
    if (!wall[f]) continue;
    for (auto& t : face_tris[f]) {
      P.push_back({t[0], t[2], t[1], shell_image(t[0], f), shell_image(t[2], f), shell_image(t[1], f)});
      pface.push_back(f);
    }
  }
  if (std::getenv("MESHFLOW_SWEEP_DEBUG")) {
    int shown = 0, bad = 0;
    for (std::size_t i = 0; i < P.size(); ++i) {
      double X3[18];
      for (int q = 0; q < 6; ++q) X3[3 * q] = m.x[P[i][q]], X3[3 * q + 1] = m.y[P[i][q]], X3[3 * q + 2] = m.z[P[i][q]];
      auto eq = model::element_quality(model::Shape::Prism, 1, X3);
      if (eq.valid) continue;
      ++bad;
      if (shown++ < 6) {
        std::string l = "invalid before untangle: prism " + std::to_string(i) + " face " + std::to_string(pface[i]) + ":";
        for (int q = 0; q < 3; ++q)
          l += " " + std::to_string(P[i][q]) + fmt(X(P[i][q])) + " uv(" + std::to_string(m.node_u[P[i][q]]) + "," +
               std::to_string(m.node_v[P[i][q]]) + ") dim " + std::to_string(m.node_entity_dim[P[i][q]]) + " -> d " +
               fmt(sub(X(P[i][q + 3]), X(P[i][q])));
        log(l);
      }
    }
    log("invalid prisms before untangle: " + std::to_string(bad) + " of " + std::to_string(P.size()));
  }
  // A wall triangle two of whose nodes are swept to one shell node has a collapsed edge, which no
  // node move repairs: the two strip corners PA and PB of a junction's end cross-section lying on
  // a third face that is no partner of that junction (sweep.hpp, "Junction ends on a third
  // face", still open; DLR-F6's pylon nose on the nacelle). Named here instead of as an inverted
  // prism after untangling.
  for (std::size_t i = 0; i < P.size(); ++i) {
    int a = -1, b = -1;
    for (int p = 0; p < 3 && a < 0; ++p)
      for (int q = p + 1; q < 3; ++q)
        if (P[i][3 + p] == P[i][3 + q]) a = p, b = q;
    if (a < 0) continue;
    std::string junction = "a junction's end cross-section";
    for (auto& j : J)
      if (std::find(j.pc.begin(), j.pc.end(), P[i][3 + a]) != j.pc.end()) {
        junction = "the end cross-section of the junction along edge " + std::to_string(j.edge) + " (faces " + std::to_string(j.A) +
                   " and " + std::to_string(j.B) + ")";
        break;
      }
    V3 c = mul(add(add(X(P[i][0]), X(P[i][1])), X(P[i][2])), 1.0 / 3);
    throw StageError("sweep: the prism on wall face " + std::to_string(pface[i]) + " at " + fmt(c) +
                     " collapses: its wall nodes at " + fmt(X(P[i][a])) + " and " + fmt(X(P[i][b])) + " are both corners of " + junction +
                     ", swept to one shell node, because that junction ends on face " + std::to_string(pface[i]) +
                     ", which is not one of its faces. Make the edges of face " + std::to_string(pface[i]) +
                     " at that end junctions too (raise shell.junction_angle_deg if they are concave, or add the tag of its "
                     "neighbour to shell.junction_with) or use shell.topology O");
  }
  // valid in either orientation (valid_or_flip below flips the others)
  auto prism_ok = [&](const std::vector<std::uint32_t>& p) { return valid_either(model::Shape::Prism, p); };
  std::vector<char> bad_before(P.size(), 0);
  for (std::size_t i = 0; i < P.size(); ++i) bad_before[i] = !prism_ok(P[i]);
  // Junction ends on a third face: the prisms there become the end cap's tets and pyramids, decided
  // before untangling (which would otherwise move and thin the cap's V' with its prisms). The
  // other prisms are untangled; a cap made invalid by that (its rim nodes' shell nodes moved) is
  // placed again, and where that fails its prisms stay (checked below like the others).
  find_caps(P, pface);
  std::vector<char> capped(P.size(), 0);
  {
    std::vector<Cap> kept;
    for (auto& c : caps) {
      V3 x0 = X(c.Vi);
      bool overlaps = false;  // with a cap made before (two junction ends on one triangle of a thin face)
      for (auto i : c.fan) overlaps = overlaps || capped[i];
      if (overlaps) {
        log("sweep: the junction along edge " + std::to_string(c.edge) + " ends on " + c.faces + " at " + fmt(X(c.V)) +
            ", not one of its faces, next to the end cap of another junction on the same prisms: no cap");
        continue;
      }
      if (double q = place_cap(c); q > 0) {
        for (auto i : c.fan) capped[i] = 1;
        kept.push_back(std::move(c));
      } else {
        log_cap(c, q, "");
        m.x[c.Vi] = x0[0], m.y[c.Vi] = x0[1], m.z[c.Vi] = x0[2];
      }
    }
    caps = std::move(kept);
  }
  std::vector<std::vector<std::uint32_t>> Pu;
  for (std::size_t i = 0; i < P.size(); ++i)
    if (!capped[i]) Pu.push_back(P[i]);
  untangle(Pu);  // reads the prisms' nodes, moves shell nodes
  std::vector<std::vector<std::uint32_t>> cap_tets, cap_pyramids;
  for (auto& c : caps) {
    double q = cap_quality(c);
    std::string when = "";
    if (!(q > 0)) q = place_cap(c), when = " (placed again after untangling)";
    log_cap(c, q, when);
    if (!(q > 0)) {
      for (auto i : c.fan) capped[i] = 0;
      continue;
    }
    cap_tets.insert(cap_tets.end(), c.tets.begin(), c.tets.end());
    cap_pyramids.insert(cap_pyramids.end(), c.pyramids.begin(), c.pyramids.end());
    ++R.end_caps;
  }
  std::vector<std::size_t> bad_after;
  for (std::size_t i = 0; i < P.size(); ++i)
    if (!capped[i] && !prism_ok(P[i])) bad_after.push_back(i);
  if (std::getenv("MESHFLOW_SWEEP_DEBUG")) {
    for (auto i : bad_after) {
      std::string l = "invalid after untangle: face " + std::to_string(pface[i]) + ":";
      for (int c = 0; c < 3; ++c) {
        auto w = P[i][c];
        bool fixed = false;
        for (auto& j : J) fixed = fixed || std::find(j.pc.begin(), j.pc.end(), P[i][c + 3]) != j.pc.end();
        l += " (" + std::to_string(m.node_entity_dim[w]) + "," + std::to_string(m.node_entity_tag[w]) + " uv " + std::to_string(m.node_u[w]) + "," +
             std::to_string(m.node_v[w]) + (fixed ? " PC" : "") + " t " + std::to_string(norm(sub(X(P[i][c + 3]), X(w)))) + ")";
      }
      log(l);
    }
    log("invalid prisms after untangle: " + std::to_string(bad_after.size()));
  }
  if (!bad_after.empty()) {
    // the capped prisms are tets and pyramids now: counted apart
    std::size_t n_capped = 0, n_capped_bad = 0;
    for (std::size_t i = 0; i < P.size(); ++i)
      if (capped[i]) ++n_capped, n_capped_bad += bad_before[i], bad_before[i] = 0;
    std::string msg = untangle_failure(P, pface, bad_before, bad_after);
    if (R.end_caps)
      msg += ". Not counted: the " + std::to_string(n_capped) + " prisms (" + std::to_string(n_capped_bad) +
             " inverted before untangling) at the " + std::to_string(R.end_caps) +
             " junction ends on a third face that end caps replace (valid tets and pyramids)";
    throw StageError(msg);
  }
  {
    // the outer surface without the capped prisms (their tets and pyramids are not moved)
    std::vector<std::vector<std::uint32_t>> live;
    std::set<std::uint32_t> frozen;
    for (std::size_t i = 0; i < P.size(); ++i)
      if (!capped[i]) live.push_back(P[i]);
    for (auto& c : caps) {
      for (auto& t : c.tets) frozen.insert(t.begin(), t.end());
      for (auto& y : c.pyramids) frozen.insert(y.begin(), y.end());
    }
    clear_crossings(live, frozen);
  }
  auto& prisms = m.block(model::Shape::Prism, 1, 3, 1);
  for (std::size_t i = 0; i < P.size(); ++i) {
    if (capped[i]) continue;
    valid_or_flip(model::Shape::Prism, P[i], "prism on wall face " + std::to_string(pface[i]));
    prisms.add(P[i].data());
    ++R.prisms;
  }
  if (prisms.size() == 0) m.blocks.pop_back();
  if (!cap_tets.empty()) {  // oriented by find_caps
    auto& tb = m.block(model::Shape::Tet, 1, 3, 1);
    for (auto& t : cap_tets) tb.add(t.data());
    auto& pb = m.block(model::Shape::Pyramid, 1, 3, 1);
    for (auto& q : cap_pyramids) pb.add(q.data());
    R.cap_tets += cap_tets.size(), R.cap_pyramids += cap_pyramids.size();
  }
  for (auto& j : J) {
    std::size_t n = j.p0.size();
    for (std::size_t k = 0; k + 1 < n; ++k) {
      std::vector<std::uint32_t> h = junction_hex(j, k);
      valid_or_flip(model::Shape::Hex, h, "junction hex of edge " + std::to_string(j.edge));
      m.block(model::Shape::Hex, 1, 3, 1).add(h.data());
      ++R.hexes;
      face_quads[j.A].push_back({j.p0[k], j.p0[k + 1], j.pa[k + 1], j.pa[k]});
      face_quads[j.B].push_back({j.p0[k], j.p0[k + 1], j.pb[k + 1], j.pb[k]});
      R.strip_quads += 2;
    }
  }
  for (int e = 0; e < ne; ++e) {
    if (slide_other[e] < 0) continue;
    for (std::size_t k = 0; k + 1 < en[e].size(); ++k) {
      std::uint32_t a = en[e][k], b = en[e][k + 1];
      face_quads[slide_other[e]].push_back({a, b, image.at(b), image.at(a)});
      ++R.slide_quads;
    }
  }
}

// The message when untangling leaves inverted prisms. Untangling smooths directions over the
// neighbours of inverted prisms and thins the layer where they stay inverted, so the prisms
// still inverted at its end may be valid ones it moved (DLR-F6 at junction_angle_deg 170: the
// nacelle's face 0, while those inverted before were on other faces). The message names the
// prisms inverted before untangling first (by face; the caller leaves out those replaced by end
// caps), and the first of them, and says when one of its wall nodes is a strip corner (PA or PB)
// of the end cross-section of a junction that ends on that prism's face without it being one of
// the junction's faces (that node is swept to the junction's outer corner PC, across the face:
// sweep.hpp, "Junction ends on a third face", where no end cap could replace those prisms).
std::string Builder::untangle_failure(const std::vector<std::vector<std::uint32_t>>& P, const std::vector<int>& pface,
                                      const std::vector<char>& bad_before, const std::vector<std::size_t>& bad_after) {
  auto by_face = [&](const std::vector<std::size_t>& list) {
    std::map<int, int> n;
    for (auto i : list) ++n[pface[i]];
    std::string s;
    for (auto [f, c] : n) s += (s.empty() ? "" : ", ") + std::to_string(f) + " (" + std::to_string(c) + ")";
    return s;
  };
  std::vector<std::size_t> before;
  for (std::size_t i = 0; i < P.size(); ++i)
    if (bad_before[i]) before.push_back(i);
  std::size_t first = bad_after.front();
  for (auto i : bad_after)
    if (bad_before[i]) {
      first = i;
      break;
    }
  bool moved_only = !bad_before[first];
  if (moved_only && !before.empty()) first = before.front();
  auto centre = [&](std::size_t i) { return mul(add(add(X(P[i][0]), X(P[i][1])), X(P[i][2])), 1.0 / 3); };
  int F = pface[first];
  std::string msg = "sweep: " + std::to_string(bad_after.size()) + " of " + std::to_string(P.size()) +
                    " prisms stay inverted after untangling the layer, on wall faces " + by_face(bad_after) + "; " +
                    std::to_string(before.size()) + " were inverted before it" +
                    (before.empty() ? std::string() : ", on wall faces " + by_face(before));
  if (moved_only) msg += " (those inverted at the end were valid before: untangling moved them)";
  // wall node -> a junction whose end cross-section has it as a strip corner (PA or PB)
  std::map<std::uint32_t, std::vector<const Junction*>> corner_of;
  for (auto& j : J)
    for (std::size_t k : {std::size_t(0), j.pa.size() - 1}) corner_of[j.pa[k]].push_back(&j), corner_of[j.pb[k]].push_back(&j);
  // the first wall node of prism i that is a strip corner of junction ends on the prism's face
  // without the face being one of those junctions' faces, and the first such junction (null if
  // none). A corner shared by the ends of two junctions one of which has the face (DLR-F6's
  // junctions along edges 159 and 182, faces 35 | 46 and 46 | 53, at their common vertex) is not
  // foreign to it.
  auto foreign_end = [&](std::size_t i) -> std::pair<std::uint32_t, const Junction*> {
    for (int c = 0; c < 3; ++c) {
      auto it = corner_of.find(P[i][c]);
      if (it == corner_of.end()) continue;
      bool own = false;
      for (auto* j : it->second) own = own || pface[i] == j->A || pface[i] == j->B;
      if (!own) return {P[i][c], it->second.front()};
    }
    return {0, nullptr};
  };
  std::size_t n_foreign = 0;
  for (auto i : before) n_foreign += foreign_end(i).second ? 1 : 0;
  if (n_foreign)
    msg += "; " + std::to_string(n_foreign) + " of those " + std::to_string(before.size()) +
           " have a wall node that is a strip corner of a junction ending on their face, which is not one of its faces";
  msg += ". First inverted before untangling: the prism on wall face " + std::to_string(F) + " at " + fmt(centre(first));
  std::string hint;
  if (auto [w, j] = foreign_end(first); j)
    hint = ": its wall node at " + fmt(X(w)) + " is a strip corner of the end cross-section of the junction along edge " +
           std::to_string(j->edge) + " (faces " + std::to_string(j->A) + " and " + std::to_string(j->B) +
           "), swept to that junction's outer corner, because the junction ends on face " + std::to_string(F) +
           ", which is not one of its faces and no end cap could replace the prisms there (sweep.hpp, \"Junction ends on a third face\"). Make the edges of face " + std::to_string(F) +
           " at that end junctions too (shell.junction_angle_deg, shell.junction_with), or use shell.topology O";
  else
    hint = " (the shell is too close to the wall or folds there); reduce shell.thickness or shell.max_gradient, or refine the "
           "walls (balance.max_size)";
  return msg + hint;
}

model::Mesh Builder::run() {
  auto t0 = std::chrono::steady_clock::now();
  nf = S.num_faces(), ne = S.num_edges(), nv = S.num_vertices();
  wall.assign(nf, 0);
  for (int f : S.faces_with_tag(cad::Tag::wall)) wall[f] = 1;
  vnode.assign(nv, kNone);
  et.assign(ne, {});
  en.assign(ne, {});
  cuts.assign(ne, {});
  junction_of.assign(ne, -1);
  slide_other.assign(ne, -1);
  slide_wall.assign(ne, -1);
  face_tris.assign(nf, {});
  face_quads.assign(nf, {});
  face_bnodes.assign(nf, {});

  nlohmann::json H = nlohmann::json::parse(SH.header);
  for (auto& b : H.at("blocks")) {
    if (b.at("kind") != "hex_junction") continue;
    Junction j;
    j.edge = b.at("edge"), j.A = b.at("face"), j.B = b.at("partner");
    j.vertices = {b.at("vertices").at(0).get<int>(), b.at("vertices").at(1).get<int>()};
    for (auto& s : b.at("stations"))
      j.st.push_back({s.at("t").get<double>(), jv3(s.at("P0")), jv3(s.at("PA")), jv3(s.at("PB")), jv3(s.at("PC")),
                      {s.at("uvA").at(0).get<double>(), s.at("uvA").at(1).get<double>()},
                      {s.at("uvB").at(0).get<double>(), s.at("uvB").at(1).get<double>()}});
    if (j.st.empty()) throw StageError("sweep: junction block of edge " + std::to_string(j.edge) + " has no stations; re-run shell");
    junction_of[j.edge] = static_cast<int>(J.size());
    J.push_back(std::move(j));
  }
  R.junction_blocks = J.size();
  for (int e = 0; e < ne; ++e) {
    if (S.edge_degenerate(e) || junction_of[e] >= 0) continue;
    auto fs = S.edge_faces(e);
    int w = -1, o = -1, nw = 0;
    for (int f : fs) {
      if (wall[f]) ++nw, w = f;
      else o = f;
    }
    if (nw == 1 && o >= 0 && fs.size() == 2) slide_other[e] = o, slide_wall[e] = w;
  }
  log("sweep: " + std::to_string(J.size()) + " junction blocks");
  // junction node arrays sized from the wall divisions
  for (auto& j : J) {
    auto* d = DV.find("w" + std::to_string(j.edge));
    if (!d) throw StageError("sweep: the divisions have no entry w" + std::to_string(j.edge) + " for the junction edge; re-run balance");
    std::size_t n = d->nodes.size();
    j.p0.assign(n, kNone), j.pa.assign(n, kNone), j.pb.assign(n, kNone), j.pc.assign(n, kNone);
  }
  junction_ends();
  slide_ends();
  build_edges();
  build_junction_curves();
  build_slides();
  auto ts = std::chrono::steady_clock::now();
  if (!PM) {
    for (int f = 0; f < nf; ++f) mesh_face(f);
  } else {
    // the lo sides and every other face first, then each periodic_hi face as the image of its lo
    // partner (periodic.hpp: nodes at transform.apply(x), parameters by projection)
    std::vector<int> lo_of(nf, -1);
    for (auto& pr : PM->faces)
      if (pr.lo != pr.hi) lo_of.at(pr.hi) = pr.lo;
    periodic_edges();
    for (int f = 0; f < nf; ++f)
      if (lo_of[f] < 0) mesh_face(f);
    for (int f = 0; f < nf; ++f)
      if (lo_of[f] >= 0) mesh_face(f, lo_of[f]);
  }
  R.surface_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - ts).count();
  volume();
  // boundary elements, lines, entities, physical groups
  std::set<int> phys_used;
  for (int f = 0; f < nf; ++f) {
    int p = tag_physical(S.face_tag(f));
    if (p) phys_used.insert(p);
    m.add_entity(2, f + 1, p ? std::vector<int>{p} : std::vector<int>{});
    if (!face_tris[f].empty()) {
      auto& b = m.block(model::Shape::Tri, 1, 2, f + 1);
      for (auto& t : face_tris[f]) b.add({t[0], t[1], t[2]});
      (wall[f] ? R.wall_triangles : R.boundary_triangles) += face_tris[f].size();
    }
    if (!face_quads[f].empty()) {
      auto& b = m.block(model::Shape::Quad, 1, 2, f + 1);
      for (auto& q : face_quads[f]) b.add({q[0], q[1], q[2], q[3]});
    }
  }
  for (int e = 0; e < ne; ++e) {
    if (en[e].size() < 2) continue;
    m.add_entity(1, e + 1);
    auto& b = m.block(model::Shape::Line, 1, 1, e + 1);
    for (std::size_t k = 0; k + 1 < en[e].size(); ++k) b.add({en[e][k], en[e][k + 1]});
  }
  for (int V = 0; V < nv; ++V)
    if (vnode[V] != kNone) m.add_entity(0, V + 1);
  m.add_entity(3, 1, {fluid});
  static const char* names[] = {"", "wall", "farfield", "symmetry", "periodic_lo", "periodic_hi"};
  for (int p : phys_used) m.add_physical(2, p, names[p]);
  m.add_physical(3, fluid, "fluid");
  // blocks in a canonical order: volume first, then faces, then lines (by entity)
  std::stable_sort(m.blocks.begin(), m.blocks.end(), [](const model::ElementBlock& a, const model::ElementBlock& b) {
    if (a.entity_dim != b.entity_dim) return a.entity_dim > b.entity_dim;
    if (a.entity_tag != b.entity_tag) return a.entity_tag < b.entity_tag;
    return static_cast<int>(a.shape) < static_cast<int>(b.shape);
  });
  if (PM) periodic_links();
  R.nodes = m.num_nodes();
  R.total_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return std::move(m);
}

}  // namespace

nlohmann::json Report::to_json() const {
  return {{"wall_triangles", wall_triangles}, {"strip_quads", strip_quads},   {"slide_quads", slide_quads},
          {"boundary_triangles", boundary_triangles}, {"prisms", prisms},     {"hexes", hexes},
          {"junction_blocks", junction_blocks},     {"edges_cut", edges_cut}, {"thinned", thinned}, {"placed", placed}, {"nodes", nodes},
          {"outer_crossings_before", outer_crossings_before}, {"outer_crossings", outer_crossings},
          {"crossing_nodes_thinned", crossing_nodes_thinned}, {"crossing_min_scale", crossing_min_scale},
          {"faces_meshed", faces_meshed},           {"surface_seconds", surface_seconds},
          {"periodic_faces_copied", periodic_faces_copied}, {"periodic_pairs", periodic_pairs},
          {"periodic_max_mismatch", periodic_max_mismatch},
          {"periodic_max_mismatch_rel", periodic_model_size > 0 ? periodic_max_mismatch / periodic_model_size : 0.0},
          {"end_caps", end_caps}, {"cap_tets", cap_tets}, {"cap_pyramids", cap_pyramids},
          {"total_seconds", total_seconds}};
}

model::Mesh sweep_mesh(const cad::Shape& shape, const shell::ShellData& shell, const balance::Divisions& div,
                       const Options& opt, Report& report, const std::function<void(const std::string&)>& log,
                       const periodic::Match* match) {
  Builder b(shape, shell, div, opt, report, log, match);
  return b.run();
}

}  // namespace meshflow::sweep
