// `meshflow init CAD_FILE [-o WORKFLOW] [--units U] [--order P] [--layers N] [--force]`: reads
// the CAD once (stages/geometry's importer), measures it (analyse.cpp) and writes a complete
// workflow a user can run as it is, every choice commented with the figure it came from.
#include "engine/command.hpp"
#include "engine/stage.hpp"
#include "stages/geometry/import.hpp"
#include "stages/init/init.hpp"

#include <cctype>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <sstream>

namespace meshflow::init {
namespace {
namespace fs = std::filesystem;

constexpr const char* kUsage = "init CAD_FILE [-o WORKFLOW] [--units U] [--order P] [--layers N] [--force]";

struct Options {
  fs::path cad, out;
  std::string units;
  int order = 4, layers = 10;
  bool force = false;
};

std::string fmt(double v) {
  char b[32];
  std::snprintf(b, sizeof b, "%.4g", v);
  return b;
}

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
    } else if (a == "-o" || a == "--output" || a == "--units" || a == "--order" || a == "--layers") {
      if (!has_value) return usage_error(a + " needs a value");
      const std::string& v = args[++i];
      if (a == "-o" || a == "--output") o.out = v;
      else if (a == "--units") o.units = v;
      else if (a == "--order" && !integer(a, v, 2, 6, o.order)) return 2;
      else if (a == "--layers" && !integer(a, v, 1, 100, o.layers)) return 2;
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

std::string workflow_text(const Options& o, const Analysis& a, const Choices& c) {
  fs::path out_dir = fs::absolute(o.out).parent_path();
  std::string cad_path = fs::relative(fs::absolute(o.cad), out_dir).generic_string();
  const std::string u = a.units;
  std::ostringstream y;
  y << "# Written by `meshflow init " << o.cad.filename().string() << "` for " << o.cad.filename().string() << ": "
    << a.solids << " solid(s), " << a.shells << " shell(s), " << a.faces << " faces, in " << u << ".\n"
    << "# Bounding box (" << fmt(a.box.lo.x) << ", " << fmt(a.box.lo.y) << ", " << fmt(a.box.lo.z) << ") - ("
    << fmt(a.box.hi.x) << ", " << fmt(a.box.hi.y) << ", " << fmt(a.box.hi.z) << ").\n"
    << "# Every choice below says what it came from; change any value and `meshflow run` reruns only\n"
    << "# the stages it affects. `meshflow run --set STAGE.PARAM=VALUE` tries a value without editing.\n"
    << "meshflow: 1\n"
    << "name: " << workflow_name(o.cad) << "\n"
    << "stages:\n";
  y << "  geometry:\n    kind: step\n    with: {file: \"" << cad_path << "\""
    << (o.units.empty() ? "" : ", units: " + o.units) << "}\n";
  const bool half = a.symmetry_plane != "none";
  if (a.domain)
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
  y << "outputs:\n"
    << "  shape: {from: heal, formats: [step]}\n"
    << "  mesh: {from: split, formats: [msh, vtu, nektar]}\n";
  return y.str();
}

int init_cmd(const std::vector<std::string>& args) {
  Options o;
  if (int rc = parse(args, o)) return rc;
  Analysis a;
  Choices c;
  try {
    cad::Shape shape = geometry::import_cad(o.cad, o.units, 1.0, [](const std::string&) {});
    a = analyse(shape);
    c = choose(a);
  } catch (const std::exception& e) {
    std::cerr << "meshflow init: " << o.cad.string() << ": " << e.what() << "\n";
    return 2;
  }
  std::string text = workflow_text(o, a, c);
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
  std::cout << "wrote " << o.out.string() << ": " << (a.domain ? "a fluid domain" : "a body in a far-field box") << ", "
            << a.walls.size() << " wall face(s), layer " << fmt(c.thickness) << " " << a.units << ", order " << o.order
            << ", " << o.layers << " layers\nrun it: meshflow run " << o.out.string() << "\n";
  return 0;
}

const CommandRegistrar reg({"init", kUsage,
                            "write a complete, commented workflow for a CAD file (body or domain, tags, layer, sizes)",
                            init_cmd});

}  // namespace
}  // namespace meshflow::init
