// meshflow medial — the "medial" artifact: writer, reader, summary, artifact type. Format: see
// medial.hpp. No CGAL, no OCCT.
#include "engine/artifact_type.hpp"
#include "engine/stage.hpp"
#include "stages/medial/medial.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <bit>
#include <cstring>
#include <fstream>
#include <map>
#include <sstream>

namespace meshflow::medial {
namespace {

static_assert(std::endian::native == std::endian::little, "the medial artifact is written little-endian");

constexpr char kMagic[8] = {'M', 'F', 'M', 'E', 'D', 'I', 'A', 'L'};
constexpr std::uint32_t kVersion = 1;
constexpr std::size_t kSampleBytes = 12 * 8 + 8 * 4 + 4;  // 132
constexpr std::size_t kPointBytes = 5 * 8 + 4 * 4 + 4;
constexpr std::size_t kHaloBytes = 6 * 4;

class Out {
 public:
  template <class T>
  void put(T v) {
    char b[sizeof(T)];
    std::memcpy(b, &v, sizeof(T));
    s_.append(b, sizeof(T));
  }
  void bytes(const char* p, std::size_t n) { s_.append(p, n); }
  std::string s_;
};

class In {
 public:
  In(const std::string& s, const std::filesystem::path& f) : s_(s), f_(f) {}
  template <class T>
  T get() {
    need(sizeof(T));
    T v;
    std::memcpy(&v, s_.data() + at_, sizeof(T));
    at_ += sizeof(T);
    return v;
  }
  std::string bytes(std::size_t n) {
    need(n);
    std::string r = s_.substr(at_, n);
    at_ += n;
    return r;
  }
  void need(std::size_t n) const {
    if (s_.size() - at_ < n)
      throw StageError("medial artifact " + f_.string() + " is truncated (at byte " + std::to_string(at_) +
                       "); re-run the medial stage (meshflow clean) to rebuild it");
  }
  std::uint64_t count(std::size_t record) {
    auto n = get<std::uint64_t>();
    if (record && n > (s_.size() - at_) / record + 1) need(n * record);
    return n;
  }
  bool done() const { return at_ == s_.size(); }

 private:
  const std::string& s_;
  const std::filesystem::path& f_;
  std::size_t at_ = 0;
};

double median(std::vector<double> v) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}
nlohmann::json stats_of(std::vector<double> v) {
  if (v.empty()) return {{"count", 0}};
  std::sort(v.begin(), v.end());
  return {{"count", v.size()}, {"min", v.front()}, {"median", v[v.size() / 2]}, {"max", v.back()}};
}

}  // namespace

void write(const MedialObject& m, const std::filesystem::path& file) {
  Out o;
  o.bytes(kMagic, 8);
  o.put<std::uint32_t>(kVersion);
  std::string h = nlohmann::json::parse(m.header).dump();  // canonical: keys sorted
  o.put<std::uint32_t>(static_cast<std::uint32_t>(h.size()));
  o.bytes(h.data(), h.size());
  o.put<std::uint64_t>(m.samples.size());
  for (std::size_t i = 0; i < m.samples.size(); ++i) {
    const Sample& s = m.samples[i];
    SampleInfo si = i < m.info.size() ? m.info[i] : SampleInfo{};
    for (double x : s.p) o.put(x);
    for (double x : s.n) o.put(x);
    o.put(s.u), o.put(s.v), o.put(s.h), o.put(si.lfs), o.put(si.r_in), o.put(si.r_out);
    o.put(s.kind), o.put(s.id);
    for (auto f : s.faces) o.put(f);
    o.put(si.pole_in), o.put(si.pole_out), o.put(si.halo_face);
    o.put<std::uint8_t>(s.refined ? 1 : 0);
    o.put<std::uint8_t>(0), o.put<std::uint8_t>(0), o.put<std::uint8_t>(0);
  }
  o.put<std::uint64_t>(m.points.size());
  for (const MedialPoint& p : m.points) {
    for (double x : p.c) o.put(x);
    o.put(p.radius), o.put(p.ball_radius);
    for (auto c : p.contacts) o.put(c);
    o.put(static_cast<std::uint8_t>(p.side));
    o.put<std::uint8_t>(p.halo ? 1 : 0);
    o.put(p.object_angle_deg);
    o.put<std::uint8_t>(0);
  }
  o.put<std::uint64_t>(m.halos.size());
  for (const Halo& h2 : m.halos) {
    o.put(h2.medial), o.put(h2.sample_a), o.put(h2.sample_b), o.put(h2.face_a), o.put(h2.face_b);
    o.put<std::int32_t>(0);
  }
  std::ofstream f(file, std::ios::binary | std::ios::trunc);
  f.write(o.s_.data(), static_cast<std::streamsize>(o.s_.size()));
  if (!f) throw StageError("medial: cannot write " + file.string());
}

MedialObject read(const std::filesystem::path& file) {
  std::ifstream f(file, std::ios::binary);
  if (!f) throw StageError("medial artifact " + file.string() + " cannot be opened; re-run the medial stage");
  std::stringstream ss;
  ss << f.rdbuf();
  std::string data = ss.str();
  In in(data, file);
  if (in.bytes(8) != std::string(kMagic, 8))
    throw StageError("file " + file.string() + " is not a meshflow medial artifact (bad magic); check the workflow's needs");
  auto ver = in.get<std::uint32_t>();
  if (ver != kVersion)
    throw StageError("medial artifact " + file.string() + " has format version " + std::to_string(ver) + ", this build reads " +
                     std::to_string(kVersion) + "; re-run the medial stage");
  MedialObject m;
  auto hl = in.get<std::uint32_t>();
  m.header = in.bytes(hl);
  if (!nlohmann::json::accept(m.header)) throw StageError("medial artifact " + file.string() + " has a corrupt header");
  auto ns = in.count(kSampleBytes);
  m.samples.resize(ns);
  m.info.resize(ns);
  for (std::size_t i = 0; i < ns; ++i) {
    Sample& s = m.samples[i];
    SampleInfo& si = m.info[i];
    for (double& x : s.p) x = in.get<double>();
    for (double& x : s.n) x = in.get<double>();
    s.u = in.get<double>(), s.v = in.get<double>(), s.h = in.get<double>();
    si.lfs = in.get<double>(), si.r_in = in.get<double>(), si.r_out = in.get<double>();
    s.kind = in.get<std::int32_t>(), s.id = in.get<std::int32_t>();
    for (auto& fc : s.faces) fc = in.get<std::int32_t>();
    si.pole_in = in.get<std::int32_t>(), si.pole_out = in.get<std::int32_t>(), si.halo_face = in.get<std::int32_t>();
    s.refined = in.get<std::uint8_t>() != 0;
    in.bytes(3);
  }
  auto np = in.count(kPointBytes);
  m.points.resize(np);
  for (auto& p : m.points) {
    for (double& x : p.c) x = in.get<double>();
    p.radius = in.get<double>(), p.ball_radius = in.get<double>();
    for (auto& c : p.contacts) c = in.get<std::int32_t>();
    p.side = static_cast<Side>(in.get<std::uint8_t>());
    p.halo = in.get<std::uint8_t>() != 0;
    p.object_angle_deg = in.get<std::uint8_t>();
    in.bytes(1);
  }
  auto nh = in.count(kHaloBytes);
  m.halos.resize(nh);
  for (auto& h : m.halos) {
    h.medial = in.get<std::int32_t>(), h.sample_a = in.get<std::int32_t>(), h.sample_b = in.get<std::int32_t>();
    h.face_a = in.get<std::int32_t>(), h.face_b = in.get<std::int32_t>();
    in.get<std::int32_t>();
  }
  if (!in.done()) throw StageError("medial artifact " + file.string() + " has trailing bytes; re-run the medial stage");
  // index sanity: a corrupt file must not make readers index out of range
  auto bad = [&](std::int64_t v, std::size_t n) { return v < -1 || v >= static_cast<std::int64_t>(n); };
  for (auto& si : m.info)
    if (bad(si.pole_in, np) || bad(si.pole_out, np)) throw StageError("medial artifact " + file.string() + " is corrupt (pole index)");
  for (auto& p : m.points)
    for (auto c : p.contacts)
      if (c < 0 || c >= static_cast<std::int64_t>(ns)) throw StageError("medial artifact " + file.string() + " is corrupt (contact index)");
  for (auto& h : m.halos)
    if (h.medial < 0 || h.medial >= static_cast<std::int64_t>(np) || bad(h.sample_a, ns) || bad(h.sample_b, ns))
      throw StageError("medial artifact " + file.string() + " is corrupt (halo)");
  return m;
}

nlohmann::json MedialObject::summary() const {
  nlohmann::json j;
  std::vector<double> rf, rb, lfs_ref, lfs_all;
  long nf = 0, nb = 0;
  for (auto& p : points) (p.side == Side::fluid ? (++nf, rf) : (++nb, rb)).push_back(p.radius);
  for (std::size_t i = 0; i < samples.size() && i < info.size(); ++i) {
    if (info[i].lfs < 0) continue;
    lfs_all.push_back(info[i].lfs);
    if (samples[i].refined) lfs_ref.push_back(info[i].lfs);
  }
  long halo_samples = 0;
  for (auto& si : info) halo_samples += si.halo_face >= 0;
  std::map<std::string, long> pairs;
  for (auto& h : halos) pairs[std::to_string(h.face_a) + "-" + std::to_string(h.face_b)]++;
  j["samples"] = samples.size();
  j["medial_points"] = {{"fluid", nf}, {"body", nb}};
  j["radius_fluid"] = stats_of(rf);
  j["radius_body"] = stats_of(rb);
  j["lfs_walls"] = stats_of(lfs_ref);
  j["lfs_all"] = stats_of(lfs_all);
  j["halos"] = halos.size();
  j["halo_samples"] = halo_samples;
  j["halo_face_pairs"] = pairs;
  (void)median;
  return j;
}

namespace {
ArtifactTypeRegistrar reg({
    .type = "medial",
    .extension = ".mfmedial",
    .summary = "medial object: boundary samples with LFS, medial points with radius, halos (MFMEDIAL 1 binary)",
    .formats = {},
    .summarize = [](const std::filesystem::path& p) { return read(p).summary(); },
});
}  // namespace

}  // namespace meshflow::medial
