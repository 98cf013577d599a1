// meshflow init: what it decides on the corpus and the paper's CAD, its refusals of bad
// arguments, and a written workflow run as it is to a valid mesh (the capsule, ~15 s).
#include <doctest/doctest.h>

#include "stages/geometry/import.hpp"
#include "stages/init/init.hpp"
#include "support.hpp"

#include <nlohmann/json.hpp>

#include <BRepAlgoAPI_Common.hxx>
#include <BRepAlgoAPI_Cut.hxx>
#include <BRep_Builder.hxx>
#include <TopExp_Explorer.hxx>
#include <TopoDS_Compound.hxx>
#include <BRepAlgoAPI_Fuse.hxx>
#include <BRepPrimAPI_MakeBox.hxx>
#include <BRepPrimAPI_MakeCylinder.hxx>
#include <BRepPrimAPI_MakeSphere.hxx>
#include <BRepTools.hxx>

#include <cmath>
#include <filesystem>
#include <fstream>

namespace fs = std::filesystem;
using meshflow::init::analyse;
using meshflow::init::choose;

namespace {
const fs::path data = MESHFLOW_DATA_DIR;
// scripts/synthetic-blade.py's arguments for the small blade row run end to end
const char* const kSmallBlade = "--sections 4 --points 24 --hub 15 --tip 18 --chord 6 6.5 --stagger 30 40";
meshflow::init::Analysis analysed(const fs::path& f) {
  return analyse(meshflow::geometry::import_cad(f, "", 1.0, [](const std::string&) {}));
}
}  // namespace

TEST_CASE("init: a body goes in a far-field box, a tunnel or a solid with a void is the domain") {
  REQUIRE(fs::exists(data / "corpus"));
  struct Case {
    const char* file;
    bool domain;
    size_t walls;
  };
  for (Case c : {Case{"corpus/sphere.step", false, 1}, Case{"corpus/rounded_box.step", false, 26},
                 Case{"corpus/two_spheres.step", false, 2},
                 Case{"corpus/cylinder_in_box.step", true, 3},       // a void: 1 solid, 2 shells
                 Case{"corpus/nekmesh_bl_cylinder.stp", true, 2},    // a channel: the box's 8 corners
                 Case{"wingtip/3d_bl_wing.stp", true, 3}}) {         // a tunnel, faces not sewn
    CAPTURE(c.file);
    auto a = analysed(data / c.file);
    CHECK(a.domain == c.domain);
    CHECK(a.walls.size() == c.walls);
    CHECK(!a.why.empty());
  }
}

TEST_CASE("init: a far-field sphere around a body is the domain, its outer shell not a wall") {
  fs::path dir = mftest::temp_dir("init-sphere-domain");
  TopoDS_Shape outer = BRepPrimAPI_MakeSphere(gp_Pnt(0.5, 1, 1.5), 100).Shape();
  TopoDS_Shape body = BRepPrimAPI_MakeBox(gp_Pnt(0, 0, 0), 1, 2, 3).Shape();
  REQUIRE(BRepTools::Write(BRepAlgoAPI_Cut(outer, body).Shape(), (dir / "domain.brep").c_str()));
  auto a = analysed(dir / "domain.brep");
  CHECK(a.domain);
  CHECK(a.walls.size() == 6);                      // the box's faces only
  CHECK(a.wall_max == doctest::Approx(3).epsilon(1e-3));
  auto c = choose(a);
  CHECK(c.thickness == doctest::Approx(0.15).epsilon(1e-3));  // 5% of the body, not of the sphere
  CHECK(c.farfield_size == doctest::Approx(0.1 * 200 / 3).epsilon(1e-3));  // a tenth of the domain
}

// A thin body (1 x 0.12 x 3) in a far-field sphere of radius 100, through init's workflow. The
// sphere is meshed at the far-field size (20, a tenth of the domain's side) in its parameter
// plane. The arc-length plane sheared it up to 6 times near the poles: 6,080 triangles where the
// size asks for ~730, one folded over in 3D and sweep stopped. In the conformal plane of a
// surface of revolution: ~950 triangles, none folded.
TEST_CASE("init: a thin body in a far-field sphere 100 times its size runs to a valid mesh, the sphere at its size") {
  fs::path dir = mftest::temp_dir("init-sphere-farfield");
  TopoDS_Shape outer = BRepPrimAPI_MakeSphere(gp_Pnt(0.5, 0, 0), 100).Shape();
  TopoDS_Shape body = BRepPrimAPI_MakeBox(gp_Pnt(0, -0.06, -1.5), 1, 0.12, 3).Shape();
  REQUIRE(BRepTools::Write(BRepAlgoAPI_Cut(outer, body).Shape(), (dir / "domain.brep").c_str()));
  fs::path wf = dir / "domain.yaml";
  REQUIRE(mftest::run_cli({"init", (dir / "domain.brep").string(), "-o", wf.string()}).code == 0);
  auto run = mftest::sh(std::string(MESHFLOW_EXE) + " run " + wf.string() + " --cache " + (dir / "cache").string() +
                        " --out " + (dir / "out").string() + " 2>&1");
  CAPTURE(run.out);
  REQUIRE(run.code == 0);
  auto split = mftest::stage_stats(dir / "out", "split");
  CHECK(split["mesh"]["invalid"] == 0);
  CHECK(split["problems"].empty());
  // the sphere (every boundary triangle that is not a wall): equilateral triangles of side 20
  // tile its area 4 pi 100^2 with ~726
  const double asked = 4 * M_PI * 100.0 * 100.0 / (std::sqrt(3.0) / 4 * 20.0 * 20.0);
  const double got = mftest::stage_stats(dir / "out", "sweep")["sweep"]["boundary_triangles"].get<double>();
  MESSAGE("far-field sphere: " << got << " triangles, " << asked << " asked for");
  CHECK(got < 2 * asked);
  CHECK(got > 0.5 * asked);
}

TEST_CASE("init: a half sphere with a half body cut into its flat face is the domain: the body walls, the sphere not") {
  fs::path dir = mftest::temp_dir("init-half-domain");
  TopoDS_Shape half = BRepAlgoAPI_Common(BRepPrimAPI_MakeSphere(gp_Pnt(0, 0, 0), 10).Shape(),
                                         BRepPrimAPI_MakeBox(gp_Pnt(-20, -20, 0), 40, 40, 20).Shape()).Shape();
  TopoDS_Shape domain = BRepAlgoAPI_Cut(half, BRepPrimAPI_MakeBox(gp_Pnt(0, -0.1, -1), 1, 0.2, 3).Shape()).Shape();
  REQUIRE(BRepTools::Write(domain, (dir / "half.brep").c_str()));
  auto a = analysed(dir / "half.brep");
  CHECK(a.domain);
  CHECK(a.why.find("body cut into it") != std::string::npos);
  CHECK(a.walls.size() == 5);
  CHECK(a.wall_max == doctest::Approx(2).epsilon(1e-3));
  // the same half sphere with no body cut into it is a body (a dome), not a domain
  REQUIRE(BRepTools::Write(half, (dir / "dome.brep").c_str()));
  CHECK(!analysed(dir / "dome.brep").domain);
}

TEST_CASE("init: a solid whose extra shell lies on its outer boundary is a body with cavities, not a domain without walls") {
  fs::path dir = mftest::temp_dir("init-cavities");
  TopoDS_Shape box = BRepPrimAPI_MakeBox(gp_Pnt(0, 0, 0), 1, 2, 3).Shape();
  TopoDS_Shape copy = BRepPrimAPI_MakeBox(gp_Pnt(0, 0, 0), 1, 2, 3).Shape();
  TopoDS_Compound c;
  BRep_Builder b;
  b.MakeCompound(c);
  b.Add(c, box);
  for (TopExp_Explorer ex(copy, TopAbs_SHELL); ex.More(); ex.Next()) b.Add(c, ex.Current());  // a loose shell
  REQUIRE(BRepTools::Write(c, (dir / "body.brep").c_str()));
  auto a = analysed(dir / "body.brep");
  CHECK(a.shells > a.solids);
  CHECK(!a.domain);
  CHECK(a.why.find("cavities") != std::string::npos);
  CHECK(!a.walls.empty());
}

TEST_CASE("init: a declared unit whose figures give an implausible size is reported with the likely unit") {
  fs::path dir = mftest::temp_dir("init-units");
  REQUIRE(BRepTools::Write(BRepPrimAPI_MakeSphere(gp_Pnt(0, 0, 0), 0.2).Shape(), (dir / "ball.brep").c_str()));
  // a BREP carries no unit: mm unless told; a 0.4 mm ball is likely a 0.4 m one
  auto a = analysed(dir / "ball.brep");
  CHECK(a.units == "mm");
  CHECK(a.likely_units == "m");
  auto init = mftest::run_cli({"init", (dir / "ball.brep").string(), "-o", (dir / "ball.yaml").string()});
  CHECK(init.code == 0);
  CHECK(init.out.find("likely m") != std::string::npos);
  CHECK(mftest::sh("grep -c '# Units: the file declares mm' " + (dir / "ball.yaml").string()).out.find("1") == 0);
  // --units m: nothing to report
  auto given = mftest::run_cli({"init", (dir / "ball.brep").string(), "-o", (dir / "ball_m.yaml").string(), "--units", "m"});
  CHECK(given.code == 0);
  CHECK(given.out.find("likely") == std::string::npos);
  // a plausible size: no note
  REQUIRE(BRepTools::Write(BRepPrimAPI_MakeSphere(gp_Pnt(0, 0, 0), 200).Shape(), (dir / "big.brep").c_str()));
  CHECK(analysed(dir / "big.brep").likely_units.empty());
}

// A comb: a block with three slots 0.02 wide through it. The inner walls of the slots are most of
// the wall, and the layer init measures from the body (5 % of its side) does not fit in them:
// the preflight runs the shell stage, which says how thick a layer the fluid holds, and init
// writes 0.9 x that instead; the stages it ran are in the run's cache.
TEST_CASE("init: the preflight lowers a layer the shell stage refuses, and its stages are cached for the run") {
  fs::path dir = mftest::temp_dir("init-preflight");
  TopoDS_Shape comb = BRepPrimAPI_MakeBox(gp_Pnt(0, 0, 0), 1, 1, 0.2).Shape();
  for (int k = 0; k < 3; ++k)
    comb = BRepAlgoAPI_Cut(comb, BRepPrimAPI_MakeBox(gp_Pnt(0.05, -0.1, 0.04 + 0.05 * k), 1, 1.2, 0.02).Shape()).Shape();
  REQUIRE(BRepTools::Write(comb, (dir / "comb.brep").c_str()));
  fs::path wf = dir / "comb.yaml", cache = dir / "cache";
  auto init = mftest::run_cli({"init", (dir / "comb.brep").string(), "-o", wf.string(), "--units", "m", "--cache", cache.string()});
  CAPTURE(init.out);
  CAPTURE(init.err);
  REQUIRE(init.code == 0);
  CHECK(init.out.find("# Preflight: the shell stage found the fluid holds a layer of at most") != std::string::npos);
  CHECK(init.out.find("# Preflight: geometry, heal, medial and shell ran to the end") != std::string::npos);
  auto text = mftest::sh("grep -o 'thickness: [0-9.e-]*' " + wf.string()).out;
  CAPTURE(text);
  const double thickness = std::stod(text.substr(text.find(' ') + 1));
  CHECK(thickness < 0.05);
  // the run finds the preflight's stages in its cache
  auto run = mftest::sh(std::string(MESHFLOW_EXE) + " run " + wf.string() + " --cache " + cache.string() +
                        " --out " + (dir / "out").string() + " --only shell 2>&1");
  CHECK(run.out.find("cached  shell") != std::string::npos);
  // --no-preflight writes the measured layer as it is
  auto plain = mftest::run_cli({"init", (dir / "comb.brep").string(), "-o", (dir / "plain.yaml").string(), "--units", "m", "--no-preflight"});
  CHECK(plain.code == 0);
  CHECK(plain.out.find("Preflight") == std::string::npos);
  fs::remove_all(dir);
}

TEST_CASE("init: a bent duct or a long pipe given as a solid is an internal flow, its ends the ports, a short cylinder a body, a pipe runs valid") {
  fs::path dir = mftest::temp_dir("init-internal");
  TopoDS_Shape duct = BRepAlgoAPI_Fuse(BRepPrimAPI_MakeBox(gp_Pnt(0, 0, 0), 1, 0.2, 0.2).Shape(),
                                       BRepPrimAPI_MakeBox(gp_Pnt(0.8, 0, 0), 0.2, 1, 0.2).Shape()).Shape();
  REQUIRE(BRepTools::Write(duct, (dir / "duct.brep").c_str()));
  auto a = analysed(dir / "duct.brep");
  CHECK(a.domain);
  CHECK(a.internal);
  CHECK(a.why.find("a bend") != std::string::npos);
  REQUIRE(a.ports.size() == 2);
  CHECK(a.walls.size() + 2 == static_cast<size_t>(a.faces));
  for (auto& p : a.ports) CHECK(p.area == doctest::Approx(0.04).epsilon(1e-6));
  // a pipe 5 diameters long: two opposite ports far apart; the corpus cylinder (as long as wide): a body
  REQUIRE(BRepTools::Write(BRepPrimAPI_MakeCylinder(0.1, 1.0).Shape(), (dir / "pipe.brep").c_str()));
  auto pipe = analysed(dir / "pipe.brep");
  CHECK(pipe.internal);
  CHECK(pipe.walls.size() == 1);
  REQUIRE(BRepTools::Write(BRepPrimAPI_MakeCylinder(0.5, 1.0).Shape(), (dir / "stub.brep").c_str()));
  CHECK(!analysed(dir / "stub.brep").domain);
  // a box is no duct: its faces are next to each other
  REQUIRE(BRepTools::Write(BRepPrimAPI_MakeBox(1, 2, 3).Shape(), (dir / "box.brep").c_str()));
  CHECK(!analysed(dir / "box.brep").domain);
  // --fluid box reads the duct as a body; the pipe's workflow tags its ports by plane and runs
  // to a valid mesh, the layer sliding on the ports
  auto body = meshflow::init::analyse(meshflow::geometry::import_cad(dir / "duct.brep", "", 1.0, [](const std::string&) {}), true);
  CHECK(!body.domain);
  auto init = mftest::run_cli({"init", (dir / "pipe.brep").string(), "-o", (dir / "pipe.yaml").string(), "--units", "m",
                               "--cache", (dir / "cache").string()});
  CAPTURE(init.out);
  CAPTURE(init.err);
  REQUIRE(init.code == 0);
  CHECK(init.out.find("an internal flow (2 ports)") != std::string::npos);
  CHECK(mftest::sh("grep -c 'tag: farfield, plane' " + (dir / "pipe.yaml").string()).out.find("2") == 0);
  auto run = mftest::sh(std::string(MESHFLOW_EXE) + " run " + (dir / "pipe.yaml").string() + " --cache " +
                        (dir / "cache").string() + " --out " + (dir / "out").string() + " 2>&1");
  CAPTURE(run.out);
  CHECK(run.code == 0);
  auto report = nlohmann::json::parse(std::ifstream(dir / "out" / "report.json"));
  for (auto& st : report["stages"])
    if (st["name"] == "heal") {
      CHECK(st["stats"]["face_tags"]["farfield"] == 2);
      CHECK(st["stats"]["face_tags"]["wall"].get<int>() >= 1);
    }
  fs::remove_all(dir);
}

TEST_CASE("init: a body standing on one side of its box is a half model on that plane, equal ends are not") {
  REQUIRE(fs::exists(data / "corpus"));
  // the swept wing's root (area 0.082) on z = 0 against its flat tip (0.020): z-
  CHECK(analysed(data / "corpus/swept_wing.step").symmetry_plane == "z-");
  // a cylinder's two equal ends, a rounded box's six sides, a sphere's none: a whole body
  CHECK(analysed(data / "corpus/cylinder.step").symmetry_plane == "none");
  CHECK(analysed(data / "corpus/rounded_box.step").symmetry_plane == "none");
  CHECK(analysed(data / "corpus/sphere.step").symmetry_plane == "none");
  // a domain has no box of its own to put on a plane
  CHECK(analysed(data / "corpus/cylinder_in_box.step").symmetry_plane == "none");
}

TEST_CASE("init: layer thickness, wall sizes and far-field size come from the measured shape") {
  REQUIRE(fs::exists(data / "corpus"));
  // sphere R 0.5: 5% of its diameter; curvature radius 0.5 asks for no refinement
  auto s = analysed(data / "corpus/sphere.step");
  CHECK(s.wall_max == doctest::Approx(1.0).epsilon(1e-3));
  CHECK(s.min_radius == doctest::Approx(0.5).epsilon(1e-3));
  auto cs = choose(s);
  CHECK(cs.thickness == doctest::Approx(0.05).epsilon(1e-3));
  CHECK(cs.min_size == 0.01);
  CHECK(cs.farfield_size == 1.0);
  // the swept wing is slender: a quarter of its smallest side, finer than 5% of its span; its
  // leading edge's curvature sets min_size below the default
  auto w = analysed(data / "corpus/swept_wing.step");
  auto cw = choose(w);
  CHECK(cw.thickness == doctest::Approx(0.25 * w.wall_min));
  CHECK(cw.thickness < 0.05 * w.wall_max);
  CHECK(cw.min_size < 0.01);
  CHECK(cw.min_size >= 0.003);
  // the cone's apex is a singular point (a degenerate edge): its unbounded curvature is not a
  // feature size; samples within 5% of the cone's length of it are not counted
  auto cone = analysed(data / "corpus/cone.step");
  CHECK(cone.singular_points == 1);
  CHECK(cone.curvature_skipped > 0);
  CHECK(cone.min_radius > 0.04);  // the cone's radius of curvature 0.075 from its apex
  // a sphere's poles are singular too, and its curvature the same everywhere
  CHECK(s.singular_points == 2);
  // a flat-walled body: no curvature, the default
  auto flat = analysed(data / "corpus/cylinder_in_box.step");
  CHECK(flat.domain);
  CHECK(choose(flat).farfield_size == doctest::Approx(1.0));  // a box 10 body lengths across
}

TEST_CASE("init: bad arguments and files exit 2 with a message, and write nothing") {
  fs::path dir = mftest::temp_dir("init-bad");
  auto r = mftest::run_cli({"init"});
  CHECK(r.code == 2);
  CHECK(r.err.find("CAD_FILE") != std::string::npos);
  r = mftest::run_cli({"init", (dir / "missing.step").string(), "-o", (dir / "w.yaml").string()});
  CHECK(r.code == 2);
  CHECK(r.err.find("does not exist") != std::string::npos);
  CHECK(!fs::exists(dir / "w.yaml"));
  mftest::write_text(dir / "junk.step", "not a step file\n");
  r = mftest::run_cli({"init", (dir / "junk.step").string(), "-o", (dir / "w.yaml").string()});
  CHECK(r.code == 2);
  CHECK(r.err.find("junk.step") != std::string::npos);
  CHECK(!fs::exists(dir / "w.yaml"));
  r = mftest::run_cli({"init", "a.step", "--order", "1"});
  CHECK(r.code == 2);
  CHECK(r.err.find("--order") != std::string::npos);
  r = mftest::run_cli({"init", "a.step", "--bogus"});
  CHECK(r.code == 2);
  mftest::write_text(dir / "taken.yaml", "keep me\n");
  r = mftest::run_cli({"init", "a.step", "-o", (dir / "taken.yaml").string()});
  CHECK(r.code == 2);
  CHECK(r.err.find("--force") != std::string::npos);
  CHECK(mftest::read_text(dir / "taken.yaml") == "keep me\n");
}

TEST_CASE("init: the capsule's workflow, written by init and run as it is, ends valid with 10 split layers") {
  fs::path cad = data / "corpus/capsule.step";
  REQUIRE(fs::exists(cad));
  fs::path dir = mftest::temp_dir("init-capsule");
  fs::path wf = dir / "capsule.yaml";
  auto r = mftest::run_cli({"init", cad.string(), "-o", wf.string()});
  REQUIRE(r.code == 0);
  std::string text = mftest::read_text(wf);
  CHECK(text.find("fluid: box") != std::string::npos);
  CHECK(text.find("# Boundary-layer thickness 0.075 m") != std::string::npos);
  // the same file gives the same workflow
  REQUIRE(mftest::run_cli({"init", cad.string(), "-o", (dir / "again.yaml").string()}).code == 0);
  CHECK(mftest::read_text(dir / "again.yaml") == text);
  auto run = mftest::sh(std::string(MESHFLOW_EXE) + " run " + wf.string() + " --cache " + (dir / "cache").string() +
                        " --out " + (dir / "out").string() + " 2>&1");
  CAPTURE(run.out);
  CHECK(run.code == 0);
  auto split = mftest::stage_stats(dir / "out", "split");
  CHECK(split["split"]["layers"] == 10);
  CHECK(split["mesh"]["invalid"] == 0);
  CHECK(split["mesh"]["elements"]["prism"] > 0);
  CHECK(split["problems"].empty());
  CHECK(fs::exists(dir / "out/mesh.msh"));
}

TEST_CASE("init: a blade row's section file (Rotor 67's export, CSV with --blades) gives a passage workflow") {
  fs::path dir = mftest::temp_dir("init-blades");
  fs::path r67 = data / "rotor67/rotor67geometry.dat";
  if (fs::exists(r67)) {
    REQUIRE(mftest::run_cli({"init", r67.string(), "-o", (dir / "r67.yaml").string()}).code == 0);
    std::string t = mftest::read_text(dir / "r67.yaml");
    CHECK(t.find("format: rotor67, blades: 22") != std::string::npos);  // the file's NB
    CHECK(t.find("periodic_match: {kind: periodic_match") != std::string::npos);
  }
  // CSV sections of a staggered elliptic blade, r = 1 .. 2, written by a spreadsheet (BOM, header)
  std::string csv = "\xEF\xBB\xBFx,y,z\n";
  for (int k = 0; k < 5; ++k) {
    double r = 1.0 + 0.25 * k, stagger = 0.5 + 0.2 * k;
    for (int i = 0; i < 40; ++i) {
      double a = 2 * M_PI * i / 40, xs = 0.15 * std::cos(a), ys = 0.015 * std::sin(a);
      double x = xs * std::cos(stagger) - ys * std::sin(stagger), rt = xs * std::sin(stagger) + ys * std::cos(stagger);
      csv += std::to_string(x) + "," + std::to_string(r * std::cos(rt / r)) + "," + std::to_string(r * std::sin(rt / r)) + "\n";
    }
    csv += "\n";
  }
  mftest::write_text(dir / "blade.csv", csv);
  auto no_count = mftest::run_cli({"init", (dir / "blade.csv").string(), "-o", (dir / "b.yaml").string()});
  CHECK(no_count.code == 2);
  CHECK(no_count.err.find("--blades") != std::string::npos);
  CHECK(!fs::exists(dir / "b.yaml"));
  REQUIRE(mftest::run_cli({"init", (dir / "blade.csv").string(), "-o", (dir / "b.yaml").string(), "--blades", "12"}).code == 0);
  CHECK(mftest::read_text(dir / "b.yaml").find("format: csv, blades: 12") != std::string::npos);
  // its geometry and heal stages run as written: a closed passage
  std::string short_wf = mftest::workflow_without(dir / "b.yaml", dir / "short.yaml",
      {"medial", "shell", "balance", "periodic_match", "sweep", "tet", "curve", "optimise", "split", "mesh"});
  auto run = mftest::sh(std::string(MESHFLOW_EXE) + " run " + short_wf + " --cache " + (dir / "cache").string() +
                        " --out " + (dir / "out").string() + " 2>&1");
  CAPTURE(run.out);
  CHECK(run.code == 0);
  CHECK(mftest::stage_stats(dir / "out", "heal")["watertight"] == true);
}

TEST_CASE("init: a synthetic blade's sections give a layer and sizes from chord, nose radius and throat, and overlapping counts are refused") {
  fs::path dir = mftest::temp_dir("init-synthetic-blade");
  auto make = [&](const std::string& name, const std::string& args) {
    auto r = mftest::sh(std::string(MESHFLOW_PYTHON) + " " + MESHFLOW_SOURCE_DIR "/scripts/synthetic-blade.py " +
                        (dir / name).string() + " " + args + " 2>&1");
    REQUIRE_MESSAGE(r.code == 0, r.out);
    return dir / name;
  };
  fs::path csv = make("profiles.csv", "--units-comment cm");
  auto r = mftest::run_cli({"init", csv.string(), "-o", (dir / "b24.yaml").string(), "--blades", "24"});
  REQUIRE_MESSAGE(r.code == 0, r.err);
  std::string t = mftest::read_text(dir / "b24.yaml");
  CHECK(t.find("format: csv, blades: 24") != std::string::npos);
  CHECK(t.find("in cm.") != std::string::npos);
  // chord 6 cm at the hub (5.983 measured, the profile's loop), 5% of it
  CHECK(t.find("# Measured: shortest chord 5.983 cm (section 1)") != std::string::npos);
  CHECK(t.find("thickness: 0.2991, thickness_relative_to: length") != std::string::npos);
  CHECK(t.find("sizes_relative_to: length") != std::string::npos);
  CHECK(t.find("half the leading-edge radius") != std::string::npos);
  // 60 blades: the throat between neighbours (0.757 cm at the hub) limits the layer
  REQUIRE(mftest::run_cli({"init", csv.string(), "-o", (dir / "b60.yaml").string(), "--blades", "60"}).code == 0);
  std::string t60 = mftest::read_text(dir / "b60.yaml");
  CHECK(t60.find("a fifth of the narrowest throat") != std::string::npos);
  CHECK(t60.find("thickness: 0.1514,") != std::string::npos);
  // 200 blades overlap: refused, with the count that fits, nothing written
  auto over = mftest::run_cli({"init", csv.string(), "-o", (dir / "b200.yaml").string(), "--blades", "200"});
  CHECK(over.code == 2);
  CHECK(over.err.find("200 blades do not fit") != std::string::npos);
  CHECK(over.err.find("--blades 135 or fewer") != std::string::npos);
  CHECK(!fs::exists(dir / "b200.yaml"));
  // a z, r, theta table is recognised by its header; --units converts
  fs::path zrt = make("profiles.txt", "--layout zrt --units-comment cm");
  REQUIRE(mftest::run_cli({"init", zrt.string(), "-o", (dir / "z.yaml").string(), "--blades", "24", "--units", "m"}).code == 0);
  std::string tz = mftest::read_text(dir / "z.yaml");
  CHECK(tz.find("format: zrt, blades: 24, units: m") != std::string::npos);
  CHECK(tz.find("shortest chord 0.05983 m") != std::string::npos);
  // a bad line: exit 2 with the file and the line
  std::string bad = mftest::read_text(csv);
  bad.insert(bad.find("\n\n") + 1, "1.0;2.0\n");
  mftest::write_text(dir / "bad.csv", bad);
  auto b = mftest::run_cli({"init", (dir / "bad.csv").string(), "-o", (dir / "bad.yaml").string(), "--blades", "24"});
  CHECK(b.code == 2);
  CHECK(b.err.find("bad.csv") != std::string::npos);
  CHECK(b.err.find(", line ") != std::string::npos);
  CHECK(!fs::exists(dir / "bad.yaml"));
}

TEST_CASE("init: a small synthetic blade row, written by init and run as it is, ends valid") {
  // scripts/synthetic-blade.py: 4 sections of a cambered NACA-like profile with a sharp trailing
  // edge, r = 15 .. 18 cm, 36 blades; order 2 and 3 layers keep it short
  fs::path dir = mftest::temp_dir("init-blade-run");
  fs::path csv = dir / "row.csv";
  auto g = mftest::sh(std::string(MESHFLOW_PYTHON) + " " + MESHFLOW_SOURCE_DIR "/scripts/synthetic-blade.py " + csv.string() +
                      " --units-comment cm " + kSmallBlade + " 2>&1");
  REQUIRE_MESSAGE(g.code == 0, g.out);
  fs::path wf = dir / "row.yaml";
  auto r = mftest::run_cli({"init", csv.string(), "-o", wf.string(), "--blades", "36", "--order", "2", "--layers", "3"});
  REQUIRE_MESSAGE(r.code == 0, r.err);
  auto run = mftest::sh(std::string(MESHFLOW_EXE) + " run " + wf.string() + " --cache " + (dir / "cache").string() +
                        " --out " + (dir / "out").string() + " 2>&1");
  CAPTURE(run.out);
  CHECK(run.code == 0);
  auto report = nlohmann::json::parse(mftest::read_text(dir / "out/report.json"));
  CHECK(report["ok"] == true);
  CHECK(report["problems"].empty());
  auto split = mftest::stage_stats(dir / "out", "split");
  CHECK(split["mesh"]["invalid"] == 0);
  CHECK(split["split"]["layers"] == 3);
  CHECK(split["mesh"]["elements"]["prism"] > 0);
  auto geo = mftest::stage_stats(dir / "out", "geometry");
  CHECK(geo["sharp_trailing_edge_point"].is_number());
  CHECK(geo["faces_by_surface"]["blade"] == 2);
}

TEST_CASE("init: the default synthetic rotor at 60 blades meshes its inflow plane (a rounding-length CAD edge is no boundary segment)") {
  // scripts/synthetic-blade.py's default rotor (6 sections, r = 15 .. 30 cm) at 60 blades: the
  // boolean leaves an edge of rounding length on the inflow plane where the hub's junction strip
  // meets the periodic side; its two ends are one node, whose two (u,v) differed by ~1e-7, and
  // sweep stopped: "the boundary loops cross themselves ... in the parameter plane"
  fs::path dir = mftest::temp_dir("init-blade-60");
  fs::path csv = dir / "rotor.csv";
  auto g = mftest::sh(std::string(MESHFLOW_PYTHON) + " " + MESHFLOW_SOURCE_DIR "/scripts/synthetic-blade.py " + csv.string() + " 2>&1");
  REQUIRE_MESSAGE(g.code == 0, g.out);
  fs::path wf = dir / "rotor.yaml";
  REQUIRE(mftest::run_cli({"init", csv.string(), "-o", wf.string(), "--blades", "60"}).code == 0);
  std::string short_wf = mftest::workflow_without(wf, dir / "short.yaml", {"tet", "curve", "optimise", "split", "mesh"});
  auto run = mftest::sh(std::string(MESHFLOW_EXE) + " run " + short_wf + " --cache " + (dir / "cache").string() + " --out " +
                        (dir / "out").string() + " 2>&1");
  CAPTURE(run.out);
  CHECK(run.code == 0);
  auto sweep = mftest::stage_stats(dir / "out", "sweep");
  CHECK(sweep["mesh"]["invalid"] == 0);
  CHECK(sweep["sweep"]["prisms"].get<int>() > 0);
}
