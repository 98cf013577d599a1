// The shell stage on the parametric naca_wing (geometry -> heal -> medial -> shell, in-process
// through the test StageContext, and once through `meshflow run`).
#include <doctest/doctest.h>

#include <set>

#include "support.hpp"

#include "../cad/test_context.hpp"
#include "wall_inputs.hpp"
#include "engine/stage.hpp"
#include "stages/cad/cad.hpp"
#include "stages/medial/medial.hpp"
#include "stages/shell/shell.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <map>
#include <memory>
#include <sstream>

using meshflow::Artifact;
using meshflow::StageError;
using meshflow::testing::TestContext;
namespace sh = meshflow::shell;

namespace {

// the shortest offset of a sampled shell point from its wall point
double min_offset(const sh::ShellData& d) {
  double t = INFINITY;
  for (std::size_t i = 0; i < d.shell_points.size(); ++i) {
    const auto &p = d.shell_points[i], &w = d.shell_wall[i];
    t = std::min(t, std::hypot(p[0] - w[0], p[1] - w[1], p[2] - w[2]));
  }
  return t;
}

// geometry -> heal -> medial once per geometry variant
struct Inputs : shelltest::WallInputs {
  explicit Inputs(const nlohmann::json& geo_params) : WallInputs("naca_wing", geo_params) {}
};
Inputs& default_wing() {
  static Inputs in(nlohmann::json{{"incidence_deg", 0.0}});
  return in;
}

long count_kind(const sh::ShellData& d, const std::string& kind) {
  long n = 0;
  nlohmann::json h = nlohmann::json::parse(d.header);
  for (auto& b : h.at("blocks")) n += b.at("kind") == kind;
  return n;
}
}  // namespace

TEST_CASE("shell on naca_wing, topology C: no self-intersection, junction blocks at the root, deterministic bytes") {
  Inputs& in = default_wing();
  TestContext a("shell", {{"topology", "C"}}, {in.shape, in.medial}), b("shell", {{"topology", "C"}}, {in.shape, in.medial});
  a.run();
  b.run();
  MESSAGE("shell C stats: " << a.stats_.dump());
  CHECK(mftest::read_text(a.artifact("shell").path) == mftest::read_text(b.artifact("shell").path));
  CHECK(a.progress_ok_);
  CHECK(a.stats_.at("self_intersections").get<long>() == 0);
  CHECK(a.stats_.at("faces_unsampled").get<long>() == 0);
  sh::ShellData d = sh::read(a.artifact("shell").path);
  CHECK(d.shell_tris.size() > 1000);
  auto shape = meshflow::cad::Shape::load(in.shape.path);
  auto sym = shape.faces_with_tag(meshflow::cad::Tag::symmetry);
  REQUIRE(sym.size() == 1);
  // junction blocks: every one at the root (z = 0), partner the symmetry face, ~90 degrees
  long nj = 0;
  nlohmann::json hdr = nlohmann::json::parse(d.header);
  for (auto& blk : hdr.at("blocks")) {
    if (blk.at("kind") != "hex_junction") continue;
    ++nj;
    CHECK(blk.at("partner").get<int>() == sym[0]);
    CHECK(std::abs(blk.at("fluid_angle_deg").get<double>() - 90) < 5);
    CHECK(blk.at("equal").size() == 3);
    for (auto& st : blk.at("stations")) {
      CHECK(std::abs(st.at("P0")[2].get<double>()) < 1e-6);
      // the strip boundary on the partner (root wall) stays on it; the outer corner is above it
      CHECK(std::abs(st.at("PB")[2].get<double>()) < 1e-6);
      CHECK(st.at("PC")[2].get<double>() > 0);
    }
  }
  CHECK(nj >= 1);
  CHECK(nj == count_kind(d, "hex_junction"));
  CHECK(count_kind(d, "prism_sweep") == static_cast<long>(shape.faces_with_tag(meshflow::cad::Tag::wall).size()));
  // the shell stays off the walls: every shell point at least ~half its thickness from them
  double T = a.stats_.at("thickness_requested").get<double>();
  CHECK(a.stats_.at("min_clearance").at("walls").get<double>() > 0.1 * a.stats_.at("thickness").at("min").get<double>());
  CHECK(a.stats_.at("min_clearance").at("farfield").get<double>() > T);
  // every shell point = wall point + thickness x unit direction, thickness within (0, T]
  for (std::size_t i = 0; i < d.shell_points.size(); ++i) {
    double l = std::hypot(d.shell_points[i][0] - d.shell_wall[i][0], d.shell_points[i][1] - d.shell_wall[i][1],
                          d.shell_points[i][2] - d.shell_wall[i][2]);
    CHECK(l > 0);
    CHECK(l <= T * (1 + 1e-9));
  }
  // sweep directions point into the fluid: away from the wall's outward (into-body) normal
  long bad_dir = 0, checked = 0;
  for (auto& g : d.faces)
    for (int j = 0; j < g.nv; j += 4)
      for (int i = 0; i < g.nu; i += 4) {
        double u = g.u0 + (g.u1 - g.u0) * i / (g.nu - 1), v = g.v0 + (g.v1 - g.v0) * j / (g.nv - 1);
        if (!shape.face_contains_uv(g.face, u, v)) continue;
        auto x = shape.face_point(g.face, u, v);
        bool at_vertex = false;  // poles of the round tip: the normal is a limit there
        for (int vx = 0; vx < shape.num_vertices(); ++vx) {
          auto q = shape.vertex_point(vx);
          at_vertex |= std::hypot(q.x - x.x, q.y - x.y, q.z - x.z) < 5e-3;  // fans at the tip poles
        }
        if (at_vertex) continue;
        auto n = shape.face_normal(g.face, u, v);
        auto [t, dd] = d.face_field(g.face, u, v);
        ++checked;
        if (dd[0] * n.x + dd[1] * n.y + dd[2] * n.z > 0.2) {  // into the body (near-tangent allowed: fans at sharp convex edges)
          if (++bad_dir < 5) MESSAGE("direction not into the fluid: face " << g.face << " at " << shape.face_point(g.face, u, v).x << " " << shape.face_point(g.face, u, v).y << " " << shape.face_point(g.face, u, v).z);
        }
      }
  CHECK(checked > 100);
  CHECK(bad_dir == 0);
  // continuity at shared edges: the face grid next to an edge agrees with the edge field
  // (an edge shorter than two cells of a face's grid, e.g. the 0.004-long trailing-edge arc of
  // the round tip, varies faster than that grid can follow: it is counted and skipped; the
  // sweep takes the edge field for nodes on it)
  double worst = 0;
  std::set<int> unresolved;
  for (auto& e : d.edges) {
    if (e.sides.size() != 1) continue;
    for (int f : shape.edge_faces(e.edge)) {
      const meshflow::shell::FaceGrid* G = nullptr;
      for (auto& g : d.faces)
        if (g.face == f) G = &g;
      if (!G) continue;
      {
        double tm = 0.5 * (e.t0 + e.t1);
        auto uv = shape.edge_uv(e.edge, f, tm);
        double du = (G->u1 - G->u0) / (G->nu - 1), dv = (G->v1 - G->v0) / (G->nv - 1);
        auto p0 = shape.face_point(f, uv.u, uv.v), pu = shape.face_point(f, uv.u + du, uv.v), pv = shape.face_point(f, uv.u, uv.v + dv);
        double cell = std::max(std::hypot(pu.x - p0.x, pu.y - p0.y, pu.z - p0.z), std::hypot(pv.x - p0.x, pv.y - p0.y, pv.z - p0.z));
        if (shape.edge_length(e.edge) < 2 * cell) {
          unresolved.insert(e.edge);
          MESSAGE("edge " << e.edge << " (length " << shape.edge_length(e.edge) << ") is shorter than two grid cells (" << cell << ") of face " << f);
          continue;
        }
      }
      for (int k = 1; k < 8; ++k) {
        double t = e.t0 + (e.t1 - e.t0) * k / 8;
        auto uv = shape.edge_uv(e.edge, f, t);
        auto [tf, df] = d.face_field(f, uv.u, uv.v);
        auto [te, de] = d.edge_field(e.edge, t, f);
        double c = df[0] * de[0] + df[1] * de[1] + df[2] * de[2];
        double ang = std::acos(std::clamp(c, -1.0, 1.0)) * 180 / M_PI;
        if (ang > worst) {
          worst = ang;
          auto p = shape.edge_point(e.edge, t);
          MESSAGE("edge " << e.edge << " face " << f << " at " << p.x << " " << p.y << " " << p.z << ": " << ang << " deg");
        }
      }
    }
  }
  MESSAGE("largest angle between face-grid and edge-field directions on the edges: " << worst << " deg");
  CHECK(worst < 15);
  CHECK(unresolved.size() <= 2);  // the blunt trailing edge's tip arc and root edge only
}

TEST_CASE("shell on naca_wing, topology O: no junction blocks, no self-intersection, lfs bound thins the trailing edge") {
  Inputs& in = default_wing();
  TestContext o("shell", {{"topology", "O"}}, {in.shape, in.medial});
  o.run();
  sh::ShellData d = sh::read(o.artifact("shell").path);
  CHECK(count_kind(d, "hex_junction") == 0);
  CHECK(o.stats_.at("counts").at("junction_edges").get<long>() == 0);
  CHECK(o.stats_.at("self_intersections").get<long>() == 0);

  // The fluid-side medial radius of a convex wing only sees the far field and the root wall:
  // at 0.05 chord nothing is reduced. Measure the trailing edge and then thin it by the LFS.
  auto M = meshflow::medial::read(in.medial.path);
  double rin_te = INFINITY, lfs_te = INFINITY;
  for (std::size_t i = 0; i < M.samples.size(); ++i)
    if (M.samples[i].refined && M.samples[i].p[0] > 0.99 && M.samples[i].p[2] > 0.2 && M.samples[i].p[2] < 0.8) {
      if (M.info[i].r_in > 0) rin_te = std::min(rin_te, M.info[i].r_in);
      lfs_te = std::min(lfs_te, M.info[i].lfs);
    }
  MESSAGE("trailing edge (x > 0.99, mid span): min fluid medial radius " << rin_te << ", min LFS " << lfs_te);
  TestContext l("shell", {{"lfs_factor", 1.0}}, {in.shape, in.medial});
  l.run();
  MESSAGE("shell lfs_factor=1 stats: " << l.stats_.dump());
  // known: the LFS-thinned shell has had one crossing pair near the root leading edge
  WARN(l.stats_.at("self_intersections").get<long>() == 0);
  sh::ShellData dl = sh::read(l.artifact("shell").path);
  auto shape = meshflow::cad::Shape::load(in.shape.path);
  // thickness along the chord at mid span on the shell sample points
  double t_te = INFINITY, t_mid = 0;
  for (std::size_t i = 0; i < dl.shell_points.size(); ++i) {
    auto& w = dl.shell_wall[i];
    if (w[2] < 0.3 || w[2] > 0.7) continue;
    double t = std::hypot(dl.shell_points[i][0] - w[0], dl.shell_points[i][1] - w[1], dl.shell_points[i][2] - w[2]);
    if (w[0] > 0.995) t_te = std::min(t_te, t);
    if (w[0] > 0.3 && w[0] < 0.5) t_mid = std::max(t_mid, t);
  }
  double T = l.stats_.at("thickness_requested").get<double>();
  MESSAGE("lfs_factor=1: thickness at the trailing edge " << t_te << ", at mid-chord " << t_mid << " (requested " << T << ")");
  CHECK(t_te < 0.1 * T);
  CHECK(t_te <= 1.5 * lfs_te + 1e-3 * T);
  CHECK(t_mid > 0.99 * T);
  CHECK(l.stats_.at("not_honoured").at("samples").get<long>() > 0);
  // the thickness field is max_gradient-Lipschitz along the grids (no steps)
  double g = l.params().at("max_gradient").get<double>(), worst = 0;
  for (auto& G : dl.faces)
    for (int j = 0; j < G.nv; ++j)
      for (int i = 0; i + 1 < G.nu; ++i) {
        double u = G.u0 + (G.u1 - G.u0) * i / (G.nu - 1), u1 = G.u0 + (G.u1 - G.u0) * (i + 1) / (G.nu - 1);
        double v = G.v0 + (G.v1 - G.v0) * j / (G.nv - 1);
        auto p = shape.face_point(G.face, u, v), q = shape.face_point(G.face, u1, v);
        double dx = std::hypot(p.x - q.x, p.y - q.y, p.z - q.z);
        double dt = std::abs(G.data[(std::size_t(j) * G.nu + i) * 4] - G.data[(std::size_t(j) * G.nu + i + 1) * 4]);
        if (dx > 1e-9) worst = std::max(worst, dt / dx);
      }
  MESSAGE("largest thickness gradient along u on the grids: " << worst << " (limit " << g << ")");
  CHECK(worst <= g * 1.05 + 1e-9);
}

TEST_CASE("shell: the medial radius bounds the thickness in a narrow far field, too thick everywhere is an error") {
  Inputs in(nlohmann::json{{"incidence_deg", 0.0}, {"farfield_chords", 0.5}, {"wake_chords", 0.5}, {"span", 0.8}});
  TestContext s("shell", {{"thickness", 0.15}}, {in.shape, in.medial});
  s.run();
  MESSAGE("narrow box, thickness 0.15 chord: " << s.stats_.dump());
  CHECK(s.stats_.at("not_honoured").at("limited_by_medial").get<long>() > 0);
  CHECK(s.stats_.at("thickness").at("min").get<double>() < 0.15);
  // known open problem: at 0.15 chord the blunt trailing-edge fan of this narrow case crosses
  // the neighbouring lower-surface shell (hundreds of pairs behind the trailing edge)
  WARN(s.stats_.at("self_intersections").get<long>() == 0);
  // no shell point reaches the far-field box, which is 0.5 chord away
  CHECK(s.stats_.at("min_clearance").at("farfield").get<double>() > 0.1);
  // a thickness no wall sample can hold
  TestContext big("shell", {{"thickness", 100.0}, {"thickness_relative_to", "length"}}, {in.shape, in.medial});
  bool thrown = false;
  try {
    big.run();
  } catch (const StageError& e) {
    thrown = true;
    MESSAGE("error: " << std::string(e.what()));
    CHECK(std::string(e.what()).find("thickness") != std::string::npos);
  }
  CHECK(thrown);
}

TEST_CASE("shell: cdt2 triangulates a square with a hole and refuses crossing segments") {
  std::vector<std::array<double, 2>> p = {{0, 0}, {1, 0}, {1, 1}, {0, 1}, {0.4, 0.4}, {0.6, 0.4}, {0.6, 0.6}, {0.4, 0.6}};
  std::vector<std::array<std::int32_t, 2>> seg = {{0, 1}, {1, 2}, {2, 3}, {3, 0}, {4, 5}, {5, 6}, {6, 7}, {7, 4}};
  auto t = sh::cdt2(p, seg);
  CHECK(t.size() == 10);  // 2n - 2 - hull = 16 - 2 - 4
  for (auto& tri : t)
    for (int c : tri) CHECK((c >= 0 && c < 8));
  // nesting depth: the 8 triangles between the loops have depth 1, the 2 of the hole depth 2
  std::vector<int> depth;
  CHECK(sh::cdt2(p, seg, &depth) == t);
  REQUIRE(depth.size() == t.size());
  CHECK(std::count(depth.begin(), depth.end(), 1) == 8);
  CHECK(std::count(depth.begin(), depth.end(), 2) == 2);
  // the two diagonals of the square cross: the intersection point would be a new vertex with no
  // input index (this used to crash the shell on DLR-F6, where station chords crossed in (u,v))
  seg.push_back({0, 2});
  seg.push_back({1, 3});
  CHECK_THROWS_AS(sh::cdt2(p, seg), std::runtime_error);
}

TEST_CASE("shell: refuses missing inputs") {
  TestContext none("shell", {}, {});
  CHECK_THROWS_AS(none.run(), StageError);
  TestContext bogus("shell", {}, {Artifact{.name = "shape", .type = "shape", .path = "/nonexistent/x.mfshape"},
                                  Artifact{.name = "medial", .type = "medial", .path = "/nonexistent/x.mfmedial"}});
  CHECK_THROWS_AS(bogus.run(), StageError);
}

TEST_CASE("meshflow run: geometry -> heal -> medial -> shell, artifact summary") {
  namespace fs = std::filesystem;
  fs::path dir = meshflow::testing::scratch_dir("shell-e2e");
  {
    std::ofstream w(dir / "wf.yaml");
    w << "meshflow: 1\nname: shell-e2e\nstages:\n"
         "  geometry: {kind: naca_wing}\n"
         "  heal: {kind: heal, needs: [geometry]}\n"
         "  medial: {kind: medial, needs: [heal]}\n"
         "  shell: {kind: shell, needs: [heal, medial], with: {thickness: 0.05, topology: C}}\n"
         "outputs:\n  shell: {from: shell}\n";
  }
  std::string cmd = std::string(MESHFLOW_EXE) + " run " + (dir / "wf.yaml").string() + " --threads 2 --cache " +
                    (dir / "cache").string() + " --out " + (dir / "out").string() + " > " + (dir / "log").string() + " 2>&1";
  int rc = std::system(cmd.c_str());
  if (rc != 0) MESSAGE(mftest::read_text(dir / "log"));
  REQUIRE(rc == 0);
  sh::ShellData d = sh::read(dir / "out" / "shell.mfshell");
  nlohmann::json s = d.summary();
  CHECK(s.at("blocks").at("hex_junction").get<long>() >= 1);
  CHECK(s.at("stats").at("self_intersections").get<long>() == 0);
  std::filesystem::remove_all(dir);
}

// The paper's wing as CAD (STEP in mm: NACA 0012, round tip, root on the tunnel wall; 9 faces).
// Default medial and shell settings: medial about 3 s, each shell about 4 s (Release).
TEST_CASE("shell on the wing STEP: junction blocks at the root (C) and none (O), thinner near the tunnel floor at the trailing edge, deterministic") {
  namespace fs = std::filesystem;
  const fs::path file = fs::path(MESHFLOW_DATA_DIR) / "wingtip/3d_bl_wing.stp";
  TestContext geo("step", {{"file", file.string()}});
  geo.run();
  TestContext heal("heal", nlohmann::json::object(), {geo.artifact("shape")});
  heal.run();
  TestContext med("medial", nlohmann::json::object(), {heal.artifact("shape")});
  med.run();
  Artifact shape = heal.artifact("shape"), medial = med.artifact("medial");
  TestContext a("shell", nlohmann::json::object(), {shape, medial}), b("shell", nlohmann::json::object(), {shape, medial});
  a.run();
  b.run();
  MESSAGE("wing STEP shell C: " << a.stats_.dump());
  CHECK(mftest::read_text(a.artifact("shell").path) == mftest::read_text(b.artifact("shell").path));
  CHECK(a.stats_.at("faces_unsampled").get<long>() == 0);
  // 35 crossing pairs before the directions were blended along the face (uv path) as rotations,
  // 11 before the sampled faces kept their CDT triangles by nesting depth (zero-area triangles of
  // one edge's stations outside the loop, at the root of the trailing-edge face and at the tip's
  // trailing edge, had been kept); the fold near the leading edge of the round tip is thinned
  long pairs = a.stats_.at("self_intersections").get<long>();
  // (crossing_rounds, default 8: 9 pairs there before thinning, see the crossing_rounds 0 run below)
  CHECK(pairs == 0);
  CHECK(a.stats_.at("sampling_refined_faces").is_array());
  auto cs = meshflow::cad::Shape::load(shape.path);
  auto sym = cs.faces_with_tag(meshflow::cad::Tag::symmetry);
  REQUIRE(sym.size() == 1);
  sh::ShellData d = sh::read(a.artifact("shell").path);
  nlohmann::json hdr = nlohmann::json::parse(d.header);
  long nj = 0;
  for (auto& blk : hdr.at("blocks")) {
    if (blk.at("kind") != "hex_junction") continue;
    ++nj;
    CHECK(blk.at("partner").get<int>() == sym[0]);  // the tunnel wall at the root, z = 0
    CHECK(std::abs(blk.at("fluid_angle_deg").get<double>() - 90) < 5);
    for (auto& st : blk.at("stations")) CHECK(std::abs(st.at("P0")[2].get<double>()) < 1e-3);
  }
  CHECK(nj == 3);  // the root: two curves (the profile is split in two edges) and the blunt trailing-edge strip
  CHECK(count_kind(d, "prism_sweep") == static_cast<long>(cs.faces_with_tag(meshflow::cad::Tag::wall).size()));
  // The tunnel floor (y = -0.4) is about 193 mm below the trailing edge: the fluid medial ball
  // there has radius ~96, alpha 0.5 gives ~48 < T = 60. Mid-chord the requested thickness holds.
  double T = a.stats_.at("thickness_requested").get<double>();
  CHECK(a.stats_.at("not_honoured").at("limited_by_medial").get<long>() > 0);
  double t_te = INFINITY, t_mid = 0;
  for (std::size_t i = 0; i < d.shell_points.size(); ++i) {
    auto& w = d.shell_wall[i];
    if (w[2] < 100 || w[2] > 700) continue;
    double t = std::hypot(d.shell_points[i][0] - w[0], d.shell_points[i][1] - w[1], d.shell_points[i][2] - w[2]);
    if (w[0] > 1300) t_te = std::min(t_te, t);
    if (w[0] > 500 && w[0] < 900) t_mid = std::max(t_mid, t);
  }
  MESSAGE("wing STEP: thickness near the trailing edge " << t_te << ", mid-chord " << t_mid << ", requested " << T);
  CHECK(t_te < 0.9 * T);
  CHECK(t_mid > 0.99 * T);
  // topology O: no junction block, the same walls
  TestContext o("shell", {{"topology", "O"}}, {shape, medial});
  o.run();
  sh::ShellData dO = sh::read(o.artifact("shell").path);
  CHECK(count_kind(dO, "hex_junction") == 0);
  CHECK(o.stats_.at("counts").at("junction_edges").get<long>() == 0);
  CHECK(o.stats_.at("self_intersections").get<long>() == 0);
  // crossing_rounds 0: no thinning; the fold at the round tip's leading edge stays (its two edges
  // are blended towards the leading-edge vertex over 2 thicknesses, up to 47 degrees off their
  // normals); the default run thinned only there, deterministically
  TestContext t0("shell", {{"crossing_rounds", 0}}, {shape, medial});
  t0.run();
  long raw_pairs = t0.stats_.at("self_intersections").get<long>();
  MESSAGE("wing STEP shell: " << raw_pairs << " crossing pairs without thinning, " << pairs << " with: "
                              << a.stats_.at("not_honoured").dump());
  CHECK(raw_pairs > 0);
  CHECK(raw_pairs <= 9);
  CHECK_FALSE(t0.stats_.at("not_honoured").contains("thinned_for_crossings"));
  REQUIRE(a.stats_.at("not_honoured").contains("thinned_for_crossings"));
  const auto& tc = a.stats_.at("not_honoured").at("thinned_for_crossings");
  CHECK(tc.at("rounds").get<int>() >= 1);
  CHECK(tc.at("crossings_before").get<long>() == raw_pairs);
  CHECK(tc.at("min_scale").get<double>() >= 0.2 - 1e-9);
  CHECK(a.stats_.at("min_clearance").at("walls_over_thickness").get<double>() >=
        0.5 * t0.stats_.at("min_clearance").at("walls_over_thickness").get<double>());
  // thinner somewhere, never below the floor
  sh::ShellData d0 = sh::read(t0.artifact("shell").path);
  const double tmin_a = min_offset(d), tmin_0 = min_offset(d0);
  CHECK(tmin_a < tmin_0);
  CHECK(tmin_a >= 0.19 * tmin_0);
}
