// End-to-end: the real `meshflow` binary on the real workflows of workflows/, as a user runs it.
#include <doctest/doctest.h>

#include "external_checks.hpp"
#include "support.hpp"

#include <nlohmann/json.hpp>

#include <array>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <random>
#include <sstream>
#include <string>
#include <sys/wait.h>
#include <unistd.h>

namespace fs = std::filesystem;
using nlohmann::json;

namespace {
using mftest::sh;
std::string meshflow() { return std::string(MESHFLOW_EXE); }

fs::path temp_dir() { return mftest::temp_dir("e2e"); }
std::string slurp(const fs::path& p) { return mftest::read_text(p); }
}  // namespace

TEST_CASE("every registered kind has a schema the validator enforces") {
  auto r = sh(meshflow() + " kinds --check");
  INFO(r.out);
  CHECK(r.code == 0);
}

TEST_CASE("schemas/workflow-editor.json is what this build generates") {
  auto r = sh(meshflow() + " kinds --editor-schema 2>/dev/null");
  REQUIRE(r.code == 0);
  INFO("regenerate it: build/meshflow kinds --editor-schema > schemas/workflow-editor.json");
  bool current = nlohmann::json::parse(r.out) == nlohmann::json::parse(slurp(fs::path(MESHFLOW_SOURCE_DIR) / "schemas/workflow-editor.json"));
  CHECK(current);
}

TEST_CASE("an independent JSON Schema validator (python3-jsonschema) accepts our workflows and our schemas") {
  std::string src = MESHFLOW_SOURCE_DIR;
  std::string files;
  for (auto& e : fs::directory_iterator(src + "/workflows"))
    if (e.path().extension() == ".yaml") files += " " + e.path().string();
  auto r = sh(std::string(MESHFLOW_PYTHON) + " " + src + "/tests/workflows/check_editor_schema.py " + src + "/schemas" + files);
  INFO(r.out);
  CHECK(r.code == 0);
  // and rejects what ours rejects
  fs::path d = temp_dir();
  std::ofstream(d / "bad.yaml") << "meshflow: 1\nname: x\nstages:\n  g: {kind: naca_wing, with: {chord: -1}}\n";
  auto bad = sh(std::string(MESHFLOW_PYTHON) + " " + src + "/tests/workflows/check_editor_schema.py " + src + "/schemas " +
                (d / "bad.yaml").string());
  CHECK(bad.code == 1);
  CHECK(bad.out.find("stages/g/with/chord") != std::string::npos);
  auto ours = sh(meshflow() + " dag " + (d / "bad.yaml").string());
  CHECK(ours.code == 2);
  fs::remove_all(d);
}

TEST_CASE("every workflow in workflows/ is valid") {
  int n = 0;
  for (auto& e : fs::directory_iterator(fs::path(MESHFLOW_SOURCE_DIR) / "workflows")) {
    if (e.path().extension() != ".yaml") continue;
    ++n;
    auto r = sh(meshflow() + " dag " + e.path().string());
    INFO(e.path().string(), r.out);
    CHECK(r.code == 0);
    // the first line tells editors where the schema is (the editor schema, with every kind's parameters)
    CHECK(slurp(e.path()).rfind("# yaml-language-server: $schema=../schemas/workflow-editor.json", 0) == 0);
  }
  CHECK(n >= 1);
}

TEST_CASE("naca_wingtip: runs, matches its golden, re-runs from cache, --set re-runs the stage") {
  fs::path d = temp_dir();
  std::string wf = std::string(MESHFLOW_SOURCE_DIR) + "/workflows/naca_wingtip.yaml";
  std::string common = " --cache " + (d / "cache").string() + " --out " + (d / "out").string();
  auto r = sh("cd " + d.string() + " && " + meshflow() + " check " + wf + common);
  INFO(r.out);
  REQUIRE(r.code == 0);
  CHECK(r.out.find("outputs agree") != std::string::npos);
  json rep = json::parse(slurp(d / "out/report.json"));
  CHECK(rep["ok"] == true);
  for (auto& s : rep["stages"]) CHECK(s["status"] == "ran");
  // the demo's order-4 boundary-layer mesh is valid everywhere: every stage's mesh has no
  // inverted element (Bezier bounds), the curved ones included after optimise untangles them
  for (auto& s : rep["stages"]) {
    if (!s.contains("stats") || !s["stats"].contains("mesh")) continue;
    INFO(s["name"].get<std::string>());
    if (s["name"] != "curve") CHECK(s["stats"]["mesh"]["invalid"] == 0);
    CHECK(s["stats"]["mesh"]["nonconforming_faces"] == 0);
  }
  // every real kind's key covers the code of its module (a changed algorithm is never a stale hit)
  for (auto& s : rep["stages"]) {
    json entry = json::parse(slurp(d / "cache/actions" / (s["key"].get<std::string>() + ".json")));
    std::string code = entry["preimage"].value("code", "");
    INFO(s["name"].get<std::string>());
    CHECK(code.size() == 64);
  }
  // independent checks of the order-4 result: VTK's own Lagrange cells (det J at samples of
  // every tet, wedge and hex) and Gmsh's AnalyseMeshQuality (authoritative for the tets)
  {
    const std::string src = MESHFLOW_SOURCE_DIR;
    auto vtk = mfcheck::vtk_flags(d / "out/mesh.vtu");
    int types = 0;
    for (auto& [cls, cb] : vtk) {
      INFO(cls);
      CHECK(cb.first > 0);
      CHECK(cb.second == 0);
      ++types;
    }
    CHECK(types == 3);  // tets, wedges, hexes
    auto by = mfcheck::gmsh_flags(d / "out/mesh.msh");
    REQUIRE(by.count("Tetrahedron"));
    CHECK(by["Tetrahedron"].first > 1000);
    CHECK(by["Tetrahedron"].second == 0);
    // the demo's CGNS: cgnscheck finds no error or warning, and the file reads back (our reader,
    // through `meshflow quality`) with the element counts and validity of the MSH
    {
      auto cg = sh("cgnscheck " + (d / "out/mesh.cgns").string() + " 2>&1");
      INFO(cg.out);
      CHECK(cg.code == 0);
      CHECK(cg.out.find("ERROR") == std::string::npos);
      CHECK(cg.out.find("WARNING") == std::string::npos);
      auto qc = sh("(" + meshflow() + " quality " + (d / "out/mesh.cgns").string() + " --json 2>/dev/null)");
      auto qm = sh("(" + meshflow() + " quality " + (d / "out/mesh.msh").string() + " --json 2>/dev/null)");
      REQUIRE(qc.code == 0);
      REQUIRE(qm.code == 0);
      json jc = json::parse(qc.out), jm = json::parse(qm.out);
      CHECK(jc["elements"] == jm["elements"]);
      CHECK(jc["nodes"] == jm["nodes"]);
      CHECK(jc["invalid"] == 0);
    }
    // Gmsh 4.8 flags order-4 pyramids whose det J its own getJacobians finds positive (README);
    // prisms and hexes it analyses only reliably at order 2, so they are not asserted here

    // the README's picture renderer, headless, on this VTU: a PNG of the size asked for
    auto png = d / "le.png";
    auto pr = sh("xvfb-run -a " + std::string(MESHFLOW_PYTHON) + " " + src + "/scripts/render-cut.py " + (d / "out/mesh.vtu").string() +
                 " " + png.string() + " --point 0 0 0.5 --normal 0 0 1 --box -0.1 0.12 -0.1 0.1 0 1 --up 0 1 0 --size 640 400 2>&1");
    INFO(pr.out);
    REQUIRE(pr.code == 0);
    std::string bytes = slurp(png);
    REQUIRE(bytes.size() > 10000);  // a picture with content, not a blank frame
    CHECK(bytes.substr(1, 3) == "PNG");
    auto be32 = [&](std::size_t o) {
      return (std::uint32_t(std::uint8_t(bytes[o])) << 24) | (std::uint32_t(std::uint8_t(bytes[o + 1])) << 16) |
             (std::uint32_t(std::uint8_t(bytes[o + 2])) << 8) | std::uint32_t(std::uint8_t(bytes[o + 3]));
    };
    CHECK(be32(16) == 640u);  // IHDR width, height
    CHECK(be32(20) == 400u);
    // a plane that misses every cell is refused with a message, not a blank picture
    auto miss = sh("xvfb-run -a " + std::string(MESHFLOW_PYTHON) + " " + src + "/scripts/render-cut.py " + (d / "out/mesh.vtu").string() +
                   " " + (d / "none.png").string() + " --point 0 0 0 --normal 0 0 1 --box 100 101 100 101 100 101 2>&1");
    CHECK(miss.code != 0);
    CHECK(miss.out.find("no cell") != std::string::npos);
  }
  auto r2 = sh(meshflow() + " run " + wf + common);
  json rep2 = json::parse(slurp(d / "out/report.json"));
  for (auto& s : rep2["stages"]) CHECK(s["status"] == "cached");
  // order 2: Gmsh's analysis is authoritative for every type; it must agree that nothing is inverted
  {
    auto o2 = sh(meshflow() + " run " + wf + common + " --set curve.order=2");
    INFO(o2.out);
    REQUIRE(o2.code == 0);
    json rep = json::parse(slurp(d / "out/report.json"));
    for (auto& s : rep["stages"]) {
      const std::string name = s["name"];
      const bool reran = name == "curve" || name == "optimise" || name == "split";
      CHECK(s["status"] == (reran ? "ran" : "cached"));
      if (name == "split") CHECK(s["stats"]["mesh"]["invalid"] == 0);
    }
    auto by = mfcheck::gmsh_flags(d / "out/mesh.msh");
    for (auto& [type, nb] : by) {
      INFO(type);
      CHECK(nb.second == 0);
    }
    CHECK(by.size() == 4);  // tets, prisms, hexes, pyramids

    // the solver-ready formats of the same run (a copy of the workflow asking for them, same
    // cache: nothing re-runs): meshio and Gmsh read the plain MSH of the linear and the order-2
    // mesh with equal counts, and the pyfr file keeps PyFR's importer rules (tests/io/pyfr_rules.py)
    std::string text = slurp(wf);
    auto swap = [&](const std::string& line_start, const std::string& to) {  // the whole line
      auto at = text.find(line_start);
      REQUIRE(at != std::string::npos);
      text.replace(at, text.find('\n', at) - at, to);
    };
    swap("linear: {from: tet", "linear: {from: tet, formats: [msh-plain]}");
    swap("mesh: {from: split", "mesh: {from: split, formats: [msh-plain, pyfr]}");
    text = text.substr(0, text.find("\ngolden:") + 1);
    std::ofstream(d / "solver.yaml") << text;
    auto sr = sh(meshflow() + " run " + (d / "solver.yaml").string() + " --cache " + (d / "cache").string() + " --out " +
                 (d / "solver").string() + " --set curve.order=2");
    INFO(sr.out);
    REQUIRE(sr.code == 0);
    json rs = json::parse(slurp(d / "solver/report.json"));
    for (auto& s : rs["stages"]) CHECK(s["status"] == "cached");
    const std::string py = std::string(MESHFLOW_PYTHON), src = MESHFLOW_SOURCE_DIR;
    for (const char* f : {"linear.plain.msh", "mesh.plain.msh"}) {
      INFO(f);
      auto c = sh(py + " -c \"import gmsh, meshio, sys\ngmsh.initialize()\ngmsh.option.setNumber('General.Terminal',0)\n"
                  "gmsh.open(sys.argv[1])\n_,t,_=gmsh.model.mesh.getElements()\nn,_,_=gmsh.model.mesh.getNodes()\nm=meshio.read(sys.argv[1])\n"
                  "print(len(n), sum(len(x) for x in t), len(m.points), sum(len(c.data) for c in m.cells))\" " +
                  (d / "solver" / f).string() + " 2>&1");
      INFO(c.out);
      REQUIRE(c.code == 0);
      std::istringstream in(c.out);
      long gn = 0, ge = 0, mn = 0, me = 0;
      in >> gn >> ge >> mn >> me;
      CHECK(gn > 1000);
      CHECK(ge > 1000);
      CHECK(mn == gn);
      CHECK(me == ge);
    }
    auto pr = sh(py + " " + src + "/tests/io/pyfr_rules.py " + (d / "solver/mesh.pyfr.msh").string());
    INFO(pr.out);
    CHECK(pr.code == 0);
    CHECK(pr.out.find("ok ") == 0);
    CHECK(pr.out.find(" 1 3 0\n") != std::string::npos);  // fluid; wall, farfield, symmetry; no periodic pair
  }
  // the mesh contract: the clean run kept every clause at every mesh stage (curve's inverted
  // elements are a note that optimise repairs); the curved mesh fills the CAD's fluid volume
  // and covers each face
  for (auto& s : rep["stages"]) {
    if (!s["stats"].contains("contract")) continue;
    INFO(s["name"].get<std::string>());
    CHECK(s["stats"]["contract"]["degenerate"] == 0);
    if (s["name"] != "curve") CHECK(s["stats"]["problems"].empty());
    if (s["stats"]["contract"].contains("volume_rel_error"))
      CHECK(s["stats"]["contract"]["volume_rel_error"].get<double>() < 1e-5);
    if (s["stats"]["contract"].contains("face_area_worst_rel_error") && s["name"] != "sweep")
      CHECK(s["stats"]["contract"]["face_area_worst_rel_error"].get<double>() < 1e-3);
  }
  // without untangling or linearising, the delivered mesh has inverted elements: not a success (exit 3), the
  // summary opens with where they are, the outputs are written and marked, check refuses
  {
    auto bad = sh(meshflow() + " run " + wf + common + " --set optimise.untangle=false --set optimise.linearise_invalid=false");
    INFO(bad.out);
    CHECK(bad.code == 3);
    auto first = bad.out.find("\nINVALID: the mesh breaks the contract");
    REQUIRE(first != std::string::npos);
    CHECK(bad.out.find("  split: validity: ", first) != std::string::npos);
    json rb = json::parse(slurp(d / "out/report.json"));
    CHECK(rb["ok"] == false);
    CHECK(rb["invalid"] == true);
    REQUIRE(rb["problems"].size() == 1);
    CHECK(rb["problems"][0]["stage"] == "split");
    CHECK(rb["problems"][0]["clause"] == "validity");
    CHECK(rb["problems"][0]["count"].get<int>() > 0);
    CHECK(rb["problems"][0]["where"][0]["at"].size() == 3);
    CHECK(rb["outputs"]["mesh"]["invalid"] == true);
    CHECK(fs::exists(d / "out/mesh.msh"));
    auto chk = sh(meshflow() + " check " + wf + common + " --set optimise.untangle=false --set optimise.linearise_invalid=false");
    CHECK(chk.code == 3);
    auto ok = sh(meshflow() + " run " + wf + common + " --set optimise.untangle=false --set optimise.linearise_invalid=false --allow-invalid");
    CHECK(ok.code == 0);
  }
  auto r3 = sh(meshflow() + " run " + wf + common + " --set geometry.span=2");
  json rep3 = json::parse(slurp(d / "out/report.json"));
  CHECK(rep3["stages"][0]["status"] == "ran");
  fs::remove_all(d);
}

TEST_CASE("cylinder_in_box.yaml to the end: every stage keeps the mesh contract, the curved mesh fills the CAD's volume") {
  REQUIRE(fs::exists(fs::path(MESHFLOW_DATA_DIR) / "corpus/cylinder_in_box.step"));
  fs::path d = temp_dir();
  std::string wf = std::string(MESHFLOW_SOURCE_DIR) + "/workflows/cylinder_in_box.yaml";
  auto t0 = std::chrono::steady_clock::now();
  auto r = sh(meshflow() + " run " + wf + " --cache " + (d / "cache").string() + " --out " + (d / "out").string() + " 2>&1");
  double secs = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  INFO(r.out);
  REQUIRE(r.code == 0);
  CHECK(secs < 120);  // issue 20's bound for this case on 2 cores (about 18 s idle)
  json rep = json::parse(slurp(d / "out/report.json"));
  CHECK(rep["ok"] == true);
  CHECK(rep["invalid"] == false);
  int checked = 0;
  for (auto& s : rep["stages"]) {
    if (!s["stats"].contains("contract")) continue;
    INFO(s["name"].get<std::string>());
    ++checked;
    CHECK(s["stats"]["problems"].empty());
    CHECK(s["stats"]["contract"]["degenerate"] == 0);
    CHECK(s["stats"]["mesh"]["max_aspect_ratio"].get<double>() < 100);  // no collapsed disc centre
    if (s["stats"]["contract"].contains("volume_rel_error"))
      CHECK(s["stats"]["contract"]["volume_rel_error"].get<double>() < 1e-9);
  }
  CHECK(checked == 5);  // sweep, tet, curve, optimise, split
  // an order-4 mesh without pyramids: meshio reads its plain MSH with Gmsh's counts (every type
  // at order 4), and its pyfr file keeps PyFR's importer rules
  const std::string py = std::string(MESHFLOW_PYTHON), src = MESHFLOW_SOURCE_DIR;
  auto c = sh(py + " -c \"import gmsh, meshio, sys\ngmsh.initialize()\ngmsh.option.setNumber('General.Terminal',0)\n"
              "gmsh.open(sys.argv[1])\n_,t,_=gmsh.model.mesh.getElements()\nn,_,_=gmsh.model.mesh.getNodes()\nm=meshio.read(sys.argv[1])\n"
              "print(len(n), sum(len(x) for x in t), len(m.points), sum(len(c.data) for c in m.cells))\" " +
              (d / "out/mesh.plain.msh").string() + " 2>&1");
  INFO(c.out);
  REQUIRE(c.code == 0);
  std::istringstream in(c.out);
  long gn = 0, ge = 0, mn = 0, me = 0;
  in >> gn >> ge >> mn >> me;
  CHECK(gn == rep["stages"].back()["stats"]["mesh"]["nodes"].get<long>());
  CHECK(ge > rep["stages"].back()["stats"]["mesh"]["elements"]["tet"].get<long>());  // volume and boundary elements
  CHECK(mn == gn);
  CHECK(me == ge);
  auto pr = sh(py + " " + src + "/tests/io/pyfr_rules.py " + (d / "out/mesh.pyfr.msh").string());
  INFO(pr.out);
  CHECK(pr.code == 0);
  CHECK(pr.out.find("ok " + std::to_string(gn) + " " + std::to_string(ge) + " 1 ") == 0);
  fs::remove_all(d);
}
