// Accuracy of the medial object on shapes with known medial objects (at the default
// parameters), the artifact round trip, bad input, and the stage on the naca_wing geometry.
#include <doctest/doctest.h>

#include "support.hpp"

#include "../cad/test_context.hpp"
#include "analytic.hpp"
#include "engine/stage.hpp"
#include "stages/medial/medial.hpp"

#include <tbb/task_arena.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <sstream>

using meshflow::StageError;
using namespace meshflow::medial;
using mftest::AnalyticModel;

namespace {


bool on_face(const MedialObject& M, const MedialPoint& p, int face) {
  for (auto q : p.contacts)
    for (int f : M.samples[q].faces)
      if (f == face) return true;
  return false;
}

struct Err {
  double worst = 0;
  long n = 0;
  void add(double e) {
    worst = std::max(worst, e);
    ++n;
  }
};

// Runs the whole method (default parameters) on a model.
MedialObject run(const BoundaryModel& m, RunReport* rep = nullptr) { return compute(m, Params{}, rep); }

}  // namespace

TEST_CASE("slab between two parallel planes: the mid-plane, radius = half gap") {
  const double g = 1.0, L = 10.0;
  AnalyticModel m;
  m.box({0, 0, 0}, {L, L, g}, true, true);
  RunReport rep;
  MedialObject M = run(m, &rep);
  Err rad, pos, lfs;
  for (auto& p : M.points) {
    if (p.side != Side::fluid) continue;
    // away from the side walls (where the medial axis branches to the edges)
    if (std::min({p.c[0], p.c[1], L - p.c[0], L - p.c[1]}) < 1.5 * g) continue;
    rad.add(std::abs(p.radius - g / 2) / g);
    pos.add(std::abs(p.c[2] - g / 2) / g);
  }
  long halo_top = 0, top = 0;
  for (std::size_t i = 0; i < M.samples.size(); ++i) {
    auto& s = M.samples[i];
    if (s.kind != 0 || std::min({s.p[0], s.p[1], L - s.p[0], L - s.p[1]}) < 2 * g) continue;
    lfs.add(std::abs(M.info[i].lfs - g / 2) / g);
    if (s.id == 5) {
      ++top;
      halo_top += M.info[i].halo_face == 4;  // the top (+z, 5) collides with the bottom (-z, 4)
    }
  }
  MESSAGE("slab: samples " << M.samples.size() << ", mid-plane points " << rad.n << ", radius error/gap " << rad.worst
                           << ", off-plane/gap " << pos.worst << ", lfs error/gap " << lfs.worst);
  CHECK(rad.n > 1000);
  CHECK(rad.worst < 0.02);
  CHECK(pos.worst < 0.02);
  CHECK(lfs.worst < 0.02);
  CHECK(top > 100);
  CHECK(halo_top >= 0.95 * top);
  CHECK(rep.samples_per_pass.size() == 2);
}

TEST_CASE("sphere inside a box: the centre (body side) and the sphere-box medial surface (fluid side)") {
  AnalyticModel m;
  m.box({-2, -2, -2}, {2, 2, 2}, true, false);  // far field
  m.sphere({0, 0, 0}, 1.0, true, true);         // the wall: face 6
  MedialObject M = run(m);
  Err centre, body_r, fluid_r, fluid_pos;
  for (auto& p : M.points) {
    double d_sph = mftest::norm(p.c) - 1.0;
    double d_box = 2.0 - std::max({std::abs(p.c[0]), std::abs(p.c[1]), std::abs(p.c[2])});
    if (p.side == Side::body) {
      if (!on_face(M, p, 6)) continue;
      centre.add(mftest::norm(p.c));
      body_r.add(std::abs(p.radius - 1.0));
    } else if (p.halo && on_face(M, p, 6)) {
      // touches the sphere and the box: equidistant from both, radius = that distance
      double d = std::min(d_sph, d_box);
      fluid_r.add(std::abs(p.radius - d) / d);
      fluid_pos.add(std::abs(d_sph - d_box) / 2 / d);
    }
  }
  MESSAGE("sphere: samples " << M.samples.size() << ", body points " << centre.n << " (|c|/R max " << centre.worst
                             << ", radius error/R " << body_r.worst << "), fluid sphere-box points " << fluid_r.n
                             << " (radius error/r " << fluid_r.worst << ", off-medial/r " << fluid_pos.worst << ")");
  CHECK(centre.n > 0);
  CHECK(centre.worst < 0.02);
  CHECK(body_r.worst < 0.02);
  CHECK(fluid_r.n > 100);
  CHECK(fluid_r.worst < 0.02);
  CHECK(fluid_pos.worst < 0.02);
}

TEST_CASE("cylinder: the axis, radius = R") {
  const double R = 1.0, L = 4.0;
  AnalyticModel m = mftest::cylinder(R, L);
  MedialObject M = run(m);
  Err axis, rad;
  for (auto& p : M.points) {
    if (p.side != Side::fluid || p.c[2] < 1.5 * R || p.c[2] > L - 1.5 * R) continue;
    axis.add(std::hypot(p.c[0], p.c[1]) / R);
    rad.add(std::abs(p.radius - R) / R);
  }
  MESSAGE("cylinder: samples " << M.samples.size() << ", axis points " << axis.n << ", distance to axis/R " << axis.worst
                               << ", radius error/R " << rad.worst);
  CHECK(axis.n > 20);
  CHECK(axis.worst < 0.02);
  CHECK(rad.worst < 0.02);
}

TEST_CASE("concave 90 degree corner: a block on a floor, the bisector plane and halos at the junction") {
  AnalyticModel m;
  // fluid box (floor z = 0 with the block's footprint cut out), not refined (far field)
  m.box({-2, -2, 0}, {2, 2, 2}, true, false, -1,
        [](int k, double u, double v) { return k != 4 || !(std::abs(u) < 0.5 && std::abs(v) < 0.5); });
  const int floor = 4;
  const int e0 = (int)m.E.size(), v0 = (int)m.V.size();
  m.box({-0.5, -0.5, 0}, {0.5, 0.5, 1}, false, true, 4);  // the block (wall), no bottom face
  for (int e = e0; e < (int)m.E.size(); ++e)
    if (m.E[e].faces.size() == 1) {  // bottom edges: block side + floor
      auto n1 = m.E[e].N(0);
      m.E[e].faces.push_back(floor);
      Vec3 n = mftest::unit(mftest::add(n1, Vec3{0, 0, -1}));
      m.E[e].N = [n](double) { return n; };
    }
  for (int v = v0; v < (int)m.V.size(); ++v)
    if (m.V[v].p[2] == 0) {
      m.V[v].faces.push_back(floor);
      m.V[v].n = mftest::unit(mftest::add(m.V[v].n, Vec3{0, 0, -1}));
    }
  const int side_px = 6 + 1;  // block faces: -x(6), +x(7), -y(8), +y(9), +z(10)
  MedialObject M = run(m);
  Err rad, bis;
  long halos = 0;
  for (auto& p : M.points) {
    if (p.side != Side::fluid) continue;
    double dx = p.c[0] - 0.5, dz = p.c[2];
    if (dx <= 0 || dx > 0.3 || dz > 0.3 || std::abs(p.c[1]) > 0.3) continue;
    if (!(on_face(M, p, side_px) && on_face(M, p, floor))) continue;
    if (p.radius < 0.03) continue;  // below the resolution of min_spacing
    double r_true = std::min(dx, dz);
    rad.add(std::abs(p.radius - r_true) / r_true);
    bis.add(std::abs(dx - dz) / 2 / r_true);
    halos += p.halo;
  }
  long halo_pairs = 0;
  for (auto& h : M.halos) halo_pairs += h.face_a == floor && h.face_b == side_px;
  MESSAGE("corner: samples " << M.samples.size() << ", junction points " << rad.n << ", radius error/r " << rad.worst
                             << ", off-bisector/r " << bis.worst << ", floor/side halos " << halo_pairs);
  CHECK(rad.n > 50);
  CHECK(rad.worst < 0.02);
  CHECK(bis.worst < 0.02);
  CHECK(halos == rad.n);
  CHECK(halo_pairs > 50);
}

TEST_CASE("threads: sampling and core give the same bytes in task arenas of 1 and 2 threads") {
  // the cylinder (curvature, a seam, caps) and the block on a floor (halos, a trimmed face)
  AnalyticModel cyl = mftest::cylinder(1.0, 3.0);
  AnalyticModel corner;
  corner.box({-2, -2, 0}, {2, 2, 2}, true, false, -1,
             [](int k, double u, double v) { return k != 4 || !(std::abs(u) < 0.5 && std::abs(v) < 0.5); });
  corner.box({-0.5, -0.5, 0}, {0.5, 0.5, 1}, false, true, 4);
  auto dir = meshflow::testing::scratch_dir("medial-threads");
  for (const AnalyticModel* m : {&cyl, &corner}) {
    std::string bytes[2];
    for (int t : {1, 2}) {
      tbb::task_arena arena(t);
      MedialObject M = arena.execute([&] { return run(*m); });
      write(M, dir / "m.mfmedial");
      bytes[t - 1] = mftest::read_text(dir / "m.mfmedial");
    }
    CHECK(bytes[0].size() > 1000);
    CHECK(bytes[0] == bytes[1]);
  }
  std::filesystem::remove_all(dir);
}

TEST_CASE("artifact: write/read round trip, deterministic bytes, corrupt files refused") {
  AnalyticModel m = mftest::cylinder(1.0, 3.0);
  MedialObject A = run(m), B = run(m);
  auto dir = meshflow::testing::scratch_dir("medial-io");
  write(A, dir / "a.mfmedial");
  write(B, dir / "b.mfmedial");
  std::string a = mftest::read_text(dir / "a.mfmedial");
  CHECK(a == mftest::read_text(dir / "b.mfmedial"));
  MedialObject R = read(dir / "a.mfmedial");
  REQUIRE(R.samples.size() == A.samples.size());
  REQUIRE(R.points.size() == A.points.size());
  CHECK(R.halos.size() == A.halos.size());
  CHECK(R.points.back().c == A.points.back().c);
  CHECK(R.info[7].lfs == A.info[7].lfs);
  write(R, dir / "c.mfmedial");
  CHECK(mftest::read_text(dir / "c.mfmedial") == a);
  CHECK(R.summary() == A.summary());
  {
    std::ofstream t(dir / "t.mfmedial", std::ios::binary);
    t.write(a.data(), a.size() / 2);
  }
  CHECK_THROWS_WITH_AS(read(dir / "t.mfmedial"), doctest::Contains("truncated"), StageError);
  {
    std::ofstream t(dir / "g.mfmedial", std::ios::binary);
    t << "meshflow-shape 1\n{}\n";
  }
  CHECK_THROWS_WITH_AS(read(dir / "g.mfmedial"), doctest::Contains("not a meshflow medial artifact"), StageError);
  CHECK_THROWS_AS(read(dir / "missing.mfmedial"), StageError);
  std::filesystem::remove_all(dir);
}

TEST_CASE("core: bad input is refused with a clear message") {
  std::vector<Sample> few(5);
  for (int i = 0; i < 5; ++i) few[i].p = {double(i), 0, 0};
  CHECK_THROWS_WITH_AS(medial_from_samples(few, {}), doctest::Contains("distinct boundary samples"), StageError);
  std::vector<Sample> flat;
  for (int i = 0; i < 10; ++i)
    for (int j = 0; j < 10; ++j) {
      Sample s;
      s.p = {i + 0.01 * j * j, j + 0.013 * i * i, 0};
      s.n = {0, 0, 1};
      flat.push_back(s);
    }
  CHECK_THROWS_WITH_AS(medial_from_samples(flat, {}), doctest::Contains("coplanar"), StageError);
  flat[3].p[2] = std::nan("");
  CHECK_THROWS_WITH_AS(medial_from_samples(flat, {}), doctest::Contains("non-finite"), StageError);
}
