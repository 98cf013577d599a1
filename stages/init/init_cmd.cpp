// `meshflow init CAD_FILE [-o WORKFLOW] [--units U] [--order P] [--layers N] [--force]`: reads
// the CAD once (stages/geometry's importer), measures it (analyse.cpp) and writes a complete
// workflow a user can run as it is, every choice commented with the figure it came from.
#include "engine/command.hpp"
#include "engine/runner.hpp"
#include "engine/stage.hpp"
#include "engine/workflow.hpp"
#include "stages/geometry/blade_sections.hpp"
#include "stages/geometry/import.hpp"
#include "stages/geometry/section_util.hpp"
#include "stages/init/init.hpp"

#include <cctype>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <iterator>
#include <regex>
#include <sstream>

namespace meshflow::init {
namespace {
namespace fs = std::filesystem;

constexpr const char* kUsage =
    "init CAD_FILE|SECTIONS [-o WORKFLOW] [--units U] [--order P] [--layers N] [--blades N] [--cache DIR] "
    "[--fluid auto|box] [--no-preflight] [--force]";

struct Options {
  fs::path cad, out, cache;
  std::string units;
  int order = 4, layers = 10, blades = 0;
  bool force = false, preflight = true, as_body = false;
};

int usage_error(const std::string& what) {
  std::cerr << "meshflow init: " << what << "\nusage: meshflow " << kUsage << "\n";
  return 2;
}

// Parses the arguments; returns 0 when they are good, else the exit code after the message.
int parse(const std::vector<std::string>& args, Options& o) {
  auto integer = [&](const std::string& flag, const std::string& v, int lo, int hi, int& out) {
    try {
      size_t n = 0;
      out = std::stoi(v, &n);
      if (n == v.size() && out >= lo && out <= hi) return true;
    } catch (const std::exception&) {
    }
    usage_error(flag + " takes a whole number from " + std::to_string(lo) + " to " + std::to_string(hi) + ", not '" + v + "'");
    return false;
  };
  for (size_t i = 0; i < args.size(); ++i) {
    const std::string& a = args[i];
    bool has_value = i + 1 < args.size();
    if (a == "--force") {
      o.force = true;
    } else if (a == "--no-preflight") {
      o.preflight = false;
    } else if (a == "-o" || a == "--output" || a == "--units" || a == "--order" || a == "--layers" || a == "--blades" ||
               a == "--cache" || a == "--fluid") {
      if (!has_value) return usage_error(a + " needs a value");
      const std::string& v = args[++i];
      if (a == "-o" || a == "--output") o.out = v;
      else if (a == "--cache") o.cache = v;
      else if (a == "--fluid" && v != "auto" && v != "box") return usage_error("--fluid takes auto or box, not '" + v + "'");
      else if (a == "--fluid") o.as_body = v == "box";
      else if (a == "--units") o.units = v;
      else if (a == "--order" && !integer(a, v, 2, 6, o.order)) return 2;
      else if (a == "--layers" && !integer(a, v, 1, 100, o.layers)) return 2;
      else if (a == "--blades" && !integer(a, v, 1, 1000, o.blades)) return 2;
    } else if (!a.empty() && a[0] == '-') {
      return usage_error("unknown option " + a);
    } else if (o.cad.empty()) {
      o.cad = a;
    } else {
      return usage_error("one CAD_FILE expected, got '" + o.cad.string() + "' and '" + a + "'");
    }
  }
  if (o.cad.empty()) return usage_error("a CAD_FILE (.step/.stp, .iges/.igs, .brep/.brp) is needed");
  if (o.out.empty()) o.out = o.cad.stem().string() + ".yaml";
  if (fs::exists(o.out) && !o.force)
    return usage_error("'" + o.out.string() + "' exists: give another -o, or --force to overwrite it");
  return 0;
}

// A workflow name: the file's stem in lower case, other characters as '-'.
std::string workflow_name(const fs::path& cad) {
  std::string n;
  for (char c : cad.stem().string()) n += std::isalnum((unsigned char)c) ? (char)std::tolower((unsigned char)c) : '-';
  return n.empty() ? "mesh" : n;
}

// A path as a YAML flow scalar: plain when it can be, else double-quoted.
std::string yaml_path(const std::string& p) {
  if (!p.empty() && p.find_first_of(":#{}[],&*?|<>=!%@`'\"\\ ") == std::string::npos && p[0] != '-') return p;
  std::string q = "\"";
  for (char c : p) q += (c == '"' || c == '\\') ? std::string("\\") + c : std::string(1, c);
  return q + "\"";
}

// A comment above a stage, wrapped at 100 columns.
std::string comment(const std::string& text) {
  std::string out, line, word;
  std::istringstream in(text);
  while (in >> word) {
    if (!line.empty() && line.size() + 1 + word.size() > 96) out += "  # " + line + "\n", line.clear();
    line += (line.empty() ? "" : " ") + word;
  }
  if (!line.empty()) out += "  # " + line + "\n";
  return out;
}

// The input file's path as the workflow names it: relative to the workflow's folder.
std::string input_path(const Options& o) {
  return yaml_path(fs::relative(fs::absolute(o.cad), fs::absolute(o.out).parent_path()).generic_string());
}

// The workflow's outputs: the healed CAD and the final mesh for the solvers.
constexpr const char* kOutputs =
    "outputs:\n"
    "  shape: {from: heal, formats: [step]}\n"
    "  mesh: {from: split, formats: [msh, vtu, nektar]}\n";

// An internal flow's tags: every face wall (a box round the whole shape), then each port's
// plane farfield: selectors that hold whatever ids heal gives the faces.
std::string port_tags(const Analysis& a) {
  auto v3 = [](const cad::Vec3& p) { return "[" + fmt(p.x) + ", " + fmt(p.y) + ", " + fmt(p.z) + "]"; };
  const double pad = 0.01 * a.extent;
  const cad::Vec3 lo{a.box.lo.x - pad, a.box.lo.y - pad, a.box.lo.z - pad}, hi{a.box.hi.x + pad, a.box.hi.y + pad, a.box.hi.z + pad};
  std::string y = "      tag_overrides:\n        - {tag: wall, box: {min: " + v3(lo) + ", max: " + v3(hi) + "}}\n";
  for (auto& p : a.ports) {
    // the point and normal at 10 significant digits: the plane selector's tolerance is 1e-6 of the diagonal
    char pt[160], nm[160];
    std::snprintf(pt, sizeof pt, "[%.10g, %.10g, %.10g]", p.point.x, p.point.y, p.point.z);
    std::snprintf(nm, sizeof nm, "[%.10g, %.10g, %.10g]", p.normal.x, p.normal.y, p.normal.z);
    y += "        - {tag: farfield, plane: {point: " + std::string(pt) + ", normal: " + nm + "}}  # port, area " + fmt(p.area) + "\n";
  }
  return y;
}

std::string workflow_text(const Options& o, const Analysis& a, const Choices& c, const std::string& preflight_note = "") {
  const std::string u = a.units;
  std::ostringstream y;
  y << "# Written by `meshflow init " << o.cad.filename().string() << "` for " << o.cad.filename().string() << ": "
    << a.solids << " solid(s), " << a.shells << " shell(s), " << a.faces << " faces, in " << u << ".\n"
    << "# Bounding box (" << fmt(a.box.lo.x) << ", " << fmt(a.box.lo.y) << ", " << fmt(a.box.lo.z) << ") - ("
    << fmt(a.box.hi.x) << ", " << fmt(a.box.hi.y) << ", " << fmt(a.box.hi.z) << ").\n"
    << (a.units_note.empty() || !o.units.empty() ? std::string() : "# Units: " + a.units_note + ".\n")
    << preflight_note
    << "# Every choice below says what it came from; change any value and `meshflow run` reruns only\n"
    << "# the stages it affects. `meshflow run --set STAGE.PARAM=VALUE` tries a value without editing.\n"
    << "meshflow: 1\n"
    << "name: " << workflow_name(o.cad) << "\n"
    << "stages:\n";
  y << "  geometry:\n    kind: step\n    with: {file: " << input_path(o)
    << (o.units.empty() ? "" : ", units: " + o.units) << "}\n";
  const bool half = a.symmetry_plane != "none";
  if (a.internal)
    y << comment("fluid: given. " + a.why + ".")
      << comment("Tags: every face wall, then the " + std::to_string(a.ports.size()) +
                 " port(s) farfield by their planes (tag_overrides below; change them there).");
  else if (a.domain)
    y << comment("fluid: given. The file is the fluid domain: " + a.why + ".")
      << comment("Tags: its faces on its bounding box's planes are farfield (symmetry where a wall meets them), the "
                 "other " + std::to_string(a.walls.size()) + " face(s) walls. Change them with tag_overrides.");
  else
    y << comment("fluid: box. The file is a body: " + a.why + ". Its " + std::to_string(a.walls.size()) +
                 " face(s) are walls, the box's faces farfield.")
      << comment("symmetry_plane: " + a.symmetry_plane + ". " + a.stands_why + "." +
                 (half ? " The box is not padded on that side and its face there is symmetry; symmetry_plane: none "
                         "meshes the whole body in a box."
                       : " symmetry_plane: x-|x+|y-|y+|z-|z+ makes that side of the box the symmetry plane of a half "
                         "model."));
  if (a.internal)
    y << "  heal:\n    kind: heal\n    needs: [geometry]\n    with:\n      fluid: given\n" << port_tags(a);
  else
    y << "  heal: {kind: heal, needs: [geometry], with: {fluid: " << (a.domain ? "given" : "box")
      << (half ? ", symmetry_plane: " + a.symmetry_plane : std::string()) << "}}\n";
  y << "  medial: {kind: medial, needs: [heal]}\n";
  y << comment("Boundary-layer thickness " + fmt(c.thickness) + " " + u + ": " + c.thickness_why +
               ". Where walls face each other closer than that, the layer thins there.")
    << "  shell:\n    kind: shell\n    needs: [heal, medial]\n    with: {thickness: " << fmt(c.thickness)
    << ", thickness_relative_to: length, topology: C}\n";
  y << comment("Wall element sizes, fractions of the walls' largest side " + fmt(a.wall_max) + " " + u +
               ": min_size " + fmt(c.min_size) + " because " + c.min_size_why + "; max_size 0.1 on flat walls.")
    << "  balance: {kind: balance, needs: [heal, shell], with: {turn_angle_deg: 30, min_size: " << fmt(c.min_size)
    << ", max_size: 0.1}}\n";
  y << comment("Far-field element size " + fmt(c.farfield_size) + " x the walls' largest side: " + c.farfield_why + ".")
    << "  sweep: {kind: sweep, needs: [heal, shell, balance], with: {farfield_size: " << fmt(c.farfield_size) << "}}\n";
  y << comment("Tetrahedra grow away from the boundary layer by size_growth 0.3 (element size per unit distance).")
    << "  tet: {kind: tet, needs: [sweep]}\n";
  y << comment("Polynomial order " + std::to_string(o.order) + (o.order == 4 ? " (the default; --order P)." : " (--order)."))
    << "  curve: {kind: curve, needs: [heal, tet], with: {order: " << o.order << "}}\n"
    << "  optimise: {kind: optimise, needs: [heal, curve]}\n";
  y << comment(std::to_string(o.layers) + " layers across the boundary layer, growing by 1.3 from the wall" +
               (o.layers == 10 ? " (--layers N); " : "; ") + "first_height: H sets the wall layer's height instead.")
    << "  split: {kind: split, needs: [optimise], with: {layers: " << o.layers << ", ratio: 1.3}}\n";
  y << kOutputs;
  return y.str();
}

// A blade row's section file (Rotor 67's export, or CSV sections): read with the blade_sector
// kind's own parsers, for the format, the blade count and the figures in the comments.
bool is_section_file(const fs::path& p) {
  std::string e = p.extension().string();
  for (auto& c : e) c = (char)std::tolower((unsigned char)c);
  return e == ".csv" || e == ".dat" || e == ".txt";
}

// The figures line of a blade workflow's header.
std::string blade_figures_text(const BladeFigures& f, const std::string& u) {
  return "# Measured: shortest chord " + fmt(f.chord) + " " + u + " (section " + std::to_string(f.chord_section + 1) +
         "), leading-edge radius " + fmt(f.le_radius) + " (section " + std::to_string(f.le_section + 1) +
         "), smallest radius of curvature " + fmt(f.min_radius) + " (section " + std::to_string(f.min_radius_section + 1) +
         "),\n# narrowest throat to the next blade " + fmt(f.throat) + " (section " + std::to_string(f.throat_section + 1) +
         ", pitch 2*pi*r/N = " + fmt(f.throat_radius * f.pitch_angle) + "), blade height " + fmt(f.height) + " " + u + ".\n";
}

std::string blade_workflow_text(const Options& o) {
  std::ifstream in(o.cad, std::ios::binary);
  if (!in) throw StageError("cannot read the section file '" + o.cad.string() + "'");
  std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const bool rotor67 = geometry::is_rotor67_export(text);
  const auto layout = geometry::detect_table_layout(text);
  const std::string format = rotor67 ? "rotor67" : layout == geometry::TableLayout::zrt ? "zrt" : "csv";
  geometry::BladeSections bs = rotor67 ? geometry::parse_rotor67(text, o.cad.string())
                                       : geometry::parse_blade_table(text, o.cad.string(), {layout, "", 0, 0});
  int blades = o.blades ? o.blades : bs.blades;
  if (blades <= 0)
    throw StageError("the section file does not say how many blades the row has: give --blades N");
  // the result's unit: --units, else the file's declared one (rotor67: ft; an undeclared table: m)
  const std::string file_units = !bs.units.empty() ? bs.units : rotor67 ? "ft" : "";
  const std::string u = !o.units.empty() ? o.units : !file_units.empty() ? file_units : "m";
  const double to_result = !bs.units.empty() && !o.units.empty() && o.units != bs.units
                               ? geometry::length_unit_in_m(bs.units) / geometry::length_unit_in_m(o.units) : 1.0;
  const BladeFigures f = measure_blade(bs, blades, to_result);
  if (blades > f.max_blades)
    throw StageError(std::to_string(blades) + " blades do not fit round the row: at section " +
                     std::to_string(f.half_angle_section + 1) + " (radius " + fmt(f.half_angle_radius) + " " + u +
                     ") the blade spans " + fmt(2 * f.half_angle * 180 / 3.14159265358979323846) +
                     " degrees about the axis, more than the pitch 360/N = " + fmt(360.0 / blades) +
                     " degrees; give --blades " + std::to_string(f.max_blades) + " or fewer (neighbouring blades would overlap)");
  const BladeChoices c = choose_blade(f);
  double x0 = 1e300, x1 = -1e300, hub = 1e300, casing = 0;
  for (auto& l : bs.loops)
    for (auto& p : l) hub = std::min(hub, p.r), casing = std::max(casing, p.r), x0 = std::min(x0, p.x), x1 = std::max(x1, p.x);
  const double cax = (x1 - x0) * to_result;
  const char* what = rotor67 ? "NASA Rotor 67 export" : format == "zrt" ? "z, r, theta table" : "x, y, z table";
  std::ostringstream y;
  y << "# Written by `meshflow init " << o.cad.filename().string() << "`: a blade row of " << blades << " blades, "
    << bs.loops.size() << " sections (" << what << "), in " << u
    << (file_units.empty() && o.units.empty() ? " (the file does not say: '# units: cm' or --units U)" : "") << ".\n"
    << "# Blade: radius " << fmt(hub * to_result) << " to " << fmt(casing * to_result) << ", axial extent " << fmt(cax) << " " << u
    << "; one passage, a 2*pi/" << blades << " sector with periodic sides.\n"
    << blade_figures_text(f, u);
  for (auto& n : bs.notes) y << "# Read: " << n << ".\n";
  y << "# Change any value and `meshflow run` reruns only the stages it affects.\n"
    << "meshflow: 1\n"
    << "name: " << workflow_name(o.cad) << "\n"
    << "stages:\n";
  y << comment("Inflow and outflow planes one axial chord (" + fmt(cax) + " " + u + ") from the blade; " +
               (o.blades ? "--blades " + std::to_string(blades) : "the file's " + std::to_string(blades) + " blades") + ".")
    << "  geometry:\n    kind: blade_sector\n    with: {file: " << input_path(o) << ", format: " << format
    << ", blades: " << blades << (o.units.empty() ? "" : ", units: " + o.units) << ", upstream: 1.0, downstream: 1.0}\n"
    << "  heal: {kind: heal, needs: [geometry]}\n"
    << "  medial: {kind: medial, needs: [heal]}\n";
  y << comment("Layer thickness " + fmt(c.thickness) + " " + u + ": " + c.thickness_why +
               "; the shell thins the layer where walls face each other closer.")
    << "  shell: {kind: shell, needs: [heal, medial], with: {thickness: " << fmt(c.thickness)
    << ", thickness_relative_to: length, topology: C}}\n";
  y << comment("Wall element sizes: min_size " + fmt(c.min_size) + " " + u + ", " + c.min_size_why + "; max_size " +
               fmt(c.max_size) + " " + u + ", " + c.max_size_why + ".")
    << "  balance: {kind: balance, needs: [heal, shell], with: {turn_angle_deg: 30, sizes_relative_to: length, min_size: "
    << fmt(c.min_size) << ", max_size: " << fmt(c.max_size) << "}}\n";
  y << comment("The periodic sides get the same surface mesh, rotated by 2*pi/" + std::to_string(blades) + ".")
    << "  periodic_match: {kind: periodic_match, needs: [heal, balance]}\n"
    << "  sweep: {kind: sweep, needs: [heal, shell, balance, periodic_match]}\n"
    << "  tet: {kind: tet, needs: [sweep]}\n";
  y << comment("Polynomial order " + std::to_string(o.order) + "; " + std::to_string(o.layers) +
               " layers across the boundary layer, growing by 1.3 from the wall.")
    << "  curve: {kind: curve, needs: [heal, tet], with: {order: " << o.order << "}}\n"
    << "  optimise: {kind: optimise, needs: [heal, curve]}\n"
    << "  split: {kind: split, needs: [optimise], with: {layers: " << o.layers << ", ratio: 1.3}}\n";
  y << kOutputs;
  return y.str();
}

// The preflight: geometry, heal, medial and shell of the workflow run on the cache its own run
// will use (so that run finds them cached), and what they refuse adapted where the refusal
// says how: a layer thicker than the domain holds is lowered to 0.9 x the largest the shell
// stage allows; a half model heal cannot close on its plane is meshed whole. At most 4 runs.
// Returns the comment lines for the workflow's header (what ran, what changed, what failed).
std::string preflight(const Options& o, Analysis& a, Choices& c) {
  const std::regex thinner(R"(Use a thickness of at most ([0-9.eE+-]+))");
  std::string changes, outcome;
  for (int attempt = 0; attempt < 4; ++attempt) {
    RunResult r;
    try {
      Workflow wf = load_workflow_text(workflow_text(o, a, c), fs::absolute(o.out)).upstream_of("shell");
      RunOptions ro;
      ro.cache_dir = o.cache;
      ro.materialise = false;
      ro.deliver = false;
      std::ostringstream sink;
      ro.out = &sink, ro.err = &sink;
      r = run_workflow(wf, ro);
    } catch (const std::exception& e) {
      return "# Preflight: not run (" + std::string(e.what()) + ").\n";
    }
    if (r.ok) {
      outcome = "geometry, heal, medial and shell ran to the end (cached for `meshflow run`)";
      break;
    }
    const StageResult* failed = nullptr;
    for (auto& st : r.stages)
      if (st.status == "failed" || st.status == "invalid") failed = &st;
    if (!failed) {
      outcome = "the run did not end ok";
      break;
    }
    std::string first = failed->error.substr(0, failed->error.find('\n'));
    outcome = "stage " + failed->name + " failed: " + first.substr(0, 300);
    std::smatch m;
    if (failed->kind == "shell" && std::regex_search(failed->error, m, thinner)) {
      const double most = std::stod(m[1].str());
      if (!(most > 0) || most >= c.thickness) break;
      changes += "# Preflight: the shell stage found the fluid holds a layer of at most " + fmt(most) + " " + a.units +
                 " over most of the wall: thickness " + fmt(c.thickness) + " -> " + fmt(0.9 * most) + ".\n";
      c.thickness = 0.9 * most;
      c.thickness_why += "; lowered by init's preflight to 0.9 x the largest the shell stage allows";
      continue;
    }
    if (failed->kind == "heal" && a.symmetry_plane != "none") {
      changes += "# Preflight: heal failed on the half model (" + first.substr(0, 200) + "): meshed whole, symmetry_plane: none.\n";
      a.stands_why += "; init's preflight: heal could not close it on that plane, so it is meshed whole";
      a.symmetry_plane = "none";
      continue;
    }
    break;
  }
  return changes + "# Preflight: " + outcome + ".\n";
}

// Writes `text` to o.out through a temporary file (no partial workflow on failure).
int write_workflow(const Options& o, const std::string& text) {
  fs::path tmp = o.out;
  tmp += ".tmp";
  {
    std::ofstream f(tmp, std::ios::binary);
    f << text;
    if (!f) {
      std::cerr << "meshflow init: cannot write '" << o.out.string() << "'\n";
      return 2;
    }
  }
  fs::rename(tmp, o.out);
  return 0;
}

int init_cmd(const std::vector<std::string>& args) {
  Options o;
  if (int rc = parse(args, o)) return rc;
  if (is_section_file(o.cad)) {
    std::string text;
    try {
      text = blade_workflow_text(o);
    } catch (const std::exception& e) {
      std::cerr << "meshflow init: " << o.cad.string() << ": " << e.what() << "\n";
      return 2;
    }
    if (int rc = write_workflow(o, text)) return rc;
    std::cout << "wrote " << o.out.string() << ": a blade row passage, order " << o.order << ", " << o.layers
              << " layers\nrun it: meshflow run " << o.out.string() << "\n";
    return 0;
  }
  Analysis a;
  Choices c;
  try {
    cad::Shape shape = geometry::import_cad(o.cad, o.units, 1.0, [](const std::string&) {});
    a = analyse(shape, o.as_body);
    c = choose(a);
  } catch (const std::exception& e) {
    std::cerr << "meshflow init: " << o.cad.string() << ": " << e.what() << "\n";
    return 2;
  }
  std::string note;
  if (o.preflight) note = preflight(o, a, c);
  if (int rc = write_workflow(o, workflow_text(o, a, c, note))) return rc;
  if (!note.empty()) std::cout << note;
  std::cout << "wrote " << o.out.string() << ": "
            << (a.internal ? "an internal flow (" + std::to_string(a.ports.size()) + " ports)" : a.domain ? "a fluid domain" : "a body in a far-field box")
            << ", "
            << a.walls.size() << " wall face(s), layer " << fmt(c.thickness) << " " << a.units << ", order " << o.order
            << ", " << o.layers << " layers\n"
            << (a.units_note.empty() || !o.units.empty() ? std::string() : "note: " + a.units_note + "\n")
            << "run it: meshflow run " << o.out.string() << "\n";
  return 0;
}

const CommandRegistrar reg({"init", kUsage,
                            "write a complete, commented workflow for a CAD file (body or domain, tags, layer, sizes)",
                            init_cmd});

}  // namespace
}  // namespace meshflow::init
