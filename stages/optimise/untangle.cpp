// Untangling of invalid curved elements by local volume optimisation (untangle.hpp).
// Libraries: LBFGSpp (L-BFGS), Eigen (its vectors), TBB only through model::mesh_quality.
#include "stages/optimise/untangle.hpp"

#include "stages/cad/cad.hpp"
#include "stages/model/basis.hpp"
#include "stages/model/element.hpp"
#include "stages/model/quality.hpp"

#include <Eigen/Core>
#include <Eigen/Eigenvalues>
#include <Eigen/LU>
#include <Eigen/SparseCholesky>
#include <Eigen/SparseCore>
#include <LBFGS.h>
#include <nlohmann/json.hpp>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>
#include <tbb/task_group.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <functional>
#include <string>
#include <cmath>
#include <map>
#include <mutex>
#include <tuple>
#include <numeric>
#include <stdexcept>
#include <utility>
#include <vector>

namespace meshflow::optimise {

using model::Mesh;
using model::Shape;

nlohmann::json UntangleReport::to_json() const {
  return {{"invalid", {{"before", invalid_before}, {"after", invalid_after}}},
          {"attempts", attempts},
          {"repaired", repaired},
          {"repaired_at_ring", repaired_at_ring},
          {"skipped_in_failed_patch", skipped},
          {"stuck_attempts", stuck},
          {"early_exits", early_exits},
          {"below_floor_retries", below_floor},
          {"nodes_moved", nodes_moved},
          {"surface_nodes_moved", surface_nodes_moved},
          {"repaired_sliding_on_cad", repaired_sliding},
          {"folded_wall_faces", folded_wall},
          {"lift", {{"computed", lifts}, {"repaired", repaired_by_lift}, {"started_from", lift_starts}}},
          {"max_move_relative", max_move},
          {"work", {{"jacobian_samples", work}, {"max_per_element", max_element_work}, {"repairs", repair_work}}},
          {"budget", {{"elements_exhausted", budget_exhausted}, {"no_progress_stop", stage_budget_exhausted},
                      {"time_limit_fired", time_limit_fired}}},
          {"unrepaired", [&] {
             nlohmann::json l = nlohmann::json::array();
             for (const auto& u : unrepaired)
               l.push_back({{"tag", u.tag}, {"centroid", {u.centroid[0], u.centroid[1], u.centroid[2]}}, {"reason", u.reason}});
             return nlohmann::json{{"count", invalid_after}, {"by_reason", unrepaired_by_reason}, {"listed", l}, {"advice", advice()}};
           }()},
          {"seconds", seconds}};
}

std::string UntangleReport::advice() const {
  if (invalid_after == 0) return "";
  auto n = [&](const char* r) {
    auto it = unrepaired_by_reason.find(r);
    return it == unrepaired_by_reason.end() ? std::size_t(0) : it->second;
  };
  std::string a;
  if (n("degenerate"))
    a += "Some straight (linear) elements there have no volume: the linear mesh is degenerate at those points; fix the "
         "stage that made them (sweep/shell: a finer or thinner shell, another shell topology) - no node move can repair "
         "them. ";
  if (n("stuck") + n("not repaired") + n("in a failed patch") + n("no free nodes"))
    a += "Curving folds these elements further than the free high-order nodes around them can absorb: make the "
         "elements there smaller or thinner (a finer surface mesh or a thinner shell near the listed points), lower "
         "curve.order, or let optimise use bigger patches (untangle_rings, at most 6). ";
  if (n("budget") + n("no progress"))
    a += "The untangling budget ran out (untangle_element_budget per element, untangle_budget of work without a repair for the stage): raising "
         "them may repair more, at the cost of time; it rarely helps elements reported as stuck. ";
  if (n("time limit"))
    a += "The safety-net time limit (untangle_time_limit) stopped the untangling: this result depends on the machine's "
         "speed. ";
  if (!a.empty()) a.pop_back();
  return a;
}

namespace {

struct ElemRef {
  std::uint32_t block = 0;
  std::uint32_t index = 0;
  bool operator<(const ElemRef& o) const { return block != o.block ? block < o.block : index < o.index; }
  bool operator==(const ElemRef& o) const { return block == o.block && index == o.index; }
};

// Basis gradients dN_a,c(s) at the sample points of one (shape, order), n nodes, ns samples, in
// the two orders the patch energy reads them (sample_jacobians, gradient_terms): by node and
// direction, samples contiguous (Dacs[(3 a + c) ns + s]), and by sample and direction, nodes
// contiguous (Dsca[(3 s + c) n + a]). For the Bezier lattice (tets, prisms), also the transform of
// det J's values at the points to its Bernstein coefficients: T (tets), or Ta (triangle) x Tb
// (line) for prisms, the points ordered s = i * nb + j (triangle point i, line point j).
struct SampleTable {
  int n = 0, ns = 0;
  std::vector<double> Dacs, Dsca;
  Eigen::MatrixXd T, Ta, Tb;
};

// The sample lattices: 0 = order P + 2 (a P=4 tet: 84 points, prism: 28 x 7 = 196); 1 (a second
// attempt) = order max(P + 2, 3 (P - 1)) (the degree of det J on a tet; a P=4 tet: 220 points),
// capped at the model's order limit; 2 (a third attempt, tets and prisms) = the lattice of det
// J's Bernstein coefficients (tet: degree 3 (P - 1); prism: 3P - 2 on the triangle x 3P - 1
// along the layer, 66 x 12 points at P=4): the penalty then acts on the coefficients, whose
// positivity proves validity, so a dip of det J between samples is seen. Other shapes: 1.
// The samples only steer the optimisation; validity is decided by the Bezier bounds afterwards.
constexpr int kMaxBezierDegree = 16;
// A straight element whose det J is below this times its longest vertex edge cubed is
// degenerate for the untangler (a regular tet: 0.7; a boundary-layer prism of aspect ratio
// 1e4: about 1e-8 to 1e-4 with its longest edge).
constexpr double kMinRelativeVolume = 1e-9;
// Early exit of the second and third attempts: a point is acceptable when every element that must
// be valid is, at a scaled Jacobian of at least this (or its own before, if lower and it was valid).
constexpr double kEarlyExitFloor = 0.05;
bool has_bezier_lattice(Shape s, int P) {
  return (s == Shape::Tet && 3 * (P - 1) <= kMaxBezierDegree) || (s == Shape::Prism && 3 * P - 1 <= kMaxBezierDegree);
}
int sample_order(int P, int lattice) { return std::min(model::kMaxOrder, lattice >= 1 ? std::max(P + 2, 3 * (P - 1)) : P + 2); }

double factorial(int k) {
  double f = 1;
  for (int i = 2; i <= k; ++i) f *= i;
  return f;
}

// Values at the equispaced lattice of a degree-d simplex (dimension 1, 2 or 3, coordinates in
// [0,1]) -> Bernstein coefficients: the inverse of the Bernstein collocation matrix. Written here
// because the model's own transforms are internal to its validity check.
Eigen::MatrixXd simplex_bezier_transform(const std::vector<std::array<int, 3>>& lat, int dim, int d) {
  const int n = int(lat.size());
  Eigen::MatrixXd M(n, n);
  for (int q = 0; q < n; ++q) {
    double l[4] = {1, 0, 0, 0};
    for (int c = 0; c < dim; ++c) l[c + 1] = double(lat[q][c]) / d, l[0] -= l[c + 1];
    for (int a = 0; a < n; ++a) {
      int e[4] = {d, 0, 0, 0};
      for (int c = 0; c < dim; ++c) e[c + 1] = lat[a][c], e[0] -= lat[a][c];
      double v = factorial(d);
      for (int c = 0; c <= dim; ++c) v *= std::pow(l[c], e[c]) / factorial(e[c]);
      M(q, a) = v;
    }
  }
  return M.fullPivLu().inverse();
}

std::vector<std::array<int, 3>> simplex_lattice(int dim, int d) {
  std::vector<std::array<int, 3>> lat;
  for (int i = 0; i <= d; ++i)
    for (int j = 0; j <= (dim >= 2 ? d - i : 0); ++j)
      for (int k = 0; k <= (dim >= 3 ? d - i - j : 0); ++k) lat.push_back({i, j, k});
  return lat;
}

const SampleTable& samples(Shape s, int order, int lattice) {
  static std::mutex mutex;
  static std::map<std::tuple<int, int, int>, SampleTable> cache;  // entries never move once made
  std::lock_guard<std::mutex> lock(mutex);
  if (lattice == 2 && !has_bezier_lattice(s, order)) lattice = 1;
  auto key = std::make_tuple(int(s), order, lattice);
  auto it = cache.find(key);
  if (it != cache.end()) return it->second;
  const auto& b = model::LagrangeBasis::get(s, order);
  std::vector<model::Vec3> pts;
  SampleTable t;
  if (lattice == 2 && s == Shape::Tet) {
    const int d = 3 * (order - 1);
    const auto lat = simplex_lattice(3, d);
    for (const auto& l : lat) pts.push_back({double(l[0]) / d, double(l[1]) / d, double(l[2]) / d});
    t.T = simplex_bezier_transform(lat, 3, d);
  } else if (lattice == 2) {  // prism: triangle x line
    const int da = 3 * order - 2, db = 3 * order - 1;
    const auto la = simplex_lattice(2, da), lb = simplex_lattice(1, db);
    for (const auto& i : la)
      for (const auto& j : lb) pts.push_back({double(i[0]) / da, double(i[1]) / da, -1 + 2 * double(j[0]) / db});
    t.Ta = simplex_bezier_transform(la, 2, da);
    t.Tb = simplex_bezier_transform(lb, 1, db);
  } else {
    pts = model::reference_nodes(s, sample_order(order, lattice));
  }
  t.n = b.size();
  t.ns = int(pts.size());
  std::vector<double> dN(3 * std::size_t(t.n));  // at one sample: dN[3 a + c]
  t.Dacs.resize(std::size_t(t.ns) * t.n * 3), t.Dsca.resize(t.Dacs.size());
  for (int k = 0; k < t.ns; ++k) {
    b.grad(pts[k], dN.data());
    for (int a = 0; a < t.n; ++a)
      for (int c = 0; c < 3; ++c) {
        t.Dacs[(3 * std::size_t(a) + c) * t.ns + k] = dN[3 * std::size_t(a) + c];
        t.Dsca[(3 * std::size_t(k) + c) * t.n + a] = dN[3 * std::size_t(a) + c];
      }
  }
  return cache.emplace(key, std::move(t)).first->second;
}

// The patch energy's two products, written out instead of Eigen's general matrix products: those
// packed the constant gradient table into blocks again at every call (19% of the untangling time
// on DLR-F6, the multiplication itself 49%), and their summation order follows the blocking.
// Here each sum runs in one fixed order whatever the vector width, so the AVX2 and baseline
// clones (target_clones, as model's tensor_jacobians) give the same bits and the untangling
// stays deterministic across machines.
//
// J of every sample: Jc[(3 c + r) ns + s] = dx_r / dxi_c at sample s = sum over the nodes a, in
// order, of X[3 a + r] dN_a,c(s); X: node coordinates, 3 per node. In blocks of samples, so that
// the block's sums stay in the first-level cache while the table streams by once.
__attribute__((target_clones("avx2", "default"))) void sample_jacobians(const SampleTable& t, const double* X, double* Jc) {
  constexpr int kBlock = 64;
  const int ns = t.ns, n = t.n;
  std::fill(Jc, Jc + 9 * std::size_t(ns), 0.0);
  for (int s0 = 0; s0 < ns; s0 += kBlock) {
    const int len = std::min(kBlock, ns - s0);
    for (int a = 0; a < n; ++a)
      for (int c = 0; c < 3; ++c) {
        const double* d = &t.Dacs[(3 * std::size_t(a) + c) * ns + s0];
        for (int r = 0; r < 3; ++r) {
          const double x = X[3 * a + r];
          double* j = Jc + std::size_t(3 * c + r) * ns + s0;
          for (int s = 0; s < len; ++s) j[s] += d[s] * x;
        }
      }
  }
}

// The gradient over the nodes of sum_s k_s det J_s: G[r n + a] = sum over the samples s with
// k_s != 0, in order, and the directions c of dN_a,c(s) k_s cof(J_s)(r, c); Cof: 9 per sample,
// cof(J)(r, c) at 3 r + c.
__attribute__((target_clones("avx2", "default"))) void gradient_terms(const SampleTable& t, const double* k, const double* Cof,
                                                                       double* G) {
  const int ns = t.ns, n = t.n;
  std::fill(G, G + 3 * std::size_t(n), 0.0);
  double* G0 = G;
  double* G1 = G + n;
  double* G2 = G + 2 * n;
  for (int s = 0; s < ns; ++s) {
    if (k[s] == 0) continue;
    const double* C = &Cof[9 * std::size_t(s)];
    for (int c = 0; c < 3; ++c) {
      const double m0 = k[s] * C[c], m1 = k[s] * C[3 + c], m2 = k[s] * C[6 + c];
      const double* d = &t.Dsca[(3 * std::size_t(s) + c) * n];
      for (int a = 0; a < n; ++a) {
        G0[a] += d[a] * m0;
        G1[a] += d[a] * m1;
        G2[a] += d[a] * m2;
      }
    }
  }
}

// The untangler's budgets ("budget" in untangle.hpp): work in Jacobian evaluations at sample
// points, counted before each energy evaluation; OutOfBudget is thrown out of the minimiser
// when an evaluation would exceed the element's budget or the time limit (so the counts, and
// the result, do not depend on timing, except for the time limit). The no-progress budget
// (stage_used, reset by each repair) is checked between elements, so an element once started
// has its whole element budget and a costly repair is not cut off by the failures before it.
// Thrown out of the minimiser by an evaluation whose point already passes the patch's acceptance
// test (early exit, "Patch::check_every"): y is that point.
struct AcceptedPoint {
  Eigen::VectorXd y;
};
struct OutOfBudget {
  enum Which { element, time } which;
};
// One invalid element's budget (each element is tried by one task, "parallel" in untangle.hpp):
// its work and its limit, the stage's start and time limit, and a progress tick.
struct Budget {
  double element_used = 0, element_limit = 0;
  double time_limit = 0;
  std::chrono::steady_clock::time_point t0, last_tick;
  std::function<void()> tick;  // progress, about every second (thread-safe)
  void charge(double cost) {
    if (element_limit > 0 && element_used + cost > element_limit) throw OutOfBudget{OutOfBudget::element};
    const auto now = std::chrono::steady_clock::now();
    if (time_limit > 0 && std::chrono::duration<double>(now - t0).count() > time_limit) throw OutOfBudget{OutOfBudget::time};
    element_used += cost;
    if (tick && now - last_tick > std::chrono::seconds(1)) {
      last_tick = now;
      tick();
    }
  }
};

// The stage's no-progress accounting, kept in the order of the invalid elements whatever order
// they ran in: stage_used is the work since the last repair, repair_work the work of the
// elements repaired so far (each one's whole work), total all work.
struct StageBudget {
  double stage_used = 0, stage_limit = 0, element_limit = 0, repair_work = 0, total = 0;
  // The no-progress limit. A stage that repaired nothing stops after stage_limit (a hopeless
  // mesh fails fast). Once it has repaired, one element that uses up its element budget does not
  // stop it alone, nor does a run of failures costing less than the repairs so far: the limit is
  // one element_limit more than the larger of stage_limit and the repairs' work (Rotor 67: one element
  // gave up on its 200 M budget after 84 repairs, which passed the 40 M stage_limit and left 171
  // of 297 untried, most of them repairable). Every repair charges work, so repair_work > 0
  // once there has been one.
  double no_progress_limit() const {
    if (!(repair_work > 0)) return stage_limit;
    return std::max(stage_limit, repair_work) + std::max(element_limit, 0.0);
  }
  bool exhausted() const { return stage_limit > 0 && stage_used >= no_progress_limit(); }
};

double det3(const double J[9]) {
  return J[0] * (J[4] * J[8] - J[5] * J[7]) - J[1] * (J[3] * J[8] - J[5] * J[6]) + J[2] * (J[3] * J[7] - J[4] * J[6]);
}

// The patch problem: free nodes, objective elements, their straight reference det J.
// A free node is either a volume node (3 variables: (x - x0) / h) or a node inside a CAD face
// (2 variables: (u - u0) / su, (v - v0) / sv with su = h / |S_u|, so a unit step moves it by
// about h; x = S(u, v), gradient by the chain rule with the face's derivatives).
struct Patch {
  const Mesh& m;
  const cad::Shape* shape = nullptr;
  std::vector<std::uint32_t> free;          // node indices
  std::map<std::uint32_t, int> free_index;  // node -> position in free
  std::vector<ElemRef> elems;               // elements with at least one free node
  std::vector<std::vector<int>> slots;      // per element and local node: position in free, or -1
  std::vector<double> jref;                 // straight det J per element
  std::vector<double> x0;                   // 3 * free.size()
  // per free node: first variable, face (-1: volume node), start parameters and scales, bounds
  std::vector<int> var, face;
  std::vector<double> uv0, scale, lo, hi;   // 2 per free node (unused for volume nodes)
  int nvars = 0;
  double h = 1, target = 0.2, spring = 1e-3;
  int lattice = 0;  // sample lattice (sample_order)
  Budget* budget = nullptr;  // charged per evaluation when set
  // Early exit: every check_every-th evaluation (0: never) tests the point with the Bezier bounds;
  // when it passes the acceptance test (each element with must_valid valid at a scaled Jacobian of
  // at least sj_floor, none below worst_before), AcceptedPoint is thrown. The count of evaluations
  // is deterministic, so is the point.
  int check_every = 0;
  mutable int evaluations = 0;
  std::vector<char> must_valid;   // per element of elems
  std::vector<double> sj_floor;   // per element of elems, when must_valid
  double worst_before = -INFINITY;
  // The elements' energy terms and gradient contributions are computed in parallel (arena),
  // each element into its own buffers, then summed in element order: the same additions in the
  // same order as one thread, so the result is bit-identical at any thread count.
  tbb::task_arena* arena = nullptr;
  mutable std::vector<std::vector<double>> eterms;                 // per element: energy terms, in order
  mutable std::vector<std::vector<std::pair<int, double>>> gterms;  // per element: (index in gx, term), in order

  explicit Patch(const Mesh& mesh) : m(mesh) {}

  // Parameters of surface node i at y, clamped to the face's parameter bounds (clamped[c] set
  // where a bound is active, so its gradient component is dropped).
  void params(std::size_t i, const Eigen::VectorXd& y, double p[2], bool clamped[2]) const {
    for (int c = 0; c < 2; ++c) {
      p[c] = uv0[2 * i + c] + scale[2 * i + c] * y[var[i] + c];
      clamped[c] = false;
      if (p[c] < lo[2 * i + c]) p[c] = lo[2 * i + c], clamped[c] = true;
      if (p[c] > hi[2 * i + c]) p[c] = hi[2 * i + c], clamped[c] = true;
    }
  }

  // Energy and gradient at y.
  double operator()(const Eigen::VectorXd& y, Eigen::VectorXd& g) const {
    if (budget) {
      double cost = 0;
      for (const ElemRef& r : elems) cost += samples(m.blocks[r.block].shape, m.blocks[r.block].order, lattice).ns;
      budget->charge(cost);
    }
    g.setZero(y.size());
    double E = 0;
    // positions of the free nodes (and the face derivatives of the surface nodes)
    std::vector<double> xf(3 * free.size()), gx(3 * free.size(), 0.0), du(3 * free.size()), dv(3 * free.size());
    std::vector<char> clamp(2 * free.size(), 0);
    for (std::size_t i = 0; i < free.size(); ++i) {
      if (face[i] < 0) {
        for (int c = 0; c < 3; ++c) xf[3 * i + c] = x0[3 * i + c] + h * y[var[i] + c];
        continue;
      }
      double p[2];
      bool cl[2];
      params(i, y, p, cl);
      clamp[2 * i] = cl[0], clamp[2 * i + 1] = cl[1];
      const auto d = shape->face_eval(face[i], p[0], p[1]);
      xf[3 * i] = d.p.x, xf[3 * i + 1] = d.p.y, xf[3 * i + 2] = d.p.z;
      du[3 * i] = d.du.x, du[3 * i + 1] = d.du.y, du[3 * i + 2] = d.du.z;
      dv[3 * i] = d.dv.x, dv[3 * i + 1] = d.dv.y, dv[3 * i + 2] = d.dv.z;
    }
    eterms.resize(elems.size());
    gterms.resize(elems.size());
    auto element = [&](std::size_t ie) {
      std::vector<double>& Et = eterms[ie];
      std::vector<std::pair<int, double>>& Gt = gterms[ie];
      Et.clear();
      Gt.clear();
      const auto& b = m.blocks[elems[ie].block];
      const std::uint32_t* nodes = b.element(elems[ie].index);
      const auto& t = samples(b.shape, b.order, lattice);
      const std::vector<int>& slot = slots[ie];
      // node coordinates, 3 per node
      thread_local std::vector<double> X, Jc, Kf, G;
      X.resize(3 * std::size_t(t.n));
      for (int a = 0; a < t.n; ++a) {
        if (slot[a] >= 0) {
          for (int c = 0; c < 3; ++c) X[3 * a + c] = xf[3 * slot[a] + c];
        } else {
          X[3 * a] = m.x[nodes[a]];
          X[3 * a + 1] = m.y[nodes[a]];
          X[3 * a + 2] = m.z[nodes[a]];
        }
      }
      const double w = 1.0 / t.ns;
      // J of every sample: Jc[(3 c + r) ns + s] = dx_r / dxi_c
      Jc.resize(9 * std::size_t(t.ns));
      sample_jacobians(t, X.data(), Jc.data());
      thread_local std::vector<double> R, Cof;
      R.resize(t.ns);
      Cof.resize(9 * std::size_t(t.ns));
      for (int s = 0; s < t.ns; ++s) {
        double J[9];
        for (int r = 0; r < 3; ++r)
          for (int c = 0; c < 3; ++c) J[3 * r + c] = Jc[std::size_t(3 * c + r) * t.ns + s];
        R[s] = det3(J) / jref[ie];
        double* C = &Cof[9 * std::size_t(s)];
        C[0] = J[4] * J[8] - J[5] * J[7];
        C[1] = J[5] * J[6] - J[3] * J[8];
        C[2] = J[3] * J[7] - J[4] * J[6];
        C[3] = J[2] * J[7] - J[1] * J[8];
        C[4] = J[0] * J[8] - J[2] * J[6];
        C[5] = J[1] * J[6] - J[0] * J[7];
        C[6] = J[1] * J[5] - J[2] * J[4];
        C[7] = J[2] * J[3] - J[0] * J[5];
        C[8] = J[0] * J[4] - J[1] * J[3];
      }
      // dE/dR per sample: the penalty on the samples, or (Bezier lattice) on the Bernstein
      // coefficients c = T R, dE/dR = T^T dE/dc
      thread_local std::vector<double> dR;
      dR.assign(t.ns, 0.0);
      bool any = false;
      if (t.T.size() || t.Ta.size()) {
        // coefficients c = T R (tet) or, R as a (line x triangle) matrix, Tb R Ta^T (prism)
        const Eigen::Index nb = t.T.size() ? t.ns : t.Tb.rows(), na = t.ns / nb;
        const Eigen::Map<const Eigen::MatrixXd> Rm(R.data(), nb, na);
        const Eigen::MatrixXd c = t.T.size() ? Eigen::MatrixXd(t.T * Rm) : Eigen::MatrixXd(t.Tb * Rm * t.Ta.transpose());
        Eigen::MatrixXd dc = Eigen::MatrixXd::Zero(nb, na);
        for (Eigen::Index k = 0; k < c.size(); ++k)
          if (c(k) < target) {
            const double d = target - c(k);
            Et.push_back(w * d * d);
            dc(k) = -2 * w * d;
            any = true;
          }
        if (any) {
          Eigen::Map<Eigen::MatrixXd> dRm(dR.data(), nb, na);
          if (t.T.size()) dRm = t.T.transpose() * dc;
          else dRm = t.Tb.transpose() * dc * t.Ta;
        }
      } else {
        for (int s = 0; s < t.ns; ++s)
          if (R[s] < target) {
            const double d = target - R[s];
            Et.push_back(w * d * d);
            dR[s] = -2 * w * d;
            any = true;
          }
      }
      if (!any) return;
      // dE/dx_(a,r) = sum_s dR_s / jref * sum_c cof(J_s)(r, c) dN_(s,a,c) (dR/dJ = cof(J) / jref)
      Kf.resize(t.ns);
      for (int s = 0; s < t.ns; ++s) Kf[s] = dR[s] / jref[ie];
      G.resize(3 * std::size_t(t.n));
      gradient_terms(t, Kf.data(), Cof.data(), G.data());
      for (int a = 0; a < t.n; ++a)
        if (slot[a] >= 0)
          for (int r2 = 0; r2 < 3; ++r2) Gt.push_back({3 * slot[a] + r2, G[std::size_t(r2) * t.n + a]});
    };
    if (arena && elems.size() > 1)
      arena->execute([&] {
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, elems.size(), 1), [&](const tbb::blocked_range<std::size_t>& r) {
          for (std::size_t ie = r.begin(); ie != r.end(); ++ie) element(ie);
        });
      });
    else
      for (std::size_t ie = 0; ie < elems.size(); ++ie) element(ie);
    for (std::size_t ie = 0; ie < elems.size(); ++ie) {
      for (double e : eterms[ie]) E += e;
      for (auto [i, v] : gterms[ie]) gx[i] += v;
    }
    for (std::size_t i = 0; i < free.size(); ++i) {
      const double* G = &gx[3 * i];
      if (face[i] < 0) {
        for (int c = 0; c < 3; ++c) g[var[i] + c] = h * G[c];
        continue;
      }
      const double* D[2] = {&du[3 * i], &dv[3 * i]};
      for (int c = 0; c < 2; ++c)
        g[var[i] + c] = clamp[2 * i + c] ? 0.0 : scale[2 * i + c] * (G[0] * D[c][0] + G[1] * D[c][1] + G[2] * D[c][2]);
    }
    for (Eigen::Index i = 0; i < y.size(); ++i) {
      E += spring * y[i] * y[i];
      g[i] += 2 * spring * y[i];
    }
    if (check_every > 0 && ++evaluations % check_every == 0 && acceptable(xf)) throw AcceptedPoint{y};
    return E;
  }

  // Whether the free nodes at xf pass the acceptance test ("check_every" above).
  bool acceptable(const std::vector<double>& xf) const {
    std::vector<double> X;
    for (std::size_t ie = 0; ie < elems.size(); ++ie) {
      const auto& b = m.blocks[elems[ie].block];
      const std::uint32_t* nodes = b.element(elems[ie].index);
      const int n = b.nodes_per_element();
      X.resize(std::size_t(n) * 3);
      for (int a = 0; a < n; ++a) {
        const int k = slots[ie][a];
        X[3 * a] = k >= 0 ? xf[3 * k] : m.x[nodes[a]];
        X[3 * a + 1] = k >= 0 ? xf[3 * k + 1] : m.y[nodes[a]];
        X[3 * a + 2] = k >= 0 ? xf[3 * k + 2] : m.z[nodes[a]];
      }
      const auto q = model::element_quality(b.shape, b.order, X.data());
      if (q.scaled_jacobian < worst_before) return false;
      if (must_valid[ie] && !(q.valid && q.scaled_jacobian >= sj_floor[ie])) return false;
    }
    return true;
  }
};

// ── The mesh's adjacency and what may move ─────────────────────────────────────────────────
struct Topology {
  bool volume = false;                // a 3D mesh (else there is nothing to untangle)
  std::vector<char> fixed;            // never moves: a vertex, on the CAD, on a lower-dimensional element or a pyramid
  std::vector<char> slides;           // inside a CAD face and may slide on it (the second mode)
  std::vector<char> layered;          // a node of a prism or hex (the boundary layer): the lift holds it
  std::vector<std::uint32_t> start;   // node -> its 3D elements (CSR: adj[start[v] .. start[v + 1]])
  std::vector<ElemRef> adj;
};

Topology build_topology(const Mesh& m, const UntangleOptions& opt, const cad::Shape* shape) {
  Topology t;
  const int dim = m.dimension();
  const std::size_t N = m.num_nodes();
  t.fixed.assign(N, 0);
  t.layered.assign(N, 0);
  t.start.assign(N + 1, 0);
  for (std::uint32_t bi = 0; bi < m.blocks.size(); ++bi) {
    const auto& b = m.blocks[bi];
    const int n = b.nodes_per_element(), nv = model::num_vertices(b.shape);
    const bool vol = model::dimension(b.shape) == dim && dim == 3;
    for (std::size_t e = 0; e < b.size(); ++e) {
      const std::uint32_t* en = b.element(e);
      for (int a = 0; a < n; ++a) {
        if (!vol || a < nv || b.shape == Shape::Pyramid) t.fixed[en[a]] = 1;
        if (vol && (b.shape == Shape::Prism || b.shape == Shape::Hex)) t.layered[en[a]] = 1;
        if (vol) ++t.start[en[a] + 1];
      }
    }
  }
  t.volume = dim == 3;
  if (!t.volume) return t;
  if (!m.node_entity_dim.empty())
    for (std::size_t i = 0; i < N; ++i)
      if (m.node_entity_dim[i] >= 0 && m.node_entity_dim[i] < 3) t.fixed[i] = 1;
  // nodes inside CAD faces that may slide on them (the second mode, with a shape): not an
  // element's vertex, not on a pyramid, not in a periodic pair (its partner would not follow),
  // with finite parameters on a face the shape has
  t.slides.assign(N, 0);
  if (shape && opt.surface && m.node_entity_dim.size() == N && m.node_u.size() == N && m.node_v.size() == N) {
    std::vector<char> pinned(N, 0);
    for (const auto& b : m.blocks) {
      const int n = b.nodes_per_element(), nv = model::num_vertices(b.shape);
      for (std::size_t e = 0; e < b.size(); ++e) {
        const std::uint32_t* en = b.element(e);
        for (int a = 0; a < n; ++a)
          if (a < nv || b.shape == Shape::Pyramid) pinned[en[a]] = 1;
      }
    }
    for (const auto& l : m.periodic)
      for (auto [a, c] : l.nodes) pinned[a] = pinned[c] = 1;
    for (std::size_t i = 0; i < N; ++i)
      t.slides[i] = !pinned[i] && m.node_entity_dim[i] == 2 && m.node_entity_tag[i] >= 1 &&
                    m.node_entity_tag[i] <= shape->num_faces() && std::isfinite(m.node_u[i]) && std::isfinite(m.node_v[i]);
  }
  for (std::size_t i = 0; i < N; ++i) t.start[i + 1] += t.start[i];
  t.adj.resize(t.start[N]);
  std::vector<std::uint32_t> fill(t.start.begin(), t.start.end() - 1);
  for (std::uint32_t bi = 0; bi < m.blocks.size(); ++bi) {
    const auto& b = m.blocks[bi];
    if (model::dimension(b.shape) != 3) continue;
    const int n = b.nodes_per_element();
    for (std::uint32_t e = 0; e < b.size(); ++e)
      for (int a = 0; a < n; ++a) t.adj[fill[b.element(e)[a]]++] = {bi, e};
  }
  return t;
}

// Why an element is left invalid (untangle.hpp, "report"); 0 = not decided.
enum Why : std::uint8_t { none, budget, stuck, not_repaired, degenerate, no_free, failed_patch, stage_budget, time_limit };
const char* const why_name[] = {"",           "budget",        "stuck",        "not repaired", "degenerate",
                                "no free nodes", "in a failed patch", "no progress", "time limit"};

// What the untangling shares: the mesh, what may move, each 3D element's validity and whether it
// lies in the largest patch of an element that could not be repaired ("hopeless": not tried).
// Tasks of elements whose largest patches share no node read and write disjoint parts of it.
struct State {
  Mesh& m;
  const UntangleOptions& opt;
  const cad::Shape* shape;
  const Topology& topo;
  tbb::task_arena& arena;
  std::vector<std::vector<char>> valid, hopeless;
  bool logging = false;
  std::chrono::steady_clock::time_point t0;
  std::function<void()> tick;  // progress, thread-safe

  State(Mesh& mesh, const UntangleOptions& o, const cad::Shape* s, const Topology& t, tbb::task_arena& a)
      : m(mesh), opt(o), shape(s), topo(t), arena(a) {}

  std::vector<double> element_X(const ElemRef& r) const {
    const auto& b = m.blocks[r.block];
    const int n = b.nodes_per_element();
    const std::uint32_t* en = b.element(r.index);
    std::vector<double> X(std::size_t(n) * 3);
    for (int a = 0; a < n; ++a) X[3 * a] = m.x[en[a]], X[3 * a + 1] = m.y[en[a]], X[3 * a + 2] = m.z[en[a]];
    return X;
  }
  model::ElementQuality quality_of(const ElemRef& r) const {
    const auto X = element_X(r);
    const auto& b = m.blocks[r.block];
    return model::element_quality(b.shape, b.order, X.data());
  }
  // det J of the straight element (vertices only) at its reference centroid
  double straight_det(const ElemRef& r) const {
    const auto& b = m.blocks[r.block];
    const int nv = model::num_vertices(b.shape);
    const std::uint32_t* en = b.element(r.index);
    std::vector<double> X(std::size_t(nv) * 3);
    for (int a = 0; a < nv; ++a) X[3 * a] = m.x[en[a]], X[3 * a + 1] = m.y[en[a]], X[3 * a + 2] = m.z[en[a]];
    const auto& lin = model::LagrangeBasis::get(b.shape, 1);
    const auto& ref = model::reference_nodes(b.shape, 1);
    model::Vec3 c{0, 0, 0};
    for (const auto& p : ref)
      for (int k = 0; k < 3; ++k) c[k] += p[k] / double(ref.size());
    double J[9];
    model::jacobian(lin, X.data(), c, J);
    return det3(J);
  }
  // mean (longest: !mean) length of the element's vertex edges
  double vertex_edge(const ElemRef& r, bool mean) const {
    const auto& b = m.blocks[r.block];
    const std::uint32_t* en = b.element(r.index);
    const auto& ev = model::edge_vertices(b.shape);
    double s = 0;
    for (auto [a, c] : ev) {
      const double l = std::hypot(m.x[en[a]] - m.x[en[c]], m.y[en[a]] - m.y[en[c]], m.z[en[a]] - m.z[en[c]]);
      s = mean ? s + l : std::max(s, l);
    }
    return mean ? s / double(ev.size()) : s;
  }
  // the patch grown by one ring of node neighbours (sorted, unique). The elements sharing a node
  // with an element are those sharing one of its vertices: in a conforming mesh two elements
  // sharing a high-order node share the edge or face it is on, and so its vertices. Walking the
  // vertices alone gives the same ring (a prism of order 4: 6 nodes of 75; this sort of every
  // node's elements was 20% of the wing's optimise stage).
  std::vector<ElemRef> grow(const std::vector<ElemRef>& patch) const {
    std::vector<ElemRef> grown = patch;
    for (const ElemRef& r : patch) {
      const auto& b = m.blocks[r.block];
      const std::uint32_t* en = b.element(r.index);
      for (int a = 0; a < model::num_vertices(b.shape); ++a)
        for (std::uint32_t k = topo.start[en[a]]; k < topo.start[en[a] + 1]; ++k) grown.push_back(topo.adj[k]);
    }
    std::sort(grown.begin(), grown.end());
    grown.erase(std::unique(grown.begin(), grown.end()), grown.end());
    return grown;
  }
};

// What trying one invalid element did: enough to account for it in the order of the invalid
// elements afterwards, and to undo it when the stage turns out to have stopped before it.
struct NodeBefore {
  std::uint32_t v;
  bool on_face;  // slid on a CAD face: (u, w) are its parameters before
  double x, y, z, u, w;
};
struct ElementRun {
  enum Kind : std::uint8_t { not_run, already_valid, in_failed_patch, tried } kind = not_run;
  bool repaired = false, sliding = false;
  bool folded = false;  // a wall face folded on the CAD: sliding was tried first
  bool by_lift = false;  // repaired by the lift alone (no L-BFGS)
  std::size_t lifts = 0, lift_starts = 0;  // lifts computed; attempts started from one
  int ring = 0;
  Why why = none;  // tried, not repaired
  double work = 0;
  std::size_t attempts = 0, early_exits = 0, stuck = 0, nodes_moved = 0, surface_nodes_moved = 0;
  std::size_t below_floor = 0;  // attempts valid but below the floors: the next attempt tried ("floor")
  double max_move = 0;
  std::vector<NodeBefore> moved;                       // the kept patch's free nodes, before
  std::vector<std::pair<ElemRef, char>> valid_before;  // validity flags it changed, before
  std::vector<ElemRef> marked_hopeless;
  std::vector<std::string> log;
};

// The patch problem of `patch` in `mode` (0: off-CAD nodes free; 1: also the nodes sliding on CAD
// faces): its free nodes and the elements that have one. none: nothing to free (mode 1: no
// sliding node); degenerate: a patch element's straight version has no volume.
enum class Built { ok, none, degenerate };
Built build_patch(const State& S, const std::vector<ElemRef>& patch, int mode, double h, Patch& P) {
  const Mesh& m = S.m;
  const auto& T = S.topo;
  // free nodes: off the CAD (mode 1: or sliding on a CAD face), not a vertex, every element in the patch
  bool any_sliding = false;
  for (const ElemRef& r : patch) {
    const auto& b = m.blocks[r.block];
    const std::uint32_t* en = b.element(r.index);
    for (int a = 0; a < b.nodes_per_element(); ++a) {
      const std::uint32_t v = en[a];
      const bool slide = mode == 1 && T.slides[v];
      if ((T.fixed[v] && !slide) || P.free_index.count(v)) continue;
      bool inside = true;
      for (std::uint32_t k = T.start[v]; k < T.start[v + 1] && inside; ++k)
        inside = std::binary_search(patch.begin(), patch.end(), T.adj[k]);
      if (!inside) continue;
      P.free_index.emplace(v, 0);
      any_sliding = any_sliding || slide;
    }
  }
  if (P.free_index.empty() || (mode == 1 && !any_sliding)) return Built::none;
  int idx = 0;
  for (auto& [v, i] : P.free_index) {  // node order: deterministic
    i = idx++;
    P.free.push_back(v);
    P.x0.insert(P.x0.end(), {m.x[v], m.y[v], m.z[v]});
    P.var.push_back(P.nvars);
    if (mode == 1 && T.slides[v]) {
      const int f = m.node_entity_tag[v] - 1;
      const auto d = S.shape->face_eval(f, m.node_u[v], m.node_v[v]);
      const auto bnd = S.shape->face_uv_bounds(f);
      const auto per = S.shape->face_periods(f);
      const double nu = std::sqrt(d.du.x * d.du.x + d.du.y * d.du.y + d.du.z * d.du.z);
      const double nv = std::sqrt(d.dv.x * d.dv.x + d.dv.y * d.dv.y + d.dv.z * d.dv.z);
      P.face.push_back(f);
      P.uv0.insert(P.uv0.end(), {m.node_u[v], m.node_v[v]});
      // a unit step moves the node by about h; a degenerate direction (a pole) does not move
      P.scale.insert(P.scale.end(), {nu > 0 ? h / nu : 0.0, nv > 0 ? h / nv : 0.0});
      // periodic directions are unbounded (the surface repeats), others stay in the face's box
      P.lo.insert(P.lo.end(), {per[0] > 0 ? -INFINITY : std::min(bnd.u0, m.node_u[v]), per[1] > 0 ? -INFINITY : std::min(bnd.v0, m.node_v[v])});
      P.hi.insert(P.hi.end(), {per[0] > 0 ? INFINITY : std::max(bnd.u1, m.node_u[v]), per[1] > 0 ? INFINITY : std::max(bnd.v1, m.node_v[v])});
      P.nvars += 2;
    } else {
      P.face.push_back(-1);
      P.uv0.insert(P.uv0.end(), {0.0, 0.0});
      P.scale.insert(P.scale.end(), {0.0, 0.0});
      P.lo.insert(P.lo.end(), {0.0, 0.0});
      P.hi.insert(P.hi.end(), {0.0, 0.0});
      P.nvars += 3;
    }
  }
  bool degenerate = false;
  for (const ElemRef& r : patch) {
    const auto& b = m.blocks[r.block];
    const std::uint32_t* en = b.element(r.index);
    std::vector<int> slot(b.nodes_per_element(), -1);
    bool has = false;
    for (int a = 0; a < b.nodes_per_element(); ++a) {
      auto f = P.free_index.find(en[a]);
      if (f != P.free_index.end()) slot[a] = f->second, has = true;
    }
    if (!has) continue;
    const double j = S.straight_det(r);
    // degenerate: its straight version has no volume, or a relative one (det J / longest
    // vertex edge^3) below kMinRelativeVolume (coincident nodes: aspect ratio 1e14, the
    // target det J / det J_straight is meaningless and the optimiser only grinds)
    const double L = S.vertex_edge(r, false);
    if (!(j > kMinRelativeVolume * L * L * L)) degenerate = true;
    P.elems.push_back(r);
    P.slots.push_back(std::move(slot));
    P.jref.push_back(j);
  }
  return degenerate ? Built::degenerate : Built::ok;
}

// The acceptance floors of a patch: never worse (no element may end below the worst of the
// patch before: the invalid element's scaled Jacobian, or another invalid one's if lower), and
// for the early exit each element's own scaled Jacobian before, or kEarlyExitFloor if that is
// higher (an invalid one: kEarlyExitFloor).
void set_floors(const State& S, const ElemRef& bad, Patch& P) {
  P.worst_before = INFINITY;
  P.sj_floor.clear();
  P.must_valid.clear();
  for (const ElemRef& r : P.elems) {
    const double sj = S.quality_of(r).scaled_jacobian;
    const bool v = S.valid[r.block][r.index];
    P.worst_before = std::min(P.worst_before, sj);
    P.sj_floor.push_back(v ? std::min(sj, kEarlyExitFloor) : kEarlyExitFloor);
    P.must_valid.push_back(v || r == bad);
  }
}

// ── The lift ("lift" in untangle.hpp) ──────────────────────────────────────────────────────
// Each node's straight position, the linear (multilinear) map of its element's vertices at the
// node's reference point: W (nodes x vertices) with X_straight = W X_vertices. Cached per
// (shape, order); entries never move once made.
const Eigen::MatrixXd& straight_weights(Shape s, int order) {
  static std::mutex mutex;
  static std::map<std::pair<int, int>, Eigen::MatrixXd> cache;
  std::lock_guard<std::mutex> lock(mutex);
  auto it = cache.find({int(s), order});
  if (it != cache.end()) return it->second;
  const auto& lin = model::LagrangeBasis::get(s, 1);
  const auto& ref = model::reference_nodes(s, order);
  Eigen::MatrixXd W(Eigen::Index(ref.size()), lin.size());
  std::vector<double> L(std::size_t(lin.size()));
  for (std::size_t a = 0; a < ref.size(); ++a) {
    lin.eval(ref[a], L.data());
    for (int v = 0; v < lin.size(); ++v) W(Eigen::Index(a), v) = L[std::size_t(v)];
  }
  return cache.emplace(std::make_pair(int(s), order), std::move(W)).first->second;
}

// Gauss-Legendre points and weights on [0, 1] (Golub-Welsch: the eigenvalues of the Jacobi
// matrix of the Legendre recurrence and the first components of their eigenvectors).
std::pair<std::vector<double>, std::vector<double>> gauss01(int n) {
  Eigen::MatrixXd T = Eigen::MatrixXd::Zero(n, n);
  for (int k = 1; k < n; ++k) T(k, k - 1) = T(k - 1, k) = k / std::sqrt(4.0 * k * k - 1);
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> es(T);
  std::vector<double> x(static_cast<std::size_t>(n), 0.0), w(static_cast<std::size_t>(n), 0.0);
  for (int k = 0; k < n; ++k) {
    x[std::size_t(k)] = 0.5 * (es.eigenvalues()[k] + 1);
    w[std::size_t(k)] = es.eigenvectors()(0, k) * es.eigenvectors()(0, k);  // sums to 1: [0, 1]'s length
  }
  return {x, w};
}

// The lift's quadrature on the reference tet (element.hpp: the unit simplex): n = P + 1 Gauss
// points per direction of the collapsed (Duffy) coordinates, whose Jacobian the weights carry.
// Exact for the stiffness of a straight tet (degree 2P - 2 <= 2n - 3 after the collapse), with
// positive weights (so the stiffness is positive semi-definite); D the basis gradients at the
// points as in SampleTable.
struct Quadrature {
  int n = 0, nq = 0;
  std::vector<double> w;
  Eigen::MatrixXd D;  // rows 3 q + c, columns nodes
};
const Quadrature& tet_quadrature(int order) {
  static std::mutex mutex;
  static std::map<int, Quadrature> cache;
  std::lock_guard<std::mutex> lock(mutex);
  auto it = cache.find(order);
  if (it != cache.end()) return it->second;
  const auto [g, gw] = gauss01(order + 1);
  std::vector<model::Vec3> pts;
  Quadrature q;
  for (std::size_t i = 0; i < g.size(); ++i)
    for (std::size_t j = 0; j < g.size(); ++j)
      for (std::size_t k = 0; k < g.size(); ++k) {  // zeta = c, eta = b (1 - c), xi = a (1 - b) (1 - c)
        const double a = g[i], b = g[j], c = g[k];
        pts.push_back({a * (1 - b) * (1 - c), b * (1 - c), c});
        q.w.push_back(gw[i] * gw[j] * gw[k] * (1 - b) * (1 - c) * (1 - c));
      }
  const auto& basis = model::LagrangeBasis::get(Shape::Tet, order);
  q.n = basis.size();
  q.nq = int(pts.size());
  q.D.resize(3 * q.nq, q.n);
  std::vector<double> dN(3 * std::size_t(q.n));
  for (int k = 0; k < q.nq; ++k) {
    basis.grad(pts[std::size_t(k)], dN.data());
    for (int a = 0; a < q.n; ++a)
      for (int c = 0; c < 3; ++c) q.D(3 * k + c, a) = dN[3 * std::size_t(a) + c];
  }
  return cache.emplace(order, std::move(q)).first->second;
}

// The harmonic lift of the patch's far field (mode 0: every free node is a volume node): the
// displacement d = x - x_straight of its free tet nodes that minimises the Dirichlet energy
// sum_e int |grad d|^2 over the straight tets, with every other node held at its displacement now
// (the curved CAD faces, the boundary layer, the patch's rim). That is the discrete Laplace
// equation K_ff d_f = -K_fb d_b, one matrix for x, y and z; K_e = sum over tet_quadrature's points
// of w |det J| B^T B (B the basis gradients in x). The boundary layer's nodes (of prisms and
// hexes) are held: curving placed them to carry the wall's displacement through the thin layer
// (curve.hpp, rule 3), and a harmonic field moved by a fraction of a tet's size can invert a
// prism a hundred times thinner (Rotor 67 with them free: 823 M samples of untangling work and a
// lower minimum; held: 420 M, bench/results/untangle.md). Eigen's sparse Cholesky (LDL^T) solves it. y: the lift as
// variables ((x - x0) / h). Charges one Jacobian evaluation per quadrature point. False: no free
// tet node, a straight tet without volume, or a system that could not be solved (the attempts
// then start where the patch is).
bool lift(const State& S, const Patch& P, Budget& B, Eigen::VectorXd& y) {
  const Mesh& m = S.m;
  // the lifted nodes: free, not in the boundary layer; lifted[i] = their index, or -1
  std::vector<int> lifted(P.free.size(), -1);
  Eigen::Index nl = 0;
  for (std::size_t i = 0; i < P.free.size(); ++i)
    if (P.face[i] < 0 && !S.topo.layered[P.free[i]]) lifted[i] = int(nl++);
  if (nl == 0) return false;
  double cost = 0;
  for (const ElemRef& r : P.elems)
    if (m.blocks[r.block].shape == Shape::Tet) cost += tet_quadrature(m.blocks[r.block].order).nq;
  B.charge(cost);
  std::vector<Eigen::Triplet<double>> trip;
  Eigen::MatrixXd rhs = Eigen::MatrixXd::Zero(nl, 3), xs = Eigen::MatrixXd::Zero(nl, 3);
  for (std::size_t ie = 0; ie < P.elems.size(); ++ie) {
    const auto& b = m.blocks[P.elems[ie].block];
    if (b.shape != Shape::Tet) continue;  // its nodes are held (layered) or fixed (pyramids)
    const std::uint32_t* en = b.element(P.elems[ie].index);
    const Quadrature& t = tet_quadrature(b.order);
    const Eigen::MatrixXd& W = straight_weights(b.shape, b.order);
    Eigen::MatrixXd Xv(W.cols(), 3);
    for (Eigen::Index v = 0; v < W.cols(); ++v) Xv(v, 0) = m.x[en[v]], Xv(v, 1) = m.y[en[v]], Xv(v, 2) = m.z[en[v]];
    const Eigen::MatrixXd Xs = W * Xv;    // straight nodes, n x 3
    const Eigen::MatrixXd JT = t.D * Xs;  // rows 3 q + c: J^T at point q
    Eigen::MatrixXd K = Eigen::MatrixXd::Zero(t.n, t.n);
    for (int q = 0; q < t.nq; ++q) {
      const Eigen::Matrix3d Jq = JT.block<3, 3>(3 * q, 0);  // J^T
      const double det = Jq.determinant();
      if (!(det > 0)) return false;
      const Eigen::MatrixXd Bq = Jq.inverse() * t.D.middleRows(3 * q, 3);  // J^-T grad_xi N
      K.noalias() += t.w[std::size_t(q)] * det * Bq.transpose() * Bq;
    }
    std::vector<int> li(std::size_t(t.n), -1);
    for (int a = 0; a < t.n; ++a)
      if (P.slots[ie][a] >= 0) li[std::size_t(a)] = lifted[std::size_t(P.slots[ie][a])];
    for (int a = 0; a < t.n; ++a) {
      const int i = li[std::size_t(a)];
      if (i < 0) continue;
      xs.row(i) = Xs.row(a);
      for (int c = 0; c < t.n; ++c) {
        if (li[std::size_t(c)] >= 0) {
          trip.emplace_back(i, li[std::size_t(c)], K(a, c));
          continue;
        }
        const std::uint32_t v = en[c];
        const Eigen::RowVector3d d(m.x[v] - Xs(c, 0), m.y[v] - Xs(c, 1), m.z[v] - Xs(c, 2));
        rhs.row(i) -= K(a, c) * d;
      }
    }
  }
  Eigen::SparseMatrix<double> A(nl, nl);
  A.setFromTriplets(trip.begin(), trip.end());
  Eigen::SimplicialLDLT<Eigen::SparseMatrix<double>> ldlt(A);
  if (ldlt.info() != Eigen::Success) return false;
  const Eigen::MatrixXd d = ldlt.solve(rhs);
  if (ldlt.info() != Eigen::Success || !d.allFinite()) return false;
  y.setZero(P.nvars);
  for (std::size_t i = 0; i < P.free.size(); ++i) {
    const int k = lifted[i];
    if (k >= 0)
      for (int c = 0; c < 3; ++c) y[P.var[i] + c] = (xs(k, c) + d(k, c) - P.x0[3 * i + c]) / P.h;
  }
  return true;
}

// One L-BFGS attempt on the patch from `start` (attempt 0, 1, 2: the lattices of
// sample_order and the targets of untangle.hpp). out >= 0: a budget ran out (OutOfBudget::Which).
struct Minimised {
  Eigen::VectorXd y;
  double fx = 0;
  int iterations = 0;  // L-BFGS's count when it returned (none when it stopped by an exception)
  bool early = false;
  bool line_search_failed = false;  // y: the last accepted point, fx not set
  int out = -1;
};
Minimised minimise(Patch& P, int attempt, const UntangleOptions& opt, Budget& B, const Eigen::VectorXd& start) {
  LBFGSpp::LBFGSParam<double> param;
  param.m = 8;
  param.epsilon = 1e-10;
  param.epsilon_rel = 0;
  // the coefficients' penalty is stiffer (T's entries are large): more iterations
  param.max_iterations = attempt == 2 ? 4 * opt.max_iterations : opt.max_iterations;
  param.max_linesearch = 40;
  LBFGSpp::LBFGSSolver<double> solver(param);
  Minimised r;
  r.y = start;
  P.budget = &B;
  // the second and third attempts (denser samples, then det J's Bernstein coefficients)
  // cost up to 10 x the first and often run all their iterations while the patch has been
  // acceptable for a long time (DLR-F6: 82 of 91 s of untangling): they stop at the first
  // tested point that passes. The floor (kEarlyExitFloor) keeps a repaired element well
  // above the meshes' lowest scaled Jacobians (0.003-0.01), and a valid element of the
  // patch at its own quality or above the floor, so stopping early does not lower the
  // mesh's minimum.
  P.check_every = attempt >= 1 ? 10 : 0;
  P.evaluations = 0;
  try {
    r.iterations = solver.minimize(P, r.y, r.fx);
  } catch (const AcceptedPoint& a) {
    r.y = a.y;
    r.early = true;
  } catch (const OutOfBudget& e) {
    r.out = e.which;  // nothing was applied to the mesh yet
  } catch (const std::exception&) {
    // a failed line search leaves y at the last accepted point, which is a descent of the energy
    r.line_search_failed = true;
  }
  P.budget = nullptr;  // the diagnostic evaluation of the log is not charged
  P.check_every = 0;
  return r;
}

// Moves the patch's free nodes to y (surface nodes by their parameters), and back to the start.
void apply(State& S, const Patch& P, const Eigen::VectorXd& y) {
  Mesh& m = S.m;
  for (std::size_t i = 0; i < P.free.size(); ++i) {
    const std::uint32_t v = P.free[i];
    if (P.face[i] < 0) {
      m.x[v] = P.x0[3 * i] + P.h * y[P.var[i]];
      m.y[v] = P.x0[3 * i + 1] + P.h * y[P.var[i] + 1];
      m.z[v] = P.x0[3 * i + 2] + P.h * y[P.var[i] + 2];
    } else {
      double p[2];
      bool cl[2];
      P.params(i, y, p, cl);
      const auto x = S.shape->face_point(P.face[i], p[0], p[1]);
      m.x[v] = x.x, m.y[v] = x.y, m.z[v] = x.z;
      m.node_u[v] = p[0], m.node_v[v] = p[1];
    }
  }
}
void restore(State& S, const Patch& P) {
  Mesh& m = S.m;
  for (std::size_t i = 0; i < P.free.size(); ++i) {
    const std::uint32_t v = P.free[i];
    m.x[v] = P.x0[3 * i];
    m.y[v] = P.x0[3 * i + 1];
    m.z[v] = P.x0[3 * i + 2];
    if (P.face[i] >= 0) m.node_u[v] = P.uv0[2 * i], m.node_v[v] = P.uv0[2 * i + 1];
  }
}

// The acceptance test ("accept" in untangle.hpp) of the applied patch: ok, and each element's
// validity now (and, with `sj`, its scaled Jacobian, aligned with P.elems).
bool accepted(const State& S, const Patch& P, const ElemRef& bad, std::vector<std::pair<ElemRef, char>>& now,
              std::vector<double>* sj = nullptr) {
  bool ok = true;
  now.clear();
  if (sj) sj->clear();
  for (const ElemRef& r : P.elems) {
    const auto q = S.quality_of(r);
    const char v = q.valid ? 1 : 0;
    if (sj) sj->push_back(q.scaled_jacobian);
    now.push_back({r, v});
    if (S.valid[r.block][r.index] && !v) ok = false;
    if (r == bad && !v) ok = false;
    if (q.scaled_jacobian < P.worst_before) ok = false;
  }
  return ok;
}

// Keeps the applied patch: the new validity flags, and what it moved (run.moved, the counts).
void keep(State& S, const Patch& P, const std::vector<std::pair<ElemRef, char>>& now, ElementRun& run) {
  const Mesh& m = S.m;
  for (auto& [r, v] : now) {
    char& f = S.valid[r.block][r.index];
    if (f != v) run.valid_before.push_back({r, f});
    f = v;
  }
  for (std::size_t i = 0; i < P.free.size(); ++i) {
    const std::uint32_t v = P.free[i];
    const bool f = P.face[i] >= 0;
    run.moved.push_back({v, f, P.x0[3 * i], P.x0[3 * i + 1], P.x0[3 * i + 2], f ? P.uv0[2 * i] : 0.0, f ? P.uv0[2 * i + 1] : 0.0});
    const double d = std::hypot(m.x[v] - P.x0[3 * i], m.y[v] - P.x0[3 * i + 1], m.z[v] - P.x0[3 * i + 2]) / P.h;
    if (d > 0) ++(P.face[i] < 0 ? run.nodes_moved : run.surface_nodes_moved);
    run.max_move = std::max(run.max_move, d);
  }
}

void log_attempt(const State& S, const Patch& P, const ElemRef& bad, int ring, int mode, const Minimised& r, double seconds,
                 bool ok, const std::vector<std::pair<ElemRef, char>>& now, ElementRun& run) {
  Eigen::VectorXd g0(r.y.size()), z0 = Eigen::VectorXd::Zero(r.y.size());
  // L-BFGS sets the energy and its iteration count only when it returns: after an early stop or
  // a failed line search the energy is evaluated here (not charged to the budget) and the log
  // says how it stopped instead of "0 iterations"
  const double after = r.early || r.line_search_failed ? P(r.y, g0) : r.fx;
  char how[48];
  if (r.early) std::snprintf(how, sizeof how, "stopped early: acceptable");
  else if (r.line_search_failed) std::snprintf(how, sizeof how, "stopped: the line search failed");
  else std::snprintf(how, sizeof how, "%d iterations", r.iterations);
  char line[256];
  std::snprintf(line, sizeof line, "untangle: element %u/%u ring %d%s: %zu free nodes, %zu elements, energy %g -> %g, %s, %.2f s: %s",
                bad.block, bad.index, ring, mode ? " sliding on the CAD" : "", P.free.size(), P.elems.size(), P(z0, g0), after,
                how, seconds, ok ? "repaired" : "not repaired");
  run.log.push_back(line);
  for (auto& [e, v] : now)
    if (!v) {
      std::snprintf(line, sizeof line, "untangle:   still invalid %u/%u (valid before: %d)", e.block, e.index, int(S.valid[e.block][e.index]));
      run.log.push_back(line);
    }
}

void log_lift(const Patch& P, const ElemRef& bad, int ring, ElementRun& run) {
  char line[256];
  std::snprintf(line, sizeof line, "untangle: element %u/%u ring %d: %zu free nodes, %zu elements: repaired by the lift", bad.block,
                bad.index, ring, P.free.size(), P.elems.size());
  run.log.push_back(line);
}

// The lifted patch's element qualities (diagnostic): the invalid element's scaled Jacobian, the
// lowest of the others and how many of them are invalid, and the penalties at the lift and now.
void log_lift_rejected(const State& S, const Patch& P, const ElemRef& bad, int ring, const std::vector<double>& xf, double el,
                       double e0, ElementRun& run) {
  double own = NAN, others = INFINITY;
  int invalid = 0, invalid_prisms = 0;
  std::vector<double> X;
  for (std::size_t ie = 0; ie < P.elems.size(); ++ie) {
    const auto& b = S.m.blocks[P.elems[ie].block];
    const std::uint32_t* nodes = b.element(P.elems[ie].index);
    X.resize(3 * std::size_t(b.nodes_per_element()));
    for (int a = 0; a < b.nodes_per_element(); ++a) {
      const int k = P.slots[ie][a];
      X[3 * a] = k >= 0 ? xf[3 * k] : S.m.x[nodes[a]];
      X[3 * a + 1] = k >= 0 ? xf[3 * k + 1] : S.m.y[nodes[a]];
      X[3 * a + 2] = k >= 0 ? xf[3 * k + 2] : S.m.z[nodes[a]];
    }
    const auto q = model::element_quality(b.shape, b.order, X.data());
    if (P.elems[ie] == bad) own = q.scaled_jacobian;
    else others = std::min(others, q.scaled_jacobian), invalid += !q.valid, invalid_prisms += !q.valid && b.shape != Shape::Tet;
  }
  char line[256];
  std::snprintf(line, sizeof line, "untangle: element %u/%u ring %d: lift not kept: its scaled J %.3g, others' lowest %.3g (%d invalid, %d not tets); penalty %g at the lift, %g now",
                bad.block, bad.index, ring, own, others, invalid, invalid_prisms, el, e0);
  run.log.push_back(line);
}

// Whether a face of the element that lies on the CAD (every node of it on a CAD entity, one
// inside a CAD face) is folded: its curved normal n = x_s x x_t turns against the normal of the
// same face made of its vertices only (the straight face the linear mesh had) at a sample of the
// face's order P + 2 lattice. On such a face det J = n . x_w (x_w the derivative into the
// element) can only be positive where n has turned if x_w turns with it, out of the domain
// through the wall: moving the off-CAD nodes can make det J positive there only by an element
// that leaves the fluid and overlaps the solid, never by a geometrically valid one. Only the
// nodes on the face, sliding on the CAD, undo the fold ("fold" in untangle.hpp).
bool folded_wall_face(const State& S, const ElemRef& r) {
  const Mesh& m = S.m;
  if (m.node_entity_dim.size() != m.num_nodes()) return false;
  const auto& b = m.blocks[r.block];
  const std::uint32_t* en = b.element(r.index);
  const auto& faces = model::face_nodes(b.shape, b.order);
  for (std::size_t f = 0; f < faces.size(); ++f) {
    const auto& fn = faces[f];
    bool on_cad = true, in_face = false;
    for (int a : fn) {
      const int d = m.node_entity_dim[en[a]];
      on_cad = on_cad && d >= 0 && d < 3;
      in_face = in_face || d == 2;
    }
    if (!on_cad || !in_face) continue;
    const Shape fs = int(fn.size()) == model::num_nodes(Shape::Tri, b.order) ? Shape::Tri : Shape::Quad;
    const int nv = model::num_vertices(fs);
    const auto& basis = model::LagrangeBasis::get(fs, b.order);
    const auto& lin = model::LagrangeBasis::get(fs, 1);
    std::vector<double> X(3 * fn.size()), XL(3 * std::size_t(nv));
    for (std::size_t a = 0; a < fn.size(); ++a) {
      const std::uint32_t v = en[fn[a]];
      X[3 * a] = m.x[v], X[3 * a + 1] = m.y[v], X[3 * a + 2] = m.z[v];
    }
    std::copy(X.begin(), X.begin() + 3 * nv, XL.begin());
    for (const model::Vec3& xi : model::reference_nodes(fs, std::min(model::kMaxOrder, b.order + 2))) {
      double J[9], JL[9];
      model::jacobian(basis, X.data(), xi, J);
      model::jacobian(lin, XL.data(), xi, JL);
      // the straight face's normal (its Jacobian's columns crossed); the curved face's normal
      // against it is the 2D Jacobian determinant of the model's validity check
      const double nl[3] = {JL[3] * JL[7] - JL[6] * JL[4], JL[6] * JL[1] - JL[0] * JL[7], JL[0] * JL[4] - JL[3] * JL[1]};
      if (model::jacobian_determinant(2, J, nl) <= 0) return true;
    }
  }
  return false;
}

// The lift of an off-CAD patch ("lift" in untangle.hpp), applied and kept when it passes the early
// exit's test (the element valid at kEarlyExitFloor, no valid element below its own quality or
// the floor): true, the element is repaired. Else the patch is as it was, and `start` becomes the
// lift when its penalty (the first attempt's) is lower than the patch's now. Throws OutOfBudget.
bool try_lift(State& S, const ElemRef& bad, int ring, Patch& P, Budget& B, ElementRun& run, Eigen::VectorXd& start) {
  Eigen::VectorXd yl;
  if (!lift(S, P, B, yl)) return false;
  ++run.lifts;
  std::vector<double> xf(P.x0.size());
  for (std::size_t i = 0; i < xf.size(); ++i) xf[i] = P.x0[i] + P.h * yl[P.var[i / 3] + int(i % 3)];
  if (P.acceptable(xf)) {
    apply(S, P, yl);
    std::vector<std::pair<ElemRef, char>> now;
    if (accepted(S, P, bad, now)) {
      if (S.logging) log_lift(P, bad, ring, run);
      keep(S, P, now, run);
      run.repaired = run.by_lift = true;
      run.ring = ring;
      return true;
    }
    restore(S, P);
  }
  P.target = S.opt.target;
  P.lattice = 0;
  P.budget = &B;
  Eigen::VectorXd g(P.nvars);
  const double el = P(yl, g), e0 = P(start, g);
  P.budget = nullptr;
  if (el < e0) start = yl, ++run.lift_starts;
  if (S.logging) log_lift_rejected(S, P, bad, ring, xf, el, e0, run);
  return false;
}

// Whether an accepted patch passes the floors as well ("floor" in untangle.hpp): every element
// that must be valid (it is, being accepted) is at its sj_floor or above (set_floors; the early
// exit's test). now, sj: accepted's, for the applied patch.
bool meets_floors(const Patch& P, const std::vector<std::pair<ElemRef, char>>& now, const std::vector<double>& sj) {
  for (std::size_t i = 0; i < P.elems.size(); ++i)
    if (P.must_valid[i] && !(now[i].second && sj[i] >= P.sj_floor[i])) return false;
  return true;
}

// Tries to repair one invalid element ("patch" .. "accept" in untangle.hpp): rings 1..max_rings,
// each off-CAD then sliding, each in up to three attempts; an element with a wall face folded on
// the CAD slides first, at every ring, and tries the off-CAD nodes alone only after that. Reads
// and writes only its largest patch (the nodes of its elements, their validity and hopeless flags).
ElementRun repair_element(State& S, const ElemRef& bad) {
  ElementRun run;
  run.kind = S.valid[bad.block][bad.index]      ? ElementRun::already_valid  // repaired with an earlier patch
             : S.hopeless[bad.block][bad.index] ? ElementRun::in_failed_patch
                                                : ElementRun::tried;
  if (run.kind != ElementRun::tried) return run;
  const auto& opt = S.opt;
  Budget B;
  B.element_limit = opt.element_budget;
  B.time_limit = opt.time_limit;
  B.t0 = S.t0;
  B.last_tick = std::chrono::steady_clock::now();
  B.tick = S.tick;
  const double h = S.vertex_edge(bad, true);  // element size: mean vertex-edge length
  if (!(h > 0)) {
    run.why = degenerate;
    return run;
  }
  bool any_attempt = false, any_degenerate = false, last_stuck = false, done = false;
  int out = -1;  // OutOfBudget::Which, when a budget ran out
  // the patches of rings 1..max_rings
  std::vector<std::vector<ElemRef>> patches;
  std::vector<ElemRef> grown{bad};
  for (int ring = 1; ring <= opt.max_rings; ++ring) patches.push_back(grown = S.grow(grown));
  int reached = 1;  // the largest ring tried
  // (ring, mode): mode 0 moves the off-CAD nodes only; mode 1 (with a shape) also slides the
  // nodes inside CAD faces on their faces. Off-CAD first, ring by ring, so a repair that needs no
  // surface move makes none; with a folded wall face, sliding first at every ring
  const bool sliding = S.shape && opt.surface;
  run.folded = sliding && folded_wall_face(S, bad);
  std::vector<std::pair<int, int>> order;
  for (int ring = 1; ring <= opt.max_rings; ++ring)
    for (int mode = 0; mode < (sliding ? 2 : 1); ++mode) order.push_back({ring, mode});
  if (run.folded)
    std::stable_sort(order.begin(), order.end(), [](const auto& a, const auto& b) { return a.second > b.second; });
  for (auto [ring, mode] : order) {
    if (done || out >= 0) break;
    reached = std::max(reached, ring);
    {
      const std::vector<ElemRef>& patch = patches[std::size_t(ring - 1)];
      Patch P(S.m);
      P.arena = &S.arena;
      P.shape = S.shape;
      P.h = h;
      P.spring = opt.spring;
      const Built built = build_patch(S, patch, mode, h, P);
      if (built == Built::none) continue;
      if (built == Built::degenerate) {  // a straight element is not valid: nothing to aim at
        any_degenerate = true;
        continue;
      }
      set_floors(S, bad, P);
      // the lift first (off-CAD patches): kept alone when it passes; else the attempts may start from it
      Eigen::VectorXd start = Eigen::VectorXd::Zero(P.nvars);
      if (mode == 0 && opt.lift) {
        try {
          if (try_lift(S, bad, ring, P, B, run, start)) {
            done = true;
            continue;
          }
        } catch (const OutOfBudget& e) {
          out = e.which;
          break;
        }
      }
      // the target on the coarse samples first, then a higher one on the dense samples: samples
      // just above the target can leave det J negative between them, which the Bezier check
      // finds; then (tets, prisms) half the target on det J's Bernstein coefficients, which see the dips
      // the first accepted result below the floors ("floor") and its acceptance test, kept if no
      // attempt passes them
      Eigen::VectorXd below;
      std::vector<std::pair<ElemRef, char>> below_now;
      // the applied patch is kept (init-captures: clang 14 cannot capture structured bindings)
      auto repaired = [&, ring = ring, mode = mode](const std::vector<std::pair<ElemRef, char>>& now) {
        keep(S, P, now, run);
        run.repaired = done = true;
        run.ring = ring;
        run.sliding = mode == 1;
      };
      const bool third = std::any_of(P.elems.begin(), P.elems.end(), [&](const ElemRef& r) {
        return has_bezier_lattice(S.m.blocks[r.block].shape, S.m.blocks[r.block].order);
      });
      for (int attempt = 0; attempt < 3 && !done; ++attempt) {
        P.target = attempt == 0 ? opt.target : attempt == 1 ? std::max(opt.target, std::min(1.0, 2.5 * opt.target)) : 0.5 * opt.target;
        P.lattice = attempt;
        if (attempt == 2 && !third) break;  // no tet or prism: the third attempt would repeat the second
        ++run.attempts;
        any_attempt = true;
        const auto ta = std::chrono::steady_clock::now();
        const Minimised r = minimise(P, attempt, opt, B, start);
        if (r.out >= 0) {  // give up on this element (or on all: time)
          out = r.out;
          break;
        }
        run.early_exits += r.early;
        // a diverged line search can leave non-finite values: that attempt failed, nothing moves
        if (!r.y.allFinite()) continue;
        apply(S, P, r.y);
        std::vector<std::pair<ElemRef, char>> now;
        std::vector<double> sj;
        const bool ok = accepted(S, P, bad, now, &sj);
        if (S.logging)
          log_attempt(S, P, bad, ring, mode, r, std::chrono::duration<double>(std::chrono::steady_clock::now() - ta).count(), ok, now, run);
        if (!ok) {
          // the coarse attempt left the energy at or above one sample's full penalty (target^2,
          // a sample at r <= 0 alone costs that much): the patch is stuck far from valid, and the
          // later attempts (a higher target on more samples, then det J's Bernstein coefficients,
          // both harder to satisfy) cannot do better; they cost up to 10 x the first (Rotor 67:
          // 1.3 and 8 s after 0.5 s on a 45-element patch, 5 and 29 s on 281 elements)
          const bool stuck_now = attempt == 0 && r.fx >= P.target * P.target;
          run.stuck += stuck_now;
          last_stuck = stuck_now;
          restore(S, P);
          if (stuck_now) break;
          continue;
        }
        if (attempt < (third ? 2 : 1) && !meets_floors(P, now, sj)) {  // valid, but a later attempt may do better
          ++run.below_floor;
          if (!below.size()) below = r.y, below_now = now;
          restore(S, P);
          continue;
        }
        repaired(now);
      }
      if (!done && below.size()) {  // no attempt passed the floors: the first valid result, as it was accepted
        apply(S, P, below);  // the same coordinates, so the same qualities as when it was accepted
        repaired(below_now);
        out = -1;  // a budget that ran out in a later attempt does not undo it
      }
    }
  }
  run.work = B.element_used;
  if (done) return run;
  run.why = out == OutOfBudget::element ? budget
            : out == OutOfBudget::time  ? time_limit
            : any_attempt               ? (last_stuck ? stuck : not_repaired)
            : any_degenerate            ? degenerate
                                        : no_free;
  if (run.why == time_limit) return run;
  // the invalid elements of its largest patch are not tried again ("hopeless")
  for (const ElemRef& r : patches[std::size_t(reached - 1)])
    if (!S.valid[r.block][r.index] && !S.hopeless[r.block][r.index]) {
      S.hopeless[r.block][r.index] = 1;
      run.marked_hopeless.push_back(r);
    }
  return run;
}

// Undoes a run (the stage stopped before its element).
void undo(State& S, const ElementRun& run) {
  for (const auto& n : run.moved) {
    S.m.x[n.v] = n.x, S.m.y[n.v] = n.y, S.m.z[n.v] = n.z;
    if (n.on_face) S.m.node_u[n.v] = n.u, S.m.node_v[n.v] = n.w;
  }
  for (const auto& [r, v] : run.valid_before) S.valid[r.block][r.index] = v;
  for (const ElemRef& r : run.marked_hopeless) S.hopeless[r.block][r.index] = 0;
}

// The invalid elements whose largest patches share a node with an earlier one's: succ[j] lists
// the later ones of j, preds[k] counts the earlier ones of k. Elements whose largest patches are
// node-disjoint read and write disjoint data, so running each after the earlier ones it conflicts
// with gives what running them all one after another in order gives.
void conflicts(const State& S, const std::vector<ElemRef>& invalid, std::vector<std::vector<std::uint32_t>>& succ,
               std::vector<int>& preds) {
  const std::size_t n = invalid.size();
  succ.assign(n, {});
  preds.assign(n, 0);
  // the vertices of each largest patch, then vertex -> the elements whose patch has it (in
  // order): two patches share a node if and only if they share a vertex (see State::grow)
  std::vector<std::vector<std::uint32_t>> nodes_of(n);
  std::vector<std::pair<std::uint32_t, std::uint32_t>> pairs;  // (vertex, element k)
  for (std::size_t k = 0; k < n; ++k) {
    std::vector<ElemRef> patch{invalid[k]};
    for (int ring = 1; ring <= S.opt.max_rings; ++ring) patch = S.grow(patch);
    std::vector<std::uint32_t> nodes;
    for (const ElemRef& r : patch) {
      const auto& b = S.m.blocks[r.block];
      const std::uint32_t* en = b.element(r.index);
      nodes.insert(nodes.end(), en, en + model::num_vertices(b.shape));
    }
    std::sort(nodes.begin(), nodes.end());
    nodes.erase(std::unique(nodes.begin(), nodes.end()), nodes.end());
    for (std::uint32_t v : nodes) pairs.push_back({v, std::uint32_t(k)});
    nodes_of[k] = std::move(nodes);
  }
  std::sort(pairs.begin(), pairs.end());
  std::vector<std::size_t> mark(n, SIZE_MAX);
  for (std::size_t k = 0; k < n; ++k)
    for (std::uint32_t v : nodes_of[k]) {
      auto it = std::lower_bound(pairs.begin(), pairs.end(), std::make_pair(v, std::uint32_t(0)));
      for (; it != pairs.end() && it->first == v && it->second < k; ++it)
        if (mark[it->second] != k) {
          mark[it->second] = k;
          succ[it->second].push_back(std::uint32_t(k));
          ++preds[k];
        }
    }
}

// Accounts for the runs in the order of the invalid elements (the no-progress budget, the
// report's counts, the reasons), emitting their log lines; finds where the stage stops.
struct Ledger {
  StageBudget SB;
  UntangleReport& rep;
  std::vector<std::vector<std::uint8_t>>& why;
  Why stopped = none;
  // false: the stage stops at this element (it and the later ones are not kept)
  bool account(const ElemRef& bad, const ElementRun& run) {
    if (run.kind == ElementRun::already_valid) return true;
    if (run.kind == ElementRun::in_failed_patch) {
      ++rep.skipped;
      why[bad.block][bad.index] = failed_patch;
      return true;
    }
    if (SB.exhausted()) {  // no progress: stop (checked between elements)
      why[bad.block][bad.index] = stage_budget;
      stopped = stage_budget;
      return false;
    }
    SB.total += run.work;
    SB.stage_used += run.work;
    rep.folded_wall += run.folded;
    rep.lifts += run.lifts;
    rep.lift_starts += run.lift_starts;
    rep.attempts += run.attempts;
    rep.early_exits += run.early_exits;
    rep.below_floor += run.below_floor;
    rep.stuck += run.stuck;
    rep.max_element_work = std::max(rep.max_element_work, run.work);
    if (run.repaired) {
      rep.nodes_moved += run.nodes_moved;
      rep.surface_nodes_moved += run.surface_nodes_moved;
      rep.max_move = std::max(rep.max_move, run.max_move);
      ++rep.repaired;
      SB.repair_work += run.work;
      SB.stage_used = 0;  // progress: the no-progress budget starts again
      ++rep.repaired_at_ring[run.ring - 1];
      rep.repaired_sliding += run.sliding;
      rep.repaired_by_lift += run.by_lift;
      return true;
    }
    why[bad.block][bad.index] = run.why;
    if (run.why == time_limit) {
      stopped = time_limit;
      return false;
    }
    if (run.why == budget) ++rep.budget_exhausted;
    return true;
  }
};

// Runs repair_element for every invalid element, each after the earlier ones whose largest
// patches share a node with its own (conflicts), in parallel otherwise; accounts for them in
// order as they complete (Ledger), skips the ones after a stop and undoes those that ran.
void repair_all(State& S, const std::vector<ElemRef>& invalid, Ledger& L, const std::function<void(const std::string&)>& log,
                const std::function<void(std::size_t, std::size_t)>& visited) {
  const std::size_t n = invalid.size();
  std::vector<std::vector<std::uint32_t>> succ;
  std::vector<int> npred;
  conflicts(S, invalid, succ, npred);
  std::vector<std::atomic<int>> pending(n);
  for (std::size_t k = 0; k < n; ++k) pending[k].store(npred[k]);
  std::vector<ElementRun> runs(n);
  std::vector<char> finished(n, 0);
  std::mutex mu;
  std::size_t frontier = 0;
  std::atomic<std::size_t> stop_at{n};
  auto advance = [&](std::size_t k) {
    std::lock_guard<std::mutex> lock(mu);
    finished[k] = 1;
    while (frontier < n && finished[frontier] && stop_at.load() == n) {
      const bool go = L.account(invalid[frontier], runs[frontier]);
      if (go || L.stopped == time_limit)
        if (log)
          for (const auto& l : runs[frontier].log) log(l);
      if (!go) stop_at.store(frontier);
      ++frontier;
      visited(frontier, L.rep.repaired);
    }
  };
  tbb::task_group tg;
  std::function<void(std::size_t)> launch = [&](std::size_t k) {
    tg.run([&, k] {
      if (k < stop_at.load()) runs[k] = repair_element(S, invalid[k]);
      advance(k);
      for (std::uint32_t s : succ[k])
        if (pending[s].fetch_sub(1) == 1) launch(s);
    });
  };
  S.arena.execute([&] {
    for (std::size_t k = 0; k < n; ++k)
      if (npred[k] == 0) launch(k);
    tg.wait();
  });
  // the stage stopped at stop_at: what ran after it is undone, the latest first
  for (std::size_t k = n; k-- > stop_at.load();) undo(S, runs[k]);
}

// The report's count of the elements still invalid, with reasons, and the first max_listed.
void list_unrepaired(const State& S, const std::vector<std::vector<std::uint8_t>>& why, Why stopped, UntangleReport& rep) {
  const Mesh& m = S.m;
  std::uint64_t running = 0;
  for (std::uint32_t bi = 0; bi < m.blocks.size(); ++bi) {
    const auto& b = m.blocks[bi];
    for (std::uint32_t e = 0; e < S.valid[bi].size(); ++e)
      if (!S.valid[bi][e]) {
        ++rep.invalid_after;
        // not reached: the no-progress budget or the time limit stopped the loop before it
        const Why w = why[bi][e] != none ? Why(why[bi][e]) : stopped != none ? stopped : not_repaired;
        ++rep.unrepaired_by_reason[why_name[w]];
        if (int(rep.unrepaired.size()) >= S.opt.max_listed) continue;
        Unrepaired u;
        u.tag = b.tags.empty() ? running + e + 1 : b.tags[e];
        u.reason = why_name[w];
        const int nv = model::num_vertices(b.shape);
        const std::uint32_t* en = b.element(e);
        for (int a = 0; a < nv; ++a) u.centroid[0] += m.x[en[a]], u.centroid[1] += m.y[en[a]], u.centroid[2] += m.z[en[a]];
        for (double& c : u.centroid) c /= nv;
        rep.unrepaired.push_back(std::move(u));
      }
    running += b.size();
  }
}

}  // namespace

UntangleReport untangle(Mesh& m, const UntangleOptions& opt, int threads, const std::function<void(const std::string&)>& log,
                        const cad::Shape* shape, const std::function<void(const UntangleProgress&)>& progress) {
  const auto t0 = std::chrono::steady_clock::now();
  tbb::task_arena arena(threads > 0 ? threads : tbb::task_arena::automatic);
  UntangleReport rep;
  rep.repaired_at_ring.assign(std::max(1, opt.max_rings), 0);
  const Topology topo = build_topology(m, opt, shape);
  if (!topo.volume) {
    rep.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    return rep;
  }
  State S(m, opt, shape, topo, arena);
  S.t0 = t0;
  S.logging = bool(log);
  std::vector<ElemRef> invalid;
  {
    const auto quality = model::mesh_quality(m, threads, opt.known_quality, opt.moved_since_known);
    S.valid.resize(m.blocks.size());
    for (std::uint32_t bi = 0; bi < m.blocks.size(); ++bi) {
      S.valid[bi].assign(quality[bi].size(), 1);
      for (std::uint32_t e = 0; e < quality[bi].size(); ++e)
        if (!quality[bi][e].valid) {
          S.valid[bi][e] = 0;
          invalid.push_back({bi, e});
        }
    }
  }
  rep.invalid_before = invalid.size();
  S.hopeless.resize(m.blocks.size());
  std::vector<std::vector<std::uint8_t>> why(m.blocks.size());
  for (std::uint32_t bi = 0; bi < m.blocks.size(); ++bi) {
    S.hopeless[bi].assign(S.valid[bi].size(), 0);
    why[bi].assign(S.valid[bi].size(), none);
  }
  Ledger L{StageBudget{}, rep, why};
  L.SB.stage_limit = opt.stage_budget;
  L.SB.element_limit = opt.element_budget;
  // progress: the elements accounted for so far and the repairs among them, from any thread
  std::mutex progress_mutex;
  std::atomic<std::size_t> visited{0}, repaired{0};
  auto report_progress = [&] {
    if (progress)
      progress({visited.load(), invalid.size(), repaired.load(), std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count()});
  };
  S.tick = [&] {
    std::unique_lock<std::mutex> lock(progress_mutex, std::try_to_lock);
    if (lock.owns_lock()) report_progress();
  };
  report_progress();
  repair_all(S, invalid, L, log, [&](std::size_t n, std::size_t r) {
    visited.store(n);
    repaired.store(r);
    std::lock_guard<std::mutex> lock(progress_mutex);
    report_progress();
  });
  rep.work = L.SB.total;
  rep.repair_work = L.SB.repair_work;
  rep.stage_budget_exhausted = L.stopped == stage_budget;
  rep.time_limit_fired = L.stopped == time_limit;
  list_unrepaired(S, why, L.stopped, rep);
  rep.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return rep;
}

}  // namespace meshflow::optimise
