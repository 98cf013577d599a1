// meshflow shell — the "shell" artifact: writer, reader, field evaluation, summary, artifact
// type. Format: see shell.hpp. No CGAL, no OCCT (the CAD through stages/cad/cad.hpp).
#include "engine/artifact_type.hpp"
#include "engine/stage.hpp"
#include "stages/shell/shell.hpp"
#include "stages/cad/cad.hpp"
#include "stages/cad/vec3.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstring>
#include <fstream>
#include <sstream>
#include <stdexcept>

namespace meshflow::shell {
namespace {

static_assert(std::endian::native == std::endian::little, "the shell artifact is written little-endian");
constexpr char kMagic[8] = {'M', 'F', 'S', 'H', 'E', 'L', 'L', '1'};

template <class T>
void put(std::string& s, const T* p, std::size_t n) {
  s.append(reinterpret_cast<const char*>(p), n * sizeof(T));
}

Vec3 normed(double x, double y, double z) {
  double l = std::sqrt(x * x + y * y + z * z);
  if (!(l > 0)) return {0, 0, 0};
  return {x / l, y / l, z / l};
}

}  // namespace

void write(const ShellData& s, const std::filesystem::path& file) {
  nlohmann::json h = nlohmann::json::parse(s.header);
  nlohmann::json arrays = nlohmann::json::array();
  std::string blob;
  nlohmann::json fg = nlohmann::json::array();
  for (auto& g : s.faces) {
    if (g.data.size() != static_cast<std::size_t>(g.nu) * g.nv * 4) throw std::logic_error("shell: face grid size");
    fg.push_back({{"face", g.face}, {"nu", g.nu}, {"nv", g.nv}, {"u0", g.u0}, {"u1", g.u1}, {"v0", g.v0}, {"v1", g.v1}});
    arrays.push_back({"face_grid_" + std::to_string(g.face), "f64", g.data.size()});
    put(blob, g.data.data(), g.data.size());
  }
  nlohmann::json ef = nlohmann::json::array();
  for (auto& e : s.edges) {
    std::size_t n = e.data.empty() ? 0 : e.data[0].size() / 4;
    ef.push_back({{"edge", e.edge}, {"t0", e.t0}, {"t1", e.t1}, {"sides", e.sides}, {"n", n}});
    for (std::size_t k = 0; k < e.data.size(); ++k) {
      if (e.data[k].size() != n * 4) throw std::logic_error("shell: edge field size");
      arrays.push_back({"edge_field_" + std::to_string(e.edge) + "_" + std::to_string(e.sides[k]), "f64", e.data[k].size()});
      put(blob, e.data[k].data(), e.data[k].size());
    }
  }
  nlohmann::json vv = nlohmann::json::array();
  for (auto& v : s.vertices) vv.push_back({{"vertex", v.vertex}, {"t", v.t}, {"d", v.d}});
  arrays.push_back({"shell_points", "f64", s.shell_points.size() * 3});
  put(blob, s.shell_points.data()->data(), s.shell_points.size() * 3);
  arrays.push_back({"shell_wall", "f64", s.shell_wall.size() * 3});
  put(blob, s.shell_wall.data()->data(), s.shell_wall.size() * 3);
  arrays.push_back({"shell_tris", "i32", s.shell_tris.size() * 3});
  put(blob, s.shell_tris.data()->data(), s.shell_tris.size() * 3);
  arrays.push_back({"shell_tri_face", "i32", s.shell_tri_face.size()});
  put(blob, s.shell_tri_face.data(), s.shell_tri_face.size());
  h["face_grids"] = fg;
  h["edge_fields"] = ef;
  h["vertex_values"] = vv;
  h["arrays"] = arrays;
  std::string js = h.dump();
  std::string out(kMagic, 8);
  std::uint32_t L = static_cast<std::uint32_t>(js.size());
  put(out, &L, 1);
  out += js;
  out += blob;
  std::ofstream f(file, std::ios::binary | std::ios::trunc);
  f.write(out.data(), static_cast<std::streamsize>(out.size()));
  f.close();
  if (!f) throw StageError("shell: writing " + file.string() + " failed (disk full?)");
}

ShellData read(const std::filesystem::path& file) {
  std::ifstream in(file, std::ios::binary);
  if (!in) throw StageError("shell artifact " + file.string() + " cannot be read; re-run the shell stage");
  std::stringstream ss;
  ss << in.rdbuf();
  const std::string s = ss.str();
  auto bad = [&](const std::string& what) {
    return StageError("shell artifact " + file.string() + " is corrupt (" + what +
                      "); re-run the shell stage (meshflow clean) to rebuild it");
  };
  if (s.size() < 12 || std::memcmp(s.data(), kMagic, 8) != 0) throw bad("not a MFSHELL1 file");
  std::uint32_t L;
  std::memcpy(&L, s.data() + 8, 4);
  if (s.size() < 12 + std::size_t(L)) throw bad("truncated header");
  nlohmann::json h;
  try {
    h = nlohmann::json::parse(s.substr(12, L));
  } catch (const std::exception& e) {
    throw bad(std::string("header: ") + e.what());
  }
  std::size_t at = 12 + L;
  auto take = [&](std::size_t bytes) {
    if (s.size() - at < bytes) throw bad("truncated data");
    const char* p = s.data() + at;
    at += bytes;
    return p;
  };
  ShellData d;
  try {
    for (auto& g : h.at("face_grids")) {
      FaceGrid G;
      G.face = g.at("face"), G.nu = g.at("nu"), G.nv = g.at("nv");
      G.u0 = g.at("u0"), G.u1 = g.at("u1"), G.v0 = g.at("v0"), G.v1 = g.at("v1");
      G.data.resize(std::size_t(G.nu) * G.nv * 4);
      std::memcpy(G.data.data(), take(G.data.size() * 8), G.data.size() * 8);
      d.faces.push_back(std::move(G));
    }
    for (auto& e : h.at("edge_fields")) {
      EdgeField E;
      E.edge = e.at("edge"), E.t0 = e.at("t0"), E.t1 = e.at("t1");
      E.sides = e.at("sides").get<std::vector<int>>();
      std::size_t n = e.at("n");
      for (std::size_t k = 0; k < E.sides.size(); ++k) {
        std::vector<double> v(n * 4);
        std::memcpy(v.data(), take(v.size() * 8), v.size() * 8);
        E.data.push_back(std::move(v));
      }
      d.edges.push_back(std::move(E));
    }
    for (auto& v : h.at("vertex_values")) d.vertices.push_back({v.at("vertex"), v.at("t"), v.at("d").get<Vec3>()});
    auto& arr = h.at("arrays");
    auto count = [&](const std::string& name) -> std::size_t {
      for (auto& a : arr)
        if (a.at(0) == name) return a.at(2);
      throw bad("no array " + name);
    };
    std::size_t np = count("shell_points") / 3;
    d.shell_points.resize(np);
    std::memcpy(d.shell_points.data(), take(np * 24), np * 24);
    std::size_t nw = count("shell_wall") / 3;
    d.shell_wall.resize(nw);
    std::memcpy(d.shell_wall.data(), take(nw * 24), nw * 24);
    std::size_t nt = count("shell_tris") / 3;
    d.shell_tris.resize(nt);
    std::memcpy(d.shell_tris.data(), take(nt * 12), nt * 12);
    std::size_t nf = count("shell_tri_face");
    d.shell_tri_face.resize(nf);
    std::memcpy(d.shell_tri_face.data(), take(nf * 4), nf * 4);
  } catch (const StageError&) {
    throw;
  } catch (const std::exception& e) {
    throw bad(e.what());
  }
  if (at != s.size()) throw bad("trailing bytes");
  for (auto& t : d.shell_tris)
    for (int i : t)
      if (i < 0 || static_cast<std::size_t>(i) >= d.shell_points.size()) throw bad("triangle index out of range");
  d.header = h.dump();
  return d;
}

std::pair<double, Vec3> grid_field(const FaceGrid& g, double u, double v) {
  double x = g.nu > 1 && g.u1 > g.u0 ? (u - g.u0) / (g.u1 - g.u0) * (g.nu - 1) : 0;
  double y = g.nv > 1 && g.v1 > g.v0 ? (v - g.v0) / (g.v1 - g.v0) * (g.nv - 1) : 0;
  x = std::clamp(x, 0.0, double(g.nu - 1));
  y = std::clamp(y, 0.0, double(g.nv - 1));
  int i = std::min(int(x), std::max(g.nu - 2, 0)), j = std::min(int(y), std::max(g.nv - 2, 0));
  double a = x - i, b = y - j;
  double r[4] = {0, 0, 0, 0};
  for (int dj = 0; dj < 2; ++dj)
    for (int di = 0; di < 2; ++di) {
      int ii = std::min(i + di, g.nu - 1), jj = std::min(j + dj, g.nv - 1);
      double w = (di ? a : 1 - a) * (dj ? b : 1 - b);
      const double* p = &g.data[(std::size_t(jj) * g.nu + ii) * 4];
      for (int k = 0; k < 4; ++k) r[k] += w * p[k];
    }
  return {r[0], normed(r[1], r[2], r[3])};
}

std::pair<double, Vec3> grid_field_on(const FaceGrid& g, const cad::Shape& shape, double u, double v) {
  using namespace cad::vec;
  auto per = shape.face_periods(g.face);
  const double lo[2] = {g.u0, g.v0}, hi[2] = {g.u1, g.v1};
  double* x[2] = {&u, &v};
  for (int c = 0; c < 2; ++c)
    if (per[c] > 0 && (*x[c] < lo[c] || *x[c] > hi[c])) {
      double mid = 0.5 * (lo[c] + hi[c]);
      *x[c] -= per[c] * std::round((*x[c] - mid) / per[c]);
    }
  auto td = grid_field(g, u, v);
  if (g.nu < 2 || g.nv < 2 || !(g.u1 > g.u0) || !(g.v1 > g.v0)) return td;
  V3 nx = mul(v3(shape.face_normal(g.face, u, v)), -1.0);
  if (norm(nx) < 0.5) return td;  // a pole: the grid's direction
  double xi = std::clamp((u - g.u0) / (g.u1 - g.u0) * (g.nu - 1), 0.0, double(g.nu - 1));
  double yj = std::clamp((v - g.v0) / (g.v1 - g.v0) * (g.nv - 1), 0.0, double(g.nv - 1));
  int i = std::min(int(xi), g.nu - 2), j = std::min(int(yj), g.nv - 2);
  double a = xi - i, b = yj - j;
  V3 dev{0, 0, 0};
  double min_dot = 1;  // the largest turn of the normal between the cell's corners and x
  for (int dj = 0; dj < 2; ++dj)
    for (int di = 0; di < 2; ++di) {
      int ii = i + di, jj = j + dj;
      double w = (di ? a : 1 - a) * (dj ? b : 1 - b);
      double uc = g.u0 + (g.u1 - g.u0) * ii / (g.nu - 1), vc = g.v0 + (g.v1 - g.v0) * jj / (g.nv - 1);
      V3 nc = mul(v3(shape.face_normal(g.face, uc, vc)), -1.0);
      if (norm(nc) < 0.5) return td;  // a pole at a corner: the grid's direction
      min_dot = std::min(min_dot, dot(nc, nx));
      const double* p = &g.data[(std::size_t(jj) * g.nu + ii) * 4];
      dev = add(dev, mul(sub(V3{p[1], p[2], p[3]}, nc), w));
    }
  // where the normal turns by less than 30 degrees across the cell the grid resolves it: its
  // own interpolation is kept (and the meshes of such faces are unchanged by this correction)
  if (min_dot > std::cos(30 * M_PI / 180)) return td;
  V3 d = add(nx, dev);
  double l = norm(d);
  if (!(l > 0.5)) return td;  // the deviation undoes the normal: keep the grid's direction
  return {td.first, mul(d, 1.0 / l)};
}

std::pair<double, Vec3> ShellData::face_field(int face, double u, double v) const {
  for (auto& g : faces)
    if (g.face == face) return grid_field(g, u, v);
  throw std::out_of_range("shell: no field grid for face " + std::to_string(face));
}

std::pair<double, Vec3> ShellData::edge_field(int edge, double t, int face) const {
  for (auto& e : edges) {
    if (e.edge != edge) continue;
    std::size_t side = 0;
    for (std::size_t k = 0; k < e.sides.size(); ++k)
      if (e.sides[k] == face) side = k;
    const auto& D = e.data[side];
    int n = static_cast<int>(D.size() / 4);
    double x = n > 1 && e.t1 > e.t0 ? (t - e.t0) / (e.t1 - e.t0) * (n - 1) : 0;
    x = std::clamp(x, 0.0, double(n - 1));
    int i = std::min(int(x), std::max(n - 2, 0));
    double a = x - i;
    int i1 = std::min(i + 1, n - 1);
    double r[4];
    for (int k = 0; k < 4; ++k) r[k] = (1 - a) * D[i * 4 + k] + a * D[i1 * 4 + k];
    return {r[0], normed(r[1], r[2], r[3])};
  }
  throw std::out_of_range("shell: no field for edge " + std::to_string(edge));
}

nlohmann::json ShellData::summary() const {
  nlohmann::json h = nlohmann::json::parse(header);
  nlohmann::json j;
  j["counts"] = h.value("counts", nlohmann::json::object());
  j["stats"] = h.value("stats", nlohmann::json::object());
  long prisms = 0, hexes = 0;
  for (auto& b : h.value("blocks", nlohmann::json::array())) (b.at("kind") == "prism_sweep" ? prisms : hexes)++;
  j["blocks"] = {{"prism_sweep", prisms}, {"hex_junction", hexes}};
  j["shell_points"] = shell_points.size();
  j["shell_triangles"] = shell_tris.size();
  double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
  for (auto& p : shell_points)
    for (int k = 0; k < 3; ++k) lo[k] = std::min(lo[k], p[k]), hi[k] = std::max(hi[k], p[k]);
  if (!shell_points.empty()) j["bbox"] = {{lo[0], lo[1], lo[2]}, {hi[0], hi[1], hi[2]}};
  return j;
}

namespace {
ArtifactTypeRegistrar reg({
    .type = "shell",
    .extension = ".mfshell",
    .summary = "near-field shell: thickness/direction fields per wall face/edge/vertex, block structure, sampled shell surface (MFSHELL1)",
    .formats = {},
    .summarize = [](const std::filesystem::path& p) { return read(p).summary(); },
});
}  // namespace

}  // namespace meshflow::shell
