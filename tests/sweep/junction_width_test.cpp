// Junction strips wider than the face they lie on (the DLR-F6 case, in small): a block with a
// second block on top leaves a ledge 0.2 wide around it, joined to the upper block's sides by
// concave edges (C-type junctions), and the shell is 0.5 thick. The strip on the ledge may be at
// most half the ledge wide, so the shell limits the thickness there (shell.hpp, "junction strips
// limited by the width of their faces"): before, the closed ring's strip curve ran 0.3 outside
// the ledge (nodes classified on the ledge lay off the body, undetected by validity) and the open
// U stopped sweep ("the nodes of CAD edge 21 are out of order after the junction corner was
// placed on it"). Each case about 10 s.
#include <doctest/doctest.h>

#include "ledge_shapes.hpp"
#include "stages/io/mesh_io.hpp"
#include "stages/model/quality.hpp"
#include "support.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <filesystem>
#include <string>

namespace {
namespace fs = std::filesystem;

// runs the ledge workflow up to `last` (sweep or tet); returns the output folder. With `result`,
// the run's exit code and output go there instead of being required to succeed.
fs::path run_ledge(const std::string& tag, bool open_u, const std::string& last, mftest::ShellResult* result = nullptr,
                   const std::string& shell_extra = "") {
  fs::path dir = mftest::temp_dir(tag);
  sweeptest::write_ledge_body(dir / "ledge.brep", 0.2, open_u);
  std::string wf = "meshflow: 1\nname: ledge\nstages:\n"
                   "  geometry: {kind: step, with: {file: ledge.brep, units: m}}\n"
                   "  heal: {kind: heal, needs: [geometry], with: {fluid: box, box_padding: 1}}\n"
                   "  medial: {kind: medial, needs: [heal]}\n"
                   "  shell: {kind: shell, needs: [heal, medial], with: {thickness: 0.125, topology: C, junction_with: [wall]" +
                   shell_extra + "}}\n"
                   "  balance: {kind: balance, needs: [heal, shell]}\n"
                   "  sweep: {kind: sweep, needs: [heal, shell, balance]}\n";
  if (last == "tet" || last == "split") wf += "  tet: {kind: tet, needs: [sweep]}\n";
  if (last == "split")
    wf += "  curve: {kind: curve, needs: [heal, tet], with: {order: 4}}\n"
          "  optimise: {kind: optimise, needs: [heal, curve]}\n"
          "  split: {kind: split, needs: [optimise], with: {layers: 10, ratio: 1.5}}\n";
  wf += "outputs:\n  mesh: {from: " + last + ", formats: [msh]}\n";
  mftest::write_text(dir / "wf.yaml", wf);
  auto r = mftest::sh(std::string(MESHFLOW_EXE) + " run " + (dir / "wf.yaml").string() + " --cache " + (dir / "cache").string() +
                      " --out " + (dir / "out").string() + " 2>&1");
  if (result) {
    *result = r;
    return dir / "out";
  }
  INFO(r.out);
  REQUIRE(r.code == 0);
  return dir / "out";
}

// the shell's face-width limit acted at the ledge: th <= 0.5 x 0.2, the requested 0.5 elsewhere
void check_shell(const fs::path& out) {
  auto st = mftest::stage_stats(out, "shell");
  REQUIRE(st.contains("not_honoured"));
  REQUIRE(st["not_honoured"].contains("limited_by_face_width"));
  auto lim = st["not_honoured"]["limited_by_face_width"];
  MESSAGE("shell: " << lim.dump() << ", crossings " << st.at("self_intersections"));
  CHECK(lim.at("stations").get<long>() > 0);
  CHECK(lim.at("min").get<double>() <= 0.1 * (1 + 1e-3));
  CHECK(lim.at("min").get<double>() > 0.09);
  CHECK(st.at("junction_strip_fallback_faces").empty());
  CHECK(st.at("thickness").at("grid_max").get<double>() == doctest::Approx(0.5));
}

// valid, conforming, and every node classified on a wall face lies on the body (its box
// [0,4] x [0,4] x [0,2]; the far-field box is 4 away)
void check_mesh(const fs::path& file) {
  auto m = meshflow::io::read_mesh(file);
  auto st = meshflow::model::mesh_stats(m);
  CHECK(st.at("invalid").get<int>() == 0);
  CHECK(st.at("nonconforming_faces").get<int>() == 0);
  REQUIRE(m.node_entity_dim.size() == m.num_nodes());
  long off = 0, on = 0;
  for (std::size_t i = 0; i < m.num_nodes(); ++i) {
    if (m.node_entity_dim[i] != 2) continue;
    double x = m.x[i], y = m.y[i], z = m.z[i];
    bool near_body = x > -1 && x < 5 && y > -1 && y < 5 && z > -1 && z < 3;
    if (!near_body) continue;
    ++on;
    const double e = 1e-9;
    if (x < -e || x > 4 + e || y < -e || y > 4 + e || z < -e || z > 2 + e) ++off;
  }
  CHECK(on > 100);
  CHECK(off == 0);
}
}  // namespace

TEST_CASE("junction along a ledge narrower than its strip (closed ring): thickness limited by the face width, strip nodes on the ledge, valid mesh through tet") {
  fs::path out = run_ledge("jw-ring", false, "tet");
  check_shell(out);
  check_mesh(out / "mesh.msh");
  auto sw = mftest::stage_stats(out, "sweep");
  CHECK(sw.at("mesh").at("elements").at("hex").get<long>() > 0);
}

// The open U: the junctions end where the upper block is flush with the lower one, at a third
// face (the common side y = 4), which is not part of the junction. The hex's end face and the side
// faces of the third face's two prisms at the junction's end vertex used to bound a pocket (the
// edge between those prisms' tops used by four faces of the outer surface; tet refused it, TetGen
// had stopped with signal 11). sweep now caps both ends (sweep.hpp, "Junction ends on a third
// face"): the third face's prisms at the vertex become tets and pyramids with apex the vertex's
// shell node and the pocket a pyramid on the end face, so tet fills the far field. Without the
// caps (end_caps 0) tet fails here again.
TEST_CASE("junction along a ledge narrower than its strip (open U, junction ends at a third face, shell.third_face_ends cap): sweep caps both junction ends, tet fills the far field, valid and conforming") {
  mftest::ShellResult r;
  fs::path out = run_ledge("jw-u", true, "tet", &r, ", third_face_ends: cap");
  INFO(r.out);
  REQUIRE(r.code == 0);
  CHECK(r.out.find("is used by 4 faces") == std::string::npos);
  check_shell(out);
  check_mesh(out / "mesh.msh");
  auto sw = mftest::stage_stats(out, "sweep");
  MESSAGE("sweep: " << sw.at("sweep").dump());
  CHECK(sw.at("sweep").at("end_caps").get<int>() == 2);
  // per end: one tet per prism of the fan at the vertex, one pyramid each plus the pocket's
  auto caps = sw.at("sweep");
  CHECK(caps.at("cap_pyramids").get<int>() == caps.at("cap_tets").get<int>() + 2);
  auto m = meshflow::io::read_mesh(out / "mesh.msh");
  auto st = meshflow::model::mesh_stats(m);
  CHECK(st.at("elements").at("hex").get<long>() > 0);
  CHECK(st.at("elements").at("pyramid").get<long>() == caps.at("cap_pyramids").get<long>());  // tet added none: no exposed quad
  CHECK(st.at("elements").at("tet").get<long>() > 1000);
}

// The open U with the default third_face_ends (averaged): the junction chain along the U ends on
// the common flush side at both ends, so the shell gives it averaged normals instead of blocks
// (stats.junction_chains_averaged: the whole chain, named by its end), no end caps are needed,
// and every near-field element is a prism, which split layers: the run reaches the end, valid
// and conforming, prisms x10. With cap (above) split refuses the caps' pyramids.
TEST_CASE("open U with shell.third_face_ends averaged (the default): the chain ending on the third face gets no blocks, and the run reaches split valid") {
  mftest::ShellResult r;
  fs::path out = run_ledge("jw-u-avg", true, "split", &r);
  INFO(r.out);
  REQUIRE(r.code == 0);
  auto sh = mftest::stage_stats(out, "shell");
  REQUIRE(sh.contains("junction_chains_averaged"));
  auto chains = sh.at("junction_chains_averaged");
  MESSAGE("shell: " << chains.dump());
  REQUIRE(chains.size() >= 1);
  for (auto& c : chains) CHECK(c.at("edges").size() >= 1);
  CHECK(sh.at("counts").at("hex_junction_blocks").get<long>() == 0);  // the U's chain is its only junction
  auto sw = mftest::stage_stats(out, "sweep");
  CHECK(sw.at("sweep").at("end_caps").get<int>() == 0);
  CHECK(sw.at("mesh").at("invalid").get<int>() == 0);
  auto lin = meshflow::io::read_mesh(out / "mesh.msh");
  auto st = meshflow::model::mesh_stats(lin);
  CHECK(st.at("order").get<int>() == 4);
  CHECK(st.at("invalid").get<int>() == 0);
  CHECK(st.at("nonconforming_faces").get<int>() == 0);
  CHECK(st.at("elements").at("prism").get<long>() == 10 * sw.at("mesh").at("elements").at("prism").get<long>());
  CHECK(st.at("elements").at("hex").get<long>() == 0);
}
