// The CAD query interface (stages/cad/cad.hpp) on shapes made by the geometry kinds and on the
// real files; the "shape" artifact type; the step kind's refusals.
#include <doctest/doctest.h>

#include "engine/artifact_type.hpp"
#include "stages/cad/cad.hpp"
#include "test_context.hpp"

#include <cmath>
#include <fstream>
#include <unistd.h>

using meshflow::StageError;
using meshflow::cad::Shape;
using meshflow::cad::Tag;
using meshflow::cad::Vec3;
using meshflow::testing::TestContext;
namespace fs = std::filesystem;

namespace {
Vec3 sub(Vec3 a, Vec3 b) { return {a.x - b.x, a.y - b.y, a.z - b.z}; }
Vec3 add(Vec3 a, Vec3 b, double s = 1) { return {a.x + s * b.x, a.y + s * b.y, a.z + s * b.z}; }
Vec3 mul(Vec3 a, double s) { return {a.x * s, a.y * s, a.z * s}; }
double norm(Vec3 a) { return std::sqrt(a.x * a.x + a.y * a.y + a.z * a.z); }

struct Wing {
  TestContext ctx{"naca_wing", {{"span", 1.5}}};
  Shape s;
  Wing() {
    ctx.run();
    s = Shape::load(ctx.artifact("shape").path);
  }
  int face(const std::string& type) const {
    for (int f : s.faces_with_tag(Tag::wall))
      if (s.face_surface_type(f) == type) return f;
    return -1;
  }
};
const Wing& wing() {
  static Wing w;
  return w;
}
}  // namespace

TEST_CASE("surface derivatives agree with finite differences") {
  const Shape& s = wing().s;
  for (const char* type : {"extrusion", "revolution"}) {
    int f = wing().face(type);
    REQUIRE(f >= 0);
    auto b = s.face_uv_bounds(f);
    for (double a : {0.21, 0.47, 0.83}) {  // (u = 0 is the C1 leading-edge knot of the profile)
      double u = b.u0 + a * (b.u1 - b.u0), v = b.v0 + (1 - a) * (b.v1 - b.v0), h = 1e-6;
      auto d = s.face_eval(f, u, v);
      auto du = mul(sub(s.face_point(f, u + h, v), s.face_point(f, u - h, v)), 0.5 / h);
      auto dv = mul(sub(s.face_point(f, u, v + h), s.face_point(f, u, v - h)), 0.5 / h);
      CHECK(norm(sub(du, d.du)) < 1e-6 * (1 + norm(d.du)));
      CHECK(norm(sub(dv, d.dv)) < 1e-6 * (1 + norm(d.dv)));
      auto e1 = s.face_eval(f, u + h, v), e0 = s.face_eval(f, u - h, v);
      CHECK(norm(sub(mul(sub(e1.du, e0.du), 0.5 / h), d.duu)) < 1e-4 * (1 + norm(d.duu)));
      CHECK(norm(sub(mul(sub(e1.dv, e0.dv), 0.5 / h), d.duv)) < 1e-4 * (1 + norm(d.duv)));
      auto g1 = s.face_eval(f, u, v + h), g0 = s.face_eval(f, u, v - h);
      CHECK(norm(sub(mul(sub(g1.dv, g0.dv), 0.5 / h), d.dvv)) < 1e-4 * (1 + norm(d.dvv)));
      CHECK(norm(sub(d.p, s.face_point(f, u, v))) < 1e-14);
    }
  }
}

TEST_CASE("curve derivatives, length, vertices") {
  const Shape& s = wing().s;
  int checked = 0;
  for (int e = 0; e < s.num_edges(); ++e) {
    if (s.edge_degenerate(e)) continue;
    auto r = s.edge_range(e);
    double t = r.lo + 0.37 * (r.hi - r.lo), h = 1e-6 * (r.hi - r.lo);
    auto d = s.edge_eval(e, t);
    auto fd = mul(sub(s.edge_point(e, t + h), s.edge_point(e, t - h)), 0.5 / h);
    CHECK(norm(sub(fd, d.d1)) < 1e-5 * (1 + norm(d.d1)));
    // length = limit of the chord sum
    double L = 0;
    const int n = 2000;
    for (int i = 0; i < n; ++i)
      L += norm(sub(s.edge_point(e, r.lo + (r.hi - r.lo) * (i + 1) / n), s.edge_point(e, r.lo + (r.hi - r.lo) * i / n)));
    CHECK(s.edge_length(e) == doctest::Approx(L).epsilon(1e-5));
    auto v = s.edge_vertices(e);
    CHECK(norm(sub(s.edge_point(e, r.lo), s.vertex_point(v[0]))) <= s.vertex_tolerance(v[0]) + 1e-9);
    CHECK(norm(sub(s.edge_point(e, r.hi), s.vertex_point(v[1]))) <= s.vertex_tolerance(v[1]) + 1e-9);
    ++checked;
  }
  CHECK(checked > 10);
}

TEST_CASE("projection to surfaces and curves recovers parameter and distance") {
  Shape s = wing().s.clone();
  int f = wing().face("extrusion");
  auto b = s.face_uv_bounds(f);
  for (double a : {0.05, 0.3, 0.5, 0.71, 0.95}) {
    double u = b.u0 + a * (b.u1 - b.u0), v = b.v0 + 0.4 * (b.v1 - b.v0);
    Vec3 n = s.face_normal(f, u, v);
    CHECK(norm(n) == doctest::Approx(1.0));
    Vec3 p = add(s.face_point(f, u, v), n, 1e-3);
    auto pr = s.project_to_face(f, p);
    CHECK(pr.distance == doctest::Approx(1e-3).epsilon(1e-6));
    CHECK(pr.u == doctest::Approx(u).epsilon(1e-7));
    CHECK(pr.v == doctest::Approx(v).epsilon(1e-7));
    auto ph = s.project_to_face(f, p, meshflow::cad::Vec2{u + 1e-3, v - 1e-3});
    CHECK(ph.distance == doctest::Approx(1e-3).epsilon(1e-6));
    CHECK(std::abs(ph.u - u) < 1e-7);
  }
  for (int e : s.face_edges(f)) {
    if (s.edge_degenerate(e)) continue;
    auto r = s.edge_range(e);
    double t = r.lo + 0.61 * (r.hi - r.lo);
    Vec3 p = s.edge_point(e, t);
    auto pr = s.project_to_edge(e, p);
    CHECK(pr.distance < 1e-9);
    CHECK(pr.t == doctest::Approx(t).epsilon(1e-7));
    auto ph = s.project_to_edge(e, add(p, {1e-9, 0, 0}), t + 0.01 * (r.hi - r.lo));
    CHECK(ph.t == doctest::Approx(t).epsilon(1e-6));
  }
}

TEST_CASE("project_to_face_near: Newton from the hint inside the face, held at the face's side past it") {
  Shape s = wing().s.clone();
  const int f = wing().face("extrusion");
  const auto b = s.face_uv_bounds(f);
  for (double a : {0.05, 0.3, 0.5, 0.71, 0.95}) {
    const double u = b.u0 + a * (b.u1 - b.u0), v = b.v0 + 0.4 * (b.v1 - b.v0);
    const Vec3 p = add(s.face_point(f, u, v), s.face_normal(f, u, v), 1e-3);
    // inside: the foot of the normal, as the global projection finds it
    auto pn = s.project_to_face_near(f, p, meshflow::cad::Vec2{u + 0.02 * (b.u1 - b.u0), v - 0.1 * (b.v1 - b.v0)});
    CHECK(pn.distance == doctest::Approx(1e-3).epsilon(1e-6));
    CHECK(std::abs(pn.u - u) < 1e-7);
    CHECK(std::abs(pn.v - v) < 1e-7 * (b.v1 - b.v0));
    // past the face's end (the span): the nearest point of the face is on its side v = v1
    const auto d = s.face_eval(f, u, b.v1);
    const double tu = d.du.x * d.dv.x + d.du.y * d.dv.y + d.du.z * d.dv.z;
    REQUIRE(std::abs(tu) < 1e-9 * norm(d.du) * norm(d.dv));  // extruded normal to the section
    const Vec3 out = mul(d.dv, 1 / norm(d.dv));
    const Vec3 q = add(add(d.p, out, 0.2), s.face_normal(f, u, b.v1), 0.05);
    auto pq = s.project_to_face_near(f, q, meshflow::cad::Vec2{u, b.v0 + 0.9 * (b.v1 - b.v0)});
    CHECK(pq.v == b.v1);
    CHECK(std::abs(pq.u - u) < 1e-7);
    CHECK(pq.distance == doctest::Approx(std::hypot(0.2, 0.05)).epsilon(1e-9));
    CHECK(norm(sub(pq.point, s.face_point(f, pq.u, pq.v))) < 1e-12);  // the point is the surface's at (u, v)
  }
}

TEST_CASE("normals point out of the fluid, curvature at the leading edge is 1/r_LE") {
  const Shape& s = wing().s;
  int f = wing().face("extrusion");
  // the leading edge of the 10 deg wing at z = 0.5 is the origin line: project it
  auto pr = s.project_to_face(f, {0, 0, 0.5});
  CHECK(pr.distance < 1e-12);
  Vec3 n = s.face_normal(f, pr.u, pr.v);
  CHECK(n.x > 0.98);  // into the wing (out of the fluid), i.e. downstream at the nose
  auto c = s.face_curvature(f, pr.u, pr.v);
  REQUIRE(c.defined);
  double r_le = std::pow(5 * 0.12 * 0.2969, 2) / 2;  // exact for the 4-digit polynomial
  CHECK(std::max(std::abs(c.k1), std::abs(c.k2)) == doctest::Approx(1 / r_le).epsilon(1e-6));
  CHECK(std::min(std::abs(c.k1), std::abs(c.k2)) < 1e-9);  // straight along the span
  CHECK(c.gauss == doctest::Approx(0).epsilon(1e-9));
}

TEST_CASE("adjacency: wires are closed loops in order, p-curves match the 3D curves") {
  const Shape& s = wing().s;
  for (int f = 0; f < s.num_faces(); ++f) {
    auto wires = s.face_wires(f);
    REQUIRE(!wires.empty());
    for (auto& w : wires) {
      for (size_t i = 0; i < w.size(); ++i) {
        auto a = w[i], b = w[(i + 1) % w.size()];
        auto va = s.edge_vertices(a.edge), vb = s.edge_vertices(b.edge);
        CHECK((a.reversed ? va[0] : va[1]) == (b.reversed ? vb[1] : vb[0]));
      }
      for (auto use : w) {
        int e = use.edge;
        auto ef = s.edge_faces(e);
        CHECK(std::find(ef.begin(), ef.end(), f) != ef.end());
        if (s.edge_degenerate(e)) continue;
        auto r = s.edge_range(e);
        for (double a : {0.0, 0.3, 1.0}) {
          double t = r.lo + a * (r.hi - r.lo);
          auto uv = s.edge_uv(e, f, t, use.reversed);
          CHECK(norm(sub(s.face_point(f, uv.u, uv.v), s.edge_point(e, t))) < 1e-6);
          CHECK(s.face_contains_uv(f, uv.u, uv.v, 1e-6));
        }
      }
    }
    for (int g : s.face_neighbours(f)) {
      auto n = s.face_neighbours(g);
      CHECK(std::find(n.begin(), n.end(), f) != n.end());
    }
  }
  // the closed fluid solid: every non-degenerate edge bounds two faces or is a seam
  CHECK(s.free_edges().empty());
  CHECK(s.multiple_edges().empty());
  auto bb = s.box();
  CHECK(bb.lo.z == doctest::Approx(0).epsilon(1e-6));
  CHECK(bb.hi.x == doctest::Approx(11).epsilon(1e-6));
}

TEST_CASE("shape artifact: type registered, summary, STEP export keeps units, corrupt files refused") {
  const auto* t = meshflow::find_artifact_type("shape");
  REQUIRE(t != nullptr);
  REQUIRE(t->summarize);
  auto path = wing().ctx.artifact("shape").path;
  auto j = t->summarize(path);
  CHECK(j["faces"] == wing().s.num_faces());
  CHECK(j["solids"] == 1);
  CHECK(j["face_tags"]["farfield"] == 5);
  CHECK(j["units"] == "m");
  auto dir = meshflow::testing::scratch_dir("export");
  t->formats.at("step").write(path, dir / "w.step");
  t->formats.at("brep").write(path, dir / "w.brep");
  {  // the same shape written again by this process: the same bytes (OCCT numbers its products per process)
    t->formats.at("step").write(path, dir / "again.step");
    auto bytes = [](const fs::path& p) {
      std::ifstream in(p, std::ios::binary);
      return std::string((std::istreambuf_iterator<char>(in)), {});
    };
    CHECK(bytes(dir / "w.step") == bytes(dir / "again.step"));
    CHECK(bytes(dir / "w.step").find("PRODUCT('meshflow','meshflow'") != std::string::npos);
  }
  TestContext back("step", {{"file", (dir / "w.step").string()}});
  back.run();
  CHECK(back.stats_["units"] == "m");
  CHECK(back.stats_["faces"] == wing().s.num_faces());
  Shape b = Shape::load(back.artifact("shape").path);
  CHECK(b.volume() == doctest::Approx(wing().s.volume()).epsilon(1e-6));
  TestContext brep("step", {{"file", (dir / "w.brep").string()}, {"scale", 1000.0}, {"units", "mm"}});
  brep.run();
  CHECK(Shape::load(brep.artifact("shape").path).box().hi.x == doctest::Approx(11000).epsilon(1e-6));

  std::ofstream(dir / "bad.mfshape") << "meshflow-shape 1\n{\"units\":\"m\",\"face_tags\":[]}\nnot a brep\n";
  CHECK_THROWS_AS(Shape::load(dir / "bad.mfshape"), StageError);
  std::ofstream(dir / "other.mfshape") << "hello\n";
  CHECK_THROWS_WITH_AS(Shape::load(dir / "other.mfshape"), doctest::Contains("not a meshflow shape artifact"), StageError);
  CHECK_THROWS_WITH_AS(Shape::load(dir / "missing.mfshape"), doctest::Contains("cannot open"), StageError);
  {  // tags that do not match the faces
    std::ifstream in(path);
    std::string all((std::istreambuf_iterator<char>(in)), {});
    auto pos = all.find("\"farfield\",");
    all.erase(pos, 11);
    std::ofstream(dir / "tags.mfshape") << all;
    CHECK_THROWS_WITH_AS(Shape::load(dir / "tags.mfshape"), doctest::Contains("face tags for"), StageError);
  }
  fs::remove_all(dir);
}

TEST_CASE("step kind refuses bad files with the file name and what to do") {
  auto dir = meshflow::testing::scratch_dir("bad");
  TestContext missing("step", {{"file", (dir / "nope.step").string()}});
  CHECK_THROWS_WITH_AS(missing.run(), doctest::Contains("does not exist"), StageError);
  std::ofstream(dir / "garbage.step") << "this is not ISO-10303-21\n";
  TestContext garbage("step", {{"file", (dir / "garbage.step").string()}});
  CHECK_THROWS_WITH_AS(garbage.run(), doctest::Contains("garbage.step"), StageError);
  std::ofstream(dir / "garbage.brep") << "nonsense\n";
  TestContext gb("step", {{"file", (dir / "garbage.brep").string()}});
  CHECK_THROWS_WITH_AS(gb.run(), doctest::Contains("not an OpenCASCADE BREP"), StageError);
  std::ofstream(dir / "x.obj") << "v 0 0 0\n";
  TestContext ext("step", {{"file", (dir / "x.obj").string()}});
  CHECK_THROWS_WITH_AS(ext.run(), doctest::Contains(".step/.stp"), StageError);
  fs::remove_all(dir);
}

TEST_CASE("relative file paths resolve against the workflow folder, DLR-F6 loads with its 130 stored faces") {
  fs::path data = MESHFLOW_DATA_DIR;
  REQUIRE(fs::exists(data / "dlr_f6/dlr_f6.brep"));
  TestContext c("step", {{"file", "dlr_f6/dlr_f6.brep"}}, {}, data);
  c.run();
  Shape s = Shape::load(c.artifact("shape").path);
  CHECK(s.num_solids() == 1);
  CHECK(s.num_faces() == 130);
  CHECK(s.valid());
  CHECK(s.units() == "mm");
  // the half model's symmetry plane is y = 0
  CHECK(std::abs(s.box().hi.y) < 1e-6);
  // the faces' boxes in parallel give OCCT's box of the whole solid, bit for bit
  const auto b1 = s.box(), b2 = s.box(2);
  CHECK(b1.lo.x == b2.lo.x);
  CHECK(b1.lo.y == b2.lo.y);
  CHECK(b1.lo.z == b2.lo.z);
  CHECK(b1.hi.x == b2.hi.x);
  CHECK(b1.hi.y == b2.hi.y);
  CHECK(b1.hi.z == b2.hi.z);
}

TEST_CASE("IGES: the paper's wing exported as IGES (in mm) and imported by the step kind: same faces, units and box") {
  fs::path data = MESHFLOW_DATA_DIR;
  REQUIRE(fs::exists(data / "wingtip/3d_bl_wing.stp"));
  TestContext c("step", {{"file", "wingtip/3d_bl_wing.stp"}}, {}, data);
  c.run();
  Shape step = Shape::load(c.artifact("shape").path);
  fs::path dir = fs::temp_directory_path() / ("meshflow-iges-" + std::to_string(::getpid()));
  fs::create_directories(dir);
  step.export_iges(dir / "wing.igs");
  {
    std::ifstream in(dir / "wing.igs");
    std::string first;
    std::getline(in, first);
    CHECK(first.size() == 80);  // IGES fixed 80-column records
  }
  TestContext i("step", {{"file", (dir / "wing.igs").string()}}, {}, dir);
  i.run();
  Shape iges = Shape::load(i.artifact("shape").path);
  CHECK(iges.units() == "mm");
  CHECK(iges.num_faces() == step.num_faces());
  auto a = step.box(), b = iges.box();
  const double diag = std::hypot(a.hi.x - a.lo.x, a.hi.y - a.lo.y, a.hi.z - a.lo.z);
  CHECK(std::abs(a.lo.x - b.lo.x) < 1e-6 * diag);
  CHECK(std::abs(a.hi.x - b.hi.x) < 1e-6 * diag);
  CHECK(std::abs(a.lo.y - b.lo.y) < 1e-6 * diag);
  CHECK(std::abs(a.hi.y - b.hi.y) < 1e-6 * diag);
  CHECK(std::abs(a.lo.z - b.lo.z) < 1e-6 * diag);
  CHECK(std::abs(a.hi.z - b.hi.z) < 1e-6 * diag);
  // the surfaces are the same: a point of every face of the STEP lies on a face of the IGES
  for (int f = 0; f < step.num_faces(); ++f) {
    auto [u0, u1, v0, v1] = step.face_uv_bounds(f);
    auto p = step.face_point(f, 0.5 * (u0 + u1), 0.5 * (v0 + v1));
    double best = INFINITY;
    for (int g = 0; g < iges.num_faces(); ++g) best = std::min(best, iges.project_to_face(g, p).distance);
    CHECK(best < 1e-6 * diag);
  }
  fs::remove_all(dir);
}

// OCCT takes its working unit into an IGES model when the file is read, from process-wide
// settings that every import changes: read after an import in another unit (init reads the file,
// then its preflight's stages run in processes forked from it), a file in metres came in 1000
// times smaller than from a fresh process. The step kind sets the file's own unit before reading.
TEST_CASE("IGES: a file in metres has the same size whatever was imported before it in the process") {
  const fs::path real = fs::path(MESHFLOW_SOURCE_DIR) / "bench/corpus/real";
  fs::path data = MESHFLOW_DATA_DIR;
  REQUIRE(fs::exists(data / "wingtip/3d_bl_wing.stp"));
  auto import = [&](const fs::path& dir, const std::string& file) {
    TestContext c("step", {{"file", file}}, {}, dir);
    c.run();
    return Shape::load(c.artifact("shape").path);
  };
  const Shape first = import(real, "wing_surfaces_5m.iges");
  import(data, "wingtip/3d_bl_wing.stp");  // an import in mm
  const Shape again = import(real, "wing_surfaces_5m.iges");
  CHECK(first.units() == "m");
  CHECK(again.units() == "m");
  auto a = first.box(), b = again.box();
  const double side = a.hi.x - a.lo.x;
  CHECK(side > 0.1);
  CHECK(side < 10);  // metres, not millimetre numbers
  CHECK(b.hi.x - b.lo.x == doctest::Approx(side).epsilon(1e-9));
  CHECK(b.hi.y - b.lo.y == doctest::Approx(a.hi.y - a.lo.y).epsilon(1e-9));
  CHECK(b.hi.z - b.lo.z == doctest::Approx(a.hi.z - a.lo.z).epsilon(1e-9));
}
