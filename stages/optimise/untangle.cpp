// Untangling of invalid curved elements by local volume optimisation (untangle.hpp).
// Libraries: LBFGSpp (L-BFGS), Eigen (its vectors), TBB only through model::mesh_quality.
#include "stages/optimise/untangle.hpp"

#include "stages/cad/cad.hpp"
#include "stages/model/basis.hpp"
#include "stages/model/element.hpp"
#include "stages/model/quality.hpp"

#include <Eigen/Core>
#include <Eigen/LU>
#include <LBFGS.h>
#include <nlohmann/json.hpp>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <array>
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
          {"nodes_moved", nodes_moved},
          {"surface_nodes_moved", surface_nodes_moved},
          {"repaired_sliding_on_cad", repaired_sliding},
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

// Basis gradients at the sample points of one (shape, order): dN[(s * n + a) * 3 + c]. For the
// Bezier lattice (tets, prisms), also the transform of det J's values at the points to its
// Bernstein coefficients: T (tets), or Ta (triangle) x Tb (line) for prisms, the points ordered
// s = i * nb + j (triangle point i, line point j).
struct SampleTable {
  int n = 0, ns = 0;
  std::vector<double> dN;
  // The same gradients as one matrix, rows (sample s, reference direction c) = 3 s + c, columns
  // nodes a: J of every sample at once is D X (X: nodes x 3), and the gradient of a sum of terms
  // M_s : J_s over the nodes is D^T M; two small dense products (Eigen's blocked kernels) instead
  // of a scalar loop per sample (84% of the untangling time on DLR-F6 was that loop).
  Eigen::MatrixXd D;
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
  t.dN.resize(std::size_t(t.ns) * t.n * 3);
  for (int k = 0; k < t.ns; ++k) b.grad(pts[k], &t.dN[std::size_t(k) * t.n * 3]);
  t.D.resize(3 * t.ns, t.n);
  for (int k = 0; k < t.ns; ++k)
    for (int a = 0; a < t.n; ++a)
      for (int c = 0; c < 3; ++c) t.D(3 * k + c, a) = t.dN[(std::size_t(k) * t.n + a) * 3 + c];
  return cache.emplace(key, std::move(t)).first->second;
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
struct Budget {
  // stage_used: work since the last repair (the no-progress budget); repair_work: the work of
  // the elements repaired so far (each one's whole element_used); total: all work
  double element_used = 0, element_limit = 0, stage_used = 0, stage_limit = 0, repair_work = 0, total = 0;
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
  double time_limit = 0;
  std::chrono::steady_clock::time_point t0, last_tick;
  std::function<void()> tick;  // progress, about every second
  void charge(double cost) {
    if (element_limit > 0 && element_used + cost > element_limit) throw OutOfBudget{OutOfBudget::element};
    const auto now = std::chrono::steady_clock::now();
    if (time_limit > 0 && std::chrono::duration<double>(now - t0).count() > time_limit) throw OutOfBudget{OutOfBudget::time};
    element_used += cost;
    stage_used += cost;
    total += cost;
    if (tick && now - last_tick > std::chrono::seconds(1)) {
      last_tick = now;
      tick();
    }
  }
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
      // node coordinates, one row per node
      thread_local Eigen::MatrixXd X, JT, M, G;
      X.resize(t.n, 3);
      for (int a = 0; a < t.n; ++a) {
        if (slot[a] >= 0) {
          for (int c = 0; c < 3; ++c) X(a, c) = xf[3 * slot[a] + c];
        } else {
          X(a, 0) = m.x[nodes[a]];
          X(a, 1) = m.y[nodes[a]];
          X(a, 2) = m.z[nodes[a]];
        }
      }
      const double w = 1.0 / t.ns;
      // J^T of every sample: JT(3 s + c, r) = dx_r / dxi_c
      JT.noalias() = t.D * X;
      thread_local std::vector<double> R, Cof;
      R.resize(t.ns);
      Cof.resize(9 * std::size_t(t.ns));
      for (int s = 0; s < t.ns; ++s) {
        double J[9];
        for (int r = 0; r < 3; ++r)
          for (int c = 0; c < 3; ++c) J[3 * r + c] = JT(3 * s + c, r);
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
      // dE/dx_(a,r) = sum_s dR_s / jref * sum_c cof(J_s)(r, c) dN_(s,a,c) = (D^T M)(a, r) with
      // M(3 s + c, r) = dR_s / jref * cof(J_s)(r, c)
      M.resize(3 * t.ns, 3);
      for (int s = 0; s < t.ns; ++s) {
        const double k = dR[s] / jref[ie];  // dR/dJ = cof(J) / jref
        const double* C = &Cof[9 * std::size_t(s)];
        for (int c = 0; c < 3; ++c)
          for (int r2 = 0; r2 < 3; ++r2) M(3 * s + c, r2) = k * C[3 * r2 + c];
      }
      G.noalias() = t.D.transpose() * M;
      for (int a = 0; a < t.n; ++a)
        if (slot[a] >= 0)
          for (int r2 = 0; r2 < 3; ++r2) Gt.push_back({3 * slot[a] + r2, G(a, r2)});
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

}  // namespace

UntangleReport untangle(Mesh& m, const UntangleOptions& opt, int threads, const std::function<void(const std::string&)>& log,
                        const cad::Shape* shape, const std::function<void(const UntangleProgress&)>& progress) {
  const auto t0 = std::chrono::steady_clock::now();
  tbb::task_arena arena(threads > 0 ? threads : tbb::task_arena::automatic);
  UntangleReport rep;
  rep.repaired_at_ring.assign(std::max(1, opt.max_rings), 0);
  const int dim = m.dimension();
  const std::size_t N = m.num_nodes();

  // node -> 3D elements (CSR), vertex flags, nodes of lower-dimensional elements and pyramids
  std::vector<char> fixed(N, 0);
  std::vector<std::uint32_t> start(N + 1, 0);
  for (std::uint32_t bi = 0; bi < m.blocks.size(); ++bi) {
    const auto& b = m.blocks[bi];
    const int n = b.nodes_per_element(), nv = model::num_vertices(b.shape);
    const bool vol = model::dimension(b.shape) == dim && dim == 3;
    for (std::size_t e = 0; e < b.size(); ++e) {
      const std::uint32_t* en = b.element(e);
      for (int a = 0; a < n; ++a) {
        if (!vol || a < nv || b.shape == Shape::Pyramid) fixed[en[a]] = 1;
        if (vol) ++start[en[a] + 1];
      }
    }
  }
  if (dim != 3) {
    rep.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    return rep;
  }
  if (!m.node_entity_dim.empty())
    for (std::size_t i = 0; i < N; ++i)
      if (m.node_entity_dim[i] >= 0 && m.node_entity_dim[i] < 3) fixed[i] = 1;
  // nodes inside CAD faces that may slide on them (the second mode, with a shape): not an
  // element's vertex, not on a pyramid, not in a periodic pair (its partner would not follow),
  // with finite parameters on a face the shape has
  std::vector<char> slides(N, 0);
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
      slides[i] = !pinned[i] && m.node_entity_dim[i] == 2 && m.node_entity_tag[i] >= 1 &&
                  m.node_entity_tag[i] <= shape->num_faces() && std::isfinite(m.node_u[i]) && std::isfinite(m.node_v[i]);
  }
  for (std::size_t i = 0; i < N; ++i) start[i + 1] += start[i];
  std::vector<ElemRef> adj(start[N]);
  {
    std::vector<std::uint32_t> fill(start.begin(), start.end() - 1);
    for (std::uint32_t bi = 0; bi < m.blocks.size(); ++bi) {
      const auto& b = m.blocks[bi];
      if (model::dimension(b.shape) != 3) continue;
      const int n = b.nodes_per_element();
      for (std::uint32_t e = 0; e < b.size(); ++e)
        for (int a = 0; a < n; ++a) adj[fill[b.element(e)[a]]++] = {bi, e};
    }
  }

  auto quality = model::mesh_quality(m, threads);
  std::vector<std::vector<char>> valid(m.blocks.size());
  std::vector<ElemRef> invalid;
  for (std::uint32_t bi = 0; bi < m.blocks.size(); ++bi) {
    valid[bi].assign(quality[bi].size(), 1);
    for (std::uint32_t e = 0; e < quality[bi].size(); ++e)
      if (!quality[bi][e].valid) {
        valid[bi][e] = 0;
        invalid.push_back({bi, e});
      }
  }
  quality.clear();
  rep.invalid_before = invalid.size();

  auto element_X = [&](const ElemRef& r, std::vector<double>& X) {
    const auto& b = m.blocks[r.block];
    const int n = b.nodes_per_element();
    const std::uint32_t* en = b.element(r.index);
    X.resize(std::size_t(n) * 3);
    for (int a = 0; a < n; ++a) X[3 * a] = m.x[en[a]], X[3 * a + 1] = m.y[en[a]], X[3 * a + 2] = m.z[en[a]];
  };
  auto quality_of = [&](const ElemRef& r) {
    std::vector<double> X;
    element_X(r, X);
    const auto& b = m.blocks[r.block];
    return model::element_quality(b.shape, b.order, X.data());
  };
  // det J of the straight element (vertices only) at its reference centroid
  auto straight_det = [&](const ElemRef& r) {
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
  };

  // Invalid elements inside the largest patch of an element that could not be repaired: their own
  // patches are nearly the same nodes and elements, so they are not tried again (an unrepairable
  // cluster, e.g. a folded face on the CAD, would otherwise cost max_rings attempts per member).
  std::vector<std::vector<char>> hopeless(m.blocks.size());
  for (std::uint32_t bi = 0; bi < m.blocks.size(); ++bi) hopeless[bi].assign(valid[bi].size(), 0);
  // Why an element is left invalid (untangle.hpp, "report"); 0 = not decided.
  enum Why : std::uint8_t { none, budget, stuck, not_repaired, degenerate, no_free, failed_patch, stage_budget, time_limit };
  static const char* const why_name[] = {"",           "budget",        "stuck",        "not repaired", "degenerate",
                                         "no free nodes", "in a failed patch", "no progress", "time limit"};
  std::vector<std::vector<std::uint8_t>> why(m.blocks.size());
  for (std::uint32_t bi = 0; bi < m.blocks.size(); ++bi) why[bi].assign(valid[bi].size(), none);
  std::size_t visited = 0;
  Budget B;
  B.t0 = B.last_tick = t0;
  B.element_limit = opt.element_budget;
  B.stage_limit = opt.stage_budget;
  B.time_limit = opt.time_limit;
  auto report_progress = [&] {
    if (progress)
      progress({visited, invalid.size(), rep.repaired, std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count()});
  };
  B.tick = report_progress;
  Why stopped = none;  // stage_budget or time_limit: the remaining elements are not tried
  for (const ElemRef& bad : invalid) {
    report_progress();
    ++visited;
    if (valid[bad.block][bad.index]) continue;  // repaired with an earlier patch
    if (hopeless[bad.block][bad.index]) {
      ++rep.skipped;
      why[bad.block][bad.index] = failed_patch;
      continue;
    }
    if (B.stage_limit > 0 && B.stage_used >= B.no_progress_limit()) {  // no progress: stop (checked between elements)
      why[bad.block][bad.index] = stage_budget;
      stopped = stage_budget;
      break;
    }
    B.element_used = 0;
    bool any_attempt = false, any_degenerate = false, last_stuck = false;
    int out = -1;  // OutOfBudget::Which, when a budget ran out on this element
    // element size h: mean vertex-edge length
    double h = 0;
    {
      const auto& b = m.blocks[bad.block];
      const std::uint32_t* en = b.element(bad.index);
      const auto& ev = model::edge_vertices(b.shape);
      for (auto [a, c] : ev)
        h += std::hypot(m.x[en[a]] - m.x[en[c]], m.y[en[a]] - m.y[en[c]], m.z[en[a]] - m.z[en[c]]);
      h /= double(ev.size());
    }
    if (!(h > 0)) {
      why[bad.block][bad.index] = degenerate;
      continue;
    }
    std::vector<ElemRef> patch{bad};
    bool done = false;
    for (int ring = 1; ring <= opt.max_rings && !done && out < 0; ++ring) {
      // grow the patch by one ring of node neighbours
      {
        std::vector<ElemRef> grown = patch;
        for (const ElemRef& r : patch) {
          const auto& b = m.blocks[r.block];
          const std::uint32_t* en = b.element(r.index);
          for (int a = 0; a < b.nodes_per_element(); ++a)
            for (std::uint32_t k = start[en[a]]; k < start[en[a] + 1]; ++k) grown.push_back(adj[k]);
        }
        std::sort(grown.begin(), grown.end());
        grown.erase(std::unique(grown.begin(), grown.end()), grown.end());
        patch = std::move(grown);
      }
      // mode 0 moves the off-CAD nodes only; mode 1 (with a shape) also slides the nodes inside
      // CAD faces on their faces: a wall face folded on the CAD cannot be repaired by the volume
      for (int mode = 0; mode < (shape && opt.surface ? 2 : 1) && !done && out < 0; ++mode) {
      Patch P(m);
      P.arena = &arena;
      P.shape = shape;
      P.h = h;
      P.target = opt.target;
      P.spring = opt.spring;
      // free nodes: off the CAD (mode 1: or sliding on a CAD face), not a vertex, every element in the patch
      bool any_sliding = false;
      for (const ElemRef& r : patch) {
        const auto& b = m.blocks[r.block];
        const std::uint32_t* en = b.element(r.index);
        for (int a = 0; a < b.nodes_per_element(); ++a) {
          const std::uint32_t v = en[a];
          const bool slide = mode == 1 && slides[v];
          if ((fixed[v] && !slide) || P.free_index.count(v)) continue;
          bool inside = true;
          for (std::uint32_t k = start[v]; k < start[v + 1] && inside; ++k)
            inside = std::binary_search(patch.begin(), patch.end(), adj[k]);
          if (!inside) continue;
          P.free_index.emplace(v, 0);
          any_sliding = any_sliding || slide;
        }
      }
      if (P.free_index.empty() || (mode == 1 && !any_sliding)) continue;
      int idx = 0;
      for (auto& [v, i] : P.free_index) {  // node order: deterministic
        i = idx++;
        P.free.push_back(v);
        P.x0.insert(P.x0.end(), {m.x[v], m.y[v], m.z[v]});
        P.var.push_back(P.nvars);
        if (mode == 1 && slides[v]) {
          const int f = m.node_entity_tag[v] - 1;
          const auto d = shape->face_eval(f, m.node_u[v], m.node_v[v]);
          const auto bnd = shape->face_uv_bounds(f);
          const auto per = shape->face_periods(f);
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
        const double j = straight_det(r);
        // degenerate: its straight version has no volume, or a relative one (det J / longest
        // vertex edge^3) below kMinRelativeVolume (coincident nodes: aspect ratio 1e14, the
        // target det J / det J_straight is meaningless and the optimiser only grinds)
        double L = 0;
        {
          const auto& b = m.blocks[r.block];
          const std::uint32_t* en = b.element(r.index);
          for (auto [a, c] : model::edge_vertices(b.shape))
            L = std::max(L, std::hypot(m.x[en[a]] - m.x[en[c]], m.y[en[a]] - m.y[en[c]], m.z[en[a]] - m.z[en[c]]));
        }
        if (!(j > kMinRelativeVolume * L * L * L)) degenerate = true;
        P.elems.push_back(r);
        P.slots.push_back(std::move(slot));
        P.jref.push_back(j);
      }
      if (degenerate) {  // a straight element is not valid: nothing to aim at
        any_degenerate = true;
        continue;
      }
      // never worse: a repair must not leave any element of the patch below the worst before
      // (the invalid element's scaled Jacobian, or another invalid one's if lower)
      double worst_before = INFINITY;
      // early exit's floor per element: its own scaled Jacobian before, or kEarlyExitFloor if
      // that is higher (an invalid one: kEarlyExitFloor)
      std::vector<double> sj_floor;
      for (const ElemRef& r : P.elems) {
        const double sj = quality_of(r).scaled_jacobian;
        worst_before = std::min(worst_before, sj);
        sj_floor.push_back(valid[r.block][r.index] ? std::min(sj, kEarlyExitFloor) : kEarlyExitFloor);
      }
      // the target on the coarse samples first, then a higher one on the dense samples: samples
      // just above the target can leave det J negative between them, which the Bezier check
      // finds; then (tets, prisms) half the target on det J's Bernstein coefficients, which see the dips
      for (int attempt = 0; attempt < 3 && !done && out < 0; ++attempt) {
        P.target = attempt == 0 ? opt.target : attempt == 1 ? std::max(opt.target, std::min(1.0, 2.5 * opt.target)) : 0.5 * opt.target;
        P.lattice = attempt;
        if (attempt == 2 && std::none_of(P.elems.begin(), P.elems.end(), [&](const ElemRef& r) {
              return has_bezier_lattice(m.blocks[r.block].shape, m.blocks[r.block].order);
            }))
          break;  // no tet or prism: the third attempt would repeat the second
        ++rep.attempts;
        any_attempt = true;

        LBFGSpp::LBFGSParam<double> param;
        param.m = 8;
        param.epsilon = 1e-10;
        param.epsilon_rel = 0;
        // the coefficients' penalty is stiffer (T's entries are large): more iterations
        param.max_iterations = attempt == 2 ? 4 * opt.max_iterations : opt.max_iterations;
        param.max_linesearch = 40;
        LBFGSpp::LBFGSSolver<double> solver(param);
        Eigen::VectorXd y = Eigen::VectorXd::Zero(P.nvars);
        double fx = 0;
        int iters = 0;
        bool early = false;
        const auto ta = std::chrono::steady_clock::now();
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
        P.worst_before = worst_before;
        P.sj_floor = sj_floor;
        P.must_valid.clear();
        for (const ElemRef& r : P.elems) P.must_valid.push_back(valid[r.block][r.index] || r == bad);
        try {
          iters = solver.minimize(P, y, fx);
        } catch (const AcceptedPoint& a) {
          y = a.y;
          early = true;
        } catch (const OutOfBudget& e) {
          // nothing was applied to the mesh yet: give up on this element (or on all, stage/time)
          out = e.which;
          break;
        } catch (const std::exception&) {
          // a failed line search leaves y at the last accepted point, which is a descent of the energy
        }
        P.budget = nullptr;  // the diagnostic evaluation below is not charged
        P.check_every = 0;
        rep.early_exits += early;
        // a diverged line search can leave non-finite values: that attempt failed, nothing moves
        if (!y.allFinite()) continue;
        // apply, check, keep or restore
        for (std::size_t i = 0; i < P.free.size(); ++i) {
          const std::uint32_t v = P.free[i];
          if (P.face[i] < 0) {
            m.x[v] = P.x0[3 * i] + h * y[P.var[i]];
            m.y[v] = P.x0[3 * i + 1] + h * y[P.var[i] + 1];
            m.z[v] = P.x0[3 * i + 2] + h * y[P.var[i] + 2];
          } else {
            double p[2];
            bool cl[2];
            P.params(i, y, p, cl);
            const auto x = shape->face_point(P.face[i], p[0], p[1]);
            m.x[v] = x.x, m.y[v] = x.y, m.z[v] = x.z;
            m.node_u[v] = p[0], m.node_v[v] = p[1];
          }
        }
        bool ok = true;
        std::vector<std::pair<ElemRef, char>> now;
        for (const ElemRef& r : P.elems) {
          const auto q = quality_of(r);
          const char v = q.valid ? 1 : 0;
          now.push_back({r, v});
          if (valid[r.block][r.index] && !v) ok = false;
          if (r == bad && !v) ok = false;
          if (q.scaled_jacobian < worst_before) ok = false;
        }
        if (log) {
          Eigen::VectorXd g0(y.size()), z0 = Eigen::VectorXd::Zero(y.size());
          char line[256];
          std::snprintf(line, sizeof line, "untangle: element %u/%u ring %d%s: %zu free nodes, %zu elements, energy %g -> %g, %d iterations%s, %.2f s: %s",
                        bad.block, bad.index, ring, mode ? " sliding on the CAD" : "", P.free.size(), P.elems.size(), P(z0, g0), fx, iters, early ? " (stopped early: acceptable)" : "",
                        std::chrono::duration<double>(std::chrono::steady_clock::now() - ta).count(), ok ? "repaired" : "not repaired");
          log(line);
          for (auto& [r, v] : now)
            if (!v) {
              std::snprintf(line, sizeof line, "untangle:   still invalid %u/%u (valid before: %d)", r.block, r.index, int(valid[r.block][r.index]));
              log(line);
            }
        }
        if (!ok) {
          // the coarse attempt left the energy at or above one sample's full penalty (target^2,
          // a sample at r <= 0 alone costs that much): the patch is stuck far from valid, and the
          // later attempts (a higher target on more samples, then det J's Bernstein coefficients,
          // both harder to satisfy) cannot do better; they cost up to 10 x the first (Rotor 67:
          // 1.3 and 8 s after 0.5 s on a 45-element patch, 5 and 29 s on 281 elements)
          const bool stuck = attempt == 0 && fx >= P.target * P.target;
          if (stuck) ++rep.stuck;
          last_stuck = stuck;
          for (std::size_t i = 0; i < P.free.size(); ++i) {
            const std::uint32_t v = P.free[i];
            m.x[v] = P.x0[3 * i];
            m.y[v] = P.x0[3 * i + 1];
            m.z[v] = P.x0[3 * i + 2];
            if (P.face[i] >= 0) m.node_u[v] = P.uv0[2 * i], m.node_v[v] = P.uv0[2 * i + 1];
          }
          if (stuck) break;
          continue;
        }
        for (auto& [r, v] : now) valid[r.block][r.index] = v;
        for (std::size_t i = 0; i < P.free.size(); ++i) {
          const std::uint32_t v = P.free[i];
          const double d = std::hypot(m.x[v] - P.x0[3 * i], m.y[v] - P.x0[3 * i + 1], m.z[v] - P.x0[3 * i + 2]) / h;
          if (d > 0) ++(P.face[i] < 0 ? rep.nodes_moved : rep.surface_nodes_moved);
          rep.max_move = std::max(rep.max_move, d);
        }
        ++rep.repaired;
        B.repair_work += B.element_used;
        B.stage_used = 0;  // progress: the no-progress budget starts again
        ++rep.repaired_at_ring[ring - 1];
        rep.repaired_sliding += mode == 1;
        done = true;
      }
      }
    }
    rep.max_element_work = std::max(rep.max_element_work, B.element_used);
    if (done) continue;
    Why w = out == OutOfBudget::element ? budget
            : out == OutOfBudget::time  ? time_limit
            : any_attempt               ? (last_stuck ? stuck : not_repaired)
            : any_degenerate            ? degenerate
                                        : no_free;
    why[bad.block][bad.index] = w;
    if (w == stage_budget || w == time_limit) {
      stopped = w;
      break;
    }
    if (w == budget) ++rep.budget_exhausted;
    for (const ElemRef& r : patch)
      if (!valid[r.block][r.index]) hopeless[r.block][r.index] = 1;
  }
  rep.work = B.total;
  rep.repair_work = B.repair_work;
  rep.stage_budget_exhausted = stopped == stage_budget;
  rep.time_limit_fired = stopped == time_limit;

  std::uint64_t running = 0;
  for (std::uint32_t bi = 0; bi < m.blocks.size(); ++bi) {
    const auto& b = m.blocks[bi];
    for (std::uint32_t e = 0; e < valid[bi].size(); ++e)
      if (!valid[bi][e]) {
        ++rep.invalid_after;
        // not reached: the no-progress budget or the time limit stopped the loop before it
        const Why w = why[bi][e] != none ? Why(why[bi][e]) : stopped != none ? stopped : not_repaired;
        ++rep.unrepaired_by_reason[why_name[w]];
        if (int(rep.unrepaired.size()) >= opt.max_listed) continue;
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
  rep.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return rep;
}

}  // namespace meshflow::optimise
