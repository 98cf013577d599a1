// Nektar++ XML: the compressed form (B64Z-LittleEndian sections, Nektar++'s default) and the
// plain form read back to the same mesh; an independent decode with Python's standard library
// (base64, zlib, struct) finds the plain file's coordinates in the compressed VERTEX section;
// EXPANSIONS; corrupt compressed sections give clear errors.
#include <doctest/doctest.h>

#include "engine/artifact_type.hpp"
#include "engine/command.hpp"
#include "stages/io/mesh_io.hpp"
#include "stages/io/nektar_b64z.hpp"
#include "stages/model/quality.hpp"

#include <nlohmann/json.hpp>

#include <tbb/task_arena.h>
#include <unistd.h>

#include <cmath>
#include <cstring>

#include <filesystem>
#include <fstream>
#include <regex>
#include <sstream>

using namespace meshflow;
using namespace meshflow::model;
namespace fs = std::filesystem;

namespace {
const std::string kData = std::string(MESHFLOW_DATA_DIR) + "/highorder/";

fs::path tmp() {
  static fs::path d = [] {
    auto p = fs::temp_directory_path() / ("mf_nektar_test_" + std::to_string(::getpid()));
    fs::create_directories(p);
    return p;
  }();
  return d;
}
std::string slurp(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), {}};
}
fs::path put(const std::string& name, const std::string& text) {
  auto p = tmp() / name;
  std::ofstream(p, std::ios::binary) << text;
  return p;
}
int run_cmd(const std::string& name, std::vector<std::string> args) {
  const Command* c = find_command(name);
  REQUIRE(c != nullptr);
  return c->run(args);
}
const char* kGmshMeshes[] = {"v4.1_cube_all.msh", "v4.1_cube_hex.msh", "v4.1_cube_prism.msh", "v4.1_cube_tet.msh"};
}  // namespace

TEST_CASE("Nektar++ XML: compressed and plain files of Gmsh-made meshes of every 3D type read back to the same mesh") {
  for (const char* f : kGmshMeshes) {
    INFO(f);
    Mesh m = io::read_mesh(kData + f);
    auto zc = tmp() / "c.xml", pl = tmp() / "p.xml", again = tmp() / "c2.xml";
    io::write_nektar(m, zc);
    io::write_nektar(m, pl, false);
    const std::string zbytes = slurp(zc), pbytes = slurp(pl);
    CHECK(zbytes.find("<VERTEX COMPRESSED=\"B64Z-LittleEndian\" BITSIZE=\"64\">") != std::string::npos);
    CHECK(pbytes.find("COMPRESSED") == std::string::npos);
    CHECK(zbytes.size() < pbytes.size());
    io::write_nektar(m, again);  // deterministic bytes
    CHECK(slurp(again) == zbytes);
    Mesh a = io::read_mesh(zc), b = io::read_mesh(pl);
    REQUIRE(a.num_nodes() == b.num_nodes());
    CHECK(a.x == b.x);  // exactly: both forms carry the same doubles
    CHECK(a.y == b.y);
    CHECK(a.z == b.z);
    REQUIRE(a.blocks.size() == b.blocks.size());
    for (size_t k = 0; k < a.blocks.size(); ++k) {
      CHECK(a.blocks[k].shape == b.blocks[k].shape);
      CHECK(a.blocks[k].nodes == b.blocks[k].nodes);
      CHECK(a.blocks[k].entity_tag == b.blocks[k].entity_tag);
    }
    auto s0 = mesh_stats(m), s = mesh_stats(a);
    CHECK(s["order"] == s0["order"]);
    CHECK(s["elements"] == s0["elements"]);
    CHECK(s["boundary"] == s0["boundary"]);
    CHECK(s["invalid"] == 0);
    CHECK(s["nonconforming_faces"] == 0);
    // EXPANSIONS: one per volume composite, NUMMODES = order + 1
    const std::string modes = "NUMMODES=\"" + std::to_string(m.order() + 1) + "\" TYPE=\"MODIFIED\" FIELDS=\"u\" />";
    const std::regex dom("<DOMAIN> C\\[([0-9]+)(-([0-9]+))? *\\] </DOMAIN>");
    std::smatch dm;
    REQUIRE(std::regex_search(zbytes, dm, dom));
    const int c0 = std::stoi(dm[1]), c1 = dm[3].matched ? std::stoi(dm[3]) : c0;
    for (int c = c0; c <= c1; ++c)
      for (auto* text : {&zbytes, &pbytes})
        CHECK(text->find("<E COMPOSITE=\"C[" + std::to_string(c) + "]\" " + modes) != std::string::npos);
    CHECK(zbytes.find("</GEOMETRY>\n  <EXPANSIONS>") != std::string::npos);
  }
}

TEST_CASE("Nektar++ XML: Python's base64 + zlib + struct decode of the compressed sections gives the plain file's data") {
  Mesh m = io::read_mesh(kData + "v4.1_cube_prism.msh");  // prisms: triangles and quadrilaterals
  auto zc = tmp() / "py_c.xml", pl = tmp() / "py_p.xml";
  io::write_nektar(m, zc);
  io::write_nektar(m, pl, false);
  const std::string script = R"(import base64, struct, sys, zlib
import xml.etree.ElementTree as ET
def records(text, fmt):
    raw = base64.b64decode(''.join(text.split()), validate=True)
    d = zlib.decompressobj()
    data = d.decompress(raw)
    assert d.eof and d.unused_data.strip(b'\0') == b'', 'stream'
    assert len(data) % struct.calcsize(fmt) == 0, 'size'
    return list(struct.iter_unpack(fmt, data))
zc = ET.parse(sys.argv[1]).getroot().find('GEOMETRY')
pl = ET.parse(sys.argv[2]).getroot().find('GEOMETRY')
assert zc.find('VERTEX').get('COMPRESSED') == 'B64Z-LittleEndian'
v = {int(i): (x, y, z) for i, x, y, z in records(zc.find('VERTEX').text, '<qddd')}
pv = {int(e.get('ID')): tuple(float(t) for t in e.text.split()) for e in pl.find('VERTEX')}
assert v == pv, 'vertices differ'
e = {i: (a, b) for i, a, b in records(zc.find('EDGE').text, '<qqq')}
pe = {int(x.get('ID')): tuple(int(t) for t in x.text.split()) for x in pl.find('EDGE')}
assert e == pe, 'edges differ'
cv = zc.find('CURVED')
index = [i for (i,) in records(cv.find('DATAPOINTS/INDEX').text, '<q')]
pts = records(cv.find('DATAPOINTS/POINTS').text, '<qddd')
faces = {}
for ci in records(cv.find('F').text, '<qqqqqq'):
    _, fid, n, _, off, ptype = ci
    faces[fid] = [c for k in index[off:off + n] for c in pts[k][1:]]
pf = {int(x.get('FACEID')): [float(t) for t in x.text.split()] for x in pl.find('CURVED') if x.tag == 'F'}
assert faces == pf, 'curved faces differ'
print('ok', len(v), len(e), len(faces), len(pts), len(index))
)";
  auto py = put("decode.py", script), out = tmp() / "decode.txt";
  const std::string cmd = std::string(MESHFLOW_PYTHON) + " " + py.string() + " " + zc.string() + " " + pl.string() + " > " + out.string() + " 2>&1";
  const int rc = std::system(cmd.c_str());
  const std::string said = slurp(out);
  INFO(said);
  REQUIRE(rc == 0);
  CHECK(said.rfind("ok ", 0) == 0);
}

TEST_CASE("Nektar++ XML: a section of many pieces is one zlib stream, the same at any thread count, read by Python's zlib") {
  // 3.5 pieces of 1 MiB: order-4 coordinates' kind of data (smooth doubles, compressible, not
  // trivially) and a run of zeros across a piece boundary (a back-reference into the dictionary)
  std::vector<double> v((7u << 20) / 2 / sizeof(double));
  for (std::size_t i = 0; i < v.size(); ++i) v[i] = std::sin(0.001 * double(i)) * 1000.0 + double(i % 97);
  std::fill(v.begin() + (1u << 17) - 1000, v.begin() + (1u << 17) + 1000, 0.0);
  const std::size_t bytes = v.size() * sizeof(double);
  REQUIRE(bytes > 3 * (1u << 20));
  std::string one, two;
  tbb::task_arena(1).execute([&] { one = io::nektar::encode(v.data(), bytes); });
  tbb::task_arena(2).execute([&] { two = io::nektar::encode(v.data(), bytes); });
  CHECK(one == two);
  CHECK(one.find('=') == std::string::npos);  // Nektar++'s zero padding, no '='
  CHECK(one.size() / 4 * 3 < bytes);          // it compresses (base64: 4 characters per 3 bytes)
  const std::string back = io::nektar::decode(one, "test");
  REQUIRE(back.size() == bytes);
  CHECK(std::memcmp(back.data(), v.data(), bytes) == 0);
  // an independent inflate: Python's zlib, which checks the Adler-32 of the whole stream
  auto b64 = tmp() / "pieces.b64", raw = tmp() / "pieces.raw", py = tmp() / "pieces.py", said = tmp() / "pieces.txt";
  std::ofstream(b64, std::ios::binary) << one;
  std::ofstream(raw, std::ios::binary).write(reinterpret_cast<const char*>(v.data()), std::streamsize(bytes));
  std::ofstream(py) << "import base64, sys, zlib\n"
                       "d = zlib.decompressobj()\n"
                       "data = d.decompress(base64.b64decode(open(sys.argv[1], 'rb').read(), validate=True))\n"
                       "assert d.eof and d.unused_data.strip(b'\\0') == b'', 'one stream'\n"
                       "assert data == open(sys.argv[2], 'rb').read(), 'data'\n"
                       "print('ok', len(data))\n";
  const std::string cmd = std::string(MESHFLOW_PYTHON) + " " + py.string() + " " + b64.string() + " " + raw.string() + " > " +
                          said.string() + " 2>&1";
  const int rc = std::system(cmd.c_str());
  INFO(slurp(said));
  CHECK(rc == 0);
  CHECK(slurp(said) == "ok " + std::to_string(bytes) + "\n");
}

TEST_CASE("Nektar++ XML: corrupt compressed sections give a clear MeshIOError and exit 2") {
  Mesh m = io::read_mesh(kData + "v4.1_cube_prism.msh");
  auto good = tmp() / "good.xml";
  io::write_nektar(m, good);
  const std::string text = slurp(good);
  const std::string open = "<VERTEX COMPRESSED=\"B64Z-LittleEndian\" BITSIZE=\"64\">";
  const size_t a = text.find(open) + open.size(), b = text.find("</VERTEX>");
  REQUIRE(b > a + 40);
  auto with_vertex = [&](const std::string& payload) { return text.substr(0, a) + payload + text.substr(b); };
  const std::string body = text.substr(a, b - a);
  const char junk[34] = "not a zlib stream";  // 33 bytes read below (zero-padded)
  struct Case {
    const char* name;
    std::string text;
    const char* msg;
  } cases[] = {
      {"b64.xml", with_vertex(body.substr(0, 20) + "!" + body.substr(21)), "not base64"},
      {"zlib.xml", with_vertex("bm90IGEgemxpYiBzdHJlYW0h"), "not a valid zlib stream"},  // base64 of "not a zlib stream!"
      {"cut.xml", with_vertex(body.substr(0, body.size() / 2 / 4 * 4)), "ends before its zlib stream does"},
      {"size.xml", with_vertex(io::nektar::encode(junk, 33)), "not a whole number of MeshVertex records of 32 bytes"},
      {"endian.xml", [&] {
         std::string t = text;
         t.replace(t.find("B64Z-LittleEndian"), 17, "B64Z-BigEndian");
         return t;
       }(), "not B64Z-LittleEndian"},
  };
  for (auto& c : cases) {
    INFO(c.name);
    auto p = put(c.name, c.text);
    try {
      io::read_mesh(p);
      FAIL("no exception");
    } catch (const io::MeshIOError& e) {
      const std::string w = e.what();
      CHECK(w.find(p.string() + ":line ") != std::string::npos);
      const bool names_section = w.find("<VERTEX>") != std::string::npos || std::string(c.name) == "endian.xml";
      CHECK(names_section);
      CHECK(w.find(c.msg) != std::string::npos);
    }
    CHECK(run_cmd("convert", {p.string(), (tmp() / "x.msh").string()}) == 2);
  }
}

TEST_CASE("Nektar++ XML: convert --plain, formats nektar and nektar-plain, no partial file on failure") {
  auto c = tmp() / "cv.xml", p = tmp() / "cv_plain.xml";
  CHECK(run_cmd("convert", {kData + "v4.1_cube_tet.msh", c.string()}) == 0);
  CHECK(run_cmd("convert", {kData + "v4.1_cube_tet.msh", p.string(), "--plain"}) == 0);
  CHECK(slurp(c).find("COMPRESSED=\"B64Z-LittleEndian\"") != std::string::npos);
  CHECK(slurp(p).find("COMPRESSED") == std::string::npos);
  CHECK(slurp(p).find("NUMMODES=\"7\"") != std::string::npos);  // order 6
  const ArtifactType* t = find_artifact_type("mesh");
  REQUIRE(t);
  REQUIRE(t->formats.count("nektar-plain") == 1);
  auto stored = tmp() / "stored.msh";
  io::write_msh(io::read_mesh(kData + "v4.1_cube_hex.msh"), stored);
  auto ez = tmp() / "e.xml", ep = tmp() / "e.plain.xml";
  t->formats.at("nektar").write(stored, ez);
  t->formats.at("nektar-plain").write(stored, ep);
  CHECK(slurp(ez).find("COMPRESSED") != std::string::npos);
  CHECK(slurp(ep).find("COMPRESSED") == std::string::npos);
  CHECK(mesh_stats(io::read_mesh(ez))["elements"] == mesh_stats(io::read_mesh(ep))["elements"]);
  // a mesh Nektar++ cannot take (two orders): an error, and neither the file nor its temporary
  Mesh m = io::read_mesh(kData + "v4.1_cube_tet.msh");
  m.blocks.push_back(m.blocks.front());
  m.blocks.back().order = 1;
  auto bad = tmp() / "bad.xml";
  CHECK_THROWS_AS(io::write_nektar(m, bad), std::exception);
  CHECK_FALSE(fs::exists(bad));
  CHECK_FALSE(fs::exists(tmp() / "bad.xml.tmp"));
}
